"""Timing helper shared by the benchmark scripts (run them from the repository root)."""

from __future__ import annotations

import statistics
import time

#: Complex refractive index of gold at R, G, B (Mitsuba's "Au" values) used by several benchmarks.
GOLD = dict(n=[0.143119, 0.374957, 1.44248], k=[3.98316, 2.38572, 1.60322])


def timeit(fn, repeat):
    """Warm up once, then time ``repeat`` calls; returns (best, median, list of times) [s]."""
    fn()
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times), statistics.median(times), times
