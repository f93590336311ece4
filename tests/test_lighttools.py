"""LightTools text .bsdf files: what is specific to the format (the format contract suite covers
recognition, damage and options of every format).

No LightTools file is public (searched: GitHub code for the block keywords AOI/POI/Side/
TristimulusValue with ScatterRadial, libbsdf's repository, which has no data files); the layout
is libbsdf's reader's (formats.md §4.2). Directions are computed here from that convention with
explicit rotation matrices, and files are read by a minimal parser of the layout written here,
independent of brdftab's reader.
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

SMALL = dict(incidences_deg=[0, 20, 45, 70], azimuths_deg=list(range(0, 360, 15)),
             radials_deg=[0, 5, 10, 15, 20, 25, 30, 40, 50, 60, 70, 80, 90])


def mini_parse(text):
    """A minimal reader of the published layout: header lists, then blocks of keyword/value
    pairs ending with TIS and nAzimuth x nRadial values, until DataEnd."""
    toks = [w for line in text.splitlines() if not line.lstrip().startswith("#") for w in line.split()]
    k = 0
    head, lists = {}, {}
    while toks[k] != "DataBegin":
        if toks[k] in ("ScatterAzimuth", "ScatterRadial"):
            n = int(toks[k + 1])
            lists[toks[k]] = [float(x) for x in toks[k + 2:k + 2 + n]]
            k += 2 + n
        else:
            head[toks[k]] = toks[k + 1]
            k += 2
    k += 1
    naz, nrad = len(lists["ScatterAzimuth"]), len(lists["ScatterRadial"])
    blocks, block = [], {}
    while toks[k] != "DataEnd":
        key, value = toks[k], toks[k + 1]
        k += 2
        if key == "TIS":
            block["TIS"] = float(value)
            block["values"] = np.array(toks[k:k + naz * nrad], float).reshape(naz, nrad)
            k += naz * nrad
            blocks.append(block)
            block = {}
        else:
            block[key] = float(value) if key in ("AOI", "POI", "Wavelength") else value
    return head, lists, blocks


def _rz(deg):
    a = np.radians(deg)
    return np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])


def _sph(theta_deg, phi_deg):
    t, p = np.radians(theta_deg), np.radians(phi_deg)
    return np.array([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])


def convention(aoi, poi, radial, azimuth):
    """(wi, wo) in brdftab's frame of a node (degrees): in the file's frame the incident direction
    lies at azimuth POI + 90 and the outgoing one at (ScatterRadial, ScatterAzimuth); brdftab's
    frame is the file's turned by -90 degrees about the normal."""
    return _rz(-90) @ _sph(aoi, poi + 90), _rz(-90) @ _sph(radial, azimuth)


def _model(rgb=False):
    m = brdftab.models
    if rgb:
        return m.create("microfacet", alpha=0.3, fresnel="conductor", n=[0.2, 0.4, 1.4], k=[3.9, 2.4, 1.6])
    return m.create("sum", terms=[m.create("lambert", albedo=0.2), m.create("microfacet", alpha=0.25)])


def test_the_convention_in_plain_angles():
    # the mirror direction of a block is at ScatterAzimuth POI + 270, ScatterRadial AOI
    wi, wo = convention(30, 40, 30, 40 + 270)
    assert np.allclose(wo, [-wi[0], -wi[1], wi[2]])
    # POI 0: brdftab's phi_i = 0, and ScatterAzimuth 90 is phi_o = 0 (the incident side)
    wi, wo = convention(30, 0, 20, 90)
    assert np.allclose(wi, _sph(30, 0)) and np.allclose(wo, _sph(20, 0))
    # brdftab's grid maps nodes the same way (and back)
    from brdftab.formats.lighttools import _grid

    g = _grid({"incidences_deg": [0, 30], "poi_deg": [0, 40], "azimuths_deg": [0, 90, 200, 300],
               "radials_deg": [0, 10, 50]}, anisotropic=True)
    wi, wo = g.directions()
    idx = np.unravel_index(np.arange(g.size), g.shape)
    for n in range(g.size):
        i, j, r, a = (ix[n] for ix in idx)
        want = convention([0, 30][i], [0, 40][j], [0, 10, 50][r], [0, 90, 200, 300][a])
        assert np.allclose(wi[n], want[0], atol=1e-12) and np.allclose(wo[n], want[1], atol=1e-12)
    frac, outside = g.locate(wi, wo)
    keep = (idx[0] > 0) & (idx[2] > 0)  # azimuths are undefined at the pole
    for f, i in zip(frac, idx):
        assert np.allclose(np.asarray(f)[keep], i[keep], atol=1e-9)
    assert not outside.any()


