"""Many specs and many validations on dask.distributed (brdftab/batch.py; ``--workers`` /
``--scheduler``). A real :class:`distributed.LocalCluster` (worker processes, no mock), shared
by the module, runs the same commands as a serial run; the files must hold the same data bit
for bit and the same attributes (the ``created`` time and the ``history`` line that dates it
aside), and the reports must be the same documents."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from _cli import cli, names, one_error

distributed = pytest.importorskip("distributed")  # the test extra installs it: CI runs these

ROOT = Path(__file__).resolve().parent.parent
GRID = '[grid]\ntype = "rusinkiewicz"\nn_theta_h = 4\nn_theta_d = 4\nn_phi_d = 6\n'
LAMBERT = '[model]\nname = "lambert"\nalbedo = {albedo}\n' + GRID + '[[output]]\npath = "{out}"\n'
#: 98 304 samples: the checks' sums span several blocks, split among threads differently in this
#: process (every core) and in a worker (one thread); the stored reports must agree all the same
GGX = ('[model]\nname = "microfacet"\nalpha = 0.3\nfresnel = "dielectric"\nn = 1.5\n'
       '[grid]\ntype = "rusinkiewicz"\nn_theta_h = 32\nn_theta_d = 32\nn_phi_d = 96\n'
       '[[output]]\npath = "ggx.nc"\n[[output]]\npath = "ggx32.nc"\ndtype = "float32"\n')
SWEEP = ('[sweep]\n"model.albedo" = [0.2, 0.6]\n[model]\nname = "lambert"\n' + GRID
         + '[[output]]\npath = "sw-{model.albedo}.nc"\n')
REFUSED = ('[model]\nname = "lambert"\nalbedo = 0.7\n' + GRID + '[[output]]\npath = "refused.nc"\n'
           '[validation.albedo]\nwhite_sky = 0.5\nlevel = "error"\n')
QUIET = ("--level", "tabulation=off")
UNDATED = ("created", "history")


@pytest.fixture(scope="module")
def scheduler():
    """One local cluster for the module: two worker processes, one thread each."""
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
                                  silence_logs=50, env={"BRDFTAB_THREADS": "1"}) as cluster:
        yield cluster.scheduler_address


def _specs(folder: Path) -> list:
    folder.mkdir(exist_ok=True)
    out = []
    for name, text in (("white.toml", LAMBERT.format(albedo=0.9, out="white.nc")), ("ggx.toml", GGX),
                       ("sw.toml", SWEEP)):
        (folder / name).write_text(text)
        out.append(folder / name)
    return out


def _same_files(a: Path, b: Path) -> None:
    """Every file of folder ``a`` is in ``b`` with the same content: netCDF data bit for bit
    and every attribute but the dated ones; other files byte for byte."""
    assert names(a) == names(b)
    for f in sorted(a.iterdir()):
        g = b / f.name
        if f.suffix != ".nc":
            assert f.read_bytes() == g.read_bytes(), f.name
            continue
        with xr.open_dataset(f) as x, xr.open_dataset(g) as y:
            assert sorted(x.variables) == sorted(y.variables)
            for v in x.variables:
                nan = x[v].dtype.kind == "f"
                assert x[v].dtype == y[v].dtype and np.array_equal(x[v].values, y[v].values, equal_nan=nan), (f.name, v)
                assert json.dumps(x[v].attrs, default=str) == json.dumps(y[v].attrs, default=str)
            ax = {k: v for k, v in x.attrs.items() if k not in UNDATED}
            ay = {k: v for k, v in y.attrs.items() if k not in UNDATED}
            assert json.dumps(ax, default=str, sort_keys=True) == json.dumps(ay, default=str, sort_keys=True), f.name


def test_a_cluster_run_writes_the_files_of_the_serial_run(tmp_path, scheduler):
    specs = _specs(tmp_path / "specs")
    serial = cli("tabulate", *specs, "--out", tmp_path / "serial")  # every check: their figures are stored
    assert serial.exit_code == 0, serial.output
    far = cli("tabulate", *specs, "--out", tmp_path / "far", "--scheduler", scheduler)
    assert far.exit_code == 0, far.output
    assert names(tmp_path / "far") == ["ggx.nc", "ggx32.nc", "sw-0.2.nc", "sw-0.6.nc", "sw-sweep.csv", "white.nc"]
    _same_files(tmp_path / "serial", tmp_path / "far")
    # the same lines, in the order of the command line (the cluster finishes them in any order)
    assert far.stdout.replace(str(tmp_path / "far"), "OUT") == serial.stdout.replace(str(tmp_path / "serial"), "OUT")
    assert "4 of 4 runs written" in far.stdout


def test_the_workers_option_starts_a_local_cluster(tmp_path):
    """--workers N: N worker processes whose kernels share the cores (BRDFTAB_THREADS)."""
    from brdftab._jit import threads
    from brdftab.batch import Engine

    with Engine(workers=2) as engine:
        got = dict(engine.map(os.getenv, [("BRDFTAB_THREADS",), ("BRDFTAB_THREADS",)]))
        pids = {engine.client.submit(os.getpid, pure=False).result() for _ in range(4)}
    assert got == {0: str(max(1, threads() // 2)), 1: str(max(1, threads() // 2))}
    assert os.getpid() not in pids
    specs = _specs(tmp_path / "specs")[:2]
    assert cli("tabulate", *specs, "--out", tmp_path / "serial", *QUIET).exit_code == 0
    r = cli("tabulate", *specs, "--out", tmp_path / "local", *QUIET, "--workers", "2")
    assert r.exit_code == 0, r.output
    _same_files(tmp_path / "serial", tmp_path / "local")


def test_a_failed_spec_reports_its_error_while_the_others_finish(tmp_path, scheduler):
    folder = tmp_path / "specs"
    folder.mkdir()
    for name, text in (("a.toml", LAMBERT.format(albedo=0.3, out="a.nc")),
                       ("bad.toml", LAMBERT.format(albedo=1.5, out="bad.nc")),  # out of range: bad input
                       ("refused.toml", REFUSED),                              # refused by a check (in a worker)
                       ("b.toml", LAMBERT.format(albedo=0.6, out="b.nc"))):
        (folder / name).write_text(text)
    args = [folder / n for n in ("a.toml", "bad.toml", "refused.toml", "b.toml")]
    r = cli("tabulate", *args, "--scheduler", scheduler)
    assert r.exit_code == 2, r.output  # bad input outranks a refused check
    errors = r.stderr.splitlines()
    assert len(errors) == 2 and all(e.startswith("brdftab: error: ") for e in errors), r.stderr
    assert "bad.toml: model.albedo:" in errors[0] and "refusing to export" in errors[1] and "refused.nc" in errors[1]
    assert names(folder) == ["a.nc", "a.toml", "b.nc", "b.toml", "bad.toml", "refused.toml"]
    assert "2 of 4 runs written; 2 failed" in r.stdout
    r = cli("tabulate", folder / "refused.toml", folder / "a.toml", "--overwrite", "--scheduler", scheduler)
    assert r.exit_code == 1 and r.stderr.count("brdftab: error:") == 1, r.output


def test_validate_on_a_cluster_gives_the_combined_report_of_the_serial_run(tmp_path, scheduler):
    specs = _specs(tmp_path / "specs")
    assert cli("tabulate", *specs, "--out", tmp_path / "t", *QUIET).exit_code == 0
    (tmp_path / "t" / "broken.nc").write_bytes(b"not a table")
    files = sorted(str(p) for p in (tmp_path / "t").glob("*.nc"))
    serial = cli("validate", *files, specs[0], "--json", "--junit", tmp_path / "serial.xml")
    far = cli("validate", *files, specs[0], "--json", "--junit", tmp_path / "far.xml", "--scheduler", scheduler)
    assert serial.exit_code == far.exit_code == 2  # one input cannot be read
    assert far.stdout == serial.stdout and far.stderr == serial.stderr
    doc = json.loads(far.stdout)
    subjects = [r["subject"].split(" (")[0] for r in doc["reports"]]
    assert subjects == [f for f in files if not f.endswith("broken.nc")] + [str(specs[0])]
    assert [e["subject"] for e in doc["errors"]] == [str(tmp_path / "t" / "broken.nc")]
    assert (tmp_path / "far.xml").read_text() == (tmp_path / "serial.xml").read_text()


def _without_dask(*args, cwd):
    code = ("import sys; sys.modules['distributed'] = None; sys.argv = ['brdftab', *sys.argv[1:]]; "
            "from brdftab._entry import main; main()")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    return subprocess.run([sys.executable, "-c", code, *map(str, args)], capture_output=True, text=True, cwd=cwd,
                          env=env, timeout=120)


@pytest.mark.parametrize("args", [("tabulate", "white.toml", "--workers", "2"),
                                  ("validate", "white.toml", "--scheduler", "tcp://127.0.0.1:8786")])
def test_without_dask_the_options_say_how_to_install_it(tmp_path, args):
    (tmp_path / "white.toml").write_text(LAMBERT.format(albedo=0.9, out="white.nc"))
    p = _without_dask(*args, cwd=tmp_path)
    one_error(p.stderr, p.returncode, f"{args[2]} needs dask.distributed, which is not installed",
              'pip install "brdftab[dist]"')
    assert names(tmp_path) == ["white.toml"]


def test_two_runs_writing_the_same_file_refuse_the_command(tmp_path):
    for name in ("a.toml", "b.toml"):
        (tmp_path / name).write_text(LAMBERT.format(albedo=0.5, out="same.nc"))
    r = cli("tabulate", tmp_path / "a.toml", tmp_path / "b.toml")
    one_error(r.stderr, r.exit_code, "a.toml and", "b.toml both write", "same.nc")
    assert names(tmp_path) == ["a.toml", "b.toml"]


def test_the_blocks_of_one_big_table_are_tabulated_on_the_cluster(tmp_path, scheduler, monkeypatch):
    """One spec whose table is over the memory budget, on a cluster: its blocks are tabulated on
    the workers (the scheduler's task stream shows them) and written here; the file holds the
    serial run's samples bit for bit, with the same attributes and stored report."""
    from distributed import get_task_stream

    from brdftab.batch import Engine
    from brdftab.pipeline import run
    from brdftab.spec import load_spec

    (tmp_path / "spec.toml").write_text(GGX)
    monkeypatch.setenv("BRDFTAB_MEMORY", "1M")  # 98 304 samples: streamed in many blocks
    serial = tmp_path / "serial"
    run(load_spec(tmp_path / "spec.toml"), out_dir=serial, progress=False, checks={"tabulation": {"level": "off"}})
    far = tmp_path / "far"
    with Engine(scheduler=scheduler) as engine, get_task_stream(engine.client) as stream:
        run(load_spec(tmp_path / "spec.toml"), out_dir=far, progress=False, checks={"tabulation": {"level": "off"}},
            engine=engine)
    blocks = [t for t in stream.data if str(t.get("key", "")).startswith("block_values")]
    assert len(blocks) > 4 and len({t["worker"] for t in blocks}) == 2  # both workers took blocks
    _same_files(serial, far)


def test_the_starts_of_a_fit_run_on_the_cluster(scheduler):
    """brdftab.fit with an engine: each start is a task on the workers; the fit equals the
    serial one bit for bit."""
    from distributed import get_task_stream

    import brdftab
    from brdftab.batch import Engine
    from brdftab.grids import grid_from_config
    from brdftab.table import tabulate

    table = tabulate(brdftab.models.create("microfacet", alpha=0.3, fresnel="schlick", f0=0.5),
                     grid_from_config({"type": "rusinkiewicz", "n_theta_h": 8, "n_theta_d": 6, "n_phi_d": 6}))
    args = dict(params={"alpha": 0.6, "fresnel": "schlick", "f0": 0.2}, starts=6, albedo=False)
    serial = brdftab.fit(table, "microfacet", ["alpha", "f0"], **args)
    with Engine(scheduler=scheduler) as engine, get_task_stream(engine.client) as stream:
        far = brdftab.fit(table, "microfacet", ["alpha", "f0"], engine=engine, **args)
    starts = [t for t in stream.data if str(t.get("key", "")).startswith("_search_one")]
    assert len(starts) == 6 and len({t["worker"] for t in starts}) == 2
    assert far.parameters == serial.parameters and far.start_results == serial.start_results
    assert far.parameters["alpha"] == pytest.approx(0.3, rel=1e-6)
