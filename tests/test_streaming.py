"""Tables larger than the memory budget: tabulated and written block by block, read, evaluated
and checked without being loaded whole."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

import brdftab
from brdftab import pipeline
from brdftab.formats import netcdf as nc_mod
from brdftab.grids import RusinkiewiczGrid, SphericalGrid
from brdftab.spec import load_spec
from brdftab.table import blocks, memory_budget, parse_size

ROOT = Path(__file__).resolve().parents[1]

ANISO = """
[model]
name = "microfacet"
distribution = "ggx"
alpha_x = 0.2
alpha_y = 0.4
shadowing = "smith"
fresnel = "schlick"
f0 = 0.04
[grid]
type = "rusinkiewicz"
anisotropic = true
n_theta_h = 12
n_phi_h = 16
n_theta_d = 12
n_phi_d = 24
phi_d_fold = "{fold}"
[[output]]
path = "{name}"
dtype = "{dtype}"
"""


def _spec(tmp_path, name="t.nc", dtype="float32", fold="none"):
    path = tmp_path / "spec.toml"
    path.write_text(ANISO.format(name=name, dtype=dtype, fold=fold))
    return load_spec(path)


def _run(tmp_path, monkeypatch, budget, **kw):
    if budget is None:
        monkeypatch.delenv("BRDFTAB_MEMORY", raising=False)
    else:
        monkeypatch.setenv("BRDFTAB_MEMORY", budget)
    return pipeline.run(_spec(tmp_path, **kw), progress=False)


def _samples(path):
    with xr.open_dataset(path, mask_and_scale=False) as ds:
        return ds["brdf"].values, dict(ds.attrs), {k: ds[k].values for k in ds.variables if k != "brdf"}


# -- the pieces ------------------------------------------------------------------------------------

@pytest.mark.parametrize("shape, items", [((7, 5, 3), 16), ((7, 5, 3), 1000), ((4, 9, 6, 2), 7), ((3,), 2)])
def test_blocks_cover_every_element_once_within_the_size(shape, items):
    seen = np.zeros(shape, int)
    for key in blocks(shape, items):
        block = seen[key]
        assert block.size <= max(items, int(np.prod(shape[len(key):])))
        seen[key] += 1
    assert np.all(seen == 1)


def test_blocks_align_to_storage_chunks():
    keys = list(blocks((10, 8, 4), 4 * 5, align=(1, 2, 4)))  # 5 rows of axis 1 fit; chunks of 2 rows
    assert len(keys) == 20 and all(k[1].stop - k[1].start == 4 for k in keys)
    assert [len(list(blocks((10, 8, 4), 4 * 5))), len(list(blocks((10, 8, 4), 4 * 5, align=(1, 3, 4))))] == [20, 30]


@pytest.mark.parametrize("grid", [RusinkiewiczGrid(5, 6, 7, 8), RusinkiewiczGrid(6, 5, 9),
                                  SphericalGrid(np.radians([30, 40, 50]), np.radians([0, 90]), np.radians([-30, 0, 30]),
                                                np.radians([-20, 0, 20]), relative_to="specular")])
def test_a_block_of_a_grid_has_the_nodes_of_the_whole_bit_for_bit(grid):
    wi, wo = grid.directions()
    wi, wo = wi.reshape(grid.shape + (3,)), wo.reshape(grid.shape + (3,))
    for key in [(slice(1, 3),), (slice(2, 3), slice(1, 2)), (slice(0, 1), slice(0, 2), slice(1, 3))]:
        sub = grid.block(key)
        a, b = sub.directions()
        assert np.array_equal(a, wi[key].reshape(-1, 3)) and np.array_equal(b, wo[key].reshape(-1, 3))
        ai, bi = np.empty_like(a), np.empty_like(b)
        sub.directions_into(0, sub.size, ai, bi)
        assert np.array_equal(ai, a) and np.array_equal(bi, b)


def test_memory_budget_setting(monkeypatch):
    monkeypatch.setenv("BRDFTAB_MEMORY", "512M")
    assert memory_budget() == 512 << 20
    monkeypatch.delenv("BRDFTAB_MEMORY")
    assert memory_budget() == 1 << 30
    assert parse_size("1.5GB") == 1_500_000_000 and parse_size("2GiB") == 2 << 30
    for bad in ("12X", "", "-1G", "100"):
        with pytest.raises(brdftab.errors.ParameterError):
            parse_size(bad)


# -- tabulate: streamed under a small budget, the same file as in memory --------------------------

@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_a_tiny_budget_streams_the_same_table_as_one_array(tmp_path, monkeypatch, dtype):
    writes = []
    orig = nc_mod.NetcdfStream.write
    monkeypatch.setattr(nc_mod.NetcdfStream, "write", lambda self, key, block: (writes.append(key),
                                                                                orig(self, key, block))[1])
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    whole = _run(tmp_path / "a", monkeypatch, None, dtype=dtype)
    assert len(writes) == 1  # fits the default budget: tabulated in memory, written in one chunk
    assert whole.tables[0]._values is not None
    streamed = _run(tmp_path / "b", monkeypatch, "1M", dtype=dtype)
    assert len(writes) > 10  # many blocks
    assert streamed.tables[0]._values is None  # read back from its file, not held
    v1, a1, c1 = _samples(whole.written[0])
    v2, a2, c2 = _samples(streamed.written[0])
    assert v1.dtype == v2.dtype == np.dtype(dtype)
    assert np.array_equal(v1, v2)  # bit for bit
    for key in ("created", "history", "validation_report"):
        a1.pop(key), a2.pop(key)
    assert a1 == a2
    assert c1.keys() == c2.keys()
    # the albedo curve the checks stored: interpolated from scratch disk, window by window
    np.testing.assert_allclose(c2["albedo"], c1["albedo"], rtol=1e-9)
    r1, r2 = whole.reports[0], streamed.reports[0]
    assert [(o.name, o.status) for o in r1.outcomes] == [(o.name, o.status) for o in r2.outcomes]
    for o1, o2 in zip(r1.outcomes, r2.outcomes):
        if isinstance(o1.figure, float):
            assert o2.figure == pytest.approx(o1.figure, rel=1e-9, abs=1e-15), o1.name
    assert not list(tmp_path.rglob(".*partial*"))


@pytest.mark.parametrize("factor, dtype, check", [(3.0, "float64", "energy"), (2e40, "float32", "finite")])
def test_a_streamed_table_that_fails_its_checks_leaves_nothing(tmp_path, factor, dtype, check):
    spec = tmp_path / "bad.toml"
    spec.write_text(f'[model]\nname = "scale"\nfactor = {factor}\n[model.term]\nname = "lambert"\nalbedo = 0.5\n'
                    '[grid]\ntype = "rusinkiewicz"\nn_theta_h = 32\nn_theta_d = 32\nn_phi_d = 64\n'
                    f'[[output]]\npath = "bad.nc"\ndtype = "{dtype}"\n')
    env = dict(os.environ, BRDFTAB_MEMORY="1M", PYTHONPATH=str(ROOT))
    r = subprocess.run([sys.executable, "-m", "brdftab", "tabulate", str(spec)], capture_output=True, text=True,
                       env=env)
    assert r.returncode == 1, r.stderr
    error = [line for line in r.stderr.splitlines() if line.startswith("brdftab: error:")]
    assert len(error) == 1 and "refusing to export" in error[0] and f"{check}:" in error[0], r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.toml"]


def test_a_run_over_budget_that_cannot_stream_says_so_in_one_line(tmp_path):
    spec = tmp_path / "m.toml"
    spec.write_text('[model]\nname = "lambert"\nalbedo = 0.5\n[grid]\ntype = "merl"\n[[output]]\npath = "m.binary"\n')
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    r = subprocess.run([sys.executable, "-m", "brdftab", "tabulate", str(spec), "--memory", "64M"],
                       capture_output=True, text=True, env=env)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("brdftab: error:")
    assert "budget of 0.0625 GiB" in lines[0] and "m.binary" in lines[0] and "--memory" in lines[0]
    assert "GiB of memory" in lines[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.toml"]


# -- reading and checking a table over the budget ----------------------------------------------------

def test_validate_over_budget_reads_blocks_and_agrees_with_the_loaded_table(tmp_path, monkeypatch):
    monkeypatch.delenv("BRDFTAB_MEMORY", raising=False)
    path = _run(tmp_path, monkeypatch, None, fold="none").written[0]  # φd pairs: node reciprocity
    loaded = brdftab.open(path)
    loaded.values  # noqa: B018 (loaded whole)
    want = brdftab.checks.run_checks(loaded)
    monkeypatch.setenv("BRDFTAB_MEMORY", "1M")
    lazy = brdftab.open(path)
    got = brdftab.checks.run_checks(lazy)
    assert lazy._values is None and lazy._slab_mode()  # never loaded: blocks and scratch windows
    assert [(o.name, o.status) for o in got.outcomes] == [(o.name, o.status) for o in want.outcomes]
    for a, b in zip(want.outcomes, got.outcomes):
        assert a.detail.split(" at ")[0] == b.detail.split(" at ")[0] or isinstance(a.figure, float), a.name
        if isinstance(a.figure, float):
            assert b.figure == pytest.approx(a.figure, rel=1e-9, abs=1e-15), a.name
    recip = got.get("reciprocity")
    assert recip.data["mode"] == "nodes" and recip.data["compared"] == want.get("reciprocity").data["compared"]
    lazy.close()


def test_out_of_core_interpolation_equals_the_loaded_table(tmp_path, monkeypatch):
    path = _run(tmp_path, monkeypatch, None, dtype="float64").written[0]
    rng = np.random.default_rng(3)
    wi = brdftab.geometry.sph_to_vec(np.arccos(rng.uniform(0.02, 1, 4000)), rng.uniform(0, 6.3, 4000))
    wo = brdftab.geometry.sph_to_vec(np.arccos(rng.uniform(0.02, 1, 4000)), rng.uniform(0, 6.3, 4000))
    with brdftab.brdf.numpy_reference():
        want = brdftab.open(path).eval(wi, wo)
    monkeypatch.setenv("BRDFTAB_MEMORY", "1M")
    t = brdftab.open(path)
    assert t._slab_mode()
    got = t.eval(wi, wo)
    assert t._values is None and t._out_of_core().window < len(t.grid.axes[0])
    assert getattr(t._out_of_core(), "_plan", None) is not None  # the compiled kernel, window by window
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=0)
    with brdftab.brdf.numpy_reference():  # and numpy's windows
        np.testing.assert_allclose(t.eval(wi, wo), want, rtol=1e-12, atol=0)
    t.close()


def test_the_table_kernel_compiles_one_signature_per_value_type(tmp_path, monkeypatch):
    """In memory and out of core, with read-only directions too, the table kernel is called with
    the same argument types: numba compiles it (about 30 s) once per value type, not again for
    read-only windows or pairs or an omitted offset (there were five signatures)."""
    from numba.core import types

    from brdftab._interp_kernels import table_eval

    path = _run(tmp_path, monkeypatch, None, dtype="float64").written[0]
    rng = np.random.default_rng(4)
    wi = brdftab.geometry.sph_to_vec(np.arccos(rng.uniform(0.02, 1, 500)), rng.uniform(0, 6.3, 500))
    wo = brdftab.geometry.sph_to_vec(np.arccos(rng.uniform(0.02, 1, 500)), rng.uniform(0, 6.3, 500))
    wi.flags.writeable = wo.flags.writeable = False
    in_memory = brdftab.open(path)
    want = in_memory.eval(wi, wo)
    monkeypatch.setenv("BRDFTAB_MEMORY", "1M")
    t = brdftab.open(path)
    assert t._slab_mode()
    np.testing.assert_allclose(t.eval(wi, wo), want, rtol=1e-12, atol=0)
    t.close()
    sigs = table_eval.compiled().signatures
    assert sigs
    for sig in sigs:  # (any test of this process may have added its own: none may differ so)
        assert not any(isinstance(a, types.Omitted) or (isinstance(a, types.Array) and not a.mutable)
                       for a in sig), sig
    values = {sig[10].dtype for sig in sigs}
    assert len(sigs) == len(values) <= 2


def test_the_memory_option_is_checked_in_one_line(tmp_path):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    r = subprocess.run([sys.executable, "-m", "brdftab", "validate", str(tmp_path / "x.nc"), "--memory", "lots"],
                       capture_output=True, text=True, env=env)
    assert r.returncode == 2 and r.stderr.strip().splitlines() == [
        "brdftab: error: --memory: expected a size such as 512M, 2G or 1.5GB, got 'lots'"]


@pytest.mark.parametrize("budget", [200_000, 1 << 20, 40 << 20])  # windows of 1, 8 and all rows
def test_scratch_ghosts_equal_the_whole_table_ghosts_for_any_window(tmp_path, monkeypatch, budget):
    from brdftab.table import OutOfCore, _horizon_ghosts

    monkeypatch.setenv("BRDFTAB_MEMORY", "1G")
    t = brdftab.open(_run(tmp_path, monkeypatch, None, dtype="float32").written[0])
    vals, ok = _horizon_ghosts(t.values, t.grid.node_above_horizon(), t.grid)
    assert not np.array_equal(ok, t.grid.node_above_horizon())  # ghosts along θd and θh were made
    ooc = OutOfCore(brdftab.open(t.ds.encoding["source"]), budget)
    got_vals, got_ok = ooc._rows(0, t.shape[0])
    assert np.array_equal(got_ok, ok) and np.array_equal(got_vals, vals)
    # a float32 table's interpolation data is float32, on scratch as in memory (half the writes)
    assert got_vals.dtype == vals.dtype == np.float32
    ooc.close()


def test_a_streamed_zarr_store_holds_the_same_table(tmp_path, monkeypatch):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    whole = _run(tmp_path / "a", monkeypatch, None, name="t.nc")
    streamed = _run(tmp_path / "b", monkeypatch, "1M", name="t.zarr")
    a, b = brdftab.open(whole.written[0]), brdftab.open(streamed.written[0])
    assert np.array_equal(a.values, b.values)
    assert b.ds.attrs["validation_passed"] == 1 and "albedo" in b.ds
    np.testing.assert_allclose(b.ds["albedo"].values, a.ds["albedo"].values, rtol=1e-9)


def test_gonio_reciprocity_over_budget_is_skipped_saying_so(tmp_path, monkeypatch):
    from brdftab.models import create
    from brdftab.table import tabulate

    deg = np.radians
    grid = SphericalGrid(deg([10, 30, 50]), deg([0, 90, 180, 270]), deg([10, 30, 50]), deg([0, 90, 180, 270]))
    path = tmp_path / "g.nc"
    brdftab.save(tabulate(create("lambert", albedo=0.5), grid, progress=False), path)
    loaded = brdftab.checks.run_checks(brdftab.open(path), only=["reciprocity"]).get("reciprocity")
    assert loaded.status == "pass" and loaded.data["mode"] == "nodes"
    monkeypatch.setenv("BRDFTAB_MEMORY", "1M")
    for where in ("brdftab.checks._tables.over_budget", "brdftab.checks.reciprocity.over_budget"):
        monkeypatch.setattr(where, lambda t: True)  # (a table this small never is)
    out = brdftab.checks.run_checks(brdftab.open(path), only=["reciprocity"]).get("reciprocity")
    assert out.status == "skip" and "over the memory budget" in out.detail and "--memory" in out.detail


def test_node_pairs_of_slabs_larger_than_a_block_share_of_the_budget(tmp_path, monkeypatch):
    """A slab of the first axis over a 64th of the budget is read as one block; one over an
    eighth of it cannot be compared and the check says so (a skip, never an internal error)."""
    path = _run(tmp_path, monkeypatch, None, fold="none").written[0]
    want = brdftab.checks.run_checks(brdftab.open(path), only=["reciprocity", "isotropy"])
    monkeypatch.setenv("BRDFTAB_MEMORY", "1M")
    t = brdftab.open(path)
    row = t.nbytes // t.shape[0]
    for budget, fits in ((row * 16, True), (row * 4, False)):  # rows over a 64th of the budget
        monkeypatch.setattr("brdftab.table.memory_budget", lambda b=budget: b)
        monkeypatch.setattr("brdftab.checks._tables.memory_budget", lambda b=budget: b, raising=False)
        got = brdftab.checks.run_checks(brdftab.open(path), only=["reciprocity", "isotropy"])
        for name in ("reciprocity", "isotropy"):
            if fits:
                assert got.get(name).figure == pytest.approx(want.get(name).figure, rel=1e-9), name
            else:
                assert got.get(name).status == "skip" and "over the memory budget" in got.get(name).detail


def test_validating_a_spec_over_budget_judges_the_streamed_table_and_writes_nothing(tmp_path, monkeypatch):
    spec = _spec(tmp_path, fold="none")
    monkeypatch.delenv("BRDFTAB_MEMORY", raising=False)
    (want,) = pipeline.validate(spec)
    monkeypatch.setenv("BRDFTAB_MEMORY", "1M")
    (got,) = pipeline.validate(spec)
    assert [(o.name, o.status) for o in got.outcomes] == [(o.name, o.status) for o in want.outcomes]
    for a, b in zip(want.outcomes, got.outcomes):
        if isinstance(a.figure, float):
            assert b.figure == pytest.approx(a.figure, rel=1e-9, abs=1e-15), a.name
    assert sorted(p.name for p in tmp_path.iterdir()) == ["spec.toml"]


def test_convert_copies_a_table_over_budget_block_by_block(tmp_path, monkeypatch):
    """convert of a table over the memory budget onto its own grid never holds it whole: the
    reader's blocks go to the writer one by one (cast to float32 there); the output holds the
    input's samples cast to float32, is judged as stored and stamped (its report, the input's,
    where it came from); a failed check leaves nothing. (zarr's block writer keeps the same
    protocol, tested above.)"""
    from brdftab.convert import convert
    from brdftab.errors import ValidationError

    monkeypatch.delenv("BRDFTAB_MEMORY", raising=False)
    spec = _spec(tmp_path)
    src = tmp_path / "src.nc"
    brdftab.save(brdftab.tabulate(spec.model, spec.grid, progress=False), src)
    monkeypatch.setenv("BRDFTAB_MEMORY", "3M")  # just below what the 55 296 samples take in memory
    assert brdftab.open(src).over_budget
    loads = []
    monkeypatch.setattr(brdftab.table.Table, "values", property(lambda self: loads.append(1) or self._values))
    writes = []
    orig = nc_mod.NetcdfStream.write
    monkeypatch.setattr(nc_mod.NetcdfStream, "write", lambda self, key, block: (writes.append(key),
                                                                                orig(self, key, block))[1])
    # (the integrals of the energy, albedo and tabulation checks over budget are tested above;
    # off here, they would be most of the run)
    quiet = {name: {"level": "off"} for name in ("energy", "albedo", "tabulation")}
    result = convert(src, tmp_path / "copy.nc", options={"dtype": "float32"}, progress=False, checks=quiet)
    assert loads == [] and len(writes) > 1  # nothing read the samples whole; several blocks
    with xr.open_dataset(src) as a, xr.open_dataset(tmp_path / "copy.nc") as b:
        assert b["brdf"].dtype == np.float32
        assert np.array_equal(a["brdf"].values.astype(np.float32), b["brdf"].values)
        assert b.attrs["validation_passed"] == 1 and b.attrs["converted_from"] == src.name
        assert b.attrs["input_validation_passed"] == 1
    assert result.report.passed and not result.resampled
    # a table whose samples fail a check (energy: albedo 1.5): refused, nothing is left
    from brdftab.models import create

    bright = tmp_path / "bright.nc"
    brdftab.save(brdftab.tabulate(create("scale", factor=3.0, term=create("lambert", albedo=0.5)),
                                  RusinkiewiczGrid(32, 32, 64), progress=False), bright)
    assert brdftab.open(bright).over_budget
    with pytest.raises(ValidationError, match="energy"):
        convert(bright, tmp_path / "bad.nc", options={"dtype": "float32"}, progress=False)
    assert not (tmp_path / "bad.nc").exists() and not list(tmp_path.rglob("*partial*"))


def test_rows_read_once_are_held_raw_on_scratch_for_the_later_passes(tmp_path, monkeypatch):
    """A table over the budget decodes its file once: the rows a first pass reads are kept as
    stored in an uncompressed scratch file, and later passes (the other checks, the
    interpolation data) get the same samples, bit for bit, without reading the file again."""
    path = _run(tmp_path, monkeypatch, None, dtype="float32").written[0]
    monkeypatch.setenv("BRDFTAB_MEMORY", "1M")
    t = brdftab.open(path)
    assert t.over_budget
    reads = []
    real = t._read
    monkeypatch.setattr(t, "_read", lambda var: reads.append(1) or real(var))
    first = [(k, np.array(v)) for k, v in t.iter_blocks(1 << 16)]
    n = len(reads)
    assert n == len(first) > 1 and t._raw.rows == t.shape[0]
    again = list(t.iter_blocks(1 << 16))
    assert len(reads) == n  # from the scratch copy
    assert all(ka == kb and a.dtype == b.dtype and np.array_equal(a, b) for (ka, a), (kb, b) in zip(first, again))
    monkeypatch.delenv("BRDFTAB_MEMORY")
    fresh = brdftab.open(path)  # and what the file holds
    assert np.array_equal(np.concatenate([b for _, b in again]), fresh.values)
    fresh.close()
    t.close()
