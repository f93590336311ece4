"""Atomic writes (brdftab._atomic): a full disk is one clear line, exit 2, nothing partial;
errors writing name the target, never the hidden temporary."""

from __future__ import annotations

import dataclasses
import errno
import os
import subprocess
from collections import namedtuple
from pathlib import Path

import pytest

import brdftab
from brdftab import _atomic, formats
from brdftab.grids import RusinkiewiczGrid
from brdftab.table import tabulate
from _cli import cli as _cli, one_error as _one_error, names as _names

TINY_GRID = '[grid]\ntype = "rusinkiewicz"\nn_theta_h = 3\nn_theta_d = 3\nn_phi_d = 4\n'


def _spec(folder: Path, output: str = "out.nc", name: str = "s.toml") -> Path:
    path = folder / name
    path.write_text(f'[model]\nname = "lambert"\nalbedo = 0.5\n{TINY_GRID}[[output]]\npath = "{output}"\n')
    return path


def _full_disk_error(result, target: Path) -> str:
    assert result.exit_code == 2, (result.exit_code, result.stderr)
    lines = result.stderr.splitlines()
    assert len(lines) == 1, result.stderr
    line = lines[0]
    assert line.startswith("brdftab: error: ") and "internal error" not in line and "HDF" not in line, line
    assert f"{target}: no space left on {os.path.abspath(target.parent)}" in line, line
    return line


@pytest.fixture(scope="module")
def source(tmp_path_factory):
    """A table whose netCDF file (about 250 kB) does not fit into 128 kB."""
    folder = tmp_path_factory.mktemp("source")
    table = tabulate(brdftab.models.create("microfacet", alpha=0.3), RusinkiewiczGrid(30, 30, 60), progress=False)
    brdftab.save(table, folder / "src.nc", complevel=1)
    assert (folder / "src.nc").stat().st_size > 200_000
    return folder / "src.nc"


@pytest.fixture
def small_disk(tmp_path, monkeypatch):
    """A folder on a 128 kB file system: a real tmpfs where this process may mount one (root);
    otherwise (fallback, simulated) a folder where the netCDF writer fails as HDF5 does on a
    full disk — a generic "NetCDF: HDF error" after writing part of the file — and
    ``statvfs`` reports no free space."""
    folder = tmp_path / "disk"
    folder.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=128k", "tmpfs", str(folder)],
                             capture_output=True).returncode == 0
    if not mounted:
        fmt = formats.FORMATS["netcdf"]
        real_write = fmt.write

        def failing(table, path, **kw):
            Path(path).write_bytes(b"\x89HDF\r\n\x1a\n partial")
            raise RuntimeError("NetCDF: HDF error")

        monkeypatch.setitem(formats.FORMATS, "netcdf", dataclasses.replace(fmt, write=failing))
        assert real_write is not failing
        real_statvfs = os.statvfs
        Full = namedtuple("Full", "f_bsize f_frsize f_blocks f_bfree f_bavail f_files f_ffree f_favail")

        def statvfs(path):
            if Path(path).resolve() == folder.resolve():
                return Full(4096, 4096, 32, 0, 0, 1000, 900, 900)
            return real_statvfs(path)

        monkeypatch.setattr(_atomic.os, "statvfs", statvfs)
    try:
        yield folder
    finally:
        if mounted:
            subprocess.run(["umount", str(folder)], capture_output=True)
            if os.path.ismount(folder):
                subprocess.run(["umount", "-l", str(folder)], capture_output=True)


def test_full_disk_while_writing_netcdf_is_one_clear_line(small_disk, source):
    target = small_disk / "out.nc"
    result = _cli("convert", source, target)
    _full_disk_error(result, target)
    assert os.listdir(small_disk) == []  # no target, no temporary, no lock
    # a run with --out on the full disk, from a spec: the same
    spec = source.parent / "s.toml"
    spec.write_text('[model]\nname = "microfacet"\nalpha = 0.3\n[grid]\ntype = "rusinkiewicz"\nn_theta_h = 30\n'
                    'n_theta_d = 30\nn_phi_d = 60\n[[output]]\npath = "x.nc"\n')
    result = _cli("tabulate", spec, "--out", small_disk, "--no-progress")
    _full_disk_error(result, small_disk / "x.nc")
    assert os.listdir(small_disk) == []


@pytest.fixture
def enospc_format():
    def write(table, path, **kw):
        with open(path, "wb") as fh:
            fh.write(b"part of it")
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))

    formats.register(formats.FileFormat(name="enospc", extensions=(".enospc",), description="test", read=None,
                                        write=write))
    yield
    formats.FORMATS.pop("enospc", None)


def test_enospc_from_a_plain_write_names_the_target_not_the_temporary(tmp_path, enospc_format):
    spec = tmp_path / "s.toml"
    spec.write_text('[model]\nname = "lambert"\n[grid]\ntype = "rusinkiewicz"\nn_theta_h = 3\nn_theta_d = 3\n'
                    'n_phi_d = 4\n[[output]]\npath = "x.enospc"\n')
    result = _cli("tabulate", spec, "--no-progress")
    line = _full_disk_error(result, tmp_path / "x.enospc")
    assert ".partial-" not in line
    assert sorted(os.listdir(tmp_path)) == ["s.toml"]


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


def test_other_write_errors_on_a_disk_with_room_are_not_called_full(tmp_path):
    fmt = formats.FileFormat(name="broken", extensions=(".broken",), description="test", read=None,
                             write=lambda table, path, **kw: (_ for _ in ()).throw(RuntimeError("NetCDF: HDF error")))
    formats.register(fmt)
    try:
        table = tabulate(brdftab.models.create("lambert"), RusinkiewiczGrid(3, 3, 4), progress=False)
        with pytest.raises(RuntimeError, match="HDF error"):
            formats.write(table, tmp_path / "x.broken")
    finally:
        formats.FORMATS.pop("broken", None)
    assert os.listdir(tmp_path) == []
