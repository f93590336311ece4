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
"""

from __future__ import annotations

import argparse

from brdftab import models
from brdftab.checks import run_checks
from brdftab.grids import RusinkiewiczGrid, SphericalGrid
from brdftab.table import CHECKED_PEAK, tabulate

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


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="only the two Rusinkiewicz cases")
    args = ap.parse_args()
    grey = models.create("lambert", albedo=0.5)
    gold = models.create("microfacet", distribution="ggx", alpha=0.2, fresnel="conductor",
                         n=[0.143119, 0.374957, 1.44248], k=[3.98316, 2.38572, 1.60322])
    worst = max(measure("grey, rusinkiewicz 100000 x 1 x 180", grey, RusinkiewiczGrid(100000, 1, 180)),
                measure("RGB, rusinkiewicz 300 x 90 x 180", gold, RusinkiewiczGrid(300, 90, 180)))
    if not args.quick:
        ggx = models.create("microfacet", distribution="ggx", alpha=0.3)
        grid = SphericalGrid(np.radians(np.arange(0, 90.0)), np.array([0.0]), np.radians(np.arange(0, 90, 0.1)),
                             np.radians(np.arange(0, 360, 0.5)))
        worst = max(worst, measure("grey, spherical 90 x 1 x 900 x 720", ggx, grid))
    print(f"largest total {worst:.2f}x; CHECKED_PEAK = {CHECKED_PEAK}: {'OK' if CHECKED_PEAK >= worst else 'TOO LOW'}")


if __name__ == "__main__":
    main()
