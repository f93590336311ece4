"""What other tools accept: the files brdftab writes, checked by those tools (Hardening III).

* netCDF: the IOOS ``compliance-checker`` (``cf:1.10``) finds no error and raises no exception
  inside its checks on any kind of table brdftab writes; h5py sees no netCDF-4-only type
  (int64, variable-length strings) in any attribute or variable, so ``nccopy -k classic`` can
  convert the file; the albedo curve is numbers; old files (string coordinate ``channel``,
  int64 flags, JSON albedo attributes) are still read.
* EXR: the table's metadata once (first part), minimal per-part headers, RGB chromaticities,
  no netCDF ``Conventions`` — as OpenEXR itself reads the file.
* Zemax/Radiant ``.bsdf`` text files are recognised and refused with one line naming them;
  a tensor field of zero size with a shape numpy cannot hold and non-float ``dtype`` are
  refused with one line.
"""

from __future__ import annotations

import json
import struct

import h5py
import netCDF4
import numpy as np
import OpenEXR
import pytest
import xarray as xr

import brdftab
from brdftab import models
from brdftab.checks import guard
from brdftab.errors import BrdftabWarning, FormatError, ParameterError
from brdftab.grids import RusinkiewiczGrid, SphericalGrid
from brdftab.table import tabulate

GOLD = dict(n=[0.143119, 0.374957, 1.44248], k=[3.98316, 2.38572, 1.60322])
GGX = models.create("microfacet", alpha=0.3, fresnel="conductor", **GOLD)
SMALL = RusinkiewiczGrid(6, 5, 4)
MERL_N = 90 * 90 * 180


def _cli(*args):
    from click.testing import CliRunner

    from brdftab.cli import main

    result = CliRunner().invoke(main, [str(a) for a in args])
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    return result


def _cf_report(path):
    """``(errors, failures)`` of compliance-checker's cf:1.10 suite: the exceptions raised inside
    its checks, and the high-priority (error) results that did not pass."""
    from compliance_checker.runner import CheckSuite

    suite = CheckSuite()
    suite.load_all_available_checkers()
    ds = suite.load_dataset(str(path))
    try:
        groups, errors = suite.run_all(ds, ["cf:1.10"], skip_checks=[])["cf:1.10"]
    finally:
        ds.close()
    failures = [(g.name, g.msgs) for g in groups if g.weight >= 3 and g.value[0] < g.value[1]]
    return errors, failures


def _netcdf4_only_types(path) -> list:
    """Attributes and variables whose HDF5 type netCDF-3 (classic) cannot hold: 64-bit integers
    and variable-length strings (h5py, independent of netCDF4-python)."""
    internal = {"DIMENSION_LIST", "REFERENCE_LIST", "CLASS", "NAME", "_Netcdf4Dimid", "_Netcdf4Coordinates",
                "_NCProperties"}
    bad = []

    def check(name, obj):
        for key in obj.attrs:
            if key in internal:
                continue
            dt = obj.attrs.get_id(key).dtype
            info = h5py.check_string_dtype(dt)
            if (dt.kind in "iu" and dt.itemsize == 8) or (info is not None and info.length is None) or dt.kind == "O":
                bad.append(f"{name or '/'}:{key} ({dt})")
        if isinstance(obj, h5py.Dataset):
            info = h5py.check_string_dtype(obj.dtype)
            if (obj.dtype.kind in "iu" and obj.dtype.itemsize == 8) or (info is not None and info.length is None):
                bad.append(f"{name} ({obj.dtype})")

    with h5py.File(path, "r") as f:
        check("", f)
        f.visititems(check)
    return bad


