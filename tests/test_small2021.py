"""Small, Butler, Marciniak 2021: the paper's printed values, spot values from the printed
equations, the φ_ref rotation, the albedo of each peaked term against quadratures resolved on
it, declared non-reciprocity, and the shipped spec."""

import cmath
import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.optimize import minimize

from brdftab import models
from brdftab.checks import run_checks
from brdftab.cli import main
from brdftab.geometry import sph_to_vec
from brdftab.integrate import directional_albedo

R = np.radians
SPECS = Path(__file__).resolve().parents[1] / "specs"
LAMBDA = 632.8e-9
A_BAR, B_BAR = 8e-4, 1e-5


@pytest.fixture(scope="module")
def model():
    return models.create("solar-cell-small2021")       # defaults: the paper's §4.4.1 parameters


def incident(theta_deg, phi_deg=180.0):
    """The paper's geometry: the source at azimuth 180° (forward scatter towards +x)."""
    return sph_to_vec(R(theta_deg), R(phi_deg))


def specular(theta_deg, phi_deg=180.0):
    return sph_to_vec(R(theta_deg), R(phi_deg) + np.pi)


# -- spot values from the printed equations, with plain math ----------------------------------

def _vec(t, p):
    return (math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t))


def _q_plain_sum(ti, ts, phi_s, n):
    """Q_ss + Q_pp + Q_ps + Q_sp (SCATMECH amplitudes; φs = 0 on the specular side)."""
    eps = complex(n) ** 2
    qi = cmath.sqrt(eps - math.sin(ti) ** 2)
    qs = cmath.sqrt(eps - math.sin(ts) ** 2)
    ci, cs, si, ss = math.cos(ti), math.cos(ts), math.sin(ti), math.sin(ts)
    q = [(eps - 1) * math.cos(phi_s) / ((ci + qi) * (cs + qs)),
         (eps - 1) * (eps * si * ss - qs * qi * math.cos(phi_s)) / ((eps * ci + qi) * (eps * cs + qs)),
         -(eps - 1) * qi * math.sin(phi_s) / ((eps * ci + qi) * (cs + qs)),
         -(eps - 1) * qs * math.sin(phi_s) / ((ci + qi) * (eps * cs + qs))]
    return sum(abs(x) ** 2 for x in q)


def _angles(v):
    return math.atan2(math.hypot(v[0], v[1]), v[2]), math.atan2(v[1], v[0])


def _eq6(wi, ws, rho, m, n):
    ti, pi_ = _angles(wi)
    ts, ps = _angles(ws)
    h = [a + b for a, b in zip(wi, ws)]
    th = math.atan2(math.hypot(h[0], h[1]), h[2])        # θh of Eq. 4 (atan2: accurate near 0)
    q = _q_plain_sum(ti, ts, ps - pi_ - math.pi, n)
    return (rho * q / (2 * (math.cos(ti) + math.cos(ts)) ** 2) / (math.pi * m * m * math.cos(th) ** 4)
            * math.exp(-math.tan(th) ** 2 / (m * m)))


def _rot_y(v, a):
    return (math.cos(a) * v[0] + math.sin(a) * v[2], v[1], -math.sin(a) * v[0] + math.cos(a) * v[2])


def _rot_z(v, a):
    return (math.cos(a) * v[0] - math.sin(a) * v[1], math.sin(a) * v[0] + math.cos(a) * v[1], v[2])


def _eq8(wi, ws, rho, m, n, dtheta, dphi0, phi_ref):
    wi2 = _rot_y(_rot_z(wi, -dphi0 - phi_ref), -dtheta)          # Eq. 7a
    ws2 = _rot_y(_rot_z(ws, -dphi0 - phi_ref), -dtheta)          # Eq. 7b
    if wi2[2] <= 0 or ws2[2] <= 0:
        return 0.0
    return _eq6(wi2, ws2, rho, m, n)


