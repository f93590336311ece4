"""The ``brdftab`` command line end to end, and the README-style Python API.

The shipped specs in ``specs/`` are tabulated into pytest's temporary folders (never into
``specs/`` itself). Subprocesses run ``python -m brdftab`` with the interpreter running the
tests; quick checks use ``click.testing.CliRunner``.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
from click.testing import CliRunner

import brdftab
from brdftab import models
from brdftab.cli import main
from brdftab.errors import BrdftabError, ParameterError
from brdftab.grids import GRIDS, merl_grid
from _cli import TINY_GRID, run as _run, cli as _cli, partials as _partials, spec as _spec, one_error as _one_error

SPECS = Path(__file__).resolve().parent.parent / "specs"
GGX_GOLD = SPECS / "ggx-gold.toml"
LAMBERT_WHITE = SPECS / "lambert-white.toml"

WI_DEG = (30.0, 0.0)
WO_DEG = (30.0, 180.0)


def _vec(theta_deg, phi_deg):
    t, p = math.radians(theta_deg), math.radians(phi_deg)
    return np.array([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)])


@pytest.fixture(scope="module")
def ggx_nc(tmp_path_factory):
    """``brdftab tabulate specs/ggx-gold.toml --out TMP`` (a real subprocess), once per module."""
    out = tmp_path_factory.mktemp("ggx-out")
    proc = _run("tabulate", GGX_GOLD, "--out", out)
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr == ""
    target = out / "ggx-gold.nc"
    assert "wrote" in proc.stdout and "ggx-gold.nc" in proc.stdout
    assert sorted(p.name for p in out.iterdir()) == ["ggx-gold.nc"]
    return target


# --------------------------------------------------------------------------------------------
# tabulate + info + the netCDF layout

def test_tabulate_writes_into_out_folder(ggx_nc):
    assert ggx_nc.is_file() and ggx_nc.stat().st_size > 0
    with open(ggx_nc, "rb") as fh:
        assert fh.read(8) == b"\x89HDF\r\n\x1a\n"  # netCDF-4 (HDF5) signature


def test_info_describes_table(ggx_nc):
    proc = _run("info", ggx_nc)
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr == ""
    text = proc.stdout
    assert "grid:" in text and "merl" in text
    for axis in ("theta_h", "theta_d", "phi_d"):
        assert axis in text
    assert "R, G, B" in text
    assert "microfacet" in text


def test_info_json(ggx_nc):
    result = _cli("info", ggx_nc, "--json")
    assert result.exit_code == 0, result.stderr
    data = json.loads(result.stdout)
    assert data["channels"] == ["R", "G", "B"]
    assert [a["name"] for a in data["axes"]] == ["theta_h", "theta_d", "phi_d"]
    assert [a["size"] for a in data["axes"]] == [90, 90, 180]
    assert data["attributes"]["model"] == "microfacet"
    assert data["nonfinite"] == 0 and data["negative"] == 0
    assert data["min"] >= 0.0 and data["max"] > 0.0


def test_netcdf_layout_and_provenance(ggx_nc):
    with xr.open_dataset(ggx_nc) as ds:
        ds = ds.load()
    assert "brdf" in ds.data_vars
    assert ds["brdf"].attrs["units"] == "sr-1"
    assert ds["brdf"].dims == ("theta_h", "theta_d", "phi_d", "channel")
    assert ds["brdf"].shape == (90, 90, 180, 3)
    assert ds["brdf"].dtype == np.float32  # the spec asks for dtype = "float32"
    for name in ("theta_h", "theta_d", "phi_d"):
        assert name in ds.coords
        assert ds[name].attrs["units"] == "rad"
    # channel names: the CF label variable channel_name over the dimension channel
    assert "channel_name" in ds.coords and "channel" not in ds.variables
    assert [str(c) for c in ds["channel_name"].values] == ["R", "G", "B"]

    attrs = ds.attrs
    assert attrs["parameterization"] == "rusinkiewicz"
    assert attrs["sample_position"] == "bin-centre"
    assert attrs["phi_d_fold"] == "reciprocity"
    assert attrs["model"] == "microfacet"
    params = json.loads(attrs["parameters"])
    assert params["alpha"] == pytest.approx(0.2)
    assert params["fresnel"] == "conductor"
    assert attrs["spec_sha256"] == hashlib.sha256(GGX_GOLD.read_bytes()).hexdigest()
    assert attrs["brdftab_version"] == brdftab.__version__
    assert attrs["created"]
    assert "T" in attrs["created"]  # ISO 8601 timestamp

    v = ds["brdf"].values
    assert np.all(np.isfinite(v)) and np.all(v >= 0) and v.max() > 0


def test_tabulate_refuses_existing_then_overwrites(ggx_nc):
    out = ggx_nc.parent
    before_bytes = ggx_nc.read_bytes()
    before = ggx_nc.stat()

    proc = _run("tabulate", GGX_GOLD, "--out", out)
    assert proc.returncode == 2
    lines = proc.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("brdftab: error: "), proc.stderr
    assert "ggx-gold.nc" in lines[0] and "--overwrite" in lines[0]
    assert "Traceback" not in proc.stderr
    assert proc.stdout == ""
    after = ggx_nc.stat()
    assert ggx_nc.read_bytes() == before_bytes
    assert (after.st_mtime_ns, after.st_ino, after.st_size) == (before.st_mtime_ns, before.st_ino, before.st_size)

    result = _cli("tabulate", GGX_GOLD, "--out", out, "--overwrite")
    assert result.exit_code == 0, result.stderr
    assert "wrote" in result.stdout
    assert ggx_nc.stat().st_ino != before.st_ino  # replaced (atomically, by rename)
    assert sorted(p.name for p in out.iterdir()) == ["ggx-gold.nc"]
    with xr.open_dataset(ggx_nc) as ds:
        assert ds["brdf"].shape == (90, 90, 180, 3)


def test_info_text_is_readable(tmp_path):
    # description, spec file and parameters shown readably
    spec = tmp_path / "layered.toml"
    spec.write_text('description = "plaster under a clear coat"\n[model]\nname = "sum"\n'
                    '[[model.terms]]\nname = "lambert"\nalbedo = 0.05\n'
                    '[[model.terms]]\nname = "microfacet"\nalpha = 0.1\n' + TINY_GRID +
                    '[[output]]\npath = "layered.nc"\n')
    assert _cli("tabulate", spec).exit_code == 0
    result = _cli("info", tmp_path / "layered.nc")
    assert result.exit_code == 0, result.stderr
    lines = result.stdout.splitlines()
    assert "  description: plaster under a clear coat" in lines
    assert any(line.startswith("  spec file:") and "layered.toml" in line for line in lines)
    assert "  model:       sum" in lines
    assert "    terms[0]: lambert" in lines and "      albedo = 0.05" in lines
    assert "    terms[1]: microfacet" in lines and "      alpha = 0.1" in lines
    assert '      distribution = "ggx"' in lines
    assert '{"' not in result.stdout  # no raw JSON


def test_progress_bar_covers_the_write(tmp_path, monkeypatch):
    from brdftab import table as table_module

    monkeypatch.setattr(table_module, "PROGRESS_DELAY", 0.0)
    spec = _spec(tmp_path, output="x.nc")
    result = _cli("tabulate", spec, "--progress")
    assert result.exit_code == 0, result.stderr
    assert "tabulating" in result.stderr and "writing x.nc" in result.stderr
    result = _cli("tabulate", spec, "--overwrite", "--no-progress")
    assert result.exit_code == 0 and result.stderr == ""


def test_progress_bar_covers_the_checks(tmp_path, monkeypatch):
    """Between tabulating and writing, the checks of what is written run under a bar of their own."""
    from brdftab import table as table_module

    monkeypatch.setattr(table_module, "PROGRESS_DELAY", 0.0)
    result = _cli("tabulate", _spec(tmp_path, output="x.nc"), "--progress")
    assert result.exit_code == 0, result.stderr
    err = result.stderr
    assert "checking x.nc" in err
    assert err.index("tabulating") < err.index("checking x.nc") < err.index("writing x.nc")


def test_tabulate_says_when_what_it_wrote_has_warnings(tmp_path):
    """A check that WARNs does not stop the export, but the run says so on stderr (not only 'wrote')."""
    spec = tmp_path / "s.toml"
    spec.write_text(f'[model]\nname = "lambert"\nalbedo = 0.5\n{TINY_GRID}[[output]]\npath = "a.nc"\n'
                    '[[output]]\npath = "b.nc"\n')
    result = _cli("tabulate", spec, "--set", "albedo.expected=0.8", "--level", "albedo=warn",
                  "--level", "bilateral=warn", "--no-progress")
    assert result.exit_code == 0, result.stderr
    assert result.stdout.count("wrote ") == 2
    lines = result.stderr.splitlines()
    assert len(lines) == 1, lines  # the two outputs share one table, hence one report
    assert lines[0].startswith("brdftab: warning: ") and f"{tmp_path / 'a.nc'}, {tmp_path / 'b.nc'} written with 1 warning: albedo: " in lines[0]
    assert "differs from the expected" in lines[0]
    result = _cli("tabulate", spec, "--overwrite", "--no-progress")  # nothing to say
    assert result.exit_code == 0 and result.stderr == ""


# --------------------------------------------------------------------------------------------
# An interrupted or killed run leaves no partial output

BIG_SPEC = """\
description = "a grid large enough that the tabulation runs for several seconds"

