"""Plots of a BRDF: the figures a BRDF is judged by, as matplotlib figures.

Every function takes a BRDF (a model from :func:`brdftab.models.create`, a table from
:func:`brdftab.open`, anything with ``eval(wi, wo, wavelengths)``) and returns a
:class:`matplotlib.figure.Figure` built without pyplot (no global state, no display: the
figure draws with the Agg canvas); :func:`save` writes it atomically, :func:`to_png_bytes`
returns PNG bytes. The kinds (:data:`KINDS`, :func:`figure` dispatches by name):

* ``in-plane`` (:func:`in_plane`) — curves of the quantity against θo in the plane of
  incidence, −89.9° … 89.9° in 0.1° steps (θo > 0 on the specular side, φo = φi + π; θo < 0 on
  the side of the source, φo = φi), one curve per θi and channel; on a log scale when asked
  (``log=True``) or, by default, when the positive values span more than a factor 100;
* ``polar`` (:func:`polar`) — the same curves in polar axes (θo as the angle from the normal);
* ``slice`` (:func:`slice_image`) — the θh × θd image at one φd (and φh), one panel per
  channel: on a Rusinkiewicz table's own θh, θd nodes, else on 1° cells;
* ``hemisphere`` (:func:`hemisphere`) — the quantity over the exit hemisphere for one
  incidence, in the Lambert azimuthal equal-area projection (:func:`equal_area`; equal areas on
  the map are equal solid angles), with a colour bar; :func:`hemisphere_values` maps given
  values at given directions in the same projection (where a check fails, for instance);
* ``albedo`` (:func:`albedo`) — the directional albedo a(θi) = ∫ f cosθo dωo, integrated by
  :func:`brdftab.integrate.albedo_curve`, with the white-sky albedo in the legend;
  :func:`albedo_values` draws a curve already computed (an albedo check's);
* ``compare`` (:func:`compare`) — two BRDFs' in-plane curves and, below, their difference
  (or ratio);
* ``mueller`` (:func:`mueller`) — a polarized BRDF's Mueller matrix in the plane of incidence,
  4 × 4 panels against θo: M00 in sr⁻¹ (panel 0, 0) and the normalized elements M_ij / M00
  (in [−1, 1]) in brdftab's ``mitsuba`` basis (both beams' x perpendicular to the plane).

The quantity on the axis (:data:`QUANTITIES`) is named with its unit: ``brdf`` is f_r in sr⁻¹,
``brdf-cos`` is f_r·cosθo in sr⁻¹, ``brf`` the reflectance factor π·f_r (dimensionless; what
remote sensing reads), and ``relative`` f_r over its value at the mirror direction of the mean
surface (dimensionless; the ratio Torrance and Sparrow plot, their Eq. 23).

Channels keep their colours: R, G, B red, green and blue, ``mono`` black, other names a cycle.
A spectral BRDF is plotted at a few of its wavelengths (at most :data:`MAX_WAVELENGTHS`, evenly
picked, or those asked for), each curve in the hue of its wavelength (the ``turbo`` colour
map across 380–780 nm: a hint, not colorimetry), or, with ``rgb=True``, as linear sRGB
channels through :func:`brdftab.colorimetry.spectral_to_rgb`.

The figures hold exactly what they show: each curve is a ``Line2D`` whose x and y data are the
plotted arrays (θo in degrees; in polar axes θo in radians), each image's array is the plotted
values (NaN where no value exists: below the horizon, outside the projection), and each
artist's ``gid`` says what it is (``"theta_i=30|channel=R"``; :func:`artists` finds them).
The title names the model and its parameters (angles in degrees), or a table's stored model
and its file.
"""

from __future__ import annotations

import io
import json
import math
import textwrap
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import LogNorm, Normalize
from matplotlib.figure import Figure

from .errors import BrdftabError
from .geometry import hd_to_io, sph_to_vec

__all__ = ["KINDS", "QUANTITIES", "FORMATS", "MAX_WAVELENGTHS", "figure", "in_plane", "polar", "slice_image",
           "hemisphere", "hemisphere_values", "hemisphere_grid", "albedo", "albedo_values", "compare", "equal_area",
           "equal_area_inverse", "artists", "save", "to_png_bytes", "output_format", "parameters_text",
           "theta_o_in_plane", "in_plane_directions", "pick_evenly", "mueller"]

KINDS = ("in-plane", "polar", "slice", "hemisphere", "albedo", "compare", "mueller")
#: Output formats by extension.
FORMATS = {".png": "png", ".svg": "svg", ".pdf": "pdf"}
#: Wavelengths of a spectral BRDF plotted by default (evenly picked from its own).
MAX_WAVELENGTHS = 5
#: The last in-plane θo before the horizon [deg] (on the horizon every BRDF is 0 by convention).
THETA_O_MAX_DEG = 89.9
#: Default incidence angles [deg] of in-plane curves.
THETA_I_DEG = (0.0, 30.0, 60.0)
#: Log scale by default when the positive values span more than this factor.
AUTO_LOG_RANGE = 100.0
#: The lowest value a log axis shows, relative to the largest.
LOG_FLOOR = 1e-5


@dataclass(frozen=True)
class Quantity:
    name: str
    symbol: str
    unit: str  # "" for dimensionless

    @property
    def axis_label(self) -> str:
        return f"{self.symbol} [{self.unit}]" if self.unit else f"{self.symbol} [dimensionless]"


QUANTITIES = {
    "brdf": Quantity("brdf", "f_r", "sr⁻¹"),
    "brdf-cos": Quantity("brdf-cos", "f_r · cos θo", "sr⁻¹"),
    "brf": Quantity("brf", "BRF = π f_r", ""),
    "relative": Quantity("relative", "f_r / f_r(mirror direction)", ""),
}

