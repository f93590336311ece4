"""Helpers for checks that look at a table's nodes: node weights and pairs, a curvature-corrected
interpolant and a reciprocal surrogate (the reciprocity check's interpolated mode), errors
near the horizon."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["missing_mask", "data_values", "node_where", "match_axis", "rusinkiewicz_node_weights", "gonio_node_weights",
           "phi_d_pairs", "cell_widths", "CorrectedInterpolant", "reciprocal_surrogate", "horizon_pairs",
           "horizon_error"]


def missing_mask(table) -> np.ndarray:
    """Boolean mask (shape of ``table.values``) of samples the table declares missing.

    ``Table.missing`` (samples outside the CF ``valid_min``/``valid_max`` of the ``brdf``
    variable); for other table-like objects, samples below ``valid_min``.
    """
    v = np.asarray(table.values)
    if hasattr(table, "missing"):
        m = table.missing
        return np.zeros(v.shape, bool) if m is None else np.broadcast_to(np.asarray(m, bool), v.shape)
    vmin = table.ds["brdf"].attrs.get("valid_min") if hasattr(table, "ds") else None
    if vmin is None:
        return np.zeros(v.shape, bool)
    with np.errstate(invalid="ignore"):
        return v < float(np.asarray(vmin).ravel()[0])


def node_where(table, flat_index: int, labels=None) -> dict:
    """Coordinates of a sample (flat index into ``table.values``) in degrees, and its channel."""
    shape = table.shape if hasattr(table, "shape") else np.asarray(table.values).shape
    idx = np.unravel_index(int(flat_index), shape)
    out = {}
    axes = {getattr(a, "name", ""): a for a in getattr(table.grid, "axes", ())}
    dims = getattr(table.grid, "dims", ())
    for k, i in enumerate(idx[:-1]):
        name = dims[k] if k < len(dims) else f"axis{k}"
        ax = axes.get(name)
        if ax is not None and hasattr(ax, "values") and name.startswith(("theta", "phi", "dtheta", "dphi")):
            out[f"{name}_deg"] = round(float(np.degrees(np.asarray(ax.values)[i])), 6)
        else:
            out[f"{name}_index"] = int(i)
    labels = labels if labels is not None else _labels(table)
    out["channel"] = labels[idx[-1]] if idx[-1] < len(labels) else int(idx[-1])
    return out


def _labels(table):
    if table.spectral:
        return [f"{x:g} nm" for x in table.wavelengths]
    return list(table.channels)


def fmt_where(w: dict) -> str:
    parts = [f"{k[:-4]} = {v:.4g}°" if k.endswith("_deg") else f"{k[:-6]} #{v}"
             for k, v in w.items() if k.endswith(("_deg", "_index"))]
    return ", ".join(parts) + f", channel {w.get('channel')}"


def match_axis(axis, targets, tol: float = 1e-7) -> np.ndarray:
    """Index of the node of ``axis`` equal to each target angle (modulo the axis period or
    wrap), or −1 where there is none."""
    vals = axis.values
    t = np.asarray(targets, float)
    mod = axis.period if axis.period is not None else axis.wrap
    if mod is not None:
        t = vals[0] + np.mod(t - vals[0], mod)
    j = np.searchsorted(vals, t)
    cands = [np.clip(j - 1, 0, vals.size - 1), np.clip(j, 0, vals.size - 1)]
    if mod is not None:  # across the seam
        cands += [np.zeros_like(j), np.full_like(j, vals.size - 1)]
    best = cands[0]
    dbest = np.full(t.shape, np.inf)
    for cand in cands:
        d = np.abs(vals[cand] - t)
        if mod is not None:
            d = np.minimum(d, mod - d)
        better = d < dbest
        best = np.where(better, cand, best)
        dbest = np.where(better, d, dbest)
    return np.where(dbest <= tol, best, -1)


def cell_widths(axis) -> np.ndarray:
    """Width of the cell around each node (half-way to its neighbours; periodic axes wrap)."""
    v = axis.values
    if v.size == 1:
        return np.array([axis.period or np.pi / 2])
    if axis.period is not None:
        ext = np.concatenate([[v[-1] - axis.period], v, [v[0] + axis.period]])
        return 0.5 * (ext[2:] - ext[:-2])
    mids = 0.5 * (v[1:] + v[:-1])
    lo = np.concatenate([[max(0.0, v[0] - (mids[0] - v[0]))], mids])
    hi = np.concatenate([mids, [v[-1] + (v[-1] - mids[-1])]])
    return hi - lo


def rusinkiewicz_node_weights(grid, phi_d_index=None, key=None) -> np.ndarray:
    """cosθi cosθo dωi dωo of each node of a Rusinkiewicz grid (shape ``grid.shape``, or with
    only the φd nodes ``phi_d_index``; ``key``: only the θh nodes of a block, a one-slice tuple).
    A broadcast view: a weight is computed once per distinct (θh, θd, φd), never per φh.

    dωi dωo = 4 cosθd sinθh sinθd dθh dφh dθd dφd (Rusinkiewicz 1998); cosθi and cosθo follow
    from (θh, θd, φd): cosθ_{i,o} = cosθh cosθd ∓ sinθh sinθd cosφd. Weights are 0 below the
    horizon.
    """
    names = grid.dims
    ax = {a.name: a for a in grid.axes}
    sel = slice(None) if phi_d_index is None else np.asarray(phi_d_index)
    shape = list(grid.shape)
    k = names.index("phi_d")
    shape[k] = len(ax["phi_d"]) if phi_d_index is None else len(sel)
    rows = slice(None) if key is None else key[0]
    shape[0] = len(ax["theta_h"].values[rows])

    def along(name, arr):
        s = [1] * len(shape)
        s[names.index(name)] = -1
        return np.reshape(arr, s)

    th = along("theta_h", ax["theta_h"].values[rows])
    td = along("theta_d", ax["theta_d"].values)
    pd = along("phi_d", ax["phi_d"].values[sel])
    a = np.cos(th) * np.cos(td)
    b = np.sin(th) * np.sin(td) * np.cos(pd)
    mu_i = np.maximum(a - b, 0.0)
    mu_o = np.maximum(a + b, 0.0)
    w = 4.0 * np.cos(td) * np.sin(th) * np.sin(td) * mu_i * mu_o
    w = w * along("theta_h", cell_widths(ax["theta_h"])[rows]) * along("theta_d", cell_widths(ax["theta_d"]))
    w = w * along("phi_d", cell_widths(ax["phi_d"])[sel])
    if "phi_h" in ax:
        dph = cell_widths(ax["phi_h"])
        if np.all(dph == dph[0]):  # uniform φh: one factor, the φh axis stays a broadcast
            w = w * dph[0]
        else:
            w = w * along("phi_h", dph)
    return np.broadcast_to(w, tuple(shape))


def data_values(ctx) -> np.ndarray:
    """The table's samples with NaN where they are declared missing (computed once per run;
    the stored array itself when nothing is missing)."""
    def compute():
        t = ctx.brdf
        v = np.asarray(t.values)
        m = t.missing if hasattr(t, "missing") else missing_mask(t)
        if m is None or not np.any(m):
            return v
        return np.where(m, np.nan, v.astype(np.result_type(v.dtype, np.float32)))
    return ctx.memo("data_values", compute)


def over_budget(table) -> bool:
    """True for a table on disk over the memory budget (:attr:`brdftab.table.Table.over_budget`):
    its node pairs are compared block by block (:func:`data_blocks`)."""
    return bool(getattr(table, "over_budget", False))


class NotBlockable(Exception):
    """A comparison of node pairs that needs the whole table at once, which is over budget."""


def data_blocks(ctx):
    """``(key, samples)`` of the table in slabs of its first axis (``key``: a one-slice tuple),
    declared missing samples NaN: the whole table as one block (:func:`data_values`) unless it
    is over the memory budget (:func:`over_budget`), then one slab after another read from disk.
    Raises :class:`NotBlockable` when a single node of the first axis is over the budget."""
    from ..table import _missing_mask, memory_budget

    t = ctx.brdf
    if not over_budget(t):
        yield (slice(0, t.grid.shape[0]),), data_values(ctx)
        return
    # a block as stored; its partners, weights (float64) and the statistics' copies take ~8x that
    row = t.nbytes // max(1, t.shape[0])
    if row * 8 > memory_budget():
        raise NotBlockable(f"one {t.grid.dims[0]} slab of the table ({row / 2**20:.3g} MiB) is over the memory "
                           "budget for comparing node pairs")
    for key, v in t.iter_blocks(max(row, memory_budget() // 64)):
        miss = _missing_mask(v, t._var.attrs)
        v = v if miss is None else np.where(miss, np.nan, v.astype(np.result_type(v.dtype, np.float32)))
        yield key, v


def flat_rows(grid, key):
    """``locate(row)``: the flat node index of row ``row`` of a block ``key`` (whole slabs of
    the first axis) of a table's samples reshaped ``[nodes, C]``."""
    start = (key[0].start or 0) * math.prod(grid.shape[1:])
    return lambda row: start + int(row)


