"""Compiled interpolation of tables and RGL ``.bsdf`` files (numba, see :mod:`brdftab._jit`).

Written straight into the caller's output array:

* :func:`table_eval` — a :class:`~brdftab.table.Table`, one pass per pair: its grid
  coordinates (Rusinkiewicz half/difference angles with the table's φd fold, or gonio angles,
  absolute or relative to the mirror direction, with the isotropic rotation onto the first φi
  node and a bilateral grid's mirror fold of φo − φi), the fractional index on each axis (``Axis.fractional_index``: linear or square-root warped, periodic, wrapped arcs,
  snapping onto nodes), the domain test (``Axis.outside``) and the multilinear weights over the
  valid corners (renormalized; missing samples and below-horizon nodes left out; horizon ghosts
  are already in the values). Pairs whose cell has no valid corner and lies wholly below the
  horizon are flagged: the caller fills them from the nearest nodes holding data (rare).
* :func:`rgl_eval` — an :class:`~brdftab.formats._rgl_read.RGLBSDF`: Mitsuba 3's ``measured``
  evaluation (the VNDF warp inverted, the spectra interpolated on the warped square, NDF and
  σ tables), with the reader's hold of f near the horizon; in blocks of pairs, each in passes
  over all its pairs (see the comment above the kernel).

Both start from the raw direction arrays as :meth:`brdftab.brdf.BRDF.eval` receives them
(:func:`_load`): rows that are not unit are normalized as ``BRDF.eval`` does, non-finite rows
give NaN, pairs at or below the horizon give 0, a zero vector is counted (the caller raises).
The numpy code in :mod:`brdftab.table` and :mod:`brdftab.formats._rgl_read` is the reference:
``tests/test_table.py`` and ``tests/test_rgl.py`` hold these kernels to it to 1e-12 relative.
"""

from __future__ import annotations

import math

import numpy as np
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

from ._jit import device, kernel, prange

HALF_PI = 0.5 * np.pi
TWO_PI = 2.0 * np.pi
PI = np.pi
#: as brdftab.grids.axis.SNAP and DOMAIN_TOL, brdftab.brdf.HORIZON, brdftab.geometry.THETA_H_ZERO
SNAP = 1e-9
DOMAIN_TOL = 1e-9
HORIZON = 1e-12
INV_TWO_PI = 1.0 / TWO_PI
THETA_H_ZERO = 1e-12
#: Pairs per block of a parallel loop (the per-block scratch arrays are allocated once per block).
BLOCK = 512

# grid kinds
RUSINKIEWICZ = 0
SPHERICAL = 1
SPHERICAL_SPECULAR = 2
# φd folds (brdftab.grids.axis.PHI_D_FOLDS order)
FOLDS = {"none": 0, "reciprocity": 1, "bilateral": 2, "reciprocity+bilateral": 3}
# axis kinds
PLAIN, PERIODIC, WRAPPED = 0, 1, 2
# validity modes of table_eval
ALL_VALID, NODE_FLAG, CHANNEL_FLAGS, NODE_MASK = 0, 1, 2, 3
# outside modes
OUTSIDE = {"nan": 0, "raise": 1, "clamp": 2}


@device
def _mod(a, b):
    """numpy's ``np.mod`` of floats (the result takes the sign of ``b``), as Python's ``%``."""
    if 0.0 < a < b:  # the common cases, with the same result as the general one
        return a
    if -b <= a < 0.0:
        return a + b
    return a % b  # Python's float modulo: fmod, then shifted by b when the signs differ


@device
def _unit(x, y, z):
    """``(x, y, z, status)`` as ``BRDF.eval`` normalizes a direction: untouched when its length
    is within 1e-12 of 1, else divided by its largest component and then by its length; status
    1 for a zero vector."""
    nrm = math.sqrt(x * x + y * y + z * z)
    if abs(nrm - 1.0) > 1e-12:
        big = max(abs(x), abs(y), abs(z))
        if big == 0.0:
            return x, y, z, 1
        x, y, z = x / big, y / big, z / big
        nrm = math.sqrt(x * x + y * y + z * z)
        x, y, z = x / nrm, y / nrm, z / nrm
    return x, y, z, 0


@device(inline=True)
def _load(wi, wo, i, check):
    """Pair ``i``: ``(ix, iy, iz, ox, oy, oz, status)``; status 0 above the horizon, 1 non-finite
    (f is NaN), 2 at or below the horizon (f is 0), 3 wi a zero vector, 4 wo a zero vector."""
    ix, iy, iz = wi[i, 0], wi[i, 1], wi[i, 2]
    ox, oy, oz = wo[i, 0], wo[i, 1], wo[i, 2]
    if check:
        ix, iy, iz, zi = _unit(ix, iy, iz)
        if zi:
            return ix, iy, iz, ox, oy, oz, 3
        ox, oy, oz, zo = _unit(ox, oy, oz)
        if zo:
            return ix, iy, iz, ox, oy, oz, 4
        if not (math.isfinite(ix) and math.isfinite(iy) and math.isfinite(iz) and math.isfinite(ox)
                and math.isfinite(oy) and math.isfinite(oz)):
            return ix, iy, iz, ox, oy, oz, 1
    if not (iz > HORIZON and oz > HORIZON):
        return ix, iy, iz, ox, oy, oz, 2
    return ix, iy, iz, ox, oy, oz, 0


@device
def _settle(out, i, nc, st):
    """Row ``i`` of a pair that is not evaluated (status ``st`` of :func:`_load`, not 0): NaN or 0
    in every channel; returns the (wi, wo) zero-vector counts it adds."""
    v = np.nan if st == 1 else 0.0
    for c in range(nc):
        out[i, c] = v
    return (1 if st == 3 else 0), (1 if st == 4 else 0)


#: Rows copied at once when directions arrive as views that are not C-contiguous (a direction
#: broadcast against many): the kernels compile for one array layout, and the copies stay small.
CHUNK = 1 << 16


def contiguous_pairs(wi, wo):
    """``(rows, wi, wo)`` covering all pairs with C-contiguous, writable float64 ``(k, 3)``
    arrays: the arrays themselves when they are, else copies of bounded chunks. (Writable: numba
    compiles a kernel anew for read-only arguments, a type of their own; the table kernel takes
    about 30 s.)"""
    m = wi.shape[0]
    if all(a.flags.c_contiguous and a.flags.writeable and a.dtype == np.float64 for a in (wi, wo)):
        yield slice(0, m), wi, wo
        return
    for s in range(0, m, CHUNK):
        rows = slice(s, min(m, s + CHUNK))
        yield rows, np.array(wi[rows], np.float64, order="C"), np.array(wo[rows], np.float64, order="C")


@intrinsic
def _prefetch(typingctx, arr, idx):
    """A hint to the processor to fetch element ``idx`` of the flat array ``arr`` into the cache
    (LLVM's ``prefetch``: read, keep in all cache levels); no effect on results."""
    if not isinstance(arr, types.Array):
        return None

    def codegen(context, builder, signature, args):
        ary = context.make_array(signature.args[0])(context, builder, args[0])
        i8p = ir.IntType(8).as_pointer()
        i32 = ir.IntType(32)
        fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(ir.VoidType(), [i8p, i32, i32, i32]),
                                            "llvm.prefetch.p0i8")
        builder.call(fn, [builder.bitcast(builder.gep(ary.data, [args[1]]), i8p), i32(0), i32(3), i32(1)])
        return context.get_dummy_value()

    return types.void(arr, types.intp), codegen


