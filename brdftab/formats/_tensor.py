"""Mitsuba's TensorFile container (``tensor_file``), read and written with numpy.

Layout (all integers little-endian)::

    offset 0   char[12]  "tensor_file\\0"
    offset 12  uint8[2]  version = (1, 0)
    offset 14  uint32    n_fields
    offset 18  n_fields × { uint16 name_len; char name[name_len] (UTF-8);
                            uint16 ndim; uint8 dtype; uint64 offset; uint64 shape[ndim] }
    then each field's data at its absolute offset, C order, little-endian.

dtype codes are Mitsuba's ``Struct::Type``: 1 uint8, 2 int8, 3 uint16, 4 int16, 5 uint32,
6 int32, 7 uint64, 8 int64, 9 float16, 10 float32, 11 float64.

The writer pads every field's data to 8 bytes, like Mitsuba's ``tensor_io.write``. The reader
checks everything a damaged file can get wrong (size, magic, version, field table, dtype
codes, data running past the end, duplicate names) and raises
:class:`~brdftab.errors.FormatError` with one line naming the file.

References: mitsuba-renderer/mitsuba3 ``src/core/tensor.cpp`` and
``src/python/python/tensor_io.py``.
"""

from __future__ import annotations

import struct

import numpy as np

from ..errors import FormatError

__all__ = ["MAGIC", "VERSION", "DTYPE_CODES", "read_tensor_file", "parse_tensor", "write_tensor_file",
           "encode_tensor", "tensor_header"]

MAGIC = b"tensor_file\0"
VERSION = (1, 0)
HEADER = 18  # magic + version + field count
ALIGN = 8

#: dtype code -> numpy dtype (little-endian)
DTYPE_CODES = {1: np.dtype("<u1"), 2: np.dtype("<i1"), 3: np.dtype("<u2"), 4: np.dtype("<i2"),
               5: np.dtype("<u4"), 6: np.dtype("<i4"), 7: np.dtype("<u8"), 8: np.dtype("<i8"),
               9: np.dtype("<f2"), 10: np.dtype("<f4"), 11: np.dtype("<f8")}
_CODE_OF = {(dt.kind, dt.itemsize): code for code, dt in DTYPE_CODES.items()}


def _as_array(name, value) -> np.ndarray:
    if isinstance(value, str):
        value = value.encode("utf-8")
    if isinstance(value, (bytes, bytearray)):
        return np.frombuffer(bytes(value), dtype=np.uint8)
    arr = np.asarray(value)
    if (arr.dtype.kind, arr.dtype.itemsize) not in _CODE_OF:
        raise FormatError(f"tensor field {name!r}: dtype {arr.dtype} cannot be stored in a tensor file")
    return np.ascontiguousarray(arr, dtype=arr.dtype.newbyteorder("<"))


