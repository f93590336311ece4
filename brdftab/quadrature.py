"""Quadrature over the hemisphere, for albedo integrals and normalization checks.

* :func:`hemisphere` — Gauss–Legendre in μ = cosθ × midpoint rule in φ (spectrally accurate
  in the periodic φ); good for smooth (diffuse) integrands.
* :func:`half_vector_hemisphere` — nodes in half-vector space with θh mapped through
  ``tanθh = c·s/(1 − s)``, s Gauss–Legendre on (0, 1), so nodes follow a lobe of width c
  (use c ≈ α for microfacet lobes); exact to ~1e-8 for ∫D cosθh dω even at α = 0.05.

The directional albedo itself has one public function, :func:`brdftab.integrate.directional_albedo`
(adaptive, following lobe hints); these fixed rules are building blocks and test references.

References: P. J. Davis, P. Rabinowitz, *Methods of Numerical Integration*, 2nd ed. (1984),
§2.7 (Gauss–Legendre), §2.9 (periodic trapezoid rule); B. Walter et al., EGSR (2007), Eq. 14
(half-vector Jacobian).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy.special import roots_legendre

from .geometry import sph_to_vec

__all__ = ["gauss_legendre", "hemisphere", "half_vector_hemisphere"]


def gauss_legendre(n: int, a: float = -1.0, b: float = 1.0):
    """``n`` Gauss–Legendre nodes and weights on [a, b]."""
    x, w = _legendre(int(n))
    return 0.5 * (b - a) * x + 0.5 * (b + a), 0.5 * (b - a) * w


@lru_cache(maxsize=32)
def _legendre(n):
    x, w = roots_legendre(n)
    x.setflags(write=False)
    w.setflags(write=False)
    return x, w


def hemisphere(n_theta: int = 64, n_phi: int = 128):
    """Directions ``(N, 3)`` and solid-angle weights [sr] on the upper hemisphere (Σw = 2π)."""
    mu, wmu = gauss_legendre(n_theta, 0.0, 1.0)
    phi = (np.arange(n_phi) + 0.5) * (2 * np.pi / n_phi)
    m, p = np.meshgrid(mu, phi, indexing="ij")
    w = np.repeat(wmu, n_phi) * (2 * np.pi / n_phi)
    return sph_to_vec(np.arccos(m).ravel(), p.ravel()), w


def half_vector_hemisphere(scale: float, n_theta: int = 256, n_phi: int = 256):
    """Half vectors ``(N, 3)`` and weights dωh [sr], concentrated within ~``scale`` of the normal."""
    s, ws = gauss_legendre(n_theta, 0.0, 1.0)
    t = scale * s / (1.0 - s)
    theta = np.arctan(t)
    dtheta = scale / (1.0 - s) ** 2 / (1.0 + t * t)
    phi = (np.arange(n_phi) + 0.5) * (2 * np.pi / n_phi)
    th, ph = np.meshgrid(theta, phi, indexing="ij")
    w = np.repeat(ws * dtheta * np.sin(theta), n_phi) * (2 * np.pi / n_phi)
    return sph_to_vec(th.ravel(), ph.ravel()), w