@device
def _prefetch_row(vals, row):
    """Prefetch rows ``row`` and ``row + 1`` (the next node along the last axis) of a
    C-contiguous 2-D array: their first and last elements."""
    k = vals.shape[1]
    _prefetch(vals, row * k)
    _prefetch(vals, min(row * k + 2 * k - 1, vals.size - 1))


# ------------------------------------------------------------------------------------------
# Tables


@device(inline=True)
def _interp(x, xp, slope, a, m, guess):
    """``np.interp(x, xp[a, :m], arange(m))`` (numpy's formula); ``guess`` ≥ 0 is a linear guess
    of the segment for uniform axes (corrected by stepping), < 0 asks for a binary search."""
    if x > xp[a, m - 1]:
        return float(m - 1)
    if x < xp[a, 0]:
        return 0.0
    if x != x:
        return x
    if guess >= 0.0:
        j = min(int(guess), m - 1)
        while j > 0 and xp[a, j] > x:
            j -= 1
        while j < m - 1 and xp[a, j + 1] <= x:
            j += 1
    else:
        lo, hi = 0, m
        while hi - lo > 1:
            mid = (lo + hi) >> 1
            if xp[a, mid] <= x:
                lo = mid
            else:
                hi = mid
        j = lo
    if j == m - 1 or xp[a, j] == x:
        return float(j)
    r = slope[a, j] * (x - xp[a, j]) + j
    if r != r:
        r = slope[a, j] * (x - xp[a, j + 1]) + (j + 1)
    return r


@device(inline=True)
def _axis_index(x, a, ax_i, ax_f, xp, slope):
    """Fractional index of coordinate ``x`` on axis ``a`` (``Axis.fractional_index``)."""
    n = ax_i[a, 0]
    if n == 1:
        return 0.0
    kind = ax_i[a, 1]
    v0 = ax_f[a, 4]
    if kind == PERIODIC:
        t = v0 + _mod(x - v0, ax_f[a, 0])
        m = n + 1
    else:
        t = x
        if kind == WRAPPED:  # reduced into [domain low, + wrap): the domain may start before the first node
            wrap = ax_f[a, 1]
            t = ax_f[a, 2] + _mod(x - ax_f[a, 2], wrap)
            v1 = ax_f[a, 5]
            if t > v1 and v0 + wrap - t < t - v1:
                t = v0
        if ax_i[a, 2]:  # square-root warp
            t = math.sqrt((t if not (t < 0.0) else 0.0) / HALF_PI)
        m = n
    guess = -1.0
    if ax_i[a, 3]:
        guess = (t - ax_f[a, 6]) * ax_f[a, 7]
        if not (guess >= 0.0):
            guess = 0.0
    idx = _interp(t, xp, slope, a, m, guess)
    if kind == PERIODIC and idx >= n:
        idx -= n
    r = math.floor(idx + 0.5)
    if abs(idx - r) < SNAP:
        idx = r
    if kind == PERIODIC and idx >= n:
        idx -= n
    return idx


@device(inline=True)
def _axis_outside(x, a, ax_i, ax_f):
    """True where ``x`` lies outside axis ``a``'s domain (``Axis.outside``)."""
    kind = ax_i[a, 1]
    if kind == PERIODIC:
        return not math.isfinite(x)
    xr = x
    if kind == WRAPPED:
        xr = ax_f[a, 2] + _mod(x - ax_f[a, 2], ax_f[a, 1])
    lo, hi = ax_f[a, 2], ax_f[a, 3]
    out = (xr < lo - DOMAIN_TOL) or (xr > hi + DOMAIN_TOL) or not math.isfinite(xr)
    if kind == WRAPPED and abs(xr - ax_f[a, 1] - lo) <= DOMAIN_TOL:
        out = False
    return out


@device
def _fold(pd, fold):
    if fold == 0:
        return _mod(pd, TWO_PI)
    if fold == 1:
        return _mod(pd, PI)
    if fold == 2:
        return abs(_mod(pd + PI, TWO_PI) - PI)
    x = _mod(pd, PI)
    return min(x, PI - x)


# atan on [0, inf) by Cody & Waite's reduction and a rational approximation on [0, 0.66]
# (the coefficients of Cephes' atan.c, S. L. Moshier): within 2 ulp of libm, without its call.
_ATAN_P = (-8.750608600031904122785e-1, -1.615753718733365076637e1, -7.500855792314704667340e1,
           -1.228866684490136173410e2, -6.485021904942025371773e1)
_ATAN_Q = (2.485846490142306297962e1, 1.650270098316988542046e2, 4.328810604912902668951e2,
           4.853903996359136964868e2, 1.945506571482613964425e2)
_MOREBITS = 6.123233995736765886130e-17
_T3P8 = 2.41421356237309504880


@device
def _atan_ratio(ay, ax):
    """atan(ay/ax) for finite ay >= 0 and 0 < ax (cephes' reduction and rational form) with one
    division: the reduced argument is ay/ax, (ay − ax)/(ay + ax) or −ax/ay by the range of the
    ratio, its ranges chosen by selects rather than branches (where the ratio is random,
    branches would mispredict about half the time)."""
    b = np.float64(ay > _T3P8 * ax)
    m = np.float64(ay > 0.66 * ax) - b
    s = 1.0 - b - m
    num = (s * ay + m * (ay - ax)) - b * ax    # exactly one term is not 0
    den = (s * ax + m * (ay + ax)) + b * ay
    y = b * HALF_PI + m * (0.25 * PI)
    extra = b * _MOREBITS + m * (0.5 * _MOREBITS)
    x = num / den
    z = x * x
    p = (((_ATAN_P[0] * z + _ATAN_P[1]) * z + _ATAN_P[2]) * z + _ATAN_P[3]) * z + _ATAN_P[4]
    q = ((((z + _ATAN_Q[0]) * z + _ATAN_Q[1]) * z + _ATAN_Q[2]) * z + _ATAN_Q[3]) * z + _ATAN_Q[4]
    return y + ((x * (z * p / q) + x) + extra)


@device(inline=True)
def _atan2(y, x):
    """``atan2(y, x)`` within 2 ulp of libm's (faster); libm's own on the axes, off finite
    values and for NaN. Both half planes in one branch-free form (π − atan(|y|/|x|) for x < 0)."""
    ax = abs(x)
    ay = abs(y)
    if not (0.0 < ax < math.inf and ay < math.inf and (x > 0.0 or y != 0.0)):
        return math.atan2(y, x)
    a = _atan_ratio(ay, ax)
    return math.copysign(PI - a if x < 0.0 else a, y)


@device
def _hypot(x, y):
    """``hypot`` for the moderate values of unit-vector sums (within an ulp of libm's, faster)."""
    return math.sqrt(x * x + y * y)


