"""Torrance–Sparrow 1967: Table I, the projected angles, Eq. 22's limit, Fig. 8's curves, the
Gaussian distribution as a microfacet D, and the shipped spec."""

import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from brdftab import models
from brdftab.cli import main
from brdftab.geometry import sph_to_vec
from brdftab.models import components as C
from brdftab.models.torrance_sparrow import g_table1, projected_angles
from brdftab.quadrature import gauss_legendre

R = np.radians
SPECS = Path(__file__).resolve().parents[1] / "specs"
FIG8 = dict(c_per_deg=0.05, g=2.0 / 3.0, rho_d=0.7, fresnel="none")


def _dirs(rng, n, zmin=1e-3):
    mu = rng.uniform(zmin, 1.0, n)
    phi = rng.uniform(0, 2 * np.pi, n)
    s = np.sqrt(1 - mu * mu)
    return np.stack([s * np.cos(phi), s * np.sin(phi), mu], axis=-1)


def in_plane(psi_deg, theta_deg):
    """Fig. 8's geometry: the source at azimuth 180°, θ > 0 forward (φ = 0), θ < 0 backward."""
    th = np.asarray(theta_deg, float)
    return sph_to_vec(R(psi_deg), np.pi), sph_to_vec(R(np.abs(th)), np.where(th >= 0, 0.0, np.pi))


def test_table_one_equals_the_vector_v_groove_everywhere():
    rng = np.random.default_rng(0)
    wi, wo = _dirs(rng, 200_000), _dirs(rng, 200_000)
    h = (wi + wo) / np.linalg.norm(wi + wo, axis=-1, keepdims=True)
    vector = C.create("shadowing", "v-groove").G(wi, wo, h)
    table = g_table1(*projected_angles(wi, wo))
    assert np.abs(vector - table).max() < 1e-9
    assert 0.3 < np.mean(vector < 1) < 0.95          # the masked and shadowed regions are visited


def test_projected_angles_take_the_right_branch_in_the_plane_of_incidence():
    # forward: ψp = ψ, θp = θ; backward: θp = −θ (Eq. 15). Eq. 14 as printed gives ψp = −ψ here.
    psi, theta = 30.0, np.array([-70.0, -10.0, 10.0, 50.0, 80.0])
    p, t = projected_angles(*in_plane(psi, theta))
    np.testing.assert_allclose(np.degrees(p), psi, atol=1e-9)
    np.testing.assert_allclose(np.degrees(t), theta, atol=1e-9)


def test_table_one_regions():
    psi = R(np.array([0.0, 20.0, 45.0, 60.0, 80.0]))
    for p in psi:
        lo = (p - np.pi) / 3 if p <= np.pi / 4 else 3 * p - np.pi
        hi = (p + np.pi) / 3
        inside = np.linspace(lo + 1e-6, hi - 1e-6, 50)
        assert np.all(np.abs(g_table1(p, inside) - 1) < 1e-12)            # unobstructed: G = 1
        outside = np.concatenate([np.linspace(-np.pi / 2, lo - 1e-3, 20), np.linspace(hi + 1e-3, np.pi / 2, 20)])
        assert np.all(g_table1(p, outside) < 1)
        # G → 0 at grazing reflection (A → 1 in Eqs. 21)
        assert g_table1(p, np.pi / 2 - 1e-9) < 1e-4 and g_table1(p, -np.pi / 2 + 1e-9) < 1e-4


def _eq14_printed(psi, theta, phi):
    """ψ′, α, β1, β2 of Eq. 14 as printed (φ from the plane of incidence, 0 on the specular side)."""
    psi_p = 0.5 * math.acos(math.cos(theta) * math.cos(psi) - math.sin(theta) * math.sin(psi) * math.cos(phi))
    b1 = math.asin(math.sin(phi) * math.sin(theta) / math.sin(2 * psi_p))
    alpha = math.acos(math.cos(psi) * math.cos(psi_p) + math.sin(psi) * math.sin(psi_p) * math.cos(b1))
    b2 = math.pi - math.asin(math.sin(b1) * math.sin(psi_p) / math.sin(alpha))
    return psi_p, alpha, b1, b2


