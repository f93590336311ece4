"""netCDF-4 tables (``.nc``) through xarray + netCDF4.

The file is the table's dataset as it is (see :mod:`brdftab.table` and
``formats/netcdf.md``): variable ``brdf`` [sr-1], coordinates in radians, CF-style
attributes and brdftab provenance, and — for a model with an ideal specular (delta) part — the
variable ``specular_reflectance`` over ``specular_theta_i`` (written like any auxiliary
variable, float64). Values are zlib-compressed; ``dtype`` chooses float64
(default, exact) or float32 storage.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import warnings

import netCDF4
import numpy as np
import xarray as xr

from .._progress import write_step
from ..params import Param
from ..errors import FormatError, ParameterError, shown
from . import FileFormat, cast_samples, register

__all__ = ["read_netcdf", "write_netcdf"]

MAGIC = (b"\x89HDF\r\n\x1a\n", b"CDF\x01", b"CDF\x02", b"CDF\x05")


def read_netcdf(path):
    """Open a table lazily: metadata now, samples when first evaluated (see :class:`Table`)."""
    from ..table import Table

    try:
        # brdf's CF missing markers are not turned into NaN (NaN is a sample that failed): see _cf_missing
        ds = xr.open_dataset(path, engine="netcdf4", cache=False, mask_and_scale={"brdf": False})
        if "brdf" in ds.data_vars:
            ds = _cf_missing(ds)
    except (OSError, ValueError, RuntimeError, KeyError, IndexError, TypeError) as exc:
        raise FormatError(f"{path}: not a readable netCDF file ({_first_line(exc)})") from None
    try:
        table = Table(ds)
        table.closers.append(ds.close)
        return table
    except ParameterError as exc:  # a value the file holds, named (e.g. a duplicate channel name)
        raise FormatError(f"{path}: {exc}") from None
    except (KeyError, ValueError, TypeError, IndexError) as exc:
        raise FormatError(f"{path}: not a brdftab table ({_first_line(exc)})") from None


#: CF attributes of ``brdf`` given in packed units (before ``scale_factor``/``add_offset``).
_PACKED_ATTRS = ("_FillValue", "missing_value", "valid_min", "valid_max", "valid_range")


def _cf_missing(ds):
    """``ds`` with ``brdf``'s CF missing markers kept as *missing*, not NaN.

    Samples equal to the variable's ``_FillValue`` or to one of its ``missing_value`` (CF) are
    missing samples, like those outside ``valid_min``/``valid_max``: the checks count them as
    missing and leave them out, the table's interpolation skips them. They are listed in the
    ``missing_value`` attribute (``_FillValue`` can only be set when a variable is created, so
    brdftab writes them back as ``missing_value``). ``scale_factor``/``add_offset`` unpack the
    samples and these attributes alike. Without ``_FillValue``, unwritten parts of a variable
    hold the library's default fill value: samples equal to it are missing
    (``unwritten_value``) unless ``valid_max``/``valid_range`` say what is data.
    """
    var = ds["brdf"].variable
    attrs = dict(var.attrs)
    packed = "scale_factor" in attrs or "add_offset" in attrs
    if packed:
        scale = float(np.asarray(attrs.get("scale_factor", 1.0)).ravel()[0])
        offset = float(np.asarray(attrs.get("add_offset", 0.0)).ravel()[0])
        var = xr.coding.variables.CFScaleOffsetCoder().decode(var, name="brdf")  # lazy: read in slabs
        attrs = dict(var.attrs)
        for key in _PACKED_ATTRS:
            if key in attrs:
                attrs[key] = np.asarray(attrs[key], np.float64) * scale + offset
    markers = [np.asarray(attrs.pop(key)).ravel() for key in ("_FillValue", "missing_value") if key in attrs]
    if markers:
        attrs["missing_value"] = np.unique(np.concatenate(markers).astype(var.dtype))
    elif var.dtype.kind == "f" and "valid_max" not in attrs and "valid_range" not in attrs:
        # any other value, +inf included, is data
        fill = netCDF4.default_fillvals.get(var.dtype.str[1:])
        if fill is not None:
            attrs["unwritten_value"] = np.asarray(fill, var.dtype)
    var.attrs = attrs  # (var.data would load every sample)
    return ds.assign({"brdf": var}) if packed else ds


def _first_line(exc) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


#: Uncompressed bytes per HDF5 chunk of ``brdf``; the variable is written one chunk at a time.
CHUNK_BYTES = 1 << 20


def _attr(value):
    """An attribute value in a type netCDF-3 (classic) has: integers (flags, counts) as int32
    (float64 beyond its range), booleans as int32, text as NC_CHAR (UTF-8 bytes when it is not
    ASCII; netCDF4 reads them back as the same text); anything else unchanged."""
    if isinstance(value, (bool, np.bool_)):
        return np.int32(value)
    if isinstance(value, (int, np.integer)):
        return np.int32(value) if -2**31 <= int(value) < 2**31 else np.float64(value)
    if isinstance(value, np.ndarray) and value.dtype.kind in "biu":
        if value.size and (value.min() < -2**31 or value.max() >= 2**31):
            return value.astype(np.float64)
        return value.astype(np.int32)
    if isinstance(value, (list, tuple)) and value and all(isinstance(v, str) for v in value):
        value = json.dumps(list(value))  # a list of strings would be NC_STRING (netCDF-4 only)
    if isinstance(value, str) and not value.isascii():
        # NC_CHAR holding UTF-8 (a non-ASCII str would become NC_STRING); a file name's bytes
        # that are not UTF-8 are written as \xNN escapes
        return shown(value).encode("utf-8")
    return value


def _attrs(attrs: dict) -> dict:
    return {k: _attr(v) for k, v in attrs.items()}


def _cf_layout(ds):
    """The dataset as written: CF-conformant and netCDF-3-compatible types.

    * A string dimension coordinate (``channel``) becomes the label variable ``channel_name``
      (an auxiliary coordinate: CF coordinate variables are numeric), stored as a char array;
    * integer attributes become int32 (netCDF-3 has no int64);
    * ``Conventions = "CF-1.10"`` and a ``history`` line are present.

    Returns ``(dataset, encoding of the char variables)``; ``ds`` is not changed."""
    from ..table import LABEL_SUFFIX

    out = ds.copy(deep=False)
    chars = {}
    for name in list(out.variables):
        v = out.variables[name]
        if v.dtype.kind not in "OSU":
            continue
        text = np.array([_text(c) for c in np.asarray(v.values).ravel()], dtype=object).reshape(v.shape)
        target = name
        if name in out.dims:
            target = f"{name}{LABEL_SUFFIX}"
            out = out.drop_vars(name).assign_coords({target: xr.Variable(v.dims, text, attrs=dict(v.attrs))})
        else:
            out[target] = xr.Variable(v.dims, text, attrs=dict(v.attrs))
        chars[target] = {"dtype": "S1", "char_dim_name": f"{target}_strlen"}
    for name in out.variables:
        out[name].attrs = _attrs(out[name].attrs)
    out.attrs = cf_global_attrs(out.attrs, "netCDF")
    return out, chars


def cf_global_attrs(attrs: dict, written_as: str, convert=None) -> dict:
    """A table's global attributes as a file stores them (``convert``: the format's attribute
    types, default netCDF's :func:`_attrs`), declaring ``Conventions = "CF-1.10"`` and with a
    ``history`` line when there is none."""
    out = (convert or _attrs)(attrs)
    out["Conventions"] = "CF-1.10"
    if not str(out.get("history", "")).strip():
        from .._version import __version__

        now = _dt.datetime.now(_dt.timezone.utc).replace(microsecond=0).isoformat()
        out["history"] = f"{now} brdftab {__version__}: written as {written_as}"
    return out


def _text(c) -> str:
    if isinstance(c, (bytes, np.bytes_)):
        return bytes(c).decode("utf-8", "replace")
    return str(c)


def write_netcdf(table, path, dtype: str = "float64", complevel: int = 1):
    """Write ``table`` to ``path`` through :func:`stream_netcdf`, one storage chunk of ``brdf`` at
    a time (each a :func:`~brdftab._progress.write_step`, so progress is shown and an interrupt
    acts between chunks)."""
    from ..table import blocks

    _FORMAT.validate_options({"dtype": dtype, "complevel": complevel})  # the declared Params
    var = table.ds["brdf"]
    total, done = int(var.size), 0
    write_step(0, total)
    with stream_netcdf(table.ds, path, dtype, complevel) as out:
        for key in blocks(var.shape, math.prod(out.chunks), align=out.chunks):
            block = var.variable[key].values
            out.write(key, block)
            done += block.size
            write_step(done, total)


class NetcdfStream:
    """The block writer of :func:`stream_netcdf` (see ``FileFormat.stream``)."""

    def __init__(self, template, path, dtype: str = "float64", complevel: int = 1):
        self.path = path
        var = template["brdf"]
        ds, encoding = _cf_layout(template)
        for name in ds.coords:
            if ds[name].dtype.kind == "f":
                encoding[name] = {"_FillValue": None}
        for name in ds.data_vars:  # auxiliary variables (e.g. merl_raw_ulp_correction): compressed, no fill
            if name != "brdf":
                encoding[name] = {**encoding.get(name, {}), "zlib": complevel > 0, "complevel": complevel,
                                  "_FillValue": None}
        if "mueller" in ds.data_vars:  # a polarized table's Mueller matrix: stored like the samples (M00 = brdf)
            encoding["mueller"]["dtype"] = np.dtype(dtype)
        rest = ds.drop_vars("brdf")  # (brdf's data, a placeholder in a streamed template, is never read)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # xarray's note on coordinates no remaining variable uses: brdf will
            rest.to_netcdf(path, engine="netcdf4", format="NETCDF4", encoding=encoding)
        self.dtype = np.dtype(dtype)
        from ..table import chunk_shape

        self.chunks = chunk_shape(var.shape, CHUNK_BYTES // self.dtype.itemsize)
        attrs = _attrs(var.attrs)
        aux = [c for c in ds.coords if c not in ds.dims and set(ds[c].dims) <= set(var.dims)]
        if aux:
            attrs["coordinates"] = " ".join(aux)
        self._written = set(ds.variables)
        self._nc = netCDF4.Dataset(path, "a")
        if "coordinates" in self._nc.ncattrs():  # xarray lists coordinates no written variable uses: brdf does
            self._nc.delncattr("coordinates")
        self._nc.set_auto_maskandscale(False)
        self._var = self._nc.createVariable("brdf", self.dtype, var.dims, zlib=complevel > 0, complevel=complevel,
                                            shuffle=True, chunksizes=self.chunks, fill_value=False)
        self._var.setncatts(attrs)

    def write(self, key, block) -> None:
        self._var[tuple(key)] = np.asarray(block, dtype=self.dtype)

    def update(self, extra) -> None:
        """Add the variables of the dataset ``extra`` (e.g. the albedo curve the checks computed)
        and set its global attributes, after the samples are written; the file is reopened when
        the writer was closed."""
        self.close()
        out, encoding = _cf_layout(extra)
        new = out.drop_vars([v for v in out.variables if v in self._written])
        encoding = {k: v for k, v in encoding.items() if k in new.variables}
        if new.variables:
            for name in new.variables:
                if new[name].dtype.kind == "f":
                    encoding[name] = {**encoding.get(name, {}), "_FillValue": None}
            new.attrs = {}
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                new.to_netcdf(self.path, mode="a", engine="netcdf4", encoding=encoding)
        with netCDF4.Dataset(self.path, "a") as nc:
            nc.setncatts(_attrs(dict(extra.attrs)))

    def close(self) -> None:
        if self._nc is not None:
            self._nc.close()
            self._nc = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def stream_netcdf(template, path, dtype: str = "float64", complevel: int = 1) -> NetcdfStream:
    """A block writer of a netCDF table (``FileFormat.stream``): coordinates, auxiliary
    variables and attributes of ``template`` written now, ``brdf`` created chunked
    (:data:`CHUNK_BYTES` per chunk) and filled by ``write(key, block)``."""
    return NetcdfStream(template, path, dtype, complevel)


def stored_netcdf(table, dtype: str = "float64", **_):
    """The table as the file holds it: samples rounded to ``dtype`` (float32 overflows to inf)."""
    return cast_samples(table, dtype)


_FORMAT = register(FileFormat(
    name="netcdf",
    extensions=(".nc", ".nc4", ".netcdf"),
    description="netCDF-4 table with CF-style units and brdftab provenance (any grid): f_r [sr-1], not "
                "multiplied by a cosine, not a reflectance factor (the variable's quantity attribute says so)",
    read=read_netcdf,
    write=write_netcdf,
    magic=MAGIC,
    utf8_paths=True,
    params=(
        Param("dtype", "choice", "Storage type of the samples (values are computed in float64).", default="float64",
              choices=("float64", "float32")),
        Param("complevel", "int", "zlib compression level (0: none).", default=1, minimum=0, maximum=9),
    ),
    precision=1e-12,  # float64 samples (float32 when dtype = float32: 1e-6)
    stored=stored_netcdf,
    stream=stream_netcdf,
))
