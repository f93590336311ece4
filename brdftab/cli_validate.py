"""``brdftab validate FILE|SPEC …``: physics checks as a CI gate.

Each path (or glob) is a table file in any format brdftab reads, or a spec (``.toml``): a spec
is tabulated on each of its target grids, as ``brdftab tabulate`` would, and checked without
writing anything. Thresholds come from the defaults, then a spec's ``[validation]`` table,
then ``--config FILE`` (its ``[validation]`` table), then ``--level`` / ``--set``.

Output: one line per check (PASS / WARN / FAIL / SKIP with its figure), or ``--json`` (the
document :data:`brdftab.checks.SCHEMA_PATH` describes), and ``--junit PATH`` for CI
dashboards. Exit code 0 when every check passed (warnings allowed), 1 when a check failed, 2
when an input could not be read or an option is wrong.
"""

from __future__ import annotations

import contextlib
import glob
import json
import sys
from pathlib import Path

import click

from ._atomic import atomic_path
from ._locks import claim
from .errors import BrdftabError, ParameterError, printable, shown

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

__all__ = ["validate", "cli_layer", "expand_paths"]

_MAGIC = set("*?[")


def expand_paths(patterns) -> tuple:
    """(paths, errors): each pattern as it is, or the sorted matches of a glob (``**`` recurses)."""
    paths, errors = [], []
    for pat in patterns:
        if _MAGIC & set(pat):
            hits = sorted(glob.glob(pat, recursive=True))
            if not hits:
                errors.append((pat, BrdftabError(f"{pat}: no file matches")))
            from .formats import is_store

            # files, and stores (folders); never the files inside a store
            stores = [Path(h) for h in hits if is_store(h)]
            paths += [Path(h) for h in hits if (Path(h) in stores or not Path(h).is_dir())
                      and not any(s in Path(h).parents for s in stores)]
        else:
            paths.append(Path(pat))
    return paths, errors


def _value(text: str):
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def _memory(ctx, param, value):
    """``--memory SIZE``: the run's memory budget, handed down as ``BRDFTAB_MEMORY``."""
    if value is not None:
        import os

        from .table import parse_size

        parse_size(value, "--memory")  # a bad size is one line, before any work
        os.environ["BRDFTAB_MEMORY"] = value
    return value


def check_options(command):
    """The ``--level CHECK=LEVEL``, ``--set CHECK.NAME=VALUE`` and ``--memory SIZE`` options of
    every command that runs checks (``validate``, ``tabulate``, ``convert``); :func:`cli_layer`
    reads the first two, the third sets the memory budget (:func:`brdftab.table.memory_budget`)."""
    command = click.option("--memory", metavar="SIZE", callback=_memory, expose_value=False,
                           help="Memory budget of the run, e.g. 512M or 4G (default 1G, or BRDFTAB_MEMORY): "
                                "larger tables are written, read and checked block by block.")(command)
    command = click.option("--set", "settings", multiple=True, metavar="CHECK.NAME=VALUE",
                           help="Set a check threshold, e.g. energy.tolerance=0.005 or albedo.expected=0.8 "
                                "(repeatable; angles as NAME_deg).")(command)
    return click.option("--level", "levels", multiple=True, metavar="CHECK=LEVEL",
                        help="Set a check's level: off, warn or error (repeatable).")(command)


def cli_layer(levels=(), settings=()) -> dict:
    """A configuration layer from ``--level CHECK=LEVEL`` and ``--set CHECK.NAME=VALUE`` (values
    are TOML: numbers, lists, strings)."""
    from .checks import configure

    layer: dict = {}
    for item in levels:
        name, sep, level = item.partition("=")
        if not sep or not name:
            raise BrdftabError(f"--level expects CHECK=LEVEL (off, warn or error), got {item!r}")
        layer.setdefault(name.strip(), {})["level"] = level.strip()
    for item in settings:
        key, sep, text = item.partition("=")
        check, dot, name = key.strip().partition(".")
        if not sep or not dot or not check or not name:
            raise BrdftabError(f"--set expects CHECK.THRESHOLD=VALUE (e.g. energy.tolerance=0.01), got {item!r}")
        layer.setdefault(check, {})[name] = _value(text.strip())
    try:
        configure(layer)
    except ParameterError as exc:
        raise BrdftabError(f"--level/--set {exc}") from None
    return layer


