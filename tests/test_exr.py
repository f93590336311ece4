"""OpenEXR slices: exact float32 round trips, header attributes, the image layout as OpenEXR
itself reads it, chosen slices, and damaged files; brdftab without OpenEXR installed.

Pixel values are checked against the model evaluated at directions built in this file from
the Rusinkiewicz inverse map (formats.md §1.2), and files are opened with ``OpenEXR.File``
directly, not only through brdftab.
"""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import OpenEXR
import pytest

import brdftab
from brdftab import formats, models, pipeline
from brdftab.channels import Layout
from brdftab.errors import BrdftabError, FormatError, ParameterError
from brdftab.grids import RusinkiewiczGrid, SphericalGrid, merl_grid
from brdftab.table import Table, make_table, tabulate

GOLD = dict(n=[0.143119, 0.374957, 1.44248], k=[3.98316, 2.38572, 1.60322])
GGX = models.create("microfacet", alpha=0.3, fresnel="conductor", **GOLD)
GRID = RusinkiewiczGrid(16, 12, 6, theta_h_spacing="merl")


def half_diff_to_dirs(theta_h, theta_d, phi_d):
    """wi = Ry(θh) d, wo = Ry(θh) (−dx, −dy, dz) with d = sph(θd, φd) (φh = 0)."""
    theta_h, theta_d, phi_d = np.broadcast_arrays(*(np.asarray(a, float) for a in (theta_h, theta_d, phi_d)))
    d = np.stack([np.sin(theta_d) * np.cos(phi_d), np.sin(theta_d) * np.sin(phi_d), np.cos(theta_d)], -1)
    out = []
    for v in (d, d * np.array([-1.0, -1.0, 1.0])):
        ct, st = np.cos(theta_h), np.sin(theta_h)
        out.append(np.stack([ct * v[..., 0] + st * v[..., 2], v[..., 1], -st * v[..., 0] + ct * v[..., 2]], -1))
    return out[0], out[1]


def merl_warp_nodes(n):
    """Bin centres uniform in sqrt(θh / (π/2))."""
    return ((np.arange(n) + 0.5) / n) ** 2 * np.pi / 2


def uniform_nodes(n, length):
    return (np.arange(n) + 0.5) * length / n


@pytest.fixture(scope="module")
def table():
    return tabulate(GGX, GRID, progress=False)


@pytest.fixture(scope="module")
def exr_file(tmp_path_factory, table):
    path = tmp_path_factory.mktemp("exr") / "ggx.exr"
    brdftab.save(table, path)
    return path


# --- round trips -----------------------------------------------------------------------------
def test_round_trip_equals_the_float32_table(exr_file, table):
    back = brdftab.open(exr_file)
    assert back.grid.equals(GRID)
    assert back.channels == ("R", "G", "B")
    assert back.values.dtype == np.float32
    np.testing.assert_array_equal(back.values, table.values.astype(np.float32))
    for key in ("model", "parameters", "isotropic", "reciprocal", "phi_d_fold", "theta_h_spacing",
                "sample_position", "brdftab_version", "created"):
        assert back.ds.attrs[key] == table.ds.attrs[key], key
    # a second conversion copies (the grid is equal): same values again
    brdftab.save(back, exr_file.with_name("again.exr"))
    np.testing.assert_array_equal(brdftab.open(exr_file.with_name("again.exr")).values, back.values)


def test_full_merl_grid_table_round_trip(tmp_path):
    t = tabulate(models.create("microfacet", alpha=0.15), merl_grid("lower-edge"), progress=False)
    path = tmp_path / "m.exr"
    brdftab.save(t, path)
    with OpenEXR.File(str(path), header_only=True) as f:
        assert len(f.parts) == 180
    back = brdftab.open(path)
    assert back.grid.equals(merl_grid("lower-edge"))
    np.testing.assert_array_equal(back.values, t.values.astype(np.float32))


@pytest.mark.parametrize("grid", [
    RusinkiewiczGrid(np.radians([0, 2, 10, 45, 89]), 5, np.radians([0, 30, 95, 180]), phi_d_fold="bilateral"),
    RusinkiewiczGrid(7, np.radians([1, 20, 70]), 9, phi_d_fold="none", sample_position="lower-edge"),
], ids=["explicit-bilateral", "lower-edge-none"])
def test_explicit_axes_and_other_folds_round_trip(tmp_path, grid):
    t = tabulate(GGX, grid, progress=False)
    brdftab.save(t, tmp_path / "x.exr")
    back = brdftab.open(tmp_path / "x.exr")
    assert back.grid.equals(grid)
    np.testing.assert_array_equal(back.values, t.values.astype(np.float32))


