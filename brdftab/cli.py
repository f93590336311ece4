"""The ``brdftab`` command line.

Verbs: ``tabulate``, ``eval``, ``info``, ``models``. Angles on the command line are in
degrees (``--wi-deg θ,φ``). Bad input prints one line on stderr and exits with code 2 —
never a traceback (``--debug`` shows it).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import click
import numpy as np

from ._version import __version__
from .errors import BrdftabError


class _Group(click.Group):
    """Turns brdftab errors into one line on stderr and exit code 2."""

    def invoke(self, ctx):
        debug = bool(ctx.params.get("debug")) or "--debug" in sys.argv[1:]
        try:
            return super().invoke(ctx)
        except BrdftabError as exc:
            if debug:
                raise
            click.echo(f"brdftab: error: {_one_line(exc)}", err=True)
            ctx.exit(exc.exit_code)
        except OSError as exc:
            if debug:
                raise
            where = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
            click.echo(f"brdftab: error: {where}{exc.strerror or exc}", err=True)
            ctx.exit(2)
        except KeyboardInterrupt:
            click.echo("brdftab: interrupted; no output written", err=True)
            ctx.exit(130)
        except MemoryError:
            if debug:
                raise
            click.echo("brdftab: error: out of memory; use a coarser grid or fewer channels", err=True)
            ctx.exit(2)
        except (click.exceptions.Exit, click.ClickException, click.Abort, SystemExit):
            raise
        except Exception as exc:  # a bug: still one line, with a pointer to --debug
            if debug:
                raise
            click.echo(f"brdftab: internal error: {type(exc).__name__}: {_one_line(exc)} "
                       "(run with --debug for the traceback)", err=True)
            ctx.exit(1)


def _one_line(exc) -> str:
    return " ".join(str(exc).split())


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="brdftab")
@click.option("--debug", is_flag=True, help="Show tracebacks instead of one-line errors.")
def main(debug):
    """Tabulate, convert and validate BRDFs."""


# --------------------------------------------------------------------------------------------
@main.command()
@click.argument("spec", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path),
              help="Write outputs into DIR instead of the spec file's folder.")
@click.option("--overwrite", is_flag=True, help="Replace existing output files.")
@click.option("--allow-invalid", is_flag=True, default=None,
              help="Write even if the table fails validation (NaN or negative samples).")
@click.option("--progress/--no-progress", default=None,
              help="Progress bar (default: on a terminal, for runs over 2 s).")
def tabulate(spec, out_dir, overwrite, allow_invalid, progress):
    """Tabulate the model of SPEC on its grid and write its outputs."""
    from .pipeline import run
    from .spec import load_spec

    s = load_spec(spec)
    if out_dir is not None and not out_dir.is_dir():
        raise BrdftabError(f"--out {out_dir}: no such folder")
    result = run(s, out_dir=out_dir, overwrite=overwrite, allow_invalid=allow_invalid, progress=progress)
    t = result.table
    what = (f"{len(t.wavelengths)} wavelength{'s' if len(t.wavelengths) > 1 else ''}" if t.spectral
            else f"channel{'s' if len(t.channels) > 1 else ''} {', '.join(t.channels)}")
    for path in result.written:
        click.echo(f"wrote {path} ({t.grid.describe()}, {what})")
    if not result.report.passed:
        click.echo(f"brdftab: warning: written despite failed checks: {result.report.summary()}", err=True)


# --------------------------------------------------------------------------------------------
def _direction(text, option):
    try:
        parts = [float(p) for p in text.replace(" ", "").split(",")]
    except ValueError:
        parts = []
    if len(parts) != 2 or not all(np.isfinite(parts)):
        raise BrdftabError(f"{option} expects two angles in degrees 'theta,phi', got {text!r}")
    theta, phi = parts
    if not 0.0 <= theta <= 90.0:
        raise BrdftabError(f"{option}: theta must lie in [0, 90] degrees, got {theta:g}")
    return theta, phi


def _load_source(source: Path):
    if source.suffix.lower() == ".toml":
        from .spec import load_spec

        s = load_spec(source)
        return s.model, s.wavelengths
    from . import formats

    return formats.read(source), None


@main.command("eval")
@click.argument("source", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--wi-deg", required=True, help="Incident direction 'theta,phi' in degrees.")
@click.option("--wo-deg", required=True, help="Outgoing direction 'theta,phi' in degrees.")
@click.option("--wavelength-nm", "wavelengths", multiple=True, type=float,
              help="Wavelength in nm (repeatable); for spectral sources.")
@click.option("--json", "as_json", is_flag=True, help="Print JSON.")
def eval_(source, wi_deg, wo_deg, wavelengths, as_json):
    """Evaluate the BRDF of SOURCE (a spec file or a table file) at one direction pair.

    Prints f in 1/sr per channel or wavelength.
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
    if as_json:
        out = {"source": str(source), "model": brdf.name, "wi_deg": list(wi_a), "wo_deg": list(wo_a),
               "units": "sr-1"}
        if isinstance(keys[0], float):
            out["wavelengths_nm"] = keys
            out["values"] = [float(v) for v in f]
        else:
            out["channels"] = {k: float(v) for k, v in zip(keys, f)}
        click.echo(json.dumps(out))
    else:
        for name, v in zip(names, f):
            click.echo(f"{name}\t{v:.9g}")


