"""Mueller-matrix checks on polarized BRDFs (models with ``eval_mueller``, polarized tables).

A table is judged at its stored nodes above the horizon (what is written, as stored; missing
samples left out); a model at random direction pairs (:func:`~brdftab.checks._pairs.sample_pairs`).
Figures are relative to M00 of the same sample. Unpolarized BRDFs SKIP these checks.

``mueller_realizability``
    physical realizability: the eigenvalues of Cloude's coherency matrix
    H = ¼ Σ M_ij σ_i ⊗ σ_j* (σ the Pauli matrices in Stokes order; trace H = M00) are
    ≥ −tolerance·M00. A sum of non-depolarizing (Jones) scatterers has H ≥ 0; a negative
    eigenvalue is a matrix no physical surface has. The figure is the smallest λ/M00 with its
    place. (Unchanged by the sign convention of S3: flipping it conjugates H.)
``mueller_bounds``
    M00 ≥ 0 and |M_ij| ≤ M00 (within ``tolerance``·M00).
``polarized_reciprocity``
    for a BRDF declared reciprocal, M(wi → wo) = Q·M(wo → wi)ᵀ·Q with Q = diag(1, 1, −1, 1),
    both in brdftab's ``mitsuba`` basis (the swapped pair's x reference is −x, a half turn that
    changes no Stokes vector). Rusinkiewicz tables compare node pairs (φd ↔ φd + π); other
    tables interpolated pairs, whose excess is a WARN (interpolation differs between the twins).
``depolarization``
    the depolarization index DI = sqrt(Σ M_ij² − M00²) / (√3 M00), 0 for an ideal depolarizer
    and 1 for a non-depolarizing (Jones) matrix, never above 1 for a physical one: reports its
    range and fails above 1 + tolerance.
``mueller_albedo``
    the directional albedo of M00 (from the Mueller matrix, not from ``eval``) ≤ 1 + tolerance
    on a sweep of θi, and ``eval`` equal to M00 (the protocol's promise) at the sampled pairs.

Measured data (origin measured or unknown) is judged as data: an unphysical figure is a WARN
with its place, not a refusal.
"""

from __future__ import annotations

import numpy as np

from ..params import Param
from ..polarization import coherency_eigenvalues, depolarization_index, reciprocity_transform
from . import Check, register
from ._pairs import fmt_pair, sample_pairs, where_deg

__all__ = ["MuellerRealizability", "MuellerBounds", "PolarizedReciprocity", "Depolarization", "MuellerAlbedo",
           "coherency_eigenvalues", "depolarization_index", "reciprocity_transform"]

def _polarized(ctx):
    from ..mueller_table import is_polarized

    return is_polarized(ctx.brdf)


def _samples(ctx, pairs, seed):
    """``(M[k, C, 4, 4], where(k) -> dict, mode)``: a table's stored nodes above the horizon with
    data (``mode`` "nodes"), else a model's random pairs."""
    def compute():
        b = ctx.brdf
        if ctx.on_grid and getattr(b, "polarized", False):
            from ..mueller_table import mueller_values

            m = mueller_values(b)
            grid = b.grid
            ok = np.broadcast_to(grid.node_above_horizon(), grid.shape)
            ok = ok & np.isfinite(m[..., 0, 0]).all(axis=-1)
            flat = np.flatnonzero(ok)
            sel = m.reshape((-1,) + m.shape[-3:])[flat]

            def where(k):
                idx = np.unravel_index(int(flat[k]), grid.shape)
                return {f"{ax.name}_deg": round(float(np.degrees(ax.values[i])), 6) for ax, i in zip(grid.axes, idx)}
            return sel, where, "nodes"
        wi, wo, _ = sample_pairs(pairs, seed)
        sel = np.asarray(b.eval_mueller(wi, wo, ctx.wavelengths), float)
        return sel, (lambda k: where_deg(wi[k], wo[k])), "pairs"
    return ctx.memo(("mueller-samples", pairs, seed), compute)


