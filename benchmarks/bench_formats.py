"""Benchmark: reading and writing MERL ``.binary`` files (and EXR slices), against copying the bytes.

Run from the repository root::

    python benchmarks/bench_formats.py [--repeat 5] [--dir /tmp]

Measures (wall-clock, ``time.perf_counter``; one warm-up run first, then ``--repeat`` runs,
reporting the best and the median), on a MERL file of GGX (α = 0.3, conductor Fresnel of
gold) and on a MERL file of arbitrary float64 bit patterns (the worst case for the exact
round trip: NaN payloads, subnormals and values whose scaling is not invertible):

1. **floor**: ``shutil.copyfile`` of the same 34,992,012 bytes, and a NumPy read + write of
   them (``np.fromfile`` / ``ndarray.tofile``): what any reader or writer pays for the I/O;
2. ``brdftab.open`` of the MERL file (header and size checks, scaling, the ulp correction
   and its checksum);
3. writing that table back to MERL (``brdftab.save``: checksum, division, write);
4. MERL → netCDF (float64) → MERL, end to end, and whether the result is byte-identical,
   with the netCDF write and read alone for comparison;
5. writing the MERL table as a 180-part EXR and reading it back.

Each brdftab figure is printed with its ratio to the plain copy. Files go to a temporary
folder under ``--dir`` (default: the system's) and are removed afterwards.
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import struct
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import brdftab
from _timing import GOLD, timeit  # benchmarks/ is on sys.path when run as a script




def report(label, best, median, floor=None):
    ratio = f"   {best / floor:6.1f}x copy" if floor else ""
    print(f"{label:<44s} best {best:7.3f} s   median {median:7.3f} s{ratio}")


def save(brdf, path, **options):
    brdftab.save(brdf, path, overwrite=True, **options)


def bench_file(label, src: Path, work: Path, repeat: int, copy_best: float):
    print(f"\n{label}: {src.stat().st_size:,} bytes")
    table = brdftab.open(src)
    corr = table.ds.get("merl_raw_ulp_correction")
    needed = "none needed" if corr is None else f"{int((corr.values != 0).sum()):,} samples ({corr.dtype})"
    print(f"  ulp corrections: {needed}")
    best, median, _ = timeit(lambda: brdftab.open(src).values, repeat)
    report("  read MERL (brdftab.open)", best, median, copy_best)
    out = work / "out.binary"
    best, median, _ = timeit(lambda: save(table, out), repeat)
    report("  write MERL (brdftab.save of the table)", best, median, copy_best)
    nc, back = work / "t.nc", work / "back.binary"

    def round_trip():
        save(brdftab.open(src), nc)
        save(brdftab.open(nc), back)

    best, median, _ = timeit(round_trip, repeat)
    report("  MERL -> netCDF -> MERL", best, median, copy_best)
    best, median, _ = timeit(lambda: save(table, nc), repeat)
    report("    of which: netCDF write (zlib level 4)", best, median, copy_best)
    best, median, _ = timeit(lambda: brdftab.open(nc).values, repeat)
    report("    of which: netCDF read", best, median, copy_best)
    same = back.read_bytes() == src.read_bytes()
    print(f"  round trip byte-identical: {same}; netCDF size {nc.stat().st_size:,} bytes")
    return table, same


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=5, help="timed repetitions after the warm-up (default 5)")
    ap.add_argument("--dir", default=None, help="folder for the temporary files (default: the system's)")
    args = ap.parse_args(argv)

    print(f"brdftab {brdftab.__version__}, numpy {np.__version__}, Python {platform.python_version()}, "
          f"{platform.machine()}, {os.cpu_count()} CPUs")
    print(f"warm-up 1 + {args.repeat} repetitions each")
    ok = True
    with tempfile.TemporaryDirectory(dir=args.dir) as tmp:
        work = Path(tmp)
        ggx = brdftab.models.create("microfacet", alpha=0.3, fresnel="conductor", **GOLD)
        model_file = work / "ggx.binary"
        t0 = time.perf_counter()
        save(ggx, model_file)
        print(f"tabulate + write GGX to MERL (once, cold):    {time.perf_counter() - t0:7.3f} s")

        rng = np.random.default_rng(0)
        raw = rng.integers(0, 2**64, size=3 * 90 * 90 * 180, dtype=np.uint64).view(np.float64)
        raw[rng.integers(0, raw.size, 100_000)] = -1.0
        bits_file = work / "bits.binary"
        with open(bits_file, "wb") as fh:
            fh.write(struct.pack("<3i", 90, 90, 180))
            fh.write(raw.astype("<f8").tobytes())
        del raw

        copy_to = work / "copy.binary"
        c_best, c_median = timeit(lambda: shutil.copyfile(model_file, copy_to), args.repeat)
        print()
        report("floor: shutil.copyfile of the bytes", c_best, c_median)

        def numpy_rw():
            a = np.fromfile(model_file, "<f8", offset=12)
            with open(copy_to, "wb") as fh:
                fh.write(model_file.read_bytes()[:12])
                a.tofile(fh)

        n_best, n_median = timeit(numpy_rw, args.repeat)
        report("floor: np.fromfile + tofile", n_best, n_median, c_best)

        table, same1 = bench_file("GGX file", model_file, work, args.repeat, c_best)
        _, same2 = bench_file("arbitrary-bits file", bits_file, work, args.repeat, c_best)
        ok = same1 and same2

        exr = work / "t.exr"
        print()
        best, median, _ = timeit(lambda: save(table, exr), args.repeat)
        report("write EXR (180 parts, float32)", best, median, c_best)
        best, median, _ = timeit(lambda: brdftab.open(exr).values, args.repeat)
        report("read EXR", best, median, c_best)
        print(f"EXR size {exr.stat().st_size:,} bytes")
    print(f"\nbyte-identical round trips: {'PASS' if ok else 'FAIL'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