def _eq9(wi, ws, a, b, c, rho, R_, lam, phi_ref):
    h = [x + y for x, y in zip(wi, ws)]
    th = math.atan2(math.hypot(h[0], h[1]), h[2])
    ph = math.atan2(h[1], h[0])
    xb = R_ * math.sin(th) * math.cos(ph - phi_ref + math.pi)     # Eq. 10a
    yb = R_ * math.sin(th) * math.sin(ph - phi_ref + math.pi)     # Eq. 10b
    zb = R_                                                       # Eq. 10c
    ci = wi[2]
    arg = 2 * b * yb / (lam * zb) * ci
    sinc = 1.0 if arg == 0 else math.sin(math.pi * arg) / (math.pi * arg)
    return rho * math.cos(2 * math.pi * a * yb / (lam * zb) * ci) ** 2 * sinc ** 2 * math.exp(-xb * xb / (c * c))


@pytest.mark.parametrize("phi_ref_deg, R_", [(0.0, 1.0), (30.0, 0.325), (-75.0, 2.0)])
def test_spot_values_agree_with_the_printed_equations(phi_ref_deg, R_):
    p = dict(phi_ref=R(phi_ref_deg), R=R_, c=4e-3, wavelength_nm=550.0, rho_d=0.05)
    model = models.create("solar-cell-small2021", **p)
    rng = np.random.default_rng(7)
    checked = 0
    n2 = model.offset.normal
    for _ in range(30):
        ti = rng.uniform(0.1, 1.3)
        pi_ = rng.uniform(-np.pi, np.pi)
        wi = _vec(ti, pi_)
        # scattered directions within a few peak widths of the mirror directions about the macro
        # normal and about the tilted one (where the terms are not negligible)
        mirror2 = 2 * (np.array(wi) @ n2) * n2 - np.array(wi)
        t2, p2 = _angles(mirror2)
        for ws in (_vec(ti + rng.normal(0, 3e-4), pi_ + np.pi + rng.normal(0, 3e-4)),
                   _vec(t2 + rng.normal(0, 3e-4), p2 + rng.normal(0, 3e-4))):
            f = model.eval(np.array(wi), np.array(ws))[0]
            f1 = _eq6(wi, ws, 0.015, 2e-4, 3.6)
            f2 = _eq8(wi, ws, 0.7, 2e-4, 1.4, R(0.5), R(45.0), p["phi_ref"])
            f3 = _eq9(wi, ws, A_BAR, B_BAR, 4e-3, 300.0, R_, 550e-9, p["phi_ref"])
            for term, value in ((model.center, f1), (model.offset, f2), (model.diffraction, f3)):
                got = term.eval(np.array(wi), np.array(ws))[0]
                if value > 1e-6:
                    assert got == pytest.approx(value, rel=1e-10)
                    checked += 1
                else:
                    assert got < 1e-5
            assert f == pytest.approx(f1 + f2 + f3 + 0.05 / math.pi, rel=1e-10)
    assert checked > 60        # the terms were compared where they are not negligible


# -- the paper's printed values (§4.4.2) ------------------------------------------------------

@pytest.mark.parametrize("theta_i, value", [(20.0, 1.11e4), (60.0, 3.91e4)])
def test_full_model_at_the_specular_direction(model, theta_i, value):
    # center peak plus the diffraction zeroth order (ρs3 = 300)
    f = model.eval(incident(theta_i), specular(theta_i))[0]
    assert f == pytest.approx(value, rel=0.01)
    assert model.diffraction.eval(incident(theta_i), specular(theta_i))[0] == pytest.approx(300.0, rel=1e-12)


@pytest.mark.parametrize("theta_i, value", [(20.0, 4.44e4), (60.0, 4.19e5)])
def test_offset_peak_maximum(model, theta_i, value):
    # a search over ±3° in θs and ±4° in φs around the specular direction
    wi = incident(theta_i)
    th = R(np.linspace(theta_i - 3, theta_i + 3, 241))
    ph = R(np.linspace(-4, 4, 321))
    T, P = np.meshgrid(th, ph, indexing="ij")
    f = model.eval(wi, sph_to_vec(T, P))[..., 0]
    i = np.unravel_index(np.argmax(f), f.shape)
    res = minimize(lambda x: -model.eval(wi, sph_to_vec(x[0], x[1]))[0], [T[i], P[i]], method="Nelder-Mead",
                   options=dict(xatol=1e-9, fatol=1e-3))
    assert -res.fun == pytest.approx(value, rel=0.01)
    if theta_i == 20.0:
        # down (+y) and to the right (+x): θs > θi and φs > 0 from the specular azimuth
        assert np.degrees(res.x[0]) == pytest.approx(20.72, abs=0.01)
        assert np.degrees(res.x[1]) == pytest.approx(1.87, abs=0.01)