[model]
name = "sum"

[[model.terms]]
name = "lambert"
albedo = 0.5

[[model.terms]]
name = "microfacet"
alpha = 0.3

[grid]
type = "rusinkiewicz"
n_theta_h = 400
n_theta_d = 400
n_phi_d = {n_phi_d}

[[output]]
path = "big.nc"
"""


def _interrupt_run(tmp_path: Path, sig) -> subprocess.CompletedProcess:
    """Start a long tabulation, send ``sig`` mid-run; enlarge the grid if it ended too early."""
    spec = tmp_path / "big.toml"
    target = tmp_path / "big.nc"
    n_phi_d, wait = 360, 1.5
    for _attempt in range(5):
        spec.write_text(BIG_SPEC.format(n_phi_d=n_phi_d))
        proc = subprocess.Popen([sys.executable, "-m", "brdftab", "tabulate", spec.name, "--no-progress"],
                                cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            time.sleep(wait)
            if proc.poll() is not None:  # finished before the signal: the run was too short
                proc.communicate()
                target.unlink(missing_ok=True)
                n_phi_d *= 2
                continue
            proc.send_signal(sig)
            out, err = proc.communicate(timeout=60)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        if sig == signal.SIGTERM and proc.returncode == -signal.SIGTERM:
            # Terminated while still starting up (before the handler was installed): wait longer.
            wait += 1.0
            continue
        return subprocess.CompletedProcess(proc.args, proc.returncode, out, err)
    pytest.fail("could not signal the tabulation while it was running")


def test_sigterm_leaves_no_partial_file(tmp_path):
    proc = _interrupt_run(tmp_path, signal.SIGTERM)
    assert proc.returncode == 143, (proc.returncode, proc.stderr)  # 128 + SIGTERM
    assert "Traceback" not in proc.stderr
    lines = proc.stderr.splitlines()
    # one line; a signal that lands while a file is being written is held until the write is
    # done, which a notice says first (on a loaded machine the run may be there already)
    assert lines[-1].startswith("brdftab: terminated") and all(
        line.startswith("brdftab: finishing the write of") for line in lines[:-1]) and len(lines) <= 2, lines
    assert not (tmp_path / "big.nc").exists()
    assert _partials(tmp_path) == []
    assert sorted(p.name for p in tmp_path.iterdir()) == ["big.toml"]


def test_sigkill_leaves_no_target_file(tmp_path):
    proc = _interrupt_run(tmp_path, signal.SIGKILL)
    assert proc.returncode == -signal.SIGKILL
    assert not (tmp_path / "big.nc").exists()


# --------------------------------------------------------------------------------------------
# eval

def _in_process(source):
    return brdftab.from_spec(source).eval(_vec(*WI_DEG), _vec(*WO_DEG))


def test_eval_spec_prints_channels_matching_api():
    proc = _run("eval", GGX_GOLD, "--wi-deg", "30,0", "--wo-deg", "30,180")
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr == ""
    lines = proc.stdout.splitlines()
    assert len(lines) == 3
    values = {}
    for line in lines:
        name, value = line.split()
        values[name] = float(value)
    assert list(values) == ["R", "G", "B"]
    assert all(v > 0 for v in values.values())
    expected = _in_process(GGX_GOLD)
    np.testing.assert_allclose([values[c] for c in "RGB"], expected, rtol=1e-8)


def test_eval_spec_json_matches_api():
    result = _cli("eval", GGX_GOLD, "--wi-deg", "30,0", "--wo-deg", "30,180", "--json")
    assert result.exit_code == 0, result.stderr
    data = json.loads(result.stdout)
    assert data["model"] == "microfacet"
    assert data["units"] == "sr-1"
    assert data["wi_deg"] == [30.0, 0.0] and data["wo_deg"] == [30.0, 180.0]
    assert list(data["channels"]) == ["R", "G", "B"]
    np.testing.assert_allclose([data["channels"][c] for c in "RGB"], _in_process(GGX_GOLD), rtol=1e-12)


def test_eval_table_agrees_with_spec(ggx_nc):
    result = _cli("eval", ggx_nc, "--wi-deg", "30,0", "--wo-deg", "30,180", "--json")
    assert result.exit_code == 0, result.stderr
    table_values = [json.loads(result.stdout)["channels"][c] for c in "RGB"]
    np.testing.assert_allclose(table_values, _in_process(GGX_GOLD), rtol=0.01)


def test_eval_reads_a_table_by_content_whatever_its_name(tmp_path):
    spec = _spec(tmp_path, output="t.nc")
    assert _cli("tabulate", spec).exit_code == 0
    (tmp_path / "t.nc").rename(tmp_path / "t.toml")
    result = _cli("eval", tmp_path / "t.toml", "--wi-deg", "30,0", "--wo-deg", "30,180", "--json")
    assert result.exit_code == 0, result.stderr
    assert json.loads(result.stdout)["channels"]["mono"] == pytest.approx(0.5 / np.pi)
    # and a spec with another extension is still a spec
    other = tmp_path / "spec.txt"
    other.write_bytes(spec.read_bytes())
    result = _cli("eval", other, "--wi-deg", "30,0", "--wo-deg", "30,180", "--json")
    assert result.exit_code == 0, result.stderr


def test_eval_cli_prints_no_numpy_warnings(tmp_path):
    spec = tmp_path / "s.toml"
    spec.write_text('[model]\nname = "microfacet"\nalpha = 1e-6\n[grid]\ntype = "merl"\n[[output]]\npath = "x.nc"\n')
    p = subprocess.run([sys.executable, "-W", "default", "-m", "brdftab", "eval", str(spec), "--wi-deg", "30,0",
                        "--wo-deg", "30,180"], capture_output=True, text=True)
    assert p.returncode == 0 and p.stderr == "", p.stderr
    assert np.isfinite(float(p.stdout.split()[-1]))


# --------------------------------------------------------------------------------------------
# models, grids, --version

def test_models_lists_models():
    result = _cli("models")
    assert result.exit_code == 0, result.stderr
    names = [line.split()[0] for line in result.stdout.splitlines() if line.strip()]
    assert "lambert" in names and "microfacet" in names


def test_models_json():
    result = _cli("models", "--json")
    assert result.exit_code == 0
    data = json.loads(result.stdout)
    assert {"lambert", "microfacet"} <= set(data)


def test_models_microfacet_details():
    result = _cli("models", "microfacet")
    assert result.exit_code == 0, result.stderr
    text = result.stdout
    for word in ("alpha", "distribution", "fresnel", "ggx", "beckmann", "conductor"):
        assert word in text
    assert "references:" in text and "Cook" in text and "Walter" in text


def test_version():
    proc = _run("--version")
    assert proc.returncode == 0
    assert brdftab.__version__ in proc.stdout
    result = _cli("--version")
    assert result.exit_code == 0 and brdftab.__version__ in result.stdout


def test_console_script_version():
    exe = Path(sys.executable).parent / "brdftab"
    if not exe.exists():
        exe = shutil.which("brdftab")
    assert exe, "the brdftab console script is not installed"
    proc = subprocess.run([str(exe), "--version"], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert brdftab.__version__ in proc.stdout


def test_grids_command_lists_types_and_keys():
    out = subprocess.run([sys.executable, "-m", "brdftab", "grids", "--json"], capture_output=True, text=True)
    assert set(json.loads(out.stdout)) == set(GRIDS)
    out = subprocess.run([sys.executable, "-m", "brdftab", "grids", "rusinkiewicz", "--json"], capture_output=True,
                         text=True)
    keys = {r["key"]: r for r in json.loads(out.stdout)["keys"]}
    assert keys["phi_d_fold"]["default"] == "reciprocity" and keys["theta_h_spacing"]["default"] == "linear"
    assert keys["n_theta_h"]["default"] == 90 and "theta_h_deg" in keys


# --------------------------------------------------------------------------------------------
# --debug after the verb; a closed pipe ends quietly

def test_debug_after_the_verb_shows_the_traceback(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('[model]\nname = "nosuch"\n')
    proc = _run("tabulate", bad, "--debug")
    assert "Traceback" in proc.stderr and "SpecError" in proc.stderr
    proc = _run("--debug", "tabulate", bad)
    assert "Traceback" in proc.stderr
    proc = _run("tabulate", bad)
    _one_error(proc.stderr, proc.returncode, "bad.toml")


def test_closed_stdout_pipe_ends_quietly():
    r, w = os.pipe()
    os.close(r)  # the reader is gone before brdftab writes a byte (like `| head -1` after its line)
    try:
        proc = subprocess.run([sys.executable, "-m", "brdftab", "models", "microfacet"], stdout=w,
                              stderr=subprocess.PIPE, text=True, timeout=120)
    finally:
        os.close(w)
    assert proc.stderr == ""
    assert proc.returncode == 141  # 128 + SIGPIPE, as for a process the pipe killed


# --------------------------------------------------------------------------------------------
# README-style Python API

def test_python_api_round_trip(tmp_path):
    brdf = brdftab.from_spec(GGX_GOLD)
    assert brdf.name == "microfacet" and brdf.channels == ("R", "G", "B")

    model = brdftab.models.create("microfacet", distribution="ggx", alpha=0.3, fresnel="schlick",
                                  f0=[0.9, 0.6, 0.3])
    path = tmp_path / "api.nc"
    grid = brdftab.grids.merl_grid()
    brdftab.save(model, path, grid=grid)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["api.nc"]

    table = brdftab.open(path)
    assert isinstance(table, brdftab.Table) and isinstance(table, brdftab.BRDF)
    assert table.grid.equals(merl_grid())
    assert table.channels == ("R", "G", "B")
    assert table.name == "microfacet"
    assert table.parameters["alpha"] == pytest.approx(0.3)
    assert table.values.dtype == np.float64

    wi, wo = grid.directions()
    expected = model.eval(wi, wo).reshape(table.values.shape)
    np.testing.assert_allclose(table.values, expected, rtol=1e-12, atol=0)

    # At its own nodes a table returns the stored values.
    rng = np.random.default_rng(1)
    flat = rng.choice(grid.size, 2000, replace=False)
    wi_n, wo_n = grid.directions()
    got = table.eval(wi_n[flat], wo_n[flat])
    np.testing.assert_allclose(got, table.values.reshape(-1, 3)[flat], rtol=1e-9, atol=1e-12)

    # Between nodes it interpolates close to the model.
    f_table = table.eval(_vec(*WI_DEG), _vec(*WO_DEG))
    np.testing.assert_allclose(f_table, model.eval(_vec(*WI_DEG), _vec(*WO_DEG)), rtol=0.01)

    # A table saved without a grid is written as it is.
    copy = tmp_path / "copy.nc"
    brdftab.save(table, copy)
    np.testing.assert_array_equal(brdftab.open(copy).values, table.values)


def test_lambert_white_is_constant(tmp_path):
    result = _cli("tabulate", LAMBERT_WHITE, "--out", tmp_path)
    assert result.exit_code == 0, result.stderr
    target = tmp_path / "lambert-white.nc"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["lambert-white.nc"]
    with xr.open_dataset(target) as ds:
        ds = ds.load()
    v = ds["brdf"].values
    assert v.shape == (90, 90, 180, 1)
    assert [str(c) for c in ds["channel_name"].values] == ["mono"]
    # Every sample with both directions above the horizon is exactly albedo / pi. The
    # Rusinkiewicz/MERL grid also holds pairs with wi or wo below the horizon
    # (theta_h + theta_d > 90 deg); by the BRDF protocol those are stored as 0.
    wi, wo = merl_grid().directions()
    above = ((wi[:, 2] > 0) & (wo[:, 2] > 0)).reshape(v.shape[:-1])
    assert above.any() and (~above).any()
    assert np.all(v[above] == 0.99 / np.pi)
    assert np.all(v[~above] == 0.0)
    assert ds.attrs["model"] == "lambert"
    assert json.loads(ds.attrs["parameters"])["albedo"] == pytest.approx(0.99)


def test_lambert_default_albedo(tmp_path):
    # albedo is documented with default 1.0 (brdftab models lambert); leaving it out must work.
    model = brdftab.models.create("lambert")
    np.testing.assert_allclose(model.eval(_vec(*WI_DEG), _vec(*WO_DEG)), [1.0 / np.pi])
    spec = tmp_path / "lambert-default.toml"
    spec.write_text('[model]\nname = "lambert"\n\n[grid]\ntype = "merl"\n\n[[output]]\npath = "x.nc"\n')
    result = _cli("eval", spec, "--wi-deg", "30,0", "--wo-deg", "30,180", "--json")
    assert result.exit_code == 0, result.stderr
    assert json.loads(result.stdout)["channels"]["mono"] == pytest.approx(1.0 / np.pi)


def test_api_misuse_is_a_brdftab_error(tmp_path):
    m = models.create("lambert", albedo=0.5)
    brdftab.save(m, tmp_path / "a.nc", grid="merl")
    brdftab.save(m, tmp_path / "b.nc", grid={"type": "rusinkiewicz", "n_theta_h": 4, "n_theta_d": 4, "n_phi_d": 4})
    assert brdftab.open(tmp_path / "a.nc").grid.equals(merl_grid())
    assert brdftab.open(tmp_path / "b.nc").grid.shape == (4, 4, 4)
    with pytest.raises(BrdftabError, match="expected a BRDF"):
        brdftab.save(np.zeros(3), tmp_path / "c.nc", grid="merl")
    with pytest.raises(BrdftabError, match="grid must be"):
        brdftab.save(m, tmp_path / "c.nc", grid=3)
    with pytest.raises(ParameterError, match="trailing axis of length 3"):
        m.eval(np.zeros((3, 2)), [0, 0, 1])


# -- formats, help that lists the choices, non-finite eval ---------------------------------------

def test_formats_lists_every_format_and_one_formats_options():
    from brdftab import formats

    r = CliRunner().invoke(main, ["formats"])
    assert r.exit_code == 0, r.output
    for name, f in formats.FORMATS.items():
        assert name in r.output and all(e in r.output for e in f.extensions)
    assert "stores merl" in r.output and "needs OpenEXR" in r.output
    r = CliRunner().invoke(main, ["formats", "merl"])
    assert r.exit_code == 0 and "symmetrize" in r.output and "phi_h_average" in r.output
    data = json.loads(CliRunner().invoke(main, ["formats", "rgl", "--json"]).output)
    assert data["read"] and data["write"] and ".bsdf" in data["extensions"] and "resolution" in data["options"]
    r = CliRunner().invoke(main, ["formats", "mrel"])
    assert r.exit_code == 2 and "did you mean 'merl'" in r.output


def test_help_lists_what_a_user_can_choose():
    from brdftab import formats

    out = CliRunner().invoke(main, ["convert", "--help"]).output
    assert all(name in out for name in formats.usable())
    assert all(name not in out for name, f in formats.FORMATS.items() if f.recognised_only)
    top = CliRunner().invoke(main, ["--help"]).output
    for verb in ("tabulate", "convert", "eval", "info", "validate", "models", "grids", "formats"):
        assert verb in top
    assert "--origin" in CliRunner().invoke(main, ["validate", "--help"]).output
    assert "--quiet" in CliRunner().invoke(main, ["validate", "--help"]).output


# -- start-up: help and version load nothing heavy ----------------------------------------------

#: What ``--help`` and ``--version`` must not load: libraries that take a good part of a second
#: to import, and the parts of brdftab that import them (the models, tables, formats, checks).
HEAVY = ("xarray", "netCDF4", "h5py", "scipy", "pandas", "OpenEXR", "Imath", "matplotlib", "numba", "llvmlite",
         "colour", "zarr", "dask", "mitsuba", "drjit",
         "brdftab.models", "brdftab.table", "brdftab.formats", "brdftab.grids", "brdftab.checks", "brdftab.brdf",
         "brdftab.spec", "brdftab.pipeline", "brdftab.convert", "brdftab._jit")


def _heavy(module_names) -> list:
    return sorted(m for m in module_names if any(m == h or m.startswith(h + ".") for h in HEAVY))


#: Runs ``brdftab ARGS`` in-process once per argument list given as JSON in argv[1]; prints
#: {"outputs": [stdout of each run], "codes": [...], "modules": [every module loaded], "called":
#: [compiled kernels that ran or were loaded from the cache], "generated": [generated kernel modules]}.
_CLI_RUNS = r"""
import contextlib, io, json, sys
from brdftab.cli import main
outputs, codes = [], []
for args in json.loads(sys.argv[1]):
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        codes.append(main(args, prog_name="brdftab", standalone_mode=False))
    outputs.append(out.getvalue())
