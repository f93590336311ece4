"""Many runs in one command: several specs, the members of sweeps, validations of many files.

Each run is a *unit*: a spec file (plus a sweep member's index) to tabulate, or a file to
validate. Units run serially in this process, or on dask.distributed (:class:`Engine`): a local
cluster of worker processes (``--workers N``) or a running scheduler (``--scheduler ADDRESS``).
A worker is sent what pickles cheaply and safely — the spec's path, the member's index and the
spec's SHA-256 (the worker refuses a spec file that changed since), or a table file's path —
and sends back small plain results: the paths written, the check reports, an error as one line
with its exit code. Tables never travel. Each unit reads its spec and writes its files itself,
exactly as a serial run does, so the files are the same (their ``created`` time aside).

One spec on a cluster runs in this process instead, and the blocks of a table it streams (one
over the memory budget) are tabulated on the workers (the model sent once, each block's nodes
sent, its values back) and written here as they arrive: the same files again.

A failed unit reports its one-line error and the others go on; the exit code is the most
serious of all: 2 when a unit had bad input (or failed for another reason than a check), else
1 when a check refused an export, else 0.
"""

from __future__ import annotations

import contextlib
import os
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

from .errors import OUT_OF_MEMORY, BrdftabError

__all__ = ["Engine", "tabulate_unit", "validate_unit", "tabulate_many", "counted", "ordered", "unit_bar",
           "MISSING_DASK"]

MISSING_DASK = 'needs dask.distributed, which is not installed: pip install "brdftab[dist]"'


def _one_line(exc) -> str:
    from .cli import _one_line as one_line

    return one_line(exc)


# --------------------------------------------------------------------------------------------
# what runs in a worker (or in this process): module-level functions of plain arguments

def _caught(fn):
    """Run ``fn()``; return ``(value, None)`` or ``(None, (message, exit code, exception))``
    for what the command line would have turned into a one-line error."""
    try:
        return fn(), None
    except BrdftabError as exc:
        return None, (_one_line(exc), exc.exit_code, exc)
    except OSError as exc:
        where = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
        return None, (f"{where}{exc.strerror or exc}", 2, None)
    except MemoryError:
        return None, (OUT_OF_MEMORY, 2, None)
    except RecursionError:
        return None, ("input nested too deeply to process", 2, None)
    except (KeyboardInterrupt, SystemExit):
        raise
    except Exception as exc:  # a bug: still one line
        return None, (f"internal error: {type(exc).__name__}: {_one_line(exc)}", 1, None)