def test_spectral_and_grey_channels(tmp_path):
    lam = models.create("lambert", albedo={"wavelengths_nm": [400, 700], "values": [0.2, 0.8]})
    t = tabulate(lam, RusinkiewiczGrid(3, 4, 2), wavelengths=[400, 550.5, 700], progress=False)
    brdftab.save(t, tmp_path / "s.exr", colour="spectral")
    with OpenEXR.File(str(tmp_path / "s.exr"), separate_channels=True) as f:
        assert sorted(f.parts[0].channels) == ["400nm", "550.5nm", "700nm"]
    back = brdftab.open(tmp_path / "s.exr")
    assert back.spectral and back.wavelengths.tolist() == [400.0, 550.5, 700.0]
    np.testing.assert_array_equal(back.values, t.values.astype(np.float32))
    grey = tabulate(models.create("lambert", albedo=0.5), RusinkiewiczGrid(3, 4, 2), progress=False)
    brdftab.save(grey, tmp_path / "g.exr")
    with OpenEXR.File(str(tmp_path / "g.exr"), separate_channels=True) as f:
        assert list(f.parts[0].channels) == ["Y"]
    assert brdftab.open(tmp_path / "g.exr").channels == ("mono",)


def test_missing_samples_stay_missing(tmp_path):
    values = np.full((4, 3, 2, 3), 0.25)
    values[1, 2, 0] = -1.0 / 1500
    t = make_table(values, RusinkiewiczGrid(4, 3, 2), Layout(("R", "G", "B")))
    t.ds["brdf"].attrs["valid_min"] = 0.0
    t = Table(t.ds)
    brdftab.save(t, tmp_path / "m.exr")
    back = brdftab.open(tmp_path / "m.exr")
    assert back.ds["brdf"].attrs["valid_min"] == 0.0
    np.testing.assert_array_equal(np.asarray(back.missing), np.asarray(t.missing))
    assert back.values[1, 2, 0, 0] == np.float32(-1.0 / 1500)


# --- the file as OpenEXR reads it --------------------------------------------------------------
def test_header_attributes(exr_file):
    with OpenEXR.File(str(exr_file), header_only=True) as f:
        headers = [dict(p.header) for p in f.parts]
    assert len(headers) == 6
    h = headers[0]  # the table's metadata, once
    assert h["parameterization"] == "rusinkiewicz"
    assert h["theta_h_spacing"] == "merl" and h["theta_h_warp"] == "sqrt"
    assert h["x_axis"] == "theta_h" and h["y_axis"] == "theta_d" and h["y_origin"] == "bottom"
    assert h["units"] == "sr-1" and h["angle_units"] == "rad"
    assert h["cosine_included"] == 0
    assert h["model"] == "microfacet"
    assert json.loads(h["parameters"])["alpha"] == 0.3
    assert json.loads(h["theta_h_rad"]) == GRID.axes[0].values.tolist()
    assert h["channel_names"] == ["R", "G", "B"]
    assert "Conventions" not in h  # a netCDF attribute
    standard = {"channels", "compression", "dataWindow", "displayWindow", "lineOrder", "pixelAspectRatio",
                "screenWindowCenter", "screenWindowWidth", "name", "type", "version", "chunkCount"}
    for k, h in enumerate(headers):
        # every part: its phi_d and the primaries of its RGB values; nothing repeated
        if k:
            assert set(h) - standard == {"phi_d_rad", "phi_d_deg", "phi_d_index", "n_phi_d", "chromaticities"}
        assert h["chromaticities"] == pytest.approx((0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127, 0.3290), abs=1e-7)
        # numbers are doubles: 1-element float64 arrays, exact
        for key, want in (("phi_d_rad", GRID.axes[2].values[k]),) + ((("param.alpha", 0.3), ("param.n.2", 1.44248))
                                                                    if k == 0 else ()):
            assert isinstance(h[key], np.ndarray) and h[key].dtype == np.float64 and h[key].shape == (1,), key
            assert h[key][0] == want, key
        assert h["phi_d_deg"][0] == pytest.approx((k + 0.5) * 30)
        assert h["phi_d_index"] == k and h["n_phi_d"] == 6


