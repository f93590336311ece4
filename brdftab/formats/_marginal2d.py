"""The continuous ``Marginal2D`` warp of Mitsuba 3, vectorized with numpy.

RGL ``.bsdf`` files store their reflectance on a *warped* 2-D domain: the reader maps the
half vector to the unit square by inverting a piecewise-bilinear 2-D distribution (the VNDF),
then interpolates the stored values there. A writer has to reproduce that map exactly, so
this module mirrors Mitsuba 3's ``Marginal2D<Float, Dimension, Continuous=true>``
(``include/mitsuba/core/distr_2d.h``) step by step:

* data ``[p0, p1, ..., H, W]``: one ``H × W`` slice per combination of the conditioning
  parameters; nodes at ``(x/(W−1), y/(H−1))`` including both ends;
* per slice, a conditional CDF along x (trapezoid rule, width ``1/(W−1)``) and a marginal CDF
  along y, accumulated in double precision and stored in float32, then normalized by the
  slice total (``normalize=True``); data are scaled by the same factor;
* between parameter values the normalized data and CDFs are interpolated linearly (weights
  clamped to [0, 1]; a parameter with one value has weight 1);
* ``sample`` inverts the marginal, then the conditional (linear densities along each
  segment); ``invert`` is its exact inverse; ``eval`` is bilinear interpolation.

Tables are kept in float32 as Mitsuba keeps them; arithmetic on them is in float64, so the
results differ from Mitsuba's float32 arithmetic by rounding only: the RGL reader built on this
module matches Mitsuba's ``measured`` eval to 5e-5 relative (measured ≤ 1.3e-5;
``tests/test_rgl.py``, ``assert_reader_is_mitsuba``).
"""

from __future__ import annotations

import itertools

import numpy as np

__all__ = ["Marginal2D"]

EPS32 = float(np.float32(2.0 ** -24))
ONE_MINUS_EPS32 = float(np.float32(1.0 - 2.0 ** -24))
#: Points processed at once (bounds the (points × row) temporaries of ``sample``).
CHUNK = 1 << 15


def _lerp(a, b, t):
    return a + t * (b - a)


