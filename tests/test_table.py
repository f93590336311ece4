"""Tables: tabulation, metadata, evaluation by interpolation; the table's domain (outside it:
NaN with one warning, an error, or the nearest node), cells next to the horizon, evaluation in
slabs, and the memory guard."""

import json
import warnings

import numpy as np
import pytest

import brdftab
from brdftab import models
from brdftab.errors import BrdftabError, BrdftabWarning, ParameterError
from brdftab.geometry import normalize, rot_z, sph_to_vec
from brdftab.grids import RusinkiewiczGrid, SphericalGrid, merl_grid
from brdftab.table import tabulate

GGX = models.create("microfacet", alpha=0.3, fresnel="conductor", n=[0.2, 0.4, 1.4], k=[3.5, 2.4, 1.8])
PLAIN_GGX = models.create("microfacet", alpha=0.3)  # no Fresnel term: one channel


def sph(theta_deg, phi_deg):
    return sph_to_vec(np.radians(theta_deg), np.radians(phi_deg))


def random_pairs(n, seed=0, max_theta=np.radians(85)):
    rng = np.random.default_rng(seed)
    # uniform in cosθ between cos(max_theta) and 1
    ti = np.arccos(rng.uniform(np.cos(max_theta), 1, n))
    to = np.arccos(rng.uniform(np.cos(max_theta), 1, n))
    return sph_to_vec(ti, rng.uniform(-np.pi, np.pi, n)), sph_to_vec(to, rng.uniform(-np.pi, np.pi, n))


@pytest.fixture(scope="module")
def merl_table():
    return tabulate(GGX, merl_grid(), progress=False)


def test_metadata(merl_table):
    ds = merl_table.ds
    assert ds["brdf"].attrs["units"] == "sr-1"
    assert ds["brdf"].dims == ("theta_h", "theta_d", "phi_d", "channel")
    assert list(ds["channel"].values) == ["R", "G", "B"]
    for c in ("theta_h", "theta_d", "phi_d"):
        assert ds[c].attrs["units"] == "rad"
    a = ds.attrs
    assert a["parameterization"] == "rusinkiewicz" and a["sample_position"] == "bin-centre"
    assert a["phi_d_fold"] == "reciprocity" and a["model"] == "microfacet"
    assert json.loads(a["parameters"])["alpha"] == 0.3
    assert a["brdftab_version"] == brdftab.__version__ and a["created"]


def test_values_equal_model_at_nodes(merl_table):
    """The table holds the model at its nodes: the same zeros (horizon) and values to 1e-12,
    the compiled kernels' bound (the tabulation takes D at each exact half-vector node and F at
    each θd node; eval computes them from normalize(wi + wo): the last digits differ)."""
    wi, wo = merl_table.grid.directions()
    v, f = merl_table.values.reshape(-1, 3), GGX.eval(wi, wo)
    assert np.array_equal(v == 0, f == 0)
    assert np.max(np.abs(v - f) / np.where(f > 0, f, 1.0)) <= 1e-12


@pytest.mark.parametrize("grid, brdf", [
    (merl_grid(), GGX),
    (merl_grid("lower-edge"), GGX),
    (RusinkiewiczGrid(20, 15, 36, phi_d_fold="none"), GGX),
    (RusinkiewiczGrid(12, 10, 18, 24), models.create("microfacet", alpha_x=0.1, alpha_y=0.4)),
    (SphericalGrid(np.radians([10, 40, 70]), np.radians([0, 90, 180, 270]), np.radians(np.arange(1, 90, 4)),
                   np.radians(np.arange(0, 360, 20))), models.create("microfacet", alpha_x=0.1, alpha_y=0.4)),
    (SphericalGrid(np.radians([20, 60]), [0.0], np.radians(np.linspace(-3, 3, 13)), np.radians([-2, 0, 2]),
                   relative_to="specular"), GGX),
], ids=["merl", "merl-edge", "rus-none", "rus-aniso", "spherical", "sph-rel"])
def test_table_at_its_own_nodes_is_exact(grid, brdf):
    table = tabulate(brdf, grid, progress=False)
    wi, wo = grid.directions()
    got = table.eval(wi, wo)
    stored = table.values.reshape(got.shape)
    above = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    # Nodes at θh = 0 or θd = 0 (lower-edge) are degenerate: all their φ nodes are one
    # physical configuration, so they are equal only to rounding.
    th, _, td, _ = brdftab.geometry.io_to_hd(wi, wo)
    degenerate = (th < 1e-9) | (td < 1e-9) if grid.parameterization == "rusinkiewicz" else np.zeros(len(wi), bool)
    ok = above & ~degenerate
    assert np.array_equal(got[ok], stored[ok])
    assert np.allclose(got[above & degenerate], stored[above & degenerate], rtol=1e-9)
    assert np.all(got[~above] == 0)


