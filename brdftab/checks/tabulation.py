"""Tabulation error: a table against the model it was made from, between its nodes.

The model is the one the caller passes (the pipeline passes the spec's model) or the one the
table's provenance names (``model`` + ``parameters``), when brdftab has it. The table is
interpolated at random cell centres — the midpoint of a random cell along every axis, in the
axis's own (warped) coordinate, where multilinear interpolation is least accurate — and
compared with the model there:

* rms relative error sqrt(Σ ((t − m) μi μo)² / Σ (m μi μo)²) over all points and channels —
  the relative error of the reflected radiance f cosθi cosθo in the L² sense (weighting by the
  cosines keeps the 1/(cosθi cosθo) growth of f at grazing angles from dominating);
* max relative error |t − m| / m over points whose m cosθi cosθo exceeds 1e-3 of its largest
  value.

The two are over different points, so the rms can exceed the max: when the error lies where
the model has (almost) nothing — a narrow lobe spread over coarse cells, where the table holds
values the model does not. The report then says so.

On a gonio grid the error is also reported with the incidence axes (θi, φi) held at their
nodes — the outgoing interpolation alone, the error of reading the table at the incidence
angles it was sampled at — so a table of a few incidence slices shows which of the two
interpolations is off (``rms_at_incidence_nodes``).

WARN by default: how closely a grid follows a model is the user's choice of resolution.
"""

from __future__ import annotations

import numpy as np

from ..params import Param
from . import Check, register
from ._pairs import fmt_pair, where_deg
from ._reference import reference
from ._tables import axis_coordinate, horizon_error, pair_directions

__all__ = ["Tabulation", "cell_centres"]


INCIDENCE_AXES = ("theta_i", "phi_i", "speos_rotation")


def cell_centres(grid, n: int, seed: int = 0, at_nodes=()):
    """(wi, wo) at the centres of ``n`` random cells of ``grid`` (above the horizon only);
    axes named in ``at_nodes`` are held at random nodes instead of cell centres."""
    own = getattr(grid, "cell_centres", None)
    if callable(own):  # scattered samples: centroids of the simplices of their triangulation
        return own(n, seed, at_nodes)
    rng = np.random.default_rng(seed)
    coords = []
    for ax in grid.axes:
        m = len(ax)
        if m == 1 or ax.name in at_nodes:
            if m > 1:
                coords.append(ax.values[rng.integers(0, m, n)])
                continue
            coords.append(np.full(n, ax.values[0]))
            continue
        top = m if ax.period is not None else m - 1
        i = rng.integers(0, top, n)
        coords.append(axis_coordinate(ax, i, 0.5))
    wi, wo = pair_directions(grid, coords)
    keep = (wi[:, 2] > 1e-9) & (wo[:, 2] > 1e-9)
    return wi[keep], wo[keep]


def compare(table_values, model_values, weight=None):
    """rms and max relative error (and the row of the worst point, and the number of points
    compared) of a table against a model, with optional per-point weights (e.g. μi μo)."""
    t = np.asarray(table_values, float)
    m = np.asarray(model_values, float)
    if t.ndim == 1:
        t, m = t[:, None], m[:, None]
    w = np.ones(t.shape[0]) if weight is None else np.asarray(weight, float)
    ok = np.isfinite(t) & np.isfinite(m)
    d = np.where(ok, t - m, 0.0) * w[:, None]
    mm = np.where(ok, m, 0.0) * w[:, None]
    top = float(np.abs(mm).max()) if mm.size else 0.0
    # squared after scaling by the largest magnitude: values near 1e200 do not overflow the sums
    scale = max(top, float(np.abs(d).max()) if d.size else 0.0)
    scale = scale if np.isfinite(scale) and scale > 0 else 1.0
    den = float(((mm / scale) ** 2).sum())
    rms = float(np.sqrt(((d / scale) ** 2).sum() / den)) if den > 0 else (0.0 if not d.any() else float("inf"))
    sig = ok & (np.abs(mm) > 1e-3 * top) & (top > 0)
    rel = np.divide(np.abs(d), np.abs(mm), out=np.zeros(d.shape), where=sig)
    worst = int(np.unravel_index(np.argmax(rel), rel.shape)[0]) if sig.any() else None
    return rms, float(rel.max()) if sig.any() else 0.0, worst, int(ok.all(axis=-1).sum())


