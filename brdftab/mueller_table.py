"""Polarized tables: the Mueller matrix of a BRDF sampled on a grid and interpolated.

A polarized table holds, beside ``brdf`` (f_r,11 = M00, what every unpolarized reader, check and
format uses), the variable ``mueller`` [sr-1] with dims ``grid.dims + (channel | wavelength,
"mueller_row", "mueller_col")``: ``mueller[..., i, j]`` is row i, column j of the Mueller
matrix M(wi, wo) that maps the Stokes vector of the light arriving from ``wi`` to that of the
light leaving along ``wo`` (no cosine). Its attributes state the frame:

* ``mueller_basis = "mitsuba"``: both beams share the x reference normalize(wi × wo) (wi the
  direction towards the light, wo towards the viewer: perpendicular to the scattering plane),
  each beam's y = z × x with z its propagation direction (Mitsuba 3's ``measured_polarized``
  frame);
* ``mueller_circular = "+S3 right circular (Chipman)"``.

Nodes where the scattering plane is undefined (wi = wo: θd = 0 on a Rusinkiewicz grid) hold the
limit of M as θd → 0 along the node's φd (the model is evaluated at θd = :data:`THETA_D_NUDGE`).

:func:`eval_mueller` interpolates the matrix like :class:`~brdftab.table.Table` interpolates
``brdf`` (the same multilinear weights, periodic axes and horizon ghosts), except that ghost
values of elements other than M00 are not clamped at 0 (they may be negative).
"""

from __future__ import annotations

import numpy as np
import xarray as xr

from .channels import Layout
from .errors import BrdftabError, FormatError, ParameterError
from .table import Table, _horizon_ghosts, _interp_dtype, _interp_last, check_memory, make_table

__all__ = ["MUELLER_VAR", "ROW_DIM", "COL_DIM", "BASIS_ATTR", "CIRCULAR_ATTR", "MITSUBA_BASIS", "MITSUBA_CIRCULAR",
           "THETA_D_NUDGE", "is_polarized", "mueller_at_nodes", "mueller_variable", "check_mueller_variable",
           "eval_mueller", "require_polarized"]

MUELLER_VAR = "mueller"
ROW_DIM = "mueller_row"
COL_DIM = "mueller_col"
BASIS_ATTR = "mueller_basis"
CIRCULAR_ATTR = "mueller_circular"
MITSUBA_BASIS = "mitsuba"
MITSUBA_CIRCULAR = "+S3 right circular (Chipman)"
#: θd [rad] at which a node with wi = wo (θd = 0) is evaluated: its value is the limit along φd.
THETA_D_NUDGE = 1e-6
#: |wi × wo| below which a pair's scattering plane counts as undefined.
DEGENERATE = 1e-9


def is_polarized(brdf) -> bool:
    """True for a BRDF that gives its Mueller matrix (``eval_mueller``): a polarized model, or a
    table holding a ``mueller`` variable."""
    flag = getattr(brdf, "polarized", None)
    if flag is not None:
        return bool(flag)
    return callable(getattr(brdf, "eval_mueller", None))


def require_polarized(brdf, what: str = "") -> None:
    """Raise a one-line error when ``brdf`` has no Mueller matrix."""
    if not is_polarized(brdf):
        where = f"{what}: " if what else ""
        raise BrdftabError(f"{where}{brdf.describe()} is not polarized (it has no Mueller matrix: use a polarized "
                           "model, or a table tabulated with polarized = true in [grid])")


def _node_directions(grid, start, stop):
    """``(wi, wo)`` of flat nodes ``start..stop``, with the pairs whose scattering plane is
    undefined (wi = wo) moved to θd = :data:`THETA_D_NUDGE` along the node's φd."""
    from .geometry import hd_to_io, io_to_hd

    wi, wo = grid.directions(start, stop)
    cross = np.linalg.norm(np.cross(wi, wo), axis=-1)
    bad = np.flatnonzero((cross < DEGENERATE) & (np.sum(wi * wo, axis=-1) > 0))  # wi = wo (not wi = -wo)
    if bad.size:
        th, ph, td, pd = io_to_hd(wi[bad], wo[bad])
        if "phi_d" in grid.dims:  # a Rusinkiewicz node: its own φd (io_to_hd cannot tell at θd = 0)
            idx = np.unravel_index(np.arange(start, stop)[bad], grid.shape)
            a = grid.dims.index("phi_d")
            pd = grid.axes[a].values[idx[a]]
            if "phi_h" in grid.dims:
                b = grid.dims.index("phi_h")
                ph = grid.axes[b].values[idx[b]]
        wi[bad], wo[bad] = hd_to_io(th, ph, np.maximum(td, THETA_D_NUDGE), pd)
    return wi, wo