def test_writer_round_trip_and_an_independent_parser(tmp_path):
    path = tmp_path / "m.bsdf"
    model = _model()
    written = brdftab.save(model, path, format="lighttools", **SMALL)
    table = brdftab.open(path)
    assert table.origin == "unknown" and table.channels == ("mono",) and table.isotropic
    # brdftab's reader: the written values within the text precision (7 significant digits)
    v, w = np.asarray(table.values), np.asarray(written.values)
    rel = np.abs(v - w)[w > 1e-12] / w[w > 1e-12]
    assert rel.max() <= 5e-7
    # an independent parser and the convention computed here: 40 random nodes equal the model's f
    head, lists, blocks = mini_parse(path.read_text())
    assert head == {"Symmetry": "Asymmetric", "SpectralContent": "Monochrome"}
    assert lists["ScatterAzimuth"] == SMALL["azimuths_deg"] and lists["ScatterRadial"] == SMALL["radials_deg"]
    assert [b["AOI"] for b in blocks] == SMALL["incidences_deg"]
    assert all(b["POI"] == 0 and b["Side"] == "Front" and b["ScatterType"] == "BRDF" for b in blocks)
    rng = np.random.default_rng(3)
    checked = 0
    for _ in range(200):
        b = blocks[rng.integers(len(blocks))]
        a, r = rng.integers(len(lists["ScatterAzimuth"])), rng.integers(len(lists["ScatterRadial"]))
        wi, wo = convention(b["AOI"], b["POI"], lists["ScatterRadial"][r], lists["ScatterAzimuth"][a])
        if wo[2] < 0.05:
            continue
        assert b["values"][a, r] == pytest.approx(model.eval(wi, wo)[0], rel=5e-7, abs=1e-12)
        checked += 1
        if checked == 40:
            break
    assert checked == 40
    # TIS: brdftab's directional albedo of the values written, at each block's incidence
    from brdftab.integrate import directional_albedo

    a = directional_albedo(table, np.radians(SMALL["incidences_deg"]), 0.0)[:, 0]
    assert np.allclose([b["TIS"] for b in blocks], a, rtol=2e-6)
    # and the albedo of the model (the table's 5-degree resolution holds the lobe to 2 %)
    am = directional_albedo(model, np.radians([0.0, 45.0]), 0.0)[:, 0]
    assert np.allclose(a[[0, 2]], am, rtol=0.02)


def test_rgb_is_written_as_xyz_tristimulus_blocks_through_colour_science(tmp_path):
    import colour

    path = tmp_path / "c.bsdf"
    model = _model(rgb=True)
    brdftab.save(model, path, format="lighttools", **SMALL)
    head, lists, blocks = mini_parse(path.read_text())
    assert head["SpectralContent"] == "XYZ" and len(blocks) == 3 * 4
    assert [b["TristimulusValue"] for b in blocks[:3]] == ["TrisX", "TrisY", "TrisZ"]
    by = {(b["AOI"], b["TristimulusValue"]): b["values"] for b in blocks}
    rng = np.random.default_rng(5)
    for _ in range(25):
        aoi = SMALL["incidences_deg"][rng.integers(1, 3)]
        a, r = rng.integers(len(lists["ScatterAzimuth"])), rng.integers(1, 8)
        wi, wo = convention(aoi, 0.0, lists["ScatterRadial"][r], lists["ScatterAzimuth"][a])
        xyz = colour.RGB_to_XYZ(model.eval(wi, wo), "sRGB")
        got = [by[aoi, t][a, r] for t in ("TrisX", "TrisY", "TrisZ")]
        assert np.allclose(got, xyz, rtol=5e-7)
    assert brdftab.open(path).channels == ("X", "Y", "Z")


