"""He–Torrance–Sillion–Greenberg (``he-torrance-1991``) and Bitterling's modified HT model.

Independent references used here, all written in this file:

* the HTSG formulas of ``shared/reference/models.md`` §3.2 evaluated pair by pair with plain
  ``math`` (the m-series summed term by term over m = 1 … g + 60√g + 200 with ``math.lgamma``,
  the effective roughness from the closed form y = W(A²) of the transcendental equation,
  scipy's Lambert W), Fresnel from the complex amplitudes r_s, r_p;
* |F(0)|² = ((n − 1)² + k²)/((n + 1)² + k²) (energy balance of HTSG at normal incidence);
* the solid angle of Bitterling's Gaussian profile (Eq. 23) in closed form: the θ integral
  Im[e^{iθi − w²} w√π (erf((b − 2iw²)/(2w)) − erf((a − 2iw²)/(2w)))] (scipy's complex erf);
* directional-hemispherical reflectance (Bitterling Eq. 8) by quadratures written here:
  Gauss–Legendre in cosθo × midpoint azimuths, a rule about the mirror direction for the cone,
  panels graded about the Gaussian profile for the modified model;
* the paper's own figures: the standard HT fit's reflectance peak ("reversal point at
  θi = 82°"), and the monotonic rise of the modified model.
"""

from __future__ import annotations

import math
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from scipy.special import erf, lambertw

from brdftab import formats, models
from brdftab.checks import run_checks
from brdftab.errors import BrdftabWarning, ParameterError
from brdftab.grids import RusinkiewiczGrid
from brdftab.integrate import directional_albedo
from brdftab.models.he_torrance import G_MAX, effective_roughness, htsg_series
from brdftab.spec import load_spec
from brdftab.table import SPECULAR_THETA_I, SPECULAR_VAR, Table, tabulate

SPECS = Path(__file__).resolve().parent.parent / "specs"

DIELECTRIC = dict(n=1.5, k=0.0, sigma0=0.1, tau=1.0, wavelength_nm=500.0)
METAL = dict(n=0.77, k=6.08, sigma0=0.1, tau=1.0, wavelength_nm=500.0)
PYROMARK_HT = dict(n=1.32, sigma0=0.281, tau=1.635, r_dh_lam=0.0169, wavelength_nm=585.0)
PYROMARK_MOD = dict(n=1.34, sigma0=0.183, tau=1.014, r_dh_lam=0.0157, width_theta=math.radians(14.9),
                    width_phi=math.radians(3.2), wavelength_nm=585.0)


def _vec(theta, phi=0.0):
    return np.array([math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta)])


# ---------------------------------------------------------------------------------------------
# independent references


def _fresnel_ref(cos_t, n, k):
    eta = complex(n, k)
    sin2 = 1.0 - cos_t * cos_t
    ct = np.sqrt(1.0 - sin2 / eta ** 2 + 0j)
    rs = (cos_t - eta * ct) / (cos_t + eta * ct)
    rp = (eta * cos_t - ct) / (eta * cos_t + ct)
    return 0.5 * (abs(rs) ** 2 + abs(rp) ** 2)


def _shadow_ref(theta, s0, tau):
    if theta == 0.0:
        return 1.0
    c = tau / math.tan(theta) / (2 * s0)
    lam = 0.5 * (math.exp(-c * c) / (math.sqrt(math.pi) * c) - math.erfc(c))
    return (1 - 0.5 * math.erfc(c)) / (lam + 1)


def _k_ref(theta, s0, tau):
    if theta == 0.0:
        return 0.0
    return math.tan(theta) * math.erfc(tau / math.tan(theta) / (2 * s0))


def _sigma_ref(ti, to, s0, tau):
    """Effective σ: z0 from the closed form y = z0²/σ0² = W(A²), A = (K_i + K_r)/(4√(π/2))."""
    a = (_k_ref(ti, s0, tau) + _k_ref(to, s0, tau)) / (4 * math.sqrt(math.pi / 2))
    y = float(lambertw(a * a).real)
    return s0 / math.sqrt(1 + y)


