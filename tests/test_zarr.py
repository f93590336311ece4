"""zarr stores (``.zarr`` folders): the same table as through netCDF, read by plain xarray and
zarr, lazy opening, block writing, conversion both ways, damaged stores, and atomic writes of a
folder (no partial store, no leftover temporary, --overwrite)."""

from __future__ import annotations

import hashlib
import json
import os
import time

import numpy as np
import pytest
import xarray as xr
import zarr
from _cli import cli, one_error, run

import brdftab
from brdftab import _atomic, _progress, formats, models
from brdftab.channels import Layout
from brdftab.errors import BrdftabError, FormatError
from brdftab.formats import zarr as zarr_format
from brdftab.grids import RusinkiewiczGrid, SphericalGrid
from brdftab.table import make_table, tabulate

GGX = models.create("microfacet", alpha=0.25, fresnel="conductor", n=[0.2, 0.4, 1.4], k=[3.5, 2.4, 1.8])
HT = models.create("he-torrance-1991", n=1.5, k=0.0, sigma0=0.1, tau=1.0, wavelength_nm=500.0)  # a delta part


@pytest.fixture(scope="module")
def rgb():
    return tabulate(GGX, RusinkiewiczGrid(12, 10, 16), progress=False)


def _same(a, b):
    """Attribute dicts hold the same values (numbers compared as numbers, whatever their type)."""
    assert set(a) == set(b), set(a) ^ set(b)
    for k in a:
        if isinstance(a[k], str) or isinstance(b[k], str):
            assert a[k] == b[k], k
        else:
            np.testing.assert_array_equal(np.asarray(a[k]), np.asarray(b[k]), err_msg=k)


def _tables_equal(nc, zr):
    """The table read from a store is the one read from the netCDF file: values bit for bit,
    every variable, coordinate and attribute (netCDF's reader adds ``unwritten_value``, the value
    of never-written parts of a file: a store has no such parts, a missing chunk is an error)."""
    assert zr.grid.equals(nc.grid) and zr.channels == nc.channels
    assert zr.values.dtype == nc.values.dtype and np.array_equal(zr.values, nc.values)
    assert set(zr.ds.variables) == set(nc.ds.variables)
    _same(nc.ds.attrs, zr.ds.attrs)
    for name in nc.ds.variables:
        attrs = {k: v for k, v in nc.ds[name].attrs.items() if k != "unwritten_value"}
        _same(attrs, zr.ds[name].attrs)
        if name != "brdf":
            assert np.array_equal(nc.ds[name].values, zr.ds[name].values), name


@pytest.mark.parametrize("make", [
    lambda: tabulate(GGX, RusinkiewiczGrid(np.radians([0, 1, 3, 10, 40, 80]), 7, 12, 8, phi_d_fold="none"),
                     progress=False),
    lambda: tabulate(HT, SphericalGrid(np.radians([0, 30]), np.radians([0, 90]), np.radians([10, 20, 30]),
                                       np.radians([0, 180]), relative_to="none"), progress=False),
    lambda: tabulate(models.create("lambert", albedo={"wavelengths_nm": [400, 700], "values": [0.2, 0.8]}),
                     RusinkiewiczGrid(3, 3, 3), wavelengths=[400, 550, 700], progress=False),
], ids=["rgb-aniso-explicit", "spherical-specular", "spectral"])
def test_a_store_reads_back_as_the_same_table_as_netcdf(tmp_path, make):
    t = make()
    t.ds.attrs["comment"] = "naïve ✓"  # non-ASCII text survives both
    brdftab.save(t, tmp_path / "t.nc")
    brdftab.save(t, tmp_path / "t.zarr")
    nc, zr = brdftab.open(tmp_path / "t.nc"), brdftab.open(tmp_path / "t.zarr")
    assert np.array_equal(zr.values, t.values)
    _tables_equal(nc, zr)
    if t.specular_reflectance is not None:
        assert np.array_equal(zr.specular_reflectance[1], t.specular_reflectance[1])
    wi, wo = t.grid.directions(0, min(t.grid.size, 3000))
    assert np.array_equal(zr.eval(wi, wo), nc.eval(wi, wo), equal_nan=True)


