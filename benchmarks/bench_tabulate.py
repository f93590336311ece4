"""Benchmark: tabulating an analytic BRDF on the MERL grid, and interpolating a table.

Run from the repository root::

    python benchmarks/bench_tabulate.py [--repeat 5] [--target 0.5]

Measures (wall-clock, ``time.perf_counter``; one warm-up run first, then ``--repeat`` runs,
reporting the best and the median):

1. ``brdftab.tabulate`` of GGX (α = 0.3, conductor Fresnel, 3 RGB channels) on
   ``merl_grid()`` (90 × 90 × 180 = 1,458,000 direction pairs → 4,374,000 values);
2. a *floor*: trivial NumPy passes over the same number of elements — the half-vector
   normalization of 1,458,000 pairs and ``np.exp`` over 4,374,000 doubles — and the ratio
   of (1) to them;
3. peak memory of one tabulation beyond what was allocated before it (``tracemalloc``,
   separate untimed run), compared with the size of the output array;
4. the same tabulation for the Lambert model (evaluation cost ~ 0: grid + bookkeeping);
5. evaluating the GGX table (multilinear interpolation) at 1e6 random direction pairs.

It prints ``target < 0.5 s: PASS/MISS`` for the median GGX tabulation time.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tracemalloc

import numpy as np

import brdftab
from brdftab.grids import merl_grid
from _timing import GOLD, timeit  # benchmarks/ is on sys.path when run as a script




def peak_extra_bytes(fn):
    """Peak traced allocation during ``fn()`` beyond the allocations alive before it."""
    tracemalloc.start()
    try:
        base, _ = tracemalloc.get_traced_memory()
        tracemalloc.reset_peak()
        result = fn()
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return peak - base, result


def mb(nbytes):
    return f"{nbytes / 2**20:.1f} MiB"


def report(label, best, median, count, unit="evaluations"):
    print(f"{label:<46s} best {best:7.3f} s   median {median:7.3f} s   "
          f"{count / best / 1e6:8.1f} M {unit}/s (best)")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=5, help="timed repetitions after the warm-up (default 5)")
    ap.add_argument("--target", type=float, default=0.5, help="target seconds for the GGX tabulation (default 0.5)")
    ap.add_argument("--interp-pairs", type=int, default=1_000_000, help="pairs for the table interpolation timing")
    args = ap.parse_args(argv)

    grid = merl_grid()
    ggx = brdftab.models.create("microfacet", distribution="ggx", alpha=0.3, fresnel="conductor", **GOLD)
    lambert = brdftab.models.create("lambert", albedo=[0.2, 0.5, 0.8])
    n_pairs = grid.size
    n_chan = len(ggx.channels)
    n_values = n_pairs * n_chan
    assert n_pairs == 1_458_000 and n_chan == 3

    print(f"brdftab {brdftab.__version__}, numpy {np.__version__}, Python {platform.python_version()}, "
          f"{platform.machine()}, {os.cpu_count()} CPUs")
    print(f"grid: {grid.describe()} = {n_pairs:,} pairs x {n_chan} channels = {n_values:,} values")
    print(f"model: {ggx.describe()}")
    print(f"warm-up 1 + {args.repeat} repetitions each\n")

    # 1. GGX tabulation
    table_box = {}

    def tab_ggx():
        table_box["t"] = brdftab.tabulate(ggx, grid, progress=False)

    best, median, times = timeit(tab_ggx, args.repeat)
    report("tabulate GGX+conductor on MERL grid", best, median, n_values)
    print(f"{'':46s} all runs: {', '.join(f'{t:.3f}' for t in times)} s")
    table = table_box["t"]
    assert table.values.shape == (90, 90, 180, 3) and np.all(np.isfinite(table.values))
    ggx_best, ggx_median = best, median

    # 2. floor: trivial numpy passes over the same number of elements
    rng = np.random.default_rng(0)
    wi = rng.normal(size=(n_pairs, 3))
    wo = rng.normal(size=(n_pairs, 3))
    x = rng.uniform(-1.0, 1.0, n_values)

    def half_vectors():
        h = wi + wo
        h /= np.sqrt(np.einsum("ij,ij->i", h, h))[:, None]
        return h

    f_best, f_median, _ = timeit(half_vectors, args.repeat)
    report("floor: half-vector normalization (pairs)", f_best, f_median, n_pairs, unit="pairs")
    e_best, e_median, _ = timeit(lambda: np.exp(x), args.repeat)
    report("floor: np.exp over 4,374,000 doubles", e_best, e_median, n_values, unit="values")
    print(f"ratio tabulate / half-vector floor: {ggx_best / f_best:6.1f}x (best), "
          f"{ggx_median / f_median:6.1f}x (median)")
    print(f"ratio tabulate / np.exp floor:      {ggx_best / e_best:6.1f}x (best), "
          f"{ggx_median / e_median:6.1f}x (median)")
    del wi, wo, x

    # 3. memory of one tabulation (untimed: tracemalloc slows allocation down)
    out_bytes = n_values * np.dtype("float64").itemsize
    del table_box["t"], table
    extra, t = peak_extra_bytes(lambda: brdftab.tabulate(ggx, grid, progress=False))
    print(f"\npeak extra memory of one tabulation: {mb(extra)} (tracemalloc); output array {mb(out_bytes)}; "
          f"temporaries beyond the output {mb(extra - out_bytes)} ({extra / out_bytes:.2f}x output)")
    table = t
    del t

    # 4. Lambert (evaluation nearly free: the cost of the grid and the chunk loop)
    l_best, l_median, _ = timeit(lambda: brdftab.tabulate(lambert, grid, progress=False), args.repeat)
    print()
    report("tabulate Lambert on MERL grid", l_best, l_median, n_values)

    # 5. table interpolation at random pairs
    m = args.interp_pairs
    c = rng.uniform(0.0, 1.0, (2, m))
    phi = rng.uniform(-np.pi, np.pi, (2, m))
    s = np.sqrt(1.0 - c * c)
    dirs = np.stack([s * np.cos(phi), s * np.sin(phi), c], axis=-1)
    q_wi, q_wo = dirs[0], dirs[1]
    i_best, i_median, _ = timeit(lambda: table.eval(q_wi, q_wo), args.repeat)
    report(f"Table.eval (interpolation) at {m:,} pairs", i_best, i_median, m * n_chan)

    status = "PASS" if ggx_median < args.target else "MISS"
    print(f"\ntarget < {args.target:g} s: {status} (GGX tabulation, median {ggx_median:.3f} s, best {ggx_best:.3f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
