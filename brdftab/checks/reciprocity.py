"""Reciprocity: f(wi, wo) = f(wo, wi) (Helmholtz reciprocity).

* Models are compared on random direction pairs (:func:`~brdftab.checks._pairs.sample_pairs`).
* Tables are compared on exact node pairs where the grid has them: a Rusinkiewicz table with
  ``phi_d_fold = none`` pairs φd with φd + π (swapping wi and wo keeps h and maps d to
  (−dx, −dy, dz)); with ``bilateral`` it pairs φd with π − φd; a gonio table pairs
  (θi, φi, θo, φo) with (θo, φo, θi, φi) (rotated about the normal when the table is isotropic
  and has one φi). A table folded by reciprocity is reciprocal by construction (whether its
  source was is the ``conventions`` check's question); where only some nodes have a partner
  (θo nodes that are θi nodes for part of the table) those node pairs are compared.
* **Interpolated.** A table on a grid without node pairs (a gonio table whose θi and θo nodes
  differ, a φd axis without the partners) is compared at random pairs inside the region it
  covers both ways, with *both* directions evaluated by the same interpolations: the table's
  multilinear one and a curvature-corrected one (its leading error term, ½ p(1 − p) h² f''
  per axis, removed with f'' from the table's second differences:
  :class:`~brdftab.checks._tables.CorrectedInterpolant`). The interpolation showing the
  smaller albedo-weighted asymmetry counts — an asymmetry of the data shows in both, an
  interpolation error need not — and that figure is judged against ``weighted_interpolated``
  (0.005). What the table's resolution can tell is measured from the table itself: the same
  figure on a reciprocal table of its content and resolution (at each node ½ (stored value +
  the corrected interpolation at the reverse pair):
  :func:`~brdftab.checks._tables.reciprocal_surrogate`), times :data:`RESOLUTION_MARGIN`, is
  its *resolution limit*. A table whose limit exceeds the threshold is judged against the
  limit, and the report says that asymmetry below it is not resolved — an interpolation error
  is not reported as asymmetry, and asymmetry beyond the limit still fails. Measured on a GGX
  gonio table (θi every 5° from 0 to 85°, θo every 5° from 2.5° to 87.5°, φo every 5°):
  α = 0.3: 0.00048 (multilinear alone 0.0031), limit 0.0024, so 1 % and 5 % asymmetry
  (0.0099, 0.050) fail; α = 0.05: 0.086 within its limit of 0.33 (5 × 0.066).
* A table whose pairs cannot be compared with their reverse inside the region it covers (a
  zoomed gonio grid around the mirror direction) is judged on the model it was made from, at
  the sampled pairs it covers one way: never skipped while that model is known.

**Data** — a table or file of measured or unknown origin (see
:attr:`brdftab.brdf.BRDF.origin`) that does not declare reciprocity (a netCDF without the
``reciprocal`` attribute, an RGL file of the database) — is not assumed reciprocal: its
asymmetry is measured within the incidence range it was measured over (up to its last θi
node, e.g. ~80° for RGL files), on the relative luminance of its channels, as the albedo-
weighted figure, and reported as WARN above ``measured_weighted`` (0.05) — or above the
table's resolution limit when it is interpolated and that is larger — never FAIL, unless the
user says the data must be reciprocal (``assume = "reciprocal"``). Data that declares
reciprocity (the file says so) is judged like a model.

A BRDF that *declares* itself non-reciprocal (``reciprocal = False``: a model whose formula is
not reciprocal by construction, or a table made from one) is not refused for it: its measured
asymmetry is reported as WARN (PASS when it is within the thresholds), never FAIL and never
skipped. A BRDF that declares reciprocity and shows asymmetry FAILs.

Figures: the largest and rms relative asymmetry |f − f'| / ½(f + f'), and the albedo-weighted
asymmetry ∫∫ |f − f'| cos cos / ∫∫ ½(f + f') cos cos. Missing samples are left out.
"""

from __future__ import annotations

import numpy as np

