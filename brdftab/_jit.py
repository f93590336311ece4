"""Compiled kernels: the one place that says how brdftab compiles its loops (numba).

Every kernel in the package is compiled with :func:`kernel` (a whole-array loop, which
:func:`parallel_rows` runs on the machine's cores, one range of rows per thread) or
:func:`device` (a scalar function a kernel calls and the compiler inlines). Both

* compile **once per machine**: numba's on-disk cache, next to the source file when that is
  writable, else in the user's cache folder (numba's own fallback; set ``NUMBA_CACHE_DIR`` to
  choose it), so an install in a read-only location still starts fast after the first run;
* keep **IEEE semantics** (``error_model="numpy"``: 1/0 is inf, 0/0 NaN, never an exception)
  and **no fast-math**: compiled results equal the numpy code they replace to the last few ulp
  (the parity tests hold them to 1e-12 relative);
* compile on their **first call**: importing a module that defines kernels does not import
  numba, so ``brdftab --help`` never loads it.

Kernels that compose registered components (a microfacet model's D, G and F) are generated as
source text by :func:`generated_module`, written to the kernel cache folder
(:func:`cache_dir`) under a name that hashes their text, and imported from there: numba caches
them like any other file, so a composition compiles once per machine, not once per process.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import importlib.util
import inspect
import os
import sys
import tempfile
import threading
from pathlib import Path

__all__ = ["kernel", "device", "prange", "cache_dir", "generated_module", "threads", "parallel_rows", "source_hash",
           "OPTIONS"]

#: Options of every compiled function (see the module docstring).
OPTIONS = dict(cache=True, error_model="numpy", fastmath=False, nogil=True)


def prange(*args):
    """numba's parallel range inside kernels; the plain ``range`` when called from Python."""
    return range(*args)


def safe_cache():
    """Make numba's on-disk cache safe for processes that compile the same function at once
    (installed once, when brdftab first compiles; a no-op without ``fcntl``, i.e. off POSIX).

    numba keeps one index per function that maps each signature to a data file named by the
    first free number, and rewrites it without a lock: two processes that compile two
    signatures of one function at once can both take ``.2.nbc``, and the index then names one
    signature's machine code for the other's arguments (seen in a fresh checkout's test run:
    151 tests failed in the checks' ``_stats_pass`` with "can't unbox array from PyObject").
    Here a lock file per function (beside its index) is held exclusively while an entry is
    saved and shared while one is loaded (where the file system has no ``flock``, numba's
    unlocked behaviour). A lock around each compilation as
    well, so that a second process would wait and load the first one's code, was tried and
    not kept (``.ci/run`` was not faster with it; cause not investigated)."""
    if _SAFE_CACHE:
        return
    with _RESOLVING:
        if _SAFE_CACHE:
            return
        _SAFE_CACHE.append(True)
        try:
            import fcntl
        except ImportError:  # pragma: no cover - not POSIX
            return
        from numba.core import caching

        @contextlib.contextmanager
        def locked(path: str, exclusive: bool = True):
            # (numba's save and load never nest, so the lock need not be re-entrant)
            fd = None
            try:
                fd = os.open(path, os.O_RDONLY | os.O_CREAT, 0o666)  # flock needs no write access
                fcntl.flock(fd, fcntl.LOCK_EX if exclusive else fcntl.LOCK_SH)
            except OSError:
                # a cache folder this process cannot write, or a file system without flock
                # (some NFS and Lustre mounts): numba's own, unlocked behaviour
                if fd is not None:
                    os.close(fd)
                fd = None
            try:
                yield
            finally:
                if fd is not None:
                    os.close(fd)  # closing the descriptor releases the lock

        save, load = caching.IndexDataCacheFile.save, caching.IndexDataCacheFile.load

        def locked_save(self, key, data):
            with locked(self._index_path + ".lock"):
                return save(self, key, data)

        def locked_load(self, key):
            with locked(self._index_path + ".lock", exclusive=False):
                return load(self, key)

        caching.IndexDataCacheFile.save = locked_save
        caching.IndexDataCacheFile.load = locked_load


