"""Small measured-like RGL ``.bsdf`` files for tests (the RGL database's files are not shipped).

A measurement differs from brdftab's own files in what it records and in its flaws: no
provenance (origin unknown, no reciprocity declared), a known asymmetry, a few negative
samples (noise below 0), and incidence measured only up to 80° (a grazing gap).
"""

from __future__ import annotations

import numpy as np

import brdftab
from brdftab.brdf import BRDF
from brdftab.formats import rgl
from brdftab.formats._tensor import write_tensor_file

#: Relative asymmetry injected: f(wi, wo) (1 + ASYM (cosθi − cosθo)).
ASYM = 0.6
THETA_I_MAX_DEG = 80.0


class Asymmetric(BRDF):
    """A reciprocal base times (1 + a (cosθi − cosθo)): not reciprocal, with a known asymmetry."""

    name = "asymmetric"

    def __init__(self, base, a):
        self.base, self.a = base, a
        self.layout = base.layout
        self.isotropic = base.isotropic
        self.reciprocal = False

    def _eval(self, wi, wo, lam, n):
        return self.base._eval(wi, wo, lam, n) * (1.0 + self.a * (wi[:, 2] - wo[:, 2]))[:, None]


def base_model():
    m = brdftab.models
    return m.create("sum", terms=[m.create("lambert", albedo=[0.2, 0.3, 0.4]),
                                  m.create("microfacet", alpha=0.25, fresnel="schlick", f0=[0.5, 0.4, 0.3])])


def measured_bsdf(path, asym: float = ASYM, negatives: int = 40, provenance: bool = False, **options):
    """Write a measured-like RGB ``.bsdf`` to ``path``; returns the model it samples.
    ``options`` override the format options (e.g. the RGL database's layout: ``resolution=32,
    vndf_resolution=128``)."""
    model = Asymmetric(base_model(), asym)
    opts = dict(n_theta_i=8, theta_i_max_deg=THETA_I_MAX_DEG, resolution=24, description="synthetic measurement")
    opts.update(options)
    payload = rgl.prepare_rgl(model, **opts)
    fields = dict(payload.fields)
    if not provenance:
        fields.pop("provenance")
    if negatives:
        rgb = fields["rgb"].copy()
        rng = np.random.default_rng(3)
        flat = rgb.reshape(-1)
        idx = rng.choice(flat.size, negatives, replace=False)
        flat[idx] = -np.abs(flat[idx]) * 0.01 - 1e-4
        fields["rgb"] = rgb
    write_tensor_file(path, fields)
    return model