_CHANNEL_COLOURS = {"R": "red", "G": "green", "B": "blue", "mono": "black"}
_CYCLE = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown", "tab:pink", "tab:olive",
          "tab:cyan", "tab:gray")
_STYLES = ("-", "--", "-.", ":", (0, (5, 1, 1, 1, 1, 1)), (0, (1, 3)), (0, (8, 3)))


# --------------------------------------------------------------------------------------------
# what is plotted: channels or wavelengths, and the quantity


@dataclass
class _Series:
    """The curves of one BRDF: names, colours, the wavelengths to evaluate at (or None), and
    whether the spectra go through sRGB."""

    names: list
    colours: list
    lam: np.ndarray | None
    rgb: bool = False
    keep: list | None = None  # the indices shown (None: all)

    def values(self, brdf, wi, wo) -> np.ndarray:
        f = np.asarray(brdf.eval(wi, wo, self.lam), float)
        if self.rgb:
            from .colorimetry import spectral_to_rgb

            f = np.asarray(spectral_to_rgb(f, self.lam), float)
        return f


def _wavelength_colour(lam: float):
    from matplotlib import colormaps

    return colormaps["turbo"](float(np.clip((lam - 380.0) / 400.0, 0.0, 1.0)))


def _colours(names) -> list:
    """Colours of channels by name: R, G, B, mono their own, ``"550 nm"`` its wavelength's hue,
    other names a cycle."""
    out, k = [], 0
    for n in names:
        n = str(n)
        if n in _CHANNEL_COLOURS:
            out.append(_CHANNEL_COLOURS[n])
            continue
        try:
            out.append(_wavelength_colour(float(n.removesuffix("nm").strip())))
            continue
        except ValueError:
            pass
        out.append(_CYCLE[k % len(_CYCLE)])
        k += 1
    return out


def pick_evenly(lam, n: int) -> np.ndarray:
    """At most ``n`` of the values ``lam``, evenly spaced by index, the first and last among them."""
    lam = np.asarray(lam, float)
    if lam.size <= n:
        return lam
    return lam[np.unique(np.round(np.linspace(0, lam.size - 1, n)).astype(int))]


def _series(brdf, wavelengths=None, rgb: bool = False, channel=None) -> _Series:
    own = getattr(brdf, "wavelengths", None)
    spectral = bool(getattr(brdf, "spectral", False))
    if rgb:
        lam = np.asarray(wavelengths if wavelengths else own if own is not None else [], float)
        if lam.size < 2:
            raise BrdftabError("sRGB needs a spectrum: a spectral BRDF or at least two wavelengths (--wavelength-nm)")
        s = _Series(["R", "G", "B"], ["red", "green", "blue"], lam, rgb=True)
    elif wavelengths or spectral:
        if wavelengths:
            lam = np.asarray(wavelengths, float)
        elif own is not None:
            lam = pick_evenly(own, MAX_WAVELENGTHS)
        else:
            raise BrdftabError(f"{brdf.name} is spectral: give the wavelengths to plot (--wavelength-nm)")
        s = _Series([f"{x:g} nm" for x in lam], [_wavelength_colour(x) for x in lam], lam)
    else:
        names = list(brdf.channels)
        colours = _colours(names)
        s = _Series(names, colours, None)
    if channel is not None:
        if channel not in s.names:
            raise BrdftabError(f"channel {channel!r} is not among {', '.join(s.names)}")
        s.keep = [s.names.index(channel)]
    return s


def _kept(s: _Series) -> list:
    return list(range(len(s.names))) if s.keep is None else s.keep


def _quantity(name: str) -> Quantity:
    try:
        return QUANTITIES[name]
    except KeyError:
        raise BrdftabError(f"unknown quantity {name!r}; one of {', '.join(QUANTITIES)}") from None


def _apply(quantity: str, f, brdf, series: _Series, wi, wo) -> np.ndarray:
    """The quantity from f [..., C] at the pairs (wi, wo)."""
    if quantity == "brdf":
        return f
    if quantity == "brdf-cos":
        return f * np.clip(np.asarray(wo, float)[..., 2], 0.0, None)[..., None]
    if quantity == "brf":
        return np.pi * f
    if quantity == "relative":
        mirror = np.broadcast_to(np.asarray(wi, float), np.shape(wo)) * np.array([-1.0, -1.0, 1.0])
        with np.errstate(divide="ignore", invalid="ignore"):
            return f / series.values(brdf, np.ascontiguousarray(np.broadcast_to(wi, np.shape(wo))), mirror)
    raise BrdftabError(f"unknown quantity {quantity!r}; one of {', '.join(QUANTITIES)}")


# --------------------------------------------------------------------------------------------
# titles


def _short(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, dict):
        if "model" in v:
            return f"{v['model']}(…)"
        if "wavelengths_nm" in v:
            return "spectrum"
        return "{…}"
    if isinstance(v, (list, tuple)):
        if v and all(isinstance(x, dict) and "model" in x for x in v):
            return "+".join(str(x["model"]) for x in v)
        return "[" + ", ".join(_short(x) for x in v) + "]"
    return str(v)


def parameters_text(name, parameters) -> str:
    """``key=value`` of a model's parameters on one line, angles in degrees under their
    ``_deg`` key."""
    from . import models

    if isinstance(parameters, str):
        try:
            parameters = json.loads(parameters)
        except json.JSONDecodeError:
            return parameters
    if not isinstance(parameters, dict):
        return ""
    cls = models.MODELS.get(name, None) if isinstance(name, str) else None
    declared = {p.name: p for p in getattr(cls, "params", ())}
    parts = []
    for key, value in parameters.items():
        p = declared.get(key)
        if p is not None and p.angle and isinstance(value, (int, float)) and not isinstance(value, bool):
            parts.append(f"{p.spec_key}={math.degrees(value):.4g}")
        elif isinstance(value, dict) and "model" in value:
            parts.append(f"{key}={value['model']}({parameters_text(value['model'], value.get('parameters', {}))})")
        else:
            parts.append(f"{key}={_short(value)}")
    return ", ".join(parts)