@pytest.mark.parametrize("theta_i", [20.0, 60.0])
def test_diffraction_orders_spacing_and_envelope(model, theta_i):
    d = model.diffraction
    wi = incident(theta_i)
    s = math.sin(R(theta_i))
    # along the band's centre line (x̄ = 0: wo_x = sinθi), out of plane in direction cosine y
    y = np.linspace(0.0, 27.5 * LAMBDA / A_BAR, 400_001)
    wo = np.stack([np.full_like(y, s), y, np.sqrt(1 - s * s - y * y)], axis=-1)
    f = d.eval(wi, wo)[:, 0]
    peaks = np.flatnonzero((f[1:-1] > f[:-2]) & (f[1:-1] >= f[2:])) + 1
    peaks = np.concatenate([[0], peaks])
    assert peaks.size >= 27
    k = np.arange(27)
    # orders λ/a apart in direction-cosine space, at both incidence angles
    np.testing.assert_allclose(np.diff(y[peaks[:27]]), LAMBDA / A_BAR, rtol=2e-3)
    # envelope ρs3·sinc²(k b/a): 300 at the center falling to ≈ 209 at the 26th order
    np.testing.assert_allclose(f[peaks[:27]], 300 * np.sinc(k * B_BAR / A_BAR) ** 2, rtol=0.01)
    assert f[peaks[26]] == pytest.approx(209.0, rel=0.01)


def _phi_h(wi, wo):
    h = wi + wo
    return math.degrees(math.atan2(h[1], h[0]))


@pytest.mark.parametrize("phi_ref", [45.0, 90.0])
def test_phi_ref_rotates_offset_peak_and_band_in_the_half_vector_azimuth(phi_ref):
    base = models.create("solar-cell-small2021")
    turned = models.create("solar-cell-small2021", phi_ref=R(phi_ref))
    for theta_i in (20.0, 40.0):
        wi = incident(theta_i)
        peaks = []
        for m in (base, turned):
            th = R(np.linspace(theta_i - 3, theta_i + 3, 241))
            ph = R(np.linspace(-6, 6, 481))
            T, P = np.meshgrid(th, ph, indexing="ij")
            f = m.offset.eval(wi, sph_to_vec(T, P))[..., 0]
            i = np.unravel_index(np.argmax(f), f.shape)
            res = minimize(lambda x: -m.offset.eval(wi, sph_to_vec(x[0], x[1]))[0], [T[i], P[i]],
                           method="Nelder-Mead", options=dict(xatol=1e-10, fatol=1e-3))
            peaks.append(_phi_h(wi, sph_to_vec(*res.x)))
        # the offset peak's half vector turns by φ_ref about the centre peak (h = n)
        assert (peaks[1] - peaks[0]) == pytest.approx(phi_ref, abs=0.05)
        # the band: on a ring of half vectors at θh = 2e-3, f3 peaks where x̄ = 0, i.e. at φh = φ_ref ± 90°
        for m, ref in ((base, 0.0), (turned, phi_ref)):
            phs = R(np.linspace(-180, 180, 36001))
            h = sph_to_vec(2e-3, phs)
            wo = 2 * (h @ wi)[:, None] * h - wi
            f = m.diffraction.eval(wi, wo)[:, 0]
            best = np.degrees(phs[np.argmax(f)])
            assert min(abs((best - ref - 90 + 180) % 360 - 180), abs((best - ref + 90 + 180) % 360 - 180)) < 0.2
    # in the scattered direction's own azimuth the offset peak does not move by φ_ref
    wi = incident(20.0)
    n2 = turned.offset.normal
    wo = 2 * (wi @ n2) * n2 - wi
    phi_s_turned = math.degrees(math.atan2(wo[1], wo[0]))
    n1 = base.offset.normal
    wo1 = 2 * (wi @ n1) * n1 - wi
    phi_s_base = math.degrees(math.atan2(wo1[1], wo1[0]))
    assert abs(phi_s_turned - phi_s_base - phi_ref) > 1.0