def test_merl_table_between_nodes_near_what_multilinear_achieves(merl_table):
    # GGX α = 0.3 on the MERL grid at random pairs (between nodes). Multilinear interpolation
    # measures median 8.4e-4, p90 1.4e-3; a nearest-node lookup gives 1.3e-2 / 3.4e-2.
    wi, wo = random_pairs(20000, seed=1)
    f = GGX.eval(wi, wo)
    t = merl_table.eval(wi, wo)
    keep = f > 1e-3 * f.max()
    rel = np.abs(t[keep] - f[keep]) / f[keep]
    assert np.median(rel) < 1.2e-3
    assert np.percentile(rel, 90) < 2e-3
    assert rel.max() < 1e-2


def _merl_node_directions(i, j, k, position):
    """MERL node (i, j, k) as (wi, wo), from the published bin formula and an explicit
    rotation Rz(φh = 0)·Ry(θh) of d = sph(θd, φd) — independent of brdftab's grids."""
    u = 0.5 if position == "bin-centre" else 0.0
    th = ((i + u) / 90) ** 2 * np.pi / 2
    td = np.radians(j + u)
    pd = np.radians(k + u)
    d = np.stack([np.sin(td) * np.cos(pd), np.sin(td) * np.sin(pd), np.cos(td)], -1)
    c, s = np.cos(th), np.sin(th)
    ry = np.array([[c, 0 * c, s], [0 * c, 1 + 0 * c, 0 * c], [-s, 0 * c, c]])  # [3, 3, n]
    wi = np.einsum("abn,nb->na", ry, d)
    wo = np.einsum("abn,nb->na", ry, d * [-1, -1, 1])
    return wi, wo


@pytest.mark.parametrize("position", ["bin-centre", "lower-edge"])
def test_merl_table_at_independently_computed_nodes(position):
    table = tabulate(GGX, merl_grid(position), progress=False)
    rng = np.random.default_rng(11)
    i, j, k = rng.integers(0, 90, 3000), rng.integers(1, 90, 3000), rng.integers(0, 180, 3000)
    wi, wo = _merl_node_directions(i, j, k, position)
    above = (wi[:, 2] > 1e-6) & (wo[:, 2] > 1e-6) & (i > 0)
    wi, wo, i, j, k = wi[above], wo[above], i[above], j[above], k[above]
    assert np.allclose(table.eval(wi, wo), GGX.eval(wi, wo), rtol=1e-9)
    assert np.array_equal(table.values[i, j, k], table.eval(wi, wo))


def test_bilateral_fold_is_applied(merl_table):
    # With φd ≡ −φd the stored axis is [0, π]: pairs with φd < 0 are right only if the table
    # folds them (without the fold they would clamp to the φd = 0 node).
    grid = RusinkiewiczGrid(45, 45, 90, phi_d_fold="bilateral")
    t = tabulate(GGX, grid, progress=False)
    wi, wo = random_pairs(20000, seed=5)
    _, _, _, pd = brdftab.geometry.io_to_hd(wi, wo)
    neg = pd < -0.2
    f = GGX.eval(wi, wo)[neg]
    keep = f > 1e-3 * f.max()
    rel = np.abs(t.eval(wi, wo)[neg][keep] - f[keep]) / f[keep]
    assert np.median(rel) < 4e-3 and neg.sum() > 5000
    mirror = wi * [1, -1, 1], wo * [1, -1, 1]  # mirror image: φd -> −φd
    assert np.allclose(t.eval(*mirror), t.eval(wi, wo), rtol=1e-12)


def test_table_honours_reciprocity_fold(merl_table):
    wi, wo = random_pairs(500, seed=2)
    assert np.allclose(merl_table.eval(wi, wo), merl_table.eval(wo, wi), rtol=1e-12)


def test_isotropic_table_rotation_invariant(merl_table):
    wi, wo = random_pairs(500, seed=3)
    a = merl_table.eval(wi, wo)
    b = merl_table.eval(rot_z(wi, 1.234), rot_z(wo, 1.234))
    assert np.allclose(a, b, rtol=1e-9)


def test_spherical_isotropic_single_phi_i_rotates():
    grid = SphericalGrid(np.radians(np.arange(0, 90, 5)), [0.0], np.radians(np.arange(0, 90, 5)),
                         np.radians(np.arange(0, 360, 10)))
    lam = models.create("sum", terms=[models.create("lambert", albedo=0.5), models.create("microfacet", alpha=0.5)])
    t = tabulate(lam, grid, progress=False)
    # a node pair rotated by 37° about the normal reads the same node value
    wi, wo = grid.directions()
    rot = t.eval(rot_z(wi, np.radians(37)), rot_z(wo, np.radians(37)))
    assert np.allclose(rot, t.values.reshape(-1, 1), rtol=1e-9)


def test_spectral_table_interpolates_wavelength():
    spectral = models.create("lambert", albedo={"wavelengths_nm": [400, 500, 700], "values": [0.1, 0.3, 0.7]})
    t = tabulate(spectral, RusinkiewiczGrid(4, 4, 4), wavelengths=[400, 500, 700], progress=False)
    assert t.spectral and list(t.wavelengths) == [400, 500, 700]
    wi, wo = sph_to_vec(0.2, 0.0), sph_to_vec(0.3, 1.0)
    assert t.eval(wi, wo, [450, 600]) == pytest.approx(np.array([0.2, 0.5]) / np.pi)
    assert t.eval(wi, wo) == pytest.approx(np.array([0.1, 0.3, 0.7]) / np.pi)