def phi_d_pairs(grid, v, partner, key=None):
    """Rows ``(f1[M, C], f2[M, C], w[M], flat)`` comparing every node with its φd partner
    (``partner[j]`` is the partner of φd node j), each unordered pair once; ``flat`` maps a
    row to the flat node index of its first node. ``v`` may be a block ``key`` (a slab of the
    first axis, :func:`data_blocks`) of the table."""
    k = grid.dims.index("phi_d")
    n = len(partner)
    sel = np.flatnonzero(np.arange(n) <= partner)
    f1 = np.take(v, sel, axis=k)
    f2 = np.take(v, partner[sel], axis=k)
    w = rusinkiewicz_node_weights(grid, sel, key)
    start = 0 if key is None else (key[0].start or 0)
    shape = f1.shape[:-1]
    c = v.shape[-1]
    def flat(row):
        idx = list(np.unravel_index(row, shape))
        idx[k] = sel[idx[k]]
        idx[0] = idx[0] + start
        return int(np.ravel_multi_index(idx, grid.shape))
    return f1.reshape(-1, c), f2.reshape(-1, c), np.ascontiguousarray(w).reshape(-1), flat


def gonio_node_weights(grid, key=None) -> np.ndarray:
    """cosθi cosθo dωi dωo of each node of a spherical (gonio) grid (shape ``grid.shape``;
    ``key``: only the θi nodes of a block, a one-slice tuple)."""
    a_ti, a_pi, a_to, a_po = grid.axes
    rows = slice(None) if key is None else key[0]
    ti = a_ti.values[rows, None, None, None]
    to = a_to.values[None, None, :, None]
    if grid.relative_to == "specular":
        to = ti + to
    w = (np.cos(ti) * np.sin(ti) * cell_widths(a_ti)[rows, None, None, None]
         * np.maximum(np.cos(to), 0.0) * np.abs(np.sin(to)) * cell_widths(a_to)[None, None, :, None]
         * cell_widths(a_pi)[None, :, None, None] * cell_widths(a_po)[None, None, None, :])
    return np.broadcast_to(w, (ti.shape[0],) + tuple(grid.shape[1:]))


