"""Benchmark: a 5-parameter fit (``brdftab.fit``, default settings) to a MERL-grid table.

The table: a Lambert + two GGX lobes (Schlick) tabulated on the MERL grid (90 × 90 × 180,
grey) with 1 % multiplicative noise; the fit frees the Lambert albedo and each lobe's α and
f0, starting from values off by factors of 2 (the two lobes are interchangeable: the
parameters are compared with the truth lobe by lobe, narrower lobe first). Prints the wall time of the fit (16 starts on
20 000 samples, refine on 200 000), its CPU time (steadier on a shared machine), the load
average, and how close the parameters came.

Then Bitterling's Cook–Torrance fit (``specs/pyromark-cook-torrance.toml``: 6 parameters) from
the centres of the bounds, on the spec's own 90 × 90 × 360 grid.

Run from the repository root::

    python benchmarks/bench_fit.py [--starts 16] [--repeat 3]
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import sys
import time

import numpy as np

import brdftab
from brdftab.grids import merl_grid
from brdftab.table import tabulate

TRUTH = {"terms.0.albedo": 0.2, "terms.1.alpha": 0.08, "terms.1.f0": 0.5, "terms.2.alpha": 0.35,
         "terms.2.f0": 0.1}


def model(values):
    return {"name": "sum", "terms": [
        {"name": "lambert", "albedo": values["terms.0.albedo"]},
        {"name": "microfacet", "alpha": values["terms.1.alpha"], "fresnel": "schlick", "f0": values["terms.1.f0"]},
        {"name": "microfacet", "alpha": values["terms.2.alpha"], "fresnel": "schlick", "f0": values["terms.2.f0"]},
    ]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--starts", type=int, default=16)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args(argv)

    from brdftab.spec import build_model

    truth = build_model(model(TRUTH), "model", "truth")
    t0 = time.perf_counter()
    table = tabulate(truth, merl_grid())
    t_tab = time.perf_counter() - t0
    rng = np.random.default_rng(1)
    table.values[...] *= 1.0 + 0.01 * rng.standard_normal(table.values.shape)
    start = model({"terms.0.albedo": 0.4, "terms.1.alpha": 0.16, "terms.1.f0": 0.25, "terms.2.alpha": 0.7,
                   "terms.2.f0": 0.2})
    print(f"table: {table.grid.describe()}, {table.values.size:,} samples (tabulated in {t_tab:.2f} s)")
    brdftab.fit(table, start, free=list(TRUTH), starts=2, albedo=False)  # warm-up: compile the kernels
    times, cpu = [], []
    for _ in range(args.repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        result = brdftab.fit(table, start, free=list(TRUTH), starts=args.starts, albedo=False)
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    got = dict(result.parameters)
    if got["terms.1.alpha"] > got["terms.2.alpha"]:  # the two lobes are interchangeable: compare by α
        for key in ("alpha", "f0"):
            got[f"terms.1.{key}"], got[f"terms.2.{key}"] = got[f"terms.2.{key}"], got[f"terms.1.{key}"]
    worst = max(abs(got[k] / v - 1) for k, v in TRUTH.items())
    print(f"5-parameter fit, {args.starts} starts: median {statistics.median(times):.2f} s "
          f"(runs {', '.join(f'{t:.2f}' for t in times)} s), CPU {statistics.median(cpu):.2f} s; "
          f"load average {os.getloadavg()[0]:.2f}; residual {result.residual:.4g}; "
          f"largest parameter error {worst:.2%}")
    # Bitterling's Cook-Torrance fit (6 parameters) from the centres of the bounds, on its spec's grid
    spec = brdftab.load_spec("specs/pyromark-cook-torrance.toml")
    table = tabulate(spec.model, spec.grid)
    cls = brdftab.models.get("cook-torrance-alpha-theta")
    truth = {"n": 1.43, "r_dh_lam": 0.0110, "p1": 0.1012, "p2": 2.661, "p3_deg": 51.51, "p4": 0.2199}
    start = {p.spec_key: (math.degrees(0.5 * (p.minimum + p.maximum)) if p.angle else 0.5 * (p.minimum + p.maximum))
             for p in cls.params if p.spec_key in truth}
    t0, c0 = time.perf_counter(), time.process_time()
    result = brdftab.fit(table, "cook-torrance-alpha-theta", free=list(truth), params=start, starts=args.starts,
                         albedo=False)
    wall, cpu_s = time.perf_counter() - t0, time.process_time() - c0
    worst = max(abs(result.parameters[k] / v - 1) for k, v in truth.items())
    print(f"Bitterling's Cook-Torrance, 6 parameters from the bounds' centres on {table.grid.describe()}, "
          f"{args.starts} starts: {wall:.2f} s, CPU {cpu_s:.2f} s; load average {os.getloadavg()[0]:.2f}; "
          f"largest parameter error {worst:.2g}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
