"""Sample audit: NaN, infinite, negative and missing samples.

A table may declare samples *missing* (``brdf:valid_min`` — the CF attribute: values below it
are not data; MERL's negative "no measurement" markers are read this way). Missing samples are
counted and reported (WARN by default, with a threshold on their fraction), not treated as
negative data, and the integrals of the other checks leave them out. Every other sample must be
finite and non-negative — except that negative samples of measured data (or data of unknown
origin) are a WARN with their count and the lowest one's place: measurement noise, reported,
not refused. Each finding says how many samples and where the first few are (axis coordinates
in degrees and the channel).

``coverage`` is the fraction of samples that are data (finite and not declared missing): a
table with none FAILs, one with less than ``warn_below`` WARNs.

A model has no samples: it is audited on the direction pairs the other checks sample
(:func:`~brdftab.checks._pairs.sample_pairs`).
"""

from __future__ import annotations

import numpy as np

from ..params import Param
from . import Check, register
from ._pairs import fmt_pair, sample_pairs, where_deg
from ._tables import fmt_where, missing_mask, node_where

__all__ = ["Finite", "NonNegative", "Missing", "Coverage"]

#: Locations listed per finding.
WHERE = 5
#: Direction pairs a model is audited on.
MODEL_PAIRS = 8192


def _table_audit(ctx):
    """Counts of NaN, infinite, negative and missing samples, the first :data:`WHERE` flat
    indices of each finding and the lowest negative sample, read block by block (a table on
    disk is never loaded whole for it)."""
    def compute():
        t = ctx.brdf
        a = {"samples": 0, "nan": 0, "inf": 0, "negative": 0, "missing": 0, "bad": 0, "lowest": 0.0,
             "lowest_at": None, "first": {"nonfinite": [], "negative": [], "missing": []}}
        for key, v, miss in _blocks(t):
            shape = v.shape
            with np.errstate(invalid="ignore"):
                nan, inf, neg = np.isnan(v), np.isinf(v), v < 0
            if miss is not None:
                nan, inf, neg = nan & ~miss, inf & ~miss, neg & ~miss
            a["samples"] += v.size
            a["nan"] += int(nan.sum())
            a["inf"] += int(inf.sum())
            count = int(neg.sum())
            a["negative"] += count
            a["missing"] += 0 if miss is None else int(miss.sum())
            a["bad"] += int((nan | inf).sum()) + (0 if miss is None else int(miss.sum()))
            for name, mask in (("nonfinite", nan | inf), ("negative", neg), ("missing", miss)):
                got = a["first"][name]
                if mask is not None and len(got) < WHERE:
                    got.extend(_flat(t, key, shape, np.flatnonzero(mask.ravel())[:WHERE - len(got)]))
            if count:
                j = int(np.argmin(np.where(neg, v, np.inf)))
                if a["lowest_at"] is None or v.flat[j] < a["lowest"]:
                    a["lowest"], a["lowest_at"] = float(v.flat[j]), _flat(t, key, shape, [j])[0]
        return a
    return ctx.memo("audit", compute)


def _blocks(t):
    """``(key, samples, missing mask or None)`` of a table's blocks."""
    if hasattr(t, "iter_blocks"):
        from ..table import _missing_mask

        for key, v in t.iter_blocks():
            yield key, v, _missing_mask(v, t._var.attrs)
        return
    v = np.asarray(t.values)
    miss = missing_mask(t)
    yield (), v, miss if miss.any() else None


def _flat(t, key, shape, rows) -> list:
    """Flat indices into the whole table of flat indices ``rows`` into its block ``key``."""
    full = t.shape if hasattr(t, "shape") else np.asarray(t.values).shape
    start = [k.start or 0 for k in key] + [0] * (len(full) - len(key))
    return [int(np.ravel_multi_index(tuple(int(i) + o for i, o in zip(np.unravel_index(int(r), shape), start)),
                                     full)) for r in rows]


def _model_audit(ctx):
    def compute():
        wi, wo, _ = sample_pairs(MODEL_PAIRS, seed=1)
        f = ctx.eval(ctx.brdf, wi, wo)
        return {"wi": wi, "wo": wo, "f": f}
    return ctx.memo("model_audit", compute)


def _where(ctx, flat):
    labels = ctx.labels()
    return [node_where(ctx.brdf, i, labels) for i in flat]


def _pair_where(a, mask):
    rows = np.flatnonzero(mask.any(axis=-1))[:WHERE]
    return [where_deg(a["wi"][r], a["wo"][r]) for r in rows]


