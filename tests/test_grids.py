"""Grids: node positions, index <-> direction maps, folds, spec configuration; azimuth axes
that cover part of the circle, all of it, or (explicit φd slices) only their own arc."""

import numpy as np
import pytest

import brdftab
from brdftab import models
from brdftab.errors import BrdftabError, ParameterError
from brdftab.geometry import io_to_hd, sph_to_vec
from brdftab.grids import (RusinkiewiczGrid, SphericalGrid, fold_phi_d, grid_from_config, merl_grid)
from brdftab.table import tabulate

GGX = models.create("microfacet", alpha=0.3)


def sph(theta_deg, phi_deg):
    return sph_to_vec(np.radians(theta_deg), np.radians(phi_deg))


def test_merl_bin_centre_nodes():
    g = merl_grid()
    assert g.shape == (90, 90, 180) and g.dims == ("theta_h", "theta_d", "phi_d")
    i = np.arange(90)
    assert np.allclose(g.axes[0].values, ((i + 0.5) / 90) ** 2 * np.pi / 2, rtol=1e-15)
    assert np.allclose(g.axes[1].values, (i + 0.5) * np.pi / 180, rtol=1e-15)
    assert np.allclose(g.axes[2].values, (np.arange(180) + 0.5) * np.pi / 180, rtol=1e-15)
    assert g.attrs() == {"parameterization": "rusinkiewicz", "grid": "merl", "theta_h_spacing": "merl",
                         "phi_d_fold": "reciprocity", "sample_position": "bin-centre"}


def test_merl_lower_edge_nodes():
    g = merl_grid("lower-edge")
    i = np.arange(90)
    assert np.array_equal(g.axes[0].values, (i / 90) ** 2 * np.pi / 2)
    assert g.axes[1].values[0] == 0 and g.axes[2].values[0] == 0
    assert g.attrs()["sample_position"] == "lower-edge"


def test_merl_nodes_fall_in_reference_bins():
    # Every bin-centre node, pushed through directions and MERL's reference (floor) lookup,
    # lands in its own bin (formats reference §1.2).
    g = merl_grid()
    wi, wo = g.directions()
    th, _, td, pd = io_to_hd(wi, wo)
    pd = np.where(pd < 0, pd + np.pi, pd)
    i = np.clip(np.floor(90 * np.sqrt(th / (np.pi / 2))), 0, 89).astype(int)
    j = np.clip(np.floor(td / (np.pi / 2) * 90), 0, 89).astype(int)
    k = np.clip(np.floor(pd / np.pi * 180), 0, 179).astype(int)
    ii, jj, kk = np.unravel_index(np.arange(g.size), g.shape)
    assert np.array_equal(i, ii) and np.array_equal(j, jj) and np.array_equal(k, kk)


@pytest.mark.parametrize("grid", [
    merl_grid(),
    RusinkiewiczGrid(30, 20, 40, theta_h_spacing="linear", phi_d_fold="none"),
    RusinkiewiczGrid(30, 20, 40, phi_d_fold="bilateral"),
    RusinkiewiczGrid(30, 20, 40, phi_d_fold="reciprocity+bilateral"),
    RusinkiewiczGrid(16, 12, 24, 36, phi_d_fold="reciprocity"),
    RusinkiewiczGrid(np.radians([0.5, 1, 2, 5, 10, 30, 60]), 10, 18),
    SphericalGrid(np.radians([5, 30, 60]), np.radians([0, 40]), np.radians(np.arange(2.5, 90, 5)),
                  np.radians(np.arange(0, 360, 15))),
    SphericalGrid(np.radians([10, 45]), [0.0], np.radians(np.arange(-5, 5.1, 0.5)), np.radians([-4, -2, 0, 2, 4]),
                  relative_to="specular"),
], ids=["merl", "rus-none", "rus-bilateral", "rus-both", "rus-aniso", "rus-explicit", "spherical", "sph-rel"])
def test_index_round_trip(grid):
    wi, wo = grid.directions()
    idx = grid.fractional_index(wi, wo)
    expected = np.unravel_index(np.arange(grid.size), grid.shape)
    for a, got, exp in zip(grid.axes, idx, expected):
        assert np.array_equal(got, exp.astype(float)), a.name


