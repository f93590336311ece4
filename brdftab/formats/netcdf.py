"""netCDF-4 tables (``.nc``) through xarray + netCDF4.

The file is the table's dataset as it is (see :mod:`brdftab.table` and
``formats/netcdf.md``): variable ``brdf`` [sr-1], coordinates in radians, CF-style
attributes and brdftab provenance. Values are zlib-compressed; ``dtype`` chooses float64
(default, exact) or float32 storage.
"""

from __future__ import annotations

import numpy as np
import xarray as xr

from ..errors import FormatError, ParameterError
from . import FileFormat, register

__all__ = ["read_netcdf", "write_netcdf"]

MAGIC = (b"\x89HDF\r\n\x1a\n", b"CDF\x01", b"CDF\x02", b"CDF\x05")


def read_netcdf(path):
    from ..table import Table

    try:
        with xr.open_dataset(path, engine="netcdf4") as ds:
            ds = ds.load()
    except (OSError, ValueError, RuntimeError) as exc:
        raise FormatError(f"{path}: not a readable netCDF file ({str(exc).splitlines()[0]})") from None
    return Table(ds)


def check_options(dtype: str = "float64", complevel: int = 4):
    if dtype not in ("float32", "float64"):
        raise ParameterError("dtype", f"expected 'float32' or 'float64', got {dtype!r}")
    if isinstance(complevel, bool) or not isinstance(complevel, int) or not 0 <= complevel <= 9:
        raise ParameterError("complevel", f"expected a whole number 0..9, got {complevel!r}")


def write_netcdf(table, path, dtype: str = "float64", complevel: int = 4):
    check_options(dtype, complevel)
    ds = table.ds
    encoding = {"brdf": {"dtype": np.dtype(dtype), "zlib": complevel > 0, "complevel": complevel,
                         "_FillValue": None}}
    for name in ds.coords:
        if ds[name].dtype.kind == "f":
            encoding[name] = {"_FillValue": None}
    ds.to_netcdf(path, engine="netcdf4", format="NETCDF4", encoding=encoding)


register(FileFormat(
    name="netcdf",
    extensions=(".nc", ".nc4", ".netcdf"),
    description="netCDF-4 table with CF-style units and brdftab provenance (any grid)",
    read=read_netcdf,
    write=write_netcdf,
    magic=MAGIC,
    options={"dtype": "float64 (default) or float32", "complevel": "zlib level 0-9 (default 4)"},
    check_options=check_options,
))