def _place(where, labels, k, c) -> tuple:
    w = dict(where(k))
    w["channel"] = labels[c] if c < len(labels) else c
    text = (fmt_pair(w) if "theta_o_deg" in w else
            ", ".join(f"{n[:-4]} = {v:.4g}°" for n, v in w.items() if n.endswith("_deg")))
    return w, f"{text}, channel {w['channel']}"


_COMMON = (
    Param("pairs", "int", "Random direction pairs (models).", default=4096, minimum=16, maximum=10_000_000),
    Param("seed", "int", "Seed of the random direction pairs.", default=0, minimum=0),
)


class _MuellerCheck(Check):
    family = "mueller"

    def applies(self, ctx):
        if not _polarized(ctx):
            return "not polarized (no Mueller matrix)"
        return None

    def _judge(self, ctx, ok, figure, threshold, detail, **data):
        out = self.outcome(ok, figure, threshold, detail, **data)
        if not ok and ctx.measured:
            out.status = "warn"
            out.detail += " (measured data: reported, not refused)"
        return out


@register
class MuellerRealizability(_MuellerCheck):
    name = "mueller_realizability"
    summary = "Cloude coherency-matrix eigenvalues of the Mueller matrix are >= -tolerance * M00."
    thresholds = (Param("tolerance", "float", "Largest accepted negative eigenvalue, relative to M00.", default=1e-6,
                        minimum=0.0),) + _COMMON

    def run(self, ctx, tolerance, pairs, seed):
        m, where, mode = _samples(ctx, pairs, seed)
        m00 = m[..., 0, 0]
        lam = coherency_eigenvalues(m)[..., 0]
        with np.errstate(invalid="ignore", divide="ignore"):
            rel = np.where(m00 > 0, lam / np.where(m00 > 0, m00, 1.0), np.where(lam < 0, -np.inf, 0.0))
        if rel.size == 0:
            return self.skip("no sample above the horizon holds data")
        k, c = np.unravel_index(int(np.nanargmin(rel)), rel.shape)
        fig = float(rel[k, c])
        bad = int(np.count_nonzero(rel < -tolerance))
        place, text = _place(where, ctx.labels(), k, c)
        return self._judge(ctx, fig >= -tolerance, fig, -tolerance,
                           f"smallest coherency eigenvalue / M00 = {fig:.3g} at {text}; {bad} of {rel.size} "
                           f"{'node samples' if mode == 'nodes' else 'sampled pairs'} below -{tolerance:g}",
                           where=place, negative=bad, compared=int(rel.size), mode=mode)


@register
class MuellerBounds(_MuellerCheck):
    name = "mueller_bounds"
    summary = "M00 >= 0 and |Mij| <= M00."
    thresholds = (Param("tolerance", "float", "Accepted excess of |Mij| over M00, relative to M00.", default=1e-6,
                        minimum=0.0),) + _COMMON

    def run(self, ctx, tolerance, pairs, seed):
        m, where, mode = _samples(ctx, pairs, seed)
        if m.size == 0:
            return self.skip("no sample above the horizon holds data")
        m00 = m[..., 0, 0]
        scale = np.maximum(np.abs(m00), np.finfo(float).tiny)
        excess = (np.abs(m).max(axis=(-2, -1)) - m00) / scale
        excess = np.where(m00 < 0, np.maximum(excess, -m00 / scale), excess)
        k, c = np.unravel_index(int(np.argmax(excess)), excess.shape)
        fig = float(excess[k, c])
        negative = int(np.count_nonzero(m00 < 0))
        place, text = _place(where, ctx.labels(), k, c)
        return self._judge(ctx, fig <= tolerance and negative == 0, fig, tolerance,
                           f"largest (max|Mij| - M00) / M00 = {fig:.3g} at {text}; {negative} samples with M00 < 0",
                           where=place, negative_m00=negative, compared=int(excess.size), mode=mode)