def _title(brdf, label=None, extra: str = "", width: int = 95) -> str:
    from .table import Table

    params = parameters_text(brdf.name, brdf.parameters)
    if isinstance(brdf, Table):
        source = label or Path(str(brdf.ds.encoding.get("source", ""))).name or "table"
        text = f"{source}: table of {brdf.name}" + (f" ({params})" if params else "")
    else:
        text = f"{brdf.name}({params})" + (f" [{label}]" if label else "")
    if extra:
        text = f"{text} — {extra}"
    return "\n".join(textwrap.wrap(text, width, break_on_hyphens=False)[:4])


def _new_figure(size=(7.0, 4.6)) -> Figure:
    fig = Figure(figsize=size, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _chars(fig) -> int:
    """Characters of a 9-point title line across the figure."""
    return max(40, int(13 * fig.get_figwidth()))


def _log_wanted(log, values) -> bool:
    if log is not None:
        return bool(log)
    v = np.asarray(values, float)
    pos = v[np.isfinite(v) & (v > 0)]
    return bool(pos.size) and float(pos.max()) > AUTO_LOG_RANGE * float(pos.min())


def _log_limits(ax, values, axis="y"):
    v = np.asarray(values, float)
    pos = v[np.isfinite(v) & (v > 0)]
    if not pos.size:
        return
    top = float(pos.max())
    lo = max(float(pos.min()), top * LOG_FLOOR)
    (ax.set_ylim if axis == "y" else ax.set_rlim)(lo / 1.5, top * 1.5)


# --------------------------------------------------------------------------------------------
# in-plane geometry


def theta_o_in_plane() -> np.ndarray:
    """The in-plane θo nodes [deg]: −89.9 … 89.9 in 0.1° steps."""
    n = int(round(THETA_O_MAX_DEG * 10))
    return np.arange(-n, n + 1) / 10.0


def in_plane_directions(theta_i_deg, theta_o_deg, phi_i_deg=0.0):
    """``(wi, wo)`` of signed in-plane θo [deg]: wi at (θi, φi); θo > 0 at φo = φi + π (the
    specular side), θo < 0 at φo = φi. Shapes: θi [I] × θo [N] → [I, N, 3]."""
    ti = np.radians(np.atleast_1d(np.asarray(theta_i_deg, float)))[:, None]
    to = np.asarray(theta_o_deg, float)[None, :]
    phi = math.radians(phi_i_deg)
    wi = sph_to_vec(ti + 0 * to, phi)
    wo = sph_to_vec(np.radians(np.abs(to)) + 0 * ti, np.where(to >= 0, phi + np.pi, phi))
    return wi, wo


def _own_theta_i(brdf, n: int):
    """A gonio table's own incidence angles [deg] (at most ``n``, evenly picked), or None."""
    for a in getattr(getattr(brdf, "grid", None), "axes", ()):
        if a.name == "theta_i":
            deg = np.round(np.degrees(np.asarray(a.values, float)), 9)
            return list(pick_evenly(deg[deg < 90.0], n)) or None
    return None


def _theta_list(theta_i_deg, default=THETA_I_DEG, brdf=None, n: int = 4) -> list:
    if theta_i_deg is None:
        own = _own_theta_i(brdf, n)
        theta_i_deg = own if own is not None else default
    vals = [float(x) for x in np.atleast_1d(np.asarray(theta_i_deg, float))]
    for t in vals:
        if not (0.0 <= t < 90.0) or not math.isfinite(t):
            raise BrdftabError(f"theta_i must lie in [0, 90) degrees, got {t:g}")
    if not vals:
        raise BrdftabError("no incidence angle given")
    return vals


def _curves(brdf, theta_i, phi_i_deg, quantity, series):
    theta_o = theta_o_in_plane()
    wi, wo = in_plane_directions(theta_i, theta_o, phi_i_deg)
    f = series.values(brdf, wi, wo)
    return theta_o, _apply(quantity, f, brdf, series, wi, wo)


def _plane_note(brdf, phi_i_deg) -> str:
    if phi_i_deg or not getattr(brdf, "isotropic", True):
        return f"plane of incidence at φi = {phi_i_deg:g}°"
    return ""


def _points_artist(ax, points, theta_i=None):
    """Mark printed values: rows (θi [deg], θo [deg], value)."""
    if points is None:
        return
    pts = np.asarray(points, float).reshape(-1, 3)
    ax.plot(pts[:, 1], pts[:, 2], linestyle="none", marker="o", markersize=7, markerfacecolor="none",
            markeredgecolor="tab:red", markeredgewidth=1.5, label="printed values", gid="points", zorder=5,
            clip_on=False)
    for t, o, v in pts:
        ax.annotate(f"{v:g}", (o, v), textcoords="offset points", xytext=(4, 6), fontsize=7, color="tab:red")


def in_plane(brdf, *, theta_i_deg=None, phi_i_deg: float = 0.0, quantity: str = "brdf", log=None,
             wavelengths=None, rgb: bool = False, channel=None, points=None, title=None, label=None) -> Figure:
    """In-plane curves of ``quantity`` against θo [deg], one per incidence angle θi [deg] and
    channel. ``points`` — rows (θi, θo, value) — are marked (a paper's printed values)."""
    q = _quantity(quantity)
    theta_i = _theta_list(theta_i_deg, brdf=brdf)
    series = _series(brdf, wavelengths, rgb, channel)
    theta_o, v = _curves(brdf, theta_i, phi_i_deg, quantity, series)
    fig = _new_figure()
    ax = fig.add_subplot()
    _draw_curves(ax, theta_o, v, theta_i, series)
    _points_artist(ax, points)
    ax.set_xlabel("θo [deg]  (> 0: specular side, < 0: source side)")
    ax.set_ylabel(q.axis_label)
    ax.set_xlim(-90, 90)
    ax.set_xticks(np.arange(-90, 91, 30))
    ax.grid(True, alpha=0.3)
    if _log_wanted(log, v):
        ax.set_yscale("log")
        _log_limits(ax, v)
    ax.legend(fontsize=7, ncol=2 if len(theta_i) * len(_kept(series)) > 6 else 1)
    ax.set_title(title or _title(brdf, label, _plane_note(brdf, phi_i_deg)), fontsize=9)
    return fig


def _draw_curves(ax, theta_o, v, theta_i, series, prefix="", marker=None, style_of=None, **kw):
    keep = _kept(series)
    for i, t in enumerate(theta_i):
        for c in keep:
            name = f"θi = {t:g}°" + (f", {series.names[c]}" if len(keep) > 1 or series.lam is not None else "")
            ls = (style_of or _STYLES)[i % len(_STYLES)] if marker is None else "none"
            ax.plot(theta_o, v[i, :, c], color=series.colours[c], linestyle=ls, marker=marker,
                    label=f"{prefix}{name}", gid=f"{prefix}theta_i={t:g}|channel={series.names[c]}", **kw)


def polar(brdf, *, theta_i_deg=None, phi_i_deg: float = 0.0, quantity: str = "brdf", log=None, wavelengths=None,
          rgb: bool = False, channel=None, title=None, label=None) -> Figure:
    """The in-plane curves in polar axes: the angle is θo from the normal (specular side to the
    right), the radius the quantity."""
    q = _quantity(quantity)
    theta_i = _theta_list(theta_i_deg, brdf=brdf)
    series = _series(brdf, wavelengths, rgb, channel)
    theta_o, v = _curves(brdf, theta_i, phi_i_deg, quantity, series)
    fig = _new_figure((7.6, 4.6))
    ax = fig.add_subplot(projection="polar")
    ax.set_theta_zero_location("N")
    ax.set_theta_direction(-1)
    ax.set_thetamin(-90)
    ax.set_thetamax(90)
    _draw_curves(ax, np.radians(theta_o), v, theta_i, series)
    if _log_wanted(log, v):
        ax.set_rscale("log")
        _log_limits(ax, v, axis="r")
    ax.set_xlabel(f"angle: θo [deg] (right: specular side); radius: {q.axis_label}", fontsize=8, labelpad=-40)
    ax.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.02, 0.5))
    ax.set_title(title or _title(brdf, label, _plane_note(brdf, phi_i_deg), _chars(fig)), fontsize=9)
    return fig