_SAFE_CACHE: list = []


#: Held while a function's globals are made numba's (re-entrant: a kernel's device functions
#: resolve theirs inside).
_RESOLVING = threading.RLock()


class _Lazy:
    """A function compiled on its first call, so that importing the module that defines it
    does not import numba. A kernel's module-level ``prange`` and the :func:`device` functions
    it calls are swapped for numba's own in the module's namespace when it compiles (numba
    reads them from there)."""

    def __init__(self, fn, options, is_device):
        functools.update_wrapper(self, fn)
        self.py_func = fn
        self.options = options
        self.is_device = is_device
        self._compiled = None

    def compiled(self):
        if self._compiled is None:
            with _RESOLVING:  # threads calling a kernel first at once (parallel_rows) wait here
                if self._compiled is None:
                    import numba

                    safe_cache()

                    # numba reads the globals when it compiles (at the first call): the device
                    # functions must be numba's before any thread can call the dispatcher
                    g = self.py_func.__globals__
                    for name in self.py_func.__code__.co_names:  # the globals the function reads
                        value = g.get(name)
                        if isinstance(value, _Lazy):
                            g[name] = value.compiled()
                        elif value is prange:
                            g[name] = numba.prange
                    self._compiled = numba.njit(**self.options)(self.py_func)  # compiles at its first call
        return self._compiled

    def serial(self):
        """A numba-parallel kernel compiled as a plain loop (for calls off the main thread)."""
        if getattr(self, "_serial", None) is None:
            import types

            f = self.py_func  # a twin under its own name: numba's cache keys entries by name, not flags
            twin = types.FunctionType(f.__code__, f.__globals__, f.__name__ + "_serial", f.__defaults__, f.__closure__)
            twin.__qualname__ = f.__qualname__ + "_serial"
            twin.__module__ = f.__module__
            self._serial = _Lazy(twin, dict(self.options, parallel=False), False).compiled()
        return self._serial

    def __call__(self, *args):
        if self.options.get("parallel") and threading.current_thread() is not threading.main_thread():
            # numba's default threading layer (workqueue) ends the process when two threads
            # launch parallel loops: off the main thread (a thread pool, dask) the plain loop runs
            return self.serial()(*args)
        return self.compiled()(*args)


def kernel(fn=None, *, parallel: bool = False):
    """Compile ``fn`` on first call as a whole-array kernel (with ``parallel``, numba's
    parallel loops over :func:`prange`; by default a serial loop that :func:`parallel_rows`
    runs on several threads)."""
    def wrap(f):
        return _Lazy(f, dict(parallel=parallel, **OPTIONS), False)
    return wrap(fn) if fn is not None else wrap


def device(fn=None, *, inline: bool = False):
    """Compile ``fn`` as a scalar function the kernels call. By default it stays a function
    that LLVM may or may not inline into its callers: numba's own inlining (``inline="always"``,
    on its typed IR) of every device function made the table interpolation kernel take about a
    minute to compile instead of ten seconds.

    ``inline``: inline it on numba's IR (a kernel compiled while ``fn`` comes from numba's
    on-disk cache calls it otherwise: LLVM sees only its machine code). Ask for it for the
    functions a hot loop calls per pair: the table interpolation kernel's stayed calls without
    it and took 40 % longer a pair (brdftab._interp_kernels.table_eval; compiles in ~24 s)."""
    def wrap(f):
        return _Lazy(f, dict(OPTIONS, **({"inline": "always"} if inline else {})), True)
    return wrap(fn) if fn is not None else wrap


def threads() -> int:
    """Threads the kernels run on: ``BRDFTAB_THREADS``, else the cores this process may use."""
    env = os.environ.get("BRDFTAB_THREADS", "")
    if env.strip().isdigit() and int(env) > 0:
        return int(env)
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


