"""netCDF read/write: exact round trips, CF attributes, atomic writes; tampered, damaged and
foreign files; lazy reading of huge declared tables; the writer's progress steps."""

import os
import subprocess
import sys

import netCDF4
import numpy as np
import pytest
import xarray as xr
from _tables import lambert_table

import brdftab
from brdftab import _progress, formats, models
from brdftab.errors import BrdftabError, FormatError
from brdftab.geometry import sph_to_vec
from brdftab.grids import RusinkiewiczGrid, SphericalGrid, merl_grid
from brdftab.table import tabulate

GGX = models.create("microfacet", alpha=0.25, fresnel="conductor", n=[0.2, 0.4, 1.4], k=[3.5, 2.4, 1.8])
PLAIN_GGX = models.create("microfacet", alpha=0.3)  # no Fresnel term: one channel


def sph(theta_deg, phi_deg):
    return sph_to_vec(np.radians(theta_deg), np.radians(phi_deg))


@pytest.mark.parametrize("grid", [
    merl_grid(),
    RusinkiewiczGrid(np.radians([0, 1, 3, 10, 40, 80]), 7, 12, 8, phi_d_fold="none"),
    SphericalGrid(np.radians([0, 30]), np.radians([0, 90]), np.radians([10, 20, 30]), np.radians([0, 180]),
                  relative_to="none"),
], ids=["merl", "rus-aniso-explicit", "spherical"])
def test_round_trip_exact(tmp_path, grid):
    t = tabulate(GGX, grid, progress=False)
    path = tmp_path / "t.nc"
    brdftab.save(t, path)
    back = brdftab.open(path)
    assert back.values.dtype == np.float64
    assert np.array_equal(back.values, t.values)
    assert back.grid.equals(grid)
    assert back.ds.attrs["parameters"] == t.ds.attrs["parameters"]
    wi, wo = grid.directions(0, min(grid.size, 5000))
    assert np.array_equal(back.eval(wi, wo), t.eval(wi, wo))


def test_cf_layout_and_float32(tmp_path):
    path = tmp_path / "t.nc"
    brdftab.save(GGX, path, grid=RusinkiewiczGrid(8, 8, 8), dtype="float32")
    with netCDF4.Dataset(path) as nc:
        assert nc.file_format == "NETCDF4"
        v = nc.variables["brdf"]
        assert v.dtype == np.float32 and v.units == "sr-1"
        assert v.filters()["zlib"]
        assert nc.variables["theta_h"].units == "rad"
        assert nc.Conventions.startswith("CF-")
        for attr in ("parameterization", "sample_position", "phi_d_fold", "model", "parameters", "spec_sha256",
                     "brdftab_version", "created"):
            assert attr in nc.ncattrs()
    ds = xr.open_dataset(path)
    # channel names are a CF label (auxiliary coordinate), not a string coordinate variable
    assert "channel" not in ds.variables and ds["brdf"].dims[-1] == "channel"
    assert list(ds["channel_name"].values) == ["R", "G", "B"] and "channel_name" in ds["brdf"].coords
    ds.close()


def test_spectral_table_round_trip(tmp_path):
    m = models.create("lambert", albedo={"wavelengths_nm": [400, 700], "values": [0.2, 0.8]})
    t = tabulate(m, RusinkiewiczGrid(3, 3, 3), wavelengths=[400, 550, 700], progress=False)
    brdftab.save(t, tmp_path / "s.nc")
    back = brdftab.open(tmp_path / "s.nc")
    assert back.spectral and np.array_equal(back.wavelengths, [400, 550, 700])
    assert back.ds["wavelength"].attrs["units"] == "nm"


def test_model_without_grid_is_refused(tmp_path):
    with pytest.raises(BrdftabError, match="grid"):
        brdftab.save(GGX, tmp_path / "x.nc")
    assert not (tmp_path / "x.nc").exists()