called, generated = [], []
if "numba" in sys.modules:
    from numba.core.dispatcher import Dispatcher
    for name, module in list(sys.modules.items()):
        if name.startswith(("brdftab", "_brdftab_")):
            called += [f"{name}.{k}" for k, v in vars(module).items() if isinstance(v, Dispatcher) and v.signatures]
if "brdftab._jit" in sys.modules:
    generated = sorted(sys.modules["brdftab._jit"]._MODULES)
json.dump({"outputs": outputs, "codes": codes, "modules": sorted(sys.modules), "called": called,
           "generated": generated}, sys.stdout)
"""


def _cli_in_fresh_process(*arg_lists) -> dict:
    proc = subprocess.run([sys.executable, "-c", _CLI_RUNS, json.dumps([list(a) for a in arg_lists])],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout)


def test_help_and_version_import_nothing_heavy():
    """``brdftab --version``, ``--help`` and every verb's ``--help`` start in about the time of a
    bare numpy import: none of them loads xarray, netCDF4, scipy, OpenEXR, numba, the models
    or the formats (the verbs import those when they run)."""
    # the console entry point itself, as a user starts it: every module it imports, from -X importtime
    for args, shows in ((["--version"], brdftab.__version__), (["convert", "--help"], "Usage: brdftab convert")):
        proc = subprocess.run([sys.executable, "-X", "importtime", "-m", "brdftab", *args], capture_output=True,
                              text=True, timeout=120)
        assert proc.returncode == 0 and shows in proc.stdout, proc
        imported = [line.rsplit("|", 1)[1].strip() for line in proc.stderr.splitlines()
                    if line.startswith("import time:")]
        assert "brdftab.cli" in imported and "numpy" in imported  # the listing is read right
        assert _heavy(imported) == [], args
    # --help and each verb's --help, with the help text they print
    verbs = sorted(main.commands)
    assert len(verbs) >= 8
    done = _cli_in_fresh_process(["--help"], *[[verb, "--help"] for verb in verbs])
    assert done["codes"] == [0] * (len(verbs) + 1)
    assert all(text.startswith("Usage: brdftab") for text in done["outputs"])
    assert all(verb in done["outputs"][0] for verb in verbs)
    assert _heavy(done["modules"]) == []
    assert _heavy(["brdftab.models.microfacet", "scipy.special", "brdftab._jit", "xarray"]) == [
        "brdftab._jit", "brdftab.models.microfacet", "scipy.special", "xarray"]  # and it would see them


def test_a_verb_s_modules_load_before_it_starts():
    """The entry point imports the modules a verb runs on before the verb starts, under its
    start-up signal handlers (:func:`brdftab.cli.preload`); never for help or version."""
    code = ("import json, sys\nfrom brdftab.cli import preload\nloaded = []\n"
            "for args in json.loads(sys.argv[1]):\n"
            "    before = set(sys.modules)\n    preload(args)\n    loaded.append(sorted(set(sys.modules) - before))\n"
            "print(json.dumps(loaded))")
    cases = [["tabulate", "--help"], ["--debug", "validate", "-h"], ["--version", "info"], [], ["nosuch", "x"],
             ["models"], ["--debug", "tabulate", "s.toml"]]
    proc = subprocess.run([sys.executable, "-c", code, json.dumps(cases)], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    loaded = json.loads(proc.stdout)
    assert loaded[:5] == [[]] * 5
    assert "brdftab.models" in loaded[5] and "xarray" not in loaded[5]
    assert {"brdftab.pipeline", "brdftab.formats", "brdftab.checks", "xarray", "netCDF4"} <= set(loaded[6])
    assert all(getattr(command, "runs_on", ()) for command in main.commands.values())


def test_convert_help_names_the_registered_formats():
    """``convert --help`` names the formats from a static copy (so that help imports no format
    module); the copy is the registry's list, extensions included, in its order."""
    from brdftab import cli as cli_module, formats

    assert cli_module.USABLE_FORMATS == tuple((n, formats.FORMATS[n].extensions) for n in formats.usable())
    out = " ".join(CliRunner().invoke(main, ["convert", "--help"]).output.split())
    for name in formats.usable():
        assert f"{name} ({'/'.join(formats.FORMATS[name].extensions)})" in out


