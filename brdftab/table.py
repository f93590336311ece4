"""Tables: a BRDF sampled on a grid, held as a self-describing ``xarray.Dataset``.

Layout of the dataset (also the netCDF layout, see ``formats/netcdf.md``):

* variable ``brdf`` (units ``sr-1``) with dims ``grid.dims + ("channel",)`` or
  ``grid.dims + ("wavelength",)``;
* one coordinate per grid axis, in radians (``units = "rad"``); ``channel`` (names) or
  ``wavelength`` (``units = "nm"``);
* optionally variable ``specular_reflectance`` (units ``1``) with dims
  ``("specular_theta_i", "channel" | "wavelength")``: the ideal specular (delta) reflectance
  of the source per incidence angle — the fraction of the incident flux sent into the mirror
  direction, which no BRDF sample can hold (a delta). :meth:`Table.specular_delta` interpolates
  it linearly in θi and the albedo integrals add it; formats that cannot store it say so on
  export (:func:`warn_specular_dropped`);
* attributes: ``parameterization``, ``grid``, ``sample_position``, ``phi_d_fold``
  (+ ``theta_h_spacing`` / ``relative_to``), ``model``, ``parameters`` (JSON, angles in
  radians), ``spec_sha256``, ``brdftab_version``, ``created``, ``isotropic``,
  ``reciprocal``, ``origin`` (``analytic`` | ``measured`` | ``unknown``; a file without it is
  ``unknown``, and one without ``reciprocal`` does not declare reciprocity) and the
  direction/φ conventions in words.

A :class:`Table` is a :class:`~brdftab.brdf.BRDF`: it evaluates at any (wi, wo) by
multilinear interpolation in its grid's index space — linear in the warped coordinate of
warped axes (MERL θh), periodic across the seam of periodic axes (φd, φh), after folding φd
by the table's declared fold. At its own nodes it returns the stored values exactly. A table of
scattered samples (:class:`~brdftab.grids.ScatteredGrid`: ASTM and CSV files) interpolates
linearly on their Delaunay triangulation instead (:mod:`brdftab.grids.scattered`).
The interpolation runs compiled, one pass per direction pair written into the result
(:mod:`brdftab._interp_kernels`); the numpy code it replaced (:meth:`Table._eval_numpy`, also the
path of a table evaluated slab by slab from disk) is its reference, and the two agree to 1e-12
relative on every grid type (``tests/test_table.py``).

Three rules keep interpolation honest:

* **Only valid nodes take part.** Nodes whose directions lie below the horizon (their stored
  0 is not data) and *missing* samples (values outside the CF ``valid_min``/``valid_max`` of
  the ``brdf`` variable, e.g. MERL's negative markers) are left out and the weights of the
  remaining corners renormalized. A query whose corners are all missing returns NaN.
  Below-horizon nodes next to the horizon get *ghost* values extrapolated from the valid
  nodes beside them (:func:`_horizon_ghosts`). A query above the horizon whose cell has no
  valid corner at all (on the MERL grid: θh and θd near 90° with φd within a fraction of a
  degree of ±90°, where the φd nodes either side put wi or wo below the horizon) is never
  read as the stored zeros: each corner takes the value of its nearest node holding data
  (:func:`_nearest_fill`). Measured on a GGX α = 0.05 MERL-grid table at 10⁶ random pairs
  with θi or θo in (89.5°, 90°): no exact zeros (1.6e-4 of them were 0 before), largest
  relative error 0.49 (beyond the last θh node, 89.0°, whose value the table holds up to
  θh = 90°; ≤ 0.34 elsewhere, ≤ 0.25 in cells without a valid corner); a Lambertian table is
  exact to rounding there (``tests/test_table.py``).
* **Outside the domain is not an answer.** A query outside the grid's domain (see
  :mod:`brdftab.grids.axis`) returns NaN with one warning per table (``outside = "nan"``,
  the default), raises (``"raise"``) or takes the nearest node (``"clamp"``).
* **Nothing is loaded before it is needed.** A table read from a file keeps its values on
  disk until it is evaluated; loading refuses honestly when the values would not fit in
  memory (:func:`check_memory`).
"""

from __future__ import annotations

import datetime as _dt
import itertools
import json
import math
import os
import warnings

import numpy as np
import xarray as xr

from ._signals import read_array
from ._version import __version__
from .brdf import BRDF, ORIGINS, compiled_enabled
from .quadrature import gauss_legendre
from .channels import Layout
from .errors import BrdftabError, BrdftabWarning, FormatError, ParameterError
from .grids import Grid, check_grid, grid_from_dataset

__all__ = ["Table", "tabulate", "make_table", "fill_values", "blocks", "chunk_shape", "memory_budget", "parse_size", "check_memory", "check_checked_memory", "OUTSIDE_MODES", "DEFAULT_CHUNK", "DIRECTION_CONVENTION",
           "PHI_CONVENTION", "SPECULAR_VAR", "SPECULAR_DIM", "SPECULAR_THETA_I", "carries_specular_delta",
           "warn_specular_dropped", "set_albedo_curve", "ALBEDO_VAR", "ALBEDO_DIM", "ALBEDO_WHITE_SKY",
           "LABEL_SUFFIX"]

OUTSIDE_MODES = ("nan", "raise", "clamp")

#: Samples evaluated per chunk; bounds the temporaries of a tabulation (~tens of MB).
DEFAULT_CHUNK = 1 << 16
#: Seconds a tabulation runs before its progress bar appears.
PROGRESS_DELAY = 2.0

#: The variable and coordinate holding an ideal specular (delta) reflectance per incidence angle.
SPECULAR_VAR = "specular_reflectance"
SPECULAR_DIM = "specular_theta_i"
#: Incidence angles [rad] at which a delta reflectance is stored: every 0.025° from 0 to 90°.
SPECULAR_THETA_I = np.radians(np.linspace(0.0, 90.0, 3601))

DIRECTION_CONVENTION = ("wi and wo are unit vectors pointing away from the surface in a local frame with the "
                        "normal along +z; theta is the polar angle from +z, phi the azimuth from +x towards +y")
PHI_CONVENTION = ("Rusinkiewicz: h = normalize(wi + wo), d = Ry(-theta_h) Rz(-phi_h) wi (MERL BRDFRead.cpp); "
                  "phi_h := 0 where theta_h = 0; spherical: azimuths of the away-pointing vectors, the mirror "
                  "direction of (theta_i, phi_i) is (theta_i, phi_i + pi)")