def test_no_overwrite_refuses_and_keeps_file(tmp_path):
    path = tmp_path / "t.nc"
    path.write_bytes(b"old")
    with pytest.raises(BrdftabError, match="already exists"):
        brdftab.save(GGX, path, grid=RusinkiewiczGrid(3, 3, 3), overwrite=False)
    assert path.read_bytes() == b"old"


def test_failed_write_leaves_nothing(tmp_path, monkeypatch):
    fmt = formats.FORMATS["netcdf"]

    def broken(table, path, **kw):
        with open(path, "wb") as fh:
            fh.write(b"half a file")
        raise RuntimeError("disk on fire")

    monkeypatch.setitem(formats.FORMATS, "netcdf", formats.FileFormat(**{**fmt.__dict__, "write": broken}))
    with pytest.raises(RuntimeError):
        brdftab.save(GGX, tmp_path / "t.nc", grid=RusinkiewiczGrid(3, 3, 3))
    assert os.listdir(tmp_path) == []


def test_stale_partial_of_dead_process_is_removed(tmp_path):
    stale = tmp_path / ".t.nc.partial-999999999"
    stale.write_bytes(b"junk")
    brdftab.save(GGX, tmp_path / "t.nc", grid=RusinkiewiczGrid(3, 3, 3))
    assert sorted(os.listdir(tmp_path)) == ["t.nc"]


def test_garbage_and_foreign_files_are_refused(tmp_path):
    bad = tmp_path / "bad.nc"
    bad.write_bytes(b"this is not netCDF")
    with pytest.raises(FormatError, match="bad.nc"):
        brdftab.open(bad)
    foreign = tmp_path / "foreign.nc"
    xr.Dataset({"t": ("x", np.arange(3.0))}).to_netcdf(foreign)
    with pytest.raises(FormatError, match="not a brdftab table"):
        brdftab.open(foreign)


def test_format_detected_by_magic_bytes(tmp_path):
    path = tmp_path / "table.dat"
    brdftab.save(GGX, tmp_path / "t.nc", grid=RusinkiewiczGrid(3, 3, 3))
    os.rename(tmp_path / "t.nc", path)
    assert formats.detect(path).name == "netcdf"
    assert brdftab.open(path).values.shape == (3, 3, 3, 3)


# --- attributes of foreign files: honoured or refused, never read as if absent ------------------
def _foreign(tmp_path, name, edit, spectral=False):
    """A brdftab file edited with netCDF4 (as another writer would have left it)."""
    path = tmp_path / name
    if spectral:
        m = models.create("lambert", albedo={"wavelengths_nm": [400, 700], "values": [0.2, 0.8]})
        brdftab.save(tabulate(m, RusinkiewiczGrid(3, 3, 3), wavelengths=[400, 550, 700], progress=False), path)
    else:
        brdftab.save(GGX, path, grid=RusinkiewiczGrid(4, 4, 4))
    with netCDF4.Dataset(path, "a") as nc:
        edit(nc)
    return path


@pytest.mark.parametrize("edit, shown", [
    (lambda nc: nc.variables["brdf"].setncattr("units", "1"), "units = '1'"),
    (lambda nc: nc.variables["brdf"].setncattr("units", "percent"), "units = 'percent'"),
    (lambda nc: nc.variables["brdf"].setncattr("units", "W m-2"), "units = 'W m-2'"),
    (lambda nc: nc.variables["brdf"].delncattr("units"), "no 'units' attribute"),
], ids=["one", "percent", "other", "missing"])
def test_brdf_units_other_than_per_steradian_are_refused(tmp_path, edit, shown):
    path = _foreign(tmp_path, "u.nc", edit)
    with pytest.raises(FormatError, match="brdf") as info:
        brdftab.open(path)
    msg = str(info.value)
    assert shown in msg and str(path) in msg and "\n" not in msg
    from click.testing import CliRunner

    from brdftab.cli import main

    r = CliRunner().invoke(main, ["info", str(path)])
    assert r.exit_code == 2 and r.stderr.count("\n") == 1 and shown in r.stderr


