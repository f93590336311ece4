"""``brdftab fit TABLE --model NAME|FILE.toml --free KEY[,KEY…] -o FIT.toml``: fit a model to a table.

The work is done by :mod:`brdftab.fitting` (imported when the verb runs, with scipy). The spec
written is complete or absent (atomic); bad input is one line ``brdftab: error: …``, exit 2.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import click

from .cli_validate import engine_options
from .errors import BrdftabError

__all__ = ["fit"]

#: Static copy of :data:`brdftab.fitting.METRICS` (``--help`` does not import scipy); a test holds them equal.
METRICS = ("log", "cos")
#: Static copy of :data:`brdftab.fitting.MAX_STARTS`; the same test holds them equal.
MAX_STARTS = 10_000


def _pairs(values, option):
    out = {}
    for text in values:
        key, sep, value = text.partition("=")
        key = key.strip()
        if not sep or not key:
            raise BrdftabError(f"{option} expects KEY=VALUE, got {text!r}")
        out[key] = value.strip()
    return out


def _bounds(values):
    out = {}
    for key, text in _pairs(values, "--bounds").items():
        try:
            lo, hi = (float(x) for x in text.split(","))
        except ValueError:
            raise BrdftabError(f"--bounds {key}: expected LO,HI (two numbers), got {text!r}") from None
        if not (math.isfinite(lo) and math.isfinite(hi)):
            raise BrdftabError(f"--bounds {key}: expected finite numbers, got {text!r}")
        out[key] = (lo, hi)
    return out


@click.command("fit")
@click.argument("table", type=click.Path(path_type=Path))
@click.option("--model", "model", required=True, metavar="NAME|FILE.toml",
              help="The starting model: a registered model name, or a TOML file whose [model] table is the start "
                   "(how a sum of terms is given).")
@click.option("--param", "params", multiple=True, metavar="KEY=VALUE",
              help="Set a key of the model (spec key and units; a TOML value: 0.3, [0.1, 0.2, 0.3], \"ggx\"); "
                   "repeatable.")
@click.option("--free", "free", multiple=True, required=True, metavar="KEY[,KEY...]",
              help="The keys to fit, as spec keys (terms of a sum by position from 0: terms.1.alpha).")
@click.option("--bounds", "bounds", multiple=True, metavar="KEY=LO,HI",
              help="Bounds of a free key instead of its declared range; repeatable.")
@click.option("--metric", type=click.Choice(METRICS), default="log", show_default=True,
              help="log: log of f (every order of magnitude alike); cos: |f - t| cos(theta_i) cos(theta_o).")
@click.option("--starts", type=click.IntRange(min=1, max=MAX_STARTS), default=16, show_default=True,
              help="Starts of the search: the start value and points spread over the bounds.")
@click.option("--max-theta-deg", type=click.FloatRange(min=0, max=90, min_open=True), default=80.0,
              show_default=True, help="Leave out samples with theta_i or theta_o beyond this (near grazing).")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the spread starts and subsamples.")
@click.option("-o", "--out", "out", type=click.Path(path_type=Path), metavar="FIT.toml",
              help="Write a spec whose [model] is the fitted model and [grid] the table's grid.")
@click.option("--report", "report", type=click.Path(path_type=Path), metavar="FIT.html",
              help="Write an HTML page: parameters, uncertainties, correlations, residual per incidence angle, "
                   "albedo of table and fit, in-plane curves of both.")
@click.option("--overwrite", is_flag=True, help="Replace FIT.toml (and FIT.html) if it exists.")
@click.option("--json", "as_json", is_flag=True, help="Print the result as one JSON object.")
@engine_options
def fit(table, model, params, free, bounds, metric, starts, max_theta_deg, seed, out, report, overwrite, as_json,
        workers, scheduler):
    """Fit the --free parameters of a model to TABLE (at its own nodes) by least squares.

    Prints the fitted parameters with their uncertainties (one standard deviation, from the
    Jacobian), the residual (rms of the metric over the samples) and the residual per
    incidence angle; -o writes a spec that tabulates the fitted model on the table's grid.
    """
    from . import fitting
    from . import open as open_table
    from ._atomic import atomic_path
    from ._locks import check_target
    from .fitting import _parse_value

    keys = [k.strip() for text in free for k in text.split(",") if k.strip()]
    given = {k: _parse_value(v) for k, v in _pairs(params, "--param").items()}
    if out is not None and out.suffix.lower() != ".toml":
        raise BrdftabError(f"{out}: the fitted spec is a TOML file: name it *.toml")
    inputs = [(table, "the table")] + ([(Path(model), "the model file")] if model.endswith(".toml") else [])
    if report is not None and report.suffix.lower() not in (".html", ".htm"):
        raise BrdftabError(f"{report}: the report is an HTML page: name it *.html")
    if out is not None and report is not None and out.resolve() == report.resolve():
        raise BrdftabError(f"{out}: -o and --report name the same file")
    for target in (out, report):
        if target is not None:
            check_target(target, overwrite, inputs)  # before the search, not after it
    source = open_table(table)
    if out is not None and hasattr(source.grid, "directions_into"):
        fitting.grid_table(source.grid)  # a grid no [grid] table reproduces: say so before the search
    from .batch import Engine

    with Engine(workers, scheduler) as engine:  # --workers / --scheduler: the starts run in parallel there
        result = fitting.fit(source, model, keys, params=given, metric=metric, bounds=_bounds(bounds),
                             starts=starts, max_theta_deg=max_theta_deg, seed=seed,
                             engine=engine if engine.distributed else None)
    if out is not None:
        text = result.spec_text(f"{out.stem}.nc", description=f"{result.model_table['name']} fitted to "
                                f"{table.name} (brdftab fit, metric {metric}, residual {result.residual:.4g})")
        with atomic_path(out, overwrite=overwrite, inputs=inputs) as tmp:
            Path(tmp).write_text(text, encoding="utf-8")
    if report is not None:
        from .report_fit import render

        page = render(result, source, table.name)
        with atomic_path(report, overwrite=overwrite, inputs=inputs) as tmp:
            Path(tmp).write_text(page, encoding="utf-8")
    if as_json:
        doc = {"table": str(table), **result.to_json()}
        if out is not None:
            doc["spec"] = str(out)
        if report is not None:
            doc["report"] = str(report)
        click.echo(json.dumps(doc))
        return
    click.echo(f"fitted {', '.join(result.free)} of {result.model_table['name']} to {table} "
               f"({result.samples} samples, {result.starts} starts, metric {metric})")
    for k in result.free:
        click.echo(f"  {k} = {result.parameters[k]:.6g} ± {result.uncertainties[k]:.2g}")
    click.echo(f"residual (rms of the {metric} metric): {result.residual:.4g}")
    for lo, hi, rms, n in result.residual_by_theta_i:
        click.echo(f"  theta_i {lo:g}-{hi:g} deg: {rms:.4g} ({n} samples)")
    for target in (out, report):
        if target is not None:
            click.echo(f"wrote {target}")