def _warp(ax, x):
    return np.sqrt(np.maximum(x, 0.0) / (np.pi / 2)) if ax.warp == "sqrt" else x


def _unwarp(ax, t):
    return t * t * (np.pi / 2) if ax.warp == "sqrt" else t


def uniform_axis(ax) -> bool:
    """True when the axis nodes are equally spaced in its (warped) coordinate."""
    t = _warp(ax, ax.values)
    if t.size < 2:
        return False
    d = np.diff(t)
    return bool(np.allclose(d, d[0], rtol=1e-6, atol=1e-12))


def axis_coordinate(ax, index, shift=0.0) -> np.ndarray:
    """Coordinate at fractional index ``index + shift`` of an axis: linear in its warped
    coordinate between nodes, extrapolated beyond the ends, across the seam of periodic axes."""
    t = _warp(ax, ax.values)
    n = t.size
    x = np.asarray(index, float) + shift
    if n == 1:
        return np.full(x.shape, ax.values[0])
    if ax.period is not None:
        tt = np.append(t, t[0] + ax.period)
        i0 = np.floor(x).astype(int)
        frac = x - i0
        i0m = np.mod(i0, n)
        base = tt[i0m] + (i0 - i0m) // n * ax.period
        return _unwarp(ax, base + frac * (tt[i0m + 1] - tt[i0m]))
    i0 = np.clip(np.floor(x).astype(int), 0, n - 2)
    frac = x - i0
    return _unwarp(ax, t[i0] + frac * (t[i0 + 1] - t[i0]))