@register
class Depolarization(_MuellerCheck):
    name = "depolarization"
    summary = "Depolarization index DI in [0, 1] (reported; above 1 + tolerance fails)."
    thresholds = (Param("tolerance", "float", "Accepted excess of DI over 1.", default=1e-6, minimum=0.0),) + _COMMON

    def run(self, ctx, tolerance, pairs, seed):
        m, where, mode = _samples(ctx, pairs, seed)
        di = depolarization_index(m)
        good = np.isfinite(di)
        if not good.any():
            return self.skip("no sample with M00 > 0")
        k, c = np.unravel_index(int(np.nanargmax(np.where(good, di, -np.inf))), di.shape)
        fig = float(di[k, c])
        place, text = _place(where, ctx.labels(), k, c)
        lo, med = float(np.min(di[good])), float(np.median(di[good]))
        return self._judge(ctx, fig <= 1.0 + tolerance, fig, 1.0 + tolerance,
                           f"depolarization index from {lo:.3g} to {fig:.3g} (median {med:.3g}); largest at {text}",
                           where=place, minimum=lo, median=med, compared=int(good.sum()), mode=mode)


@register
class PolarizedReciprocity(_MuellerCheck):
    name = "polarized_reciprocity"
    summary = "M(wi -> wo) = Q M(wo -> wi)^T Q, Q = diag(1, 1, -1, 1), for a BRDF declared reciprocal."
    thresholds = (Param("max_relative", "float", "Largest accepted |difference| relative to M00.", default=1e-6,
                        minimum=0.0),) + _COMMON

    def applies(self, ctx):
        why = super().applies(ctx)
        if why is None and not getattr(ctx.brdf, "reciprocal", False):
            return "not declared reciprocal"
        return why

    def run(self, ctx, max_relative, pairs, seed):
        b = ctx.brdf
        if ctx.on_grid and getattr(b.grid, "parameterization", "") == "rusinkiewicz":
            return self._nodes(ctx, max_relative)
        wi, wo, _ = ctx.memo(("pairs", pairs, seed), lambda: sample_pairs(pairs, seed))
        a = np.asarray(b.eval_mueller(wi, wo, ctx.wavelengths), float)
        r = reciprocity_transform(np.asarray(b.eval_mueller(wo, wi, ctx.wavelengths), float))
        out = self._report(ctx, a, r, lambda k: where_deg(wi[k], wo[k]), max_relative,
                           "interpolated pairs" if ctx.is_table else "random pairs")
        if ctx.is_table and out.status == "fail":
            # a table off its nodes: the twins are interpolated between different nodes
            out.status = "warn"
            out.detail += " (a table off its nodes: interpolation differs between the twins; reported, not judged)"
        return out

    def _nodes(self, ctx, max_relative):
        from ..mueller_table import mueller_values
        from ._tables import match_axis

        b = ctx.brdf
        grid = b.grid
        th, td, pd = grid.axes
        partner = match_axis(pd, np.mod(pd.values + np.pi, 2 * np.pi))
        have = partner >= 0
        if not have.any():
            return self.skip("no φd node has its reciprocal partner (φd + 180°) among the nodes")
        m = mueller_values(b)
        ok = np.broadcast_to(grid.node_above_horizon(), grid.shape)[..., have]
        a = m[:, :, have][ok]
        r = reciprocity_transform(m[:, :, partner[have]][ok])
        flat = np.flatnonzero(ok)
        sub = (len(th.values), len(td.values), int(have.sum()))
        phi_idx = np.flatnonzero(have)

        def where(k):
            i, j, p = np.unravel_index(int(flat[k]), sub)
            return {"theta_h_deg": round(float(np.degrees(th.values[i])), 6),
                    "theta_d_deg": round(float(np.degrees(td.values[j])), 6),
                    "phi_d_deg": round(float(np.degrees(pd.values[phi_idx[p]])), 6)}
        return self._report(ctx, a, r, where, max_relative, "node pairs (phi_d and phi_d + 180°)")

    def _report(self, ctx, a, r, where, max_relative, how):
        scale = np.maximum(np.maximum(np.abs(a[..., 0, 0]), np.abs(r[..., 0, 0])), np.finfo(float).tiny)
        diff = np.abs(a - r).max(axis=(-2, -1)) / scale
        diff = np.where(np.isfinite(diff), diff, 0.0)
        if diff.size == 0:
            return self.skip("no pair above the horizon holds data")
        k, c = np.unravel_index(int(np.argmax(diff)), diff.shape)
        fig = float(diff[k, c])
        place, text = _place(where, ctx.labels(), k, c)
        return self._judge(ctx, fig <= max_relative, fig, max_relative,
                           f"max |M - Q M'^T Q| / M00 = {fig:.3g} at {text} over {diff.size} {how}",
                           where=place, compared=int(diff.size))


