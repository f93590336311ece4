"""Rayleigh–Rice polarization factor Q for a complex index (first-order vector perturbation).

The four amplitudes q_αβ (first letter: incident polarization, second: scattered), for an
index n̂ = n + ik (k ≥ 0; ε = n̂²; q_i = sqrt(ε − sin²θi), q_s = sqrt(ε − sin²θs), principal
complex roots):

    q_ss = (ε−1) cosφs / [(cosθi + q_i)(cosθs + q_s)]
    q_pp = (ε−1) [ε sinθi sinθs − q_s q_i cosφs] / [(ε cosθi + q_i)(ε cosθs + q_s)]
    q_ps = −(ε−1) q_i sinφs / [(ε cosθi + q_i)(cosθs + q_s)]
    q_sp = −(ε−1) q_s sinφs / [(cosθi + q_i)(ε cosθs + q_s)]

and Q_αβ = |q_αβ|². Papers that write the index as n − ik (Small et al. 2021, Torrance and
Sparrow 1967) describe the same medium: |q|² does not depend on the sign convention.

**Azimuth convention.** φs is the azimuth of the scattered direction measured right-handedly
about the normal from the plane of incidence, with **φs = 0 on the specular (forward) side**
(SCATMECH's convention: the Bragg frequency f_x = (sinθs cosφs − sinθi)/λ vanishes at the
mirror direction). In brdftab's frame, where wi points toward the source with azimuth φi and
the mirror direction has azimuth φi + π, this is φs = φo − φi − π:
cosφs = −(wi_xy · wo_xy)/(|wi_xy| |wo_xy|), sinφs = −(wi_xy × wo_xy)_z/(|wi_xy| |wo_xy|). At
normal incidence (or θs = 0) the plane of incidence is undefined; the unpolarized sums do not
depend on the choice there (φs := 0 is used).

**Polarized form.** The amplitudes are the Jones matrix [[q_ss, q_ps], [q_sp, q_pp]] acting on
(E_s, E_p) in SCATMECH's ``psps`` basis (s = normalize(ẑ × k) per beam, exp(−iωt)):
:func:`q_jones`; :func:`q_mueller` is its Mueller matrix (SCATMECH's Jones-to-Mueller conversion),
whose element (0, 0) is the half-sum ½ Σ Q_αβ (:func:`q_unpolarized`). At the mirror direction it
is the Fresnel Mueller matrix (tested against Mitsuba's ``specular_reflection`` after
:func:`brdftab.polarization.convert_basis`).

Identities (tested): at the mirror direction q_ss = −r_s, q_pp = ±r_p (Fresnel amplitudes), so
Q_ss = R_s, Q_pp = R_p and the cross terms vanish; Q_ss = 0 at φs = 90°; exchanging the incident
and scattered directions swaps Q_ps and Q_sp and keeps Q_ss, Q_pp.

Two normalizations of the unpolarized factor are in use:

* :func:`q_sum` — the plain sum Q_ss + Q_sp + Q_ps + Q_pp (Butler's convention; twice the
  Fresnel reflectance at the mirror direction). Small et al. 2021, Eqs. 6 and 8, use this
  one: it reproduces their printed peak values (§4.4.2);
* :func:`q_unpolarized` — the half-sum (the average over the two incident polarizations,
  SCATMECH's Mueller element M11): equal to the Fresnel reflectance at the mirror direction.
  This is the ``rayleigh-rice`` Fresnel choice of ``microfacet``.

Q is not bounded by 1 away from the mirror direction for metals (n = 0.7686 + 6.078i,
θi = 45°, θs = 20°, φs = 180°: Q = 2.025); it is not clamped.

References: [Stover2012] §5 (Rayleigh–Rice vector perturbation theory); NIST SCATMECH
``Microroughness_BRDF_Model::jones()`` (code/urough.cpp), whose amplitudes these are;
[Butler2015] Q and the Fresnel reflectance; [Small2021] Eqs. 5–8.
"""

from __future__ import annotations

import cmath
import math

import numpy as np

from .._jit import device

__all__ = ["scattering_azimuth", "q_amplitudes", "q_components", "q_sum", "q_unpolarized", "q_jones", "q_mueller"]


def scattering_azimuth(wi, wo):
    """(cosφs, sinφs, sinθi, cosθi, sinθs, cosθs) for direction pairs ``wi``, ``wo[..., 3]``.

    φs = φo − φi − π: 0 on the specular side (SCATMECH's convention), right-handed about +z.
    Where the plane of incidence is undefined (θi = 0 or θs = 0) φs := 0.
    """
    wi = np.asarray(wi, float)
    wo = np.asarray(wo, float)
    ci, co = wi[..., 2], wo[..., 2]
    si = np.hypot(wi[..., 0], wi[..., 1])
    so = np.hypot(wo[..., 0], wo[..., 1])
    den = si * so
    dot = wi[..., 0] * wo[..., 0] + wi[..., 1] * wo[..., 1]
    cross = wi[..., 0] * wo[..., 1] - wi[..., 1] * wo[..., 0]
    ok = den > 1e-300
    safe = np.where(ok, den, 1.0)
    cos_phi = np.where(ok, -dot / safe, 1.0)
    sin_phi = np.where(ok, -cross / safe, 0.0)
    return cos_phi, sin_phi, si, ci, so, co


