"""Output targets: checks and claims (advisory locks) before a run does any work.

**Targets.** :func:`check_target` refuses a target that resolves — through ``..``, symbolic
links or hard links — to a file the run reads (the spec, coefficient files, an input table, a
grid file: whatever ``overwrite`` says), a folder, anything but a regular file (a device node,
a FIFO, a socket: ``--overwrite`` never replaces one by a regular file), an existing file
unless ``overwrite``, and a path below something that is not a folder.

**Stores.** A format written as a folder (a zarr store, ``.zarr``) registers its suffix with
:func:`register_store`. Its targets are folders: an existing store is replaced only with
``overwrite``, and a folder that is not such a store, or a file, is never replaced by one.

**Claims.** Before any work starts, a run claims each of its targets with an advisory lock
file beside it, ``.<name>.lock`` (``fcntl.flock``). The kernel releases the lock of a process
that dies, SIGKILL included, so a lock file left by a killed run is stale and the next run
takes it over. A second run aimed at a claimed target is refused at once, not after all its
work. Claiming also creates missing output folders (removed again if the run fails and they
are still empty).

**Side files.** The lock file and the temporary a write goes to (see
:mod:`brdftab._atomic`) are named after the target by :func:`side_name`. For a name so long
that the suffix would pass the file system's limit (255 bytes), the target's name is cut and
a hash of it added, so any name the file system accepts can be written.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import stat
from dataclasses import dataclass
from pathlib import Path

from .errors import BrdftabError

try:  # POSIX
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None

__all__ = ["check_target", "claim", "same_file", "side_name", "register_store", "store_test", "LOCK_SUFFIX",
           "PARTIAL_SUFFIX"]

LOCK_SUFFIX = ".lock"
PARTIAL_SUFFIX = ".partial-"
#: The longest suffix a side file adds to its stem: ``.partial-`` and a pid (Linux: ≤ 7 digits).
_LONGEST_SUFFIX = len(PARTIAL_SUFFIX) + 10


def _name_max(folder: Path) -> int:
    try:
        return int(os.pathconf(folder if str(folder) else ".", "PC_NAME_MAX"))
    except (OSError, ValueError, AttributeError):
        return 255


def _side_stem(target: Path) -> str:
    """``.<name>``, or for a long name ``.<start of name>~<hash>``: short enough that every side
    file name (stem + suffix) fits the file system."""
    stem = f".{target.name}"
    limit = _name_max(_existing_folder(target.parent)) - _LONGEST_SUFFIX
    raw = os.fsencode(stem)
    if len(raw) <= limit:
        return stem
    digest = hashlib.sha256(raw).hexdigest()[:16]
    keep = raw[:max(1, limit - len(digest) - 1)]
    return _cut(keep) + "~" + digest


def _cut(raw: bytes) -> str:
    """``raw`` as text, without a multi-byte character cut in half at its end."""
    for drop in range(4):
        try:
            return raw[:len(raw) - drop].decode("utf-8")
        except UnicodeDecodeError:
            continue
    return os.fsdecode(raw)


def side_name(target, suffix: str) -> Path:
    """The path of the side file of ``target`` with ``suffix`` (``.lock``, ``.partial-<pid>``)."""
    target = Path(target)
    return target.with_name(_side_stem(target) + suffix)


def _existing_folder(folder: Path) -> Path:
    while not folder.exists() and folder.parent != folder:
        folder = folder.parent
    return folder


# --------------------------------------------------------------------------------------------
# targets and inputs

def same_file(a, b) -> bool:
    """True when paths ``a`` and ``b`` name the same file (after ``..`` and symlinks; hard links too)."""
    a, b = Path(a), Path(b)
    try:
        if os.path.realpath(a) == os.path.realpath(b):
            return True
    except (OSError, ValueError):
        return False
    with contextlib.suppress(OSError, ValueError):
        return os.path.samefile(a, b)
    return False


_KINDS = ((stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"), (stat.S_ISFIFO, "a FIFO"),
          (stat.S_ISSOCK, "a socket"))


def _not_regular(target: Path) -> str | None:
    """What ``target`` is when it exists and is not a regular file (after symlinks), else None."""
    try:
        mode = os.stat(target).st_mode
    except (OSError, ValueError):
        return None
    if stat.S_ISREG(mode) or stat.S_ISDIR(mode):
        return None
    for test, what in _KINDS:
        if test(mode):
            return what
    return "not a regular file"  # pragma: no cover - no other kinds on POSIX


#: Suffix (lower case) of a store's target -> (format name, ``is_store(path) -> bool``).
_STORES: dict = {}


def register_store(suffix: str, name: str, is_store) -> None:
    """Targets ending in ``suffix`` are folders written as format ``name``'s stores;
    ``is_store(folder)`` tells whether an existing folder is one (and so may be replaced)."""
    _STORES[suffix.lower()] = (name, is_store)


def store_test(target):
    """``(format name, is_store)`` when ``target`` is a store's path (by its suffix), else None."""
    return _STORES.get(Path(target).suffix.lower())