# --------------------------------------------------------------------------------------------
# θh × θd slice


def _slice_nodes(brdf):
    """θh, θd nodes [rad]: a Rusinkiewicz table's own, else the centres of 1° cells."""
    grid = getattr(brdf, "grid", None)
    axes = {a.name: np.asarray(a.values, float) for a in getattr(grid, "axes", ())}
    if "theta_h" in axes and "theta_d" in axes:
        return axes["theta_h"], axes["theta_d"]
    centres = np.radians(np.arange(90) + 0.5)
    return centres, centres


def slice_image(brdf, *, phi_d_deg: float = 90.0, phi_h_deg: float = 0.0, quantity: str = "brdf", log=None,
                wavelengths=None, rgb: bool = False, channel=None, title=None, label=None) -> Figure:
    """The θh × θd image at one φd (and φh) [deg], one panel per channel (NaN below the
    horizon). A Rusinkiewicz table is shown on its own θh, θd nodes."""
    q = _quantity(quantity)
    series = _series(brdf, wavelengths, rgb, channel)
    keep = _kept(series)
    if len(keep) > 3:
        keep = [keep[i] for i in np.unique(np.round(np.linspace(0, len(keep) - 1, 3)).astype(int))]
    th, td = _slice_nodes(brdf)
    wi, wo = hd_to_io(th[:, None], math.radians(phi_h_deg), td[None, :], math.radians(phi_d_deg))
    above = (wi[..., 2] > 1e-12) & (wo[..., 2] > 1e-12)
    f = series.values(brdf, wi, wo)
    v = _apply(quantity, f, brdf, series, wi, wo)
    v = np.where(above[..., None], v, np.nan)
    use_log = _log_wanted(log, v[..., keep])
    fig = _new_figure((4.0 * len(keep) + 1.0, 4.2))
    axes = fig.subplots(1, len(keep), squeeze=False)[0]
    for ax, c in zip(axes, keep):
        img = v[..., c].T  # rows θd, columns θh
        norm = None
        if use_log:
            pos = img[np.isfinite(img) & (img > 0)]
            if pos.size:
                norm = LogNorm(max(float(pos.min()), float(pos.max()) * LOG_FLOOR), float(pos.max()))
        mesh = ax.pcolormesh(np.degrees(th), np.degrees(td), img, shading="nearest", cmap="inferno", norm=norm,
                             gid=f"slice|channel={series.names[c]}")
        fig.colorbar(mesh, ax=ax, label=q.axis_label, shrink=0.85)
        ax.set_xlabel("θh [deg]")
        ax.set_ylabel("θd [deg]")
        ax.set_aspect("equal")
        ax.set_title(series.names[c], fontsize=9, color=series.colours[c] if not series.rgb else "black")
    note = f"φd = {phi_d_deg:g}°" + (f", φh = {phi_h_deg:g}°" if phi_h_deg or not brdf.isotropic else "")
    fig.suptitle(title or _title(brdf, label, note, _chars(fig)), fontsize=9)
    return fig


