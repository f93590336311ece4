"""Helpers the command-line tests share: run brdftab in-process or as a subprocess, read its one
error line, small specs and folder listings."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from click.testing import CliRunner

from brdftab.cli import main

TINY_GRID = '[grid]\ntype = "rusinkiewicz"\nn_theta_h = 3\nn_theta_d = 3\nn_phi_d = 4\n'


def run(*args, cwd=None, timeout=120):
    """``python -m brdftab ARGS`` as a subprocess (a CompletedProcess with text output)."""
    return subprocess.run([sys.executable, "-m", "brdftab", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd, timeout=timeout)


def cli(*args):
    """brdftab in-process (click's CliRunner); an exception other than the exit is a failure."""
    result = CliRunner().invoke(main, [str(a) for a in args])
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    return result


def one_error(stderr: str, code: int, *expected) -> str:
    """The one error line (exit code 2, no traceback), containing every ``expected`` text."""
    assert code == 2, f"exit code {code}, stderr {stderr!r}"
    assert "Traceback" not in stderr, stderr
    lines = stderr.splitlines()
    assert len(lines) == 1, f"expected one line on stderr, got {stderr!r}"
    assert lines[0].startswith("brdftab: error: "), lines[0]
    for text in expected:
        assert text in lines[0], f"{text!r} missing from {lines[0]!r}"
    return lines[0]


def names(folder: Path) -> list:
    return sorted(p.name for p in folder.iterdir())


def partials(folder: Path) -> list:
    return sorted(p.name for p in folder.iterdir() if ".partial-" in p.name)


def spec(folder: Path, output: str = "out.nc", name: str = "s.toml") -> Path:
    """A Lambertian spec on a tiny grid writing ``output``."""
    path = folder / name
    path.write_text(f'[model]\nname = "lambert"\nalbedo = 0.5\n{TINY_GRID}[[output]]\npath = "{output}"\n')
    return path
