"""MERL ``.binary``: byte layout, the reference lookup of BRDFRead.cpp, exact round trips,
missing samples, refusals and damaged files.

The reference reader below (half/difference angles, floor indexing, scale factors) is written
from the published BRDFRead.cpp formulas, independently of brdftab; every file is also read
back as raw bytes with NumPy, never only through brdftab.
"""

from __future__ import annotations

import struct

import numpy as np
import pytest
import xarray as xr
from click.testing import CliRunner

import brdftab
from brdftab import formats, models, pipeline
from brdftab.brdf import BRDF
from brdftab.channels import Layout
from brdftab.checks import run_checks
from brdftab.cli import main
from brdftab.errors import BrdftabError, BrdftabWarning, FormatError
from brdftab.grids import RusinkiewiczGrid, merl_grid
from brdftab.table import Table, make_table, tabulate

N = 90 * 90 * 180
SIZE = 12 + 3 * N * 8
#: BRDFRead.cpp: RED_SCALE = 1.0/1500, GREEN_SCALE = 1.15/1500, BLUE_SCALE = 1.66/1500
REF_SCALE = (1.0 / 1500, 1.15 / 1500, 1.66 / 1500)
GOLD = dict(n=[0.143119, 0.374957, 1.44248], k=[3.98316, 2.38572, 1.60322])


# --- an independent reference reader (BRDFRead.cpp) ------------------------------------------
def rotate_vector(v, axis, angle):
    """Rodrigues' rotation, as ``rotate_vector`` in BRDFRead.cpp (vectorized over v and angle)."""
    axis = np.asarray(axis, float)
    c, s = np.cos(angle)[..., None], np.sin(angle)[..., None]
    return v * c + axis * (v @ axis)[..., None] * (1 - c) + np.cross(axis, v) * s


def std_coords_to_half_diff_coords(wi, wo):
    half = (wi + wo) / 2
    half /= np.linalg.norm(half, axis=-1, keepdims=True)
    theta_h = np.arccos(np.clip(half[..., 2], -1, 1))
    phi_h = np.arctan2(half[..., 1], half[..., 0])
    diff = rotate_vector(rotate_vector(wi, (0, 0, 1), -phi_h), (0, 1, 0), -theta_h)
    theta_d = np.arccos(np.clip(diff[..., 2], -1, 1))
    phi_d = np.arctan2(diff[..., 1], diff[..., 0])
    return theta_h, theta_d, phi_d


def reference_index(theta_h, theta_d, phi_d):
    """theta_half_index / theta_diff_index / phi_diff_index of BRDFRead.cpp (floor into bins)."""
    i = np.where(theta_h <= 0, 0, np.floor(np.sqrt(np.maximum(theta_h, 0) / (np.pi / 2) * 90 * 90)))
    j = np.floor(theta_d / (np.pi / 2) * 90)
    phi_d = np.where(phi_d < 0, phi_d + np.pi, phi_d)  # reciprocity: phi_d -> phi_d + pi
    k = np.floor(phi_d / np.pi * 180)
    return (np.clip(i, 0, 89).astype(int), np.clip(j, 0, 89).astype(int), np.clip(k, 0, 179).astype(int))


def reference_lookup(raw_flat, wi, wo):
    """``lookup_brdf_val``: scaled R, G, B at the bins of the pairs, plus the bin indices."""
    i, j, k = reference_index(*std_coords_to_half_diff_coords(wi, wo))
    ind = k + 180 * (j + 90 * i)
    rgb = np.stack([raw_flat[c * N + ind] * REF_SCALE[c] for c in range(3)], axis=-1)
    return rgb, (i, j, k)


def sample_position(i, j, k, position="bin-centre"):
    """(θh, θd, φd) [rad] of bin (i, j, k) at its declared sample position (formats.md §1.4)."""
    u = 0.5 if position == "bin-centre" else 0.0
    return ((i + u) / 90) ** 2 * np.pi / 2, (j + u) * np.pi / 180, (k + u) * np.pi / 180


