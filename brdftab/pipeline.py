"""spec → model → (one table per target grid) → checks → write (atomically): ``brdftab tabulate``.

Every output's format says which grid it stores (:func:`brdftab.formats.target_grid`): netCDF
keeps the spec's grid, MERL always stores the MERL grid, and so on. The model is tabulated
once per distinct target grid — each output is written from the model sampled on its own
grid, never from an interpolation of a table made on another grid. Every table is checked
before anything is written; a failed check refuses the whole run unless invalid output is
explicitly allowed.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

from . import formats
from ._locks import check_target, claim, same_file
from ._progress import check_progress, write_progress
from ._signals import terminate_as_interrupt
from .brdf import BRDF
from .checks import Report, guard
from .errors import BrdftabError
from .spec import Spec
from .table import tabulate

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
        for r in self.reports:
            merged.outcomes.extend(r.outcomes)
        return merged


def plan(spec: Spec, out_dir=None) -> list:
    """The outputs of ``spec`` with their formats and target grids (nothing is computed)."""
    out = []
    for o in spec.outputs:
        fmt = formats.format_for(o.path, o.format)
        fmt.ensure_available()
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
        progress: bool | None = None, checks: dict | None = None) -> Result:
    """Tabulate ``spec`` and write its outputs.

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

    provenance = {"spec_sha256": spec.sha256, "spec_file": spec.path.name}
    if spec.description:
        provenance["comment"] = spec.description
    config = {k: v for k, v in spec.validation.items() if k != "allow_invalid"}
    layers = [config, checks or {}]
    allow = spec.validation.get("allow_invalid", False) if allow_invalid is None else allow_invalid
    result = Result()
    # Claim every target before any work: a concurrent run to the same file is refused now.
    with terminate_as_interrupt(), claim([p.target for p in planned], overwrite, inputs):
        jobs = []  # (Planned, payload to write, the BRDF that payload holds)
        for grid, members in _groups(planned):
            # one tabulation per target grid; formats with their own prepare (they sample the
            # model themselves, like the RGL writer) are given the model
            needs_table = any(m.format.prepare is None for m in members)
            if needs_table:
                source = tabulate(spec.model, grid, spec.wavelengths, progress=progress, provenance=provenance)
            else:
                source = spec.model
            for m in members:
                options = _with_wavelengths(m, spec.wavelengths)
                with formats.naming(m.target):
                    payload = formats.prepare(m.format, source, m.grid, options)
                jobs.append((m, options, payload, payload if isinstance(payload, BRDF) else source))
        # validate what is written, before anything is: a table's metadata gets the report
        reports = {}
        for m, _, _, checked in jobs:
            key = id(checked)
            if key in reports:
                continue
            where = ", ".join(str(j[0].target) for j in jobs if j[3] is checked)
            grid = getattr(checked, "grid", None)
            # the spec's model, unless the format tabulated something derived from it (MERL's
            # φh average or symmetrization): then the table's provenance names what it holds
            made_from = getattr(checked, "ds", None)
            derived = made_from is not None and made_from.attrs.get("model") != spec.model.name
            label = ", ".join(j[0].target.name for j in jobs if j[3] is checked)
            with check_progress(label, progress, _progress_delay(started)):
                reports[key] = guard(checked, layers, allow_invalid=allow, what=where,
                                     reference=None if derived else spec.model, wavelengths=spec.wavelengths,
                                     subject=f"{spec.path.name} on "
                                             f"{grid.describe() if grid is not None else 'its own grid'}")
        for m, options, payload, checked in jobs:
            with write_progress(m.target.name, progress, _progress_delay(started)):
                formats.write_prepared(m.format, payload, m.target, overwrite=overwrite, options=options)
            result.written.append(m.target)
            result.tables.append(payload if hasattr(payload, "grid") else checked)
            result.reports.append(reports[id(checked)])
    return result


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
    """Check what :func:`run` would export for ``spec``, writing nothing: the model tabulated
    on each target grid (or the model itself for formats that sample it), checked with the
    spec's ``[validation]`` and ``checks`` (command-line layer). Returns one
    :class:`~brdftab.checks.Report` per target grid."""
    from .checks import run_checks

    config = {k: v for k, v in spec.validation.items() if k != "allow_invalid"}
    provenance = {"spec_sha256": spec.sha256, "spec_file": spec.path.name}
    reports = []
    for grid, members in _groups(plan(spec)):
        if any(m.format.prepare is None for m in members):
            source = tabulate(spec.model, grid, spec.wavelengths, progress=progress, provenance=provenance)
        else:
            source = spec.model
        where = grid.describe() if grid is not None else "its own grid"
        reports.append(run_checks(source, [config, checks or {}], reference=spec.model, wavelengths=spec.wavelengths,
                                  subject=f"{spec.path} ({where})"))
    return reports