@pytest.mark.parametrize("version", [3, 2])
def test_plain_xarray_and_zarr_read_the_store(tmp_path, rgb, version):
    path = tmp_path / "t.zarr"
    brdftab.save(rgb, path, zarr_format=version)
    assert (path / ("zarr.json" if version == 3 else ".zgroup")).is_file()
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # consolidated metadata: no fallback warning from a plain open
        ds = xr.open_zarr(path)
    dims = ("theta_h", "theta_d", "phi_d", "channel")
    assert ds["brdf"].dims == dims and ds["brdf"].attrs["units"] == "sr-1"
    assert list(ds["channel_name"].values) == ["R", "G", "B"] and "channel_name" in ds["brdf"].coords
    for ax in rgb.grid.axes:
        assert ds[ax.name].attrs["units"] == "rad" and np.array_equal(ds[ax.name].values, ax.values)
    np.testing.assert_array_equal(ds["brdf"].values, rgb.values)
    assert ds.attrs["parameterization"] == "rusinkiewicz" and ds.attrs["Conventions"] == "CF-1.10"
    g = zarr.open_group(path, mode="r")
    a = g["brdf"]
    assert a.shape == rgb.values.shape and a.dtype == np.float64 and a.attrs["units"] == "sr-1"
    names = a.metadata.dimension_names if version == 3 else tuple(a.attrs["_ARRAY_DIMENSIONS"])
    assert tuple(names) == dims
    np.testing.assert_array_equal(g["theta_h"][:], rgb.grid.axes[0].values)
    assert json.loads(g.attrs["parameters"]) == json.loads(rgb.ds.attrs["parameters"])
    assert np.array_equal(brdftab.open(path).values, rgb.values)


def test_float32_option_stores_float32_and_the_checks_judge_it(tmp_path, rgb):
    path = tmp_path / "t.zarr"
    brdftab.save(rgb, path, dtype="float32")
    assert zarr.open_group(path, mode="r")["brdf"].dtype == np.float32
    back = brdftab.open(path)
    assert back.values.dtype == np.float32
    assert np.array_equal(back.values, rgb.values.astype(np.float32))
    stored = formats.stored(formats.FORMATS["zarr"], rgb, {"dtype": "float32"})
    assert np.array_equal(stored.values, back.values.astype(np.float64))


def test_missing_markers_are_missing_samples_as_in_netcdf(tmp_path, rgb):
    ds = rgb.ds.copy(deep=True)
    v = ds["brdf"].values
    v[3, 2, :5, 0] = -1.0
    v[7, 1, 4, :] = -2.0
    ds["brdf"].attrs["missing_value"] = np.array([-1.0, -2.0])
    t = brdftab.table.Table(ds)
    brdftab.save(t, tmp_path / "t.nc")
    brdftab.save(t, tmp_path / "t.zarr")
    nc, zr = brdftab.open(tmp_path / "t.nc"), brdftab.open(tmp_path / "t.zarr")
    _tables_equal(nc, zr)
    assert zr.missing.sum() == 5 + 3 and np.array_equal(zr.missing, nc.missing)
    assert zr.statistics()["missing"] == 8


def test_a_store_another_writer_sharded_is_read_and_a_missing_shard_named(tmp_path, rgb):
    path = tmp_path / "t.zarr"
    brdftab.save(rgb, path)
    g = zarr.open_group(path, mode="r+")
    attrs, dims = dict(g["brdf"].attrs), g["brdf"].metadata.dimension_names
    del g["brdf"]
    a = g.create_array("brdf", shape=rgb.values.shape, dtype="f8", chunks=(2, 10, 16, 3), shards=(4, 10, 16, 3),
                       attributes=attrs, dimension_names=dims, fill_value=np.nan)
    a[:] = rgb.values
    with pytest.warns(UserWarning, match="Consolidated metadata"):  # zarr-python's note on format 3
        zarr.consolidate_metadata(path)
    assert np.array_equal(brdftab.open(path).values, rgb.values)
    (path / "brdf" / "c" / "2" / "0" / "0" / "0").unlink()  # θh rows 8..11
    with pytest.raises(FormatError, match=r"the chunk brdf/c/2/0/0/0 of 'brdf' is missing"):
        brdftab.open(path).values


