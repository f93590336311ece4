"""The ``zernike-expansion`` model (SCATMECH ZernikeExpansion_BRDF_Model, f_r,11).

Oracles, each independent of the model's code:

* SCATMECH's formula written out again here, literally (factorial radial polynomials, SCATMECH's
  angles θi, θs, φs with Δφ = φs − π, A evaluated on column 3, column 6 as the azimuthal order);
* the Lambert identity (a single n = m = l = 0 row is f = a / 2π, albedo a / 2);
* a Gauss–Legendre (cosθo) × midpoint (φo) quadrature written here, beside brdftab's own;
* Germer's measured f_r,11 of sintered PTFE (``data/ptfe/PTFE.data.csv``) and his fitted
  coefficients (``PTFE.coeff.csv``), shipped in the repository (NIST, public domain).
"""

from __future__ import annotations

import hashlib
import math
import re
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from numpy.polynomial.legendre import leggauss

import brdftab
from brdftab import models
from brdftab.cli import main
from brdftab.errors import BrdftabWarning, ParameterError
from brdftab.geometry import rot_z, sph_to_vec
from brdftab.integrate import directional_albedo
from brdftab.models.zernike import radial_zernike
from brdftab.spec import load_spec
from test_contract import check_contract

REPO = Path(__file__).resolve().parents[1]
SPEC = REPO / "specs" / "ptfe-zernike.toml"
SYNTHETIC = REPO / "tests" / "data" / "zernike-synthetic.coeff.csv"
PTFE = REPO / "data" / "ptfe"
PTFE_COEFF = PTFE / "PTFE.coeff.csv"
PTFE_DATA = PTFE / "PTFE.data.csv"


def _model(coefficients, **kw):
    return models.create("zernike-expansion", coefficients=str(coefficients), **kw)


def _write(tmp_path, text, name="c.csv"):
    path = tmp_path / name
    path.write_text(text)
    return path