def pair_directions(grid, coords):
    """(wi, wo) of grid coordinates (one array per axis, in the grid's axis order)."""
    from ..geometry import hd_to_io, sph_to_vec

    own = getattr(grid, "pair_directions", None)
    if callable(own):
        return own(coords)
    c = dict(zip(grid.dims, coords))
    if grid.parameterization == "rusinkiewicz":
        return hd_to_io(c["theta_h"], c.get("phi_h", 0.0), c["theta_d"], c["phi_d"])
    ti, pi_ = c["theta_i"], c["phi_i"]
    if grid.relative_to == "specular":
        to, po = ti + c["dtheta_o"], pi_ + np.pi + c["dphi_o"]
    else:
        to, po = c["theta_o"], c["phi_o"]
    return sph_to_vec(ti, pi_), sph_to_vec(to, po)


# -- a curvature-corrected interpolant (the reciprocity check's interpolated mode) --------------

class CorrectedInterpolant:
    """A table's multilinear interpolation and the same with its leading error term removed.

    Multilinear interpolation at fraction p of a cell of width h along an axis is off by
    ½ p(1 − p) h² f'' (+ higher orders) per axis; f'' is estimated at every node from the
    second divided difference of its neighbours along the axis (in the axis' warped coordinate,
    across the seam of periodic axes; copied from the neighbour at the ends of other axes),
    interpolated to the query like the values, and the term subtracted. At the nodes both
    agree with the stored values. Only nodes the table's interpolation uses take part (its
    ``(values, valid)``: horizon ghosts included, missing samples left out); f'' is 0 where a
    node lacks a valid 3-node stencil. The corrected value is not taken below 0 (below the
    multilinear value where that is negative).

    ``(wi, wo) → (linear, corrected)``, each ``[N, C]`` over the table's stored channels.
    """

    def __init__(self, table, values=None, valid=None):
        if values is None:
            values, valid = table._interp_data()
        self.table = table
        self.grid = table.grid
        self.values = values
        # a broadcast mask would be copied by every interpolation (reshape): materialize it once
        self.valid = None if valid is None else np.ascontiguousarray(valid)
        self.curvature = [_second_difference(values, self.valid, a, ax) if len(ax) >= 3 else None
                          for a, ax in enumerate(self.grid.axes)]

    def __call__(self, wi, wo):
        from ..table import _data_nodes, _multilinear, _nearest_fill

        axes = self.grid.axes
        idx, _ = self.grid.locate(wi, wo, isotropic=self.table.isotropic)
        fill = _nearest_fill(self.values, lambda: _data_nodes(self.grid, self.values, self.valid), axes)
        linear = _multilinear(self.values, idx, axes, self.valid, fill=fill)  # as the table evaluates
        corrected = np.array(linear, float, copy=True)
        for a, cur in enumerate(self.curvature):
            if cur is None:
                continue
            d2, has = cur
            p, h = _cell_fraction(axes[a], idx[a])
            f2 = _multilinear(d2, idx, axes, has)
            corrected -= (0.5 * p * (1.0 - p) * h * h)[:, None] * np.nan_to_num(f2, nan=0.0, posinf=0.0, neginf=0.0)
        # a BRDF is not negative: the correction may not take a value below 0 (or below the
        # multilinear value where the table itself is negative)
        np.maximum(corrected, np.minimum(linear, 0.0), out=corrected, where=np.isfinite(linear))
        return linear, corrected


