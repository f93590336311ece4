"""Polarized tables (:mod:`brdftab.mueller_table`): the Mueller matrix tabulated beside f_r,11,
interpolated by ``Table.eval_mueller``, stored in netCDF and zarr with ``mueller_row`` /
``mueller_col`` dimensions and its frame as attributes, and asked for by ``[grid] polarized``.

References: the closed-form test models of :mod:`_polarized` (their Mueller matrix at the nodes
and, between nodes, the interpolation error shrinking with the grid step).
"""

from __future__ import annotations

import numpy as np
import pytest
from _polarized import GGXConductor, Scaled

import brdftab
from brdftab.errors import BrdftabError, FormatError, ParameterError
from brdftab.geometry import sph_to_vec
from brdftab.grids import RusinkiewiczGrid, SphericalGrid
from brdftab.models._registry import MODELS
from brdftab.spec import load_spec
from brdftab.table import tabulate


def pairs(n=200, seed=0, min_cos=0.15):
    rng = np.random.default_rng(seed)
    mu = rng.uniform(min_cos, 1.0, (2, n))
    phi = rng.uniform(0, 2 * np.pi, (2, n))
    return sph_to_vec(np.arccos(mu[0]), phi[0]), sph_to_vec(np.arccos(mu[1]), phi[1])


@pytest.fixture(scope="module")
def table():
    return tabulate(GGXConductor(0.3), RusinkiewiczGrid(12, 12, 24, phi_d_fold="none"), polarized=True,
                    progress=False)


def test_nodes_hold_the_models_mueller_matrix_and_brdf_is_its_m00(table):
    model = GGXConductor(0.3)
    wi, wo = table.grid.directions()
    m = table.ds["mueller"].values.reshape(-1, 5, 4, 4)
    above = (wi[:, 2] > 1e-12) & (wo[:, 2] > 1e-12)
    ref = model.eval_mueller(wi[above], wo[above])
    assert np.abs(m[above] - ref).max() <= 1e-12 * np.abs(ref).max()
    assert np.array_equal(table.values.reshape(-1, 5), m[..., 0, 0])
    assert table.ds["mueller"].dims[-2:] == ("mueller_row", "mueller_col")
    assert table.ds["mueller"].attrs["mueller_basis"] == "mitsuba"
    assert table.ds["mueller"].attrs["mueller_circular"].startswith("+S3 right circular")
    # eval_mueller interpolates to the node values at the nodes, and eval is its M00 everywhere
    sel = np.flatnonzero(above)[::37]
    got = table.eval_mueller(wi[sel], wo[sel])
    assert np.abs(got - m[sel]).max() <= 1e-9 * np.abs(m[sel]).max()
    a, b = pairs()
    assert np.array_equal(table.eval(a, b), table.eval_mueller(a, b)[..., 0, 0])


def test_interpolation_error_shrinks_with_the_grid_step():
    model = GGXConductor(0.5)
    a, b = pairs(400, seed=4)
    ref = model.eval_mueller(a, b)
    errs = []
    for n in (8, 16, 32):
        t = tabulate(model, RusinkiewiczGrid(n, n, 4 * n, phi_d_fold="none"), polarized=True, progress=False)
        errs.append(float(np.median(np.abs(t.eval_mueller(a, b) - ref).max(axis=(-2, -1)) / ref[..., 0, 0])))
    print("median max|ΔM_ij|/M00 at n =", (8, 16, 32), ":", errs)
    assert errs[0] > 2.5 * errs[1] > 2.5 * 2.5 * errs[2]  # about second order (4x per halving)


def test_off_diagonal_ghosts_below_the_horizon_are_not_clamped_at_zero(table):
    # M23 is negative for this conductor: a ghost node below the horizon keeps its sign
    from brdftab.mueller_table import ghosted_mueller

    g = ghosted_mueller(table)
    below = ~table.grid.node_above_horizon()
    ghosts = g[below]
    finite = np.isfinite(ghosts[..., 0, 0]).all(axis=-1)
    assert finite.any()
    assert (ghosts[finite][..., 2, 3] < 0).any()
    assert (ghosts[finite][..., 0, 0] >= 0).all()


