"""Benchmark: exporting an analytic BRDF as a Mitsuba 3 / RGL ``.bsdf`` file, and reading it back.

Run from the repository root::

    python benchmarks/bench_rgl.py [--repeat 5] [--target 0.5]

Measures (wall-clock, ``time.perf_counter``; one warm-up run first, then ``--repeat`` runs,
reporting the best and the median):

1. ``brdftab.save(model, "x.bsdf")`` of the RGL recipe model (GGX α = 0.3 with Schlick
   F0 = (0.9, 0.6, 0.3) and height-correlated G2, plus Lambert (0.05, 0.1, 0.2)) as an
   isotropic RGB file with 9 θi and 32 × 32 samples per θi (ndf/sigma 2 × 128, vndf 64 × 64):
   the whole export, including the atomic write;
2. its parts: the ndf and sigma tables (with the back-scattering bound); the vndf tables and
   their Marginal2D warp; warping the 9 × 32 × 32 sample nodes and evaluating the model there;
   encoding the tensor file;
3. the same export with the NDF taken from the back-scattering (power iteration) instead of
   the model's D, and an anisotropic export (17 φi × 9 θi, ndf/sigma 256 × 128);
4. reading the file back and evaluating it (the reader's VNDF inversion) at 1e5 random pairs.

It prints ``target < 0.5 s: PASS/MISS`` for the median of (1).
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
from pathlib import Path

import numpy as np

import brdftab
from brdftab.formats import _rgl_write, rgl
from brdftab.formats._marginal2d import Marginal2D
from brdftab.formats._tensor import encode_tensor
from _timing import hemisphere_pairs, timeit  # benchmarks/ is on sys.path when run as a script



def report(label, best, median, extra=""):
    print(f"{label:<52s} best {best * 1e3:8.1f} ms   median {median * 1e3:8.1f} ms{extra}")


def recipe_model():
    c = brdftab.models.create
    return c("sum", terms=[
        c("lambert", albedo=[0.05, 0.1, 0.2]),
        c("microfacet", alpha=0.3, fresnel="schlick", f0=[0.9, 0.6, 0.3], shadowing="smith-height-correlated"),
    ])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=5, help="timed repetitions after the warm-up (default 5)")
    ap.add_argument("--target", type=float, default=0.5, help="target seconds for the isotropic export (default 0.5)")
    ap.add_argument("--eval-pairs", type=int, default=100_000, help="pairs for the reader's evaluation timing")
    args = ap.parse_args(argv)

    model = recipe_model()
    opts = dict(n_theta_i=9, resolution=32)
    print(f"brdftab {brdftab.__version__}, numpy {np.__version__}, Python {platform.python_version()}, "
          f"{platform.machine()}, {os.cpu_count()} CPUs")
    print(f"model: {model.describe()}")
    print("file: isotropic RGB, 9 theta_i x 32x32 samples, ndf/sigma 2x128, vndf 64x64")
    print(f"warm-up 1 + {args.repeat} repetitions each\n")

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "recipe.bsdf"

        # 1. the whole export
        def export():
            brdftab.save(model, path, overwrite=True, **opts)

        best, median, times = timeit(export, args.repeat)
        report("export (brdftab.save, atomic write)", best, median)
        runs = ", ".join(f"{t * 1e3:.1f}" for t in times)
        print(f"{'':52s} all runs: {runs} ms; file {path.stat().st_size / 1024:.1f} KiB")
        export_median = median

        # 2. parts
        o = rgl.check_options(**opts)
        th_i = o["theta_i"].astype(np.float32).astype(np.float64)
        ph_i = np.zeros(1)
        ndf, _ = _rgl_write._choose_ndf(model, "auto", None)

        def tables():
            raised = rgl.backscatter_bound(model, ndf, None, 128, 2, False)
            return _rgl_write._ndf_tables(raised, ndf, 128, 2, False, model.name)

        b, m, _ = timeit(tables, args.repeat)
        report("  ndf + sigma tables (2 x 128)", b, m)
        d, ndf32, sigma32 = tables()

        def vndf_and_warp():
            v = _rgl_write._vndf_table(d, th_i, ph_i, 64)
            return Marginal2D(v, (ph_i.astype(np.float32), th_i.astype(np.float32)))

        b, m, _ = timeit(vndf_and_warp, args.repeat)
        report("  vndf tables + Marginal2D warp (9 x 64x64)", b, m)
        warp = vndf_and_warp()

        def nodes_and_model():
            wi, wo, u_m, _, _ = rgl.node_geometry(warp, th_i, ph_i, 32, True)
            ok = wo[:, 2] > 0
            return model.eval(wi[ok], wo[ok])

        b, m, _ = timeit(nodes_and_model, args.repeat)
        report("  warp 9 x 32x32 nodes + evaluate the model", b, m)
        payload = rgl.prepare_rgl(model, **opts)
        b, m, _ = timeit(lambda: encode_tensor(payload.fields), args.repeat)
        report("  encode the tensor file", b, m)

        # 3. variants
        bs_path = Path(tmp) / "backscatter.bsdf"
        b, m, _ = timeit(lambda: brdftab.save(model, bs_path, overwrite=True, ndf="backscatter", **opts), args.repeat)
        report("export, NDF by power iteration (back-scattering)", b, m)
        aniso = brdftab.models.create("microfacet", alpha_x=0.15, alpha_y=0.4, fresnel="schlick", f0=[0.9, 0.6, 0.3])
        an_path = Path(tmp) / "aniso.bsdf"
        b, m, _ = timeit(lambda: brdftab.save(aniso, an_path, overwrite=True), args.repeat)
        report("export anisotropic (17 phi_i x 9 theta_i x 32x32)", b, m,
               f"; file {an_path.stat().st_size / 2**20:.1f} MiB")

        # 4. reading and evaluating
        b, m, _ = timeit(lambda: brdftab.open(path), args.repeat)
        report("read + validate the isotropic file", b, m)
        bsdf = brdftab.open(path)
        n = args.eval_pairs
        wi, wo = hemisphere_pairs(n)
        b, m, _ = timeit(lambda: bsdf.eval(wi, wo), args.repeat)
        report(f"reader eval at {n:,} pairs", b, m, f"; {n / b / 1e6:.2f} M pairs/s (best)")

    status = "PASS" if export_median < args.target else "MISS"
    print(f"\ntarget < {args.target:g} s: {status} (isotropic export, median {export_median:.3f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