def half_diff_to_dirs(theta_h, theta_d, phi_d, phi_h=0.0):
    """wi = Rz(φh) Ry(θh) d and wo = Rz(φh) Ry(θh) (−dx, −dy, dz) (formats.md §1.2)."""
    theta_h, theta_d, phi_d, phi_h = np.broadcast_arrays(*(np.asarray(a, float) for a in
                                                           (theta_h, theta_d, phi_d, phi_h)))
    d = np.stack([np.sin(theta_d) * np.cos(phi_d), np.sin(theta_d) * np.sin(phi_d), np.cos(theta_d)], -1)
    d_mirror = d * np.array([-1.0, -1.0, 1.0])
    out = []
    for v in (d, d_mirror):
        ct, st = np.cos(theta_h), np.sin(theta_h)
        x = ct * v[..., 0] + st * v[..., 2]
        z = -st * v[..., 0] + ct * v[..., 2]
        cp, sp = np.cos(phi_h), np.sin(phi_h)
        out.append(np.stack([cp * x - sp * v[..., 1], sp * x + cp * v[..., 1], z], -1))
    return out[0], out[1]


def raw_planes(path):
    assert path.stat().st_size == SIZE
    assert struct.unpack("<3i", path.read_bytes()[:12]) == (90, 90, 180)
    return np.fromfile(path, "<f8", offset=12).reshape(3, 90, 90, 180)


def write_raw(path, raw):
    with open(path, "wb") as fh:
        fh.write(struct.pack("<3i", 90, 90, 180))
        fh.write(np.asarray(raw, "<f8").tobytes())
    return path


def random_hemisphere(rng, n):
    z = rng.uniform(0.02, 1.0, n)
    phi = rng.uniform(-np.pi, np.pi, n)
    s = np.sqrt(1 - z * z)
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], -1)


# --- fixtures --------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def ggx():
    return models.create("microfacet", alpha=0.2, fresnel="conductor", **GOLD)


@pytest.fixture(scope="module")
def ggx_file(tmp_path_factory, ggx):
    path = tmp_path_factory.mktemp("merl") / "ggx.binary"
    brdftab.save(ggx, path)
    return path


@pytest.fixture(scope="module")
def random_raw():
    """Arbitrary float64 bit patterns (NaN payloads, infinities, subnormals ...) and -1 markers."""
    rng = np.random.default_rng(2024)
    raw = rng.integers(0, 2**64, size=3 * N, dtype=np.uint64).view(np.float64).copy()
    raw[rng.integers(0, raw.size, 50_000)] = -1.0
    raw[:8] = [0.0, -0.0, np.inf, -np.inf, 5e-324, -5e-324, np.finfo(float).max, 1e-310]
    # measured-looking values too: decimal numbers of a few digits
    raw[8:200_008] = np.round(rng.uniform(0, 2000, 200_000), 3)
    return raw


# --- byte layout and the reference lookup ----------------------------------------------------
@pytest.mark.parametrize("position", ["bin-centre", "lower-edge"])
def test_reference_lookup_returns_the_model_at_the_declared_sample_position(tmp_path, ggx, ggx_file, position):
    path = ggx_file
    if position == "lower-edge":
        path = tmp_path / "ggx-lower.binary"
        brdftab.save(ggx, path, sample_position=position)
    raw = raw_planes(path).ravel()
    rng = np.random.default_rng(7)
    wi, wo = random_hemisphere(rng, 4000), random_hemisphere(rng, 4000)
    got, (i, j, k) = reference_lookup(raw, wi, wo)
    node_wi, node_wo = half_diff_to_dirs(*sample_position(i, j, k, position))
    want = ggx.eval(node_wi, node_wo)
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=0)
    assert np.mean(got[:, 0] > 0) > 0.5  # most looked-up bins hold data, not horizon zeros
    assert len(np.unique(i)) > 40  # the pairs cover the theta_h range


