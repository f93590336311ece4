"""Checks on BRDFs and tables, run before every export.

This module currently checks the samples of a table (non-finite and negative values). The
energy, reciprocity and symmetry checks build on :mod:`brdftab.quadrature`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["Check", "Report", "check_samples"]


@dataclass
class Check:
    """One check: its name, whether it passed, the measured value and a one-line detail."""

    name: str
    passed: bool
    value: float
    threshold: float
    detail: str

    def to_json(self) -> dict:
        return {"name": self.name, "passed": self.passed, "value": self.value, "threshold": self.threshold,
                "detail": self.detail}


@dataclass
class Report:
    checks: list = field(default_factory=list)

    @property
    def passed(self) -> bool:
        return all(c.passed for c in self.checks)

    @property
    def failures(self) -> list:
        return [c for c in self.checks if not c.passed]

    def summary(self) -> str:
        bad = self.failures
        if not bad:
            return "all checks passed"
        return "; ".join(f"{c.name}: {c.detail}" for c in bad)

    def to_json(self) -> dict:
        return {"passed": self.passed, "checks": [c.to_json() for c in self.checks]}


def check_samples(table) -> Report:
    """NaN/±inf and negative samples of a table (both must be absent)."""
    v = np.asarray(table.values)
    total = v.size
    nonfinite = int(np.count_nonzero(~np.isfinite(v)))
    negative = int(np.count_nonzero(v < 0))
    most_negative = float(v[v < 0].min()) if negative else 0.0
    return Report([
        Check("finite", nonfinite == 0, float(nonfinite), 0.0,
              f"{nonfinite} of {total} samples are NaN or infinite"),
        Check("non-negative", negative == 0, float(negative), 0.0,
              f"{negative} of {total} samples are negative (lowest {most_negative:.4g} sr-1)"),
    ])
