"""Analytic models at the extremes of their parameters: tiny roughness is refused by its range
and small roughness stays finite; Fresnel terms at an index match are zero, not negative."""

import warnings

import numpy as np
import pytest

from brdftab import models
from brdftab.errors import ParameterError
from brdftab.geometry import sph_to_vec
from brdftab.models.fresnel import fresnel_conductor, fresnel_dielectric


def sph(theta_deg, phi_deg):
    return sph_to_vec(np.radians(theta_deg), np.radians(phi_deg))


def test_tiny_roughness_refused_by_its_range_and_small_ones_finite():
    with pytest.raises(ParameterError, match="alpha"):
        models.create("microfacet", alpha=1e-200)
    m = models.create("microfacet", alpha=1e-6, distribution="beckmann")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no RuntimeWarning reaches the user
        f = m.eval(sph_to_vec(np.radians(np.linspace(0, 89.9, 50)), 0.0), sph(30, 180))
    assert np.isfinite(f).all() and (f >= 0).all()


def test_conductor_fresnel_index_matched_is_zero_not_negative():
    c = np.linspace(0, 1, 10001)
    f = fresnel_conductor(c, 1.0, 0.0)
    assert np.all(np.isfinite(f)) and np.all(f >= 0) and f[1:].max() < 1e-12
    assert f[0] == 1.0  # exactly grazing
    d = fresnel_dielectric(c, 1.0)
    assert np.all(np.isfinite(d)) and d[1:].max() < 1e-12


def _shipped_models():
    from pathlib import Path

    from brdftab.spec import load_spec

    found = {}
    for path in sorted((Path(__file__).resolve().parents[1] / "specs").glob("*.toml")):
        m = load_spec(path).model
        found.setdefault(m.name, m)
    found.setdefault("microfacet-conductor", models.create("microfacet", alpha=0.3, fresnel="conductor", n=0.2, k=3))
    found.setdefault("microfacet-dielectric", models.create("microfacet", alpha=0.3, fresnel="dielectric", n=1.5))
    return found


@pytest.mark.parametrize("name, base", list(_shipped_models().items()))
def test_every_accepted_extreme_parameter_keeps_the_model_finite(name, base):
    """Each number parameter of each shipped model at the edges of what it accepts (its bounds,
    just inside an open bound, ±1e300 without one): refused as a ParameterError or finite at
    75 direction pairs up to 89.9°. An index n of 1e-300 or 1e300 and a He–Torrance cone of
    1e-8° were accepted and gave NaN or inf."""
    th = np.radians([0, 30, 60, 85, 89.9])
    wi = sph_to_vec(th, 0.0)
    wo = sph_to_vec(*np.meshgrid(th, np.radians([0, 90, 180]))).reshape(-1, 3)
    wi, wo = np.repeat(wi, len(wo), 0), np.tile(wo, (len(wi), 1))
    cls = type(base)
    tried = 0
    for p in cls.params:
        if p.kind not in ("float", "channel"):
            continue
        lo = [] if p.minimum is None else [p.minimum + 1e-300 if p.exclusive_minimum else p.minimum]
        edges = (lo or [-1e300]) + ([p.maximum] if p.maximum is not None else [1e300])
        if p.exclusive_minimum and p.minimum == 0:
            edges.append(1e-300)
        for x in edges:
            kw = {k: v for k, v in base._values.items() if v is not None}
            kw[p.name] = x
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # extrapolation notes of fitted models
                try:
                    m = cls(**kw)
                except ParameterError:
                    continue
                f = m.eval(wi, wo)
            tried += 1
            assert np.all(np.isfinite(f)), f"{name}: {p.name} = {x:g} accepted but f is not finite"
    assert tried > 0