def test_chunk_size_does_not_change_values():
    g = RusinkiewiczGrid(10, 9, 8)
    a = tabulate(GGX, g, chunk_size=7, progress=False)
    b = tabulate(GGX, g, chunk_size=1 << 20, progress=False)
    assert np.array_equal(a.values, b.values)


def test_float32_tabulation():
    t = tabulate(GGX, RusinkiewiczGrid(6, 6, 6), dtype="float32", progress=False)
    assert t.values.dtype == np.float32


def test_table_eval_shapes():
    t = tabulate(GGX, RusinkiewiczGrid(6, 6, 6), progress=False)
    wi = normalize(np.ones((4, 5, 3)))
    assert t.eval(wi, wi).shape == (4, 5, 3)


def test_anisotropic_model_on_isotropic_grid_is_refused():
    from brdftab.errors import ParameterError

    aniso = models.create("microfacet", alpha_x=0.1, alpha_y=0.4)
    with pytest.raises(ParameterError, match="anisotropic"):
        tabulate(aniso, RusinkiewiczGrid(8, 8, 16), progress=False)


def test_long_eval_is_chunked_and_equal(monkeypatch):
    import brdftab.brdf as brdf_module

    wi, wo = random_pairs(1000, seed=9, max_theta=np.radians(95))  # some below the horizon
    whole = GGX.eval(wi, wo)
    monkeypatch.setattr(brdf_module, "EVAL_CHUNK", 7)
    assert np.array_equal(GGX.eval(wi, wo), whole)
    assert np.all(whole[wo[:, 2] <= 0] == 0)


def test_progress_bar_shown_only_when_asked(monkeypatch, capsys):
    import brdftab.table as table_module

    monkeypatch.setattr(table_module, "PROGRESS_DELAY", 0.0)
    tabulate(GGX, RusinkiewiczGrid(8, 8, 8), chunk_size=64, progress=True)
    assert "tabulating" in capsys.readouterr().err
    tabulate(GGX, RusinkiewiczGrid(8, 8, 8), chunk_size=64, progress=False)
    assert capsys.readouterr().err == ""


# -- near the horizon: no exact zeros from a model that is not zero there ------------------------

def _grazing_pairs(n, seed):
    """Pairs with θi or θo in (89.5°, 90°) (uniform in cosθ there; the other direction uniform in
    cosθ over the hemisphere), azimuths uniform."""
    rng = np.random.default_rng(seed)
    near = np.arccos(rng.uniform(0.0, np.cos(np.radians(89.5)), n))
    other = np.arccos(rng.uniform(0.0, 1.0, n))
    swap = rng.random(n) < 0.5
    ti, to = np.where(swap, near, other), np.where(swap, other, near)
    return sph_to_vec(ti, rng.uniform(-np.pi, np.pi, n)), sph_to_vec(to, rng.uniform(-np.pi, np.pi, n))


@pytest.mark.parametrize("name, params, bound", [
    ("lambert", {"albedo": 0.5}, 1e-12),
    # measured over 10⁶ such pairs: worst −0.49, where θh lies beyond the last θh node (89.0°) and
    # the table holds that node's value; elsewhere ≤ 0.34 (a coarse θh axis near 90°)
    ("microfacet", {"alpha": 0.05}, 0.5),
])
def test_merl_table_near_the_horizon_has_no_exact_zeros(name, params, bound):
    model = models.create(name, **params)
    table = tabulate(model, merl_grid(), progress=False)
    wi, wo = _grazing_pairs(300_000, seed=4)
    f, t = model.eval(wi, wo), table.eval(wi, wo)
    assert np.all(f > 0)
    # before: ~1.6e-4 of these pairs read exactly 0 (every corner of their cell below the horizon)
    assert np.count_nonzero(t == 0) == 0
    rel = np.abs(t - f) / f
    assert rel.max() < bound


def test_cells_with_every_corner_below_the_horizon_take_the_nearest_data():
    # (θh, θd) near 90° with φd ≈ ±90°: wi and wo graze the horizon on opposite sides of h; the
    # φd nodes either side (±0.5°) put wi or wo below it, so no corner of the cell holds data
    from brdftab.geometry import hd_to_io

    rng = np.random.default_rng(2)
    n = 200_000
    th, td = np.radians(rng.uniform(80, 89, n)), np.radians(rng.uniform(80, 89.9, n))
    pd = np.radians(rng.choice([-90.0, 90.0], n) + rng.uniform(-0.2, 0.2, n))
    wi, wo = hd_to_io(th, 0.0, td, pd)
    keep = (wi[:, 2] > 1e-6) & (wo[:, 2] > 1e-6)
    wi, wo = wi[keep], wo[keep]
    assert keep.sum() > 1000
    for model, bound in ((models.create("lambert", albedo=0.5), 1e-12),
                         # measured here: −0.18 … +0.02 of the model (−0.25 at worst over 2·10⁶ grazing
                         # pairs): the nearest data lies a few nodes away. Before: 18 574 of these were 0
                         (models.create("microfacet", alpha=0.05), 0.3)):
        table = tabulate(model, merl_grid(), progress=False)
        f, t = model.eval(wi, wo), table.eval(wi, wo)
        assert np.count_nonzero(t == 0) == 0
        assert np.max(np.abs(t - f) / f) < bound