def test_openexr_sees_float_rgb_images_with_theta_d_upwards(exr_file):
    with OpenEXR.File(str(exr_file), separate_channels=True) as f:
        parts = [(p.name(), {n: c.pixels for n, c in p.channels.items()}) for p in f.parts]
    th = merl_warp_nodes(16)
    td = uniform_nodes(12, np.pi / 2)
    pd = uniform_nodes(6, np.pi)
    jj, ii = np.meshgrid(np.arange(12), np.arange(16), indexing="ij")  # image rows, columns
    for k, (name, chans) in enumerate(parts):
        assert name == f"phi_d {k}"
        assert sorted(chans) == ["B", "G", "R"]
        for c, ch in enumerate("RGB"):
            img = chans[ch]
            assert img.dtype == np.float32 and img.shape == (12, 16)  # height = theta_d, width = theta_h
            # row r from the top holds theta_d node 11 - r; column i holds theta_h node i
            wi, wo = half_diff_to_dirs(th[ii], td[11 - jj], pd[k])
            np.testing.assert_allclose(img, GGX.eval(wi, wo)[..., c].astype(np.float32), rtol=2e-7, atol=0)
    bottom_left = parts[0][1]["R"][11, 0]
    assert bottom_left == np.float32(GGX.eval(*half_diff_to_dirs(th[0], td[0], pd[0]))[0])


def test_chosen_slices_make_a_single_part_image(tmp_path):
    path = tmp_path / "s.exr"
    written = brdftab.save(GGX, path, grid=GRID, phi_d_deg=[90])
    assert written.grid.axes[2].values.tolist() == [np.pi / 2]
    with OpenEXR.File(str(path), separate_channels=True) as f:
        assert len(f.parts) == 1
        h = dict(f.parts[0].header)
        img = f.parts[0].channels["G"].pixels.copy()
    assert h["phi_d_rad"][0] == np.pi / 2 and h["phi_d_deg"][0] == 90.0
    th, td = merl_warp_nodes(16), uniform_nodes(12, np.pi / 2)
    jj, ii = np.meshgrid(np.arange(12), np.arange(16), indexing="ij")
    wi, wo = half_diff_to_dirs(th[ii], td[11 - jj], np.pi / 2)
    np.testing.assert_allclose(img, GGX.eval(wi, wo)[..., 1].astype(np.float32), rtol=2e-7, atol=0)
    back = brdftab.open(path)
    assert back.grid.describe() == "rusinkiewicz theta_h[16] x theta_d[12] x phi_d[1]"
    two = brdftab.save(GGX, tmp_path / "two.exr", grid=GRID, phi_d_deg=[135, 45])
    assert np.degrees(two.grid.axes[2].values).tolist() == pytest.approx([45, 135])


def test_spec_with_exr_output(tmp_path):
    spec = tmp_path / "s.toml"
    spec.write_text('[model]\nname = "lambert"\nalbedo = [0.1, 0.2, 0.3]\n'
                    '[grid]\ntype = "rusinkiewicz"\nn_theta_h = 8\nn_theta_d = 8\nn_phi_d = 4\n'
                    '[[output]]\npath = "all.exr"\n[[output]]\npath = "one.exr"\nphi_d_deg = [45]\n')
    pipeline.run(brdftab.load_spec(spec), progress=False)
    assert brdftab.open(tmp_path / "all.exr").values.shape == (8, 8, 4, 3)
    one = brdftab.open(tmp_path / "one.exr")
    assert one.values.shape == (8, 8, 1, 3) and one.grid.axes[2].values[0] == np.radians(45)


