"""MERL BRDF database files (``.binary``): read, and write any isotropic reciprocal RGB BRDF.

Layout (see ``formats/merl.md``): a 12-byte header of three little-endian int32
``(90, 90, 180)`` = (n_θh, n_θd, n_φd), then three planar blocks of 90·90·180 little-endian
float64, R then G then B, φd fastest and θh slowest; 34,992,012 bytes in all. Physical values
are ``f = raw · s`` with ``s = (1, 1.15, 1.66) / 1500``. Negative raw values mark bins without
a measurement.

Reading gives a table on :func:`~brdftab.grids.merl_grid` (``bin-centre``: the file does not
say where its samples sit, and the reference reader truncates into bins). Negative samples
are kept as they are (scaled) and declared *missing* with ``brdf:valid_min = 0``.

The scale factors are not exactly invertible in floating point: ``fl(fl(raw·s)/s)`` can
differ from ``raw`` by an ulp. The reader therefore also stores the integer
``merl_raw_ulp_correction`` (bit-pattern difference between ``raw`` and ``fl(f/s)``, zero
almost everywhere) with a SHA-256 of the values it produced; the writer adds it back only when
the table's values still hash to that checksum. MERL → netCDF (float64) → MERL is thereby
byte-identical, and a table whose values were changed is written as ``f/s``.

Writing copies the values of a table on the MERL grid and tabulates anything else at the
declared sample position (``sample_position``: ``bin-centre`` or ``lower-edge``). MERL is
isotropic and folds φd by reciprocity: an anisotropic or non-reciprocal source is refused
unless ``phi_h_average`` or ``symmetrize`` asks for its φh average or its reciprocal part.
"""

from __future__ import annotations

import hashlib
import struct
import warnings
from pathlib import Path

import numpy as np
import xarray as xr

from ..colorimetry import PARAMS as COLOUR_PARAMS
from ..channels import Layout
from ..params import Kind, Param, register_kind
from ..errors import BrdftabWarning, FormatError, ParameterError
from ..grids import merl_grid
from . import FileFormat, averaged, read_head, register

__all__ = ["read_merl", "write_merl", "merl_raw", "prepare_merl", "SCALE", "DIMS", "FILE_SIZE", "CORRECTION",
           "MISSING_RAW"]

#: Header (n_θh, n_θd, n_φd); bbm accepts nothing else, most readers check only the product.
DIMS = (90, 90, 180)
N_BIN = DIMS[0] * DIMS[1] * DIMS[2]
HEADER = struct.pack("<3i", *DIMS)
FILE_SIZE = len(HEADER) + 3 * N_BIN * 8
#: Physical value = raw · SCALE[c] (MERL BRDFRead.cpp: RED/GREEN/BLUE_SCALE).
SCALE = np.array([1.0, 1.15, 1.66]) / 1500.0
#: Raw value written for "no data" bins (below the horizon, missing samples).
MISSING_RAW = -1.0
#: Name of the integer variable that makes MERL → table → MERL bit-exact.
CORRECTION = "merl_raw_ulp_correction"
#: φh samples of ``phi_h_average = true``.
DEFAULT_PHI_H_SAMPLES = 36
RGB = ("R", "G", "B")
_BELOW_HORIZON = ("zero", "missing")
_NEGATIVE = ("zero", "missing")
_POSITIONS = ("bin-centre", "lower-edge")


# --------------------------------------------------------------------------------------------
# Reading


def sniff(head: bytes, size: int) -> bool:
    """A MERL file has no magic number: its 12-byte header is (90, 90, 180) little-endian."""
    return head[:len(HEADER)] == HEADER


