"""Make ``brdftab/models/pyramid_walk.npz``, the sequence table of the ``pyramid-microfacet``
model's ``walk = "traced"``, with the package's ray tracer of the random pyramid array.

    python tools/make_pyramid_walk.py [--rays 10000] [--tiles 16] [--out PATH]

At each incidence node (θ = 0, 3.5, …, 84, 87, 89°; φ = 0, 9, …, 45° from a face normal's azimuth)
``--tiles`` random tiles of 1000 pyramids (seeds 1000 + t: not the tests' seeds) are each hit by
``--rays`` rays (seeds of their own), traced to ``depth`` = 3 bounces. Nodes on a mirror line of
the array (φ = 0°, φ = 45°; every symmetry at θ = 0) average the counts with their mirror
images. About 25 million rays: 10 to 20 minutes on one core.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from brdftab.models.pyramid_tracer import PyramidField, sequence_codes
from brdftab.models.pyramid_walk import TABLE, WalkTable, n_codes, symmetry_permutations

THETA_DEG = np.concatenate([np.arange(0.0, 85.0, 3.5), [87.0, 89.0]])
PHI_DEG = np.array([0, 9, 18, 27, 36, 45], float)
DEPTH = 3
PYRAMIDS = 1000
FIELD_SEED = 1000
RAY_SEED = 100_000


def counts(fields, theta, phi, rays, seed):
    """Fractions (first [4], escape [n_codes], inside [4^depth]) of the rays from (θ, φ)."""
    wi = np.array([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])
    nc = n_codes(DEPTH)
    hist = np.zeros(nc + 4 ** DEPTH)
    first = np.zeros(4)
    total = 0
    for t, field in enumerate(fields):
        tr = field.trace(wi, rays, seed=seed + t, max_bounces=DEPTH)
        code = sequence_codes(tr.faces, tr.bounces, DEPTH)
        hist += np.bincount(code[code >= 0], minlength=hist.size)
        first += np.bincount(tr.faces[tr.faces[:, 0] >= 0, 0], minlength=4)
        total += rays
    return first / total, hist[:nc] / total, hist[nc:] / total


def symmetrize(first, esc, ins, ops):
    """Mean of the node's fractions over the symmetries ``ops`` that leave it in place."""
    faces, esc_perm, ins_perm = symmetry_permutations(DEPTH)
    return (np.mean([first[faces[op]] for op in ops], axis=0), np.mean([esc[esc_perm[op]] for op in ops], axis=0),
            np.mean([ins[ins_perm[op]] for op in ops], axis=0))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rays", type=int, default=10_000, help="rays per tile and node")
    ap.add_argument("--tiles", type=int, default=16, help="random tiles of 1000 pyramids")
    ap.add_argument("--theta-deg", type=float, nargs="+", default=THETA_DEG, help="θ nodes (first 0 or above)")
    ap.add_argument("--phi-deg", type=float, nargs="+", default=PHI_DEG, help="φ nodes in 0 … 45")
    ap.add_argument("--out", type=Path, default=TABLE)
    args = ap.parse_args(argv)
    theta_deg, phi_deg = np.asarray(args.theta_deg, float), np.asarray(args.phi_deg, float)
    fields = [PyramidField(PYRAMIDS, seed=FIELD_SEED + t) for t in range(args.tiles)]
    nt, nph = theta_deg.size, phi_deg.size
    first = np.zeros((nt, nph, 4))
    esc = np.zeros((nt, nph, n_codes(DEPTH)))
    ins = np.zeros((nt, nph, 4 ** DEPTH))
    start = time.time()
    node = 0
    for i, th in enumerate(theta_deg):
        for j, ph in enumerate(phi_deg):
            if th == 0 and j > 0:
                first[i, j], esc[i, j], ins[i, j] = first[i, 0], esc[i, 0], ins[i, 0]
                continue
            f, e, n = counts(fields, np.radians(th), np.radians(ph), args.rays, RAY_SEED + node * args.tiles)
            node += 1
            # the symmetries that fix the node (the query → domain maps of symmetry_permutations):
            # identity; the mirror y → −y (turn by −270° then the diagonal mirror) at φ = 0; the
            # diagonal mirror at φ = 45°; all eight at normal incidence
            ops = range(8) if th == 0 else (0, 7) if ph == 0 else (0, 1) if ph == 45 else (0,)
            first[i, j], esc[i, j], ins[i, j] = symmetrize(f, e, n, ops)
            print(f"θ {th:4.1f}° φ {ph:4.1f}°  first {np.round(first[i, j], 4)}  {time.time() - start:6.0f} s",
                  flush=True)
    meta = {"rays_per_tile": args.rays, "tiles": args.tiles, "pyramids": PYRAMIDS, "field_seed": FIELD_SEED,
            "ray_seed": RAY_SEED}
    WalkTable(np.radians(theta_deg), np.radians(phi_deg), DEPTH, first, esc, ins, meta).save(args.out)
    print(f"wrote {args.out} ({args.out.stat().st_size} bytes) in {time.time() - start:.0f} s")


if __name__ == "__main__":
    main()
