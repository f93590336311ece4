"""Geometry: spherical <-> vectors, rotations, Rusinkiewicz conversions."""

import numpy as np
import pytest

from brdftab.geometry import (THETA_H_ZERO, hd_to_io, io_to_hd, normalize, reflect, rot_x, rot_y, rot_z,
                              rotation_matrix, sph_to_vec, vec_to_sph)


def random_upper(rng, n):
    v = normalize(rng.normal(size=(n, 3)))
    v[:, 2] = np.abs(v[:, 2])
    return v


def wrap(a):
    """Angle difference wrapped to (-pi, pi]."""
    return np.angle(np.exp(1j * a))


def test_sph_round_trip():
    rng = np.random.default_rng(0)
    theta = rng.uniform(0, np.pi, 1000)
    phi = rng.uniform(-np.pi, np.pi, 1000)
    v = sph_to_vec(theta, phi)
    assert np.allclose(np.linalg.norm(v, axis=-1), 1.0, atol=1e-15)
    t2, p2 = vec_to_sph(v)
    assert np.max(np.abs(t2 - theta)) < 1e-12
    assert np.max(np.abs(wrap(p2 - phi))) < 1e-12


def test_rotations_match_rodrigues_matrix():
    rng = np.random.default_rng(1)
    v = rng.normal(size=(50, 3))
    for fn, axis in ((rot_x, [1, 0, 0]), (rot_y, [0, 1, 0]), (rot_z, [0, 0, 1])):
        a = 0.7
        expected = v @ rotation_matrix(axis, a).T
        assert np.allclose(fn(v, a), expected, atol=1e-14)
    # right-handed: +x rotated about +z by 90 degrees is +y
    assert np.allclose(rot_z([1.0, 0, 0], np.pi / 2), [0, 1, 0], atol=1e-15)
    assert np.allclose(rot_y([0, 0, 1.0], np.pi / 2), [1, 0, 0], atol=1e-15)


def test_reflect():
    assert np.allclose(reflect(sph_to_vec(0.3, 0.2), [0, 0, 1.0]), sph_to_vec(0.3, 0.2 + np.pi))


def test_round_trip_io_hd_io_random_pairs():
    rng = np.random.default_rng(2)
    wi, wo = random_upper(rng, 200_000), random_upper(rng, 200_000)
    wi2, wo2 = hd_to_io(*io_to_hd(wi, wo))
    assert np.max(np.abs(wi2 - wi)) < 1e-12
    assert np.max(np.abs(wo2 - wo)) < 1e-12


def test_round_trip_hd_io_hd_random_coordinates():
    rng = np.random.default_rng(3)
    n = 200_000
    th = rng.uniform(1e-6, np.pi / 2, n)
    ph = rng.uniform(-np.pi, np.pi, n)
    # θd -> 90° makes wi and wo antiparallel and h = normalize(wi + wo) ill-conditioned
    # (relative error ~ eps / cosθd), so this direction of the round trip stops at 89°.
    td = rng.uniform(0, np.radians(89), n)
    pd = rng.uniform(-np.pi, np.pi, n)
    th2, ph2, td2, pd2 = io_to_hd(*hd_to_io(th, ph, td, pd))
    assert np.max(np.abs(th2 - th)) < 1e-12
    assert np.max(np.abs(td2 - td)) < 1e-12
    assert np.max(np.abs(wrap(ph2 - ph))) < 1e-10  # φ precision degrades as 1/sinθ
    big = td > 1e-4
    assert np.max(np.abs(wrap(pd2 - pd)[big])) < 1e-10


@pytest.mark.parametrize("ti, pi_, to, po, th, td", [
    (30, 0, 60, 180, 15, 45),     # in the plane of incidence
    (45, 0, 45, 180, 0, 45),      # mirror pair: θh = 0, θd = θi
    (0, 0, 0, 0, 0, 0),           # both along the normal
    (60, 90, 0, 0, 30, 30),       # wi at 60°, wo at the normal: h bisects
    (40, 10, 40, 10, 40, 0),      # retro-reflection: h = wi, θd = 0
])
def test_hand_computed_cases(ti, pi_, to, po, th, td):
    wi = sph_to_vec(np.radians(ti), np.radians(pi_))
    wo = sph_to_vec(np.radians(to), np.radians(po))
    got = io_to_hd(wi, wo)
    assert np.degrees(got[0]) == pytest.approx(th, abs=1e-10)
    assert np.degrees(got[2]) == pytest.approx(td, abs=1e-10)


def test_hand_computed_azimuths():
    # θi=30°, φi=0; θo=60°, φo=180°: h lies in the x-z plane tilted towards -x (φh = 180°);
    # rotating wi into the half frame leaves d in the x-z plane pointing to -x: φd = ±180°.
    th, ph, td, pd = io_to_hd(sph_to_vec(np.radians(30), 0.0), sph_to_vec(np.radians(60), np.pi))
    assert abs(wrap(ph - np.pi)) < 1e-12
    assert abs(wrap(pd - np.pi)) < 1e-12
    # out of plane: wi at (60°, 90°), wo at the normal -> h at (30°, 90°), d = (θd=30°, φd=0)
    th, ph, td, pd = io_to_hd(sph_to_vec(np.radians(60), np.pi / 2), [0, 0, 1.0])
    assert np.degrees(ph) == pytest.approx(90, abs=1e-10)
    assert np.degrees(pd) == pytest.approx(0, abs=1e-10)