class Marginal2D:
    """A conditional piecewise-bilinear 2-D distribution (or plain interpolant).

    ``data``: array ``param_res + (H, W)``; ``params``: one 1-D array of parameter values per
    leading axis (increasing). ``normalize=False, sampling=False`` gives a raw bilinear
    interpolant (Mitsuba's ``ndf``, ``sigma`` and ``spectra`` tables).
    """

    def __init__(self, data, params=(), normalize: bool = True, sampling: bool = True):
        data = np.asarray(data, np.float32)
        self.params = [np.asarray(p, np.float32).astype(np.float64) for p in params]
        res = data.shape[:len(self.params)]
        if data.ndim != len(self.params) + 2 or any(len(p) != r for p, r in zip(self.params, res)):
            raise ValueError("data shape does not match the parameter resolutions")
        self.h, self.w = data.shape[-2:]
        if self.h < 2 or self.w < 2:
            raise ValueError("input array resolution must be >= 2")
        self.res = res
        self.n_slices = int(np.prod(res, dtype=np.int64)) if res else 1
        # slice strides of the parameters (C order; a parameter with one value has stride 0)
        strides, acc = [], 1
        for r in reversed(res):
            strides.append(acc if r > 1 else 0)
            acc *= r
        self.strides = strides[::-1]
        d = data.reshape(self.n_slices, self.h, self.w)
        self.sampling = sampling
        if sampling:
            dd = d.astype(np.float64)
            cond = np.cumsum((0.5 / (self.w - 1)) * (dd[:, :, :-1] + dd[:, :, 1:]), axis=2)  # [S, H, W-1]
            row = cond[:, :, -1]
            marg = np.cumsum((0.5 / (self.h - 1)) * (row[:, :-1] + row[:, 1:]), axis=1)  # [S, H-1]
            with np.errstate(all="ignore"):  # float32 overflow of absurd data gives inf/NaN, not an error
                norm = (1.0 / marg[:, -1]).astype(np.float32) if normalize else np.ones(self.n_slices, np.float32)
                self.cond = (cond.astype(np.float32) * norm[:, None, None]).astype(np.float64)
                self.marg = (marg.astype(np.float32) * norm[:, None]).astype(np.float64)
                self.data = (d * norm[:, None, None]).astype(np.float64)
        elif normalize:
            raise ValueError("normalize without sampling is not used by the readers")
        else:
            self.data = d.astype(np.float64)

    # ------------------------------------------------------------------------------------
    def _corners(self, params):
        """Slice indices ``[C, M]`` and weights ``[C, M]`` of the parameter interpolation."""
        if not self.params:
            return np.zeros((1, 1), np.intp), np.ones((1, 1))
        per_dim = []
        for vals, p, stride in zip(self.params, params, self.strides):
            p = np.asarray(p, np.float64)
            if vals.size == 1:
                per_dim.append(((np.zeros(p.shape, np.intp), np.ones(p.shape)),
                                (np.zeros(p.shape, np.intp), np.zeros(p.shape))))
                continue
            i = np.clip(np.searchsorted(vals, p, side="left") - 1, 0, vals.size - 2)
            with np.errstate(invalid="ignore"):
                w1 = np.clip((p - vals[i]) / (vals[i + 1] - vals[i]), 0.0, 1.0)
            per_dim.append(((i * stride, 1.0 - w1), ((i + 1) * stride, w1)))
        slices, weights = [], []
        for combo in itertools.product((0, 1), repeat=len(per_dim)):
            s = 0
            w = 1.0
            for dim, bit in zip(per_dim, combo):
                s = s + dim[bit][0]
                w = w * dim[bit][1]
            slices.append(np.broadcast_to(s, np.shape(w)))
            weights.append(w)
        return np.asarray(slices), np.asarray(weights)

    def fixed(self, params) -> "Marginal2D":
        """The distribution at one parameter point ``params`` (one scalar per parameter), as a
        Marginal2D without parameters: its tables are the parameter interpolation of this one's,
        summed corner by corner in the order :meth:`_gather` sums them, so it samples, evaluates
        and inverts to the same bits, without interpolating the corners at every point (a file's
        albedo rule samples tens of thousands of points at one incidence)."""
        sl, wt = self._corners([np.full(1, float(p)) for p in params])
        out = object.__new__(Marginal2D)
        out.params, out.res, out.n_slices, out.strides = [], (), 1, []
        out.h, out.w, out.sampling = self.h, self.w, self.sampling
        names = ("data", "cond", "marg") if self.sampling else ("data",)
        for name in names:
            table = getattr(self, name)
            acc = 0.0
            for c in range(sl.shape[0]):
                w = float(wt[c, 0])
                if w != 0.0 or sl.shape[0] == 1:
                    acc = acc + w * table[int(sl[c, 0])]
            setattr(out, name, np.asarray(acc, np.float64)[None])
        return out

    @staticmethod
    def _gather(table, slices, weights, *index):
        """Σ_c weights[c] · table[slices[c], *index]."""
        if slices.shape[0] == 1:
            return weights[0] * table[(slices[0],) + index]
        out = 0.0
        for c in range(slices.shape[0]):
            w = weights[c]
            nz = w != 0
            if nz.all():
                out = out + w * table[(slices[c],) + index]
            elif nz.any():
                part = np.zeros(w.shape)
                part[nz] = w[nz] * table[(slices[c][nz],) + tuple(np.broadcast_to(i, w.shape)[nz] for i in index)]
                out = out + part
        return out

    def _prepare(self, points, params):
        points = np.asarray(points, np.float64).reshape(-1, 2)
        m = points.shape[0]
        params = [np.broadcast_to(np.asarray(p, np.float64), (m,)) for p in params]
        return points, params, m

    # ------------------------------------------------------------------------------------
    def eval(self, pos, params=()):
        """Bilinear interpolation of the (normalized) data at ``pos[M, 2]`` = (x, y)."""
        pos, params, m = self._prepare(pos, params)
        sl, wt = self._corners(params)
        x = np.clip(pos[:, 0], 0.0, 1.0) * (self.w - 1)
        y = np.clip(pos[:, 1], 0.0, 1.0) * (self.h - 1)
        ix = np.minimum(x.astype(np.intp), self.w - 2)
        iy = np.minimum(y.astype(np.intp), self.h - 2)
        tx, ty = x - ix, y - iy
        g = self._gather
        v00 = g(self.data, sl, wt, iy, ix)
        v10 = g(self.data, sl, wt, iy, ix + 1)
        v01 = g(self.data, sl, wt, iy + 1, ix)
        v11 = g(self.data, sl, wt, iy + 1, ix + 1)
        return _lerp(_lerp(v00, v10, tx), _lerp(v01, v11, tx), ty)

    def invert(self, points, params=()):
        """Inverse of :meth:`sample`: unit-square ``points[M, 2]`` -> uniform variates, pdf."""
        points, params, m = self._prepare(points, params)
        sl, wt = self._corners(params)
        g = self._gather
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            s = np.clip(points, 0.0, 1.0) * np.array([self.w - 1, self.h - 1], float)
            px = np.minimum(s[:, 0].astype(np.intp), self.w - 2)
            py = np.minimum(s[:, 1].astype(np.intp), self.h - 2)
            sx, sy = s[:, 0] - px, s[:, 1] - py
            v00 = g(self.data, sl, wt, py, px)
            v10 = g(self.data, sl, wt, py, px + 1)
            v01 = g(self.data, sl, wt, py + 1, px)
            v11 = g(self.data, sl, wt, py + 1, px + 1)
            c0, c1 = _lerp(v00, v01, sy), _lerp(v10, v11, sy)
            pdf = _lerp(c0, c1, sx)
            sx = sx * _lerp(c0, c1, 0.5 * sx) / (self.w - 1)
            prev = np.maximum(px - 1, 0)
            before = _lerp(g(self.cond, sl, wt, py, prev), g(self.cond, sl, wt, py + 1, prev), sy)
            sx = sx + np.where(px > 0, before, 0.0)
            r0 = g(self.cond, sl, wt, py, self.w - 2)
            r1 = g(self.cond, sl, wt, py + 1, self.w - 2)
            sx = sx / _lerp(r0, r1, sy)
            sy = sy * _lerp(r0, r1, 0.5 * sy) / (self.h - 1)
            sy = sy + np.where(py > 0, g(self.marg, sl, wt, np.maximum(py - 1, 0)), 0.0)
        return np.stack([sx, sy], axis=-1), pdf

    def sample(self, u, params=()):
        """Warp uniform variates ``u[M, 2]`` to points of the unit square; returns (points, pdf)."""
        u, params, m = self._prepare(u, params)
        out = np.empty((m, 2))
        pdf = np.empty(m)
        for start in range(0, m, CHUNK):
            stop = min(start + CHUNK, m)
            out[start:stop], pdf[start:stop] = self._sample(u[start:stop], [p[start:stop] for p in params])
        return out, pdf

    def _sample(self, u, params):
        sl, wt = self._corners(params)
        g = self._gather
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            sx = np.clip(u[:, 0], EPS32, ONE_MINUS_EPS32)
            sy = np.clip(u[:, 1], EPS32, ONE_MINUS_EPS32)
            # row: first marginal CDF entry >= sy
            row = _binary_search(0, self.h - 2, lambda i: g(self.marg, sl, wt, i) < sy)
            sy = sy - np.where(row > 0, g(self.marg, sl, wt, np.maximum(row - 1, 0)), 0.0)
            r0 = g(self.cond, sl, wt, row, self.w - 2)
            r1 = g(self.cond, sl, wt, row + 1, self.w - 2)
            sy = _sample_segment(sy, self.h - 1, r0, r1)
            sx = sx * _lerp(r0, r1, sy)

            def conditional(i):
                return _lerp(g(self.cond, sl, wt, row, i), g(self.cond, sl, wt, row + 1, i), sy)

            col = _binary_search(0, self.w - 1, lambda i: conditional(i) < sx)
            col = np.minimum(col, self.w - 2)
            sx = sx - np.where(col > 0, conditional(np.maximum(col - 1, 0)), 0.0)
            v00 = g(self.data, sl, wt, row, col)
            v10 = g(self.data, sl, wt, row, col + 1)
            v01 = g(self.data, sl, wt, row + 1, col)
            v11 = g(self.data, sl, wt, row + 1, col + 1)
            c0, c1 = _lerp(v00, v01, sy), _lerp(v10, v11, sy)
            sx = _sample_segment(sx, self.w - 1, c0, c1)
        pts = np.stack([(col + sx) / (self.w - 1), (row + sy) / (self.h - 1)], axis=-1)
        return pts, _lerp(c0, c1, sx)


