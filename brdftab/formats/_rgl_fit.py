"""Least-squares stored values of an RGL ``.bsdf`` file (format option ``values = "fit"``).

A file read at a pair (ωi, ωo) returns a linear combination of its stored values: the bilinear
weights of the 4 sample nodes around the warped point in each θi (and φi) slice the reader
blends, times D̂/(4σ̂) (:meth:`._rgl_read.RGLBSDF.stored_weights`). Values that are the source
sampled at the nodes (``values = "nodes"``) make every reading exact at the nodes; between them
the reading is the reader's interpolation of the samples. Where the source has structure finer
than the sample cells (a measured table's own interpolation cells, its noise), the values that
make the readings closest to the source between the nodes too are those of the least-squares
problem

    minimize  Σ_q [(A v − r)_q / (|r_q| + FIT_FLOOR·r₉₉)]²  +  FIT_DAMP² Σ_j [(v_j − v0_j) / s_j]²

over seeded query pairs q (:data:`FIT_QUERIES_PER_VALUE` per stored value, at most
:data:`FIT_MAX_QUERIES`; half uniform in solid angle, half near the mirror direction, θi within
the file's θi nodes, θi, θo ≤ :data:`FIT_MAX_THETA_DEG`), r = the source's f·cosθo, v0 the node
samples, s_j = max(|v0_j|, FIT_FLOOR·max|v0|): the relative error of the reading, with a pull towards
the node samples that keeps values no query reaches (and the tails) at their samples. Solved by
LSQR per stored channel; a value the fit makes negative is set to 0, or to its node sample
where that is negative (measured RGB may hold negatives: a film's red in its mirror peak).

Measured: a glossy table with 4 % sample noise reads 1.70 → 1.51 % median error
(tests/test_rgl.py::test_fitted_values_read_a_rough_table_closer); the real RGL files' netCDF
conversions written back to ``.bsdf`` read 0.1–0.3 points of median error closer to the table
than node samples do (a script, formats/rgl-bsdf.md). Not a gain everywhere: a Lambertian
table's worst error grows with the fit, which ``values = "auto"`` therefore tries only where
node samples miss (:data:`._rgl_write.FIT_WHEN_SCORE`), and keeps only where it reads no
farther off at grazing directions (:data:`._rgl_write.FIT_GRAZING_TOLERANCE`).
"""

from __future__ import annotations

import numpy as np

__all__ = ["FIT_DAMP", "FIT_FLOOR", "FIT_ITERATIONS", "FIT_MAX_QUERIES", "FIT_MAX_THETA_DEG", "FIT_QUERIES_PER_VALUE",
           "FIT_SEED", "fit_values"]

#: Query pairs per stored value (per slice sample node), and their cap.
FIT_QUERIES_PER_VALUE = 4
FIT_MAX_QUERIES = 1 << 19
#: Pull towards the node samples, relative to the values' own size (see the module docstring).
FIT_DAMP = 0.3
#: The relative error is taken against |r| + FIT_FLOOR·(99th percentile of r): values far
#: below the lobe count in proportion to that floor, not as relative errors of noise.
FIT_FLOOR = 1e-3
#: LSQR iterations per channel at most (a film whose values span 7 decades converges slowly:
#: 2000 iterations took 30 s for an RGB file and read 0.1 points of median error closer than 250).
FIT_ITERATIONS = 250
#: The queries' largest elevation of ωi and ωo [deg].
FIT_MAX_THETA_DEG = 89.0
#: Seed of the query pairs (not those of the checks that judge the file: convert's check points
#: and the ``warp`` choice use other streams).
FIT_SEED = 20_251_127


def fit_values(brdf, fields: dict, key: str, lam, n_source: int) -> np.ndarray:
    """The ``key`` field (``rgb``/``spectra``, ``[Nφi, Nθi, C, N, N]`` float32) of ``fields`` with
    least-squares values against ``brdf`` (see the module docstring). ``lam``: the wavelengths
    the source is evaluated at (None for RGB); ``n_source``: its channels (1 for a grey source
    written to R, G and B: fitted once)."""
    from scipy.sparse import diags
    from scipy.sparse.linalg import lsqr

    from ..geometry import mirror_biased_pairs
    from ._rgl_read import RGLBSDF

    spec = fields[key]
    n_phi, n_theta, n_chan, n, _ = spec.shape
    v0 = np.moveaxis(spec, 2, -1).reshape(-1, n_chan).astype(np.float64)  # [(φi, θi, y, x), C]
    n_queries = int(min(FIT_MAX_QUERIES, FIT_QUERIES_PER_VALUE * v0.shape[0]))
    c_low = np.cos(np.radians(FIT_MAX_THETA_DEG))
    # ωi within the file's θi nodes: beyond them the readers hold the end slices, which the
    # fit must not bend towards incidences the file does not store
    th = fields["theta_i"].astype(np.float64)
    wi_z = (max(c_low, float(np.cos(th[-1]))), float(np.cos(th[0])))
    wi, wo = mirror_biased_pairs(n_queries, np.random.default_rng(FIT_SEED), z_low=c_low, z_span=1.0 - c_low,
                                 wi_z=wi_z)
    with np.errstate(all="ignore"):  # (a scattered table's extrapolation counts: prepare_rgl keeps the file's)
        ref = np.asarray(brdf.eval(wi, wo, lam), float) * wo[:, 2:3]
    ok = np.all(np.isfinite(ref), axis=-1)
    a = RGLBSDF(fields, "<candidate>").stored_weights(wi[ok], wo[ok])
    ref = ref[ok]
    out = v0.copy()
    for c in range(n_source):
        r, v = ref[:, c], v0[:, c]
        top = np.percentile(np.abs(r), 99) if r.size else 0.0
        vmax = np.abs(v).max()
        if top <= 0 or vmax <= 0:
            continue
        row = 1.0 / (np.abs(r) + FIT_FLOOR * top)
        scale = np.maximum(np.abs(v), FIT_FLOOR * vmax)
        system = diags(row) @ a @ diags(scale)
        rhs = row * (r - a @ v)
        step = lsqr(system, rhs, damp=FIT_DAMP, atol=1e-8, btol=1e-8, iter_lim=FIT_ITERATIONS)[0]
        # no negatives beyond the node samples' own (a measured RGB file may hold some)
        out[:, c] = np.maximum(v + scale * step, np.minimum(v, 0.0))
    if n_source == 1 and n_chan > 1:
        out[:, 1:] = out[:, :1]
    return np.moveaxis(out.reshape(n_phi, n_theta, n, n, n_chan), -1, 2).astype(np.float32)