def test_table_metadata_history_and_label_form_of_channels():
    from brdftab.errors import FormatError
    from brdftab.table import Table

    t = tabulate(GGX, RusinkiewiczGrid(3, 3, 3), progress=False)
    assert t.ds.attrs["history"].endswith(f"table of microfacet on {t.grid.describe()}")
    assert t.ds.attrs["created"] in t.ds.attrs["history"]
    # the CF label form (as netCDF stores it) gives the same table; the caller's dataset is untouched
    ds = t.ds.drop_vars("channel").assign_coords(channel_name=("channel", [b"R", b"G", b"B"]))
    again = Table(ds)
    assert again.channels == ("R", "G", "B") and "channel_name" in ds.coords and "channel" not in ds.variables
    np.testing.assert_array_equal(again.values, t.values)
    bare = t.ds.copy()
    bare["brdf"].attrs = {}
    with pytest.raises(FormatError, match="no 'units' attribute"):
        Table(bare)


# -- a table knows its domain ------------------------------------------------------------------

@pytest.fixture(scope="module")
def gonio30():
    g = SphericalGrid(np.radians([30]), [0.0], np.radians(np.arange(0, 86, 5)), np.radians(np.arange(0, 360, 10)))
    return tabulate(PLAIN_GGX, g, progress=False)


def test_outside_theta_i_is_nan_with_one_warning(gonio30):
    t = gonio30
    t._warned = False
    with pytest.warns(BrdftabWarning, match="outside the domain"):
        f = t.eval(sph(50, 0), sph(50, 180))
    assert np.isnan(f).all()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # warned once per table
        assert np.isnan(t.eval(sph(50, 0), sph(40, 180))).all()
    # inside: the node value
    assert t.eval(sph(30, 0), sph(30, 180))[0] == pytest.approx(PLAIN_GGX.eval(sph(30, 0), sph(30, 180))[0],
                                                                rel=1e-12)
    # an isotropic table rotates φi onto its node: not outside
    assert np.isfinite(t.eval(sph(30, 77), sph(30, 257))).all()
    # θo = 88° is beyond the last θo node (85°)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert np.isnan(t.eval(sph(30, 0), sph(88, 180))).all()


def test_outside_modes(gonio30):
    t = gonio30
    t.outside = "raise"
    try:
        with pytest.raises(BrdftabError, match=r"theta_i in \[30, 30\] deg"):
            t.eval(sph(50, 0), sph(50, 180))
        t.outside = "clamp"
        assert np.isfinite(t.eval(sph(50, 0), sph(50, 180))).all()
        with pytest.raises(ParameterError):
            t.outside = "bogus"
    finally:
        t.outside = "nan"


def test_specular_zoom_is_outside_far_from_specular():
    g = SphericalGrid(np.radians([40]), [0.0], np.radians(np.linspace(-2, 2, 9)), np.radians(np.linspace(-2, 2, 9)),
                      relative_to="specular")
    t = tabulate(PLAIN_GGX, g, progress=False)
    t.outside = "raise"
    assert np.isfinite(t.eval(sph(40, 0), sph(41, 181))).all()
    with pytest.raises(BrdftabError, match="outside"):
        t.eval(sph(40, 0), sph(60, 180))
    with pytest.raises(BrdftabError, match="outside"):
        t.eval(sph(40, 0), sph(40, 150))


def test_folds_and_periodic_axes_and_bin_edges_are_inside():
    t = tabulate(PLAIN_GGX, merl_grid(), progress=False)
    t.outside = "raise"
    rng = np.random.default_rng(0)
    wi = sph_to_vec(np.arccos(rng.uniform(0.02, 1, 5000)), rng.uniform(-np.pi, np.pi, 5000))
    wo = sph_to_vec(np.arccos(rng.uniform(0.02, 1, 5000)), rng.uniform(-np.pi, np.pi, 5000))
    assert np.isfinite(t.eval(wi, wo)).all()
    assert np.isfinite(t.eval(sph(30, 0), sph(30, 180))).all()  # θh = 0: before the first bin centre