@pytest.mark.parametrize("units", ["sr^-1", "1/sr", "sr-1"])
def test_brdf_units_spelled_otherwise_are_honoured(tmp_path, units):
    path = _foreign(tmp_path, "u.nc", lambda nc: nc.variables["brdf"].setncattr("units", units))
    t = brdftab.open(path)
    np.testing.assert_array_equal(t.values, tabulate(GGX, RusinkiewiczGrid(4, 4, 4), progress=False).values)


@pytest.mark.parametrize("units, factor", [("um", 1e-3), ("µm", 1e-3), ("micrometer", 1e-3), ("m", 1e-9),
                                           ("nanometer", 1.0)])
def test_wavelengths_in_other_length_units_are_converted_to_nm(tmp_path, units, factor):
    def edit(nc):
        v = nc.variables["wavelength"]
        v[:] = v[:] * factor
        v.setncattr("units", units)
    t = brdftab.open(_foreign(tmp_path, "w.nc", edit, spectral=True))
    np.testing.assert_allclose(t.wavelengths, [400.0, 550.0, 700.0], rtol=1e-12)
    # 0.55 um is 550 nm: the albedo there is 0.5, not an extrapolation (or refusal) at 0.55 nm
    w = np.array([0.0, 0.0, 1.0])
    assert t.eval(w, w, wavelengths=[550.0])[0] == pytest.approx(0.5 / np.pi, rel=1e-12)
    assert t.ds["wavelength"].attrs["units"] == ("nm" if factor != 1.0 else units)


@pytest.mark.parametrize("edit, shown", [
    (lambda nc: nc.variables["wavelength"].delncattr("units"), "no 'units' attribute"),
    (lambda nc: nc.variables["wavelength"].setncattr("units", "cm-1"), "units = 'cm-1'"),
], ids=["missing", "wavenumber"])
def test_wavelengths_without_a_length_unit_are_refused(tmp_path, edit, shown):
    path = _foreign(tmp_path, "w.nc", edit, spectral=True)
    with pytest.raises(FormatError, match="wavelength") as info:
        brdftab.open(path)
    assert shown in str(info.value) and "\n" not in str(info.value)


def test_specular_reflectance_in_percent_is_converted(tmp_path):
    m = models.create("he-torrance-1991", n=1.5, k=0.0, sigma0=0.1, tau=1.0, wavelength_nm=500.0)
    path = tmp_path / "s.nc"
    t = tabulate(m, RusinkiewiczGrid(3, 3, 3), progress=False)
    brdftab.save(t, path)
    with netCDF4.Dataset(path, "a") as nc:
        v = nc.variables["specular_reflectance"]
        v[:] = v[:] * 100
        v.setncattr("units", "percent")
    theta, rho = brdftab.open(path).specular_reflectance
    np.testing.assert_allclose(rho, t.specular_reflectance[1], rtol=1e-12)
    with netCDF4.Dataset(path, "a") as nc:
        nc.variables["specular_reflectance"].setncattr("units", "sr-1")
    with pytest.raises(FormatError, match="specular_reflectance' has units = 'sr-1'"):
        brdftab.open(path)


def test_non_numeric_table_variable_is_refused(tmp_path):
    t = tabulate(PLAIN_GGX, RusinkiewiczGrid(2, 2, 2), progress=False)
    ds = t.ds.copy()
    ds["brdf"] = ds["brdf"].astype(str)
    ds.to_netcdf(tmp_path / "s.nc")
    with pytest.raises(FormatError, match="numeric"):
        brdftab.open(tmp_path / "s.nc")