def mueller_at_nodes(brdf, grid, lam, out, chunk: int = 1 << 14, bar=None) -> None:
    """Fill ``out[grid.shape + (n, 4, 4)]`` with ``brdf.eval_mueller`` (Mitsuba's basis) at the
    nodes of ``grid``, ``chunk`` nodes at a time."""
    require_polarized(brdf)
    flat = out.reshape((-1,) + out.shape[-3:])
    for start in range(0, grid.size, chunk):
        stop = min(start + chunk, grid.size)
        wi, wo = _node_directions(grid, start, stop)
        m = np.asarray(brdf.eval_mueller(wi, wo, lam, basis=MITSUBA_BASIS), float)
        if m.shape != (stop - start,) + out.shape[-3:]:
            raise BrdftabError(f"{brdf.describe()}: eval_mueller returned shape {m.shape}, expected "
                               f"{(stop - start,) + out.shape[-3:]}")
        flat[start:stop] = m
        if bar is not None:
            bar.update(stop - start)


def mueller_variable(values, grid, chan_dim: str) -> xr.Variable:
    """The ``mueller`` variable of a table (``values[grid.shape + (n, 4, 4)]``)."""
    return xr.Variable(grid.dims + (chan_dim, ROW_DIM, COL_DIM), values, attrs={
        "units": "sr-1",
        "long_name": "Mueller matrix of the bidirectional reflectance distribution function",
        "quantity": "M[..., i, j]: row i, column j, mapping the Stokes vector arriving from wi to the one leaving "
                    "along wo (not multiplied by cos(theta)); M[..., 0, 0] equals brdf",
        BASIS_ATTR: MITSUBA_BASIS,
        "mueller_frame": "both beams share x = normalize(wi x wo) (wi towards the light, wo towards the viewer), "
                         "y = z x x with z the propagation direction of each beam",
        CIRCULAR_ATTR: MITSUBA_CIRCULAR,
    })


def mueller_coords() -> dict:
    return {ROW_DIM: xr.Variable((ROW_DIM,), np.arange(4, dtype=np.int32), attrs={"long_name": "Mueller matrix row"}),
            COL_DIM: xr.Variable((COL_DIM,), np.arange(4, dtype=np.int32),
                                 attrs={"long_name": "Mueller matrix column"})}


def check_mueller_variable(ds, grid_dims, chan_dim) -> None:
    """Refuse (FormatError, one line) a ``mueller`` variable of the wrong shape or frame."""
    var = ds[MUELLER_VAR]
    expected = tuple(grid_dims) + (chan_dim, ROW_DIM, COL_DIM)
    if set(var.dims) != set(expected):
        raise FormatError(f"table variable '{MUELLER_VAR}' has dims {var.dims}, expected {expected}")
    if var.sizes[ROW_DIM] != 4 or var.sizes[COL_DIM] != 4:
        raise FormatError(f"table variable '{MUELLER_VAR}' must be 4 x 4 per sample, not "
                          f"{var.sizes[ROW_DIM]} x {var.sizes[COL_DIM]}")
    if var.sizes[chan_dim] != ds["brdf"].sizes[chan_dim]:
        raise FormatError(f"table variable '{MUELLER_VAR}' has {var.sizes[chan_dim]} {chan_dim}s, brdf "
                          f"{ds['brdf'].sizes[chan_dim]}")
    basis = _text(var.attrs.get(BASIS_ATTR, ""))
    if basis != MITSUBA_BASIS:
        raise FormatError(f"table variable '{MUELLER_VAR}' has {BASIS_ATTR} = {basis!r}; brdftab reads Mueller tables "
                          f"in the {MITSUBA_BASIS!r} basis")
    circ = _text(var.attrs.get(CIRCULAR_ATTR, MITSUBA_CIRCULAR))
    if not circ.startswith("+S3 right"):
        raise FormatError(f"table variable '{MUELLER_VAR}' has {CIRCULAR_ATTR} = {circ!r}; expected "
                          f"{MITSUBA_CIRCULAR!r} with the {MITSUBA_BASIS!r} basis")


def _text(v) -> str:
    if isinstance(v, (bytes, np.bytes_)):
        return bytes(v).decode("utf-8", "replace")
    return str(v.item() if hasattr(v, "item") else v)


def mueller_values(table) -> np.ndarray:
    """The stored Mueller samples ``grid.shape + (C, 4, 4)`` (loaded and cached, float64)."""
    cached = table.__dict__.get("_mueller_values")
    if cached is None:
        var = table.ds[MUELLER_VAR].transpose(*(table.grid.dims + (table._var.dims[-1], ROW_DIM, COL_DIM)))
        check_memory(var.size * 8, f"the Mueller matrices of {table.describe()}", peak=1.0)
        cached = table._read(var).astype(float)
        table.__dict__["_mueller_values"] = cached
    return cached