def test_isotropic_table_rotates_phi_i_outside_its_nodes():
    m = models.create("lambert", albedo=0.5)
    m2 = models.create("sum", terms=[m, PLAIN_GGX])
    g = SphericalGrid(np.radians([20, 40]), np.radians([0, 10, 20]), np.radians(np.arange(0, 90, 5)),
                      np.radians(np.arange(0, 360, 10)))
    t = tabulate(m2, g, progress=False)
    wi, wo = sph_to_vec(np.radians(40), np.radians(100)), sph_to_vec(np.radians(40), np.radians(280))
    # φi = 100° is not covered; rotated onto φi = 0 it is the mirror configuration, a node
    assert t.eval(wi, wo)[0] == pytest.approx(m2.eval(wi, wo)[0], rel=1e-9)


# -- interpolation next to the horizon -----------------------------------------------------------

def test_horizon_cells_no_worse_than_elsewhere():
    t = tabulate(PLAIN_GGX, merl_grid(), progress=False)
    assert t.eval(sph(43.7, 0), sph(89, 26))[0] == pytest.approx(PLAIN_GGX.eval(sph(43.7, 0), sph(89, 26))[0],
                                                                 rel=0.01)
    rng = np.random.default_rng(1)
    n = 400000
    lo = np.cos(np.radians(89))
    wi = sph_to_vec(np.arccos(rng.uniform(lo, 1, n)), rng.uniform(0, 2 * np.pi, n))
    wo = sph_to_vec(np.arccos(rng.uniform(lo, 1, n)), rng.uniform(0, 2 * np.pi, n))
    f, g = PLAIN_GGX.eval(wi, wo)[:, 0], t.eval(wi, wo)[:, 0]
    rel = np.abs(g - f) / f
    # cells touching the horizon: any corner node below it
    above = t.grid.node_above_horizon()
    idx = t.grid.fractional_index(wi, wo)
    touch = np.zeros(n, bool)
    for corner in np.ndindex(2, 2, 2):
        sel = []
        for a, (ax, x) in enumerate(zip(t.grid.axes, idx)):
            i = np.floor(x).astype(int) + corner[a]
            sel.append(i % len(ax) if ax.period else np.clip(i, 0, len(ax) - 1))
        touch |= ~above[tuple(sel)]
    assert touch.sum() > 1000
    assert rel[touch].max() <= 1.1 * rel[~touch].max()  # measured before the fix: 0.43 against 7.6e-3


def test_table_with_horizon_nodes_interpolates_sanely():
    m = models.create("microfacet", alpha=0.3, shadowing="v-groove")
    g = SphericalGrid(np.radians([80, 85, 90]), [0.0], np.radians([80, 85, 90]), [np.pi])
    t = tabulate(m, g, progress=False)
    assert np.all(np.isfinite(t.values)) and t.values.max() < 1e3
    wi, wo = sph_to_vec(np.radians(87.5), 0.0), sph_to_vec(np.radians(87.5), np.pi)
    assert t.eval(wi, wo)[0] < 10 * m.eval(wi, wo)[0]


# -- evaluation in slabs ---------------------------------------------------------------------------

def test_slab_evaluation_equals_whole_table_evaluation(tmp_path, monkeypatch):

    path = tmp_path / "t.nc"
    brdftab.save(tabulate(PLAIN_GGX, merl_grid(), progress=False), path)
    rng = np.random.default_rng(4)
    wi = sph_to_vec(np.arccos(rng.uniform(0.05, 1, 2000)), rng.uniform(0, 6.3, 2000))
    wo = sph_to_vec(np.arccos(rng.uniform(0.05, 1, 2000)), rng.uniform(0, 6.3, 2000))
    whole = brdftab.open(path).eval(wi, wo)
    monkeypatch.setenv("BRDFTAB_MEMORY", "8M")  # a window of a few θh rows
    t = brdftab.open(path)
    near = wi[:, 2] > 0.9  # queries near the normal use few θh slabs
    got = t.eval(wi[near], wo[near])
    assert t._values is None  # never loaded whole
    np.testing.assert_allclose(got, whole[near], rtol=1e-12)
    np.testing.assert_allclose(t.eval(wi, wo), whole, rtol=1e-12)


# -- tabulation: wavelengths and the memory guard --------------------------------------------------

def test_unsorted_table_wavelengths_are_refused():
    m = models.create("lambert", albedo={"wavelengths_nm": [400, 700], "values": [0.1, 0.2]})
    with pytest.raises(ParameterError, match="increase"):
        tabulate(m, RusinkiewiczGrid(2, 2, 2), wavelengths=[700, 400, 550], progress=False)


def test_memory_guard_uses_the_measured_peak(monkeypatch):
    from brdftab import table as table_mod

    g = merl_grid()
    out = g.size * 3 * 4  # float32 output bytes
    monkeypatch.setattr(table_mod, "available_memory", lambda: int(1.5 * out))  # > table, < its measured peak
    with pytest.raises(BrdftabError, match="GiB of memory"):
        tabulate(PLAIN_GGX, g, dtype="float32", progress=False)
    monkeypatch.setattr(table_mod, "available_memory", lambda: int(3 * out + (64 << 20)))
    assert tabulate(PLAIN_GGX, g, dtype="float32", progress=False).values.dtype == np.float32