@pytest.fixture(scope="module")
def ptfe():
    """Germer's multi-wavelength PTFE fit at 532 nm, scale 1."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no warning at 532 nm: inside the fitted range, non-negative
        return _model(PTFE_COEFF, wavelength_nm=532.0, scale=1.0)


# --------------------------------------------------------------------------------------------
# SCATMECH's formula, written out independently


def _radial_factorial(n, l, rho):
    """SCATMECH's Radial_Zernike_Polynomial (code/zernike.cpp): the factorial sum."""
    m = abs(l)
    if (n - m) % 2 == 1:
        return np.zeros_like(rho)
    total = np.zeros_like(rho)
    for s in range((n - m) // 2 + 1):  # empty when |l| > n
        c = (-1) ** s * math.factorial(n - s) / (
            math.factorial(s) * math.factorial((n + m) // 2 - s) * math.factorial((n - m) // 2 - s))
        total = total + c * rho ** (n - 2 * s)
    return total


def _scatmech_f11(rows, theta_i, theta_s, phi_s, lam_um, scale=1.0):
    """``ZernikeExpansion_BRDF_Model::mueller()[0][0]`` in SCATMECH's angles (φs = 0: specular
    side), with λ^p a true power."""
    rho_i = math.sqrt(2.0) * np.sin(theta_i / 2.0)
    rho_r = math.sqrt(2.0) * np.sin(theta_s / 2.0)
    phi_i = np.pi - 0.0          # rotation = 0
    phi_r = phi_s - 0.0
    brdf = 0.0
    for i, j, n, m, k, l, p, a in rows:
        if (i, j) != (1, 1):
            continue
        amp = 4.0 if (n == 0 or (n == m and l == 0)) else (2.0 if (n == m or l == 0) else 1.0)
        pre = 0.5 / np.pi * math.sqrt((n + 1.0) * (m + 1.0) / amp) * lam_um ** p
        brdf = brdf + a * pre * (_radial_factorial(n, l, rho_i) * _radial_factorial(m, l, rho_r)
                                 + _radial_factorial(m, l, rho_i) * _radial_factorial(n, l, rho_r)) \
            * np.cos(l * (phi_r - phi_i))
    return scale * brdf


def _scatmech_angles(wi, wo):
    """θi, θs and SCATMECH's φs (0 on the specular side) of brdftab direction pairs (wi, wo both
    pointing away from the surface)."""
    theta_i = np.arccos(wi[:, 2])
    theta_s = np.arccos(wo[:, 2])
    phi_wi = np.arctan2(wi[:, 1], wi[:, 0])
    phi_wo = np.arctan2(wo[:, 1], wo[:, 0])
    return theta_i, theta_s, phi_wo - (phi_wi + np.pi)


def _read_rows(path):
    rows = []
    for line in Path(path).read_text().splitlines():
        line = line.split(";")[0].replace(",", " ").split()
        if line:
            rows.append(tuple(int(x) for x in line[:7]) + (float(line[7]),))
    return rows


def _random_pairs(n, seed=0, theta_max=89.5):
    rng = np.random.default_rng(seed)
    mu = rng.uniform(np.cos(np.radians(theta_max)), 1.0, (2, n))
    return (sph_to_vec(np.arccos(mu[0]), rng.uniform(-np.pi, np.pi, n)),
            sph_to_vec(np.arccos(mu[1]), rng.uniform(-np.pi, np.pi, n)))


def test_radial_polynomials_match_scatmech_factorial_sum():
    rho = np.linspace(0.0, 1.0, 101)
    for n in range(12):
        for l in range(-n - 2, n + 3):
            np.testing.assert_allclose(radial_zernike(n, l, rho), _radial_factorial(n, l, rho), rtol=0, atol=1e-12,
                                       err_msg=f"R_{n}^{l}")
    assert radial_zernike(5, 1, np.array([1.0]))[0] == pytest.approx(1.0)   # R_n^l(1) = 1
    assert not np.any(radial_zernike(2, 4, rho))                           # |l| > n: 0, as in SCATMECH


def test_expansion_follows_scatmech_term_by_term(tmp_path):
    # column 6 (not 5) is the azimuthal order of 11 rows; p = 3 is a true cube; p < 0; every A case
    text = """; hand-made rows exercising each rule
1, 1, 0, 0, 0, 0, 0, 2.0
1, 1, 1, 1, 0, 1, 0, -0.3
1, 1, 2, 0, 0, 0, 3, 0.4
1, 1, 0, 2, 0, 0, 0, 0.1
1, 1, 3, 1, 1, 1, 0, 0.05
1, 1, 2, 2, 2, 2, 1, 0.1
1, 1, 4, 2, 7, 2, -1, 0.02
1, 2, 2, 0, 2, 0, 0, 9.0
"""
    path = _write(tmp_path, text)
    rows = _read_rows(path)
    wi, wo = _random_pairs(4000, seed=3)
    for lam_nm in (532.0, 700.0, 1064.0):
        m = _model(path, wavelength_nm=lam_nm, fit_max_nm=2000.0)
        ref = _scatmech_f11(rows, *_scatmech_angles(wi, wo), lam_nm / 1000.0)
        got = m.expansion(wi, wo)[:, 0]
        np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-13)
    # λ^3, not SCATMECH's λ² for p = 3
    cube = _model(_write(tmp_path, "1 1 0 0 0 0 3 2.0\n", "p3.csv"), wavelength_nm=700.0)
    f = cube.eval(wi[:1], wo[:1])[0, 0]
    assert f == pytest.approx(2.0 * 0.7 ** 3 / (2 * np.pi), rel=1e-14)


def test_single_constant_row_is_lambertian(tmp_path):
    m = _model(_write(tmp_path, "1, 1, 0, 0, 0, 0, 0, 1.4\n"), scale=0.5)
    wi, wo = _random_pairs(500, seed=1)
    lam = models.create("lambert", albedo=0.35)   # f = scale · a / 2π = (scale · a / 2) / π
    np.testing.assert_allclose(m.eval(wi, wo), lam.eval(wi, wo), rtol=1e-14)
    np.testing.assert_allclose(directional_albedo(m, np.radians([0.0, 45.0, 80.0])), 0.35, rtol=1e-9)


# --------------------------------------------------------------------------------------------
# Germer's PTFE: albedo, reciprocity, forward lobe, measured data


def _albedo_gl(model, theta_i, n_mu=64, n_phi=128):
    """∫ f cosθo dωo by Gauss–Legendre in μ = cosθo × midpoint rule in φo (written here)."""
    x, w = leggauss(n_mu)
    mu, wmu = 0.5 * (x + 1.0), 0.5 * w
    phi = (np.arange(n_phi) + 0.5) * 2 * np.pi / n_phi
    MU, PHI = np.meshgrid(mu, phi, indexing="ij")
    st = np.sqrt(1.0 - MU ** 2)
    wo = np.stack([st * np.cos(PHI), st * np.sin(PHI), MU], axis=-1).reshape(-1, 3)
    wi = np.array([np.sin(theta_i), 0.0, np.cos(theta_i)])
    f = model.eval(np.broadcast_to(wi, wo.shape), wo)[:, 0].reshape(MU.shape)
    return float(np.sum(f * MU * wmu[:, None]) * 2 * np.pi / n_phi)


def test_ptfe_albedo_is_one_within_one_percent(ptfe):
    theta = np.radians([0.0, 30.0, 60.0])
    ours = directional_albedo(ptfe, theta)[:, 0]
    mine = np.array([_albedo_gl(ptfe, t) for t in theta])
    np.testing.assert_allclose(ours, mine, rtol=1e-4)        # two quadratures agree
    np.testing.assert_allclose(mine, 1.0, atol=0.01)          # Germer's fit: a ≈ 1 (0.9999, 1.0024, 1.0063)
    # the tolerance is not vacuous: Germer's single-wavelength 532 nm fit is > 1 % darker (models.md §2.6: 0.984)
    single = _model(PTFE / "PTFE.532.coeff.csv")
    assert _albedo_gl(single, 0.0) < 0.99


def test_ptfe_is_exactly_reciprocal_and_isotropic(ptfe):
    wi, wo = _random_pairs(20000, seed=7, theta_max=89.99)
    f = ptfe.eval(wi, wo)
    assert np.array_equal(f, ptfe.eval(wo, wi))               # bit for bit
    g = ptfe.eval(rot_z(wi, 1.234), rot_z(wo, 1.234))
    np.testing.assert_allclose(g, f, rtol=1e-12)
    check_contract(ptfe, seed=5)


def _without(tmp_path, name, drop):
    """Germer's file without the 11 rows for which ``drop(n, m, l)`` is true."""
    rows = PTFE_COEFF.read_text().splitlines()
    kept = []
    for r in rows:
        i, j, n, m, _k, l = (int(x) for x in r.split(",")[:6])
        if not ((i, j) == (1, 1) and drop(n, m, l)):
            kept.append(r)
    return _model(_write(tmp_path, "\n".join(kept) + "\n", name)), len(rows) - len(kept)


def test_ptfe_l1_term_raises_the_forward_lobe(ptfe, tmp_path):
    # the leading l = 1 term, a_11,11^1 = −0.34 (p = 0) and its p = 1 partner; and the whole l = 1 harmonic
    leading, n_leading = _without(tmp_path, "lead.csv", lambda n, m, l: abs(l) == 1 and n == m == 1)
    harmonic, n_harmonic = _without(tmp_path, "harm.csv", lambda n, m, l: abs(l) == 1)
    assert (n_leading, n_harmonic) == (2, 20)
    for other, angles in ((leading, (15.0, 30.0, 45.0, 60.0, 75.0)), (harmonic, (30.0, 45.0, 60.0, 75.0))):
        for theta in angles:
            wi = sph_to_vec(np.radians(theta), 0.0)
            forward = sph_to_vec(np.radians(theta), np.pi)   # the mirror direction (SCATMECH φs = 0)
            backward = wi                                    # retro-reflection (φs = π)
            d_fwd = (ptfe.eval(wi, forward) - other.eval(wi, forward))[0]
            d_back = (ptfe.eval(wi, backward) - other.eval(wi, backward))[0]
            assert d_fwd > 0.003 and d_back < -0.003, (theta, d_fwd, d_back)
            assert d_fwd == pytest.approx(-d_back, rel=1e-9)  # cos(l·π) = −cos(0) for odd l
    wi = sph_to_vec(np.radians(45.0), 0.0)
    assert ptfe.eval(wi, sph_to_vec(np.radians(45.0), np.pi))[0] > ptfe.eval(wi, wi)[0]


def _measured(lam_um):
    data = np.genfromtxt(PTFE_DATA, delimiter=",", skip_header=1, usecols=range(6))
    rows = data[np.isclose(data[:, 0], lam_um)]
    assert rows.shape[0] > 1800
    return rows


def _rms_log_error(model, rows, lam_nm, flip_source=True):
    """rms of log(model / measured) over Germer's rows; a negative θi with φi = 0 is a source at
    azimuth 180° (``flip_source``; without it, the convention error)."""
    theta_i = np.radians(np.abs(rows[:, 1]))
    phi_src = np.radians(rows[:, 2]) + np.where((rows[:, 1] < 0) & flip_source, np.pi, 0.0)
    wi = sph_to_vec(theta_i, phi_src)
    wo = sph_to_vec(np.radians(rows[:, 3]), np.radians(rows[:, 4]))
    f = model.eval(wi, wo, wavelengths=[lam_nm])[:, 0]
    return float(np.sqrt(np.mean(np.log(f / rows[:, 5]) ** 2)))


def test_ptfe_matches_germers_measured_brdf(ptfe):
    rows = _measured(0.532)
    err = _rms_log_error(ptfe, rows, 532.0)
    assert err < 0.03, err                                    # 2.17 %
    wrong = _rms_log_error(ptfe, rows, 532.0, flip_source=False)
    assert wrong > 0.10, wrong                                # 11.5 %: the azimuth convention matters
    # the same coefficients at Germer's other wavelengths (λ^p terms), evaluated on request
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BrdftabWarning)       # 1064 nm: negative at grazing (tested below)
        for lam in (0.351, 0.633, 1.064):
            assert _rms_log_error(ptfe, _measured(lam), lam * 1000.0) < 0.03, lam


# --------------------------------------------------------------------------------------------
# Wavelengths, negativity, range warnings


def test_wavelength_is_a_parameter_and_a_request(ptfe):
    wi, wo = _random_pairs(200, seed=2)
    default = ptfe.eval(wi, wo)
    assert default.shape == (200, 1) and ptfe.channels == ("mono",)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BrdftabWarning)       # 1064 nm: clamping reported, tested below
        three = ptfe.eval(wi, wo, wavelengths=[351.0, 532.0, 1064.0])
    assert three.shape == (200, 3)
    np.testing.assert_array_equal(three[:, 1], default[:, 0])
    assert not np.allclose(three[:, 0], three[:, 2])          # PTFE.coeff.csv has p = 1 terms
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BrdftabWarning)       # 1064 nm: clamping reported, tested below
        at1064 = _model(PTFE_COEFF, wavelength_nm=1064.0)
    np.testing.assert_array_equal(at1064.eval(wi, wo)[:, 0], three[:, 2])
    # scale = r(λ), here a spectrum
    spec = _model(PTFE_COEFF, scale={"wavelengths_nm": [400.0, 700.0], "values": [0.5, 1.0]})
    np.testing.assert_allclose(spec.eval(wi, wo, wavelengths=[550.0]), 0.75 * ptfe.eval(wi, wo, wavelengths=[550.0]),
                               rtol=1e-14)
    with pytest.raises(ParameterError, match="scale"):
        _model(PTFE_COEFF, scale=[0.9, 0.9, 0.9])


