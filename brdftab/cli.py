"""The ``brdftab`` command line.

Verbs: ``tabulate``, ``convert``, ``eval``, ``info``, ``models``, ``plot``, ``fit``. Angles on the command line
are in degrees (``--wi-deg θ,φ``). Bad input — in a file or on the command line — prints one
line ``brdftab: error: …`` on stderr and exits with code 2, never a traceback (``--debug``,
before or after the verb, shows it). A refused validation exits with 1 where documented,
SIGINT with 130, SIGTERM with 143; a closed output pipe (``brdftab models | head -1``) ends
quietly with 141, as a process killed by SIGPIPE would.

This module imports click and numpy only: each verb imports what it runs on (models, formats,
checks; xarray, netCDF4, scipy through them) when it runs, so ``--help``, ``--version`` and a
verb's ``--help`` answer in about the time of ``import numpy``. Help text that names choices
from a registry takes them from a static copy that a test holds equal to it.
"""

from __future__ import annotations

import contextlib
import importlib
import json
import os
import signal
import sys
import warnings
from pathlib import Path

import click
import numpy as np

from . import _atomic, _signals
from ._version import __version__
from .cli_fit import fit
from .cli_plot import plot
from .cli_validate import check_options, cli_layer, engine_options, origin_option, validate
from .errors import OUT_OF_MEMORY, BrdftabError, printable as _printable, shown

DEBUG_KEY = "brdftab.debug"


def _set_debug(ctx, param, value):
    if value:
        ctx.meta[DEBUG_KEY] = True


def _debug_option():
    return click.Option(["--debug"], is_flag=True, expose_value=False, is_eager=True, callback=_set_debug,
                        help="Show tracebacks instead of one-line errors.")


def _one_line(exc) -> str:
    """A message on one line, a file name's bytes that are not UTF-8 as \\xNN escapes."""
    return shown(" ".join(str(exc).split()))


def _error(text: str) -> None:
    click.echo(f"brdftab: error: {_printable(text)}", err=True)  # a file name's control characters escaped


def _quiet_closed_pipe() -> None:
    """stdout's reader went away: send what is left to /dev/null so the exit stays quiet."""
    with contextlib.suppress(Exception):
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)


def _stopped(kind: str, written_before: int) -> str:
    done = _atomic.completed()[written_before:]
    if done:
        return f"brdftab: {kind}; only {', '.join(str(p) for p in done)} written"
    return f"brdftab: {kind}; no output written"


def _show_warning(message, category, filename, lineno, file=None, line=None):
    text = _one_line(message)
    if issubclass(category, RuntimeWarning) and text.split(" encountered in ")[0] in _FP_MEANING:
        text = _floating_point(text, filename, lineno)
    if text in _shown:  # the same numerical note from every chunk or check: once per run
        return
    _shown.add(text)
    click.echo(f"brdftab: warning: {text}", err=True)


#: NumPy's floating-point warnings ("overflow encountered in square"), said in words.
_FP_MEANING = {
    "overflow": "a value exceeded the float64 range (about 1.8e308) and became infinite",
    "invalid value": "an undefined operation (0/0, inf - inf, inf/inf, sqrt of a negative) gave NaN",
    "divide by zero": "a division by zero gave an infinite value",
    "underflow": "a value below the float64 range became 0",
}
_shown: set = set()


def _floating_point(text: str, filename: str, lineno: int) -> str:
    """One line for a NumPy floating-point warning: what happened and in which part of brdftab
    (figures computed from such values may be inf or NaN)."""
    kind, _, op = text.partition(" encountered in ")
    path = Path(filename)
    parts = path.parts
    where = "/".join(parts[parts.index("brdftab"):]) if "brdftab" in parts else path.name
    noun = {"invalid value": "invalid operation", "divide by zero": "division by zero"}.get(kind, kind)
    meaning = _FP_MEANING[kind]
    if kind == "overflow" and op == "cast":  # a conversion to a narrower type, e.g. float32 storage
        meaning = "a value exceeded the range of the type it was converted to (float32: about 3.4e38) and became infinite"
    return f"numerical {noun} ({op}) in {where}, line {lineno}: {meaning}; figures computed from it may be inf or NaN"


