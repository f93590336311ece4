"""Compiled kernels against the numpy code they replace: the shared parity check."""

import numpy as np

from brdftab.brdf import numpy_reference

#: Relative agreement of a compiled kernel with the numpy code it replaces.
RTOL = 1e-12


def pairs(seed, n=20000):
    """Random upper-hemisphere pairs (a quarter near the mirror direction) and the rows the
    BRDF protocol treats specially: below and on the horizon, non-unit, huge, tiny, NaN, inf."""
    rng = np.random.default_rng(seed)

    def upper(k):
        v = rng.normal(size=(k, 3))
        v[:, 2] = np.abs(v[:, 2])
        return v / np.linalg.norm(v, axis=1, keepdims=True)

    wi, wo = upper(n), upper(n)
    # near the mirror direction too (the peak of narrow lobes)
    h = upper(n // 4) * np.array([0.1, 0.1, 1.0])
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    wo[: n // 4] = 2 * np.sum(wi[: n // 4] * h, axis=1, keepdims=True) * h - wi[: n // 4]
    special_i = np.array([[0.3, 0.2, -0.5], [0.6, 0.0, 0.0], [3.0, 1.0, 2.0], [1e200, 0.0, 1e200],
                          [1e-300, 1e-300, 2e-300], [np.nan, 0.0, 1.0], [0.0, np.inf, 1.0], [0.2, 0.1, 0.97],
                          [0.0, 0.0, 1.0], [1.0, 0.0, 1e-13]])
    special_o = np.array([[0.1, 0.1, 0.9], [0.2, 0.3, 0.9], [-1.0, 0.5, 4.0], [0.0, 1.0, 1.0], [0.5, 0.5, 0.5],
                          [0.0, 0.0, 1.0], [0.1, 0.1, 0.9], [0.2, 0.1, 0.97], [0.0, 0.0, 1.0], [0.3, 0.0, 0.9]])
    return np.concatenate([wi, special_i]), np.concatenate([wo, special_o])


def assert_parity(m, wavelengths=None, seed=0, wi=None, wo=None):
    """Assert that ``m`` has a compiled kernel and that it equals ``m``'s numpy evaluation to
    :data:`RTOL` at :func:`pairs` (or the given ``wi``, ``wo``): same NaN and zero rows, the
    rest relative; and broadcast one wi against many wo."""
    if wi is None:
        wi, wo = pairs(seed)
    lam = m.layout.resolve(wavelengths)
    assert m.kernel(lam, m.layout.n_out(lam)) is not None, f"{m.describe()}: no compiled kernel"
    got = m.eval(wi, wo, wavelengths)
    with numpy_reference():
        assert m.kernel(lam, m.layout.n_out(lam)) is None
        ref = m.eval(wi, wo, wavelengths)
    assert got.shape == ref.shape
    assert np.array_equal(np.isnan(got), np.isnan(ref)), f"{m.describe()}: NaN rows differ"
    assert np.array_equal(got == 0, ref == 0), f"{m.describe()}: zero rows differ"
    ok = ~np.isnan(ref)
    rel = np.abs(got[ok] - ref[ok]) / np.maximum(np.abs(ref[ok]), 1e-300)
    assert rel.max() <= RTOL, f"{m.describe()}: compiled differs from numpy by {rel.max():.3g} (relative)"
    # broadcasting (one wi against many wo) goes through the same kernel
    one = m.eval(wi[7], wo[:50], wavelengths)
    with numpy_reference():
        one_ref = m.eval(wi[7], wo[:50], wavelengths)
    np.testing.assert_allclose(one, one_ref, rtol=RTOL, atol=0)


def asymmetry_numpy(f1, f2, weight=None, floor: float = 1e-9) -> dict:
    """The numpy form of :func:`brdftab.checks._pairs.asymmetry` that its compiled passes
    replaced (the reference of their parity test)."""
    f1, f2 = np.asarray(f1), np.asarray(f2)
    if f1.dtype.kind != "f" or f2.dtype.kind != "f":
        f1, f2 = f1.astype(float), f2.astype(float)
    if f1.ndim == 1:
        f1, f2 = f1[:, None], f2[:, None]
    ok = np.isfinite(f1) & np.isfinite(f2)
    excluded = 0
    if not ok.all():
        rows_ok = ok.all(axis=1)
        excluded = int((~rows_ok).sum())
        f1 = np.where(ok, f1, 0.0)
        f2 = np.where(ok, f2, 0.0)
    amean = np.abs(f1 + f2)
    amean *= 0.5
    diff = np.abs(f1 - f2)
    top = float(amean.max()) if amean.size else 0.0
    sig = amean > max(floor * top, np.finfo(float).tiny)
    n_sig = int(sig.sum())
    out = {"compared": int(f1.shape[0]) - excluded, "excluded": excluded, "max_relative": 0.0,
           "rms_relative": 0.0, "worst": None, "weighted": None}
    if n_sig:
        rel = np.divide(diff, amean, out=np.zeros(diff.shape, diff.dtype), where=sig)
        i = int(np.argmax(rel))
        out["max_relative"] = float(rel.flat[i])
        out["worst"] = i // rel.shape[1] if rel.flat[i] > 0 else None
        out["rms_relative"] = float(np.sqrt(np.einsum("ij,ij->", rel, rel, dtype=float) / n_sig))
    if weight is not None:
        w = np.asarray(weight, float)
        den = w @ amean.astype(float, copy=False) if amean.size else np.zeros(0)
        num = w @ diff.astype(float, copy=False) if diff.size else np.zeros(0)
        ratio = np.divide(num, den, out=np.zeros_like(num), where=den > 0)
        out["weighted"] = float(ratio.max()) if ratio.size else 0.0
    return out
