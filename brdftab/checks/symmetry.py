"""Symmetries: isotropy (rotation about the normal) and bilateral symmetry (φd ↔ −φd).

``isotropy``
    A BRDF declared isotropic must not change when both directions are rotated about the
    normal: models are compared on random pairs rotated by random angles; an anisotropic
    Rusinkiewicz table must not vary along φh; a gonio table with several φi nodes is compared
    with its first φi node rotated (node pairs only). An isotropic Rusinkiewicz table, or a
    gonio table with one φi node, is isotropic by construction. A BRDF declared anisotropic is
    measured and reported, never failed.
``bilateral``
    An isotropic BRDF is usually also mirror-symmetric about the plane of the normal and the
    half vector: f(θh, θd, φd) = f(θh, θd, −φd). Models are compared on random pairs; tables on
    node pairs (φd ↔ 2π − φd, or π − φd under the reciprocity fold; φo ↔ 2φi − φo on gonio
    grids). A bilateral fold is symmetric by construction. WARN by default: measured
    materials with oriented structure may break it legitimately.
"""

from __future__ import annotations

import numpy as np

from ..geometry import hd_to_io, io_to_hd, rot_z
from ..params import Param
from . import Check, register
from ._pairs import asymmetry, asymmetry_blocks, fmt_pair, sample_pairs, where_deg
from ._tables import (NotBlockable, data_blocks, flat_rows, gonio_node_weights, match_axis, node_where, phi_d_pairs,
                      rusinkiewicz_node_weights)

__all__ = ["Isotropy", "Bilateral"]


def _thresholds(max_rel, weighted):
    return (
        Param("max_relative", "float", "Largest accepted relative difference of a pair and its transformed twin.",
              default=max_rel, minimum=0.0),
        Param("weighted", "float", "Largest accepted albedo-weighted relative difference.", default=weighted,
              minimum=0.0),
        Param("pairs", "int", "Random direction pairs (models).", default=16384, minimum=16, maximum=10_000_000),
        Param("seed", "int", "Seed of the random direction pairs.", default=0, minimum=0),
    )


def _rows(ctx, pairs, weights):
    """Rows of node pairs, block by block (:func:`~brdftab.checks._tables.data_blocks`):
    ``pairs(v)`` gives the partner of each sample of a block ``v`` (a slab of the first axis),
    ``weights(grid, key=key)`` the node weights of a block."""
    grid = ctx.brdf.grid

    def rows():
        for key, v in data_blocks(ctx):
            c = v.shape[-1]
            w = np.broadcast_to(weights(grid, key=key), v.shape[:-1])
            yield v.reshape(-1, c), np.asarray(pairs(v)).reshape(-1, c), w.reshape(-1), flat_rows(grid, key)
    return rows