def test_listing_commands_run_no_compiled_kernel():
    """The short listing commands (models, grids, formats, checks) never compile, load or
    generate a compiled kernel: that cost is paid by the runs that evaluate a BRDF."""
    done = _cli_in_fresh_process(["models"], ["models", "microfacet"], ["models", "pyramid-microfacet"], ["grids"],
                       ["grids", "merl"], ["formats"], ["formats", "rgl"], ["validate", "--list-checks"])
    assert done["codes"] == [0] * 8 and "microfacet" in done["outputs"][0] and "energy" in done["outputs"][-1]
    assert done["called"] == [] and done["generated"] == []


def test_eval_of_missing_samples_exits_1_with_valid_json(tmp_path):
    g = merl_grid()
    path = tmp_path / "empty.binary"
    path.write_bytes(np.array(g.shape, dtype="<i4").tobytes() + np.full((3,) + g.shape, -1.0).tobytes())
    args = ["eval", str(path), "--wi-deg", "30,0", "--wo-deg", "30,180"]
    r = _run(*args)
    assert r.returncode == 1 and "not finite" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    r = _run(*args, "--json")
    assert r.returncode == 1
    doc = json.loads(r.stdout)      # valid JSON: null, not NaN
    assert doc["finite"] is False and doc["channels"] == {"R": None, "G": None, "B": None}


