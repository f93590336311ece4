"""zarr tables (``.zarr`` directory stores) through zarr-python and xarray.

The store holds the same dataset as a netCDF table (see ``formats/zarr.md`` and
``formats/netcdf.md``): variable ``brdf`` [sr-1], coordinates in radians, CF-style attributes
and brdftab provenance, the channel names as the label variable ``channel_name``, and the
optional ``specular_reflectance`` and albedo variables. ``brdf`` is written block by block
(:func:`stream_zarr`) in chunks of whole trailing axes of about 4 MiB, compressed with zstd
(level 3, with its checksum); ``dtype`` chooses float64 (default, exact) or float32 storage. Reading is lazy, and a
chunk file missing from the store is an error, never read as the fill value.
"""

from __future__ import annotations

import json
import warnings
from itertools import product
from pathlib import Path

import numpy as np
import xarray as xr
from xarray.backends import BackendArray

from .._progress import write_step
from .._signals import read_array
from ..errors import FormatError, ParameterError, shown
from ..params import Param
from . import FileFormat, cast_samples, register
from .netcdf import _text, cf_global_attrs

__all__ = ["read_zarr", "write_zarr", "stream_zarr", "is_store", "ZarrWriter"]

#: Uncompressed bytes per chunk of ``brdf`` (chosen by ``benchmarks/bench_storage.py``, see
#: ``formats/zarr.md``): chunks of shape ``(1,)*k + (s,) + shape[k+1:]``, like the netCDF writer.
CHUNK_BYTES = 4 << 20
#: The compressor (chosen by the same measurement); ``complevel`` sets its level, 0 stores the
#: chunks uncompressed. One of :data:`CODECS`.
CODEC = "zstd"
#: The compressors measured: Blosc (zstd or lz4 inside, byte shuffle), zstd, gzip (netCDF's
#: zlib). Blosc chunks carry a CRC-32C (zarr format 3; a damaged Blosc chunk can crash its
#: decoder instead of failing), zstd chunks their content checksum; gzip has its own.
CODECS = ("blosc-zstd", "blosc-lz4", "zstd", "gzip")
#: Bytes of ``brdf`` a write of a whole table sends to zarr in one call (whole chunks, which zarr
#: compresses in parallel).
BLOCK_BYTES = 32 << 20
#: The store's metadata files (zarr format 3, format 2).
MARKERS = ("zarr.json", ".zgroup")


def is_store(path) -> bool:
    """True when the folder ``path`` is a zarr store (its root metadata file is there)."""
    path = Path(path)
    return any((path / m).is_file() for m in MARKERS)


def _zarr():
    import zarr

    return zarr


# --------------------------------------------------------------------------------------------
# reading