def _config_file(path: Path) -> dict:
    from .checks import configure

    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8-sig"))
    except FileNotFoundError:
        raise BrdftabError(f"--config {path}: no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise BrdftabError(f"--config {path}: cannot read ({exc})") from None
    except tomllib.TOMLDecodeError as exc:
        raise BrdftabError(f"--config {path}: invalid TOML: {exc}") from None
    layer = raw.get("validation", raw)
    if not isinstance(layer, dict):
        raise BrdftabError(f"--config {path}: expected a [validation] table")
    layer = {k: v for k, v in layer.items() if k != "allow_invalid"}
    try:
        configure(layer)
    except ParameterError as exc:
        raise BrdftabError(f"--config {path}: validation.{exc}") from None
    return layer


def engine_options(command):
    """``--workers N`` / ``--scheduler ADDRESS``: run many units on dask.distributed."""
    command = click.option("--scheduler", metavar="ADDRESS",
                           help="Run on the dask.distributed cluster whose scheduler listens at ADDRESS "
                                "(e.g. tcp://10.0.0.5:8786).")(command)
    return click.option("--workers", type=click.IntRange(min=1), metavar="N",
                        help="Run on a local dask.distributed cluster of N worker processes (needs the 'dist' "
                             "extra). Default: one after another in this process.")(command)


def origin_option(command):
    """``--origin``: the user's word on where a table's values come from."""
    return click.option("--origin", type=click.Choice(["analytic", "measured", "unknown"]), default=None,
                        help="Where the input's values come from (default: what the file records; a file that "
                             "records nothing is 'unknown'). Measured and unknown data are not assumed reciprocal "
                             "and their negative samples are reported, not refused.")(command)


def _check_one(path: Path, layers, progress, origin=None, bar=False, reads=None):
    """Reports for one input (a spec or a table file); ``reads`` (a list) gets the files a
    spec's model reads."""
    import warnings

    from . import formats
    from .checks import run_checks
    from .errors import BrdftabWarning

    if path.suffix.lower() == ".toml":
        from .pipeline import validate as validate_spec
        from .spec import load_spec
        from .sweep import is_sweep, load

        if is_sweep(path):  # every member, as tabulate would write it; a member that cannot be made is an error
            sweep = load(path)
            bad = next((m for m in sweep.members if m.error is not None), None)
            if bad is not None:
                raise type(bad.error)(f"{path} [{bad.describe()}]: {str(bad.error).removeprefix(f'{path}: ')}")
            specs = [(m.spec, f" [{m.describe()}]") for m in sweep.members]
        else:
            specs = [(load_spec(path), "")]
        out = []
        for spec, member in specs:
            if reads is not None:
                reads += spec.inputs
            for r in validate_spec(spec, checks=layers, progress=progress):
                r.subject = f"{spec.path}{member}{r.subject.removeprefix(str(spec.path))}"  # which member
                out.append(r)
        return out
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BrdftabWarning)
        table = formats.read(path)
    return [run_checks(table, layers, subject=shown(path), origin=origin, progress=bar)]


def list_checks() -> str:
    from .checks import CHECKS

    lines = []
    for name, c in CHECKS.items():
        lines.append(f"{name} [{c.family}, default level {c.level}]: {c.summary}")
        for p in c.thresholds:
            default = p.default
            if p.angle and isinstance(default, float):
                import math

                default = round(math.degrees(default), 6)
            lines.append(f"    {p.spec_key} = {default!r}: {p.doc}")
    return "\n".join(lines)


@click.command("validate")
@click.argument("paths", nargs=-1)
@click.option("--json", "as_json", is_flag=True,
              help="Print a JSON document (schema: brdftab/checks/report.schema.json) instead of text.")
