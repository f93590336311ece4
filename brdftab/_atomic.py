"""Atomic writes: the target is either the complete new file or untouched.

A file is written to a hidden temporary beside the target, ``.<name>.partial-<pid>`` (see
:func:`brdftab._locks.side_name` for very long names), and then renamed onto it. A run that
fails, is interrupted (Ctrl-C) or is terminated (SIGTERM) removes its temporary file. A run
killed with SIGKILL cannot clean up: it leaves at most a hidden temporary, never a partial
target, and the next write to the same target removes such leftovers.

A store written as a folder (zarr, ``.zarr``) is written the same way: into the hidden
temporary folder, renamed into place only when complete (``renameat2`` with
``RENAME_NOREPLACE`` refuses an existing target atomically). Replacing an existing store
(``overwrite``) swaps the two folders in one step (``RENAME_EXCHANGE``) and then removes the
old one; where the file system cannot swap, the old store is first renamed aside, so the target
is at every moment the old store, nothing, or the new store — never part of one. A temporary or
set-aside folder left by a killed run is removed by the next write like a temporary file.

A write that fails because its file system is full says so — ``no space left on <folder>`` —
whatever the library reported (HDF5 reports a full disk as a generic "HDF error").

The other jobs around a write have their own modules: claims and target checks in
:mod:`brdftab._locks`, signals in :mod:`brdftab._signals`, the progress bar in
:mod:`brdftab._progress`.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import os
import shutil
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


def _partial_name(target: Path, pid) -> Path:
    return side_name(target, f"{PARTIAL_SUFFIX}{pid}")


#: Suffix of the name an old store is renamed to while a new one takes its place (where the
#: file system cannot swap two folders in one step): ``.<name>.partial-<pid>o``.
_ASIDE = "o"


def _remove(path: Path) -> None:
    """Remove a temporary: a file, or a folder (a store) with everything in it."""
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        with contextlib.suppress(OSError):
            path.unlink()


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
        tail = p.name[len(prefix):]
        try:
            pid = int(tail[:-len(_ASIDE)] if tail.endswith(_ASIDE) else tail)
        except ValueError:
            continue
        if pid == os.getpid() or (fcntl is None and _alive(pid)):
            continue
        _remove(p)


# --------------------------------------------------------------------------------------------
# a full file system

#: A write that fails while less than this many bytes are free on its file system is reported
#: as a full disk: libraries (HDF5) report ENOSPC only as a generic error, and what is left
#: after such a failure is less than one of their chunks (1 MiB for netCDF).
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
                folder = tmp.is_dir()
                if folder:
                    _fsync_tree(tmp)
                else:
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
            if not folder and target.is_dir():  # a store's path (.zarr) given to a file format
                raise BrdftabError(f"{target}: is a folder, not a file")
            try:
                if folder:
                    _commit_folder(tmp, target, overwrite)
                elif overwrite:
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
            _remove(tmp)
            raise


# --------------------------------------------------------------------------------------------
# a folder (a store) renamed into place

_RENAME_NOREPLACE, _RENAME_EXCHANGE = 1, 2
_AT_FDCWD = -100


def _renameat2(src: Path, dst: Path, flags: int) -> bool:
    """Linux ``renameat2(src, dst, flags)``: True when done, False when the system or the file
    system does not offer it (the caller falls back); other failures raise OSError."""
    try:
        fn = ctypes.CDLL(None, use_errno=True).renameat2
    except (OSError, AttributeError, TypeError):
        return False
    fn.argtypes = (ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint)
    if fn(_AT_FDCWD, os.fsencode(src), _AT_FDCWD, os.fsencode(dst), flags) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.ENOSYS, errno.EINVAL, getattr(errno, "ENOTSUP", errno.EINVAL)):
        return False
    raise OSError(err, os.strerror(err), str(dst))


def _exists_error(target: Path) -> BrdftabError:
    return BrdftabError(f"{target}: already exists (use --overwrite to replace it)")


def _commit_folder(tmp: Path, target: Path, overwrite: bool) -> None:
    """Rename the complete folder ``tmp`` onto ``target``: refused when ``target`` exists (unless
    ``overwrite``); an existing store is swapped out in one step and then removed."""
    if overwrite and os.path.lexists(target):
        if _renameat2(tmp, target, _RENAME_EXCHANGE):
            _remove(tmp)  # the old store, now under the temporary name
            return
        aside = _partial_name(target, f"{os.getpid()}{_ASIDE}")
        os.rename(target, aside)
        try:
            os.rename(tmp, target)
        except BaseException:
            with contextlib.suppress(OSError):
                os.rename(aside, target)  # the old store back in place
            raise
        _remove(aside)
        return
    try:
        if _renameat2(tmp, target, _RENAME_NOREPLACE):
            return
        if os.path.lexists(target):
            raise _exists_error(target)
        # rename() fails on an existing file or a non-empty folder: nothing is ever replaced
        os.rename(tmp, target)
    except (FileExistsError, IsADirectoryError, NotADirectoryError):
        raise _exists_error(target) from None
    except OSError as exc:
        if exc.errno == errno.ENOTEMPTY:
            raise _exists_error(target) from None
        raise


def _fsync_tree(folder: Path) -> None:
    """fsync every file and folder below ``folder`` (a store is complete on disk before it is
    renamed into place)."""
    for root, _dirs, files in os.walk(folder):
        for name in files:
            fd = os.open(os.path.join(root, name), os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
        _fsync_dir(Path(root))


def _fsync_dir(folder: Path) -> None:
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