#: Rows below which a kernel runs on the calling thread alone (a thread hand-off costs more).
MIN_PARALLEL_ROWS = 1 << 15
_POOL: list = []


def parallel_rows(fn, m: int, min_rows: int = MIN_PARALLEL_ROWS):
    """Call ``fn(lo, hi)`` over ``[0, m)`` split into one contiguous range per thread, in a
    pool of :func:`threads` threads (the kernels release the GIL), and return the results in
    order (on the calling thread alone below ``min_rows`` rows: kernels whose rows cost much
    more than a pair's evaluation pass fewer). Kernels are compiled serial (``parallel=False``): they compile in about half the
    time of numba's parallel loops, and the threads here give the same speed-up."""
    t = threads()
    if t == 1 or m < min_rows:
        return [fn(0, m)]
    if not _POOL or _POOL[0][0] != t:
        from concurrent.futures import ThreadPoolExecutor

        _POOL[:] = [(t, ThreadPoolExecutor(max_workers=t, thread_name_prefix="brdftab-kernel"))]
    edges = [m * k // t for k in range(t + 1)]
    futures = [_POOL[0][1].submit(fn, lo, hi) for lo, hi in zip(edges[:-1], edges[1:])]
    return [f.result() for f in futures]


def source_hash(*functions) -> str:
    """A short hash of the source text of ``functions`` (plain or :func:`device` ones) and of
    every function they call through their module's globals, transitively: part of a
    generated module's name, so editing any function a kernel inlines compiles anew (numba's
    cache alone watches only the file of the kernel itself)."""
    import types

    h = hashlib.sha256()
    seen = set()
    todo = list(functions)
    while todo:
        f = todo.pop(0)
        f = getattr(f, "py_func", f)
        if not isinstance(f, types.FunctionType) or f in seen:
            continue
        seen.add(f)
        try:
            h.update(inspect.getsource(f).encode())
        except (OSError, TypeError):
            h.update(f"{f.__module__}.{f.__qualname__}".encode())
        todo += [f.__globals__.get(name) for name in f.__code__.co_names]
    return h.hexdigest()[:16]


def cache_dir() -> Path:
    """The folder for generated kernel modules: ``BRDFTAB_CACHE_DIR``, else the user's cache
    folder (``XDG_CACHE_HOME`` or ``~/.cache``)/brdftab/kernels, else a temporary folder
    when neither can be written."""
    env = os.environ.get("BRDFTAB_CACHE_DIR")
    candidates = [Path(env)] if env else []
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    candidates += [Path(base) / "brdftab" / "kernels",
                   Path(tempfile.gettempdir()) / f"brdftab-kernels-{os.getuid() if hasattr(os, 'getuid') else 0}"]
    for path in candidates:
        try:
            path.mkdir(parents=True, exist_ok=True)
            probe = path / f".probe-{os.getpid()}"
            probe.write_text("")
            probe.unlink()
            return path
        except OSError:
            continue
    raise OSError("no writable folder for compiled kernels; set BRDFTAB_CACHE_DIR")


_MODULES: dict = {}


def generated_module(prefix: str, source: str):
    """Import the module whose text is ``source`` (generated kernel code), from a file in
    :func:`cache_dir` named ``<prefix>_<hash of the text and numba's version>.py``.

    The file is written once (atomically: a half-written file is never imported) and never
    changed afterwards, so numba's cache of the kernels in it stays valid across processes.
    """
    import numba

    safe_cache()
    digest = hashlib.sha256(f"{numba.__version__}\n{sys.version}\n{source}".encode()).hexdigest()[:20]
    name = f"_brdftab_{prefix}_{digest}"
    if name in _MODULES:
        return _MODULES[name]
    folder = cache_dir()
    path = folder / f"{name}.py"
    if not path.exists() or path.read_text() != source:
        tmp = folder / f".{name}.{os.getpid()}.tmp"
        tmp.write_text(source)
        os.replace(tmp, path)
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # numba's cache finds the kernels' module by name
    spec.loader.exec_module(module)
    _MODULES[name] = module
    return module
