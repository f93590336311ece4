"""spec → model → grid → table → validate → write (atomically), for ``brdftab tabulate``."""

from __future__ import annotations

from dataclasses import dataclass

from . import formats
from ._atomic import check_target, terminate_as_interrupt
from .errors import BrdftabError, ValidationError
from .spec import Spec
from .table import Table, tabulate
from .validate import Report, check_samples

__all__ = ["Result", "run"]


@dataclass
class Result:
    table: Table
    report: Report
    written: list


def run(spec: Spec, out_dir=None, overwrite: bool = False, allow_invalid: bool | None = None,
        progress: bool | None = None) -> Result:
    """Tabulate ``spec`` and write its outputs.

    Output paths resolve against ``out_dir`` when given (else the spec's folder). Every
    target is checked before any work starts: an existing file without ``overwrite`` is
    refused. The table is validated before export; a failed check refuses the export unless
    ``allow_invalid`` (or the spec's ``validation.allow_invalid``) is true.
    """
    targets = [out.target(out_dir) for out in spec.outputs]
    for target in targets:
        check_target(target, overwrite)
    if len({t.resolve() for t in targets}) != len(targets):
        raise BrdftabError(f"{spec.path}: two outputs write the same file")

    provenance = {"spec_sha256": spec.sha256, "spec_file": spec.path.name}
    if spec.description:
        provenance["comment"] = spec.description
    with terminate_as_interrupt():
        table = tabulate(spec.model, spec.grid, spec.wavelengths, progress=progress, provenance=provenance)
        report = check_samples(table)
        allow = spec.validation.get("allow_invalid", False) if allow_invalid is None else allow_invalid
        if not report.passed and not allow:
            raise ValidationError(f"refusing to export: {report.summary()} (pass --allow-invalid to write anyway)")
        written = []
        for out, target in zip(spec.outputs, targets):
            formats.write(table, target, format=out.format, overwrite=overwrite, **out.options)
            written.append(target)
    return Result(table, report, written)