@contextlib.contextmanager
def _recorded(into: list):
    """Warnings raised in the block, kept as plain ``(category, text, filename, lineno)`` for
    the command line to show as its own."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("default")
        try:
            yield
        finally:
            for w in caught:
                into.append((w.category, str(w.message), w.filename, w.lineno))


def _figures(report) -> dict:
    """What a summary row says of a report: the largest directional albedo a(θi) with its θi
    and channel (the energy check's figure), the white-sky albedo per channel, each check's verdict."""
    out = {"passed": report.passed, "verdicts": {o.name: o.status for o in report.outcomes}}
    energy, albedo = report.get("energy"), report.get("albedo")
    if energy is not None and energy.status != "skip" and energy.figure is not None:
        out["albedo_max"] = float(energy.figure)
        out["albedo_max_theta_i_deg"] = energy.data.get("theta_i_deg")
        out["albedo_max_channel"] = energy.data.get("channel")
    elif albedo is not None and albedo.status != "skip" and albedo.data.get("values"):
        import numpy as np

        v = np.asarray(albedo.data["values"], float)
        k = np.unravel_index(int(np.nanargmax(v)), v.shape)
        out["albedo_max"] = float(v[k])
        out["albedo_max_theta_i_deg"] = albedo.data["theta_i_deg"][k[0]]
        out["albedo_max_channel"] = albedo.data["channels"][k[1]]
    if albedo is not None and albedo.data.get("white_sky") is not None:
        out["white_sky"] = [None if x is None else float(x) for x in albedo.data["white_sky"]]
        out["channels"] = list(albedo.data.get("channels") or [])
    return out


def result_lines(result) -> tuple:
    """(stdout lines, stderr lines) ``brdftab tabulate`` prints for a finished run: one
    ``wrote`` line per output, then a warning per report that failed (written anyway) or warned."""
    out, err = [], []
    for path, t in zip(result.written, result.tables):
        what = (f"{len(t.wavelengths)} wavelength{'s' if len(t.wavelengths) > 1 else ''}" if t.spectral
                else f"channel{'s' if len(t.channels) > 1 else ''} {', '.join(t.channels)}")
        grid = getattr(t, "grid", None)
        out.append(f"wrote {path} ({grid.describe() if grid is not None else 'its own grid'}, {what})")
    groups = []  # [(report, [paths written with it])] in the order written
    for path, report in zip(result.written, result.reports):
        for r, paths in groups:
            if r is report:
                paths.append(path)
                break
        else:
            groups.append((report, [path]))
    for report, paths in groups:
        names = ", ".join(str(p) for p in paths)
        if report.failures:
            err.append(f"brdftab: warning: {names} written despite failed checks: {report.summary()}")
        elif report.warnings:
            n = len(report.warnings)
            err.append(f"brdftab: warning: {names} written with {n} warning{'s' if n > 1 else ''}: "
                       + "; ".join(f"{o.name}: {_one_line(o.detail)}" for o in report.warnings))
    return out, err


def _relative(res: dict, root) -> dict:
    """Paths under ``root`` in a unit's messages shown relative to it, as a serial run given
    relative paths shows them (a worker is given absolute paths)."""
    if not root or Path(root).parent == Path(root):
        return res
    head = str(Path(root)) + os.sep

    def rel(text):
        return None if text is None else text.replace(head, "")

    res["lines"] = [rel(x) for x in res["lines"]]
    res["stderr"] = [rel(x) for x in res["stderr"]]
    res["error"] = rel(res["error"])
    for o in res["outputs"]:
        if o.get("path"):
            o["path"] = rel(o["path"])
    return res


def tabulate_unit(path: str, member, sha256, out_dir, overwrite: bool, allow_invalid, checks: dict,
                  progress=False, root=None, engine=None) -> dict:
    """Tabulate one spec (``member``: the index of a sweep member, or None) and write its
    outputs with :func:`brdftab.pipeline.run`; returns a plain dict: ``lines`` / ``errors`` to
    print, ``outputs`` (per output: path and the figures of its report), ``error`` and ``code``
    (paths under ``root`` shown relative to it)."""
    return _relative(_tabulate_unit(path, member, sha256, out_dir, overwrite, allow_invalid, checks, progress,
                                    engine), root)


def _tabulate_unit(path, member, sha256, out_dir, overwrite, allow_invalid, checks, progress, engine=None) -> dict:
    from .pipeline import run
    from .spec import load_spec
    from .sweep import member_spec

    caught: list = []
    res = {"lines": [], "stderr": [], "outputs": [], "error": None, "code": 0, "warnings": caught}

    def work():
        spec = load_spec(path) if member is None else member_spec(path, member, sha256)
        return run(spec, out_dir=out_dir, overwrite=overwrite, allow_invalid=allow_invalid, progress=progress,
                   checks=checks, engine=engine)

    with _recorded(caught):
        result, err = _caught(work)
    if err is not None:
        res["error"], res["code"] = err[0], err[1]
        report = getattr(err[2], "report", None)
        if report is not None:  # refused by a check: its verdicts still go into a sweep's summary
            res["outputs"].append({"path": None, "status": "refused", **_figures(report)})
        return res
    res["lines"], res["stderr"] = result_lines(result)
    for path_, report in zip(result.written, result.reports):
        status = "written" if report.passed else "written, checks failed"
        res["outputs"].append({"path": str(path_), "status": status, **_figures(report)})
    return res


def validate_unit(path: str, layers: list, origin=None, progress=False) -> dict:
    """Validate one input (a table file or a spec) as ``brdftab validate`` does; returns
    ``reports`` (:class:`~brdftab.checks.Report`: plain data), ``reads`` (the files a spec's
    model reads, as ``(path, what)``) and ``error`` / ``code``."""
    from .cli_validate import _check_one

    reads: list = []
    caught: list = []
    with _recorded(caught):
        reports, err = _caught(lambda: _check_one(Path(path), layers, progress, origin, bar=False, reads=reads))
    return {"reports": reports or [], "reads": [(str(p), what) for p, what in reads], "warnings": caught,
            "error": None if err is None else err[0], "code": 0 if err is None else err[1]}


# --------------------------------------------------------------------------------------------
# the engine

class Engine:
    """Where units run: in this process, one after another (no ``workers`` nor ``scheduler``),
    or on dask.distributed — a :class:`distributed.LocalCluster` of ``workers`` processes with
    one thread each (each process's kernels get their share of the cores: ``BRDFTAB_THREADS``
    is the cores over the workers, at least 1), or the cluster whose scheduler listens at
    ``scheduler``. Use as a context manager; :meth:`map` yields ``(index, result)`` as units finish."""

    def __init__(self, workers: int | None = None, scheduler: str | None = None):
        if workers is not None and scheduler is not None:
            raise BrdftabError("--workers and --scheduler: give one (a local cluster of N workers, or the address "
                               "of a running scheduler)")
        self.workers, self.scheduler = workers, scheduler
        self.client = self.cluster = None
        if self.distributed:
            try:
                import distributed  # noqa: F401
            except ImportError:
                option = "--workers" if workers is not None else "--scheduler"
                raise BrdftabError(f"{option} {MISSING_DASK}") from None

    @property
    def distributed(self) -> bool:
        return self.workers is not None or self.scheduler is not None

    def __enter__(self):
        if not self.distributed:
            return self
        import logging

        from distributed import Client, LocalCluster

        if self.scheduler is not None:
            try:
                self.client = Client(self.scheduler, timeout="10s")
            except (OSError, TimeoutError, ValueError) as exc:
                raise BrdftabError(f"--scheduler {self.scheduler}: cannot connect ({_one_line(exc)})") from None
            return self
        from ._jit import threads

        share = max(1, threads() // self.workers)
        self.cluster = LocalCluster(n_workers=self.workers, threads_per_worker=1, processes=True,
                                    dashboard_address=":0",  # any free port: a taken 8787 would warn
                                    silence_logs=logging.CRITICAL,  # one-line errors only, ours
                                    env={"BRDFTAB_THREADS": str(share)})
        self.client = Client(self.cluster)
        return self

    def __exit__(self, *exc):
        with contextlib.suppress(Exception):
            if self.client is not None:
                self.client.close()
        with contextlib.suppress(Exception):
            if self.cluster is not None:
                self.cluster.close()
        return False

    def map(self, fn, calls: list):
        """``fn(*args)`` for each ``args`` in ``calls``: yields ``(index, result)`` (in order
        when serial, as they finish on a cluster). ``fn`` returns its errors as results; a
        worker that dies gives ``{"error": ..., "code": 1}``."""
        if not self.distributed:
            for i, args in enumerate(calls):
                yield i, fn(*args)
            return
        from distributed import as_completed

        futures = [self.client.submit(fn, *args, pure=False) for args in calls]
        index = {f.key: i for i, f in enumerate(futures)}
        for fut in as_completed(futures):
            i = index[fut.key]
            try:
                result = fut.result()
            except Exception as exc:  # the worker died (out of memory, killed): this unit failed
                result = {"error": f"{calls[i][0]}: the worker running it failed ({type(exc).__name__}: "
                                   f"{_one_line(exc)})", "code": 1, "lines": [], "stderr": [], "outputs": [],
                          "reports": [], "reads": [], "warnings": []}
            yield i, result


def ordered(results):
    """``(index, result)`` pairs in any order → results in index order, each as soon as every
    earlier one has arrived."""
    waiting, nxt = {}, 0
    for i, r in results:
        waiting[i] = r
        while nxt in waiting:
            yield nxt, waiting.pop(nxt)
            nxt += 1


@contextlib.contextmanager
def unit_bar(total: int, desc: str, unit: str, enabled):
    """A tqdm bar counting finished units (``enabled`` None: on a terminal only)."""
    from tqdm.auto import tqdm

    bar = tqdm(total=total, desc=desc, unit=unit, disable=None if enabled is None else not enabled, leave=False)
    try:
        yield bar
    finally:
        bar.close()


def show_warnings(caught) -> None:
    """Show warnings a unit recorded as this process's own (the command line's one-line form)."""
    for category, text, filename, lineno in caught:
        warnings.showwarning(category(text) if isinstance(category, type) else text, category, filename, lineno)


def worst(codes) -> int:
    """The exit code of many units: 2 over 1 over 0."""
    codes = set(codes)
    return 2 if 2 in codes else (1 if 1 in codes else (max(codes) if codes else 0))


# --------------------------------------------------------------------------------------------
# brdftab tabulate SPEC... (sweeps, several specs, a cluster)

@dataclass
class _Plan:
    """One spec of the command line: a plain spec, or a sweep with its members."""

    path: Path
    spec: object = None      # a plain spec
    sweep: object = None     # a sweep (brdftab.sweep.Sweep)
    error: str | None = None
    code: int = 0
    results: dict = field(default_factory=dict)  # member index (None: the spec) -> result


def _targets(plan, out_dir) -> list:
    specs = [plan.spec] if plan.spec is not None else [m.spec for m in plan.sweep.members if m.spec is not None]
    out = [(o.target(out_dir), s) for s in specs for o in s.outputs]
    if plan.sweep is not None:
        out.append((plan.sweep.summary_target(out_dir), None))
    return out


def _plan(paths, out_dir, overwrite) -> list:
    """Every spec read and every sweep expanded, before any work: a spec that cannot be read is
    reported then, and two runs that would write the same file refuse the command."""
    from ._locks import check_target
    from .spec import load_spec
    from .sweep import is_sweep, load

    plans = []
    for p in paths:
        plan = _Plan(Path(p))

        def read(plan=plan):
            if is_sweep(plan.path):
                plan.sweep = load(plan.path)
                target = plan.sweep.summary_target(out_dir)
                inputs = [(plan.path, "the spec file")]
                check_target(target, overwrite, inputs)
                for m in plan.sweep.members:
                    if m.spec is not None and any(o.target(out_dir) == target for o in m.spec.outputs):
                        raise BrdftabError(f"{plan.path}: the sweep summary {target} is also an output of member "
                                           f"{m.index} ({m.describe()})")
            else:
                plan.spec = load_spec(plan.path)

        _, err = _caught(read)
        if err is not None:
            plan.error, plan.code = err[0], err[1]
        plans.append(plan)
    seen = {}
    for plan in plans:
        if plan.error is not None:
            continue
        for target, spec in _targets(plan, out_dir):
            key = os.path.normcase(os.path.abspath(target))
            if key in seen and (seen[key][0] is not plan or seen[key][1] is not spec):
                other = seen[key][0]
                who = f"{other.path} and {plan.path}" if other is not plan else f"two members of {plan.path}"
                raise BrdftabError(f"{who} both write {target}: give them different output paths, or run them apart")
            seen[key] = (plan, spec)
    return plans


def _member_message(message: str, sweep, member) -> str:
    """A member's error with the member named: ``s.toml [model.alpha = -1]: model.alpha: …``."""
    head = f"{sweep.path}: "
    rest = message[len(head):] if message.startswith(head) else message
    return f"{sweep.path} [{member.describe()}]: {rest}"