def read_merl(path):
    """Read a MERL ``.binary`` file into a :class:`~brdftab.table.Table` (RGB, MERL grid)."""
    path = Path(path)
    head, size = read_head(path, len(HEADER))
    _check_layout(path, head, size)
    try:
        raw = np.fromfile(path, dtype="<f8", count=3 * N_BIN, offset=len(HEADER))
    except (OSError, ValueError) as exc:
        raise FormatError(f"{path}: cannot read the MERL samples ({exc})") from None
    if raw.size != 3 * N_BIN:  # the file shrank after the size check
        raise FormatError(f"{path}: truncated MERL file: {raw.size} of {3 * N_BIN} samples")
    return _table_from_raw(raw.reshape((3,) + DIMS), path.name)


def _check_layout(path, head: bytes, size: int) -> None:
    expected = f"a MERL .binary file has a 12-byte header (90, 90, 180) and {FILE_SIZE:,} bytes in all"
    if len(head) < len(HEADER):
        raise FormatError(f"{path}: too short for a MERL .binary file ({size} bytes; {expected})")
    dims = struct.unpack("<3i", head)
    if dims != DIMS:
        if struct.unpack(">3i", head) == DIMS:
            raise FormatError(f"{path}: MERL header is big-endian; MERL files are little-endian")
        raise FormatError(f"{path}: MERL header dims {dims}, expected exactly (90, 90, 180) "
                          "(n_theta_h, n_theta_d, n_phi_d as little-endian int32)")
    if size != FILE_SIZE:
        what = "truncated" if size < FILE_SIZE else f"{size - FILE_SIZE:,} bytes of trailing data in"
        raise FormatError(f"{path}: {what} MERL file ({size:,} bytes; {expected})")


def _table_from_raw(raw, name: str):
    """A table from raw samples ``[c, θh, θd, φd]`` (keeps what makes writing them back exact)."""
    from ..table import Table, make_table

    values = np.empty(DIMS + (3,))
    diffs = []
    with np.errstate(all="ignore"):  # NaN/inf samples are data here; the checks report them
        for c in range(3):
            np.multiply(raw[c], SCALE[c], out=values[..., c])
            back = values[..., c] / SCALE[c]
            d = raw[c].view(np.int64) - back.view(np.int64)  # int64 wraps: exact modulo 2**64
            diffs.append(d if d.any() else None)
    provenance = {
        "title": f"MERL BRDF {name}",
        "model": "unknown",  # a MERL file names no model: it is data (measured or tabulated elsewhere)
        "material": Path(name).stem,
        "parameters": "{}",
        "isotropic": 1,
        "reciprocal": 1,
        "source_file": name,
        "source_format": "merl",
        "merl_scale": "physical = raw * (1, 1.15, 1.66) / 1500 for R, G, B",
    }
    table = make_table(values, merl_grid(), Layout(RGB), provenance=provenance)
    ds = table.ds
    for key in ("created", "brdftab_version", "history", "source"):  # a MERL file records none of them
        ds.attrs.pop(key, None)
    brdf = ds["brdf"]
    brdf.attrs["valid_min"] = 0.0
    brdf.attrs["comment"] = ("negative samples are MERL 'no measurement' markers: declared missing by valid_min, "
                             "stored as raw * scale")
    used = [d for d in diffs if d is not None]
    if used:
        lo, hi = min(int(d.min()) for d in used), max(int(d.max()) for d in used)
        dtype = next(t for t in (np.int8, np.int16, np.int32, np.int64)
                     if np.iinfo(t).min <= lo and hi <= np.iinfo(t).max)
        corr = np.zeros(DIMS + (3,), dtype)
        for c, d in enumerate(diffs):
            if d is not None:
                corr[..., c] = d
        ds[CORRECTION] = xr.Variable(brdf.dims, corr, attrs={
            "long_name": "MERL raw sample bits minus the bits of brdf / scale",
            "comment": "added back by the MERL writer while brdf still hashes to values_sha256; makes "
                       "MERL -> table -> MERL byte-identical",
            "values_sha256": _values_sha256(values),
        })
    return Table(ds)


def _values_sha256(values) -> str:
    return hashlib.sha256(np.ascontiguousarray(values, dtype="<f8").data).hexdigest()


# --------------------------------------------------------------------------------------------
# Writing


