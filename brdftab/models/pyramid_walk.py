"""The sequence table of the ``pyramid-microfacet`` model's ``walk = "traced"``: how often a
ray tracer of the random pyramid array (:mod:`brdftab.models.pyramid_tracer`) sees each face
sequence, tabulated over incidence and interpolated.

``pyramid_walk.npz`` (made by ``tools/make_pyramid_walk.py``) holds, at incidence nodes
(θ, φ) with φ measured from a face normal's azimuth over the symmetry domain 0° … 45° (the
random array is invariant under 90° turns and the mirrors about a face normal's azimuth and
about the diagonal), the fractions of the rays that

* first hit face k (``first`` [θ, φ, 4]),
* escape after exactly the face sequence s of 1 … ``depth`` bounces (``escape`` [θ, φ, codes];
  s = (k1, …, kL) has code ``offset(L) + Σ k_i 4^(L−i)``, offset(L) = (4^L − 4)/3),
* are still inside after ``depth`` bounces, by their first ``depth`` faces (``inside``
  [θ, φ, 4^depth]).

:class:`WalkTable` interpolates them bilinearly in (θ, φ) (θ clamped to the last node),
relative to the uncorrelated walk's branching (:meth:`WalkTable.ratios`), and relabels the
faces of the node's symmetry image back to the query's. The interpolation is compiled
(:func:`interpolate_rows`; :func:`cell_of` and :func:`ratio_in_cell` for the kernels of
:mod:`~brdftab.models.pyramid`);
inside :func:`brdftab.brdf.numpy_reference` the numpy code runs instead (the parity tests
compare the two).
"""

from __future__ import annotations

import math
from functools import lru_cache
from pathlib import Path

import numpy as np

from .._jit import device, kernel

TABLE = Path(__file__).with_name("pyramid_walk.npz")


def offset(length) -> int:
    """First code of the sequences of ``length`` bounces: (4^L − 4)/3."""
    return (4 ** np.asarray(length) - 4) // 3


def n_codes(depth: int) -> int:
    """Number of codes of the sequences of 1 … ``depth`` bounces."""
    return int(offset(depth + 1))


def symmetry_permutations(depth: int):
    """Face and code maps of the 8 symmetries of the array, indexed ``2 r + m``: the query's
    direction turned by −90° r, then mirrored about the diagonal when m = 1, lands in the
    symmetry domain; its face k is the domain's face ``faces[op, k]``. Returns (faces [8, 4],
    escape codes [8, n_codes], inside codes [8, 4^depth]): query code c ↦ domain code."""
    faces = np.zeros((8, 4), int)
    for r in range(4):
        for m in range(2):
            k = (np.arange(4) - r) % 4
            faces[2 * r + m] = (1 - k) % 4 if m else k
    esc = np.zeros((8, n_codes(depth)), int)
    ins = np.zeros((8, 4 ** depth), int)
    for op in range(8):
        for length in range(1, depth + 1):
            digits = _digits(np.arange(4 ** length), length)
            esc[op, offset(length):offset(length + 1)] = offset(length) + _code(faces[op][digits])
        ins[op] = _code(faces[op][_digits(np.arange(4 ** depth), depth)])
    return faces, esc, ins


