"""Rayleigh–Rice polarization factor Q: identities, reference values, and Q as a Fresnel choice."""

import numpy as np
import pytest

from brdftab import models
from brdftab.geometry import sph_to_vec
from brdftab.models.fresnel import fresnel_amplitudes, fresnel_conductor
from brdftab.models.rayleigh_rice import q_components, q_sum, q_unpolarized

R = np.radians
INDICES = [(1.5, 0.0), (3.6, 0.0), (1.4, 0.0), (0.7686, 6.078), (4.05, 0.05)]


def pair(theta_i, theta_s, phi_s, phi_i=0.0):
    """wi toward the source at azimuth φi; the scattered direction at φs from the specular side
    (SCATMECH's convention: φs = 0 is the mirror azimuth φi + π)."""
    return sph_to_vec(theta_i, phi_i), sph_to_vec(theta_s, phi_i + np.pi + phi_s)


@pytest.mark.parametrize("n, k", INDICES)
def test_q_at_the_mirror_direction_is_fresnel(n, k):
    theta = R(np.array([0.0, 10.0, 30.0, 45.0, 60.0, 75.0, 85.0]))
    wi, wo = pair(theta, theta, 0.0, phi_i=0.3)
    qss, qpp, qps, qsp = q_components(wi, wo, n, k)
    rs, rp = fresnel_amplitudes(np.cos(theta), n + 1j * k)
    np.testing.assert_allclose(qss, np.abs(rs) ** 2, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(qpp, np.abs(rp) ** 2, rtol=1e-12, atol=1e-15)
    assert np.all(qps < 1e-25) and np.all(qsp < 1e-25)
    # the half-sum is the unpolarized Fresnel reflectance; Small et al.'s plain sum is twice it
    np.testing.assert_allclose(q_unpolarized(wi, wo, n, k), fresnel_conductor(np.cos(theta), n, k), rtol=1e-10)
    np.testing.assert_allclose(q_sum(wi, wo, n, k), 2 * fresnel_conductor(np.cos(theta), n, k), rtol=1e-10)


@pytest.mark.parametrize("n, k", INDICES)
def test_q_ss_vanishes_at_90_degrees_and_cross_terms_in_plane(n, k):
    rng = np.random.default_rng(1)
    ti, ts = rng.uniform(0.05, 1.5, 50), rng.uniform(0.05, 1.5, 50)
    qss, _, _, _ = q_components(*pair(ti, ts, R(90.0)), n, k)
    assert np.all(qss < 1e-28)
    for phi in (0.0, np.pi):
        _, _, qps, qsp = q_components(*pair(ti, ts, phi), n, k)
        assert np.all(qps < 1e-28) and np.all(qsp < 1e-28)


@pytest.mark.parametrize("n, k", INDICES)
def test_q_is_symmetric_under_exchange(n, k):
    rng = np.random.default_rng(2)
    m = 2000
    wi = sph_to_vec(rng.uniform(0, 1.55, m), rng.uniform(0, 2 * np.pi, m))
    wo = sph_to_vec(rng.uniform(0, 1.55, m), rng.uniform(0, 2 * np.pi, m))
    a = q_components(wi, wo, n, k)
    b = q_components(wo, wi, n, k)
    np.testing.assert_allclose(a[0], b[0], rtol=1e-10, atol=1e-14)   # ss
    np.testing.assert_allclose(a[1], b[1], rtol=1e-10, atol=1e-14)   # pp
    np.testing.assert_allclose(a[2], b[3], rtol=1e-10, atol=1e-14)   # ps <-> sp
    np.testing.assert_allclose(q_sum(wi, wo, n, k), q_sum(wo, wi, n, k), rtol=1e-12)
    # Q depends on the azimuth, not only on the angle to the half vector: not a Fresnel F(wi·h)
    assert np.ptp(q_unpolarized(*pair(R(30.0), R(45.0), R(np.array([0.0, 60.0, 120.0]))), n, k)) > 1e-3


@pytest.mark.parametrize("args, n, k, expected", [
    # SCATMECH Microroughness_BRDF_Model amplitudes, half-sum, computed independently for the
    # project's reference notes (models.md §5.1; the n = 1.5 specular value is Mitsuba's F(30°))
    ((30, 45, 0), 1.5, 0.0, {"Q": 0.04587134}),
    ((30, 45, 90), 1.5, 0.0, {"Qss": 0.0, "Qpp": 0.01029820, "Qps": 0.06706114, "Qsp": 0.06193815,
                              "Q": 0.06964875}),
    ((60, 30, 45), 1.5, 0.0, {"Q": 0.06967486}),
    ((30, 45, 90), 4.05, 0.05, {"Q": 0.63667460}),
    ((45, 20, 180), 0.7686, 6.078, {"Q": 2.02543847}),   # Q > 1 off specular for a metal: not clamped
    ((30, 30, 0), 1.5, 0.0, {"Q": 0.04152263}),
])
def test_q_reference_values(args, n, k, expected):
    wi, wo = pair(*R(np.array(args, float)))
    qss, qpp, qps, qsp = q_components(wi, wo, n, k)
    got = {"Qss": qss, "Qpp": qpp, "Qps": qps, "Qsp": qsp, "Q": q_unpolarized(wi, wo, n, k)}
    for key, value in expected.items():
        assert got[key] == pytest.approx(value, abs=2e-8), key


def test_rayleigh_rice_is_a_fresnel_choice_of_microfacet():
    common = dict(distribution="beckmann", alpha=0.2, shadowing="smith", n=[1.5, 0.2], k=[0.0, 3.0])
    mq = models.create("microfacet", fresnel="rayleigh-rice", **common)
    mf = models.create("microfacet", fresnel="conductor", **common)
    assert not mq.energy_conserving        # Q may exceed 1 off the mirror direction
    theta = R(np.linspace(0, 85, 18))
    wi = sph_to_vec(theta, 1.1)
    spec = wi * np.array([-1, -1, 1])
    np.testing.assert_allclose(mq.eval(wi, spec), mf.eval(wi, spec), rtol=1e-12)
    # off the mirror direction they differ (Q depends on θi, θs and φs, F on wi·h only)
    wo = sph_to_vec(R(40.0), 1.1 + np.pi + R(70.0))
    assert not np.allclose(mq.eval(wi[3], wo), mf.eval(wi[3], wo), rtol=1e-3)
    # and Q inside microfacet is the unpolarized half-sum
    h = (wi[3] + wo) / np.linalg.norm(wi[3] + wo)
    base = mq.dist.D(h) * mq.shadow.G(wi[3], wo, h, mq.dist) / (4 * wi[3][2] * wo[2])
    np.testing.assert_allclose(mq.eval(wi[3], wo), base * q_unpolarized(wi[3], wo, np.array([1.5, 0.2]),
                                                                          np.array([0.0, 3.0])), rtol=1e-12)