def q_amplitudes(wi, wo, n, k=0.0):
    """The complex amplitudes ``(q_ss, q_pp, q_ps, q_sp)`` for pairs ``wi``, ``wo[..., 3]``
    (pointing away from the surface) and index ``n + ik``; ``n``, ``k`` broadcast against
    the leading shape (e.g. ``n[None, :]`` with ``wi[:, None, :]`` for per-channel indices)."""
    cos_phi, sin_phi, si, ci, so, co = scattering_azimuth(wi, wo)
    eps = (np.asarray(n, float) + 1j * np.asarray(k, float)) ** 2
    qi = np.sqrt(eps - si * si + 0j)
    qs = np.sqrt(eps - so * so + 0j)
    e1 = eps - 1.0
    a_s_i = ci + qi          # s denominators
    a_s_s = co + qs
    a_p_i = eps * ci + qi    # p denominators
    a_p_s = eps * co + qs
    q_ss = e1 * cos_phi / (a_s_i * a_s_s)
    q_pp = e1 * (eps * si * so - qs * qi * cos_phi) / (a_p_i * a_p_s)
    q_ps = -e1 * qi * sin_phi / (a_p_i * a_s_s)
    q_sp = -e1 * qs * sin_phi / (a_s_i * a_p_s)
    return q_ss, q_pp, q_ps, q_sp


def q_components(wi, wo, n, k=0.0):
    """``(Q_ss, Q_pp, Q_ps, Q_sp)`` = |q_αβ|² (see :func:`q_amplitudes`)."""
    return tuple(np.abs(q) ** 2 for q in q_amplitudes(wi, wo, n, k))


def q_sum(wi, wo, n, k=0.0):
    """Plain sum Q_ss + Q_pp + Q_ps + Q_sp (= R_s + R_p = 2 F at the mirror direction):
    the factor of Small et al. 2021, Eqs. 6 and 8."""
    return sum(q_components(wi, wo, n, k))


def q_unpolarized(wi, wo, n, k=0.0):
    """Half-sum ½(Q_ss + Q_pp + Q_ps + Q_sp): the unpolarized factor, equal to the Fresnel
    reflectance at the mirror direction."""
    return 0.5 * q_sum(wi, wo, n, k)


def q_jones(wi, wo, n, k=0.0):
    """The Jones matrices ``[..., 2, 2]`` = [[q_ss, q_ps], [q_sp, q_pp]] (first index: scattered
    polarization; SCATMECH's ``psps`` basis) of :func:`q_amplitudes`."""
    q_ss, q_pp, q_ps, q_sp = q_amplitudes(wi, wo, n, k)
    return np.stack([np.stack([q_ss, q_ps], axis=-1), np.stack([q_sp, q_pp], axis=-1)], axis=-2)


def q_mueller(wi, wo, n, k=0.0):
    """Mueller matrices ``[..., 4, 4]`` of :func:`q_jones`, in SCATMECH's ``psps`` basis and circular
    sign (:func:`brdftab.polarization.mueller_from_jones`); element (0, 0) is :func:`q_unpolarized`."""
    from ..polarization import mueller_from_jones

    return mueller_from_jones(q_jones(wi, wo, n, k), circular=-1)


@device
def q_sum_scalar(wix, wiy, wiz, wox, woy, woz, n, k):
    """:func:`q_sum` of one pair (the compiled kernels' form; same arithmetic)."""
    ci, co = wiz, woz
    si = math.hypot(wix, wiy)
    so = math.hypot(wox, woy)
    den = si * so
    if den > 1e-300:
        cos_phi = -(wix * wox + wiy * woy) / den
        sin_phi = -(wix * woy - wiy * wox) / den
    else:
        cos_phi, sin_phi = 1.0, 0.0
    z = complex(n, k)
    eps = z * z
    qi = cmath.sqrt(eps - si * si + 0j)
    qs = cmath.sqrt(eps - so * so + 0j)
    e1 = eps - 1.0
    a_s_i = ci + qi
    a_s_s = co + qs
    a_p_i = eps * ci + qi
    a_p_s = eps * co + qs
    q_ss = e1 * cos_phi / (a_s_i * a_s_s)
    q_pp = e1 * (eps * si * so - qs * qi * cos_phi) / (a_p_i * a_p_s)
    q_ps = -e1 * qi * sin_phi / (a_p_i * a_s_s)
    q_sp = -e1 * qs * sin_phi / (a_s_i * a_p_s)
    return abs(q_ss) ** 2 + abs(q_pp) ** 2 + abs(q_ps) ** 2 + abs(q_sp) ** 2


@device
def q_unpolarized_scalar(wix, wiy, wiz, wox, woy, woz, n, k):
    """:func:`q_unpolarized` of one pair (the compiled kernels' form; same arithmetic)."""
    return 0.5 * q_sum_scalar(wix, wiy, wiz, wox, woy, woz, n, k)
