"""Command-line and file-safety hardening: every case here was a defect with a reproduction.

Process-level behaviour (signals, pipes, exit codes) runs ``python -m brdftab`` (or a small
script that registers a test format and then runs the command line) as a real subprocess;
the rest runs in-process through ``click.testing.CliRunner``.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
from click.testing import CliRunner

import brdftab
from brdftab import _locks, _progress, formats
from brdftab.brdf import BRDF
from brdftab.cli import main
from brdftab.errors import BrdftabError
from brdftab.grids import RusinkiewiczGrid
from brdftab.pipeline import run
from brdftab.spec import Output, Spec, load_spec

SPECS = Path(__file__).resolve().parent.parent / "specs"
GGX_GOLD = SPECS / "ggx-gold.toml"

TINY_GRID = '[grid]\ntype = "rusinkiewicz"\nn_theta_h = 3\nn_theta_d = 3\nn_phi_d = 4\n'


def _spec(folder: Path, output: str = "out.nc", name: str = "s.toml", extra: str = "", fmt: str = "") -> Path:
    path = folder / name
    fmt_line = f'format = "{fmt}"\n' if fmt else ""
    path.write_text(f'{extra}[model]\nname = "lambert"\nalbedo = 0.5\n{TINY_GRID}[[output]]\npath = "{output}"\n'
                    f"{fmt_line}")
    return path


def _run(*args, cwd=None, timeout=120, **kw):
    return subprocess.run([sys.executable, "-m", "brdftab", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd, timeout=timeout, **kw)


def _cli(*args):
    result = CliRunner().invoke(main, [str(a) for a in args])
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    return result


def _one_error(stderr: str, code: int, *expected, exit_code: int = 2) -> str:
    assert code == exit_code, f"exit code {code}, stderr {stderr!r}"
    assert "Traceback" not in stderr, stderr
    lines = stderr.splitlines()
    assert len(lines) == 1, f"expected one line on stderr, got {stderr!r}"
    assert lines[0].startswith("brdftab: error: "), lines[0]
    for text in expected:
        assert text in lines[0], f"{text!r} missing from {lines[0]!r}"
    return lines[0]


def _names(folder: Path) -> list:
    return sorted(p.name for p in folder.iterdir())


# --------------------------------------------------------------------------------------------
# 1. No output may be a file the run reads

def test_spec_cannot_be_overwritten_by_its_own_output(tmp_path):
    spec = _spec(tmp_path, output="self.toml", name="self.toml", fmt="netcdf")
    before = spec.read_bytes()
    for extra in ([], ["--overwrite"]):
        proc = _run("tabulate", spec.name, *extra, cwd=tmp_path)
        _one_error(proc.stderr, proc.returncode, "self.toml", "spec file", "reads")
        assert spec.read_bytes() == before
        assert _names(tmp_path) == ["self.toml"]


def test_output_through_a_symlink_to_the_spec_is_refused(tmp_path):
    spec = _spec(tmp_path, output="link.nc")
    (tmp_path / "link.nc").symlink_to(spec.name)
    before = spec.read_bytes()
    result = _cli("tabulate", spec, "--overwrite")
    _one_error(result.stderr, result.exit_code, "link.nc", "spec file")
    assert spec.read_bytes() == before and (tmp_path / "link.nc").is_symlink()


def test_spec_reached_through_a_symlink_is_protected(tmp_path):
    real = _spec(tmp_path, output="real.toml", name="real.toml", fmt="netcdf")
    (tmp_path / "alias.toml").symlink_to("real.toml")
    before = real.read_bytes()
    result = _cli("tabulate", tmp_path / "alias.toml", "--overwrite")
    _one_error(result.stderr, result.exit_code, "real.toml", "spec file")
    assert real.read_bytes() == before


def test_hard_link_to_the_spec_is_refused(tmp_path):
    spec = _spec(tmp_path, output="hard.nc")
    os.link(spec, tmp_path / "hard.nc")
    result = _cli("tabulate", spec, "--overwrite")
    _one_error(result.stderr, result.exit_code, "hard.nc", "spec file")


class _ReadsAFile(BRDF):
    """A model that declares a coefficient file it reads."""

    name = "reads-a-file"

    def __init__(self, path):
        self.input_files = [path]

    def _eval(self, wi, wo, lam, n):
        return np.full((wi.shape[0], n), 0.1)


def test_model_input_files_cannot_be_outputs(tmp_path):
    coeffs = tmp_path / "coeffs.nc"
    coeffs.write_bytes(b"coefficients")
    spec = Spec(path=tmp_path / "s.toml", sha256="", model=_ReadsAFile(coeffs), grid=RusinkiewiczGrid(2, 2, 2),
                wavelengths=None, outputs=[Output(coeffs, "netcdf", {})], validation={"allow_invalid": False})
    assert (coeffs, "an input file of the model") in spec.inputs
    with pytest.raises(BrdftabError, match="coeffs.nc: is an input file of the model"):
        run(spec, overwrite=True, progress=False)
    assert coeffs.read_bytes() == b"coefficients"


# --------------------------------------------------------------------------------------------
# 9. Missing output folders are created (and removed again when the run fails)

def test_out_folder_and_output_subfolders_are_created(tmp_path):
    spec = _spec(tmp_path, output="sub/deeper/x.nc")
    result = _cli("tabulate", spec)
    assert result.exit_code == 0, result.stderr
    assert _names(tmp_path / "sub" / "deeper") == ["x.nc"]
    out = tmp_path / "new" / "out"
    result = _cli("tabulate", spec, "--out", out)
    assert result.exit_code == 0, result.stderr
    assert _names(out / "sub" / "deeper") == ["x.nc"]


def test_folders_created_for_a_refused_run_are_removed(tmp_path):
    spec = Spec(path=tmp_path / "s.toml", sha256="", model=_Broken(), grid=RusinkiewiczGrid(3, 3, 3),
                wavelengths=None, outputs=[Output(tmp_path / "a" / "b" / "x.nc", "netcdf", {})],
                validation={"allow_invalid": False})
    with pytest.raises(BrdftabError, match="refusing"):
        run(spec, progress=False)
    assert _names(tmp_path) == []


class _Broken(BRDF):
    name = "broken"

    def _eval(self, wi, wo, lam, n):
        return np.full((wi.shape[0], n), np.nan)


def test_output_below_a_file_is_refused(tmp_path):
    (tmp_path / "afile").write_text("x")
    spec = _spec(tmp_path, output="afile/x.nc")
    result = _cli("tabulate", spec)
    _one_error(result.stderr, result.exit_code, "afile", "not a folder")


# --------------------------------------------------------------------------------------------
# 10. --debug after the verb; click usage errors are one line with exit code 2

def test_debug_after_the_verb_shows_the_traceback(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('[model]\nname = "nosuch"\n')
    proc = _run("tabulate", bad, "--debug")
    assert "Traceback" in proc.stderr and "SpecError" in proc.stderr
    proc = _run("--debug", "tabulate", bad)
    assert "Traceback" in proc.stderr
    proc = _run("tabulate", bad)
    _one_error(proc.stderr, proc.returncode, "bad.toml")


@pytest.mark.parametrize("args, expected", [
    (["eval", GGX_GOLD, "--wi-deg", "30,0"], ["--wo-deg"]),                                   # missing option
    (["eval", SPECS, "--wi-deg", "30,0", "--wo-deg", "30,180"], ["is a directory"]),         # folder as spec
    (["tabulate", SPECS], ["is a directory"]),
    (["eval", GGX_GOLD, "--wi-deg", "30,0", "--wo-deg", "30,180", "--wavelength-nm", "abc"],
     ["--wavelength-nm", "abc"]),                                                            # not a number
    (["tabulate", GGX_GOLD, "--no-such-option"], ["--no-such-option"]),
    (["nosuchverb"], ["nosuchverb"]),
    (["tabulate"], ["SPEC"]),
])
def test_usage_errors_are_one_line(args, expected):
    result = _cli(*args)
    _one_error(result.stderr, result.exit_code, *expected)
    assert result.stdout == ""


def test_usage_error_subprocess():
    proc = _run("eval", GGX_GOLD, "--wi-deg", "30,0")
    _one_error(proc.stderr, proc.returncode, "--wo-deg")
    assert proc.stdout == ""


# --------------------------------------------------------------------------------------------
# 11. A closed pipe ends quietly; deep nesting is one clear line; a BOM is accepted

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


@pytest.mark.parametrize("text", [
    "description = " + "[" * 2000 + "]" * 2000 + "\n",           # deeper than the TOML parser recurses
    "description = " + "[" * 100 + "]" * 100 + "\n",             # parsed, but deeper than any spec needs
    "".join(f"[model{'.term' * i}]\nname = 'scale'\nfactor = 1\n" for i in range(120)),
], ids=["arrays-2000", "arrays-100", "models-120"])
def test_deeply_nested_spec_is_one_clear_line(tmp_path, text):
    spec = tmp_path / "deep.toml"
    spec.write_text(text)
    proc = _run("tabulate", spec)
    line = _one_error(proc.stderr, proc.returncode, "deep.toml", "nested too deeply")
    assert "internal error" not in line


def test_utf8_bom_is_accepted(tmp_path):
    spec = _spec(tmp_path, output="bom.nc")
    spec.write_bytes(b"\xef\xbb\xbf" + spec.read_bytes())
    result = _cli("eval", spec, "--wi-deg", "30,0", "--wo-deg", "30,180", "--json")
    assert result.exit_code == 0, result.stderr
    assert json.loads(result.stdout)["channels"]["mono"] == pytest.approx(0.5 / np.pi)
    result = _cli("tabulate", spec)
    assert result.exit_code == 0, result.stderr
    assert (tmp_path / "bom.nc").is_file()


# --------------------------------------------------------------------------------------------
# 12. Errors writing name the target, never the hidden temporary

def _register(name, write, read=None):
    fmt = formats.FileFormat(name=name, extensions=(f".{name}",), description="test", read=read, write=write)
    formats.register(fmt)
    return fmt


@pytest.fixture
def denied_format():
    def write(table, path, **kw):
        raise PermissionError(13, "Permission denied", str(path))

    _register("denied", write)
    yield
    formats.FORMATS.pop("denied", None)


def test_write_error_names_the_target_not_the_temporary(tmp_path, denied_format):
    spec = _spec(tmp_path, output="x.denied")
    result = _cli("tabulate", spec)
    line = _one_error(result.stderr, result.exit_code, "x.denied", "Permission denied")
    assert ".partial-" not in line
    assert _names(tmp_path) == ["s.toml"]


def test_unwritable_folder_is_refused_before_any_work(tmp_path, monkeypatch):
    real_open = os.open

    def deny_locks(path, *args, **kw):
        if str(path).endswith(".lock"):
            raise PermissionError(13, "Permission denied", str(path))
        return real_open(path, *args, **kw)

    monkeypatch.setattr(_locks.os, "open", deny_locks)
    monkeypatch.setattr("brdftab.pipeline.tabulate", _must_not_tabulate)
    with pytest.raises(BrdftabError) as exc:
        run(load_spec(_spec(tmp_path, output="x.nc")), progress=False)
    assert "x.nc: cannot write in folder" in str(exc.value) and ".lock" not in str(exc.value)


def _must_not_tabulate(*args, **kwargs):
    raise AssertionError("the run started its work")


# --------------------------------------------------------------------------------------------
# 13. SIGTERM exits 143; a signal during a write acts at once; one target, one run at a time

STEPPED_WRITER = textwrap.dedent("""
    import sys, time
    from brdftab import formats
    from brdftab._progress import write_step
    from brdftab.cli import main

    def stepped(table, path, **kw):
        # 10 s of writing in 0.1 s steps, reporting each step
        with open(path, "wb") as fh:
            for i in range(100):
                fh.write(b"x" * 1000)
                fh.flush()
                time.sleep(0.1)
                write_step(i + 1, 100)

    formats.register(formats.FileFormat(name="stepped", extensions=(".stepped",), description="test",
                                        read=None, write=stepped))
    main(sys.argv[1:], prog_name="brdftab")
