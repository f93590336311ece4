"""README.md runs as printed: every shell command, every Python block and every TOML snippet.

The commands run in order, exactly as printed, with bash, in a temporary folder holding a copy
of ``specs/`` (so a command may use what an earlier one wrote, as a reader following the README
would). ``pip install … && COMMAND`` runs COMMAND (the package under test is installed); the
README's ``pytest`` line is the command CI itself runs (``.ci/run``), so it is not run again
from inside the suite. Each command must exit 0 within two minutes.
"""

from __future__ import annotations

import os
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
    shutil.copytree(ROOT / "docs", d / "docs")          # the gallery: its commands remake its images
    _COPIED[d] = {p.relative_to(d).as_posix() for p in d.rglob("*") if p.is_file()}  # the checkout's files
    return d


_COPIED: dict = {}


def test_the_readme_has_commands_and_code():
    cmds = commands()
    assert any(c.startswith("pip install . && brdftab tabulate specs/") for c in cmds)
    assert any(c == 'pip install ".[test]" && pytest' for c in cmds)
    assert len(cmds) > 10 and blocks("python") and blocks("toml")


def test_every_shell_command_runs_as_printed(folder):
    bindir = Path(sys.executable).parent
    env = {"PATH": f"{bindir}:/usr/bin:/bin", "HOME": str(folder), "LANG": "C.UTF-8"}
    if os.environ.get("PYTHONPATH"):  # the package under test: conftest.py puts the checkout first
        env["PYTHONPATH"] = os.environ["PYTHONPATH"]
    # the models' compiled kernels from the user's cache folder, as a reader's second command
    # finds them (HOME is the scratch folder): compiling them again is not what is tested here
    from brdftab._jit import cache_dir

    env["BRDFTAB_CACHE_DIR"] = str(cache_dir())
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


# --------------------------------------------------------------------------------------------
# The README leaves a checkout clean, installs what exists, and its figures are measured

def _ignored(rel: str, patterns: list) -> bool:
    """Whether ``.gitignore``'s ``patterns`` ignore the relative path ``rel`` (the subset of
    gitignore syntax the file uses: ``dir/``, ``*.ext``, ``path/*.ext``)."""
    import fnmatch

    parts = rel.split("/")
    for pat in patterns:
        if pat.endswith("/"):
            if pat.rstrip("/") in parts[:-1]:
                return True
        elif "/" in pat:
            if fnmatch.fnmatch(rel, pat.lstrip("/")):
                return True
        elif any(fnmatch.fnmatch(p, pat) for p in parts):
            return True
    return False


def test_readme_commands_leave_only_ignored_files(folder):
    """After the commands and the Python blocks (earlier in this module), every file they wrote
    in the checkout lies where ``.gitignore`` ignores it: a reader's clone stays clean."""
    patterns = [line.strip() for line in (ROOT / ".gitignore").read_text().splitlines()
                if line.strip() and not line.startswith("#")]
    tracked = _COPIED[folder]
    written = [p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file()]
    # HOME is this folder for the commands: caches under ~/.something are not the checkout's
    written = [w for w in written if not w.startswith(".") and w not in tracked]
    assert "out/gold.nc" in written and "out/ggx.nc" in written  # the commands ran (this module's order)
    stray = [w for w in written if not _ignored(w, patterns)]
    assert not stray, f"README commands leave untracked files: {stray}"


def test_the_ci_snippet_installs_brdftab_from_the_repository():
    (ci,) = [b for b in blocks("yaml") if "brdftab validate" in b]
    installs = [line.strip() for line in ci.splitlines() if "pip install" in line]
    assert installs and all("git+https://github.com/" in line for line in installs), installs


def _readme_text() -> str:
    return " ".join(README.read_text(encoding="utf-8").split())


