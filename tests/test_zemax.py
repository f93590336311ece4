"""Zemax / Radiant "BSDF Data Interchange" .bsdf files: what is specific to the format (the
format contract suite covers recognition, damage and options of every format).

Directions are computed here from the published convention (formats.md §4.1, libbsdf's
SpecularCoordinateSystem) with explicit rotation matrices, and the files are read by a minimal
parser of the layout written here, independent of brdftab's reader.
"""

from __future__ import annotations

import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from _mutate import mutations

import brdftab
from brdftab.errors import BrdftabWarning, FormatError

DATA = Path(__file__).parent / "data"
#: A measured file from the field: Radiant Imaging's Imaging Sphere (2008), PlaneSymmetrical,
#: Monochrome, 13 incidences 15-75 deg, 19 azimuths 0-180, 11 radial angles 0-80 (from
#: ansys/optical-automation tests/workflows/example_models/test_13_planesymmetric_brdf_zemax.bsdf, MIT).
RADIANT = DATA / "radiant-planesymmetric-brdf.bsdf"
SMALL = dict(incidences_deg=[0, 20, 45, 70], azimuths_deg=list(range(0, 360, 15)),
             radials_deg=[0, 1, 2, 4, 6, 8, 10, 14, 20, 30, 45, 60, 90, 120, 150, 180])


def mini_parse(text):
    """A minimal reader of the published layout: header lists, then per content block, per
    (rotation, incidence): TIS and nAzimuth x nRadial values."""
    toks = [w for line in text.splitlines() if not line.lstrip().startswith("#") for w in line.split()]
    k = 0
    head, lists = {}, {}
    while toks[k] not in ("Monochrome", "TristimulusX", "DataBegin"):
        key = toks[k]
        if key in ("SampleRotation", "AngleOfIncidence", "ScatterAzimuth", "ScatterRadial"):
            n = int(toks[k + 1])
            lists[key] = [float(x) for x in toks[k + 2:k + 2 + n]]
            k += 2 + n
        else:
            head[key] = toks[k + 1]
            k += 2
    rot, aoi = lists.get("SampleRotation", [0.0]), lists["AngleOfIncidence"]
    naz, nrad = len(lists["ScatterAzimuth"]), len(lists["ScatterRadial"])
    blocks = {}
    while k < len(toks):
        name = toks[k]
        assert toks[k + 1] == "DataBegin"
        k += 2
        data = np.empty((len(rot), len(aoi), naz, nrad))
        tis = np.empty((len(rot), len(aoi)))
        for j in range(len(rot)):
            for i in range(len(aoi)):
                assert toks[k] == "TIS"
                tis[j, i] = float(toks[k + 1])
                k += 2
                data[j, i] = np.array(toks[k:k + naz * nrad], float).reshape(naz, nrad)
                k += naz * nrad
        assert toks[k] == "DataEnd"
        k += 1
        blocks[name] = (data, tis)
    return head, lists, blocks


def convention(theta_i_deg, phi_i_deg, radial_deg, azimuth_deg):
    """(wi, wo) of a node by the published convention, with rotation matrices: ωo = Rz(φi) ·
    Rxz(θi) · sph(radial, azimuth)."""
    ti, pi_, r, a = np.radians([theta_i_deg, phi_i_deg, radial_deg, azimuth_deg])
    s = np.array([np.sin(r) * np.cos(a), np.sin(r) * np.sin(a), np.cos(r)])
    rxz = np.array([[np.cos(ti), 0, -np.sin(ti)], [0, 1, 0], [np.sin(ti), 0, np.cos(ti)]])
    rz = np.array([[np.cos(pi_), -np.sin(pi_), 0], [np.sin(pi_), np.cos(pi_), 0], [0, 0, 1]])
    wi = np.array([np.sin(ti) * np.cos(pi_), np.sin(ti) * np.sin(pi_), np.cos(ti)])
    return wi, rz @ rxz @ s