def test_chunked_directions_equal_whole():
    g = RusinkiewiczGrid(10, 10, 20)
    wi, wo = g.directions()
    wi2, wo2 = g.directions(37, 211)
    assert np.array_equal(wi[37:211], wi2) and np.array_equal(wo[37:211], wo2)


@pytest.mark.parametrize("fold, lo, hi", [("none", 0, 2 * np.pi), ("reciprocity", 0, np.pi),
                                          ("bilateral", 0, np.pi), ("reciprocity+bilateral", 0, np.pi / 2)])
def test_fold_ranges_and_symmetries(fold, lo, hi):
    x = np.linspace(-np.pi, np.pi, 1001)
    f = fold_phi_d(x, fold)
    assert np.all(f >= lo) and np.all(f <= hi + 1e-15)
    if "reciprocity" in fold:
        assert np.allclose(fold_phi_d(x + np.pi, fold), f, atol=1e-12)
    if "bilateral" in fold:
        assert np.allclose(fold_phi_d(-x, fold), f, atol=1e-12)
    if fold == "none":
        assert np.allclose(np.cos(f), np.cos(x)) and np.allclose(np.sin(f), np.sin(x))


def test_swapping_wi_wo_adds_pi_to_phi_d():
    # the reason MERL's reciprocity fold is φd ≡ φd + π
    rng = np.random.default_rng(0)
    wi = sph_to_vec(rng.uniform(0, 1.4, 100), rng.uniform(-3, 3, 100))
    wo = sph_to_vec(rng.uniform(0, 1.4, 100), rng.uniform(-3, 3, 100))
    pd1 = io_to_hd(wi, wo)[3]
    pd2 = io_to_hd(wo, wi)[3]
    assert np.allclose(np.mod(pd2 - pd1, 2 * np.pi), np.pi, atol=1e-9)


def test_config_rusinkiewicz_and_ranges():
    g = grid_from_config({"type": "rusinkiewicz", "n_theta_h": 45, "theta_h_spacing": "merl", "n_theta_d": 30,
                          "phi_d_deg": [{"start": 0, "stop": 180, "step": 10, "endpoint": False}],
                          "sample_position": "lower-edge"})
    assert g.shape == (45, 30, 18)
    assert np.allclose(np.degrees(g.axes[2].values), np.arange(0, 180, 10))
    assert g.axes[0].warp == "sqrt"


def test_config_spherical_zoomed_around_specular():
    # a coarse theta_o sweep plus a fine 0.1° zoom around the mirror direction of θi = 30°
    g = grid_from_config({"type": "spherical", "theta_i_deg": [30], "phi_i_deg": [0],
                          "theta_o_deg": [{"start": 0, "stop": 85, "step": 5}, {"start": 29, "stop": 31, "step": 0.1}],
                          "phi_o_deg": [{"start": 0, "stop": 360, "num": 72, "endpoint": False}]})
    to = np.degrees(g.axes[2].values)
    assert np.all(np.diff(to) > 0) and np.isclose(to, 30.0).sum() == 1
    assert np.sum((to >= 29) & (to <= 31)) == 21
    assert g.axes[3].period == pytest.approx(2 * np.pi)
    rel = grid_from_config({"type": "spherical", "relative_to": "specular", "theta_i_deg": [10, 50],
                            "phi_i_deg": [0], "dtheta_o_deg": {"start": -2, "stop": 2, "num": 41},
                            "dphi_o_deg": {"start": -2, "stop": 2, "num": 41}})
    wi, wo = rel.directions()
    mid = np.ravel_multi_index((1, 0, 20, 20), rel.shape)
    assert np.allclose(wo[mid], sph_to_vec(np.radians(50), np.pi), atol=1e-12)


