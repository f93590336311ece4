"""Reciprocity f(wi, wo) = f(wo, wi) of the symmetric models (property test)."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from brdftab import models
from brdftab.geometry import sph_to_vec

theta = st.floats(0.0, np.radians(89.5))
phi = st.floats(-np.pi, np.pi)
alpha = st.floats(0.01, 2.0)
index = st.floats(0.05, 5.0)


@st.composite
def microfacets(draw):
    params = {"distribution": draw(st.sampled_from(["ggx", "beckmann"])),
              "shadowing": draw(st.sampled_from(["smith", "smith-height-correlated", "v-groove", "none"])),
              "fresnel": draw(st.sampled_from(["none", "schlick", "dielectric", "conductor"]))}
    if draw(st.booleans()):
        params["alpha"] = draw(alpha)
    else:
        params["alpha_x"], params["alpha_y"] = draw(alpha), draw(alpha)
    if params["fresnel"] == "schlick":
        params["f0"] = [draw(st.floats(0, 1)) for _ in range(3)]
    if params["fresnel"] in ("dielectric", "conductor"):
        params["n"] = [draw(index) for _ in range(3)]
    if params["fresnel"] == "conductor":
        params["k"] = [draw(st.floats(0, 8)) for _ in range(3)]
    return models.create("microfacet", **params)


@st.composite
def brdfs(draw):
    kind = draw(st.sampled_from(["lambert", "microfacet", "sum"]))
    if kind == "lambert":
        return models.create("lambert", albedo=draw(st.floats(0, 1)))
    if kind == "microfacet":
        return draw(microfacets())
    return models.create("sum", terms=[models.create("lambert", albedo=0.3), draw(microfacets())])


@settings(max_examples=300, deadline=None)
@given(brdfs(), theta, phi, theta, phi)
def test_reciprocity(brdf, ti, pi_, to, po):
    assert brdf.reciprocal
    wi, wo = sph_to_vec(ti, pi_), sph_to_vec(to, po)
    a = brdf.eval(wi, wo)
    b = brdf.eval(wo, wi)
    assert np.all(np.isfinite(a)) and np.all(a >= 0)
    assert np.allclose(a, b, rtol=1e-12, atol=1e-300)
