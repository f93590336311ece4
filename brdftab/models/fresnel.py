"""Fresnel reflectance for unpolarized light.

``cos_i`` is the cosine of the angle between the incident direction and the (micro)surface
normal; indices are relative (substrate over incident medium). A complex index is ``n + ik``
with k >= 0 (absorbing).

References
----------
* M. Born, E. Wolf, *Principles of Optics*, 7th ed., §1.5.2 (dielectric) and §14.2
  (absorbing media) — the complex-amplitude form :func:`fresnel_amplitudes`.
* K. D. Möller, *Optics* (1988); as used by Mitsuba 3 ``fresnel_conductor`` and pbrt-v3
  ``FrConductor`` — the real-arithmetic form :func:`fresnel_conductor`.
* C. Schlick, "An inexpensive BRDF model for physically-based rendering", CGF 13(3) (1994).
"""

from __future__ import annotations

import math

import numpy as np

from .._jit import device

__all__ = ["fresnel_amplitudes", "fresnel_complex", "fresnel_conductor", "fresnel_dielectric",
           "fresnel_schlick", "INDEX_MIN", "INDEX_MAX"]

#: The range of a refractive index n (real part) and of an extinction coefficient k that model
#: parameters accept: the Fresnel terms are finite there. Beyond it they are not (n or k of
#: about 1e77 overflow n², an n of about 1e-155 underflows it: NaN); real materials lie far
#: inside (n ≈ 0.05 for silver in the visible, k below 100).
INDEX_MIN = 1e-6
INDEX_MAX = 1e6


def fresnel_amplitudes(cos_i, eta):
    """Complex amplitude reflection coefficients ``(r_s, r_p)`` for a complex relative index.

    ``cosθt = sqrt(1 − sin²θi/η²)`` (principal root); ``r_s = (cosθi − η cosθt)/(cosθi + η cosθt)``,
    ``r_p = (η cosθi − cosθt)/(η cosθi + cosθt)``.
    """
    cos_i = np.asarray(cos_i, float)
    eta = np.asarray(eta, complex)
    sin2_t = (1.0 - cos_i**2) / eta**2
    cos_t = np.sqrt(1.0 - sin2_t + 0j)
    r_s = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    r_p = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    return r_s, r_p


def fresnel_complex(cos_i, eta):
    """Unpolarized reflectance ``(|r_s|² + |r_p|²)/2`` from :func:`fresnel_amplitudes`."""
    r_s, r_p = fresnel_amplitudes(cos_i, eta)
    return 0.5 * (np.abs(r_s) ** 2 + np.abs(r_p) ** 2)


def fresnel_conductor(cos_i, n, k):
    """Unpolarized reflectance of an absorbing medium with index ``n + ik`` (real arithmetic).

    Equal to :func:`fresnel_complex` with ``eta = n + 1j k``; about 3× faster. Broadcasts
    ``cos_i`` against ``n`` and ``k`` (e.g. ``cos_i[:, None]`` with per-channel indices).
    """
    c = np.clip(cos_i, 0.0, 1.0)
    c2 = c * c
    s2 = 1.0 - c2
    n2 = n * n
    k2 = k * k
    t0 = n2 - k2 - s2
    a2b2 = np.sqrt(t0 * t0 + 4.0 * n2 * k2)
    a = np.sqrt(np.maximum(0.5 * (a2b2 + t0), 0.0))
    t1 = a2b2 + c2
    t2 = 2.0 * a * c
    t3 = c2 * a2b2 + s2 * s2
    t4 = t2 * s2
    with np.errstate(divide="ignore", invalid="ignore"):
        rs = np.where(t1 + t2 > 0, (t1 - t2) / (t1 + t2), 1.0)   # 0/0 only at grazing with n=1, k=0
        rp = rs * np.where(t3 + t4 > 0, (t3 - t4) / (t3 + t4), 1.0)
    # rounding can push an index-matched interface (n = 1, k = 0) a few ulp below 0
    return np.clip(0.5 * (rs + rp), 0.0, 1.0)


def fresnel_dielectric(cos_i, eta):
    """Unpolarized reflectance of a dielectric interface with real relative index ``eta``.

    Total internal reflection (``eta < 1`` beyond the critical angle) gives 1.
    """
    c = np.clip(cos_i, 0.0, 1.0)
    s2_t = (1.0 - c * c) / (eta * eta)
    tir = (eta < 1.0) & (s2_t >= 1.0)
    ct = np.sqrt(np.maximum(1.0 - s2_t, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        r_s = (c - eta * ct) / (c + eta * ct)
        r_p = (eta * c - ct) / (eta * c + ct)
        f = 0.5 * (r_s * r_s + r_p * r_p)
    # exactly grazing incidence (c = 0) reflects everything; 0/0 there when eta = 1
    return np.where(tir | (c == 0.0), 1.0, f)


def fresnel_schlick(cos_i, f0):
    """Schlick's approximation ``F0 + (1 − F0)(1 − cosθ)⁵``."""
    c = np.clip(cos_i, 0.0, 1.0)
    return f0 + (1.0 - f0) * (1.0 - c) ** 5


# --------------------------------------------------------------------------------------------
# Scalar forms for compiled kernels: one cosine, the index of channel ``c`` in row ``p[c]``;
# the same arithmetic, in the same order, as the array forms above (parity tests: 1e-12).


@device
def conductor_scalar(cos_i, n, k):
    """:func:`fresnel_conductor` of one cosine."""
    c = min(max(cos_i, 0.0), 1.0)
    c2 = c * c
    s2 = 1.0 - c2
    n2 = n * n
    k2 = k * k
    t0 = n2 - k2 - s2
    a2b2 = math.sqrt(t0 * t0 + 4.0 * n2 * k2)
    a = math.sqrt(max(0.5 * (a2b2 + t0), 0.0))
    t1 = a2b2 + c2
    t2 = 2.0 * a * c
    t3 = c2 * a2b2 + s2 * s2
    t4 = t2 * s2
    rs = (t1 - t2) / (t1 + t2) if t1 + t2 > 0 else 1.0
    rp = rs * ((t3 - t4) / (t3 + t4) if t3 + t4 > 0 else 1.0)
    return min(max(0.5 * (rs + rp), 0.0), 1.0)


@device
def dielectric_scalar(cos_i, eta):
    """:func:`fresnel_dielectric` of one cosine."""
    c = min(max(cos_i, 0.0), 1.0)
    s2_t = (1.0 - c * c) / (eta * eta)
    if (eta < 1.0 and s2_t >= 1.0) or c == 0.0:
        return 1.0
    ct = math.sqrt(max(1.0 - s2_t, 0.0))
    r_s = (c - eta * ct) / (c + eta * ct)
    r_p = (eta * c - ct) / (eta * c + ct)
    return 0.5 * (r_s * r_s + r_p * r_p)


@device
def schlick_scalar(cos_i, f0):
    """:func:`fresnel_schlick` of one cosine."""
    c = min(max(cos_i, 0.0), 1.0)
    return f0 + (1.0 - f0) * math.pow(1.0 - c, 5.0)