def test_negative_expansion_is_clamped_and_reported():
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        m = _model(PTFE_COEFF, wavelength_nm=1064.0)
    neg = [w for w in caught if issubclass(w.category, BrdftabWarning) and "negative" in str(w.message)]
    assert len(neg) == 1 and "clamped to 0" in str(neg[0].message) and "1064 nm" in str(neg[0].message)
    # grazing pairs, where Germer's 1064 nm expansion dips below 0 (SCATMECH's own formula says so)
    theta = np.radians(np.linspace(80.0, 89.99, 40))
    dphi = np.linspace(0.0, np.pi, 25)
    T1, T2, P = np.meshgrid(theta, theta, dphi, indexing="ij")
    wi = sph_to_vec(T1.ravel(), 0.0)
    wo = sph_to_vec(T2.ravel(), P.ravel())
    ref = _scatmech_f11(_read_rows(PTFE_COEFF), *_scatmech_angles(wi, wo), 1.064)
    raw = m.expansion(wi, wo)[:, 0]
    np.testing.assert_allclose(raw, ref, rtol=1e-10, atol=1e-12)
    assert raw.min() < -0.15                                  # ≈ −0.22 sr⁻¹ at the horizon
    before = m.clamped
    f = m.eval(wi, wo)[:, 0]
    np.testing.assert_array_equal(f, np.maximum(raw, 0.0))    # clamped there, untouched elsewhere
    assert m.clamped - before == int(np.sum(raw < 0)) > 0
    check_contract(m, seed=11)                                # clamping keeps the contract
    # 532 nm: no negative value, nothing clamped, no warning
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ok = _model(PTFE_COEFF, wavelength_nm=532.0)
        ok.eval(wi, wo)
    assert not caught and ok.clamped == 0 and ok.evaluated == wi.shape[0]