@device(inline=True)
def _rusinkiewicz(ix, iy, iz, ox, oy, oz, want_ph):
    """``(θh, φh, θd, φd)`` of a pair (:func:`brdftab.geometry.io_to_hd`); φh is 0 unless
    ``want_ph``."""
    hx, hy, hz = ix + ox, iy + oy, iz + oz
    rxy = _hypot(hx, hy)
    norm = _hypot(rxy, hz)
    th = _atan2(rxy, hz)
    pole = rxy <= THETA_H_ZERO * norm
    ch = hz / norm
    sh = rxy / norm
    if pole:
        ph, cp, sp = 0.0, 1.0, 0.0
    else:
        ph = _atan2(hy, hx) if want_ph else 0.0
        cp, sp = hx / rxy, hy / rxy
    x1 = cp * ix + sp * iy
    y1 = -sp * ix + cp * iy
    dx = ch * x1 - sh * iz
    dz = sh * x1 + ch * iz
    return th, ph, _atan2(_hypot(dx, y1), dz), _atan2(y1, dx)


@device(inline=True)
def _coordinates(ix, iy, iz, ox, oy, oz, kind, fold, iso, ax_i, ax_f):
    """The four padded axis coordinates of a pair (``Grid._coordinates``; a 3-axis grid has a
    one-node dummy axis first)."""
    if kind == RUSINKIEWICZ:
        th, ph, td, pd = _rusinkiewicz(ix, iy, iz, ox, oy, oz, ax_i[0, 5] == 0)
        pd = _fold(pd, fold)
        if ax_i[0, 5]:  # the dummy axis of an isotropic grid
            return 0.0, th, td, pd
        return th, ph, td, pd
    ti = _atan2(_hypot(ix, iy), iz)
    pi_ = _atan2(iy, ix)
    to = _atan2(_hypot(ox, oy), oz)
    po = _atan2(oy, ox)
    if iso or fold == 2:
        off = True
        if ax_i[1, 0] > 1:
            off = _axis_outside(pi_, 1, ax_i, ax_f)
        if off:
            shift = ax_f[1, 4] - pi_
            pi_ = pi_ + shift
            po = po + shift
    if fold == 2:  # a bilateral gonio grid: |φo − φi| folded into [0, π]
        po = pi_ + abs(_mod(po - pi_ + PI, TWO_PI) - PI)
    if kind == SPHERICAL_SPECULAR:
        to = to - ti
        po = _mod(po - pi_, TWO_PI) - PI
    return ti, pi_, to, po


@kernel(parallel=True)  # numba's parallel loop: measured faster per core here than serial + threads
def table_eval(wi, wo, check, kind, fold, iso, ax_i, ax_f, xp, slope, vals, valid, vmode, mode, out, flags,
               offset=0):
    """Interpolate at every pair into ``out[M, C]``; ``flags[M]`` = 1 where a cell without valid
    corners lies below the horizon (the caller fills it). ``vmode``: every node valid
    (:data:`ALL_VALID`), validity per node in the last column of ``vals`` (:data:`NODE_FLAG`),
    per node and channel in ``valid`` (:data:`CHANNEL_FLAGS`), or per node in ``valid[:, 0]``
    (:data:`NODE_MASK`). ``vals`` and ``valid`` may hold a window of the table's nodes: row 0
    is the table's node ``offset`` (every corner of the pairs must lie in it). Returns
    ``(outside pairs, flagged pairs, wi zero vectors, wo zero vectors)``."""
    m = wi.shape[0]
    nc = out.shape[1]
    n_axes = 4
    first = 1 if ax_i[0, 5] else 0  # an isotropic grid's dummy axis takes no part
    n_blocks = (m + BLOCK - 1) // BLOCK
    n_out = 0
    n_fill = 0
    zi = 0
    zo = 0
    for b in prange(n_blocks):
        den = np.empty(nc)
        x = np.empty(n_axes)
        lo = np.empty((BLOCK, n_axes), np.int64)
        hi = np.empty((BLOCK, n_axes), np.int64)
        fr = np.zeros((BLOCK, n_axes))
        go = np.empty(BLOCK, np.bool_)
        start = b * BLOCK
        stop = min(m, start + BLOCK)
        # pass 1: coordinates and cells (arithmetic); pass 2: the gathers, free of long
        # dependency chains, so the memory accesses of successive pairs overlap
        for i in range(start, stop):
            j = i - start
            go[j] = False
            flags[i] = 0
            ix, iy, iz, ox, oy, oz, st = _load(wi, wo, i, check)
            if st != 0:
                # written out rather than :func:`_settle` (a call that takes ``out``, in this
                # parallel loop, made every pair about 50 % slower; so did calling the devices
                # above without numba's inlining: they are ``device(inline=True)``)
                v = np.nan if st == 1 else 0.0
                for c in range(nc):
                    out[i, c] = v
                if st == 3:
                    zi += 1
                elif st == 4:
                    zo += 1
                continue
            x[0], x[1], x[2], x[3] = _coordinates(ix, iy, iz, ox, oy, oz, kind, fold, iso, ax_i, ax_f)
            outside = False
            for a in range(first, n_axes):
                if _axis_outside(x[a], a, ax_i, ax_f):
                    outside = True
            if outside:
                n_out += 1
                if mode != 2:
                    for c in range(nc):
                        out[i, c] = np.nan
                    continue
            bad = False
            lo[j, 0] = 0
            hi[j, 0] = 0
            for a in range(first, n_axes):
                k = _axis_index(x[a], a, ax_i, ax_f, xp, slope)
                if k != k:
                    bad = True
                    break
                # the cell: low and high node (as flat offsets) and the fraction
                n = ax_i[a, 0]
                fl = math.floor(k)
                i0 = int(fl)
                if ax_i[a, 1] == PERIODIC:  # k in [0, n)
                    i0 = i0 % n if (i0 < 0 or i0 >= n) else i0
                    i1 = i0 + 1 if i0 + 1 < n else 0
                else:
                    i0 = min(max(i0, 0), n - 1)
                    i1 = min(i0 + 1, n - 1)
                lo[j, a] = i0 * ax_i[a, 4]
                hi[j, a] = i1 * ax_i[a, 4]
                fr[j, a] = k - fl
            if bad:
                for c in range(nc):
                    out[i, c] = np.nan
                continue
            go[j] = True
            # prefetch the cell's rows now (they arrive while the next pairs' coordinates are
            # computed), so the gathers of pass 2 mostly hit the cache
            p0 = lo[j, 0] + lo[j, 1] + lo[j, 2] + lo[j, 3] - offset
            d2 = hi[j, 2] - lo[j, 2]
            _prefetch_row(vals, p0)
            _prefetch_row(vals, p0 + d2)
            if first == 0 or hi[j, 1] != lo[j, 1]:
                p1 = p0 + hi[j, 1] - lo[j, 1]
                _prefetch_row(vals, p1)
                _prefetch_row(vals, p1 + d2)
        n_corners = 1 << (n_axes - first)
        for i in range(start, stop):
            j = i - start
            if not go[j]:
                continue
            for c in range(nc):
                out[i, c] = 0.0
                den[c] = 0.0
            dn = 0.0
            slow = False
            for sweep in range(2):
                # sweep 0: the weighted sum over valid corners; sweep 1 (rare: no valid corner
                # in some channel): the plain sum with missing samples read as 0, and whether
                # every weighted corner is a below-horizon node holding 0
                if sweep == 1 and not slow:
                    break
                if sweep == 0:
                    # the cell's corners as nested loops over the axes (axis 0 outermost: the
                    # order and the products of table._corners)
                    for b0 in range(2 - first):
                        w0 = fr[j, 0] if b0 else 1.0 - fr[j, 0]
                        q0 = hi[j, 0] if b0 else lo[j, 0]
                        for b1 in range(2):
                            w1 = w0 * (fr[j, 1] if b1 else 1.0 - fr[j, 1])
                            q1 = q0 + (hi[j, 1] if b1 else lo[j, 1])
                            for b2 in range(2):
                                w2 = w1 * (fr[j, 2] if b2 else 1.0 - fr[j, 2])
                                q2 = q1 + (hi[j, 2] if b2 else lo[j, 2])
                                for b3 in range(2):
                                    w = w2 * (fr[j, 3] if b3 else 1.0 - fr[j, 3])
                                    pos = q2 + (hi[j, 3] if b3 else lo[j, 3]) - offset
                                    if w == 0.0:
                                        continue
                                    if vmode == ALL_VALID:
                                        for c in range(nc):
                                            out[i, c] += w * float(vals[pos, c])
                                    elif vmode == NODE_FLAG:
                                        if vals[pos, nc] != 0.0:
                                            dn += w
                                            for c in range(nc):
                                                out[i, c] += w * float(vals[pos, c])
                                    elif vmode == NODE_MASK:
                                        if valid[pos, 0]:
                                            dn += w
                                            for c in range(nc):
                                                out[i, c] += w * float(vals[pos, c])
                                    else:
                                        for c in range(nc):
                                            if valid[pos, c]:
                                                out[i, c] += w * float(vals[pos, c])
                                                den[c] += w
                for corner in range(n_corners if sweep == 1 else 0):
                    # weight multiplied in axis order as table._corners does; bit (n_axes - 1 - a)
                    # of the corner picks the high node of axis a
                    w = 1.0
                    pos = -offset
                    for a in range(first, n_axes):
                        if (corner >> (n_axes - 1 - a)) & 1:
                            w *= fr[j, a]
                            pos += hi[j, a]
                        else:
                            w *= 1.0 - fr[j, a]
                            pos += lo[j, a]
                    if w == 0.0:
                        continue
                    for c in range(nc):
                        if den[c] > 0.0:
                            continue
                        v = float(vals[pos, c])
                        ok = vals[pos, nc] != 0.0 if vmode == NODE_FLAG else valid[pos, 0 if vmode == NODE_MASK else c]
                        if ok or v >= 0.0:
                            out[i, c] += w * v
                        if v != 0.0:
                            den[c] = -1.0  # not all zero: NaN
                if sweep == 0 and vmode != ALL_VALID:
                    for c in range(nc):
                        if vmode == NODE_FLAG or vmode == NODE_MASK:
                            den[c] = dn
                        if den[c] > 0.0:
                            out[i, c] = out[i, c] / den[c]
                        else:
                            out[i, c] = 0.0
                            den[c] = 0.0
                            slow = True
            if slow:
                fill = False
                for c in range(nc):
                    if den[c] == 0.0:
                        fill = True  # plain interpolation of below-horizon zeros: filled by the caller
                    elif den[c] < 0.0:
                        out[i, c] = np.nan
                if fill:
                    flags[i] = 1
                    n_fill += 1
    return n_out, n_fill, zi, zo