def test_g_over_cos_theta_is_finite_at_grazing_and_eq22_needs_the_corrected_branch():
    vg = C.create("shadowing", "v-groove")
    psi, phi = R(30.0), R(45.0)
    wi = sph_to_vec(psi, np.pi)
    limits = []
    for theta in R(np.array([89.0, 89.9, 89.99, 89.9999])):
        wo = sph_to_vec(theta, phi)
        h = (wi + wo) / np.linalg.norm(wi + wo)
        limits.append(vg.G(wi, wo, h) / wo[2])
    wo = sph_to_vec(R(90.0), phi)
    h = (wi + wo) / np.linalg.norm(wi + wo)
    expected = 2 * h[2] / (wo @ h)                               # 2(n·h)/(ωo·h) = 2cosα/cosψ′
    assert limits[-1] == pytest.approx(expected, rel=1e-5) and expected == pytest.approx(2.68, abs=0.005)
    psi_p, alpha, b1, b2 = _eq14_printed(psi, R(90.0), phi)
    assert 2 * h[2] / (wo @ h) == pytest.approx(2 * math.cos(alpha) / math.cos(psi_p), rel=1e-12)
    printed = 2 / math.tan(alpha) / math.cos(b2 - phi)            # Eq. 22 with Eq. 14's β2
    corrected = 2 / math.tan(alpha) / math.cos(math.pi - b2 - phi)   # β2 on the other branch
    assert printed == pytest.approx(4.90, abs=0.005)
    assert corrected == pytest.approx(expected, rel=1e-10)
    # in the plane of incidence the printed branch has the wrong sign
    psi_p, alpha, b1, b2 = _eq14_printed(psi, R(90.0), 0.0)
    assert 2 / math.tan(alpha) / math.cos(b2) < 0


@pytest.mark.parametrize("psi, theta_max, value", [(10.0, 13.3, 1.0021), (45.0, 75.0, 1.3181)])
def test_fig8_in_plane_maxima(psi, theta_max, value):
    m = models.create("torrance-sparrow-1967", **FIG8)
    theta = np.linspace(-89.99, 89.99, 179_981)
    r = m.relative(*in_plane(psi, theta))[:, 0]
    i = int(np.argmax(r))
    assert r[i] == pytest.approx(value, rel=0.01) and theta[i] == pytest.approx(theta_max, abs=0.1)
    if psi == 10.0:   # no off-specular peak: the curve falls to 0.61 at the horizon
        assert r[-1] == pytest.approx(0.61, abs=0.01)


def test_fig8_psi_75_peaks_at_the_horizon():
    m = models.create("torrance-sparrow-1967", **FIG8)
    theta = np.linspace(0.0, 90.0 - 1e-6, 9001)
    r = m.relative(*in_plane(75.0, theta))[:, 0]
    assert int(np.argmax(r)) == theta.size - 1 and r[-1] == pytest.approx(3.1955, rel=0.01)


def test_alpha_in_radians_would_give_a_different_figure():
    # c = 0.05 per radian instead of per degree: the ψ = 10° curve peaks at the horizon at 1.55
    m = models.create("torrance-sparrow-1967", **{**FIG8, "c_per_deg": 0.05 * math.pi / 180})
    theta = np.linspace(0.0, 90.0 - 1e-5, 9001)
    r = m.relative(*in_plane(10.0, theta))[:, 0]
    assert int(np.argmax(r)) == theta.size - 1 and r[-1] == pytest.approx(1.55, abs=0.01)


def test_absolute_form_spot_values_and_reciprocity():
    m = models.create("torrance-sparrow-1967", c_per_deg=0.05, g=0.5, rho_d=[0.7, 0.5], fresnel="conductor",
                      n=1.2, k=7.0)
    rng = np.random.default_rng(3)
    wi, wo = _dirs(rng, 5), _dirs(rng, 5)
    f = m.eval(wi, wo)
    for j in range(5):
        a, b = wi[j], wo[j]
        hv = (a + b) / np.linalg.norm(a + b)
        alpha_deg = math.degrees(math.acos(hv[2]))
        cos_d = float(a @ hv)
        G = min(1.0, 2 * hv[2] * b[2] / cos_d, 2 * hv[2] * a[2] / cos_d)
        eta = complex(1.2, 7.0)
        ct = np.sqrt(1 - (1 - cos_d ** 2) / eta ** 2 + 0j)
        rs = (cos_d - eta * ct) / (cos_d + eta * ct)
        rp = (eta * cos_d - ct) / (eta * cos_d + ct)
        F = 0.5 * (abs(rs) ** 2 + abs(rp) ** 2)
        for c, rho in enumerate((0.7, 0.5)):
            expect = rho / math.pi * (1 + 0.5 * F * G * math.exp(-(0.05 * alpha_deg) ** 2) / (a[2] * b[2]))
            assert f[j, c] == pytest.approx(expect, rel=1e-10)
    wi, wo = _dirs(rng, 20_000), _dirs(rng, 20_000)
    np.testing.assert_allclose(m.eval(wi, wo), m.eval(wo, wi), rtol=1e-12)