class Table(BRDF):
    """A tabulated BRDF backed by an ``xarray.Dataset`` (see the module docstring).

    ``outside`` chooses what a query outside the grid's domain gives: ``"nan"`` (default,
    with one warning), ``"raise"`` (:class:`~brdftab.errors.BrdftabError` naming the domain)
    or ``"clamp"`` (the nearest node).
    """

    def __init__(self, ds: xr.Dataset, outside: str = "nan"):
        if "brdf" not in ds.data_vars:
            raise FormatError("not a brdftab table: no variable 'brdf'")
        if "parameterization" not in ds.attrs:
            raise FormatError("not a brdftab table: no 'parameterization' attribute")
        try:
            self.grid: Grid = grid_from_dataset(ds)
        except (ParameterError, KeyError) as exc:
            raise FormatError(f"table grid cannot be reconstructed: {exc}") from None
        var = ds["brdf"]
        if var.dtype.kind not in "fiu":
            raise FormatError(f"table variable 'brdf' must be numeric, not {var.dtype}")
        chan_dim = "wavelength" if "wavelength" in var.dims else "channel"
        expected = self.grid.dims + (chan_dim,)
        if var.dims != expected:
            if set(var.dims) != set(expected):
                raise FormatError(f"table variable 'brdf' has dims {var.dims}, expected {expected}")
            var = var.transpose(*expected)
        _check_brdf_units(var)
        ds = _normalized(ds, chan_dim)
        if chan_dim not in ds.variables:
            raise FormatError(f"table has no '{chan_dim}' coordinate (nor a '{chan_dim}{LABEL_SUFFIX}' label variable)")
        self.ds = ds
        self._var = var
        self._values = None
        self._missing = False  # not computed yet (None: no missing samples)
        if chan_dim == "wavelength":
            lam = np.asarray(ds["wavelength"].values, float)
            if lam.ndim != 1 or not np.all(np.isfinite(lam)) or np.any(lam <= 0) or np.any(np.diff(lam) <= 0):
                raise FormatError("coordinate 'wavelength' must hold positive, strictly increasing wavelengths [nm]")
            self.layout = Layout(None, lam)
        else:
            self.layout = Layout(tuple(_label_text(c) for c in ds["channel"].values))
        self.name = str(ds.attrs.get("model", "table"))
        # Without the attribute only an isotropic parameterization implies isotropy.
        self.isotropic = _flag(ds.attrs.get("isotropic", int(ds.attrs["parameterization"] == "rusinkiewicz")))
        self.reciprocal = _flag(ds.attrs.get("reciprocal", 0))
        #: False when the file does not say whether its data is reciprocal ("unknown")
        self.reciprocity_declared = "reciprocal" in ds.attrs
        origin = ds.attrs.get("origin", "unknown")
        if origin not in ORIGINS:
            raise FormatError(f"attribute 'origin' = {origin!r}: expected one of {', '.join(map(repr, ORIGINS))}")
        self.origin = str(origin)
        self.outside = outside
        self._warned = False
        if getattr(self.grid, "scattered", False):
            self.grid.space_isotropic = self.isotropic
            #: queries, queries outside the samples' hull, farthest extrapolation distance (counted
            #: by every evaluation; :func:`brdftab.convert.convert` reports them)
            self.extrapolation = [0, 0, 0.0]
        self._specular = None
        #: Callables that release the file this table reads lazily (:meth:`close`).
        self.closers = []
        if SPECULAR_VAR in ds.data_vars:
            self._check_specular(ds, chan_dim)
        if "mueller" in ds.data_vars:
            from .mueller_table import check_mueller_variable

            check_mueller_variable(ds, self.grid.dims, chan_dim)

    @property
    def polarized(self) -> bool:
        """True when the table holds the Mueller matrix (variable ``mueller``, see
        :mod:`brdftab.mueller_table`); ``brdf`` is then its M00."""
        return "mueller" in self.ds.data_vars

    def eval_mueller(self, wi, wo, wavelengths=None, basis: str = "mitsuba") -> np.ndarray:
        """The Mueller matrix ``[..., n_channels, 4, 4]`` at ``(wi, wo)`` by interpolation (see
        :func:`brdftab.mueller_table.eval_mueller`); only for a polarized table."""
        from .mueller_table import eval_mueller

        return eval_mueller(self, wi, wo, wavelengths, basis)

    def close(self) -> None:
        """Release the file a table read lazily holds open (its samples are no longer readable
        unless they were loaded)."""
        for close in self.closers:
            close()
        self.ds.close()

    def _check_specular(self, ds, chan_dim):
        var = ds[SPECULAR_VAR]
        if var.dims != (SPECULAR_DIM, chan_dim):
            raise FormatError(f"table variable '{SPECULAR_VAR}' has dims {var.dims}, expected "
                              f"{(SPECULAR_DIM, chan_dim)}")
        if SPECULAR_DIM not in ds.variables:
            raise FormatError(f"table has no '{SPECULAR_DIM}' coordinate for '{SPECULAR_VAR}'")
        coord = ds[SPECULAR_DIM]
        theta = np.asarray(coord.values, float)
        units = str(coord.attrs.get("units", "rad")).strip().lower()
        if units in ("degree", "degrees", "deg"):
            theta = np.radians(theta)
        elif units not in ("rad", "radian", "radians"):
            raise FormatError(f"coordinate '{SPECULAR_DIM}' has units {coord.attrs.get('units')!r}; expected 'rad' "
                              "or 'degree'")
        if (theta.ndim != 1 or theta.size == 0 or not np.all(np.isfinite(theta)) or np.any(np.diff(theta) <= 0)
                or theta[0] < -1e-12 or theta[-1] > np.pi / 2 + 1e-9):
            raise FormatError(f"coordinate '{SPECULAR_DIM}' must hold strictly increasing angles in [0, 90] degrees")
        self._specular_theta = theta
        self._specular_scale = _fraction_scale(var, SPECULAR_VAR)

    @property
    def specular_reflectance(self):
        """``(θi [rad], ρ_s[θi, C])`` of the stored ideal specular reflectance, or None."""
        if SPECULAR_VAR not in self.ds.data_vars:
            return None
        if self._specular is None:
            vals = self._read(self.ds[SPECULAR_VAR]).astype(float) * self._specular_scale
            if not np.all(np.isfinite(vals)) or np.any(vals < 0):
                src = self.ds.encoding.get("source", "the table file")
                raise FormatError(f"{src}: '{SPECULAR_VAR}' must hold finite reflectances >= 0")
            self._specular = vals
        return self._specular_theta, self._specular

    @property
    def specular_delta(self):
        """ρ_s(wi, wavelengths) → [..., C] when the table carries an ideal specular reflectance
        (:data:`SPECULAR_VAR`), else None: linear in θi between the stored angles, 0 at and
        below the horizon."""
        return self._specular_delta if SPECULAR_VAR in self.ds.data_vars else None

    def _specular_delta(self, wi, wavelengths=None):
        lam = self.layout.resolve(wavelengths)
        n = self.layout.n_out(lam)
        theta, vals = self.specular_reflectance
        wi = np.asarray(wi, float)
        lead = wi.shape[:-1]
        w = wi.reshape(-1, 3)
        with np.errstate(invalid="ignore", divide="ignore"):
            cz = w[:, 2] / np.linalg.norm(w, axis=-1)
        ti = np.arccos(np.clip(cz, -1.0, 1.0))
        out = np.stack([np.interp(ti, theta, vals[:, c]) for c in range(vals.shape[1])], axis=-1)
        out[~(cz > 1e-12)] = 0.0
        out[~np.isfinite(cz)] = np.nan
        if lam is not None and self.spectral:
            stored = self.layout.wavelengths
            if not (stored.shape == lam.shape and np.array_equal(stored, lam)):
                out = _interp_last(out, stored, lam)
        elif out.shape[1] != n:
            out = np.repeat(out, n, axis=1)
        return out.reshape(lead + (n,))

    @property
    def outside(self) -> str:
        return self._outside

    @outside.setter
    def outside(self, mode: str):
        if mode not in OUTSIDE_MODES:
            raise ParameterError("outside", f"expected one of {', '.join(map(repr, OUTSIDE_MODES))}, got {mode!r}")
        self._outside = mode

    @property
    def nbytes(self) -> int:
        """Bytes of the stored samples (whether or not they are loaded)."""
        return int(np.prod(self._var.shape, dtype=float) * self._var.dtype.itemsize)

    @property
    def values(self) -> np.ndarray:
        """The stored samples, shape ``grid.shape + (n_channels,)`` (loaded on first use)."""
        if self._values is None:
            check_memory(self.nbytes, f"the table {self.describe()}", peak=1.0)
            self._values = self._read(self._var)
        return self._values

    def _read(self, var) -> np.ndarray:
        """Samples from disk (in slabs: Ctrl-C acts between them); a damaged file is a
        :class:`FormatError` naming it."""
        try:
            return read_array(var)
        except (RuntimeError, OSError, ValueError, KeyError) as exc:
            src = self.ds.encoding.get("source", "the table file")
            raise FormatError(f"{src}: damaged sample data ({' '.join(str(exc).split()) or type(exc).__name__})") \
                from None

    @property
    def missing(self) -> np.ndarray | None:
        """Bool mask of missing samples (shape of :attr:`values`), or None when there are none.

        A sample is missing when it lies below the ``valid_min`` or above the ``valid_max``
        attribute of the ``brdf`` variable (CF), e.g. MERL's negative "no data" markers, or
        equals one of its ``missing_value`` markers (a netCDF file's ``_FillValue`` too).
        """
        if self._missing is False:
            self._missing = _missing_mask(self.values, self._var.attrs)
        return self._missing

    def node_values(self, flat) -> np.ndarray:
        """The samples ``[M, C]`` (float64) of the nodes at flat indices ``flat`` into the grid,
        NaN where declared missing; read block by block when the table is not loaded."""
        flat = np.asarray(flat, np.intp)
        c = self.shape[-1]
        out = np.empty((flat.size, c))
        if self._values is not None:
            out[:] = self._values.reshape(-1, c)[flat]
            miss = self.missing
            if miss is not None:
                out[miss.reshape(-1, c)[flat]] = np.nan
            return out
        lead = flat // math.prod(self.shape[1:-1])  # index along the first axis
        for key, block in self.iter_blocks():
            a, b = key[0].start, key[0].stop
            if len(key) > 1:  # blocks within one node of the first axis: read the nodes alone
                break
            rows = np.flatnonzero((lead >= a) & (lead < b))
            if rows.size:
                v = block.reshape(-1, c)[flat[rows] - a * math.prod(self.shape[1:-1])]
                miss = _missing_mask(v, self._var.attrs)
                out[rows] = np.where(miss, np.nan, v) if miss is not None else v
        else:
            return out
        for r, node in enumerate(flat):
            v = self._read(self._var[np.unravel_index(int(node), self.shape[:-1])]).reshape(1, c)
            miss = _missing_mask(v, self._var.attrs)
            out[r] = np.where(miss, np.nan, v) if miss is not None else v
        return out

    @property
    def shape(self) -> tuple:
        """Shape of the stored samples: ``grid.shape + (n_channels,)``."""
        return tuple(self._var.shape)

    def iter_chunks(self, max_bytes: int = 64 << 20):
        """Yield the samples in slabs along the first axis without loading them all."""
        for _, chunk in self.iter_blocks(max_bytes):
            yield chunk

    def iter_blocks(self, max_bytes: int = 64 << 20, align=None):
        """Yield ``(key, samples[key])``: the samples in blocks of at most ``max_bytes`` (whole
        slabs of the first axis when they fit, see :func:`blocks`; ``align``: a chunk shape the
        blocks keep whole where they can), read from disk one at a time unless the table is
        loaded; ``key`` is a tuple of slices over the leading axes."""
        if self._values is not None:
            yield (), self._values
            return
        item = self._var.dtype.itemsize
        for key in blocks(self.shape, max(1, int(max_bytes // item)), align=align):
            if len(key) == 1 and key[0].step in (None, 1):
                yield key, self._rows(key[0].start or 0, key[0].stop)
            else:
                yield key, self._read(self._var[key])

    def _rows(self, a: int, b: int) -> np.ndarray:
        """The stored samples of rows ``a:b`` of the first axis. A table over the memory budget
        keeps the rows it has read from the start, as stored, in an uncompressed scratch file
        (:class:`RawRows`): the checks pass over such a table several times, and every later
        pass maps them from there instead of decoding the file again."""
        cache = self._raw_rows()
        if cache is not None and b <= cache.rows:
            return cache.read(a, b)
        block = self._read(self._var[a:b])
        if cache is not None and a == cache.rows:
            cache.append(block)
        return block

    def _raw_rows(self):
        cached = getattr(self, "_raw", None)
        if cached is None and self.over_budget:
            cached = self._raw = RawRows(self.shape, self._var.dtype)
            self.closers.append(cached.close)
        return cached

    #: The rule of :meth:`albedo_rule` covers the table's domain: the albedo integrals report
    #: its projected solid angle as their coverage (see :mod:`brdftab.integrate`).
    rule_coverage = "hemisphere"

    @property
    def albedo_rule(self):
        """A gonio table's own outgoing quadrature (a hint for :mod:`brdftab.integrate`), or
        None for other grids (the generic half-vector rule follows their lobes).

        A gonio table's lobes sit wherever its data put them (a pyramid's exit lobes, a tilted
        peak), so its albedo is integrated on its own cells — every (θo, φo) cell (or (Δθo, Δφo)
        cell of a grid relative to the mirror direction), weight dθ dφ sinθ: two Gauss–Legendre
        nodes across each cell in θ, where the interpolant (linear in θ within a cell) meets the
        weight sinθ cosθo, and the centre in φ (linear, constant weight). A GGX α = 0.1 gonio
        table of 10° steps integrates to a fine quadrature of the same interpolant within 0.1 %
        (tested). The rule covers the table's domain (its coverage is that domain's projected
        solid angle): an axis whose domain is wider than its nodes (cell-centred nodes, an MDL
        ``.mbsdf`` table) adds the cells between the domain's edges and the end nodes, where the
        table holds its end values, and a bilateral grid (φo − φi folded into [0, π]) counts its
        half circle twice."""
        if getattr(self.grid, "parameterization", "") != "spherical":
            # a grid whose table is constant over cells states its exact rule (Klems, tensor tree)
            return getattr(self.grid, "outgoing_rule", None)
        return self._gonio_rule

    def _gonio_rule(self, wi, wavelengths=None):
        from .geometry import sph_to_vec, vec_to_sph

        grid = self.grid
        wi = np.asarray(wi, float).reshape(3)
        ti, pi_ = (float(x) for x in vec_to_sph(wi))
        a_to, a_po = grid.axes[2], grid.axes[3]

        def cells(ax, nodes):
            v = np.asarray(ax.values, float)
            if ax.period is not None and v.size > 1:
                v = np.append(v, v[0] + ax.period)
            elif ax.period is None:  # a domain wider than the nodes (cell-centred nodes): its edges too
                lo, hi = ax.domain
                v = np.concatenate([[lo] if lo < v[0] - 1e-9 else [], v, [hi] if hi > v[-1] + 1e-9 else []])
            if v.size < 2:
                return np.array([]), np.array([]), v
            x, w = gauss_legendre(nodes, 0.0, 1.0)
            return (v[:-1, None] + np.diff(v)[:, None] * x).ravel(), (np.diff(v)[:, None] * w).ravel(), v

        # 2 Gauss–Legendre nodes per cell in θ (f, linear there, meets sinθ cosθ), the centre
        # in φ (f linear, the weight constant)
        t_mid, dt, t_edges = cells(a_to, 2)
        p_mid, dp, _ = cells(a_po, 1)
        if grid.relative_to != "specular" and t_mid.size:
            # each θ cell's weights scaled to its exact projected solid angle ½(sin²b − sin²a):
            # a constant f integrates exactly, and a rule over the whole hemisphere covers π
            approx = (dt * np.sin(t_mid) * np.cos(t_mid)).reshape(-1, 2).sum(axis=1)
            exact = 0.5 * (np.sin(t_edges[1:]) ** 2 - np.sin(t_edges[:-1]) ** 2)
            dt = dt * np.repeat(np.where(approx > 0, exact / np.where(approx > 0, approx, 1.0), 1.0), 2)
        if t_mid.size == 0 or p_mid.size == 0:
            return np.zeros((0, 3)), np.zeros(0)
        T, P = np.meshgrid(t_mid, p_mid, indexing="ij")
        W = dt[:, None] * dp[None, :]
        bilateral = getattr(grid, "phi_d_fold", "none") == "bilateral"
        if bilateral:
            W = 2.0 * W  # the mirror half circle: f(φi − Δφ) = f(φi + Δφ) by the fold
        if grid.relative_to == "specular":
            T = ti + T
            P = pi_ + np.pi + P
        elif self.isotropic or bilateral:
            ax = grid.axes[1]
            off = ax.outside(np.array([pi_]))[0] if len(ax) > 1 else True
            if off:  # the table answers this φi by rotation onto its first φi node
                P = P + (pi_ - ax.values[0])
        keep = (T > 0) & (T < np.pi / 2)
        T, P, W = T[keep], P[keep], W[keep]
        return sph_to_vec(T, P), W * np.sin(T)

    def statistics(self) -> dict:
        """Sample counts and range, streamed in slabs (a table need not fit in memory).

        ``missing`` counts declared missing samples (see :attr:`missing`), which are left out
        of ``min``/``max``/``negative``/``nonfinite``.
        """
        total = nonfinite = negative = missing = 0
        lo, hi = np.inf, -np.inf
        for chunk in self.iter_chunks():
            total += chunk.size
            miss = _missing_mask(chunk, self._var.attrs)
            data = chunk[~miss] if miss is not None else chunk.ravel()
            missing += 0 if miss is None else int(miss.sum())
            fin = np.isfinite(data)
            nonfinite += int(data.size - fin.sum())
            good = data[fin]
            negative += int((good < 0).sum())
            if good.size:
                lo, hi = min(lo, float(good.min())), max(hi, float(good.max()))
        return {"dtype": str(self._var.dtype), "samples": int(total), "min": lo if np.isfinite(lo) else None,
                "max": hi if np.isfinite(hi) else None, "nonfinite": nonfinite, "negative": negative,
                "missing": missing}

    @property
    def parameters(self) -> dict:
        try:
            return json.loads(self.ds.attrs.get("parameters", "{}"))
        except json.JSONDecodeError:
            return {}

    def describe(self) -> str:
        return f"table of {self.name} on {self.grid.describe()}"

    def _out_of_core(self) -> "OutOfCore":
        cached = getattr(self, "_ooc", None)
        if cached is None:
            cached = self._ooc = OutOfCore(self, memory_budget())
            self.closers.append(cached.close)
        return cached

    def _interp_data(self):
        """``(values, valid)`` used for interpolation (see :func:`_horizon_ghosts`); cached."""
        cached = getattr(self, "_interp", None)
        if cached is not None:
            return cached
        values = self.values
        above = self.grid.node_above_horizon()
        miss = self.missing
        if above.all():
            valid = None if miss is None else ~miss
        else:
            values, above = _horizon_ghosts(values, above, self.grid, miss)
            valid = np.broadcast_to(above[..., None], values.shape)
            if miss is not None:
                valid = valid & ~miss
        self._interp = (values, valid)
        return self._interp

    def _kernel_plan(self):
        """The compiled interpolation's view of this table (:class:`brdftab._interp_kernels.TablePlan`:
        values with horizon ghosts, valid mask, packed axes) and the nearest-data fill; cached."""
        cached = getattr(self, "_plan", None)
        if cached is None:
            from ._interp_kernels import TablePlan

            values, valid = self._interp_data()
            grid = self.grid
            fill = _nearest_fill(values, lambda: _data_nodes(grid, values, valid), grid.axes)
            cached = self._plan = (TablePlan(grid, values, valid, self.isotropic), fill)
        return cached

    @property
    def eval_batch(self) -> int | None:
        """Pairs an integration should evaluate per call (None: its own default): a table read
        from scratch disk (:meth:`_slab_mode`) passes over it once per call, so it takes as many
        pairs at once as a quarter of the memory budget holds (about 800 bytes per pair with the
        integration's and the interpolation's temporaries, measured)."""
        return max(1 << 16, memory_budget() // (4 * 800)) if self._slab_mode() else None

    @property
    def over_budget(self) -> bool:
        """True for a table on disk that working on in memory would take more than the memory
        budget (:func:`memory_budget`): loaded and checked whole, a table takes
        :data:`CHECKED_PEAK` times its samples in float64 (measured), the figure a tabulation
        run is streamed by too. Such a table is read block by block and evaluated window by
        window from scratch disk."""
        if self._values is not None:
            return False
        return float(self.grid.size) * self.shape[-1] * 8 * CHECKED_PEAK > memory_budget()

    def _slab_mode(self) -> bool:
        """A table over the memory budget (:attr:`over_budget`) is evaluated window by window
        from scratch disk (numpy, :class:`OutOfCore`), or from the few rows of its first axis
        the queries need."""
        return self.over_budget and self.grid.axes[0].period is None

    def eval(self, wi, wo, wavelengths=None, *, assume_unit: bool = False) -> np.ndarray:
        """f(wi, wo) by multilinear interpolation (see :meth:`BRDF.eval` and the module
        docstring), in one compiled pass per pair written into the result: the same
        normalization, NaN and horizon rules as every BRDF, then grid coordinates, weights over
        the valid nodes and the channels (numpy inside :func:`brdftab.brdf.numpy_reference`)."""
        if self._slab_mode() or not compiled_enabled() or not self.grid.compiled:
            return BRDF.eval(self, wi, wo, wavelengths, assume_unit=assume_unit)
        from .geometry import as_directions

        wi, wo = as_directions(wi, wo)
        lam = self.layout.resolve(wavelengths)
        n = self.layout.n_out(lam)
        lead = wi.shape[:-1]
        out = self._interpolate(wi.reshape(-1, 3), wo.reshape(-1, 3), not assume_unit)
        return self._channels(out, lam, n).reshape(lead + (n,))

    def _eval(self, wi, wo, lam, n):
        if not compiled_enabled() or not self.grid.compiled:
            return self._eval_numpy(wi, wo, lam, n)
        if self._slab_mode():
            ooc = self._windowed(wi, wo)
            if ooc is None:
                return self._eval_numpy(wi, wo, lam, n)
            return self._channels(self._interpolate(wi, wo, False, ooc), lam, n)
        return self._channels(self._interpolate(wi, wo, False), lam, n)

    def _windowed(self, wi, wo):
        """The scratch data (:class:`OutOfCore`) a table over the budget interpolates the pairs
        from by the compiled kernel, window by window; None where numpy does it: a few rows of
        the first axis read directly (no scratch made), or missing samples per channel."""
        ooc = getattr(self, "_ooc", None)
        if ooc is None:
            plan = OutOfCore.window_plan(self.grid, self.isotropic)
            cells = plan.cells(wi, wo, False)
            n = self.shape[0]
            lo = max(0, int(cells.min()) - SLAB_MARGIN) if cells.size else 0
            hi = min(n, int(cells.max()) + SLAB_MARGIN + 2) if cells.size else min(n, 1)
            per_row = self.grid.size // n * self.shape[-1] * (self._var.dtype.itemsize + 8 * 3)
            if (hi - lo) * per_row <= memory_budget() // 8:
                return None  # few rows: read them (the numpy path's choice, made on the same cells)
            ooc = self._out_of_core()
        return ooc if ooc.missing is None else None

    def _interpolate(self, wi, wo, check, ooc=None):
        """The compiled interpolation at ``(M, 3)`` pairs: ``(M, stored channels)``, NaN outside
        the domain (or raising, or clamped, as :attr:`outside` says); from the scratch data
        ``ooc`` (:class:`OutOfCore`) window by window when given."""
        m = wi.shape[0]
        flags = np.empty(m, np.uint8)
        if ooc is not None:
            out = np.empty((m, self.shape[-1]))
            n_out, n_fill, zero_i, zero_o = ooc.evaluate(wi, wo, check, self._outside, self.isotropic, out, flags)
        else:
            plan, fill = self._kernel_plan()
            out = np.empty((m, plan.n_channels))
            n_out, n_fill, zero_i, zero_o = plan.run(wi, wo, check, self._outside, out, flags)
        if zero_i or zero_o:
            raise ParameterError("wi" if zero_i else "wo", "a direction has zero length")
        if n_out and self._outside == "raise":
            raise BrdftabError(f"{n_out} direction pair(s) outside the domain of the {self.describe()}"
                               f" ({self.grid.domain_text()})")
        if n_fill:
            # cells whose corners all lie below the horizon: the nearest nodes holding data
            rows = np.flatnonzero(flags)
            a, b = wi[rows], wo[rows]
            if check:
                from .brdf import _unit

                a, b = _unit(np.array(a), "wi"), _unit(np.array(b), "wo")
            idx, _ = self.grid.locate(a, b, isotropic=self.isotropic)
            if ooc is not None:
                out[rows] = ooc.interpolate(idx)
            else:
                values, valid = self._interp_data()
                out[rows] = _multilinear(values, idx, self.grid.axes, valid, fill=fill)
        if n_out and self._outside == "nan" and not self._warned:
            self._warned = True
            warnings.warn(f"{n_out} direction pair(s) lie outside the domain of the "
                          f"{self.describe()} ({self.grid.domain_text()}); they evaluate to NaN",
                          BrdftabWarning, stacklevel=4)
        return out

    def _channels(self, out, lam, n):
        """Stored channels to the requested ones: wavelengths interpolated, a grey table broadcast."""
        if lam is not None and self.spectral:
            stored = self.layout.wavelengths
            if not (stored.shape == lam.shape and np.array_equal(stored, lam)):
                out = _interp_last(out, stored, lam)
        elif out.shape[1] != n:
            out = np.repeat(out, n, axis=1)  # a grey table broadcast to n outputs
        return out

    def _eval_numpy(self, wi, wo, lam, n):
        """The numpy interpolation (the reference the compiled path is tested against, and the
        path of a table evaluated slab by slab from disk)."""
        if getattr(self.grid, "scattered", False):
            return self._channels(self._eval_scattered(wi, wo), lam, n)
        idx, outside = self.grid.locate(wi, wo, isotropic=self.isotropic)
        if self._slab_mode():
            lo, hi = _slab_rows(self, idx[0])
            per_row = self.grid.size // self.shape[0] * self.shape[-1] * (self._var.dtype.itemsize + 8 * 3)
            if getattr(self, "_ooc", None) is None and (hi - lo) * per_row <= memory_budget() // 8:
                out = _slab_eval(self, wi, wo, lo, hi)  # few rows: read them, no scratch
            else:
                out = self._out_of_core().interpolate(idx)
        else:
            values, valid = self._interp_data()
            fill = _nearest_fill(values, lambda: _data_nodes(self.grid, values, valid), self.grid.axes)
            out = _multilinear(values, idx, self.grid.axes, valid, fill=fill)
        if outside.any() and self._outside != "clamp":
            if self._outside == "raise":
                raise BrdftabError(f"{int(outside.sum())} direction pair(s) outside the domain of the {self.describe()}"
                                   f" ({self.grid.domain_text()})")
            out[outside] = np.nan
            if not self._warned:
                self._warned = True
                warnings.warn(f"{int(outside.sum())} direction pair(s) lie outside the domain of the "
                              f"{self.describe()} ({self.grid.domain_text()}); they evaluate to NaN",
                              BrdftabWarning, stacklevel=4)
        return self._channels(out, lam, n)

    def _eval_scattered(self, wi, wo):
        """A scattered table's interpolation (:mod:`brdftab.grids.scattered`): linear on the
        samples' triangulation; outside its hull NaN (one warning), an error, or the nearest
        sample's value, as :attr:`outside` says, counted in :attr:`extrapolation`."""
        cached = getattr(self, "_scattered", None)
        if cached is None:
            values = np.array(self.values, dtype=float)
            miss = self.missing
            if miss is not None:
                values[miss] = np.nan
            cached = self._scattered = self.grid.interpolant(values, self.isotropic)
        out, outside, dist = cached(self.grid.query_space(wi, wo, self.isotropic))
        n_out = int(outside.sum())
        stats = self.extrapolation
        stats[0] += outside.size
        stats[1] += n_out
        if n_out:
            stats[2] = max(stats[2], float(dist.max()))
        if n_out and self._outside == "raise":
            raise BrdftabError(f"{n_out} direction pair(s) outside the domain of the {self.describe()}"
                               f" ({self.grid.domain_text()})")
        if n_out and self._outside == "nan":
            out[outside] = np.nan
        if n_out and not self._warned:
            self._warned = True
            what = ("they evaluate to NaN" if self._outside == "nan" else
                    f"each takes its nearest sample's value (up to {float(dist.max()):.3g} away in projected-"
                    "hemisphere coordinates)")
            warnings.warn(f"{n_out} of {outside.size} direction pair(s) lie outside the domain of the "
                          f"{self.describe()} ({self.grid.domain_text()}); {what}", BrdftabWarning, stacklevel=5)
        return out


#: Axes along which below-horizon nodes get ghost values, in order of preference: the axis
#: that crosses the horizon most directly in each parameterization.
GHOST_AXES = ("theta_d", "theta_o", "dtheta_o", "theta_i", "theta_h")


def _horizon_ghosts(values, above, grid, missing=None, axes=None, inplace=False, floor=0.0):
    """Values with *ghost* samples at below-horizon nodes next to the horizon, for interpolation.

    A below-horizon node stores 0 (f is 0 there by definition), which is not data: linear
    interpolation towards it would pull a table down within a cell of the horizon. Each
    below-horizon node whose two nearer neighbours along a ghost axis are valid gets the
    quadratic extrapolation of the three nearer valid nodes (linear where there are only two;
    clamped at 0), and counts as valid for interpolation. The axes are tried in turn (θd,
    then θh for Rusinkiewicz grids; θo, θi for gonio grids), each pass seeing the ghosts of
    the one before. The stored table is unchanged. Only the nodes next to the horizon are
    computed (about 1 % of a MERL grid). Returns ``(values, valid_nodes)``. ``axes``: the ghost
    axes to pass along (default :data:`GHOST_AXES`; a subset runs those passes alone).
    ``inplace``: write the ghosts into ``values`` instead of a copy. The ghosts take the dtype
    of float32 values (they are estimates: a float32 table's interpolation data stays half the
    size, in memory and on scratch disk, and the two agree exactly); other values are copied
    to float64. ``floor``: the
    lowest ghost value, per channel when an array (the Mueller elements of a polarized table
    other than M00 may be negative: ``-inf``).
    """
    vals = None  # copied on the first ghost
    ok = np.array(above, copy=True)
    bad = None if missing is None else missing.any(axis=-1)
    for name in GHOST_AXES if axes is None else axes:
        if name not in grid.dims:
            continue
        a = grid.dims.index(name)
        x = grid.axes[a].values
        n = x.size
        if n < 3:
            continue
        for step in (1, -1):  # ghosts above (θ increasing) and below the valid run
            node_ok = ok if bad is None else (ok & ~bad)
            prev1 = _shifted(node_ok, step, a)
            prev2 = _shifted(node_ok, 2 * step, a)
            cand = ~ok & prev1 & prev2
            where = np.nonzero(cand)
            if where[0].size == 0:
                continue
            if vals is None:
                vals = values if inplace else np.array(values, dtype=_interp_dtype(values.dtype), copy=True)
            g = where[a]
            j1, j2, j3 = g - step, g - 2 * step, g - 3 * step
            at = lambda j: where[:a] + (j,) + where[a + 1:]  # noqa: E731
            has3 = (j3 >= 0) & (j3 < n)
            j3c = np.clip(j3, 0, n - 1)
            has3 &= node_ok[at(j3c)]
            xg, x1, x2, x3 = x[g], x[j1], x[j2], x[j3c]
            v1, v2, v3 = vals[at(j1)], vals[at(j2)], vals[at(j3c)]
            lin = v1 + ((xg - x1) / (x1 - x2))[:, None] * (v1 - v2)
            with np.errstate(divide="ignore", invalid="ignore"):
                l1 = ((xg - x2) * (xg - x3) / ((x1 - x2) * (x1 - x3)))[:, None]
                l2 = ((xg - x1) * (xg - x3) / ((x2 - x1) * (x2 - x3)))[:, None]
                l3 = ((xg - x1) * (xg - x2) / ((x3 - x1) * (x3 - x2)))[:, None]
                quad = l1 * v1 + l2 * v2 + l3 * v3
            vals[where] = np.maximum(np.where(has3[:, None], quad, lin), floor)
            ok[where] = True
    return (values if vals is None else vals), ok


def _interp_dtype(dtype) -> np.dtype:
    """The dtype of a table's interpolation data (values with horizon ghosts): float32 for a
    float32 table, float64 otherwise."""
    return np.dtype(np.float32) if np.dtype(dtype) == np.float32 else np.dtype(np.float64)


def _shifted(mask, step, axis):
    """``out[i] = mask[i - step]`` along ``axis`` (False where ``i - step`` is off the axis)."""
    out = np.zeros_like(mask)
    n = mask.shape[axis]
    src = [slice(None)] * mask.ndim
    dst = [slice(None)] * mask.ndim
    if step > 0:
        src[axis], dst[axis] = slice(0, n - step), slice(step, n)
    else:
        src[axis], dst[axis] = slice(-step, n), slice(0, n + step)
    out[tuple(dst)] = mask[tuple(src)]
    return out


#: Offsets examined at most per shell when searching the nearest node holding data (bounds the
#: search radius: ~29 nodes on a 3-axis grid, ~10 on a 4-axis one).
NEAREST_SHELL_MAX = 1 << 18


def _nearest_fill(values, source, axes):
    """``fill(positions)`` for :func:`_multilinear`: the values ``[k, C]`` of the node nearest to
    each node at flat ``positions`` that holds data — ``source`` (bool, the grid's shape, or a
    callable giving it on first use): above the horizon and not missing. Nearest by Euclidean
    distance in index space (periodic axes wrapped), searched in growing cubes around the node;
    NaN where none lies within the search radius (see :data:`NEAREST_SHELL_MAX`)."""
    c = values.shape[-1]
    flat_vals = values.reshape(-1, c)
    shape = values.shape[:-1]
    state = {}

    def fill(pos):
        if "src" not in state:
            src = source() if callable(source) else source
            state["src"] = np.broadcast_to(np.asarray(src, bool), shape).reshape(-1)
        src = state["src"]
        uniq, inv = np.unique(np.asarray(pos, np.intp), return_inverse=True)
        best = np.where(src[uniq], uniq, -1)
        pending = np.flatnonzero(best < 0)
        nodes = np.stack(np.unravel_index(uniq, shape), axis=-1)
        movable = tuple(len(a) > 1 for a in axes)
        r = 0
        while pending.size:
            r += 1
            offs = _shell(r, movable)
            if offs is None:
                break
            step = max(1, (1 << 20) // len(offs))
            for s0 in range(0, pending.size, step):
                p = pending[s0:s0 + step]
                cand = nodes[p][:, None, :] + offs[None]
                inside = np.ones(cand.shape[:2], bool)
                for a, ax in enumerate(axes):
                    if ax.period is not None:
                        cand[..., a] %= shape[a]
                    else:
                        inside &= (cand[..., a] >= 0) & (cand[..., a] < shape[a])
                        np.clip(cand[..., a], 0, shape[a] - 1, out=cand[..., a])
                flat = np.ravel_multi_index(tuple(np.moveaxis(cand, -1, 0)), shape)
                ok = inside & src[flat]
                hit = np.flatnonzero(ok.any(axis=1))
                best[p[hit]] = flat[hit, np.argmax(ok[hit], axis=1)]  # offsets sorted by distance
            pending = pending[best[pending] < 0]
        out = np.full((uniq.size, c), np.nan)
        got = best >= 0
        out[got] = flat_vals[best[got]]
        return out[inv]

    return fill


def _shell(r, movable):
    """Index offsets ``[s, ndim]`` at max-norm distance ``r`` along the ``movable`` axes, nearest
    (Euclidean) first; None when there are more than :data:`NEAREST_SHELL_MAX` of them."""
    key = (r, movable)
    if key in _SHELLS:
        return _SHELLS[key]
    k = sum(movable)
    if k == 0 or (2 * r + 1) ** k > NEAREST_SHELL_MAX:
        return None
    grid = np.indices((2 * r + 1,) * k).reshape(k, -1).T - r
    grid = grid[np.abs(grid).max(axis=1) == r]
    grid = grid[np.argsort((grid ** 2).sum(axis=1), kind="stable")]
    out = np.zeros((grid.shape[0], len(movable)), np.intp)
    out[:, np.flatnonzero(movable)] = grid
    _SHELLS[key] = out
    return out


_SHELLS: dict = {}


#: Nodes of margin on each side of a window of the first axis when the interpolation data of a
#: table too large to load are built (the horizon ghosts look three nodes back).
SLAB_MARGIN = 4
#: Rows of the first axis on each side of an evaluation window read with it (the cells of its
#: queries and the nearest data nodes of cells without any).
WINDOW_MARGIN = 1


def scratch_dir() -> str | None:
    """Folder of scratch files (``BRDFTAB_SCRATCH``, else the system's temporary folder)."""
    return os.environ.get("BRDFTAB_SCRATCH") or None


def _map_rows(f, lo, hi, shape, dtype, writable=False) -> np.ndarray:
    """Rows ``lo:hi`` (each of ``shape``, ``dtype``) of the scratch file ``f`` as an array mapped
    from it, not copied (read-only, or copy-on-write when ``writable``): the pages leave the
    process's memory when the array is dropped (unmapped)."""
    import mmap

    dtype = np.dtype(dtype)
    row = math.prod(shape) * dtype.itemsize
    start, stop = lo * row, hi * row
    if stop <= start:
        return np.empty((max(0, hi - lo),) + tuple(shape), dtype)
    base = start - start % mmap.ALLOCATIONGRANULARITY
    mapped = mmap.mmap(f.fileno(), stop - base, access=mmap.ACCESS_COPY if writable else mmap.ACCESS_READ,
                       offset=base)
    return np.frombuffer(mapped, dtype, count=(hi - lo) * math.prod(shape),
                         offset=start - base).reshape((hi - lo,) + tuple(shape))


class RawRows:
    """Rows of a table's first axis as stored (its dtype, uncompressed), appended in order to an
    anonymous scratch file (deleted when closed or when the process ends) and read back
    mapped, copy-on-write: rows ``0:rows`` are held."""

    def __init__(self, shape, dtype):
        import tempfile

        self.row_shape = tuple(shape[1:])
        self.dtype = np.dtype(dtype)
        self.row_bytes = math.prod(self.row_shape) * self.dtype.itemsize
        self.rows = 0
        self.file = tempfile.TemporaryFile(dir=scratch_dir())

    def append(self, block) -> None:
        block = np.ascontiguousarray(block, self.dtype)
        self.file.seek(self.rows * self.row_bytes)
        self.file.write(block.tobytes())
        self.file.flush()
        self.rows += block.shape[0]

    def read(self, a: int, b: int) -> np.ndarray:
        return _map_rows(self.file, a, b, self.row_shape, self.dtype, writable=True)

    def close(self) -> None:
        self.file.close()


class OutOfCore:
    """The interpolation data of a table too large for the memory budget, on scratch disk.

    Built once, window by window of the first axis, as the whole-table interpolation has them
    (:func:`_horizon_ghosts`): the values with their horizon ghosts (in the table's
    interpolation dtype, :func:`_interp_dtype`: float32 for a float32 table), the valid nodes
    and the declared missing samples, in anonymous temporary files (deleted when closed, or
    when the process ends however it ends). The ghosts along the other axes come from each
    window alone; those along the first axis (θh, θi: the last ghost axis) in a second sweep over
    the scratch, block by block of a row's nodes over all rows (they are independent per node).
    Evaluation sorts the queries by their cell along the first axis and interpolates them window
    by window, each window (plus :data:`WINDOW_MARGIN` rows) read back: one pass over the
    scratch per call, memory bounded by the budget. The result equals the whole-table
    interpolation except where a cell has no valid corner and its nearest data node lies beyond
    the window's margin (the nearest node within it is taken)."""

    def __init__(self, table, budget: int):
        import tempfile

        self.grid = grid = table.grid
        self.shape = table.shape
        self.n0 = n0 = self.shape[0]
        self.nodes = math.prod(self.shape[1:-1])  # nodes per row of the first axis
        self.row = self.nodes * self.shape[-1]     # samples per row
        folder = scratch_dir()
        self.dtype = dtype = _interp_dtype(table._var.dtype)
        self.values = tempfile.TemporaryFile(dir=folder)
        self.ok = tempfile.TemporaryFile(dir=folder)
        self.missing = None
        first = grid.dims[0]
        present = [a for a in GHOST_AXES if a in grid.dims]
        inner = tuple(a for a in present if a != first)
        try:
            # pass 1: read as stored, ghosts along the other axes (row by row independent)
            # per row: as stored, in the interpolation dtype, the missing mask; node masks and the
            # ghosts' indices
            per_row = self.row * (table._var.dtype.itemsize + dtype.itemsize + 1) + self.nodes * 48
            step = max(1, (budget // 2) // per_row)
            buf = np.empty(min(step, n0) * self.row, dtype)  # the rows, reused slab after slab
            for a in range(0, n0, step):
                b = min(n0, a + step)
                slab = table._rows(a, b)
                sub = grid.sliced(a, b)
                miss = _missing_mask(slab, table._var.attrs)
                above = sub.node_above_horizon()
                vals = buf[:slab.size].reshape(slab.shape)
                np.copyto(vals, slab, casting="unsafe")
                del slab
                vals, ok = _horizon_ghosts(vals, above, sub, miss, axes=inner, inplace=True)
                if miss is not None and self.missing is None:
                    self.missing = tempfile.TemporaryFile(dir=folder)
                    self.missing.write(np.zeros(a * self.row, np.bool_).tobytes())
                if self.missing is not None:
                    self.missing.write(np.zeros(vals.shape, np.bool_).tobytes() if miss is None
                                       else np.ascontiguousarray(miss).tobytes())
                self.values.write(memoryview(vals))  # C-contiguous: written without a copy
                self.ok.write(memoryview(np.ascontiguousarray(ok, np.bool_)))
            if first in present and present[-1] == first and n0 >= 3:
                self._first_axis_pass(first, budget)
            for f in (self.values, self.ok, self.missing):
                if f is not None:
                    f.flush()  # evaluation maps the files
        except BaseException:
            self.close()
            raise
        # a window: its rows of values and node masks, in half the budget
        self.window = max(1, (budget // 2) // (self.row * (dtype.itemsize + 2)) - 1 - 2 * WINDOW_MARGIN)

    def _first_axis_pass(self, first, budget) -> None:
        """Ghosts along the first axis: independent for every node of a row, so made over all
        rows for one range of the row's nodes at a time (a column block: every row's segment of
        it read from the scratch, ghosted in place and written back)."""
        from types import SimpleNamespace

        n0, nodes, c = self.n0, self.nodes, self.shape[-1]
        # per node of a column block: its values over the rows, the corner values and node masks
        # and indices the ghost pass makes
        size = self.dtype.itemsize
        per_node = n0 * (c * size * 3 + 48)
        cols = max(1, (budget // 2) // per_node)
        columns = SimpleNamespace(dims=(first, "node"), axes=(self.grid.axes[0], None))
        files = [(self.values, size * c, self.dtype, (c,)), (self.ok, 1, np.bool_, ())]
        if self.missing is not None:
            files.append((self.missing, c, np.bool_, (c,)))
        for c0 in range(0, nodes, cols):
            c1 = min(nodes, c0 + cols)
            parts = []
            for f, item, dtype, tail in files:
                out = np.empty((n0, c1 - c0) + tail, dtype)
                for r in range(n0):
                    f.seek((r * nodes + c0) * item)
                    f.readinto(memoryview(out[r].reshape(-1).view(np.uint8)))
                parts.append(out)
            vals, ok = parts[0], parts[1]
            if ok.all():
                continue
            before = ok.copy()
            _, ok = _horizon_ghosts(vals, ok, columns, parts[2] if len(parts) > 2 else None, axes=(first,),
                                    inplace=True)
            for r in np.flatnonzero((ok != before).any(axis=1)):  # rows that got ghosts
                self.values.seek((r * nodes + c0) * size * c)
                self.values.write(np.ascontiguousarray(vals[r]).tobytes())
                self.ok.seek(r * nodes + c0)
                self.ok.write(np.ascontiguousarray(ok[r]).tobytes())

    @staticmethod
    def _read(f, lo, hi, shape, dtype, item):
        """Rows ``lo:hi`` of a scratch file, mapped (:func:`_map_rows`): an evaluation window's
        interpolation touches only the pages its queries' corners are on. Copy-on-write rather
        than read-only, though nothing writes them: the compiled kernel then takes them as it
        takes a table in memory (numba compiles anew for read-only arrays, about 30 s)."""
        return _map_rows(f, lo, hi, shape, dtype, writable=True)

    def _rows(self, lo, hi):
        """(values, valid nodes) of rows ``lo:hi`` of the first axis."""
        return (self._read(self.values, lo, hi, self.shape[1:], self.dtype, self.dtype.itemsize),
                self._read(self.ok, lo, hi, self.shape[1:-1], np.bool_, 1))

    def _missing(self, lo, hi):
        return None if self.missing is None else self._read(self.missing, lo, hi, self.shape[1:], np.bool_, 1)

    @staticmethod
    def window_plan(grid, isotropic):
        """The compiled kernel's plan (:class:`brdftab._interp_kernels.WindowPlan`) of a grid."""
        from ._interp_kernels import WindowPlan

        return WindowPlan(grid, isotropic)

    def evaluate(self, wi, wo, check, mode, isotropic, out, flags):
        """The compiled interpolation (:func:`brdftab._interp_kernels.table_eval`) at ``(M, 3)``
        pairs into ``out[M, C]`` and ``flags[M]``, window by window of the first axis as
        :meth:`interpolate` goes (each pair in the window of its cell, the window's rows
        mapped); returns the kernel's counts summed (outside, to fill, zero wi, zero wo)."""
        plan = getattr(self, "_plan", None)
        if plan is None or plan[0] != isotropic:
            plan = self._plan = (isotropic, self.window_plan(self.grid, isotropic))
        plan = plan[1]
        total = np.zeros(4, np.int64)
        c = self.shape[-1]
        for sel, lo, hi in self._windows(plan.cells(wi, wo, check)):
            vals, ok = self._rows(lo, hi)
            part = np.empty((sel.size, c))
            part_flags = np.empty(sel.size, np.uint8)
            total += plan.run(wi[sel], wo[sel], check, mode, part, part_flags, vals.reshape(-1, c),
                              ok.reshape(-1, 1), lo)
            out[sel] = part
            flags[sel] = part_flags
        return tuple(int(x) for x in total)

    def _windows(self, cells):
        """``(queries, lo, hi)`` per window of the first axis holding queries: the indices of the
        queries whose cell (``cells``, its low node; −1: none) lies in the window, and the rows
        ``lo:hi`` read with it (its margin and the high nodes of its last cells)."""
        order = np.argsort(cells, kind="stable")
        sorted_cells = cells[order]
        for a in range(0, self.n0, self.window):
            b = min(self.n0, a + self.window)
            sel = order[np.searchsorted(sorted_cells, a):np.searchsorted(sorted_cells, b)]
            if sel.size:
                yield sel, max(0, a - WINDOW_MARGIN), min(self.n0, b + 1 + WINDOW_MARGIN)

    def interpolate(self, idx) -> np.ndarray:
        """Values ``[M, C]`` at fractional indices ``idx`` (one array per axis, as
        :meth:`Grid.locate` gives them), NaN where the first one is not finite."""
        m = idx[0].shape[0]
        out = np.full((m, self.shape[-1]), np.nan)
        cell = np.full(m, -1, np.intp)
        finite = np.isfinite(idx[0])
        cell[finite] = np.clip(np.floor(idx[0][finite]), 0, self.n0 - 1).astype(np.intp)
        for sel, lo, hi in self._windows(cell):
            vals, ok = self._rows(lo, hi)
            valid = np.broadcast_to(ok[..., None], vals.shape)
            miss = self._missing(lo, hi)
            if miss is not None:
                valid = valid & ~miss
            sub = self.grid.sliced(lo, hi)
            local = [idx[0][sel] - lo] + [x[sel] for x in idx[1:]]
            out[sel] = _multilinear(vals, local, sub.axes, None if valid.all() else valid,
                                    fill=_nearest_fill(vals, lambda: _data_nodes(sub, vals, valid), sub.axes))
        return out

    def close(self) -> None:
        for f in (self.values, self.ok, self.missing):
            if f is not None:
                f.close()


def _slab_rows(table, i0):
    """``(lo, hi)``: the rows of the first axis the queries at first-axis indices ``i0`` need,
    with the margin their horizon ghosts need."""
    n = len(table.grid.axes[0])
    finite = np.isfinite(i0)
    lo = int(max(0, np.floor(i0[finite].min()) - SLAB_MARGIN)) if finite.any() else 0
    hi = int(min(n, np.ceil(i0[finite].max()) + SLAB_MARGIN + 1)) if finite.any() else min(n, 1)
    return lo, hi


def _slab_eval(table, wi, wo, lo, hi):
    """Evaluate a table that is not loaded from the slab ``lo:hi`` of its first axis
    (:func:`_slab_rows`), read from disk: queries that need few rows of a huge table."""
    slab = table._rows(lo, hi)
    grid = table.grid.sliced(lo, hi)
    miss = _missing_mask(slab, table._var.attrs)
    above = grid.node_above_horizon()
    values, ok = _horizon_ghosts(slab, above, grid, miss) if not above.all() else (slab, above)
    valid = np.broadcast_to(ok[..., None], values.shape)
    if miss is not None:
        valid = valid & ~miss
    idx, _ = grid.locate(wi, wo, isotropic=table.isotropic)
    return _multilinear(values, idx, grid.axes, None if valid.all() else valid,
                        fill=_nearest_fill(values, lambda: _data_nodes(grid, values, valid), grid.axes))


def _data_nodes(grid, values, valid):
    """Nodes that can stand in for a cell without valid corners (bool, grid shape): valid in every
    channel — above the horizon, or a horizon ghost that is not 0 (a ghost clamped to 0 is no
    estimate) — and not missing."""
    ok = np.asarray(valid, bool).all(axis=-1)
    return ok & (grid.node_above_horizon() | (values > 0).all(axis=-1))


def _missing_mask(values, attrs):
    """Missing samples: outside the CF ``valid_min``/``valid_max``/``valid_range``, equal to one of
    the CF ``missing_value`` markers (NaN among them: NaN samples), or equal to
    ``unwritten_value`` (netCDF's fill value in parts of a file that were never written)."""
    lo = attrs.get("valid_min")
    hi = attrs.get("valid_max")
    vr = attrs.get("valid_range")
    if vr is not None and np.size(vr) == 2:
        lo, hi = np.asarray(vr, float).ravel()
    mask = None
    with np.errstate(invalid="ignore"):
        unwritten = attrs.get("unwritten_value")
        if unwritten is not None:
            mask = values == np.asarray(unwritten, values.dtype).ravel()[0]
        markers = attrs.get("missing_value")  # CF missing markers (a netCDF's _FillValue too)
        if markers is not None:
            markers = np.asarray(markers, values.dtype).ravel()
            m = np.isin(values, markers[~np.isnan(markers)])
            if np.isnan(markers).any():
                m |= np.isnan(values)
            mask = m if mask is None else (mask | m)
        if lo is not None:
            m = values < float(np.asarray(lo).ravel()[0])
            mask = m if mask is None else (mask | m)
        if hi is not None:
            m = values > float(np.asarray(hi).ravel()[0])
            mask = m if mask is None else (mask | m)
    if mask is None or not mask.any():
        return None
    return mask


def _flag(v) -> bool:
    if isinstance(v, str):
        return v.strip().lower() in ("1", "true", "yes")
    return bool(v)


# --------------------------------------------------------------------------------------------
# Metadata read from files: units, channel labels, the albedo curve

#: A table's ``brdf`` is f_r in sr⁻¹; these spellings of that unit are accepted.
PER_STERADIAN = ("sr-1", "sr^-1", "sr**-1", "1/sr", "/sr", "steradian-1", "steradian^-1", "1/steradian",
                 "persr", "persteradian")
#: Wavelength units and their factor to nanometres.
WAVELENGTH_UNITS = {
    **dict.fromkeys(("nm", "nanometer", "nanometers", "nanometre", "nanometres", "1e-9m", "1e-9 m"), 1.0),
    **dict.fromkeys(("um", "µm", "μm", "micrometer", "micrometers", "micrometre", "micrometres", "micron",
                     "microns", "1e-6m", "1e-6 m"), 1e3),
    **dict.fromkeys(("mm", "millimeter", "millimeters", "millimetre", "millimetres"), 1e6),
    **dict.fromkeys(("m", "meter", "meters", "metre", "metres"), 1e9),
    **dict.fromkeys(("angstrom", "angstroms", "å", "Å"), 0.1),
}
#: A string-valued dimension ``X`` (``channel``) is stored in netCDF as the CF label variable
#: ``X_name`` (an auxiliary coordinate over ``X``): CF coordinate variables are numeric.
LABEL_SUFFIX = "_name"
#: The albedo curve of the last validation (:func:`brdftab.checks.stamp`), stored as numbers:
#: ``albedo(albedo_theta_i, channel|wavelength)`` and ``albedo_white_sky(channel|wavelength)``.
ALBEDO_VAR = "albedo"
ALBEDO_DIM = "albedo_theta_i"
ALBEDO_WHITE_SKY = "albedo_white_sky"
#: Channel dimension of an albedo curve whose channels are not the table's.
ALBEDO_CHANNEL = "albedo_channel"
#: JSON text attributes that held the albedo curve in files written before it was a variable.
LEGACY_ALBEDO_ATTRS = ("albedo_theta_i_deg", "albedo_values", "albedo_white_sky", "albedo_channels")


def _unit_text(attrs) -> str | None:
    u = attrs.get("units")
    if u is None:
        return None
    if isinstance(u, bytes):
        u = u.decode("utf-8", "replace")
    return str(u.item() if hasattr(u, "item") else u)


def _check_brdf_units(var) -> None:
    """``brdf`` must say that it holds f_r in sr⁻¹: a missing or different unit (``1``,
    ``percent``: a reflectance factor or a reflectance) is refused, never read as f_r."""
    units = _unit_text(var.attrs)
    if units is None:
        raise FormatError("variable 'brdf' has no 'units' attribute; brdftab reads f_r in 'sr-1' (add units = "
                          "'sr-1' if the values are f_r)")
    if units.strip().lower().replace(" ", "") not in PER_STERADIAN:
        raise FormatError(f"variable 'brdf' has units = {units!r}; brdftab reads f_r in 'sr-1' only (a "
                          "dimensionless or percent value is a reflectance factor or a reflectance, not f_r)")


def _fraction_scale(var, name) -> float:
    """Factor to a fraction of a dimensionless variable (``1``, absent; ``percent``: 0.01)."""
    units = _unit_text(var.attrs)
    u = "1" if units is None else units.strip().lower()
    if u in ("1", "", "fraction"):
        return 1.0
    if u in ("percent", "%"):
        return 0.01
    raise FormatError(f"variable '{name}' has units = {units!r}; expected '1' (a fraction) or 'percent'")


def _label_text(c) -> str:
    if isinstance(c, (bytes, np.bytes_)):
        return bytes(c).decode("utf-8", "replace")
    return str(c)


def _normalized(ds, chan_dim: str):
    """``ds`` in the in-memory layout: string labels as the coordinate of their dimension
    (netCDF stores them as ``<dim>_name``), wavelengths in nm, the albedo curve as variables.
    Returns ``ds`` itself when nothing changes, else a shallow copy (the caller's is untouched)."""
    labels = [name for name, v in ds.variables.items() if name.endswith(LABEL_SUFFIX) and v.ndim == 1
              and v.dims[0] == name[:-len(LABEL_SUFFIX)] and v.dims[0] not in ds.variables and v.dtype.kind in "OSU"]
    lam = ds.variables.get("wavelength") if chan_dim == "wavelength" else None
    factor = None
    if lam is not None:
        units = _unit_text(lam.attrs)
        if units is None:
            raise FormatError("coordinate 'wavelength' has no 'units' attribute; expected 'nm' (or another length "
                              "unit such as 'um')")
        key = units.strip()
        factor = WAVELENGTH_UNITS.get(key, WAVELENGTH_UNITS.get(key.lower()))
        if factor is None:
            raise FormatError(f"coordinate 'wavelength' has units = {units!r}; expected 'nm' (or another length unit "
                              "such as 'um')")
    legacy = ALBEDO_VAR not in ds.variables and all(k in ds.attrs for k in LEGACY_ALBEDO_ATTRS[:2])
    if factor == 1.0:
        factor = None  # already nm
    if not labels and factor is None and not legacy:
        return ds
    ds = ds.copy(deep=False)
    for name in labels:
        dim = name[:-len(LABEL_SUFFIX)]
        v = ds.variables[name]
        text = np.array([_label_text(c) for c in np.asarray(v.values).ravel()], dtype=object)
        ds = ds.drop_vars(name).assign_coords({dim: xr.Variable((dim,), text, attrs=dict(v.attrs))})
    if factor is not None:
        v = ds.variables["wavelength"]
        nm = np.asarray(v.values, float) * factor
        ds = ds.assign_coords(wavelength=xr.Variable(("wavelength",), nm, attrs={**v.attrs, "units": "nm"}))
    if legacy:
        _legacy_albedo(ds)
    return ds


def _channel_labels(ds, chan_dim: str) -> list:
    if chan_dim == "wavelength":
        return [f"{float(x):g} nm" for x in np.asarray(ds["wavelength"].values, float)]
    return [_label_text(c) for c in ds["channel"].values]


def set_albedo_curve(ds, theta_i_deg, values, white_sky=None, labels=None) -> None:
    """Store an albedo curve in ``ds`` (in place) as numbers other tools can plot:
    ``albedo[albedo_theta_i, C]`` (``units = "1"``, the mean over φi) with the coordinate
    ``albedo_theta_i`` in rad, and ``albedo_white_sky[C]``. C is the table's channel (or
    wavelength) dimension when ``labels`` name its channels, else ``albedo_channel``."""
    chan_dim = "wavelength" if "wavelength" in ds["brdf"].dims else "channel"
    theta = np.radians(np.asarray(theta_i_deg, float).ravel())
    vals = np.asarray(values, float).reshape(theta.size, -1)
    for name in (ALBEDO_VAR, ALBEDO_WHITE_SKY, ALBEDO_DIM, ALBEDO_CHANNEL):
        if name in ds.variables:
            del ds[name]
    for key in LEGACY_ALBEDO_ATTRS:
        ds.attrs.pop(key, None)
    own = _channel_labels(ds, chan_dim)
    labels = own if labels is None else [str(x) for x in labels]
    dim = chan_dim
    if labels != own or vals.shape[1] != len(own):
        dim = ALBEDO_CHANNEL
        if len(labels) != vals.shape[1]:
            labels = [f"c{i}" for i in range(vals.shape[1])]
        ds.coords[dim] = xr.Variable((dim,), np.array(labels, dtype=object),
                                     attrs={"long_name": "channel of the albedo curve"})
    ds.coords[ALBEDO_DIM] = xr.Variable((ALBEDO_DIM,), theta, attrs={
        "units": "rad", "long_name": "incidence angle of the albedo curve"})
    ds[ALBEDO_VAR] = xr.Variable((ALBEDO_DIM, dim), vals, attrs={
        "units": "1", "long_name": "directional-hemispherical albedo a(theta_i) = integral of f_r cos(theta_o) "
        "over the hemisphere, mean over phi_i", "source": "brdftab validation (albedo check)"})
    if white_sky is not None:
        ws = np.asarray(white_sky, float).ravel()
        if ws.size == vals.shape[1]:
            ds[ALBEDO_WHITE_SKY] = xr.Variable((dim,), ws, attrs={
                "units": "1", "long_name": "white-sky (bihemispherical) albedo",
                "comment": "NaN when the albedo curve does not run from 0 to at least 80 degrees"})


def _legacy_albedo(ds) -> None:
    """Turn the JSON albedo attributes of older files into :func:`set_albedo_curve`'s variables
    (left as they are when they cannot be parsed: they are information, not data)."""
    try:
        got = {k: json.loads(str(ds.attrs[k])) for k in LEGACY_ALBEDO_ATTRS if k in ds.attrs}
        theta = np.asarray(got["albedo_theta_i_deg"], float).ravel()
        vals = np.asarray(got["albedo_values"], float)
        if theta.size == 0 or vals.size % theta.size:
            return
        set_albedo_curve(ds, theta, vals, got.get("albedo_white_sky"), got.get("albedo_channels"))
    except (ValueError, TypeError, KeyError):
        return


def _multilinear(values, idx, axes, valid=None, fill=None):
    """Interpolate ``values[grid..., C]`` at fractional indices ``idx`` (one array per axis).

    With ``valid`` (bool, shape of ``values``) only valid corners take part and their weights
    are renormalized; where no corner with weight is valid the result is NaN if any of them
    is missing data, else — every corner below the horizon — the same interpolation of the
    values ``fill(flat positions)`` gives for the corners (the nearest nodes holding data,
    :func:`_nearest_fill`), or the plain (stored, zero) interpolation without ``fill``.
    """
    m = idx[0].shape[0]
    c = values.shape[-1]
    flat = values.reshape(-1, c)
    vflat = None if valid is None else valid.reshape(-1, c)
    strides = np.cumprod((values.shape[:-1] + (1,))[::-1])[::-1][1:]
    lows, highs, fracs = [], [], []
    for ax, x in zip(axes, idx):
        n = len(ax)
        i0 = np.floor(x).astype(np.intp)
        f = x - i0
        if ax.period is not None:
            i0 %= n
            i1 = (i0 + 1) % n
        else:
            i0 = np.clip(i0, 0, n - 1)
            i1 = np.minimum(i0 + 1, n - 1)
        lows.append(i0)
        highs.append(i1)
        fracs.append(f)
    out = np.zeros((m, c))
    if vflat is not None:
        plain = np.zeros((m, c))
        den = np.zeros((m, c))
    for w, pos in _corners(lows, highs, fracs, strides, m):
        if not w.any():
            continue
        # a corner of weight 0 takes no part (its sample may be NaN), as in the compiled kernel
        part = (w != 0.0)[:, None]
        v = flat[pos]
        if vflat is None:
            out += w[:, None] * np.where(part, v, 0.0)
            continue
        ok = vflat[pos] & part
        wv = np.where(ok, w[:, None], 0.0)
        out += wv * np.where(ok, v, 0.0)
        den += wv
        plain += w[:, None] * np.where(part & (ok | (v >= 0)), v, 0.0)
    if vflat is None:
        return out
    with np.errstate(invalid="ignore", divide="ignore"):
        res = out / den
    none = den <= 0
    if none.any():
        # no valid corner: all below the horizon (stored zeros) or some missing (NaN)
        res = np.where(none, plain, res)
        # True where every weighted corner is a below-horizon node (stored 0, not missing)
        horizon = np.ones((m, c), bool)
        for w, pos in _corners(lows, highs, fracs, strides, m):
            horizon &= (w[:, None] == 0) | (flat[pos] == 0)
        res[none & ~horizon] = np.nan
        rows = np.flatnonzero((none & horizon).any(axis=1))
        if fill is not None and rows.size:
            # a query above the horizon in a cell whose corners all lie below it: the stored
            # zeros are not data; each corner takes the value of its nearest node that is
            num = np.zeros((rows.size, c))
            wsum = np.zeros((rows.size, c))
            for w, pos in _corners([a[rows] for a in lows], [a[rows] for a in highs], [a[rows] for a in fracs],
                                   strides, rows.size):
                if not w.any():
                    continue
                v = fill(pos)
                got = np.isfinite(v)
                num += np.where(got, w[:, None] * np.where(got, v, 0.0), 0.0)
                wsum += np.where(got, w[:, None], 0.0)
            take = (none & horizon)[rows] & (wsum > 0)
            with np.errstate(invalid="ignore", divide="ignore"):
                res[rows] = np.where(take, num / wsum, res[rows])
    return res


def _corners(lows, highs, fracs, strides, m):
    """``(weight, flat position)`` of each corner of the cells holding ``m`` queries."""
    for corner in itertools.product((0, 1), repeat=len(lows)):
        w = np.ones(m)
        pos = np.zeros(m, dtype=np.intp)
        for a, bit in enumerate(corner):
            w *= fracs[a] if bit else (1.0 - fracs[a])
            pos += (highs[a] if bit else lows[a]) * strides[a]
        yield w, pos


def _interp_last(out, stored, lam):
    lo, hi = stored[0], stored[-1]
    if np.any(lam < lo - 1e-9) or np.any(lam > hi + 1e-9):
        raise ParameterError("wavelengths", f"outside the table's wavelengths [{lo:g}, {hi:g}] nm")
    if stored.size == 1:
        return np.repeat(out, lam.size, axis=1)
    j = np.clip(np.searchsorted(stored, lam, side="right") - 1, 0, stored.size - 2)
    t = (lam - stored[j]) / (stored[j + 1] - stored[j])
    return out[:, j] * (1 - t) + out[:, j + 1] * t


def tabulate(brdf: BRDF, grid: Grid, wavelengths=None, *, dtype="float64", chunk_size: int = DEFAULT_CHUNK,
             progress: bool | None = None, provenance: dict | None = None, polarized: bool = False) -> Table:
    """Sample ``brdf`` on ``grid`` (and ``wavelengths`` [nm] if spectral) into a :class:`Table`.

    ``polarized``: tabulate the Mueller matrix of a polarized model too (variable ``mueller``,
    :mod:`brdftab.mueller_table`); ``brdf`` then holds its M00.

    Works over the flattened grid in chunks of ``chunk_size`` samples, so memory beyond the
    output array stays bounded. ``progress``: True/False, or None for a bar on a terminal
    only; the bar appears once a tabulation has run for 2 s.

    >>> from brdftab import models, tabulate
    >>> from brdftab.grids import RusinkiewiczGrid
    >>> table = tabulate(models.create("lambert", albedo=0.5), RusinkiewiczGrid(8, 8, 16), progress=False)
    >>> table.values.shape, table.ds.attrs["phi_d_fold"], table.ds.attrs["origin"]
    ((8, 8, 16, 1), 'reciprocity', 'analytic')
    >>> bool(abs(table.values.max() * 3.141592653589793 - 0.5) < 1e-12)
    True
    """
    check_grid(brdf, grid)
    lam = brdf.layout.resolve(wavelengths)
    if lam is not None and np.any(np.diff(lam) <= 0):
        raise ParameterError("wavelengths", "a table's wavelengths must increase strictly")
    n = brdf.layout.n_out(lam)
    dtype = _checked_dtype(dtype)
    if polarized:
        from .mueller_table import mueller_at_nodes, require_polarized

        require_polarized(brdf)
        _check_polarized_grid(grid)
        _check_memory(grid, 17 * n, dtype)
        mueller = np.empty(grid.shape + (n, 4, 4), dtype=dtype)
        bar = _progress(grid.size, progress)
        try:
            mueller_at_nodes(brdf, grid, lam, mueller, chunk=max(1, chunk_size // 16), bar=bar)
        finally:
            if bar is not None:
                bar.close()
        values = np.ascontiguousarray(mueller[..., 0, 0])
        return make_table(values, grid, brdf.layout if lam is None else Layout(None, lam), brdf=brdf,
                          provenance=provenance, specular=_specular_samples(brdf, lam), mueller=mueller)
    _check_memory(grid, n, dtype)
    values = np.empty(grid.shape + (n,), dtype=dtype)
    bar = _progress(grid.size, progress)
    try:
        fill_values(brdf, grid, lam, values, chunk_size, bar)
    finally:
        if bar is not None:
            bar.close()
    return make_table(values, grid, brdf.layout if lam is None else Layout(None, lam), brdf=brdf,
                      provenance=provenance, specular=_specular_samples(brdf, lam))


def _check_polarized_grid(grid) -> None:
    """A polarized table needs a grid without a symmetry fold: a fold's symmetry acts on the
    Mueller matrix too (reciprocity transposes it, a mirror flips the signs of S2 and S3)."""
    fold = getattr(grid, "phi_d_fold", "none")
    if fold != "none":
        raise ParameterError("polarized", f"a polarized table needs a grid without a symmetry fold (phi_d_fold = "
                             f"'none'), not phi_d_fold = {fold!r}: the fold's symmetry acts on the Mueller matrix too")


def _checked_dtype(dtype):
    requested = dtype
    try:
        dtype = np.dtype(dtype)
    except (TypeError, ValueError):
        dtype = None
    if dtype is None or dtype.kind != "f" or dtype.itemsize not in (4, 8):
        shown = str(dtype) if dtype is not None else repr(requested)
        raise ParameterError("dtype", f"a table holds floating-point samples: expected 'float32' or 'float64', "
                             f"got {shown}")
    return dtype


def fill_values(brdf: BRDF, grid: Grid, lam, values, chunk_size: int = DEFAULT_CHUNK, bar=None) -> None:
    """Sample ``brdf`` at every node of ``grid`` into ``values[grid.shape + (n,)]`` (float64 or
    float32): the model's structured tabulation when it has one, else its compiled evaluation,
    else :meth:`BRDF.eval` in chunks of ``chunk_size`` nodes. Every node's value depends on that
    node alone, so a block of a grid (:meth:`Grid.block`) gets the same bits as the whole."""
    n = values.shape[-1]
    flat = values.reshape(-1, n)
    size = grid.size
    structured = brdf.tabulate_into(grid, lam, n, values, bar)
    run = None if structured else brdf.kernel(lam, n)
    if run is not None:
        _tabulate_compiled(run, grid, flat, chunk_size, bar)
    for start in range(0, 0 if (structured or run is not None) else size, chunk_size):
        stop = min(start + chunk_size, size)
        wi, wo = grid.directions(start, stop)
        flat[start:stop] = brdf.eval(wi, wo, lam, assume_unit=True)
        if bar is not None:
            bar.update(stop - start)


def _split(shape, max_items: int):
    """``(k, s)``: the first axis ``k`` whose trailing axes hold at most ``max_items`` elements
    (the last axis when none does) and the run ``s`` of its nodes that fits."""
    max_items = max(1, int(max_items))
    for k in range(len(shape)):
        tail = math.prod(shape[k + 1:])
        if tail <= max_items or k == len(shape) - 1:
            break
    return k, max(1, min(shape[k], max_items // max(1, tail)))


def chunk_shape(shape, max_items: int) -> tuple:
    """The storage chunk ``(1,)*k + (s,) + shape[k+1:]`` of at most ``max_items`` elements (one
    element of the last axis at least): the shape of :func:`blocks`' blocks, which follow the
    first axis, as every reader of a table too large to load does."""
    shape = tuple(int(x) for x in shape)
    k, step = _split(shape, max_items)
    return (1,) * k + (step,) + shape[k + 1:]


def blocks(shape, max_items: int, align=None):
    """Keys (tuples of slices over the leading axes) that cut an array of ``shape`` into blocks
    of at most ``max_items`` elements (at least one element of the last axes kept whole):
    whole slabs of the first axis when they fit, else single nodes of the leading axes and a
    run of the next. ``align`` (a chunk shape of the same rank) makes the runs whole chunks
    where it can, so each block writes whole storage chunks."""
    shape = tuple(int(x) for x in shape)
    k, step = _split(shape, max_items)
    if align is not None and len(align) == len(shape):
        c = int(align[k])
        if 0 < c < step:
            step -= step % c
    for lead in np.ndindex(*shape[:k]):
        head = tuple(slice(i, i + 1) for i in lead)
        for start in range(0, shape[k], step):
            yield head + (slice(start, min(start + step, shape[k])),)


def _tabulate_compiled(run, grid, flat, chunk_size, bar):
    """:func:`tabulate` through a compiled evaluation ``run`` (:meth:`BRDF.kernel`): each thread
    takes ``chunk_size`` nodes at a time, writes their directions (:meth:`Grid.directions_into`),
    sorts them (horizon) and evaluates into the table (float64) or a buffer (float32)."""
    from ._brdf_kernels import prepare
    from ._jit import parallel_rows, threads
    from .brdf import HORIZON

    n = flat.shape[1]
    step = chunk_size * threads()
    for start in range(0, flat.shape[0], step):
        stop = min(start + step, flat.shape[0])

        def work(lo, hi, start=start):
            lo, hi = start + lo, start + hi
            wi = np.empty((hi - lo, 3))
            wo = np.empty((hi - lo, 3))
            grid.directions_into(lo, hi, wi, wo)
            direct = flat.dtype == np.float64
            out = flat[lo:hi] if direct else np.empty((hi - lo, n))
            out[:] = 0.0
            state = np.empty(hi - lo, np.uint8)
            prepare(wi, wo, state, out, True, HORIZON)
            run(wi, wo, state, out, False)
            if not direct:
                flat[lo:hi] = out

        parallel_rows(work, stop - start)
        if bar is not None:
            bar.update(stop - start)


def carries_specular_delta(brdf) -> bool:
    """True when ``brdf`` has an ideal specular (delta) part: a callable ``specular_delta``."""
    return callable(getattr(brdf, "specular_delta", None))


def _specular_samples(brdf, lam):
    """``(θi, ρ_s[θi, C])`` of an isotropic BRDF's delta at :data:`SPECULAR_THETA_I`, or None.
    An anisotropic BRDF's delta depends on φi too: it is not stored (and said so)."""
    if not carries_specular_delta(brdf):
        return None
    if not brdf.isotropic:
        warn_specular_dropped(brdf, "a table (anisotropic deltas are not stored)")
        return None
    wi = np.stack([np.sin(SPECULAR_THETA_I), np.zeros_like(SPECULAR_THETA_I), np.cos(SPECULAR_THETA_I)], axis=-1)
    vals = np.asarray(brdf.specular_delta(wi, lam), float).reshape(SPECULAR_THETA_I.size, -1)
    return SPECULAR_THETA_I, vals


def warn_specular_dropped(brdf, where: str) -> None:
    """Say (one line, a :class:`BrdftabWarning`) that ``where`` (a format) cannot hold the ideal
    specular (delta) reflectance of ``brdf``, so only its finite part is written."""
    if not carries_specular_delta(brdf):
        return
    try:
        theta = SPECULAR_THETA_I[::40]
        wi = np.stack([np.sin(theta), np.zeros_like(theta), np.cos(theta)], axis=-1)
        lam = brdf.layout.resolve(None) if not brdf.spectral or brdf.wavelengths is not None else None
        top = float(np.nanmax(brdf.specular_delta(wi, lam))) if lam is not None or not brdf.spectral else None
    except BrdftabError:
        top = None
    size = f" (a reflectance of up to {top:.3g})" if top is not None else ""
    warnings.warn(f"{where} cannot hold the ideal specular (delta) part of '{brdf.name}'{size}: it is not stored, "
                  "only the finite BRDF f_r is written", BrdftabWarning, stacklevel=3)


def make_table(values, grid: Grid, layout: Layout, brdf: BRDF | None = None, provenance: dict | None = None,
               specular=None, mueller=None) -> Table:
    """Wrap sampled ``values[grid..., C]`` into a :class:`Table` with full metadata.

    ``specular = (theta_i [rad], rho[θi, C])`` adds the ideal specular reflectance variable;
    ``mueller[grid..., C, 4, 4]`` the Mueller matrix (:mod:`brdftab.mueller_table`; ``values``
    should be its M00)."""
    coords = {}
    for ax in grid.axes:
        coords[ax.name] = xr.Variable((ax.name,), ax.values, attrs=grid.coord_attrs(ax.name))
    aux = getattr(grid, "aux_coords", None)
    if aux is not None:  # per-node coordinates (a scattered table's angles)
        coords.update(aux())
    if layout.spectral:
        chan_dim = "wavelength"
        coords["wavelength"] = xr.Variable(("wavelength",), np.asarray(layout.wavelengths, float),
                                           attrs={"units": "nm", "long_name": "vacuum wavelength"})
    else:
        chan_dim = "channel"
        coords["channel"] = xr.Variable(("channel",), np.array(layout.channels, dtype=object),
                                        attrs={"long_name": "colour channel"})
    var = xr.Variable(grid.dims + (chan_dim,), values, attrs={
        "units": "sr-1",
        "long_name": "bidirectional reflectance distribution function",
        "quantity": "f_r = dL_o / dE_i (not multiplied by cos(theta_o), not a reflectance factor)",
    })
    created = _dt.datetime.now(_dt.timezone.utc).replace(microsecond=0).isoformat()
    attrs = {
        "Conventions": "CF-1.10",
        "title": f"BRDF table: {brdf.name if brdf else 'unknown'}",
        "source": f"brdftab {__version__}",
    }
    attrs.update(grid.attrs())
    attrs.update({
        "model": brdf.name if brdf is not None else "unknown",
        "parameters": json.dumps(brdf.parameters if brdf is not None else {}, sort_keys=True),
        "spec_sha256": "",
        "brdftab_version": __version__,
        "created": created,
        "isotropic": int(brdf.isotropic if brdf is not None else 0),
        "reciprocal": int(brdf.reciprocal if brdf is not None else 0),
        "origin": str(getattr(brdf, "origin", "analytic")) if brdf is not None else "unknown",
        "direction_convention": DIRECTION_CONVENTION,
        "phi_convention": PHI_CONVENTION,
        "history": f"{created} brdftab {__version__}: table of {brdf.name if brdf is not None else 'unknown'} on "
                   f"{grid.describe()}",
    })
    if provenance:
        attrs.update(provenance)
    data = {"brdf": var}
    if specular is not None:
        theta, rho = specular
        coords[SPECULAR_DIM] = xr.Variable((SPECULAR_DIM,), np.asarray(theta, float), attrs={
            "units": "rad", "long_name": "incidence angle of the ideal specular reflectance"})
        data[SPECULAR_VAR] = xr.Variable((SPECULAR_DIM, chan_dim), np.asarray(rho, float), attrs={
            "units": "1", "long_name": "ideal specular (delta) reflectance",
            "quantity": "fraction of the incident flux reflected into the mirror direction by the source's "
                        "delta component; not contained in brdf, add it to directional albedos",
            "interpolation": "linear in the incidence angle"})
    if mueller is not None:
        from .mueller_table import BASIS_ATTR, MITSUBA_BASIS, MUELLER_VAR, mueller_coords, mueller_variable

        coords.update(mueller_coords())
        data[MUELLER_VAR] = mueller_variable(mueller, grid, chan_dim)
        attrs["polarized"] = 1
        attrs[BASIS_ATTR] = MITSUBA_BASIS
    ds = xr.Dataset(data, coords=coords, attrs=attrs)
    return Table(ds)


#: Peak memory of a tabulation relative to its output table (float64 output 1.2x, float32
#: 1.66x, measured with tracemalloc), plus the chunk temporaries (~30 MiB at the default chunk
#: size); ``benchmarks/bench_check_memory.py`` checks the peak resident memory against both.
TABULATE_PEAK = {8: 1.25, 4: 1.7}
CHUNK_OVERHEAD = 64 << 20
#: Peak memory of tabulating a float64 table and then running the default checks on it, relative
#: to the table: measured (``benchmarks/bench_check_memory.py``, peak resident memory) 5.3x for
#: RGB on a Rusinkiewicz grid, 6.8x grey on a Rusinkiewicz grid, 8.8x grey on a spherical grid
#: (the reciprocity and bilateral checks pair every sample with its mirror image). ``tabulate``
#: runs refuse up front what the checks could not finish (:func:`check_checked_memory`).
CHECKED_PEAK = 9.0


#: Memory a run may use for its tables, its checks and their temporaries unless told otherwise
#: (``--memory`` on the command line, the ``BRDFTAB_MEMORY`` environment variable): a table
#: whose tabulation and checks would need more is streamed to its file block by block.
DEFAULT_MEMORY_BUDGET = 1 << 30
_SIZE_UNITS = {"": 1, "b": 1, "k": 1 << 10, "kb": 1000, "kib": 1 << 10, "m": 1 << 20, "mb": 1000 ** 2,
               "mib": 1 << 20, "g": 1 << 30, "gb": 1000 ** 3, "gib": 1 << 30, "t": 1 << 40, "tb": 1000 ** 4,
               "tib": 1 << 40}


def parse_size(text, what: str = "memory") -> int:
    """Bytes of a size written ``"1G"``, ``"512MiB"``, ``"2.5GB"`` or a plain number of bytes
    (``K``/``M``/``G``/``T`` alone are binary, ``KB``... decimal, ``KiB``... binary); at least
    1 MiB.

    >>> parse_size("1G"), parse_size("500MB"), parse_size("2097152")
    (1073741824, 500000000, 2097152)
    """
    import re

    m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+(?:[eE][+-]?[0-9]+)?)\s*([A-Za-z]*)\s*", str(text))
    unit = m.group(2).lower() if m else None
    if m is None or unit not in _SIZE_UNITS:
        raise ParameterError(what, f"expected a size such as 512M, 2G or 1.5GB, got {str(text)!r}")
    size = float(m.group(1)) * _SIZE_UNITS[unit]
    if not math.isfinite(size):
        raise ParameterError(what, f"{str(text)!r} is too large a size")
    if not (size >= 1 << 20):
        raise ParameterError(what, f"{str(text)!r} is less than 1 MiB; a run needs more than that")
    return int(size)


def memory_budget() -> int:
    """Bytes a run may use for its tables and checks: ``BRDFTAB_MEMORY`` when set (a size, see
    :func:`parse_size`), else :data:`DEFAULT_MEMORY_BUDGET`."""
    text = os.environ.get("BRDFTAB_MEMORY", "").strip()
    return parse_size(text, "BRDFTAB_MEMORY") if text else DEFAULT_MEMORY_BUDGET


def available_memory() -> int | None:
    """Bytes of memory available to this process now (MemAvailable), or None if unknown."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_AVPHYS_PAGES")
    except (ValueError, OSError, AttributeError):  # pragma: no cover - non-POSIX
        return None


def check_memory(nbytes: float, what: str, peak: float = 1.25) -> None:
    """Refuse work whose measured peak (``peak`` × ``nbytes`` + chunk temporaries) exceeds the
    memory available now; the message says how much is needed and what to do."""
    have = available_memory()
    need = float(nbytes) * peak + CHUNK_OVERHEAD
    if have is not None and need > have:
        raise BrdftabError(f"{what} needs about {need / 2**30:.3g} GiB of memory ({nbytes / 2**30:.3g} GiB of samples);"
                           f" only {have / 2**30:.3g} GiB is available; use a coarser grid or fewer channels")


def check_checked_memory(tables, what: str) -> None:
    """Refuse, before any tabulation, a run that tabulates float64 tables of ``tables``
    ``(grid, n channels)`` pairs, keeps them all, and checks each: the tables together plus
    the checks' peak on the largest (:data:`CHECKED_PEAK`) must fit the memory available now."""
    sizes = [float(grid.size) * n * 8 for grid, n in tables]
    if not sizes:
        return
    total = sum(sizes) + max(sizes) * (CHECKED_PEAK - 1.0)
    check_memory(sum(sizes), what, peak=total / sum(sizes))


def _check_memory(grid: Grid, n: int, dtype) -> None:
    """Refuse a tabulation whose measured peak exceeds the available memory, before allocating."""
    item = np.dtype(dtype).itemsize
    check_memory(float(grid.size) * n * item, f"tabulating {grid.describe()} x {n} channels as {np.dtype(dtype)}",
                 peak=TABULATE_PEAK.get(item, 1.7))


def _progress(total: int, progress: bool | None):
    if progress is False:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, unit="sample", unit_scale=True, desc="tabulating", delay=PROGRESS_DELAY,
                disable=None if progress is None else False, leave=False)