@register
class Tabulation(Check):
    name = "tabulation"
    family = "tabulation"
    summary = "A table against the model in its provenance, at cell centres: rms and max relative error."
    level = "warn"
    thresholds = (
        Param("rms", "float", "Largest accepted rms relative error of f cosθi cosθo, "
              "sqrt(Σ((t − m) μi μo)² / Σ(m μi μo)²).", default=0.05, minimum=0.0),
        Param("max_relative", "float", "Largest accepted relative error at one point (where m cosθi cosθo "
              "exceeds 1e-3 of its largest value).", default=1.0, minimum=0.0),
        Param("points", "int", "Random cell centres compared.", default=8192, minimum=16, maximum=10_000_000),
        Param("seed", "int", "Seed of the random cells.", default=0, minimum=0),
    )

    def applies(self, ctx):
        if not ctx.is_table:
            return "not a table"
        if not ctx.on_grid:
            return "the table is not on a brdftab grid (no cell centres)"
        model, why = reference(ctx)
        return why if model is None else None

    def run(self, ctx, rms, max_relative, points, seed):
        t = ctx.brdf
        model, _ = reference(ctx)
        wi, wo = cell_centres(t.grid, points, seed)
        lam = ctx.wavelengths if ctx.wavelengths is not None else (t.wavelengths if t.spectral else None)
        ft = t.eval(wi, wo, lam)
        fm = model.eval(wi, wo, lam)
        e_rms, e_max, worst, n = compare(ft, fm, wi[:, 2] * wo[:, 2])
        if n == 0:
            return self.skip(f"no cell centre of the {t.grid.describe()} could be compared with {model.name} "
                             "(every one is missing, outside the domain or below the horizon)")
        at, where = "", None
        if worst is not None:
            where = where_deg(wi[worst], wo[worst])
            at = f" at {fmt_pair(where)}"
        ok = e_rms <= rms and e_max <= max_relative
        extra, data = "", {}
        held = [a.name for a in t.grid.axes if a.name in INCIDENCE_AXES and len(a) > 1]
        if held:
            wi2, wo2 = cell_centres(t.grid, points, seed + 1, at_nodes=INCIDENCE_AXES)
            r2, m2, _, n2 = compare(t.eval(wi2, wo2, lam), model.eval(wi2, wo2, lam), wi2[:, 2] * wo2[:, 2])
            if n2:
                extra = f"; at the {', '.join(held)} nodes: rms {r2:.3g}, max {m2:.3g}"
                data = {"rms_at_incidence_nodes": r2, "max_relative_at_incidence_nodes": m2}
        h = horizon_error(t, model, points, seed, wavelengths=lam)
        if h is not None:
            extra += (f"; within {h['band_deg']:g}° of the horizon: max {h['max_relative']:.3g} at "
                      f"{fmt_pair(h['where'])}" + (f", {h['zeros']} exact zeros" if h["zeros"] else ""))
            data["horizon"] = h
        if e_rms > e_max:
            extra += ("; the rms exceeds the max because the error lies where the model is below 1e-3 of its peak "
                      "(the table holds values there that the model does not)")
        return self.outcome(ok, e_rms, rms, f"rms relative error of f cosθi cosθo {e_rms:.3g} (sqrt(Σ(t − m)²/Σm²) "
                            f"over all points), max {e_max:.3g}{at} (pointwise |t − m|/m where m cosθi cosθo ≥ 1e-3 "
                            f"of its peak), against {model.describe()} at {n} cell centres{extra} (accepted: {rms:g} / "
                            f"{max_relative:g})", rms=e_rms, max_relative=e_max, where=where, points=n,
                            model=model.name, max_relative_threshold=max_relative, **data)