def check_target(target, overwrite: bool = False, inputs=()) -> None:
    """Refuse a target that is an input of the run, a folder (unless the target is a store's,
    see :func:`register_store`, and the folder is such a store), not a regular file, exists
    (unless ``overwrite``), or lies below something that is not a folder.

    ``inputs`` are the files the run reads (paths, or ``(path, "what it is")`` pairs); a
    target that resolves to one of them is refused whether or not ``overwrite`` is given. A
    missing output folder is not an error: it is created when the target is claimed.
    """
    target = Path(target)
    if "\x00" in str(target):
        raise BrdftabError(f"{target!r}: a path cannot contain a NUL character")
    for item in inputs:
        src, what = item if isinstance(item, tuple) else (item, "an input file")
        if same_file(target, src):
            raise BrdftabError(f"{target}: is {what} {src}, which this run reads; write the output to another "
                               "path")
    store = store_test(target)
    if store is not None:
        name, is_store = store
        if target.is_dir() and not is_store(target):
            raise BrdftabError(f"{target}: is a folder that is not a {name} store; brdftab replaces only a store "
                               "(remove the folder or write to another path)")
        if target.exists() and not target.is_dir():
            raise BrdftabError(f"{target}: is a file; a {target.suffix} output is a folder (a {name} store): remove "
                               "the file or write to another path")
    elif target.is_dir():
        raise BrdftabError(f"{target}: is a folder, not a file")
    kind = _not_regular(target)
    if kind is not None:
        raise BrdftabError(f"{target}: is {kind}, not a regular file; brdftab writes (and replaces) regular "
                           "files only")
    if target.exists() and not overwrite:
        raise BrdftabError(f"{target}: already exists (use --overwrite to replace it)")
    folder = target.parent
    while not folder.exists():
        if folder.is_symlink():  # a dangling link: mkdir would fail
            raise BrdftabError(f"{target}: folder {folder} is a broken symbolic link")
        if folder.parent == folder:
            break
        folder = folder.parent
    if folder.exists() and not folder.is_dir():
        raise BrdftabError(f"{target}: {folder} is not a folder")


# --------------------------------------------------------------------------------------------
# claims (advisory locks) and output folders

@dataclass
class _Held:
    lock: Path
    fd: int
    count: int = 1


_held: dict = {}  # realpath of target -> _Held; claims of this process (re-entrant)


def holds(target) -> bool:
    """True when this process has claimed ``target``."""
    return _key(Path(target)) in _held


def _key(target: Path) -> str:
    return os.path.join(os.path.realpath(target.parent), target.name)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _refuse_busy(target: Path, lock: Path) -> BrdftabError:
    pid = ""
    with contextlib.suppress(OSError, ValueError, IndexError):
        pid = lock.read_text().split()[0]
    who = f"another brdftab run (pid {pid})" if pid else "another brdftab run"
    return BrdftabError(f"{target}: {who} is writing this file; wait for it to finish (lock {lock.name})")


def cannot_write(target: Path, exc: OSError) -> BrdftabError:
    return BrdftabError(f"{target}: cannot write in folder {target.parent or '.'} ({exc.strerror or exc})")


def _take_lock(target: Path) -> _Held:
    lock = side_name(target, LOCK_SUFFIX)
    for _attempt in range(100):
        try:
            if fcntl is None:  # pragma: no cover - no flock: exclusive creation + pid
                fd = os.open(lock, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o644)
            else:
                fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
        except FileExistsError:  # pragma: no cover - fallback path
            try:
                pid = int(lock.read_text().split()[0])
            except (OSError, ValueError, IndexError):
                pid = None
            if pid is not None and not _alive(pid):
                with contextlib.suppress(OSError):
                    lock.unlink()
                continue
            raise _refuse_busy(target, lock) from None
        except OSError as exc:
            raise cannot_write(target, exc) from None
        if fcntl is not None:
            # A lock file whose writer died (even by SIGKILL) is not locked any more: the
            # kernel dropped its flock, so it is taken over here.
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                os.close(fd)
                raise _refuse_busy(target, lock) from None
            # A run releasing its claim unlinks the lock file while holding it: make sure we
            # locked the file that is at the path now, not one just removed.
            try:
                same = os.path.samestat(os.fstat(fd), os.stat(lock))
            except OSError:
                same = False
            if not same:
                os.close(fd)
                continue
        try:
            os.ftruncate(fd, 0)
            os.write(fd, f"{os.getpid()}\n".encode())
        except OSError:
            pass
        return _Held(lock, fd)
    raise _refuse_busy(target, lock)


def _release(held: _Held) -> None:
    with contextlib.suppress(OSError):
        held.lock.unlink()
    with contextlib.suppress(OSError):
        os.close(held.fd)


def _make_folders(folder: Path) -> list:
    """Create ``folder`` and missing parents; returns the folders created (outermost first)."""
    missing = []
    f = folder
    while not f.exists() and f.parent != f:
        missing.append(f)
        f = f.parent
    created = []
    for f in reversed(missing):
        try:
            f.mkdir()
        except FileExistsError:
            continue
        created.append(f)
    return created


@contextlib.contextmanager
def claim(targets, overwrite: bool = False, inputs=()):
    """Claim ``targets`` for this run: check them, create their folders, take their locks.

    Refuses (:class:`BrdftabError`, before anything is written) a target that fails
    :func:`check_target` or that another run has claimed. Re-entrant within a process. On
    leaving the block the locks are released; folders created here are removed again when
    the block failed and they are still empty.
    """
    targets = [Path(t) for t in targets]
    for t in targets:
        check_target(t, overwrite, inputs)
    created, taken = [], []
    ok = False
    try:
        for t in targets:
            try:
                created += _make_folders(t.parent)
            except OSError as exc:
                raise BrdftabError(f"{t}: cannot create folder {t.parent} ({exc.strerror or exc})") from None
            key = _key(t)
            if key in _held:
                _held[key].count += 1
            else:
                _held[key] = _take_lock(t)
            taken.append(key)
        yield targets
        ok = True
    finally:
        for key in reversed(taken):
            held = _held[key]
            held.count -= 1
            if held.count == 0:
                del _held[key]
                _release(held)
        if not ok:
            for f in reversed(created):
                with contextlib.suppress(OSError):
                    f.rmdir()