def test_wavelengths_outside_the_fitted_range_warn(ptfe):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        _model(PTFE_COEFF, wavelength_nm=1200.0)
    texts = [str(w.message) for w in caught if issubclass(w.category, BrdftabWarning)]
    assert any(re.search(r"1200 nm is outside .* \(351-1064 nm\)", t) for t in texts), texts
    m = _model(SYNTHETIC, wavelength_nm=532.0)
    wi, wo = _random_pairs(10, seed=4)
    with pytest.warns(BrdftabWarning, match="300 nm is outside"):
        m.eval(wi, wo, wavelengths=[300.0, 532.0])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        m.eval(wi, wo, wavelengths=[300.0, 532.0])           # once per wavelength
        m.eval(wi, wo, wavelengths=[351.0, 1064.0])           # the ends are inside
        _model(SYNTHETIC, wavelength_nm=450.0, fit_min_nm=400.0, fit_max_nm=500.0)
    assert not caught, [str(w.message) for w in caught]
    with pytest.warns(BrdftabWarning, match="399 nm is outside"):
        _model(SYNTHETIC, wavelength_nm=399.0, fit_min_nm=400.0, fit_max_nm=500.0)
    with pytest.raises(ParameterError, match="fit_min_nm"):
        _model(SYNTHETIC, fit_min_nm=600.0, fit_max_nm=500.0)