def tabulate_many(paths, out_dir=None, overwrite=False, allow_invalid=None, checks=None, progress=None,
                  workers=None, scheduler=None, echo=print, echo_err=None) -> int:
    """``brdftab tabulate SPEC...``: every spec and every sweep member run as a unit (serially,
    or on the cluster of ``workers`` / ``scheduler``); each sweep's summary table written when
    its members are done. Returns the exit code (:func:`worst` of the units')."""
    import sys

    echo_err = echo_err or (lambda text: print(text, file=sys.stderr))
    engine = Engine(workers, scheduler)  # a missing dask: one line, before anything is read
    plans = _plan(paths, out_dir, overwrite)
    codes = []
    for plan in plans:
        if plan.error is not None:
            echo_err(f"brdftab: error: {plan.error}")
            codes.append(plan.code)
    units = []  # (plan, member or None)
    for plan in plans:
        if plan.spec is not None:
            units.append((plan, None))
        elif plan.sweep is not None:
            for m in plan.sweep.members:
                if m.error is not None:
                    plan.results[m.index] = {"error": _one_line(m.error), "code": m.error.exit_code, "outputs": []}
                    echo_err(f"brdftab: error: {_member_message(_one_line(m.error), plan.sweep, m)}")
                    codes.append(m.error.exit_code)
                else:
                    units.append((plan, m))
    far = engine.distributed  # a worker may have another working folder: absolute paths
    where = (lambda p: str(Path(p).absolute())) if far else str
    out = None if out_dir is None else where(out_dir)
    inner = progress if (len(units) == 1 and not far) else (progress if progress is False else False)
    cwd = str(Path.cwd())
    root = None if out_dir is not None and Path(out_dir).is_absolute() else cwd  # show paths as given
    calls = [(where(plan.path), None if m is None else m.index, plan.sweep.sha256 if m is not None else None, out,
              overwrite, allow_invalid, checks or {}, inner, root if far and not plan.path.is_absolute() else None)
             for plan, m in units]
    bar_on = progress if len(units) > 1 or far else False
    started = time.time()
    try:
        _run_units(engine, units, calls, plans, bar_on, far, out_dir, overwrite, echo, echo_err, codes)
    except BaseException:
        if far:  # stopped: the files workers finished (up to the cluster's end) are written, say so
            _finished_since(started, plans, out_dir)
        raise
    n = len(units) + sum(1 for p in plans for m in (p.sweep.members if p.sweep else ()) if m.error is not None) \
        + sum(1 for p in plans if p.error is not None)
    if n > 1:
        failed = sum(1 for c in codes if c)
        echo(f"{n - failed} of {n} runs written" + (f"; {failed} failed" if failed else ""))
    return worst(codes)


