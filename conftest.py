"""pytest settings shared by the tests and the doctests of brdftab/ (both test paths)."""

import contextlib
import hashlib
import inspect
import os
import signal
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
    sources were compiled before (a stamp under the user's cache folder) and numba's cache still
    holds the table kernel, and for runs that execute no test: ``--collect-only``, ``--help``,
    ``--fixtures``, ``--fixtures-per-test``, ``--markers``, ``--setup-only``, ``--setup-plan``.
    A failure, or a warm-up not done within :data:`WARM_TIMEOUT_S`, is reported and the tests
    run all the same (they compile what they need)."""
    parts = [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]
    if str(ROOT) not in parts:
        os.environ["PYTHONPATH"] = os.pathsep.join([str(ROOT), *parts])
    opt = config.option
    if (hasattr(config, "workerinput") or not (config.getoption("numprocesses", None) or 0)
            or opt.collectonly or opt.help or opt.showfixtures or opt.show_fixtures_per_test or opt.markers
            or opt.setuponly or opt.setupplan):
        return
    stamp = _warm_stamp()
    if stamp.exists() and _kernels_on_disk():
        return
    sys.stderr.write("compiling brdftab's kernels once before the tests (tests/_warm.py; about a minute on a "
                     "fresh checkout)\n")
    start = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="brdftab-warm-", ignore_cleanup_errors=True) as folder:
        # each part in a session of its own: a part past the time limit is killed with the
        # commands it started
        procs = [subprocess.Popen([sys.executable, str(ROOT / "tests" / "_warm.py"), part, os.path.join(folder, part)],
                                  cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                                  start_new_session=True)
                 for part in ("f64", "f32", "rgl")]
        errors = []
        try:
            for p in procs:
                try:
                    errors.append(p.communicate(timeout=max(1.0, WARM_TIMEOUT_S - (time.monotonic() - start)))[1]
                                  .strip())
                except subprocess.TimeoutExpired:
                    _kill(p)
                    errors.append(f"not done after {WARM_TIMEOUT_S} s")
        finally:  # (Ctrl-C does not reach the parts' sessions)
            for p in procs:
                _kill(p)
    if all(p.returncode == 0 for p in procs):
        stamp.parent.mkdir(parents=True, exist_ok=True)
        stamp.touch()
        sys.stderr.write(f"compiled brdftab's kernels in {time.monotonic() - start:.0f} s (tests/_warm.py)\n")
    else:
        sys.stderr.write(f"compiling brdftab's kernels before the tests failed: {'; '.join(e for e in errors if e)}\n")


#: The warm-up's time limit [s]: beyond it the tests start and compile what they need.
WARM_TIMEOUT_S = 600


def _kill(proc) -> None:
    """End a warm-up part still running, with the commands it started (its session)."""
    if proc.poll() is None:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()


def _kernels_on_disk() -> bool:
    """Whether numba's cache holds the table kernel (``_interp_kernels.table_eval``), in the
    folder numba itself chooses for it (``NUMBA_CACHE_DIR``, next to the source, or its
    user-wide fallback where that is not writable: numba's cache locators, asked in numba's
    order). A stamp alone would outlive a deleted cache. False where it cannot be told (the
    warm-up then runs: a few seconds when the kernels are on disk)."""
    try:
        from numba.core.caching import CacheImpl

        from brdftab._interp_kernels import table_eval

        fn = table_eval.py_func
        source = inspect.getfile(fn)
        for locator in CacheImpl._locator_classes:
            found = locator.from_function(fn, source)
            if found is not None:
                pattern = f"*.{fn.__qualname__}-{fn.__code__.co_firstlineno}.py*.nbi"
                return any(Path(found.get_cache_path()).glob(pattern))
    except Exception:  # numba's internals moved: warm up
        pass
    return False


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