class _Pairwise(Check):
    """Shared reporting of a pair comparison."""

    what = ""

    def _report(self, ctx, s, max_relative, weighted, how, where_text, passed=None, **extra):
        ok = s["max_relative"] <= max_relative and s["weighted"] <= weighted if passed is None else passed
        return self.outcome(ok, s["max_relative"], max_relative,
                            f"max relative {self.what} {s['max_relative']:.3g}{where_text}, rms "
                            f"{s['rms_relative']:.3g}, albedo-weighted {s['weighted']:.3g} over {s['compared']} {how} "
                            f"(accepted: {max_relative:g} / {weighted:g})", weighted_threshold=weighted, **extra, **s)

    def _sampled(self, ctx, transform, max_relative, weighted, pairs, seed, passed=None, note=""):
        wi, wo, w = ctx.memo(("pairs", pairs, seed), lambda: sample_pairs(pairs, seed))
        wi2, wo2, keep = transform(wi, wo, np.random.default_rng(seed + 1))
        f1 = ctx.eval(ctx.brdf, wi[keep], wo[keep])
        f2 = ctx.eval(ctx.brdf, wi2[keep], wo2[keep])
        s = asymmetry(f1, f2, w[keep])
        if not s["compared"]:  # every pair outside the table's domain or missing: nothing was measured
            return self.skip(f"no random pair has data on both sides: the {self.what} cannot be measured", compared=0)
        worst = s.pop("worst")
        at = ""
        if worst is not None:
            s["where"] = where_deg(wi[keep][worst], wo[keep][worst])
            at = f" at {fmt_pair(s['where'])}"
        if ctx.is_table and passed is None:
            # a table evaluated off its nodes: interpolation differs between the twins, so only
            # the albedo-weighted figure is judged
            passed = s["weighted"] <= weighted
            note += " (interpolated: the albedo-weighted figure is judged)"
        out = self._report(ctx, s, max_relative, weighted, "random pairs", at, passed=passed,
                           mode="interpolated" if ctx.is_table else "pairs")
        out.detail += note
        return out

    def _nodes(self, ctx, rows, max_relative, weighted, passed=None, note=""):
        """Judge node pairs given block by block (``rows()``, see :func:`_rows`)."""
        c = ctx.brdf.shape[-1]
        try:
            s = asymmetry_blocks(rows)
        except NotBlockable as exc:
            return self.skip(f"{exc} (raise the budget with --memory or BRDFTAB_MEMORY to compare them)")
        if not s["compared"]:  # every pair has a missing or non-finite side: nothing was measured
            return self.skip(f"no node pair has data on both sides (of {s['excluded']}): the {self.what} cannot be "
                             "measured", compared=0)
        worst = s.pop("worst")
        at = ""
        if worst is not None:
            where = node_where(ctx.brdf, worst * c, ctx.labels())
            where.pop("channel", None)
            s["where"] = where
            at = " at " + ", ".join(f"{k[:-4]} = {x:.4g}°" for k, x in where.items())
        out = self._report(ctx, s, max_relative, weighted, "node pairs", at, passed=passed, mode="nodes")
        out.detail += note
        return out


@register
class Isotropy(_Pairwise):
    name = "isotropy"
    family = "symmetry"
    summary = "A BRDF declared isotropic does not change under rotation about the normal."
    what = "anisotropy"
    thresholds = _thresholds(1e-6, 1e-3)

    def run(self, ctx, max_relative, weighted, pairs, seed):
        b = ctx.brdf
        declared = b.isotropic
        passed = None if declared else True
        note = "" if declared else " (declared anisotropic: reported, not judged)"
        if ctx.on_grid and b.grid.node_checks:
            grid = b.grid
            if grid.parameterization == "rusinkiewicz":
                if "phi_h" not in grid.dims:
                    return self.outcome(True, 0.0, max_relative, "isotropic by construction (no phi_h axis)",
                                        mode="construction")
                k = grid.dims.index("phi_h")
                mean = lambda v: np.broadcast_to(np.nanmean(v, axis=k, keepdims=True), v.shape)  # noqa: E731
                return self._nodes(ctx, _rows(ctx, mean, rusinkiewicz_node_weights), max_relative, weighted,
                                   passed, note)
            a_ti, a_pi, a_to, a_po = grid.axes
            if grid.phi_d_fold == "bilateral":
                return self.outcome(True, 0.0, max_relative, "isotropic by construction (the table holds "
                                    "|phi_o - phi_i| only: phi_d_fold = 'bilateral')", mode="construction")
            if len(a_pi) == 1:
                # nothing to compare: a check that measures nothing is skipped, not passed
                return self.skip("one φi node: isotropy cannot be measured (the table is rotated about the normal "
                                 "for other φi)" if declared else "one φi node: isotropy cannot be measured")
            if grid.relative_to == "specular":
                # (θi, φi_b, Δθ, Δφ) rotates onto (θi, φi_0, Δθ, Δφ): compare with the first φi node
                def partner(v):
                    return np.broadcast_to(v[:, :1], v.shape)
            else:
                shift = a_pi.values - a_pi.values[0]
                jd = match_axis(a_po, (a_po.values[None, :] - shift[:, None]).ravel()).reshape(len(a_pi), len(a_po))
                valid = jd >= 0
                if not valid[1:].any():
                    return self.skip("no gonio nodes are related by a rotation about the normal")

                def partner(v):
                    p = v[:, np.zeros_like(jd), :, np.where(valid, jd, 0)]
                    # advanced indexing moved the broadcast (φi, φo) axes first: put them back
                    p = np.moveaxis(p, (0, 1), (1, 3))
                    return np.where(valid[None, :, None, :, None], p, np.nan)
            return self._nodes(ctx, _rows(ctx, partner, gonio_node_weights), max_relative, weighted, passed,
                               note)

        def rotate(wi, wo, rng):
            psi = rng.uniform(0.0, 2 * np.pi, wi.shape[0])
            return rot_z(wi, psi), rot_z(wo, psi), np.ones(wi.shape[0], bool)

        return self._sampled(ctx, rotate, max_relative, weighted, pairs, seed, passed, note)


