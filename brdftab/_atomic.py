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
from pathlib import Path

from .errors import BrdftabError

__all__ = ["atomic_path", "terminate_as_interrupt"]


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
    if target.exists() and not overwrite:
        raise BrdftabError(f"{target}: already exists (use --overwrite to replace it)")
    if not target.parent.is_dir():
        raise BrdftabError(f"{target}: folder {target.parent} does not exist")
    _remove_stale(target)
    tmp = _partial_name(target, os.getpid())
    try:
        yield tmp
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


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