@pytest.mark.parametrize("cfg, key", [
    ({"type": "merl", "sample_position": "centre"}, "sample_position"),
    ({"type": "merll"}, "type"),
    ({"type": "merl", "n_theta_h": 10}, "n_theta_h"),
    ({"type": "rusinkiewicz", "n_theta_h": 0}, "n_theta_h"),
    ({"type": "rusinkiewicz", "n_theta_h": 2.5}, "n_theta_h"),
    ({"type": "rusinkiewicz", "phi_d_fold": "mirror"}, "phi_d_fold"),
    ({"type": "rusinkiewicz", "theta_h_deg": [0, 95]}, "theta_h_deg"),
    ({"type": "rusinkiewicz", "n_phi_h": 10}, "n_phi_h"),
    ({"type": "rusinkiewicz", "anisotropic": True, "phi_d_fold": "bilateral"}, "phi_d_fold"),
    ({"type": "spherical", "theta_i_deg": [0], "phi_i_deg": [0], "theta_o_deg": [0]}, "phi_o_deg"),
    ({"type": "spherical", "theta_i_deg": [0], "phi_i_deg": [0], "theta_o_deg": [0], "phi_o_deg": [0],
      "dphi_o_deg": [0]}, "dphi_o_deg"),
    ({"type": "spherical", "theta_i_deg": [{"start": 0, "stop": 10}], "phi_i_deg": [0], "theta_o_deg": [0],
      "phi_o_deg": [0]}, "theta_i_deg"),
])
def test_config_errors_name_the_key(cfg, key):
    with pytest.raises(ParameterError) as exc:
        grid_from_config(cfg)
    assert exc.value.key == key


def test_equality():
    assert merl_grid().equals(merl_grid())
    assert not merl_grid().equals(merl_grid("lower-edge"))
    assert not merl_grid().equals(RusinkiewiczGrid(90, 90, 180))  # linear θh


@pytest.mark.parametrize("grid", [merl_grid(), merl_grid("lower-edge"), RusinkiewiczGrid(8, 9, 10, 12, phi_d_fold="none"),
                                  RusinkiewiczGrid(np.radians([0, 10, 45, 80, 90]), np.radians([0, 30, 89.9, 90]), 7)])
def test_rusinkiewicz_horizon_mask_equals_the_directions(grid):
    # the closed form for wi_z, wo_z against the node directions themselves
    wi, wo = grid.directions()
    expected = ((wi[:, 2] > 1e-12) & (wo[:, 2] > 1e-12)).reshape(grid.shape)
    assert np.array_equal(grid.node_above_horizon(), expected)
    assert 0 < expected.sum() < expected.size


# -- azimuth axes ----------------------------------------------------------------------------------

def test_partial_phi_axis_returns_its_own_nodes():
    m = models.create("microfacet", alpha_x=0.2, alpha_y=0.5)
    g = SphericalGrid(np.radians([30]), np.radians([10]), np.radians([20, 40]), np.radians([200, 220, 240]))
    t = tabulate(m, g, progress=False)
    wi, wo = g.directions()
    assert np.array_equal(t.eval(wi, wo), t.values.reshape(-1, 1))
    # queries in the uncovered arc go to the nearer end node
    g_ax = g.axes[3]
    assert g_ax.fractional_index(np.radians([250, 180, 0, 190])).tolist() == [2, 0, 2, 0]  # 0° is 120° from 240°
    assert g_ax.fractional_index(np.radians([-100, -140])).tolist() == [2, 1]  # 260° and 220°