def _merl_like(path):
    rng = np.random.default_rng(7)
    raw = np.round(rng.uniform(0, 2000, 3 * MERL_N), 3)
    raw[rng.integers(0, raw.size, 1000)] = -1.0
    with open(path, "wb") as fh:
        fh.write(struct.pack("<3i", 90, 90, 180))
        fh.write(raw.astype("<f8").tobytes())
    return path


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    """Every kind of netCDF file brdftab writes: {kind: path}."""
    d = tmp_path_factory.mktemp("conformance")
    out = {}
    brdftab.save(GGX, d / "rgb.nc", grid=SMALL)
    out["rgb"] = d / "rgb.nc"
    grey = tabulate(models.create("lambert", albedo=0.5), SphericalGrid(np.radians([0, 30, 60]), [0.0],
                                                                       np.radians([10, 40, 80]),
                                                                       np.radians([0, 90, 180, 270])),
                    progress=False)
    brdftab.save(grey, d / "grey.nc", dtype="float32")
    out["grey-spherical-float32"] = d / "grey.nc"
    spec = models.create("lambert", albedo={"wavelengths_nm": [400, 700], "values": [0.2, 0.8]})
    brdftab.save(tabulate(spec, SMALL, wavelengths=[400, 550, 700], progress=False), d / "spectral.nc")
    out["spectral"] = d / "spectral.nc"
    validated = tabulate(GGX, SMALL, progress=False)
    validated.ds.attrs["comment"] = "a description with θi = 5° and µm"  # non-ASCII text
    guard(validated, allow_invalid=True)  # the check report and the albedo curve
    brdftab.save(validated, d / "validated.nc")
    out["validated"] = d / "validated.nc"
    delta = models.create("he-torrance-1991", n=1.5, k=0.0, sigma0=0.1, tau=1.0, wavelength_nm=500.0)
    brdftab.save(tabulate(delta, SMALL, progress=False), d / "specular.nc")
    out["specular"] = d / "specular.nc"
    merl = brdftab.open(_merl_like(d / "m.binary"))
    brdftab.save(merl, d / "merl.nc")
    out["merl"] = d / "merl.nc"
    return out


KINDS = ["rgb", "grey-spherical-float32", "spectral", "validated", "specular", "merl"]


@pytest.mark.parametrize("kind", KINDS)
def test_compliance_checker_cf_1_10_finds_no_error_and_does_not_crash(written, kind):
    errors, failures = _cf_report(written[kind])
    assert errors == {}, f"compliance-checker raised inside its checks: {errors}"
    assert failures == []


def test_compliance_checker_crashed_on_the_old_string_channel_coordinate(tmp_path):
    # the layout written before (a string coordinate variable 'channel'): the same check fails,
    # so the test above can fail
    old = tmp_path / "old.nc"
    xr.Dataset({"brdf": (("theta_h", "channel"), np.ones((2, 3)), {"units": "sr-1", "long_name": "f_r"})},
               coords={"theta_h": ("theta_h", [0.1, 0.2], {"units": "rad", "long_name": "theta_h"}),
                       "channel": ("channel", ["R", "G", "B"], {"long_name": "colour channel"})},
               attrs={"Conventions": "CF-1.10", "history": "x"}).to_netcdf(old)
    errors, _ = _cf_report(old)
    assert errors, "compliance-checker no longer stumbles over string coordinate variables"


@pytest.mark.parametrize("kind", KINDS)
def test_no_netcdf4_only_types_so_nccopy_k_classic_works(written, kind):
    assert _netcdf4_only_types(written[kind]) == []


def test_old_layout_had_netcdf4_only_types(tmp_path):
    old = tmp_path / "old.nc"
    xr.Dataset(attrs={"isotropic": 1, "note": "θ"}).to_netcdf(old)  # xarray's int64 and NC_STRING
    assert len(_netcdf4_only_types(old)) == 2


def test_channel_names_are_a_cf_label_and_flags_are_int32(written):
    with netCDF4.Dataset(written["rgb"]) as nc:
        assert "channel" in nc.dimensions and "channel" not in nc.variables
        label = nc.variables["channel_name"]
        assert label.dtype == np.dtype("S1") and label.dimensions == ("channel", "channel_name_strlen")
        label.set_auto_chartostring(False)
        assert [b"".join(row).decode() for row in label[:]] == [b"R", b"G", b"B"] or \
            [b"".join(row).decode() for row in label[:]] == ["R", "G", "B"]
        assert nc.variables["brdf"].coordinates == "channel_name"
        for key in ("isotropic", "reciprocal"):
            assert nc.getncattr(key).dtype == np.int32
        assert nc.Conventions == "CF-1.10" and "brdftab" in nc.history
    with netCDF4.Dataset(written["validated"]) as nc:
        assert nc.validation_passed.dtype == np.int32
    back = brdftab.open(written["rgb"])
    assert back.channels == ("R", "G", "B")
    assert np.array_equal(back.values, tabulate(GGX, SMALL, progress=False).values)