class _Group(click.Group):
    """Turns every error into one line on stderr and an exit code; adds ``--debug`` to every verb."""

    def add_command(self, cmd, name=None):
        if not any("--debug" in getattr(p, "opts", ()) for p in cmd.params):
            cmd.params.append(_debug_option())
        super().add_command(cmd, name)

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True, **extra):
        """Run the command line; usage errors and signals end with one line and an exit code."""
        written_before = len(_atomic.completed())
        if prog_name is None:
            prog_name = "brdftab"
        show = warnings.showwarning
        warnings.showwarning = _show_warning
        _shown.clear()
        try:
            with _signals.handling():  # SIGINT -> KeyboardInterrupt, SIGTERM -> Terminated
                code = self._main(args, prog_name, complete_var, written_before, **extra)
                swallowed = _signals.pending()
                if swallowed is not None and code not in (130, 143):  # a library lost its exception
                    terminated = swallowed == signal.SIGTERM
                    click.echo(_stopped("terminated" if terminated else "interrupted", written_before), err=True)
                    code = 143 if terminated else 130
            with contextlib.suppress(Exception):
                sys.stdout.flush()
        except BrokenPipeError:
            _quiet_closed_pipe()
            code = 141
        finally:
            warnings.showwarning = show
        if not standalone_mode:
            return code
        sys.exit(code or 0)

    def _main(self, args, prog_name, complete_var, written_before, **extra):
        try:
            rv = super().main(args, prog_name, complete_var, standalone_mode=False, **extra)
        except click.exceptions.NoArgsIsHelpError as exc:
            click.echo(exc.ctx.get_help() if exc.ctx is not None else _one_line(exc.format_message()))
            return 0
        except click.UsageError as exc:
            hint = f" (see '{exc.ctx.command_path} --help')" if exc.ctx is not None else ""
            _error(f"{_one_line(exc.format_message()).rstrip('.')}{hint}")
            return 2
        except click.ClickException as exc:
            _error(_one_line(exc.format_message()))
            return 2
        except click.Abort as exc:  # KeyboardInterrupt or EOF while click parsed the command line
            terminated = isinstance(exc.__context__, _signals.Terminated)
            click.echo(_stopped("terminated" if terminated else "interrupted", written_before), err=True)
            return 143 if terminated else 130
        except _signals.Terminated:
            click.echo(_stopped("terminated", written_before), err=True)
            return 143
        except KeyboardInterrupt:
            click.echo(_stopped("interrupted", written_before), err=True)
            return 130
        return rv if isinstance(rv, int) else 0

    def invoke(self, ctx):
        written_before = len(_atomic.completed())

        def debug():
            return bool(ctx.meta.get(DEBUG_KEY))

        try:
            return super().invoke(ctx)
        except BrdftabError as exc:
            if debug():
                raise
            _error(_one_line(exc))
            ctx.exit(exc.exit_code)
        except BrokenPipeError:  # the reader of stdout has gone (| head): end quietly
            _quiet_closed_pipe()
            ctx.exit(141)
        except OSError as exc:
            if debug():
                raise
            where = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
            _error(f"{where}{exc.strerror or exc}")
            ctx.exit(2)
        except _signals.Terminated:
            click.echo(_stopped("terminated", written_before), err=True)
            ctx.exit(143)
        except KeyboardInterrupt:
            click.echo(_stopped("interrupted", written_before), err=True)
            ctx.exit(130)
        except MemoryError:
            if debug():
                raise
            _error(OUT_OF_MEMORY)
            ctx.exit(2)
        except RecursionError:
            if debug():
                raise
            _error("input nested too deeply to process")
            ctx.exit(2)
        except (click.exceptions.Exit, click.ClickException, click.Abort, SystemExit):
            raise
        except Exception as exc:  # a bug: still one line, with a pointer to --debug
            if debug():
                raise
            click.echo(f"brdftab: internal error: {type(exc).__name__}: {_one_line(exc)} "
                       "(run with --debug for the traceback)", err=True)
            ctx.exit(1)


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="brdftab")
@click.option("--debug", is_flag=True, expose_value=False, is_eager=True, callback=_set_debug,
              help="Show tracebacks instead of one-line errors (also accepted after the verb).")
def main():
    """Tabulate, convert and validate BRDFs."""


def _runs_on(*modules):
    """Declare the brdftab modules a verb runs on (``.pipeline``, ...). The command line itself
    imports none of them, so that ``--help`` and ``--version`` start at once; :func:`preload`
    imports a verb's before the verb starts."""
    def mark(command):
        command.runs_on = modules
        return command
    return mark


def preload(args) -> None:
    """Import the modules the verb in ``args`` runs on (nothing for ``--help``, ``--version``
    or no verb). The entry point calls this while its start-up signal handlers are in place:
    a signal while xarray, netCDF4 or scipy load ends the run as one during start-up does."""
    if any(a in ("-h", "--help", "--version") for a in args):
        return
    verb = next((a for a in args if not a.startswith("-")), None)
    for module in getattr(main.commands.get(verb), "runs_on", ()):
        importlib.import_module(module, __package__)


