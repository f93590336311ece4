"""spec → model → (one table per target grid) → checks → write (atomically): ``brdftab tabulate``.

Every output's format says which grid it stores (:func:`brdftab.formats.target_grid`): netCDF
keeps the spec's grid, MERL always stores the MERL grid, and so on. The model is tabulated
once per distinct target grid — each output is written from the model sampled on its own
grid, never from an interpolation of a table made on another grid. Every table is checked
before anything is written; a failed check refuses the whole run unless invalid output is
explicitly allowed.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from . import formats
from ._atomic import check_target, terminate_as_interrupt
from .checks import Report, run_checks
from .errors import BrdftabError, ValidationError
from .spec import Spec
from .table import Table, tabulate

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

    Output paths resolve against ``out_dir`` when given (else the spec's folder). Every
    target is checked before any work starts: an existing file without ``overwrite`` is
    refused. Each table is validated before export; a failed check refuses the export unless
    ``allow_invalid`` (or the spec's ``validation.allow_invalid``) is true. ``checks`` is a
    configuration layer over the spec's ``[validation]`` (command-line thresholds).
    """
    planned = plan(spec, out_dir)
    for p in planned:
        check_target(p.target, overwrite)
    if len({p.target.resolve() for p in planned}) != len(planned):
        raise BrdftabError(f"{spec.path}: two outputs write the same file")

    provenance = {"spec_sha256": spec.sha256, "spec_file": spec.path.name}
    if spec.description:
        provenance["comment"] = spec.description
    config = {k: v for k, v in spec.validation.items() if k != "allow_invalid"}
    layers = [config, checks or {}]
    allow = spec.validation.get("allow_invalid", False) if allow_invalid is None else allow_invalid
    result = Result()
    with terminate_as_interrupt():
        jobs = []  # (Planned, brdf to write, report)
        for grid, members in _groups(planned):
            # formats with their own prepare (they sample the model themselves) get the model
            needs_table = any(m.format.prepare is None for m in members)
            if needs_table:
                source = tabulate(spec.model, grid, spec.wavelengths, progress=progress, provenance=provenance)
            else:
                source = spec.model
            report = run_checks(source, _merge(layers))
            if not report.passed and not allow:
                where = ", ".join(str(m.target) for m in members)
                raise ValidationError(f"refusing to export {where}: {report.summary()} "
                                      "(pass --allow-invalid to write anyway)")
            for m in members:
                jobs.append((m, source, report))
        for m, source, report in jobs:
            written = formats.write(source, m.target, grid=m.grid, format=m.format.name, overwrite=overwrite,
                                    **m.options)
            result.written.append(m.target)
            result.tables.append(written if isinstance(written, Table) else source)
            result.reports.append(report)
    return result


def _merge(layers) -> dict:
    out = {}
    for layer in layers:
        for name, cfg in layer.items():
            out.setdefault(name, {}).update(cfg)
    return out