def test_a_store_takes_any_folder_name(tmp_path, rgb):
    path = tmp_path / os.fsdecode(b"g\xff \xe2\x9c\x93.zarr")  # not UTF-8, and non-ASCII
    brdftab.save(rgb, path)
    assert np.array_equal(brdftab.open(path).values, rgb.values)


# -- lazy opening, block writing ------------------------------------------------------------------

def _declared(path, n_theta_h=2000, written=10):
    """A store declaring a float64 table of n_theta_h x 90 x 180 x 3 (777 MB at 2000) of which only
    the first ``written`` θh rows (ones) are written, through the block writer."""
    grid = RusinkiewiczGrid(n_theta_h, 90, 180)
    shape = grid.shape + (3,)
    template = make_table(np.broadcast_to(np.float64(0.0), shape), grid, Layout(("R", "G", "B"))).ds
    with zarr_format.stream_zarr(template, path) as w:
        assert w.chunks == (10,) + shape[1:]  # 10 θh slabs per chunk (3.7 MiB)
        w.write((slice(0, written),), np.ones((written,) + shape[1:]))
    w.update(xr.Dataset(attrs={"validation_passed": 1}))  # after the samples, as a streamed run does
    return path


def test_opening_a_huge_store_reads_no_samples(tmp_path):
    path = _declared(tmp_path / "huge.zarr")
    t0 = time.perf_counter()
    t = brdftab.open(path)
    assert time.perf_counter() - t0 < 5 and t._values is None and t.nbytes == 2000 * 90 * 180 * 3 * 8
    assert t.ds.attrs["validation_passed"] == 1
    # a pair near θh = 0 is evaluated from the slab it needs (the table is over 256 MiB)
    wi = np.array([[np.sin(0.3), 0.0, np.cos(0.3)]])
    wo = np.array([[-np.sin(0.3), 0.0, np.cos(0.3)]])
    np.testing.assert_allclose(t.eval(wi, wo), 1.0, rtol=1e-12)
    assert t._values is None
    # the rows never written are missing chunks: an error naming one, never values
    with pytest.raises(FormatError, match=r"damaged store: the chunk brdf/c/1/0/0/0 of 'brdf' is missing"):
        next(x for i, x in enumerate(t.iter_chunks(max_bytes=4 << 20)) if i > 1)


def test_info_streams_and_never_loads_the_table(tmp_path, rgb, monkeypatch):
    path = tmp_path / "t.zarr"
    brdftab.save(rgb, path)
    t = brdftab.open(path)
    stats = t.statistics()
    assert t._values is None and stats["max"] == float(rgb.values.max())
    res = cli("info", "--json", path)
    assert res.exit_code == 0 and json.loads(res.output)["format"] == "zarr"


def test_reads_come_in_whole_chunks(tmp_path, rgb, monkeypatch):
    from brdftab._signals import read_array

    monkeypatch.setattr(zarr_format, "CHUNK_BYTES", 3 * 10 * 16 * 3 * 8)  # chunks of 3 θh rows
    path = tmp_path / "t.zarr"
    brdftab.save(rgb, path)
    t = brdftab.open(path)
    keys = []
    get = zarr_format._CheckedArray._get
    monkeypatch.setattr(zarr_format._CheckedArray, "_get", lambda self, key: keys.append(key[0]) or get(self, key))
    values = read_array(t._var, slab_bytes=10 * 16 * 3 * 8)  # one row per slab asked: whole chunks read
    assert np.array_equal(values, rgb.values)
    assert [k.start for k in keys] == [0, 3, 6, 9] and all(k.stop - k.start == 3 for k in keys)