# --------------------------------------------------------------------------------------------
@_runs_on(".pipeline", ".batch", ".sweep")
@main.command()
@click.argument("specs", metavar="SPEC...", nargs=-1, required=True,
                type=click.Path(dir_okay=False, path_type=Path))
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path),
              help="Write outputs into DIR instead of the spec file's folder (created if missing).")
@click.option("--overwrite", is_flag=True, help="Replace existing output files.")
@click.option("--allow-invalid", is_flag=True, default=None,
              help="Write even if a check fails (the report is stored in the file's metadata).")
@check_options
@click.option("--progress/--no-progress", default=None,
              help="Progress bar (default: on a terminal, for runs over 2 s).")
@engine_options
@click.pass_context
def tabulate(ctx, specs, out_dir, overwrite, allow_invalid, levels, settings, progress, workers, scheduler):
    """Tabulate the model of each SPEC on each output's grid, validate, and write its outputs.

    A spec with a [sweep] table runs once per member and writes a summary table. Several
    specs (and sweep members) run one after another, or in parallel with --workers or
    --scheduler; a failed one reports its error while the others finish."""
    from .batch import Engine, result_lines, tabulate_many
    from .pipeline import run
    from .spec import load_spec
    from .sweep import is_sweep

    layer = cli_layer(levels, settings)
    Engine(workers, scheduler)  # a missing dask or both options: one line before anything is read
    if len(specs) > 1 or workers is not None or scheduler is not None or is_sweep(specs[0]):
        ctx.exit(tabulate_many(specs, out_dir=out_dir, overwrite=overwrite, allow_invalid=allow_invalid,
                               checks=layer, progress=progress, workers=workers, scheduler=scheduler,
                               echo=click.echo, echo_err=lambda text: click.echo(_printable(text), err=True)))
    result = run(load_spec(specs[0]), out_dir=out_dir, overwrite=overwrite, allow_invalid=allow_invalid,
                 progress=progress, checks=layer)
    lines, warned = result_lines(result)
    for line in lines:
        click.echo(line)
    for line in warned:  # what the checks found in what was written: one line per report
        click.echo(line, err=True)


#: The formats brdftab reads and writes, with their extensions, as ``convert --to`` lists them:
#: a copy of :func:`brdftab.formats.usable` kept here so that ``--help`` does not import the
#: format modules (xarray, netCDF4, the models); a test holds it equal to the registry.
USABLE_FORMATS = (("netcdf", (".nc", ".nc4", ".netcdf")), ("zarr", (".zarr",)), ("merl", (".binary",)),
                  ("pbsdf", (".pbsdf",)), ("rgl", (".bsdf",)), ("exr", (".exr",)), ("zemax", (".bsdf",)),
                  ("lighttools", (".bsdf",)), ("mbsdf", (".mbsdf",)),
                  ("speos", (".anisotropicbsdf",)), ("speos-brdf", (".brdf",)), ("radiance", (".xml",)),
                  ("astm", (".astm",)), ("csv", (".csv",)))


def _format_names() -> str:
    return ", ".join(f"{n} ({'/'.join(ext)})" for n, ext in USABLE_FORMATS)


# --------------------------------------------------------------------------------------------
@_runs_on(".convert", ".checks")
@main.command()
@click.argument("source", metavar="IN", type=click.Path(path_type=Path))
@click.argument("target", metavar="OUT", type=click.Path(path_type=Path))
@click.option("--to", "fmt", metavar="FORMAT",
              help="Output format (default: from OUT's extension); one of " + _format_names() + ".")
@click.option("--grid", "grid_text", metavar="GRID",
              help="Grid to write on: a grid type ('merl', 'rusinkiewicz', ...) or a TOML inline table of [grid] "
                   "keys, e.g. '{type = \"rusinkiewicz\", n_theta_h = 45}'. Default: IN's grid (or the one the "
                   "format stores).")
@click.option("--grid-file", type=click.Path(dir_okay=False, path_type=Path),
              help="Read the grid from the [grid] table of a TOML file (a spec file works).")
@click.option("--option", "-o", "options", metavar="KEY=VALUE", multiple=True,
              help="Format option (repeatable); VALUE is a TOML value or plain text, e.g. -o dtype=float32.")
@click.option("--fold", is_flag=True,
              help="Average IN into the target grid's symmetries when it has fewer (an anisotropic table on an "
                   "isotropic grid, a non-reciprocal one on a grid folded by reciprocity).")