def _series_ref(g, e):
    if g == 0:
        return 0.0
    top = int(g + 60 * math.sqrt(g) + 200)
    logs = [m * math.log(g) - g - math.lgamma(m + 1) - math.log(m) - e / m for m in range(1, top)]
    a = max(logs)
    return math.exp(a) * math.fsum(math.exp(x - a) for x in logs)


def _rho_dd_ref(wi, wo, n, k, sigma0, tau, wavelength_nm, **_):
    lam = wavelength_nm * 1e-3
    ti, to = math.acos(wi[2]), math.acos(wo[2])
    v = wi + wo
    vv = float(v @ v)
    vz = float(v[2])
    kk = 2 * math.pi / lam
    sig = _sigma_ref(ti, to, sigma0, tau)
    g = (kk * sig * (wi[2] + wo[2])) ** 2
    e = tau ** 2 * kk ** 2 * (vv - vz * vz) / 4
    d = math.pi ** 2 * tau ** 2 / (4 * lam ** 2) * _series_ref(g, e)
    shadow = _shadow_ref(ti, sigma0, tau) * _shadow_ref(to, sigma0, tau)
    f = _fresnel_ref(math.sqrt(vv) / 2, n, k)
    return f / math.pi * (vv / vz) ** 2 * shadow * d / (wi[2] * wo[2])


def _rho_s_ref(theta, n, k, sigma0, tau, wavelength_nm, **_):
    lam = wavelength_nm * 1e-3
    sig = _sigma_ref(theta, theta, sigma0, tau)
    g = (2 * math.pi / lam * sig * 2 * math.cos(theta)) ** 2
    return _fresnel_ref(math.cos(theta), n, k) * math.exp(-g) * _shadow_ref(theta, sigma0, tau) ** 2


def _hemisphere(n_mu, n_phi):
    x, w = np.polynomial.legendre.leggauss(n_mu)
    mu, wmu = 0.5 * (x + 1), 0.5 * w
    phi = (np.arange(n_phi) + 0.5) * 2 * np.pi / n_phi
    m, p = np.meshgrid(mu, phi, indexing="ij")
    st = np.sqrt(1 - m * m)
    wo = np.stack([st * np.cos(p), st * np.sin(p), m], axis=-1).reshape(-1, 3)
    return wo, np.repeat(wmu, n_phi) * 2 * np.pi / n_phi


def _albedo_smooth(fn, theta_i, n_mu=100, n_phi=200):
    """∫ fn(wi, wo) cosθo dωo for each θi (φi = 0) by Gauss–Legendre in cosθo × midpoint φo."""
    wo, w = _hemisphere(n_mu, n_phi)
    out = []
    for t in np.atleast_1d(theta_i):
        wi = np.broadcast_to(_vec(t), wo.shape)
        out.append(float(np.sum(fn(wi, wo) * w * wo[:, 2])))
    return np.array(out)


def _albedo_cone(model, theta_i, half_width, n_mu=24, n_chi=64):
    """∫ f_cone cosθo dωo: Gauss–Legendre in cosψ ∈ [cos w, 1] about the mirror direction × midpoint
    azimuths about it (nodes below the horizon left out)."""
    x, w = np.polynomial.legendre.leggauss(n_mu)
    c0 = math.cos(half_width)
    mu = c0 + (1 - c0) * 0.5 * (x + 1)
    wmu = (1 - c0) * 0.5 * w
    chi = (np.arange(n_chi) + 0.5) * 2 * np.pi / n_chi
    out = []
    for t in np.atleast_1d(theta_i):
        r = _vec(t, math.pi)
        e1 = np.array([math.cos(t), 0.0, math.sin(t)])      # ⟂ r, in the plane of incidence
        e2 = np.cross(r, e1)
        s = np.sqrt(1 - mu * mu)
        wo = (mu[:, None, None] * r + s[:, None, None] * (np.cos(chi)[None, :, None] * e1
                                                          + np.sin(chi)[None, :, None] * e2)).reshape(-1, 3)
        wts = np.repeat(wmu, n_chi) * 2 * np.pi / n_chi
        keep = wo[:, 2] > 0
        wo, wts = wo[keep], wts[keep]
        wi = np.broadcast_to(_vec(t), wo.shape)
        out.append(float(np.sum(model._cone(wi, wo, None, 1)[:, 0] * wts * wo[:, 2])))
    return np.array(out)