# --- refusals ----------------------------------------------------------------------------------
def test_grids_without_theta_h_theta_d_images_are_refused(tmp_path):
    sph = SphericalGrid([0.1], [0.0], [0.2, 0.3], [0.0, np.pi])
    with pytest.raises(ParameterError, match="isotropic Rusinkiewicz"):
        brdftab.save(GGX, tmp_path / "a.exr", grid=sph)
    with pytest.raises(ParameterError, match="isotropic Rusinkiewicz"):
        brdftab.save(GGX, tmp_path / "a.exr", grid=RusinkiewiczGrid(4, 4, 4, 4, phi_d_fold="none"))
    with pytest.raises(BrdftabError, match="phi_d_deg"):
        brdftab.save(GGX, tmp_path / "a.exr", grid=GRID, phi_d_deg=[200])  # reciprocity: [0, 180)
    with pytest.raises(BrdftabError, match="phi_d_deg"):
        brdftab.save(GGX, tmp_path / "a.exr", grid=GRID, phi_d_deg=["90"])
    assert list(tmp_path.iterdir()) == []


# --- damaged files -----------------------------------------------------------------------------
def _rewrite(src, dst, edit_header=None, edit_channels=None, parts=None):
    with OpenEXR.File(str(src), separate_channels=True) as f:
        items = [(dict(p.header), {n: c.pixels for n, c in p.channels.items()}) for p in f.parts]
    items = items if parts is None else [items[i] for i in parts]
    out = []
    for k, (h, ch) in enumerate(items):
        h = {key: v for key, v in h.items() if key not in ("channels", "chunkCount", "dataWindow", "name", "type")}
        if edit_header:
            edit_header(k, h)
        if edit_channels:
            ch = edit_channels(k, ch)
        out.append(OpenEXR.Part(h, ch, f"p{k}"))
    with OpenEXR.File(out) as f:
        f.write(str(dst))
    return dst


def _drop(key):
    return lambda k, h: h.pop(key, None)  # the table's metadata is in the first part only


def _set(key, value):
    return lambda k, h: h.__setitem__(key, value)


@pytest.mark.parametrize("kwargs, message", [
    (dict(edit_channels=lambda k, ch: {n: a for n, a in ch.items() if n != "B"}), "missing EXR channel 'B'"),
    (dict(edit_channels=lambda k, ch: {n: a.astype(np.uint32) for n, a in ch.items()}), "float image"),
    (dict(edit_channels=lambda k, ch: {n: a[:, :8].copy() for n, a in ch.items()}), "JSON list of 8 angles"),
    (dict(edit_channels=lambda k, ch: {n: (a if k else a[:, :8].copy()) for n, a in ch.items()}), "same size"),
    (dict(edit_header=_drop("parameterization")), "not a brdftab BRDF slice"),
    (dict(edit_header=lambda k, h: [h.pop("phi_d_rad"), h.pop("phi_d_deg")]), "no phi_d_rad"),
    (dict(edit_header=_set("phi_d_rad", np.array([0.5]))), "same phi_d"),
    (dict(edit_header=_set("theta_h_rad", "[0.1, oops")), "theta_h_rad"),
    (dict(edit_header=_set("theta_d_rad", json.dumps([0.1] * 12))), "theta_d"),
    (dict(edit_header=_set("phi_d_fold", "sideways")), "phi_d_fold"),
    (dict(edit_header=_set("channel_names", ["R", "G", "B", "R"])), "channel_names"),
    (dict(edit_header=_set("wavelengths_nm", "[500]")), "wavelengths_nm"),
    (dict(edit_header=_set("theta_h_node_rule", "middle")), "node_rule"),
])
def test_damaged_slices_give_one_line(tmp_path, exr_file, kwargs, message):
    bad = _rewrite(exr_file, tmp_path / "bad.exr", **kwargs)
    with pytest.raises(FormatError, match=message) as info:
        brdftab.open(bad)
    assert str(bad) in str(info.value) and "\n" not in str(info.value)