def test_the_convention_in_plain_angles():
    # radial 0 is the mirror direction; azimuth 0 points towards the normal, 180 away from it
    wi, wo = convention(30, 40, 0, 0)
    assert np.allclose(wo, [-wi[0], -wi[1], wi[2]])
    for az, theta_o in ((0, 20), (180, 40)):
        _, wo = convention(30, 0, 10, az)
        assert np.isclose(np.degrees(np.arccos(wo[2])), theta_o) and np.isclose(wo[1], 0) and wo[0] < 0
    _, wo = convention(30, 0, 30, 0)
    assert np.allclose(wo, [0, 0, 1])  # radial θi towards the normal is the normal
    # at normal incidence azimuth a, radial r is (θo, φo) = (r, φi + a): azimuth 0 is φo = φi
    _, wo = convention(0, 40, 20, 0)
    assert np.allclose(wo, [np.sin(np.radians(20)) * np.cos(np.radians(40)),
                            np.sin(np.radians(20)) * np.sin(np.radians(40)), np.cos(np.radians(20))])
    # brdftab's grid maps nodes the same way (and back)
    from brdftab.grids import SpecularPolarGrid

    g = SpecularPolarGrid(np.radians([0, 30]), np.radians([40]), np.radians([0, 90, 180, 270]),
                          np.radians([0, 10, 50]))
    wi, wo = g.directions()
    idx = np.unravel_index(np.arange(g.size), g.shape)
    deg = [np.degrees(ax.values[i]) for ax, i in zip(g.axes, idx)]
    for n in range(g.size):
        a, b = convention(deg[0][n], deg[1][n], deg[3][n], deg[2][n])
        assert np.allclose(wi[n], a, atol=1e-12) and np.allclose(wo[n], b, atol=1e-12)
    frac, outside = g.locate(wi, wo)
    keep = idx[3] > 0  # azimuth is undefined at the mirror direction itself
    for f, i in zip(frac, idx):
        assert np.allclose(np.asarray(f)[keep], i[keep], atol=1e-9)
    assert not outside.any()


def _model(rgb=False):
    m = brdftab.models
    if rgb:
        return m.create("microfacet", alpha=0.3, fresnel="conductor", n=[0.2, 0.4, 1.4], k=[3.9, 2.4, 1.6])
    return m.create("sum", terms=[m.create("lambert", albedo=0.2), m.create("microfacet", alpha=0.25)])


def test_writer_round_trip_and_an_independent_parser(tmp_path):
    path = tmp_path / "m.bsdf"
    model = _model()
    written = brdftab.save(model, path, format="zemax", sample_rotations_deg=[0, 30], **SMALL)
    table = brdftab.open(path)
    assert table.origin == "unknown" and table.channels == ("mono",)  # a foreign file is never "analytic"
    # brdftab's reader: the written values within the text precision (7 significant digits)
    v, w = np.asarray(table.values), np.asarray(written.values)
    rel = np.abs(v - w)[w > 1e-12] / w[w > 1e-12]
    assert rel.max() <= 5e-7
    # an independent parser and the convention computed here: 40 random nodes equal the model's f
    head, lists, blocks = mini_parse(path.read_text())
    assert head["ScatterType"] == "BRDF" and head["SpectralContent"] == "Monochrome"
    assert head["Symmetry"] == "Asymmetrical" and "Source" not in head
    data, tis = blocks["Monochrome"]
    rng = np.random.default_rng(3)
    checked = 0
    for _ in range(200):
        j, i, a, r = (rng.integers(n) for n in data.shape)
        wi, wo = convention(lists["AngleOfIncidence"][i], lists["SampleRotation"][j], lists["ScatterRadial"][r],
                            lists["ScatterAzimuth"][a])
        if wo[2] < 0.05 or wi[2] < 0.05:
            continue
        f = model.eval(wi, wo)[0]
        assert data[j, i, a, r] == pytest.approx(f, rel=5e-7, abs=1e-12)
        checked += 1
        if checked == 40:
            break
    assert checked == 40
    # TIS: brdftab's directional albedo of the values written, at each block's incidence
    from brdftab.integrate import directional_albedo

    a = directional_albedo(table, np.radians(lists["AngleOfIncidence"]), 0.0)[:, 0]
    assert np.allclose(tis[0], a, rtol=2e-6)
    # and the albedo of the model itself, at small and large incidence (the table's resolution)
    # (this grid's 16 radial angles hold the lobe to 3.1 % of the model's albedo)
    am = directional_albedo(model, np.radians([0.0, 45.0]), 0.0)[:, 0]
    assert np.allclose(tis[0, [0, 2]], am, rtol=0.035)