def _panels(centre, width, lo, hi, nodes=8):
    steps = width * 2.0 ** np.arange(-1, 12)
    edges = np.unique(np.clip(np.concatenate([[lo, hi], centre + steps, centre - steps, [centre]]), lo, hi))
    x, w = np.polynomial.legendre.leggauss(nodes)
    a, b = edges[:-1, None], edges[1:, None]
    return (a + (b - a) * 0.5 * (x + 1)).ravel(), ((b - a) * 0.5 * w).ravel()


def _albedo_profile(model, theta_i):
    """∫ f cosθo dωo of the modified model on (θo, φo) panels graded about the profile's centre
    (θo = θi, φo = φi + π) by w_θ and w_φ; weights sinθo dθo dφo."""
    out = []
    for t in np.atleast_1d(theta_i):
        th, wth = _panels(t, model.width_theta, 0.0, math.pi / 2)
        dp, wdp = _panels(0.0, model.width_phi, -math.pi, math.pi)
        tt, pp = np.meshgrid(th, math.pi + dp, indexing="ij")
        st = np.sin(tt)
        wo = np.stack([st * np.cos(pp), st * np.sin(pp), np.cos(tt)], axis=-1).reshape(-1, 3)
        wts = ((wth * np.sin(th))[:, None] * wdp[None, :]).ravel()
        wi = np.broadcast_to(_vec(t), wo.shape)
        out.append(float(np.sum(model.eval(wi, wo)[:, 0] * wts * wo[:, 2])))
    return np.array(out)


# ---------------------------------------------------------------------------------------------
# the formulas


def test_rho_dd_and_specular_reflectance_match_the_formulas():
    rng = np.random.default_rng(3)
    for params in (DIELECTRIC, METAL, PYROMARK_HT):
        m = models.create("he-torrance-1991", **params)
        for _ in range(12):
            ti, to = rng.uniform(0, math.radians(88), 2)
            wi, wo = _vec(ti, rng.uniform(0, 2 * np.pi)), _vec(to, rng.uniform(0, 2 * np.pi))
            got = m._directional_diffuse(wi[None], wo[None], None, 1)[0, 0]
            want = _rho_dd_ref(wi, wo, **{"k": 0.0, **params})
            assert got == pytest.approx(want, rel=1e-9, abs=1e-300)
        theta = np.radians([0.0, 20.0, 45.0, 70.0, 85.0, 89.5])
        got = m.specular_reflectance(theta)[:, 0]
        want = [_rho_s_ref(t, **{"k": 0.0, **params}) for t in theta]
        np.testing.assert_allclose(got, want, rtol=1e-10)


def test_newton_solve_matches_lambert_w_and_converges_fast():
    k_sum = np.geomspace(1e-12, 1e12, 241)
    y, steps = effective_roughness(k_sum, iterations=True)
    a = k_sum / (4 * math.sqrt(math.pi / 2))
    want = lambertw(a * a).real
    assert np.max(np.abs(y - want) / want) < 1e-12
    assert steps <= 12
    assert effective_roughness(np.array([0.0]))[0] == 0.0


@pytest.mark.parametrize("g", [0.5, 30.0, 632.0, 2500.0, 1e4])
def test_series_is_summed_until_converged_at_large_g(g):
    e = np.array([0.0, 1.0, 50.0, 1e3, 1e5])
    got, terms = htsg_series(np.full(e.shape, g), e, terms=True)
    want = np.array([_series_ref(g, x) for x in e])
    np.testing.assert_allclose(got, want, rtol=1e-9)
    if g >= 632:
        # a fixed cut at m = 200 (He.cal) would miss the whole Poisson mass at m ≈ g ± √g
        cut = sum(math.exp(m * math.log(g) - g - math.lgamma(m + 1) - math.log(m)) for m in range(1, 201))
        assert cut < 1e-12 * want[0]
        assert terms.max() > 4 * math.sqrt(g)


