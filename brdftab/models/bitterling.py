"""Cook–Torrance with an incidence-dependent roughness α(θi) (Bitterling et al., Pyromark 2500).

    f = D(h; α(θi)) F(θ_loc) G1(ω̂i; α(θi)) G1(ω̂o; α(θi)) / (4 cosθi cosθo) + R_dh,Lam / π

([Bitterling2024] Eqs. 11–15, with Eq. 12's GGX D — or Beckmann — and Eq. 14–15's separable
Smith G, F the unpolarized Fresnel reflectance of the real index n at the local angle
cosθ_loc = ω̂i·h (Eq. 11's F((θi − θr)/2) in the paper's signed in-plane angles), and
R_dh,Lam/π the uniform diffuse part, Eq. 9). The roughness follows the paper's empirical fit

    α(θi) = p1 (1 − tanh(p2 (θi − p3))) + p4        (Eq. 20)

with **θi and p3 in radians** inside the formula (the paper prints p3 = 51.51° in degrees;
with both in degrees p2 = 2.661 would make α a step from 0.4223 to 0.2199 at 51.5°, not the
sigmoid of its Fig. 4). With the paper's fit α = 0.4206 at 0°, 0.2831 at 60° and 0.2333 at
80° (tested). D and Λ are :func:`~brdftab.models.distributions.d_ggx` /
:func:`~brdftab.models.distributions.lambda_ggx` (or the Beckmann pair) evaluated with one α
per sample.

Because α depends on the incidence direction only, f(ω̂i, ω̂o) ≠ f(ω̂o, ω̂i): the model
declares itself non-reciprocal (its measured asymmetry is reported as WARN). For each
incidence direction it is a plain microfacet BRDF with a fixed α, so its lobe integrates like
one; energy conservation is not claimed (the Lambertian part is added on top).

References: [Bitterling2024] Eqs. 9, 11–15, 20; [Cook1982]; [Walter2007]; [Trowbridge1975].
"""

from __future__ import annotations

import math

import numpy as np

from .._jit import device
from ..brdf import Model
from ..params import Param
from .distributions import d_beckmann, d_ggx, lambda_beckmann, lambda_ggx
from .fresnel import INDEX_MIN, fresnel_dielectric
from ._registry import register

__all__ = ["CookTorranceAlphaTheta", "alpha_of_theta"]

_FUNCTIONS = {"ggx": (d_ggx, lambda_ggx), "beckmann": (d_beckmann, lambda_beckmann)}


def alpha_of_theta(theta_i, p1, p2, p3, p4):
    """Eq. 20: α(θi) = p1 (1 − tanh(p2 (θi − p3))) + p4, θi and p3 in radians.

    Evaluated as p1 · 2/(exp(2x) + 1) + p4 (the same function: 1 − tanh x = 2/(exp(2x) + 1)),
    which keeps its relative accuracy where tanh x → 1; 1 − tanh x loses it there (relative
    error ε/(1 − tanh x)), and the Beckmann exponent tan²θ/α² multiplies α's error by up to ~1500."""
    with np.errstate(over="ignore"):
        return p1 * (2.0 / (np.exp(2.0 * (p2 * (np.asarray(theta_i, float) - p3))) + 1.0)) + p4