# -- albedo of peaked terms -------------------------------------------------------------------

def _peak_albedo_reference(term, wi, centre, width, n_r=500, n_phi=256):
    """∫ f cosθo dωo on a polar grid in outgoing space about the peak's direction ``centre``,
    radii out to 40 widths with Gauss–Legendre, uniform azimuth (independent of brdftab's rule)."""
    from brdftab.quadrature import gauss_legendre

    c = centre / np.linalg.norm(centre)
    u = np.cross(c, [0.0, 0.0, 1.0])
    u = u / np.linalg.norm(u) if np.linalg.norm(u) > 1e-9 else np.array([1.0, 0.0, 0.0])
    v = np.cross(c, u)
    r, wr = gauss_legendre(n_r, 0.0, 40 * width)
    ph = (np.arange(n_phi) + 0.5) * 2 * np.pi / n_phi
    dirs = (np.cos(r)[:, None, None] * c + np.sin(r)[:, None, None]
            * (np.cos(ph)[None, :, None] * u + np.sin(ph)[None, :, None] * v))
    w = (wr * np.sin(r))[:, None] * (2 * np.pi / n_phi)
    f = term.eval(wi, dirs.reshape(-1, 3))[:, 0].reshape(n_r, n_phi)
    return float(np.sum(f * dirs[..., 2] * w))


def _band_albedo_reference(d, wi):
    """∫ f3 cosθo dωo: a dense midpoint rule in half-vector disk coordinates (x along the bars,
    y across), ten points per fringe period, the Gaussian resolved by 61 points over ±6c/R."""
    ci = wi[2]
    P = LAMBDA / (2 * A_BAR * ci)
    y = np.arange(-1.0, 1.0, P / 10) + P / 20
    x = np.linspace(-6 * d.c / d.R, 6 * d.c / d.R, 61)
    dx = x[1] - x[0]
    total = 0.0
    for chunk in np.array_split(y, 40):
        X, Y = np.meshgrid(x, chunk, indexing="ij")
        ok = X * X + Y * Y < 1
        X, Y = X[ok], Y[ok]
        hz = np.sqrt(1 - X * X - Y * Y)
        h = X[:, None] * d.e1 + Y[:, None] * d.e2 + hz[:, None] * np.array([0, 0, 1.0])
        c = h @ wi
        wo = 2 * c[:, None] * h - wi
        keep = wo[:, 2] > 0
        f = d.eval(wi, wo[keep])[:, 0]
        total += float(np.sum(f * wo[keep, 2] * 4 * c[keep] / hz[keep])) * dx * (P / 10)
    return total


@pytest.mark.parametrize("theta_i, centre, offset, band", [(20.0, 0.0048, 0.020, 0.0013),
                                                           (60.0, 0.0049, 0.051, 0.0007)])
def test_albedo_of_each_term_follows_its_peak(model, theta_i, centre, offset, band):
    wi = incident(theta_i)
    ref_c = _peak_albedo_reference(model.center, wi, specular(theta_i), 2e-4)
    n2 = model.offset.normal
    ref_o = _peak_albedo_reference(model.offset, wi, 2 * (wi @ n2) * n2 - wi, 2e-4)
    ref_b = _band_albedo_reference(model.diffraction, wi)
    assert ref_c == pytest.approx(centre, rel=0.05)
    assert ref_o == pytest.approx(offset, rel=0.05)
    assert ref_b == pytest.approx(band, rel=0.08)
    # brdftab's quadrature, driven by each term's lobe hints, against the resolved references
    ti, pi_ = R(theta_i), np.pi
    assert directional_albedo(model.center, ti, pi_)[0] == pytest.approx(ref_c, rel=1e-3)
    assert directional_albedo(model.offset, ti, pi_)[0] == pytest.approx(ref_o, rel=1e-3)
    assert directional_albedo(model.diffraction, ti, pi_)[0] == pytest.approx(ref_b, rel=5e-3)
    total = directional_albedo(model, ti, pi_)[0]
    assert total == pytest.approx(ref_c + ref_o + ref_b, rel=2e-3)
    # without the hints the generic rule misses the tilted peak and the band entirely
    from brdftab.integrate import outgoing_rule

    wo, w = outgoing_rule(ti, pi_, 2e-4)
    keep = wo[:, 2] > 0
    plain = float(np.sum(model.eval(wi, wo[keep])[:, 0] * w[keep] * wo[keep, 2]))
    assert abs(plain - total) > 0.1 * ref_o


