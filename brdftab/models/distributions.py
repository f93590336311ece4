"""Microfacet normal distributions D(h) and their Smith Λ functions.

Plain vectorized functions over unit vectors ``[..., 3]`` in the local frame (normal +z).
Roughness α is the Beckmann/GGX slope parameter (dimensionless); anisotropic forms take
α_x, α_y along the frame's x and y axes. Every D is area-normalized: ∫ D(h) cosθh dω_h = 1.

References
----------
* P. Beckmann, A. Spizzichino, *The Scattering of Electromagnetic Waves from Rough
  Surfaces*, Pergamon (1963) — Beckmann distribution.
* T. S. Trowbridge, K. P. Reitz, "Average irregularity representation of a rough surface
  for ray reflection", JOSA 65, 531 (1975) — GGX/Trowbridge–Reitz distribution.
* B. Walter, S. R. Marschner, H. Li, K. E. Torrance, "Microfacet models for refraction
  through rough surfaces", EGSR (2007), Eqs. 27–34 — D and Smith G1 for both.
* E. Heitz, "Understanding the masking-shadowing function in microfacet-based BRDFs",
  JCGT 3(2) (2014), §5 — Λ, anisotropic α(φ), height-correlated G2.
* M. Bitterling et al., "Physical models of the bidirectional reflectance of solar receiver
  coatings", Solar Energy, Eqs. 12 and 15 — GGX D and G1 as used for Pyromark 2500.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.special import erfc

from .._jit import device

__all__ = ["d_beckmann", "d_ggx", "lambda_beckmann", "lambda_ggx"]

_SQRT_PI = np.sqrt(np.pi)


def _slope2(h, alpha_x, alpha_y):
    # tan²θ · (cos²φ/αx² + sin²φ/αy²) = (hx²/αx² + hy²/αy²) / hz²  (times hz² left out)
    return (h[..., 0] / alpha_x) ** 2 + (h[..., 1] / alpha_y) ** 2


def d_beckmann(h, alpha_x, alpha_y=None):
    """Beckmann NDF [sr⁻¹]: ``exp(−tan²θh (cos²φh/αx² + sin²φh/αy²)) / (π αx αy cos⁴θh)``.

    ``h[..., 3]`` unit microfacet normals; 0 where ``h_z <= 0``.
    """
    alpha_y = alpha_x if alpha_y is None else alpha_y
    hz = h[..., 2]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        c2 = hz * hz
        d = np.exp(-_slope2(h, alpha_x, alpha_y) / c2) / (np.pi * alpha_x * alpha_y * c2 * c2)
    return np.where(hz > 0, d, 0.0)


def d_ggx(h, alpha_x, alpha_y=None):
    """GGX (Trowbridge–Reitz) NDF [sr⁻¹]: ``1 / (π αx αy (hx²/αx² + hy²/αy² + hz²)²)``.

    Isotropic form: ``α² / (π (α² cos²θh + sin²θh)²)`` (Bitterling et al. Eq. 12).
    """
    alpha_y = alpha_x if alpha_y is None else alpha_y
    hz = h[..., 2]
    t = _slope2(h, alpha_x, alpha_y) + hz * hz
    return np.where(hz > 0, 1.0 / (np.pi * alpha_x * alpha_y * t * t), 0.0)


def _alpha_tan2(w, alpha_x, alpha_y):
    # α(φ)² tan²θ = (wx² αx² + wy² αy²) / wz²
    with np.errstate(divide="ignore", invalid="ignore"):
        return ((w[..., 0] * alpha_x) ** 2 + (w[..., 1] * alpha_y) ** 2) / (w[..., 2] ** 2)


def lambda_beckmann(w, alpha_x, alpha_y=None):
    """Exact Smith Λ of the Beckmann distribution for directions ``w[..., 3]``.

    ``Λ = ½ [exp(−a²)/(a√π) − erfc(a)]`` with ``a = 1/(α(φ) tanθ)``. This is the exact form
    (not Walter's rational approximation, which is off by up to 0.35 %). Λ = 0 at the normal.
    """
    alpha_y = alpha_x if alpha_y is None else alpha_y
    t2 = _alpha_tan2(w, alpha_x, alpha_y)
    with np.errstate(divide="ignore", invalid="ignore"):
        a = 1.0 / np.sqrt(t2)
        lam = 0.5 * (np.exp(-a * a) / (a * _SQRT_PI) - erfc(a))
    return np.where(t2 > 0, lam, 0.0)


def lambda_ggx(w, alpha_x, alpha_y=None):
    """Exact Smith Λ of GGX: ``(−1 + sqrt(1 + α(φ)² tan²θ)) / 2``."""
    alpha_y = alpha_x if alpha_y is None else alpha_y
    t2 = _alpha_tan2(w, alpha_x, alpha_y)
    return 0.5 * (np.sqrt(1.0 + t2) - 1.0)


# --------------------------------------------------------------------------------------------
# Scalar forms for compiled kernels (one direction; ``p`` = [α_x, α_y]). The same arithmetic,
# in the same order, as the array forms above: the parity tests hold them to 1e-12.


@device
def ggx_D_scalar(hx, hy, hz, p):
    """:func:`d_ggx` of one unit normal."""
    if hz <= 0.0:
        return 0.0
    ax, ay = p[0], p[1]
    u = hx / ax
    v = hy / ay
    t = u * u + v * v + hz * hz
    return 1.0 / (np.pi * ax * ay * t * t)


@device
def ggx_lambda_scalar(wx, wy, wz, p):
    """:func:`lambda_ggx` of one direction."""
    u = wx * p[0]
    v = wy * p[1]
    t2 = (u * u + v * v) / (wz * wz)
    return 0.5 * (math.sqrt(1.0 + t2) - 1.0)


@device
def beckmann_D_scalar(hx, hy, hz, p):
    """:func:`d_beckmann` of one unit normal."""
    if hz <= 0.0:
        return 0.0
    ax, ay = p[0], p[1]
    c2 = hz * hz
    u = hx / ax
    v = hy / ay
    return math.exp(-(u * u + v * v) / c2) / (np.pi * ax * ay * c2 * c2)


@device
def beckmann_lambda_scalar(wx, wy, wz, p):
    """:func:`lambda_beckmann` of one direction."""
    u = wx * p[0]
    v = wy * p[1]
    t2 = (u * u + v * v) / (wz * wz)
    if not t2 > 0.0:
        return 0.0
    a = 1.0 / math.sqrt(t2)
    return 0.5 * (math.exp(-a * a) / (a * _SQRT_PI) - math.erfc(a))