def test_theta_h_zero_is_defined_not_noise():
    # Mirror pairs: φh must be exactly 0 and φd the azimuth of wi, whatever rounding does.
    rng = np.random.default_rng(4)
    theta = rng.uniform(0, np.radians(89), 1000)
    phi = rng.uniform(-np.pi, np.pi, 1000)
    wi = sph_to_vec(theta, phi)
    wo = sph_to_vec(theta, phi + np.pi)
    th, ph, td, pd = io_to_hd(wi, wo)
    assert np.all(th < 1e-14)
    assert np.all(ph == 0.0)
    assert np.allclose(td, theta, atol=1e-12)
    assert np.max(np.abs(wrap(pd - phi))) < 1e-12
    # hd_to_io at θh = 0 with φh = 0 gives back the same pair
    wi2, wo2 = hd_to_io(0.0, 0.0, td, pd)
    assert np.allclose(wi2, wi, atol=1e-12) and np.allclose(wo2, wo, atol=1e-12)
    assert THETA_H_ZERO < 1e-9


def test_broadcasting_and_shapes():
    wi = sph_to_vec(np.radians([10, 20, 30]), 0.0)[:, None, :]   # (3, 1, 3)
    wo = sph_to_vec(np.radians([40, 50]), np.pi)[None, :, :]      # (1, 2, 3)
    out = io_to_hd(wi, wo)
    assert all(o.shape == (3, 2) for o in out)
    wi2, wo2 = hd_to_io(*out)
    assert wi2.shape == (3, 2, 3)
    assert np.allclose(wo2, np.broadcast_to(wo, (3, 2, 3)), atol=1e-12)


def test_merl_reference_indices_agree():
    # Rusinkiewicz coordinates reproduce MERL's reference lookup (BRDFRead.cpp) bin indices
    # for directions built from its inverse at bin centres.
    i, j, k = np.meshgrid(np.arange(90), np.arange(0, 90, 7), np.arange(0, 180, 11), indexing="ij")
    th = ((i + 0.5) / 90) ** 2 * np.pi / 2
    td = (j + 0.5) * np.pi / 180
    pd = (k + 0.5) * np.pi / 180
    wi, wo = hd_to_io(th, 0.0, td, pd)
    th2, _, td2, pd2 = io_to_hd(wi, wo)
    pd2 = np.where(pd2 < 0, pd2 + np.pi, pd2)
    assert np.array_equal(np.floor(90 * np.sqrt(th2 / (np.pi / 2))).astype(int), i)
    assert np.array_equal(np.floor(td2 / (np.pi / 2) * 90).astype(int), j)
    assert np.array_equal(np.floor(pd2 / np.pi * 180).astype(int), k)


@pytest.mark.parametrize("scale", [1e155, 1e300, 1e-160, 1e-320])
def test_huge_and_tiny_finite_directions_keep_their_direction(scale):
    """|v|² of [1e155, 0, 1e155] overflows (and of [1e-320, 0, 1e-320] underflows): the
    direction is still 45° from the normal, normalized and evaluated like [1, 0, 1]."""
    from brdftab import models

    v = np.array([scale, 0.0, scale])
    assert np.allclose(normalize(v), [np.sqrt(0.5), 0.0, np.sqrt(0.5)], rtol=0, atol=1e-15)
    ggx = models.create("microfacet", alpha=0.3)
    wo = np.array([-0.3, 0.2, 0.9])
    expected = ggx.eval([1.0, 0.0, 1.0], wo)
    assert expected[0] > 0.1
    assert np.allclose(ggx.eval(v, wo), expected, rtol=1e-14, atol=0)
    assert np.allclose(ggx.eval(wo, v), ggx.eval(wo, [1.0, 0.0, 1.0]), rtol=1e-14, atol=0)


def test_mirror_biased_pairs_cover_the_range_and_the_mirror_direction():
    """Unit pairs with cosθ in the range asked for; half of the wo within a few degrees of the
    mirror direction (slopes up to 0.5 standard deviations), the other half spread evenly."""
    from brdftab.geometry import mirror_biased_pairs, reflect

    c80 = np.cos(np.radians(80.0))
    wi, wo = mirror_biased_pairs(4000, np.random.default_rng(1), z_low=c80, z_span=1.0 - c80)
    assert np.allclose(np.linalg.norm(wi, axis=1), 1) and np.allclose(np.linalg.norm(wo, axis=1), 1)
    assert wi[:, 2].min() >= c80 and wo[:, 2].min() >= c80 and wi[:, 2].max() <= 1.0
    mirror = reflect(wi, np.array([0.0, 0.0, 1.0]))
    off = np.degrees(np.arccos(np.clip(np.sum(wo * mirror, axis=1), -1, 1)))
    assert np.median(off[:2000]) < 15 < np.median(off[2000:])
    # cosθ of wi uniform over its range (solid angle): mean in the middle of the range
    assert np.mean(wi[:, 2]) == pytest.approx((1 + c80) / 2, abs=0.01)