def test_directional_diffuse_is_reciprocal():
    rng = np.random.default_rng(7)
    n = 4000
    wi = np.array([_vec(t, p) for t, p in zip(np.arccos(rng.uniform(0.01, 1, n)), rng.uniform(0, 2 * np.pi, n))])
    wo = np.array([_vec(t, p) for t, p in zip(np.arccos(rng.uniform(0.01, 1, n)), rng.uniform(0, 2 * np.pi, n))])
    for params in (DIELECTRIC, METAL, PYROMARK_HT):
        m = models.create("he-torrance-1991", **params)
        assert m.reciprocal
        f, g = m.eval(wi, wo), m.eval(wo, wi)
        assert np.max(np.abs(f - g) / np.maximum(f, 1e-300)) <= 1e-12
        # the cone variant's ρ_dd is the same function
        cone = models.create("he-torrance-1991", cone_half_width=math.radians(4.5), **params)
        assert not cone.reciprocal
        np.testing.assert_array_equal(cone._directional_diffuse(wi, wo, None, 1),
                                      m._directional_diffuse(wi, wo, None, 1))


# ---------------------------------------------------------------------------------------------
# energy


@pytest.mark.parametrize("params", [DIELECTRIC, METAL, dict(DIELECTRIC, sigma0=1.0, tau=10.0)],
                         ids=["dielectric", "metal", "dielectric-g632"])
def test_normal_incidence_energy_equals_fresnel(params):
    """ρ_s + ∫ ρ_dd cosθr dω = |F(0)|² within 1 % (Σ_{m≥1} Poisson = 1 − e^{−g})."""
    m = models.create("he-torrance-1991", **params)
    n, k = params["n"], params["k"]
    f0 = ((n - 1) ** 2 + k ** 2) / ((n + 1) ** 2 + k ** 2)
    dd = _albedo_smooth(lambda a, b: m.eval(a, b)[:, 0], [0.0], n_mu=400, n_phi=8)[0]
    total = dd + m.specular_delta(_vec(0.0))[0]
    assert total == pytest.approx(f0, rel=0.01)


@pytest.mark.parametrize("params", [DIELECTRIC, METAL], ids=["dielectric", "metal"])
def test_smooth_limit_directional_diffuse_vanishes_specular_becomes_fresnel(params):
    theta = np.radians([0.0, 60.0])
    dd, rs = [], []
    for s0 in (0.004, 0.002, 0.001):
        m = models.create("he-torrance-1991", **dict(params, sigma0=s0))
        dd.append(_albedo_smooth(lambda a, b: m.eval(a, b)[:, 0], theta, n_mu=200, n_phi=64))
        rs.append(m.specular_reflectance(theta)[:, 0])
    fres = np.array([_fresnel_ref(math.cos(t), params["n"], params["k"]) for t in theta])
    dd, rs = np.array(dd), np.array(rs)
    # ρ_dd ∝ g ∝ σ0²: a quarter per halving of σ0
    np.testing.assert_allclose(dd[1:] / dd[:-1], 0.25, rtol=0.02)
    g_max = (4 * math.pi * 0.001 / 0.5) ** 2          # g at normal incidence and reflection, σ0 = 1 nm
    assert np.all(dd[-1] <= 1.05 * g_max * fres)
    assert np.all(np.abs(rs[-1] / fres - 1) <= 1.05 * g_max)
    assert np.all(np.abs(rs[-1] / fres - 1) < np.abs(rs[0] / fres - 1))


# ---------------------------------------------------------------------------------------------
# Bitterling et al.: directional-hemispherical reflectance (Eq. 8)


