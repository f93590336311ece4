"""Shadowing–masking functions G(wi, wo, h) for microfacet BRDFs.

All take unit vectors ``[..., 3]`` in the local frame (normal +z) and return a
dimensionless factor in [0, 1].

References
----------
* B. G. Smith, "Geometrical shadowing of a random rough surface", IEEE TAP 15, 668 (1967);
  Walter et al. EGSR 2007 Eq. 23 — separable Smith G = G1(wi) G1(wo), G1 = 1/(1+Λ).
* E. Heitz, JCGT 3(2) (2014), Eq. 99 — height-correlated G2 = 1/(1 + Λ(wi) + Λ(wo)).
* K. E. Torrance, E. M. Sparrow, JOSA 57, 1105 (1967); J. F. Blinn, SIGGRAPH (1977);
  R. L. Cook, K. E. Torrance, ACM TOG 1, 7 (1982) — V-groove
  ``G = min(1, 2 cosθh cosθo/(wo·h), 2 cosθh cosθi/(wo·h))``.
"""

from __future__ import annotations

import numpy as np

from .distributions import smith_lambda

__all__ = ["G_METHODS", "g_smith", "g_smith_height_correlated", "g_vgroove", "g_none", "smith_g1", "shadowing"]


def smith_g1(w, h, alpha_x, alpha_y=None, distribution="ggx"):
    """Smith masking G1(w, h) = χ⁺(w·h) / (1 + Λ(w))."""
    g = 1.0 / (1.0 + smith_lambda(w, alpha_x, alpha_y, distribution))
    return np.where(np.sum(w * h, axis=-1) > 0, g, 0.0)


def g_smith(wi, wo, h, alpha_x, alpha_y=None, distribution="ggx"):
    """Separable Smith G = G1(wi) G1(wo) (the classic Cook–Torrance + Smith form)."""
    return smith_g1(wi, h, alpha_x, alpha_y, distribution) * smith_g1(wo, h, alpha_x, alpha_y, distribution)


def g_smith_height_correlated(wi, wo, h, alpha_x, alpha_y=None, distribution="ggx"):
    """Height-correlated Smith G2 = χ⁺ / (1 + Λ(wi) + Λ(wo))."""
    li = smith_lambda(wi, alpha_x, alpha_y, distribution)
    lo = smith_lambda(wo, alpha_x, alpha_y, distribution)
    ok = (np.sum(wi * h, axis=-1) > 0) & (np.sum(wo * h, axis=-1) > 0)
    return np.where(ok, 1.0 / (1.0 + li + lo), 0.0)


def g_vgroove(wi, wo, h, alpha_x=None, alpha_y=None, distribution=None):
    """Torrance–Sparrow/Blinn V-groove G = min(1, 2 (n·h)(n·wo)/(wo·h), 2 (n·h)(n·wi)/(wo·h)).

    Independent of the roughness; valid for out-of-plane directions (Cook–Torrance 1982).
    """
    hz = h[..., 2]
    wo_h = np.sum(wo * h, axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        g = np.minimum(1.0, 2.0 * hz * np.minimum(wo[..., 2], wi[..., 2]) / wo_h)
    return np.where(wo_h > 0, np.maximum(g, 0.0), 0.0)


def g_none(wi, wo, h, alpha_x=None, alpha_y=None, distribution=None):
    """No shadowing: G = 1."""
    return np.ones(np.broadcast_shapes(wi.shape, wo.shape)[:-1])


#: Shadowing functions by name.
G_METHODS = {
    "smith": g_smith,
    "smith-height-correlated": g_smith_height_correlated,
    "v-groove": g_vgroove,
    "none": g_none,
}


def shadowing(wi, wo, h, alpha_x, alpha_y=None, distribution="ggx", method="smith"):
    """G(wi, wo, h) by name (``G_METHODS``)."""
    return G_METHODS[method](wi, wo, h, alpha_x, alpha_y, distribution)
