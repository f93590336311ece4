"""Direction pairs and asymmetry statistics shared by the checks.

:func:`sample_pairs` draws (wi, wo) pairs for checks on models (and on tables where no node
pairs exist): wi cosine-weighted, wo from an equal mixture of a cosine-weighted direction and
mirror reflections of wi about GGX-distributed normals of widths 0.003, 0.03 and 0.3 (so
narrow specular lobes are visited as well as the diffuse background). Each pair carries the
importance weight cosθi cosθo / p(wi, wo), so Σ w g / N estimates ∫∫ g cosθi cosθo dωi dωo
(multiple importance sampling, balance heuristic: E. Veach, PhD thesis, Stanford (1997),
§9.2).

:func:`asymmetry` compares two evaluations of the same pairs (f and its reflected, swapped or
rotated twin): the largest and rms relative difference, and the *albedo-weighted* difference
∫∫ |f − f'| cos cos / ∫∫ ½(f + f') cos cos — the fraction of the reflected energy that differs.
"""

from __future__ import annotations

import math

import numpy as np

from .._jit import kernel
from ..geometry import vec_to_sph
from ..models.distributions import d_ggx

__all__ = ["sample_pairs", "asymmetry", "where_deg", "SCALES"]

#: GGX widths of the mirror components of the pair sampler.
SCALES = (0.003, 0.03, 0.3)
_Z = 1e-9


def _cosine(rng, n):
    u1, u2 = rng.random(n), rng.random(n)
    r = np.sqrt(u1)
    phi = 2 * np.pi * u2
    return np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(np.maximum(1.0 - u1, 0.0))], axis=-1)


def _ggx_normals(rng, n, alpha):
    u1, u2 = rng.random(n), rng.random(n)
    t = alpha * np.sqrt(u1 / np.maximum(1.0 - u1, 1e-300))
    c = 1.0 / np.sqrt(1.0 + t * t)
    s = t * c
    phi = 2 * np.pi * u2
    return np.stack([s * np.cos(phi), s * np.sin(phi), c], axis=-1)


def mixture_pdf(wi, wo, scales=SCALES):
    """Density [1/sr] of wo given wi under the sampler's mixture."""
    h = wi + wo
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    cos_oh = np.einsum("...i,...i->...", wo, h)
    p = np.maximum(wo[..., 2], 0.0) / np.pi
    for s in scales:
        p = p + d_ggx(h, s) * h[..., 2] / (4.0 * np.maximum(cos_oh, 1e-300))
    return p / (1 + len(scales))


def sample_pairs(n: int, seed: int = 0, scales=SCALES):
    """About ``n`` pairs ``(wi, wo, weight)`` above the horizon (see the module docstring)."""
    rng = np.random.default_rng(seed)
    wi = _cosine(rng, n)
    comp = rng.integers(0, 1 + len(scales), n)
    wo = _cosine(rng, n)
    for k, s in enumerate(scales, start=1):
        sel = comp == k
        h = _ggx_normals(rng, int(sel.sum()), s)
        v = wi[sel]
        wo[sel] = 2.0 * np.einsum("ij,ij->i", v, h)[:, None] * h - v
    keep = (wi[:, 2] > _Z) & (wo[:, 2] > _Z)
    wi, wo = wi[keep], wo[keep]
    weight = np.pi * wo[:, 2] / mixture_pdf(wi, wo, scales)
    return wi, wo, weight


#: Rows summed together by one compiled pass: the statistics are sums of per-block sums in block
#: order, the same figures whatever the number of threads (a serial run and a worker process agree).
BLOCK = 1 << 15


def asymmetry(f1, f2, weight=None, floor: float = 1e-9) -> dict:
    """Statistics of ``|f1 − f2|`` relative to their mean, over pairs ``[N, C]``.

    Pairs where either value is not finite are left out (counted in ``excluded``); relative
    differences use pairs whose mean exceeds ``floor`` × the largest mean. Returns
    ``max_relative``, ``rms_relative``, ``weighted`` (albedo-weighted, needs ``weight``),
    ``worst`` (row of the pair with the largest relative difference, or None), ``compared``.
    Two compiled passes over the pairs, on every core (values read as stored and taken in
    float64; the first largest difference is the worst).
    """
    return asymmetry_blocks(lambda: iter([(f1, f2, weight, None)]), floor, weighted=weight is not None)


