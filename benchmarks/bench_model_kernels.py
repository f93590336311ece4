"""Benchmark: compiled vs numpy evaluation of the HTSG and Zernike models, against the numpy floor.

Run from the repository root::

    python benchmarks/bench_model_kernels.py [--pairs 150000] [--repeat 9]

At random upper-hemisphere pairs, in one run: the numpy floor ``h = normalize(wi + wo)``,
then for ``he-torrance-1991`` (the Pyromark spec, cone), ``he-torrance-modified`` (its spec),
``zernike-expansion`` (the shipped PTFE spec and the synthetic test file) the rate of
``model.eval`` inside :func:`brdftab.brdf.numpy_reference` and compiled, in million pairs per
second, and the compiled time as a multiple of the floor's: the median over rounds that
alternate the floor and the model (the machine may be shared).
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np

import brdftab
from brdftab.brdf import numpy_reference

ROOT = Path(__file__).resolve().parents[1]


def best(fn, repeat):
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", type=int, default=150000)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--rounds", type=int, default=5)
    args = ap.parse_args(argv)
    rng = np.random.default_rng(1)

    def upper(k):
        v = rng.normal(size=(k, 3))
        v[:, 2] = np.abs(v[:, 2])
        return v / np.linalg.norm(v, axis=1, keepdims=True)

    n = args.pairs
    wi, wo = upper(n), upper(n)

    def floor():
        h = wi + wo
        return h / np.linalg.norm(h, axis=1, keepdims=True)

    cases = [("he-torrance-1991, pyromark-he-torrance.toml",
              brdftab.from_spec(ROOT / "specs" / "pyromark-he-torrance.toml")),
             ("he-torrance-modified, pyromark-modified-ht.toml",
              brdftab.from_spec(ROOT / "specs" / "pyromark-modified-ht.toml")),
             ("zernike-expansion, ptfe-zernike.toml", brdftab.from_spec(ROOT / "specs" / "ptfe-zernike.toml")),
             ("zernike-expansion, synthetic file",
              brdftab.models.create("zernike-expansion",
                                    coefficients=str(ROOT / "tests" / "data" / "zernike-synthetic.coeff.csv")))]
    for _, m in cases:
        m.eval(wi[:1000], wo[:1000])  # compiles, or loads the compiled kernel from the cache
    print(f"{n:,} pairs; each figure the median of {args.rounds} rounds, a round alternating the floor and the "
          f"model (best of {args.repeat} runs each)")
    floors = []
    for label, m in cases:
        with numpy_reference():
            t_np = best(lambda m=m: m.eval(wi, wo), 2)
        rates, ratios = [], []
        for _ in range(args.rounds):
            t_floor = best(floor, args.repeat)
            t_c = best(lambda m=m: m.eval(wi, wo), args.repeat)
            floors.append(n / t_floor / 1e6)
            rates.append(n / t_c / 1e6)
            ratios.append(t_c / t_floor)
        print(f"{label:<48s} numpy {n / t_np / 1e6:7.3f}  compiled {statistics.median(rates):7.3f} M pairs/s;  "
              f"compiled time = {statistics.median(ratios):5.2f} x floor")
    print(f"numpy floor h = normalize(wi + wo): {statistics.median(floors):.1f} M pairs/s (median)")

if __name__ == "__main__":
    main()