@click.option("--overwrite", is_flag=True, help="Replace OUT if it exists.")
@click.option("--allow-invalid", is_flag=True,
              help="Write OUT even if it fails validation (stamped validation_passed = 0).")
@origin_option
@check_options
@click.option("--progress/--no-progress", default=None,
              help="Progress bar (default: on a terminal, for runs over 2 s).")
@click.option("--json", "as_json", is_flag=True, help="Print what was done as JSON.")
def convert(source, target, fmt, grid_text, grid_file, options, fold, overwrite, allow_invalid, origin, levels,
            settings, progress, as_json):
    """Convert the table file IN into OUT, in another format or on another grid.

    IN's check results are reported (and carried in OUT's metadata) without refusing; what is
    written is validated before it is written: an OUT that fails a check is refused with exit
    code 1 and nothing written, unless --allow-invalid. A table already on the target grid is
    copied; otherwise it is resampled (default grid: IN's own, or one that keeps IN's
    symmetries), and the difference between OUT and IN is reported; a resampled OUT whose
    relative error of f at θi, θo ≤ 80° exceeds a median of 2 % or a 95th percentile of 10 %
    is refused (exit code 1) unless --allow-invalid.
    """
    from . import convert as conv

    if grid_text is not None and grid_file is not None:
        raise click.UsageError("give either --grid or --grid-file, not both")
    opts = {}
    for text in options:
        key, value = conv.format_option(text)
        if key in opts:
            raise BrdftabError(f"--option {key} given twice")
        opts[key] = value
    grid = wavelengths = None
    inputs = []
    if grid_text is not None:
        grid, wavelengths = conv._build_grid(conv.grid_option(grid_text), "--grid")
    elif grid_file is not None:
        grid, wavelengths = conv._build_grid(conv.grid_file(grid_file), f"{grid_file}: grid")
        inputs.append((grid_file, "the grid file"))
    checks = None
    if levels or settings:

        checks = cli_layer(levels, settings)
    result = conv.convert(source, target, grid=grid, wavelengths=wavelengths, format=fmt, options=opts,
                          overwrite=overwrite, fold=fold, allow_invalid=allow_invalid, checks=checks,
                          progress=progress, inputs=inputs, origin=origin)
    if result.input_report is not None and result.input_report is not result.report:
        for o in result.input_report.failures + result.input_report.warnings:
            click.echo(f"brdftab: warning: input {source.name}: {o.status.upper()} {o.name}: {o.detail}", err=True)
    for o in result.report.warnings:
        click.echo(f"brdftab: warning: {o.name}: {o.detail}", err=True)
    for o in result.report.failures:
        click.echo(f"brdftab: warning: written despite a failed check: {o.name}: {o.detail}", err=True)
    if as_json:
        click.echo(json.dumps(result.to_json(), default=str))
        return
    written = result.written
    what = ""
    if getattr(written, "spectral", False):
        what = f", {len(written.wavelengths)} wavelengths"
    elif getattr(written, "channels", None):
        what = f", channel{'s' if len(written.channels) > 1 else ''} {', '.join(written.channels)}"
    grid_text_out = f"{result.target_grid}" if result.target_grid else "the format's own sampling"
    click.echo(f"wrote {result.target} ({result.format}, {grid_text_out}{what})")
    for why in result.folded:
        click.echo(f"folded: averaged because {why}")
    colour = getattr(written, "ds", None) is not None and "colour_illuminant" in written.ds.attrs \
        and getattr(result.input_table, "spectral", False)
    if colour:
        a = written.ds.attrs
        click.echo(f"colour: the spectra converted to {a['colour_space']} under {a['colour_illuminant']}, "
                   f"{a['colour_observer']} ({a['colour_conversion']})")
    if not result.resampled:
        click.echo("copied: same grid as the input" + (", in colour" if colour else ", values unchanged"))
        return
    click.echo(f"resampled: {result.source_grid or 'the input'} -> {grid_text_out}")
    if result.refined:
        click.echo(f"refined: {result.refined}")
    x = result.extrapolated
    if x:
        click.echo(f"extrapolated: {x['outside']} of {x['nodes']} nodes ({100 * x['fraction']:.3g} %) lie outside the "
                   f"hull of the input's scattered samples and take their nearest sample's value (up to "
                   f"{x['max_distance']:.3g} away)")
    d = result.difference
    if d is not None:
        click.echo(f"resampling error of f cosθi cosθo: rms relative {d.rms_rel:.3g}, max relative {d.max_rel:.3g} "
                   f"({d.points} check points, written table vs {'the averaged ' if result.folded else ''}input)")
        click.echo(f"median relative error of f at θi, θo ≤ 80°: {d.median_rel:.3g}, 95th percentile {d.p95_rel:.3g}")
    elif result.note:
        click.echo(f"resampling error: not computed ({result.note})")