from ..channels import luminance_weights
from ..params import Param
from . import Check, register
from ._pairs import SCALES, asymmetry, asymmetry_blocks, fmt_pair, sample_pairs, where_deg
from ._reference import reference
from ._tables import (CorrectedInterpolant, NotBlockable, data_blocks, data_values, gonio_node_weights, match_axis,
                      node_where, over_budget, phi_d_pairs, reciprocal_surrogate)

__all__ = ["Reciprocity", "covered", "as_data", "measured_theta_max", "interpolated_asymmetry", "RESOLUTION_MARGIN"]

#: An interpolated comparison cannot tell asymmetry below this many times the asymmetry the
#: table's own interpolation gives a reciprocal table of the same content and resolution (its
#: *resolution limit*). Measured ratios of the asymmetry an exactly reciprocal table shows to
#: that estimate: 1.0–1.3 on uniform gonio grids whose θi and θo nodes are offset and on
#: Rusinkiewicz grids without φd partners, up to 2.7 on irregular node lists and anisotropic
#: lobes between φi nodes, 3.8 for a GGX lobe of α = 0.005 on 10° θi steps.
RESOLUTION_MARGIN = 5.0


def as_data(ctx) -> bool:
    """The BRDF is judged as data: of measured or unknown origin and not declared reciprocal
    (or a table that does not say whether it is)."""
    b = ctx.brdf
    if b.reciprocal and getattr(b, "reciprocity_declared", True):
        return False
    return ctx.measured or not getattr(b, "reciprocity_declared", True)


def measured_theta_max(brdf):
    """The last measured incidence angle [rad] of data that has one (an RGL file's θi nodes, a
    gonio table's θi axis), else None."""
    theta = getattr(brdf, "theta_i", None)
    if theta is None:
        grid = getattr(brdf, "grid", None)
        for ax in getattr(grid, "axes", ()) or ():
            if getattr(ax, "name", "") == "theta_i":
                theta = ax.values
    if theta is None or np.size(theta) == 0:
        return None
    top = float(np.max(theta))
    return top if 0 < top < np.pi / 2 - 1e-9 else None


def _scattered(b) -> bool:
    """A table of scattered samples: no multilinear cells, its own interpolation compares pairs."""
    return bool(getattr(getattr(b, "grid", None), "scattered", False))


def covered(table, wi, wo) -> np.ndarray:
    """True for pairs inside the table's domain (:meth:`~brdftab.grids.Grid.locate`)."""
    _, outside = table.grid.locate(wi, wo, isotropic=table.isotropic)
    return ~np.asarray(outside, bool)


def node_pairs(ctx):
    """``rows()`` giving the node pairs of a table block by block — ``(f, f', w, flat)`` for
    :func:`~brdftab.checks._pairs.asymmetry_blocks` — or None when its nodes have no partners
    (then the pairs are sampled and interpolated). A Rusinkiewicz table pairs every node with
    its φd partner within slabs of θh (read one at a time when the table is over the memory
    budget); a gonio table pairs (θi, φi) with (θo, φo) across the whole table, which must fit
    the budget (:class:`~brdftab.checks._tables.NotBlockable` otherwise)."""
    table = ctx.brdf
    grid = table.grid
    if grid.parameterization == "rusinkiewicz":
        fold = grid.phi_d_fold
        ax = grid.axes[grid.dims.index("phi_d")]
        if fold == "none":
            target = ax.values + np.pi
        elif fold == "bilateral":
            target = np.pi - ax.values
        else:
            return None
        j = match_axis(ax, target)
        if np.any(j < 0):
            return None

        def rows():
            for key, v in data_blocks(ctx):
                yield phi_d_pairs(grid, v, j, key)
        return rows
    if _scattered(table):
        return _scattered_pairs(table, data_values(ctx))
    if not grid.node_checks:
        return None  # nodes without partners: pairs are sampled and interpolated
    if over_budget(table):
        raise NotBlockable("a gonio table's (θi, φi) ↔ (θo, φo) node pairs span the whole table, which is over "
                           "the memory budget")
    nodes = _node_pairs_spherical(table, data_values(ctx))
    return None if nodes is None else (lambda: iter([nodes]))


