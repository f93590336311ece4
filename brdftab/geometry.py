"""Directions, frames, rotations and Rusinkiewicz half/difference coordinates.

Conventions (used everywhere in brdftab):

* Directions are unit vectors that point **away** from the surface, in a local frame whose
  normal is +z. A direction is below the horizon when its z component is <= 0.
* ``sph(θ, φ) = (sinθ cosφ, sinθ sinφ, cosθ)``; θ is the polar angle from +z, φ the
  azimuth measured counter-clockwise from +x. All angles are in radians.
* Azimuths returned by this module lie in (−π, π] (``atan2``).
* Rusinkiewicz coordinates follow the MERL reference code (``BRDFRead.cpp``): the half vector
  ``h = normalize(wi + wo)`` has angles (θh, φh); the difference vector is
  ``d = Ry(−θh) · Rz(−φh) · wi`` with angles (θd, φd). The inverse is
  ``wi = Rz(φh) · Ry(θh) · d`` and ``wo = 2 (wi·h) h − wi``.
* At θh = 0 (exact mirror configuration) φh is undefined. brdftab defines φh = 0 there
  (``sin θh < THETA_H_ZERO``), so φd equals the azimuth of wi. Round trips through
  ``hd_to_io`` are exact for φh = 0 at θh = 0; for other φh the pair is the same but the
  reported (φh, φd) become (0, φh + φd).

Reference: S. M. Rusinkiewicz, "A New Change of Variables for Efficient BRDF Representation",
Eurographics Workshop on Rendering (1998); W. Matusik et al., MERL BRDF database
``BRDFRead.cpp`` (2003).
"""

from __future__ import annotations

import math

import numpy as np

from ._jit import device

__all__ = [
    "THETA_H_ZERO",
    "reduce_azimuth_deg",
    "sph_to_vec",
    "vec_to_sph",
    "normalize",
    "rot_x",
    "rot_y",
    "rot_z",
    "rotation_matrix",
    "half_vector",
    "reflect",
    "io_to_hd",
    "hd_to_io",
    "as_directions",
    "mirror_biased_pairs",
]

#: Below this value of sin θh the half vector is taken to be the normal and φh := 0.
THETA_H_ZERO = 1e-12


def reduce_azimuth_deg(phi: float) -> float:
    """An azimuth in degrees reduced exactly into (−360, 360), never −0 (the command line's
    angles, before they become radians: 1e20° is 280°, which ``radians(1e20)`` loses).

    >>> reduce_azimuth_deg(1e20), reduce_azimuth_deg(-360.0), reduce_azimuth_deg(-30.0)
    (280.0, 0.0, -30.0)
    """
    return math.fmod(phi, 360.0) + 0.0


def sph_to_vec(theta, phi):
    """Unit vector(s) ``(sinθ cosφ, sinθ sinφ, cosθ)`` from polar angle θ and azimuth φ [rad].

    Broadcasts over any shape; the result has a trailing axis of length 3.
    """
    theta, phi = np.broadcast_arrays(np.asarray(theta, float), np.asarray(phi, float))
    st = np.sin(theta)
    return np.stack([st * np.cos(phi), st * np.sin(phi), np.cos(theta)], axis=-1)


def vec_to_sph(v):
    """Polar angle θ ∈ [0, π] and azimuth φ ∈ (−π, π] [rad] of vectors ``v[..., 3]``.

    θ uses ``atan2(hypot(x, y), z)``, which keeps full precision near the pole (``acos``
    does not). Vectors need not be normalized.
    """
    v = np.asarray(v, float)
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    return np.arctan2(np.hypot(x, y), z), np.arctan2(y, x)


def normalize(v):
    """``v / |v|`` along the last axis, for any finite non-zero ``v``: divided by its largest
    component first, so |v|² neither overflows (``[1e155, 0, 1e155]``) nor underflows
    (``[1e-320, 0, 1e-320]``). A zero or non-finite vector gives NaN."""
    v = np.asarray(v, float)
    with np.errstate(invalid="ignore", divide="ignore"):
        u = v / np.max(np.abs(v), axis=-1, keepdims=True)
        return u / np.linalg.norm(u, axis=-1, keepdims=True)