def test_specular_direction_lands_in_theta_h_bin_zero(ggx_file, tmp_path):
    sharp = models.create("microfacet", alpha=0.01, fresnel="conductor", **GOLD)
    path = tmp_path / "sharp.binary"
    brdftab.save(sharp, path)
    raw = raw_planes(path)
    theta = np.radians([0.7, 10.5, 33.5, 60.5, 80.5])
    phi = np.radians([0.5, 45.5, 100.5, 170.5, 300.5])
    wi = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1)
    wo = wi * np.array([-1.0, -1.0, 1.0])  # the mirror direction
    got, (i, j, k) = reference_lookup(raw.ravel(), wi, wo)
    assert i.tolist() == [0] * 5
    assert j.tolist() == [0, 10, 33, 60, 80]
    # bin 0 holds the model at theta_h = (0.5/90)^2 * 90 degrees, the peak of the sharp lobe
    node_wi, node_wo = half_diff_to_dirs(*sample_position(i, j, k))
    np.testing.assert_allclose(got, sharp.eval(node_wi, node_wo), rtol=1e-12, atol=0)
    assert np.all(raw[0, 0, j, k] > 3 * raw[0, 10, j, k])
    # brdftab's reader puts the same samples at the same bins
    values = brdftab.open(path).values
    np.testing.assert_array_equal(values[i, j, k], got)


def test_scale_factors_are_applied_on_read(tmp_path):
    raw = np.empty((3, 90, 90, 180))
    raw[0], raw[1], raw[2] = 1500.0, 3000.0, 4500.0
    table = brdftab.open(write_raw(tmp_path / "s.binary", raw))
    v = table.values
    assert table.channels == ("R", "G", "B")
    assert v.shape == (90, 90, 180, 3)
    assert np.all(v[..., 0] == 1500.0 * (1.0 / 1500))
    assert np.all(v[..., 1] == 3000.0 * (1.15 / 1500))
    assert np.all(v[..., 2] == 4500.0 * (1.66 / 1500))
    np.testing.assert_allclose(v[0, 0, 0], [1.0, 2.3, 4.98], rtol=1e-15)


def test_scale_factors_are_undone_on_write(tmp_path):
    values = np.empty((90, 90, 180, 3))
    values[...] = [0.5, 0.25, 0.125]
    values[3, 4, 5] = [1.0, 2.0, 3.0]  # planar order and index order: one distinct bin
    table = make_table(values, merl_grid(), Layout(("R", "G", "B")))
    path = tmp_path / "w.binary"
    brdftab.save(table, path)
    raw = raw_planes(path)
    assert np.all(raw[0][~_mask((3, 4, 5))] == 0.5 / (1.0 / 1500))
    assert np.all(raw[1][~_mask((3, 4, 5))] == 0.25 / (1.15 / 1500))
    assert np.all(raw[2][~_mask((3, 4, 5))] == 0.125 / (1.66 / 1500))
    np.testing.assert_allclose(raw[:, 0, 0, 0], [750.0, 326.0869565217391, 112.95180722891565], rtol=1e-15)
    flat = raw.ravel()
    ind = 5 + 180 * (4 + 90 * 3)
    assert [flat[c * N + ind] for c in range(3)] == [1.0 / (1.0 / 1500), 2.0 / (1.15 / 1500), 3.0 / (1.66 / 1500)]


def _mask(ijk):
    m = np.zeros((90, 90, 180), bool)
    m[ijk] = True
    return m


def test_grey_model_is_written_to_all_three_planes(tmp_path):
    path = tmp_path / "grey.binary"
    brdftab.save(models.create("lambert", albedo=0.3), path)
    raw = raw_planes(path)
    f = 0.3 / np.pi
    for c in range(3):
        assert raw[c, 0, 0, 0] == pytest.approx(f / REF_SCALE[c], rel=1e-15)
    assert np.all(raw[:, 89, 89] == 0)  # bins whose sample position is below the horizon: 0 by default


# --- exact round trips -----------------------------------------------------------------------
def test_model_merl_netcdf_merl_is_byte_identical(tmp_path, ggx_file):
    table = brdftab.open(ggx_file)
    brdftab.save(table, tmp_path / "t.nc")
    back = brdftab.open(tmp_path / "t.nc")
    assert back.values.dtype == np.float64
    brdftab.save(back, tmp_path / "again.binary")
    assert (tmp_path / "again.binary").read_bytes() == ggx_file.read_bytes()