def merl_raw(table) -> np.ndarray:
    """The raw samples ``[c, θh, θd, φd]`` (little-endian float64) a MERL file of ``table`` holds."""
    if not _is_merl_grid(table.grid):
        raise FormatError(f"a MERL file needs a table on the MERL grid, not on {table.grid.describe()}")
    if table.channels != RGB:
        raise FormatError(f"a MERL file stores channels R, G, B, not {table.channels or 'a spectrum'}")
    values = np.asarray(table.values)
    raw = np.empty((3,) + DIMS, dtype="<f8")
    with np.errstate(all="ignore"):
        for c in range(3):
            np.divide(values[..., c], SCALE[c], out=raw[c])
    corr = _correction(table, values)
    if corr is not None:
        bits = raw.view(np.int64)
        for c in range(3):
            bits[c] += corr[..., c]  # int64 arithmetic wraps: the exact raw bits come back
    return raw


def _correction(table, values):
    ds = table.ds
    if CORRECTION not in ds.data_vars:
        return None
    var = ds[CORRECTION]
    want = var.attrs.get("values_sha256")
    dims = table.grid.dims + ("channel",)
    if (not isinstance(want, str) or values.dtype != np.float64 or var.dtype.kind != "i"
            or set(var.dims) != set(dims) or _values_sha256(values) != want):
        return None  # values changed since the MERL file was read (or foreign data): write f / s
    corr = np.asarray(var.transpose(*dims).values, dtype=np.int64)
    return corr if corr.shape == values.shape else None


def write_merl(table, path, sample_position=None, below_horizon="zero", phi_h_average=False, symmetrize=False,
               negative="zero", **colour):
    """Write ``table`` (on the MERL grid, channels R, G, B; see :func:`prepare_merl`) to ``path``."""
    check_options(sample_position, below_horizon, phi_h_average, symmetrize, negative, **colour)
    raw = merl_raw(table)
    with open(path, "wb") as fh:
        fh.write(HEADER)
        fh.write(memoryview(raw).cast("B"))


def _is_merl_grid(grid) -> bool:
    return grid is not None and any(grid.equals(merl_grid(p)) for p in _POSITIONS)


def native_grid(requested, options: dict):
    """The MERL grid: at ``sample_position`` if given, else the requested MERL grid's, else bin centres."""
    pos = options.get("sample_position")
    if pos is not None:
        return merl_grid(pos)
    if _is_merl_grid(requested):
        return requested
    return merl_grid()


class _CountKind(Kind):
    """true/false, or a whole number of samples in the declared range."""

    name = "count"

    def expected(self, p):
        return f"true, false or a whole number of samples ({p.range_text()})"

    def convert(self, p, value):
        if isinstance(value, (bool, np.bool_)):
            return bool(value)
        if isinstance(value, (int, np.integer)) and p.in_range(np.array([float(value)])):
            return int(value)
        raise ParameterError(p.name, f"expected {self.expected(p)}, got {value!r}")


register_kind(_CountKind())


def check_options(sample_position=None, below_horizon="zero", phi_h_average=False, symmetrize=False, negative="zero",
                  illuminant="D65", observer="cie1931-2", wavelengths_nm=None):
    if sample_position is not None and (not isinstance(sample_position, str) or sample_position not in _POSITIONS):
        raise ParameterError("sample_position", f"expected 'bin-centre' or 'lower-edge', got {sample_position!r}")
    if not isinstance(below_horizon, str) or below_horizon not in _BELOW_HORIZON:
        raise ParameterError("below_horizon", f"expected 'zero' or 'missing', got {below_horizon!r}")
    if not isinstance(negative, str) or negative not in _NEGATIVE:
        raise ParameterError("negative", f"expected 'zero' or 'missing', got {negative!r}")
    _phi_h_samples(phi_h_average)
    if not isinstance(symmetrize, bool):
        raise ParameterError("symmetrize", f"expected true or false, got {symmetrize!r}")
    if (illuminant, observer) != ("D65", "cie1931-2"):
        from ..colorimetry import from_options

        from_options(illuminant, observer)