def _warped(ax):
    return _warp(ax, ax.values)


def _cell_fraction(ax, x):
    """Fraction ``p`` within its cell and the cell's width ``h`` (warped coordinate) of
    fractional indices ``x`` along ``ax`` (as :func:`brdftab.table._multilinear` splits them)."""
    t = _warped(ax)
    n = t.size
    i0 = np.floor(x).astype(np.intp)
    if ax.period is not None:
        p = x - i0
        i0 %= n
        tt = np.append(t, t[0] + ax.period)
        return p, tt[i0 + 1] - tt[i0]
    i0 = np.clip(i0, 0, n - 2)
    p = np.clip(x - i0, 0.0, 1.0)
    return p, t[i0 + 1] - t[i0]


def _second_difference(values, valid, axis, ax):
    """``(f'', has)``: the second divided difference of ``values`` along ``axis`` at every node
    (warped coordinate; periodic axes wrap; the end nodes of other axes copy their neighbour)
    and where it rests on three valid nodes (f'' is 0 elsewhere; ``has`` None when everywhere)."""
    t = _warped(ax)
    v = np.moveaxis(np.asarray(values, float), axis, 0)
    ok = None if valid is None else np.moveaxis(np.asarray(valid, bool), axis, 0)
    periodic = ax.period is not None
    if periodic:
        tt = np.concatenate([t, [t[0] + ax.period]])
        slope = np.empty(v.shape)  # slope[j]: between nodes j and j + 1 (across the seam for the last)
        np.subtract(v[1:], v[:-1], out=slope[:-1])
        np.subtract(v[0], v[-1], out=slope[-1])
    else:
        tt = t
        slope = np.diff(v, axis=0)
    h = np.diff(tt)
    shape = (-1,) + (1,) * (v.ndim - 1)
    slope /= h.reshape(shape)
    out = np.zeros(v.shape)
    if periodic:  # node j: slopes j − 1 (wrapping) and j
        hs = (h + np.roll(h, 1)).reshape(shape)
        np.subtract(slope, np.roll(slope, 1, axis=0), out=out)
        out *= 2.0 / hs
    else:
        hs = (h[1:] + h[:-1]).reshape(shape)
        np.subtract(slope[1:], slope[:-1], out=out[1:-1])
        out[1:-1] *= 2.0 / hs
    good = np.isfinite(out)
    if ok is not None:
        three = ok & np.roll(ok, 1, axis=0) & np.roll(ok, -1, axis=0)
        good &= three
    if not periodic:
        good[0] = good[-1] = False
    np.copyto(out, 0.0, where=~good)
    if not periodic:
        out[0], good[0] = out[1], good[1]
        out[-1], good[-1] = out[-2], good[-2]
    out = np.ascontiguousarray(np.moveaxis(out, 0, axis))
    return out, (None if good.all() else np.ascontiguousarray(np.moveaxis(good, 0, axis)))


