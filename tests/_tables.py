"""A small Lambert table file for tests, optionally edited as another writer (or a damaged
measurement) would have left it."""

from __future__ import annotations

import brdftab
from brdftab import models
from brdftab.table import tabulate


def lambert_table(tmp_path, fill=None, name="lam.nc"):
    """``tmp_path/name``: Lambert (albedo 0.7) on a 12 x 12 x 24 Rusinkiewicz grid; ``fill(ds)``,
    if given, edits the loaded dataset before it is written back."""
    t = tabulate(models.create("lambert", albedo=0.7), brdftab.grids.RusinkiewiczGrid(12, 12, 24), progress=False)
    path = tmp_path / name
    brdftab.save(t, path)
    if fill is not None:
        import xarray as xr

        with xr.open_dataset(path) as ds:
            ds = ds.load()
        fill(ds)
        ds.to_netcdf(path, mode="w")
    return path