def test_albedo_curve_is_stored_as_numbers(written):
    with netCDF4.Dataset(written["validated"]) as nc:
        assert not any(k.startswith("albedo") for k in nc.ncattrs())
        a = nc.variables["albedo"]
        assert a.dimensions == ("albedo_theta_i", "channel") and a.units == "1"
        theta = nc.variables["albedo_theta_i"][:]
        assert nc.variables["albedo_theta_i"].units == "rad" and theta.size == 90
        assert theta[-1] == pytest.approx(np.radians(89.0))
        values = a[:]
        ws = nc.variables["albedo_white_sky"][:]
        report = json.loads(nc.validation_report)
        assert nc.comment == "a description with θi = 5° and µm"
    # the same numbers as the check report, and as an independent integral at θi = 0
    albedo = next(c for c in report["checks"] if c["name"] == "albedo")
    np.testing.assert_allclose(values, albedo["data"]["values"], rtol=1e-12)
    np.testing.assert_allclose(ws, albedo["data"]["white_sky"], rtol=1e-12)
    t = brdftab.open(written["validated"])
    n = 400
    th = (np.arange(n) + 0.5) / n * np.pi / 2
    ph = (np.arange(2 * n) + 0.5) / (2 * n) * 2 * np.pi
    T, P = np.meshgrid(th, ph, indexing="ij")
    wo = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1).reshape(-1, 3)
    f = t.eval(np.broadcast_to([0.0, 0.0, 1.0], wo.shape), wo)
    a0 = (f * (np.cos(T) * np.sin(T)).reshape(-1, 1)).sum(0) * (np.pi / 2 / n) * (np.pi / n)
    np.testing.assert_allclose(values[0], a0, rtol=1e-2)  # a coarse table: quadratures differ a little
    assert "albedo" in t.ds.data_vars


def test_old_files_are_still_read(tmp_path):
    """The layout of files written before: string coordinate 'channel', int64 flags, the albedo
    curve as JSON attributes. Read, and rewritten in the new layout."""
    t = tabulate(GGX, SMALL, progress=False)
    ds = t.ds.copy()
    ds.attrs.update({"isotropic": np.int64(1), "reciprocal": np.int64(1), "validation_passed": np.int64(1),
                     "albedo_theta_i_deg": json.dumps([0.0, 45.0]),
                     "albedo_values": json.dumps([[0.1, 0.2, 0.3], [0.4, 0.5, 0.6]]),
                     "albedo_white_sky": json.dumps([0.7, 0.8, 0.9]),
                     "albedo_channels": json.dumps(["R", "G", "B"])})
    ds.to_netcdf(tmp_path / "old.nc")
    with netCDF4.Dataset(tmp_path / "old.nc") as nc:
        assert nc.variables["channel"].dtype is str and nc.isotropic.dtype == np.int64
    old = brdftab.open(tmp_path / "old.nc")
    assert old.channels == ("R", "G", "B") and old.isotropic and old.reciprocal
    np.testing.assert_array_equal(old.values, t.values)
    np.testing.assert_allclose(old.ds["albedo"].values, [[0.1, 0.2, 0.3], [0.4, 0.5, 0.6]])
    np.testing.assert_allclose(np.degrees(old.ds["albedo_theta_i"].values), [0.0, 45.0])
    np.testing.assert_allclose(old.ds["albedo_white_sky"].values, [0.7, 0.8, 0.9])
    brdftab.save(old, tmp_path / "new.nc")
    assert _netcdf4_only_types(tmp_path / "new.nc") == []
    errors, failures = _cf_report(tmp_path / "new.nc")
    assert errors == {} and failures == []
    again = brdftab.open(tmp_path / "new.nc")
    np.testing.assert_array_equal(again.ds["albedo"].values, old.ds["albedo"].values)


# --- EXR ---------------------------------------------------------------------------------------
def _exr_headers(path):
    with OpenEXR.File(str(path), header_only=True) as f:
        return [dict(p.header) for p in f.parts]


STANDARD = {"channels", "compression", "dataWindow", "displayWindow", "lineOrder", "pixelAspectRatio",
            "screenWindowCenter", "screenWindowWidth", "name", "type", "version", "chunkCount", "tiles"}


