"""A fixed-rule albedo for tests: an independent reference for :func:`brdftab.integrate.directional_albedo`.

brdftab has one public directional albedo (:func:`brdftab.integrate.directional_albedo`,
adaptive, used by the checks). The tests compare it, and the models, with this plain product
rule on :mod:`brdftab.quadrature`'s hemisphere or half-vector nodes, which shares none of its
adaptive machinery.
"""

from __future__ import annotations

import numpy as np

from brdftab.quadrature import half_vector_hemisphere, hemisphere

__all__ = ["fixed_albedo"]


def fixed_albedo(brdf, wi, wavelengths=None, *, lobe_width: float | None = None, n_theta: int = 128,
                 n_phi: int = 128):
    """Directional-hemispherical reflectance ∫ f(wi, wo) cosθo dωo for each ``wi[..., 3]``.

    ``lobe_width`` None uses :func:`hemisphere`; a number uses :func:`half_vector_hemisphere`
    with that scale (for peaked lobes). Returns ``[..., n_channels]``.
    """
    wi = np.asarray(wi, float)
    lead = wi.shape[:-1]
    wi2 = wi.reshape(-1, 3)
    out = []
    if lobe_width is None:
        wo, w = hemisphere(n_theta, n_phi)
        for v in wi2:
            f = brdf.eval(v[None, :], wo, wavelengths)
            out.append(np.einsum("nc,n->c", f, w * wo[:, 2]))
    else:
        h, wh = half_vector_hemisphere(lobe_width, n_theta, n_phi)
        for v in wi2:
            c = h @ v
            keep = c > 0
            hk, ck = h[keep], c[keep]
            wo = 2.0 * ck[:, None] * hk - v
            f = brdf.eval(v[None, :], wo, wavelengths)
            out.append(np.einsum("nc,n->c", f, wh[keep] * 4.0 * ck * np.maximum(wo[:, 2], 0.0)))
    return np.asarray(out).reshape(lead + (-1,))