# --------------------------------------------------------------------------------------------
# hemisphere


def equal_area(theta, phi):
    """Lambert azimuthal equal-area projection of directions (θ, φ) [rad] of the upper
    hemisphere onto the unit disc: r = √2 sin(θ/2), (x, y) = r (cos φ, sin φ); the horizon is
    r = 1 and equal areas are equal solid angles (dω = π dA)."""
    r = math.sqrt(2.0) * np.sin(0.5 * np.asarray(theta, float))
    return r * np.cos(phi), r * np.sin(phi)


def equal_area_inverse(x, y):
    """(θ, φ) [rad] of points of the unit disc (NaN outside it)."""
    r = np.hypot(x, y)
    with np.errstate(invalid="ignore"):
        theta = np.where(r <= 1.0, 2.0 * np.arcsin(np.clip(r, 0, 1) / math.sqrt(2.0)), np.nan)
    return theta, np.arctan2(y, x)


def _disc_frame(ax):
    """Circles of θ = 30°, 60°, 90° and the azimuth ticks, in the equal-area projection."""
    t = np.linspace(0, 2 * np.pi, 361)
    for deg in (30, 60, 90):
        r = math.sqrt(2.0) * math.sin(math.radians(deg) / 2)
        ax.plot(r * np.cos(t), r * np.sin(t), color="0.6" if deg < 90 else "0.2", lw=0.6, gid=f"ring={deg}")
        ax.text(r * math.cos(math.radians(60)), r * math.sin(math.radians(60)), f"{deg}°", fontsize=6, color="0.4")
    for deg, ha, va in ((0, "left", "center"), (90, "center", "bottom"), (180, "right", "center"),
                        (270, "center", "top")):
        a = math.radians(deg)
        ax.text(1.03 * math.cos(a), 1.03 * math.sin(a), f"φ={deg}°", fontsize=6, color="0.3", ha=ha, va=va)
    ax.set_xlim(-1.3, 1.3)
    ax.set_ylim(-1.15, 1.15)
    ax.set_aspect("equal")
    ax.set_xlabel("x = √2 sin(θo/2) cos φo")
    ax.set_ylabel("y = √2 sin(θo/2) sin φo")


def _norm(values, log):
    v = np.asarray(values, float)
    pos = v[np.isfinite(v) & (v > 0)]
    if log and pos.size:
        return LogNorm(max(float(pos.min()), float(pos.max()) * LOG_FLOOR), float(pos.max()))
    fin = v[np.isfinite(v)]
    return Normalize(float(fin.min()), float(fin.max())) if fin.size else None


def hemisphere_grid(n: int):
    """Pixel centres of an n × n map of the unit square [−1, 1]² and their directions:
    ``(x[n], y[n], theta[n, n], phi[n, n])``, rows along y (NaN θ outside the disc)."""
    c = -1.0 + (np.arange(n) + 0.5) * 2.0 / n
    X, Y = np.meshgrid(c, c)
    theta, phi = equal_area_inverse(X, Y)
    return c, c, theta, phi


def hemisphere(brdf, *, theta_i_deg=None, phi_i_deg: float = 0.0, quantity: str = "brdf", log=None,
               wavelengths=None, rgb: bool = False, channel=None, n: int = 161, title=None, label=None) -> Figure:
    """The quantity over the exit hemisphere for one incidence (θi, φi) [deg], in the Lambert
    azimuthal equal-area projection (:func:`equal_area`), one panel per channel (at most 3),
    an n × n image (NaN outside the disc) of the values at the pixel centres: a lobe narrower
    than a pixel can fall between them (a larger ``n`` resolves it). The incident direction is
    marked ``+``, its mirror direction ``×``."""
    q = _quantity(quantity)
    theta_i = _theta_list(theta_i_deg, default=(30.0,), brdf=brdf, n=1)
    if len(theta_i) != 1:
        raise BrdftabError("a hemisphere map shows one incidence angle; give one theta_i")
    ti = math.radians(theta_i[0])
    pi_ = math.radians(phi_i_deg)
    series = _series(brdf, wavelengths, rgb, channel)
    keep = _kept(series)
    if len(keep) > 3:
        keep = [keep[i] for i in np.unique(np.round(np.linspace(0, len(keep) - 1, 3)).astype(int))]
    _, _, theta, phi = hemisphere_grid(n)
    inside = np.isfinite(theta)
    wo = sph_to_vec(np.where(inside, theta, 0.0), phi)
    wi = np.ascontiguousarray(np.broadcast_to(sph_to_vec(ti, pi_), wo.shape))
    v = _apply(quantity, series.values(brdf, wi, wo), brdf, series, wi, wo)
    v = np.where(inside[..., None], v, np.nan)
    use_log = _log_wanted(log, v[..., keep])
    fig = _new_figure((4.3 * len(keep) + 1.2, 4.6))
    axes = fig.subplots(1, len(keep), squeeze=False)[0]
    for ax, c in zip(axes, keep):
        img = ax.imshow(v[..., c], origin="lower", extent=(-1, 1, -1, 1), cmap="inferno",
                        norm=_norm(v[..., c], use_log), interpolation="nearest",
                        gid=f"hemisphere|channel={series.names[c]}")
        _disc_frame(ax)
        xi, yi = equal_area(ti, pi_)
        xm, ym = equal_area(ti, pi_ + np.pi)
        ax.plot([xi], [yi], marker="+", color="cyan", markersize=9, linestyle="none", gid="incident")
        ax.plot([xm], [ym], marker="x", color="cyan", markersize=7, linestyle="none", gid="mirror")
        fig.colorbar(img, ax=ax, label=q.axis_label, shrink=0.8)
        ax.set_title(series.names[c], fontsize=9)
    fig.suptitle(title or _title(brdf, label, f"θi = {theta_i[0]:g}°, φi = {phi_i_deg:g}° (+), equal-area map",
                                 _chars(fig)), fontsize=9)
    return fig