def test_exr_metadata_once_and_rgb_chromaticities(tmp_path):
    t = tabulate(models.create("lambert", albedo=[0.2, 0.5, 0.8]), RusinkiewiczGrid(16, 16, 180), progress=False)
    guard(t, allow_invalid=True)  # a long validation report in the metadata
    path = tmp_path / "slices.exr"
    brdftab.save(t, path)
    headers = _exr_headers(path)
    assert len(headers) == 180
    first = headers[0]
    assert first["parameterization"] == "rusinkiewicz" and "validation_report" in first
    assert "Conventions" not in first
    assert json.loads(first["albedo_values"])[0] == pytest.approx([0.2, 0.5, 0.8], rel=1e-3)
    for k, h in enumerate(headers):
        assert h["name"] == f"phi_d {k:03d}"
        assert h["chromaticities"] == pytest.approx((0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127, 0.3290), abs=1e-7)
        if k:
            assert set(h) - STANDARD == {"phi_d_rad", "phi_d_deg", "phi_d_index", "n_phi_d", "chromaticities"}
    # the metadata is a small part of the file: strip it and compare the sizes
    with OpenEXR.File(str(path), separate_channels=True) as f:
        parts = [OpenEXR.Part({k: v for k, v in p.header.items() if k in ("compression", "chromaticities")},
                              {n: c.pixels for n, c in p.channels.items()}, p.name()) for p in f.parts]
    with OpenEXR.File(parts) as f:
        f.write(str(tmp_path / "bare.exr"))
    overhead = path.stat().st_size - (tmp_path / "bare.exr").stat().st_size
    once = sum(len(k) + len(v if isinstance(v, str) else repr(v)) for k, v in first.items() if k not in STANDARD)
    assert once > 10_000  # the table's metadata (with its validation report)
    # about once, not once per part (180 times), plus the per-part phi_d
    assert overhead < once + 180 * 150, f"{overhead} bytes of metadata; the table's metadata is {once} bytes"
    back = brdftab.open(path)
    np.testing.assert_array_equal(back.values, t.values.astype(np.float32))
    np.testing.assert_allclose(back.ds["albedo"].values, t.ds["albedo"].values, rtol=1e-12)


def test_exr_grey_and_spectral_declare_no_chromaticities(tmp_path):
    brdftab.save(models.create("lambert", albedo=0.5), tmp_path / "g.exr", grid=RusinkiewiczGrid(3, 3, 2))
    assert all("chromaticities" not in h for h in _exr_headers(tmp_path / "g.exr"))


def test_docs_name_the_parts_and_the_merl_material_as_the_files_do():
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    exr_md = (root / "formats" / "exr.md").read_text(encoding="utf-8")
    assert "`phi_d 000`" in exr_md and "`phi_d 0`" in exr_md
    merl_md = (root / "formats" / "merl.md").read_text(encoding="utf-8")
    assert "model name is the file's stem" not in merl_md
    assert "`model` is `unknown`" in merl_md and "material" in merl_md


def test_merl_table_names_its_material_not_a_model(tmp_path):
    t = brdftab.open(_merl_like(tmp_path / "gold-metallic-paint.binary"))
    assert t.ds.attrs["model"] == "unknown" and t.ds.attrs["material"] == "gold-metallic-paint"
    out = _cli("info", tmp_path / "gold-metallic-paint.binary")
    assert out.exit_code == 0
    assert "material:    gold-metallic-paint" in out.stdout and "model:       unknown" in out.stdout


# --- Zemax/Radiant text .bsdf, tensor fields, dtype -----------------------------------------------
ZEMAX = """# Data exported by a goniophotometer; this comment line is longer than sixty-four bytes.
# Second comment
Source  Measured
Symmetry  PlaneSymmetrical
SpectralContent  Monochrome
ScatterType  BRDF
SampleRotation  1
0
AngleOfIncidence  2
0 30
ScatterAzimuth  2
0 180
ScatterRadial  2
0 10

Monochrome
DataBegin
TIS 0.5
0.1 0.2
0.3 0.4
TIS 0.4
0.1 0.2
0.3 0.4
DataEnd
"""

LIGHTTOOLS = """# LightTools BSDF
Symmetry Asymmetric
SpectralContent Monochrome
ScatterAzimuth 2
0 180
ScatterRadial 2
0 10
DataBegin
AOI 0
POI 0
Side Front
ScatterType BRDF
TIS 0.5
0.1 0.2
0.3 0.4
DataEnd
"""