def _rot(v, angle, i, j):
    # Right-handed rotation by `angle` in the (i, j) coordinate plane; broadcasts angle and v.
    v = np.asarray(v, float)
    c, s = np.cos(angle), np.sin(angle)
    out = np.array(np.broadcast_to(v, np.broadcast_shapes(v.shape, np.shape(angle) + (3,))))
    vi, vj = v[..., i], v[..., j]
    out[..., i] = c * vi - s * vj
    out[..., j] = s * vi + c * vj
    return out


def rot_x(v, angle):
    """Rotate vectors ``v[..., 3]`` right-handedly about +x by ``angle`` [rad]."""
    return _rot(v, angle, 1, 2)


def rot_y(v, angle):
    """Rotate vectors ``v[..., 3]`` right-handedly about +y by ``angle`` [rad]."""
    return _rot(v, angle, 2, 0)


def rot_z(v, angle):
    """Rotate vectors ``v[..., 3]`` right-handedly about +z by ``angle`` [rad]."""
    return _rot(v, angle, 0, 1)


def rotation_matrix(axis, angle):
    """3×3 right-handed rotation matrix about unit ``axis`` by ``angle`` [rad] (Rodrigues)."""
    a = normalize(np.asarray(axis, float))
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * (k @ k)


def half_vector(wi, wo):
    """Unit half vector ``normalize(wi + wo)``."""
    return normalize(np.asarray(wi, float) + np.asarray(wo, float))


def reflect(w, n):
    """Mirror direction of ``w`` about unit normal(s) ``n``: ``2 (w·n) n − w``."""
    w = np.asarray(w, float)
    n = np.asarray(n, float)
    return 2.0 * np.sum(w * n, axis=-1, keepdims=True) * n - w


def mirror_biased_pairs(n, rng, z_low=1e-6, z_span=1.0 - 2e-6, wi_z=None):
    """``n`` random direction pairs ``(wi, wo)`` for judging a BRDF's representation: wi uniform
    in solid angle with cosθ in [``z_low``, ``z_low + z_span``] (or in ``wi_z`` = (low, high));
    wo the same for half the pairs, and for the other half near the mirror direction of wi,
    reflected about a normal whose slopes are normal with a standard deviation log-uniform in
    [0.01, 0.5] (kept where its cosθ stays above ``z_low``), so that narrow lobes are judged
    too. ``rng``: a numpy Generator."""
    def hemisphere(low, span):
        z = rng.random(n) * span + low
        phi = rng.random(n) * 2 * np.pi
        r = np.sqrt(1 - z * z)
        return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)

    wi = hemisphere(z_low, z_span) if wi_z is None else hemisphere(wi_z[0], wi_z[1] - wi_z[0])
    wo = hemisphere(z_low, z_span)
    half = n // 2
    spread = np.exp(rng.uniform(np.log(0.01), np.log(0.5), half))
    slopes = rng.normal(size=(half, 2)) * spread[:, None]
    m = np.concatenate([-slopes, np.ones((half, 1))], axis=1)
    m /= np.linalg.norm(m, axis=1, keepdims=True)
    near = reflect(wi[:half], m)
    keep = near[:, 2] > z_low
    wo[:half][keep] = near[keep]
    return wi, wo


def as_directions(*dirs):
    """Broadcast direction arrays ``[..., 3]`` against each other as float64."""
    from .errors import ParameterError

    try:
        arrs = [np.asarray(d, dtype=float) for d in dirs]
    except (TypeError, ValueError):
        raise ParameterError("directions", "expected arrays of numbers with a trailing axis of length 3") from None
    for a in arrs:
        if a.ndim == 0 or a.shape[-1] != 3:
            raise ParameterError("directions", f"expected a trailing axis of length 3, got shape {a.shape}")
    try:
        return np.broadcast_arrays(*arrs)
    except ValueError:
        raise ParameterError("directions", f"shapes {[a.shape for a in arrs]} do not broadcast") from None