def test_checks_show_progress_only_when_asked_and_slow(monkeypatch, capsys):
    import time as _time

    from brdftab import checks
    from brdftab.checks import run_checks

    lam = brdftab.models.create("lambert", albedo=0.5)
    real = checks.CHECKS["finite"].run

    def slow(ctx, **kw):
        _time.sleep(1.3)
        return real(ctx, **kw)

    monkeypatch.setattr(checks.CHECKS["finite"], "run", slow)
    run_checks(lam, only=("finite", "non-negative"), progress=True)
    assert "checking" in capsys.readouterr().err
    run_checks(lam, only=("finite", "non-negative"), progress=False)
    assert capsys.readouterr().err == ""
    monkeypatch.setattr(checks.CHECKS["finite"], "run", real)
    run_checks(lam, only=("finite", "non-negative"), progress=True)   # fast: the bar waits 1 s, never shows
    assert capsys.readouterr().err == ""


def test_info_shows_only_what_a_merl_file_records(tmp_path):
    """A MERL file holds samples only: no creation time, no brdftab version, no history."""
    path = tmp_path / "paint.binary"
    brdftab.save(brdftab.models.create("lambert", albedo=0.3), path)
    r = _cli("info", path)
    assert r.exit_code == 0, r.stderr
    keys = {line.split(":")[0].strip() for line in r.stdout.splitlines() if line.startswith("  ")}
    assert not keys & {"created", "brdftab_version", "history", "validation"}, r.stdout
    attrs = json.loads(_cli("info", path, "--json").stdout)["attributes"]
    assert not {"created", "brdftab_version", "history", "source"} & set(attrs)