@kernel(parallel=True)
def first_cells(wi, wo, check, kind, fold, iso, ax_i, ax_f, xp, slope, cells):
    """``cells[M]``: the low node, along the grid's first axis, of the cell :func:`table_eval`
    interpolates pair ``i`` in (clamped into the axis as it clamps it; 0 for a pair it does not
    interpolate): what an evaluation window by window of that axis sorts the pairs by."""
    m = wi.shape[0]
    a = 1 if ax_i[0, 5] else 0
    n = ax_i[a, 0]
    for i in prange(m):
        cells[i] = 0
        ix, iy, iz, ox, oy, oz, st = _load(wi, wo, i, check)
        if st != 0:
            continue
        x0, x1, x2, x3 = _coordinates(ix, iy, iz, ox, oy, oz, kind, fold, iso, ax_i, ax_f)
        x = x1 if a == 1 else x0
        k = _axis_index(x, a, ax_i, ax_f, xp, slope)
        if k != k:
            continue
        i0 = int(math.floor(k))
        if ax_i[a, 1] == PERIODIC:
            i0 = i0 % n if (i0 < 0 or i0 >= n) else i0
        else:
            i0 = min(max(i0, 0), n - 1)
        cells[i] = i0


def _axis_arrays(axes, strides, iso_dummy):
    """Pack (up to 4) :class:`~brdftab.grids.axis.Axis` objects into the kernel's arrays,
    padding a 3-axis grid with a leading one-node axis that is never outside."""
    ax = list(axes)
    st = list(strides)
    if len(ax) == 3:
        ax = [None] + ax
        st = [0] + st
    width = max(len(a) + 1 for a in ax if a is not None)
    ax_i = np.zeros((4, 6), np.int64)
    ax_f = np.zeros((4, 8))
    xp = np.full((4, width), np.inf)
    slope = np.zeros((4, width))
    for k, (a, s) in enumerate(zip(ax, st)):
        if a is None:
            ax_i[k] = (1, PLAIN, 0, 0, 0, 1)
            ax_f[k, 2:4] = (-np.inf, np.inf)
            xp[k, 0] = 0.0
            continue
        n = len(a)
        kind = PERIODIC if a.period is not None else (WRAPPED if a.wrap is not None else PLAIN)
        warp = int(a.warp == "sqrt")
        if kind == PERIODIC:
            nodes = np.append(a.values, a.values[0] + a.period)
        else:
            nodes = a._t(a.values)
        d = np.diff(nodes)
        uniform = bool(nodes.size > 1 and np.all(np.abs(d - d.mean()) <= 0.01 * d.mean()))
        ax_i[k] = (n, kind, warp, int(uniform), s, 0)
        ax_f[k, :6] = (a.period or 0.0, a.wrap or 0.0, a.domain[0], a.domain[1], a.values[0], a.values[-1])
        if uniform:
            ax_f[k, 6] = nodes[0]
            ax_f[k, 7] = (nodes.size - 1) / (nodes[-1] - nodes[0])
        xp[k, :nodes.size] = nodes
        if nodes.size > 1:
            slope[k, :nodes.size - 1] = (np.arange(1.0, nodes.size) - np.arange(nodes.size - 1.0)) / d
    return ax_i, ax_f, xp, slope


#: Value arrays at least this large are placed on 2 MiB pages where the system allows it.
LARGE_PAGE_BYTES = 4 << 20
_HUGE = 2 << 20


