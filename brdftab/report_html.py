"""The visual validation report: one self-contained HTML page (``brdftab validate … --html``).

Per input: the verdict, every check with its figure, threshold, level and detail (the same
outcomes as the text, JSON and JUnit reports), the directional-albedo curve the albedo check
computed, in-plane curves and an equal-area hemisphere map of the BRDF (:mod:`brdftab.plot`),
and for a failed reciprocity or energy check a map of where it fails; for a polarized BRDF
its Mueller matrix in the plane of incidence (``plot --kind mueller``). Images are PNGs embedded
as ``data:`` URIs and the page has no script and no external resource, so it opens offline
and as a CI artifact; tests/test_report_html.py renders it in headless Chromium and checks that
every image decodes and the console stays silent.
"""

from __future__ import annotations

import base64
import html
import math
from dataclasses import dataclass

import numpy as np

from ._version import __version__
from .errors import BrdftabError

__all__ = ["Entry", "render"]

#: Incidence angles [deg] of the in-plane curves and of the hemisphere map.
THETA_I_DEG = (0.0, 30.0, 60.0)
MAP_THETA_I_DEG = 30.0

_CSS = """
body { font-family: system-ui, sans-serif; margin: 1.5em; color: #222; }
h1 { font-size: 1.4em; } h2 { font-size: 1.15em; margin-top: 2em; border-bottom: 1px solid #ccc; }
table { border-collapse: collapse; margin: 0.6em 0; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.5em; text-align: left; vertical-align: top; }
th { background: #f2f2f2; }
td.num { text-align: right; font-variant-numeric: tabular-nums; white-space: nowrap; }
.s-pass { color: #1a7f37; font-weight: 600; } .s-warn { color: #9a6700; font-weight: 600; }
.s-fail { color: #cf222e; font-weight: 700; } .s-skip { color: #6e7781; font-weight: 600; }
tr.row-fail td { background: #fff0f0; } tr.row-warn td { background: #fffbe6; }
.verdict { font-size: 1.05em; } figure { display: inline-block; margin: 0.5em 1em 0.5em 0; }
figcaption { font-size: 0.85em; color: #555; max-width: 560px; }
img { max-width: 100%; height: auto; border: 1px solid #eee; }
.note { color: #555; font-size: 0.9em; }
"""


@dataclass
class Entry:
    """One input of the report: its check ``report`` and the BRDF to draw (None: none)."""

    report: object
    brdf: object = None
    what: str = ""  # what the drawings show, e.g. "the spec's model"


def render(entries, errors=(), title: str = "brdftab validation report") -> str:
    """The HTML page of ``entries`` (:class:`Entry`) and unreadable inputs ``errors``
    (``(subject, exception)`` pairs)."""
    import datetime as _dt

    passed = sum(e.report.passed for e in entries)
    stamp = _dt.datetime.now(_dt.timezone.utc).replace(microsecond=0).isoformat()
    parts = ["<!DOCTYPE html>", '<html lang="en">', "<head>", '<meta charset="utf-8">',
             f"<title>{_e(title)}</title>", f"<style>{_CSS}</style>", "</head>", "<body>",
             f"<h1>{_e(title)}</h1>",
             f'<p class="verdict">{len(entries)} checked: {passed} passed, {len(entries) - passed} failed; '
             f"{len(errors)} could not be read. brdftab {__version__}, {stamp}.</p>"]
    if errors:
        parts.append("<h2>Inputs that could not be read</h2><table><tr><th>input</th><th>error</th></tr>")
        parts += [f"<tr class=\"row-fail\"><td>{_e(s)}</td><td>{_e(' '.join(str(x).split()))}</td></tr>"
                  for s, x in errors]
        parts.append("</table>")
    for i, entry in enumerate(entries):
        parts.append(_section(entry, i))
    parts += ["</body>", "</html>"]
    return "\n".join(parts) + "\n"


def _e(text) -> str:
    return html.escape(str(text), quote=True)


def _number(x) -> str:
    if x is None:
        return ""
    try:
        v = float(x)
    except (TypeError, ValueError):
        return _e(x)
    if not math.isfinite(v):
        return _e(str(v))
    return f"{v:.4g}"


def _section(entry: Entry, index: int) -> str:
    r = entry.report
    status = "pass" if r.passed else "fail"
    counts = r.counts()
    out = [f'<h2 id="input-{index}">{_e(r.subject or "BRDF")} — <span class="s-{status}">'
           f'{"PASSED" if r.passed else "FAILED"}</span></h2>',
           f"<p>{counts['pass']} pass, {counts['warn']} warn, {counts['fail']} fail, {counts['skip']} skip.</p>",
           "<table><tr><th>check</th><th>family</th><th>level</th><th>status</th><th>figure</th><th>threshold</th>"
           "<th>detail</th></tr>"]
    for o in r.outcomes:
        out.append(f'<tr class="row-{_e(o.status)}" id="check-{index}-{_e(o.name)}"><td>{_e(o.name)}</td>'
                   f"<td>{_e(o.family)}</td><td>{_e(o.level)}</td>"
                   f'<td class="s-{_e(o.status)}">{_e(o.status.upper())}</td><td class="num">{_number(o.figure)}</td>'
                   f'<td class="num">{_number(o.threshold)}</td><td>{_e(o.detail)}</td></tr>')
    out.append("</table>")
    figures = _figures(entry)
    if figures:
        out.append('<div class="figures">')
        out += [f'<figure><img alt="{_e(alt)}" src="data:image/png;base64,{data}"><figcaption>{_e(caption)}'
                "</figcaption></figure>" for alt, data, caption in figures]
        out.append("</div>")
    return "\n".join(out)