def test_rgb_is_written_as_xyz_through_colour_science(tmp_path):
    import colour

    path = tmp_path / "c.bsdf"
    model = _model(rgb=True)
    brdftab.save(model, path, format="zemax", symmetry="PlaneSymmetrical",
                 **{**SMALL, "azimuths_deg": list(range(0, 181, 15))})
    head, lists, blocks = mini_parse(path.read_text())
    assert head["SpectralContent"] == "XYZ" and head["Symmetry"] == "PlaneSymmetrical"
    assert set(blocks) == {"TristimulusX", "TristimulusY", "TristimulusZ"}
    rng = np.random.default_rng(5)
    for _ in range(25):
        i = rng.integers(1, 3)
        a, r = rng.integers(len(lists["ScatterAzimuth"])), rng.integers(1, 8)
        wi, wo = convention(lists["AngleOfIncidence"][i], 0.0, lists["ScatterRadial"][r], lists["ScatterAzimuth"][a])
        xyz = colour.RGB_to_XYZ(model.eval(wi, wo), "sRGB")
        got = [blocks[n][0][0, i, a, r] for n in ("TristimulusX", "TristimulusY", "TristimulusZ")]
        assert np.allclose(got, xyz, rtol=5e-7)
    # the mirrored half is read from the stored one: azimuth a > 180 equals 360 - a
    table = brdftab.open(path)
    wi, wo1 = convention(45, 0, 10, 60)
    _, wo2 = convention(45, 0, 10, 300)
    assert np.array_equal(table.eval(wi, wo1), table.eval(wi, wo2))
    assert table.channels == ("X", "Y", "Z")


def _radiant_nodes(n=30, seed=1):
    _, lists, blocks = mini_parse(RADIANT.read_text())
    data = blocks["Monochrome"][0]
    rng = np.random.default_rng(seed)
    out = []
    while len(out) < n:
        i, a, r = rng.integers(data.shape[1]), rng.integers(data.shape[2]), rng.integers(1, data.shape[3])
        az = lists["ScatterAzimuth"][a]
        if rng.random() < 0.5 and 0 < az < 180:
            az = 360.0 - az  # the mirrored half of a PlaneSymmetrical file
        wi, wo = convention(lists["AngleOfIncidence"][i], 0.0, lists["ScatterRadial"][r], az)
        if wo[2] > 0.02:
            out.append((wi, wo, data[0, i, a, r]))
    return out


def test_a_measured_file_from_the_field_reads_and_converts_to_netcdf(tmp_path):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        table = brdftab.open(RADIANT)
    assert table.origin == "measured" and table.grid.type_name == "specular-polar"
    assert table.grid.azimuth_fold == "plane" and table.shape == (13, 1, 19, 11, 1)
    # its TIS (the instrument's) and the albedo of its data disagree: one warning with both figures
    msg = [str(w.message) for w in caught if issubclass(w.category, BrdftabWarning)]
    assert len(msg) == 1 and "TIS 0.257189" in msg[0] and "directional albedo of its data is 0.2" in msg[0]
    nodes = _radiant_nodes()
    wi = np.array([n[0] for n in nodes])
    wo = np.array([n[1] for n in nodes])
    want = np.array([n[2] for n in nodes])
    assert np.array_equal(table.eval(wi, wo)[:, 0], want)
    # validate reads it as measured data, and convert writes netCDF value for value
    proc = subprocess.run([sys.executable, "-m", "brdftab", "convert", str(RADIANT), str(tmp_path / "r.nc")],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and "copied" in proc.stdout, proc.stderr
    nc = brdftab.open(tmp_path / "r.nc")
    assert type(nc.grid).__name__ == "SpecularPolarGrid" and nc.origin == "measured"
    assert np.array_equal(nc.values, table.values)
    assert np.array_equal(nc.eval(wi, wo)[:, 0], want)
    brdftab.save(table, tmp_path / "r.zarr")  # zarr holds the same grid, value for value
    assert np.array_equal(brdftab.open(tmp_path / "r.zarr").values, table.values)
    rng = np.random.default_rng(0)
    from brdftab.geometry import sph_to_vec

    a = sph_to_vec(rng.uniform(0.2, 1.4, 400), rng.uniform(0, 6.3, 400))
    b = sph_to_vec(rng.uniform(0.0, 1.5, 400), rng.uniform(0, 6.3, 400))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BrdftabWarning)
        assert np.array_equal(nc.eval(a, b), table.eval(a, b), equal_nan=True)
    # and back: the netCDF table written as Zemax holds the file's numbers on the file's nodes
    from brdftab.convert import convert

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BrdftabWarning)
        convert(tmp_path / "r.nc", tmp_path / "r.bsdf", format="zemax", progress=False)
    head, lists, blocks = mini_parse((tmp_path / "r.bsdf").read_text())
    _, lists0, blocks0 = mini_parse(RADIANT.read_text())
    assert head["Source"] == "Measured" and head["Symmetry"] == "PlaneSymmetrical" and lists == lists0
    assert np.array_equal(blocks["Monochrome"][0], blocks0["Monochrome"][0])