def test_plane_symmetrical_files_hold_one_side_of_the_plane_of_incidence(tmp_path):
    path = tmp_path / "p.bsdf"
    model = _model()
    brdftab.save(model, path, format="lighttools", symmetry="PlaneSymmetrical",
                 **{**SMALL, "azimuths_deg": list(range(90, 271, 15))})
    head, lists, blocks = mini_parse(path.read_text())
    assert head["Symmetry"] == "PlaneSymmetrical" and lists["ScatterAzimuth"] == list(range(90, 271, 15))
    table = brdftab.open(path)
    assert table.grid.phi_d_fold == "bilateral"
    # a stored node and its mirror image across the plane of incidence (file azimuth 90 - d and 90 + d)
    for aoi, d, r in ((20, 30, 25), (45, 75, 40), (70, 150, 10)):
        b = next(b for b in blocks if b["AOI"] == aoi)
        stored = b["values"][lists["ScatterAzimuth"].index(90 + d), lists["ScatterRadial"].index(r)]
        for az in (90 + d, 90 - d):
            wi, wo = convention(aoi, 0, r, az)
            assert table.eval(wi, wo)[0] == stored
        assert stored == pytest.approx(model.eval(*convention(aoi, 0, r, 90 - d))[0], rel=5e-7)
    # the table read is written back on its own nodes: the same file content
    with warnings.catch_warnings():
        warnings.simplefilter("error", BrdftabWarning)
        brdftab.save(table, tmp_path / "again.bsdf", format="lighttools")
    head2, lists2, blocks2 = mini_parse((tmp_path / "again.bsdf").read_text())
    assert head2 == head and lists2 == lists
    assert all(np.array_equal(b1["values"], b2["values"]) and b1["TIS"] == b2["TIS"] for b1, b2 in zip(blocks, blocks2))
    # a file holding the other side (azimuths POI - 90 .. POI + 90) reads as its mirror image
    other = HAND.replace("Symmetry Asymmetric", "Symmetry PlaneSymmetrical").replace(
        "ScatterAzimuth 4\n0 90 180 270", "ScatterAzimuth 4\n-90 0 45 90")
    (tmp_path / "o.bsdf").write_text(other)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BrdftabWarning)
        t = brdftab.open(tmp_path / "o.bsdf")
    for az, want in ((-90, 0.51), (270, 0.51), (0, 0.61), (180, 0.61), (45, 0.71), (135, 0.71), (90, 0.81)):
        assert t.eval(*convention(40, 0, 30, az))[0] == want  # file azimuth 90 - d is stored, 90 + d mirrors it
    with pytest.raises(brdftab.errors.BrdftabError, match="one side of the plane of incidence"):
        brdftab.save(model, tmp_path / "q.bsdf", format="lighttools", symmetry="PlaneSymmetrical",
                     azimuths_deg=[0, 90, 180])