def _large_pages(shape, dtype):
    """An empty array, on transparent huge pages when it is large and the system grants them
    (``madvise``): interpolation reads a few nodes at random places of a table of tens of MB,
    and with 4 KiB pages nearly every read also misses the address translation cache."""
    dtype = np.dtype(dtype)
    nbytes = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
    if nbytes < LARGE_PAGE_BYTES:
        return np.empty(shape, dtype)
    import mmap

    advice = getattr(mmap, "MADV_HUGEPAGE", None)
    if advice is None:
        return np.empty(shape, dtype)
    buf = mmap.mmap(-1, nbytes + _HUGE)
    raw = np.frombuffer(buf, np.uint8)
    offset = (-raw.ctypes.data) % _HUGE
    try:
        buf.madvise(advice, offset, len(buf) - offset)
    except (OSError, ValueError):
        pass
    return raw[offset:offset + nbytes].view(dtype).reshape(shape)


class TablePlan:
    """What :func:`table_eval` needs of a table, computed once and cached on it: the values
    with horizon ghosts as one contiguous ``[nodes, C]`` array in the stored dtype (with a
    column of node validity when validity is per node), the valid mask when it differs between
    channels, and the packed axes."""

    def __init__(self, grid, values, valid, isotropic):
        c = values.shape[-1]
        self.n_channels = c
        flat = np.asarray(values).reshape(-1, c)
        self.valid = np.ones((1, 1), np.bool_)
        if valid is None:
            self.vmode = ALL_VALID
            self.vals = _large_pages(flat.shape, flat.dtype)
            self.vals[...] = flat
        else:
            ok = np.asarray(valid).reshape(-1, c)
            per_node = ok[:, 0]
            if np.array_equal(np.broadcast_to(per_node[:, None], ok.shape), ok):
                # validity per node: a last column of 1/0 beside the values (one cache line)
                self.vmode = NODE_FLAG
                self.vals = _large_pages((flat.shape[0], c + 1), flat.dtype)
                self.vals[:, :c] = flat
                self.vals[:, c] = per_node
            else:
                self.vmode = CHANNEL_FLAGS
                self.vals = _large_pages(flat.shape, flat.dtype)
                self.vals[...] = flat
                self.valid = np.ascontiguousarray(ok)
        _plan_grid(self, grid, isotropic)

    def run(self, wi, wo, check, mode, out, flags):
        """:func:`table_eval` over all pairs (in chunks when they are not C-contiguous); returns
        its counts summed."""
        total = np.zeros(4, np.int64)
        for rows, a, b in contiguous_pairs(wi, wo):
            # (offset given, as WindowPlan gives it: one compiled signature, not two)
            total += table_eval(a, b, check, self.kind, self.fold, self.iso, self.ax_i, self.ax_f, self.xp,
                                self.slope, self.vals, self.valid, self.vmode, OUTSIDE[mode], out[rows], flags[rows],
                                0)
        return tuple(int(x) for x in total)


def _plan_grid(plan, grid, isotropic):
    """Set a plan's packed axes (``ax_i``, ``ax_f``, ``xp``, ``slope``), grid kind, φd fold and
    isotropy from ``grid``."""
    shape = grid.shape
    strides = [int(np.prod(shape[k + 1:], dtype=np.int64)) for k in range(len(shape))]
    plan.ax_i, plan.ax_f, plan.xp, plan.slope = _axis_arrays(grid.axes, strides, len(shape) == 3)
    p = getattr(grid, "parameterization", "")
    if p == "spherical":
        plan.kind = SPHERICAL_SPECULAR if grid.relative_to == "specular" else SPHERICAL
        plan.fold = FOLDS[getattr(grid, "phi_d_fold", "none")]  # none or bilateral
    else:
        plan.kind = RUSINKIEWICZ
        plan.fold = FOLDS[grid.phi_d_fold]
    plan.iso = bool(isotropic)


class WindowPlan:
    """The compiled interpolation of a table held in windows of its first axis (a table over
    the memory budget, its interpolation data in scratch files mapped window by window):
    :meth:`cells` gives each pair's cell along that axis, :meth:`run` interpolates pairs whose
    cells lie in a window from that window's values ``[rows × nodes per row, C]`` (float32 for
    a float32 table, else float64) and node validity ``[rows × nodes per row, 1]``, exactly as
    :class:`TablePlan` does from the whole table."""

    def __init__(self, grid, isotropic):
        _plan_grid(self, grid, isotropic)
        self.row_nodes = int(np.prod(grid.shape[1:], dtype=np.int64))

    def cells(self, wi, wo, check):
        cells = np.empty(wi.shape[0], np.int64)
        for rows, a, b in contiguous_pairs(wi, wo):
            first_cells(a, b, check, self.kind, self.fold, self.iso, self.ax_i, self.ax_f, self.xp, self.slope,
                        cells[rows])
        return cells

    def run(self, wi, wo, check, mode, out, flags, vals, valid, first_row):
        total = np.zeros(4, np.int64)
        offset = int(first_row * self.row_nodes)
        for rows, a, b in contiguous_pairs(wi, wo):
            total += table_eval(a, b, check, self.kind, self.fold, self.iso, self.ax_i, self.ax_f, self.xp,
                                self.slope, vals, valid, NODE_MASK, OUTSIDE[mode], out[rows], flags[rows], offset)
        return total


# ------------------------------------------------------------------------------------------
# RGL .bsdf files (Mitsuba 3's `measured`)
#
# The pairs go through in blocks of RGL_BLOCK, each in passes over all the block's pairs at
# once (structure of arrays: one scratch row per quantity): the coordinates, the parameter
# cells, the gathers of the warp's tables per parameter corner, the warp's inversion, the
# gathers of the spectra, the NDF/σ factor, the output. The arithmetic passes are plain loops
# without branches, which the compiler turns into SIMD instructions; the gathers stay scalar
# loads (LLVM emits no gather instructions for this processor family), one pair at a time with
# the sums in registers. The rare pairs that are not unit vectors or not finite are settled in
# scalar code between the passes (:func:`_load`).

#: Pairs per block of the RGL evaluation (its scratch rows stay within the core's L2 cache).
RGL_BLOCK = 256
# rows of a block's float scratch: status (0 evaluated; -1 the scalar code decides; else
# _load's), u(θi), u(φi), u(θm), u(φm[−φi]), θi, φi, cosθo (held), then the corners' weights
# (4), the warp's gathered values (9: data at its cell's four nodes, cond before the cell and
# at the row's end on both rows, marg), the warped sample's cell fractions (2), the factor
# (NDF/σ, 1/cosθo) and the spectra (one row per stored channel)
_R_ST, _R_UI0, _R_UI1, _R_UM0, _R_UM1, _R_TH, _R_PH, _R_OZ = 0, 1, 2, 3, 4, 5, 6, 7
_R_W = 8
_R_ACC = 12
_R_TX, _R_TY, _R_SCALE = 21, 22, 23
_R_SPEC = 24
# rows of its integer scratch: the corners' slices (4), the warp cell (px, py), the spectra's
# cell (jx, jy), the parameter cells (φi, θi)
_I_Q, _I_PX, _I_PY, _I_JX, _I_JY, _I_A, _I_B = 0, 4, 5, 6, 7, 8, 9


