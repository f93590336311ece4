"""Scattered samples: direction pairs that form no grid (gonio measurements, ASTM E1392 and CSV
files; see ``formats/astm.md`` and ``formats/csv.md``).

A :class:`ScatteredGrid` holds ``N`` samples, each a pair (θi, φi, θo, φo) [rad], on one axis
``sample`` (0 … N−1). A table on it stores ``brdf[sample, channel]`` and the four angles as
coordinate variables ``theta_i(sample)``, ``phi_i(sample)``, ``theta_o(sample)`` and
``phi_o(sample)``, so netCDF and zarr hold the samples as they are and a table read back
evaluates exactly as the file it came from.

**Interpolation.** Each pair is a point in projected-hemisphere coordinates, where a direction
ω is (ωx, ωy), its projection onto the surface (the unit disk):

* isotropic tables (the table says so): the pair is turned about the normal until ωi lies in
  the x–z plane (φi → 0), and the point is (sin θi, ωo'x, ωo'y) — three coordinates;
* anisotropic tables: (ωi x, ωi y, ωo x, ωo y) — four.

The samples are triangulated (Delaunay, :class:`scipy.spatial.Delaunay`), and a query inside
the triangulation's hull takes the barycentric (linear) combination of the samples at the
corners of its simplex (scipy's ``find_simplex`` and affine ``transform``, as
:class:`scipy.interpolate.LinearNDInterpolator` does it). Samples in incidence layers (a few
θi shared by many samples, as gonioreflectometers measure) are triangulated layer by layer in
the outgoing coordinates and interpolated linearly in sin θi between the two layers around a
query. A
coordinate that is the same for every sample (one incidence angle, a principal-plane scan) is
left out of the triangulation, and a query with another value of it is outside. At a sample the
interpolation returns the stored value exactly. Samples with a missing channel (NaN, or outside
the CF valid range) and samples below the horizon take no part.

**Extrapolation.** A query outside the hull is *outside the domain*: like any table, a scattered
table answers NaN there with one warning that counts them (``outside = "nan"``), raises
(``"raise"``), or (``"clamp"``) takes the value of the nearest sample in the same coordinates,
warning how many queries did and how far the farthest was. ``brdftab convert`` resamples a
scattered table onto a grid with ``"clamp"`` and reports the fraction of the grid's nodes that
were extrapolated so.

Accuracy (``tests/test_scattered.py``): an RGB Lambert + GGX α = 0.3 model sampled at 3000 random
isotropic pairs (θi, θo ≤ 80°) and evaluated at 2000 held-out random pairs with θi, θo ≤ 75°
(99.2 % of them inside the hull): median relative error 0.89 %, 95th percentile 4.1 %.
"""

from __future__ import annotations

import numpy as np
import xarray as xr

from ..errors import ParameterError
from ..geometry import sph_to_vec
from .axis import HALF_PI, Axis
from .base import Grid, register

__all__ = ["ScatteredGrid", "ScatteredInterpolant", "ANGLES", "pair_space"]

FOLDS = ("none", "bilateral")
#: Under the bilateral fold, an outgoing direction this close to the plane of incidence (in
#: projected coordinates) lies on it: text files round their radians (Cornell's to 1e-6, so
#: φs = 3.141593 stands for π).
PLANE = 1e-6
#: The coordinate variables of a scattered table, one value per sample.
ANGLES = ("theta_i", "phi_i", "theta_o", "phi_o")
#: A coordinate whose samples all lie within this of one value is left out of the triangulation.
FLAT = 1e-12
#: A query this close to the samples' common value of a left-out coordinate is on it.
ON_FLAT = 1e-9
INTERPOLATION = ("linear (barycentric) on the Delaunay triangulation of the samples in projected-hemisphere "
                 "coordinates: (sin theta_i, omega_o x, omega_o y) with phi_i turned to 0 for an isotropic table, "
                 "(omega_i x, omega_i y, omega_o x, omega_o y) otherwise; outside the hull: NaN, or the nearest "
                 "sample's value when clamped")


