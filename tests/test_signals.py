"""Signals (brdftab._signals): Ctrl-C and SIGTERM end any command within a second, with exit
130 / 143, never swallowed by a library and never after leaving a partial file.

The process-level cases run the command line as a real subprocess; the rest run in-process
(pytest runs tests in the main thread, where Python runs signal handlers).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
from _stepped import start_stepped, wait_for
from click.testing import CliRunner

import brdftab
from brdftab import _signals, formats
from brdftab._signals import held_signals
from brdftab.cli import main
from brdftab.grids import RusinkiewiczGrid
from brdftab.table import tabulate

TINY_GRID = '[grid]\ntype = "rusinkiewicz"\nn_theta_h = 3\nn_theta_d = 3\nn_phi_d = 4\n'


# --------------------------------------------------------------------------------------------
# A signal while netCDF4 reads samples (defect: 6 of 6 tries swallowed, exit 0)

#: Runs the command line after marking (file "reading") the moment netCDF4 starts reading the
#: samples of ``brdf``, so the test can signal during the read.
READ_MARKER = textwrap.dedent("""
    import sys
    from pathlib import Path
    import xarray.backends.netCDF4_ as backend

    original = backend.NetCDF4ArrayWrapper._getitem

    def getitem(self, key):
        if self.variable_name == "brdf":
            Path("reading").touch()
        return original(self, key)

    backend.NetCDF4ArrayWrapper._getitem = getitem
    from brdftab.cli import main
    main(sys.argv[1:], prog_name="brdftab")
""")


@pytest.fixture(scope="module")
def big_table(tmp_path_factory):
    """A 115 MB (float64) netCDF table: netCDF4 needs a few tenths of a second to read it."""
    folder = tmp_path_factory.mktemp("big")
    table = tabulate(brdftab.models.create("lambert", albedo=0.5), RusinkiewiczGrid(200, 200, 360), progress=False)
    brdftab.save(table, folder / "big.nc")
    return folder / "big.nc"


@pytest.mark.parametrize("verb, sig, code, word", [
    ("validate", signal.SIGINT, 130, "interrupted"),
    ("info", signal.SIGTERM, 143, "terminated"),
    ("convert", signal.SIGINT, 130, "interrupted"),
])
def test_signal_during_a_netcdf_read_ends_the_command_within_a_second(tmp_path, big_table, verb, sig, code, word):
    (tmp_path / "marker.py").write_text(READ_MARKER)
    args = [verb, str(big_table)] + (["out.nc"] if verb == "convert" else [])
    proc = subprocess.Popen([sys.executable, "marker.py", *args], cwd=tmp_path, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        while not (tmp_path / "reading").exists():
            assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
            time.sleep(0.005)
        time.sleep(0.05)  # well inside the read of the samples
        sent = time.monotonic()
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=30)
        took = time.monotonic() - sent
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == code, f"exit {proc.returncode} after the signal: {err!r}"
    assert took < 1.0, f"the command ran on for {took:.2f} s after the signal"
    assert "Traceback" not in err
    assert err.splitlines()[-1] == f"brdftab: {word}; no output written"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["marker.py", "reading"]  # no output, no partial


# --------------------------------------------------------------------------------------------
# Reads in slabs: the same values; a signal acts between slabs, never inside the library

def test_read_in_slabs_gives_the_stored_values(tmp_path, monkeypatch):
    table = tabulate(brdftab.models.create("microfacet", alpha=0.3), RusinkiewiczGrid(12, 10, 16), progress=False)
    brdftab.save(table, tmp_path / "t.nc")
    monkeypatch.setattr(_signals, "READ_SLAB_BYTES", 2048)  # many slabs
    back = brdftab.open(tmp_path / "t.nc")
    np.testing.assert_array_equal(back.values, table.values)
    chunks = list(brdftab.open(tmp_path / "t.nc").iter_chunks(max_bytes=5000))  # not loaded: streamed
    assert len(chunks) > 1
    np.testing.assert_array_equal(np.concatenate(chunks), table.values)


class _LibraryVariable:
    """A file-backed variable whose reads send SIGINT to this process from "inside the library"
    (as Ctrl-C during netCDF4's C call) and notice if an exception is raised there."""

    _in_memory = False
    encoding: dict = {}

    def __init__(self, shape, log, signal_at=1):
        self.shape, self.log, self.signal_at = shape, log, signal_at
        self.ndim, self.size, self.dtype = len(shape), int(np.prod(shape)), np.dtype(float)
        self.start = 0

    def __getitem__(self, key):
        part = _LibraryVariable(np.empty(self.shape)[key].shape, self.log, self.signal_at)
        part.start = key.start
        return part

    @property
    def values(self):
        self.log.append(self.start)
        try:
            if len(self.log) == self.signal_at + 1:
                os.kill(os.getpid(), signal.SIGINT)
            for _ in range(200):  # library work during which Python would run the handler
                sum(range(50))
        except BaseException:
            self.log.append("raised inside the library")
            raise
        return np.full(self.shape, float(self.start))


def test_sigint_during_a_slab_acts_after_that_slab_not_inside_it():
    log = []
    var = _LibraryVariable((10, 1000), log)
    with pytest.raises(KeyboardInterrupt):
        _signals.read_array(var, slab_bytes=2 * 8000)  # 2 rows a slab: 5 slabs
    assert "raised inside the library" not in log
    assert log == [0, 2], f"slabs read: {log}"  # the signal came during slab 2; slab 3 was never read
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_held_signals_act_at_the_checkpoint():
    with _signals.held_signals():
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.01)  # the handler has run (and only recorded it)
        with pytest.raises(KeyboardInterrupt):
            _signals.checkpoint()
        _signals.checkpoint()  # acted on once
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_deferred_signals_hold_sigint_until_the_block_ends():
    reached_end = False
    with pytest.raises(KeyboardInterrupt):
        with held_signals():
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.05)
            reached_end = True
    assert reached_end