@device
def _elevation(x, y, z):
    """The polar angle of a unit vector above the horizon (z > 0): atan2(|xy|, z), the number
    of Mitsuba's 2 asin(|w − ẑ|/2) (``_rgl_warp.elevation``) to rounding, branch-free."""
    return _atan_ratio(math.sqrt(x * x + y * y), z)


@device
def _atan2_sel(y, x):
    """``atan2(y, x)`` of finite values by selects only (:func:`_atan2`'s number; on the axes
    libm's: ±π/2, and ±0 or ±π at y = x = 0 by the signs of the zeros)."""
    ax = abs(x)
    ay = abs(y)
    a = _atan_ratio(ay, 1.0 if (ax == 0.0 and ay == 0.0) else ax)  # atan(y/0) = π/2 exactly
    return math.copysign(PI - a if math.copysign(1.0, x) < 0.0 else a, y)


@device
def _theta2u(t):
    return math.sqrt((t if t > 0.0 else 0.0) * (2.0 / PI))


@device
def _lerp(a, b, t):
    return a + t * (b - a)


#: Parameter axes up to this many values are searched by counting the values below p (every
#: value compared: a loop over the pairs the compiler vectorizes); longer ones by halving steps.
COUNT_SEARCH = 32


@device
def _param_cells(vals, p, cnt, idx, wgt, lo_v, hi_v):
    """The cells of parameters ``p[:cnt]`` on the axis ``vals`` as ``Marginal2D._corners``
    finds them: into ``idx`` the index (searchsorted(vals, p, "left") − 1 clipped to the
    cells), into ``wgt`` the clamped weight of index + 1 (``lo_v``, ``hi_v``: scratch for the
    cell's end values); each step a pass over all the values (so that the passes vectorize)."""
    n = vals.shape[0]
    if n == 1:
        for j in range(cnt):
            idx[j] = 0
            wgt[j] = 0.0
        return
    for j in range(cnt):
        idx[j] = 0
    if n <= COUNT_SEARCH:
        # searchsorted(vals, p, "left") = the number of values below p
        for k in range(n):
            v = vals[k]
            for j in range(cnt):
                idx[j] += 1 if v < p[j] else 0
    else:
        step = 1
        while 2 * step <= n:
            step *= 2
        while step > 0:
            for j in range(cnt):
                k = min(idx[j] + step, n)
                idx[j] = k if vals[np.uint64(k - 1)] < p[j] else idx[j]
            step >>= 1
    for j in range(cnt):
        i = min(max(idx[j] - 1, 0), n - 2)
        idx[j] = i
        lo_v[j] = vals[np.uint64(i)]
        hi_v[j] = vals[np.uint64(i + 1)]
    for j in range(cnt):
        w1 = (p[j] - lo_v[j]) / (hi_v[j] - lo_v[j])
        wgt[j] = min(max(w1, 0.0), 1.0)


@device
def _bilinear2(table, x, y):
    """A raw bilinear table ``[H, W]`` at ``(x, y)`` of the unit square (``Marginal2D.eval``)."""
    h, w = table.shape
    x = min(max(x, 0.0), 1.0) * (w - 1)
    y = min(max(y, 0.0), 1.0) * (h - 1)
    ix = min(int(x), w - 2)
    iy = min(int(y), h - 2)
    tx, ty = x - ix, y - iy
    iy0, iy1, ix0, ix1 = np.uint64(iy), np.uint64(iy + 1), np.uint64(ix), np.uint64(ix + 1)  # (see _warp_at)
    return _lerp(_lerp(table[iy0, ix0], table[iy0, ix1], tx), _lerp(table[iy1, ix0], table[iy1, ix1], tx), ty)


@device
def _warp_at(data_f, cond_f, marg_f, q, px, py, h, w):
    """The warp's numbers of slice ``q`` at cell ``(px, py)``: data at the cell's four nodes
    (x fastest), cond before the cell and at the row's end on rows py and py + 1 (before the
    cell: at max(px − 1, 0)), marg before the row (at max(py − 1, 0)). (Indices are unsigned:
    they are not negative, and numba then leaves out its test for indices from the end.)"""
    g = (q * h + py) * w + px
    k = (q * h + py) * (w - 1)
    pm = max(px - 1, 0)
    m = q * (h - 1) + max(py - 1, 0)
    return (data_f[np.uint64(g)], data_f[np.uint64(g + 1)], data_f[np.uint64(g + w)], data_f[np.uint64(g + w + 1)],
            cond_f[np.uint64(k + pm)], cond_f[np.uint64(k + (w - 1) + pm)], cond_f[np.uint64(k + (w - 2))],
            cond_f[np.uint64(k + (w - 1) + (w - 2))], marg_f[np.uint64(m)])


@device
def _spectrum_at(spec_f, g, ns, row, tx, ty):
    """The spectra's bilinear interpolant at flat index ``g`` (node (jx, jy) of a slice, one
    channel; ``row`` numbers a row), fractions ``tx``, ``ty``."""
    g00 = spec_f[np.uint64(g)]
    g10 = spec_f[np.uint64(g + ns)]
    g01 = spec_f[np.uint64(g + row)]
    g11 = spec_f[np.uint64(g + row + ns)]
    l0 = g00 + tx * (g10 - g00)
    l1 = g01 + tx * (g11 - g01)
    return l0 + ty * (l1 - l0)


@device(inline=True)  # inlined on numba's IR: LLVM finds it too large to inline, and its loop then stays scalar
def _rgl_coordinates(ix, iy, iz, ox, oy, oz, hold, c0, s0, iso, reduction):
    """``(u(θi), u(φi), u(θm), u(φm[−φi]), θi, φi, cosθo)`` of a pair of unit vectors above the
    horizon, with the hold of ωo beyond θ_hold and the mirroring of reduced files (selects
    only)."""
    low = hold and oz < c0
    r = math.sqrt(ox * ox + oy * oy)
    k = s0 / (r if low else 1.0)
    ox = ox * k if low else ox
    oy = oy * k if low else oy
    oz = c0 if low else oz
    if not iso and reduction >= 2:
        # mulsign_neg: wi to y <= 0 (and x <= 0 for a quarter); a half turns both axes
        sy = -1.0 if iy >= 0.0 else 1.0
        sx = (-1.0 if ix >= 0.0 else 1.0) if reduction == 4 else sy
        ix, iy, ox, oy = ix * sx, iy * sy, ox * sx, oy * sy
    mx, my, mz = ix + ox, iy + oy, iz + oz
    mn = 1.0 / math.sqrt(mx * mx + my * my + mz * mz)
    mx, my, mz = mx * mn, my * mn, mz * mn
    th_i = _elevation(ix, iy, iz)
    th_m = _elevation(mx, my, mz)
    ph_i = _atan2_sel(iy, ix)
    ph_m = _atan2_sel(my, mx)
    uy = ((ph_m - ph_i if iso else ph_m) + PI) * INV_TWO_PI
    return (_theta2u(th_i), (ph_i + PI) * INV_TWO_PI, _theta2u(th_m), uy - np.floor(uy), th_i, ph_i, oz)