def _finished_since(started: float, plans, out_dir) -> None:
    """Note as written every planned output renamed into place since ``started``."""
    from ._atomic import completed, written_elsewhere

    known = {os.path.abspath(p) for p in completed()}
    for plan in plans:
        if plan.error is None:
            for target, spec in _targets(plan, out_dir):
                with contextlib.suppress(OSError):
                    if os.path.abspath(target) not in known and os.stat(target).st_mtime >= started - 1:
                        written_elsewhere([target])


def _run_units(engine, units, calls, plans, bar_on, far, out_dir, overwrite, echo, echo_err, codes) -> None:
    one = far and len(units) == 1 and units[0][1] is None
    with engine, unit_bar(len(calls), "tabulating", "run", bar_on and not one) as bar:
        # one spec on a cluster: run here, its streamed table's blocks tabulated on the workers
        results = [(0, tabulate_unit(*calls[0], engine=engine))] if one else engine.map(tabulate_unit, calls)
        for i, res in ordered(counted(results, bar, _written if far and not one else None)):
            plan, m = units[i]
            plan.results[None if m is None else m.index] = res
            show_warnings(res.get("warnings", ()))
            with _external(bar):
                for line in res["lines"]:
                    echo(line)
                for line in res["stderr"]:
                    echo_err(line)
                if res["error"] is not None:
                    msg = res["error"] if m is None else _member_message(res["error"], plan.sweep, m)
                    echo_err(f"brdftab: error: {msg}")
            codes.append(res["code"])
            if plan.sweep is not None and len(plan.results) == len(plan.sweep.members):
                with _external(bar):
                    _summary(plan.sweep, plan.results, out_dir, overwrite, echo, echo_err, codes)