def test_albedo_is_about_1_29_rho_d_at_every_incidence():
    from brdftab.integrate import directional_albedo

    m = models.create("torrance-sparrow-1967", **FIG8)
    theta = R(np.array([0.0, 20.0, 40.0, 60.0, 75.0, 85.0]))
    a = directional_albedo(m, theta)[:, 0] / 0.7
    # independent: Gauss–Legendre in cosθo × uniform φo
    mu, wmu = gauss_legendre(256, 0.0, 1.0)
    phi = (np.arange(512) + 0.5) * 2 * np.pi / 512
    wo = sph_to_vec(np.arccos(mu)[:, None], phi[None, :]).reshape(-1, 3)
    wts = (wmu[:, None] * np.full(512, 2 * np.pi / 512)[None, :]).ravel() * wo[:, 2]
    for t, got in zip(theta, a):
        f = m.eval(sph_to_vec(t, np.pi), wo)[:, 0]
        assert got == pytest.approx(float(f @ wts) / 0.7, rel=2e-3)
    assert np.all(np.abs(a - 1.29) < 0.03)


def test_gaussian_angle_distribution_is_a_microfacet_d():
    d = C.create("distribution", "torrance-sparrow", c_per_deg=0.05)
    # ∫ D cosθh dω = 1 (independent Gauss–Legendre in θh)
    th, w = gauss_legendre(400, 0.0, np.pi / 2)
    h = sph_to_vec(th, 0.0)
    assert float(2 * np.pi * np.sum(d.D(h) * np.cos(th) * np.sin(th) * w)) == pytest.approx(1.0, abs=1e-9)
    # Smith Λ from the projected area: (1 + Λ(ω)) cosθ = ∫ D max(0, ω·h) dω_h (brute force)
    t2, w2 = gauss_legendre(300, 0.0, np.pi / 2)
    p2 = (np.arange(600) + 0.5) * 2 * np.pi / 600
    hh = sph_to_vec(t2[:, None], p2[None, :])
    dw = (w2 * np.sin(t2))[:, None] * (2 * np.pi / 600)
    for theta in R(np.array([0.0, 30.0, 60.0, 80.0, 88.0])):
        om = sph_to_vec(theta, 0.4)
        proj = float(np.sum(d.D(hh) * np.maximum(hh @ om, 0.0) * dw))
        assert (1 + d.lambda_(om)) * math.cos(theta) == pytest.approx(proj, rel=1e-5)
    # sampling follows D cosθh: mean of cosθh against the quadrature
    rng = np.random.default_rng(5)
    s = d.sample(rng.random(200_000), rng.random(200_000))
    mean = 2 * np.pi * np.sum(d.D(h) * np.cos(th) ** 2 * np.sin(th) * w)
    assert s[:, 2].mean() == pytest.approx(mean, abs=3e-3)
    # usable in microfacet: the Smith weak white furnace ∫ D G1(ωo) max(0, ωo·h)/cosθo dω_h = 1
    om = sph_to_vec(R(70.0), 0.0)
    furnace = float(np.sum(d.D(hh) * d.G1(om) * np.maximum(hh @ om, 0.0) * dw)) / om[2]
    assert furnace == pytest.approx(1.0, rel=1e-5)
    mf = models.create("microfacet", distribution="torrance-sparrow", c_per_deg=0.05, shadowing="smith")
    assert mf.energy_conserving and mf.lobe_width == pytest.approx(1 / (0.05 * 180 / math.pi))
    with pytest.raises(Exception, match="only used with distribution"):
        models.create("microfacet", distribution="ggx", c_per_deg=0.05)


def test_shipped_spec_tabulates_and_validates(tmp_path):
    spec = tmp_path / "torrance-sparrow-aluminum.toml"
    shutil.copy(SPECS / spec.name, spec)
    runner = CliRunner()
    r = runner.invoke(main, ["tabulate", str(spec)])
    assert r.exit_code == 0, r.output
    assert (tmp_path / "torrance-sparrow-aluminum.nc").exists()
    r = runner.invoke(main, ["validate", str(spec)])
    assert r.exit_code == 0, r.output
    assert "FAIL" not in r.output and "energy" in r.output
