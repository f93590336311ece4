"""Benchmark: peak memory of tabulating a table and running the default checks on it.

Run from the repository root (Linux: reads and resets the peak resident set size through
``/proc/self/status`` and ``/proc/self/clear_refs``)::

    python benchmarks/bench_check_memory.py            # the three cases below, ~3 min
    python benchmarks/bench_check_memory.py --quick    # the two Rusinkiewicz cases, ~30 s

For each case it prints the table's size and the peak resident memory of the tabulation and
of the checks (``brdftab.checks.run_checks`` with the defaults), above what was resident before
the tabulation, as multiples of the table. ``brdftab.table.CHECKED_PEAK`` (what ``tabulate`` and
``validate`` runs reserve up front) must be at least the largest "total" printed.

Measured on the development machine: total 6.8x (grey, Rusinkiewicz 100000 x 1 x 180),
5.3x (RGB, Rusinkiewicz 300 x 90 x 180), 8.8x (grey, spherical 90 x 1 x 900 x 720).

Then, as multiples of the output array: a tabulation alone (GGX gold, RGB, on the MERL grid)
with float64 and float32 output, against what ``tabulate`` reserves
(``brdftab.table.TABULATE_PEAK`` times the table plus ``CHUNK_OVERHEAD``); and ``model.eval``
(the same model) and ``Table.eval`` (its MERL-grid table) at 10 M random pairs, beyond the
input directions: their goal is at most 2x.
"""

from __future__ import annotations

import argparse

from brdftab import models
from brdftab.checks import run_checks
from brdftab.grids import RusinkiewiczGrid, SphericalGrid, merl_grid
from brdftab.table import CHECKED_PEAK, CHUNK_OVERHEAD, TABULATE_PEAK, tabulate
from _timing import GOLD, hemisphere_pairs  # benchmarks/ is on sys.path when run as a script

import numpy as np


def _status():
    with open("/proc/self/status") as fh:
        d = {line.split(":")[0]: int(line.split()[1]) * 1024 for line in fh if line.startswith(("VmRSS", "VmHWM"))}
    return d["VmRSS"], d["VmHWM"]


def _reset_peak():
    with open("/proc/self/clear_refs", "w") as fh:
        fh.write("5")


def measure(label, model, grid):
    base, _ = _status()
    _reset_peak()
    table = tabulate(model, grid, progress=False)
    _, peak_tab = _status()
    _reset_peak()
    report = run_checks(table, reference=model)
    _, peak_checks = _status()
    nbytes = table.values.nbytes
    print(f"{label:42s} table {nbytes / 2**20:7.1f} MiB  tabulation {(peak_tab - base) / nbytes:4.2f}x  "
          f"total with checks {(peak_checks - base) / nbytes:4.2f}x  ({report.summary()[:40]})", flush=True)
    return (peak_checks - base) / nbytes


def peak(fn):
    """(result of ``fn()``, peak resident memory during it beyond what was resident before)."""
    base, _ = _status()
    _reset_peak()
    out = fn()
    return out, _status()[1] - base


def tabulation_and_eval(model):
    for dtype in ("float64", "float32"):
        table, extra = peak(lambda: tabulate(model, merl_grid(), dtype=dtype, progress=False))
        nbytes = table.values.nbytes
        reserved = TABULATE_PEAK[table.values.itemsize] * nbytes + CHUNK_OVERHEAD
        print(f"tabulation alone, RGB, MERL grid, {dtype}: {extra / nbytes:4.2f}x the table "
              f"({extra / 2**20:.0f} MiB; TABULATE_PEAK x table + CHUNK_OVERHEAD = {reserved / 2**20:.0f} MiB: "
              f"{'OK' if reserved >= extra else 'TOO LOW'})", flush=True)
    wi, wo = hemisphere_pairs(10_000_000)
    for label, brdf in (("model.eval", model), ("Table.eval, MERL grid", table)):
        f, extra = peak(lambda: brdf.eval(wi, wo))
        print(f"{label} at 10 M pairs: {extra / f.nbytes:4.2f}x the output ({f.nbytes / 2**20:.0f} MiB)", flush=True)
        del f


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="only the two Rusinkiewicz cases")
    args = ap.parse_args()
    grey = models.create("lambert", albedo=0.5)
    gold = models.create("microfacet", distribution="ggx", alpha=0.2, fresnel="conductor", **GOLD)
    worst = max(measure("grey, rusinkiewicz 100000 x 1 x 180", grey, RusinkiewiczGrid(100000, 1, 180)),
                measure("RGB, rusinkiewicz 300 x 90 x 180", gold, RusinkiewiczGrid(300, 90, 180)))
    if not args.quick:
        ggx = models.create("microfacet", distribution="ggx", alpha=0.3)
        grid = SphericalGrid(np.radians(np.arange(0, 90.0)), np.array([0.0]), np.radians(np.arange(0, 90, 0.1)),
                             np.radians(np.arange(0, 360, 0.5)))
        worst = max(worst, measure("grey, spherical 90 x 1 x 900 x 720", ggx, grid))
    print(f"largest total {worst:.2f}x; CHECKED_PEAK = {CHECKED_PEAK}: {'OK' if CHECKED_PEAK >= worst else 'TOO LOW'}")
    tabulation_and_eval(gold)


if __name__ == "__main__":
    main()