def test_arbitrary_raw_bits_survive_merl_netcdf_merl(tmp_path, random_raw):
    src = write_raw(tmp_path / "r.binary", random_raw)
    table = brdftab.open(src)
    # scaling alone would not be invertible here: raw * s / s differs from raw for some samples
    s = np.repeat(np.array(REF_SCALE), N)
    with np.errstate(all="ignore"):
        naive = random_raw * s / s
    assert np.any(naive.view(np.int64) != random_raw.view(np.int64))
    brdftab.save(table, tmp_path / "direct.binary")
    assert (tmp_path / "direct.binary").read_bytes() == src.read_bytes()
    brdftab.save(table, tmp_path / "r.nc")
    brdftab.save(brdftab.open(tmp_path / "r.nc"), tmp_path / "back.binary")
    assert (tmp_path / "back.binary").read_bytes() == src.read_bytes()


def test_changed_values_are_written_as_value_over_scale(tmp_path):
    rng = np.random.default_rng(5)
    raw = rng.uniform(0, 3000, 3 * N)
    raw[:1000] = rng.integers(0, 2**64, 1000, dtype=np.uint64).view(np.float64)  # needs corrections
    table = brdftab.open(write_raw(tmp_path / "c.binary", raw))
    assert "merl_raw_ulp_correction" in table.ds.data_vars
    values = np.array(table.values)
    values[10, 20, 30] = [0.1, 0.2, 0.3]
    ds = table.ds.copy()
    ds["brdf"] = xr.Variable(ds["brdf"].dims, values, attrs=ds["brdf"].attrs)
    brdftab.save(Table(ds), tmp_path / "changed.binary")
    got = raw_planes(tmp_path / "changed.binary")
    with np.errstate(all="ignore"):
        for c in range(3):
            want = values[..., c] / REF_SCALE[c]
            assert np.array_equal(got[c].view(np.int64), want.view(np.int64))


# --- missing samples -------------------------------------------------------------------------
def test_negative_samples_are_missing_not_zero_and_not_refused(tmp_path):
    raw = np.full((3, 90, 90, 180), 600.0)
    raw[:, 60:, :, :] = -1.0  # theta_h bins 60..89: no measurement
    raw[1, 5, 5, 5] = -2.5
    table = brdftab.open(write_raw(tmp_path / "m.binary", raw))
    assert table.ds["brdf"].attrs["valid_min"] == 0.0
    v = table.values
    assert np.all(v[60:, :, :, 0] == -1.0 * REF_SCALE[0]) and np.all(v[60:, :, :, 2] == -1.0 * REF_SCALE[2])
    assert v[5, 5, 5, 1] == -2.5 * REF_SCALE[1]
    assert int(np.asarray(table.missing).sum()) == int((raw < 0).sum())
    report = run_checks(table, {}, only=("finite", "non-negative", "missing"))
    assert report.get("missing").data["missing"] == int((raw < 0).sum())
    assert report.get("non-negative").status == "pass"
    # a query inside the missing block is NaN, one in the measured part is the data
    wi, wo = half_diff_to_dirs(*sample_position(75, 10, 20))
    assert np.all(np.isnan(table.eval(wi, wo)))
    wi, wo = half_diff_to_dirs(*sample_position(20, 10, 20))
    np.testing.assert_allclose(table.eval(wi, wo), 600.0 * np.array(REF_SCALE), rtol=1e-15)


def test_below_horizon_bins_can_be_marked_missing(tmp_path):
    lam = models.create("lambert", albedo=[0.2, 0.4, 0.6])
    path = tmp_path / "h.binary"
    brdftab.save(lam, path, below_horizon="missing")
    raw = raw_planes(path)
    i, j, k = np.meshgrid(np.arange(90), np.arange(90), np.arange(180), indexing="ij")
    wi, wo = half_diff_to_dirs(*sample_position(i, j, k))
    zmin = np.minimum(wi[..., 2], wo[..., 2])
    below, above = zmin < -1e-9, zmin > 1e-9
    assert below.sum() > 100_000 and (below | above).all()
    for c in range(3):
        assert np.all(raw[c][below] == -1.0)
        np.testing.assert_allclose(raw[c][above], [0.2, 0.4, 0.6][c] / np.pi / REF_SCALE[c], rtol=1e-15)
    table = brdftab.open(path)
    assert int(np.asarray(table.missing).sum()) == 3 * int(below.sum())


