"""Sampling grids: parameterizations that map index space to direction pairs and back.

A :class:`Grid` is a tuple of :class:`Axis` objects. It turns flat sample indices into
``(wi, wo)`` pairs (for tabulation) and direction pairs into *fractional indices* (for
interpolating a table). Three parameterizations:

``rusinkiewicz`` (isotropic)
    axes ``theta_h, theta_d, phi_d`` (Rusinkiewicz half/difference angles, φh = 0).
``rusinkiewicz`` (anisotropic)
    axes ``theta_h, phi_h, theta_d, phi_d``.
``merl``
    the exact MERL grid: 90 θh nodes on the square-root warp θh = (u/90)²·π/2, 90 θd nodes
    of 1°, 180 φd nodes of 1° over [0, π) folded by reciprocity; node u = i + ½ (``bin-centre``,
    default) or u = i (``lower-edge``). It is a Rusinkiewicz grid and is stored as one.
``spherical``
    gonio axes ``theta_i, phi_i, theta_o, phi_o``; or, with ``relative_to = "specular"``,
    ``theta_i, phi_i, dtheta_o, dphi_o`` where θo = θi + Δθo and φo = φi + π + Δφo (zoomed grids
    around the mirror direction).

φd conventions (``phi_d_fold``; φd is the azimuth of the difference vector, see
:mod:`brdftab.geometry`):

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

Sample position: ``bin-centre`` puts node i at the centre of bin i of a uniform partition of
the axis range, ``lower-edge`` at its lower edge; explicit values are used as given.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .errors import ParameterError
from .geometry import _hd_to_io_trig, io_to_hd, sph_to_vec, vec_to_sph
from .params import suggest

__all__ = ["Axis", "Grid", "RusinkiewiczGrid", "SphericalGrid", "merl_grid", "grid_from_config",
           "grid_from_dataset", "check_grid", "fold_phi_d", "PHI_D_FOLDS", "SAMPLE_POSITIONS", "GRID_TYPES"]

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
SNAP = 1e-9  # fractional indices this close to a node are snapped onto it

_LONG_NAMES = {
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
    """Map φd [rad] into the stored range of ``fold`` (see module docstring)."""
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
    """One grid axis: node coordinates [rad], an optional warp, an optional period.

    ``warp = "sqrt"`` means the axis is uniform in ``u = sqrt(x / (π/2))`` (MERL θh);
    interpolation between nodes is linear in the warped coordinate. ``period`` makes the axis
    periodic (interpolation runs across the seam). ``wrap`` marks an angle axis that does not
    cover its circle: queries are reduced modulo ``wrap`` and those in the uncovered gap go
    to the nearer end node.
    """

    name: str
    values: np.ndarray
    warp: str = "linear"
    period: float | None = None
    wrap: float | None = None

    def __post_init__(self):
        v = np.asarray(self.values, float)
        object.__setattr__(self, "values", v)
        if v.ndim != 1 or v.size == 0:
            raise ParameterError(self.name, "an axis needs at least one value")
        if np.any(np.diff(v) <= 0):
            raise ParameterError(self.name, "axis values must increase strictly")
        if self.period is not None and v[-1] - v[0] >= self.period:
            raise ParameterError(self.name, "periodic axis values must span less than one period")

    def __len__(self):
        return self.values.size

    def _t(self, x):
        return np.sqrt(np.maximum(x, 0.0) / HALF_PI) if self.warp == "sqrt" else x

    def reduce(self, x):
        """Angles reduced into [v0, v0 + wrap) for a wrapped axis; gap values go to the nearer end."""
        if self.wrap is None or self.period is not None:
            return x
        v0, v1 = self.values[0], self.values[-1]
        xw = v0 + np.mod(x - v0, self.wrap)
        to_first = (xw > v1) & (v0 + self.wrap - xw < xw - v1)
        return np.where(to_first, v0, xw)

    def in_gap(self, x):
        """True where angle ``x`` lies outside the covered arc of a wrapped axis."""
        if self.period is not None:
            return np.zeros(np.shape(x), bool)
        if self.wrap is None:
            return (x < self.values[0]) | (x > self.values[-1])
        v0 = self.values[0]
        return v0 + np.mod(x - v0, self.wrap) > self.values[-1] + 1e-12

    def fractional_index(self, x):
        """Continuous index of coordinates ``x``: clamped to [0, n−1], or in [0, n) if periodic."""
        n = self.values.size
        x = self.reduce(np.asarray(x, float))
        if n == 1:
            return np.zeros_like(x)
        if self.period is not None:
            v0 = self.values[0]
            xw = v0 + np.mod(x - v0, self.period)
            idx = np.interp(xw, np.append(self.values, v0 + self.period), np.arange(n + 1.0))
            idx = np.where(idx >= n, idx - n, idx)
        else:
            idx = np.interp(self._t(x), self._t(self.values), np.arange(float(n)))
        r = np.rint(idx)
        idx = np.where(np.abs(idx - r) < SNAP, r, idx)
        if self.period is not None:
            idx = np.where(idx >= n, idx - n, idx)
        return idx

    def equals(self, other: "Axis") -> bool:
        return (self.name == other.name and self.warp == other.warp and self.period == other.period
                and self.wrap == other.wrap and self.values.shape == other.values.shape and np.array_equal(self.values, other.values))


class Grid:
    """Base class: a tuple of axes plus conversions between indices and direction pairs."""

    parameterization = "grid"
    axes: tuple = ()

    @property
    def dims(self) -> tuple:
        return tuple(a.name for a in self.axes)

    @property
    def shape(self) -> tuple:
        return tuple(len(a) for a in self.axes)

    @property
    def size(self) -> int:
        return math.prod(self.shape)

    @property
    def coords(self) -> dict:
        return {a.name: a.values for a in self.axes}

    def attrs(self) -> dict:
        """Dataset attributes that, with the coordinates, reconstruct this grid."""
        raise NotImplementedError

    def coord_attrs(self, name) -> dict:
        return {"units": "rad", "long_name": _LONG_NAMES.get(name, name)}

    def directions(self, start: int = 0, stop: int | None = None):
        """``(wi, wo)`` of flat sample indices ``start..stop`` (C order), each ``(m, 3)``."""
        stop = self.size if stop is None else stop
        idx = np.unravel_index(np.arange(start, stop), self.shape)
        return self._directions(idx)

    def _directions(self, idx):
        raise NotImplementedError

    def fractional_index(self, wi, wo, isotropic: bool = False):
        """Fractional index per axis of direction pairs ``[..., 3]`` (list of arrays)."""
        raise NotImplementedError

    def equals(self, other) -> bool:
        """Same parameterization, conventions and node coordinates (values can be copied)."""
        return (type(self) is type(other) and self.attrs() == other.attrs()
                and len(self.axes) == len(other.axes)
                and all(a.equals(b) for a, b in zip(self.axes, other.axes)))

    def describe(self) -> str:
        return f"{self.attrs().get('grid', self.parameterization)} " + " x ".join(
            f"{a.name}[{len(a)}]" for a in self.axes)


def _uniform(lo, length, n, position):
    offset = 0.5 if position == "bin-centre" else 0.0
    return lo + (np.arange(n) + offset) * length / n


class RusinkiewiczGrid(Grid):
    """Half/difference grid (isotropic or anisotropic). See the module docstring."""

    parameterization = "rusinkiewicz"

    def __init__(self, theta_h=90, theta_d=90, phi_d=180, phi_h=None, *, theta_h_spacing="linear",
                 phi_d_fold="reciprocity", sample_position="bin-centre", name="rusinkiewicz"):
        if not isinstance(phi_d_fold, str) or phi_d_fold not in PHI_D_FOLDS:
            raise ParameterError("phi_d_fold", f"expected one of {', '.join(map(repr, PHI_D_FOLDS))}, got "
                                 f"{phi_d_fold!r}{suggest(phi_d_fold, PHI_D_FOLDS)}")
        if not isinstance(sample_position, str) or sample_position not in SAMPLE_POSITIONS:
            raise ParameterError("sample_position", f"expected one of {', '.join(map(repr, SAMPLE_POSITIONS))},"
                                 f" got {sample_position!r}")
        if not isinstance(theta_h_spacing, str) or theta_h_spacing not in ("linear", "merl", "explicit"):
            raise ParameterError("theta_h_spacing", f"expected 'linear', 'merl' or an explicit list, got "
                                 f"{theta_h_spacing!r}")
        self.anisotropic = phi_h is not None
        if self.anisotropic and "bilateral" in phi_d_fold:
            raise ParameterError("phi_d_fold", "a bilateral fold assumes isotropy; use 'none' or 'reciprocity' "
                                 "with an anisotropic grid")
        self.theta_h_spacing = "explicit" if not np.isscalar(theta_h) else theta_h_spacing
        self.phi_d_fold = phi_d_fold
        self.sample_position = sample_position
        self.name = name
        fold_len, fold_periodic = PHI_D_FOLDS[phi_d_fold]

        def axis(label, spec, lo, length, periodic, warp="linear"):
            if np.isscalar(spec):
                n = _count(label, spec)
                if warp == "sqrt":
                    vals = _uniform(0.0, 1.0, n, sample_position) ** 2 * HALF_PI
                else:
                    vals = _uniform(lo, length, n, sample_position)
                return Axis(label, vals, warp, length if periodic else None)
            vals = np.asarray(spec, float)
            why = f" (phi_d_fold = '{phi_d_fold}')" if label == "phi_d" else ""
            _check_range(label, vals, lo, lo + length, closed=not periodic, why=why)
            return Axis(label, vals, "linear", length if periodic else None)

        th = axis("theta_h", theta_h, 0.0, HALF_PI, False, "sqrt" if self.theta_h_spacing == "merl" else "linear")
        td = axis("theta_d", theta_d, 0.0, HALF_PI, False)
        pd = axis("phi_d", phi_d, 0.0, fold_len, fold_periodic)
        if self.anisotropic:
            ph = axis("phi_h", phi_h, 0.0, TWO_PI, True)
            self.axes = (th, ph, td, pd)
        else:
            self.axes = (th, td, pd)
        self._explicit = {a.name: not np.isscalar(s) for a, s in
                          zip(self.axes, (theta_h, phi_h, theta_d, phi_d) if self.anisotropic
                              else (theta_h, theta_d, phi_d))}
        self._trig = [(np.cos(a.values), np.sin(a.values)) for a in self.axes]

    def attrs(self) -> dict:
        explicit = all(self._explicit.values())
        return {
            "parameterization": "rusinkiewicz-anisotropic" if self.anisotropic else "rusinkiewicz",
            "grid": self.name,
            "theta_h_spacing": self.theta_h_spacing,
            "phi_d_fold": self.phi_d_fold,
            "sample_position": "explicit" if explicit else self.sample_position,
        }

    def _directions(self, idx):
        if self.anisotropic:
            (cth, sth), (cph, sph), (ctd, std), (cpd, spd) = self._trig
            ih, iph, itd, ipd = idx
            return _hd_to_io_trig(cth[ih], sth[ih], cph[iph], sph[iph], ctd[itd], std[itd], cpd[ipd], spd[ipd])
        (cth, sth), (ctd, std), (cpd, spd) = self._trig
        ih, itd, ipd = idx
        return _hd_to_io_trig(cth[ih], sth[ih], 1.0, 0.0, ctd[itd], std[itd], cpd[ipd], spd[ipd])

    def fractional_index(self, wi, wo, isotropic: bool = False):
        th, ph, td, pd = io_to_hd(wi, wo)
        pd = fold_phi_d(pd, self.phi_d_fold)
        if self.anisotropic:
            a_th, a_ph, a_td, a_pd = self.axes
            return [a_th.fractional_index(th), a_ph.fractional_index(ph),
                    a_td.fractional_index(td), a_pd.fractional_index(pd)]
        a_th, a_td, a_pd = self.axes
        return [a_th.fractional_index(th), a_td.fractional_index(td), a_pd.fractional_index(pd)]

    @classmethod
    def from_dataset(cls, ds, attrs):
        aniso = attrs["parameterization"] == "rusinkiewicz-anisotropic"
        spacing = attrs.get("theta_h_spacing", "linear")
        fold = attrs.get("phi_d_fold", "reciprocity")
        pos = attrs.get("sample_position", "bin-centre")
        grid = cls.__new__(cls)
        grid.anisotropic = aniso
        grid.theta_h_spacing = spacing
        grid.phi_d_fold = fold
        grid.sample_position = "bin-centre" if pos == "explicit" else pos
        grid.name = attrs.get("grid", "rusinkiewicz")
        fold_len, fold_periodic = PHI_D_FOLDS[fold]
        names = ("theta_h", "phi_h", "theta_d", "phi_d") if aniso else ("theta_h", "theta_d", "phi_d")
        axes = []
        for name in names:
            vals = np.asarray(ds[name].values, float)
            warp = "sqrt" if (name == "theta_h" and spacing == "merl") else "linear"
            period = {"phi_d": fold_len if fold_periodic else None, "phi_h": TWO_PI}.get(name)
            axes.append(Axis(name, vals, warp, period))
        grid.axes = tuple(axes)
        grid._explicit = {n: pos == "explicit" for n in names}
        grid._trig = [(np.cos(a.values), np.sin(a.values)) for a in grid.axes]
        return grid


def merl_grid(sample_position: str = "bin-centre") -> RusinkiewiczGrid:
    """The exact MERL 90×90×180 grid (θh square-root warp, φd over [0, π) by reciprocity)."""
    return RusinkiewiczGrid(90, 90, 180, theta_h_spacing="merl", phi_d_fold="reciprocity",
                            sample_position=sample_position, name="merl")


class SphericalGrid(Grid):
    """Gonio grid over (θi, φi, θo, φo), optionally relative to the mirror direction."""

    parameterization = "spherical"

    def __init__(self, theta_i, phi_i, theta_o, phi_o, *, relative_to="none"):
        if relative_to not in ("none", "specular"):
            raise ParameterError("relative_to", f"expected 'none' or 'specular', got {relative_to!r}")
        self.relative_to = relative_to
        rel = relative_to == "specular"
        ti = np.asarray(theta_i, float)
        _check_range("theta_i", ti, 0.0, HALF_PI, closed=True)
        to = np.asarray(theta_o, float)
        if rel:
            _check_range("dtheta_o", to, -HALF_PI, np.pi, closed=True)
            if ti.size and to.size and ti[0] + to[0] < -1e-12:
                raise ParameterError("dtheta_o", f"theta_i + dtheta_o must be >= 0 (a negative theta_o is the same "
                                     f"direction as its mirror across the normal); the smallest is "
                                     f"{np.degrees(ti[0] + to[0]):g} degrees")
        else:
            _check_range("theta_o", to, 0.0, HALF_PI, closed=True)
        self.axes = (
            Axis("theta_i", ti),
            _phi_axis("phi_i", phi_i),
            Axis("dtheta_o" if rel else "theta_o", to),
            _phi_axis("dphi_o" if rel else "phi_o", phi_o, centred=rel),
        )
        self._trig = [(np.cos(a.values), np.sin(a.values)) for a in self.axes]

    def attrs(self) -> dict:
        return {"parameterization": "spherical", "grid": "spherical", "relative_to": self.relative_to,
                "sample_position": "explicit", "phi_d_fold": "none"}

    def _directions(self, idx):
        i_ti, i_pi, i_to, i_po = idx
        ti = self.axes[0].values[i_ti]
        pi_ = self.axes[1].values[i_pi]
        to = self.axes[2].values[i_to]
        po = self.axes[3].values[i_po]
        if self.relative_to == "specular":
            to = ti + to
            po = pi_ + np.pi + po
        return sph_to_vec(ti, pi_), sph_to_vec(to, po)

    def fractional_index(self, wi, wo, isotropic: bool = False):
        ti, pi_ = vec_to_sph(wi)
        to, po = vec_to_sph(wo)
        if isotropic:
            # Rotate pairs whose φi the table does not cover onto its first φi node.
            ax = self.axes[1]
            off = ax.in_gap(pi_) if len(ax) > 1 else np.ones(np.shape(pi_), bool)
            shift = np.where(off, ax.values[0] - pi_, 0.0)
            pi_ = pi_ + shift
            po = po + shift
        if self.relative_to == "specular":
            to = to - ti
            po = np.mod(po - pi_, TWO_PI) - np.pi  # wrap(φo − φi − π) into [−π, π)
        return [a.fractional_index(x) for a, x in zip(self.axes, (ti, pi_, to, po))]

    @classmethod
    def from_dataset(cls, ds, attrs):
        rel = attrs.get("relative_to", "none") == "specular"
        names = ("theta_i", "phi_i", "dtheta_o" if rel else "theta_o", "dphi_o" if rel else "phi_o")
        vals = [np.asarray(ds[n].values, float) for n in names]
        return cls(*vals, relative_to="specular" if rel else "none")


def _phi_axis(name, values, centred=False):
    """An azimuth axis: periodic when its nodes go round the circle without a wider gap at the
    seam than between them; otherwise wrapped (queries in the gap go to the nearer end)."""
    v = np.asarray(values, float)
    if v.ndim != 1 or v.size == 0:
        raise ParameterError(name, "an axis needs at least one value")
    lo, hi = (-np.pi, np.pi) if centred else (-TWO_PI, TWO_PI)
    _check_range(name, v, lo, hi, closed=True)
    if v.size > 1 and np.isclose(v[-1] - v[0], TWO_PI, rtol=0, atol=1e-9):
        v = v[:-1]  # 0° and 360° are one azimuth: keep the first
    if v[-1] - v[0] >= TWO_PI:
        raise ParameterError(name, "azimuths must span less than 360 degrees")
    if v.size > 1:
        seam = v[0] + TWO_PI - v[-1]
        if seam <= np.diff(v).max() * (1 + 1e-9):
            return Axis(name, v, "linear", TWO_PI)
    return Axis(name, v, "linear", None, TWO_PI)


#: Most nodes one axis may have (a guard against typos such as 10**9).
MAX_AXIS_NODES = 1_000_000


def _count(label, n):
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise ParameterError(f"n_{label}", f"expected a positive whole number of samples, got {n!r}")
    if n > MAX_AXIS_NODES:
        raise ParameterError(f"n_{label}", f"at most {MAX_AXIS_NODES} nodes per axis, got {n}")
    return int(n)


def _check_range(label, vals, lo, hi, closed=True, why=""):
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
# Grids from spec tables ([grid] section) and from stored tables


def _angles(cfg, key, used):
    """Angles in degrees under ``<key>_deg``: a list, or ranges {start, stop, step|num}."""
    raw = cfg[f"{key}_deg"]
    used.add(f"{key}_deg")
    return np.radians(_expand(f"{key}_deg", raw))


def _expand(key, raw):
    """A value list: numbers, or {start, stop, step} / {start, stop, num[, endpoint]} ranges, merged."""
    items = raw if isinstance(raw, list) else [raw]
    out = []
    for item in items:
        if isinstance(item, bool):
            raise ParameterError(key, "expected numbers or ranges {start, stop, step|num}")
        if isinstance(item, (int, float)):
            if not np.isfinite(item):
                raise ParameterError(key, "expected finite numbers")
            out.append(float(item))
        elif isinstance(item, dict):
            out.extend(_range(key, item))
        else:
            raise ParameterError(key, "expected numbers or ranges {start, stop, step|num}")
    if not out:
        raise ParameterError(key, "expected at least one value")
    return np.unique(np.round(np.asarray(out), 12))


def _range(key, r):
    allowed = {"start", "stop", "step", "num", "endpoint"}
    extra = set(r) - allowed
    if extra:
        bad = sorted(extra)[0]
        raise ParameterError(f"{key}.{bad}", f"unknown range key{suggest(bad, allowed)}; valid: start, stop, step, "
                             "num, endpoint")
    if "start" not in r or "stop" not in r or (("step" in r) == ("num" in r)):
        raise ParameterError(key, "a range needs start, stop and exactly one of step or num")
    for k in ("start", "stop", "step"):
        if k in r and (isinstance(r[k], bool) or not isinstance(r[k], (int, float)) or not np.isfinite(r[k])):
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
    count = (stop - start) / step
    if not count < MAX_AXIS_NODES:
        raise ParameterError(f"{key}.step", f"the range would have more than {MAX_AXIS_NODES} values")
    n = int(np.floor(count + 1e-9)) + 1
    vals = start + step * np.arange(n)
    if not endpoint:
        vals = vals[vals < stop - 1e-9]
    return list(vals)


_GRID_KEYS = {
    "merl": {"type", "sample_position", "wavelengths_nm"},
    "rusinkiewicz": {"type", "anisotropic", "theta_h_spacing", "phi_d_fold", "sample_position", "wavelengths_nm",
                     "n_theta_h", "n_theta_d", "n_phi_d", "n_phi_h",
                     "theta_h_deg", "theta_d_deg", "phi_d_deg", "phi_h_deg"},
    "spherical": {"type", "relative_to", "wavelengths_nm", "theta_i_deg", "phi_i_deg", "theta_o_deg", "phi_o_deg",
                  "dtheta_o_deg", "dphi_o_deg"},
}
GRID_TYPES = tuple(_GRID_KEYS)


def grid_from_config(cfg: dict) -> Grid:
    """Build a grid from a ``[grid]`` table (angles in degrees under ``*_deg`` keys).

    ``wavelengths_nm`` is allowed in the table (the spectral axis); it is read by the caller.
    Raises :class:`ParameterError` naming the offending key.
    """
    kind = cfg.get("type")
    if not isinstance(kind, str) or kind not in _GRID_KEYS:
        raise ParameterError("type", f"expected one of {', '.join(map(repr, GRID_TYPES))}, got {kind!r}"
                             f"{suggest(kind, GRID_TYPES)}")
    valid = _GRID_KEYS[kind]
    for key in cfg:
        if key not in valid:
            raise ParameterError(key, f"unknown key for a '{kind}' grid{suggest(key, valid)}; valid: "
                                 f"{', '.join(sorted(valid))}")
    try:
        return _grid_from_config(kind, cfg)
    except ParameterError as exc:
        # axis errors name the axis; the spec key of an explicit list is <axis>_deg
        if exc.key in _LONG_NAMES and f"{exc.key}_deg" in cfg:
            raise ParameterError(f"{exc.key}_deg", exc.detail) from None
        raise


def _grid_from_config(kind, cfg):
    pos = cfg.get("sample_position", "bin-centre")
    if kind == "merl":
        return merl_grid(_choice("sample_position", pos, SAMPLE_POSITIONS))
    if kind == "rusinkiewicz":
        aniso = cfg.get("anisotropic", False)
        if not isinstance(aniso, bool):
            raise ParameterError("anisotropic", "expected true or false")
        used = set()
        defaults = {"theta_h": 90, "theta_d": 90, "phi_d": 180, "phi_h": 360}
        axes = {}
        for ax in ("theta_h", "theta_d", "phi_d", "phi_h"):
            if ax == "phi_h" and not aniso:
                if f"n_{ax}" in cfg or f"{ax}_deg" in cfg:
                    raise ParameterError(f"n_{ax}" if f"n_{ax}" in cfg else f"{ax}_deg",
                                         "phi_h is only sampled with anisotropic = true")
                continue
            if f"n_{ax}" in cfg and f"{ax}_deg" in cfg:
                raise ParameterError(f"{ax}_deg", f"give either n_{ax} or {ax}_deg, not both")
            if f"{ax}_deg" in cfg:
                axes[ax] = _angles(cfg, ax, used)
            else:
                axes[ax] = _count(ax, cfg.get(f"n_{ax}", defaults[ax]))
        spacing = cfg.get("theta_h_spacing", "linear")
        if "theta_h_deg" in cfg and "theta_h_spacing" in cfg:
            raise ParameterError("theta_h_spacing", "not used with an explicit theta_h_deg list")
        _choice("theta_h_spacing", spacing, ("linear", "merl"))
        return RusinkiewiczGrid(axes["theta_h"], axes["theta_d"], axes["phi_d"], axes.get("phi_h"),
                                theta_h_spacing=spacing, phi_d_fold=cfg.get("phi_d_fold", "reciprocity"),
                                sample_position=_choice("sample_position", pos, SAMPLE_POSITIONS))
    rel = _choice("relative_to", cfg.get("relative_to", "none"), ("none", "specular"))
    used = set()
    o_names = ("dtheta_o", "dphi_o") if rel == "specular" else ("theta_o", "phi_o")
    wrong = ("theta_o", "phi_o") if rel == "specular" else ("dtheta_o", "dphi_o")
    for w in wrong:
        if f"{w}_deg" in cfg:
            raise ParameterError(f"{w}_deg", f"not used with relative_to = '{rel}'; give "
                                 f"{o_names[0]}_deg and {o_names[1]}_deg")
    vals = []
    for ax in ("theta_i", "phi_i") + o_names:
        if f"{ax}_deg" not in cfg:
            raise ParameterError(f"{ax}_deg", "missing: a spherical grid needs angles in degrees for "
                                 f"theta_i, phi_i, {o_names[0]}, {o_names[1]}")
        vals.append(_angles(cfg, ax, used))
    return SphericalGrid(*vals, relative_to=rel)


def _choice(key, value, choices):
    if not isinstance(value, str) or value not in choices:
        raise ParameterError(key, f"expected one of {', '.join(map(repr, choices))}, got {value!r}"
                             f"{suggest(value, choices)}")
    return value


def check_grid(brdf, grid: Grid) -> None:
    """Refuse grids that would silently lose part of ``brdf``.

    An anisotropic BRDF needs φh (an anisotropic Rusinkiewicz grid or a spherical grid); a
    non-reciprocal one cannot be folded by reciprocity; a bilateral fold needs isotropy.
    """
    fold = getattr(grid, "phi_d_fold", "none")
    if not brdf.isotropic and getattr(grid, "anisotropic", True) is False:
        raise ParameterError("anisotropic", f"model '{brdf.name}' is anisotropic; an isotropic grid would sample "
                             "only phi_h = 0 (use an anisotropic Rusinkiewicz grid or a spherical grid)")
    if not brdf.reciprocal and "reciprocity" in fold:
        raise ParameterError("phi_d_fold", f"model '{brdf.name}' is not reciprocal; folding phi_d by reciprocity "
                             "would discard half of it (use phi_d_fold = 'none')")
    if not brdf.isotropic and "bilateral" in fold:
        raise ParameterError("phi_d_fold", f"model '{brdf.name}' is anisotropic; a bilateral fold assumes isotropy")


def grid_from_dataset(ds) -> Grid:
    """Reconstruct the grid of a stored table from its coordinates and attributes."""
    attrs = dict(ds.attrs)
    p = attrs.get("parameterization")
    if p in ("rusinkiewicz", "rusinkiewicz-anisotropic"):
        return RusinkiewiczGrid.from_dataset(ds, attrs)
    if p == "spherical":
        return SphericalGrid.from_dataset(ds, attrs)
    raise ParameterError("parameterization", f"unknown table parameterization {p!r}")