def pair_space(wi, wo, isotropic: bool, bilateral: bool = False) -> np.ndarray:
    """Projected-hemisphere coordinates ``[M, 3]`` (isotropic) or ``[M, 4]`` of unit direction
    pairs ``[M, 3]`` (see the module docstring); ``bilateral``: ωo' mirrored onto y ≥ 0."""
    wi = np.asarray(wi, float).reshape(-1, 3)
    wo = np.asarray(wo, float).reshape(-1, 3)
    if not isotropic:
        return np.stack([wi[:, 0], wi[:, 1], wo[:, 0], wo[:, 1]], axis=1)
    s = np.hypot(wi[:, 0], wi[:, 1])
    safe = np.where(s > 0, s, 1.0)
    c, n = np.where(s > 0, wi[:, 0] / safe, 1.0), np.where(s > 0, wi[:, 1] / safe, 0.0)
    y = -n * wo[:, 0] + c * wo[:, 1]
    if bilateral:  # mirrored onto y >= 0; within PLANE of the plane of incidence is on it
        y = np.where(np.abs(y) <= PLANE, 0.0, np.abs(y))
    return np.stack([s, c * wo[:, 0] + n * wo[:, 1], y], axis=1)


def _space_to_pairs(p, isotropic: bool):
    """Direction pairs of points in :func:`pair_space` (the inverse; z from the unit length)."""
    p = np.asarray(p, float)
    if isotropic:
        s = np.clip(p[:, 0], 0.0, 1.0)
        wi = np.stack([s, np.zeros_like(s), np.sqrt(1.0 - s * s)], axis=1)
        xo, yo = p[:, 1], p[:, 2]
    else:
        xi, yi = p[:, 0], p[:, 1]
        wi = np.stack([xi, yi, np.sqrt(np.clip(1.0 - xi * xi - yi * yi, 0.0, 1.0))], axis=1)
        xo, yo = p[:, 2], p[:, 3]
    wo = np.stack([xo, yo, np.sqrt(np.clip(1.0 - xo * xo - yo * yo, 0.0, 1.0))], axis=1)
    return wi, wo


def _set_transforms(tri) -> None:
    """Give ``tri`` its barycentric transforms (:attr:`scipy.spatial.Delaunay.transform`: per
    simplex the inverse of [p_j − p_d] and the vertex p_d; NaN for a degenerate simplex), computed
    here in one batched inverse: scipy computes them simplex by simplex through LAPACK, which
    takes seconds for a few thousand simplices when the BLAS threads compete for the cores."""
    p = tri.points[tri.simplices]                        # [m, d + 1, d]
    d = p.shape[2]
    m = np.swapaxes(p[:, :d, :] - p[:, d:, :], 1, 2)      # columns p_j − p_d
    scale = np.abs(m).max(axis=(1, 2))
    det = np.linalg.det(m)
    good = np.abs(det) > 1e3 * np.finfo(float).eps * np.maximum(scale, 1e-300) ** d
    out = np.full((p.shape[0], d + 1, d), np.nan)
    out[good, :d, :] = np.linalg.inv(m[good])
    out[:, d, :] = p[:, d, :]
    if getattr(tri, "_transform", "absent") is None:  # scipy's lazily computed cache
        tri._transform = out


