"""Cook–Torrance microfacet reflection f = D(h) G(wi, wo) F(wi·h) / (4 cosθi cosθo).

``h = normalize(wi + wo)``. D is Beckmann or GGX (isotropic α or anisotropic α_x, α_y);
G is separable Smith, height-correlated Smith (exact Λ, including Beckmann's erfc form),
the Torrance–Sparrow V-groove, or none; F is none, Schlick, dielectric (real n) or conductor
(complex n + ik), per channel or per wavelength.

References
----------
* R. L. Cook, K. E. Torrance, "A reflectance model for computer graphics", ACM TOG 1, 7
  (1982) — the D·G·F/(4 cosθi cosθo) form and the V-groove G.
* B. Walter et al., "Microfacet models for refraction through rough surfaces", EGSR (2007),
  Eq. 20 — the same form with GGX and Smith G.
* E. Heitz, JCGT 3(2) (2014) — Smith Λ, height-correlated G2, anisotropy.
* M. Bitterling et al., Solar Energy — Eqs. 11–15 (GGX + separable Smith for Pyromark 2500).
"""

from __future__ import annotations

import numpy as np

from ..brdf import Model
from ..channels import combine_layouts
from ..errors import ParameterError
from ..params import Param
from .distributions import D_METHODS, LAMBDA_METHODS
from .fresnel import fresnel_conductor, fresnel_dielectric, fresnel_schlick

__all__ = ["Microfacet"]


class Microfacet(Model):
    name = "microfacet"
    summary = "Cook–Torrance microfacet BRDF D·G·F/(4 cosθi cosθo) with Beckmann or GGX."
    reference = ("R. L. Cook, K. E. Torrance, ACM TOG 1, 7 (1982); B. Walter et al., EGSR (2007); "
                 "E. Heitz, JCGT 3(2) (2014).")
    params = (
        Param("distribution", "choice", "Microfacet normal distribution D.", default="ggx",
              choices=("ggx", "beckmann")),
        Param("alpha", "float", "Isotropic roughness α (slope parameter of D).", default=None,
              minimum=0.0, exclusive_minimum=True, used_when="unless alpha_x/alpha_y"),
        Param("alpha_x", "float", "Roughness along the frame's x axis (anisotropic).", default=None,
              minimum=0.0, exclusive_minimum=True, used_when="with alpha_y, instead of alpha"),
        Param("alpha_y", "float", "Roughness along the frame's y axis (anisotropic).", default=None,
              minimum=0.0, exclusive_minimum=True, used_when="with alpha_x, instead of alpha"),
        Param("shadowing", "choice", "Shadowing–masking G.", default="smith",
              choices=("smith", "smith-height-correlated", "v-groove", "none")),
        Param("fresnel", "choice", "Fresnel term F.", default="none",
              choices=("none", "schlick", "dielectric", "conductor")),
        Param("f0", "channel", "Reflectance at normal incidence (Schlick).", default=None,
              minimum=0.0, maximum=1.0, used_when="fresnel = 'schlick'"),
        Param("n", "channel", "Real part of the relative refractive index.", default=None,
              minimum=0.0, exclusive_minimum=True, used_when="fresnel = 'dielectric' or 'conductor'"),
        Param("k", "channel", "Extinction coefficient (imaginary part of the index, n + ik).", default=None,
              minimum=0.0, used_when="fresnel = 'conductor'"),
    )

    _NEEDS = {"none": (), "schlick": ("f0",), "dielectric": ("n",), "conductor": ("n", "k")}

    def _setup(self, distribution, alpha, alpha_x, alpha_y, shadowing, fresnel, f0, n, k):
        if alpha is not None and (alpha_x is not None or alpha_y is not None):
            raise ParameterError("alpha", "give either alpha or alpha_x and alpha_y, not both")
        if alpha is None:
            if alpha_x is None or alpha_y is None:
                raise ParameterError("alpha", "missing roughness: give alpha (isotropic) or alpha_x and alpha_y")
            self.alpha_x, self.alpha_y = alpha_x, alpha_y
        else:
            self.alpha_x = self.alpha_y = alpha
        self.isotropic = self.alpha_x == self.alpha_y
        self.distribution = distribution
        self.shadowing = shadowing
        self.fresnel = fresnel
        given = {"f0": f0, "n": n, "k": k}
        for name in self._NEEDS[fresnel]:
            if given[name] is None:
                raise ParameterError(name, f"required when fresnel = '{fresnel}'")
        for name, value in given.items():
            if value is not None and name not in self._NEEDS[fresnel]:
                users = [f for f, need in self._NEEDS.items() if name in need]
                raise ParameterError(
                    name, f"only used with fresnel = {' or '.join(repr(u) for u in users)} (fresnel is '{fresnel}')"
                )
        self.f0, self.n, self.k = f0, n, k
        self.layout = combine_layouts([v.layout for v in given.values() if v is not None])
        self._d = D_METHODS[distribution]
        self._lambda = LAMBDA_METHODS[distribution]

    def _g(self, wi, wo):
        # With h = normalize(wi + wo) both wi·h and wo·h equal |wi + wo|/2 > 0 above the
        # horizon, so the χ⁺ factors of the Smith forms are 1 here.
        if self.shadowing == "none":
            return 1.0
        if self.shadowing == "v-groove":
            return None
        li = self._lambda(wi, self.alpha_x, self.alpha_y)
        lo = self._lambda(wo, self.alpha_x, self.alpha_y)
        if self.shadowing == "smith":
            return 1.0 / ((1.0 + li) * (1.0 + lo))
        return 1.0 / (1.0 + li + lo)

    def _f(self, cos_d, lam, n):
        c = cos_d[:, None]
        if self.fresnel == "none":
            return 1.0
        if self.fresnel == "schlick":
            return fresnel_schlick(c, self.f0.at(lam, n))
        if self.fresnel == "dielectric":
            return fresnel_dielectric(c, self.n.at(lam, n))
        return fresnel_conductor(c, self.n.at(lam, n), self.k.at(lam, n))

    def _eval(self, wi, wo, lam, n):
        h = wi + wo
        norm = np.sqrt(np.einsum("...i,...i->...", h, h))
        h /= norm[:, None]
        cos_d = 0.5 * norm  # wi·h = |wi + wo| / 2
        d = self._d(h, self.alpha_x, self.alpha_y)
        g = self._g(wi, wo)
        if g is None:  # V-groove
            g = np.minimum(1.0, 2.0 * h[:, 2] * np.minimum(wi[:, 2], wo[:, 2]) / cos_d)
        base = d * g / (4.0 * wi[:, 2] * wo[:, 2])
        f = self._f(cos_d, lam, n)
        return base[:, None] * f if np.ndim(f) else np.repeat(base[:, None], n, axis=1)
