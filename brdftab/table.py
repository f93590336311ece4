"""Tables: a BRDF sampled on a grid, held as a self-describing ``xarray.Dataset``.

Layout of the dataset (also the netCDF layout, see ``formats/netcdf.md``):

* variable ``brdf`` (units ``sr-1``) with dims ``grid.dims + ("channel",)`` or
  ``grid.dims + ("wavelength",)``;
* one coordinate per grid axis, in radians (``units = "rad"``); ``channel`` (names) or
  ``wavelength`` (``units = "nm"``);
* attributes: ``parameterization``, ``grid``, ``sample_position``, ``phi_d_fold``
  (+ ``theta_h_spacing`` / ``relative_to``), ``model``, ``parameters`` (JSON, angles in
  radians), ``spec_sha256``, ``brdftab_version``, ``created``, ``isotropic``,
  ``reciprocal`` and the direction/φ conventions in words.

A :class:`Table` is a :class:`~brdftab.brdf.BRDF`: it evaluates at any (wi, wo) by
multilinear interpolation in its grid's index space — linear in the warped coordinate of
warped axes (MERL θh), periodic across the seam of periodic axes (φd, φh), clamped at the
ends of the others, after folding φd by the table's declared fold. At its own nodes it
returns the stored values exactly.
"""

from __future__ import annotations

import datetime as _dt
import itertools
import json
import os

import numpy as np
import xarray as xr

from ._version import __version__
from .brdf import BRDF
from .channels import Layout
from .errors import BrdftabError, FormatError, ParameterError
from .grids import Grid, check_grid, grid_from_dataset

__all__ = ["Table", "tabulate", "DEFAULT_CHUNK", "DIRECTION_CONVENTION", "PHI_CONVENTION"]

#: Samples evaluated per chunk; bounds the temporaries of a tabulation (~tens of MB).
DEFAULT_CHUNK = 1 << 16
#: Seconds a tabulation runs before its progress bar appears.
PROGRESS_DELAY = 2.0

DIRECTION_CONVENTION = ("wi and wo are unit vectors pointing away from the surface in a local frame with the "
                        "normal along +z; theta is the polar angle from +z, phi the azimuth from +x towards +y")
PHI_CONVENTION = ("Rusinkiewicz: h = normalize(wi + wo), d = Ry(-theta_h) Rz(-phi_h) wi (MERL BRDFRead.cpp); "
                  "phi_h := 0 where theta_h = 0; spherical: azimuths of the away-pointing vectors, the mirror "
                  "direction of (theta_i, phi_i) is (theta_i, phi_i + pi)")


class Table(BRDF):
    """A tabulated BRDF backed by an ``xarray.Dataset`` (see the module docstring)."""

    def __init__(self, ds: xr.Dataset):
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
        self.ds = ds
        self._values = np.asarray(var.values)
        if chan_dim == "wavelength":
            self.layout = Layout(None, np.asarray(ds["wavelength"].values, float))
        else:
            self.layout = Layout(tuple(str(c) for c in ds["channel"].values))
        self.name = str(ds.attrs.get("model", "table"))
        # Without the attribute only an isotropic parameterization implies isotropy.
        self.isotropic = _flag(ds.attrs.get("isotropic", int(ds.attrs["parameterization"] == "rusinkiewicz")))
        self.reciprocal = _flag(ds.attrs.get("reciprocal", 0))

    @property
    def values(self) -> np.ndarray:
        """The stored samples, shape ``grid.shape + (n_channels,)``."""
        return self._values

    @property
    def parameters(self) -> dict:
        try:
            return json.loads(self.ds.attrs.get("parameters", "{}"))
        except json.JSONDecodeError:
            return {}

    def describe(self) -> str:
        return f"table of {self.name} on {self.grid.describe()}"

    def _eval(self, wi, wo, lam, n):
        idx = self.grid.fractional_index(wi, wo, isotropic=self.isotropic)
        out = _multilinear(self._values, idx, self.grid.axes)
        if lam is not None and self.spectral:
            stored = self.layout.wavelengths
            if not (stored.shape == lam.shape and np.array_equal(stored, lam)):
                out = _interp_last(out, stored, lam)
        elif out.shape[1] != n:
            out = np.repeat(out, n, axis=1)  # a grey table broadcast to n outputs
        return out


