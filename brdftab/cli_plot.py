"""``brdftab plot FILE|SPEC -o OUT.png|svg|pdf``: a figure of a table or of a spec's model.

The figure is built by :mod:`brdftab.plot` (imported when the verb runs, with matplotlib) and
written atomically: OUT is complete or absent. Bad input (an unknown extension, an unreadable
source, an option the kind does not take) is one line ``brdftab: error: …`` and exit code 2.
"""

from __future__ import annotations

import math
from pathlib import Path

import click

from .errors import BrdftabError

__all__ = ["plot", "KINDS", "QUANTITIES"]

#: Static copies of :data:`brdftab.plot.KINDS` and ``QUANTITIES`` (so that ``--help`` does not
#: import matplotlib); a test holds them equal.
KINDS = ("in-plane", "polar", "slice", "hemisphere", "albedo", "compare", "mueller")
QUANTITIES = ("brdf", "brdf-cos", "brf", "relative")


def _angles(text, option):
    if text is None:
        return None
    try:
        values = [float(x) for x in text.replace(" ", "").split(",") if x != ""]
    except ValueError:
        raise BrdftabError(f"{option} expects angles in degrees separated by commas, got {text!r}") from None
    if not values:
        raise BrdftabError(f"{option} expects at least one angle in degrees, got {text!r}")
    return values


def _azimuth(value, option):
    """An azimuth in degrees, reduced exactly (:func:`brdftab.geometry.reduce_azimuth_deg`);
    not finite: one line."""
    if value is None:
        return None
    if not math.isfinite(value):
        raise BrdftabError(f"{option} expects a finite angle in degrees, got {value!r}")
    from .geometry import reduce_azimuth_deg

    return reduce_azimuth_deg(value)


def _title(text):
    """``--title`` as matplotlib will draw it: math text (between $ signs) that matplotlib
    cannot typeset is one line now, not an error while the figure is saved."""
    if not text:
        return text
    from matplotlib.mathtext import MathTextParser
    from matplotlib.text import Text

    try:
        body, is_math = Text()._preprocess_math(text)
    except AttributeError:  # (matplotlib's internals moved: it judges the title when drawing)
        return text
    if is_math is True:
        try:
            MathTextParser("path").parse(body)
        except ValueError as exc:
            why = str(exc).strip().splitlines()[-1] if str(exc).strip() else type(exc).__name__
            raise BrdftabError(f"--title: matplotlib cannot typeset '{text}' as math text ({why}); write \\$ "
                               "for a dollar sign") from None
    return text