def _phi_h_samples(value) -> int:
    """Number of φh samples asked for by ``phi_h_average`` (0: no averaging)."""
    if isinstance(value, bool):
        return DEFAULT_PHI_H_SAMPLES if value else 0
    if isinstance(value, (int, np.integer)) and 2 <= value <= 3600:
        return int(value)
    raise ParameterError("phi_h_average", f"expected true, false or a number of phi_h samples from 2 to 3600, "
                         f"got {value!r}")


def prepare_merl(brdf, grid, sample_position=None, below_horizon="zero", phi_h_average=False, symmetrize=False,
                 negative="zero", illuminant="D65", observer="cie1931-2", wavelengths_nm=None):
    """The RGB table on the MERL grid that :func:`write_merl` writes for ``brdf``.

    A table already on the target MERL grid is copied. Anything else is tabulated at the
    grid's sample positions; an anisotropic source needs ``phi_h_average`` (its mean over φh
    is written) and a non-reciprocal one ``symmetrize`` (``(f(wi, wo) + f(wo, wi)) / 2`` is
    written). ``below_horizon = "missing"`` marks tabulated bins whose directions lie below the
    horizon with the raw value −1 instead of 0; bins where a resampled table has no data (NaN)
    are marked −1 too.

    MERL reads every negative value as a "no measurement" marker, so negative samples that are
    data (measurement noise below 0 in measured or unknown-origin data, not declared missing)
    would come back as missing bins: with ``negative = "zero"`` (the default) they are written
    as 0, and one warning line gives their count and the lowest value; ``negative = "missing"``
    writes them as they are (read back as missing). Samples the source declares missing stay
    markers; negative values of an analytic model are left for the non-negative check (written
    anyway, with ``allow_invalid``, they are markers and read back as missing).

    A spectral source is written in linear sRGB converted through colour-science
    (:func:`brdftab.colorimetry.convert_for_writer`: ``illuminant``, ``observer``, and for a
    model ``wavelengths_nm``); MERL files hold no metadata, so one warning line says so.
    """
    from ..colorimetry import convert_for_writer
    from ..table import Table, tabulate

    from ..table import warn_specular_dropped

    check_options(sample_position, below_horizon, phi_h_average, symmetrize, negative, illuminant, observer,
                  wavelengths_nm)
    warn_specular_dropped(brdf, "the MERL .binary format")
    brdf = convert_for_writer(brdf, "MERL .binary", illuminant, observer, wavelengths_nm)
    target = grid if _is_merl_grid(grid) else merl_grid(sample_position or "bin-centre")
    n_phi_h = _phi_h_samples(phi_h_average)
    _check_channels(brdf)
    if isinstance(brdf, Table) and target.equals(brdf.grid) and not n_phi_h and not symmetrize:
        return _clamp_negatives(_as_rgb(brdf), negative)
    if not brdf.isotropic and not n_phi_h:
        raise FormatError(f"MERL files are isotropic and '{brdf.name}' is anisotropic (phi_h would be dropped); "
                          "pass phi_h_average = true (or a number of phi_h samples) to write its average over phi_h")
    if not brdf.reciprocal and not symmetrize:
        raise FormatError(f"MERL files fold phi_d by reciprocity (phi_d ~ phi_d + pi) and '{brdf.name}' is not "
                          "reciprocal; pass symmetrize = true to write (f(wi, wo) + f(wo, wi)) / 2")
    source, provenance = averaged(brdf, n_phi_h, symmetrize)
    table = _clamp_negatives(_as_rgb(tabulate(source, target, provenance=provenance or None)), negative)
    missing = None
    if isinstance(brdf, Table):
        # where the source table has no data (missing samples, outside its domain) it gives NaN
        nan = np.isnan(table.values).any(axis=-1)
        missing = nan if nan.any() else None
    if below_horizon == "missing":
        below = ~target.node_above_horizon()
        missing = below if missing is None else (missing | below)
    if missing is not None:
        values = np.array(table.values)
        values[missing] = MISSING_RAW * SCALE
        ds = table.ds.copy()
        ds["brdf"] = xr.Variable(table.grid.dims + ("channel",), values, attrs={**ds["brdf"].attrs, "valid_min": 0.0})
        table = Table(ds)
    return table