def hemisphere_values(directions, values, *, title: str = "", label: str = "value", unit: str = "", log=False,
                      incident=None, cmap: str = "viridis") -> Figure:
    """Given ``values[N]`` at unit ``directions[N, 3]`` (upper hemisphere), a map in the
    equal-area projection: one dot per direction (a ``PathCollection`` whose offsets are the
    projected positions and whose array is the values). ``incident`` (a direction) is marked."""
    d = np.asarray(directions, float).reshape(-1, 3)
    v = np.asarray(values, float).reshape(-1)
    if d.shape[0] != v.size:
        raise BrdftabError(f"{d.shape[0]} directions but {v.size} values")
    theta = np.arctan2(np.hypot(d[:, 0], d[:, 1]), d[:, 2])
    x, y = equal_area(theta, np.arctan2(d[:, 1], d[:, 0]))
    fig = _new_figure((5.2, 4.4))
    ax = fig.add_subplot()
    pts = ax.scatter(x, y, c=v, s=max(4.0, 1600.0 / max(v.size, 1) ** 0.5), cmap=cmap,
                     norm=_norm(v, log), gid="values")
    _disc_frame(ax)
    if incident is not None:
        w = np.asarray(incident, float)
        xi, yi = equal_area(math.atan2(math.hypot(w[0], w[1]), w[2]), math.atan2(w[1], w[0]))
        ax.plot([xi], [yi], marker="+", color="red", markersize=9, linestyle="none", gid="incident")
    fig.colorbar(pts, ax=ax, label=f"{label} [{unit}]" if unit else label, shrink=0.8)
    ax.set_title(title, fontsize=9)
    return fig


# --------------------------------------------------------------------------------------------
# albedo


def albedo(brdf, *, theta_i_deg=None, phi_i_deg=0.0, wavelengths=None, rgb: bool = False, channel=None,
           title=None, label=None) -> Figure:
    """The directional albedo a(θi) = ∫ f cosθo dωo per channel (at each φi [deg] given, one
    line style each), by :func:`brdftab.integrate.albedo_curve`; the legend gives the white-sky
    albedo, the title the smallest coverage when the BRDF lacks data somewhere."""
    from .integrate import albedo_curve

    theta = _theta_list(theta_i_deg, np.arange(0.0, 90.0, 3.0), brdf, n=10 ** 6)
    phis = [float(p) for p in np.atleast_1d(np.asarray(phi_i_deg, float))]
    series = _series(brdf, wavelengths, rgb, channel)
    curve = albedo_curve(brdf, np.radians(theta), np.radians(phis), series.lam)
    values = curve.values
    if series.rgb:  # the albedo is linear in f: the albedo spectra through the same conversion
        from .colorimetry import spectral_to_rgb

        values = np.asarray(spectral_to_rgb(values, series.lam), float)
    keep = _kept(series)
    cov = float(np.nanmin(curve.coverage)) if curve.coverage.size else 1.0
    note = f"coverage ≥ {100 * cov:.3g} % of the projected solid angle" if cov < 0.999 else ""
    return albedo_values(theta, values[..., keep], [series.names[c] for c in keep], phi_i_deg=phis,
                         colours=[series.colours[c] for c in keep], title=title or _title(brdf, label, note))


def albedo_values(theta_i_deg, values, channels=None, *, phi_i_deg=None, limit=None, colours=None,
                  title=None) -> Figure:
    """A directional-albedo curve already computed (e.g. by the albedo check): ``values[T, C]``
    (or ``[T, P, C]`` at each of ``phi_i_deg[P]``, one line style each; the first φi when
    ``phi_i_deg`` is not given) at ``theta_i_deg[T]``, one line per channel named in ``channels``
    (``"R"``, ``"550 nm"``, …; at most :data:`MAX_WAVELENGTHS` of more, evenly picked) in the
    channels' colours, with the white-sky albedo of each (from the mean over φi) in the legend.
    ``limit`` draws the energy check's bound, dashed (a value below 0.5 is its tolerance above 1).
    Curves are ``gid`` ``"albedo|channel=R"`` (``"albedo|phi_i=30|channel=R"`` with several φi)."""
    from .integrate import white_sky_albedo

    theta = np.asarray(theta_i_deg, float).reshape(-1)
    v = np.asarray(values, float)
    if v.ndim == 3 and phi_i_deg is None:
        v = v[:, :1, :]
    elif v.ndim < 3:
        v = v.reshape(v.shape[0] if v.ndim else 1, 1, -1)
    if v.shape[0] != theta.size:
        raise BrdftabError(f"{theta.size} incidence angles but {v.shape[0]} albedo values")
    phis = [0.0] if phi_i_deg is None else [float(p) for p in np.atleast_1d(np.asarray(phi_i_deg, float))]
    if len(phis) != v.shape[1]:
        raise BrdftabError(f"{len(phis)} azimuths but albedo values for {v.shape[1]}")
    names = [str(c) for c in channels] if channels is not None else (
        ["mono"] if v.shape[-1] == 1 else [f"c{i}" for i in range(v.shape[-1])])
    if len(names) != v.shape[-1]:
        raise BrdftabError(f"{len(names)} channel names for {v.shape[-1]} albedo channels")
    colours = list(colours) if colours is not None else _colours(names)
    keep = list(pick_evenly(np.arange(len(names)), MAX_WAVELENGTHS).astype(int))
    with np.errstate(invalid="ignore"):
        white = white_sky_albedo(np.radians(theta), v.mean(axis=1)) if theta.size > 1 else [None] * len(names)
    fig = _new_figure()
    ax = fig.add_subplot()
    for j, p in enumerate(phis):
        for c in keep:
            name = names[c]
            text = name + (f", φi = {p:g}°" if len(phis) > 1 else "")
            if white[c] is not None and j == 0 and np.isfinite(white[c]):
                text += f" (white-sky {white[c]:.4g})"
            gid = f"albedo|phi_i={p:g}|channel={name}" if len(phis) > 1 else f"albedo|channel={name}"
            ax.plot(theta, v[:, j, c], color=colours[c], linestyle=_STYLES[j % len(_STYLES)], marker=".",
                    label=text, gid=gid)
    if limit is not None:
        bound = 1.0 + float(limit) if float(limit) < 0.5 else float(limit)
        ax.axhline(bound, color="tab:red", linestyle="--", lw=1.0, label=f"energy limit {bound:g}", gid="limit")
    ax.set_xlabel("θi [deg]")
    ax.set_ylabel("directional albedo a(θi) = ∫ f_r cos θo dωo [dimensionless]")
    ax.set_xlim(0, 90)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7)
    ax.set_title(title or "directional albedo", fontsize=9)
    return fig


