"""spec → model → (one table per target grid) → checks → write (atomically): ``brdftab tabulate``.

Every output's format says which grid it stores (:func:`brdftab.formats.target_grid`): netCDF
keeps the spec's grid, MERL always stores the MERL grid, and so on. The model is tabulated
once per distinct target grid — each output is written from the model sampled on its own
grid, never from an interpolation of a table made on another grid. Every table is checked
before anything is written; a failed check refuses the whole run unless invalid output is
explicitly allowed.
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import formats
from ._atomic import atomic_path
from ._locks import check_target, claim, same_file
from ._progress import check_progress, write_progress
from ._signals import held_signals, terminate_as_interrupt
from .brdf import BRDF
from .checks import Report, guard
from .errors import BrdftabError
from .spec import Spec
from .table import CHECKED_PEAK, check_checked_memory, memory_budget, tabulate

__all__ = ["Result", "Planned", "plan", "run"]


@dataclass
class Planned:
    """One output: its target path, format, options and the grid that format stores."""

    target: object
    format: object
    options: dict
    grid: object


@dataclass
class Result:
    """What a run wrote: per output the target path and the table (or model) written, and the
    check report of the BRDF it was written from."""

    written: list = field(default_factory=list)
    tables: list = field(default_factory=list)
    reports: list = field(default_factory=list)

    @property
    def table(self):
        return self.tables[0] if self.tables else None

    @property
    def report(self) -> Report:
        merged = Report()
        seen = set()
        for r in self.reports:  # outputs that store the same values share one report: once
            if id(r) not in seen:
                seen.add(id(r))
                merged.outcomes.extend(r.outcomes)
        return merged


def plan(spec: Spec, out_dir=None) -> list:
    """The outputs of ``spec`` with their formats and target grids (nothing is computed)."""
    out = []
    for o in spec.outputs:
        fmt = formats.format_for(o.path, o.format)
        fmt.ensure_available()
        fmt.check_path(o.target(out_dir))
        with formats.naming(o.target(out_dir)):
            grid = formats.target_grid(fmt, spec.grid, o.options)
        out.append(Planned(o.target(out_dir), fmt, dict(o.options), grid))
    return out


def _groups(planned):
    groups = []  # [(grid, [Planned])]
    for p in planned:
        for grid, members in groups:
            if grid is not None and p.grid is not None and grid.equals(p.grid):
                members.append(p)
                break
        else:
            groups.append((p.grid, [p]))
    return groups


def run(spec: Spec, out_dir=None, overwrite: bool = False, allow_invalid: bool | None = None,
        progress: bool | None = None, checks: dict | None = None, engine=None) -> Result:
    """Tabulate ``spec`` and write its outputs.

    ``engine`` (a :class:`brdftab.batch.Engine` on a dask cluster): the blocks of a table
    streamed to its files (over the memory budget) are tabulated on the cluster's workers and
    written here; the files are those of a serial run.

    Output paths resolve against ``out_dir`` when given (else the spec's folder; missing
    folders are created). Every target is checked and claimed before any work starts: an
    existing file without ``overwrite``, a file this run reads (the spec, the model's input
    files) and a file another run is writing are refused. Each table is validated before
    export; a failed check refuses the export unless ``allow_invalid`` (or the spec's
    ``validation.allow_invalid``) is true. ``checks`` is a
    configuration layer over the spec's ``[validation]`` (command-line thresholds).
    """
    started = time.monotonic()
    planned = plan(spec, out_dir)
    inputs = spec.inputs
    for p in planned:
        check_target(p.target, overwrite, inputs)
    for i, p in enumerate(planned):
        if any(same_file(p.target, q.target) for q in planned[:i]):
            raise BrdftabError(f"{spec.path}: two outputs write the same file {p.target}")

    _check_memory(spec, planned)

    provenance = spec.provenance  # the spec file, its description, a sweep member's values
    config = {k: v for k, v in spec.validation.items() if k != "allow_invalid"}
    layers = [config, checks or {}]
    allow = spec.validation.get("allow_invalid", False) if allow_invalid is None else allow_invalid
    result = Result()
    # Claim every target before any work: a concurrent run to the same file is refused now.
    with terminate_as_interrupt(), claim([p.target for p in planned], overwrite, inputs), \
            contextlib.ExitStack() as streamed:
        jobs = _jobs(spec, planned, provenance, progress)
        for job in [j for j in jobs if isinstance(j, _Streamed)]:
            # written block by block to its temporary and checked there, as stored; renamed
            # into place when this block ends, after every other output passed its checks too
            tmps = [streamed.enter_context(atomic_path(m.target, overwrite=overwrite)) for m in job.members]
            job.write(spec, tmps, progress, _progress_delay(started), engine)
            for m, tmp in zip(job.members, tmps):
                with check_progress(m.target.name, progress, _progress_delay(started)):
                    table, report = job.check(spec, m, tmp, layers, allow)
                result.written.append(m.target)
                result.tables.append(table)
                result.reports.append(report)
        jobs = [j for j in jobs if not isinstance(j, _Streamed)]
        # validate what is written, as stored, before anything is: a table's metadata gets the report
        reports = {}
        for job in jobs:
            if job.key in reports:
                continue
            where = ", ".join(str(j.planned.target) for j in jobs if j.key == job.key)
            label = ", ".join(j.planned.target.name for j in jobs if j.key == job.key)
            with check_progress(label, progress, _progress_delay(started)):
                reports[job.key] = job.check(spec, layers, subject=_subject(spec, job), allow_invalid=allow,
                                             what=where)
        if not allow:
            _judge_sampling(spec, jobs)
        for job in jobs:
            m = job.planned
            with write_progress(m.target.name, progress, _progress_delay(started)):
                formats.write_prepared(m.format, job.payload, m.target, overwrite=overwrite, options=job.options)
            result.written.append(m.target)
            result.tables.append(job.payload if hasattr(job.payload, "grid") else job.checked)
            result.reports.append(reports[job.key])
    return result


@dataclass
class _Job:
    """One output ready to write: what the format writes (``payload``) and what the checks
    judge (``checked``: the values as stored, :func:`brdftab.formats.stored`), or why the stored
    values cannot be read back at all (``unstorable``)."""

    planned: Planned
    options: dict
    payload: object
    checked: object
    unstorable: object = None

    @property
    def key(self):
        return id(self.unstorable if self.unstorable is not None else self.checked)

    def check(self, spec, layers, subject, allow_invalid=True, what=""):
        from .checks import unstorable_report

        if self.unstorable is not None:
            return unstorable_report(self.unstorable, layers, allow_invalid=allow_invalid, what=what, subject=subject)
        # the spec's model, unless the format tabulated something derived from it (MERL's
        # φh average or symmetrization): then the table's provenance names what it holds
        made_from = getattr(self.checked, "ds", None)
        derived = made_from is not None and made_from.attrs.get("model") != spec.model.name
        reference, wavelengths = _reference(spec, self)
        return guard(self.checked, layers, allow_invalid=allow_invalid, what=what,
                     reference=None if derived else reference, wavelengths=wavelengths, subject=subject)


def _reference(spec, job):
    """The model a job's stored values are judged against, and the wavelengths to judge at: the
    spec's model at the spec's wavelengths, or, for a spectral model written in colour (a format
    that stores colour), the model seen in that colour (:func:`brdftab.colorimetry.to_colour`
    with the job's options), without wavelengths."""
    from .colorimetry import seen_as_written

    reference = seen_as_written(spec.model, job.checked, job.options, spec.wavelengths)
    return reference, (spec.wavelengths if reference is spec.model else None)


def _jobs(spec, planned, provenance, progress) -> list:
    """Every planned output prepared: the model tabulated once per target grid (formats with
    their own ``prepare``, like the RGL writer, are given the model), then each format's
    payload and the BRDF its file will hold."""
    from .table import Table

    jobs = []
    for grid, members in _groups(planned):
        needs_table = any(m.format.prepare is None for m in members)
        if needs_table and _streams(spec, grid, members):
            jobs.append(_Streamed(grid, members, provenance))
            continue
        if needs_table:
            source = tabulate(spec.model, grid, spec.wavelengths, progress=progress, provenance=provenance,
                              polarized=spec.polarized)
        else:
            source = spec.model
        for m in members:
            options = _with_wavelengths(m, spec.wavelengths)
            unstorable = None
            with formats.naming(m.target):
                payload = formats.prepare(m.format, source, m.grid, options)
                try:
                    checked = formats.stored(m.format, payload, options)
                except formats.NotStorable as exc:
                    checked, unstorable = None, exc
            if isinstance(checked, Table):
                payload = checked  # the samples as the file holds them: written, stamped and checked
            elif checked is None and unstorable is None:
                checked = payload if isinstance(payload, BRDF) else source
            jobs.append(_Job(m, options, payload, checked, unstorable))
    return jobs


def block_values(model, grid, lam, n: int) -> np.ndarray:
    """f of ``model`` at the nodes of ``grid`` (a block of a table's grid), ``[*grid.shape, n]``:
    what a cluster worker computes for a streamed table (:meth:`_Streamed._write_on`)."""
    from .table import fill_values

    values = np.empty(grid.shape + (n,))
    fill_values(model, grid, lam, values)
    return values


class _Streamed:
    """The outputs of one grid tabulated block by block into their files (formats with a
    ``stream`` writer), so that no more than a block of the table is in memory: each block is
    sampled on :meth:`Grid.block` (the same values, bit for bit, as the whole grid gives) and
    written to every output; the checks then judge each file as stored (read back lazily, within
    the memory budget) and what they stamp is added to the file before it is renamed into place."""

    def __init__(self, grid, members, provenance):
        self.grid = grid
        self.members = members
        self.provenance = provenance
        self.writers = []

    def write(self, spec, tmps, progress, delay, engine=None) -> None:
        from .channels import Layout
        from .table import _checked_dtype, _progress, _specular_samples, blocks, fill_values, make_table

        model, grid = spec.model, self.grid
        lam = model.layout.resolve(spec.wavelengths)
        n = model.layout.n_out(lam)
        layout = model.layout if lam is None else Layout(None, lam)
        # the table's dataset with a broadcast zero for its samples: nothing of its size is allocated
        template = make_table(np.broadcast_to(np.zeros((), np.float64), grid.shape + (n,)), grid, layout,
                              brdf=model, provenance=self.provenance, specular=_specular_samples(model, lam))
        names = ", ".join(m.target.name for m in self.members)
        with contextlib.ExitStack() as stack:
            for m, tmp in zip(self.members, tmps):
                if "dtype" in m.options:
                    _checked_dtype(m.options["dtype"])
                with held_signals(writing=names):  # (library code: a signal acts when it is done)
                    self.writers.append(stack.enter_context(m.format.stream(template.ds, tmp, **m.options)))
            # one block in float64 (its casts and the evaluation's temporaries come on top): a
            # sixteenth of the budget
            items = max(1, memory_budget() // (16 * 8 * n))
            bar = _progress(grid.size, progress)
            if bar is not None:
                bar.delay = delay
            keys = blocks(grid.shape, items, align=self.writers[0].chunks[:-1])
            try:
                if engine is not None and engine.distributed:
                    self._write_on(engine, model, grid, lam, n, keys, bar, names)
                    return
                for key in keys:
                    sub = grid.block(key)
                    values = np.empty(sub.shape + (n,))
                    fill_values(model, sub, lam, values, bar=bar)  # (interrupted as any tabulation)
                    self._write_block(key, values, names)
            finally:
                if bar is not None:
                    bar.close()

    def _write_block(self, key, values, names) -> None:
        from ._signals import checkpoint

        with held_signals(writing=names):
            for w in self.writers:
                w.write(key + (slice(None),), values)
            checkpoint()  # Ctrl-C / SIGTERM received during the write act here

    def _write_on(self, engine, model, grid, lam, n, keys, bar, names) -> None:
        """The blocks tabulated on ``engine``'s cluster (:func:`block_values`: the same code,
        hence the same bits, as in this process), a bounded number at a time, and written here
        as they arrive (the writers take blocks in any order)."""
        import itertools

        from distributed import as_completed

        client = engine.client
        remote_model = client.scatter(model, broadcast=True)
        workers = max(1, len(client.scheduler_info().get("workers", {})))
        pending = {}

        def submit(key):
            fut = client.submit(block_values, remote_model, grid.block(key), lam, n, pure=False)
            pending[fut.key] = key
            return fut

        keys = iter(keys)
        running = as_completed([submit(k) for k in itertools.islice(keys, 2 * workers)])
        for fut in running:
            key = pending.pop(fut.key)
            try:
                values = fut.result()
            except Exception as exc:  # the worker died, or the model raised there
                raise BrdftabError(f"a worker tabulating a block of {grid.describe()} failed "
                                   f"({type(exc).__name__}: {' '.join(str(exc).split())})") from None
            self._write_block(key, values, names)
            if bar is not None:
                bar.update(int(np.prod(values.shape[:-1])))
            nxt = next(keys, None)
            if nxt is not None:
                running.add(submit(nxt))

    def check(self, spec, m, tmp, layers, allow):
        """Judge the file ``tmp`` of output ``m`` as stored and add the report to it; returns the
        table (read lazily from ``tmp``) and the report."""
        from .checks import guard

        table = m.format.read(tmp)
        report = guard(table, layers, allow_invalid=allow, what=str(m.target), reference=spec.model,
                       wavelengths=spec.wavelengths, subject=f"{spec.path.name} on {self.grid.describe()}")
        stamped = table.ds.drop_vars("brdf")
        table.close()
        self.writers[self.members.index(m)].update(stamped)
        return table, report


def _subject(spec, job) -> str:
    grid = getattr(job.checked, "grid", None) if job.checked is not None else job.planned.grid
    return f"{spec.path.name} on {grid.describe() if grid is not None else 'its own grid'}"


def _judge_sampling(spec: Spec, jobs) -> None:
    """A format that samples the model its own way (the RGL writer's warped samples) is judged
    as a resampled conversion is (:func:`brdftab.convert.difference`, with the same bound): a
    file that misrepresents the model beyond it is refused, naming the figures."""
    from .convert import InvalidOutput, difference

    for job in jobs:
        if job.planned.format.prepare is None or not isinstance(job.checked, BRDF):
            continue
        if job.planned.format.polarized:  # a .pbsdf is tabulated on the planned grid node for node, like a table
            continue
        gate, _ = difference(_reference(spec, job)[0], job.checked)
        beyond = gate.exceeds() if gate is not None else []
        if beyond:
            raise InvalidOutput(f"refusing to export {job.planned.target}: its {job.planned.format.name} samples "
                                f"misrepresent the model {spec.model.name}: relative error of f at θi, θo ≤ 80° "
                                f"{', '.join(beyond)} over {gate.points} check points (nothing written; choose "
                                "finer format options, or pass --allow-invalid to write it anyway)")


def _n_channels(spec: Spec) -> int:
    """Values a node of the spec's tables holds: its channels (17 times as many for a polarized
    table: brdf and the 16 Mueller elements)."""
    layout = spec.model.layout
    n = layout.n_out(layout.resolve(spec.wavelengths))
    return 17 * n if getattr(spec, "polarized", False) else n


def _group_channels(spec: Spec, members, n: int) -> int:
    """Channels of the table one grid's outputs hold: three for a spectral model written only to
    formats that store colour (converted as it is sampled), else the model's ``n``."""
    if spec.model.spectral and members and all(m.format.colour and m.format.prepare is not None for m in members):
        return 3
    if not getattr(spec, "polarized", False) and any(m.format.polarized for m in members):
        return 17 * n  # a .pbsdf output is tabulated polarized: brdf and 16 Mueller elements a sample
    return n


#: The most samples (nodes x channels) a table may have: beyond 2^53 a count is no longer exact
#: in float64 (and 2^53 float64 samples are 64 PiB). A grid of 10^6 nodes on each of four axes,
#: 10^24 samples (beyond numpy's 2^63), was an internal error, "iterator is too large".
MAX_SAMPLES = 2 ** 53


def _in_memory_bytes(grid, n: int) -> float:
    """Peak memory of tabulating ``grid`` x ``n`` channels in memory and checking it (the
    figure by which a table read from disk is over the budget too, :attr:`Table.over_budget`)."""
    return float(grid.size) * n * 8 * CHECKED_PEAK


def _streams(spec: Spec, grid, members) -> bool:
    """True when the outputs of ``grid`` are tabulated block by block into their files: every
    one can be written so (``FileFormat.stream``) and the in-memory run would exceed the memory
    budget (:func:`brdftab.table.memory_budget`)."""
    if grid is None or getattr(spec, "polarized", False) or not all(m.format.stream is not None and
                                                                     m.format.prepare is None for m in members):
        return False  # (a polarized table, 16 Mueller elements a sample beside brdf, is tabulated whole)
    return _in_memory_bytes(grid, _n_channels(spec)) > memory_budget()


def _check_memory(spec: Spec, planned) -> None:
    """Refuse up front a run whose tables and checks would not fit in memory (not after the
    tabulation, when the checks run out of it); outputs streamed to their files are bounded by
    the memory budget instead, whatever their size up to :data:`MAX_SAMPLES`."""
    n = _n_channels(spec)
    budget = memory_budget()
    for grid, members in _groups(planned):
        channels = _group_channels(spec, members, n)
        if grid is not None and grid.size * channels > MAX_SAMPLES:
            raise BrdftabError(
                f"{spec.path.name}: {grid.describe()} x {channels} channel(s) is {float(grid.size) * channels:.3g} "
                f"samples, more than a table can hold (2^53 = {float(MAX_SAMPLES):.3g}); use a coarser grid")
        if grid is None or _streams(spec, grid, members):  # (a format sampling the model itself on a
            continue                                       # grid it names, like MERL's, holds it whole)
        need = _in_memory_bytes(grid, channels)
        if need > budget and (getattr(spec, "polarized", False) or any(m.format.polarized for m in members)):
            raise BrdftabError(
                f"{spec.path.name}: tabulating and checking the polarized table {grid.describe()} (brdf and 16 Mueller "
                f"elements a sample) needs about {need / 2**30:.3g} GiB of memory, more than the budget of "
                f"{budget / 2**30:.3g} GiB; polarized tables are tabulated whole: use a coarser grid or raise the "
                "budget (--memory, BRDFTAB_MEMORY)")
        if need > budget:
            whole = [m.target.name for m in members if m.format.stream is None]
            raise BrdftabError(
                f"{spec.path.name}: tabulating and checking {grid.describe()} x {n} channels needs about "
                f"{need / 2**30:.3g} GiB of memory, more than the budget of {budget / 2**30:.3g} GiB, and "
                f"{', '.join(whole)} {'is' if len(whole) == 1 else 'are'} written whole (its format cannot be "
                "written block by block); write a netCDF (.nc) or zarr (.zarr) table, which is streamed within the "
                "budget, use a coarser grid, or raise the budget (--memory, BRDFTAB_MEMORY)")
    tables = [(grid, n) for grid, members in _groups(planned)
              if grid is not None and any(m.format.prepare is None for m in members)
              and not _streams(spec, grid, members)]
    where = ", ".join(g.describe() for g, _ in tables)
    check_checked_memory(tables, f"{spec.path.name}: tabulating and checking {where} x {n} channels")


def _with_wavelengths(m, wavelengths) -> dict:
    """A format that samples the model itself is given the spec's wavelengths when it takes them."""
    options = dict(m.options)
    if (wavelengths is not None and m.format.prepare is not None and "wavelengths_nm" in m.format.options
            and "wavelengths_nm" not in options):
        options["wavelengths_nm"] = [float(x) for x in wavelengths]
    return options


def _progress_delay(started: float) -> float:
    """Seconds until a progress bar may appear: the bar covers the run, not each phase."""
    from . import table

    return max(0.0, table.PROGRESS_DELAY - (time.monotonic() - started))


def validate(spec: Spec, checks: dict | None = None, progress: bool | None = None) -> list:
    """Check what :func:`run` would export for ``spec``, writing nothing: each output prepared
    as :func:`run` prepares it (the model tabulated on each target grid, or sampled by the
    format itself) and judged as its file would store it, with the spec's ``[validation]`` and
    ``checks`` (command-line layer). Returns one :class:`~brdftab.checks.Report` per distinct
    stored BRDF."""
    config = {k: v for k, v in spec.validation.items() if k != "allow_invalid"}
    provenance = spec.provenance
    reports = {}
    planned = plan(spec)
    _check_memory(spec, planned)
    for job in _jobs(spec, planned, provenance, progress):
        if isinstance(job, _Streamed):
            # judged as run() judges it: written block by block to a scratch file, read back
            import tempfile

            for m in job.members:
                with tempfile.TemporaryDirectory(prefix="brdftab-validate-") as folder:
                    scratch = Planned(Path(folder) / m.target.name, m.format, m.options, m.grid)
                    one = _Streamed(job.grid, [scratch], provenance)
                    one.write(spec, [scratch.target], progress, 0.0)
                    table = m.format.read(scratch.target)
                    reports[id(scratch)] = guard(table, [config, checks or {}], allow_invalid=True,
                                                 reference=spec.model, wavelengths=spec.wavelengths,
                                                 subject=f"{spec.path} ({job.grid.describe()})")
                    table.close()
            continue
        if job.key not in reports:
            grid = getattr(job.checked, "grid", None) if job.checked is not None else job.planned.grid
            where = grid.describe() if grid is not None else "its own grid"
            reports[job.key] = job.check(spec, [config, checks or {}], subject=f"{spec.path} ({where})")
    return list(reports.values())