def _view(table):
    """A table whose channels are the 16·C Mueller elements (M00 of channel c at 16·c), on the
    table's grid: its interpolation is the table's."""
    cached = table.__dict__.get("_mueller_view")
    if cached is not None:
        return cached
    m = mueller_values(table)
    c = m.shape[-3]
    # in the table's interpolation dtype (float32 samples exactly as stored: their horizon
    # ghosts are then the f table's, and eval equals M00 of eval_mueller)
    flat = m.reshape(table.grid.shape + (c * 16,)).astype(_interp_dtype(table._var.dtype), copy=False)
    names = tuple(f"m{i}{j}_{k}" for k in range(c) for i in range(4) for j in range(4))
    view = make_table(flat, table.grid, Layout(names))
    view.__class__ = _MuellerView
    view.isotropic = table.isotropic
    view.outside = table.outside
    table.__dict__["_mueller_view"] = view
    return view


def element_floor(n_channels: int) -> np.ndarray:
    """Lowest ghost value per Mueller-element channel (16 per channel, M00 first): 0 for M00
    (an intensity, clamped like ``brdf``), −inf for the others (they may be negative)."""
    floor = np.full(n_channels * 16, -np.inf)
    floor[::16] = 0.0
    return floor


def ghosted(values, grid):
    """``(values, valid)``: Mueller samples ``grid.shape + (16·C,)`` with the horizon ghosts of
    :func:`brdftab.table._horizon_ghosts` at below-horizon nodes (M00 clamped at 0, the other
    elements not) and the nodes that hold data (None: all); NaN samples are missing."""
    above = grid.node_above_horizon()
    nan = np.isnan(values).any(axis=-1)
    bad = np.broadcast_to(nan[..., None], values.shape) if nan.any() else None
    if above.all() and bad is None:
        return values, None
    values, ok = _horizon_ghosts(np.where(bad, 0.0, values) if bad is not None else values, above, grid, bad,
                                 floor=element_floor(values.shape[-1] // 16))
    valid = np.broadcast_to(ok[..., None], values.shape)
    if bad is not None:
        valid = valid & ~bad
    return values, valid


class _MuellerView(Table):
    """The Mueller elements of a polarized table as channels (see :func:`_view`)."""

    def _interp_data(self):
        cached = getattr(self, "_interp", None)
        if cached is None:
            cached = self._interp = ghosted(self.values, self.grid)
        return cached


def ghosted_mueller(table) -> np.ndarray:
    """The Mueller samples ``grid.shape + (C, 4, 4)`` with the horizon ghosts the interpolation
    uses at below-horizon nodes (what a reader that interpolates every stored node, such as
    Mitsuba's ``measured_polarized``, should find there); NaN where no value is known."""
    view = _view(table)
    return ghosted_nan(*view._interp_data(), table.grid)


def ghosted_nan(values, valid, grid):
    """``values`` (from :func:`ghosted`) ``grid.shape + (C, 4, 4)`` with NaN where not valid."""
    out = np.array(values, float, copy=True)
    if valid is not None:
        out[~np.asarray(valid)] = np.nan
    return out.reshape(grid.shape + (-1, 4, 4))


def eval_mueller(table, wi, wo, wavelengths=None, basis: str = MITSUBA_BASIS) -> np.ndarray:
    """The interpolated Mueller matrix of a polarized ``table`` at ``(wi, wo)``:
    ``[..., n_channels, 4, 4]`` in ``basis`` (zero where either direction is below the horizon)."""
    from .geometry import as_directions

    if not is_polarized(table):
        raise BrdftabError(f"{table.describe()} holds no Mueller matrix (tabulate with polarized = true in [grid])")
    wi, wo = as_directions(wi, wo)
    lam = table.layout.resolve(wavelengths)
    n = table.layout.n_out(lam)
    lead = wi.shape[:-1]
    view = _view(table)
    c = table.shape[-1]
    out = view.eval(wi.reshape(-1, 3), wo.reshape(-1, 3)).reshape(-1, c, 4, 4)
    if lam is not None and table.spectral:
        stored = table.layout.wavelengths
        if not (stored.shape == lam.shape and np.array_equal(stored, lam)):
            flat = np.moveaxis(out, 1, -1).reshape(-1, c)
            out = np.moveaxis(_interp_last(flat, stored, lam).reshape(-1, 4, 4, n), -1, 1)
    elif c != n:
        out = np.repeat(out, n, axis=1)
    out = out.reshape(lead + (n, 4, 4))
    if basis != MITSUBA_BASIS:
        out = _convert(out, wi, wo, basis)
    return out


def _convert(m, wi, wo, basis):
    try:
        from .polarization import convert_basis
    except ImportError:  # pragma: no cover - the basis conversions live in brdftab.polarization
        raise ParameterError("basis", f"only {MITSUBA_BASIS!r} is available without brdftab.polarization") from None
    return convert_basis(m, wi[..., None, :], wo[..., None, :], MITSUBA_BASIS, basis)