def test_plain_image_and_truncated_file(tmp_path, exr_file, capfd):
    plain = tmp_path / "plain.exr"
    with OpenEXR.File({}, {"RGB": np.zeros((4, 5, 3), np.float32)}) as f:
        f.write(str(plain))
    with pytest.raises(FormatError, match="not a brdftab BRDF slice"):
        brdftab.open(plain)
    data = exr_file.read_bytes()
    for cut in (3, 100, len(data) // 2, len(data) - 10):
        short = tmp_path / f"short{cut}.exr"
        short.write_bytes(data[:cut])
        with pytest.raises(FormatError) as info:
            brdftab.open(short)
        assert str(short) in str(info.value) and "\n" not in str(info.value)
    corrupt = bytearray(data)
    corrupt[-3000:-2000] = bytes(1000)  # pixel data of the last part
    (tmp_path / "corrupt.exr").write_bytes(bytes(corrupt))
    with pytest.raises(FormatError, match="damaged"):
        brdftab.open(tmp_path / "corrupt.exr")
    out, err = capfd.readouterr()
    assert out == "" and err == ""  # the library's own messages are not shown


def test_format_is_detected_by_magic(tmp_path, exr_file):
    other = tmp_path / "slices.dat"
    other.write_bytes(exr_file.read_bytes())
    assert formats.detect(other).name == "exr"
    assert brdftab.open(other).grid.equals(GRID)


# --- layout attributes of other writers: honoured or refused, never read as if absent -----------
def test_top_origin_images_are_flipped(tmp_path, exr_file, table):
    top = _rewrite(exr_file, tmp_path / "top.exr", edit_header=_set("y_origin", "top"),
                   edit_channels=lambda k, ch: {n: a[::-1, :].copy() for n, a in ch.items()})
    back = brdftab.open(top)
    assert back.grid.equals(GRID)
    np.testing.assert_array_equal(back.values, table.values.astype(np.float32))
    # read as if the attribute were absent, the file would be upside down
    plain = _rewrite(exr_file, tmp_path / "plain.exr",
                     edit_channels=lambda k, ch: {n: a[::-1, :].copy() for n, a in ch.items()})
    assert not np.array_equal(brdftab.open(plain).values, back.values)


def test_theta_d_on_x_images_are_transposed(tmp_path, exr_file, table):
    def swap(k, h):
        h["x_axis"], h["y_axis"] = "theta_d", "theta_h"
    # x = theta_d (columns), y = theta_h (bottom row = first node)
    moved = _rewrite(exr_file, tmp_path / "swap.exr", edit_header=swap,
                     edit_channels=lambda k, ch: {n: np.ascontiguousarray(a[::-1, :].T[::-1, :])
                                                  for n, a in ch.items()})
    with OpenEXR.File(str(moved), header_only=True) as f:
        lo, hi = f.parts[0].header["dataWindow"]
        assert (hi[0] + 1, hi[1] + 1) == (12, 16)  # width = theta_d nodes, height = theta_h nodes
    back = brdftab.open(moved)
    assert back.grid.equals(GRID)
    np.testing.assert_array_equal(back.values, table.values.astype(np.float32))


def test_declared_sqrt_warp_is_honoured_without_node_lists(tmp_path, exr_file, table):
    def strip(k, h):
        for key in ("theta_h_spacing", "theta_h_rad", "theta_d_rad"):
            h.pop(key, None)
    warped = _rewrite(exr_file, tmp_path / "warp.exr", edit_header=strip)
    back = brdftab.open(warped)
    assert back.grid.axes[0].warp == "sqrt"
    np.testing.assert_allclose(back.grid.axes[0].values, merl_warp_nodes(16), rtol=0, atol=1e-12)
    np.testing.assert_array_equal(back.values, table.values.astype(np.float32))
    w = half_diff_to_dirs(0.2, 0.5, np.radians(45))
    assert back.eval(*w) == pytest.approx(table.eval(*w), rel=1e-6)
    # without theta_h_warp the same pixels sit at linear nodes: a different BRDF
    bare = _rewrite(exr_file, tmp_path / "bare.exr", edit_header=lambda k, h: [strip(k, h), h.pop("theta_h_warp", 0)])
    assert brdftab.open(bare).grid.axes[0].warp == "linear"


@pytest.mark.parametrize("key, value, message", [
    ("y_origin", "left", "y_origin = 'left'"),
    ("x_axis", "theta_i", "x_axis = 'theta_i'"),
    ("pixel_position", "corner", "pixel_position = 'corner'"),
    ("angle_units", "deg", "angle_units = 'deg'"),
    ("cosine_included", 1, "cosine_included = 1"),
    ("units", "1", "units = '1'"),
    ("units", "percent", "units = 'percent'"),
    ("theta_h_warp", "cubic", "theta_h_warp = 'cubic'"),
    ("theta_h_warp", "linear", "theta_h_warp = 'linear' contradicts"),
    ("chromaticities", (0.7347, 0.2653, 0.0, 1.0, 0.0001, -0.077, 0.32168, 0.33767), "chromaticities"),
])
def test_layout_attributes_that_cannot_be_honoured_are_refused(tmp_path, exr_file, key, value, message):
    bad = _rewrite(exr_file, tmp_path / "bad.exr", edit_header=_set(key, value))
    with pytest.raises(FormatError) as info:
        brdftab.open(bad)
    msg = str(info.value)
    assert message in msg and str(bad) in msg and "\n" not in msg


# -- OpenEXR is an optional library ------------------------------------------------------------------

def test_import_and_other_formats_work_without_openexr(tmp_path):
    code = ("import sys; sys.modules['OpenEXR'] = None\n"
            "import brdftab, brdftab.formats as f\n"
            "print(sorted(n for n, x in f.FORMATS.items() if not x.available))\n"
            "t = brdftab.tabulate(brdftab.models.create('lambert'), brdftab.grids.RusinkiewiczGrid(3, 3, 3),"
            " progress=False)\n"
            f"brdftab.save(t, {str(tmp_path / 'a.nc')!r})\n"
            "try:\n"
            f"    brdftab.save(t, {str(tmp_path / 'a.exr')!r})\n"
            "except brdftab.BrdftabError as e:\n"
            "    print('ERR', e)\n")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    lines = p.stdout.splitlines()
    assert "'exr'" in lines[0]
    assert lines[1].startswith("ERR") and "OpenEXR" in lines[1] and "not installed" in lines[1]
    assert (tmp_path / "a.nc").exists() and not (tmp_path / "a.exr").exists()


def test_values_beyond_float32_fail_finite_as_stored(tmp_path):
    """EXR pixels are float32: a table finite in float64 but beyond float32 is refused by the
    finite check (exit 1, nothing written), counting the samples that would be infinite."""
    from _cli import run

    big = models.create("scale", factor=2e40, term=models.create("lambert", albedo=0.5))
    t = tabulate(big, RusinkiewiczGrid(6, 5, 8), progress=False)
    src = tmp_path / "big.nc"
    brdftab.save(t, src)
    v = np.asarray(t.values)
    over = int(np.count_nonzero(v > np.finfo(np.float32).max))
    assert 0 < over < v.size
    r = run("convert", src, tmp_path / "big.exr", "--level", "energy=off")
    assert r.returncode == 1, r.stderr
    assert f"finite: {over} of {v.size} samples are NaN or infinite (0 NaN, {over} infinite)" in r.stderr
    assert not (tmp_path / "big.exr").exists()


def test_cf_missing_markers_stay_missing_in_exr(tmp_path):
    """Samples a netCDF marks missing with its CF _FillValue (-999 here) are still missing in the
    EXR file made from it (the missing_value header), not data that fails non-negative."""
    import xarray as xr
    from click.testing import CliRunner

    from brdftab.cli import main

    grid = {"type": "rusinkiewicz", "n_theta_h": 6, "n_theta_d": 5, "n_phi_d": 8}
    brdftab.save(models.create("lambert", albedo=0.5), tmp_path / "a.nc", grid=grid)
    with xr.open_dataset(tmp_path / "a.nc") as ds:
        ds = ds.load()
    v = ds["brdf"].values.copy()
    v[0, 0, :, 0] = -999.0
    ds["brdf"].values[:] = v
    ds["brdf"].encoding["_FillValue"] = -999.0
    ds.to_netcdf(tmp_path / "fill.nc")
    source = brdftab.open(tmp_path / "fill.nc")
    assert int(source.missing.sum()) == 8
    r = CliRunner().invoke(main, ["convert", str(tmp_path / "fill.nc"), str(tmp_path / "fill.exr")])
    assert r.exit_code == 0, r.stderr
    back = brdftab.open(tmp_path / "fill.exr")
    np.testing.assert_array_equal(back.missing, source.missing)
    hdr = OpenEXR.File(str(tmp_path / "fill.exr"), header_only=True).parts[0].header
    assert json.loads(hdr["missing_value"]) == [-999.0]
    r = CliRunner().invoke(main, ["validate", str(tmp_path / "fill.exr")])
    assert r.exit_code == 0 and "FAIL" not in r.stdout, r.stdout
    assert "8 of 240 samples are missing" in r.stdout, r.stdout
