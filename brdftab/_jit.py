"""Compiled kernels: the one place that says how brdftab compiles its loops (numba).

Every kernel in the package is compiled with :func:`kernel` (a whole-array loop, run in
parallel over the machine's cores) or :func:`device` (a scalar function a kernel calls and the
compiler inlines). Both

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

import functools
import hashlib
import importlib.util
import inspect
import os
import sys
import tempfile
from pathlib import Path

__all__ = ["kernel", "device", "prange", "cache_dir", "generated_module", "threads", "source_hash", "OPTIONS"]

#: Options of every compiled function (see the module docstring).
OPTIONS = dict(cache=True, error_model="numpy", fastmath=False, nogil=True)


def prange(*args):
    """numba's parallel range inside kernels; the plain ``range`` when called from Python."""
    return range(*args)


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
            import numba

            g = self.py_func.__globals__
            for name, value in list(g.items()):
                if isinstance(value, _Lazy) and value is not self:
                    g[name] = value.compiled()
                elif value is prange:
                    g[name] = numba.prange
            self._compiled = numba.njit(**self.options)(self.py_func)
        return self._compiled

    def __call__(self, *args):
        return self.compiled()(*args)


def kernel(fn=None, *, parallel: bool = True):
    """Compile ``fn`` on first call as a whole-array kernel (``parallel`` loops over
    :func:`prange`)."""
    def wrap(f):
        return _Lazy(f, dict(parallel=parallel, **OPTIONS), False)
    return wrap(fn) if fn is not None else wrap


def device(fn):
    """Compile ``fn`` as a scalar function inlined into the kernels that call it."""
    return _Lazy(fn, dict(inline="always", **OPTIONS), True)


def threads() -> int:
    """Threads a parallel kernel runs on (numba's setting; ``NUMBA_NUM_THREADS`` sets it)."""
    import numba

    return numba.get_num_threads()


def source_hash(*functions) -> str:
    """A short hash of the source text of ``functions`` (plain or :func:`device` ones): part of
    a generated module's name, so editing a component's scalar function compiles anew."""
    h = hashlib.sha256()
    for f in functions:
        f = getattr(f, "py_func", f)
        try:
            h.update(inspect.getsource(f).encode())
        except (OSError, TypeError):
            h.update(f"{f.__module__}.{f.__qualname__}".encode())
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
    spec.loader.exec_module(module)
    _MODULES[name] = module
    return module