def test_the_block_writer_takes_blocks_in_any_order(tmp_path, rgb):
    path = tmp_path / "t.zarr"
    shape = rgb.values.shape
    with zarr_format.stream_zarr(rgb.ds, path, dtype="float32") as w:
        for start in range(shape[0] - 5, -5, -5):  # backwards, not aligned to the chunks
            lo = max(0, start)
            w.write((slice(lo, start + 5), slice(None), slice(0, 7)), rgb.values[lo:start + 5, :, :7])
            w.write((slice(lo, start + 5), slice(None), slice(7, None)), rgb.values[lo:start + 5, :, 7:])
    w.update(xr.Dataset(attrs={"validation_summary": "all checks passed"}))
    back = brdftab.open(path)
    assert back.ds.attrs["validation_summary"] == "all checks passed"
    assert np.array_equal(back.values, rgb.values.astype(np.float32))
    assert zarr.open_group(path, mode="r")["brdf"].chunks == w.chunks


def test_copies_of_a_writer_write_disjoint_chunks_of_one_store(tmp_path, rgb, monkeypatch):
    import pickle

    monkeypatch.setattr(zarr_format, "CHUNK_BYTES", 10 * 16 * 3 * 8)  # one θh row per chunk
    path = tmp_path / "t.zarr"
    w = zarr_format.stream_zarr(rgb.ds, path)
    copies = [pickle.loads(pickle.dumps(w)) for _ in range(2)]  # as sent to worker processes
    for i in range(rgb.values.shape[0]):
        copies[i % 2].write((slice(i, i + 1),), rgb.values[i:i + 1])
    w.close()
    assert np.array_equal(brdftab.open(path).values, rgb.values)


def test_writing_reports_steps_and_reads_an_open_table_block_by_block(tmp_path, rgb, monkeypatch):
    brdftab.save(rgb, tmp_path / "t.nc")
    source = brdftab.open(tmp_path / "t.nc")
    monkeypatch.setattr(zarr_format, "CHUNK_BYTES", 10 * 16 * 3 * 8)
    monkeypatch.setattr(zarr_format, "BLOCK_BYTES", 2 * 10 * 16 * 3 * 8)
    steps = []
    _progress._observers.append(lambda done, total: steps.append((done, total)))
    try:
        brdftab.save(source, tmp_path / "t.zarr")
    finally:
        _progress._observers.pop()
    total = rgb.values.size
    assert steps[0] == (0, total) and steps[-1] == (total, total) and len(steps) == 1 + 6
    assert source._values is None  # the source was read one block at a time, never whole
    assert np.array_equal(brdftab.open(tmp_path / "t.zarr").values, rgb.values)


# -- the command line ----------------------------------------------------------------------------

def _store_digest(folder):
    h = hashlib.sha256()
    for p in sorted(q for q in folder.rglob("*") if q.is_file()):
        h.update(p.relative_to(folder).as_posix().encode() + b"\0" + p.read_bytes())
    return h.hexdigest()


def test_convert_both_ways_copies_the_values(tmp_path, rgb):
    brdftab.save(rgb, tmp_path / "a.nc")
    res = cli("convert", tmp_path / "a.nc", tmp_path / "b.zarr")
    assert res.exit_code == 0 and "copied" in res.output, res.output
    res = cli("convert", tmp_path / "b.zarr", tmp_path / "c.nc")
    assert res.exit_code == 0 and "copied" in res.output, res.output
    b, c = brdftab.open(tmp_path / "b.zarr"), brdftab.open(tmp_path / "c.nc")
    assert np.array_equal(b.values, rgb.values) and np.array_equal(c.values, rgb.values)
    assert c.ds.attrs["converted_from"] == "b.zarr"
    assert c.ds.attrs["converted_from_sha256"] == _store_digest(tmp_path / "b.zarr")
    res = cli("eval", tmp_path / "b.zarr", "--wi-deg", "30,0", "--wo-deg", "30,180", "--json")
    assert res.exit_code == 0
    expect = rgb.eval(np.array([np.sin(np.radians(30)), 0, np.cos(np.radians(30))]),
                      np.array([-np.sin(np.radians(30)), 0, np.cos(np.radians(30))]))
    assert json.loads(res.output)["channels"]["R"] == pytest.approx(float(expect[0]), rel=1e-12)
    res = cli("validate", tmp_path / "b.zarr")
    assert res.exit_code == 0, res.output
    res = cli("validate", str(tmp_path / "*"))  # a glob takes the store, not the files inside it
    assert res.exit_code == 0 and res.output.count("PASSED") == 3, res.output