def test_energy_and_albedo_checks_see_the_peaks(model):
    cfg = {"n_theta_i": 10, "n_phi_i": 2}
    r = run_checks(model, {"energy": cfg, "albedo": cfg}, only=("energy", "albedo"))
    assert r.passed
    data = r.get("albedo").data
    theta = np.asarray(data["theta_i_deg"])
    phi = np.asarray(data["phi_i_deg"])
    values = np.asarray(data["values_phi"])[..., 0]
    assert r.get("energy").figure == pytest.approx(values.max(), rel=1e-12)
    # the checks' a(θi, φi) against the resolved references, term by term, at two sweep nodes
    for i, j in ((2, 1), (9, 0)):       # (19.8°, 180°) and (89°, 0°): the largest albedo
        wi = incident(theta[i], phi[j])
        n2 = model.offset.normal
        ref = (_peak_albedo_reference(model.center, wi, specular(theta[i], phi[j]), 2e-4)
               + _peak_albedo_reference(model.offset, wi, 2 * (wi @ n2) * n2 - wi, 2e-4)
               + _band_albedo_reference(model.diffraction, wi))
        assert values[i, j] == pytest.approx(ref, rel=5e-3)


def test_diffraction_declares_non_reciprocity_and_validate_reports_it(model):
    assert not model.diffraction.reciprocal and not model.reciprocal
    assert model.center.reciprocal and model.offset.reciprocal
    o = run_checks(model, only=("reciprocity",)).get("reciprocity")
    assert o.status == "warn" and o.data["weighted"] > 0 and o.data["max_relative"] > 0.01
    assert "declared non-reciprocal" in o.detail


def test_shipped_spec_tabulates_and_validates_with_the_asymmetry_as_warn(tmp_path):
    spec = tmp_path / "solar-cell-small2021.toml"
    shutil.copy(SPECS / spec.name, spec)
    runner = CliRunner()
    r = runner.invoke(main, ["tabulate", str(spec)])
    assert r.exit_code == 0, r.output
    assert (tmp_path / "solar-cell-small2021.nc").exists()
    r = runner.invoke(main, ["validate", "--json", str(spec)])
    assert r.exit_code == 0, r.output
    doc = json.loads(r.output)
    checks = {c["name"]: c for c in doc["reports"][0]["checks"]}
    assert checks["reciprocity"]["status"] == "warn" and checks["reciprocity"]["data"]["max_relative"] > 0.01
    assert all(c["status"] != "fail" for c in checks.values())
    # the table resolves the peaks at its incidence angles (the outgoing interpolation)
    assert checks["tabulation"]["data"]["rms_at_incidence_nodes"] < 0.2


def test_bar_width_above_spacing_is_one_parameter_error():
    from brdftab.errors import ParameterError
    with pytest.raises(ParameterError, match="bar width must not exceed"):
        models.create("small2021-diffraction", a=1e-5, b=1e-3)
    with pytest.raises(ParameterError, match="bar width must not exceed"):
        models.create("solar-cell-small2021", a=1e-5, b=1e-3)


def test_absurd_weights_are_one_parameter_error():
    # finite but absurd magnitudes overflowed to NaN at evaluation; they are refused up front
    from brdftab.errors import ParameterError

    for key in ("rho_s1", "rho_s2", "rho_s3"):
        with pytest.raises(ParameterError, match=key):
            models.create("solar-cell-small2021", **{key: 1e308})
    with pytest.raises(ParameterError, match="g"):
        models.create("torrance-sparrow-1967", rho_d=0.5, g=1e308)
