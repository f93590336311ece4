"""Helpers shared by the benchmark scripts (run them from the repository root)."""

from __future__ import annotations

import statistics
import time

import numpy as np

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


def hemisphere_pairs(n, seed=0):
    """``n`` direction pairs (wi, wo), each uniform over the upper hemisphere's solid angle,
    as float64 arrays of shape (n, 3)."""
    rng = np.random.default_rng(seed)

    def dirs():
        c = rng.uniform(0.0, 1.0, n)
        phi = rng.uniform(-np.pi, np.pi, n)
        s = np.sqrt(1.0 - c * c)
        return np.stack([s * np.cos(phi), s * np.sin(phi), c], axis=-1)

    return dirs(), dirs()
