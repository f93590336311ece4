"""Output targets and claims (brdftab._locks): no output may be an input (the spec, through a
link, or a model's input file), a device, a FIFO, a folder or below a file; an existing file is
replaced only when asked; missing folders are created (and removed again when the run fails);
any file name the file system accepts can be written; one target, one run at a time, and a lock
left by a killed run is stale."""

from __future__ import annotations

import os
import signal
import socket
import stat
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
from _stepped import start_stepped, wait_for

import brdftab
from brdftab import _locks, models
from brdftab.brdf import BRDF
from brdftab.errors import BrdftabError
from brdftab.grids import RusinkiewiczGrid
from brdftab.pipeline import run
from brdftab.spec import Output, Spec, load_spec
from _cli import cli as _cli, names as _names, one_error as _error_line, run as _run

TINY_GRID = '[grid]\ntype = "rusinkiewicz"\nn_theta_h = 3\nn_theta_d = 3\nn_phi_d = 4\n'
GGX = models.create("microfacet", alpha=0.3)


def _spec(folder: Path, output: str = "out.nc", name: str = "s.toml", fmt: str = "") -> Path:
    path = folder / name
    fmt_line = f'format = "{fmt}"\n' if fmt else ""
    path.write_text(f'[model]\nname = "lambert"\nalbedo = 0.5\n{TINY_GRID}[[output]]\npath = "{output}"\n'
                    f"{fmt_line}")
    return path


def _one_error(result, *expected) -> str:
    assert result.exit_code == 2, (result.exit_code, result.stderr)
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("brdftab: error: "), result.stderr
    for text in expected:
        assert text in lines[0], f"{text!r} missing from {lines[0]!r}"
    return lines[0]


def _must_not_tabulate(*args, **kwargs):
    raise AssertionError("the run started its work")


@pytest.fixture(scope="module")
def table_file(tmp_path_factory):
    folder = tmp_path_factory.mktemp("table")
    spec = _spec(folder, output="t.nc")
    assert _cli("tabulate", spec, "--no-progress").exit_code == 0
    return folder / "t.nc"


# --------------------------------------------------------------------------------------------
# 1. An output that resolves to an input is refused, for every command that writes

def _aliases(folder: Path, name: str) -> list:
    """Paths that name ``folder/name``: itself, with ./ and .., a symlink and a hard link."""
    (folder / "sub").mkdir(exist_ok=True)
    (folder / "sym-link").symlink_to(name)
    os.link(folder / name, folder / "hard-link")
    return [folder / name, Path(f"{folder}/./{name}"), Path(f"{folder}/sub/../{name}"), folder / "sym-link",
            folder / "hard-link"]


def test_validate_junit_cannot_replace_the_table_it_checks(tmp_path, table_file):
    table = tmp_path / "t.nc"
    table.write_bytes(table_file.read_bytes())
    before = table.read_bytes()
    for junit in _aliases(tmp_path, "t.nc"):
        result = _cli("validate", table, "--junit", junit)
        _one_error(result, str(junit), "which this run reads")
        assert table.read_bytes() == before
    assert _names(tmp_path) == ["hard-link", "sub", "sym-link", "t.nc"]
    # and a report elsewhere is written
    result = _cli("validate", table, "--junit", tmp_path / "report.xml")
    assert result.exit_code == 0, result.stderr
    assert (tmp_path / "report.xml").read_text().startswith("<?xml")


def test_validate_junit_cannot_replace_a_spec_or_the_config_file(tmp_path):
    spec = _spec(tmp_path)
    (tmp_path / "sub").mkdir()
    config = tmp_path / "checks.toml"
    config.write_text("[validation]\n")
    spec_before, config_before = spec.read_bytes(), config.read_bytes()
    _one_error(_cli("validate", spec, "--junit", tmp_path / "sub" / ".." / "s.toml"), "s.toml", "which this run reads")
    _one_error(_cli("validate", spec, "--config", config, "--junit", config), "checks.toml", "--config file")
    assert spec.read_bytes() == spec_before and config.read_bytes() == config_before


def test_tabulate_and_convert_outputs_through_dot_dot_are_refused(tmp_path, table_file):
    (tmp_path / "sub").mkdir()
    spec = _spec(tmp_path, output='sub/../s.toml"\nformat = "netcdf')
    before = spec.read_bytes()
    _one_error(_cli("tabulate", spec, "--overwrite"), "spec file")
    assert spec.read_bytes() == before
    table = tmp_path / "t.nc"
    table.write_bytes(table_file.read_bytes())
    _one_error(_cli("convert", table, tmp_path / "sub" / ".." / "t.nc", "--overwrite"), "input table")


def test_spec_cannot_be_overwritten_by_its_own_output(tmp_path):
    spec = _spec(tmp_path, output="self.toml", name="self.toml", fmt="netcdf")
    before = spec.read_bytes()
    for extra in ([], ["--overwrite"]):
        proc = _run("tabulate", spec.name, *extra, cwd=tmp_path)
        _error_line(proc.stderr, proc.returncode, "self.toml", "spec file", "reads")
        assert spec.read_bytes() == before
        assert _names(tmp_path) == ["self.toml"]


