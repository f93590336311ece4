"""Atomic writes: the target is either the complete new file or untouched.

A file is written to a hidden temporary beside the target, ``.<name>.partial-<pid>`` (see
:func:`brdftab._locks.side_name` for very long names), and then renamed onto it. A run that
fails, is interrupted (Ctrl-C) or is terminated (SIGTERM) removes its temporary file. A run
killed with SIGKILL cannot clean up: it leaves at most a hidden temporary, never a partial
target, and the next write to the same target removes such leftovers.

A write that fails because its file system is full says so — ``no space left on <folder>`` —
whatever the library reported (HDF5 reports a full disk as a generic "HDF error").

The other jobs around a write have their own modules: claims and target checks in
:mod:`brdftab._locks`, signals in :mod:`brdftab._signals`, the progress bar in
:mod:`brdftab._progress`.
"""

from __future__ import annotations

import contextlib
import errno
import os
from pathlib import Path

from ._locks import PARTIAL_SUFFIX, _alive, cannot_write, claim, fcntl, side_name
from ._signals import checkpoint
from .errors import BrdftabError

__all__ = ["atomic_path", "completed", "FULL_BELOW"]

_completed: list = []  # targets renamed into place by this process


def completed() -> list:
    """Targets this process has written completely so far (renamed into place), and those its
    worker processes reported written (:func:`written_elsewhere`)."""
    return list(_completed)


def written_elsewhere(targets) -> None:
    """Count ``targets``, written completely by a worker process of this run, as written (an
    interrupted run names them among what it wrote)."""
    _completed.extend(Path(t) for t in targets)


def _partial_name(target: Path, pid: int) -> Path:
    return side_name(target, f"{PARTIAL_SUFFIX}{pid}")


def _remove_stale(target: Path) -> None:
    """Remove temporaries of ``target`` left by runs that died. Called with the target's claim
    held: no other live run writes it, so every other temporary of it is a leftover."""
    prefix = side_name(target, PARTIAL_SUFFIX).name
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
        if pid == os.getpid() or (fcntl is None and _alive(pid)):
            continue
        with contextlib.suppress(OSError):
            p.unlink()


# --------------------------------------------------------------------------------------------
# a full file system

#: A write that fails while less than this many bytes are free on its file system is reported
#: as a full disk: libraries (HDF5) report ENOSPC only as a generic error, and what is left
#: after such a failure is less than one of their chunks (2 MiB for netCDF).
FULL_BELOW = 4 << 20

_FULL_ERRNOS = {errno.ENOSPC, getattr(errno, "EDQUOT", errno.ENOSPC)}


def _out_of_space(folder: Path) -> bool:
    try:
        st = os.statvfs(folder)
    except (OSError, AttributeError):
        return False
    blocks = st.f_bfree if hasattr(os, "geteuid") and os.geteuid() == 0 else st.f_bavail
    if blocks * st.f_frsize < FULL_BELOW:
        return True
    return st.f_files > 0 and st.f_ffree == 0  # no inodes left


def _full(target: Path, exc: BaseException | None = None) -> BrdftabError:
    quota = isinstance(exc, OSError) and exc.errno == getattr(errno, "EDQUOT", None)
    what = "disk quota exceeded on" if quota else "no space left on"
    return BrdftabError(f"{target}: {what} {os.path.abspath(target.parent)} (free some space or write elsewhere)")


# --------------------------------------------------------------------------------------------
# the write

@contextlib.contextmanager
def atomic_path(target, overwrite: bool = False, inputs=()):
    """Yield a temporary path to write; on success rename it onto ``target``.

    Refuses (:class:`BrdftabError`) a target that :func:`brdftab._locks.check_target` refuses
    or that another run has claimed. Errors writing the temporary name the target, not the
    temporary; a full file system is one clear error. Nothing is committed after a signal,
    even one a library swallowed.
    """
    target = Path(target)
    with claim([target], overwrite, inputs):
        _remove_stale(target)
        tmp = _partial_name(target, os.getpid())
        try:
            try:
                yield tmp
                checkpoint()  # a signal received during the write: stop before committing
                with open(tmp, "rb+") as fh:
                    os.fsync(fh.fileno())
            except OSError as exc:
                # netCDF4 reports some HDF5 failures on a full disk as EACCES (Permission denied)
                if exc.errno in _FULL_ERRNOS or _out_of_space(target.parent):
                    raise _full(target, exc) from None
                if exc.filename is not None and os.path.basename(str(exc.filename)) == tmp.name:
                    raise cannot_write(target, exc) from None
                raise
            except BrdftabError:
                raise
            except Exception:
                if _out_of_space(target.parent):  # e.g. "NetCDF: HDF error" on a full disk
                    raise _full(target) from None
                raise
            try:
                if overwrite:
                    os.replace(tmp, target)
                else:
                    try:  # link() refuses an existing target atomically, unlike exists() + replace()
                        os.link(tmp, target)
                    except FileExistsError:
                        raise BrdftabError(f"{target}: already exists (use --overwrite to replace it)") from None
                    tmp.unlink()
            except OSError as exc:
                if exc.errno in _FULL_ERRNOS:
                    raise _full(target, exc) from None
                raise cannot_write(target, exc) from None
            _fsync_dir(target.parent)
            _completed.append(target)
        except BaseException:
            with contextlib.suppress(OSError):
                tmp.unlink()
            raise


def _fsync_dir(folder: Path) -> None:
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