@kernel  # serial: the caller runs it on threads (brdftab._jit.parallel_rows)
def rgl_eval(wi, wo, check, hold, divide, iso, reduction, jacobian, theta_hold, p_phi, p_theta, st_phi, st_theta,
             data, cond, marg, spectra, ndf, sigma, lo, hi, t, out):
    """f (``divide``: f·cosθo / cosθo, with ``hold``) or f·cosθo of an RGL file at every pair,
    into ``out[M, n]`` (channels ``lo``, ``hi``, weight ``t`` of the stored spectra).
    Returns ``(wi zero vectors, wo zero vectors)``."""
    m = wi.shape[0]
    nc = lo.shape[0]
    ns = spectra.shape[3]
    h, w = data.shape[1], data.shape[2]
    res = spectra.shape[1]
    n_phi = p_phi.shape[0]
    n_theta = p_theta.shape[0]
    # corners over (φi, θi), first parameter most significant; one or two per parameter
    nq = (2 if n_phi > 1 else 1) * (2 if n_theta > 1 else 1)
    c0 = math.cos(theta_hold)
    s0 = math.sin(theta_hold)
    inv_w = 1.0 / (w - 1)
    inv_h = 1.0 / (h - 1)
    data_f = data.reshape(data.size)
    cond_f = cond.reshape(cond.size)
    marg_f = marg.reshape(marg.size)
    spec_f = spectra.reshape(spectra.size)
    n_blocks = (m + RGL_BLOCK - 1) // RGL_BLOCK
    zi = 0
    zo = 0
    for b in range(n_blocks):
        start = b * RGL_BLOCK
        cnt = min(m, start + RGL_BLOCK) - start
        sc = np.empty((_R_SPEC + ns, RGL_BLOCK))
        si = np.empty((10, RGL_BLOCK), np.int64)
        a_i = wi[start:start + cnt]
        a_o = wo[start:start + cnt]
        # pass 1: the directions copied into rows (loads of every third number do not
        # vectorize); the pairs' status (those not plainly unit and finite: -1, then settled
        # in scalar code, normalized as BRDF.eval does); their coordinates
        for j in range(cnt):
            sc[_R_ACC, j] = a_i[j, 0]
            sc[_R_ACC + 1, j] = a_i[j, 1]
            sc[_R_ACC + 2, j] = a_i[j, 2]
            sc[_R_ACC + 3, j] = a_o[j, 0]
            sc[_R_ACC + 4, j] = a_o[j, 1]
            sc[_R_ACC + 5, j] = a_o[j, 2]
        n_odd = 0
        for j in range(cnt):
            ix, iy, iz = sc[_R_ACC, j], sc[_R_ACC + 1, j], sc[_R_ACC + 2, j]
            ox, oy, oz = sc[_R_ACC + 3, j], sc[_R_ACC + 4, j], sc[_R_ACC + 5, j]
            if check:
                odd = not (abs(math.sqrt(ix * ix + iy * iy + iz * iz) - 1.0) <= 1e-12
                           and abs(math.sqrt(ox * ox + oy * oy + oz * oz) - 1.0) <= 1e-12)
            else:
                s = ix + iy + iz + ox + oy + oz
                odd = s - s != 0.0  # a component is not finite (or their sum overflows)
            st = 0.0 if (iz > HORIZON and oz > HORIZON) else 2.0
            sc[_R_ST, j] = -1.0 if odd else st
            n_odd += 1 if odd else 0
        if n_odd:
            for j in range(cnt):
                if sc[_R_ST, j] != -1.0:
                    continue
                ix, iy, iz, ox, oy, oz, st = _load(wi, wo, start + j, check)
                if st == 0 and not (math.isfinite(ix) and math.isfinite(iy) and math.isfinite(iz)
                                    and math.isfinite(ox) and math.isfinite(oy) and math.isfinite(oz)):
                    st = 1  # (unchecked input) not finite: NaN
                sc[_R_ST, j] = st
                sc[_R_ACC, j], sc[_R_ACC + 1, j], sc[_R_ACC + 2, j] = ix, iy, iz
                sc[_R_ACC + 3, j], sc[_R_ACC + 4, j], sc[_R_ACC + 5, j] = ox, oy, oz
        for j in range(cnt):
            good = sc[_R_ST, j] == 0.0
            # pairs not evaluated take the normal's coordinates (their cells stay in the tables)
            ix = sc[_R_ACC, j] if good else 0.0
            iy = sc[_R_ACC + 1, j] if good else 0.0
            iz = sc[_R_ACC + 2, j] if good else 1.0
            ox = sc[_R_ACC + 3, j] if good else 0.0
            oy = sc[_R_ACC + 4, j] if good else 0.0
            oz = sc[_R_ACC + 5, j] if good else 1.0
            ui0, ui1, um0, um1, th_i, ph_i, ozh = _rgl_coordinates(ix, iy, iz, ox, oy, oz, hold, c0, s0, iso,
                                                                   reduction)
            sc[_R_UI0, j] = ui0
            sc[_R_UI1, j] = ui1
            sc[_R_UM0, j] = um0
            sc[_R_UM1, j] = um1
            sc[_R_TH, j] = th_i
            sc[_R_PH, j] = ph_i
            sc[_R_OZ, j] = ozh
        # pass 2: parameter cells and corners (slices q, weights)
        _param_cells(p_phi, sc[_R_PH], cnt, si[_I_A], sc[_R_W + 2], sc[_R_ACC], sc[_R_ACC + 1])
        _param_cells(p_theta, sc[_R_TH], cnt, si[_I_B], sc[_R_W + 3], sc[_R_ACC], sc[_R_ACC + 1])
        for j in range(cnt):
            a = si[_I_A, j]
            bb = si[_I_B, j]
            wa = sc[_R_W + 2, j]
            wb = sc[_R_W + 3, j]
            if n_phi > 1 and n_theta > 1:
                si[_I_Q, j] = a * st_phi + bb * st_theta
                si[_I_Q + 1, j] = a * st_phi + (bb + 1) * st_theta
                si[_I_Q + 2, j] = (a + 1) * st_phi + bb * st_theta
                si[_I_Q + 3, j] = (a + 1) * st_phi + (bb + 1) * st_theta
                sc[_R_W, j] = (1.0 - wa) * (1.0 - wb)
                sc[_R_W + 1, j] = (1.0 - wa) * wb
                sc[_R_W + 2, j] = wa * (1.0 - wb)
                sc[_R_W + 3, j] = wa * wb
            elif n_theta > 1:
                si[_I_Q, j] = bb * st_theta
                si[_I_Q + 1, j] = (bb + 1) * st_theta
                sc[_R_W, j] = 1.0 - wb
                sc[_R_W + 1, j] = wb
            elif n_phi > 1:
                si[_I_Q, j] = a * st_phi
                si[_I_Q + 1, j] = (a + 1) * st_phi
                sc[_R_W, j] = 1.0 - wa
                sc[_R_W + 1, j] = wa
            else:
                si[_I_Q, j] = 0
                sc[_R_W, j] = 1.0
        # pass 3: the warp's cell at u_m, then its tables there summed over the corners (one
        # pair at a time: the gathers are scalar loads either way, the sums stay in registers)
        for j in range(cnt):
            sxx = min(max(sc[_R_UM0, j], 0.0), 1.0) * (w - 1)
            syy = min(max(sc[_R_UM1, j], 0.0), 1.0) * (h - 1)
            px = min(int(sxx), w - 2)
            py = min(int(syy), h - 2)
            si[_I_PX, j] = px
            si[_I_PY, j] = py
            sc[_R_TX, j] = sxx - px
            sc[_R_TY, j] = syy - py
        for j in range(cnt):
            px = si[_I_PX, j]
            py = si[_I_PY, j]
            v0 = sc[_R_W, j]
            if nq == 2:  # an isotropic file's two θi slices (or φi's of a file with one θi)
                v1 = sc[_R_W + 1, j]
                a0, a1, a2, a3, a4, a5, a6, a7, a8 = _warp_at(data_f, cond_f, marg_f, si[_I_Q, j], px, py, h, w)
                b0, b1, b2, b3, b4, b5, b6, b7, b8 = _warp_at(data_f, cond_f, marg_f, si[_I_Q + 1, j], px, py, h, w)
                sc[_R_ACC, j] = v0 * a0 + v1 * b0
                sc[_R_ACC + 1, j] = v0 * a1 + v1 * b1
                sc[_R_ACC + 2, j] = v0 * a2 + v1 * b2
                sc[_R_ACC + 3, j] = v0 * a3 + v1 * b3
                sc[_R_ACC + 4, j] = v0 * a4 + v1 * b4
                sc[_R_ACC + 5, j] = v0 * a5 + v1 * b5
                sc[_R_ACC + 6, j] = v0 * a6 + v1 * b6
                sc[_R_ACC + 7, j] = v0 * a7 + v1 * b7
                sc[_R_ACC + 8, j] = v0 * a8 + v1 * b8
                continue
            a0, a1, a2, a3, a4, a5, a6, a7, a8 = _warp_at(data_f, cond_f, marg_f, si[_I_Q, j], px, py, h, w)
            a0, a1, a2, a3, a4, a5, a6, a7, a8 = (v0 * a0, v0 * a1, v0 * a2, v0 * a3, v0 * a4, v0 * a5, v0 * a6,
                                                  v0 * a7, v0 * a8)
            for c in range(1, nq):
                v = sc[_R_W + c, j]
                b0, b1, b2, b3, b4, b5, b6, b7, b8 = _warp_at(data_f, cond_f, marg_f, si[_I_Q + c, j], px, py, h, w)
                a0, a1, a2, a3, a4, a5, a6, a7, a8 = (a0 + v * b0, a1 + v * b1, a2 + v * b2, a3 + v * b3, a4 + v * b4,
                                                      a5 + v * b5, a6 + v * b6, a7 + v * b7, a8 + v * b8)
            sc[_R_ACC, j] = a0
            sc[_R_ACC + 1, j] = a1
            sc[_R_ACC + 2, j] = a2
            sc[_R_ACC + 3, j] = a3
            sc[_R_ACC + 4, j] = a4
            sc[_R_ACC + 5, j] = a5
            sc[_R_ACC + 6, j] = a6
            sc[_R_ACC + 7, j] = a7
            sc[_R_ACC + 8, j] = a8
        # pass 4: vndf.invert(u_m), and the spectra's cell at the warped sample
        for j in range(cnt):
            fx = sc[_R_TX, j]
            fy = sc[_R_TY, j]
            e0 = _lerp(sc[_R_ACC, j], sc[_R_ACC + 2, j], fy)
            e1 = _lerp(sc[_R_ACC + 1, j], sc[_R_ACC + 3, j], fy)
            fx = fx * _lerp(e0, e1, 0.5 * fx) * inv_w
            fx = fx + _lerp(sc[_R_ACC + 4, j], sc[_R_ACC + 5, j], fy) if si[_I_PX, j] > 0 else fx
            r0 = sc[_R_ACC + 6, j]
            r1 = sc[_R_ACC + 7, j]
            fx = fx / _lerp(r0, r1, fy)
            fy = fy * _lerp(r0, r1, 0.5 * fy) * inv_h
            fy = fy + sc[_R_ACC + 8, j] if si[_I_PY, j] > 0 else fy
            x = min(max(fx, 0.0), 1.0) * (res - 1)
            y = min(max(fy, 0.0), 1.0) * (res - 1)
            jx = max(min(int(x), res - 2), 0)  # (0 for a NaN sample: a cell in the table)
            jy = max(min(int(y), res - 2), 0)
            si[_I_JX, j] = jx
            si[_I_JY, j] = jy
            sc[_R_TX, j] = x - jx
            sc[_R_TY, j] = y - jy
        # pass 5: the spectra there, summed over the corners (every corner, as the reader's lookup)
        row = res * ns
        sl = res * row
        for j in range(cnt):
            si[_I_JX, j] = (si[_I_JY, j] * res + si[_I_JX, j]) * ns  # the cell's flat offset in a slice
        for k in range(ns):
            if nq == 2:
                for j in range(cnt):
                    cell = si[_I_JX, j] + k
                    tx = sc[_R_TX, j]
                    ty = sc[_R_TY, j]
                    sc[_R_SPEC + k, j] = (sc[_R_W, j] * _spectrum_at(spec_f, si[_I_Q, j] * sl + cell, ns, row, tx, ty)
                                          + sc[_R_W + 1, j] * _spectrum_at(spec_f, si[_I_Q + 1, j] * sl + cell, ns,
                                                                           row, tx, ty))
                continue
            for j in range(cnt):
                sc[_R_SPEC + k, j] = sc[_R_W, j] * _spectrum_at(spec_f, si[_I_Q, j] * sl + si[_I_JX, j] + k, ns, row,
                                                                sc[_R_TX, j], sc[_R_TY, j])
            for c in range(1, nq):
                for j in range(cnt):
                    sc[_R_SPEC + k, j] += sc[_R_W + c, j] * _spectrum_at(spec_f, si[_I_Q + c, j] * sl + si[_I_JX, j] + k,
                                                                         ns, row, sc[_R_TX, j], sc[_R_TY, j])
        # pass 6: the factor (its tables' gathers, then the divisions in a loop that vectorizes)
        # and the output channels
        if jacobian:
            for j in range(cnt):
                sc[_R_ACC, j] = _bilinear2(ndf, sc[_R_UM0, j], sc[_R_UM1, j])
                sc[_R_ACC + 1, j] = _bilinear2(sigma, sc[_R_UI0, j], sc[_R_UI1, j])
        for j in range(cnt):
            scale = sc[_R_ACC, j] / (4.0 * sc[_R_ACC + 1, j]) if jacobian else 1.0
            sc[_R_SCALE, j] = scale / sc[_R_OZ, j] if divide else scale
        for c in range(nc):
            l_c, h_c, t_c = lo[c], hi[c], t[c]
            for j in range(cnt):
                out[start + j, c] = (sc[_R_SPEC + l_c, j] * (1.0 - t_c) + sc[_R_SPEC + h_c, j] * t_c) * sc[_R_SCALE, j]
        for j in range(cnt):
            st = sc[_R_ST, j]
            if st != 0.0:
                di, do = _settle(out, start + j, nc, int(st))
                zi += di
                zo += do
    return zi, zo