# --------------------------------------------------------------------------------------------
def _direction(text, option):
    written = text.replace(" ", "").split(",")
    try:
        parts = [float(p) for p in written]
    except ValueError:
        parts = []
    if len(parts) != 2 or not all(np.isfinite(parts)):
        raise BrdftabError(f"{option} expects two angles in degrees 'theta,phi', got {text!r}")
    theta, phi = parts
    if not 0.0 <= theta <= 90.0:  # the digits as written: 90.0000001 is not "90"
        raise BrdftabError(f"{option}: theta must lie in [0, 90] degrees, got {written[0]}")
    from .geometry import reduce_azimuth_deg

    return theta, reduce_azimuth_deg(phi)


def _content_format(path: Path):
    """The registered table format whose content (magic bytes, sniffer) ``path`` has, or None."""
    from . import formats

    try:
        with open(path, "rb") as fh:
            head = fh.read(formats.HEAD_BYTES)
            size = fh.seek(0, 2)
    except OSError:
        return None
    for fmt in formats.FORMATS.values():
        if fmt.opens(head, size):
            return fmt
    return None


def _is_table_file(path: Path) -> bool:
    """A table by content; else by a table format's extension. Anything else is a spec."""
    from . import formats

    if _content_format(path) is not None:
        return True
    if path.suffix.lower() == ".toml":
        return False
    try:
        formats.format_for(path)
    except BrdftabError:
        return False
    return True


def _load_source(source: Path):
    if not source.is_dir() and not _is_table_file(source):  # a folder: a store, or one error line
        from .spec import load_spec

        s = load_spec(source)
        return s.model, s.wavelengths
    from . import formats

    table = formats.read(source)
    if hasattr(table, "outside"):
        table.outside = "raise"  # a direction pair outside the table's domain is an error, not NaN
    return table, None


@_runs_on(".spec", ".formats", ".geometry")
@main.command("eval")
@click.argument("source", type=click.Path(path_type=Path))
@click.option("--wi-deg", required=True, help="Incident direction 'theta,phi' in degrees.")
@click.option("--wo-deg", required=True, help="Outgoing direction 'theta,phi' in degrees.")
@click.option("--wavelength-nm", "wavelengths", multiple=True, type=float,
              help="Wavelength in nm (repeatable); for spectral sources.")
@click.option("--json", "as_json", is_flag=True, help="Print JSON.")
def eval_(source, wi_deg, wo_deg, wavelengths, as_json):
    """Evaluate the BRDF of SOURCE (a spec file or a table file) at one direction pair.

    SOURCE is read as a table when its content is a table format's (whatever its name),
    otherwise as a spec. Prints f in 1/sr per channel or wavelength.
    """
    from .geometry import sph_to_vec

    wi_a = _direction(wi_deg, "--wi-deg")
    wo_a = _direction(wo_deg, "--wo-deg")
    brdf, spec_lam = _load_source(source)
    lam = list(wavelengths) or (None if spec_lam is None else list(spec_lam))
    wi = sph_to_vec(*np.radians(wi_a))
    wo = sph_to_vec(*np.radians(wo_a))
    f = brdf.eval(wi, wo, lam)
    if brdf.spectral or lam is not None:
        names = [f"{x:g} nm" for x in (lam if lam is not None else brdf.wavelengths)]
        keys = [float(x) for x in (lam if lam is not None else brdf.wavelengths)]
    else:
        names = list(brdf.channels)
        keys = names
    finite = bool(np.all(np.isfinite(f)))

    def value(v):
        return float(v) if np.isfinite(v) else None  # JSON has no NaN: null

    if as_json:
        out = {"source": str(source), "model": brdf.name, "wi_deg": list(wi_a), "wo_deg": list(wo_a),
               "units": "sr-1", "finite": finite}
        if isinstance(keys[0], float):
            out["wavelengths_nm"] = keys
            out["values"] = [value(v) for v in f]
        else:
            out["channels"] = {k: value(v) for k, v in zip(keys, f)}
        click.echo(json.dumps(out))
    else:
        for name, v in zip(names, f):
            click.echo(f"{_printable(name)}\t{v:.9g}")
    if not finite:
        bad = [n for n, v in zip(names, f) if not np.isfinite(v)]
        err = BrdftabError(f"{source}: f is not finite at this pair in {', '.join(bad)} (missing samples or no data "
                           "there)")
        err.exit_code = 1
        raise err