def test_conforming_file_without_optional_attributes_is_read(tmp_path):
    # another writer: coordinates in degrees, only the required attributes
    import xarray as xr

    g = merl_grid()
    t = tabulate(PLAIN_GGX, g, progress=False)
    ds = xr.Dataset({"brdf": (("theta_h", "theta_d", "phi_d", "channel"), t.values, {"units": "sr-1"})},
                    coords={n: (n, np.degrees(a.values), {"units": "degree"}) for n, a in zip(g.dims, g.axes)}
                    | {"channel": ["mono"]},
                    attrs={"parameterization": "rusinkiewicz", "phi_d_fold": "reciprocity"})
    ds.to_netcdf(tmp_path / "other.nc")
    back = brdftab.open(tmp_path / "other.nc")
    assert back.grid.equals(g)
    w1, w2 = sph(25, 0), sph(40, 200)
    assert back.eval(w1, w2) == pytest.approx(t.eval(w1, w2), rel=1e-12)
    ds.attrs.pop("phi_d_fold")
    ds.to_netcdf(tmp_path / "nofold.nc")
    with pytest.raises(FormatError, match="phi_d_fold"):
        brdftab.open(tmp_path / "nofold.nc")


# -- CF missing markers: _FillValue and missing_value samples are missing, not NaN ----------------

def _cf_file(path, encoding, attrs=None):
    """A Lambertian (ρ = 0.5) table on a small grid as another CF writer (xarray) stores it, with
    four samples not measured: NaN in memory, written as the encoding's marker."""
    g = RusinkiewiczGrid(6, 6, 12)
    t = tabulate(models.create("lambert", albedo=0.5), g, progress=False)
    values = t.values.copy()
    gone = [(0, 0, 0, 0), (1, 2, 3, 0), (5, 5, 11, 0), (3, 1, 7, 0)]
    for i in gone:
        values[i] = np.nan
    ds = xr.Dataset({"brdf": (g.dims + ("channel",), values, {"units": "sr-1", **(attrs or {})})},
                    coords={n: (n, a.values, {"units": "rad"}) for n, a in zip(g.dims, g.axes)} | {"channel": ["mono"]},
                    attrs={"parameterization": "rusinkiewicz", "phi_d_fold": "reciprocity",
                           "sample_position": "bin-centre", "reciprocal": 1, "isotropic": 1})
    ds.to_netcdf(path, encoding={"brdf": encoding})
    return path, len(gone)


@pytest.mark.parametrize("encoding", [
    {"_FillValue": -1.0},                                                   # _FillValue
    {"_FillValue": None, "missing_value": -999.0},                          # missing_value
    {"dtype": "int16", "scale_factor": 1e-5, "add_offset": 0.0, "_FillValue": -32768},  # packed
    {"_FillValue": np.nan},                                                 # xarray's default for floats
], ids=["fill-value", "missing-value", "packed", "nan-fill"])
def test_cf_missing_markers_are_missing_samples(tmp_path, encoding):
    from brdftab.checks import run_checks

    path, n = _cf_file(tmp_path / "cf.nc", encoding)
    with netCDF4.Dataset(path) as nc:  # the file holds the marker, as CF says
        nc.set_auto_maskandscale(False)
        v = nc["brdf"]
        marker = v.getncattr("_FillValue") if "_FillValue" in v.ncattrs() else v.getncattr("missing_value")
        raw = v[0, 0, 0, 0]
        assert raw == marker or (np.isnan(marker) and np.isnan(raw))
    t = brdftab.open(path)
    assert int(t.missing.sum()) == n
    stats = t.statistics()
    assert stats["missing"] == n and stats["nonfinite"] == 0
    assert stats["max"] == pytest.approx(0.5 / np.pi, rel=1e-4 if "scale_factor" in encoding else 1e-12)
    report = run_checks(t, only=("finite", "missing", "energy"))
    assert report.get("finite").status == "pass", report.to_text()      # not NaN failures
    assert report.get("missing").detail.startswith(f"{n} of {t.values.size} samples are missing")
    assert report.get("energy").figure == pytest.approx(0.5, abs=2e-3)  # left out of the integrals


def test_cf_missing_markers_survive_a_round_trip_through_brdftab(tmp_path):
    path, n = _cf_file(tmp_path / "cf.nc", {"_FillValue": -1.0})
    brdftab.save(brdftab.open(path), tmp_path / "again.nc")
    back = brdftab.open(tmp_path / "again.nc")
    assert int(back.missing.sum()) == n and back.statistics()["nonfinite"] == 0


# -- the reader checks the file: tampered attributes and coordinates -------------------------------

