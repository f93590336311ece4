"""Progress of the phases after tabulating: the "checking NAME" bar while the checks run, the
"writing NAME" bar while a file is written, and the writers' steps.

A writer calls :func:`write_step` between slabs. That updates the bar of the innermost
:func:`write_progress` block and is a :func:`brdftab._signals.checkpoint`: a SIGINT or SIGTERM
received during the write takes effect there (and the temporary file is removed as usual).
"""

from __future__ import annotations

import contextlib
import threading
import time

from ._signals import checkpoint

__all__ = ["check_progress", "write_progress", "write_step"]

_observers: list = []


def write_step(done: int, total: int) -> None:
    """Called by file writers between slabs: ``done`` of ``total`` samples are written.

    Updates the "writing" progress bar, and is the point where a SIGINT or SIGTERM received
    during the write takes effect.
    """
    if _observers:
        with contextlib.suppress(Exception):
            _observers[-1](done, total)
    checkpoint()


class _PhaseBar:
    """A tqdm bar for one phase (checks, a write): samples written when a writer reports
    steps, else the elapsed time (refreshed by a small thread while the phase runs)."""

    def __init__(self, desc, enabled, delay):
        from tqdm.auto import tqdm

        self.delay = delay
        self.start = time.monotonic()
        self.bar = tqdm(total=None, desc=desc, unit="sample", unit_scale=True, delay=delay,
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
def _phase(desc, progress: bool | None, delay: float | None, observe: bool):
    if progress is False:
        yield
        return
    if delay is None:
        from .table import PROGRESS_DELAY

        delay = PROGRESS_DELAY
    bar = _PhaseBar(desc, progress, max(0.0, delay))
    if observe:
        _observers.append(bar)
    try:
        yield
    finally:
        if observe:
            _observers.remove(bar)
        bar.close()


def write_progress(label, progress: bool | None = None, delay: float | None = None):
    """Show a "writing LABEL" progress bar while the block runs.

    ``progress``: True/False, or None for a bar on a terminal only. The bar appears once the
    block has run for ``delay`` seconds (default: the tabulation's progress delay).
    """
    return _phase(f"writing {label}", progress, delay, observe=True)


def check_progress(label, progress: bool | None = None, delay: float | None = None):
    """Show a "checking LABEL" bar (the elapsed time) while the checks of what is about to be
    written run; ``progress`` and ``delay`` as for :func:`write_progress`."""
    return _phase(f"checking {label}", progress, delay, observe=False)