def _digits(code, length):
    """Faces [N, length] of base-4 codes (first face most significant)."""
    return (np.asarray(code)[:, None] // 4 ** np.arange(length - 1, -1, -1)) % 4


def _code(digits):
    return (digits * 4 ** np.arange(digits.shape[1] - 1, -1, -1)).sum(axis=1)


def domain_op(phi):
    """(symmetry index, azimuth in the domain 0 … π/4) of azimuths ``phi`` [rad] measured from
    a face normal's azimuth."""
    quarter = 0.5 * np.pi
    p = np.mod(np.asarray(phi, float), 2.0 * np.pi)
    r = np.minimum((p // quarter).astype(int), 3)
    p = p - r * quarter
    m = p > 0.5 * quarter
    return 2 * r + m, np.where(m, quarter - p, p)


class WalkTable:
    """Tabulated sequence fractions (see the module) and their interpolation.

    The walk needs the tracer's branching after a sequence s: escape, or go on to face j. Near
    the incidence where a branch opens (the travelling direction crosses the horizon or the
    plane of face j) its probability grows from 0 with a kink that linear interpolation would
    smear over a whole node step. So what is interpolated is the tracer's branching relative to
    the uncorrelated walk's at the same incidence, whose branches open at exactly the same
    incidences (escape with G1(d), face j with (1 − G1(d)) a_j T_j(−d) / Σ_l a_l T_l(−d), Dirac
    facets): the ratio of the interpolated tracer fractions to the interpolated uncorrelated
    ones, each weighted by the fraction reaching s (:meth:`ratios`)."""

    def __init__(self, theta, phi, depth, first, escape, inside, meta=None):
        self.theta = np.asarray(theta, float)
        self.phi = np.asarray(phi, float)
        self.depth = int(depth)
        self.first = np.asarray(first, float)
        self.escape = np.asarray(escape, float)
        self.inside = np.asarray(inside, float)
        self.meta = dict(meta or {})
        self.faces, self.esc_perm, self.ins_perm = symmetry_permutations(self.depth)
        self._ratio_parts = None

    @classmethod
    def load(cls, path=TABLE) -> WalkTable:
        with np.load(path) as z:
            meta = {k[5:]: z[k][()] for k in z.files if k.startswith("meta_")}
            return cls(np.radians(z["theta_deg"]), np.radians(z["phi_deg"]), int(z["depth"]), z["first"],
                       z["escape"], z["inside"], meta)

    def save(self, path):
        np.savez_compressed(path, theta_deg=np.degrees(self.theta), phi_deg=np.degrees(self.phi), depth=self.depth,
                            first=self.first.astype(np.float32), escape=self.escape.astype(np.float32),
                            inside=self.inside.astype(np.float32),
                            **{f"meta_{k}": np.asarray(v) for k, v in self.meta.items()})

    def reach(self):
        """Fraction reaching the L-th hit along each sequence s of 1 … depth bounces (indexed
        by s's code) [θ, φ, n_codes]: what escapes after s plus what reaches s + j, j = 0 … 3."""
        out = np.zeros_like(self.escape)
        lo = offset(self.depth)
        below = self.escape[..., lo:] + self.inside
        out[..., lo:] = below
        for level in range(self.depth - 1, 0, -1):
            a, b = offset(level), offset(level + 1)
            below = self.escape[..., a:b] + below.reshape(below.shape[:-1] + (4 ** level, 4)).sum(axis=-1)
            out[..., a:b] = below
        return out

    def uncorrelated(self):
        """The uncorrelated walk's branching at the nodes (Dirac facets, φ0 = 0): probability
        [θ, φ, n_codes] of escaping right after s, and of going on to the last face of s (for
        s of two or more bounces), given s; 0 on branches the geometry closes."""
        from .pyramid import FACET_WEIGHT, facet_normals

        f = facet_normals(0.0)
        th, ph = np.meshgrid(self.theta, self.phi, indexing="ij")
        wi = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=-1)
        esc = np.zeros(th.shape + (n_codes(self.depth),))
        hit = np.zeros_like(esc)
        # level 1: d after the first face, feasible where that face faces ωi
        d = -wi[..., None, :] + 2.0 * (wi @ f.T)[..., None] * f                # [θ, φ, 4, 3]
        ok = (wi @ f.T) > 0
        for level in range(1, self.depth + 1):
            lo = offset(level)
            cd = np.einsum("...j,kj->...k", d, f)                              # ⟨d, f_k⟩
            area = FACET_WEIGHT * np.maximum(-cd, 0.0)
            up = d[..., 2] > 0
            with np.errstate(divide="ignore", invalid="ignore"):
                g1 = np.where(up, np.minimum(1.0, d[..., 2] / (FACET_WEIGHT * np.maximum(cd, 0.0).sum(axis=-1))), 0.0)
                split = area / area.sum(axis=-1, keepdims=True)
            g1 = np.where(ok, np.nan_to_num(g1, nan=1.0), 0.0)
            esc[..., lo:offset(level + 1)] = g1
            if level == self.depth:
                break
            p = np.where(ok[..., None], (1.0 - g1)[..., None] * np.nan_to_num(split), 0.0)
            hit[..., offset(level + 1):offset(level + 2)] = p.reshape(p.shape[:-2] + (-1,))
            d = d[..., None, :] - 2.0 * cd[..., None] * f                      # d reflected on each face
            d = d.reshape(d.shape[:-3] + (-1, 3))
            ok = (ok[..., None] & (cd < 0)).reshape(ok.shape[:-1] + (-1,))
        return esc, hit

    def _parts(self):
        """Numerators and denominators of :meth:`ratios` at the nodes."""
        if self._ratio_parts is None:
            reach = self.reach()
            u_esc, u_hit = self.uncorrelated()
            parent = np.zeros_like(reach)
            for level in range(2, self.depth + 1):
                a, b = offset(level), offset(level + 1)
                parent[..., a:b] = np.repeat(reach[..., offset(level - 1):a], 4, axis=-1)
            self._ratio_parts = (np.stack([self.escape, reach * u_esc], axis=-1),
                                 np.stack([reach, parent * u_hit], axis=-1))
        return self._ratio_parts

    @staticmethod
    def _weights(grid, x):
        """Linear interpolation indices and weights on ``grid`` (clamped at its ends)."""
        x = np.clip(x, grid[0], grid[-1])
        j = np.clip(np.searchsorted(grid, x, side="right") - 1, 0, grid.size - 2)
        t = (x - grid[j]) / (grid[j + 1] - grid[j])
        return j, t

    def _interpolate(self, w, arrays, columns):
        """Bilinear interpolation of ``arrays`` [θ, φ, n_codes, ...] at unit directions ``w[U, 3]``
        for the query's codes ``columns`` (see :meth:`_interpolate_numpy`), compiled
        (:func:`interpolate_rows`) unless inside :func:`brdftab.brdf.numpy_reference`."""
        if not compiled():
            return self._interpolate_numpy(w, arrays, columns)
        theta_w, phi_w = self.angles(w)
        columns = np.ascontiguousarray(columns, dtype=np.int64)                # [U, C] or [1, C]
        out = []
        for arr in arrays:
            extra = arr.shape[3:]
            flat = self._flat(arr)
            res = np.empty((w.shape[0], columns.shape[1], flat.shape[1]))
            interpolate_rows(theta_w, phi_w, columns, flat, self.theta, self.phi, self.esc_perm, res)
            out.append(res.reshape((w.shape[0], columns.shape[1]) + extra))
        return out

    def _flat(self, arr):
        """``arr`` [θ, φ, n_codes, ...] as a C-contiguous [θ φ n_codes, rest] array (kept for the
        arrays of :meth:`_parts`, which live as long as the table)."""
        cache = self.__dict__.setdefault("_flat_cache", {})
        key = id(arr)
        if key not in cache or cache[key][0] is not arr:
            cache[key] = (arr, np.ascontiguousarray(arr.reshape(arr.shape[0] * arr.shape[1] * arr.shape[2], -1),
                                                    dtype=float))
        return cache[key][1]

    def ratio_arrays(self, hit=False):
        """What the compiled kernels need to evaluate the ratios of one code (:func:`ratio_in_cell`):
        (θ nodes, φ nodes, code maps, flat escape parts[, flat hit parts])."""
        parts = self._parts()
        return (self.theta, self.phi, np.ascontiguousarray(self.esc_perm, dtype=np.int64), self._flat(parts[0])) \
            + ((self._flat(parts[1]),) if hit else ())

    @staticmethod
    def angles(w):
        """Polar angles and azimuths of unit directions ``w[U, 3]`` as :meth:`_interpolate` takes
        them (the compiled kernels take these, computed by numpy)."""
        w = np.asarray(w, float).reshape(-1, 3)
        return np.arccos(np.clip(w[:, 2], -1.0, 1.0)), np.arctan2(w[:, 1], w[:, 0])

    def _interpolate_numpy(self, w, arrays, columns):
        """Bilinear interpolation of ``arrays`` [θ, φ, n_codes, ...] at unit directions
        ``w[U, 3]`` (azimuths from a face normal's) for the query's codes ``columns``:
        [U, len(columns), ...] each (the node's codes are the query's relabelled by the symmetry
        that maps w into the domain)."""
        w = np.asarray(w, float).reshape(-1, 3)
        theta = np.arccos(np.clip(w[:, 2], -1.0, 1.0))
        op, phi = domain_op(np.arctan2(w[:, 1], w[:, 0]))
        i, s = self._weights(self.theta, theta)
        j, t = self._weights(self.phi, phi)
        cols = self.esc_perm[op[:, None], columns]                            # [U, C]
        nc = self.escape.shape[-1]
        base = ((i * self.phi.size + j) * nc)[:, None] + cols                   # flat (θ node, φ node, code)
        step = self.phi.size * nc
        weights = ((1 - s) * (1 - t), (1 - s) * t, s * (1 - t), s * t)
        out = []
        for arr in arrays:
            flat = arr.reshape((-1,) + arr.shape[3:])
            extra = (slice(None), None) + (None,) * (arr.ndim - 3)
            v = 0.0
            for wgt, off in zip(weights, (0, nc, step, step + nc)):
                v = v + wgt[extra] * np.take(flat, base + off, axis=0)
            out.append(v)
        return out

    def ratios(self, w, columns=slice(None), hit=True):
        """The tracer's branching relative to the uncorrelated walk's, interpolated at unit
        directions ``w[U, 3]`` given in the frame of the facets (azimuth from a face normal's):
        (escape [U, C], hit [U, C]) for the codes ``columns`` (default all; or [U, C] codes
        per direction): for a sequence s,
        escape[s] multiplies the uncorrelated probability of escaping right after s, and
        hit[s] that of going on to s's last face after s without it. NaN where no node near w
        sees a ray on the branch's parent while the branch is open (no information). With
        ``hit`` False, hit is None."""
        if not isinstance(columns, np.ndarray):
            columns = np.arange(n_codes(self.depth))[columns][None, :]
        parts = self._interpolate(w, self._parts()[:2 if hit else 1], columns)
        with np.errstate(divide="ignore", invalid="ignore"):
            r = [np.where(p[..., 1] > 0, p[..., 0] / p[..., 1], np.nan) for p in parts]
        return r[0], (r[1] if hit else None)


def compiled() -> bool:
    """Whether the compiled helpers run (False inside :func:`brdftab.brdf.numpy_reference`)."""
    from ..brdf import _COMPILED

    return _COMPILED[-1]


# --------------------------------------------------------------------------------------------
# Compiled interpolation: the arithmetic of WalkTable._interpolate_numpy, one direction at a time


@device
def _np_mod(a, b):
    """numpy's ``np.mod`` of floats (b > 0): fmod, then shifted into [0, b)."""
    m = np.fmod(a, b)
    if m != 0.0 and m < 0.0:
        m += b
    return m


@device
def _floordiv_rest(a, b, m):
    """numpy's ``a // b`` of floats (b > 0), which rounds the quotient as its divmod does, given
    m = fmod(a, b)."""
    div = (a - m) / b
    if m != 0.0 and m < 0.0:
        div -= 1.0
    if div == 0.0:
        return 0.0
    f = math.floor(div)
    if div - f > 0.5:
        f += 1.0
    return f


@device
def _fmod_small(a, b):
    """fmod(a, b) for 0 <= a <= 4b (b > 0), exact as fmod is: by subtractions of b and 2b, each
    exact (Sterbenz: the operands are within a factor 2)."""
    if a < b:
        return a
    if a < 2.0 * b:
        return a - b
    r = a - 2.0 * b
    if r < b:
        return r
    if r < 2.0 * b:
        return r - b
    return r - 2.0 * b


@device(inline=True)
def _axis_index(grid, x):
    """The index of :func:`_axis` for ``x`` already clamped to the nodes: the last node at or
    below x (numpy's ``searchsorted(side="right") - 1``, at most the last cell's), found from a
    guess by the mean step, stepping to the neighbours (the nodes increase)."""
    n = grid.shape[0]
    g = (x - grid[0]) / (grid[n - 1] - grid[0]) * (n - 1)
    j = int(g) if (g >= 0.0 and g < n) else 0
    while j > 0 and grid[j] > x:
        j -= 1
    while j < n - 1 and grid[j + 1] <= x:
        j += 1
    return min(max(j, 0), n - 2)


@device(inline=True)
def _axis(grid, x):
    """:meth:`WalkTable._weights` of one value: (index, weight)."""
    n = grid.shape[0]
    x = min(max(x, grid[0]), grid[n - 1])
    j = _axis_index(grid, x)
    return j, (x - grid[j]) / (grid[j + 1] - grid[j])


@device
def _domain(phi_w):
    """The symmetry index of :func:`domain_op` and the azimuth it maps ``phi_w`` to. (numpy's mod
    and floor division of an azimuth within ±2π take no fmod: fmod(φ, 2π) is φ there, and
    :func:`_fmod_small` gives the quarter's remainder.)"""
    quarter = 0.5 * np.pi
    two_pi = 2.0 * np.pi
    if -two_pi < phi_w < two_pi:
        p = phi_w + two_pi if phi_w < 0.0 else phi_w
    else:
        p = _np_mod(phi_w, two_pi)
    m = _fmod_small(p, quarter) if (p >= 0.0 and p <= 4.0 * quarter) else np.fmod(p, quarter)
    r = min(int(_floordiv_rest(p, quarter, m)), 3)
    p = p - r * quarter
    m = p > 0.5 * quarter
    op = 2 * r + (1 if m else 0)
    if m:
        p = quarter - p
    return op, p


@device(inline=True)
def cell_of(theta_w, phi_w, theta, phi):
    """Symmetry index, flat index of the (θ, φ) cell's first node and the bilinear weights of a
    direction of polar angle ``theta_w`` and azimuth ``phi_w`` (from a face normal's;
    :func:`domain_op`)."""
    op, p = _domain(phi_w)
    i, s = _axis(theta, theta_w)
    j, t = _axis(phi, p)
    w00, w01, w10, w11 = corner_weights(s, t)
    return op, i * phi.shape[0] + j, w00, w01, w10, w11


@device
def corner_weights(s, t):
    """The bilinear weights of a cell's four nodes at fractions ``s`` (θ), ``t`` (φ)."""
    return (1 - s) * (1 - t), (1 - s) * t, s * (1 - t), s * t


@device
def bilinear_ratio(w00, w01, w10, w11, n00, n01, n10, n11, d00, d01, d10, d11):
    """The interpolated ratio Σ w n / Σ w d of a cell's nodes (numerators ``n``, denominators
    ``d``), 1 where no node has rays (the sum of d is 0)."""
    num = (((0.0 + w00 * n00) + w01 * n01) + w10 * n10) + w11 * n11
    den = (((0.0 + w00 * d00) + w01 * d01) + w10 * d10) + w11 * d11
    if den > 0.0:
        return num / den
    return 1.0


@kernel
def interpolate_rows(theta_w, phi_w, columns, flat, theta, phi, esc_perm, out):
    """``out[U, C, P]``: ``flat`` [θ φ n_codes, P] interpolated at directions of polar angles
    ``theta_w[U]`` and azimuths ``phi_w[U]`` for the query codes ``columns`` [U, C] (or [1, C]
    for every direction). (The angles come from numpy: its arctan2 and libm's differ in the
    last digit, which the weights next to a node whose value is 0 would magnify.)"""
    nc = esc_perm.shape[1]
    step = phi.shape[0] * nc
    for u in range(theta_w.shape[0]):
        op, cell, w00, w01, w10, w11 = cell_of(theta_w[u], phi_w[u], theta, phi)
        cu = u if columns.shape[0] > 1 else 0
        for c in range(columns.shape[1]):
            b = cell * nc + esc_perm[op, columns[cu, c]]
            for q in range(flat.shape[1]):
                out[u, c, q] = (((0.0 + w00 * flat[b, q]) + w01 * flat[b + nc, q]) + w10 * flat[b + step, q]) \
                    + w11 * flat[b + step + nc, q]


@device(inline=True)
def ratio_in_cell(op, cell, w00, w01, w10, w11, code, phi, esc_perm, flat):
    """A ratio of :meth:`WalkTable.ratios` for one query ``code`` at a direction in the cell
    ``cell`` (symmetry ``op``, weights ``w``: :func:`cell_of`), ``flat`` :meth:`WalkTable.ratio_arrays`'
    escape parts or the hit parts; 1 where no node of the cell sees a ray on the branch (NaN
    there)."""
    nc = esc_perm.shape[1]
    step = phi.shape[0] * nc
    b = cell * nc + esc_perm[op, code]
    return bilinear_ratio(w00, w01, w10, w11, flat[b, 0], flat[b + nc, 0], flat[b + step, 0], flat[b + step + nc, 0],
                          flat[b, 1], flat[b + nc, 1], flat[b + step, 1], flat[b + step + nc, 1])


@lru_cache(maxsize=1)
def table() -> WalkTable:
    """The shipped table (loaded once)."""
    return WalkTable.load()