def _clamp_negatives(table, negative: str):
    """``table`` with its negative data samples (not declared missing) set to 0, said in one
    warning line, unless ``negative = "missing"``; the table itself when it has none. Only
    measured data (or data of unknown origin) is clamped: a negative value of an analytic model
    is an error the non-negative check must see, not noise."""
    from ..table import Table

    if negative == "missing" or getattr(table, "origin", "unknown") == "analytic":
        return table
    values = np.asarray(table.values)
    with np.errstate(invalid="ignore"):
        neg = values < 0
    miss = table.missing
    if miss is not None:
        neg &= ~np.broadcast_to(np.asarray(miss, bool), neg.shape)
    count = int(np.count_nonzero(neg))
    if not count:
        return table
    lowest = float(values[neg].min())
    warnings.warn(f"{count} of {values.size} samples are negative (lowest {lowest:.4g} sr-1): written as 0, as MERL "
                  "reads negative values as missing-measurement markers (negative = \"missing\" keeps them "
                  "negative)", BrdftabWarning, stacklevel=3)
    ds = table.ds.copy(deep=False)
    ds["brdf"] = ds["brdf"].copy(data=np.where(neg, 0.0, values))
    out = Table(ds)
    out.origin = table.origin
    return out


def _check_channels(brdf) -> None:
    if brdf.spectral:
        raise FormatError(f"MERL files store R, G, B and '{brdf.name}' is spectral")
    if brdf.channels not in (RGB, ("mono",)):
        raise FormatError(f"MERL files store R, G, B; '{brdf.name}' has channels {', '.join(brdf.channels)}")


def _as_rgb(table):
    """``table`` itself if it is RGB; a grey table repeated into R, G, B."""
    from ..table import Table

    if table.channels == RGB:
        return table
    ds = table.ds
    var = ds["brdf"]
    rgb = xr.Variable(var.dims, np.repeat(np.asarray(var.values), 3, axis=-1), attrs=dict(var.attrs))
    out = ds.drop_vars(list(ds.data_vars) + ["channel"]).assign_coords(
        channel=xr.Variable(("channel",), np.array(RGB, dtype=object), attrs=dict(ds["channel"].attrs)))
    out["brdf"] = rgb
    return Table(out)


register(FileFormat(
    name="merl",
    extensions=(".binary",),
    description="MERL BRDF database binary (90 x 90 x 180 RGB float64, isotropic, reciprocal): f_r [sr-1] "
                "divided by MERL's channel scales (1, 1.15, 1.66)/1500, no cosine; negative = no measurement",
    read=read_merl,
    write=write_merl,
    sniff=sniff,
    native_grid=native_grid,
    prepare=prepare_merl,
    check_options=check_options,
    colour=True,
    params=(
        Param("sample_position", "choice", "Where tabulated samples sit in MERL's bins (default: bin-centre).",
              default=None, choices=_POSITIONS),
        Param("below_horizon", "choice", "Value of bins whose directions lie below the horizon: 0, or MERL's "
              "missing marker (raw -1).", default="zero", choices=_BELOW_HORIZON),
        Param("phi_h_average", "count", "Write the phi_h average of an anisotropic BRDF: true (36 samples) or a "
              "sample count.", default=False, minimum=2, maximum=3600),
        Param("symmetrize", "bool", "Write (f(wi, wo) + f(wo, wi)) / 2 of a non-reciprocal BRDF.", default=False),
        Param("negative", "choice", "Negative samples that are data (measurement noise): written as 0, or as they "
              "are (MERL reads them as missing).", default="zero", choices=_NEGATIVE),
    ) + COLOUR_PARAMS,
    precision=1e-12,  # float64, scaled per channel
))