def _written(res) -> None:
    """Note the files a worker reports written (an interrupted run names them)."""
    from ._atomic import written_elsewhere

    written_elsewhere(o["path"] for o in res["outputs"] if o.get("path") and o["status"] != "refused")


def counted(results, bar, each=None):
    """``(index, result)`` pairs as units finish, counted on ``bar`` (and given to ``each``)."""
    for item in results:
        bar.update(1)
        if each is not None:
            each(item[1])
        yield item


@contextlib.contextmanager
def _external(bar):
    """Print around a progress bar (cleared first, redrawn after)."""
    if bar.disable:
        yield
        return
    from tqdm import tqdm

    with tqdm.external_write_mode(nolock=False):
        yield


def _summary(sweep, results, out_dir, overwrite, echo, echo_err, codes) -> None:
    """Write the sweep's summary table (one row per member and output) and say where."""
    from .sweep import write_summary

    def write():
        return write_summary(sweep, results, out_dir, overwrite)

    target, err = _caught(write)
    if err is not None:
        echo_err(f"brdftab: error: {err[0]}")
        codes.append(err[1])
        return
    done = sum(1 for r in results.values() if r.get("code") == 0)
    n = len(sweep.members)
    echo(f"wrote {target} (sweep summary: {done} of {n} members written"
         + (f", {n - done} failed)" if n - done else ")"))