def asymmetry_blocks(rows, floor: float = 1e-9, weighted: bool = True) -> dict:
    """:func:`asymmetry` over pairs given in blocks, for pairs that do not fit in memory at once
    (a table read block by block): ``rows()`` returns an iterator of ``(f1, f2, weight, locate)``
    blocks and is called twice (the largest mean first, then the statistics). ``worst`` is
    ``locate(row in its block)`` (the row counted over all blocks when ``locate`` is None)."""
    from .._jit import parallel_rows

    def prepared():
        for f1, f2, w, locate in rows():
            f1, f2 = np.asarray(f1), np.asarray(f2)
            if f1.dtype.kind != "f" or f2.dtype.kind != "f":
                f1, f2 = f1.astype(float), f2.astype(float)
            if f1.ndim == 1:
                f1, f2 = f1[:, None], f2[:, None]
            f1, f2 = np.ascontiguousarray(f1), np.ascontiguousarray(f2)
            if f1.dtype != f2.dtype:
                f1, f2 = f1.astype(float), f2.astype(float)
            yield f1, f2, (np.zeros(0) if w is None else np.ascontiguousarray(w, float)), locate

    top, excluded, n = 0.0, 0, 0
    for f1, f2, _, _ in prepared():
        parts = parallel_rows(lambda lo, hi: _top_pass(f1[lo:hi], f2[lo:hi]), f1.shape[0])
        top = max([top] + [p[0] for p in parts])
        excluded += sum(int(p[1]) for p in parts)
        n += f1.shape[0]
    thresh = max(floor * top, np.finfo(float).tiny)
    n_sig, sumsq, best, worst, num, den, offset = 0, 0.0, 0.0, None, None, None, 0
    for f1, f2, w, locate in prepared():
        nc = f1.shape[1]

        n_rows = f1.shape[0]

        def stats(b0, b1):  # blocks [b0, b1): the same partial sums on any number of threads
            out = []
            for lo in range(b0 * BLOCK, min(b1 * BLOCK, n_rows), BLOCK):
                hi = min(lo + BLOCK, n_rows)
                a, b = np.zeros(nc), np.zeros(nc)
                r = _stats_pass(f1[lo:hi], f2[lo:hi], thresh, w[lo:hi] if w.size else w, a, b)
                out.append(r + (a, b, lo))
            return out

        parts = [p for chunk in parallel_rows(stats, -(-n_rows // BLOCK), min_rows=2) for p in chunk]
        n_sig += sum(int(p[0]) for p in parts)
        sumsq += sum(p[3] for p in parts)
        for p in parts:  # ranges in order: the first largest stays
            if p[1] > best:
                best = float(p[1])
                row = int(p[6] + p[2])
                worst = locate(row) if locate is not None else offset + row
        num = sum((p[4] for p in parts), np.zeros(nc) if num is None else num)
        den = sum((p[5] for p in parts), np.zeros(nc) if den is None else den)
        offset += n_rows
    out = {"compared": n - excluded, "excluded": excluded, "max_relative": 0.0, "rms_relative": 0.0,
           "worst": None, "weighted": None}
    if n_sig:
        out["max_relative"] = best
        out["worst"] = worst
        out["rms_relative"] = float(np.sqrt(sumsq / n_sig))
    if weighted:
        num = np.zeros(1) if num is None else num
        den = np.zeros(1) if den is None else den
        ratio = np.divide(num, den, out=np.zeros_like(num), where=den > 0)
        out["weighted"] = float(ratio.max()) if ratio.size else 0.0
    return out


@kernel
def _top_pass(f1, f2):
    """(largest |f1 + f2| / 2 over finite values, rows with a non-finite value)."""
    top = 0.0
    excluded = 0
    for i in range(f1.shape[0]):
        row_ok = True
        for c in range(f1.shape[1]):
            a = float(f1[i, c])
            b = float(f2[i, c])
            if math.isfinite(a) and math.isfinite(b):
                m = abs(a + b) * 0.5
                if m > top:
                    top = m
            else:
                row_ok = False
        if not row_ok:
            excluded += 1
    return top, excluded


@kernel
def _stats_pass(f1, f2, thresh, w, num, den):
    """(pairs above ``thresh``, largest relative difference, its row, Σ relative²); adds the
    weighted |f1 − f2| and mean per channel into ``num``, ``den`` (``w`` empty: none)."""
    n_sig = 0
    worst = 0.0
    row = 0
    sumsq = 0.0
    weighted = w.shape[0] > 0
    for i in range(f1.shape[0]):
        for c in range(f1.shape[1]):
            a = float(f1[i, c])
            b = float(f2[i, c])
            if not (math.isfinite(a) and math.isfinite(b)):
                a = 0.0
                b = 0.0
            m = abs(a + b) * 0.5
            d = abs(a - b)
            if weighted:
                num[c] += w[i] * d
                den[c] += w[i] * m
            if m > thresh:
                n_sig += 1
                r = d / m
                sumsq += r * r
                if r > worst:
                    worst = r
                    row = i
    return n_sig, worst, row, sumsq


def where_deg(wi, wo) -> dict:
    """(θi, φi, θo, φo) of one pair in degrees, for reports."""
    ti, pi_ = vec_to_sph(wi)
    to, po = vec_to_sph(wo)
    return {"theta_i_deg": round(float(np.degrees(ti)), 4), "phi_i_deg": round(float(np.degrees(pi_)), 4),
            "theta_o_deg": round(float(np.degrees(to)), 4), "phi_o_deg": round(float(np.degrees(po)), 4)}


def fmt_pair(w: dict) -> str:
    return (f"(θi, φi, θo, φo) = ({w['theta_i_deg']:.3g}°, {w['phi_i_deg']:.3g}°, {w['theta_o_deg']:.3g}°, "
            f"{w['phi_o_deg']:.3g}°)")
