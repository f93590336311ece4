"""Cook–Torrance microfacet reflection f = D(h) G(wi, wo) F(wi·h) / (4 cosθi cosθo).

``h = normalize(wi + wo)``. The model composes one registered component of each kind
(:mod:`brdftab.models.components`): a distribution D (``beckmann``, ``ggx``; isotropic α or
anisotropic α_x, α_y), a shadowing term G (``smith``, ``smith-height-correlated``,
``v-groove``, ``none``) and a Fresnel term F (``none``, ``schlick``, ``dielectric``,
``conductor``, ``rayleigh-rice``; per channel or per wavelength). Specs name the components with flat keys
(``distribution = "ggx"``, ``fresnel = "conductor"``, ``n``, ``k``); each component's own
parameters are accepted only with that component.

Polarized: with a ``dielectric``, ``conductor`` or ``rayleigh-rice`` Fresnel term the model has a
Mueller matrix, D·G·M_F/(4 cosθi cosθo), M_F the term's Fresnel Mueller matrix of the facet
h (computed in the facet's s/p frame and rotated into and out of it; see
:mod:`brdftab.models.components`). In the ``mitsuba`` basis it agrees with Mitsuba 3's polarized
``roughconductor`` (tests/test_polarization.py).

References: [Cook1982] the D·G·F/(4 cosθi cosθo) form and the V-groove G; [Walter2007] Eq. 20,
the same form with GGX and Smith G; [Heitz2014] Smith Λ, height-correlated G2, anisotropy;
[Bitterling2024] Eqs. 11–15, GGX + separable Smith for Pyromark 2500.
"""

from __future__ import annotations

import numpy as np

from ..brdf import Model
from . import components as C
from ._registry import register

__all__ = ["Microfacet", "ComposedParams"]


class ComposedParams:
    """Class attribute computed from the component registries at each access, so components
    registered after a model class still appear among its parameters and choices."""

    def __init__(self, build):
        self.build = build

    def __get__(self, obj, cls):
        return self.build()


def _microfacet_params():
    return (
        C.component_param("distribution", "ggx", "Microfacet normal distribution D."),
        *C.member_params("distribution"),
        C.component_param("shadowing", "smith", "Shadowing–masking G."),
        *C.member_params("shadowing"),
        C.component_param("fresnel", "none", "Fresnel term F ('none' reflects 100 %)."),
        *C.member_params("fresnel"),
    )


def split_components(values: dict, kinds=("distribution", "shadowing", "fresnel")) -> dict:
    """The flat parameter values of a composing model, by component kind (each kind's own
    parameters: the union over its registered members)."""
    out = {}
    for kind in kinds:
        names = {p.name for p in C.member_params(kind)}
        out[kind] = {k: v for k, v in values.items() if k in names}
    return out