@click.option("--junit", type=click.Path(dir_okay=False, path_type=Path), metavar="PATH",
              help="Also write JUnit XML to PATH (testsuite per input, testcase per check).")
@click.option("--html", "html_path", type=click.Path(dir_okay=False, path_type=Path), metavar="PATH",
              help="Also write a self-contained HTML report to PATH: every check, the albedo curve, in-plane "
                   "curves and a hemisphere map per input, and a map of where a failed reciprocity or energy "
                   "check fails.")
@check_options
@click.option("--config", "config_file", type=click.Path(dir_okay=False, path_type=Path),
              help="A TOML file whose [validation] table applies to every input (over a spec's own).")
@click.option("--list-checks", "list_checks_", is_flag=True,
              help="List the checks, their levels and thresholds, and exit.")
@click.option("--progress/--no-progress", default=False, help="Progress bar while a spec is tabulated.")
@click.option("--quiet", "-q", is_flag=True,
              help="No progress bar while the checks run (default: one on a terminal once they take over 1 s).")
@origin_option
@engine_options
@click.pass_context
def validate(ctx, paths, as_json, junit, html_path, levels, settings, config_file, list_checks_, progress, quiet,
             origin, workers, scheduler):
    """Check BRDF tables and specs: reciprocity, energy, albedo, sample audit, symmetry,
    conventions and tabulation error.

    PATHS are table files or spec files (.toml); globs are expanded. Exit code 0 when every
    check passed (warnings allowed), 1 when a check failed, 2 when an input could not be read.
    With --workers or --scheduler the inputs are checked in parallel; the report is the same.
    """
    if list_checks_:
        click.echo(list_checks())
        return
    from .batch import Engine

    engine = Engine(workers, scheduler)  # a missing dask or both options: one line before any check
    if not paths:
        raise BrdftabError("validate: give one or more table files or specs (or --list-checks)")
    layers = []
    if config_file is not None:
        layers.append(_config_file(config_file))
    layers.append(cli_layer(levels, settings))
    for option, report_path in (("--junit", junit), ("--html", html_path)):
        if report_path is not None and not report_path.parent.exists():
            raise BrdftabError(f"{option} {report_path}: no such folder {report_path.parent}")
    inputs, errors = expand_paths(paths)
    _refuse_missing(inputs, errors)
    # no report may replace a file this run reads (through .., symbolic or hard links too)
    reads = [(p, "the input file") for p in inputs] + ([(config_file, "the --config file")] if config_file else [])
    with contextlib.ExitStack() as outputs:
        reports_to = [p for p in (junit, html_path) if p is not None]
        if reports_to:  # claimed before any check runs: an unwritable folder is refused now
            outputs.enter_context(claim(reports_to, overwrite=True, inputs=reads))
        code = _validate(inputs, reads, layers, as_json, junit, progress, quiet, origin, engine, html_path)
    ctx.exit(code)


def _refuse_missing(inputs, errors) -> None:
    """Every input must be there before any checking starts (a spec may take minutes): one
    line naming each missing file, folder given as a file and glob that matches nothing."""
    from .formats import is_store

    problems = [" ".join(str(exc).split()) for _, exc in errors]
    for p in inputs:
        if p.is_dir() and not is_store(p):
            problems.append(f"{p}: is a folder, not a file")
        elif not p.exists():
            problems.append(f"{p}: no such file" + (" (a broken symbolic link)" if p.is_symlink() else ""))
    if problems:
        raise BrdftabError(f"{'; '.join(problems)} (nothing checked)")