@register
class Finite(Check):
    name = "finite"
    family = "samples"
    summary = "No NaN or infinite samples (declared missing samples excepted)."

    def run(self, ctx):
        if ctx.is_table:
            a = _table_audit(ctx)
            nan, inf = a["nan"], a["inf"]
            bad = nan + inf
            total = a["samples"]
            where = _where(ctx, a["first"]["nonfinite"])
            at = f"; first at {fmt_where(where[0])}" if where else ""
            stored = getattr(ctx.brdf, "stored_dtype", None)
            if stored and bad:  # finite in float64, not in the file's storage type
                at += (f"; as stored in {stored} (largest finite value "
                       f"{float(np.finfo(np.dtype(stored)).max):.4g})")
            return self.outcome(bad == 0, bad, 0, f"{bad} of {total} samples are NaN or infinite ({nan} NaN, "
                                f"{inf} infinite){at}", nan=nan, inf=inf, samples=total, where=where)
        a = _model_audit(ctx)
        f = a["f"]
        nan_m, inf_m = np.isnan(f), np.isinf(f)
        nan, inf = int(nan_m.any(axis=-1).sum()), int(inf_m.any(axis=-1).sum())
        bad = int((nan_m | inf_m).any(axis=-1).sum())
        where = _pair_where(a, nan_m | inf_m)
        at = f"; first at {fmt_pair(where[0])}" if where else ""
        return self.outcome(bad == 0, bad, 0, f"{bad} of {f.shape[0]} sampled direction pairs give NaN or infinite "
                            f"values ({nan} NaN, {inf} infinite){at}", nan=nan, inf=inf, pairs=int(f.shape[0]),
                            where=where)


@register
class NonNegative(Check):
    name = "non-negative"
    family = "samples"
    summary = "No negative samples (declared missing samples excepted)."

    def run(self, ctx):
        if ctx.is_table:
            a = _table_audit(ctx)
            count = a["negative"]
            total = a["samples"]
            lowest = a["lowest"]
            where = _where(ctx, a["first"]["negative"])
            worst = None
            if count:
                worst = node_where(ctx.brdf, a["lowest_at"], ctx.labels())
            at = f"; lowest at {fmt_where(worst)}" if worst else ""
            out = self.outcome(count == 0, count, 0, f"{count} of {total} samples are negative (lowest {lowest:.4g} "
                               f"sr-1){at}", negative=count, lowest=lowest, samples=total, where=where,
                               worst=worst, origin=ctx.origin)
            if count and ctx.measured:
                # measured (or unknown) data: noise can dip below 0; reported, not refused
                out.status = "warn"
                out.detail += f" ({ctx.origin} data: reported, not refused)"
            return out
        a = _model_audit(ctx)
        f = a["f"]
        with np.errstate(invalid="ignore"):
            neg = f < 0
        count = int(neg.any(axis=-1).sum())
        lowest = float(f[neg].min()) if count else 0.0
        where = _pair_where(a, neg)
        at = f"; first at {fmt_pair(where[0])}" if where else ""
        return self.outcome(count == 0, count, 0, f"{count} of {f.shape[0]} sampled direction pairs give negative "
                            f"values (lowest {lowest:.4g} sr-1){at}", negative=count, lowest=lowest,
                            pairs=int(f.shape[0]), where=where)


@register
class Missing(Check):
    name = "missing"
    family = "samples"
    summary = "Fraction of samples the table declares missing (e.g. MERL's negative markers)."
    level = "warn"
    thresholds = (Param("max_fraction", "float", "Largest accepted fraction of missing samples.", default=0.0,
                        minimum=0.0, maximum=1.0),)

    def applies(self, ctx):
        return None if ctx.is_table else "not a table (no samples)"

    def run(self, ctx, max_fraction):
        a = _table_audit(ctx)
        total = a["samples"]
        missing = a["missing"]
        frac = missing / total if total else 0.0
        where = _where(ctx, a["first"]["missing"])
        at = f"; first at {fmt_where(where[0])}" if where else ""
        return self.outcome(frac <= max_fraction, frac, max_fraction,
                            f"{missing} of {total} samples are missing ({100 * frac:.3g} %, at most "
                            f"{100 * max_fraction:.3g} % accepted){at}", missing=missing, samples=total, where=where)


@register
class Coverage(Check):
    name = "coverage"
    family = "samples"
    summary = "Fraction of samples that are data (finite, not declared missing): none fails, few warn."
    thresholds = (Param("warn_below", "float", "Coverage below which the table is reported (WARN).", default=0.5,
                        minimum=0.0, maximum=1.0),)

    def applies(self, ctx):
        return None if ctx.is_table else "not a table (no samples)"

    def run(self, ctx, warn_below):
        a = _table_audit(ctx)
        total = a["samples"]
        valid = total - a["bad"]
        frac = valid / total if total else 0.0
        text = f"{valid} of {total} samples are data ({100 * frac:.4g} %; missing, NaN and infinite ones are not)"
        if valid == 0:
            return self.outcome(False, frac, 0.0, f"{text}: the table holds no data", valid=valid, samples=total)
        out = self.outcome(True, frac, warn_below, f"{text} (reported below {100 * warn_below:.4g} %)", valid=valid,
                           samples=total)
        if frac < warn_below:
            out.status = "warn"
        return out