@pytest.fixture(scope="module")
def good_nc(tmp_path_factory):
    path = tmp_path_factory.mktemp("nc") / "good.nc"
    t = tabulate(PLAIN_GGX, brdftab.grids.RusinkiewiczGrid(12, 10, 18, theta_h_spacing="merl"), progress=False)
    brdftab.save(t, path)
    return path


def _tamper(src, dst, fn):
    import shutil

    shutil.copy(src, dst)
    with netCDF4.Dataset(dst, "a") as nc:
        fn(nc)
    return dst


@pytest.mark.parametrize("name, fn, expected", [
    ("bogus-spacing", lambda nc: nc.setncattr("theta_h_spacing", "bogus"), "theta_h_spacing"),
    ("bogus-fold", lambda nc: nc.setncattr("phi_d_fold", "bogus"), "phi_d_fold"),
    ("relabelled-fold", lambda nc: nc.setncattr("phi_d_fold", "none"), "phi_d"),
    ("nan-coordinate", lambda nc: nc.variables["theta_d"].__setitem__(3, np.nan), "theta_d"),
    ("degrees-labelled-rad", lambda nc: nc.variables["theta_d"].__setitem__(slice(None),
                                                                          np.degrees(nc.variables["theta_d"][:])),
     "theta_d"),
    ("unknown-units", lambda nc: nc.variables["phi_d"].setncattr("units", "furlong"), "units"),
    ("wrong-spacing", lambda nc: nc.setncattr("theta_h_spacing", "linear"), "theta_h"),
    ("no-parameterization-value", lambda nc: nc.setncattr("parameterization", "hexagonal"), "parameterization"),
])
def test_tampered_files_are_refused_naming_the_attribute(tmp_path, good_nc, name, fn, expected):
    bad = _tamper(good_nc, tmp_path / f"{name}.nc", fn)
    with pytest.raises(FormatError, match=expected) as exc:
        brdftab.open(bad)
    assert str(bad) in str(exc.value) and "\n" not in str(exc.value)
    p = subprocess.run([sys.executable, "-m", "brdftab", "info", str(bad)], capture_output=True, text=True)
    assert p.returncode == 2 and p.stderr.count("\n") == 1 and expected in p.stderr, p.stderr


def test_missing_coordinate_is_refused(tmp_path, good_nc):
    import xarray as xr

    with xr.open_dataset(good_nc) as ds:
        ds = ds.load().drop_vars("theta_h")
    bad = tmp_path / "nocoord.nc"
    ds.to_netcdf(bad)
    with pytest.raises(FormatError, match="missing coordinate 'theta_h'"):
        brdftab.open(bad)


def test_coordinates_in_degrees_are_converted(tmp_path, good_nc):
    def to_degrees(nc):
        for name in ("theta_h", "theta_d", "phi_d"):
            v = nc.variables[name]
            v[:] = np.degrees(v[:])
            v.setncattr("units", "degree")
            if "domain" in v.ncattrs():
                v.setncattr("domain", np.degrees(v.getncattr("domain")))
    t = brdftab.open(_tamper(good_nc, tmp_path / "deg.nc", to_degrees))
    ref = brdftab.open(good_nc)
    w1, w2 = sph(20, 0), sph(40, 170)
    assert t.eval(w1, w2) == pytest.approx(ref.eval(w1, w2), rel=1e-9)


def test_damaged_sample_data_is_a_format_error(tmp_path):
    path = lambert_table(tmp_path)
    data = bytearray(path.read_bytes())
    mid = len(data) // 2
    data[mid:mid + 4000] = bytes(b ^ 0xFF for b in data[mid:mid + 4000])
    path.write_bytes(bytes(data))
    for cmd in (["info"], ["validate"], ["eval", "--wi-deg", "30,0", "--wo-deg", "30,180"]):
        p = subprocess.run([sys.executable, "-m", "brdftab", cmd[0], str(path), *cmd[1:]], capture_output=True,
                           text=True)
        assert p.returncode == 2 and p.stderr.count("\n") == 1, (cmd, p.stderr)
        assert "damaged" in p.stderr or "not a readable netCDF" in p.stderr, p.stderr


