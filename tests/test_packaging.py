"""The package a user installs is the one the tests run.

The tests, and every subprocess they start (``conftest.py`` puts the checkout first on
``PYTHONPATH``), import brdftab from the checkout. What ``pip install .`` puts elsewhere is
checked here: every file of the checkout's package is installed, with the same bytes; with an
editable install (the checkout itself), every data file of the package is declared in
``pyproject.toml``'s package data, and every package folder is a package setuptools finds.
"""

from __future__ import annotations

import fnmatch
import os
import subprocess
import sys
from pathlib import Path

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "brdftab"


def _files(root: Path) -> set:
    """The package's files: sources and data, without caches (``__pycache__``: bytecode and
    numba's compiled kernels)."""
    return {p.relative_to(root).as_posix() for p in root.rglob("*") if p.is_file() and "__pycache__" not in p.parts}


def _installed(tmp_path) -> Path:
    """The folder of the brdftab that Python imports outside the checkout: ``PYTHONPATH``
    without the checkout (conftest.py put it first; other entries, e.g. a Spack or Nix
    environment's, stay)."""
    env = dict(os.environ)
    parts = [p for p in env.get("PYTHONPATH", "").split(os.pathsep)
             if p and Path(p).resolve() != ROOT]
    env["PYTHONPATH"] = os.pathsep.join(parts)
    proc = subprocess.run([sys.executable, "-c", "import brdftab; print(brdftab.__file__)"], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, f"brdftab is not installed: {proc.stderr.strip()[-500:]}"
    return Path(proc.stdout.strip()).resolve().parent


def test_the_installed_package_is_the_checkouts(tmp_path):
    installed = _installed(tmp_path)
    ours = _files(PACKAGE)
    assert "models/pyramid_walk.npz" in ours and "checks/report.schema.json" in ours
    if installed == PACKAGE:
        # an editable install: what a wheel would hold is what pyproject.toml declares
        conf = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
        data = conf["package-data"]
        for rel in sorted(ours):
            folder, name = rel.rpartition("/")[0], rel.rpartition("/")[2]
            package = ".".join(["brdftab", *filter(None, folder.split("/"))])
            if not name.endswith(".py"):
                assert any(fnmatch.fnmatch(name, pat) for pat in data.get(package, [])), \
                    f"brdftab/{rel} is not in pyproject.toml's package data of {package!r}: a wheel leaves it out"
            assert (PACKAGE / folder / "__init__.py").is_file(), f"brdftab/{folder} is not a package: a wheel leaves it out"
        assert conf["packages"]["find"]["include"] == ["brdftab*"]
        return
    missing = sorted(ours - _files(installed))
    assert not missing, f"the installed brdftab ({installed}) lacks {missing[:10]}: pip install . again, or declare them"
    differ = sorted(r for r in ours if (PACKAGE / r).read_bytes() != (installed / r).read_bytes())
    assert not differ, f"the installed brdftab ({installed}) is not this checkout: {differ[:10]} differ (pip install .)"