@register
class CookTorranceAlphaTheta(Model):
    name = "cook-torrance-alpha-theta"
    summary = ("Cook–Torrance (GGX or Beckmann, separable Smith, dielectric Fresnel) with Bitterling's "
               "incidence-dependent roughness α(θi) = p1 (1 − tanh(p2 (θi − p3))) + p4, plus R_dh,Lam/π.")
    reference = "Bitterling2024; Cook1982; Walter2007; Trowbridge1975"
    params = (
        Param("distribution", "choice", "Microfacet normal distribution D (the paper uses GGX).", default="ggx",
              choices=tuple(_FUNCTIONS)),
        Param("n", "float", "Real refractive index of the Fresnel term.", minimum=INDEX_MIN, maximum=10.0),
        Param("r_dh_lam", "float", "Directional-hemispherical reflectance R_dh,Lam of the uniform diffuse part "
              "(the BRDF adds R_dh,Lam/π).", default=0.0, minimum=0.0, maximum=1.0),
        Param("p1", "float", "Amplitude p1 of the tanh step of α(θi) (Eq. 20).", minimum=0.0, maximum=1.0),
        Param("p2", "float", "Steepness p2 of the tanh step, per radian of θi.", units="1/rad", minimum=0.0,
              maximum=100.0),
        Param("p3", "float", "Centre p3 of the tanh step.", units="rad", minimum=0.0,
              maximum=float(np.pi / 2), angle=True),
        Param("p4", "float", "Grazing-incidence floor p4 of α(θi).", minimum=0.001, maximum=1.0),
    )
    reciprocal = False

    def _setup(self, distribution, n, r_dh_lam, p1, p2, p3, p4):
        self.distribution = distribution
        self._d, self._lambda = _FUNCTIONS[distribution]
        self.n = n
        self.r_dh_lam = r_dh_lam
        self.p1, self.p2, self.p3, self.p4 = p1, p2, p3, p4

    def alpha(self, theta_i):
        """α(θi) of Eq. 20 for incidence angles ``theta_i`` [rad]."""
        return alpha_of_theta(theta_i, self.p1, self.p2, self.p3, self.p4)

    @property
    def lobe_width(self) -> float:
        # the narrowest lobe: α decreases with θi, so its value at grazing incidence
        return float(self.alpha(0.5 * np.pi))

    def _kernel(self, lam, n):
        run = _alpha_theta_kernel(self.distribution)
        consts = np.array([self.p1, self.p2, self.p3, self.p4, self.n, self.r_dh_lam / np.pi])

        def evaluate(wi, wo, state, out, add):
            run(wi, wo, state, out, consts, bool(self.r_dh_lam), add)
        return evaluate

    def _eval(self, wi, wo, lam, n):
        theta_i = np.arctan2(np.hypot(wi[:, 0], wi[:, 1]), wi[:, 2])
        a = self.alpha(theta_i)
        h = wi + wo
        norm = np.sqrt(np.einsum("ij,ij->i", h, h))
        h /= norm[:, None]
        cos_d = 0.5 * norm  # wi·h = |wi + wo| / 2
        g = 1.0 / ((1.0 + self._lambda(wi, a)) * (1.0 + self._lambda(wo, a)))
        f = self._d(h, a) * g * fresnel_dielectric(cos_d, self.n) / (4.0 * wi[:, 2] * wo[:, 2])
        if self.r_dh_lam:
            f = f + self.r_dh_lam / np.pi
        return np.repeat(f[:, None], n, axis=1)


@device
def alpha_of_theta_scalar(wx, wy, wz, p1, p2, p3, p4):
    """:func:`alpha_of_theta` at the polar angle of the direction ``w`` (one direction; the polar
    angle from sqrt(x² + y²), within an ulp of the array form's hypot at a tenth of its cost)."""
    theta = math.atan2(math.sqrt(wx * wx + wy * wy), wz)
    return p1 * (2.0 / (math.exp(2.0 * (p2 * (theta - p3))) + 1.0)) + p4


_KERNEL = '''\
# Generated by brdftab.models.bitterling (do not edit): cook-torrance-alpha-theta with {dist}; sources {digest}
import math

import numba

from brdftab._jit import OPTIONS
from brdftab.models.bitterling import alpha_of_theta_scalar
from brdftab.geometry import pair_scalar
from brdftab.models.components import get
from brdftab.models.fresnel import dielectric_scalar
from brdftab.models.fused import as_device

_P = as_device(pair_scalar)
_ALPHA = as_device(alpha_of_theta_scalar)
_D = as_device(get("distribution", {dist!r}).jit_D)
_L = as_device(get("distribution", {dist!r}).jit_lambda)
_F = as_device(dielectric_scalar)


@numba.njit(**OPTIONS)
def run(wi, wo, state, out, k, diffuse, add):
    nc = out.shape[1]
    for i in range(wi.shape[0]):
        if state[i] != 1:
            continue
        wix, wiy, wiz, wox, woy, woz = _P(wi, wo, i)
        a = _ALPHA(wix, wiy, wiz, k[0], k[1], k[2], k[3])
        pa = (a, a)
        hx = wix + wox
        hy = wiy + woy
        hz = wiz + woz
        norm = math.sqrt(hx * hx + hy * hy + hz * hz)
        g = 1.0 / ((1.0 + _L(wix, wiy, wiz, pa)) * (1.0 + _L(wox, woy, woz, pa)))
        v = _D(hx / norm, hy / norm, hz / norm, pa) * g * _F(0.5 * norm, k[4]) / (4.0 * wiz * woz)
        if diffuse:
            v = v + k[5]
        for c in range(nc):
            out[i, c] = out[i, c] + v if add else v
'''


def _alpha_theta_kernel(dist):
    """The compiled loop of :class:`CookTorranceAlphaTheta` with distribution ``dist`` (the
    registered component's scalar D and Λ at one α per pair; generated so that an edit of a
    scalar form it inlines compiles anew)."""
    from .._jit import generated_module, source_hash
    from ..geometry import pair_scalar
    from .components import get
    from .fresnel import dielectric_scalar

    cls = get("distribution", dist)
    source = _KERNEL.format(dist=dist, digest=source_hash(alpha_of_theta_scalar, pair_scalar, cls.jit_D,
                                                          cls.jit_lambda, dielectric_scalar))
    return generated_module("alpha_theta", source).run
