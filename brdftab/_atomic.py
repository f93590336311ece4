"""Safe file output: claims, atomic writes, signals and progress while writing.

**Atomic writes.** A file is written to a hidden temporary beside the target,
``.<name>.partial-<pid>``, and then renamed onto it. A run that fails, is interrupted
(Ctrl-C) or is terminated (SIGTERM) removes its temporary file; the target is either the
complete new file or untouched. A run killed with SIGKILL cannot clean up: it leaves at most
a hidden temporary, never a partial target, and the next write to the same target removes
such leftovers of dead processes.

**Claims.** Before any work starts, a run claims each of its targets with an advisory lock
file ``.<name>.lock`` beside it (``fcntl.flock``; the kernel releases the lock of a process
that dies, so a lock file left by a killed run is reclaimed by the next one). A second run
aimed at a claimed target is refused at once, not after all its work. Claiming also creates
missing output folders (removed again if the run fails and they are still empty).

**Inputs.** No target may resolve — through symlinks or hard links — to a file the run reads
(the spec, coefficient files, an input table): :func:`check_target` refuses it whatever
``overwrite`` says.

**Signals.** Writers in HDF5/netCDF hold non-reentrant library locks, so SIGINT and SIGTERM
are held back during a write (:func:`deferred_signals`). A writer that calls
:func:`write_step` between slabs reports its progress there, and a held-back signal takes
effect at the next step; for a writer that does not, a note says that the write is being
finished first. SIGTERM raises :class:`Terminated` (a ``KeyboardInterrupt``) so that cleanup
code runs; the command line exits with 143 for it and 130 for SIGINT.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from .errors import BrdftabError

try:  # POSIX
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None

__all__ = ["atomic_path", "check_target", "claim", "same_file", "deferred_signals", "terminate_as_interrupt",
           "Terminated", "write_step", "write_progress", "completed"]


class Terminated(KeyboardInterrupt):
    """Raised in the main thread when the process receives SIGTERM (see :func:`terminate_as_interrupt`)."""


def _partial_name(target: Path, pid: int) -> Path:
    return target.with_name(f".{target.name}.partial-{pid}")


def _lock_name(target: Path) -> Path:
    return target.with_name(f".{target.name}.lock")


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


# --------------------------------------------------------------------------------------------
# targets and inputs

def same_file(a, b) -> bool:
    """True when paths ``a`` and ``b`` name the same file (after symlinks; hard links too)."""
    a, b = Path(a), Path(b)
    try:
        if os.path.realpath(a) == os.path.realpath(b):
            return True
    except (OSError, ValueError):
        return False
    with contextlib.suppress(OSError, ValueError):
        return os.path.samefile(a, b)
    return False


def check_target(target, overwrite: bool = False, inputs=()) -> None:
    """Refuse a target that is an input of the run, a folder, exists (unless ``overwrite``),
    or lies below something that is not a folder.

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
    if target.is_dir():
        raise BrdftabError(f"{target}: is a folder, not a file")
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
_completed: list = []  # targets renamed into place by this process


def completed() -> list:
    """Targets this process has written completely so far (renamed into place)."""
    return list(_completed)


def _key(target: Path) -> str:
    return os.path.join(os.path.realpath(target.parent), target.name)


def _refuse_busy(target: Path, lock: Path) -> BrdftabError:
    pid = ""
    with contextlib.suppress(OSError, ValueError):
        pid = lock.read_text().split()[0]
    who = f"another brdftab run (pid {pid})" if pid else "another brdftab run"
    return BrdftabError(f"{target}: {who} is writing this file; wait for it to finish (lock {lock.name})")


def _cannot_write(target: Path, exc: OSError) -> BrdftabError:
    return BrdftabError(f"{target}: cannot write in folder {target.parent or '.'} ({exc.strerror or exc})")


def _take_lock(target: Path) -> _Held:
    lock = _lock_name(target)
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
            raise _cannot_write(target, exc) from None
        if fcntl is not None:
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


_current_target: list = []  # targets being written (for the note on held-back signals)


@contextlib.contextmanager
def atomic_path(target, overwrite: bool = False, inputs=()):
    """Yield a temporary path to write; on success rename it onto ``target``.

    Refuses (:class:`BrdftabError`) a target that :func:`check_target` refuses or that another
    run has claimed. Errors writing the temporary name the target, not the temporary.
    """
    target = Path(target)
    with claim([target], overwrite, inputs):
        _remove_stale(target)
        tmp = _partial_name(target, os.getpid())
        _current_target.append(target)
        try:
            try:
                yield tmp
                with open(tmp, "rb+") as fh:
                    os.fsync(fh.fileno())
            except OSError as exc:
                if exc.filename is not None and os.path.basename(str(exc.filename)) == tmp.name:
                    raise _cannot_write(target, exc) from None
                raise
            if overwrite:
                os.replace(tmp, target)
            else:
                try:  # link() refuses an existing target atomically, unlike exists() + replace()
                    os.link(tmp, target)
                except FileExistsError:
                    raise BrdftabError(f"{target}: already exists (use --overwrite to replace it)") from None
                tmp.unlink()
            _fsync_dir(target.parent)
            _completed.append(target)
        except BaseException:
            with contextlib.suppress(OSError):
                tmp.unlink()
            raise
        finally:
            _current_target.pop()