def _binary_search(start: int, end: int, pred):
    """Dr.Jit's ``binary_search``: the first index in [start, end] where the (monotone)
    predicate is false, or ``end``; vectorized over the predicate's points."""
    iterations = int(np.floor(np.log2(end - start))) + 1 if start < end else 0
    lo, hi = None, None
    for _ in range(iterations):
        if lo is None:
            mid = np.int64((start + end) >> 1)
            cond = pred(np.full(1, mid))
            lo = np.where(cond, min(mid + 1, end), start)
            hi = np.where(cond, end, mid)
            continue
        mid = (lo + hi) >> 1
        cond = pred(mid)
        lo, hi = np.where(cond, np.minimum(mid + 1, hi), lo), np.where(cond, hi, mid)
    return np.full(1, start) if lo is None else lo


def _sample_segment(s, inv_width, v0, v1):
    """Position in [0, 1] along a segment of width 1/inv_width with linear density v0 -> v1
    whose integral up to it is ``s`` (Mitsuba's ``sample_segment``)."""
    non_const = np.abs(v0 - v1) > 1e-4 * (v0 + v1)
    divisor = np.where(non_const, v0 - v1, v0 + v1)
    s = s * (2.0 * inv_width)
    s = np.where(non_const, v0 - np.sqrt(np.maximum(v0 * v0 + s * (v1 - v0), 0.0)), s)
    return np.where(divisor != 0.0, s / np.where(divisor != 0.0, divisor, 1.0), s)