def test_standard_ht_fit_reflectance_reverses_at_82_degrees():
    theta = np.radians(np.arange(70.0, 90.0))
    delta = models.create("he-torrance-1991", **PYROMARK_HT)
    rdh = _albedo_smooth(lambda a, b: delta.eval(a, b)[:, 0], theta) + delta.specular_reflectance(theta)[:, 0]
    i = int(np.argmax(rdh))
    assert abs(math.degrees(theta[i]) - 82.0) <= 1.0
    assert rdh[i] == pytest.approx(0.169, abs=0.001)
    assert np.all(np.diff(rdh[i:]) < 0)
    # the fitted cone variant (w = 4.5°) reverses at the same angle
    w = math.radians(4.5)
    cone = models.create("he-torrance-1991", cone_half_width=w, **PYROMARK_HT)
    rc = (_albedo_smooth(lambda a, b: cone._diffuse_parts(a, b, None, 1)[:, 0], theta)
          + _albedo_cone(cone, theta, w))
    j = int(np.argmax(rc))
    assert abs(math.degrees(theta[j]) - 82.0) <= 1.0
    assert np.all(np.diff(rc[j:]) < 0)


def test_modified_ht_reflectance_rises_monotonically():
    m = models.create("he-torrance-modified", **PYROMARK_MOD)
    theta = np.radians(np.arange(0.0, 90.0))
    rdh = _albedo_profile(m, theta)
    assert np.all(np.diff(rdh) > -1e-4)
    assert rdh[0] == pytest.approx(0.037, abs=0.001)
    assert rdh[-1] == pytest.approx(0.66, abs=0.01)


def test_albedo_integrals_resolve_the_cone_and_the_profile():
    """brdftab.integrate (the albedo/energy checks) integrates each part on its own rule (the
    models' ``quadrature_parts`` / ``albedo_rule``): it agrees with the quadratures written here."""
    theta = np.radians([0.0, 30.0, 60.0, 75.0, 82.0, 86.0, 89.0])
    w = math.radians(4.5)
    cone = models.create("he-torrance-1991", cone_half_width=w, **PYROMARK_HT)
    ref = (_albedo_smooth(lambda a, b: cone._diffuse_parts(a, b, None, 1)[:, 0], theta)
           + _albedo_cone(cone, theta, w))
    np.testing.assert_allclose(directional_albedo(cone, theta)[:, 0], ref, rtol=0, atol=1e-4)
    mod = models.create("he-torrance-modified", **PYROMARK_MOD)
    np.testing.assert_allclose(directional_albedo(mod, theta)[:, 0], _albedo_profile(mod, theta), rtol=0, atol=1e-4)


def test_modified_solid_angle_matches_closed_form():
    for wt_deg in (0.1, 3.2, 14.9, 45.0):
        m = models.create("he-torrance-modified", **dict(PYROMARK_MOD, width_theta=math.radians(wt_deg)))
        w, wp = m.width_theta, m.width_phi
        theta = np.linspace(0.0, math.pi / 2, 397)
        a, b = -theta, math.pi / 2 - theta
        z = 2j * w * w
        th_int = np.imag(np.exp(1j * theta - w * w) * w * math.sqrt(math.pi)
                         * (erf((b - z) / (2 * w)) - erf((a - z) / (2 * w))))
        want = 2 * math.sqrt(math.pi) * wp * math.erf(math.pi / (2 * wp)) * th_int
        np.testing.assert_allclose(m.solid_angle(theta), want, rtol=1e-9)


def test_modified_profile_wraps_the_azimuth_about_the_mirror_direction():
    m = models.create("he-torrance-modified", **PYROMARK_MOD)
    ti = math.radians(40.0)
    wi = _vec(ti, 0.3)
    side = [_vec(ti, 0.3 + math.pi + s * math.radians(1.0)) for s in (-1, 1)]
    g = m.profile(np.array([wi, wi]), np.array(side))
    want = math.exp(-(math.radians(1.0) / (2 * m.width_phi)) ** 2)
    np.testing.assert_allclose(g, want, rtol=1e-12)


