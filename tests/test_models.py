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
