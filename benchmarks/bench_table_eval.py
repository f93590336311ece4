"""Benchmark: ``Table.eval`` on a MERL-grid RGB GGX table and ``brdftab.open(f).eval`` of an RGL
``.bsdf`` file, in pairs/s, with Mitsuba 3's ``measured`` BSDF on the same file as the anchor
(when its LLVM variant loads), and the peak memory of ``Table.eval`` against its output.

Run from the repository root::

    python benchmarks/bench_table_eval.py [--pairs 1000000] [--rounds 5] [--no-mitsuba] [--memory]

Ratios are medians over rounds that alternate ours and Mitsuba's (the machine's load swings).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np

import brdftab
from brdftab.grids import merl_grid
from brdftab.table import tabulate

GOLD = dict(n=[0.143119, 0.374957, 1.44248], k=[3.98316, 2.38572, 1.60322])


def pairs(m, seed=1):
    rng = np.random.default_rng(seed)

    def hemi(k):
        u1, u2 = rng.random(k), rng.random(k)
        z = u1  # uniform in solid angle over the upper hemisphere
        r = np.sqrt(1 - z * z)
        return np.stack([r * np.cos(2 * np.pi * u2), r * np.sin(2 * np.pi * u2), z], axis=-1)

    return hemi(m), hemi(m)


def ggx_model():
    return brdftab.models.create("microfacet", alpha=0.3, fresnel="conductor", **GOLD)


def mitsuba_measured(path):
    os.environ.setdefault("DRJIT_LIBLLVM_PATH", "/usr/lib/x86_64-linux-gnu/libLLVM-19.so")
    import mitsuba as mi

    mi.set_variant("llvm_ad_rgb")
    bsdf = mi.load_dict({"type": "measured", "filename": str(path)})

    def run(wi, wo):
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(wi[:, 0], wi[:, 1], wi[:, 2])
        ctx = mi.BSDFContext()
        return np.array(bsdf.eval(ctx, si, mi.Vector3f(wo[:, 0], wo[:, 1], wo[:, 2])))

    return run


def timed(fn, *args):
    t0 = time.perf_counter()
    fn(*args)
    return time.perf_counter() - t0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--pairs", type=int, default=1_000_000)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--no-mitsuba", action="store_true")
    ap.add_argument("--memory", action="store_true", help="also measure peak memory on 10 M pairs")
    args = ap.parse_args(argv)
    m = args.pairs
    wi, wo = pairs(m)
    wi32, wo32 = wi.astype(np.float32), wo.astype(np.float32)
    table = tabulate(ggx_model(), merl_grid(), progress=False)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "ggx.bsdf"
        brdftab.save(ggx_model(), path, overwrite=True)
        rgl = brdftab.open(path)
        mits = None
        if not args.no_mitsuba:
            try:
                mits = mitsuba_measured(path)
                mits(wi32[:1000], wo32[:1000])
            except Exception as exc:  # noqa: BLE001 - the anchor is optional
                print(f"mitsuba anchor unavailable: {exc}")
                mits = None
        table.eval(wi[:1000], wo[:1000])
        rgl.eval(wi[:1000], wo[:1000])
        rows = {"table": [], "rgl": [], "mitsuba": []}
        for _ in range(args.rounds):
            rows["table"].append(timed(table.eval, wi, wo))
            if mits is not None:
                rows["mitsuba"].append(timed(mits, wi32, wo32))
            rows["rgl"].append(timed(rgl.eval, wi, wo))
            if mits is not None:
                rows["mitsuba"].append(timed(mits, wi32, wo32))
        print(f"{m} random upper-hemisphere pairs, {args.rounds} rounds, median")
        med = {k: statistics.median(v) for k, v in rows.items() if v}
        for k, t in med.items():
            ratio = f"   {med['mitsuba'] / t:.3f}x Mitsuba measured" if "mitsuba" in med and k != "mitsuba" else ""
            print(f"{k:10s} {m / t / 1e6:8.2f} M pairs/s{ratio}")
    if args.memory:
        n = 10_000_000
        wi, wo = pairs(n, seed=2)
        table.eval(wi[:10], wo[:10])
        tracemalloc.start()
        out = table.eval(wi, wo)
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        print(f"Table.eval on {n} pairs: peak {peak / 2**20:.1f} MiB, output {out.nbytes / 2**20:.1f} MiB, "
              f"ratio {peak / out.nbytes:.2f}")


if __name__ == "__main__":
    sys.exit(main())