def test_resampled_table_without_data_there_gives_missing_markers(tmp_path):
    lam = models.create("lambert", albedo=[0.2, 0.4, 0.6])
    grid = RusinkiewiczGrid(10, np.radians(np.linspace(0, 40, 9)), 12, theta_h_spacing="merl")
    partial = tabulate(lam, grid, progress=False)  # theta_d only up to 40 degrees
    path = tmp_path / "p.binary"
    with pytest.warns(UserWarning, match="outside the domain"):
        brdftab.save(partial, path)
    raw = raw_planes(path)
    i, j, k = np.meshgrid(np.arange(90), np.arange(90), np.arange(180), indexing="ij")
    wi, wo = half_diff_to_dirs(*sample_position(i, j, k))
    above = np.minimum(wi[..., 2], wo[..., 2]) > 1e-9
    beyond = j >= 41  # theta_d bins beyond the table's last node (40 degrees)
    for c in range(3):
        assert np.all(raw[c][beyond & above] == -1.0)
        np.testing.assert_allclose(raw[c][(j < 40) & above], [0.2, 0.4, 0.6][c] / np.pi / REF_SCALE[c], rtol=1e-14)
        assert np.all(raw[c][~above] == 0)
    assert brdftab.open(path).ds["brdf"].attrs["valid_min"] == 0.0


def _noisy_merl_table(count=500, seed=7):
    """A measured Lambert table on the MERL grid with ``count`` small negative noise samples
    (not declared missing, as a netCDF measurement holds them); returns (table, mask, lowest)."""
    lam = models.create("lambert", albedo=[0.2, 0.4, 0.6])
    table = tabulate(lam, merl_grid(), progress=False)
    values = np.array(table.values)
    rng = np.random.default_rng(seed)
    flat = rng.choice(values.size, count, replace=False)
    values.reshape(-1)[flat] = -rng.uniform(1e-5, 3e-3, count)
    ds = table.ds.copy()
    ds["brdf"] = xr.Variable(ds["brdf"].dims, values, attrs=ds["brdf"].attrs)
    ds.attrs["origin"] = "measured"
    mask = values < 0
    return Table(ds), mask, float(values[mask].min())


def test_negative_noise_is_written_as_zero_not_as_missing_markers(tmp_path):
    """MERL reads negative values as 'no measurement': noise below 0 is written as 0 (one warning
    with the count and the lowest value), so nothing reads back as missing."""
    table, mask, lowest = _noisy_merl_table()
    path = tmp_path / "noisy.binary"
    with pytest.warns(UserWarning) as caught:
        brdftab.save(table, path)
    lines = [str(w.message) for w in caught if "negative" in str(w.message)]
    assert len(lines) == 1, lines
    assert f"{int(mask.sum())} of {mask.size} samples are negative (lowest {lowest:.4g} sr-1): written as 0" in lines[0]
    raw = raw_planes(path)
    planes = np.moveaxis(np.asarray(table.values), -1, 0)
    assert not (raw < 0).any()  # no missing markers
    for c in range(3):
        assert np.all(raw[c][mask[..., c]] == 0.0)
        np.testing.assert_allclose(raw[c][~mask[..., c]] * REF_SCALE[c], planes[c][~mask[..., c]], rtol=1e-15)
    assert brdftab.open(path).missing is None


def test_negative_noise_can_be_kept_as_markers(tmp_path):
    table, mask, _ = _noisy_merl_table(count=50)
    path = tmp_path / "kept.binary"
    brdftab.save(table, path, negative="missing")
    assert int(np.asarray(brdftab.open(path).missing).sum()) == int(mask.sum())