def test_info_escapes_control_and_bidi_characters(tmp_path):
    spec = tmp_path / "s.toml"
    # a terminal escape (clear screen) and a right-to-left override, written as TOML escapes
    spec.write_text('description = "paint\\u001b[2J\\u202eecnahne"\n[model]\nname = "lambert"\n'
                    f'{TINY_GRID}[[output]]\npath = "x.nc"\n')
    assert _cli("tabulate", spec, "--no-progress").exit_code == 0
    r = _cli("info", tmp_path / "x.nc")
    assert r.exit_code == 0, r.stderr
    assert "\x1b" not in r.stdout and "\u202e" not in r.stdout
    assert "  description: paint\\x1b[2J\\u202eecnahne" in r.stdout.splitlines()
    doc = json.loads(_cli("info", tmp_path / "x.nc", "--json").stdout)  # JSON escapes them itself
    assert doc["attributes"]["comment"] == "paint\x1b[2J\u202eecnahne"


def test_info_shows_the_stored_validation_result(tmp_path):
    good = _spec(tmp_path, output="good.nc")
    assert _cli("tabulate", good, "--no-progress").exit_code == 0
    bad = tmp_path / "bad.toml"
    bad.write_text('[model]\nname = "scale"\nfactor = 1.5\n[model.term]\nname = "lambert"\nalbedo = 0.8\n'
                   f'{TINY_GRID}[[output]]\npath = "bad.nc"\n')
    assert _cli("tabulate", bad, "--allow-invalid", "--no-progress").exit_code == 0
    lines = _cli("info", tmp_path / "good.nc").stdout.splitlines()
    assert any(line.startswith("  validation:") and "passed: all checks passed (" in line for line in lines), lines
    lines = _cli("info", tmp_path / "bad.nc").stdout.splitlines()
    shown = next(line for line in lines if line.startswith("  validation:"))
    assert "FAILED: energy: max a(θi) = 1.2" in shown
    doc = json.loads(_cli("info", tmp_path / "bad.nc", "--json").stdout)
    assert doc["validation"]["passed"] is False
    assert doc["validation"]["summary"].startswith("energy: max a(θi) = 1.2")