def test_output_through_a_symlink_to_the_spec_is_refused(tmp_path):
    spec = _spec(tmp_path, output="link.nc")
    (tmp_path / "link.nc").symlink_to(spec.name)
    before = spec.read_bytes()
    result = _cli("tabulate", spec, "--overwrite")
    _error_line(result.stderr, result.exit_code, "link.nc", "spec file")
    assert spec.read_bytes() == before and (tmp_path / "link.nc").is_symlink()


def test_spec_reached_through_a_symlink_is_protected(tmp_path):
    real = _spec(tmp_path, output="real.toml", name="real.toml", fmt="netcdf")
    (tmp_path / "alias.toml").symlink_to("real.toml")
    before = real.read_bytes()
    result = _cli("tabulate", tmp_path / "alias.toml", "--overwrite")
    _error_line(result.stderr, result.exit_code, "real.toml", "spec file")
    assert real.read_bytes() == before


def test_hard_link_to_the_spec_is_refused(tmp_path):
    spec = _spec(tmp_path, output="hard.nc")
    os.link(spec, tmp_path / "hard.nc")
    result = _cli("tabulate", spec, "--overwrite")
    _error_line(result.stderr, result.exit_code, "hard.nc", "spec file")


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
# A target that is a folder, lies below a file, or exists already (unless --overwrite) is
# refused; missing output folders are created (and removed again when the run fails)

def test_output_that_is_a_folder_or_duplicate_is_refused(tmp_path):
    (tmp_path / "out.nc").mkdir()
    with pytest.raises(BrdftabError, match="is a folder"):
        brdftab.save(GGX, tmp_path / "out.nc", grid=RusinkiewiczGrid(2, 2, 2))
    from brdftab.pipeline import run
    from brdftab.spec import load_spec

    (tmp_path / "sub").mkdir()
    spec = tmp_path / "s.toml"
    spec.write_text('[model]\nname = "lambert"\n[grid]\ntype = "rusinkiewicz"\nn_theta_h = 2\nn_theta_d = 2\n'
                    'n_phi_d = 2\n[[output]]\npath = "a.nc"\n[[output]]\npath = "sub/../a.nc"\n')
    with pytest.raises(BrdftabError, match="same file"):
        run(load_spec(spec), progress=False)
    assert not (tmp_path / "a.nc").exists()


def test_output_below_a_file_is_refused(tmp_path):
    (tmp_path / "afile").write_text("x")
    spec = _spec(tmp_path, output="afile/x.nc")
    result = _cli("tabulate", spec)
    _error_line(result.stderr, result.exit_code, "afile", "not a folder")


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


# --------------------------------------------------------------------------------------------
# 4. --overwrite never replaces a device node or a FIFO by a regular file

def test_overwrite_refuses_a_fifo(tmp_path, table_file):
    fifo = tmp_path / "x.nc"
    os.mkfifo(fifo)
    spec = _spec(tmp_path, output="x.nc")
    _one_error(_cli("tabulate", spec, "--overwrite"), "x.nc", "is a FIFO, not a regular file")
    _one_error(_cli("convert", table_file, fifo, "--overwrite"), "x.nc", "is a FIFO")
    _one_error(_cli("validate", table_file, "--junit", fifo), "x.nc", "is a FIFO")
    (tmp_path / "via-link.nc").symlink_to("x.nc")
    _one_error(_cli("convert", table_file, tmp_path / "via-link.nc", "--overwrite"), "is a FIFO")
    assert fifo.is_fifo()
    assert _names(tmp_path) == ["s.toml", "via-link.nc", "x.nc"]  # no lock, no partial


def _special_file(path: Path) -> str:
    """A character device node at ``path`` (the same device as /dev/null; as root), or else a
    Unix socket: never a real system device, which the old code replaced by a regular file."""
    try:
        os.mknod(path, stat.S_IFCHR | 0o666, os.makedev(1, 3))
        return "is a character device, not a regular file"
    except (PermissionError, AttributeError):
        server = socket.socket(socket.AF_UNIX)
        server.bind(str(path))
        server.close()
        return "is a socket, not a regular file"


def test_overwrite_refuses_a_device_node(tmp_path, table_file):
    device = tmp_path / "dev.nc"
    refusal = _special_file(device)
    before = os.stat(device)
    _one_error(_cli("convert", table_file, device, "--overwrite"), "dev.nc", refusal)
    _one_error(_cli("validate", table_file, "--junit", device), "dev.nc", refusal)
    _one_error(_cli("tabulate", _spec(tmp_path, output="dev.nc"), "--overwrite"), "dev.nc", refusal)
    after = os.stat(device)
    assert (after.st_ino, after.st_mode, after.st_rdev) == (before.st_ino, before.st_mode, before.st_rdev)
    assert _names(tmp_path) == ["dev.nc", "s.toml"]  # no lock, no partial