def test_zero_to_360_inclusive_is_one_full_periodic_axis():
    g = grid_from_config({"type": "spherical", "theta_i_deg": [30], "phi_i_deg": [0], "theta_o_deg": [30, 40],
                          "phi_o_deg": {"start": 0, "stop": 360, "step": 30}})
    ax = g.axes[3]
    assert len(ax) == 12 and ax.period == pytest.approx(2 * np.pi)
    m = models.create("sum", terms=[models.create("lambert", albedo=0.3), models.create("microfacet", alpha=0.4)])
    t = tabulate(m, g, progress=False)
    wi, wo = sph_to_vec(np.radians(30), 0.0), sph_to_vec(np.radians(30), np.radians(210))
    assert t.eval(wi, wo)[0] == pytest.approx(m.eval(wi, wo)[0], rel=0.05)


def test_explicit_phi_d_slices_cover_only_their_arc(tmp_path):
    # one φd slice (e.g. a single-slice EXR) is not an answer for every φd; an evenly spaced
    # list that goes round the fold's period stays periodic
    one = brdftab.grids.RusinkiewiczGrid(20, 20, np.radians([90.0]))
    assert one.axes[2].period is None and one.axes[2].domain == pytest.approx((np.pi / 2, np.pi / 2))
    t = tabulate(GGX, one, progress=False)
    t.outside = "raise"
    with pytest.raises(BrdftabError, match=r"phi_d in \[90, 90\] deg"):
        t.eval(sph(30, 0), sph(40, 115))
    ring = brdftab.grids.RusinkiewiczGrid(20, 20, np.radians(np.arange(0, 180, 10.0)))
    assert ring.axes[2].period == pytest.approx(np.pi)
    brdftab.save(t, tmp_path / "one.nc")
    assert brdftab.open(tmp_path / "one.nc").grid.axes[2].period is None


def test_wrapped_axis_domain_may_start_before_its_first_node():
    """Cell-centred azimuths (nodes at (k + ½)·30° over a [0, 180°] domain): a query between the
    domain's low edge and the first node is inside and takes the first node's value; the uncovered
    arc stays outside."""
    from brdftab.grids.axis import Axis

    ax = Axis("phi_o", np.radians([15.0, 45, 75, 105, 135, 165]), wrap=2 * np.pi, domain=(0.0, np.pi))
    x = np.radians([5.0, 0.0, 170, 180, 30, 200, 350])
    assert ax.outside(x).tolist() == [False, False, False, False, False, True, True]
    assert ax.fractional_index(x).tolist() == pytest.approx([0, 0, 5, 5, 0.5, 5, 0])


def test_bilateral_spherical_grid():
    """phi_d_fold = "bilateral": one φi node, φo nodes within [φi, φi + 180°]; a pair is folded
    onto |φo − φi|; the fold is kept by a table file."""
    g = grid_from_config({"type": "spherical", "theta_i_deg": [10, 50], "phi_i_deg": [0], "theta_o_deg": [20, 60],
                          "phi_o_deg": [0, 90, 180], "phi_d_fold": "bilateral"})
    assert g.attrs()["phi_d_fold"] == "bilateral"
    wi, wo = sph_to_vec(np.radians(10), np.radians(100)), sph_to_vec(np.radians(20), np.radians(100 - 90))
    c = g._coordinates(wi[None], wo[None])
    assert np.degrees([c[1][0], c[3][0]]) == pytest.approx([0, 90])
    for bad, key in (({"phi_i_deg": [0, 10]}, "phi_i"), ({"phi_o_deg": [0, 200]}, "phi_o"),
                     ({"relative_to": "specular", "dtheta_o_deg": [0], "dphi_o_deg": [0], "theta_o_deg": None,
                       "phi_o_deg": None}, "phi_d_fold")):
        cfg = {"type": "spherical", "theta_i_deg": [10], "phi_i_deg": [0], "theta_o_deg": [20], "phi_o_deg": [0],
               "phi_d_fold": "bilateral", **bad}
        with pytest.raises(ParameterError) as e:
            grid_from_config({k: v for k, v in cfg.items() if v is not None})
        assert e.value.key.startswith(key)
    with pytest.raises(ParameterError, match="anisotropic; a bilateral fold assumes isotropy"):
        tabulate(models.create("microfacet", alpha_x=0.1, alpha_y=0.3), g, progress=False)