def test_info_of_a_table_naming_no_registered_model(tmp_path):
    # a MERL file names its material, not a model: info describes it (no unknown-model error)
    path = tmp_path / "paint.binary"
    brdftab.save(brdftab.models.create("lambert", albedo=0.3), path)
    r = CliRunner().invoke(main, ["info", str(path)])
    assert r.exit_code == 0 and "model:       unknown" in r.output, r.output


def test_path_that_is_not_utf8_is_one_line_or_works(tmp_path):
    """POSIX names may hold any bytes: where the format's library takes only UTF-8 paths
    (netCDF/HDF5, OpenEXR) the path is refused up front in one line, exit 2, nothing created;
    formats brdftab writes itself take the name as it is."""
    from _cli import names

    one_error, run, spec = _one_error, _run, _spec(tmp_path)
    folder = tmp_path / os.fsdecode(b"out\xff")
    proc = run("tabulate", spec, "--out", folder)
    one_error(proc.stderr, proc.returncode, "out\\xff/out.nc", "netcdf", "valid UTF-8")
    assert names(tmp_path) == [spec.name]
    table = tmp_path / "t.nc"
    assert run("tabulate", spec).returncode == 0 and (tmp_path / "out.nc").exists()
    (tmp_path / "out.nc").rename(table)
    for ext in ("nc", "exr"):  # in-process: the same surrogate-escaped names
        result = _cli("convert", table, tmp_path / os.fsdecode(b"t\xff." + ext.encode()))
        one_error(result.stderr, result.exit_code, f"t\\xff.{ext}", "valid UTF-8")
        assert _cli("info", tmp_path / os.fsdecode(b"t\xff." + ext.encode())).exit_code == 2
    assert names(tmp_path) == sorted([spec.name, table.name])
    merl = tmp_path / os.fsdecode(b"t\xff.binary")
    brdftab.save(models.create("lambert", albedo=0.5), merl)
    assert brdftab.open(merl).eval([0, 0, 1], [0.6, 0, 0.8])[0] == pytest.approx(0.5 / math.pi, rel=1e-6)
    # such a file's name goes into what is made from it (provenance, reports) as \xff escapes
    for ext in ("nc", "exr"):
        result = _cli("convert", merl, tmp_path / f"from-merl.{ext}")
        assert result.exit_code == 0, result.stderr
        shown = _cli("info", tmp_path / f"from-merl.{ext}").stdout
        assert "converted_from:        t\\xff.binary" in shown, shown
    result = _cli("validate", merl, "--junit", tmp_path / "r.xml")
    assert result.exit_code == 0, result.stderr
    assert 't\\xff.binary" tests=' in (tmp_path / "r.xml").read_text(encoding="utf-8")


