"""Measurement: a polarized GGX conductor written as a ``.pbsdf`` and rendered by Mitsuba 3's
``measured_polarized``, against Mitsuba's own polarized ``roughconductor``.

Run from the repository root::

    python benchmarks/bench_pbsdf_mitsuba.py [--n-theta 90] [--n-phi-d 360] [--alpha 0.3] [--pairs 2000]

The model is the closed-form test model of ``tests/_polarized.py`` (GGX D, separable Smith G,
conductor Fresnel Mueller matrix; equal to Mitsuba's polarized ``roughconductor`` within 1e-5
of M00, ``tests/test_pbsdf.py``). It is streamed to a ``.pbsdf`` (:func:`brdftab.formats.pbsdf.
stream_pbsdf`, one φd slab in memory) on an (n_theta × n_theta × n_phi_d) Rusinkiewicz grid at
bin centres, loaded by ``measured_polarized`` (``scalar_spectral_polarized``) and evaluated at
random direction pairs (cosθ ≥ 0.15 for both) at the five wavelengths, with the camera along
wo and the light along wi; ``roughconductor`` with each wavelength's (n, k) is evaluated at the
same pairs. Both are rotated into the frame x = normalize(ω_light × ω_view). Printed: the
median and 95th percentile of |ΔM00| / M00, of max_ij |Δ(M_ij / M00)| (the normalized
elements), and the count of NaN elements. The file of the default grid is about 940 MB
(written to a temporary folder and removed).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from _polarized import KAIST_NM, GGXConductor  # noqa: E402

from brdftab.formats.pbsdf import stream_pbsdf  # noqa: E402
from brdftab.geometry import sph_to_vec  # noqa: E402
from brdftab.grids import RusinkiewiczGrid  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--n-theta", type=int, default=90)
    ap.add_argument("--n-phi-d", type=int, default=360)
    ap.add_argument("--alpha", type=float, default=0.3)
    ap.add_argument("--pairs", type=int, default=2000)
    args = ap.parse_args(argv)

    import mitsuba as mi

    mi.set_variant("scalar_spectral_polarized")
    from test_pbsdf import mitsuba_mueller

    model = GGXConductor(args.alpha)
    grid = RusinkiewiczGrid(args.n_theta, args.n_theta, args.n_phi_d, phi_d_fold="none")
    rng = np.random.default_rng(7)
    mu = rng.uniform(0.15, 1.0, (2, args.pairs))
    phi = rng.uniform(-np.pi, np.pi, (2, args.pairs))
    wi, wo = sph_to_vec(np.arccos(mu[0]), phi[0]), sph_to_vec(np.arccos(mu[1]), phi[1])
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "ggx.pbsdf"
        t0 = time.perf_counter()
        stream_pbsdf(model, grid, path)
        print(f"streamed {grid.describe()} x 5 wavelengths: {path.stat().st_size / 2**20:.0f} MiB in "
              f"{time.perf_counter() - t0:.0f} s")
        table = mi.load_dict({"type": "measured_polarized", "filename": str(path)})
        got = mitsuba_mueller(table, wi, wo, KAIST_NM)
    ref = np.zeros_like(got)
    for k, lam in enumerate(KAIST_NM):
        eta = model.eta(lam)
        rc = mi.load_dict({"type": "roughconductor", "distribution": "ggx", "alpha": args.alpha,
                           "eta": float(eta.real), "k": float(eta.imag), "sample_visible": False})
        ref[:, k] = mitsuba_mueller(rc, wi, wo, [lam])[:, 0]
    m00 = np.abs(got[..., 0, 0] - ref[..., 0, 0]) / ref[..., 0, 0]
    norm = np.abs(got / got[..., :1, :1] - ref / ref[..., :1, :1]).max(axis=(-2, -1))
    q = lambda a: f"median {np.median(a):.3g}, p95 {np.percentile(a, 95):.3g}"  # noqa: E731
    print(f"{args.pairs} pairs x 5 wavelengths, alpha {args.alpha}, grid {args.n_theta} x {args.n_theta} x "
          f"{args.n_phi_d}:")
    print(f"  |dM00| / M00:                 {q(m00)}")
    print(f"  max_ij |d(Mij / M00)|:        {q(norm)}")
    print(f"  NaN elements:                 {int(np.isnan(got).sum())}")


if __name__ == "__main__":
    main()
