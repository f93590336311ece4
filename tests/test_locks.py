"""Output targets and claims (brdftab._locks): no output may be an input, a device or a FIFO;
any file name the file system accepts can be written; a lock left by a killed run is stale."""

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

import pytest
from click.testing import CliRunner

from brdftab import _locks
from brdftab.cli import main

TINY_GRID = '[grid]\ntype = "rusinkiewicz"\nn_theta_h = 3\nn_theta_d = 3\nn_phi_d = 4\n'


def _spec(folder: Path, output: str = "out.nc", name: str = "s.toml") -> Path:
    path = folder / name
    path.write_text(f'[model]\nname = "lambert"\nalbedo = 0.5\n{TINY_GRID}[[output]]\npath = "{output}"\n')
    return path


def _cli(*args):
    result = CliRunner().invoke(main, [str(a) for a in args])
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    return result


def _one_error(result, *expected) -> str:
    assert result.exit_code == 2, (result.exit_code, result.stderr)
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("brdftab: error: "), result.stderr
    for text in expected:
        assert text in lines[0], f"{text!r} missing from {lines[0]!r}"
    return lines[0]


def _names(folder: Path) -> list:
    return sorted(p.name for p in folder.iterdir())


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
        deadline = time.monotonic() + 60
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