""")


def _start_stepped(tmp_path: Path, *args):
    (tmp_path / "stepped.py").write_text(STEPPED_WRITER)
    if not (tmp_path / "s.toml").exists():
        _spec(tmp_path, output="x.stepped")
    return subprocess.Popen([sys.executable, "stepped.py", "tabulate", "s.toml", "--no-progress", *args],
                            cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wait_for(tmp_path: Path, marker: str, proc, timeout=60):
    deadline = time.time() + timeout
    while not any(marker in p.name for p in tmp_path.iterdir()):
        assert proc.poll() is None and time.time() < deadline, proc.communicate()
        time.sleep(0.02)


@pytest.mark.parametrize("sig, code, word", [(signal.SIGTERM, 143, "terminated"),
                                             (signal.SIGINT, 130, "interrupted")])
def test_signal_during_a_stepped_write_acts_at_the_next_step(tmp_path, sig, code, word):
    proc = _start_stepped(tmp_path)
    try:
        _wait_for(tmp_path, ".partial-", proc)
        time.sleep(0.3)
        sent = time.monotonic()
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=30)
        took = time.monotonic() - sent
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == code, err
    assert err.splitlines() == [f"brdftab: {word}; no output written"]
    assert took < 3.0, f"the write went on for {took:.1f} s after the signal"
    assert _names(tmp_path) == ["s.toml", "stepped.py"]


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


def test_second_run_to_the_same_target_is_refused_at_the_start(tmp_path):
    first = _start_stepped(tmp_path)
    try:
        _wait_for(tmp_path, ".lock", first)
        started = time.monotonic()
        second = _start_stepped(tmp_path, "--overwrite")
        out, err = second.communicate(timeout=60)
        took = time.monotonic() - started
        assert first.poll() is None, "the first run ended before the second was refused"
    finally:
        first.kill()
        first.wait()
    _one_error(err, second.returncode, "x.stepped", "another brdftab run", f"pid {first.pid}")
    assert took < 8.0


def test_lock_held_by_another_process_refuses_before_tabulating(tmp_path, monkeypatch):
    spec = load_spec(_spec(tmp_path, output="x.nc"))
    holder = subprocess.Popen([sys.executable, "-c", textwrap.dedent(f"""
        import fcntl, os, sys, time
        fd = os.open({str(tmp_path / '.x.nc.lock')!r}, os.O_RDWR | os.O_CREAT)
        fcntl.flock(fd, fcntl.LOCK_EX)
        os.write(fd, str(os.getpid()).encode())
        print("locked", flush=True)
        time.sleep(60)
    """)], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        monkeypatch.setattr("brdftab.pipeline.tabulate", _must_not_tabulate)
        with pytest.raises(BrdftabError, match="another brdftab run"):
            run(spec, progress=False)
    finally:
        holder.kill()
        holder.wait()
    assert not (tmp_path / "x.nc").exists()


def test_stale_lock_of_a_dead_run_is_reclaimed(tmp_path):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    (tmp_path / ".x.nc.lock").write_text(dead.stdout)  # left by a killed run: nobody holds it
    spec = _spec(tmp_path, output="x.nc")
    result = _cli("tabulate", spec)
    assert result.exit_code == 0, result.stderr
    assert _names(tmp_path) == ["s.toml", "x.nc"]


# --------------------------------------------------------------------------------------------
# 14. The progress bar covers the write

def test_progress_bar_covers_the_write(tmp_path, monkeypatch):
    from brdftab import table as table_module

    monkeypatch.setattr(table_module, "PROGRESS_DELAY", 0.0)
    spec = _spec(tmp_path, output="x.nc")
    result = _cli("tabulate", spec, "--progress")
    assert result.exit_code == 0, result.stderr
    assert "tabulating" in result.stderr and "writing x.nc" in result.stderr
    result = _cli("tabulate", spec, "--overwrite", "--no-progress")
    assert result.exit_code == 0 and result.stderr == ""


# --------------------------------------------------------------------------------------------
# 15. eval picks the reader by content

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


# --------------------------------------------------------------------------------------------
# 16. info shows description, spec file and parameters readably

def test_info_text_is_readable(tmp_path):
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


# --------------------------------------------------------------------------------------------
# 17. brdftab.save does not replace a file unless asked

def test_save_refuses_to_replace_unless_overwrite(tmp_path):
    model = brdftab.models.create("lambert", albedo=0.5)
    path = tmp_path / "x.nc"
    path.write_bytes(b"keep me")
    with pytest.raises(BrdftabError, match="already exists"):
        brdftab.save(model, path, grid=RusinkiewiczGrid(2, 2, 2))
    assert path.read_bytes() == b"keep me"
    brdftab.save(model, path, grid=RusinkiewiczGrid(2, 2, 2), overwrite=True)
    assert brdftab.open(path).values.max() == pytest.approx(0.5 / np.pi)
    assert _names(tmp_path) == ["x.nc"]