# -- a huge declared table is not loaded to be described or evaluated ------------------------------

def _huge(path, n_theta_h=2000):
    """A small file declaring a float64 table of n_theta_h x 90 x 180 x 3 (nothing written)."""
    g = merl_grid()
    with netCDF4.Dataset(path, "w") as nc:
        nc.createDimension("theta_h", n_theta_h)
        for name, n in (("theta_d", 90), ("phi_d", 180), ("channel", 3)):
            nc.createDimension(name, n)
        u = (np.arange(n_theta_h) + 0.5) / n_theta_h
        for name, vals in (("theta_h", u ** 2 * np.pi / 2), ("theta_d", g.axes[1].values),
                           ("phi_d", g.axes[2].values)):
            v = nc.createVariable(name, "f8", (name,))
            v[:] = vals
            v.units = "rad"
        c = nc.createVariable("channel", str, ("channel",))
        for i, x in enumerate("RGB"):
            c[i] = x
        nc.createVariable("brdf", "f8", ("theta_h", "theta_d", "phi_d", "channel"), zlib=True,
                          chunksizes=(1, 90, 180, 3))
        nc.variables["brdf"].units = "sr-1"  # without it the file does not say the values are f_r: refused
        nc.variables["brdf"][0] = np.ones((90, 180, 3))  # one slab written
        nc.setncatts({"parameterization": "rusinkiewicz", "grid": "huge", "theta_h_spacing": "merl",
                      "phi_d_fold": "reciprocity", "sample_position": "bin-centre"})
    return path


def test_open_is_lazy_and_fill_values_are_missing(tmp_path):
    path = _huge(tmp_path / "huge.nc", n_theta_h=4)
    t = brdftab.open(path)
    assert t._values is None  # nothing loaded by opening
    miss = t.missing
    assert miss is not None and miss.sum() == 3 * 90 * 180 * 3 and not miss[0].any()


def test_info_on_a_huge_declared_table_streams(tmp_path):
    path = _huge(tmp_path / "huge.nc")  # declares 2000 x 90 x 180 x 3 float64 = 777 MB
    code = ("import resource, subprocess, sys; "
            f"p = subprocess.run([sys.executable, '-m', 'brdftab', 'info', '--json', {str(path)!r}], "
            "capture_output=True, text=True); "
            "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss); print(p.returncode); print(p.stdout)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True).stdout.splitlines()
    peak_kib, rc = int(out[0]), int(out[1])
    assert rc == 0
    import json

    info = json.loads(out[2])
    assert info["missing"] == (2000 - 1) * 90 * 180 * 3
    assert info["max"] == 1.0  # the fill value 9.97e36 is not data
    assert peak_kib < 450 * 1024, f"info used {peak_kib / 1024:.0f} MiB for a 777 MB declared table"


def test_eval_on_a_huge_declared_table_reads_a_slab(tmp_path):
    path = _huge(tmp_path / "huge.nc")  # 777 MB declared, one θh slab written (ones)
    code = ("import resource, subprocess, sys; "
            f"p = subprocess.run([sys.executable, '-m', 'brdftab', 'eval', {str(path)!r}, '--wi-deg', '30,0', "
            "'--wo-deg', '30,180', '--json'], capture_output=True, text=True); "
            "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss); print(p.returncode); "
            "print(p.stdout.strip() or p.stderr.strip())")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True).stdout.splitlines()
    peak_kib, rc = int(out[0]), int(out[1])
    assert rc == 0, out
    import json

    # the mirror pair sits at θh = 0: the written slab (1.0); the unwritten neighbours are missing
    assert json.loads(out[2])["channels"]["R"] == pytest.approx(1.0, rel=1e-12)
    assert peak_kib < 450 * 1024, f"eval used {peak_kib / 1024:.0f} MiB for a 777 MB declared table"


# -- the writer reports its steps --------------------------------------------------------------------

