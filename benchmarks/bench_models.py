"""Benchmark: the seed models tabulated on the MERL grid, and each shipped spec end to end.

Run from the repository root::

    python benchmarks/bench_models.py [--repeat 3] [--skip-specs]

Measures (wall clock, one warm-up then ``--repeat`` runs, best and median):

1. ``brdftab.tabulate(model, merl_grid())`` — 1,458,000 direction pairs — for every seed
   model with the parameters of its spec (Torrance–Sparrow 1967, the Small 2021 solar cell,
   Cook–Torrance α(θi), He–Torrance 1991 with the delta and with the cone, the modified
   He–Torrance, the Zernike expansion, the pyramid microfacet model when registered), with
   the evaluation rate in million pairs per second. A model whose spec uses another grid is
   still timed on the MERL grid (with the reciprocity fold relaxed: ``phi_d_fold = "none"``
   on a 90 × 90 × 180 Rusinkiewicz grid for non-reciprocal models), so the figures compare;
2. unless ``--skip-specs``: ``brdftab tabulate`` and ``brdftab validate`` of every spec in
   ``specs/`` as a subprocess (what a user waits for, checks and writing included), into a
   temporary folder.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import brdftab
from brdftab.grids import RusinkiewiczGrid, merl_grid
from _timing import timeit  # benchmarks/ is on sys.path when run as a script

ROOT = Path(__file__).resolve().parents[1]
SPECS = ROOT / "specs"


def seed_models():
    """(label, model) for each seed model, built from its spec's [model] table."""
    out = []
    for path in sorted(SPECS.glob("*.toml")):
        if path.stem in ("ggx-gold", "lambert-white"):
            continue
        try:
            out.append((path.stem, brdftab.from_spec(path)))
        except brdftab.BrdftabError as exc:  # a spec whose model is not registered in this checkout
            print(f"{path.stem}: skipped ({exc})")
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--skip-specs", action="store_true")
    args = ap.parse_args(argv)
    n = merl_grid().size
    print(f"python {sys.version.split()[0]}, brdftab {brdftab.__version__}; {n:,} direction pairs per table")
    for label, model in seed_models():
        grid = merl_grid() if model.reciprocal and model.isotropic else RusinkiewiczGrid(
            90, 90, 180, None if model.isotropic else 4, theta_h_spacing="merl", phi_d_fold="none")
        pairs = grid.size
        best, median, _ = timeit(lambda: brdftab.tabulate(model, grid, progress=False), args.repeat)
        print(f"{label:<28s} {model.name:<26s} best {best:7.2f} s  median {median:7.2f} s  "
              f"{pairs / best / 1e6:6.2f} M pairs/s")
    if args.skip_specs:
        return
    print("end to end (subprocess, checks and writing included):")
    with tempfile.TemporaryDirectory() as tmp:
        for path in sorted(SPECS.glob("*.toml")):
            work = Path(tmp) / path.stem
            work.mkdir()
            for f in SPECS.iterdir():
                if f.suffix in (".toml", ".csv"):
                    shutil.copy(f, work)
            for verb in ("tabulate", "validate"):
                start = time.perf_counter()
                proc = subprocess.run([sys.executable, "-m", "brdftab", verb, str(work / path.name)],
                                      capture_output=True, text=True)
                took = time.perf_counter() - start
                print(f"  brdftab {verb:<8s} {path.name:<36s} {took:6.1f} s  exit {proc.returncode}")


if __name__ == "__main__":
    main()