def test_table_larger_than_memory_is_refused_before_allocating():
    g = RusinkiewiczGrid(1_000_000, 1_000_000, 1_000_000)
    with pytest.raises(BrdftabError, match="GiB"):
        tabulate(PLAIN_GGX, g, progress=False)


# -- the compiled interpolation is the numpy one -------------------------------------------------

#: Pairs this close [rad] to where the last digit of a coordinate picks the cell or the branch —
#: a node (cell boundary; missing and below-horizon nodes are nodes), a domain edge (± its
#: tolerance), a periodic seam, the clamp point of a wrapped arc, the horizon, the θh pole —
#: are left out of the parity test: there the compiled and numpy paths may round a coordinate
#: to different sides, and both answers are right.
PARITY_MARGIN = 1e-9


def _near_boundaries(table, wi, wo):
    """Bool per pair: within PARITY_MARGIN of a cell boundary, domain edge, seam, the horizon
    or the θh pole (see PARITY_MARGIN)."""
    from brdftab.geometry import io_to_hd, vec_to_sph
    from brdftab.grids.axis import DOMAIN_TOL

    grid = table.grid
    wi, wo = (np.array(w).reshape(-1, 3) for w in np.broadcast_arrays(normalize(wi), normalize(wo)))
    near = (np.abs(wi[:, 2]) < 2 * PARITY_MARGIN) | (np.abs(wo[:, 2]) < 2 * PARITY_MARGIN)
    coords = grid._coordinates(wi, wo, table.isotropic)
    raw = {}
    rotated = np.zeros(wi.shape[0], bool)
    if grid.parameterization == "spherical":
        raw[1] = vec_to_sph(wi)[1]  # the isotropic rotation asks whether φi is inside
        if table.isotropic:  # a rotated pair sits on the first φi node by construction: both snap
            ax = grid.axes[1]
            rotated = ax.outside(raw[1]) if len(ax) > 1 else np.ones(wi.shape[0], bool)
    else:
        near |= io_to_hd(wi, wo)[0] < PARITY_MARGIN
    for a, ax in enumerate(grid.axes):
        edges = list(ax.values)
        if ax.period is not None:
            edges += [ax.values[0] + ax.period]
            base, span = ax.values[0], ax.period
        else:
            lo, hi = ax.domain
            edges += [lo, hi, lo - DOMAIN_TOL, hi + DOMAIN_TOL]
            base, span = (ax.values[0], ax.wrap) if ax.wrap is not None else (None, None)
            if ax.wrap is not None:
                edges += [lo + ax.wrap - DOMAIN_TOL, lo + ax.wrap + DOMAIN_TOL,
                          0.5 * (ax.values[0] + ax.wrap + ax.values[-1]), ax.values[0] + ax.wrap]
        if ax.name == "dphi_o":
            edges += [-np.pi, np.pi]
        edges = np.asarray(edges)
        for x in [coords[a]] + ([raw[a]] if a in raw else []):
            xs = [x] if base is None else [x, base + np.mod(x - base, span)]
            for y in xs:
                d = np.min(np.abs(y[:, None] - edges[None, :]), axis=1) < PARITY_MARGIN
                near |= d & ~rotated if (a == 1 and x is coords[a]) else d
    return near


def _numpy_eval(table, wi, wo, wavelengths=None):
    """Table.eval through the numpy interpolation (the reference)."""
    from brdftab.brdf import BRDF

    table._eval = table._eval_numpy
    try:
        return BRDF.eval(table, wi, wo, wavelengths)
    finally:
        del table._eval


def _parity_pairs(n, seed):
    """Uniform pairs, pairs near the mirror direction and grazing ones, plus rows the
    evaluation must treat as every BRDF does: below the horizon, non-unit, non-finite."""
    rng = np.random.default_rng(seed)
    wi, wo = random_pairs(n, seed, max_theta=np.radians(89.999))
    k = n // 4
    wo[:k] = normalize(np.array([-1.0, -1.0, 1.0]) * wi[:k] + rng.normal(scale=0.05, size=(k, 3)))
    g = slice(k, 2 * k)
    wi[g] = sph_to_vec(np.radians(rng.uniform(80, 90, k)), rng.uniform(-np.pi, np.pi, k))
    wo[g] = sph_to_vec(np.radians(rng.uniform(80, 90, k)), rng.uniform(-np.pi, np.pi, k))
    wi[2 * k:2 * k + 5, 2] *= -1  # below the horizon
    wi[2 * k + 5:2 * k + 10] *= 3.0  # not unit
    wo[2 * k + 10, 1] = np.nan
    return wi, wo


def _assert_parity(table, wi, wo, wavelengths=None):
    keep = ~_near_boundaries(table, wi, wo)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BrdftabWarning)  # pairs outside the domain: NaN, said once
        got = table.eval(wi, wo, wavelengths)
        want = _numpy_eval(table, wi, wo, wavelengths)
    assert got.shape == want.shape and keep.mean() > 0.9
    np.testing.assert_allclose(got[keep], want[keep], rtol=1e-12, atol=0)
    return got, want, keep