def test_declared_missing_samples_stay_markers(tmp_path):
    """A MERL file's own markers are missing data, not noise: written back unchanged (no warning)."""
    raw = np.full((3, 90, 90, 180), 600.0)
    raw[:, 70:] = -1.0
    table = brdftab.open(write_raw(tmp_path / "m.binary", raw))
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        brdftab.save(table, tmp_path / "back.binary")
    assert (tmp_path / "back.binary").read_bytes() == (tmp_path / "m.binary").read_bytes()


def test_measured_rgl_file_with_noise_converts_to_merl_without_missing_bins(tmp_path):
    """A measured-like RGL file with negative samples, resampled onto the MERL grid: the noise
    that interpolates below 0 is written as 0, not as markers that read back as missing."""
    from _measured import measured_bsdf

    measured_bsdf(tmp_path / "meas.bsdf", negatives=2000)
    source = brdftab.open(tmp_path / "meas.bsdf")
    with pytest.warns(UserWarning, match=r"\d+ of 4374000 samples are negative \(lowest -[0-9.e-]+ sr-1\): written "
                                         "as 0"):
        brdftab.save(source, tmp_path / "meas.binary", symmetrize=True)
    assert not (raw_planes(tmp_path / "meas.binary") < 0).any()
    assert brdftab.open(tmp_path / "meas.binary").missing is None


# --- what MERL cannot hold -------------------------------------------------------------------
class _Anisotropic(BRDF):
    """f = c (1 + 0.5 (hx² − hy²)) with h the unnormalized half vector over its length²: the
    cos 2φh term averages to zero over φh, leaving c."""

    name = "aniso-test"
    layout = Layout(("R", "G", "B"))
    isotropic = False
    reciprocal = True
    C = np.array([0.1, 0.2, 0.3])

    def _eval(self, wi, wo, lam, n):
        h = wi + wo
        h = h / np.linalg.norm(h, axis=-1, keepdims=True)
        return self.C * (1 + 0.5 * (h[:, :1] ** 2 - h[:, 1:2] ** 2))


class _NonReciprocal(BRDF):
    name = "nonrecip-test"
    layout = Layout(("R", "G", "B"))
    isotropic = True
    reciprocal = False
    C = np.array([0.1, 0.2, 0.3])

    def _eval(self, wi, wo, lam, n):
        return self.C * (1 + 0.5 * wi[:, :1] + 0.1 * wo[:, 2:3])


def test_anisotropic_source_is_refused_unless_phi_h_averaged(tmp_path):
    path = tmp_path / "a.binary"
    with pytest.raises(FormatError, match="anisotropic.*phi_h_average"):
        brdftab.save(_Anisotropic(), path)
    assert not path.exists()
    with pytest.raises(BrdftabError, match="anisotropic"):
        brdftab.save(models.create("microfacet", alpha_x=0.1, alpha_y=0.3), path)
    brdftab.save(_Anisotropic(), path, phi_h_average=3)
    raw = raw_planes(path)
    i, j, k = np.meshgrid(np.arange(0, 90, 7), np.arange(0, 90, 11), np.arange(0, 180, 13), indexing="ij")
    wi, wo = half_diff_to_dirs(*sample_position(i, j, k))
    above = np.minimum(wi[..., 2], wo[..., 2]) > 1e-9
    for c in range(3):
        got = raw[c][i, j, k] * REF_SCALE[c]
        np.testing.assert_allclose(got[above], _Anisotropic.C[c], rtol=1e-12)
        assert np.all(got[~above] == 0)
    assert brdftab.open(path).ds.attrs.get("isotropic") == 1


def test_non_reciprocal_source_is_refused_unless_symmetrized(tmp_path):
    path = tmp_path / "n.binary"
    with pytest.raises(FormatError, match="not reciprocal.*symmetrize"):
        brdftab.save(_NonReciprocal(), path)
    assert not path.exists()
    brdftab.save(_NonReciprocal(), path, symmetrize=True)
    raw = raw_planes(path)
    i, j, k = np.meshgrid(np.arange(0, 90, 9), np.arange(0, 90, 8), np.arange(0, 180, 17), indexing="ij")
    wi, wo = half_diff_to_dirs(*sample_position(i, j, k))
    above = np.minimum(wi[..., 2], wo[..., 2]) > 1e-9
    sym = 1 + 0.25 * (wi[..., 0] + wo[..., 0]) + 0.05 * (wo[..., 2] + wi[..., 2])
    for c in range(3):
        got = raw[c][i, j, k] * REF_SCALE[c]
        np.testing.assert_allclose(got[above], _NonReciprocal.C[c] * sym[above], rtol=1e-12)


