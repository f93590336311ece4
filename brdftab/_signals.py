"""Signals: Ctrl-C (SIGINT) and SIGTERM end a run promptly, cleanly and never unnoticed.

**Raising.** On the command line (:func:`handling`) SIGINT raises ``KeyboardInterrupt`` and
SIGTERM raises :class:`Terminated` (a ``KeyboardInterrupt``), so cleanup code runs (temporary
files removed, claims released); the command line exits with 130 and 143 for them. The Python
API gets the same for SIGTERM within :func:`terminate_as_interrupt`.

**Held inside libraries.** A Python signal handler runs at the next bytecode, which may be
inside a C extension that is not ready for an exception there: netCDF4 (Cython) clears any
exception raised while it looks attributes up after a read, so a Ctrl-C during a netCDF read
used to vanish and the command ran on to exit 0; HDF5 holds non-reentrant locks while it
writes. Library calls therefore run in :func:`held_signals` blocks, where the handlers only
record the signal. It takes effect at the next :func:`checkpoint` — between slabs of a read
(:func:`read_array`) or of a write (:func:`brdftab._progress.write_step`), where stopping is
safe — or when the block ends. Reads come in slabs of :data:`READ_SLAB_BYTES`, so a signal
acts within a fraction of a second; a writer that reports no steps says that it finishes the
write first.

**Never lost.** A signal raised by :func:`handling`'s handler stays *pending* until the command
line has dealt with it. Should some library swallow its exception anyway, the next
:func:`checkpoint` raises it again, :func:`brdftab._atomic.atomic_path` does not commit a file
after it, and the command line ends with the signal's exit code instead of 0.

Python runs signal handlers in the main thread only; in other threads all of this does nothing.
"""

from __future__ import annotations

import contextlib
import signal
import sys
import threading
from dataclasses import dataclass

import numpy as np

__all__ = ["Terminated", "handling", "pending", "terminate_as_interrupt", "held_signals", "checkpoint",
           "read_array", "READ_SLAB_BYTES"]

SIGNALS = (signal.SIGINT, signal.SIGTERM)


class Terminated(KeyboardInterrupt):
    """Raised in the main thread when the process receives SIGTERM (see :func:`terminate_as_interrupt`)."""


def _main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


def _exception(signum):
    return Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()


# --------------------------------------------------------------------------------------------
# raising: the command line's handlers

_pending: list = []  # the signal handle() raised for, until the command line has dealt with it


def _handle(signum, frame):
    """SIGINT → KeyboardInterrupt, SIGTERM → Terminated; the signal stays pending."""
    if not _pending:
        _pending.append(signum)
    raise _exception(signum)


def pending():
    """The signal (number) received under :func:`handling`, or None."""
    return _pending[0] if _pending else None


@contextlib.contextmanager
def handling():
    """Within the block SIGINT raises ``KeyboardInterrupt`` and SIGTERM :class:`Terminated`; a
    signal received stays :func:`pending` until the block ends (the command line's ``main``).

    A signal that is ignored (``SIG_IGN``, e.g. SIGINT of a background job) stays ignored.
    """
    if not _main_thread():
        yield
        return
    previous = {}
    for s in SIGNALS:
        if signal.getsignal(s) is not signal.SIG_IGN:
            previous[s] = signal.signal(s, _handle)
    _pending.clear()
    try:
        yield
    finally:
        for s, handler in previous.items():
            if handler is not None:
                signal.signal(s, handler)
        _pending.clear()


def _raise_terminated(signum, frame):
    raise Terminated()


@contextlib.contextmanager
def terminate_as_interrupt():
    """Within the block, SIGTERM raises :class:`Terminated` so cleanup code runs (API runs;
    under :func:`handling` it does already)."""
    # Errors raised in the block must pass through untouched: no yield inside the try below.
    previous = None
    try:
        current = signal.getsignal(signal.SIGTERM)
        if current is not _raise_terminated and current is not _handle and current is not signal.SIG_IGN:
            previous = signal.signal(signal.SIGTERM, _raise_terminated)
    except ValueError:  # not in the main thread: nothing to install
        previous = None
    try:
        yield
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


# --------------------------------------------------------------------------------------------
# held inside libraries

