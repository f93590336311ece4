"""The ``brdftab`` console entry point: signals are handled from the first instant.

Importing the command line (numpy, xarray, netCDF4) takes a good part of a second; a Ctrl-C or
SIGTERM in that window used to print a traceback or end with a signal status. Here the
handlers come first, so an interrupt during start-up ends quietly with 130 (SIGINT) or 143
(SIGTERM), as it does once a command runs.
"""

from __future__ import annotations

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


def main():
    try:
        previous = {signal.SIGTERM: signal.signal(signal.SIGTERM, _early_term),
                    signal.SIGINT: signal.signal(signal.SIGINT, _early_int)}
    except ValueError:  # not the main thread
        previous = {}
    try:
        from .cli import main as cli_main
    except KeyboardInterrupt:
        _stop_starting()
    except ImportError:
        # a C extension whose initialization the interrupt cut short reports ImportError
        if _interrupted:
            _stop_starting()
        raise
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
    return cli_main(prog_name="brdftab")