def _scattered_pairs(table, v):
    """Node pairs of scattered samples: each sample (wi, wo) with the sample at (wo, wi) (the
    same point of the interpolation space within 1e-9), weighted cosθi cosθo; None when fewer
    than half of the samples have one (then pairs are sampled and interpolated)."""
    from scipy.spatial import cKDTree

    from ..grids.scattered import pair_space

    grid = table.grid
    wi, wo = grid.directions()
    here = pair_space(wi, wo, table.isotropic)
    d, j = cKDTree(here).query(pair_space(wo, wi, table.isotropic))
    has = d <= 1e-9
    if has.sum() < 0.5 * grid.size:
        return None
    c = v.shape[-1]
    v = v.reshape(-1, c)
    partner = np.where(has[:, None], v[j], np.nan)
    w = np.where(has, wi[:, 2] * wo[:, 2], 0.0)
    nodes = (v, partner, w, lambda row: int(row))
    return lambda: iter([nodes])


def _node_pairs_spherical(table, v):
    """(partner values, weights) for the (θi, φi) ↔ (θo, φo) partner of every node, or None."""
    grid = table.grid
    if grid.relative_to != "none":
        return None
    a_ti, a_pi, a_to, a_po = grid.axes
    ia = match_axis(a_ti, a_to.values)          # θi index of each θo node
    ic = match_axis(a_to, a_ti.values)          # θo index of each θi node
    if table.isotropic:
        # f(θi, φi_b, θo, φo_d) = f(θo, φi_0, θi, φi_b − φo_d + φi_0)
        jb = np.zeros((len(a_pi), len(a_po)), int)
        target = a_pi.values[:, None] - a_po.values[None, :] + a_pi.values[0]
        if getattr(grid, "phi_d_fold", "none") == "bilateral":  # |φo − φi| folded into [0, π]
            target = a_pi.values[0] + np.abs(np.mod(target - a_pi.values[0] + np.pi, 2 * np.pi) - np.pi)
        jd = match_axis(a_po, target.ravel())
        jd = jd.reshape(len(a_pi), len(a_po))
    else:
        jb = np.broadcast_to(match_axis(a_pi, a_po.values)[None, :], (len(a_pi), len(a_po)))
        jd = np.broadcast_to(match_axis(a_po, a_pi.values)[:, None], (len(a_pi), len(a_po)))
    A = ic[:, None, None, None]
    B = jb[None, :, None, :]
    Cc = ia[None, None, :, None]
    D = jd[None, :, None, :]
    valid = (A >= 0) & (B >= 0) & (Cc >= 0) & (D >= 0)
    valid = np.broadcast_to(valid, grid.shape)
    if not valid.any():
        return None
    # partner value at (θi', φi', θo', φo') = (θo_c, φ(b, d), θi_a, φ(b, d))
    Ii = np.broadcast_to(np.where(Cc >= 0, Cc, 0), grid.shape)
    Ip = np.broadcast_to(np.where(B >= 0, B, 0), grid.shape)
    Io = np.broadcast_to(np.where(A >= 0, A, 0), grid.shape)
    Iq = np.broadcast_to(np.where(D >= 0, D, 0), grid.shape)
    partner = v[Ii, Ip, Io, Iq]
    w = np.where(valid, gonio_node_weights(grid), 0.0)
    partner = np.where(valid[..., None], partner, np.nan)
    c = v.shape[-1]
    return v.reshape(-1, c), partner.reshape(-1, c), w.reshape(-1), lambda row: int(row)