def test_modified_specular_part_matches_eq_24():
    """f_sp,mod = F(θm) e^{−g} Γ / (cosθm dω_i,g), G_HT = 1, g of the pair (local half-vector)."""
    p = PYROMARK_MOD
    m = models.create("he-torrance-modified", **p)
    for ti_deg, to_deg, dphi_deg in ((30, 40, 2.0), (70, 60, -1.5), (85, 80, 0.5)):
        ti, to = math.radians(ti_deg), math.radians(to_deg)
        wi, wo = _vec(ti, 0.0), _vec(to, math.pi + math.radians(dphi_deg))
        cos_m = math.sqrt(float((wi + wo) @ (wi + wo))) / 2
        gamma = math.exp(-(math.radians(dphi_deg) / (2 * p["width_phi"])) ** 2) * \
            math.exp(-((to - ti) / (2 * p["width_theta"])) ** 2)
        sig = _sigma_ref(ti, to, p["sigma0"], p["tau"])
        g = (2 * math.pi / 0.585 * sig * (wi[2] + wo[2])) ** 2
        domega = m.solid_angle(np.array([ti]))[0]
        want = _fresnel_ref(cos_m, p["n"], 0.0) * math.exp(-g) * gamma / (cos_m * domega)
        want += _rho_dd_ref(wi, wo, **dict(p, k=0.0)) + p["r_dh_lam"] / math.pi
        assert m.eval(wi, wo)[0] == pytest.approx(want, rel=1e-9)


# ---------------------------------------------------------------------------------------------
# wavelength, parameters


@pytest.mark.parametrize("name, params", [("he-torrance-1991", PYROMARK_HT),
                                          ("he-torrance-1991", dict(PYROMARK_HT, cone_half_width=0.08)),
                                          ("he-torrance-modified", PYROMARK_MOD)])
def test_wavelength_is_a_model_parameter(name, params):
    m = models.create(name, **params)
    assert m.channels == ("mono",)
    rng = np.random.default_rng(1)
    wi = np.array([_vec(t, p) for t, p in zip(rng.uniform(0, 1.5, 50), rng.uniform(0, 6, 50))])
    wo = wi * np.array([-1.0, -1.0, 1.0]) + rng.normal(0, 0.05, (50, 3))
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    own = m.eval(wi, wo)
    assert own.shape == (50, 1)
    spec = m.eval(wi, wo, wavelengths=[400.0, 585.0, 700.0])
    assert spec.shape == (50, 3)
    np.testing.assert_array_equal(spec[:, 1], own[:, 0])
    other = models.create(name, **dict(params, wavelength_nm=400.0))
    np.testing.assert_allclose(spec[:, 0], other.eval(wi, wo)[:, 0], rtol=1e-13)
    assert not np.allclose(spec[:, 0], spec[:, 2])
    if callable(getattr(m, "specular_delta", None)):
        d = m.specular_delta(wi, [400.0, 585.0, 700.0])
        np.testing.assert_array_equal(d[:, 1], m.specular_delta(wi)[:, 0])
        np.testing.assert_allclose(d[:, 0], other.specular_delta(wi)[:, 0], rtol=1e-13)


def test_parameters_outside_the_model_are_refused_with_one_line():
    with pytest.raises(ParameterError) as exc:   # rms radius of curvature τ²/(√12 σ0) = 0.29 µm < λ
        models.create("he-torrance-1991", n=1.5, sigma0=1.0, tau=1.0, wavelength_nm=500.0)
    assert "curvature" in str(exc.value) and "\n" not in str(exc.value)
    sigma0 = 1.01 * math.sqrt(G_MAX) / (4 * math.pi) * 0.5
    with pytest.raises(ParameterError, match="geometric-optics"):
        models.create("he-torrance-1991", n=1.5, sigma0=sigma0, tau=100.0, wavelength_nm=500.0)
    m = models.create("he-torrance-1991", n=1.5, sigma0=0.3, tau=1.2, wavelength_nm=500.0)
    with pytest.raises(ParameterError, match="wavelengths"):   # fine at 500 nm, not at 2 µm
        m.eval(_vec(0.3), _vec(0.3, math.pi), wavelengths=[500.0, 2000.0])