def test_readme_he_torrance_reversal_figures_are_measured():
    """0.169 is the delta variant's peak; the shipped spec (4.5° cone) peaks at 0.1624."""
    import math

    import numpy as np
    from test_he_torrance import PYROMARK_HT, _albedo_cone, _albedo_smooth

    from brdftab import models
    from brdftab.spec import load_spec

    text = _readme_text()
    m = re.search(r"peaks at θi = (\d+)° \(the paper's \"reversal point\"\) and falls after it\. The peak is "
                  r"([\d.]+) for the ideal \(delta\) specular variant, without `cone_half_width_deg`, and ([\d.]+) "
                  r"for the shipped spec", text)
    assert m, "the README's He-Torrance sentence changed"
    at, delta_peak, cone_peak = float(m.group(1)), float(m.group(2)), float(m.group(3))
    theta = np.radians(np.arange(70.0, 90.0))
    delta = models.create("he-torrance-1991", **PYROMARK_HT)
    rd = _albedo_smooth(lambda a, b: delta.eval(a, b)[:, 0], theta) + delta.specular_reflectance(theta)[:, 0]
    shipped = load_spec(ROOT / "specs" / "pyromark-he-torrance.toml").model
    w = shipped.parameters["cone_half_width"]
    assert math.degrees(w) == pytest.approx(4.5)
    rc = _albedo_smooth(lambda a, b: shipped._diffuse_parts(a, b, None, 1)[:, 0], theta) + _albedo_cone(shipped, theta, w)
    for curve, printed in ((rd, delta_peak), (rc, cone_peak)):
        i = int(np.argmax(curve))
        assert math.degrees(theta[i]) == at
        assert curve[i] == pytest.approx(printed, abs=0.5 * 10 ** -(len(str(printed)) - 2))
    assert abs(rd.max() - rc.max()) > 0.005  # two different figures


def test_readme_torrance_sparrow_horizon_figure_is_a_limit():
    import numpy as np
    from test_torrance_sparrow import FIG8, in_plane

    from brdftab import models

    text = _readme_text()
    m = re.search(r"for ψ = 75°, a rise towards the horizon to the limit ([\d.]+) \(θ → 90°; at exactly 90° the "
                  r"model returns 0", text)
    assert m, "the README's Torrance-Sparrow sentence changed"
    model = models.create("torrance-sparrow-1967", **FIG8)
    near = model.relative(*in_plane(75.0, np.array([90.0 - 1e-6])))[0, 0]
    at = model.relative(*in_plane(75.0, np.array([90.0])))[0, 0]
    assert near == pytest.approx(float(m.group(1)), rel=1e-4)
    assert at == 0.0


def test_readme_small2021_grid_does_not_resolve_the_diffraction_orders():
    """At the peaks of orders 2..26 along the band, the table on the spec's 0.005° lattice holds
    the fraction of the model the README prints (measured on patches of that lattice: the
    interpolation at a point only reads the nodes around it)."""
    import math

    import numpy as np

    from brdftab.geometry import sph_to_vec
    from brdftab.grids import grid_from_config
    from brdftab.spec import load_spec
    from brdftab.table import tabulate

    text = _readme_text()
    m = re.search(r"so at the peaks of orders 2 to 26 the table holds between ([\d.]+) and ([\d.]+) of the model", text)
    assert m, "the README's Small 2021 sentence changed"
    spec = load_spec(ROOT / "specs" / "solar-cell-small2021.toml")
    model, grid = spec.model, spec.grid
    step = 0.005
    assert list(np.round(np.degrees(grid.axes[0].values), 6)) == [20.0, 40.0, 60.0]
    assert np.allclose(np.diff(np.degrees(grid.axes[3].values)), step)  # the lattice the patches reuse
    lam, a = spec.model.parameters["wavelength_nm"] * 1e-9, spec.model.parameters["a"]
    k = np.concatenate([-np.arange(2, 27), np.arange(2, 27)])
    ratios = []
    for ti in (20.0, 40.0, 60.0):
        wi = sph_to_vec(math.radians(ti), math.pi)
        s = math.sin(math.radians(ti))
        y = k * lam / a  # order k on the band's centre line, out of the plane of incidence
        wo = np.stack([np.full_like(y, s), y, np.sqrt(1 - s * s - y * y)], axis=-1)
        dth = np.degrees(np.arccos(wo[:, 2])) - ti
        dph = np.degrees(np.arctan2(wo[:, 1], wo[:, 0]))

        def span(x):  # nodes of the spec's lattice (-3 + i·step) around x, two either side
            return {"start": round(-3 + (math.floor((x.min() + 3) / step) - 2) * step, 3),
                    "stop": round(-3 + (math.ceil((x.max() + 3) / step) + 2) * step, 3), "step": step}

        patch = grid_from_config({"type": "spherical", "relative_to": "specular", "theta_i_deg": [ti],
                                  "phi_i_deg": [180.0], "dtheta_o_deg": span(dth), "dphi_o_deg": span(dph)})
        table = tabulate(model, patch, progress=False)
        ratios.append(table.eval(wi, wo)[:, 0] / model.eval(wi, wo)[:, 0])
    ratios = np.concatenate(ratios)
    assert ratios.min() == pytest.approx(float(m.group(1)), abs=0.005)
    assert ratios.max() == pytest.approx(float(m.group(2)), abs=0.005)