def test_a_polarized_table_needs_a_polarized_model_and_no_phi_d_fold():
    with pytest.raises(BrdftabError, match="not polarized"):
        tabulate(brdftab.models.create("microfacet", distribution="ggx", alpha=0.3, fresnel="schlick", f0=0.9), RusinkiewiczGrid(4, 4, 8, phi_d_fold="none"),
                 polarized=True)
    with pytest.raises(ParameterError, match="phi_d_fold = 'none'"):
        tabulate(GGXConductor(0.3), RusinkiewiczGrid(4, 4, 8), polarized=True)
    with pytest.raises(BrdftabError, match="holds no Mueller matrix"):
        tabulate(brdftab.models.create("microfacet", distribution="ggx", alpha=0.3, fresnel="schlick", f0=0.9), RusinkiewiczGrid(4, 4, 8)).eval_mueller(
            *pairs(3))


def test_a_spherical_polarized_table_interpolates_its_mueller_matrix():
    grid = SphericalGrid(np.radians(np.arange(0, 90, 10.0)), [0.0], np.radians(np.arange(0, 90, 5.0)),
                         np.radians(np.arange(0, 360, 10.0)))
    model = GGXConductor(0.6)
    t = tabulate(model, grid, polarized=True, progress=False)
    wi, wo = grid.directions()
    above = (wi[:, 2] > 1e-12) & (wo[:, 2] > 1e-12)
    ref = model.eval_mueller(wi[above], wo[above])
    got = t.ds["mueller"].values.reshape(-1, 5, 4, 4)[above]
    backscatter = np.linalg.norm(np.cross(wi[above], wo[above]), axis=-1) < 1e-9
    assert np.abs(got[~backscatter] - ref[~backscatter]).max() <= 1e-12 * np.abs(ref).max()
    assert np.isfinite(got).all()  # wi = wo nodes hold a limit, not NaN


@pytest.mark.parametrize("ext, dtype", [(".nc", "float64"), (".nc", "float32"), (".zarr", "float64"),
                                        (".zarr", "float32")])
def test_netcdf_and_zarr_store_the_mueller_matrix_with_its_frame(table, tmp_path, ext, dtype):
    path = tmp_path / f"t{ext}"
    brdftab.save(table, path, dtype=dtype)
    back = brdftab.open(path)
    assert back.polarized
    var = back.ds["mueller"]
    assert var.dims == table.grid.dims + ("wavelength", "mueller_row", "mueller_col")
    assert var.dtype == np.dtype(dtype)
    assert var.attrs["mueller_basis"] == "mitsuba" and "right circular" in var.attrs["mueller_circular"]
    a, b = pairs(50, seed=2)
    exp = table.eval_mueller(a, b)
    tol = 1e-12 if dtype == "float64" else 1e-6
    assert (np.abs(back.eval_mueller(a, b) - exp) / exp[..., :1, :1]).max() <= tol
    assert np.array_equal(back.eval(a, b), back.eval_mueller(a, b)[..., 0, 0])


def test_a_file_in_another_basis_is_refused_in_one_line(table):
    ds = table.ds.copy()
    ds["mueller"].attrs["mueller_basis"] = "psps"
    from brdftab.table import Table

    with pytest.raises(FormatError, match="mueller_basis = 'psps'"):
        Table(ds)


class _SpecModel(GGXConductor):
    """The GGX test model as a registered model (name ``test-polarized``)."""

    name = "test-polarized"
    params = ()

    def __init__(self, **kw):
        super().__init__(0.3)


