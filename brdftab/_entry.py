"""The ``brdftab`` console entry point: signals are handled from the first instant.

The command line itself imports little (numpy, click), so ``--help`` and ``--version`` answer at
once; a verb's modules (xarray, netCDF4, scipy, the models) take a good part of a second more
and are imported here too, before the verb starts (:func:`brdftab.cli.preload`). A Ctrl-C or
SIGTERM in that window used to print a traceback or end with a signal status. Here the
handlers come first, so an interrupt during start-up ends quietly with 130 (SIGINT) or 143
(SIGTERM), as it does once a command runs. A signal the run inherits as ignored (``SIG_IGN``:
SIGINT of a script's background job, ``nohup``-style launchers) stays ignored from the first
instruction on, as it does once a command runs (:func:`brdftab._signals.handling`).
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys


def _early_term(signum, frame):
    sys.stderr.write("brdftab: terminated while starting; no output written\n")
    sys.stderr.flush()
    os._exit(143)


_interrupted: list = []


def _early_int(signum, frame):
    _interrupted.append(signum)
    raise KeyboardInterrupt


def _stop_starting():
    # nothing has been written yet; exit at once (an interpreter interrupted inside an import
    # would otherwise report death by SIGINT instead of the exit status 130)
    sys.stderr.write("brdftab: interrupted while starting; no output written\n")
    sys.stderr.flush()
    os._exit(130)


def _exit_now(code: int):
    """End the process at once with ``code``: the run is over (its files closed, temporaries
    removed); tearing down the interpreter's modules would take a good part of a second more."""
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os._exit(code)


def _late(signum, frame):
    # a signal after the command has dealt with its outputs (or between the imports and the
    # command): end now with its status, never with a traceback from the interpreter's shutdown
    _exit_now(143 if signum == signal.SIGTERM else 130)


def main():
    previous = {}
    try:
        for s, handler in ((signal.SIGTERM, _early_term), (signal.SIGINT, _early_int)):
            if signal.getsignal(s) is not signal.SIG_IGN:  # an inherited "ignore" is kept
                previous[s] = signal.signal(s, handler)
    except ValueError:  # not the main thread
        pass
    try:
        from .cli import main as cli_main, preload

        preload(sys.argv[1:])  # the verb's modules (xarray, netCDF4, the models) load under these handlers
        if _interrupted:  # an import swallowed the KeyboardInterrupt (a bare except in a library)
            raise KeyboardInterrupt
    except KeyboardInterrupt:
        _stop_starting()
    except ImportError:
        # a C extension whose initialization the interrupt cut short reports ImportError
        if _interrupted:
            _stop_starting()
        raise
    finally:
        for s in previous:
            signal.signal(s, _late)
    code = cli_main(prog_name="brdftab", standalone_mode=False) or 0
    # the run is over, whatever its code: end now (a signal during the interpreter's teardown of
    # xarray, scipy... would otherwise kill the process by that signal after a finished run)
    _exit_now(code)
