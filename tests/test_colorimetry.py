"""Spectra to colour through colour-science (brdftab.colorimetry) and the writers that store
colour (MERL, EXR): the conversion is colour-science's own, sample for sample."""

from __future__ import annotations

import json
import subprocess
import sys
import warnings

import colour
import numpy as np
import OpenEXR
import pytest

import brdftab
from brdftab import colorimetry
from brdftab.channels import luminance_weights
from brdftab.errors import ParameterError
from brdftab.grids.rusinkiewicz import RusinkiewiczGrid
from brdftab.models import create
from brdftab.table import tabulate

LAM31 = np.linspace(400.0, 700.0, 31)
# aluminium, Rakić 1995 (refractiveindex.info), at 400, 550 and 700 nm
AL = {"n": {"wavelengths_nm": [400, 550, 700], "values": [0.490, 0.958, 1.83]},
      "k": {"wavelengths_nm": [400, 550, 700], "values": [4.86, 6.69, 8.31]}}


def colour_science(spectra, lam, illuminant="D65", observer="CIE 1931 2 Degree Standard Observer", space="sRGB"):
    """colour-science's own conversion, spectrum by spectrum: sd_to_XYZ with the observer and
    illuminant as its defaults build them from their names, / 100, then XYZ_to_RGB (linear)."""
    cmfs, sd_illuminant = colour.colorimetry.handle_spectral_arguments(cmfs_default=observer,
                                                                        illuminant_default=illuminant)
    lam = np.asarray(lam, float)
    step = np.diff(lam)
    method = "ASTM E308" if np.allclose(step, step[0]) and round(step[0]) in (1, 5, 10, 20) else "Integration"
    out = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for s in np.asarray(spectra, float).reshape(-1, lam.size):
            sd = colour.SpectralDistribution(s, lam) if lam.size >= 6 else \
                colour.SpectralDistribution(s, lam, interpolator=colour.LinearInterpolator)
            xyz = colour.sd_to_XYZ(sd, cmfs, sd_illuminant, method=method) / 100.0
            out.append(xyz if space == "XYZ" else colour.XYZ_to_RGB(
                xyz, space, illuminant=colour.CCS_ILLUMINANTS[observer][illuminant]))
    return np.array(out)


@pytest.mark.parametrize("lam", [LAM31, np.arange(380.0, 781.0, 5.0), np.array([400, 420, 455, 500, 560, 610, 700.0]),
                                 np.array([450.0, 550.0, 650.0])], ids=["10nm", "5nm", "irregular", "three"])
@pytest.mark.parametrize("illuminant, observer", [("D65", "cie1931-2"), ("A", "cie1964-10")])
def test_the_conversion_is_colour_sciences_own(lam, illuminant, observer):
    spectra = np.random.default_rng(3).random((6, lam.size))
    obs = colorimetry.OBSERVERS[observer]
    for space in ("XYZ", "sRGB"):
        got = colorimetry.Colorimetry(illuminant, observer, space).matrix(lam)
        np.testing.assert_allclose(spectra @ got, colour_science(spectra, lam, illuminant, obs, space), rtol=0,
                                   atol=1e-12)


def test_a_constant_spectrum_is_white_of_that_luminance():
    """Y of a constant spectrum v is v, and under D65 it is sRGB's white (v, v, v) — within the
    ASTM E308 weights of a 400-700 nm spectrum (which leave out the observer's tails)."""
    xyz = colorimetry.spectral_to_xyz(np.full(31, 0.25), LAM31)
    assert abs(xyz[1] - 0.25) < 1e-12
    np.testing.assert_allclose(colorimetry.spectral_to_rgb(np.full(31, 0.25), LAM31), 0.25, rtol=2e-4)


def test_spectral_luminance_weights_are_cie_y():
    """The luminance of a spectrum (the RGL writer's luminance field, the reciprocity check's
    weighting) is its CIE Y under D65 relative to a constant spectrum's."""
    s = np.random.default_rng(5).random(31)
    y = colour_science([s, np.ones(31)], LAM31, space="XYZ")[:, 1]
    assert abs(luminance_weights(None, LAM31) @ s - y[0] / y[1]) < 1e-12
    assert np.allclose(luminance_weights(None, [900.0, 1000.0, 1100.0]), 1 / 3)  # no colour: the mean


def test_bad_conversions_are_one_line():
    with pytest.raises(ParameterError, match="unknown illuminant"):
        colorimetry.Colorimetry("D66")
    with pytest.raises(ParameterError, match="unknown observer"):
        colorimetry.Colorimetry("D65", "cie2000")
    with pytest.raises(ParameterError, match="no colour"):
        colorimetry.spectral_to_rgb([1.0], [550.0])
    with pytest.raises(ParameterError, match="outside the observer"):
        colorimetry.spectral_to_rgb([1.0, 1.0], [1000.0, 1100.0])


