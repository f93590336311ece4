"""Helpers for checks that look at a table's nodes."""

from __future__ import annotations

import numpy as np

__all__ = ["missing_mask", "data_values", "node_where", "match_axis", "rusinkiewicz_node_weights", "gonio_node_weights",
           "phi_d_pairs", "cell_widths"]


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
    shape = np.asarray(table.values).shape
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


def rusinkiewicz_node_weights(grid, phi_d_index=None) -> np.ndarray:
    """cosθi cosθo dωi dωo of each node of a Rusinkiewicz grid (shape ``grid.shape``, or with
    only the φd nodes ``phi_d_index``).

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

    def along(name, arr):
        s = [1] * len(shape)
        s[names.index(name)] = -1
        return np.reshape(arr, s)

    th = along("theta_h", ax["theta_h"].values)
    td = along("theta_d", ax["theta_d"].values)
    pd = along("phi_d", ax["phi_d"].values[sel])
    a = np.cos(th) * np.cos(td)
    b = np.sin(th) * np.sin(td) * np.cos(pd)
    mu_i = np.maximum(a - b, 0.0)
    mu_o = np.maximum(a + b, 0.0)
    w = 4.0 * np.cos(td) * np.sin(th) * np.sin(td) * mu_i * mu_o
    w = w * along("theta_h", cell_widths(ax["theta_h"])) * along("theta_d", cell_widths(ax["theta_d"]))
    w = w * along("phi_d", cell_widths(ax["phi_d"])[sel])
    if "phi_h" in ax:
        w = w * along("phi_h", cell_widths(ax["phi_h"]))
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


def phi_d_pairs(grid, v, partner):
    """Rows ``(f1[M, C], f2[M, C], w[M], flat)`` comparing every node with its φd partner
    (``partner[j]`` is the partner of φd node j), each unordered pair once; ``flat`` maps a
    row to the flat node index of its first node."""
    k = grid.dims.index("phi_d")
    n = len(partner)
    sel = np.flatnonzero(np.arange(n) <= partner)
    f1 = np.take(v, sel, axis=k)
    f2 = np.take(v, partner[sel], axis=k)
    w = rusinkiewicz_node_weights(grid, sel)
    shape = f1.shape[:-1]
    c = v.shape[-1]
    def flat(row):
        idx = list(np.unravel_index(row, shape))
        idx[k] = sel[idx[k]]
        return int(np.ravel_multi_index(idx, grid.shape))
    return f1.reshape(-1, c), f2.reshape(-1, c), np.ascontiguousarray(w).reshape(-1), flat


def gonio_node_weights(grid) -> np.ndarray:
    """cosθi cosθo dωi dωo of each node of a spherical (gonio) grid (shape ``grid.shape``)."""
    a_ti, a_pi, a_to, a_po = grid.axes
    ti = a_ti.values[:, None, None, None]
    to = a_to.values[None, None, :, None]
    if grid.relative_to == "specular":
        to = ti + to
    w = (np.cos(ti) * np.sin(ti) * cell_widths(a_ti)[:, None, None, None]
         * np.maximum(np.cos(to), 0.0) * np.abs(np.sin(to)) * cell_widths(a_to)[None, None, :, None]
         * cell_widths(a_pi)[None, :, None, None] * cell_widths(a_po)[None, None, None, :])
    return np.broadcast_to(w, grid.shape)


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

    c = dict(zip(grid.dims, coords))
    if grid.parameterization == "rusinkiewicz":
        return hd_to_io(c["theta_h"], c.get("phi_h", 0.0), c["theta_d"], c["phi_d"])
    ti, pi_ = c["theta_i"], c["phi_i"]
    if grid.relative_to == "specular":
        to, po = ti + c["dtheta_o"], pi_ + np.pi + c["dphi_o"]
    else:
        to, po = c["theta_o"], c["phi_o"]
    return sph_to_vec(ti, pi_), sph_to_vec(to, po)
