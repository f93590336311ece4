"""README.md runs as printed: every shell command, every Python block and every TOML snippet.

The commands run in order, exactly as printed, with bash, in a temporary folder holding a copy
of ``specs/`` (so a command may use what an earlier one wrote, as a reader following the README
would). ``pip install … && COMMAND`` runs COMMAND (the package under test is installed); the
README's ``pytest`` line is the command CI itself runs (``.ci/run``), so it is not run again
from inside the suite. Each command must exit 0 within two minutes.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
LIMIT_S = 120.0


def blocks(lang: str) -> list:
    text = README.read_text(encoding="utf-8")
    return re.findall(r"^```" + re.escape(lang) + r"\n(.*?)^```", text, flags=re.S | re.M)


def commands() -> list:
    out = []
    for block in blocks("sh"):
        for line in block.splitlines():
            line = line.strip()
            if line and not line.startswith("#"):
                out.append(line)
    return out


def runnable(line: str):
    """The part of a README line to run here (None: not run, with the reason in the docstring)."""
    line = re.sub(r"^pip install \S+ && ", "", line)
    return None if line == "pytest" else line


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    d = tmp_path_factory.mktemp("readme")
    shutil.copytree(ROOT / "specs", d / "specs", ignore=shutil.ignore_patterns("*.nc", "*.binary", "*.exr",
                                                                              "*.bsdf"))
    shutil.copytree(ROOT / "data", d / "data")          # the specs' input files (data/ptfe)
    return d


def test_the_readme_has_commands_and_code():
    cmds = commands()
    assert any(c.startswith("pip install . && brdftab tabulate specs/") for c in cmds)
    assert any(c == 'pip install ".[test]" && pytest' for c in cmds)
    assert len(cmds) > 10 and blocks("python") and blocks("toml")


def test_every_shell_command_runs_as_printed(folder):
    bindir = Path(sys.executable).parent
    env = {"PATH": f"{bindir}:/usr/bin:/bin", "HOME": str(folder), "LANG": "C.UTF-8"}
    for line in commands():
        cmd = runnable(line)
        if cmd is None:
            continue
        start = time.monotonic()
        proc = subprocess.run(["bash", "-c", cmd], cwd=folder, env=env, capture_output=True, text=True,
                              timeout=LIMIT_S + 60)
        took = time.monotonic() - start
        assert proc.returncode == 0, f"{line!r} exited {proc.returncode}: {proc.stderr.strip()[-2000:]}"
        assert took < LIMIT_S, f"{line!r} took {took:.0f} s"
        assert "Traceback" not in proc.stderr, proc.stderr


def test_every_python_block_runs(folder):
    # after the shell commands (same module-scoped folder): the blocks use what they wrote
    for code in blocks("python"):
        proc = subprocess.run([sys.executable, "-c", code], cwd=folder, capture_output=True, text=True, timeout=300)
        assert proc.returncode == 0, f"README Python block failed:\n{code}\n{proc.stderr[-3000:]}"


def test_every_toml_snippet_is_a_valid_spec_part(tmp_path):
    if sys.version_info >= (3, 11):
        import tomllib
    else:  # pragma: no cover
        import tomli as tomllib
    from brdftab.checks import configure
    from brdftab.grids import grid_from_config
    from brdftab.spec import build_model

    checked = 0
    for text in blocks("toml"):
        raw = tomllib.loads(text)
        if "model" in raw:
            build_model(raw["model"], "model", ROOT / "specs" / "readme.toml")   # paths as in the spec folder
            checked += 1
        if "grid" in raw:
            grid_from_config({k: v for k, v in raw["grid"].items() if k != "wavelengths_nm"})
            checked += 1
        if "validation" in raw:
            configure({k: v for k, v in raw["validation"].items() if k != "allow_invalid"})
            checked += 1
    assert checked >= 8
