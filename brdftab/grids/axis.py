"""Grid axes, the φd folds, and angle lists as spec values.

An :class:`Axis` holds node coordinates [rad] and knows how queries map to fractional
indices (linear, or linear in a warped coordinate), whether it is periodic, and its
**domain**: the interval of coordinates the table covers. A uniform axis (``n`` nodes at
bin centres or lower edges of a partition) covers its whole range (a MERL-grid table answers
θh = 0 although its first node sits half a bin away); an explicit list covers only
``[first, last]``. Queries outside the domain are *outside*: tables return NaN there (or
raise, or clamp, as asked), never an answer borrowed from the nearest node.

φd conventions (``phi_d_fold``; φd is the azimuth of the Rusinkiewicz difference vector):

``none``
    φd ∈ [0, 2π), periodic.
``reciprocity``
    φd ≡ φd + π (swapping wi and wo adds π to φd); stored over [0, π), periodic with period
    π. This is MERL's fold.
``bilateral``
    φd ≡ −φd (mirror symmetry about the plane of h and the normal); stored over [0, π].
    This is ALTA's fold.
``reciprocity+bilateral``
    both; stored over [0, π/2].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ParameterError
from ..params import Kind, as_float, register_kind, suggest

__all__ = ["Axis", "angle_axis", "fold_phi_d", "PHI_D_FOLDS", "SAMPLE_POSITIONS", "NODE_RULES", "HALF_PI", "TWO_PI",
           "MAX_AXIS_NODES", "uniform_values", "count", "check_range", "expand_angles", "expand_range", "LONG_NAMES"]

HALF_PI = 0.5 * np.pi
TWO_PI = 2.0 * np.pi
PHI_D_FOLDS = {
    # name: (stored range length, periodic)
    "none": (TWO_PI, True),
    "reciprocity": (np.pi, True),
    "bilateral": (np.pi, False),
    "reciprocity+bilateral": (HALF_PI, False),
}
SAMPLE_POSITIONS = ("bin-centre", "lower-edge")
#: How an axis' nodes were placed: at bin centres or lower edges of a uniform partition of
#: the axis range, or as an explicit list.
NODE_RULES = SAMPLE_POSITIONS + ("explicit",)
SNAP = 1e-9  # fractional indices this close to a node are snapped onto it
DOMAIN_TOL = 1e-9  # rad: queries this close outside a domain edge are inside
#: Most nodes one axis may have (a guard against typos such as 10**9).
MAX_AXIS_NODES = 1_000_000

LONG_NAMES = {
    "theta_h": "polar angle of the half vector",
    "phi_h": "azimuth of the half vector",
    "theta_d": "polar angle of the difference vector",
    "phi_d": "azimuth of the difference vector",
    "theta_i": "polar angle of the incident direction",
    "phi_i": "azimuth of the incident direction",
    "theta_o": "polar angle of the outgoing direction",
    "phi_o": "azimuth of the outgoing direction",
    "dtheta_o": "theta_o minus theta_i",
    "dphi_o": "phi_o minus (phi_i + pi)",
}


def fold_phi_d(phi_d, fold: str):
    """Map φd [rad] into the stored range of ``fold`` (see the module docstring)."""
    if fold == "none":
        return np.mod(phi_d, TWO_PI)
    if fold == "reciprocity":
        return np.mod(phi_d, np.pi)
    if fold == "bilateral":
        return np.abs(np.mod(phi_d + np.pi, TWO_PI) - np.pi)
    if fold == "reciprocity+bilateral":
        x = np.mod(phi_d, np.pi)
        return np.minimum(x, np.pi - x)
    raise ValueError(f"unknown phi_d fold {fold!r}")


@dataclass(frozen=True, eq=False)
class Axis:
    """One grid axis: node coordinates [rad], warp, period, domain.

    ``warp = "sqrt"`` means the axis is uniform in ``u = sqrt(x / (π/2))`` (MERL θh);
    interpolation between nodes is linear in the warped coordinate. ``period`` makes the axis
    periodic (interpolation runs across the seam; no query is outside). ``wrap`` marks an
    angle axis that does not cover its circle: queries are reduced modulo ``wrap``; those in
    the uncovered arc are outside. ``domain`` is the covered interval (default: the nodes'
    span); ``rule`` says how the nodes were placed (:data:`NODE_RULES`).
    """

    name: str
    values: np.ndarray
    warp: str = "linear"
    period: float | None = None
    wrap: float | None = None
    domain: tuple | None = None
    rule: str = "explicit"

    def __post_init__(self):
        v = np.asarray(self.values, float)
        object.__setattr__(self, "values", v)
        if v.ndim != 1 or v.size == 0:
            raise ParameterError(self.name, "an axis needs at least one value")
        if not np.all(np.isfinite(v)):
            raise ParameterError(self.name, "axis values must be finite")
        if np.any(np.diff(v) <= 0):
            raise ParameterError(self.name, "axis values must increase strictly")
        if self.period is not None and v[-1] - v[0] >= self.period:
            raise ParameterError(self.name, "periodic axis values must span less than one period")
        if self.domain is None:
            object.__setattr__(self, "domain", (float(v[0]), float(v[-1])))
        else:
            lo, hi = (float(x) for x in self.domain)
            if not (lo <= v[0] + DOMAIN_TOL and v[-1] <= hi + DOMAIN_TOL):
                raise ParameterError(self.name, "axis nodes lie outside the axis domain")
            object.__setattr__(self, "domain", (lo, hi))

    def __len__(self):
        return self.values.size

    def _t(self, x):
        return np.sqrt(np.maximum(x, 0.0) / HALF_PI) if self.warp == "sqrt" else x

    def _reduced(self, x):
        """Angles of a wrapped axis reduced into [lo, lo + wrap), lo the domain's low end (the
        first node, or below it when the domain reaches past the nodes: cell-centred nodes)."""
        if self.wrap is None or self.period is not None:
            return x
        lo = self.domain[0]
        return lo + np.mod(x - lo, self.wrap)

    def outside(self, x):
        """True where coordinate ``x`` lies outside this axis' domain."""
        x = np.asarray(x, float)
        if self.period is not None:
            return ~np.isfinite(x)
        xr = self._reduced(x)
        lo, hi = self.domain
        out = (xr < lo - DOMAIN_TOL) | (xr > hi + DOMAIN_TOL) | ~np.isfinite(xr)
        if self.wrap is not None:
            # the arc just below v0 (reduced to near v0 + wrap) is inside when within tolerance
            out &= ~(np.abs(xr - self.wrap - lo) <= DOMAIN_TOL)
        return out

    def fractional_index(self, x):
        """Continuous index of coordinates ``x``: clamped to [0, n−1], or in [0, n) if periodic.

        Outside the domain the index is clamped to the nearer end (the uncovered arc of a wrapped
        axis goes to the nearer end node); callers ask :meth:`outside` first.
        """
        n = self.values.size
        x = np.asarray(x, float)
        if n == 1:
            return np.zeros_like(x)
        if self.period is not None:
            v0 = self.values[0]
            xw = v0 + np.mod(x - v0, self.period)
            idx = np.interp(xw, np.append(self.values, v0 + self.period), np.arange(n + 1.0))
            idx = np.where(idx >= n, idx - n, idx)
        else:
            xr = self._reduced(x)
            if self.wrap is not None:  # the uncovered arc clamps to the nearer end node
                v0, v1 = self.values[0], self.values[-1]
                xr = np.where((xr > v1) & (v0 + self.wrap - xr < xr - v1), v0, xr)
            idx = np.interp(self._t(xr), self._t(self.values), np.arange(float(n)))
        r = np.rint(idx)
        idx = np.where(np.abs(idx - r) < SNAP, r, idx)
        if self.period is not None:
            idx = np.where(idx >= n, idx - n, idx)
        return idx

    def equals(self, other: "Axis") -> bool:
        return (self.name == other.name and self.warp == other.warp and self.period == other.period
                and self.wrap == other.wrap and self.values.shape == other.values.shape
                and np.array_equal(self.values, other.values))

    def domain_text(self) -> str:
        if self.period is not None:
            return f"{self.name} (periodic)"
        lo, hi = np.degrees(self.domain)
        return f"{self.name} in [{lo:.6g}, {hi:.6g}] deg"