class _CheckedArray(BackendArray):
    """``brdf`` of a store, read lazily through zarr: every chunk a read needs must be in the
    store (zarr would return its fill value for a missing one: a damaged store would read as
    data), and a chunk that does not decode is a :class:`FormatError` naming the store."""

    def __init__(self, array, root: Path):
        self.array = array
        self.root = root
        self.shape = tuple(array.shape)
        self.dtype = np.dtype(array.dtype)
        self._chunks = tuple(getattr(array, "shards", None) or array.chunks)  # the stored objects: shards if any
        self._seen: set = set()

    def __getitem__(self, key):
        from xarray.core import indexing

        return indexing.explicit_indexing_adapter(key, self.shape, indexing.IndexingSupport.BASIC, self._get)

    def _missing(self, key):
        ranges = []
        for k, n, c in zip(key, self.shape, self._chunks):
            if isinstance(k, slice):
                start, stop, step = k.indices(n)
                idx = range(start, stop, step)
                if not len(idx):
                    return None
                ranges.append(range(idx[0] // c, idx[-1] // c + 1) if step == 1 else sorted({i // c for i in idx}))
            else:
                ranges.append((int(k) % n // c,))
        meta = self.array.metadata
        for coords in product(*ranges):
            if coords in self._seen:
                continue
            name = meta.encode_chunk_key(coords)
            if not (self.root / name).is_file():
                return name
            self._seen.add(coords)
        return None

    def _get(self, key):
        key = tuple(key) + (slice(None),) * (len(self.shape) - len(tuple(key)))
        missing = self._missing(key)
        if missing is not None:
            raise FormatError(f"{self.root.parent}: damaged store: the chunk {self.root.name}/{missing} of "
                              f"'{self.root.name}' is missing")
        try:
            return np.asarray(self.array[key])
        except Exception as exc:  # a codec's error on damaged bytes (its types vary by codec)
            text = " ".join(str(exc).split()) or type(exc).__name__
            raise FormatError(f"{self.root.parent}: damaged sample data in '{self.root.name}' ({text})") from None


def _first_line(exc) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


#: CF attributes that make ``brdf``'s samples missing markers or packed values.
_CF_MARKERS = ("_FillValue", "missing_value", "scale_factor", "add_offset")


def read_zarr(path):
    """Open a store lazily: metadata now, samples when first used (see :class:`~brdftab.table.Table`)."""
    from xarray.core import indexing

    from ..table import Table

    path = Path(path)
    zarr = _zarr()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # on stores without consolidated metadata (other writers')
            ds = xr.open_dataset(path, engine="zarr", chunks=None, cache=False, mask_and_scale={"brdf": False})
            group = zarr.open_group(path, mode="r")
        if "brdf" in ds.data_vars:
            var = ds["brdf"].variable
            checked = _CheckedArray(group["brdf"], path / "brdf")
            ds = ds.assign({"brdf": xr.Variable(var.dims, indexing.LazilyIndexedArray(checked), dict(var.attrs),
                                                dict(var.encoding))})
            if any(k in var.attrs for k in _CF_MARKERS):
                from .netcdf import _cf_missing  # the same CF reading as a netCDF table's

                ds = _cf_missing(ds)
                ds["brdf"].attrs.pop("unwritten_value", None)  # no unwritten parts: a missing chunk is an error
    except FormatError:
        raise
    except Exception as exc:  # zarr and xarray raise many types for a damaged or foreign store
        raise FormatError(f"{path}: not a readable zarr store ({_first_line(exc)})") from None
    ds = _plain(ds)
    ds.encoding["source"] = str(path)
    try:
        return Table(ds)
    except ParameterError as exc:  # a value the store holds, named (e.g. a duplicate channel name)
        raise FormatError(f"{path}: {exc}") from None
    except (KeyError, ValueError, TypeError, IndexError) as exc:
        raise FormatError(f"{path}: not a brdftab table ({_first_line(exc)})") from None


def _plain(ds):
    """``ds`` with the values a netCDF table reads as: string variables as object arrays (zarr
    gives numpy's StringDType), and numeric list attributes (JSON) as numpy arrays."""

    for name in list(ds.variables):
        v = ds.variables[name]
        if v.dtype.kind == "T":
            plain = xr.Variable(v.dims, np.asarray(v.values, dtype=object), dict(v.attrs), dict(v.encoding))
            ds = ds.assign_coords({name: plain}) if name in ds.coords else ds.assign({name: plain})
    for v in ds.variables.values():
        v.attrs = {k: _from_json(a) for k, a in v.attrs.items()}
    ds.attrs = {k: _from_json(a) for k, a in ds.attrs.items()}
    return ds


def _from_json(value):
    if isinstance(value, list) and value and all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                                 for x in value):
        return np.asarray(value)
    return value


# --------------------------------------------------------------------------------------------
# writing

def _to_json(value):
    """An attribute value as JSON holds it: numpy scalars and arrays as numbers and lists, a
    list of strings as JSON text (as netCDF stores it), a file name's non-UTF-8 bytes as \\xNN."""
    if isinstance(value, (bool, np.bool_)):
        return int(value)
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating):
        return float(value)
    if isinstance(value, np.ndarray):
        if value.dtype.kind in "OSU":
            value = [str(x) for x in value.ravel()]
        else:
            return value.tolist()
    if isinstance(value, (bytes, np.bytes_)):
        return bytes(value).decode("utf-8", "replace")
    if isinstance(value, (list, tuple)) and value and all(isinstance(v, str) for v in value):
        return json.dumps(list(value))
    if isinstance(value, str):
        return shown(value)
    return value


def _attrs(attrs: dict) -> dict:
    return {k: _to_json(v) for k, v in attrs.items()}


def _layout(ds):
    """The dataset as stored, without ``brdf`` (written by the block writer): the schema of a
    netCDF table — a string dimension coordinate (``channel``) becomes the label variable
    ``channel_name``, ``Conventions`` and a ``history`` line are present — with JSON attributes.
    Returns ``(rest, brdf attributes)``; ``ds`` is not changed and ``brdf``'s data never read."""
    from ..table import LABEL_SUFFIX

    rest = ds.drop_vars("brdf")
    brdf_attrs = _attrs(ds["brdf"].attrs)
    labels = []
    for name in list(rest.variables):
        v = rest.variables[name]
        if v.dtype.kind not in "OSUT":
            continue
        text = np.array([_text(c) for c in np.asarray(v.values).ravel()], dtype=object).reshape(v.shape)
        if name in rest.dims:
            label = f"{name}{LABEL_SUFFIX}"
            rest = rest.drop_vars(name).assign_coords({label: xr.Variable(v.dims, text, attrs=dict(v.attrs))})
            labels.append(label)
        else:
            rest[name] = xr.Variable(v.dims, text, attrs=dict(v.attrs))
    for name in rest.variables:
        rest[name].attrs = _attrs(rest[name].attrs)
    aux = labels + [c for c in ds.coords if c not in ds.dims and set(ds[c].dims) <= set(ds["brdf"].dims)]
    if aux:
        brdf_attrs["coordinates"] = " ".join(dict.fromkeys(aux))
    rest.attrs = cf_global_attrs(ds.attrs, "zarr", _attrs)
    return rest, brdf_attrs


def _compressors(zarr_format: int, complevel: int, codec: str | None = None):
    """The codecs after serialisation of ``brdf`` and the auxiliary variables (None: none)."""
    codec = CODEC if codec is None else codec
    if complevel <= 0:
        return None
    if codec.startswith("blosc-") and zarr_format == 2:
        codec = "zstd"  # format 2 has no checksum codec to guard Blosc's decoder: zstd's own checksum
    if zarr_format == 2:
        import numcodecs

        return ((numcodecs.Zstd(level=complevel, checksum=True),) if codec == "zstd"
                else (numcodecs.GZip(level=complevel),))
    from zarr.codecs import BloscCodec, Crc32cCodec, GzipCodec, ZstdCodec

    if codec.startswith("blosc-"):
        return (BloscCodec(cname=codec[6:], clevel=complevel, shuffle="shuffle"), Crc32cCodec())
    return (ZstdCodec(level=complevel, checksum=True),) if codec == "zstd" else (GzipCodec(level=complevel),)


class ZarrWriter:
    """The block writer of a zarr store (see :attr:`brdftab.formats.FileFormat.stream`).

    A writer pickles: copies sent to other processes write blocks of the same store in
    parallel, each block whole chunks (:attr:`chunks`) that no other copy writes; the writer
    that created the store closes it once all have finished."""

    def __init__(self, template, path, dtype: str = "float64", complevel: int = 3, zarr_format: int = 3,
                 chunk_bytes: int | None = None, codec: str | None = None):
        zarr = _zarr()
        self.path = Path(path)
        var = template["brdf"]
        self.dtype = np.dtype(dtype)
        self.shape = tuple(var.shape)
        rest, brdf_attrs = _layout(template)
        codecs = _compressors(zarr_format, complevel, codec)
        encoding = {}
        for name in rest.variables:
            enc = {"compressors": codecs}
            if rest[name].dtype.kind == "f":
                enc["_FillValue"] = None
            if name == "mueller":  # a polarized table's Mueller matrix: stored like the samples (M00 = brdf)
                enc["dtype"] = self.dtype
            encoding[name] = enc
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # xarray's note on coordinates no remaining variable uses: brdf will
            rest.to_zarr(self.path, mode="w-", zarr_format=zarr_format, consolidated=False, encoding=encoding)
        self.group = zarr.open_group(self.path, mode="r+")
        if zarr_format == 2:
            brdf_attrs["_ARRAY_DIMENSIONS"] = list(var.dims)  # xarray's dimension names in format 2
            dims = {}
        else:
            dims = {"dimension_names": tuple(var.dims)}
        from ..table import chunk_shape

        self.chunks = chunk_shape(self.shape, (CHUNK_BYTES if chunk_bytes is None else chunk_bytes)
                                  // self.dtype.itemsize)
        self.array = self.group.create_array(
            "brdf", shape=self.shape, dtype=self.dtype, chunks=self.chunks, compressors=codecs, filters=None,
            fill_value=np.nan, attributes=brdf_attrs, config={"write_empty_chunks": True}, **dims)
        self.zarr_format = zarr_format
        self.closed = False

    def write(self, key, block) -> None:
        """Store ``block`` (cast to the storage type) at ``key`` (slices over ``brdf``'s dims)."""
        self.array[tuple(key)] = np.asarray(block).astype(self.dtype, copy=False)

    def update(self, extra) -> None:
        """After the checks: add the variables of the dataset ``extra`` the store lacks (the
        albedo curve) and set its global attributes (the report); the metadata is consolidated
        again."""
        from ..table import LABEL_SUFFIX

        self.close()
        have = set(self.group.array_keys())
        new = [n for n in extra.data_vars if n not in have]
        if new:
            part = extra[new]
            part = part.drop_vars([c for c in part.coords if c in have or f"{c}{LABEL_SUFFIX}" in have])
            part.attrs = {}
            codecs = _compressors(self.zarr_format, 3)
            encoding = {n: {"compressors": codecs, **({"_FillValue": None} if part[n].dtype.kind == "f" else {})}
                        for n in part.variables}
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                part.to_zarr(self.path, mode="a", zarr_format=self.zarr_format, consolidated=False,
                             encoding=encoding)
        self.group = _zarr().open_group(self.path, mode="r+")
        self.group.attrs.update(_attrs(dict(extra.attrs)))
        self.closed = False
        self.close()

    def close(self) -> None:
        """Finish the store: its metadata consolidated into one file (xarray opens it in one read)."""
        if self.closed:
            return
        self.closed = True
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # format 3: consolidated metadata is zarr-python's extension
            _zarr().consolidate_metadata(self.path, zarr_format=self.zarr_format)

    def __enter__(self):
        return self

    def __exit__(self, kind, exc, tb):
        if kind is None:
            self.close()
        return False


def stream_zarr(template, path, dtype: str = "float64", complevel: int = 3, zarr_format: int = 3) -> ZarrWriter:
    """A :class:`ZarrWriter` creating the store ``path`` for ``template`` (a table's dataset)."""
    _FORMAT.validate_options({"dtype": dtype, "complevel": complevel, "zarr_format": zarr_format})
    return ZarrWriter(template, path, dtype=dtype, complevel=complevel, zarr_format=zarr_format)


def write_zarr(table, path, dtype: str = "float64", complevel: int = 3, zarr_format: int = 3):
    """Write ``table`` to the store ``path`` block by block through :func:`stream_zarr` (each block
    a :func:`~brdftab._progress.write_step`; a table on disk is read one block at a time)."""
    from ..table import blocks

    var = table.ds["brdf"]
    total, done = int(var.size), 0
    with stream_zarr(table.ds, path, dtype=dtype, complevel=complevel, zarr_format=zarr_format) as out:
        write_step(0, total)
        for key in blocks(var.shape, BLOCK_BYTES // out.dtype.itemsize, align=out.chunks):
            block = read_array(var.variable[key])
            out.write(key, block)
            done += block.size
            write_step(done, total)


def stored_zarr(table, dtype: str = "float64", **_):
    """The table as the store holds it: samples rounded to ``dtype`` (float32 overflows to inf)."""
    return cast_samples(table, dtype)


_FORMAT = register(FileFormat(
    name="zarr",
    extensions=(".zarr",),
    description="zarr directory store (a folder holding zarr.json or .zgroup) with the netCDF table's schema, "
                "CF-style units and brdftab provenance (any grid): f_r [sr-1], no cosine, not a reflectance factor",
    read=read_zarr,
    write=write_zarr,
    requires=("zarr",),
    params=(
        Param("dtype", "choice", "Storage type of the samples (values are computed in float64).", default="float64",
              choices=("float64", "float32")),
        Param("complevel", "int", "zstd compression level (0: none).", default=3, minimum=0, maximum=19),
        Param("zarr_format", "int", "zarr format version: 3 (current) or 2 (for readers that know only 2).",
              default=3, minimum=2, maximum=3),
    ),
    precision=1e-12,  # float64 samples (float32 when dtype = float32: 1e-6)
    stored=stored_zarr,
    stream=stream_zarr,
    store=is_store,
))