def test_numpy_floating_point_warnings_are_one_line_naming_where(capsys, tmp_path):
    """NumPy's "overflow encountered in square" says neither where nor what it means: the CLI
    says both, once per run however many chunks repeat it."""
    from brdftab import cli as cli_module

    cli_module._shown.clear()
    for _ in range(3):
        cli_module._show_warning(RuntimeWarning("overflow encountered in square"), RuntimeWarning,
                                 "/somewhere/site-packages/brdftab/checks/tabulation.py", 71)
    cli_module._show_warning(RuntimeWarning("invalid value encountered in scalar divide"), RuntimeWarning,
                             "/somewhere/brdftab/integrate.py", 9)
    cli_module._show_warning(RuntimeWarning("overflow encountered in cast"), RuntimeWarning,
                             "/somewhere/brdftab/formats/__init__.py", 40)
    assert capsys.readouterr().err.splitlines() == [
        "brdftab: warning: numerical overflow (square) in brdftab/checks/tabulation.py, line 71: a value exceeded "
        "the float64 range (about 1.8e308) and became infinite; figures computed from it may be inf or NaN",
        "brdftab: warning: numerical invalid operation (scalar divide) in brdftab/integrate.py, line 9: an undefined "
        "operation (0/0, inf - inf, inf/inf, sqrt of a negative) gave NaN; figures computed from it may be inf or NaN",
        "brdftab: warning: numerical overflow (cast) in brdftab/formats/__init__.py, line 40: a value exceeded the "
        "range of the type it was converted to (float32: about 3.4e38) and became infinite; figures computed from it "
        "may be inf or NaN"]
    # end to end: a model of values near the float64 limit; no bare NumPy message reaches the user
    spec = tmp_path / "huge.toml"
    spec.write_text('[model]\nname = "scale"\nfactor = 1e300\n[model.term]\nname = "lambert"\nalbedo = 0.5\n'
                    + TINY_GRID + '[[output]]\npath = "huge.nc"\n')
    proc = _run("validate", spec)
    assert proc.returncode == 1 and "energy" in proc.stdout, proc
    for line in proc.stderr.splitlines():
        assert line.startswith("brdftab: warning: numerical ") and "brdftab/" in line and ", line " in line, line


def test_error_lines_escape_control_characters_of_file_names(tmp_path):
    """A file name is the user's data: an escape sequence in it is shown as \\x1b in the one
    error line, not sent to the terminal (which would recolour it and hide the name)."""
    name = tmp_path / "q\x1b[31m.nc"
    for verb in ("info", "validate"):
        proc = _run(verb, name)
        line = _one_error(proc.stderr, proc.returncode, "q\\x1b[31m.nc")
        assert "\x1b" not in line