def test_odd_channels_are_refused_and_spectra_are_written_in_srgb(tmp_path):
    """Channels other than R, G, B (or grey) are refused; a spectral BRDF is written as
    colour-science's linear sRGB of its spectrum (here the model's own two wavelengths, which
    colour-science interpolates linearly and integrates), saying so in one warning."""
    import warnings

    import colour

    two = make_table(np.zeros((3, 3, 3, 2)), RusinkiewiczGrid(3, 3, 3), Layout(("a", "b")))
    with pytest.raises(FormatError, match="R, G, B"):
        brdftab.save(two, tmp_path / "t.binary")
    assert list(tmp_path.iterdir()) == []
    spec = models.create("lambert", albedo={"wavelengths_nm": [400, 700], "values": [0.2, 0.8]})
    with pytest.warns(BrdftabWarning, match="2 wavelengths .* sRGB .*D65"):
        brdftab.save(spec, tmp_path / "s.binary")
    cmfs, d65 = colour.colorimetry.handle_spectral_arguments(illuminant_default="D65")
    sd = colour.SpectralDistribution([0.2 / np.pi, 0.8 / np.pi], [400.0, 700.0],
                                     interpolator=colour.LinearInterpolator)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rgb = colour.XYZ_to_RGB(colour.sd_to_XYZ(sd, cmfs, d65, method="Integration") / 100, "sRGB")
    got = brdftab.open(tmp_path / "s.binary").eval([0.3, 0.1, 0.9], [-0.2, 0.4, 0.8])
    np.testing.assert_allclose(got, rgb, rtol=1e-12)


@pytest.mark.parametrize("options, key", [
    ({"sample_position": "centre"}, "sample_position"),
    ({"below_horizon": "nan"}, "below_horizon"),
    ({"phi_h_average": 1}, "phi_h_average"),
    ({"symmetrize": "yes"}, "symmetrize"),
    ({"dtype": "float32"}, "dtype"),
])
def test_bad_options_name_the_option(tmp_path, options, key):
    with pytest.raises(BrdftabError, match=key):
        brdftab.save(models.create("lambert"), tmp_path / "o.binary", **options)


# --- recognising and refusing files ----------------------------------------------------------
def test_merl_file_is_recognised_by_its_header(tmp_path, ggx_file):
    other = tmp_path / "renamed.dat"
    other.symlink_to(ggx_file)
    assert formats.detect(other).name == "merl"
    assert brdftab.open(other).grid.equals(merl_grid())


def _header_file(path, dims, size=SIZE, endian="<"):
    with open(path, "wb") as fh:
        fh.write(struct.pack(f"{endian}3i", *dims))
        fh.truncate(size)  # sparse: zeros
    return path


@pytest.mark.parametrize("make, message", [
    (lambda p: p.write_bytes(b""), "too short"),
    (lambda p: p.write_bytes(b"\x5a\x00\x00\x00\x5a"), "too short"),
    (lambda p: _header_file(p, (90, 90, 180), size=SIZE - 8), "truncated"),
    (lambda p: _header_file(p, (90, 90, 180), size=1000), "truncated"),
    (lambda p: _header_file(p, (90, 90, 180), size=SIZE + 3), "trailing"),
    (lambda p: _header_file(p, (180, 90, 90)), r"header dims \(180, 90, 90\)"),
    (lambda p: _header_file(p, (90, 90, 360), size=12 + 3 * 90 * 90 * 360 * 8), r"header dims \(90, 90, 360\)"),
    (lambda p: _header_file(p, (90, 90, 180), endian=">"), "big-endian"),
])
def test_damaged_files_give_one_line(tmp_path, make, message):
    path = tmp_path / "bad.binary"
    make(path)
    with pytest.raises(FormatError, match=message) as info:
        brdftab.open(path)
    text = str(info.value)
    assert str(path) in text and "\n" not in text


