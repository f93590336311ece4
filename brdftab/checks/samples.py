"""Sample audit: NaN, infinite, negative and missing samples of a table.

A table may declare samples *missing* (``brdf:valid_min = 0`` — the CF attribute: values
below it are not data; MERL's negative "no measurement" markers are read this way). Missing
samples are counted and reported, not treated as negative data; every other sample must be
finite and non-negative.
"""

from __future__ import annotations

import numpy as np

from ..params import Param
from . import Check, Outcome, register

__all__ = ["Finite", "NonNegative", "Missing"]


def _is_table(brdf) -> str | None:
    return None if hasattr(brdf, "values") and hasattr(brdf, "grid") else "not a table (no samples to audit)"


def _counts(table):
    v = np.asarray(table.values)
    missing = np.asarray(table.missing) if getattr(table, "missing", None) is not None else np.zeros(v.shape, bool)
    data = v[~missing]
    return v.size, data, int(missing.sum())


@register
class Finite(Check):
    name = "finite"
    family = "samples"
    summary = "No NaN or infinite samples."
    applies = staticmethod(_is_table)

    def run(self, table):
        total, data, _ = _counts(table)
        nan = int(np.isnan(data).sum())
        inf = int(np.isinf(data).sum())
        bad = nan + inf
        return Outcome(self.name, "pass" if bad == 0 else "fail", float(bad), 0.0,
                       f"{bad} of {total} samples are NaN or infinite ({nan} NaN, {inf} infinite)",
                       data={"nan": nan, "inf": inf, "samples": total})


@register
class NonNegative(Check):
    name = "non-negative"
    family = "samples"
    summary = "No negative samples (declared missing samples excepted)."
    applies = staticmethod(_is_table)

    def run(self, table):
        total, data, _ = _counts(table)
        with np.errstate(invalid="ignore"):
            neg = data < 0
        count = int(neg.sum())
        lowest = float(data[neg].min()) if count else 0.0
        return Outcome(self.name, "pass" if count == 0 else "fail", float(count), 0.0,
                       f"{count} of {total} samples are negative (lowest {lowest:.4g} sr-1)",
                       data={"negative": count, "lowest": lowest, "samples": total})


@register
class Missing(Check):
    name = "missing"
    family = "samples"
    summary = "Fraction of samples the table declares missing (e.g. MERL's negative markers)."
    level = "warn"
    thresholds = (Param("max_fraction", "float", "Largest accepted fraction of missing samples.", default=0.0,
                        minimum=0.0, maximum=1.0),)
    applies = staticmethod(_is_table)

    def run(self, table, max_fraction):
        total, _, missing = _counts(table)
        frac = missing / total if total else 0.0
        return Outcome(self.name, "pass" if frac <= max_fraction else "fail", frac, max_fraction,
                       f"{missing} of {total} samples are missing ({100 * frac:.3g} %)",
                       data={"missing": missing, "samples": total})