def test_a_btdf_file_is_refused_in_one_line(tmp_path):
    path = tmp_path / "t.bsdf"
    path.write_text(RADIANT.read_text().replace("ScatterType  BRDF", "ScatterType  BTDF"))
    with pytest.raises(FormatError, match="BTDF.*reflection") as info:
        brdftab.open(path)
    assert "\n" not in str(info.value)


def test_tis_mismatch_is_a_warning_with_both_figures(tmp_path):
    path = tmp_path / "m.bsdf"
    brdftab.save(_model(), path, format="zemax", **SMALL)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        brdftab.open(path)  # its own TIS: no warning
    text = path.read_text()
    first = next(line for line in text.splitlines() if line.startswith("TIS "))
    path.write_text(text.replace(first, "TIS 0.9", 1))
    with pytest.warns(BrdftabWarning, match=r"TIS 0\.9 in the file at incidence 0 deg.*albedo of its data is "
                                            + first.split()[1][:5].replace(".", r"\.")):
        brdftab.open(path)


DAMAGE = {
    "missing keyword": (lambda t: t.replace("ScatterRadial", "ScatterRadius"), "unknown keyword 'ScatterRadius'"),
    "count mismatch": (lambda t: t.replace("AngleOfIncidence  13", "AngleOfIncidence  14"), "expected"),
    "not a number": (lambda t: t.replace("6.375E-02", "6.375E-0x", 1), "expected BSDF values"),
    "negative count": (lambda t: t.replace("ScatterAzimuth 19", "ScatterAzimuth -19"), "expected a count"),
    "truncated": (lambda t: t[: len(t) * 2 // 3], "truncated"),
    "no DataEnd": (lambda t: t.replace("DataEnd", ""), "DataEnd"),
    "no symmetry": (lambda t: t.replace("Symmetry  PlaneSymmetrical\n", ""), "missing keyword Symmetry"),
}


@pytest.mark.parametrize("what", sorted(DAMAGE))
def test_damaged_files_are_refused_in_one_line_naming_file_and_line(tmp_path, what):
    cut, words = DAMAGE[what]
    path = tmp_path / "bad.bsdf"
    text = RADIANT.read_text()
    assert cut(text) != text
    path.write_text(cut(text))
    with pytest.raises(FormatError) as info:
        brdftab.open(path)
    msg = str(info.value)
    assert "\n" not in msg and str(path) in msg and words in msg and ": line " in msg


def test_a_spec_output_tabulates_ggx_gold_to_zemax_validated(tmp_path):
    spec = (Path(__file__).parent.parent / "specs" / "ggx-gold.toml").read_text()
    spec = spec[:spec.index("[[output]]")] + (
        '[[output]]\npath = "ggx-gold.bsdf"\nformat = "zemax"\nincidences_deg = [0, 5, 10, 15, 20, 25, 30, 35, 40]\n'
        f'azimuths_deg = {list(range(0, 360, 10))}\n')
    (tmp_path / "s.toml").write_text(spec)
    from brdftab.pipeline import run
    from brdftab.spec import load_spec

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        run(load_spec(tmp_path / "s.toml"), progress=False)  # refuses (raises) when a check fails
    out = tmp_path / "ggx-gold.bsdf"
    assert out.exists() and not [w for w in caught if issubclass(w.category, BrdftabWarning)]
    head, lists, _ = mini_parse(out.read_text())
    assert head["SpectralContent"] == "XYZ" and lists["AngleOfIncidence"] == list(range(0, 45, 5))
    # the file against the model in XYZ at the grid's cell centres (the pre-export comparison)
    from brdftab.colorimetry import XYZView
    from brdftab.convert import difference

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BrdftabWarning)
        d, _ = difference(XYZView(load_spec(tmp_path / "s.toml").model), brdftab.open(out))
    assert d.median_rel <= 0.005 and d.p95_rel <= 0.025


def test_a_spectral_model_is_written_as_xyz_through_colorimetry(tmp_path):
    from brdftab.colorimetry import spectral_to_xyz

    al = {"n": {"wavelengths_nm": [400, 550, 700], "values": [0.490, 0.958, 1.83]},
          "k": {"wavelengths_nm": [400, 550, 700], "values": [4.86, 6.69, 8.31]}}
    model = brdftab.models.create("microfacet", alpha=0.3, fresnel="conductor", n=al["n"], k=al["k"])
    lam = np.linspace(400.0, 700.0, 16)
    path = tmp_path / "s.bsdf"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BrdftabWarning)
        brdftab.save(model, path, format="zemax", wavelengths_nm=lam.tolist(),
                     **{**SMALL, "incidences_deg": [0, 40], "azimuths_deg": [0, 90, 180, 270]})
    head, lists, blocks = mini_parse(path.read_text())
    assert head["SpectralContent"] == "XYZ"
    for i, a, r in ((0, 0, 3), (1, 1, 5), (1, 2, 8), (0, 3, 10), (1, 0, 2)):
        wi, wo = convention(lists["AngleOfIncidence"][i], 0.0, lists["ScatterRadial"][r], lists["ScatterAzimuth"][a])
        xyz = spectral_to_xyz(model.eval(wi, wo, lam), lam)
        got = [blocks[n][0][0, i, a, r] for n in ("TristimulusX", "TristimulusY", "TristimulusZ")]
        assert np.allclose(got, xyz, rtol=1e-6)