def io_to_hd(wi, wo):
    """Rusinkiewicz coordinates of direction pairs.

    Parameters
    ----------
    wi, wo : array_like [..., 3]
        Unit vectors pointing away from the surface (any leading shape, broadcast).

    Returns
    -------
    theta_h, phi_h, theta_d, phi_d : ndarray [rad]
        θh ∈ [0, π], φh ∈ (−π, π], θd ∈ [0, π], φd ∈ (−π, π]. At θh = 0 φh is defined as 0.
    """
    wi, wo = as_directions(wi, wo)
    h = wi + wo
    hx, hy, hz = h[..., 0], h[..., 1], h[..., 2]
    rxy = np.hypot(hx, hy)
    norm = np.hypot(rxy, hz)
    theta_h = np.arctan2(rxy, hz)
    pole = rxy <= THETA_H_ZERO * norm
    phi_h = np.where(pole, 0.0, np.arctan2(hy, hx))
    # d = Ry(-θh) Rz(-φh) wi, written out with the cosines of the angles.
    ch = hz / norm
    sh = rxy / norm
    safe = np.where(pole, 1.0, rxy)
    cp = np.where(pole, 1.0, hx / safe)
    sp = np.where(pole, 0.0, hy / safe)
    x, y, z = wi[..., 0], wi[..., 1], wi[..., 2]
    x1 = cp * x + sp * y
    y1 = -sp * x + cp * y
    dx = ch * x1 - sh * z
    dz = sh * x1 + ch * z
    theta_d = np.arctan2(np.hypot(dx, y1), dz)
    phi_d = np.arctan2(y1, dx)
    return theta_h, phi_h, theta_d, phi_d


def hd_to_io(theta_h, phi_h, theta_d, phi_d):
    """Direction pairs from Rusinkiewicz coordinates (inverse of :func:`io_to_hd`).

    All arguments in radians, broadcast against each other. Returns ``(wi, wo)`` with a
    trailing axis of length 3. Pairs may lie below the horizon (z <= 0): the caller decides.
    """
    th, ph, td, pd = np.broadcast_arrays(*(np.asarray(a, float) for a in (theta_h, phi_h, theta_d, phi_d)))
    return _hd_to_io_trig(np.cos(th), np.sin(th), np.cos(ph), np.sin(ph),
                          np.cos(td), np.sin(td), np.cos(pd), np.sin(pd))


@device
def pair_scalar(wi, wo, i):
    """``(wix, wiy, wiz, wox, woy, woz)``: row ``i`` of the pair arrays ``wi``, ``wo[M, 3]`` (compiled kernels)."""
    return wi[i, 0], wi[i, 1], wi[i, 2], wo[i, 0], wo[i, 1], wo[i, 2]


@device
def half_vector_scalar(wix, wiy, wiz, wox, woy, woz):
    """``(hx, hy, hz, cosθd)`` of one pair for compiled kernels: h = normalize(wi + wo) and
    cosθd = wi·h = |wi + wo| / 2 (the arithmetic of the models' array code)."""
    hx = wix + wox
    hy = wiy + woy
    hz = wiz + woz
    norm = math.sqrt(hx * hx + hy * hy + hz * hz)
    return hx / norm, hy / norm, hz / norm, 0.5 * norm


@device
def hd_to_io_scalar(cth, sth, cph, sph_, ctd, std, cpd, spd):
    """``(wix, wiy, wiz, wox, woy, woz)`` of one node for compiled kernels: :func:`_hd_to_io_trig`'s
    arithmetic, the same bits."""
    dx = std * cpd
    dy = std * spd
    dz = ctd
    ax = cth * dx + sth * dz
    az = -sth * dx + cth * dz
    bx = cth * dx - sth * dz
    bz = sth * dx + cth * dz
    return (cph * ax - sph_ * dy, sph_ * ax + cph * dy, az,
            -(cph * bx) + sph_ * dy, -(sph_ * bx) - cph * dy, bz)


def _hd_to_io_trig(cth, sth, cph, sph_, ctd, std, cpd, spd):
    """:func:`hd_to_io` from precomputed cosines and sines (grids reuse per-axis tables)."""
    dx = std * cpd
    dy = std * spd
    dz = ctd
    # Ry(θh): (x, y, z) -> (cosθ x + sinθ z, y, −sinθ x + cosθ z); then Rz(φh).
    ax = cth * dx + sth * dz
    az = -sth * dx + cth * dz
    bx = cth * dx - sth * dz          # the same for the mirrored d = (−dx, −dy, dz), negated x
    bz = sth * dx + cth * dz
    wi = np.stack([cph * ax - sph_ * dy, sph_ * ax + cph * dy, az], axis=-1)
    wo = np.stack([-(cph * bx) + sph_ * dy, -(sph_ * bx) - cph * dy, bz], axis=-1)
    return wi, wo