# --------------------------------------------------------------------------------------------
# A signal whose exception a library swallowed is not lost

@pytest.fixture
def swallowing_format():
    """A format whose preparation runs "library" code that swallows KeyboardInterrupt, as
    netCDF4's attribute lookups did."""

    def prepare(brdf, grid, **options):
        try:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.05)
        except BaseException:  # noqa: BLE001 - the point: a library that swallows everything
            pass
        return tabulate(brdf, grid, progress=False)

    def write(table, path, **options):
        Path(path).write_bytes(b"written after the interrupt")

    formats.register(formats.FileFormat(name="swallow", extensions=(".swallow",), description="test", read=None,
                                        write=write, prepare=prepare))
    yield
    formats.FORMATS.pop("swallow", None)


def test_swallowed_interrupt_still_stops_the_command_and_writes_nothing(tmp_path, swallowing_format):
    spec = tmp_path / "s.toml"
    spec.write_text(f'[model]\nname = "lambert"\n{TINY_GRID}[[output]]\npath = "x.swallow"\n')
    result = CliRunner().invoke(main, ["tabulate", str(spec), "--no-progress"])
    assert result.exit_code == 130, (result.exit_code, result.stderr)
    assert result.stderr.splitlines() == ["brdftab: interrupted; no output written"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.toml"]
    assert _signals.pending() is None  # the next command starts afresh
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


@pytest.mark.parametrize("sig, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_a_signal_during_start_up_ends_quietly(tmp_path, sig, code):
    """The entry point installs its handlers before the heavy imports (numpy, xarray, netCDF4):
    a signal while they load ends with 130 / 143 and no traceback."""
    import subprocess
    import sys
    import time

    for delay in (0.25, 0.4, 0.6):      # after the interpreter itself has started
        proc = subprocess.Popen([sys.executable, "-m", "brdftab", "models"], stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True)
        time.sleep(delay)
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=30)
        if proc.returncode == 0:       # it had finished already: nothing to interrupt
            continue
        assert proc.returncode == code, (delay, proc.returncode, err)
        assert "Traceback" not in err and len(err.strip().splitlines()) <= 1, err


def test_an_interrupt_a_library_swallows_during_start_up_still_ends_the_run():
    """A Ctrl-C while the verb's modules load raises KeyboardInterrupt inside some import; a
    library's bare ``except:`` there can swallow it, and the run then went on to the end with
    exit code 0 (seen once in CI: a Ctrl-C at a terminal 0.3 s after the start, under load)."""
    script = textwrap.dedent("""
        import os, signal, sys
        import brdftab.cli
        from brdftab import _entry

        def preload(argv):  # an import whose library swallows the interrupt
            try:
                os.kill(os.getpid(), signal.SIGINT)
            except BaseException:
                pass

        brdftab.cli.preload = preload
        sys.argv = ["brdftab", "models"]
        _entry.main()
    """)
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 130, (proc.returncode, proc.stderr)
    assert proc.stderr.splitlines() == ["brdftab: interrupted while starting; no output written"]
    assert proc.stdout == ""


# --------------------------------------------------------------------------------------------
# A signal during a write: the temporary is removed; a writer that reports its steps stops at
# the next step, one that does not finishes the write first

SLOW_WRITER = textwrap.dedent("""
    import sys, time
    from brdftab import formats
    from brdftab.cli import main

    def slow(table, path, **kw):
        with open(path, "wb") as fh:
            fh.write(b"partial")
            fh.flush()
            time.sleep(3)
            fh.write(b" and the rest")

    fmt = formats.FileFormat(name="slow", extensions=(".slow",), description="test", read=None, write=slow)
    formats.register(fmt)
    main(["tabulate", sys.argv[1]], prog_name="brdftab")
""")


def test_sigterm_while_writing_removes_the_temporary_and_exits(tmp_path):
    (tmp_path / "slow.py").write_text(SLOW_WRITER)
    (tmp_path / "s.toml").write_text('[model]\nname = "lambert"\n[grid]\ntype = "rusinkiewicz"\nn_theta_h = 3\n'
                                     'n_theta_d = 3\nn_phi_d = 3\n[[output]]\npath = "x.slow"\n')
    proc = subprocess.Popen([sys.executable, "slow.py", "s.toml"], cwd=tmp_path, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 30
    while not any(".partial-" in p.name for p in tmp_path.iterdir()):
        assert proc.poll() is None and time.time() < deadline, "the writer never started"
        time.sleep(0.02)
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 143, err  # 128 + SIGTERM
    # this writer reports no steps, so the run says it finishes the write before it stops
    assert err.splitlines() == ["brdftab: finishing the write of x.slow before stopping...",
                                "brdftab: terminated; no output written"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.toml", "slow.py"]


@pytest.mark.parametrize("sig, code, word", [(signal.SIGTERM, 143, "terminated"),
                                             (signal.SIGINT, 130, "interrupted")])
def test_signal_during_a_stepped_write_acts_at_the_next_step(tmp_path, sig, code, word):
    proc = start_stepped(tmp_path)
    try:
        wait_for(tmp_path, ".partial-", proc)
        time.sleep(0.3)
        sent = time.monotonic()
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=30)
        took = time.monotonic() - sent
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == code, err
    assert err.splitlines() == [f"brdftab: {word}; no output written"]
    assert took < 3.0, f"the write went on for {took:.1f} s after the signal"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.toml", "stepped.py"]


# --------------------------------------------------------------------------------------------
# An inherited "ignore" (a script's background job) and Ctrl-C at a terminal, through the
# console entry point (``python -m brdftab``)

RUN_SPEC = ('[model]\nname = "lambert"\nalbedo = 0.5\n[grid]\ntype = "rusinkiewicz"\nn_theta_h = 90\n'
            'n_theta_d = 90\nn_phi_d = 180\n[[output]]\npath = "x.nc"\n')


def test_an_inherited_ignored_sigint_stays_ignored_from_start_up_to_the_end(tmp_path):
    """``trap '' INT`` in a script (or SIG_IGN in a parent) runs brdftab with SIGINT ignored:
    SIGINTs from the first instant (the imports) to the end change nothing."""
    (tmp_path / "s.toml").write_text(RUN_SPEC)

    def ignore_sigint():
        signal.signal(signal.SIGINT, signal.SIG_IGN)

    proc = subprocess.Popen([sys.executable, "-m", "brdftab", "tabulate", "s.toml", "--no-progress"], cwd=tmp_path,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=ignore_sigint)
    sent = 0
    try:
        time.sleep(0.15)  # past the interpreter's own start-up (site), into brdftab's
        while proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            sent += 1
            time.sleep(0.05)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    assert sent >= 10
    assert err == "" and out.startswith("wrote x.nc")
    assert (tmp_path / "x.nc").exists()


def _at_a_terminal(tmp_path, args):
    """``python -m brdftab ARGS`` as the foreground process of a new pseudo-terminal; returns
    (process, the terminal's master side): writing ``\\x03`` there is a Ctrl-C."""
    import fcntl
    import pty
    import termios

    master, slave = pty.openpty()

    def controlling_terminal():
        os.setsid()
        fcntl.ioctl(slave, termios.TIOCSCTTY, 0)

    proc = subprocess.Popen([sys.executable, "-m", "brdftab", *args], cwd=tmp_path, stdin=slave,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=controlling_terminal, pass_fds=(slave,))
    os.close(slave)
    return proc, master


@pytest.mark.parametrize("when", ["start-up", "tabulating"])
def test_ctrl_c_at_a_terminal_ends_the_run_with_130_within_0_2_s(tmp_path, when):
    (tmp_path / "s.toml").write_text(RUN_SPEC)
    proc, master = _at_a_terminal(tmp_path, ["tabulate", "s.toml", "--no-progress"])
    try:
        if when == "start-up":
            time.sleep(0.3)  # numpy, xarray, netCDF4 are loading
            assert proc.poll() is None
        else:
            wait_for(tmp_path, ".lock", proc)  # the output is claimed: the run is under way
            time.sleep(0.1)
        sent = time.monotonic()
        os.write(master, b"\x03")
        proc.wait(timeout=30)
        took = time.monotonic() - sent
        out, err = proc.communicate()
    finally:
        os.close(master)
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, err
    word = "interrupted while starting" if when == "start-up" else "interrupted"
    assert err.splitlines() == [f"brdftab: {word}; no output written"]
    assert took < 0.2, f"the run ended {took:.2f} s after Ctrl-C"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.toml"]