# -- Klems and tensor-tree grids (Radiance XML) ----------------------------------------------------------

def test_klems_grid_patches_cover_the_hemisphere_and_nodes_locate_to_themselves():
    """Full, half and quarter Klems bases: the patches' projected solid angles sum to π; every node's
    directions (patch centres, the incident one turned by 180°) locate to that node; the patch of
    random directions is the one whose polar bounds and azimuth span hold them (written here)."""
    from brdftab.grids import KlemsGrid
    from brdftab.grids.klems import KLEMS_BASES

    for basis, n in (("full", 145), ("half", 77), ("quarter", 41)):
        g = KlemsGrid(basis)
        assert g.shape == (n, n) and g.lambdas.sum() == pytest.approx(np.pi, rel=1e-14)
        wi, wo = g.directions()
        idx, outside = g.locate(wi, wo)
        assert not outside.any()
        flat = np.ravel_multi_index([i.astype(int) for i in idx], g.shape)
        np.testing.assert_array_equal(flat, np.arange(g.size))
        rings = KLEMS_BASES[basis]
        rng = np.random.default_rng(0)
        v = sph_to_vec(np.arccos(rng.uniform(0.001, 1, 500)), rng.uniform(-np.pi, np.pi, 500))
        _, o = g.locate(np.tile([0.0, 0.0, 1.0], (500, 1)), v)[0]
        theta, phi = np.degrees(np.arccos(v[:, 2])), np.degrees(np.arctan2(v[:, 1], v[:, 0])) % 360
        for t, p, k in zip(theta, phi, o.astype(int)):
            first = 0
            for r, (lo, m) in enumerate(rings):
                hi = rings[r + 1][0] if r + 1 < len(rings) else 90.0
                if lo <= t < hi:
                    centre = 360.0 * (k - first) / m
                    assert 0 <= k - first < m and abs((p - centre + 180) % 360 - 180) <= 180.0 / m + 1e-9
                    break
                first += m


def test_tensor_tree_grid_maps_cells_as_radiance_does():
    """Shirley-Chiu's concentric maps invert each other; every node locates to itself (rank 3 and 4); a
    rank-3 table is the same for every incident azimuth (the outgoing direction turns with it); the
    outgoing rule integrates a constant to π."""
    from brdftab.grids import TensorTreeGrid
    from brdftab.grids.tensor_tree import disk2square, square2disk

    rng = np.random.default_rng(1)
    s = rng.random((2, 1000))
    np.testing.assert_allclose(disk2square(*square2disk(*s)), s, atol=1e-12)
    for rank, level in ((3, 3), (4, 2)):
        g = TensorTreeGrid(rank, level)
        wi, wo = g.directions()
        idx, outside = g.locate(wi, wo)
        assert not outside.any()
        np.testing.assert_array_equal(np.ravel_multi_index([i.astype(int) for i in idx], g.shape), np.arange(g.size))
        w_o, w = g.outgoing_rule(wi[0])
        assert (w * w_o[:, 2]).sum() == pytest.approx(np.pi, rel=1e-12)
    g = TensorTreeGrid(3, 4)
    wi, wo = sph_to_vec(np.radians(40.0), 0.0), sph_to_vec(np.radians(30.0), np.radians(150.0))
    turn = np.radians(77.0)
    rot = np.array([[np.cos(turn), -np.sin(turn), 0], [np.sin(turn), np.cos(turn), 0], [0, 0, 1]])
    a, b = g.locate(wi[None], wo[None])[0], g.locate((rot @ wi)[None], (rot @ wo)[None])[0]
    assert [float(x[0]) for x in a] == [float(x[0]) for x in b]