# --------------------------------------------------------------------------------------------
# Coefficient files: accepted layouts and every error


def test_coefficient_layouts_accepted(tmp_path):
    germer = _model(PTFE_COEFF).coefficients
    assert len(germer.a) == 660 and germer.n_f11 == 80
    i, j, n, m, k, l, p = germer.rows.T
    assert int(np.sum(np.abs(l) > n)) == 60                   # legitimate rows with |l| > n
    text = "\n".join([
        "; comment line",
        "",
        "1 1 0 0 0 0 0 2.0   ; whitespace separated, trailing comment",
        "1,1,1,1,0,1,0,-0.3",          # 11 row: column 5 ignored (k = 0 with l = 1 would be odd)
        "1, 2, 2, 1, 0, 1, 0, 0.1",    # k with n (2 − 0), l with m (1 − 1): even; l with n would be odd
        "1, 3, 0, 2, 0, 2, 0, 0.1",    # |l| > n off the 11 element
        "  4 ,\t4, 0, 0, 0, 0, 0, +1e-3",
    ]) + "\n"
    m = _model(_write(tmp_path, text))
    assert m.coefficients.n_f11 == 2 and len(m.coefficients.a) == 5
    assert list(m.coefficients.lines) == [3, 4, 5, 6, 7]


BAD_ROWS = [
    ("1, 1, 0, 0, 0, 0, 2.0", "expected 8 columns"),
    ("1, 1, 0, 0, 0, 0, 0, 2.0, 7", "expected 8 columns"),
    ("1, 1, x, 0, 0, 0, 0, 2.0", "column 3 (n) must be a whole number"),
    ("1, 1, 1.0, 1, 1, 1, 0, 2.0", "column 3 (n) must be a whole number"),
    ("1, 1, 0, 0, 0, 0, 0, abc", "column 8 (a) must be a number"),
    ("1, 1, 0, 0, 0, 0, 0, nan", "must be finite"),
    ("2, 1, 0, 0, 0, 0, 0, 0.5", "i > j"),
    ("1, 5, 0, 0, 0, 0, 0, 0.5", "1 to 4"),
    ("1, 1, -2, 0, 0, 0, 0, 0.5", "radial orders"),
    ("1, 1, 1, 0, 1, 1, 0, 0.5", "m - l = 0 - 1 is odd"),          # 11: column 6 with column 4
    ("1, 1, 2, 1, 1, 1, 0, 0.5", "n - l = 2 - 1 is odd"),          # 11: column 6 with column 3
    ("1, 1, 1, 1, 1, 0, 0, 0.5", "n - l = 1 - 0 is odd"),          # 11: column 5 (k = 1) is not used
    ("1, 2, 2, 1, 1, 1, 0, 0.5", "n - k = 2 - 1 is odd"),          # off 11: column 5 with column 3
    ("1, 2, 1, 2, 1, 1, 0, 0.5", "m - l = 2 - 1 is odd"),          # off 11: column 6 with column 4
    # orders beyond the documented limit: refused on reading, not tens of GB at evaluation
    ("1, 1, 20000, 20000, 0, 0, 0, 0.5", "orders above 100 are not supported (n = 20000, m = 20000"),
    ("1, 1, 0, 0, 0, 102, 0, 0.5", "orders above 100 are not supported (l = 102"),
    pytest.param("1, 1, " + "2" * 400 + ", 0, 0, 0, 0, 0.5",
                 "orders above 100 are not supported (n = 22222222... (400 digits)", id="order-of-400-digits"),
    ("1, 1, 0, 0, 0, 0, 17, 0.5", "power of the wavelength p must lie in -16..16, got 17"),
]