def _fsync_dir(folder: Path) -> None:
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


# --------------------------------------------------------------------------------------------
# signals

@dataclass
class _Deferral:
    previous: dict
    received: list = field(default_factory=list)
    steps: bool = False  # the writer calls write_step (so a held-back signal acts soon)
    noted: bool = False


_deferrals: list = []  # active deferred_signals blocks (innermost last)


def _note(text: str) -> None:
    with contextlib.suppress(Exception):
        sys.stderr.write(f"brdftab: {text}\n")
        sys.stderr.flush()


def _deliver(signum, handler) -> None:
    if callable(handler):
        handler(signum, None)
    elif handler == signal.SIG_DFL:
        signal.raise_signal(signum)


@contextlib.contextmanager
def deferred_signals():
    """Hold SIGINT and SIGTERM until the block ends (or the writer's next :func:`write_step`).

    File writers (HDF5/netCDF) hold non-reentrant library locks; an exception raised inside
    them by a signal handler can deadlock their cleanup. Within this block the handlers only
    record the signal. It is acted on at the writer's next :func:`write_step` — between
    slabs, where stopping is safe — or at the end of the block; when the writer does not call
    :func:`write_step`, a note on stderr says the write is being finished first. Python runs
    signal handlers in the main thread only, so this works whatever other threads exist;
    elsewhere it does nothing.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    sigs = (signal.SIGINT, signal.SIGTERM)
    state = _Deferral(previous={})

    def record(signum, frame):
        state.received.append(signum)
        if not state.steps and not state.noted:
            state.noted = True
            what = _current_target[-1].name if _current_target else "the output"
            _note(f"finishing the write of {what} before stopping...")

    state.previous = {s: signal.signal(s, record) for s in sigs}
    _deferrals.append(state)
    try:
        yield
    finally:
        _deferrals.remove(state)
        for s, handler in state.previous.items():
            signal.signal(s, handler)
        if state.received:
            signum = state.received[0]
            state.received.clear()
            _deliver(signum, state.previous[signum])


def _checkpoint() -> None:
    if not _deferrals or threading.current_thread() is not threading.main_thread():
        return
    state = _deferrals[-1]
    state.steps = True
    if state.received:
        signum = state.received[0]
        handler = state.previous[signum]
        if callable(handler):  # a Python handler (KeyboardInterrupt, Terminated): act now
            state.received.clear()
            handler(signum, None)


def _raise_terminated(signum, frame):
    raise Terminated()


@contextlib.contextmanager
def terminate_as_interrupt():
    """Within the block, SIGTERM raises :class:`Terminated` so cleanup code runs."""
    # Errors raised in the block must pass through untouched: no yield inside the try below.
    previous = None
    try:
        if signal.getsignal(signal.SIGTERM) is not _raise_terminated:
            previous = signal.signal(signal.SIGTERM, _raise_terminated)
    except ValueError:  # not in the main thread: nothing to install
        previous = None
    try:
        yield
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


# --------------------------------------------------------------------------------------------
# progress while writing

_observers: list = []


def write_step(done: int, total: int) -> None:
    """Called by file writers between slabs: ``done`` of ``total`` samples are written.

    Updates the "writing" progress bar, and is the point where a SIGINT or SIGTERM received
    during the write takes effect (the temporary file is then removed as usual).
    """
    if _observers:
        with contextlib.suppress(Exception):
            _observers[-1](done, total)
    _checkpoint()


class _WriteBar:
    """A tqdm bar for one write: samples written when the writer reports steps, else the
    elapsed time (refreshed by a small thread while the writer runs)."""

    def __init__(self, label, enabled, delay):
        from tqdm.auto import tqdm

        self.delay = delay
        self.start = time.monotonic()
        self.bar = tqdm(total=None, desc=f"writing {label}", unit="sample", unit_scale=True, delay=delay,
                        disable=None if enabled is None else not enabled, leave=False,
                        bar_format="{desc}: {elapsed}")
        self._stop = threading.Event()
        self._thread = None
        if not self.bar.disable:
            self._thread = threading.Thread(target=self._tick, name="brdftab-write-progress", daemon=True)
            self._thread.start()

    def _tick(self):
        while not self._stop.wait(0.5):
            if time.monotonic() - self.start >= self.delay:
                with contextlib.suppress(Exception):
                    self.bar.refresh()

    def __call__(self, done, total):
        if self.bar.total != total:
            self.bar.total = total
            self.bar.bar_format = None
        self.bar.update(done - self.bar.n)

    def close(self):
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        self.bar.close()


@contextlib.contextmanager
def write_progress(label, progress: bool | None = None, delay: float | None = None):
    """Show a "writing LABEL" progress bar while the block runs.

    ``progress``: True/False, or None for a bar on a terminal only. The bar appears once the
    block has run for ``delay`` seconds (default: the tabulation's progress delay).
    """
    if progress is False:
        yield
        return
    if delay is None:
        from .table import PROGRESS_DELAY

        delay = PROGRESS_DELAY
    bar = _WriteBar(label, progress, max(0.0, delay))
    _observers.append(bar)
    try:
        yield
    finally:
        _observers.remove(bar)
        bar.close()