def read_points(path: Path) -> list:
    """Rows ``theta_i_deg, theta_o_deg, value`` of a CSV file (a header line and ``#``
    comments allowed); a malformed line is one error naming the file and the line."""
    rows, header_allowed = [], True
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise BrdftabError(f"{path}: cannot read the points file ({getattr(exc, 'strerror', None) or exc})") from None
    for number, line in enumerate(text.splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        first, header_allowed = header_allowed, False
        try:
            row = [float(f) for f in line.split(",")]
        except ValueError:
            if first:
                continue  # a header line
            raise BrdftabError(f"{path}, line {number}: expected three numbers theta_i_deg, theta_o_deg, value, "
                               f"got {line!r}") from None
        if len(row) != 3 or not all(map(math.isfinite, row)):
            raise BrdftabError(f"{path}, line {number}: expected three finite numbers theta_i_deg, theta_o_deg, "
                               f"value, got {line!r}")
        rows.append(row)
    if not rows:
        raise BrdftabError(f"{path}: no points (expected lines theta_i_deg, theta_o_deg, value)")
    return rows


def _source(path: Path):
    from .cli import _load_source

    brdf, spec_lam = _load_source(path)
    if hasattr(brdf, "outside"):
        brdf.outside = "nan"  # outside a table's domain the figure has a gap, not an error
    return brdf, spec_lam


@click.command("plot")
@click.argument("source", metavar="FILE|SPEC", type=click.Path(path_type=Path))
@click.option("-o", "--out", "out", required=True, type=click.Path(path_type=Path), metavar="OUT",
              help="The figure to write: .png, .svg or .pdf (format by extension).")
@click.option("--kind", type=click.Choice(KINDS), default="in-plane", show_default=True,
              help="in-plane curves for several θi; polar: the same in polar axes; slice: the θh × θd image at "
                   "one φd; hemisphere: one incidence over the exit hemisphere (equal-area map); albedo: the "
                   "directional albedo a(θi); compare: FILE|SPEC and --against side by side, with their "
                   "difference; mueller: a polarized BRDF's Mueller matrix in the plane of incidence (M00 and "
                   "Mij / M00 against θo).")
@click.option("--theta-i-deg", "theta_i", metavar="DEG[,DEG...]",
              help="Incidence angles in degrees (default 0,30,60; hemisphere: one, default 30; albedo: 0 to 87 "
                   "in 3° steps; a gonio table: its own).")
@click.option("--phi-i-deg", "phi_i", type=float, default=None,
              help="Azimuth of the plane of incidence in degrees (anisotropic BRDFs; default 0).")
@click.option("--phi-d-deg", "phi_d", type=float, default=None, help="slice: the φd of the image (default 90).")
@click.option("--quantity", type=click.Choice(QUANTITIES), default=None,
              help="What the axis shows: brdf (f_r in 1/sr, the default), brdf-cos (f_r cosθo in 1/sr), brf "
                   "(the reflectance factor π f_r, dimensionless) or relative (f_r over its value at the mirror "
                   "direction).")
@click.option("--log/--linear", "log", default=None,
              help="Logarithmic or linear value axis (default: log when the values span over a factor 100).")
@click.option("--against", type=click.Path(path_type=Path), metavar="FILE|SPEC",
              help="compare: the second BRDF (a table file or a spec).")
@click.option("--ratio", is_flag=True, help="compare: show the ratio B / A instead of the difference B − A.")
@click.option("--wavelength-nm", "wavelengths", multiple=True, type=float,
              help="Wavelength in nm to plot (repeatable; default: up to 5 of a spectral BRDF's own).")
@click.option("--rgb", is_flag=True, help="Plot a spectral BRDF as linear sRGB channels (D65, CIE 1931 2°).")
@click.option("--channel", help="Plot only this channel (R, mono, ...; for spectral BRDFs '550 nm').")
@click.option("--points", type=click.Path(dir_okay=False, path_type=Path), metavar="CSV",
              help="in-plane: mark these values (CSV lines theta_i_deg, theta_o_deg, value), e.g. a paper's "
                   "printed ones.")
@click.option("--title", help="The figure's title (default: the model and its parameters, or the table's file).")
@click.option("--dpi", type=click.IntRange(20, 600), default=100, show_default=True,
              help="Resolution of a PNG.")
@click.option("--overwrite", is_flag=True, help="Replace OUT if it exists.")
def plot(source, out, kind, theta_i, phi_i, phi_d, quantity, log, against, ratio, wavelengths, rgb, channel, points,
         title, dpi, overwrite):
    """Plot the BRDF of FILE (a table) or SPEC (a spec's model, not tabulated) into OUT.

    `brdftab plot table.nc -o p.png` draws in-plane curves of f_r for θi = 0, 30, 60°.
    """
    from . import plot as plots

    fmt = plots.output_format(out)  # an unknown extension: one line before anything is read
    given = {"--against": against, "--ratio": ratio or None, "--phi-d-deg": phi_d, "--points": points,
             "--quantity": quantity, "--log/--linear": log, "--phi-i-deg": phi_i, "--theta-i-deg": theta_i}
    allowed = {"in-plane": {"--points", "--quantity", "--log/--linear", "--phi-i-deg", "--theta-i-deg"},
               "polar": {"--quantity", "--log/--linear", "--phi-i-deg", "--theta-i-deg"},
               "slice": {"--phi-d-deg", "--quantity", "--log/--linear"},
               "hemisphere": {"--quantity", "--log/--linear", "--phi-i-deg", "--theta-i-deg"},
               "albedo": {"--phi-i-deg", "--theta-i-deg"},
               "compare": {"--against", "--ratio", "--quantity", "--log/--linear", "--phi-i-deg", "--theta-i-deg"},
               "mueller": {"--log/--linear", "--phi-i-deg", "--theta-i-deg"}}
    for option, value in given.items():
        if value is not None and option not in allowed[kind]:
            raise click.UsageError(f"{option} does not apply to --kind {kind}")
    if kind == "compare" and against is None:
        raise click.UsageError("--kind compare needs --against FILE|SPEC")
    options = {"wavelengths": list(wavelengths) or None, "rgb": rgb, "channel": channel, "title": _title(title)}
    phi_i, phi_d = _azimuth(phi_i, "--phi-i-deg"), _azimuth(phi_d, "--phi-d-deg")
    if theta_i is not None:
        options["theta_i_deg"] = _angles(theta_i, "--theta-i-deg")
    if phi_i is not None:
        options["phi_i_deg"] = phi_i
    if phi_d is not None:
        options["phi_d_deg"] = phi_d
    if quantity is not None:
        options["quantity"] = quantity
    if log is not None:
        options["log"] = log
    if ratio:
        options["ratio"] = True
    if points is not None:
        options["points"] = read_points(points)
    brdf, spec_lam = _source(source)
    if options["wavelengths"] is None and spec_lam is not None:
        # the wavelengths the spec tabulates: a few of them (sRGB: all of them)
        lam = spec_lam if rgb else plots.pick_evenly(spec_lam, plots.MAX_WAVELENGTHS)
        options["wavelengths"] = [float(x) for x in lam]
    options["label"] = source.name
    if kind == "compare":
        options["other"], _ = _source(against)
        options["other_label"] = against.name
    fig = plots.figure(kind, brdf, **options)
    inputs = [(source, "the plotted file")] + ([(against, "the file compared")] if against is not None else []) + (
        [(points, "the points file")] if points is not None else [])
    plots.save(fig, out, overwrite=overwrite, dpi=dpi, inputs=inputs)
    click.echo(f"wrote {out} ({kind}, {fmt})")