def _with_missing(table, per_channel):
    """``table`` with a block of MERL-style negative markers (valid_min = 0) and a NaN sample
    declared missing: in every channel, or in one channel only."""
    ds = table.ds.copy(deep=True)
    v = ds["brdf"].values
    sl = (slice(3, 6), slice(2, 5), slice(0, 7))
    if per_channel:
        v[sl + (1,)] = -1.0
    else:
        v[sl] = -1.0
    v[(8, 8, 3)] = np.nan
    ds["brdf"].attrs.update(valid_min=0.0, missing_value=np.nan)
    return brdftab.table.Table(ds)


_ANISO_GGX = models.create("microfacet", alpha_x=0.2, alpha_y=0.5)


@pytest.mark.parametrize("make", [
    lambda: tabulate(GGX, RusinkiewiczGrid(16, 12, 24, theta_h_spacing="merl"), progress=False),
    lambda: tabulate(models.create("lambert", albedo=0.4), RusinkiewiczGrid(
        10, 9, 12, phi_d_fold="bilateral", sample_position="lower-edge"), dtype="float32", progress=False),
    lambda: tabulate(GGX, RusinkiewiczGrid(np.radians([0, 2, 5, 10, 20, 40, 60, 80, 89]), 10,
                                           np.radians([0, 20, 45, 70, 90]), phi_d_fold="reciprocity+bilateral"),
                     progress=False),
    lambda: tabulate(_ANISO_GGX, RusinkiewiczGrid(8, 8, 16, 12, phi_d_fold="none"), progress=False),
    lambda: tabulate(_ANISO_GGX, RusinkiewiczGrid(8, 8, 12, 12, phi_d_fold="reciprocity"), progress=False),
    lambda: _with_missing(tabulate(GGX, RusinkiewiczGrid(12, 12, 24, theta_h_spacing="merl"), progress=False),
                          per_channel=False),
    lambda: _with_missing(tabulate(GGX, RusinkiewiczGrid(12, 12, 24), progress=False), per_channel=True),
], ids=["merl-warp", "bilateral-float32-grey", "explicit-r+b", "aniso-none", "aniso-reciprocity",
        "missing-per-node", "missing-per-channel"])
def test_compiled_interpolation_equals_numpy_on_rusinkiewicz_grids(make):
    table = make()
    wi, wo = _parity_pairs(4000, 3)
    got, want, keep = _assert_parity(table, wi, wo)
    assert np.array_equal(np.isnan(got), np.isnan(want))  # NaN rows (missing, non-finite) agree everywhere
    # a direction broadcast against many, and the pairs a combinator hands to _eval
    _assert_parity(table, wi[7], wo)
    above = (wi[:, 2] > 0) & (wo[:, 2] > 0) & np.isfinite(wo).all(axis=1)
    a, b = normalize(wi[above]), normalize(wo[above])
    k = ~_near_boundaries(table, a, b)
    lam, n = None, table.layout.n_out(None)
    np.testing.assert_allclose(table._eval(a, b, lam, n)[k], table._eval_numpy(a, b, lam, n)[k], rtol=1e-12, atol=0)


def test_compiled_interpolation_equals_numpy_on_the_merl_grid(merl_table):
    from brdftab.geometry import hd_to_io

    wi, wo = _parity_pairs(3000, 4)
    _assert_parity(merl_table, wi, wo)
    # cells with every corner below the horizon (filled from the nearest data; see
    # test_cells_with_every_corner_below_the_horizon_take_the_nearest_data)
    rng = np.random.default_rng(5)
    th, td = np.radians(rng.uniform(80, 89, 3000)), np.radians(rng.uniform(80, 89.9, 3000))
    wi, wo = hd_to_io(th, 0.0, td, np.radians(rng.choice([-90.0, 90.0], 3000) + rng.uniform(-0.2, 0.2, 3000)))
    plan, _ = merl_table._kernel_plan()
    flags = np.empty(3000, np.uint8)
    assert plan.run(wi, wo, True, "nan", np.empty((3000, 3)), flags)[1] > 100
    _assert_parity(merl_table, wi, wo)


