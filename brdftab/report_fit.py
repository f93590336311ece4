"""The fit report: one self-contained HTML page (``brdftab fit … --report FIT.html``).

The fitted parameters with their uncertainties and bounds, the correlation matrix, the
residual per incidence angle, the directional albedo of table and fit, and a figure
(:mod:`brdftab.plot`): the table's in-plane curves against the fit's.
Images are PNGs embedded as ``data:`` URIs (no script, no external resource), as in the
validation report (:mod:`brdftab.report_html`), whose style the page shares.
"""

from __future__ import annotations

from ._version import __version__
from .report_html import _CSS, _e, _number, _png

__all__ = ["render"]


def render(result, table, label: str) -> str:
    """The HTML page of ``result`` (:class:`brdftab.fitting.FitResult`) fitted to ``table``
    (named ``label``)."""
    import datetime as _dt

    stamp = _dt.datetime.now(_dt.timezone.utc).replace(microsecond=0).isoformat()
    name = result.model_table["name"]
    title = f"{name} fitted to {label}"
    parts = ["<!DOCTYPE html>", '<html lang="en">', "<head>", '<meta charset="utf-8">',
             f"<title>{_e(title)}</title>", f"<style>{_CSS}</style>", "</head>", "<body>", f"<h1>{_e(title)}</h1>",
             f"<p>metric <b>{_e(result.metric)}</b>, residual (rms over {result.samples} samples) "
             f"<b>{_number(result.residual)}</b>; {result.starts} starts. brdftab {__version__}, {stamp}.</p>",
             "<h2>Parameters</h2>",
             "<table><tr><th>key</th><th>value</th><th>uncertainty (1σ)</th><th>lower bound</th>"
             "<th>upper bound</th></tr>"]
    for k in result.free:
        lo, hi = result.bounds[k]
        parts.append(f"<tr><td>{_e(k)}</td><td class=\"num\">{_number(result.parameters[k])}</td>"
                     f"<td class=\"num\">{_number(result.uncertainties[k])}</td><td class=\"num\">{_number(lo)}</td>"
                     f"<td class=\"num\">{_number(hi)}</td></tr>")
    parts.append("</table>")
    if len(result.free) > 1:
        parts.append("<h2>Correlations</h2><table><tr><th></th>"
                     + "".join(f"<th>{_e(k)}</th>" for k in result.free) + "</tr>")
        for k, row in zip(result.free, result.correlations):
            parts.append(f"<tr><th>{_e(k)}</th>" + "".join(f'<td class="num">{_number(c)}</td>' for c in row)
                         + "</tr>")
        parts.append("</table>")
    parts.append(f"<h2>Residual per incidence angle</h2><table><tr><th>θi [deg]</th><th>rms ({_e(result.metric)})"
                 "</th><th>samples</th></tr>")
    for lo, hi, rms, n in result.residual_by_theta_i:
        parts.append(f'<tr><td>{lo:g}–{hi:g}</td><td class="num">{_number(rms)}</td><td class="num">{n}</td></tr>')
    parts.append("</table>")
    figures = []
    if result.albedo:
        a = result.albedo
        channels = _channels(result.model, table)
        parts.append("<h2>Directional albedo</h2><table><tr><th>θi [deg]</th>"
                     + "".join(f"<th>table {_e(c)}</th><th>fit {_e(c)}</th>" for c in channels) + "</tr>")
        for t, row_t, row_f in zip(a["theta_i_deg"], a["table"], a["fit"]):
            cells = "".join(f'<td class="num">{_number(x)}</td><td class="num">{_number(y)}</td>'
                            for x, y in zip(row_t, row_f))
            parts.append(f"<tr><td>{t:g}</td>{cells}</tr>")
        parts.append("</table>")
    figures += _figures(result, table, label)
    if figures:
        parts.append('<div class="figures">')
        parts += [f'<figure><img alt="{_e(alt)}" src="data:image/png;base64,{data}"><figcaption>{_e(caption)}'
                  "</figcaption></figure>" for alt, data, caption in figures]
        parts.append("</div>")
    parts += ["</body>", "</html>"]
    return "\n".join(parts) + "\n"


def _channels(model, table) -> list:
    if getattr(table, "spectral", False):
        return [f"{x:g} nm" for x in table.wavelengths]
    return list(table.channels or model.channels or ("f",))


def _figures(result, table, label) -> list:
    from . import plot

    out = []
    fig = plot.compare(table, result.model, theta_i_deg=[0.0, 30.0, 60.0], log=True, label=label,
                       other_label="fit")
    out.append(("in-plane curves of table and fit", _png(fig),
                "In the plane of incidence: the table (lines) and the fit (dots), and fit − table below."))
    return out