def _png(fig) -> str:
    from .plot import to_png_bytes

    try:
        return base64.b64encode(to_png_bytes(fig)).decode("ascii")
    finally:
        fig.clear()


def _figures(entry: Entry) -> list:
    """(alt text, base64 PNG, caption) of the entry's drawings: failure maps first."""
    from . import plot

    r, brdf = entry.report, entry.brdf
    what = f" ({entry.what})" if entry.what else ""
    out = []
    recip, energy, alb = r.get("reciprocity"), r.get("energy"), r.get("albedo")
    if brdf is not None and recip is not None and recip.status == "fail":
        fig, caption = _reciprocity_map(brdf, recip)
        out.append(("reciprocity failure map", _png(fig), caption + what))
    if brdf is not None and energy is not None and energy.status == "fail":
        ti = float(energy.data.get("theta_i_deg", MAP_THETA_I_DEG))
        pi_ = float(energy.data.get("phi_i_deg", 0.0))
        fig = plot.figure("hemisphere", brdf, theta_i_deg=[ti], phi_i_deg=pi_, quantity="brdf-cos")
        out.append(("energy failure map", _png(fig),
                    f"energy FAIL: where the reflected energy goes at the worst incidence, θi = {ti:g}°, φi = "
                    f"{pi_:g}° (f·cosθo over the exit hemisphere; the albedo there is {_number(energy.figure)}, "
                    f"threshold {_number(energy.threshold)}){what}"))
    if alb is not None and alb.data.get("values") is not None:
        limit = None if energy is None or energy.threshold is None else float(energy.threshold)
        fig = plot.albedo_values(alb.data["theta_i_deg"], alb.data["values"], alb.data.get("channels"),
                                 limit=limit, title=f"directional albedo a(θi) as the albedo check computed it{what}")
        out.append(("albedo curve", _png(fig), "directional albedo a(θi) = ∫ f cosθo dωo per channel"
                    + ("" if limit is None else f"; dashed: the energy check's limit {limit:g}")))
    if brdf is not None:
        for alt, kind, opts, caption in (
                ("in-plane curves", "in-plane", {"theta_i_deg": list(THETA_I_DEG)},
                 "f_r in the plane of incidence for θi = " + ", ".join(f"{t:g}°" for t in THETA_I_DEG)),
                ("hemisphere map", "hemisphere", {"theta_i_deg": [MAP_THETA_I_DEG]},
                 f"f_r over the exit hemisphere at θi = {MAP_THETA_I_DEG:g}° (equal-area projection)")):
            try:
                fig = plot.figure(kind, brdf, **opts)
            except BrdftabError as exc:  # e.g. a spectral BRDF without wavelengths: say so, draw the rest
                out.append((alt, _placeholder(), f"{alt}: not drawn ({exc})"))
                continue
            out.append((alt, _png(fig), caption + what))
        from .mueller_table import is_polarized

        if is_polarized(brdf):
            try:
                fig = plot.figure("mueller", brdf, theta_i_deg=[MAP_THETA_I_DEG])
            except BrdftabError as exc:
                out.append(("Mueller matrix", _placeholder(), f"Mueller matrix: not drawn ({exc})"))
            else:
                out.append(("Mueller matrix", _png(fig), "the Mueller matrix in the plane of incidence at θi = "
                            f"{MAP_THETA_I_DEG:g}°: M00 and M_ij / M00 (x ⊥ plane, +S3 right circular){what}"))
    return out


def _placeholder() -> str:
    """A 1 × 1 white PNG (a figure that could not be drawn still decodes)."""
    import struct
    import zlib

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    png = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 1, 1, 8, 2, 0, 0, 0))
           + chunk(b"IDAT", zlib.compress(b"\x00\xff\xff\xff")) + chunk(b"IEND", b""))
    return base64.b64encode(png).decode("ascii")


def _reciprocity_map(brdf, outcome, n: int = 41):
    """The relative asymmetry |f(wi, wo) − f(wo, wi)| / ½(f(wi, wo) + f(wo, wi)) (the largest
    over channels) over the exit hemisphere at the incidence where the check found the worst
    pair (or θi = 45°), in the equal-area projection."""
    from . import plot
    from .geometry import sph_to_vec

    where = outcome.data.get("where") or {}
    ti = float(where.get("theta_i_deg", 45.0)) if isinstance(where, dict) else 45.0
    pi_ = float(where.get("phi_i_deg", 0.0)) if isinstance(where, dict) else 0.0
    _, _, theta, phi = plot.hemisphere_grid(n)
    inside = np.isfinite(theta) & (np.nan_to_num(theta) < math.radians(89.0))
    wo = sph_to_vec(theta[inside], phi[inside])
    wi = np.broadcast_to(sph_to_vec(math.radians(ti), math.radians(pi_)), wo.shape).copy()
    lam = getattr(brdf, "wavelengths", None) if getattr(brdf, "spectral", False) else None
    a = np.asarray(brdf.eval(wi, wo, lam), float)
    b = np.asarray(brdf.eval(wo, wi, lam), float)
    with np.errstate(invalid="ignore", divide="ignore"):
        rel = np.where((a + b) > 0, np.abs(a - b) / (0.5 * (a + b)), 0.0)
    rel = np.nan_to_num(rel).max(axis=-1)
    fig = plot.hemisphere_values(wo, rel, title=f"reciprocity: relative asymmetry at θi = {ti:g}°, φi = {pi_:g}°",
                                 label="|f(wi,wo) − f(wo,wi)| / mean", incident=wi[0], cmap="magma")
    caption = (f"reciprocity FAIL ({outcome.detail}): where f(wi, wo) and f(wo, wi) differ, over the exit "
               f"hemisphere at θi = {ti:g}° (largest here {float(rel.max()):.3g})")
    return fig, caption