@register
class Bilateral(_Pairwise):
    name = "bilateral"
    family = "symmetry"
    summary = "Mirror symmetry f(θh, θd, φd) = f(θh, θd, −φd) of an isotropic BRDF."
    level = "warn"
    what = "asymmetry"
    thresholds = _thresholds(1e-6, 1e-3)

    def applies(self, ctx):
        return None if ctx.brdf.isotropic else "anisotropic BRDF (bilateral symmetry is not expected)"

    def run(self, ctx, max_relative, weighted, pairs, seed):
        b = ctx.brdf
        if ctx.on_grid and getattr(b.grid, "scattered", False) and b.grid.phi_d_fold == "bilateral":
            return self.outcome(True, 0.0, max_relative, "symmetric by construction (scattered samples of one side of "
                                "the plane of incidence, mirrored: phi_d_fold = 'bilateral')", mode="construction")
        if ctx.on_grid and b.grid.node_checks:
            grid = b.grid
            if grid.parameterization == "rusinkiewicz":
                fold = grid.phi_d_fold
                if "bilateral" in fold:
                    return self.outcome(True, 0.0, max_relative, f"symmetric by construction (phi_d_fold = '{fold}')",
                                        mode="construction")
                ax = grid.axes[grid.dims.index("phi_d")]
                target = -ax.values if fold == "none" else np.pi - ax.values
                j = match_axis(ax, target)
                if np.any(j < 0):
                    return self.skip("the φd nodes have no mirror partners (−φd)")
                def rows():
                    for key, v in data_blocks(ctx):
                        yield phi_d_pairs(grid, v, j, key)
                return self._nodes(ctx, rows, max_relative, weighted)
            if grid.phi_d_fold == "bilateral":
                return self.outcome(True, 0.0, max_relative, "symmetric by construction (phi_d_fold = 'bilateral')",
                                    mode="construction")
            a_ti, a_pi, a_to, a_po = grid.axes
            if grid.relative_to == "specular":
                j = np.broadcast_to(match_axis(a_po, -a_po.values)[None, :], (len(a_pi), len(a_po)))
            else:
                target = 2 * a_pi.values[:, None] - a_po.values[None, :]
                j = match_axis(a_po, target.ravel()).reshape(len(a_pi), len(a_po))
            valid = j >= 0
            if not valid.any():
                return self.skip("no gonio nodes are mirror images about the plane of incidence")
            ib = np.broadcast_to(np.arange(len(a_pi))[:, None], j.shape)

            def partner(v):
                p = v[:, ib, :, np.where(valid, j, 0)]
                p = np.moveaxis(p, (0, 1), (1, 3))
                return np.where(valid[None, :, None, :, None], p, np.nan)
            return self._nodes(ctx, _rows(ctx, partner, gonio_node_weights), max_relative, weighted)

        def mirror(wi, wo, rng):
            th, ph, td, pd = io_to_hd(wi, wo)
            wi2, wo2 = hd_to_io(th, ph, td, -pd)
            keep = (wi2[:, 2] > 1e-9) & (wo2[:, 2] > 1e-9)
            return wi2, wo2, keep

        return self._sampled(ctx, mirror, max_relative, weighted, pairs, seed)