def reciprocal_surrogate(interp: CorrectedInterpolant, chunk: int = 1 << 16) -> CorrectedInterpolant:
    """A reciprocal table of the same content and resolution as ``interp``'s table: at every
    node holding data whose reverse pair lies in the table's domain, ½ (stored value + the
    corrected interpolation at the reverse pair); elsewhere the stored value (horizon ghosts
    recomputed from these values). Interpolating it both ways measures how much asymmetry the
    table's resolution alone produces."""
    from ..table import _horizon_ghosts

    table, grid = interp.table, interp.grid
    stored = np.asarray(table.values)
    c = stored.shape[-1]
    miss = table.missing if hasattr(table, "missing") else None
    g = np.array(stored, float, copy=True).reshape(-1, c)
    above = grid.node_above_horizon()
    use = above.reshape(-1) if miss is None else (above & ~np.asarray(miss, bool).any(axis=-1)).reshape(-1)
    for start in range(0, grid.size, chunk):
        stop = min(start + chunk, grid.size)
        sel = np.flatnonzero(use[start:stop])
        if sel.size == 0:
            continue
        wi, wo = grid.directions(start, stop)
        wi, wo = wi[sel], wo[sel]
        _, outside = grid.locate(wo, wi, isotropic=table.isotropic)
        keep = ~np.asarray(outside, bool)
        if not keep.any():
            continue
        rows = start + sel[keep]
        _, rev = interp(wo[keep], wi[keep])
        fine = np.isfinite(rev)
        g[rows] = np.where(fine, 0.5 * (g[rows] + np.where(fine, rev, 0.0)), g[rows])
    g = g.reshape(stored.shape)
    if above.all():
        valid = None if miss is None else ~np.asarray(miss, bool)
    else:
        g, ok = _horizon_ghosts(g, above, grid, miss)
        valid = np.broadcast_to(ok[..., None], g.shape)
        if miss is not None:
            valid = valid & ~np.asarray(miss, bool)
    return CorrectedInterpolant(table, g, valid)


# -- errors near the horizon (for the tabulation check's report) ---------------------------------

def horizon_pairs(grid, n: int, seed: int = 0, band: float = np.radians(0.5), isotropic: bool = False):
    """About ``n`` pairs ``(wi, wo)`` with θi or θo within ``band`` [rad] of the horizon (uniform
    in cosθ there; the other direction uniform in cosθ over the hemisphere; azimuths uniform),
    kept where they lie inside ``grid``'s domain."""
    from ..geometry import sph_to_vec

    rng = np.random.default_rng(seed)
    near = np.arccos(rng.uniform(0.0, np.sin(band), n))
    other = np.arccos(rng.uniform(0.0, 1.0, n))
    swap = rng.random(n) < 0.5
    ti, to = np.where(swap, near, other), np.where(swap, other, near)
    wi = sph_to_vec(ti, rng.uniform(-np.pi, np.pi, n))
    wo = sph_to_vec(to, rng.uniform(-np.pi, np.pi, n))
    keep = (wi[:, 2] > 1e-12) & (wo[:, 2] > 1e-12)
    _, outside = grid.locate(wi, wo, isotropic=isotropic)
    keep &= ~np.asarray(outside, bool)
    return wi[keep], wo[keep]


def horizon_error(table, model, n: int = 8192, seed: int = 0, band: float = np.radians(0.5), wavelengths=None):
    """A table against its model within ``band`` of the horizon (:func:`horizon_pairs`): the
    largest relative error |t − m| / m where m > 0 and the pair where it occurs, and how many
    such pairs the table reads as exactly 0. None when no pair lies in the table's domain
    there. Returns ``{"band_deg", "points", "max_relative", "where", "zeros"}`` (``where`` as
    :func:`~brdftab.checks._pairs.where_deg`)."""
    from ._pairs import where_deg

    wi, wo = horizon_pairs(table.grid, n, seed, band, getattr(table, "isotropic", False))
    if wi.shape[0] == 0:
        return None
    t = np.asarray(table.eval(wi, wo, wavelengths), float)
    m = np.asarray(model.eval(wi, wo, wavelengths), float)
    if t.shape != m.shape:  # a grey model behind an RGB table (MERL stores three channels)
        t, m = np.broadcast_arrays(t, m)
    pos = np.isfinite(t) & np.isfinite(m) & (m > 0)
    if not pos.any():
        return None
    rel = np.divide(np.abs(t - m), m, out=np.zeros(m.shape), where=pos)
    k = int(np.unravel_index(np.argmax(rel), rel.shape)[0])
    return {"band_deg": float(np.degrees(band)), "points": int(pos.any(axis=-1).sum()),
            "max_relative": float(rel.max()), "where": where_deg(wi[k], wo[k]),
            "zeros": int(np.count_nonzero((t == 0) & pos))}