# --------------------------------------------------------------------------------------------
@main.command()
@click.argument("file", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--json", "as_json", is_flag=True, help="Print JSON.")
def info(file, as_json):
    """Describe a table file: grid, channels, provenance and value range."""
    from . import formats

    fmt = formats.detect(file)
    table = formats.read(file)
    ds = table.ds
    v = table.values
    finite = np.isfinite(v)
    axes = [{"name": a.name, "size": len(a), "min_deg": float(np.degrees(a.values[0])),
             "max_deg": float(np.degrees(a.values[-1]))} for a in table.grid.axes]
    attrs = {k: (v_.item() if hasattr(v_, "item") else v_) for k, v_ in ds.attrs.items()}
    data = {
        "file": str(file),
        "format": fmt.name,
        "grid": table.grid.describe(),
        "axes": axes,
        "channels": list(table.channels) if not table.spectral else None,
        "wavelengths_nm": [float(x) for x in table.wavelengths] if table.spectral else None,
        "dtype": str(v.dtype),
        "samples": int(v.size),
        "min": float(v[finite].min()) if finite.any() else None,
        "max": float(v[finite].max()) if finite.any() else None,
        "nonfinite": int((~finite).sum()),
        "negative": int((v < 0).sum()),
        "attributes": attrs,
    }
    if as_json:
        click.echo(json.dumps(data, default=str))
        return
    click.echo(f"{file}  [{fmt.name}]")
    click.echo(f"  grid:        {data['grid']}")
    for a in axes:
        click.echo(f"    {a['name']:<9} {a['size']:>5} nodes  {a['min_deg']:.4g} .. {a['max_deg']:.4g} deg")
    if table.spectral:
        click.echo(f"  wavelengths: {', '.join(f'{x:g}' for x in table.wavelengths)} nm")
    else:
        click.echo(f"  channels:    {', '.join(table.channels)}")
    click.echo(f"  values:      {v.dtype}, {v.size} samples, min {data['min']:.6g}, max {data['max']:.6g} sr-1, "
               f"{data['nonfinite']} non-finite, {data['negative']} negative"
               if data["min"] is not None else f"  values:      {v.size} samples, none finite")
    for key in ("model", "parameters", "parameterization", "sample_position", "phi_d_fold", "theta_h_spacing",
                "relative_to", "spec_sha256", "brdftab_version", "created"):
        if key in attrs:
            click.echo(f"  {key + ':':<18} {attrs[key]}")


# --------------------------------------------------------------------------------------------
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
        click.echo(json.dumps({"name": cls.name, "summary": cls.summary, "reference": cls.reference,
                               "parameters": rows}))
        return
    click.echo(f"{cls.name}: {cls.summary}")
    click.echo(f"reference: {cls.reference}")
    click.echo("parameters (spec key, accepted values, default):")
    for r, p in zip(rows, cls.params):
        default = "required" if r["required"] else ("none" if r["default"] is None else f"default {r['default']!r}")
        units = f" [{r['units']}]" if r["units"] and r["units"] != "1" else ""
        when = f"; {r['used_when']}" if r["used_when"] else ""
        click.echo(f"  {r['spec_key']}{units}: {p.expected()}; {default}{when}")
        click.echo(f"      {r['doc']}")


if __name__ == "__main__":  # pragma: no cover
    main()