# --- the command line ------------------------------------------------------------------------
def test_spec_outputs_merl_from_the_same_tabulation_as_netcdf(tmp_path):
    spec = tmp_path / "s.toml"
    spec.write_text('[model]\nname = "microfacet"\nalpha = 0.3\n[grid]\ntype = "merl"\n'
                    '[[output]]\npath = "t.nc"\n[[output]]\npath = "t.binary"\n')
    result = pipeline.run(brdftab.load_spec(spec), progress=False)
    assert sorted(p.name for p in result.written) == ["t.binary", "t.nc"]
    table = brdftab.open(tmp_path / "t.nc")
    brdftab.save(table, tmp_path / "from-nc.binary")
    assert (tmp_path / "from-nc.binary").read_bytes() == (tmp_path / "t.binary").read_bytes()


def test_refusal_on_the_command_line_is_one_line(tmp_path):
    spec = tmp_path / "aniso.toml"
    spec.write_text('[model]\nname = "microfacet"\nalpha_x = 0.1\nalpha_y = 0.4\n'
                    '[grid]\ntype = "rusinkiewicz"\nanisotropic = true\nn_theta_h = 4\nn_theta_d = 4\nn_phi_d = 4\n'
                    'n_phi_h = 4\nphi_d_fold = "none"\n[[output]]\npath = "a.binary"\n')
    result = CliRunner().invoke(main, ["tabulate", str(spec)])
    assert result.exit_code == 2
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and "anisotropic" in lines[0] and "phi_h_average" in lines[0], result.output
    assert list(tmp_path.iterdir()) == [spec]


def test_a_table_resampled_onto_the_merl_grid_is_not_judged_as_samples_of_its_model(tmp_path):
    """Converting a table of a model to MERL resamples it: its bins hold interpolations of that
    table, so the conventions check does not compare them node by node with the model (that
    refused every such conversion); the output records what it was resampled from."""
    src = tmp_path / "ggx.nc"
    brdftab.save(tabulate(models.create("microfacet", alpha=0.3), RusinkiewiczGrid(16, 16, 32), progress=False), src)
    from brdftab.convert import convert

    result = convert(src, tmp_path / "ggx.binary")
    c = result.report.get("conventions")
    assert c.status == "pass" and "resampled from ggx.nc" in c.detail
    assert result.written.ds.attrs["resampled_from"] == "ggx.nc"


def test_a_grid_the_format_does_not_store_is_said_to_be_ignored(tmp_path):
    """MERL has its own grid: ``save(..., grid=other)`` writes the MERL grid and says so."""
    import warnings

    from brdftab.errors import BrdftabWarning

    lam = models.create("lambert", albedo=0.5)
    with pytest.warns(BrdftabWarning, match=r"x.binary: the merl format stores its own grid, merl .*; the grid given "
                                             r"\(rusinkiewicz theta_h\[4\] x theta_d\[4\] x phi_d\[8\]\) is not used"):
        written = brdftab.save(lam, tmp_path / "x.binary", grid=RusinkiewiczGrid(4, 4, 8))
    assert written.grid.equals(merl_grid())
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the MERL grid itself, or no grid: nothing to say
        brdftab.save(lam, tmp_path / "y.binary", grid="merl")
        brdftab.save(lam, tmp_path / "z.binary")


def test_negative_values_of_an_analytic_model_are_not_clamped_but_refused(tmp_path):
    """Clamping is for measurement noise: a table of an analytic model with negative values is
    left as it is, so the non-negative check refuses it before export."""
    from brdftab.checks import ChecksFailed, guard
    from brdftab.formats.merl import prepare_merl

    table, mask, _ = _noisy_merl_table(count=20)
    table.ds.attrs["origin"] = "analytic"
    table = Table(table.ds)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        prepared = prepare_merl(table, merl_grid())
    assert int((np.asarray(prepared.values) < 0).sum()) == int(mask.sum())
    with pytest.raises(ChecksFailed, match="non-negative"):
        guard(prepared, only=("non-negative",))
