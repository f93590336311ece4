"""Atomic file output: write to a hidden temporary beside the target, then rename.

A run that fails, is interrupted (Ctrl-C) or is terminated (SIGTERM) removes its temporary
file; the target is either the complete new file or untouched. A run killed with SIGKILL
cannot clean up: it leaves at most a hidden ``.<name>.partial-<pid>`` file, never a partial
target, and the next write to the same target removes such leftovers of dead processes.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
from pathlib import Path

from .errors import BrdftabError

__all__ = ["atomic_path", "deferred_signals", "terminate_as_interrupt"]


def _partial_name(target: Path, pid: int) -> Path:
    return target.with_name(f".{target.name}.partial-{pid}")


def _remove_stale(target: Path) -> None:
    prefix = f".{target.name}.partial-"
    try:
        entries = list(target.parent.iterdir())
    except OSError:
        return
    for p in entries:
        if not p.name.startswith(prefix):
            continue
        try:
            pid = int(p.name[len(prefix):])
        except ValueError:
            continue
        if pid == os.getpid() or _alive(pid):
            continue
        with contextlib.suppress(OSError):
            p.unlink()


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


@contextlib.contextmanager
def atomic_path(target, overwrite: bool = False):
    """Yield a temporary path to write; on success rename it onto ``target``.

    Refuses (:class:`BrdftabError`) when ``target`` exists and ``overwrite`` is false, or when
    its folder does not exist.
    """
    target = Path(target)
    check_target(target, overwrite)
    _remove_stale(target)
    tmp = _partial_name(target, os.getpid())
    try:
        yield tmp
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        if overwrite:
            os.replace(tmp, target)
        else:
            try:  # link() refuses an existing target atomically, unlike exists() + replace()
                os.link(tmp, target)
            except FileExistsError:
                raise BrdftabError(f"{target}: already exists (use --overwrite to replace it)") from None
            tmp.unlink()
        _fsync_dir(target.parent)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def check_target(target, overwrite: bool = False) -> None:
    """Refuse a target that exists (unless ``overwrite``), is a folder, or has no folder."""
    target = Path(target)
    if "\x00" in str(target):
        raise BrdftabError(f"{target!r}: a path cannot contain a NUL character")
    if target.is_dir():
        raise BrdftabError(f"{target}: is a folder, not a file")
    if target.exists() and not overwrite:
        raise BrdftabError(f"{target}: already exists (use --overwrite to replace it)")
    if not target.parent.is_dir():
        raise BrdftabError(f"{target}: folder {target.parent} does not exist")


def _fsync_dir(folder: Path) -> None:
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


@contextlib.contextmanager
def deferred_signals():
    """Hold SIGINT and SIGTERM until the block ends, then act on them as usual.

    File writers (HDF5/netCDF) hold non-reentrant library locks; an exception raised inside
    them by a signal handler can deadlock their cleanup. Within this block the handlers only
    record the signal; at the end the original handler runs (a KeyboardInterrupt then
    interrupts before the temporary file is renamed). Python runs signal handlers in the
    main thread only, so this works whatever other threads exist; elsewhere it does nothing.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    received = []

    def record(signum, frame):
        received.append(signum)

    sigs = (signal.SIGINT, signal.SIGTERM)
    previous = {s: signal.signal(s, record) for s in sigs}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        if received:
            signum = received[0]
            handler = previous[signum]
            if callable(handler):
                handler(signum, None)
            elif handler == signal.SIG_DFL:
                signal.raise_signal(signum)


@contextlib.contextmanager
def terminate_as_interrupt():
    """Within the block, SIGTERM raises KeyboardInterrupt so cleanup code runs."""
    def handler(signum, frame):
        raise KeyboardInterrupt

    try:
        previous = signal.signal(signal.SIGTERM, handler)
    except ValueError:  # not in the main thread
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)