def test_tabulate_writes_a_store_output(tmp_path):
    spec = tmp_path / "s.toml"
    spec.write_text('[model]\nname = "lambert"\nalbedo = 0.5\n[grid]\ntype = "rusinkiewicz"\nn_theta_h = 6\n'
                    'n_theta_d = 6\nn_phi_d = 8\n[[output]]\npath = "x.zarr"\ndtype = "float32"\n'
                    '[[output]]\npath = "x.nc"\ndtype = "float32"\n')
    res = cli("tabulate", spec)
    assert res.exit_code == 0, res.output
    zr, nc = brdftab.open(tmp_path / "x.zarr"), brdftab.open(tmp_path / "x.nc")
    _tables_equal(nc, zr)
    assert zr.ds.attrs["validation_passed"] == 1
    assert sorted(os.listdir(tmp_path)) == ["s.toml", "x.nc", "x.zarr"]


def test_a_folder_that_is_not_a_store_is_one_error(tmp_path):
    folder = tmp_path / "plain"
    folder.mkdir()
    (folder / "notes.txt").write_text("x")
    for cmd in (["info", folder], ["eval", folder, "--wi-deg", "30,0", "--wo-deg", "30,180"],
                ["convert", folder, tmp_path / "o.nc"]):
        res = cli(*cmd)
        one_error(res.stderr, res.exit_code, "plain: is a folder, neither a table file nor a zarr store")