def _validate(inputs, reads, layers, as_json, junit, progress, quiet, origin, engine=None, html_path=None) -> int:
    from .checks import junit_xml, run_document

    reports, errors = [], []
    if engine is not None and engine.distributed:
        reports, errors = _validate_on(engine, inputs, reads, layers, origin, quiet)
    for path in inputs if engine is None or not engine.distributed else ():
        try:
            reports += _check_one(path, layers, progress, origin, bar=not quiet and sys.stderr.isatty(), reads=reads)
        except BrdftabError as exc:
            errors.append((shown(path), exc))
        except OSError as exc:
            errors.append((shown(path), BrdftabError(f"{path}: {exc.strerror or exc}")))
    for subject, exc in errors:
        click.echo(f"brdftab: error: {printable(shown(' '.join(str(exc).split())))}", err=True)
    if as_json:
        click.echo(json.dumps(run_document(reports, errors), indent=1))
    else:
        for r in reports:  # channel names and file text as data: control and bidi characters escaped
            click.echo("\n".join(printable(line) for line in r.to_text().splitlines()))
        if len(reports) + len(errors) > 1:
            failed = sum(not r.passed for r in reports)
            click.echo(f"{len(reports)} checked: {len(reports) - failed} passed, {failed} failed; "
                       f"{len(errors)} could not be read")
    if junit is not None:
        with atomic_path(junit, overwrite=True, inputs=reads) as tmp:
            tmp.write_text(junit_xml(reports, errors), encoding="utf-8")
    if html_path is not None:
        page = _html_report(inputs, reports, errors, origin)
        with atomic_path(html_path, overwrite=True, inputs=reads) as tmp:
            tmp.write_text(page, encoding="utf-8")
    return 2 if errors else (1 if any(not r.passed for r in reports) else 0)


def _html_report(inputs, reports, errors, origin) -> str:
    """The HTML report (:mod:`brdftab.report_html`): each report drawn from its input, a table
    file read again (lazily) or a spec's model; a sweep's members are not drawn."""
    import warnings

    from . import formats
    from .errors import BrdftabWarning
    from .report_html import Entry, render

    drawn = {}

    def drawable(path):
        if path not in drawn:
            brdf, what = None, ""
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", BrdftabWarning)
                    if path.suffix.lower() == ".toml":
                        from .spec import load_spec
                        from .sweep import is_sweep

                        if not is_sweep(path):
                            brdf, what = load_spec(path).model, "the spec's model"
                    else:
                        brdf = formats.read(path)
                        if origin is not None:
                            brdf.origin = origin
            except BrdftabError:
                brdf = None
            drawn[path] = (brdf, what)
        return drawn[path]

    entries = []
    for r in reports:
        src = max((p for p in inputs if str(r.subject).startswith(shown(p))), key=lambda p: len(shown(p)), default=None)
        brdf, what = drawable(src) if src is not None else (None, "")
        entries.append(Entry(r, brdf, what))
    return render(entries, errors)


def _validate_on(engine, inputs, reads, layers, origin, quiet) -> tuple:
    """(reports, errors) of every input checked on ``engine``'s cluster (absolute paths sent,
    reports back as plain data), in the order of the inputs: the same as a serial run's."""
    from .batch import counted, ordered, show_warnings, unit_bar, validate_unit

    calls = [(str(Path(p).absolute()), layers, origin) for p in inputs]
    results = [None] * len(inputs)
    with engine, unit_bar(len(calls), "validating", "file", False if quiet else None) as bar:
        for i, res in ordered(counted(engine.map(validate_unit, calls), bar)):
            results[i] = res
    reports, errors = [], []
    for path, res in zip(inputs, results):
        show_warnings(res.get("warnings", ()))
        _subjects(res["reports"], Path(path))
        reports += res["reports"]
        reads += [(Path(p), what) for p, what in res.get("reads", ()) if (Path(p), what) not in reads]
        if res["error"] is not None:
            err = BrdftabError(_as_given(res["error"], path))
            err.exit_code = res["code"]
            errors.append((shown(path), err))
    return reports, errors


def _as_given(text: str, path: Path) -> str:
    """A worker's message about ``path`` (sent absolute) with the path as the user gave it."""
    head = shown(Path(path).absolute())
    return shown(path) + text[len(head):] if text.startswith(head) else text


def _subjects(reports, path: Path) -> None:
    """Report subjects name the input as the user gave it (a worker was given its absolute path)."""
    for r in reports:
        r.subject = _as_given(r.subject, path)