@register
class Microfacet(Model):
    name = "microfacet"
    summary = "Cook–Torrance microfacet BRDF D·G·F/(4 cosθi cosθo) with Beckmann or GGX."
    reference = "Cook1982; Walter2007; Heitz2014"
    params = ComposedParams(_microfacet_params)

    def _setup(self, distribution, shadowing, fresnel, **values):
        parts = split_components(values)
        self.dist = C.build("distribution", distribution, parts["distribution"])
        self.shadow = C.build("shadowing", shadowing, parts["shadowing"])
        self.fres = C.build("fresnel", fresnel, parts["fresnel"])
        self.alpha_x = getattr(self.dist, "alpha_x", None)
        self.alpha_y = getattr(self.dist, "alpha_y", None)
        self.isotropic = self.dist.isotropic
        self.layout = self.fres.layout
        self.polarized = self.fres.polarized
        # D·G·F/(4 cos cos) conserves energy when G accounts for masking (G = 1 does not),
        # and when F does not exceed 1 (the Rayleigh–Rice Q can, away from the mirror direction)
        self.energy_conserving = shadowing != "none" and fresnel != "rayleigh-rice"

    @property
    def lobe_width(self) -> float:
        return self.dist.width

    @property
    def lobe_axes(self):
        return self.dist.axes

    @property
    def albedo_rule(self):
        """The distribution's own outgoing quadrature rule, when it has one (a pyramid's four
        facet lobes sit far from the mirror direction); else None (the generic rule)."""
        return getattr(self.dist, "albedo_rule", None)

    def ndf(self, h):
        """The normal distribution D(h) [sr⁻¹] at unit microfacet normals ``h[..., 3]`` (0 where h_z <= 0)."""
        return self.dist.D(np.asarray(h, float))

    def _kernel(self, lam, n):
        from .fused import microfacet_kernel

        run = microfacet_kernel(self.dist, self.shadow, self.fres)
        if run is None:
            return None
        pd = self.dist.jit_params()
        pf = np.ascontiguousarray(self.fres.jit_params(lam, n))

        def evaluate(wi, wo, state, out, add):
            run(wi, wo, state, out, pd, pf, add)
        return evaluate

    def tabulate_into(self, grid, lam, n, values, bar=None) -> bool:
        """On a Rusinkiewicz grid: D once per half-vector node, F once per θd node (unless it
        depends on the whole pair), G per pair (:func:`~brdftab.models.fused.microfacet_tabulation`)."""
        from ..grids.rusinkiewicz import RusinkiewiczGrid

        if not isinstance(grid, RusinkiewiczGrid) or self.kernel(lam, n) is None:
            return False
        from .fused import microfacet_tabulation

        run = microfacet_tabulation(self.dist, self.shadow, self.fres)
        if run is None:
            return False
        from .._jit import parallel_rows
        from ..brdf import HORIZON

        trig = grid.node_trig()
        cth, sth, cph, sph, ctd, std, cpd, spd = trig
        nh, nph, ntd, npd = len(cth), len(cph), len(ctd), len(cpd)
        h = np.stack([sth[:, None] * cph[None, :], sth[:, None] * sph[None, :],
                      np.broadcast_to(cth[:, None], (nh, nph))], axis=-1)
        with np.errstate(all="ignore"):
            d_nodes = np.ascontiguousarray(self.dist.D(h), float)
            f = self.fres.F(ctd, lam, n) if self.fres.depends != "pair" else 1.0
        f_nodes = np.ascontiguousarray(np.broadcast_to(np.asarray(f, float), (ntd, n)))
        pd = self.dist.jit_params()
        pf = np.ascontiguousarray(self.fres.jit_params(lam, n))
        out = values.reshape(nh, nph, ntd, npd, n)
        rows = max(1, (1 << 18) // max(1, nph * ntd * npd))  # θh rows between progress updates
        for lo in range(0, nh, rows):
            hi = min(nh, lo + rows)
            parallel_rows(lambda a, b: run(*trig, d_nodes, f_nodes, pd, pf, out, lo + a, lo + b, HORIZON),
                          hi - lo)
            if bar is not None:
                bar.update((hi - lo) * nph * ntd * npd)
        return True

    def _eval(self, wi, wo, lam, n):
        h = wi + wo
        norm = np.sqrt(np.einsum("...i,...i->...", h, h))
        h /= norm[:, None]
        cos_d = 0.5 * norm  # wi·h = |wi + wo| / 2
        base = self.dist.D(h) * self.shadow.G(wi, wo, h, self.dist) / (4.0 * wi[:, 2] * wo[:, 2])
        f = self.fres.F_pair(wi, wo, cos_d, lam, n)
        return base[:, None] * f if np.ndim(f) else np.repeat(base[:, None], n, axis=1)

    def _mueller(self, wi, wo, lam, n):
        h = wi + wo
        norm = np.sqrt(np.einsum("...i,...i->...", h, h))
        h = h / norm[:, None]
        base = self.dist.D(h) * self.shadow.G(wi, wo, h, self.dist) / (4.0 * wi[:, 2] * wo[:, 2])
        return base[:, None, None, None] * self.fres.F_mueller(wi, wo, 0.5 * norm, lam, n)