@register
class MuellerAlbedo(_MuellerCheck):
    name = "mueller_albedo"
    summary = ("eval equals M00 (whose directional albedo the energy check then judges); where it does not, "
               "the albedo of M00 <= 1 + tolerance too.")
    thresholds = (
        Param("tolerance", "float", "Accepted albedo excess over 1.", default=0.01, minimum=0.0),
        Param("eval_tolerance", "float", "Largest accepted |eval - M00| relative to M00.", default=1e-9, minimum=0.0),
        Param("n_theta_i", "int", "Incidence angles from 0 to 85 degrees.", default=10, minimum=1, maximum=1000),
    ) + _COMMON

    def run(self, ctx, tolerance, eval_tolerance, n_theta_i, pairs, seed):
        from ..brdf import BRDF
        from ..integrate import directional_albedo

        src = ctx.brdf

        class M00(BRDF):
            name = f"M00 of {src.name}"
            layout = src.layout
            isotropic = src.isotropic
            reciprocal = src.reciprocal
            lobe_width = getattr(src, "lobe_width", None)
            lobe_axes = getattr(src, "lobe_axes", None)

            def _eval(self, wi, wo, lam, n):
                return np.asarray(src.eval_mueller(wi, wo, lam), float)[..., 0, 0]

        theta = np.radians(np.linspace(0.0, 85.0, n_theta_i))
        a = directional_albedo(M00(), theta, 0.0, ctx.wavelengths)
        i, c = np.unravel_index(int(np.nanargmax(a)), a.shape)
        top = float(a[i, c])
        wi, wo, _ = ctx.memo(("pairs", pairs, seed), lambda: sample_pairs(pairs, seed))
        f = np.asarray(src.eval(wi, wo, ctx.wavelengths), float)
        m00 = np.asarray(src.eval_mueller(wi, wo, ctx.wavelengths), float)[..., 0, 0]
        gap = np.abs(f - m00) / np.maximum(np.abs(m00), np.finfo(float).tiny)
        gap = np.where(np.isfinite(gap), gap, 0.0)
        g = float(gap.max()) if gap.size else 0.0
        label = ctx.labels()[c] if c < len(ctx.labels()) else c
        where = f"max albedo of M00 = {top:.4g} at θi = {np.degrees(theta[i]):.3g}°, channel {label}"
        if g <= eval_tolerance:
            # M00 is eval: its albedo is the one the energy check judges (one verdict, not two)
            return self._judge(ctx, True, g, eval_tolerance,
                               f"max |eval - M00| / M00 = {g:.3g} (accepted ≤ {eval_tolerance:g}): M00 is f_r, "
                               f"its albedo judged by the energy check ({where})",
                               theta_i_deg=np.degrees(theta), values=a, eval_gap=g)
        ok = top <= 1.0 + tolerance
        return self._judge(ctx, False, top if not ok else g, 1.0 + tolerance if not ok else eval_tolerance,
                           f"{where} (accepted ≤ {1 + tolerance:g}); max |eval - M00| / M00 = {g:.3g} (accepted ≤ "
                           f"{eval_tolerance:g}): eval is not M00", theta_i_deg=np.degrees(theta), values=a, eval_gap=g)