# --------------------------------------------------------------------------------------------
# comparison


def compare(brdf, other, *, theta_i_deg=None, phi_i_deg: float = 0.0, quantity: str = "brdf", log=None,
            wavelengths=None, rgb: bool = False, channel=None, ratio: bool = False, title=None, label=None,
            other_label=None) -> Figure:
    """Two BRDFs' in-plane curves (``brdf``: lines, ``other``: dots) and, below, ``other −
    brdf`` in the quantity's unit (or ``other / brdf`` with ``ratio``). Their channels must
    agree (a grey one broadcasts against the other's)."""
    q = _quantity(quantity)
    theta_i = _theta_list(theta_i_deg, brdf=brdf)
    series = _series(brdf, wavelengths, rgb, channel)
    if series.lam is not None:  # both at the same wavelengths (through the same sRGB conversion)
        other_series = _Series(series.names, series.colours, series.lam, series.rgb, series.keep)
    else:
        other_series = _series(other)
    if other_series.names != series.names and other_series.names != ["mono"] and series.names != ["mono"]:
        raise BrdftabError(f"cannot compare channels {', '.join(series.names)} with {', '.join(other_series.names)}")
    theta_o, a = _curves(brdf, theta_i, phi_i_deg, quantity, series)
    _, b = _curves(other, theta_i, phi_i_deg, quantity, other_series)
    a, b = np.broadcast_arrays(a, b)
    if series.names == ["mono"] and other_series.names != ["mono"]:
        series = other_series
    with np.errstate(divide="ignore", invalid="ignore"):
        d = b / a if ratio else b - a
    fig = _new_figure((6.6, 5.8))
    top, bottom = fig.subplots(2, 1, sharex=True, height_ratios=(3, 2))
    la = label or getattr(brdf, "name", "A")
    lb = other_label or getattr(other, "name", "B")
    _draw_curves(top, theta_o, a, theta_i, series, prefix="A: ")
    step = max(1, theta_o.size // 60)
    sub = slice(0, None, step)
    _draw_curves(top, theta_o[sub], b[:, sub], theta_i, series, prefix="B: ", marker="o", markersize=3,
                 markerfacecolor="none")
    top.set_ylabel(q.axis_label)
    top.grid(True, alpha=0.3)
    if _log_wanted(log, np.concatenate([a.ravel(), b.ravel()])):
        top.set_yscale("log")
        _log_limits(top, np.concatenate([a.ravel(), b.ravel()]))
    top.legend(fontsize=6, ncol=2)
    _draw_curves(bottom, theta_o, d, theta_i, series, prefix="B/A: " if ratio else "B−A: ")
    bottom.axhline(1.0 if ratio else 0.0, color="0.5", lw=0.6)
    bottom.set_ylabel("B / A [dimensionless]" if ratio else
                      f"B − A [{q.unit}]" if q.unit else "B − A [dimensionless]")
    bottom.set_xlabel("θo [deg]  (> 0: specular side, < 0: source side)")
    bottom.set_xlim(-90, 90)
    bottom.set_xticks(np.arange(-90, 91, 30))
    bottom.grid(True, alpha=0.3)
    head = title or f"A (lines): {_title(brdf, la)}\nB (dots): {_title(other, lb)}"
    note = _plane_note(brdf, phi_i_deg)
    fig.suptitle(head + (f"\n{note}" if note and not title else ""), fontsize=8)
    return fig


def mueller(brdf, *, theta_i_deg=None, phi_i_deg: float = 0.0, log=None, wavelengths=None, rgb: bool = False,
            channel=None, title=None, label=None) -> Figure:
    """The Mueller matrix of a polarized BRDF in the plane of incidence: 4 × 4 panels of curves
    against θo [deg] (one per θi and channel), M00 [sr⁻¹] in panel (0, 0) and M_ij / M00 in the
    others (NaN where M00 = 0), in brdftab's ``mitsuba`` basis. Curves' ``gid``:
    ``"theta_i=30|channel=550 nm|element=m01"``."""
    from .mueller_table import is_polarized

    if not is_polarized(brdf):
        raise BrdftabError(f"{brdf.name} is not polarized: it has no Mueller matrix to plot")
    if rgb:
        raise BrdftabError("a Mueller matrix is plotted per wavelength, not as sRGB (leave out --rgb)")
    theta_i = _theta_list(theta_i_deg, brdf=brdf)
    series = _series(brdf, wavelengths, False, channel)
    theta_o = theta_o_in_plane()
    wi, wo = in_plane_directions(theta_i, theta_o, phi_i_deg)
    m = np.asarray(brdf.eval_mueller(wi, wo, series.lam), float)  # [I, N, C, 4, 4]
    m00 = m[..., 0, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        norm = np.where(m00[..., None, None] > 0, m / m00[..., None, None], np.nan)
    fig = _new_figure((11.0, 9.0))
    axes = fig.subplots(4, 4, sharex=True)
    for i in range(4):
        for j in range(4):
            ax = axes[i, j]
            values = m00 if (i, j) == (0, 0) else norm[..., i, j]
            name = "M00" if (i, j) == (0, 0) else f"m{i}{j}"
            for a, t in enumerate(theta_i):
                for c in _kept(series):
                    ax.plot(theta_o, values[a, :, c], color=series.colours[c], linestyle=_STYLES[a % len(_STYLES)],
                            label=f"θi = {t:g}°" + (f", {series.names[c]}" if series.lam is not None else ""),
                            gid=f"theta_i={t:g}|channel={series.names[c]}|element=m{i}{j}")
            ax.set_title(f"{name}" + (" [sr⁻¹]" if (i, j) == (0, 0) else " = M%d%d / M00" % (i, j)), fontsize=8)
            ax.grid(True, alpha=0.3)
            ax.tick_params(labelsize=7)
            if (i, j) == (0, 0):
                if _log_wanted(log, values):
                    ax.set_yscale("log")
                    _log_limits(ax, values)
            else:
                ax.set_ylim(-1.05, 1.05)
            if i == 3:
                ax.set_xlabel("θo [deg]", fontsize=7)
    axes[0, 0].set_xlim(-90, 90)
    axes[0, 0].set_xticks(np.arange(-90, 91, 45))
    axes[0, 0].legend(fontsize=6)
    fig.suptitle(title or _title(brdf, label, "Mueller matrix in the plane of incidence (x ⊥ plane, +S3 right "
                                 "circular)" + (f", {_plane_note(brdf, phi_i_deg)}" if _plane_note(brdf, phi_i_deg)
                                                else "")), fontsize=9)
    return fig


# --------------------------------------------------------------------------------------------
# dispatch and output

_FUNCTIONS = {"in-plane": in_plane, "polar": polar, "slice": slice_image, "hemisphere": hemisphere,
              "albedo": albedo, "compare": compare, "mueller": mueller}


def figure(kind: str, brdf, **options) -> Figure:
    """The figure of ``kind`` (one of :data:`KINDS`) for ``brdf``; ``options`` are the keyword
    arguments of that kind's function (``compare`` takes the second BRDF as ``other``). An
    option the kind does not take is one clear error."""
    import inspect

    fn = _FUNCTIONS.get(kind)
    if fn is None:
        raise BrdftabError(f"unknown plot kind {kind!r}; one of {', '.join(KINDS)}")
    accepted = inspect.signature(fn).parameters
    for key, value in options.items():
        if key not in accepted:
            raise BrdftabError(f"option {key.replace('_', '-')} does not apply to a plot of kind {kind!r}")
    if kind == "compare" and options.get("other") is None:
        raise BrdftabError("a comparison needs a second BRDF (--against)")
    if kind == "compare":
        options = dict(options)
        other = options.pop("other")
        return fn(brdf, other, **options)
    return fn(brdf, **options)


def artists(fig: Figure, prefix: str = "") -> dict:
    """The figure's curves, images and point sets by ``gid`` (those starting with ``prefix``)."""
    out = {}
    for ax in fig.axes:
        for a in list(ax.lines) + list(ax.images) + list(ax.collections):
            gid = a.get_gid()
            if gid and gid.startswith(prefix):
                out.setdefault(gid, a)
    return out


def to_png_bytes(fig: Figure, dpi: float = 80) -> bytes:
    """The figure as PNG bytes: opaque RGB (the figures have a white background, so dropping
    the alpha channel loses nothing), compressed with Pillow's ``optimize``."""
    from PIL import Image

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    out = io.BytesIO()
    with Image.open(io.BytesIO(buf.getvalue())) as image:
        image.convert("RGB").save(out, format="png", optimize=True)
    return out.getvalue()


def output_format(path) -> str:
    """The file format of an output path by its extension (:data:`FORMATS`); else one error."""
    ext = Path(path).suffix.lower()
    if ext not in FORMATS:
        raise BrdftabError(f"{path}: unknown plot format {ext or '(no extension)'!r}; use "
                           f"{', '.join(FORMATS)}")
    return FORMATS[ext]


def save(fig: Figure, path, *, overwrite: bool = False, dpi: float = 100, inputs=()) -> Path:
    """Write ``fig`` to ``path`` (PNG, SVG or PDF by extension) atomically: the file is
    complete or absent. An existing file is replaced only with ``overwrite``, and never when it
    is one of ``inputs`` (the files plotted: paths or ``(path, "what it is")`` pairs)."""
    from ._atomic import atomic_path

    fmt = output_format(path)
    path = Path(path)
    with atomic_path(path, overwrite=overwrite, inputs=inputs) as tmp:
        with open(tmp, "wb") as fh:
            if fmt == "png":
                fh.write(to_png_bytes(fig, dpi))
            else:  # no creation date: the same figure gives the same file
                fig.savefig(fh, format=fmt, dpi=dpi, metadata={"Date": None} if fmt == "svg" else
                            {"CreationDate": None})
    return path