@pytest.mark.parametrize("outside", ["nan", "clamp"])
@pytest.mark.parametrize("make", [
    # periodic azimuths, θ up to 80° (beyond: outside), isotropic model, float32 samples
    lambda: tabulate(GGX, SphericalGrid(np.radians(np.arange(0, 81, 10)), np.radians(np.arange(0, 360, 30)),
                                        np.radians(np.arange(0, 81, 5)), np.radians(np.arange(0, 360, 15))),
                     dtype="float32", progress=False),
    # azimuths covering arcs only (wrapped axes); isotropic: φi outside its arc rotates onto it
    lambda: tabulate(GGX, SphericalGrid(np.radians(np.arange(0, 90, 10)), np.radians([0, 30, 60, 90]),
                                        np.radians(np.arange(0, 90, 10)), np.radians(np.arange(-60, 181, 20))),
                     progress=False),
    # anisotropic: no rotation, one φi node
    lambda: tabulate(_ANISO_GGX, SphericalGrid(np.radians(np.arange(0, 90, 10)), [0.0],
                                               np.radians(np.arange(0, 90, 10)), np.radians(np.arange(0, 360, 20))),
                     progress=False),
    # relative to the mirror direction, zoomed
    lambda: tabulate(GGX, SphericalGrid(np.radians(np.arange(20, 80, 10)), np.radians(np.arange(0, 360, 45)),
                                        np.radians(np.arange(-20, 21, 4)), np.radians(np.arange(-40, 41, 8)),
                                        relative_to="specular"), progress=False),
], ids=["periodic", "wrapped-arcs", "aniso-single-phi-i", "specular"])
def test_compiled_interpolation_equals_numpy_on_gonio_grids(make, outside):
    table = make()
    table.outside = outside
    wi, wo = _parity_pairs(4000, 5)
    got, want, keep = _assert_parity(table, wi, wo)
    if outside == "nan":
        assert np.isnan(got[keep]).any() and not np.isnan(got[keep]).all()
        table.outside = "raise"
        with pytest.raises(BrdftabError, match="outside the domain"):
            table.eval(wi, wo)


def test_compiled_interpolation_of_spectral_tables_and_bad_directions():
    spec = models.create("lambert", albedo={"wavelengths_nm": [400, 500, 600, 700], "values": [0.2, 0.4, 0.5, 0.7]})
    table = tabulate(spec, RusinkiewiczGrid(6, 6, 12), wavelengths=[400, 500, 600, 700], progress=False)
    wi, wo = _parity_pairs(400, 6)
    _assert_parity(table, wi, wo, wavelengths=[450, 650])
    with pytest.raises(ParameterError, match="zero length"):
        table.eval(np.zeros(3), wo)


def test_kernel_atan2_is_within_two_ulp_of_numpy():
    # the compiled coordinates use their own atan2 (brdftab._interp_kernels._atan2)
    import numba

    from brdftab._interp_kernels import _atan2
    from brdftab.models.fused import as_device

    atan2 = as_device(_atan2)   # (the compiled function, whether or not a kernel compiled it already)

    @numba.njit
    def run(a, b, out):
        for i in range(a.size):
            out[i] = atan2(a[i], b[i])

    rng = np.random.default_rng(1)
    n = 200_000
    a = rng.normal(size=n) * 10.0 ** rng.uniform(-12, 6, n)
    b = rng.normal(size=n) * 10.0 ** rng.uniform(-12, 6, n)
    special = np.array([0.0, -0.0, np.inf, -np.inf, np.nan, 1.0, -1.0, 1e-320, -1e-320])
    sa, sb = np.meshgrid(special, special)
    a, b = np.concatenate([a, sa.ravel()]), np.concatenate([b, sb.ravel()])
    got, want = np.empty(a.size), np.arctan2(a, b)
    run(a, b, got)
    fin = ~np.isnan(want)
    assert np.array_equal(np.isnan(got), np.isnan(want))
    assert np.array_equal(np.signbit(got[fin]), np.signbit(want[fin]))
    assert np.max(np.abs(got[fin] - want[fin]) / np.spacing(np.abs(want[fin]))) <= 2.0


def test_compiled_interpolation_equals_numpy_on_a_bilateral_cell_centred_grid():
    """An MDL .mbsdf grid (cell-centred θi, θo, |φo − φi| over [0, π], bilateral fold): compiled and
    numpy interpolation agree, every pair above the horizon is inside the domain, and mirroring
    both directions about a vertical plane changes nothing."""
    from brdftab.formats.mbsdf import mbsdf_grid

    table = tabulate(GGX, mbsdf_grid(9, 14), progress=False)
    wi, wo = _parity_pairs(4000, 8)
    got, want, keep = _assert_parity(table, wi, wo)
    rows = keep & np.all(np.isfinite(wi), axis=1) & np.all(np.isfinite(wo), axis=1) & (wi[:, 2] > 0)
    assert not np.isnan(got[rows]).any()
    mirror = np.array([1.0, -1.0, 1.0])
    np.testing.assert_allclose(table.eval(wi[rows] * mirror, wo[rows] * mirror), got[rows], rtol=1e-12, atol=0)


def test_gonio_rule_of_a_cell_centred_bilateral_table_covers_the_hemisphere_exactly():
    """The albedo rule of a table on an .mbsdf grid integrates from the domain edges (θo from 0 to
    90°, the half cells beyond the end nodes) and both halves of the mirror fold, with each θ cell's
    projected solid angle exact: a Lambertian table's albedo and coverage to rounding."""
    from brdftab.formats.mbsdf import mbsdf_grid
    from brdftab.integrate import directional_albedo

    table = tabulate(models.create("lambert", albedo=0.4), mbsdf_grid(6, 8), progress=False)
    a, c = directional_albedo(table, np.radians([0.0, 30.0, 75.0]), coverage=True)
    np.testing.assert_allclose(a, 0.4, rtol=1e-12)
    np.testing.assert_allclose(c, 1.0, rtol=1e-12)