@pytest.mark.parametrize("row, why", BAD_ROWS)
def test_coefficient_file_errors_name_file_and_line(tmp_path, row, why):
    path = _write(tmp_path, f"; header\n1, 1, 0, 0, 0, 0, 0, 2.0\n\n{row}\n1, 1, 2, 0, 0, 0, 0, 0.2\n")
    with pytest.raises(ParameterError) as info:
        _model(path)
    msg = str(info.value)
    assert f"{path}, line 4: " in msg and why in msg and "\n" not in msg, msg
    # the same through a spec and the CLI: exit 2, one line naming the file and the line
    spec = tmp_path / "z.toml"
    spec.write_text(f'[model]\nname = "zernike-expansion"\ncoefficients = "{path.name}"\n[grid]\ntype = "merl"\n'
                    '[[output]]\npath = "z.nc"\n')
    for cmd in ("validate", "tabulate"):
        result = CliRunner().invoke(main, [cmd, str(spec)])
        assert result.exit_code == 2, result.output
        lines = result.stderr.splitlines()
        assert len(lines) == 1 and lines[0].startswith("brdftab: error: "), result.stderr
        assert f"{path}, line 4: " in lines[0] and "model.coefficients" in lines[0] and why in lines[0]
    assert not (tmp_path / "z.nc").exists()


