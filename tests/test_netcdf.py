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
    assert list(ds["channel"].values) == ["R", "G", "B"]
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
