"""``brdftab convert IN OUT``: any readable format to any writable one, copied or resampled.

Tables are made in pytest's temporary folders through the Python API; the command runs
in-process (``CliRunner``) and, for exit codes and stderr, as a subprocess.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
from _tables import lambert_table
from click.testing import CliRunner

import brdftab
from brdftab import formats
from brdftab.brdf import BRDF
from brdftab.cli import main
from brdftab.grids import RusinkiewiczGrid, merl_grid
from brdftab.table import tabulate

SPECS = Path(__file__).resolve().parent.parent / "specs"
GOLD = brdftab.models.create("microfacet", distribution="ggx", alpha=0.2, fresnel="conductor",
                             n=[0.143119, 0.374957, 1.44248], k=[3.98316, 2.38572, 1.60322])
RESAMPLED = re.compile(r"rms relative ([0-9.e+-]+), max relative ([0-9.e+-]+) \((\d+) check points")


def _cli(*args):
    result = CliRunner().invoke(main, [str(a) for a in args])
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    return result


def _run(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "brdftab", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd, timeout=300)


def _one_error(stderr, code, *expected, exit_code=2):
    assert code == exit_code, f"exit code {code}, stderr {stderr!r}"
    lines = stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("brdftab: error: "), stderr
    assert "Traceback" not in stderr
    for text in expected:
        assert text in lines[0], f"{text!r} missing from {lines[0]!r}"
    return lines[0]


def _partials(folder: Path):
    return [p.name for p in folder.iterdir() if ".partial-" in p.name or p.name.endswith(".lock")]


@pytest.fixture(scope="module")
def rusi_nc(tmp_path_factory) -> Path:
    """GGX gold on a coarse isotropic Rusinkiewicz grid (not the MERL grid)."""
    path = tmp_path_factory.mktemp("src") / "gold-rusi.nc"
    brdftab.save(GOLD, path, grid=RusinkiewiczGrid(30, 30, 60))
    return path


@pytest.fixture(scope="module")
def merl_nc(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("src") / "gold-merl.nc"
    brdftab.save(GOLD, path, grid=merl_grid(), dtype="float32")
    return path


# --------------------------------------------------------------------------------------------
# round trips

def test_same_grid_is_copied_value_identical(rusi_nc, tmp_path):
    out = tmp_path / "copy.nc"
    result = _cli("convert", rusi_nc, out)
    assert result.exit_code == 0, result.stderr
    assert "copied" in result.stdout and "resampled" not in result.stdout
    with xr.open_dataset(rusi_nc) as a, xr.open_dataset(out) as b:
        assert a["brdf"].dtype == b["brdf"].dtype
        np.testing.assert_array_equal(a["brdf"].values, b["brdf"].values)
        for name in a.coords:
            np.testing.assert_array_equal(a[name].values, b[name].values)
        fresh = ("validation_", "albedo_", "converted_from", "history")  # the conversion's own report and step
        keep = lambda d: {k: v for k, v in d.items() if not k.startswith(fresh)}  # noqa: E731
        assert keep(a.attrs) == keep(b.attrs)  # provenance carried over unchanged
        assert b.attrs["history"].startswith(a.attrs["history"] + "\n")  # ... with the conversion appended
        assert "validation_report" in b.attrs
    assert sorted(p.name for p in tmp_path.iterdir()) == ["copy.nc"]


def test_rusinkiewicz_to_merl_reports_resampling(rusi_nc, tmp_path):
    out = tmp_path / "merl.nc"
    result = _cli("convert", rusi_nc, out, "--grid", "merl")
    assert result.exit_code == 0, result.stderr
    assert "resampled" in result.stdout and "copied" not in result.stdout
    m = RESAMPLED.search(result.stdout)
    assert m, result.stdout
    rms, max_rel, points = float(m.group(1)), float(m.group(2)), int(m.group(3))
    assert 0 < rms <= max_rel < 0.5  # a 30 x 30 x 60 table resampled onto MERL's grid
    assert points >= 1000
    written = brdftab.open(out)
    assert written.grid.equals(merl_grid())
    # the written nodes hold the source table evaluated there (tabulated, not copied)
    source = brdftab.open(rusi_nc)
    wi, wo = merl_grid().directions(500_000, 500_200)
    np.testing.assert_allclose(written.values.reshape(-1, 3)[500_000:500_200], source.eval(wi, wo), rtol=1e-12)
    assert written.ds.attrs["converted_from"] == rusi_nc.name


def test_resampling_figures_as_json(rusi_nc, tmp_path):
    # so coarse a grid misrepresents the source beyond the bound: written only when allowed
    refused = _cli("convert", rusi_nc, tmp_path / "r.nc", "--grid", "{type = 'rusinkiewicz', n_theta_h = 20}")
    assert refused.exit_code == 1 and "misrepresents" in refused.stderr and not (tmp_path / "r.nc").exists()
    result = _cli("convert", rusi_nc, tmp_path / "r.nc", "--grid", "{type = 'rusinkiewicz', n_theta_h = 20}",
                  "--json", "--allow-invalid")
    assert result.exit_code == 0, result.stderr
    data = json.loads(result.stdout)
    assert data["resampled"] is True and data["format"] == "netcdf"
    assert data["target_grid"].startswith("rusinkiewicz theta_h[20]")
    d = data["difference"]
    assert 0 < d["rms_relative_difference"] <= d["max_relative_difference"] and d["check_points"] > 1000
    assert data["checks"]["passed"] is True


def test_same_grid_merl_netcdf_to_merl_binary_is_a_copy(merl_nc, tmp_path):
    out = tmp_path / "gold.binary"
    result = _cli("convert", merl_nc, out)
    assert result.exit_code == 0, result.stderr
    assert "copied" in result.stdout
    back = brdftab.open(out)
    np.testing.assert_allclose(back.values, brdftab.open(merl_nc).values, rtol=1e-6)


# --------------------------------------------------------------------------------------------
# every registered format, none named here

@pytest.fixture(scope="module")
def writable():
    return sorted(n for n, f in formats.available().items() if f.write is not None)


def test_convert_into_every_registered_format(merl_nc, tmp_path, writable):
    assert "netcdf" in writable
    for name in writable:
        fmt = formats.FORMATS[name]
        out = tmp_path / f"out-{name}{fmt.extensions[0]}"
        proc = _cli("convert", merl_nc, out, "--to", name)  # in process: twelve runs on the MERL grid
        assert "Traceback" not in proc.stderr
        if proc.exit_code == 0:
            assert (out.is_file() and out.stat().st_size > 0) or formats.is_store(out), name  # a file or a store
            assert proc.stdout.startswith(f"wrote {out}"), proc.stdout
            if fmt.read is not None:  # and back again, onto a grid brdftab writes
                back = tmp_path / f"back-{name}.nc"
                proc = _cli("convert", out, back, "--grid", "merl")
                assert proc.exit_code in (0, 1, 2), proc.stderr
                assert "Traceback" not in proc.stderr and "internal error" not in proc.stderr, proc.stderr
        else:
            _one_error(proc.stderr, proc.exit_code, exit_code=proc.exit_code)
            assert not out.exists()
        assert _partials(tmp_path) == []


def test_a_format_registered_later_works_without_changes(rusi_nc, tmp_path):
    written = []

    def write(table, path, scale=1.0):
        written.append(scale)
        (table.ds * 1).to_netcdf(path, engine="netcdf4")

    from brdftab.params import Param

    fmt = formats.FileFormat(name="plugin-test", extensions=(".plug",), description="test", read=None, write=write,
                             params=(Param("scale", "float", "A scale factor.", default=1.0, minimum=0.0),))
    formats.register(fmt)
    try:
        result = _cli("convert", rusi_nc, tmp_path / "x.plug", "-o", "scale=2.5")
        assert result.exit_code == 0, result.stderr
        assert written == [2.5] and "copied" in result.stdout
        result = _cli("convert", rusi_nc, tmp_path / "y.dat", "--to", "plugin-test", "--grid", "merl")
        assert result.exit_code == 0, result.stderr
        assert "resampled" in result.stdout and RESAMPLED.search(result.stdout)
    finally:
        formats.FORMATS.pop("plugin-test", None)


# --------------------------------------------------------------------------------------------
# options and grids from the command line

def test_format_options(rusi_nc, tmp_path):
    result = _cli("convert", rusi_nc, tmp_path / "f32.nc", "-o", "dtype=float32", "--option", "complevel=9")
    assert result.exit_code == 0, result.stderr
    with xr.open_dataset(tmp_path / "f32.nc") as ds:
        assert ds["brdf"].dtype == np.float32


@pytest.mark.parametrize("args, expected", [
    (["-o", "dtype=float16"], ["dtype", "float16"]),
    (["-o", "compression=4"], ["compression", "unknown option"]),
    (["-o", "dtype"], ["--option", "KEY=VALUE"]),
    (["-o", "dtype=float32", "-o", "dtype=float64"], ["dtype", "twice"]),
    (["--to", "netcdff"], ["netcdff", "did you mean 'netcdf'"]),
    (["--grid", "merll"], ["--grid", "merll"]),
    (["--grid", "{type = 'rusinkiewicz', n_theta_h = 0}"], ["--grid", "n_theta_h"]),
    (["--grid", "{type = "], ["--grid"]),
    (["--grid", "merl", "--grid-file", "x.toml"], ["--grid", "--grid-file"]),
    (["--grid-file", "no-such.toml"], ["no-such.toml"]),
])
def test_bad_options_are_one_line(rusi_nc, tmp_path, args, expected):
    out = tmp_path / "x.nc"
    result = _cli("convert", rusi_nc, out, *args)
    _one_error(result.stderr, result.exit_code, *expected)
    assert list(tmp_path.iterdir()) == []


def test_grid_from_a_grid_file_or_a_spec(rusi_nc, tmp_path):
    grid_toml = tmp_path / "grid.toml"
    grid_toml.write_text('[grid]\ntype = "rusinkiewicz"\nn_theta_h = 10\nn_theta_d = 10\nn_phi_d = 20\n')
    # so coarse a grid misrepresents the source (refused by default): allowed here, the grid is the point
    result = _cli("convert", rusi_nc, tmp_path / "g.nc", "--grid-file", grid_toml, "--allow-invalid")
    assert result.exit_code == 0, result.stderr
    assert brdftab.open(tmp_path / "g.nc").grid.shape == (10, 10, 20)
    result = _cli("convert", rusi_nc, tmp_path / "s.nc", "--grid-file", SPECS / "ggx-gold.toml")
    assert result.exit_code == 0, result.stderr
    assert brdftab.open(tmp_path / "s.nc").grid.equals(merl_grid())
    (tmp_path / "nogrid.toml").write_text("[model]\nname = 'lambert'\n")
    result = _cli("convert", rusi_nc, tmp_path / "n.nc", "--grid-file", tmp_path / "nogrid.toml")
    _one_error(result.stderr, result.exit_code, "nogrid.toml", "[grid]")


def test_errors_inside_the_run_keep_their_one_line(tmp_path):
    src = lambert_table(tmp_path)
    p = subprocess.run([sys.executable, "-m", "brdftab", "convert", str(src), str(tmp_path / "o.bsdf"),
                        "-o", "ndf=model"], capture_output=True, text=True)
    assert p.returncode == 2 and p.stderr.count("\n") == 1 and "ndf" in p.stderr and "internal" not in p.stderr
    assert not (tmp_path / "o.bsdf").exists()
    p = subprocess.run([sys.executable, "-m", "brdftab", "convert", str(src), str(tmp_path / "o.bsdf"),
                        "--grid", "merl"], capture_output=True, text=True)
    assert p.returncode == 2 and "--grid is not used" in p.stderr


# --------------------------------------------------------------------------------------------
# refusals: the input itself, existing files, invalid input, lost symmetries

def test_output_cannot_be_the_input(rusi_nc, tmp_path):
    before = rusi_nc.read_bytes()
    for extra in ([], ["--overwrite"]):
        result = _cli("convert", rusi_nc, rusi_nc, *extra)
        _one_error(result.stderr, result.exit_code, rusi_nc.name, "input table")
    link = tmp_path / "link.nc"
    link.symlink_to(rusi_nc)
    result = _cli("convert", rusi_nc, link, "--overwrite", "--grid", "merl")
    _one_error(result.stderr, result.exit_code, "link.nc", "input table")
    assert rusi_nc.read_bytes() == before and link.is_symlink()


def test_existing_output_needs_overwrite(rusi_nc, tmp_path):
    out = tmp_path / "x.nc"
    out.write_bytes(b"keep")
    proc = _run("convert", rusi_nc, out)
    _one_error(proc.stderr, proc.returncode, "x.nc", "--overwrite")
    assert out.read_bytes() == b"keep"
    assert _cli("convert", rusi_nc, out, "--overwrite").exit_code == 0
    assert brdftab.open(out).grid.shape == (30, 30, 60)


class _HalfNaN(BRDF):
    name = "half-nan"

    def _eval(self, wi, wo, lam, n):
        f = np.full((wi.shape[0], n), 0.2)
        f[wi[:, 0] > 0.3] = np.nan
        return f


def test_invalid_input_is_refused_with_exit_code_1(tmp_path):
    bad = tmp_path / "bad.nc"
    brdftab.save(tabulate(_HalfNaN(), RusinkiewiczGrid(6, 6, 8), progress=False), bad)
    out = tmp_path / "out.nc"
    proc = _run("convert", bad, out)
    line = _one_error(proc.stderr, proc.returncode, "bad.nc", "finite", "NaN", "figure", "--allow-invalid",
                      exit_code=1)
    assert re.search(r"figure \d+", line)
    assert not out.exists() and _partials(tmp_path) == []
    proc = _run("convert", bad, out, "--allow-invalid")
    assert proc.returncode == 0, proc.stderr
    assert out.exists() and "warning" in proc.stderr and "finite" in proc.stderr
    # a check can be turned down, as for brdftab validate
    proc = _run("convert", bad, tmp_path / "lenient.nc", "--level", "finite=warn")
    assert proc.returncode == 0, proc.stderr


def test_anisotropic_to_merl_needs_fold(tmp_path):
    aniso = brdftab.models.create("microfacet", alpha_x=0.2, alpha_y=0.5)
    src = tmp_path / "aniso.nc"
    brdftab.save(aniso, src, grid=RusinkiewiczGrid(8, 8, 12, phi_h=12, phi_d_fold="reciprocity"))
    for target, extra in ((tmp_path / "a.nc", ["--grid", "merl"]), (tmp_path / "a.binary", [])):
        result = _cli("convert", src, target, *extra)
        _one_error(result.stderr, result.exit_code, "anisotropic", "--fold")
        assert not target.exists()
    small = tmp_path / "iso.nc"
    result = _cli("convert", src, small, "--grid", "{type = 'rusinkiewicz', n_theta_h = 8, n_theta_d = 8, "
                  "n_phi_d = 12}", "--fold")
    assert result.exit_code == 0, result.stderr
    assert "folded" in result.stdout and "anisotropic" in result.stdout
    table = brdftab.open(small)
    assert table.isotropic
    # the written value is the mean over rotations about the normal (12 phi_h nodes: exact)
    source = brdftab.open(src)
    wi, wo = table.grid.directions(100, 101)
    rots = [np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
            for a in 2 * np.pi * np.arange(12) / 12]
    expected = np.mean([source.eval(wi @ r.T, wo @ r.T) for r in rots], axis=0)
    np.testing.assert_allclose(table.values.reshape(-1, 1)[100], expected[0], rtol=1e-9)


def test_grid_outside_the_source_domain_is_refused(tmp_path):
    src = tmp_path / "gonio.nc"
    grid = brdftab.grids.grid_from_config({"type": "spherical", "theta_i_deg": [30], "phi_i_deg": [0],
                                           "theta_o_deg": [0, 20, 40, 60], "phi_o_deg": [0, 90, 180, 270]})
    brdftab.save(brdftab.models.create("lambert", albedo=0.5), src, grid=grid)
    result = _cli("convert", src, tmp_path / "m.nc", "--grid", "merl")
    _one_error(result.stderr, result.exit_code, "outside the source's domain", "--allow-invalid")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["gonio.nc"]


def test_progress_covers_the_write(rusi_nc, tmp_path, monkeypatch):
    from brdftab import table as table_module

    monkeypatch.setattr(table_module, "PROGRESS_DELAY", 0.0)
    result = _cli("convert", rusi_nc, tmp_path / "p.nc", "--grid", "merl", "--progress")
    assert result.exit_code == 0, result.stderr
    assert "tabulating" in result.stderr and "writing p.nc" in result.stderr


def test_allow_invalid_conversion_keeps_the_report(tmp_path):
    import json

    import xarray as xr

    from brdftab.grids import RusinkiewiczGrid
    from brdftab.table import make_table

    g = RusinkiewiczGrid(6, 6, 6)
    values = np.full(g.shape + (1,), 0.1)
    values[1, 1, 1, 0] = np.nan
    from brdftab.channels import Layout

    bad = make_table(values, g, Layout())
    src = tmp_path / "bad.nc"
    brdftab.save(bad, src)
    from click.testing import CliRunner

    from brdftab.cli import main

    r = CliRunner().invoke(main, ["convert", str(src), str(tmp_path / "out.nc")])
    assert r.exit_code == 1 and not (tmp_path / "out.nc").exists()
    r = CliRunner().invoke(main, ["convert", str(src), str(tmp_path / "out.nc"), "--allow-invalid"])
    assert r.exit_code == 0, r.output
    with xr.open_dataset(tmp_path / "out.nc") as ds:
        rep = json.loads(ds.attrs["validation_report"])
        assert ds.attrs["validation_passed"] == 0
    assert any(c["name"] == "finite" and c["status"] == "fail" for c in rep["checks"])


# -- measured data and what a conversion writes -------------------------------------------------

@pytest.fixture(scope="module")
def measured(tmp_path_factory):
    from _measured import measured_bsdf

    path = tmp_path_factory.mktemp("measured") / "paint.bsdf"
    measured_bsdf(path)
    return path


def test_measured_bsdf_converts_with_its_warnings(measured, tmp_path):
    out = tmp_path / "paint.nc"
    result = _cli("convert", measured, out)           # no --grid: one rule for every input
    assert result.exit_code == 0, result.stderr
    assert "input paint.bsdf: WARN reciprocity" in result.stderr and "WARN non-negative" in result.stderr
    with xr.open_dataset(out) as ds:
        attrs = dict(ds.attrs)
    assert attrs["validation_passed"] == 1 and attrs["input_validation_passed"] == 1
    assert "reciprocity" in attrs["input_validation_summary"] and attrs["origin"] == "unknown"
    assert attrs["reciprocal"] == 0 and attrs["phi_d_fold"] == "none"
    rep = json.loads(attrs["input_validation_report"])
    assert {c["name"]: c["status"] for c in rep["checks"]}["reciprocity"] == "warn"
    # the default grid reproduces the file: median relative error of f within 3 % at θ <= 80°
    m = re.search(r"median relative error of f at θi, θo ≤ 80°: ([0-9.e+-]+)", result.stdout)
    assert m and float(m.group(1)) < 0.03
    back, src = brdftab.open(out), brdftab.open(measured)
    rng = np.random.default_rng(2)
    mu = rng.uniform(np.cos(np.radians(80)), 1, (2, 4000))
    wi = brdftab.geometry.sph_to_vec(np.arccos(mu[0]), rng.uniform(0, 6.28, 4000))
    wo = brdftab.geometry.sph_to_vec(np.arccos(mu[1]), rng.uniform(0, 6.28, 4000))
    a, b = back.eval(wi, wo), src.eval(wi, wo)
    ok = b > 1e-3
    assert np.median(np.abs(a[ok] - b[ok]) / b[ok]) < 0.03


def test_measured_bsdf_to_merl_needs_fold_and_to_exr_keeps_the_full_turn(measured, tmp_path):
    result = _cli("convert", measured, tmp_path / "paint.binary")
    _one_error(result.stderr.splitlines()[-1], result.exit_code, "not reciprocal", "--fold")
    assert not (tmp_path / "paint.binary").exists()
    result = _cli("convert", measured, tmp_path / "paint.binary", "--fold")
    assert result.exit_code == 0, result.stderr
    assert "folded" in result.stdout
    result = _cli("convert", measured, tmp_path / "paint.exr")
    assert result.exit_code == 0, result.stderr
    exr = brdftab.open(tmp_path / "paint.exr")
    assert exr.grid.phi_d_fold == "none" and exr.origin == "unknown"


def test_output_that_fails_a_check_is_refused_unless_allowed(rusi_nc, tmp_path):
    out = tmp_path / "strict.nc"
    strict = ["--grid", "{type = 'rusinkiewicz', n_theta_h = 8, n_theta_d = 8, n_phi_d = 16}",
              "--level", "tabulation=error", "--set", "tabulation.rms=1e-9"]
    proc = _run("convert", rusi_nc, out, *strict)
    _one_error(proc.stderr, proc.returncode, "refusing to write", "tabulation", "--allow-invalid", exit_code=1)
    assert not out.exists() and _partials(tmp_path) == []
    proc = _run("convert", rusi_nc, out, *strict, "--allow-invalid")
    assert proc.returncode == 0, proc.stderr
    with xr.open_dataset(out) as ds:
        assert ds.attrs["validation_passed"] == 0
        rep = json.loads(ds.attrs["validation_report"])
    assert {c["name"]: c["status"] for c in rep["checks"]}["tabulation"] == "fail"


def test_lambert_round_trip_through_bsdf_writes_what_it_checks(tmp_path):
    src = tmp_path / "white.nc"
    brdftab.save(brdftab.models.create("lambert", albedo=0.99), src, grid="merl")
    assert _cli("convert", src, tmp_path / "white.bsdf").exit_code == 0
    result = _cli("convert", tmp_path / "white.bsdf", tmp_path / "back.nc")
    assert result.exit_code == 0, result.stderr
    back = brdftab.open(tmp_path / "back.nc")
    assert back.ds.attrs["validation_passed"] == 1
    rep = json.loads(back.ds.attrs["validation_report"])
    energy = next(c for c in rep["checks"] if c["name"] == "energy")
    assert energy["figure"] <= 1.0            # it was 3.92 at 89°, stamped passed
    # f at grazing stays near the Lambertian's (it was +48 %)
    wi = brdftab.geometry.sph_to_vec(np.radians(30.0), 0.0)
    wo = brdftab.geometry.sph_to_vec(np.radians([80.0, 85.0, 88.0, 89.5]), np.pi)
    assert np.all(np.abs(back.eval(wi, wo)[:, 1] / (0.99 / np.pi) - 1) < 0.1)


def test_all_missing_merl_is_refused(tmp_path):
    g = merl_grid()
    path = tmp_path / "empty.binary"
    path.write_bytes(np.array(g.shape, dtype="<i4").tobytes() + np.full((3,) + g.shape, -1.0).tobytes())
    proc = _run("convert", path, tmp_path / "empty.nc")
    _one_error(proc.stderr, proc.returncode, "coverage", exit_code=1)
    assert not (tmp_path / "empty.nc").exists()


# --------------------------------------------------------------------------------------------
# Provenance: a converted table names its source file and checksum, and keeps every step

def test_a_convert_of_a_convert_records_each_source_and_keeps_every_step(tmp_path):
    import hashlib

    spec = tmp_path / "s.toml"
    spec.write_text('[model]\nname = "lambert"\nalbedo = 0.5\n[grid]\ntype = "rusinkiewicz"\nn_theta_h = 6\n'
                    'n_theta_d = 6\nn_phi_d = 12\n[[output]]\npath = "a.nc"\n')
    assert _cli("tabulate", spec, "--no-progress").exit_code == 0
    coarse = '{type = "rusinkiewicz", n_theta_h = 3, n_theta_d = 3, n_phi_d = 6}'
    r = _cli("convert", tmp_path / "a.nc", tmp_path / "b.nc", "--grid", coarse)  # resampled
    assert r.exit_code == 0, r.stderr
    r = _cli("convert", tmp_path / "b.nc", tmp_path / "c.nc")  # copied
    assert r.exit_code == 0, r.stderr
    for made, source in (("b.nc", "a.nc"), ("c.nc", "b.nc")):
        with xr.open_dataset(tmp_path / made) as ds:
            attrs = dict(ds.attrs)
        assert attrs["converted_from"] == source
        assert attrs["converted_from_sha256"] == hashlib.sha256((tmp_path / source).read_bytes()).hexdigest()
    steps = attrs["history"].splitlines()
    assert len(steps) == 3, steps
    assert steps[0].endswith("table of lambert on rusinkiewicz theta_h[6] x theta_d[6] x phi_d[12]")
    a_sum = hashlib.sha256((tmp_path / "a.nc").read_bytes()).hexdigest()
    assert f"converted a.nc (sha256 {a_sum}) to b.nc, resampled onto rusinkiewicz theta_h[3]" in steps[1]
    assert f"converted b.nc (sha256 {attrs['converted_from_sha256']}) to c.nc, copied" in steps[2]
    # info shows the steps, oldest first
    shown = _cli("info", tmp_path / "c.nc").stdout.splitlines()
    at = shown.index("  history:")
    assert [line.strip() for line in shown[at + 1:at + 4]] == steps


def test_a_table_converted_from_a_merl_file_records_it(tmp_path):
    import hashlib

    src = tmp_path / "paint.binary"
    brdftab.save(brdftab.models.create("lambert", albedo=0.3), src)
    r = _cli("convert", src, tmp_path / "paint.nc")
    assert r.exit_code == 0, r.stderr
    with xr.open_dataset(tmp_path / "paint.nc") as ds:
        attrs = dict(ds.attrs)
    digest = hashlib.sha256(src.read_bytes()).hexdigest()
    assert attrs["converted_from"] == "paint.binary" and attrs["converted_from_sha256"] == digest
    # the MERL file records no history: the conversion is the first step
    first = (f"{attrs['created']} brdftab {brdftab.__version__}: converted paint.binary (sha256 {digest}) to "
             "paint.nc, copied")
    assert attrs["history"].splitlines() == [first]


def test_resampling_bound_is_met_by_a_measured_file(tmp_path):
    """The default conversion of a measured-like RGL file to netCDF stays inside
    convert.RESAMPLING_BOUND (median and 95th percentile at θ ≤ 80°), so the bound refuses only
    conversions that misrepresent their source."""
    from _measured import measured_bsdf

    from brdftab.convert import RESAMPLING_BOUND, convert

    measured_bsdf(tmp_path / "m.bsdf")
    result = convert(tmp_path / "m.bsdf", tmp_path / "m.nc", progress=False)
    d = result.difference
    print(f"measured-like .bsdf -> netCDF: median {100 * d.median_rel:.2f} %, p95 {100 * d.p95_rel:.2f} %")
    assert d.median_rel < RESAMPLING_BOUND["median"] and d.p95_rel < RESAMPLING_BOUND["p95"]
    assert not d.exceeds()


def test_default_grid_refines_theta_h_for_a_narrow_lobe(tmp_path):
    """A mirror-like measured-like file (GGX α = 0.01 over a dark Lambertian, in the RGL
    database's layout, no provenance: judged as data of unknown origin):
    on the default grid's 90 MERL-spaced θh nodes its resampling misrepresents it beyond
    convert.RESAMPLING_BOUND (median 2.6 %), so the default conversion refines θh (180 nodes:
    median 0.3 %, p95 2.8 %), says so with the coarse grid's figures, and is written instead
    of refused; a grid asked for is never refined."""
    from brdftab.convert import RESAMPLING_BOUND, InvalidOutput, convert, default_grid
    from brdftab.formats import rgl
    from brdftab.formats._tensor import write_tensor_file

    m = brdftab.models
    model = m.create("sum", terms=[m.create("lambert", albedo=0.05),
                                   m.create("microfacet", alpha=0.01, fresnel="schlick", f0=[0.5, 0.4, 0.3])])
    src = tmp_path / "film.bsdf"
    fields = dict(rgl.prepare_rgl(model, n_theta_i=8, theta_i_max_deg=80.0, resolution=32,
                                  vndf_resolution=128).fields)
    fields.pop("provenance")
    write_tensor_file(src, fields)
    source = brdftab.open(src)
    r = _cli("convert", src, tmp_path / "film.nc", "--json")
    assert r.exit_code == 0, r.output
    result = json.loads(r.stdout)
    assert brdftab.open(tmp_path / "film.nc").grid.shape[:3] == (180, 90, 180)
    assert result["refined"].startswith("θh refined to 180 nodes") and "90 θh nodes: median" in result["refined"]
    median, p95 = (result["difference"][f"{k}_relative_difference_80deg"] for k in ("median", "p95"))
    print(f"GGX 0.01 .bsdf -> netCDF, 180 θh nodes: median {100 * median:.2f} %, p95 {100 * p95:.2f} %")
    assert median < RESAMPLING_BOUND["median"] / 2 and p95 < RESAMPLING_BOUND["p95"] / 2
    with pytest.raises(InvalidOutput, match="misrepresents"):  # the 90-node grid, asked for: refused
        convert(src, tmp_path / "asked.nc", grid=default_grid(source), progress=False)


def test_memory_check_up_front_covers_the_resampled_table_and_its_checks(tmp_path, monkeypatch):
    """A conversion onto a grid whose table fits but whose checks do not is refused before
    resampling (as tabulate is), in one line naming the grid; nothing is written."""
    from brdftab import table as table_mod

    src = tmp_path / "a.nc"
    brdftab.save(brdftab.models.create("lambert", albedo=[0.2, 0.5, 0.8]), src,
                 grid={"type": "rusinkiewicz", "n_theta_h": 6, "n_theta_d": 6, "n_phi_d": 12})
    nbytes = 30 * 20 * 40 * 3 * 8
    monkeypatch.setattr(table_mod, "available_memory", lambda: table_mod.CHUNK_OVERHEAD + 3 * nbytes)
    monkeypatch.setattr(table_mod, "tabulate", lambda *a, **k: pytest.fail("resampled before the memory check"))
    r = _cli("convert", src, tmp_path / "b.nc", "--grid",
             '{type = "rusinkiewicz", n_theta_h = 30, n_theta_d = 20, n_phi_d = 40}')
    assert r.exit_code == 2, r.stderr
    assert "a.nc: resampling onto and checking rusinkiewicz theta_h[30] x theta_d[20] x phi_d[40] x 3 channels needs " \
           "about" in r.stderr, r.stderr
    assert not (tmp_path / "b.nc").exists()