# --------------------------------------------------------------------------------------------
@_runs_on(".formats")
@main.command()
@click.argument("file", type=click.Path(path_type=Path))
@click.option("--json", "as_json", is_flag=True, help="Print JSON.")
def info(file, as_json):
    """Describe a table file: grid, channels, provenance and value range."""
    from . import formats

    fmt = formats.detect(file)
    table = formats.read(file)
    ds = table.ds
    stats = table.statistics()  # streamed: the samples are never loaded whole
    axes = [{"name": a.name, "size": len(a), "min_deg": float(np.degrees(a.values[0])),
             "max_deg": float(np.degrees(a.values[-1]))} for a in table.grid.axes]
    if getattr(table.grid, "scattered", False):  # scattered samples: the range of each angle
        g = table.grid
        axes = [{"name": n, "size": g.size, "min_deg": float(np.degrees(getattr(g, n).min())),
                 "max_deg": float(np.degrees(getattr(g, n).max())), "samples": True}
                for n in ("theta_i", "phi_i", "theta_o", "phi_o")]
    attrs = {k: (v_.item() if hasattr(v_, "item") else v_) for k, v_ in ds.attrs.items()}
    data = {
        "file": str(file),
        "format": fmt.name,
        "grid": table.grid.describe(),
        "axes": axes,
        "channels": list(table.channels) if not table.spectral else None,
        "wavelengths_nm": [float(x) for x in table.wavelengths] if table.spectral else None,
        **stats,
        "attributes": attrs,
    }
    validation = _stored_validation(attrs)
    data.update(validation)  # "validation" and "input_validation": {"passed", "summary"}, as recorded
    if as_json:
        click.echo(json.dumps(data, default=str))
        return
    lines = [f"{file}  [{fmt.name}]"]
    if attrs.get("comment"):
        lines.append(f"  description: {_one_line(attrs['comment'])}")
    if attrs.get("spec_file") or attrs.get("spec_sha256"):
        sha = str(attrs.get("spec_sha256") or "")
        name = attrs.get("spec_file") or "(unnamed)"
        lines.append(f"  spec file:   {name}" + (f"  (sha256 {sha[:16]}...)" if sha else ""))
    if attrs.get("material"):
        lines.append(f"  material:    {attrs['material']}")
    lines.append(f"  model:       {attrs.get('model', table.name)}")
    lines += _parameter_lines(attrs.get("model"), attrs.get("parameters"), 4)
    lines.append(f"  grid:        {data['grid']}")
    for a in axes:
        what = "samples" if a.get("samples") else "nodes"
        lines.append(f"    {a['name']:<9} {a['size']:>5} {what}  {a['min_deg']:.4g} .. {a['max_deg']:.4g} deg")
    if table.spectral:
        lines.append(f"  wavelengths: {', '.join(f'{x:g}' for x in table.wavelengths)} nm")
    else:
        lines.append(f"  channels:    {', '.join(table.channels)}")
    missing = f", {data['missing']} missing" if data["missing"] else ""
    lines.append(f"  values:      {data['dtype']}, {data['samples']} samples, min {data['min']:.6g}, max "
                 f"{data['max']:.6g} sr-1, {data['nonfinite']} non-finite, {data['negative']} negative{missing}"
                 if data["min"] is not None else f"  values:      {data['samples']} samples, none finite{missing}")
    if getattr(table, "polarized", False):
        var = table.ds["mueller"]
        lines.append(f"  mueller:     4 x 4 per sample ({var.dtype}), basis {var.attrs.get('mueller_basis')}, "
                     f"{var.attrs.get('mueller_circular')}; brdf is its M00")
    for key, what in (("validation", "validation:"), ("input_validation", "input validation:")):
        if key in validation:
            v = validation[key]
            verdict = {True: "passed", False: "FAILED", None: "recorded"}[v.get("passed")]
            lines.append(f"  {what:<22} {verdict}" + (f": {_one_line(v['summary'])}" if v.get("summary") else ""))
    for key in ("origin", "reciprocal", "isotropic", "parameterization", "sample_position", "phi_d_fold",
                "theta_h_spacing", "relative_to", "converted_from", "converted_from_sha256", "sweep_member",
                "sweep_values", "brdftab_version", "created"):
        if key in attrs:  # only what the file records
            lines.append(f"  {key + ':':<22} {attrs[key]}")
    steps = [step for step in str(attrs.get("history", "")).splitlines() if step.strip()]
    if steps:
        lines.append("  history:")
        lines += [f"    {' '.join(step.split())}" for step in steps]
    for line in lines:
        click.echo(_printable(line))


