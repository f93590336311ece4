"""Cook–Torrance with Bitterling et al.'s incidence-dependent roughness α(θi) (Eq. 20).

Independent references, written here: the values of α(θi) the paper's fit gives (Fig. 4: a
sigmoid from 0.42 to 0.24; 0.4206 at 0°, 0.2831 at 60°, 0.2333 at 80°, four digits); the
paper's Eq. 11–15 with Eq. 12 written in θm and the Fresnel reflectance from r_s, r_p; and a
directional-hemispherical reflectance by a half-vector quadrature written here.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from brdftab import models
from brdftab.checks import run_checks
from brdftab.errors import ParameterError
from brdftab.models.bitterling import alpha_of_theta
from brdftab.spec import load_spec

SPECS = Path(__file__).resolve().parent.parent / "specs"
FIT = dict(n=1.43, r_dh_lam=0.0110, p1=0.1012, p2=2.661, p3=math.radians(51.51), p4=0.2199)


def _vec(theta, phi=0.0):
    return np.array([math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta)])


def test_alpha_of_theta_is_the_papers_sigmoid():
    m = models.create("cook-torrance-alpha-theta", **FIT)
    got = m.alpha(np.radians([0.0, 60.0, 80.0]))
    np.testing.assert_allclose(got, [0.4206, 0.2831, 0.2333], atol=0.001)
    # the shipped spec gives p3 in degrees (p3_deg): the same function
    spec = load_spec(SPECS / "pyromark-cook-torrance.toml").model
    np.testing.assert_allclose(spec.alpha(np.radians([0.0, 60.0, 80.0])), got, rtol=1e-12)
    # θi and p3 in degrees would turn Eq. 20 into a step (0.4223 up to 51.5°, then 0.2199): not that
    step = lambda deg: FIT["p1"] * (1 - math.tanh(FIT["p2"] * (deg - 51.51))) + FIT["p4"]  # noqa: E731
    assert step(30.0) == pytest.approx(0.4223, abs=1e-4) and step(60.0) == pytest.approx(0.2199, abs=1e-4)
    a30, a60 = m.alpha(np.radians([30.0, 60.0]))
    assert abs(a30 - step(30.0)) > 0.02 and abs(a60 - step(60.0)) > 0.05
    # a sigmoid decreasing from 0.42 to about 0.22 (the paper's Fig. 4 range 0.42 … 0.24)
    a = m.alpha(np.radians(np.arange(0.0, 90.5, 0.5)))
    assert np.all(np.diff(a) < 0) and a[0] < 0.43 and a[-1] > 0.22


def test_alpha_of_theta_keeps_its_relative_accuracy_on_the_floor():
    """Where tanh → 1, α = p1 (1 − tanh x) + p4 is evaluated without the cancellation of 1 − tanh x
    (whose rounding, up to 2e-13 of α at p4 = 0.001, the Beckmann exponent would amplify), to a few
    ulp of a 40-digit evaluation."""
    import decimal

    p1, p2, p3, p4 = 1.0, 100.0, 0.2, 0.001
    theta = np.linspace(0.0, np.pi / 2, 401)
    got = alpha_of_theta(theta, p1, p2, p3, p4)
    with decimal.localcontext() as ctx:
        ctx.prec = 40
        ref = [float(decimal.Decimal(p1) * (1 - (e - 1) / (e + 1)) + decimal.Decimal(p4))
               for e in ((2 * decimal.Decimal(p2 * (float(t) - p3))).exp() for t in theta)]
    np.testing.assert_allclose(got, ref, rtol=1e-15, atol=0)


def _fresnel_ref(c, n):
    s2 = 1 - c * c
    ct = math.sqrt(1 - s2 / (n * n))
    rs = (c - n * ct) / (c + n * ct)
    rp = (n * c - ct) / (n * c + ct)
    return 0.5 * (rs * rs + rp * rp)


def test_brdf_is_eq_11_with_alpha_of_the_incidence():
    m = models.create("cook-torrance-alpha-theta", **FIT)
    rng = np.random.default_rng(5)
    for _ in range(40):
        ti, to = rng.uniform(0, math.radians(88), 2)
        wi, wo = _vec(ti, rng.uniform(0, 2 * math.pi)), _vec(to, rng.uniform(0, 2 * math.pi))
        a = FIT["p1"] * (1 - math.tanh(FIT["p2"] * (ti - FIT["p3"]))) + FIT["p4"]
        h = (wi + wo) / np.linalg.norm(wi + wo)
        tm = math.acos(h[2])
        d = a * a / (math.pi * (a * a * math.cos(tm) ** 2 + math.sin(tm) ** 2) ** 2)          # Eq. 12
        g1 = lambda t: 2 / (1 + math.sqrt(1 + a * a * math.tan(t) ** 2))                       # noqa: E731
        want = d * _fresnel_ref(float(wi @ h), FIT["n"]) * g1(ti) * g1(to) / (4 * wi[2] * wo[2]) \
            + FIT["r_dh_lam"] / math.pi
        assert m.eval(wi, wo)[0] == pytest.approx(want, rel=1e-12)
    # with the Beckmann distribution instead
    b = models.create("cook-torrance-alpha-theta", distribution="beckmann", **FIT)
    wi, wo = _vec(0.5), _vec(0.7, 2.9)
    a = float(b.alpha(0.5))
    h = (wi + wo) / np.linalg.norm(wi + wo)
    t2 = (h[0] ** 2 + h[1] ** 2) / h[2] ** 2
    d = math.exp(-t2 / (a * a)) / (math.pi * a * a * h[2] ** 4)

    def lam(w):
        x = 1 / (a * math.sqrt(w[0] ** 2 + w[1] ** 2) / w[2])
        return 0.5 * (math.exp(-x * x) / (x * math.sqrt(math.pi)) - math.erfc(x))
    want = d * _fresnel_ref(float(wi @ h), FIT["n"]) / ((1 + lam(wi)) * (1 + lam(wo)) * 4 * wi[2] * wo[2]) \
        + FIT["r_dh_lam"] / math.pi
    assert b.eval(wi, wo)[0] == pytest.approx(want, rel=1e-12)


def test_not_reciprocal_and_reported_as_warn():
    m = models.create("cook-torrance-alpha-theta", **FIT)
    assert not m.reciprocal
    wi, wo = _vec(math.radians(10.0)), _vec(math.radians(70.0), math.pi)
    f, g = m.eval(wi, wo)[0], m.eval(wo, wi)[0]
    assert abs(f - g) / (0.5 * (f + g)) > 0.1          # α(10°) = 0.41 vs α(70°) = 0.25
    out = run_checks(m, only=["reciprocity"]).get("reciprocity")
    assert out.status == "warn" and out.figure > 1e-6 and "declared non-reciprocal" in out.detail


def test_albedo_is_a_microfacet_albedo_at_alpha_of_theta():
    """For each θi the model is a GGX microfacet lobe of α(θi) plus R_dh,Lam: its albedo equals that of
    the plain microfacet model at that α (dielectric Fresnel), plus R_dh,Lam — by a half-vector
    quadrature written here (tanθh = α s/(1 − s), Gauss–Legendre in s × midpoint φh)."""
    m = models.create("cook-torrance-alpha-theta", **FIT)
    x, w = np.polynomial.legendre.leggauss(400)
    s, ws = 0.5 * (x + 1), 0.5 * w
    phi = (np.arange(256) + 0.5) * 2 * math.pi / 256
    for ti in np.radians([0.0, 45.0, 80.0]):
        a = float(m.alpha(ti))
        t = a * s / (1 - s)
        th = np.arctan(t)
        dth = a / (1 - s) ** 2 / (1 + t * t)
        tt, pp = np.meshgrid(th, phi, indexing="ij")
        h = np.stack([np.sin(tt) * np.cos(pp), np.sin(tt) * np.sin(pp), np.cos(tt)], axis=-1).reshape(-1, 3)
        wh = (np.repeat(ws * dth * np.sin(th), phi.size) * 2 * math.pi / phi.size)
        wi = _vec(ti)
        c = h @ wi
        wo = 2 * c[:, None] * h - wi
        keep = (c > 0) & (wo[:, 2] > 0)
        f = m.eval(np.broadcast_to(wi, wo[keep].shape), wo[keep])[:, 0] - FIT["r_dh_lam"] / math.pi
        spec = float(np.sum(f * wh[keep] * 4 * c[keep] * wo[keep, 2]))
        plain = models.create("microfacet", distribution="ggx", alpha=a, shadowing="smith", fresnel="dielectric",
                              n=FIT["n"])
        ref = float(np.sum(plain.eval(np.broadcast_to(wi, wo[keep].shape), wo[keep])[:, 0]
                           * wh[keep] * 4 * c[keep] * wo[keep, 2]))
        assert spec == pytest.approx(ref, rel=1e-12)
        assert 0.0 < spec < 1.0


def test_parameters_out_of_range_are_refused():
    with pytest.raises(ParameterError, match="p4"):
        models.create("cook-torrance-alpha-theta", **dict(FIT, p4=0.0))
    with pytest.raises(ParameterError, match="distribution"):
        models.create("cook-torrance-alpha-theta", **dict(FIT, distribution="phong"))
