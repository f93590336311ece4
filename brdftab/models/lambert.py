"""Lambertian (ideal diffuse) reflection.

``f = ρ / π`` [sr⁻¹] with ρ the directional-hemispherical reflectance (albedo) per channel.

Polarized, it is the ideal depolarizer: the Mueller matrix is diag(ρ/π, 0, 0, 0) in every basis
(reflected light is unpolarized whatever arrives).

Reference: J. H. Lambert, *Photometria* (1760); F. E. Nicodemus et al., *Geometrical
Considerations and Nomenclature for Reflectance*, NBS Monograph 160 (1977), §5.
"""

from __future__ import annotations

import numpy as np

from ..brdf import Model
from ..params import Param
from ._registry import register

__all__ = ["Lambert"]


@register
class Lambert(Model):
    name = "lambert"
    summary = "Ideal diffuse reflector, f = albedo / π."
    reference = "Lambert1760; Nicodemus1977"
    params = (
        Param("albedo", "channel", "Directional-hemispherical reflectance ρ (per channel or spectrum).",
              default=1.0, minimum=0.0, maximum=1.0),
    )

    polarized = True

    def _setup(self, albedo):
        self.albedo = albedo
        self.layout = albedo.layout
        self.energy_conserving = True

    def _kernel(self, lam, n):
        from .._brdf_kernels import constant_rows

        value = np.ascontiguousarray(np.broadcast_to(np.asarray(self.albedo.at(lam, n) / np.pi, float), (n,)))

        def evaluate(wi, wo, state, out, add):
            constant_rows(state, out, value, add)
        return evaluate

    def _eval(self, wi, wo, lam, n):
        rho = self.albedo.at(lam, n)
        return np.broadcast_to(rho / np.pi, (wi.shape[0], n)).copy()

    def _mueller(self, wi, wo, lam, n):
        out = np.zeros((wi.shape[0], n, 4, 4))
        out[:, :, 0, 0] = self._eval(wi, wo, lam, n)
        return out