def _flag(v) -> bool:
    if isinstance(v, str):
        return v.strip().lower() in ("1", "true", "yes")
    return bool(v)


def _multilinear(values, idx, axes):
    """Interpolate ``values[grid..., C]`` at fractional indices ``idx`` (one array per axis)."""
    m = idx[0].shape[0]
    c = values.shape[-1]
    flat = values.reshape(-1, c)
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
    for corner in itertools.product((0, 1), repeat=len(axes)):
        w = np.ones(m)
        pos = np.zeros(m, dtype=np.intp)
        for a, bit in enumerate(corner):
            w *= fracs[a] if bit else (1.0 - fracs[a])
            pos += (highs[a] if bit else lows[a]) * strides[a]
        if not w.any():
            continue
        out += w[:, None] * flat[pos]
    return out


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
             progress: bool | None = None, provenance: dict | None = None) -> Table:
    """Sample ``brdf`` on ``grid`` (and ``wavelengths`` [nm] if spectral) into a :class:`Table`.

    Works over the flattened grid in chunks of ``chunk_size`` samples, so memory beyond the
    output array stays bounded. ``progress``: True/False, or None for a bar on a terminal
    only; the bar appears once a tabulation has run for 2 s.
    """
    check_grid(brdf, grid)
    lam = brdf.layout.resolve(wavelengths)
    if lam is not None and np.any(np.diff(lam) <= 0):
        raise ParameterError("wavelengths", "a table's wavelengths must increase strictly")
    n = brdf.layout.n_out(lam)
    dtype = np.dtype(dtype)
    _check_memory(grid, n, dtype)
    values = np.empty(grid.shape + (n,), dtype=dtype)
    flat = values.reshape(-1, n)
    size = grid.size
    bar = _progress(size, progress)
    try:
        for start in range(0, size, chunk_size):
            stop = min(start + chunk_size, size)
            wi, wo = grid.directions(start, stop)
            flat[start:stop] = brdf.eval(wi, wo, lam)
            if bar is not None:
                bar.update(stop - start)
    finally:
        if bar is not None:
            bar.close()
    return make_table(values, grid, brdf.layout if lam is None else Layout(None, lam), brdf=brdf,
                      provenance=provenance)


def make_table(values, grid: Grid, layout: Layout, brdf: BRDF | None = None, provenance: dict | None = None) -> Table:
    """Wrap sampled ``values[grid..., C]`` into a :class:`Table` with full metadata."""
    coords = {}
    for ax in grid.axes:
        coords[ax.name] = xr.Variable((ax.name,), ax.values, attrs=grid.coord_attrs(ax.name))
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
        "created": _dt.datetime.now(_dt.timezone.utc).replace(microsecond=0).isoformat(),
        "isotropic": int(brdf.isotropic if brdf is not None else 0),
        "reciprocal": int(brdf.reciprocal if brdf is not None else 0),
        "direction_convention": DIRECTION_CONVENTION,
        "phi_convention": PHI_CONVENTION,
    })
    if provenance:
        attrs.update(provenance)
    ds = xr.Dataset({"brdf": var}, coords=coords, attrs=attrs)
    return Table(ds)


def _check_memory(grid: Grid, n: int, dtype) -> None:
    """Refuse a table larger than this machine's memory before allocating it."""
    need = float(grid.size) * n * np.dtype(dtype).itemsize
    try:
        have = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):  # pragma: no cover - non-POSIX
        return
    if need > 0.8 * have:
        raise BrdftabError(f"the table would need {need / 2**30:.3g} GiB ({grid.describe()} x {n} channels x "
                           f"{np.dtype(dtype).itemsize} bytes), more than this machine's {have / 2**30:.3g} GiB "
                           "of memory allows; use a coarser grid")


def _progress(total: int, progress: bool | None):
    if progress is False:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, unit="sample", unit_scale=True, desc="tabulating", delay=PROGRESS_DELAY,
                disable=None if progress is None else False, leave=False)