def test_an_anisotropic_source_is_written_with_planes_of_incidence(tmp_path):
    model = brdftab.models.create("microfacet", alpha_x=0.15, alpha_y=0.4)
    path = tmp_path / "a.bsdf"
    with pytest.raises(FormatError, match="anisotropic.*poi_deg"):
        brdftab.save(model, path, format="lighttools", poi_deg=[0], **SMALL)
    brdftab.save(model, path, format="lighttools", poi_deg=[0, 45, 90, 135, 180, 225, 270, 315],
                 **{**SMALL, "incidences_deg": [0, 30, 60]})
    _, lists, blocks = mini_parse(path.read_text())
    assert len(blocks) == 8 * 3 and sorted({b["POI"] for b in blocks}) == [0, 45, 90, 135, 180, 225, 270, 315]
    rng = np.random.default_rng(11)
    for _ in range(25):
        b = blocks[rng.integers(len(blocks))]
        a, r = rng.integers(len(lists["ScatterAzimuth"])), rng.integers(1, len(lists["ScatterRadial"]) - 1)
        wi, wo = convention(b["AOI"], b["POI"], lists["ScatterRadial"][r], lists["ScatterAzimuth"][a])
        assert b["values"][a, r] == pytest.approx(model.eval(wi, wo)[0], rel=5e-7, abs=1e-12)
    table = brdftab.open(path)
    assert not table.isotropic and len(table.grid.axes[1]) == 8


HAND = """# a hand-written file: Front and Back BRDF, a Front BTDF
Symmetry Asymmetric
SpectralContent Monochrome
ScatterAzimuth 4
0 90 180 270
ScatterRadial 3
0 30 60
DataBegin
AOI 0
POI 0
Side Front
ScatterType BRDF
Wavelength 550
TIS 0.2
0.1 0.11 0.12
0.1 0.21 0.22
0.1 0.31 0.32
0.1 0.41 0.42
AOI 40
POI 0
Side Front
ScatterType BTDF
TIS 0.1
1 1 1 1 1 1 1 1 1 1 1 1
AOI 40
POI 0
Side Back
ScatterType BRDF
TIS 0.1
2 2 2 2 2 2 2 2 2 2 2 2
AOI 40
POI 0
Side Front
ScatterType BRDF
Wavelength 550
TIS 0.3
0.5 0.51 0.52
0.5 0.61 0.62
0.5 0.71 0.72
0.5 0.81 0.82
DataEnd
"""


def test_the_front_reflection_is_read_and_other_blocks_are_skipped_with_a_note(tmp_path):
    path = tmp_path / "h.bsdf"
    path.write_text(HAND)
    with pytest.warns(BrdftabWarning, match=r"read the Front BRDF blocks; skipped 1 Front BTDF, 1 Back BRDF"):
        table = brdftab.open(path)
    ds = table.ds
    assert ds.attrs["lighttools_side"] == "Front" and "1 Front BTDF" in ds.attrs["lighttools_skipped"]
    assert ds.attrs["lighttools_wavelength_nm"] == 550 and "f_r [1/sr]" in ds.attrs["lighttools_quantity"]
    # the numbers of the file at their directions: AOI 40, azimuth 270 (phi_o = 180: the forward side), radial 30
    wi, wo = convention(40, 0, 30, 270)
    assert table.eval(wi, wo)[0] == 0.81
    assert np.array_equal(ds["lighttools_tis"].values[:, 0, 0], [0.2, 0.3])
    # a back side alone is read as the reflection; transmission alone is refused in one line
    back = "AOI 40\nPOI 0\nSide Back\nScatterType BRDF\nTIS 0.1\n" + " ".join(["2"] * 12) + "\n"
    assert back in HAND
    path.write_text(HAND.replace(back, "").replace("Side Front", "Side Back"))
    with pytest.warns(BrdftabWarning, match="read the Back BRDF blocks; skipped 1 Back BTDF"):
        t = brdftab.open(path)
    assert t.ds.attrs["lighttools_side"] == "Back" and t.eval(wi, wo)[0] == 0.81
    path.write_text(HAND.replace("ScatterType BRDF", "ScatterType BTDF"))
    with pytest.raises(FormatError, match="transmission.*reflection") as info:
        brdftab.open(path)
    assert "\n" not in str(info.value)