def _al_table():
    model = create("microfacet", alpha=0.3, fresnel="conductor", material="Al")  # Rakić, refractiveindex.info
    return model, tabulate(model, RusinkiewiczGrid(6, 6, 8), LAM31, progress=False)


def test_a_spectral_conductor_in_exr_is_colour_sciences_srgb(tmp_path):
    """A spectral aluminium table (n, k from the database) at 31 wavelengths written to EXR (the default colour = rgb):
    every pixel is colour-science's sRGB of that sample's spectrum to 1e-6 (float32 pixels), and
    the header records illuminant, observer and colourspace; colour = spectral keeps the spectra."""
    _, table = _al_table()
    brdftab.save(table, tmp_path / "al.exr")
    back = brdftab.open(tmp_path / "al.exr")
    assert back.channels == ("R", "G", "B")
    ref = colour_science(np.asarray(table.values), LAM31).reshape(back.values.shape)
    np.testing.assert_allclose(back.values, ref, rtol=1e-6, atol=1e-9)
    with OpenEXR.File(str(tmp_path / "al.exr")) as f:
        hdr = dict(f.parts[0].header)
    assert hdr["colour_illuminant"] == "D65" and hdr["colour_observer"] == "CIE 1931 2 Degree Standard Observer"
    assert hdr["colour_space"] == "sRGB (linear)" and "colour-science" in hdr["colour_conversion"]
    # the checks rebuild the model from the provenance and see it in the recorded colour: the
    # samples match it at the nodes (float32), as a later `brdftab validate` finds
    from brdftab.checks import run_checks

    report = run_checks(back, only=("conventions", "tabulation"))
    assert report.get("conventions").status == "pass" and report.get("conventions").data["node_error"] < 1e-6
    assert report.get("tabulation").status in ("pass", "warn")
    brdftab.save(table, tmp_path / "al-a.exr", illuminant="A")
    ref_a = colour_science(np.asarray(table.values), LAM31, illuminant="A").reshape(back.values.shape)
    np.testing.assert_allclose(brdftab.open(tmp_path / "al-a.exr").values, ref_a, rtol=1e-6, atol=1e-9)
    brdftab.save(table, tmp_path / "al-s.exr", colour="spectral")
    assert brdftab.open(tmp_path / "al-s.exr").spectral


def test_a_spectral_spec_tabulates_to_merl_in_srgb_saying_so(tmp_path):
    """A spectral spec with a MERL output: the file holds colour-science's sRGB of the model's
    spectra (MERL has no metadata: one warning line says what was used), and the checks judge it
    against the model seen in that colour (they pass)."""
    spec = tmp_path / "al.toml"
    spec.write_text(f"""[model]
name = "microfacet"
alpha = 0.3
fresnel = "conductor"
n = {json.dumps(AL["n"]).replace('": ', '" = ').replace('"wavelengths_nm"', 'wavelengths_nm').replace('"values"', 'values')}
k = {json.dumps(AL["k"]).replace('": ', '" = ').replace('"wavelengths_nm"', 'wavelengths_nm').replace('"values"', 'values')}

[grid]
type = "rusinkiewicz"
n_theta_h = 8
n_theta_d = 8
n_phi_d = 8
wavelengths_nm = {{start = 400, stop = 700, num = 31}}

[[output]]
path = "al.binary"
""")
    run = subprocess.run([sys.executable, "-m", "brdftab", "tabulate", str(spec)], cwd=tmp_path,
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    notes = [line for line in run.stderr.splitlines() if "spectral" in line]
    assert len(notes) == 1 and "sRGB (linear) under D65, CIE 1931 2 Degree Standard Observer" in notes[0], run.stderr
    back = brdftab.open(tmp_path / "al.binary")
    model = create("microfacet", alpha=0.3, fresnel="conductor", **AL)
    rng = np.random.default_rng(2)
    wi, wo = rng.normal(size=(2, 40, 3))
    wi[:, 2], wo[:, 2] = np.abs(wi[:, 2]) + 0.3, np.abs(wo[:, 2]) + 0.3
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    # the MERL grid's interpolation against colour-science's sRGB of the model's spectra
    ref = colour_science(model.eval(wi, wo, LAM31), LAM31)
    got = np.asarray(back.eval(wi, wo))
    assert np.median(np.abs(got - ref) / ref) < 0.01


def test_converting_keeps_numpy_print_options():
    """colour-science switches numpy to its 1.13 legacy printing when imported; brdftab imports
    it keeping the caller's options."""
    code = ("import numpy as np\nfrom brdftab.colorimetry import spectral_to_rgb\n"
            "spectral_to_rgb([0.2, 0.4, 0.6], [450.0, 550.0, 650.0])\nimport colour\n"
            "print(repr(np.array([0.5])), np.get_printoptions()['legacy'])")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert run.stdout.split() == ["array([0.5])", "False"]
