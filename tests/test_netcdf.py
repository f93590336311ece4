"""netCDF read/write: exact round trips, CF attributes, atomic writes."""

import os

import netCDF4
import numpy as np
import pytest
import xarray as xr

import brdftab
from brdftab import formats, models
from brdftab.errors import BrdftabError, FormatError
from brdftab.grids import RusinkiewiczGrid, SphericalGrid, merl_grid
from brdftab.table import tabulate

GGX = models.create("microfacet", alpha=0.25, fresnel="conductor", n=[0.2, 0.4, 1.4], k=[3.5, 2.4, 1.8])


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