def test_netcdf_writer_reports_steps_and_writes_the_same_values(tmp_path, monkeypatch):
    from brdftab.formats import netcdf
    from brdftab.table import tabulate

    monkeypatch.setattr(netcdf, "CHUNK_BYTES", 512)
    table = tabulate(brdftab.models.create("microfacet", alpha=0.3), RusinkiewiczGrid(12, 10, 16), progress=False)
    steps = []
    _progress._observers.append(lambda done, total: steps.append((done, total)))
    try:
        brdftab.save(table, tmp_path / "a.nc", dtype="float32")
    finally:
        _progress._observers.pop()
    total = table.values.size
    assert len(steps) > 5 and steps[0] == (0, total) and steps[-1] == (total, total)
    assert all(b[0] >= a[0] for a, b in zip(steps, steps[1:]))
    back = brdftab.open(tmp_path / "a.nc")
    np.testing.assert_array_equal(back.values, table.values.astype(np.float32))
    with xr.open_dataset(tmp_path / "a.nc") as ds:
        assert ds["brdf"].dtype == np.float32 and ds["brdf"].attrs["units"] == "sr-1"
        assert "_FillValue" not in ds["brdf"].encoding or ds["brdf"].encoding["_FillValue"] is None


def _beyond_float32_table(tmp_path):
    """A float64 netCDF table whose values above the horizon exceed float32 (finite in float64)."""
    big = models.create("scale", factor=2e40, term=models.create("lambert", albedo=0.5))
    t = tabulate(big, RusinkiewiczGrid(6, 5, 8), progress=False)
    path = tmp_path / "big.nc"
    brdftab.save(t, path)
    v = np.asarray(t.values)
    return path, int(np.count_nonzero(v > np.finfo(np.float32).max)), v.size


def test_convert_to_float32_judges_the_stored_values(tmp_path):
    """Converted with dtype = float32, values beyond float32 are stored as inf: the output fails
    the finite check (exit 1, nothing written) although the float64 input is finite."""
    from _cli import run

    src, over, total = _beyond_float32_table(tmp_path)
    assert over > 0
    r = run("convert", src, tmp_path / "f32.nc", "-o", "dtype=float32", "--level", "energy=off")
    assert r.returncode == 1, r.stderr
    assert f"finite: {over} of {total} samples are NaN or infinite (0 NaN, {over} infinite)" in r.stderr
    assert "as stored in float32" in r.stderr and not (tmp_path / "f32.nc").exists()
    r = run("convert", src, tmp_path / "f32.nc", "-o", "dtype=float32", "--level", "energy=off", "--allow-invalid")
    assert r.returncode == 0, r.stderr
    back = brdftab.open(tmp_path / "f32.nc")
    assert back.ds.attrs["validation_passed"] == 0 and np.isinf(back.values).sum() == over
    r = run("convert", src, tmp_path / "f64.nc", "--level", "energy=off")  # float64 holds them
    assert r.returncode == 0, r.stderr


def test_duplicate_channel_names_are_refused_on_read(tmp_path):
    """Three channels all called R: which one would ``eval --json`` report? Refused, naming it."""
    path = tmp_path / "rrr.nc"
    brdftab.save(models.create("lambert", albedo=[0.2, 0.5, 0.8]), path, grid=RusinkiewiczGrid(3, 3, 4))
    with netCDF4.Dataset(path, "a") as nc:
        nc["channel_name"][:] = netCDF4.stringtochar(np.array(["R", "G", "R"], dtype="S1"))
    with pytest.raises(FormatError, match=r"rrr.nc: .*duplicate channel name 'R' \(channels R, G, R\)"):
        brdftab.open(path)
    proc = subprocess.run([sys.executable, "-m", "brdftab", "eval", str(path), "--wi-deg", "10,0", "--wo-deg",
                           "10,180", "--json"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and proc.stdout == "", proc
    assert proc.stderr.splitlines() == [f"brdftab: error: {path}: channels: duplicate channel name 'R' (channels R, "
                                        "G, R): each channel needs its own name"]