def test_spec_grid_polarized_tabulates_the_mueller_matrix(tmp_path, monkeypatch):
    monkeypatch.setitem(MODELS, "test-polarized", _SpecModel)
    spec = tmp_path / "p.toml"
    spec.write_text('[model]\nname = "test-polarized"\n[grid]\ntype = "rusinkiewicz"\nn_theta_h = 6\nn_theta_d = 6\n'
                    'n_phi_d = 12\nphi_d_fold = "none"\npolarized = true\nwavelengths_nm = [450, 500, 550, 600, 650]\n'
                    '[[output]]\npath = "p.nc"\n[[output]]\npath = "p.pbsdf"\n')
    from brdftab.pipeline import run

    result = run(load_spec(spec))
    assert result.report.get("mueller_realizability").status == "pass"
    nc = brdftab.open(tmp_path / "p.nc")
    pb = brdftab.open(tmp_path / "p.pbsdf")
    assert nc.polarized and pb.polarized
    a, b = pairs(30)
    assert (np.abs(nc.eval_mueller(a, b) - pb.eval_mueller(a, b)) / nc.eval_mueller(a, b)[..., :1, :1]).max() < 1e-6
    # refused: a fold, an unpolarized model
    spec.write_text(spec.read_text().replace('phi_d_fold = "none"\n', ""))
    with pytest.raises(BrdftabError, match="grid.polarized: a polarized table needs phi_d_fold = 'none'"):
        load_spec(spec)
    spec.write_text('[model]\nname = "microfacet"\nalpha = 0.3\nfresnel = "schlick"\nf0 = 0.9\n[grid]\ntype = "rusinkiewicz"\nphi_d_fold = "none"\n'
                    'polarized = true\n[[output]]\npath = "p.nc"\n')
    with pytest.raises(BrdftabError, match="grid.polarized: the model 'microfacet' has no Mueller matrix"):
        load_spec(spec)


def test_scaled_test_model_is_what_the_checks_tests_use():
    m = Scaled(GGXConductor(0.3), np.diag([1.0, 1.0, 1.0, -1.0]))
    a, b = pairs(5)
    assert np.allclose(m.eval_mueller(a, b)[..., 3, 3], -GGXConductor(0.3).eval_mueller(a, b)[..., 3, 3])


def test_a_polarized_table_resampled_onto_another_grid_stays_polarized(table, tmp_path):
    out = tmp_path / "fine.nc"
    fine = RusinkiewiczGrid(16, 16, 32, phi_d_fold="none")
    brdftab.save(table, out, grid=fine)
    back = brdftab.open(out)
    assert back.polarized and back.grid.equals(fine)
    # the resampled table holds the source table's interpolation at its nodes
    wi, wo = fine.directions()
    up = np.flatnonzero((wi[:, 2] > 0.2) & (wo[:, 2] > 0.2))[::50]
    assert np.allclose(back.ds["mueller"].values.reshape(-1, 5, 4, 4)[up], table.eval_mueller(wi[up], wo[up]),
                       rtol=0, atol=1e-12 * table.values.max())
    # a folded grid cannot hold it: f_r is written, with a warning
    with pytest.warns(brdftab.errors.BrdftabWarning, match="only f_r"):
        brdftab.save(table, tmp_path / "merl.nc", grid=RusinkiewiczGrid(8, 8, 16))
    assert not brdftab.open(tmp_path / "merl.nc").polarized


def test_a_polarized_run_over_the_memory_budget_is_refused_up_front(tmp_path, monkeypatch):
    monkeypatch.setitem(MODELS, "test-polarized", _SpecModel)
    spec = tmp_path / "big.toml"
    spec.write_text('[model]\nname = "test-polarized"\n[grid]\ntype = "rusinkiewicz"\nn_theta_h = 90\nn_theta_d = 90\n'
                    'n_phi_d = 360\nphi_d_fold = "none"\nwavelengths_nm = [450, 500, 550, 600, 650]\n'
                    '[[output]]\npath = "big.pbsdf"\n')
    from brdftab.pipeline import run

    with pytest.raises(BrdftabError, match="polarized table .* needs about .* GiB") as info:
        run(load_spec(spec))
    assert "\n" not in str(info.value) and not (tmp_path / "big.pbsdf").exists()