@pytest.mark.parametrize("content, why", [
    (b"", "no rows for the unpolarized element"),
    (b"; only comments\n\n", "no rows for the unpolarized element"),
    (b"1, 2, 0, 0, 0, 0, 0, 1.0\n", "no rows for the unpolarized element"),
    (b"1, 1, 0, 0, 0, 0, 0, 2.\xff\n", "not a UTF-8 text"),
])
def test_coefficient_file_level_errors(tmp_path, content, why):
    path = tmp_path / "c.csv"
    path.write_bytes(content)
    with pytest.raises(ParameterError, match=why) as info:
        _model(path)
    assert str(path) in str(info.value)
    with pytest.raises(ParameterError, match="no such coefficient file"):
        _model(tmp_path / "missing.csv")
    with pytest.raises(ParameterError, match="is a folder"):
        _model(tmp_path)
    with pytest.raises(ParameterError, match="expected the path of a coefficient file"):
        models.create("zernike-expansion", coefficients=5)


def test_provenance_pins_the_file_content(tmp_path):
    path = _write(tmp_path, "1, 1, 0, 0, 0, 0, 0, 2.0\n")
    m = _model(path)
    record = m.parameters["coefficients"]
    assert record["path"] == str(path.resolve()) and len(record["sha256"]) == 64
    again = models.create("zernike-expansion", **m.parameters)   # how a table's provenance rebuilds it
    wi, wo = _random_pairs(5)
    np.testing.assert_array_equal(again.eval(wi, wo), m.eval(wi, wo))
    path.write_text("1, 1, 0, 0, 0, 0, 0, 1.0\n")
    with pytest.raises(ParameterError, match="content changed"):
        models.create("zernike-expansion", **m.parameters)


# --------------------------------------------------------------------------------------------
# The spec: the shipped example and Germer's file


def _run(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "brdftab", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd, timeout=120)


def test_shipped_spec_tabulates_germers_ptfe(tmp_path):
    spec = load_spec(SPEC)
    assert spec.model.coefficients.path == PTFE_COEFF.resolve()    # relative to the spec, not the cwd
    assert (PTFE_COEFF.resolve(), "an input file of the model") in [(p.resolve(), w) for p, w in spec.inputs]
    out = tmp_path / "out"
    proc = _run("tabulate", SPEC, "--out", out, cwd=tmp_path)      # run from elsewhere
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr
    table = brdftab.open(out / "ptfe-zernike.nc")
    wi, wo = _random_pairs(300, seed=9, theta_max=80.0)
    np.testing.assert_allclose(table.eval(wi, wo), spec.model.eval(wi, wo), rtol=0.02)
    record = table.parameters["coefficients"]
    assert Path(record["path"]).resolve() == PTFE_COEFF.resolve()
    assert record["sha256"] == hashlib.sha256(PTFE_COEFF.read_bytes()).hexdigest()
    # the table reproduces Germer's measurement about as well as the model does (2.2 % rms log)
    rows = _measured(0.532)
    rows = rows[np.abs(rows[:, 1]) <= 60.0]
    theta_i = np.radians(np.abs(rows[:, 1]))
    wi = sph_to_vec(theta_i, np.radians(rows[:, 2]) + np.pi)
    wo = sph_to_vec(np.radians(rows[:, 3]), np.radians(rows[:, 4]))
    f = table.eval(wi, wo)[:, 0]
    assert np.sqrt(np.mean(np.log(f / rows[:, 5]) ** 2)) < 0.035
    proc = _run("validate", SPEC, cwd=tmp_path)
    assert proc.returncode == 0 and "FAIL" not in proc.stdout, proc.stdout + proc.stderr
    proc = _run("validate", out / "ptfe-zernike.nc", cwd=tmp_path)   # the model rebuilt from provenance
    assert proc.returncode == 0 and "against zernike-expansion" in proc.stdout, proc.stdout + proc.stderr