@register
class Reciprocity(Check):
    name = "reciprocity"
    family = "reciprocity"
    summary = "f(wi, wo) = f(wo, wi): largest, rms and albedo-weighted relative asymmetry."
    thresholds = (
        Param("max_relative", "float", "Largest accepted relative asymmetry |f(wi,wo) − f(wo,wi)| / their mean "
              "(judged where the pairs are exact: models and table node pairs).", default=1e-6, minimum=0.0),
        Param("weighted", "float", "Largest accepted albedo-weighted asymmetry "
              "∫∫|f − f'| cosθi cosθo / ∫∫ ½(f + f') cosθi cosθo.", default=1e-3, minimum=0.0),
        Param("weighted_interpolated", "float", "Largest accepted albedo-weighted asymmetry of a table without node "
              "pairs, compared at random pairs by interpolating both directions the same way (multilinear and "
              "curvature-corrected; the smaller figure counts). A table too coarse for it is judged against its "
              "resolution limit instead — 5 × the asymmetry its interpolation gives a reciprocal table of the same "
              "content — and the report says so.", default=0.005, minimum=0.0),
        Param("pairs", "int", "Random direction pairs (models, and tables without node pairs).", default=16384,
              minimum=16, maximum=10_000_000),
        Param("seed", "int", "Seed of the random direction pairs.", default=0, minimum=0),
        Param("measured_weighted", "float", "Data not declared reciprocal (measured or unknown origin): the "
              "luminance- and albedo-weighted asymmetry above which it is reported (WARN).", default=0.05,
              minimum=0.0),
        Param("assume", "choice", "'declared': judge what the BRDF declares (data not declared reciprocal is "
              "reported, never refused); 'reciprocal': the BRDF must be reciprocal (asymmetry fails).",
              default="declared", choices=("declared", "reciprocal")),
    )

    def run(self, ctx, max_relative, weighted, weighted_interpolated, pairs, seed, measured_weighted, assume):
        try:
            return self._judge(ctx, max_relative, weighted, weighted_interpolated, pairs, seed, measured_weighted,
                               assume)
        except NotBlockable as exc:
            return self.skip(f"{exc} (raise the budget with --memory or BRDFTAB_MEMORY to compare them)")

    def _judge(self, ctx, max_relative, weighted, weighted_interpolated, pairs, seed, measured_weighted, assume):
        b = ctx.brdf
        if assume == "declared" and as_data(ctx):
            return self._data(ctx, measured_weighted, pairs, seed)
        out = self._run(ctx, max_relative, weighted, weighted_interpolated, pairs, seed)
        if assume == "declared" and not b.reciprocal and out.status == "fail":
            out.status = "warn"  # declared non-reciprocal: reported, never refused
        return out

    def _data(self, ctx, threshold, pairs, seed):
        """Measured or unknown data without a reciprocity declaration: luminance, measured range."""
        b = ctx.brdf
        top = measured_theta_max(b)
        why = "reciprocity not declared" if not getattr(b, "reciprocity_declared", False) else "declared non-reciprocal"
        lum = luminance_weights(ctx.labels() if ctx.wavelengths is None and not b.spectral else None,
                                None if ctx.wavelengths is None and not b.spectral else
                                (ctx.wavelengths if ctx.wavelengths is not None else b.wavelengths))
        mode = "nodes"
        nodes = None
        if ctx.on_grid and "reciprocity" not in getattr(b.grid, "phi_d_fold", "none"):
            nodes = node_pairs(ctx)
        elif ctx.on_grid:
            return self.outcome(True, 0.0, threshold, f"reciprocal by construction (phi_d_fold = "
                                f"'{b.grid.phi_d_fold}'); {why}, origin {ctx.origin}", mode="fold", weighted=0.0,
                                max_relative=0.0, rms_relative=0.0, origin=ctx.origin)
        if nodes is not None:
            def luminance(rows=nodes):
                for f1, f2, w, flat in rows():
                    yield f1 @ lum, f2 @ lum, w, flat
            n = None
        else:
            mode = "interpolated" if ctx.is_table else "pairs"
            wi, wo, w = sample_pairs(pairs, seed, pair_scales(b))
            keep = np.ones(wi.shape[0], bool)
            if top is not None:
                keep &= (wi[:, 2] >= np.cos(top) - 1e-12) & (wo[:, 2] >= np.cos(top) - 1e-12)
            if ctx.on_grid:
                keep &= covered(b, wi, wo) & covered(b, wo, wi)
            if not keep.any():
                return self.skip(f"no sampled pair lies inside the measured range together with its reverse ({why})")
            wi, wo, w = wi[keep], wo[keep], w[keep]
            n = (wi, wo)
        extra = {}
        if nodes is None and ctx.on_grid and not _scattered(b):
            # both directions interpolated the same way; judged against the resolution limit too
            s, extra = interpolated_asymmetry(ctx, wi, wo, w, lum)
        else:
            if nodes is None:
                s = asymmetry(ctx.eval(b, wi, wo) @ lum, ctx.eval(b, wo, wi) @ lum, w)
            else:
                s = asymmetry_blocks(luminance)
        worst = s.pop("worst")
        at = ""
        if worst is not None and n is not None:
            s["where"] = where_deg(n[0][worst], n[1][worst])
            at = f" at {fmt_pair(s['where'])}"
        upto = f"θ ≤ {np.degrees(top):.4g}° (the measured range)" if top is not None else "the whole hemisphere"
        limit = max(threshold, extra.get("resolution_limit", 0.0))
        ok = s["weighted"] <= limit
        reported = f"reported above {threshold:g}"
        if limit > threshold:
            reported = (f"reported above {limit:.3g}, this table's resolution limit: {RESOLUTION_MARGIN:g} × "
                        f"{extra['interpolation_asymmetry']:.3g}, the asymmetry its interpolation gives a reciprocal "
                        "table of the same content; asymmetry below it is not resolved by this table")
        out = self.outcome(True, s["weighted"], limit,
                           f"{why} ({ctx.origin} data): luminance- and albedo-weighted asymmetry {s['weighted']:.3g} "
                           f"over {upto} ({reported}), max relative {s['max_relative']:.3g}{at}, "
                           f"rms {s['rms_relative']:.3g}, {s['compared']} {'node ' if mode == 'nodes' else ''}pairs"
                           + (f" (both directions by {extra['interpolant']} interpolation)" if extra else ""),
                           mode=mode, origin=ctx.origin, theta_max_deg=None if top is None else float(np.degrees(top)),
                           luminance=True, weighted_threshold=threshold, **extra, **s)
        if not ok:
            out.status = "warn"
        return out

    def _run(self, ctx, max_relative, weighted, weighted_interpolated, pairs, seed):
        b = ctx.brdf
        declared = "" if b.reciprocal else " (declared non-reciprocal)"
        if ctx.on_grid:
            fold = getattr(b.grid, "phi_d_fold", "none")
            if "reciprocity" in fold:
                return self.outcome(True, 0.0, max_relative, f"reciprocal by construction (phi_d_fold = '{fold}')",
                                    mode="fold", max_relative=0.0, rms_relative=0.0, weighted=0.0)
            nodes = node_pairs(ctx)
            if nodes is not None:
                return self._nodes(ctx, nodes, max_relative, weighted, declared)
        return self._sampled(ctx, max_relative, weighted, weighted_interpolated, pairs, seed, declared)

    def _nodes(self, ctx, nodes, max_relative, weighted, declared):
        t = ctx.brdf
        c = t.shape[-1]
        s = asymmetry_blocks(nodes)
        ok = s["max_relative"] <= max_relative and s["weighted"] <= weighted
        at = ""
        if s["worst"] is not None:
            where = node_where(t, s["worst"] * c, ctx.labels())
            where.pop("channel", None)
            at = " at " + ", ".join(f"{k[:-4]} = {x:.4g}°" for k, x in where.items())
            s["where"] = where
        s.pop("worst")
        return self.outcome(ok, s["max_relative"], max_relative,
                            f"max relative asymmetry {s['max_relative']:.3g}{at}, rms {s['rms_relative']:.3g}, "
                            f"albedo-weighted {s['weighted']:.3g} over {s['compared']} node pairs "
                            f"(accepted: {max_relative:g} / {weighted:g}){declared}",
                            mode="nodes", weighted_threshold=weighted, **s)

    def _sampled(self, ctx, max_relative, weighted, weighted_interpolated, pairs, seed, declared):
        b = ctx.brdf
        scales = pair_scales(b if not ctx.is_table else (reference(ctx)[0] or b))
        wi, wo, w = ctx.memo(("pairs", pairs, seed, scales), lambda: sample_pairs(pairs, seed, scales))
        interp = ctx.is_table
        if ctx.on_grid:
            keep = covered(b, wi, wo) & covered(b, wo, wi)
            if not keep.any():
                return self._on_source(ctx, wi, wo, w, max_relative, weighted, declared)
            wi, wo, w = wi[keep], wo[keep], w[keep]
            if not _scattered(b):
                return self._interpolated(ctx, wi, wo, w, weighted_interpolated, declared)
            # scattered samples: both directions by the table's own (Delaunay) interpolation below
        f1 = ctx.eval(b, wi, wo)
        f2 = ctx.eval(b, wo, wi)
        s = asymmetry(f1, f2, w)
        worst = s.pop("worst")
        at = ""
        if worst is not None:
            s["where"] = where_deg(wi[worst], wo[worst])
            at = f" at {fmt_pair(s['where'])}"
        if interp:  # a table not on a brdftab grid: its own interpolation, errors included
            ok = s["weighted"] <= weighted_interpolated
            return self.outcome(ok, s["weighted"], weighted_interpolated,
                                f"albedo-weighted asymmetry {s['weighted']:.3g} (accepted {weighted_interpolated:g}), "
                                f"max relative {s['max_relative']:.3g}{at}, rms {s['rms_relative']:.3g}, "
                                f"by the table's interpolation at {s['compared']} random pairs (not on a brdftab grid:"
                                f" its interpolation error counts as asymmetry){declared}", mode="interpolated",
                                weighted_threshold=weighted_interpolated, **s)
        ok = s["max_relative"] <= max_relative and s["weighted"] <= weighted
        return self.outcome(ok, s["max_relative"], max_relative,
                            f"max relative asymmetry {s['max_relative']:.3g}{at}, rms {s['rms_relative']:.3g}, "
                            f"albedo-weighted {s['weighted']:.3g} over {s['compared']} random pairs "
                            f"(accepted: {max_relative:g} / {weighted:g}){declared}",
                            mode="pairs", weighted_threshold=weighted, **s)

    def _interpolated(self, ctx, wi, wo, w, threshold, declared):
        """A table on a grid without node pairs: both directions interpolated the same way, the
        figure judged against ``threshold`` or, when larger, the table's resolution limit."""
        s, extra = interpolated_asymmetry(ctx, wi, wo, w)
        worst = s.pop("worst")
        at = ""
        if worst is not None:
            s["where"] = where_deg(wi[worst], wo[worst])
            at = f" at {fmt_pair(s['where'])}"
        limit = extra["resolution_limit"]
        accepted = max(threshold, limit)
        ok = s["weighted"] <= accepted
        noise = extra["interpolation_asymmetry"]
        if limit <= threshold:
            judged = (f"(accepted {threshold:g}; the table's interpolation alone gives {noise:.2g} on a reciprocal "
                      "table of the same content)")
        else:
            judged = (f"(accepted {accepted:.3g}, this table's resolution limit: {RESOLUTION_MARGIN:g} × {noise:.3g}, "
                      "the asymmetry its interpolation gives a reciprocal table of the same content; asymmetry below "
                      f"it is not resolved by this table, {threshold:g} is accepted where it is)")
        return self.outcome(ok, s["weighted"], accepted,
                            f"albedo-weighted asymmetry {s['weighted']:.3g} {judged}, max relative "
                            f"{s['max_relative']:.3g}{at}, rms {s['rms_relative']:.3g}, both directions by "
                            f"{extra['interpolant']} interpolation at {s['compared']} random pairs{declared}",
                            mode="interpolated", weighted_threshold=threshold, resolved=limit <= threshold,
                            **extra, **s)

    def _on_source(self, ctx, wi, wo, w, max_relative, weighted, declared):
        """A table none of whose sampled pairs it covers together with their reverse: judge
        the model it was made from at the pairs the table covers one way."""
        t = ctx.brdf
        model, why = reference(ctx)
        if model is None:
            return self.skip(f"the table covers no direction pair together with its reverse, and {why}")
        keep = covered(t, wi, wo)
        if keep.sum() < 16:
            # the table covers a small region (a zoomed gonio grid of a few incidence slices):
            # compare at its own cell centres, equally weighted in its coordinates
            from .tabulation import cell_centres

            wi, wo = cell_centres(t.grid, w.size, 0)
            w = wi[:, 2] * wo[:, 2]
        else:
            wi, wo, w = wi[keep], wo[keep], w[keep]
        s = asymmetry(ctx.eval(model, wi, wo), ctx.eval(model, wo, wi), w)
        worst = s.pop("worst")
        at = ""
        if worst is not None:
            s["where"] = where_deg(wi[worst], wo[worst])
            at = f" at {fmt_pair(s['where'])}"
        ok = s["max_relative"] <= max_relative and s["weighted"] <= weighted
        return self.outcome(ok, s["max_relative"], max_relative,
                            f"the table covers no pair together with its reverse; its source {model.name}: max "
                            f"relative asymmetry {s['max_relative']:.3g}{at}, rms {s['rms_relative']:.3g}, "
                            f"albedo-weighted {s['weighted']:.3g} over {s['compared']} pairs the table covers "
                            f"(accepted: {max_relative:g} / {weighted:g}){declared}",
                            mode="source", weighted_threshold=weighted, **s)