def test_a_damaged_store_is_one_error(tmp_path, rgb, monkeypatch):
    monkeypatch.setattr(zarr_format, "CHUNK_BYTES", 4 * 10 * 16 * 3 * 8)
    path = tmp_path / "t.zarr"
    brdftab.save(rgb, path)
    chunk = path / "brdf" / "c" / "1" / "0" / "0" / "0"  # θh rows 4..7
    data = chunk.read_bytes()
    chunk.write_bytes(data[:20] + bytes(b ^ 0x5A for b in data[20:60]) + data[60:])
    p = run("info", path)  # the entry point itself, once
    one_error(p.stderr, p.returncode, "damaged sample data in 'brdf'")
    chunk.unlink()
    for cmd in (["info", path], ["validate", path], ["convert", path, tmp_path / "o.nc"]):
        res = cli(*cmd)
        one_error(res.stderr, res.exit_code, "damaged store: the chunk brdf/c/1/0/0/0 of 'brdf' is missing")
    assert not (tmp_path / "o.nc").exists()
    # format 2 (zstd's checksum guards the chunks)
    brdftab.save(rgb, tmp_path / "v2.zarr", zarr_format=2)
    chunk = tmp_path / "v2.zarr" / "brdf" / "1.0.0.0"
    data = chunk.read_bytes()
    chunk.write_bytes(data[:20] + bytes(b ^ 0x5A for b in data[20:60]) + data[60:])
    with pytest.raises(FormatError, match=r"damaged sample data in 'brdf' \(.*corrupt"):
        brdftab.open(tmp_path / "v2.zarr").values
    chunk.write_bytes(data[:len(data) // 2])
    with pytest.raises(FormatError, match="damaged sample data in 'brdf'"):
        brdftab.open(tmp_path / "v2.zarr").values


# -- atomic writes of a folder --------------------------------------------------------------------

def _broken_after(n, exc):
    real = zarr_format.ZarrWriter.write
    calls = []

    def write(self, key, block):
        calls.append(key)
        if len(calls) > n:
            raise exc
        real(self, key, block)
    return write


@pytest.mark.parametrize("exc", [RuntimeError("disk on fire"), KeyboardInterrupt()])
def test_a_failed_write_leaves_no_store_and_no_temporary(tmp_path, rgb, monkeypatch, exc):
    monkeypatch.setattr(zarr_format, "BLOCK_BYTES", 10 * 16 * 3 * 8)
    monkeypatch.setattr(zarr_format, "CHUNK_BYTES", 10 * 16 * 3 * 8)
    brdftab.save(rgb, tmp_path / "t.zarr")
    before = _store_digest(tmp_path / "t.zarr")
    monkeypatch.setattr(zarr_format.ZarrWriter, "write", _broken_after(3, exc))
    for target, overwrite in ((tmp_path / "new.zarr", False), (tmp_path / "t.zarr", True)):
        with pytest.raises(type(exc)):
            brdftab.save(rgb, target, overwrite=overwrite)
        assert sorted(os.listdir(tmp_path)) == ["t.zarr"]  # no partial store, no temporary, no lock
    assert _store_digest(tmp_path / "t.zarr") == before  # the store it was to replace is intact


@pytest.mark.parametrize("swap", [True, False], ids=["renameat2", "rename-aside"])
def test_overwrite_replaces_a_store_and_without_it_is_refused(tmp_path, rgb, monkeypatch, swap):
    if not swap:  # a system or file system without renameat2: the fallback
        monkeypatch.setattr(_atomic, "_renameat2", lambda src, dst, flags: False)
    path = tmp_path / "t.zarr"
    brdftab.save(rgb, path)
    other = tabulate(models.create("lambert", albedo=0.3), rgb.grid, progress=False)
    with pytest.raises(BrdftabError, match="already exists"):
        brdftab.save(other, path)
    assert np.array_equal(brdftab.open(path).values, rgb.values)
    # refused at the rename too (a store that appeared after the up-front check)
    tmp = tmp_path / "other.zarr"
    brdftab.save(other, tmp)
    with pytest.raises(BrdftabError, match="already exists"):
        _atomic._commit_folder(tmp, path, overwrite=False)
    assert np.array_equal(brdftab.open(path).values, rgb.values)
    brdftab.save(other, path, overwrite=True)
    assert np.array_equal(brdftab.open(path).values, other.values)
    assert sorted(os.listdir(tmp_path)) == ["other.zarr", "t.zarr"]


def test_stale_temporaries_of_dead_runs_are_removed(tmp_path, rgb):
    for name in (".t.zarr.partial-999999999", ".t.zarr.partial-999999998o"):
        (tmp_path / name / "brdf").mkdir(parents=True)
        (tmp_path / name / "zarr.json").write_text("{}")
    brdftab.save(rgb, tmp_path / "t.zarr")
    assert sorted(os.listdir(tmp_path)) == ["t.zarr"]


def test_store_targets_are_folders_and_other_targets_are_not(tmp_path, rgb):
    (tmp_path / "plain.zarr").mkdir()
    (tmp_path / "plain.zarr" / "keep.txt").write_text("mine")
    with pytest.raises(BrdftabError, match="is a folder that is not a zarr store"):
        brdftab.save(rgb, tmp_path / "plain.zarr", overwrite=True)
    assert (tmp_path / "plain.zarr" / "keep.txt").read_text() == "mine"
    (tmp_path / "file.zarr").write_text("a file")
    with pytest.raises(BrdftabError, match="is a file; a .zarr output is a folder"):
        brdftab.save(rgb, tmp_path / "file.zarr", overwrite=True)
    brdftab.save(rgb, tmp_path / "t.zarr")
    with pytest.raises(BrdftabError, match="is a folder, not a file"):
        brdftab.save(rgb, tmp_path / "t.zarr", format="netcdf", overwrite=True)
    (tmp_path / "d.nc").mkdir()
    res = cli("convert", tmp_path / "t.zarr", tmp_path / "d.nc", "--overwrite")
    one_error(res.stderr, res.exit_code, "d.nc: is a folder, not a file")
    res = cli("convert", tmp_path / "t.zarr", tmp_path / "t.zarr", "--overwrite")
    one_error(res.stderr, res.exit_code, "which this run reads")