def test_shipped_ptfe_data_are_germers_files():
    """The copies in data/ptfe are the published files, byte for byte (SOURCE.md lists their sums)."""
    listed = re.findall(r"^([0-9a-f]{64})  (\S+)$", (PTFE / "SOURCE.md").read_text(), flags=re.M)
    assert {name for _, name in listed} == {"PTFE.coeff.csv", "PTFE.532.coeff.csv", "PTFE.633.coeff.csv",
                                            "PTFE.data.csv"}
    for digest, name in listed:
        assert hashlib.sha256((PTFE / name).read_bytes()).hexdigest() == digest, name
    assert _measured(0.532).shape == (1824, 6)


def test_no_output_may_overwrite_the_coefficient_file(tmp_path):
    coeff = tmp_path / "c.csv"
    coeff.write_bytes(SYNTHETIC.read_bytes())
    spec = tmp_path / "s.toml"
    spec.write_text('[model]\nname = "zernike-expansion"\ncoefficients = "c.csv"\n[grid]\ntype = "merl"\n'
                    '[[output]]\npath = "c.csv"\nformat = "netcdf"\n')
    result = CliRunner().invoke(main, ["tabulate", str(spec), "--overwrite"])
    assert result.exit_code == 2 and "input file of the model" in result.stderr, result.stderr
    assert coeff.read_bytes() == SYNTHETIC.read_bytes()


def test_evaluation_memory_does_not_grow_with_the_orders(tmp_path, monkeypatch):
    """Every radial polynomial and cos(lΔφ) is held per direction pair: pairs are taken in
    chunks of EXPANSION_BYTES, so a file of high orders does not need (orders × pairs) memory
    (a 2-line file of order 20000 took more than 8 GB). Peak measured with tracemalloc."""
    import tracemalloc

    from brdftab.models import zernike

    rows = ["1, 1, 0, 0, 0, 0, 0, 0.3"] + [f"1, 1, {n}, {n}, 0, {n}, 0, 1e-4" for n in range(2, 101, 2)]
    path = _write(tmp_path, "\n".join(rows) + "\n")
    monkeypatch.setattr(zernike, "EXPANSION_BYTES", 4 << 20)
    tracemalloc.start()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", BrdftabWarning)
            m = _model(path)  # scans 99,225 direction pairs for negative values
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    # without chunks: (2 x 51 radial tables + 101 cosines) x 99,225 pairs x 8 bytes = 161 MB
    assert peak < 40 << 20, peak / 2**20
    assert m.coefficients.n_f11 == 51
    # evaluated in chunks (64 kB: a few hundred pairs each), the sum still follows SCATMECH's
    monkeypatch.setattr(zernike, "EXPANSION_BYTES", 64 << 10)
    rows = "1, 1, 0, 0, 0, 0, 0, 2.0\n1, 1, 1, 1, 0, 1, 0, -0.3\n1, 1, 4, 2, 7, 2, -1, 0.02\n1, 1, 6, 6, 0, 4, 0, 0.01\n"
    small = _write(tmp_path, rows, "small.csv")
    wi, wo = _random_pairs(4000, seed=5)
    ref = _scatmech_f11(_read_rows(small), *_scatmech_angles(wi, wo), 0.532)
    np.testing.assert_allclose(_model(small).expansion(wi, wo)[:, 0], ref, rtol=1e-12, atol=1e-13)