def test_mutated_files_give_a_format_error_or_a_table_never_a_crash():
    """Tokens of the measured file deleted, duplicated or replaced at random: the parser answers
    each with its content or one FormatError line naming the line."""
    from brdftab.formats.zemax import parse_zemax

    lines = RADIANT.read_text().splitlines()
    junk = ["", "-1", "0", "1e999", "nan", "TIS", "DataEnd", "DataBegin", "x", "3.5", "Monochrome", "999999"]
    errors = 0
    for text in mutations(lines, junk, 150):
        try:
            parse_zemax("m.bsdf", text)
        except FormatError as exc:
            errors += 1
            assert "\n" not in str(exc) and str(exc).startswith("m.bsdf: line ")
    assert errors > 50


def test_an_anisotropic_source_is_written_with_sample_rotations_as_incident_azimuths(tmp_path):
    model = brdftab.models.create("microfacet", alpha_x=0.15, alpha_y=0.4)
    path = tmp_path / "a.bsdf"
    with pytest.raises(FormatError, match="anisotropic.*sample_rotations_deg"):
        brdftab.save(model, path, format="zemax", sample_rotations_deg=[0], **SMALL)
    brdftab.save(model, path, format="zemax", sample_rotations_deg=[0, 45, 90, 135, 180, 225, 270, 315],
                 **{**SMALL, "incidences_deg": [0, 30, 60]})
    _, lists, blocks = mini_parse(path.read_text())
    data = blocks["Monochrome"][0]
    rng = np.random.default_rng(11)
    for _ in range(25):
        j, i, a, r = (int(rng.integers(n)) for n in data.shape)
        r = max(r, 1)
        wi, wo = convention(lists["AngleOfIncidence"][i], lists["SampleRotation"][j], lists["ScatterRadial"][r],
                            lists["ScatterAzimuth"][a])
        if wo[2] > 0.05:
            assert data[j, i, a, r] == pytest.approx(model.eval(wi, wo)[0], rel=5e-7, abs=1e-12)
    table = brdftab.open(path)
    assert not table.isotropic and len(table.grid.axes[1]) == 8