def interpolated_asymmetry(ctx, wi, wo, w, project=None):
    """Asymmetry of a table on a brdftab grid at pairs ``(wi, wo)`` it covers both ways, with
    both directions interpolated the same way, and what its resolution can tell.

    Each direction is evaluated by the table's multilinear interpolation and by its
    curvature-corrected interpolation (:class:`~brdftab.checks._tables.CorrectedInterpolant`);
    the interpolant showing the smaller albedo-weighted asymmetry is reported (an asymmetry of
    the data shows in both; an interpolation error need not). The same is measured on a
    reciprocal table of the same content and resolution
    (:func:`~brdftab.checks._tables.reciprocal_surrogate`): that figure, times
    :data:`RESOLUTION_MARGIN`, is the table's resolution limit. ``project`` (a ``[C]`` vector,
    e.g. luminance weights) combines the channels first. Returns ``(statistics of
    asymmetry(), extra)``, ``extra`` holding ``interpolant``, ``weighted_multilinear``,
    ``weighted_corrected``, ``interpolation_asymmetry`` and ``resolution_limit``.
    """
    t = ctx.brdf
    if over_budget(t):
        raise NotBlockable("comparing interpolated pairs needs the whole table, which is over the memory budget")
    interp = ctx.memo("corrected_interpolant", lambda: CorrectedInterpolant(t))
    surrogate = ctx.memo("reciprocal_surrogate", lambda: reciprocal_surrogate(interp))

    def both(fn):
        l1, c1 = fn(wi, wo)
        l2, c2 = fn(wo, wi)
        l1, c1, l2, c2 = (_channels(ctx, x, project) for x in (l1, c1, l2, c2))
        return asymmetry(l1, l2, w), asymmetry(c1, c2, w)

    lin, cor = both(interp)
    _, gcor = both(surrogate)
    s, name = (cor, "curvature-corrected") if cor["weighted"] <= lin["weighted"] else (lin, "multilinear")
    noise = gcor["weighted"]
    return s, {"interpolant": name, "weighted_multilinear": lin["weighted"], "weighted_corrected": cor["weighted"],
               "interpolation_asymmetry": noise, "resolution_limit": RESOLUTION_MARGIN * noise}


def _channels(ctx, out, project=None):
    """Stored channels of a table as ``ctx`` evaluates them (its wavelengths), optionally
    combined by ``project``."""
    t = ctx.brdf
    if ctx.wavelengths is not None and t.spectral:
        from ..table import _interp_last

        stored = np.asarray(t.wavelengths, float)
        if not (stored.shape == ctx.wavelengths.shape and np.array_equal(stored, ctx.wavelengths)):
            out = _interp_last(out, stored, ctx.wavelengths)
    return out if project is None else out @ project


def pair_scales(brdf) -> tuple:
    """Widths of the pair sampler's mirror components: the default ones, plus the BRDF's
    declared lobe width when it is narrower than all of them (so a 2e-4-wide peak is visited)."""
    width = getattr(brdf, "lobe_width", None)
    if callable(width) or width is None or not np.isfinite(width) or width >= min(SCALES):
        return SCALES
    return (float(width),) + tuple(SCALES)