@pytest.mark.parametrize("name", ["z.bsdf", "z.txt"])
def test_zemax_text_bsdf_is_read_by_its_content(tmp_path, name):
    path = tmp_path / name
    path.write_text(ZEMAX)
    table = brdftab.open(path)
    assert table.grid.type_name == "specular-polar" and table.origin == "measured"
    assert np.array_equal(table.values[..., 0], [[[[0.1, 0.2], [0.3, 0.4]]]] * 2)


@pytest.mark.parametrize("name", ["l.bsdf", "l.txt"])
def test_lighttools_text_bsdf_is_read_by_its_content(tmp_path, name):
    path = tmp_path / name
    path.write_text(LIGHTTOOLS)
    with pytest.warns(BrdftabWarning, match="TIS 0.5"):
        table = brdftab.open(path)
    assert table.grid.type_name == "spherical" and table.origin == "unknown"
    # [theta_i, phi_i, theta_o (radial), phi_o (azimuth), C]: each azimuth row of the file is a column here
    assert np.array_equal(table.values[0, 0, :, :, 0], [[0.1, 0.3], [0.2, 0.4]])
    path.write_text(LIGHTTOOLS.replace("Symmetry Asymmetric", "Symmetry PlaneSymmetrical"))
    with pytest.raises(FormatError, match="one side of the plane of incidence"):
        brdftab.open(path)  # azimuths 0 and 180 lie on both sides of the plane of incidence (90 / 270)
    r = _cli("info", path)
    assert r.exit_code == 2 and r.stderr.count("\n") == 1 and "PlaneSymmetrical" in r.stderr and "Traceback" not in r.stderr


def test_other_text_files_keep_their_messages(tmp_path):
    spec = tmp_path / "s.nc"
    spec.write_text("# a comment\n[model]\nname = 'lambert'\n")
    with pytest.raises(FormatError, match="not a readable netCDF file"):
        brdftab.open(spec)
    garbage = tmp_path / "x.bsdf"
    garbage.write_text("Symmetry but nothing else that a Zemax file has\n")
    with pytest.raises(FormatError) as info:
        brdftab.open(garbage)
    assert "Zemax" not in str(info.value)


def test_rgl_tensor_files_are_still_rgl(tmp_path):
    brdftab.save(GGX, tmp_path / "g.bsdf")
    assert brdftab.formats.detect(tmp_path / "g.bsdf").name == "rgl"
    assert brdftab.open(tmp_path / "g.bsdf").eval([0.0, 0.0, 1.0], [0.3, 0.0, 0.95]).shape[-1] == 3


def _tensor_bytes(shape, name=b"rgb", code=10):
    from brdftab.formats._tensor import MAGIC

    head = (MAGIC + struct.pack("<BBI", 1, 0, 1) + struct.pack("<H", len(name)) + name
            + struct.pack("<HBQ", len(shape), code, 64) + struct.pack(f"<{len(shape)}Q", *shape))
    return head + b"\0" * max(0, 80 - len(head))


@pytest.mark.parametrize("shape", [(0, 2**63), (0, 2**64 - 1), (2**32, 2**32, 0), (0,) * 70, (1,) * 70])
def test_zero_size_tensor_field_with_an_impossible_shape_is_one_line(tmp_path, shape):
    path = tmp_path / "z.bsdf"
    path.write_bytes(_tensor_bytes(shape))
    with pytest.raises(FormatError, match="rgb") as info:
        brdftab.open(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)
    r = _cli("info", path)
    assert r.exit_code == 2 and r.stderr.count("\n") == 1, r.stderr


@pytest.mark.parametrize("dtype", ["int8", "uint16", "int64", "bool", "complex128", "float16", "nonsense"])
def test_tabulate_refuses_non_float_dtypes(dtype):
    with pytest.raises(ParameterError, match="dtype") as info:
        tabulate(GGX, SMALL, dtype=dtype, progress=False)
    assert "\n" not in str(info.value)


def test_tabulate_float_dtypes_are_exact():
    t32 = tabulate(GGX, SMALL, dtype="float32", progress=False)
    t64 = tabulate(GGX, SMALL, dtype=np.float64, progress=False)
    assert t32.values.dtype == np.float32 and t64.values.dtype == np.float64
    np.testing.assert_array_equal(t32.values, t64.values.astype(np.float32))

