"""Benchmark: storing tables as zarr stores (chunk shapes, compressors) and as netCDF.

Run from the repository root::

    python benchmarks/bench_storage.py [--repeat 3] [--dir /tmp] [--quick]

Two tables (values computed once, float64):

* **iso RGB**: GGX α 0.3 with the conductor Fresnel of gold on the MERL grid,
  90 × 90 × 180 × 3 (4.4 M samples, 35 MB in float64);
* **aniso grey**: GGX αx 0.2, αy 0.4, dielectric Fresnel (n 1.5) on an anisotropic
  Rusinkiewicz grid 45 × 90 × 45 × 90 (θh × φh × θd × φd; 16.4 M samples, 131 MB).

For each storage (netCDF as ``write_netcdf`` writes it, at the zlib levels of ``--nc-levels`` and
chunks of ``--nc-chunks`` MiB; zarr with the compressors of
:data:`brdftab.formats.zarr.CODECS` at the levels of ``--codecs`` and chunks of ``--chunks``
MiB, shape ``(1,…,s, whole trailing axes)``), float64 and float32:

1. **write**: ``brdftab.save`` of the table (atomic: the store is fsynced and renamed);
2. **size**: bytes on disk (a store: the sum of its files) and the number of files;
3. **slice**: reading one θh slab (``Table._read(Table._var[i])``: what slab evaluation and
   ``info`` read) — the median over 8 slabs spread over the axis, through a fresh open;
4. **pairs**: ``brdftab.open`` + ``Table.eval`` of 10,000 random pairs (uniform in solid angle):
   a table under 256 MiB is read whole, so this is the time to load it.

Times are the best of ``--repeat`` runs (after one warm-up), with the files in the page cache:
they measure the library's decoding, not the disk.
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import brdftab
from _timing import GOLD, hemisphere_pairs, timeit  # benchmarks/ is on sys.path when run as a script
from brdftab.formats import netcdf as nc_format
from brdftab.formats import zarr as zarr_format
from brdftab.grids import RusinkiewiczGrid, merl_grid


def tables(quick: bool):
    m = brdftab.models
    iso = m.create("microfacet", alpha=0.3, fresnel="conductor", **GOLD)
    aniso = m.create("microfacet", alpha_x=0.2, alpha_y=0.4, fresnel="dielectric", n=1.5)
    if quick:
        return {"iso RGB": brdftab.tabulate(iso, RusinkiewiczGrid(45, 45, 90), progress=False)}
    return {"iso RGB": brdftab.tabulate(iso, merl_grid(), progress=False),
            "aniso grey": brdftab.tabulate(aniso, RusinkiewiczGrid(45, 45, 90, 90), progress=False)}


def size_of(path: Path):
    if path.is_dir():
        files = [p for p in path.rglob("*") if p.is_file()]
        return sum(p.stat().st_size for p in files), len(files)
    return path.stat().st_size, 1


def best(fn, repeat):
    return timeit(fn, repeat)[0]


def measure(table, folder: Path, label: str, ext: str, repeat: int, options: dict, setup=lambda: None):
    path = folder / f"t{ext}"
    setup()

    def write():
        brdftab.save(table, path, overwrite=True, **options)

    t_write = best(write, repeat)
    nbytes, nfiles = size_of(path)
    n0 = table.values.shape[0]
    picks = np.linspace(0, n0 - 1, 8).round().astype(int)

    def one_slice():
        t = brdftab.open(path)
        times = []
        for i in picks:
            t0 = time.perf_counter()
            t._read(t._var[int(i):int(i) + 1])
            times.append(time.perf_counter() - t0)
        return statistics.median(times)

    one_slice()
    t_slice = min(one_slice() for _ in range(repeat))
    wi, wo = hemisphere_pairs(10_000, seed=1)

    def pairs():
        t = brdftab.open(path)
        t.eval(wi, wo)

    t_pairs = best(pairs, repeat)
    back = brdftab.open(path)
    exact = np.array_equal(back.values, table.values.astype(options.get("dtype", "float64")))
    print(f"| {label:<34s} | {t_write:7.2f} | {nbytes / 2**20:8.1f} | {nfiles:5d} | {t_slice * 1e3:8.1f} | "
          f"{t_pairs:7.2f} | {'yes' if exact else 'NO'} |", flush=True)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--dir", default=None, help="folder for the files (default: the system's temporary folder)")
    ap.add_argument("--quick", action="store_true", help="a 45 x 45 x 90 RGB table only, fewer variants")
    ap.add_argument("--dtype", nargs="+", default=["float64", "float32"])
    ap.add_argument("--chunks", nargs="+", type=int, default=[1, 4, 16], help="zarr chunk sizes [MiB]")
    ap.add_argument("--nc-chunks", nargs="+", type=int, default=[2], help="netCDF chunk sizes [MiB]")
    ap.add_argument("--nc-levels", nargs="+", type=int, default=[4], help="netCDF zlib levels")
    ap.add_argument("--codecs", nargs="*", default=["blosc-zstd:5", "blosc-lz4:5", "zstd:1", "zstd:3", "zstd:5",
                                                    "gzip:4"],
                    help="zarr compressors as CODEC:LEVEL (CODEC one of brdftab.formats.zarr.CODECS)")
    args = ap.parse_args(argv)
    print(f"brdftab {brdftab.__version__}, Python {sys.version.split()[0]}, {os.cpu_count()} CPUs, "
          f"load {os.getloadavg()[0]:.2f}")
    chunk_sizes = (4,) if args.quick else tuple(args.chunks)
    variants = [(c, int(level)) for c, level in (v.rsplit(":", 1) for v in args.codecs)]
    for name, table in tables(args.quick).items():
        print(f"\n{name}: {table.grid.describe()}, {table.values.shape[-1]} channel(s), "
              f"{table.values.nbytes / 2**20:.0f} MiB in float64\n")
        print("| storage                            | write s | size MiB | files | slice ms | pairs s | exact |")
        print("|---|---|---|---|---|---|---|")
        for dtype in args.dtype:
            folder = Path(tempfile.mkdtemp(dir=args.dir))
            try:
                for level in args.nc_levels:
                    for mib in args.nc_chunks:
                        saved_nc = nc_format.CHUNK_BYTES

                        def setup_nc(mib=mib):
                            nc_format.CHUNK_BYTES = mib << 20

                        try:
                            measure(table, folder, f"netCDF zlib {level}, {mib} MiB, {dtype}", ".nc", args.repeat,
                                    {"dtype": dtype, "complevel": level}, setup_nc)
                        finally:
                            nc_format.CHUNK_BYTES = saved_nc
                for codec, level in variants:
                    for mib in chunk_sizes:
                        saved = (zarr_format.CODEC, zarr_format.CHUNK_BYTES)

                        def setup(codec=codec, mib=mib):
                            zarr_format.CODEC, zarr_format.CHUNK_BYTES = codec, mib << 20

                        try:
                            measure(table, folder, f"zarr {codec} {level}, {mib} MiB, {dtype}", ".zarr",
                                    args.repeat, {"dtype": dtype, "complevel": level}, setup)
                        finally:
                            zarr_format.CODEC, zarr_format.CHUNK_BYTES = saved
            finally:
                shutil.rmtree(folder, ignore_errors=True)
    print(f"\nload at the end {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