def test_cli_refuses_a_surface_outside_the_model(tmp_path):
    spec = tmp_path / "bad.toml"
    spec.write_text('[model]\nname = "he-torrance-1991"\nn = 1.5\nsigma0 = 1.0\ntau = 1.0\nwavelength_nm = 500\n'
                    '[grid]\ntype = "merl"\n[[output]]\npath = "bad.nc"\n')
    proc = subprocess.run([sys.executable, "-m", "brdftab", "validate", str(spec)], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 2
    assert len(proc.stderr.strip().splitlines()) == 1 and "curvature" in proc.stderr


# ---------------------------------------------------------------------------------------------
# the specular delta in tables, albedo integrals and other formats


@pytest.fixture(scope="module")
def delta_table():
    m = models.create("he-torrance-1991", **PYROMARK_HT)
    return m, tabulate(m, RusinkiewiczGrid(45, 45, 45), progress=False)


def test_netcdf_table_carries_the_delta(delta_table, tmp_path):
    m, t = delta_table
    assert SPECULAR_VAR in t.ds.data_vars
    theta, rho = t.specular_reflectance
    np.testing.assert_array_equal(theta, SPECULAR_THETA_I)
    np.testing.assert_allclose(rho[:, 0], m.specular_reflectance(theta)[:, 0], rtol=1e-12, atol=1e-300)
    formats.write(t, tmp_path / "ht.nc")
    back = formats.read(tmp_path / "ht.nc")
    np.testing.assert_array_equal(back.specular_reflectance[0], theta)
    np.testing.assert_array_equal(back.specular_reflectance[1], rho)
    # between the stored angles: linear in θi, within h²/8 max|ρ_s''| of its interval
    probe = np.radians([3.3, 41.17, 81.93, 88.21, 89.99])
    wi = np.array([_vec(t_, 0.4) for t_ in probe])
    err = np.abs(back.specular_delta(wi) - m.specular_delta(wi))[:, 0]
    h = theta[1] - theta[0]
    for t_, e in zip(probe, err):
        lo = theta[np.searchsorted(theta, t_) - 1]
        fine = np.linspace(lo, lo + h, 41)
        step = fine[1] - fine[0]
        curv = np.abs(np.diff(m.specular_reflectance(fine)[:, 0], 2)) / step ** 2
        assert e <= 1.01 * h * h / 8 * curv.max() + 1e-15
    # a table without it has none
    plain = Table(t.ds.drop_vars(SPECULAR_VAR))
    assert plain.specular_delta is None


def test_a_malformed_delta_variable_is_refused_with_one_line(delta_table):
    from brdftab.errors import FormatError

    _, t = delta_table
    bad = t.ds.copy()
    bad[SPECULAR_VAR] = bad[SPECULAR_VAR] * -1.0
    with pytest.raises(FormatError, match="finite reflectances"):
        Table(bad).specular_delta(_vec(0.3)[None])
    bad = t.ds.copy()
    bad = bad.assign_coords({"specular_theta_i": bad["specular_theta_i"].values[::-1]})
    with pytest.raises(FormatError, match="strictly increasing"):
        Table(bad)


def test_albedo_of_model_and_table_includes_the_delta(delta_table):
    m, t = delta_table
    theta = np.radians([0.0, 60.0, 82.0])
    wi = np.array([_vec(x) for x in theta])
    dd = _albedo_smooth(lambda a, b: m.eval(a, b)[:, 0], theta)
    rs = m.specular_reflectance(theta)[:, 0]
    a_model = directional_albedo(m, theta)[:, 0]
    np.testing.assert_allclose(a_model, rs + dd, rtol=0, atol=2e-4)
    a_table = directional_albedo(t, theta)[:, 0]
    a_plain = directional_albedo(Table(t.ds.drop_vars(SPECULAR_VAR)), theta)[:, 0]
    np.testing.assert_allclose(a_table, a_plain + t.specular_delta(wi)[:, 0], rtol=1e-12)
    np.testing.assert_allclose(a_table, a_model, rtol=0.02)
    # the energy check reports the albedo with the delta (it peaks at 82°: 0.169)
    energy = run_checks(t, {"energy": {"n_theta_i": 90}}, only=["energy"], reference=m).get("energy")
    assert energy.figure == pytest.approx(0.169, abs=0.003)
    assert energy.figure > float(np.max(a_plain)) + 0.05


def _delta_warnings(record):
    return [str(w.message) for w in record if issubclass(w.category, BrdftabWarning) and "delta" in str(w.message)]


@pytest.mark.parametrize("ext", [".exr", ".bsdf", ".binary"])
def test_formats_without_a_delta_say_so(delta_table, tmp_path, ext):
    m, t = delta_table
    source = t if ext == ".exr" else m
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        formats.write(source, tmp_path / f"ht{ext}", **({"resolution": 16, "n_theta_i": 3} if ext == ".bsdf" else {}))
    said = _delta_warnings(record)
    assert len(said) == 1 and "not stored" in said[0] and "\n" not in said[0]
    # netCDF holds it: nothing to say
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        formats.write(t, tmp_path / "ht.nc", overwrite=True)
    assert not _delta_warnings(record)


def test_cli_convert_says_the_delta_is_not_stored(delta_table, tmp_path):
    _, t = delta_table
    formats.write(t, tmp_path / "ht.nc")
    proc = subprocess.run([sys.executable, "-m", "brdftab", "convert", str(tmp_path / "ht.nc"),
                           str(tmp_path / "ht.exr")], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    lines = [x for x in proc.stderr.splitlines() if "delta" in x]
    assert len(lines) == 1 and lines[0].startswith("brdftab: warning:")


# ---------------------------------------------------------------------------------------------
# the shipped Pyromark specs


@pytest.mark.parametrize("name", ["pyromark-cook-torrance", "pyromark-he-torrance", "pyromark-modified-ht"])
def test_pyromark_spec_tabulates_and_validates(name, tmp_path):
    spec = SPECS / f"{name}.toml"
    run = lambda *a: subprocess.run([sys.executable, "-m", "brdftab", *map(str, a)], capture_output=True,  # noqa: E731
                                    text=True, timeout=300)
    proc = run("tabulate", spec, "--out", tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"{name}.nc"]
    proc = run("validate", spec)
    assert proc.returncode == 0, proc.stderr
    line = next(x for x in proc.stdout.splitlines() if "reciprocity" in x)
    assert line.split()[0] == "WARN" and "declared non-reciprocal" in line
    model = load_spec(spec).model
    assert not model.reciprocal
    table = formats.read(tmp_path / f"{name}.nc")
    assert table.grid.phi_d_fold == "none" and not table.reciprocal


def test_cone_narrower_than_its_bound_is_refused():
    """A 1e-8° cone has a solid angle 2π(1 − cos w) of 0 in floating point: infinite lobe. The
    parameter's bound (0.001°) refuses it; at the bound the cone is finite at the mirror."""
    with pytest.raises(ParameterError, match=r"cone_half_width: expected a number >= 0.001 deg .*got 1e-08"):
        models.create("he-torrance-1991", cone_half_width=math.radians(1e-8), **PYROMARK_HT)
    wi, wo = _vec(math.radians(30)), _vec(math.radians(30), math.pi)
    diffuse = models.create("he-torrance-1991", **PYROMARK_HT).eval(wi, wo)  # the delta variant: no cone in f
    content = []
    for w_deg in (1e-3, 1e-2):  # at the mirror the cone's f times its solid angle does not depend on w
        w = math.radians(w_deg)
        f = models.create("he-torrance-1991", cone_half_width=w, **PYROMARK_HT).eval(wi, wo)
        assert np.all(np.isfinite(f))
        content.append((f - diffuse) * 4 * math.pi * math.sin(w / 2) ** 2)
    assert content[0][0] > 0 and content[0] == pytest.approx(content[1], rel=1e-5)
