"""Benchmark: validating BRDF tables (``brdftab validate``) and validation before export.

Run from the repository root::

    python benchmarks/bench_validate.py [--repeat 3] [--target 2.0]

Measures (wall clock, ``time.perf_counter``, and this process's CPU time,
``time.process_time``, which other processes on a shared machine do not inflate; one warm-up,
then ``--repeat`` runs, best and median):

1. **MERL-grid validation** — the target case: a GGX gold table (α = 0.3, conductor, RGB,
   float32) on the MERL grid (90 × 90 × 180 × 3 = 4,374,000 samples) written to netCDF; each
   run reads the file afresh (as ``brdftab validate FILE`` does) and runs the sample audit
   (finite, non-negative, missing), reciprocity and the 90-angle albedo sweep (energy +
   albedo, θi = 0 … 89°). One more, instrumented run splits the time into reading the
   samples, the table's interpolation set-up on first evaluation, the audit, reciprocity and
   the albedo sweep.
2. The same on a MERL-grid table with 3 % of its samples declared missing (``valid_min``,
   MERL-style negative markers near grazing θd), which the integrals leave out.
3. A Rusinkiewicz table folded by nothing (90 × 90 × 360 × 3): reciprocity on its 4.4 M
   exact node pairs (φd ↔ φd + π) plus audit and sweep.
4. Every default check on the MERL-grid file (adds isotropy, bilateral symmetry, conventions
   and tabulation error against the model in the provenance).
5. Validation before export: ``brdftab tabulate specs/ggx-gold.toml`` through the pipeline
   with every check off and with the default checks; the difference is the added time.

It prints ``target < 2 s: PASS/MISS`` for the median of (1).
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

import brdftab
from brdftab.checks import CHECKS, run_checks
from brdftab.grids import RusinkiewiczGrid, merl_grid
from brdftab.table import Table
from _timing import GOLD  # benchmarks/ is on sys.path when run as a script

TARGET_SET = ("finite", "non-negative", "missing", "reciprocity", "energy", "albedo")
ROOT = Path(__file__).resolve().parent.parent


#: CPU seconds of this process per timed run (wall-clock time on a shared machine also counts
#: the waits for other processes; CPU time does not).
CPU = []


def timeit(fn, repeat):
    fn()
    times = []
    CPU.clear()
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        times.append(time.perf_counter() - t0)
        CPU.append(time.process_time() - c0)
    return min(times), statistics.median(times), times


def report(label, best, median, times=None):
    extra = f"   runs: {', '.join(f'{t:.2f}' for t in times)}" if times else ""
    cpu = f"   CPU median {statistics.median(CPU):6.3f} s" if CPU else ""
    print(f"{label:<58s} best {best:6.3f} s   median {median:6.3f} s{cpu}{extra}")


def validate(path, only=TARGET_SET):
    table = brdftab.open(path)
    r = run_checks(table, only=only, subject=str(path))
    return r


def breakdown(path):
    """One instrumented run: where the time of validating ``path`` goes, (wall, CPU) seconds."""
    out = {}

    def step(label, fn):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        out[label] = (time.perf_counter() - t0, time.process_time() - c0)

    box = {}
    step("read samples", lambda: box.setdefault("t", brdftab.open(path)).values)
    table = box["t"]
    z = np.array([0.0, 0.0, 1.0])
    step("interpolation set-up (first Table.eval)", lambda: table.eval(z, z))
    for label, only in (("audit", ("finite", "non-negative", "missing")), ("reciprocity", ("reciprocity",)),
                        ("albedo sweep (energy + albedo)", ("energy", "albedo"))):
        step(label, lambda only=only: run_checks(table, only=only))
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=3, help="timed repetitions after the warm-up (default 3)")
    ap.add_argument("--target", type=float, default=2.0, help="target seconds for the MERL-grid validation")
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")

    print(f"brdftab {brdftab.__version__}, numpy {np.__version__}, Python {platform.python_version()}, "
          f"{platform.machine()}, {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f}")
    ggx = brdftab.models.create("microfacet", distribution="ggx", alpha=0.3, fresnel="conductor", **GOLD)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        merl = tmp / "gold-merl.nc"
        brdftab.save(ggx, merl, grid=merl_grid(), dtype="float32")

        # 2. the same with declared missing samples (MERL-style negative markers near grazing θd)
        t = brdftab.open(merl)
        ds = t.ds.load()
        v = ds["brdf"].values
        rng = np.random.default_rng(0)
        grazing = np.zeros(v.shape[:-1], bool)
        grazing[:, 84:, :] = rng.random(grazing[:, 84:, :].shape) < 0.5
        v[grazing] = -1.0
        ds["brdf"].attrs["valid_min"] = 0.0
        holes = tmp / "gold-merl-missing.nc"
        brdftab.save(Table(ds), holes, dtype="float32")
        frac = grazing.mean()

        # 3. a table folded by nothing: exact node pairs for reciprocity
        none = tmp / "gold-none.nc"
        brdftab.save(ggx, none, grid=RusinkiewiczGrid(90, 90, 360, theta_h_spacing="merl", phi_d_fold="none"),
                     dtype="float32")

        print(f"table: {merl_grid().describe()} x 3 channels (float32 netCDF), model {ggx.describe()}")
        print(f"checks timed: {', '.join(TARGET_SET)} (energy + albedo share one 90-angle sweep)")
        print(f"warm-up 1 + {args.repeat} repetitions; each run reads the file afresh\n")

        best, median, times = timeit(lambda: validate(merl), args.repeat)
        report("1. MERL grid: audit + reciprocity + 90-angle albedo", best, median, times)
        target_median, target_cpu = median, statistics.median(CPU)
        for label, (wall, cpu) in breakdown(merl).items():
            print(f"     {label:<50s} {wall:6.3f} s wall {cpu:6.3f} s CPU")
        r = validate(merl)
        assert r.passed, r.summary()

        best, median, times = timeit(lambda: validate(holes), args.repeat)
        report(f"2. the same, {100 * frac:.1f} % of samples missing", best, median, times)
        r = validate(holes)
        e = r.get("energy")
        print(f"     missing: {r.get('missing').detail.split(';')[0]}")
        print(f"     energy:  max a = {e.figure:.4f}, coverage >= {100 * e.data['coverage_min']:.1f} %")

        best, median, times = timeit(lambda: validate(none), args.repeat)
        report("3. phi_d_fold = none, 90x90x360: node-pair reciprocity", best, median, times)
        print(f"     {validate(none).get('reciprocity').detail}")

        best, median, times = timeit(lambda: validate(merl, only=tuple(CHECKS)), args.repeat)
        report("4. MERL grid: every default check", best, median, times)

        # 5. validation before export
        from brdftab.pipeline import run
        from brdftab.spec import load_spec

        spec = load_spec(ROOT / "specs" / "ggx-gold.toml")
        off = {n: {"level": "off"} for n in CHECKS}
        b_off, m_off, _ = timeit(lambda: run(spec, out_dir=tmp, overwrite=True, progress=False, checks=off),
                                 args.repeat)
        c_off = statistics.median(CPU)
        report("5. tabulate specs/ggx-gold.toml, checks off", b_off, m_off)
        b_on, m_on, _ = timeit(lambda: run(spec, out_dir=tmp, overwrite=True, progress=False), args.repeat)
        c_on = statistics.median(CPU)
        report("   tabulate specs/ggx-gold.toml, default checks", b_on, m_on)
        print(f"     added by validation before export: {m_on - m_off:.3f} s (median wall), "
              f"{b_on - b_off:.3f} s (best wall), {c_on - c_off:.3f} s (median CPU)")

    status = "PASS" if target_median < args.target else "MISS"
    print(f"\ntarget < {args.target:g} s: {status} (MERL-grid validation, median {target_median:.3f} s wall, "
          f"{target_cpu:.3f} s CPU)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