def angle_axis(name, values, period, domain=None) -> "Axis":
    """An explicit list on an angle axis of period ``period``: periodic when its nodes go
    round the circle without a wider gap at the seam than between them; otherwise it covers
    only its listed arc (``[first, last]``, or ``domain``) and queries elsewhere are outside
    (a single φd slice is not an answer for every φd)."""
    v = np.asarray(values, float)
    if v.size > 1:
        seam = v[0] + period - v[-1]
        if seam <= np.diff(v).max() * (1 + 1e-9):
            return Axis(name, v, "linear", period)
    return Axis(name, v, "linear", None, period, domain=domain)


def uniform_values(n: int, lo: float, length: float, position: str, warp: str = "linear") -> np.ndarray:
    """``n`` nodes at bin centres or lower edges of a uniform partition of ``[lo, lo + length)``
    (for ``warp = "sqrt"``: uniform in ``sqrt(x / (π/2))`` over ``[0, π/2)``)."""
    offset = 0.5 if position == "bin-centre" else 0.0
    u = (np.arange(n) + offset) / n
    if warp == "sqrt":
        return u ** 2 * HALF_PI
    return lo + u * length


def count(label, n):
    """A node count from a spec or file: a whole number from 1 to :data:`MAX_AXIS_NODES`."""
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise ParameterError(f"n_{label}", f"expected a positive whole number of samples, got {n!r}")
    if n > MAX_AXIS_NODES:
        raise ParameterError(f"n_{label}", f"at most {MAX_AXIS_NODES} nodes per axis, got {n}")
    return int(n)