def _stored_validation(attrs) -> dict:
    """The validation results a file records: {"validation": {"passed", "summary"}} and the
    same for "input_validation" (a conversion's input), for those it has."""
    out = {}
    for key in ("validation", "input_validation"):
        passed, summary = attrs.get(f"{key}_passed"), attrs.get(f"{key}_summary")
        if passed is None and summary is None:
            continue
        try:
            verdict = None if passed is None else bool(int(passed))
        except (TypeError, ValueError):
            verdict = None
        out[key] = {"passed": verdict, "summary": None if summary is None else str(summary)}
    return out


def _toml_value(v) -> str:
    """A parameter value written as in a spec file."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return f"{v:.6g}"
    if isinstance(v, (int, str)):
        return json.dumps(v, ensure_ascii=False) if isinstance(v, str) else str(v)
    if v is None:
        return "none"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{k} = {_toml_value(x)}" for k, x in v.items()) + "}"
    return str(v)


def _parameter_lines(model, parameters, indent: int) -> list:
    """``name = value`` lines of a table's ``parameters`` attribute (JSON); nested models
    indented under their name, angles in degrees under their ``_deg`` spec key."""
    from . import models as registry

    if parameters is None or parameters == "":
        return []
    if isinstance(parameters, str):
        try:
            parameters = json.loads(parameters)
        except json.JSONDecodeError:
            return [f"{' ' * indent}parameters: {_one_line(parameters)}"]
    if not isinstance(parameters, dict):
        return [f"{' ' * indent}parameters: {_one_line(parameters)}"]
    cls = registry.MODELS.get(model, None) if isinstance(model, str) else None
    declared = {p.name: p for p in getattr(cls, "params", ())}
    pad = " " * indent
    lines = []

    def nested(v):
        return isinstance(v, dict) and "model" in v and isinstance(v.get("parameters", {}), dict)

    for key, value in parameters.items():
        p = declared.get(key)
        if nested(value):
            lines.append(f"{pad}{key}: {value['model']}")
            lines += _parameter_lines(value["model"], value.get("parameters", {}), indent + 2)
        elif isinstance(value, list) and value and all(nested(x) for x in value):
            for i, x in enumerate(value):
                lines.append(f"{pad}{key}[{i}]: {x['model']}")
                lines += _parameter_lines(x["model"], x.get("parameters", {}), indent + 2)
        elif p is not None and p.angle and isinstance(value, (int, float)) and not isinstance(value, bool):
            lines.append(f"{pad}{p.spec_key} = {_toml_value(float(np.degrees(value)))}")
        else:
            lines.append(f"{pad}{key} = {_toml_value(value)}")
    return lines


# --------------------------------------------------------------------------------------------
@_runs_on(".models", ".references")
@main.command()
@click.argument("name", required=False)
@click.option("--json", "as_json", is_flag=True, help="Print JSON.")
def models(name, as_json):
    """List the models, or show the parameters of model NAME."""
    from . import models as registry

    if name is None:
        if as_json:
            click.echo(json.dumps({n: c.summary for n, c in sorted(registry.MODELS.items())}))
            return
        width = max(len(n) for n in registry.MODELS)
        for n, cls in sorted(registry.MODELS.items()):
            click.echo(f"{n:<{width}}  {cls.summary}")
        return
    cls = registry.get(name)
    rows = []
    for p in cls.params:
        default = None if p.required else p.default
        rows.append({
            "name": p.name, "spec_key": p.spec_key, "kind": p.kind, "units": "deg (spec) / rad (API)" if p.angle
            else p.units, "default": default if not hasattr(default, "to_json") else default.to_json(),
            "required": p.required, "range": p.range_text(), "choices": list(p.choices), "doc": p.doc,
            "used_when": p.used_when,
        })
    if as_json:
        from .references import cite, keys_in

        click.echo(json.dumps({"name": cls.name, "summary": cls.summary, "reference": cls.reference,
                               "references": dict(zip(keys_in(cls.reference), cite(cls.reference))),
                               "parameters": rows}))
        return
    click.echo(f"{cls.name}: {cls.summary}")
    from .references import cite

    for i, text in enumerate(cite(cls.reference)):
        click.echo(f"{'references:' if i == 0 else '':<11} {text}")
    click.echo("parameters (spec key, accepted values, default):")
    for r, p in zip(rows, cls.params):
        default = ("required" if r["required"] else
                   "none" if r["default"] is None else f"default {_toml_value(r['default'])}")
        units = f" [{r['units']}]" if r["units"] and r["units"] != "1" else ""
        when = f"; {r['used_when']}" if r["used_when"] else ""
        click.echo(f"  {r['spec_key']}{units}: {p.expected()}; {default}{when}")
        click.echo(f"      {r['doc']}")


# --------------------------------------------------------------------------------------------
@_runs_on(".grids")
@main.command()
@click.argument("type_name", metavar="TYPE", required=False)
@click.option("--json", "as_json", is_flag=True, help="Print JSON.")
def grids(type_name, as_json):
    """List the grid types, or show the [grid] keys of grid TYPE with their defaults."""
    from .grids import COMMON_PARAMS, GRIDS

    if type_name is None:
        if as_json:
            click.echo(json.dumps({n: c.summary for n, c in GRIDS.items()}))
            return
        width = max(len(n) for n in GRIDS)
        for n, cls in GRIDS.items():
            click.echo(f"{n:<{width}}  {cls.summary}")
        return
    cls = GRIDS.get(type_name)
    params = tuple(cls.params) + COMMON_PARAMS
    rows = [{"key": p.spec_key, "expected": p.expected(), "default": p.to_json(None if p.required else p.default),
             "required": p.required, "used_when": p.used_when, "doc": p.doc} for p in params]
    if as_json:
        click.echo(json.dumps({"type": type_name, "summary": cls.summary, "keys": rows}))
        return
    click.echo(f"{type_name}: {cls.summary}")
    click.echo("keys ([grid] table; angles in degrees):")
    for r in rows:
        default = "required" if r["required"] else ("no default" if r["default"] is None
                                                    else f"default {_toml_value(r['default'])}")
        when = f"; {r['used_when']}" if r["used_when"] else ""
        click.echo(f"  {r['key']}: {r['expected']}; {default}{when}")
        click.echo(f"      {r['doc']}")


# --------------------------------------------------------------------------------------------
def _format_rows():
    from . import formats as fm

    rows = []
    for name, f in fm.FORMATS.items():
        try:
            g = fm.target_grid(f, None, {})
            stores = g.describe() if g is not None else ("any brdftab grid (the table's own)" if f.native_grid is None
                                                         else "its own sample layout")
        except BrdftabError:
            stores = "a grid chosen per file"
        rows.append({"name": name, "extensions": list(f.extensions), "description": f.description,
                     "read": f.read is not None, "write": f.write is not None, "stores": stores,
                     "requires": list(f.requires), "available": f.available,
                     "options": {p.name: {"expected": p.expected(), "default": p.to_json(p.default), "doc": p.doc}
                                 for p in f.params}})
    return rows


@_runs_on(".formats")
@main.command("formats")
@click.argument("name", required=False)
@click.option("--json", "as_json", is_flag=True, help="Print JSON.")
def formats_(name, as_json):
    """List the file formats (extensions, the grid each stores, read/write, optional library),
    or show the options of format NAME (given to tabulate as [[output]] keys and to convert as
    -o KEY=VALUE)."""
    rows = _format_rows()
    if name is None:
        if as_json:
            click.echo(json.dumps({r["name"]: {k: v for k, v in r.items() if k != "options"} for r in rows}))
            return
        for r in rows:
            rw = "/".join(x for x, ok in (("read", r["read"]), ("write", r["write"])) if ok)
            lib = f"; needs {', '.join(r['requires'])}" + ("" if r["available"] else " (not installed)") \
                if r["requires"] else ""
            click.echo(f"{r['name']:<7} {', '.join(r['extensions']):<10} {rw:<10} stores {r['stores']}{lib}")
            click.echo(f"        {r['description']}")
        return
    from . import formats as fm

    fm.FORMATS.get(name)  # an unknown name: one wording for every registry
    r = {row["name"]: row for row in rows}[name]
    if as_json:
        click.echo(json.dumps(r))
        return
    click.echo(f"{r['name']}: {r['description']}")
    click.echo(f"  extensions: {', '.join(r['extensions'])}; stores {r['stores']}")
    click.echo("options (-o KEY=VALUE with convert, KEY = VALUE in an [[output]] table):" if r["options"]
               else "options: none")
    for key, o in r["options"].items():
        default = "" if o["default"] is None else f"; default {_toml_value(o['default'])}"
        click.echo(f"  {key}: {o['expected']}{default}")
        click.echo(f"      {o['doc']}")


main.add_command(_runs_on(".pipeline", ".formats", ".checks")(validate))
main.add_command(_runs_on(".plot", ".spec", ".formats", ".integrate")(plot))
main.add_command(_runs_on(".fitting", ".spec", ".formats", ".integrate", ".batch")(fit))

if __name__ == "__main__":  # pragma: no cover
    main()