def test_a_full_circle_of_azimuths_keeps_its_first_node(tmp_path):
    path = tmp_path / "c.bsdf"
    text = HAND.replace("ScatterAzimuth 4\n0 90 180 270", "ScatterAzimuth 5\n0 90 180 270 360")
    text = text.replace("0.1 0.41 0.42\n", "0.1 0.41 0.42\n0.1 0.11 0.12\n").replace(
        "0.5 0.81 0.82\n", "0.5 0.81 0.82\n0.5 0.51 0.52\n").replace("1 1 1 1 1 1 1 1 1 1 1 1", " ".join(["1"] * 15))
    text = text.replace(" ".join(["2"] * 12), " ".join(["2"] * 15))
    path.write_text(text)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BrdftabWarning)
        table = brdftab.open(path)
    assert len(table.grid.axes[3]) == 4 and table.grid.axes[3].period is not None
    wi, wo = convention(40, 0, 60, 0)
    assert table.eval(wi, wo)[0] == 0.52


def _bad(text, old, new):
    assert old in text
    return text.replace(old, new, 1)


DAMAGE = {
    "unknown keyword": (lambda t: _bad(t, "ScatterRadial 3", "ScatterRadius 3"), "unknown keyword 'ScatterRadius'"),
    "count mismatch": (lambda t: _bad(t, "ScatterRadial 3", "ScatterRadial 4"), "expected"),
    "not a number": (lambda t: _bad(t, "0.21", "0.2x"), "expected BSDF values"),
    "truncated": (lambda t: t[: len(t) * 2 // 3], "truncated"),
    "no DataEnd": (lambda t: _bad(t, "DataEnd", ""), "DataEnd"),
    "no symmetry": (lambda t: _bad(t, "Symmetry Asymmetric\n", ""), "missing keyword Symmetry"),
    "no AOI": (lambda t: _bad(t, "AOI 0\n", ""), "no AOI"),
    "a duplicate block": (lambda t: _bad(t, "AOI 40\nPOI 0\nSide Front\nScatterType BRDF", "AOI 0\nPOI 0\nSide "
                                         "Front\nScatterType BRDF"), "a second Front BRDF block at AOI 0"),
    "a missing block": (lambda t: _bad(t, "AOI 40\nPOI 0\nSide Front\nScatterType BRDF", "AOI 40\nPOI 30\nSide "
                                       "Front\nScatterType BRDF"), "no Front BRDF block at AOI"),
    "AOI beyond 90": (lambda t: _bad(t, "AOI 0\n", "AOI 100\n"), "AOI 100"),
    "bad side": (lambda t: _bad(t, "Side Back", "Side Middle"), "Side 'Middle'"),
    "spectral": (lambda t: _bad(t, "Wavelength 550\nTIS 0.3", "Wavelength 650\nTIS 0.3"), "2 wavelengths"),
    "XYZ without tristimulus": (lambda t: _bad(t, "SpectralContent Monochrome", "SpectralContent XYZ"),
                                "no TristimulusValue"),
}


@pytest.mark.parametrize("what", sorted(DAMAGE))
def test_damaged_files_are_refused_in_one_line_naming_the_file(tmp_path, what):
    cut, words = DAMAGE[what]
    path = tmp_path / "bad.bsdf"
    path.write_text(cut(HAND))
    with pytest.raises(FormatError) as info:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", BrdftabWarning)
            brdftab.open(path)
    msg = str(info.value)
    assert "\n" not in msg and str(path) in msg and words in msg


def test_damaged_file_on_the_command_line_is_one_line_and_exit_2(tmp_path):
    path = tmp_path / "bad.bsdf"
    path.write_text(HAND.replace("AOI 40\nPOI 0\nSide Front\nScatterType BRDF", "AOI 40\nPOI 30\nSide Front\n"
                                 "ScatterType BRDF"))
    proc = subprocess.run([sys.executable, "-m", "brdftab", "info", str(path)], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert proc.stderr.startswith("brdftab: error:") and len(proc.stderr.strip().splitlines()) == 1
    assert "no Front BRDF block at AOI 0, POI 30" in proc.stderr


def test_mutated_files_give_a_format_error_or_a_table_never_a_crash():
    """Tokens of a file deleted, duplicated or replaced at random: the parser answers each with
    its content or one FormatError line naming the line."""
    from brdftab.formats.lighttools import parse_lighttools

    lines = HAND.splitlines()
    junk = ["", "-1", "0", "1e999", "nan", "TIS", "DataEnd", "DataBegin", "AOI", "x", "3.5", "TrisX", "999999"]
    errors = 0
    for text in mutations(lines, junk, 150):
        try:
            parse_lighttools("m.bsdf", text)
        except FormatError as exc:
            errors += 1
            assert "\n" not in str(exc) and str(exc).startswith("m.bsdf: line ")
    assert errors > 50


def test_a_long_header_beyond_the_sniffed_head_is_still_read_as_lighttools(tmp_path):
    path = tmp_path / "long.bsdf"
    az = np.arange(0.0, 360.0, 0.25)  # 1440 azimuths: the header alone is longer than the 4 KiB sniffed
    rows = "\n".join("0.1 0.2" for _ in az)
    path.write_text(f"Symmetry Asymmetric\nSpectralContent Monochrome\nScatterAzimuth {az.size}\n"
                    + " ".join(f"{a:g}" for a in az) + f"\nScatterRadial 2\n0 10\nDataBegin\nAOI 0\nPOI 0\nTIS 0.1\n"
                    f"{rows}\nDataEnd\n")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BrdftabWarning)
        table = brdftab.open(path)
    assert table.ds.attrs["source_format"] == "lighttools" and table.shape == (1, 1, 2, az.size, 1)


def test_a_file_converts_to_netcdf_value_for_value_and_back(tmp_path):
    """convert copies the file's nodes into netCDF; the netCDF table evaluates as the reader
    does, and written back as LightTools it holds the file's numbers on the file's nodes."""
    src = tmp_path / "m.bsdf"
    brdftab.save(_model(rgb=True), src, format="lighttools", **SMALL)
    table = brdftab.open(src)
    from click.testing import CliRunner

    from brdftab.cli import main

    r = CliRunner().invoke(main, ["convert", str(src), str(tmp_path / "m.nc")])
    assert r.exit_code == 0 and "copied" in r.output, r.output
    nc = brdftab.open(tmp_path / "m.nc")
    assert type(nc.grid).__name__ == "SphericalGrid" and nc.origin == "unknown"
    assert np.array_equal(nc.values, table.values)
    # 30 nodes of the file at the directions the convention gives them
    _, lists, blocks = mini_parse(src.read_text())
    rng = np.random.default_rng(2)
    wi, wo, want = [], [], []
    while len(want) < 30:
        b = blocks[rng.integers(len(blocks))]
        a, r = rng.integers(len(lists["ScatterAzimuth"])), rng.integers(1, len(lists["ScatterRadial"]))
        w = convention(b["AOI"], b["POI"], lists["ScatterRadial"][r], lists["ScatterAzimuth"][a])
        wi.append(w[0])
        wo.append(w[1])
        want.append((b["TristimulusValue"], b["values"][a, r]))
    wi, wo = np.array(wi), np.array(wo)
    for t in (table, nc):
        got = t.eval(wi, wo)
        for n, (name, v) in enumerate(want):
            assert got[n, "XYZ".index(name[-1])] == v
    from brdftab.geometry import sph_to_vec

    a = sph_to_vec(rng.uniform(0.0, 1.4, 400), rng.uniform(0, 6.3, 400))
    b = sph_to_vec(rng.uniform(0.0, 1.5, 400), rng.uniform(0, 6.3, 400))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BrdftabWarning)
        assert np.array_equal(nc.eval(a, b), table.eval(a, b), equal_nan=True)
    brdftab.save(table, tmp_path / "m.zarr")  # zarr holds the same grid, value for value
    assert np.array_equal(brdftab.open(tmp_path / "m.zarr").values, table.values)
    from brdftab.convert import convert

    convert(tmp_path / "m.nc", tmp_path / "back.bsdf", format="lighttools", progress=False)
    head, lists2, blocks2 = mini_parse((tmp_path / "back.bsdf").read_text())
    assert lists2 == lists and len(blocks2) == len(blocks)
    for b1, b2 in zip(blocks, blocks2):
        assert {k: v for k, v in b1.items() if k != "values"} == {k: v for k, v in b2.items() if k != "values"}
        assert np.array_equal(b1["values"], b2["values"])


@pytest.mark.parametrize("spec", ["ggx-gold", "pyromark-cook-torrance"])
def test_a_spec_output_tabulates_a_seed_model_to_lighttools_validated(tmp_path, spec):
    text = (Path(__file__).parent.parent / "specs" / f"{spec}.toml").read_text()
    text = text[:text.index("[[output]]")] + (
        f'[[output]]\npath = "{spec}.bsdf"\nformat = "lighttools"\n')
    (tmp_path / "s.toml").write_text(text)
    from brdftab.pipeline import run
    from brdftab.spec import load_spec

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BrdftabWarning)
        run(load_spec(tmp_path / "s.toml"), progress=False)  # refuses (raises) when a check fails
    out = tmp_path / f"{spec}.bsdf"
    head, lists, blocks = mini_parse(out.read_text())
    # the default grid: AOI 0..85 every 5, azimuths every 5, radial angles every 2.5 degrees
    assert [b["AOI"] for b in blocks][::3 if head["SpectralContent"] == "XYZ" else 1] == list(range(0, 90, 5))
    assert lists["ScatterAzimuth"] == list(range(0, 360, 5)) and lists["ScatterRadial"][:3] == [0, 2.5, 5]
    # 20 nodes of the file against the model (in XYZ for the coloured one) at the convention's directions
    from brdftab.colorimetry import XYZView

    model = load_spec(tmp_path / "s.toml").model
    view = XYZView(model) if head["SpectralContent"] == "XYZ" else model
    rng = np.random.default_rng(4)
    for _ in range(20):
        b = blocks[rng.integers(len(blocks))]
        a, r = rng.integers(len(lists["ScatterAzimuth"])), rng.integers(0, len(lists["ScatterRadial"]) - 2)
        wi, wo = convention(b["AOI"], b["POI"], lists["ScatterRadial"][r], lists["ScatterAzimuth"][a])
        c = "XYZ".index(b["TristimulusValue"][-1]) if "TristimulusValue" in b else 0
        assert b["values"][a, r] == pytest.approx(view.eval(wi, wo)[c], rel=5e-7, abs=1e-12)
    # the file against the model at the pre-export comparison's points (the default grid's resolution)
    from brdftab.convert import difference
    from brdftab.integrate import directional_albedo

    table = brdftab.open(out)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BrdftabWarning)
        d, _ = difference(view, table)
    median, p95 = {"ggx-gold": (0.01, 0.025), "pyromark-cook-torrance": (0.0025, 0.013)}[spec]
    assert d.median_rel <= median and d.p95_rel <= p95
    # the file does not say whether its data are reciprocal: judged as data (Pyromark's model is
    # not reciprocal: its asymmetry is reported, never a failure)
    from brdftab.checks import run_checks

    assert not table.reciprocity_declared
    report = run_checks(table)
    assert report.passed and report.get("reciprocity").status == ("warn" if spec.startswith("pyromark") else "pass")
    # TIS of the blocks at AOI 0 and 45 against the model's own directional albedo
    tis = table.ds["lighttools_tis"].values[[0, 9], 0, :]
    assert np.allclose(tis, directional_albedo(view, np.radians([0.0, 45.0]), 0.0), rtol=0.0025)