class ScatteredInterpolant:
    """Linear interpolation of sample points ``[N, d]`` holding ``values[N, C]`` (see the module
    docstring): ``(values [M, C], outside [M], distance [M])`` of query points, the values of
    outside queries being their nearest sample's.

    Samples in *layers* — a few distinct values of the first coordinate (the incidence sinθi of
    an isotropic table), each shared by several samples, as a gonioreflectometer measures them —
    are triangulated layer by layer in the other coordinates and interpolated linearly in the
    first between the two layers either side (a triangulation across the layers would be full
    of flat simplices); any other set on one Delaunay triangulation of all its coordinates."""

    def __init__(self, points, values, layered: bool = True):
        from scipy.spatial import cKDTree

        points = np.asarray(points, float)
        values = np.asarray(values, float)
        self.values = values
        self.tree = cKDTree(points)
        lo, hi = points.min(axis=0), points.max(axis=0)
        self.flat = np.flatnonzero(hi - lo <= FLAT)
        self.flat_at = lo[self.flat]
        self.free = np.flatnonzero(hi - lo > FLAT)
        self.layers = None
        self.tri = None
        self.line = None
        u = np.round(points[:, 0], 12)
        levels = np.unique(u)
        if (layered and points.shape[1] == 3 and 0 in self.free and 2 <= levels.size <= points.shape[0] // 3
                and all(np.count_nonzero(u == x) >= 3 for x in levels)):
            self.layers = (levels, [ScatteredInterpolant(points[u == x][:, 1:], values[u == x], False)
                                    for x in levels])
            return
        pts = points[:, self.free]
        if self.free.size == 1:
            order = np.argsort(pts[:, 0], kind="stable")
            self.line = (pts[order, 0], values[order])
        elif self.free.size >= 2:
            from scipy.spatial import ConvexHull, Delaunay, QhullError

            try:
                self.tri = Delaunay(pts)
                _set_transforms(self.tri)
                # the hull's facet planes: queries outside are found without a search of the
                # triangulation (scipy falls back to trying every simplex for them)
                self.hull = ConvexHull(pts).equations
            except (QhullError, ValueError) as exc:
                raise ParameterError("samples", f"the {len(points)} samples cannot be triangulated: they span fewer "
                                     f"dimensions than their {self.free.size} varying coordinates "
                                     f"({' '.join(str(exc).split())[:120]})") from None

    def _raw(self, q):
        """Interpolated values (NaN rows: outside) of query points ``q[M, d]``."""
        m, c = q.shape[0], self.values.shape[1]
        out = np.full((m, c), np.nan)
        if self.layers is not None:
            levels, subs = self.layers
            u = q[:, 0]
            k = np.clip(np.searchsorted(levels, u, side="right") - 1, 0, levels.size - 2)
            t = (u - levels[k]) / (levels[k + 1] - levels[k])
            t = np.where(np.abs(t) <= 1e-9, 0.0, np.where(np.abs(t - 1) <= 1e-9, 1.0, t))
            inside = (t >= 0) & (t <= 1)
            for j in np.unique(k[inside]):
                rows = np.flatnonzero(inside & (k == j))
                tt = t[rows][:, None]
                lo = np.where(tt < 1, subs[j]._raw(q[rows, 1:]), 0.0)
                hi = np.where(tt > 0, subs[j + 1]._raw(q[rows, 1:]), 0.0)
                out[rows] = (1 - tt) * lo + tt * hi  # NaN where a needed layer is outside
            return out
        ok = np.all(np.abs(q[:, self.flat] - self.flat_at) <= ON_FLAT, axis=1)
        if self.tri is not None:
            a, b = self.hull[:, :-1], self.hull[:, -1]
            rows = np.flatnonzero(ok)
            x = q[rows][:, self.free]
            near = np.all(x @ a.T + b <= ON_FLAT, axis=1)
            rows, x = rows[near], x[near]
            # the simplex of each query and its barycentric coordinates (scipy's affine
            # transforms, Delaunay.transform): the weights of the simplex's samples
            simplex = self.tri.find_simplex(x)
            found = simplex >= 0
            rows, x, simplex = rows[found], x[found], simplex[found]
            if rows.size:
                d = x.shape[1]
                t = self.tri.transform[simplex]
                bary = np.einsum("mij,mj->mi", t[:, :d, :], x - t[:, d, :])
                w = np.concatenate([bary, 1.0 - bary.sum(axis=1, keepdims=True)], axis=1)
                out[rows] = np.einsum("mk,mkc->mc", w, self.values[self.tri.simplices[simplex]])
        elif self.line is not None:
            x, v = self.line
            xq = q[:, self.free[0]]
            rows = np.flatnonzero(ok & (xq >= x[0] - ON_FLAT) & (xq <= x[-1] + ON_FLAT))
            for j in range(c):
                out[rows, j] = np.interp(xq[rows], x, v[:, j])
        else:
            out[ok] = self.values[0]
        return out

    def inside(self, q) -> np.ndarray:
        q = np.asarray(q, float)
        return ~np.isnan(self._raw(q)).any(axis=1)

    def __call__(self, q):
        q = np.asarray(q, float)
        out = self._raw(q)
        outside = np.isnan(out).any(axis=1)
        dist = np.zeros(q.shape[0])
        rows = np.flatnonzero(outside)
        if rows.size:
            d, j = self.tree.query(q[rows])
            out[rows] = self.values[j]
            dist[rows] = d
        return out, outside, dist

    def centres(self, rng, n: int) -> np.ndarray:
        """``n`` points where linear interpolation is least accurate: centroids of random simplices
        (between layers: a layer's simplex centroid half way to the next layer)."""
        if self.layers is not None:
            levels, subs = self.layers
            k = rng.integers(0, levels.size - 1, n)
            out = np.empty((n, 3))
            for j in np.unique(k):
                rows = np.flatnonzero(k == j)
                out[rows, 0] = 0.5 * (levels[j] + levels[j + 1])
                out[rows, 1:] = subs[j].centres(rng, rows.size)
            return out
        pts = self.tree.data
        if self.tri is None:
            return pts[rng.integers(0, pts.shape[0], n)]
        simplices = self.tri.simplices
        pick = simplices[rng.integers(0, len(simplices), n)]
        out = np.repeat(pts[:1], n, axis=0)
        out[:, self.free] = self.tri.points[pick].mean(axis=1)
        return out