def tensor_header(layout: dict) -> tuple:
    """``(header bytes, {name: data offset})`` of a tensor file whose fields are ``layout``
    (name -> ``(numpy dtype, shape)``), in order: the field table, each field's data to start at
    its offset (8-byte aligned, after the table and the fields before it). Lets a writer stream
    a large field's data after the header."""
    for name in layout:
        if not isinstance(name, str) or not name or len(name.encode("utf-8")) > 0xFFFF:
            raise FormatError(f"tensor field name {name!r} is not a non-empty string of at most 65535 bytes")
    table_size = HEADER + sum(13 + len(k.encode("utf-8")) + 8 * len(shape) for k, (_, shape) in layout.items())
    offsets, pos = {}, table_size
    for k, (dtype, shape) in layout.items():
        pos = -(-pos // ALIGN) * ALIGN
        offsets[k] = pos
        n = 1
        for s in shape:
            n *= int(s)
        pos += n * np.dtype(dtype).itemsize
    out = bytearray(MAGIC + struct.pack("<BBI", *VERSION, len(layout)))
    for k, (dtype, shape) in layout.items():
        dt = np.dtype(dtype)
        key = k.encode("utf-8")
        out += struct.pack("<H", len(key)) + key
        out += struct.pack("<HBQ", len(shape), _CODE_OF[(dt.kind, dt.itemsize)], offsets[k])
        out += struct.pack(f"<{len(shape)}Q", *shape)
    assert len(out) == table_size
    return bytes(out), offsets


def encode_tensor(fields: dict) -> bytes:
    """The bytes of a tensor file holding ``fields`` (name -> array, str or bytes), in order."""
    arrays = {}
    for name, value in fields.items():
        if not isinstance(name, str) or not name or len(name.encode("utf-8")) > 0xFFFF:
            raise FormatError(f"tensor field name {name!r} is not a non-empty string of at most 65535 bytes")
        arrays[name] = _as_array(name, value)
    header, offsets = tensor_header({k: (a.dtype, a.shape) for k, a in arrays.items()})
    out = bytearray(header)
    for k, a in arrays.items():
        out += b"\0" * (offsets[k] - len(out))
        out += a.tobytes()
    return bytes(out)


def write_tensor_file(path, fields: dict) -> None:
    """Write ``fields`` to ``path`` as a tensor file (8-byte aligned data)."""
    data = encode_tensor(fields)
    with open(path, "wb") as fh:
        fh.write(data)


def read_tensor_file(path) -> dict:
    """Fields of the tensor file at ``path`` as ``{name: ndarray}`` (native byte order, copies)."""
    try:
        with open(path, "rb") as fh:
            data = fh.read()
    except OSError as exc:
        raise FormatError(f"{path}: cannot read ({exc.strerror or exc})") from None
    return parse_tensor(data, str(path))


def parse_tensor(data: bytes, where: str = "<bytes>") -> dict:
    """Parse the bytes of a tensor file; ``where`` names it in error messages."""
    size = len(data)
    if size < HEADER:
        raise FormatError(f"{where}: too short for a tensor file ({size} bytes, the header alone is {HEADER})")
    if data[:12] != MAGIC:
        raise FormatError(f"{where}: not a tensor file (the first 12 bytes are not 'tensor_file\\0')")
    version = (data[12], data[13])
    if version != VERSION:
        raise FormatError(f"{where}: unsupported tensor file version {version[0]}.{version[1]} (expected 1.0)")
    (n_fields,) = struct.unpack_from("<I", data, 14)
    room = (size - HEADER) // 13  # each field entry takes at least 13 bytes
    if n_fields > room:
        raise FormatError(f"{where}: the header announces {n_fields} fields but the file has room for at most "
                          f"{room} (truncated or damaged)")
    pos = HEADER
    entries = {}
    for i in range(n_fields):
        if pos + 2 > size:
            raise FormatError(f"{where}: field table truncated at field {i} of {n_fields}")
        (name_len,) = struct.unpack_from("<H", data, pos)
        pos += 2
        if pos + name_len + 11 > size:
            raise FormatError(f"{where}: field table truncated at field {i} of {n_fields}")
        raw_name = data[pos:pos + name_len]
        pos += name_len
        try:
            name = raw_name.decode("utf-8")
        except UnicodeDecodeError:
            raise FormatError(f"{where}: field {i} has a name that is not valid UTF-8") from None
        ndim, code, offset = struct.unpack_from("<HBQ", data, pos)
        pos += 11
        if pos + 8 * ndim > size:
            raise FormatError(f"{where}: field table truncated in the shape of field {name!r}")
        shape = struct.unpack_from(f"<{ndim}Q", data, pos)
        pos += 8 * ndim
        if code not in DTYPE_CODES:
            raise FormatError(f"{where}: field {name!r} has an invalid dtype code {code} (valid: 1-11)")
        if name in entries:
            raise FormatError(f"{where}: field {name!r} appears twice")
        dtype = DTYPE_CODES[code]
        count = 1
        for s in shape:
            count *= s
        nbytes = count * dtype.itemsize
        if offset > size or nbytes > size - offset:
            raise FormatError(f"{where}: the data of field {name!r} ({nbytes} bytes at offset {offset}) run past "
                              f"the end of the file ({size} bytes)")
        entries[name] = (dtype, tuple(int(s) for s in shape), int(offset), int(count))
    fields = {}
    for name, (dtype, shape, offset, count) in entries.items():
        try:
            if count == 0:
                fields[name] = np.zeros(shape, dtype.newbyteorder("="))
                continue
            arr = np.frombuffer(data, dtype=dtype, count=count, offset=offset)
            fields[name] = arr.astype(dtype.newbyteorder("="), copy=True).reshape(shape)
        except (ValueError, MemoryError, OverflowError):  # e.g. (0, 2**63) or more than 64 dimensions
            raise FormatError(f"{where}: field {name!r} has a shape numpy cannot hold "
                              f"({len(shape)} dimensions, up to {max(shape, default=0)})") from None
    return fields