@dataclass
class _Hold:
    writing: str | None  # the file being written (for the note), or None: a read
    steps: bool = False  # the block calls checkpoint (so a held-back signal acts soon)
    noted: bool = False


_holds: list = []      # active held_signals blocks (innermost last)
_received: list = []   # signals recorded while held
_saved: dict = {}      # the handlers the outermost block replaced


def _note(text: str) -> None:
    with contextlib.suppress(Exception):
        sys.stderr.write(f"brdftab: {text}\n")
        sys.stderr.flush()


def _record(signum, frame):
    _received.append(signum)
    hold = _holds[-1] if _holds else None
    if hold is not None and hold.writing is not None and not hold.steps and not hold.noted:
        hold.noted = True
        _note(f"finishing the write of {hold.writing} before stopping...")


def _deliver(signum, handler) -> None:
    if callable(handler):
        handler(signum, None)
    elif handler == signal.SIG_DFL:
        signal.raise_signal(signum)


@contextlib.contextmanager
def held_signals(writing: str | None = None):
    """Hold SIGINT and SIGTERM while the block runs library code; they act at the next
    :func:`checkpoint` or when the block ends.

    ``writing``: the name of the file being written, for the note shown when a signal arrives
    and the block has not called :func:`checkpoint` (a writer that reports no steps). Blocks
    nest; the outermost one installs and restores the handlers.
    """
    if not _main_thread():
        yield
        return
    hold = _Hold(writing)
    outermost = not _holds
    if outermost:
        _received.clear()
        _saved.clear()
        for s in SIGNALS:
            handler = signal.getsignal(s)
            if handler is not signal.SIG_IGN and handler is not None:
                _saved[s] = signal.signal(s, _record)
    _holds.append(hold)
    try:
        yield
    finally:
        _holds.pop()
        if outermost:
            saved = dict(_saved)
            _saved.clear()
            for s, handler in saved.items():
                signal.signal(s, handler)
            if _received:
                signum = _received[0]
                _received.clear()
                _deliver(signum, saved.get(signum))


def checkpoint() -> None:
    """A safe point to stop: act on a signal held back by :func:`held_signals`, or raise again
    a :func:`pending` one whose exception a library swallowed."""
    if not _main_thread():
        return
    if _holds:
        _holds[-1].steps = True
        if _received:
            signum = _received[0]
            handler = _saved.get(signum)
            if callable(handler):  # a Python handler (KeyboardInterrupt, Terminated): act now
                _received.clear()
                handler(signum, None)
    if _pending:
        raise _exception(_pending[0])


# --------------------------------------------------------------------------------------------
# reads in slabs

#: Bytes read from a file in one library call: a signal acts after at most one slab.
READ_SLAB_BYTES = 8 << 20


def read_array(var, slab_bytes: int | None = None) -> np.ndarray:
    """``var``'s values as a numpy array (an xarray ``DataArray`` or ``Variable``).

    Values already in memory are returned as they are. Values in a file are read in slabs
    along the first axis (whole chunks where the file says how it is chunked: netCDF/HDF5,
    zarr) with signals held while the library reads, and a :func:`checkpoint` after each slab: Ctrl-C
    stops a large read within a fraction of a second instead of being lost inside netCDF4.
    """
    variable = getattr(var, "variable", var)
    if getattr(variable, "_in_memory", True) or variable.ndim == 0:
        return np.asarray(variable.values)
    slab_bytes = READ_SLAB_BYTES if slab_bytes is None else slab_bytes
    n0 = variable.shape[0]
    row = max(1, variable.size // max(1, n0)) * variable.dtype.itemsize
    rows = max(1, slab_bytes // row)
    chunks = variable.encoding.get("chunksizes") or variable.encoding.get("chunks")  # netCDF, zarr
    if chunks and chunks[0] and chunks[0] < n0:
        rows = max(int(chunks[0]), rows // int(chunks[0]) * int(chunks[0]))
    out = None
    with held_signals():
        for start in range(0, n0, rows):
            slab = np.asarray(variable[start:start + rows].values)
            if out is None:
                if start + rows >= n0:
                    out = slab
                    break
                out = np.empty(variable.shape, slab.dtype)
            out[start:start + rows] = slab
            checkpoint()
    if out is None:  # an empty first axis
        out = np.asarray(variable.values)
    checkpoint()
    return out