def check_range(label, vals, lo, hi, closed=True, why=""):
    """Refuse angle lists that are empty, non-finite, unsorted or outside ``[lo, hi]``."""
    if vals.ndim != 1 or vals.size == 0 or not np.all(np.isfinite(vals)):
        raise ParameterError(label, "expected a non-empty list of finite angles")
    if np.any(np.diff(vals) <= 0):
        raise ParameterError(label, "values must increase strictly")
    eps = 1e-12
    if vals[0] < lo - eps or vals[-1] > hi + eps or (not closed and vals[-1] >= hi - eps):
        bracket = "]" if closed else ")"
        raise ParameterError(label, f"values must lie in [{np.degrees(lo):g}, {np.degrees(hi):g}{bracket} degrees"
                                    f"{why}, got {np.degrees(vals[0]):g} .. {np.degrees(vals[-1]):g}")


# --------------------------------------------------------------------------------------------
# Angle lists in spec files: numbers and {start, stop, step|num[, endpoint]} ranges, degrees


def expand_angles(key, raw):
    """Radians from a list of degrees and/or ranges {start, stop, step|num[, endpoint]}, merged."""
    items = raw if isinstance(raw, list) else [raw]
    out = []
    for item in items:
        if isinstance(item, bool):
            raise ParameterError(key, "expected numbers or ranges {start, stop, step|num}")
        if isinstance(item, (int, float)):
            if not _finite(item):
                raise ParameterError(key, "expected finite numbers")
            out.append(float(item))
        elif isinstance(item, dict):
            out.extend(expand_range(key, item))
        else:
            raise ParameterError(key, "expected numbers or ranges {start, stop, step|num}")
    if not out:
        raise ParameterError(key, "expected at least one value")
    return np.radians(np.unique(np.round(np.asarray(out), 12)))


def expand_range(key, r):
    """The values of a range ``{start, stop, step|num[, endpoint]}`` (in the units written)."""
    allowed = {"start", "stop", "step", "num", "endpoint"}
    extra = set(r) - allowed
    if extra:
        bad = sorted(extra)[0]
        raise ParameterError(f"{key}.{bad}", f"unknown range key{suggest(bad, allowed)}; valid: start, stop, step, "
                             "num, endpoint")
    if "start" not in r or "stop" not in r or (("step" in r) == ("num" in r)):
        raise ParameterError(key, "a range needs start, stop and exactly one of step or num")
    for k in ("start", "stop", "step"):
        if k in r and (isinstance(r[k], bool) or not isinstance(r[k], (int, float))
                       or not _finite(r[k])):
            raise ParameterError(f"{key}.{k}", "expected a finite number")
    start, stop = float(r["start"]), float(r["stop"])
    endpoint = r.get("endpoint", True)
    if not isinstance(endpoint, bool):
        raise ParameterError(f"{key}.endpoint", "expected true or false")
    if "num" in r:
        num = r["num"]
        if isinstance(num, bool) or not isinstance(num, int) or not 1 <= num <= MAX_AXIS_NODES:
            raise ParameterError(f"{key}.num", f"expected a whole number from 1 to {MAX_AXIS_NODES}")
        return list(np.linspace(start, stop, num, endpoint=endpoint))
    step = float(r["step"])
    if step <= 0 or stop < start:
        raise ParameterError(f"{key}.step", "expected step > 0 and stop >= start")
    n_steps = (stop - start) / step
    if not n_steps < MAX_AXIS_NODES:
        raise ParameterError(f"{key}.step", f"the range would have more than {MAX_AXIS_NODES} values")
    n = int(np.floor(n_steps + 1e-9)) + 1
    vals = start + step * np.arange(n)
    if not endpoint:
        vals = vals[vals < stop - 1e-9]
    return list(vals)


def _finite(x) -> bool:
    x = as_float(x)
    return x is not None and bool(np.isfinite(x))


class AnglesKind(Kind):
    """A list of angles: numbers and ranges in degrees in a spec (``<name>_deg``), radians inside."""

    name = "angles"

    def expected(self, p):
        return "angles in degrees: numbers and/or ranges {start, stop, step|num}"

    def convert(self, p, value):
        if isinstance(value, np.ndarray):
            return np.asarray(value, float)
        return expand_angles(p.spec_key, value)

    def to_json(self, value):
        return np.degrees(value).tolist()


register_kind(AnglesKind())
