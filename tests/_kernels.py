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