@register
class ScatteredGrid(Grid):
    """Scattered direction pairs (``N`` samples on the axis ``sample``); see the module docstring."""

    type_name = "scattered"
    summary = ("Scattered direction pairs (theta_i, phi_i, theta_o, phi_o) of a measurement or a text table, "
               "interpolated linearly on their Delaunay triangulation (ASTM E1392 and CSV files).")
    parameterizations = ("scattered",)
    parameterization = "scattered"
    compiled = False
    node_checks = False
    #: A table on this grid interpolates through :meth:`interpolant` (not :meth:`locate`'s indices).
    scattered = True
    params = ()

    def __init__(self, theta_i, phi_i, theta_o, phi_o, *, phi_d_fold: str = "none"):
        arrays = [np.asarray(a, float).reshape(-1) for a in (theta_i, phi_i, theta_o, phi_o)]
        n = arrays[0].size
        if n == 0:
            raise ParameterError("sample", "a scattered table needs at least one sample")
        for name, a in zip(ANGLES, arrays):
            if a.size != n:
                raise ParameterError(name, f"{a.size} values for {n} samples")
            if not np.all(np.isfinite(a)):
                k = int(np.flatnonzero(~np.isfinite(a))[0])
                raise ParameterError(name, f"sample {k}: the angle is not a finite number")
        for name, a in (("theta_i", arrays[0]), ("theta_o", arrays[2])):
            bad = np.flatnonzero((a < 0) | (a >= HALF_PI))
            if bad.size:
                k = int(bad[0])
                raise ParameterError(name, f"sample {k}: {name} = {np.degrees(a[k]):.6g} deg; polar angles lie in "
                                     "[0, 90) deg (angles in radians where the file says so)")
        if phi_d_fold not in FOLDS:
            raise ParameterError("phi_d_fold", f"expected one of {', '.join(map(repr, FOLDS))}, got {phi_d_fold!r}")
        self.theta_i, self.phi_i, self.theta_o, self.phi_o = arrays
        #: "bilateral": the samples are one side of the plane of incidence of an isotropic
        #: surface, mirrored onto the other (f(θi, θo, Δφ) = f(θi, θo, −Δφ))
        self.phi_d_fold = phi_d_fold
        self.axes = (Axis("sample", np.arange(n, dtype=float)),)
        self._hull = {}
        #: The interpolation space of the table on this grid (a table sets it from its isotropy).
        self.space_isotropic = True

    # -- what a table stores -----------------------------------------------------------------
    def attrs(self) -> dict:
        return {"parameterization": "scattered", "grid": "scattered", "sample_position": "explicit",
                "phi_d_fold": self.phi_d_fold, "interpolation": INTERPOLATION}

    def coord_attrs(self, name) -> dict:
        return {"long_name": "sample number (a scattered direction pair)", "node_rule": "explicit"}

    def aux_coords(self) -> dict:
        """The per-sample angles as coordinate variables over ``sample`` (radians)."""
        from .axis import LONG_NAMES

        return {name: xr.Variable(("sample",), getattr(self, name), attrs={
            "units": "rad", "long_name": LONG_NAMES[name]}) for name in ANGLES}

    @classmethod
    def from_dataset(cls, ds, attrs):
        from .base import _DEGREE_UNITS, _RADIAN_UNITS

        vals = []
        for name in ANGLES:
            if name not in ds.variables:
                raise ParameterError(name, f"missing coordinate '{name}' (one angle per sample)")
            var = ds[name]
            if var.dims != ("sample",) or var.dtype.kind not in "fiu":
                raise ParameterError(name, f"coordinate '{name}' must be numeric over the dimension 'sample'")
            units = str(var.attrs.get("units", "")).strip().lower()
            v = np.asarray(var.values, float)
            if units in _DEGREE_UNITS:
                v = np.radians(v)
            elif units not in _RADIAN_UNITS:
                raise ParameterError(name, f"coordinate '{name}' has units {var.attrs.get('units')!r}; expected 'rad' "
                                     "or 'degree'")
            vals.append(v)
        from .base import choice_attr

        fold = choice_attr(attrs, "phi_d_fold", FOLDS, default="none")
        try:
            return cls(*vals, phi_d_fold=fold)
        except ParameterError as exc:
            raise ParameterError(exc.key, f"coordinate '{exc.key}': {exc.detail}") from None

    @classmethod
    def from_config(cls, values: dict):
        raise ParameterError("type", "a scattered grid holds the samples of a file (ASTM, CSV); a spec tabulates on "
                             "a gonio or Rusinkiewicz grid, and a scattered format writes that grid's nodes")

    @classmethod
    def from_grid(cls, grid: Grid) -> "ScatteredGrid":
        """The nodes of ``grid`` whose directions both lie above the horizon, as scattered samples
        (C order, duplicates of the same pair kept once)."""
        from ..geometry import vec_to_sph

        if isinstance(grid, ScatteredGrid):
            return grid
        keep = np.flatnonzero(grid.node_above_horizon().reshape(-1))
        wi, wo = grid.directions()
        wi, wo = wi[keep], wo[keep]
        ti, pi_ = vec_to_sph(wi)
        to, po = vec_to_sph(wo)
        pi_ = np.where(ti == 0.0, 0.0, pi_)  # the normal: one direction whatever its azimuth
        po = np.where(to == 0.0, 0.0, po)
        good = (ti < HALF_PI) & (to < HALF_PI)
        a = np.stack([ti, pi_, to, po], axis=1)[good]
        _, first = np.unique(np.round(a, 12), axis=0, return_index=True)
        a = a[np.sort(first)]
        out = cls(*a.T)
        out.made_from = grid  # (the grid a writer was given: its nodes are the samples)
        return out

    # -- shape and directions ----------------------------------------------------------------
    def _directions(self, idx):
        (k,) = idx
        return sph_to_vec(self.theta_i[k], self.phi_i[k]), sph_to_vec(self.theta_o[k], self.phi_o[k])

    def pair_directions(self, coords):
        """``(wi, wo)`` of sample numbers (one array, the ``sample`` coordinate)."""
        k = np.clip(np.rint(np.asarray(coords[0], float)).astype(np.intp), 0, self.size - 1)
        return self._directions((k,))

    def block(self, key) -> "ScatteredGrid":
        (s,) = key
        g = ScatteredGrid(self.theta_i[s], self.phi_i[s], self.theta_o[s], self.phi_o[s], phi_d_fold=self.phi_d_fold)
        g.space_isotropic = self.space_isotropic
        return g

    def equals(self, other) -> bool:
        """The same samples (angles within 1e-12 rad: a text file's degrees read back)."""
        return (isinstance(other, ScatteredGrid) and other.size == self.size and other.phi_d_fold == self.phi_d_fold
                and all(np.allclose(getattr(self, n), getattr(other, n), rtol=0, atol=1e-12) for n in ANGLES))

    def describe(self) -> str:
        return f"scattered[{self.size} samples]"

    def coverage_text(self) -> str:
        """The ranges the samples span (degrees)."""
        t = np.degrees([self.theta_i.min(), self.theta_i.max(), self.theta_o.min(), self.theta_o.max()])
        return f"theta_i {t[0]:.4g}..{t[1]:.4g} deg, theta_o {t[2]:.4g}..{t[3]:.4g} deg"

    def domain_text(self) -> str:
        return f"the hull of its {self.size} samples ({self.coverage_text()})"

    def incidence_angles(self) -> np.ndarray:
        """The distinct θi of the samples (those within 1e-9 rad of each other counted once, as
        the first sample holds it), increasing."""
        _, first = np.unique(np.round(self.theta_i, 9), return_index=True)
        return self.theta_i[first]

    # -- interpolation ------------------------------------------------------------------------
    def query_space(self, wi, wo, isotropic: bool) -> np.ndarray:
        """The interpolation coordinates of direction pairs for a table of this isotropy (a
        bilateral fold implies isotropy)."""
        bilateral = self.phi_d_fold == "bilateral"
        return pair_space(wi, wo, isotropic or bilateral, bilateral)

    def space(self, isotropic: bool) -> np.ndarray:
        wi, wo = self.directions()
        return self.query_space(wi, wo, isotropic)

    @staticmethod
    def one_sided(theta_i, phi_i, theta_o, phi_o) -> bool:
        """True when the samples share one incident azimuth and lie on one side of the plane of
        incidence (relative azimuths all in [0, π] or all in [−π, 0]), as gonio measurements of
        isotropic surfaces often do: such samples are read with the bilateral fold."""
        if np.ptp(phi_i) != 0.0:
            return False
        y = np.sin(theta_o) * np.sin(np.asarray(phi_o) - phi_i[0])
        return bool(np.all(y <= 1e-9) or np.all(y >= -1e-9))

    def interpolant(self, values, isotropic: bool) -> ScatteredInterpolant:
        """The interpolant of ``values[N, C]`` (NaN: missing) over the samples that hold data in
        every channel (and lie above the horizon)."""
        values = np.asarray(values, float).reshape(self.size, -1)
        ok = np.isfinite(values).all(axis=1)
        if not ok.any():
            raise ParameterError("brdf", "no sample holds data in every channel: nothing to interpolate")
        return ScatteredInterpolant(self.space(isotropic)[ok], values[ok])

    def _hull_of(self, isotropic: bool) -> ScatteredInterpolant:
        key = bool(isotropic)
        if key not in self._hull:
            self._hull[key] = ScatteredInterpolant(self.space(isotropic), np.zeros((self.size, 1)))
        return self._hull[key]

    def locate(self, wi, wo, isotropic: bool = False):
        """``([NaN indices], outside)``: a scattered grid has no fractional indices; ``outside``
        is True for pairs outside the hull of its samples."""
        wi = np.asarray(wi, float)
        lead = wi.shape[:-1]
        q = self.query_space(wi, wo, isotropic)
        outside = ~self._hull_of(isotropic).inside(q)
        return [np.full(lead, np.nan)], outside.reshape(lead)

    def cell_centres(self, n: int, seed: int = 0, at_nodes=()):
        """``(wi, wo)`` at ``n`` points where the interpolation is least accurate (centroids of
        random simplices, half way between incidence layers), above the horizon; for the checks."""
        rng = np.random.default_rng(seed)
        iso = self.space_isotropic or self.phi_d_fold == "bilateral"
        wi, wo = _space_to_pairs(self._hull_of(iso).centres(rng, n), iso)
        keep = (wi[:, 2] > 1e-9) & (wo[:, 2] > 1e-9)
        return wi[keep], wo[keep]
