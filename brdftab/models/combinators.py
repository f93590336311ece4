"""Combinators: build a BRDF out of other BRDFs.

* ``sum`` — f = Σ f_k (e.g. a diffuse base plus a specular lobe);
* ``scale`` — f = s · f_term with s per channel or spectral.

Channels combine as in :func:`brdftab.channels.combine_layouts`: grey terms broadcast to the
others; RGB and spectral terms cannot be mixed. A combination is isotropic (reciprocal) when
every term is.

Reference: F. E. Nicodemus et al., NBS Monograph 160 (1977) — BRDFs of independent
scattering mechanisms add.
"""

from __future__ import annotations

import numpy as np

from ..brdf import Model
from ..channels import combine_layouts
from ..params import Param

__all__ = ["Sum", "Scale"]


class Sum(Model):
    name = "sum"
    summary = "Sum of terms, f = Σ f_k."
    reference = "Nicodemus1977"
    params = (Param("terms", "brdfs", "The BRDFs to add ([[model.terms]] tables in a spec).", units=""),)

    def _setup(self, terms):
        self.terms = terms
        self.layout = combine_layouts(t.layout for t in terms)
        self.isotropic = all(t.isotropic for t in terms)
        self.reciprocal = all(t.reciprocal for t in terms)
        # a sum of energy-conserving terms may exceed 1: nothing is claimed

    @property
    def lobe_width(self):
        widths = [t.lobe_width for t in self.terms if t.lobe_width is not None]
        return min(widths) if widths else None

    def _eval(self, wi, wo, lam, n):
        out = self.terms[0]._eval(wi, wo, lam, n)
        for t in self.terms[1:]:
            out = out + t._eval(wi, wo, lam, n)
        return out


class Scale(Model):
    name = "scale"
    summary = "A term multiplied by a per-channel or spectral factor, f = s · f_term."
    reference = "Nicodemus1977"
    params = (
        Param("factor", "channel", "Multiplier s (per channel or spectrum).", minimum=0.0),
        Param("term", "brdf", "The BRDF to scale ([model.term] table in a spec).", units=""),
    )

    def _setup(self, factor, term):
        self.factor = factor
        self.term = term
        self.layout = combine_layouts([factor.layout, term.layout])
        self.isotropic = term.isotropic
        self.reciprocal = term.reciprocal
        self.energy_conserving = term.energy_conserving and bool(np.all(factor.values <= 1.0))

    @property
    def lobe_width(self):
        return self.term.lobe_width

    def _eval(self, wi, wo, lam, n):
        return self.term._eval(wi, wo, lam, n) * np.asarray(self.factor.at(lam, n))[None, :]
