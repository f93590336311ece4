"""pytest settings shared by the tests and the doctests of brdftab/ (both test paths)."""

import hashlib
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent

_PRINT_OPTIONS = np.get_printoptions()


@pytest.fixture(autouse=True)
def _numpy_print_options():
    """Every test and doctest starts with numpy's default print options: a test that imports
    colour-science directly switches the process to numpy 1.13's legacy printing, which would
    change how the doctests' arrays print (brdftab itself imports it keeping the options)."""
    np.set_printoptions(**_PRINT_OPTIONS)
    yield


# --------------------------------------------------------------------------------------------
# one brdftab under test, its numba kernels compiled once per run (tests/_warm.py)

def pytest_configure(config):
    """Subprocesses (``python -m brdftab``, the ``brdftab`` command, scripts) import brdftab
    from this checkout, as the tests do: ``PYTHONPATH`` starts with it. (The installed package
    is checked file by file against the checkout in ``tests/test_packaging.py``.)

    In the controller of a run on several worker processes, brdftab's kernels are compiled once
    (``tests/_warm.py``) before the workers start. numba keeps compiled kernels next to their
    source, but a process that needs a kernel before another has written it compiles it as
    well: on a fresh checkout each worker and every CLI subprocess of the first minutes compiled
    the table kernel again (26 s per value type). Skipped when the kernels of exactly these
    sources were compiled before (a stamp under the user's cache folder); a failure is reported
    and the tests run all the same (they compile what they need)."""
    parts = [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]
    if str(ROOT) not in parts:
        os.environ["PYTHONPATH"] = os.pathsep.join([str(ROOT), *parts])
    if (hasattr(config, "workerinput") or not (config.getoption("numprocesses", None) or 0)
            or config.option.collectonly):
        return
    stamp = _warm_stamp()
    if stamp.exists():
        return
    start = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="brdftab-warm-") as folder:
        procs = [subprocess.Popen([sys.executable, str(ROOT / "tests" / "_warm.py"), part, os.path.join(folder, part)],
                                  cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
                 for part in ("f64", "f32", "rgl")]
        errors = [p.communicate()[1].strip() for p in procs]
    if all(p.returncode == 0 for p in procs):
        stamp.parent.mkdir(parents=True, exist_ok=True)
        stamp.touch()
        sys.stderr.write(f"compiled brdftab's kernels in {time.monotonic() - start:.0f} s (tests/_warm.py)\n")
    else:
        sys.stderr.write(f"compiling brdftab's kernels before the tests failed: {'; '.join(e for e in errors if e)}\n")


def _warm_stamp() -> Path:
    """A file whose presence says the kernels of the checkout's sources (as they are now, for
    this numba and Python) were compiled: named by a hash of the sources' paths, sizes and
    modification times (what numba's cache checks)."""
    import numba

    h = hashlib.sha256(f"{sys.version}|{numba.__version__}".encode())
    for path in sorted((ROOT / "brdftab").rglob("*.py")):
        st = path.stat()
        h.update(f"{path}|{st.st_size}|{st.st_mtime_ns}".encode())
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "brdftab" / "warm" / h.hexdigest()[:32]