# --------------------------------------------------------------------------------------------
# 8. Any file name the file system accepts can be written (the side files used to pass 255 bytes)

@pytest.mark.parametrize("name", ["a" * 252 + ".nc", "é" * 126 + ".nc", "b" * 239 + ".nc"],
                         ids=["255-ascii", "255-utf8", "242"])
def test_longest_file_names_can_be_written(tmp_path, table_file, name):
    assert len(name.encode()) in (255, 242)
    target = tmp_path / name
    for extra in ([], ["--overwrite"]):
        result = _cli("convert", table_file, target, *extra)
        assert result.exit_code == 0, result.stderr
    assert _names(tmp_path) == [name]
    spec = _spec(tmp_path, output=name)
    result = _cli("tabulate", spec, "--overwrite", "--no-progress")
    assert result.exit_code == 0, result.stderr
    assert _names(tmp_path) == sorted([name, "s.toml"])


def test_side_names_fit_the_file_system_and_stay_distinct(tmp_path):
    long_a, long_b = "x" * 250 + "-a.nc", "x" * 250 + "-b.nc"
    for name in (long_a, long_b, "é" * 126 + ".nc"):
        for suffix in (".lock", f".partial-{4194304}"):
            side = _locks.side_name(tmp_path / name, suffix)
            assert len(os.fsencode(side.name)) <= 255 and side.name.startswith(".") and side.name.endswith(suffix)
            side.name.encode("utf-8")  # no character cut in half
    assert _locks.side_name(tmp_path / long_a, ".lock") != _locks.side_name(tmp_path / long_b, ".lock")
    assert _locks.side_name(tmp_path / "x.nc", ".lock").name == ".x.nc.lock"  # short names as before


# --------------------------------------------------------------------------------------------
# A lock left by a run killed with SIGKILL (exit 137) is stale: the next run takes it over

SLOW_WRITER = textwrap.dedent("""
    import sys, time
    from brdftab import formats
    from brdftab.cli import main

    def slow(table, path, **kw):
        with open(path, "wb") as fh:
            fh.write(b"partial")
            fh.flush()
            time.sleep(float(sys.argv[1]))
            fh.write(b" and the rest")

    formats.register(formats.FileFormat(name="slow", extensions=(".slow",), description="test", read=None,
                                        write=slow))
    main(sys.argv[2:], prog_name="brdftab")
""")


def test_lock_of_a_killed_writer_is_stale(tmp_path):
    (tmp_path / "slow.py").write_text(SLOW_WRITER)
    _spec(tmp_path, output="x.slow")
    first = subprocess.Popen([sys.executable, "slow.py", "60", "tabulate", "s.toml", "--no-progress"], cwd=tmp_path,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        # the writer validates before it writes: on a machine whose kernel caches are empty that
        # compiles the table interpolation first (tens of seconds on a busy machine)
        deadline = time.monotonic() + 300
        while not (tmp_path / ".x.slow.lock").exists() or not any(".partial-" in n for n in _names(tmp_path)):
            assert first.poll() is None and time.monotonic() < deadline, first.communicate()
            time.sleep(0.02)
        first.send_signal(signal.SIGKILL)
        first.communicate(timeout=30)
    finally:
        if first.poll() is None:
            first.kill()
            first.wait()
    assert first.returncode == -signal.SIGKILL  # exit 137 in a shell
    assert f".x.slow.partial-{first.pid}" in _names(tmp_path) and ".x.slow.lock" in _names(tmp_path)
    second = subprocess.run([sys.executable, "slow.py", "0", "tabulate", "s.toml", "--no-progress"], cwd=tmp_path,
                            capture_output=True, text=True, timeout=120)
    assert second.returncode == 0, second.stderr
    assert (tmp_path / "x.slow").read_bytes() == b"partial and the rest"
    assert _names(tmp_path) == ["s.toml", "slow.py", "x.slow"]  # stale lock and temporary removed


def test_stale_lock_of_a_dead_run_is_reclaimed(tmp_path):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    (tmp_path / ".x.nc.lock").write_text(dead.stdout)  # left by a killed run: nobody holds it
    spec = _spec(tmp_path, output="x.nc")
    result = _cli("tabulate", spec)
    assert result.exit_code == 0, result.stderr
    assert _names(tmp_path) == ["s.toml", "x.nc"]


# --------------------------------------------------------------------------------------------
# One target, one run at a time: a second run is refused at the start, before any work

def test_second_run_to_the_same_target_is_refused_at_the_start(tmp_path):
    first = start_stepped(tmp_path)
    try:
        wait_for(tmp_path, ".lock", first)
        started = time.monotonic()
        second = start_stepped(tmp_path, "--overwrite")
        out, err = second.communicate(timeout=60)
        took = time.monotonic() - started
        assert first.poll() is None, "the first run ended before the second was refused"
    finally:
        first.kill()
        first.wait()
    _error_line(err, second.returncode, "x.stepped", "another brdftab run", f"pid {first.pid}")
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
