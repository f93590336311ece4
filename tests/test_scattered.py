"""Scattered tables (brdftab.grids.scattered): linear interpolation on the samples' Delaunay
triangulation, its measured accuracy, what happens outside the hull, netCDF storage and the
resampling report of ``brdftab convert``."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import brdftab
from brdftab.errors import BrdftabError, BrdftabWarning
from brdftab.grids import ScatteredGrid, SphericalGrid


def source():
    m = brdftab.models
    return m.create("sum", terms=[m.create("lambert", albedo=[0.1, 0.2, 0.3]),
                                  m.create("microfacet", alpha=0.3, fresnel="conductor", n=[0.2, 0.4, 1.4],
                                           k=[3.9, 2.4, 1.6])])


def directions(theta, phi):
    """Unit vectors of polar angle theta and azimuth phi (written out here, not brdftab's)."""
    return np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=-1)


def random_table(n, seed, top=80.0):
    rng = np.random.default_rng(seed)
    mu = np.cos(np.radians(top))
    ti, to = np.arccos(rng.uniform(mu, 1, n)), np.arccos(rng.uniform(mu, 1, n))
    grid = ScatteredGrid(ti, np.zeros(n), to, rng.uniform(-np.pi, np.pi, n))
    return brdftab.tabulate(source(), grid, progress=False)


def test_interpolation_accuracy_at_held_out_pairs():
    """3000 random isotropic samples of Lambert + GGX α = 0.3 (θ ≤ 80°); 2000 held-out pairs with θ ≤ 75°
    (random azimuths: the table turns them to φi = 0), 99.2 % of them inside the hull: median relative
    error 0.89 %, 95th percentile 4.1 % (the figures formats/astm.md and formats/csv.md state)."""
    table = random_table(3000, 1)
    rng = np.random.default_rng(7)
    mu = np.cos(np.radians(75.0))
    wi = directions(np.arccos(rng.uniform(mu, 1, 2000)), rng.uniform(-np.pi, np.pi, 2000))
    wo = directions(np.arccos(rng.uniform(mu, 1, 2000)), rng.uniform(-np.pi, np.pi, 2000))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BrdftabWarning)
        got = table.eval(wi, wo)
    ref = source().eval(wi, wo)
    inside = np.isfinite(got).all(axis=1)
    assert inside.mean() > 0.98
    rel = np.abs(got[inside] - ref[inside]) / ref[inside]
    assert np.median(rel) < 0.0095 and np.percentile(rel, 95) < 0.043, (np.median(rel), np.percentile(rel, 95))


def test_samples_are_returned_exactly_and_the_layers_interpolate_linearly_in_incidence():
    """A gonio set (incidence layers): at its samples the table returns the stored values; half way
    between two layers it returns the mean of the two layers at the same outgoing direction."""
    grid = ScatteredGrid.from_grid(SphericalGrid(np.radians([20.0, 40.0]), [0.0], np.radians(np.arange(0, 81, 10.0)),
                                                 np.radians(np.arange(0, 360, 30.0))))
    table = brdftab.tabulate(source(), grid, progress=False)
    wi, wo = grid.directions()
    assert np.allclose(table.eval(wi, wo), table.values, rtol=1e-13, atol=0)
    wo1 = directions(np.radians(35.0), np.radians(100.0))
    a = table.eval(directions(np.radians(20.0), 0.0), wo1)
    b = table.eval(directions(np.radians(40.0), 0.0), wo1)
    s = 0.5 * (np.sin(np.radians(20.0)) + np.sin(np.radians(40.0)))   # linear in sinθi
    mid = table.eval(directions(np.arcsin(s), 0.0), wo1)
    assert np.allclose(mid, 0.5 * (a + b), rtol=1e-12)


def test_outside_the_hull_is_nan_with_a_warning_or_the_nearest_sample():
    table = random_table(400, 3, top=60.0)
    wi = directions(np.radians([30.0, 85.0]), 0.0)
    wo = directions(np.radians([30.0, 20.0]), np.pi)
    with pytest.warns(BrdftabWarning, match=r"1 of 2 direction pair\(s\) lie outside the domain.*NaN"):
        f = table.eval(wi, wo)
    assert np.isfinite(f[0]).all() and np.isnan(f[1]).all()
    table = random_table(400, 3, top=60.0)  # (a table warns once)
    table.outside = "clamp"
    with pytest.warns(BrdftabWarning, match="each takes its nearest sample's value"):
        g = table.eval(wi, wo)
    assert np.array_equal(g[0], f[0])
    assert np.any(np.all(table.values == g[1], axis=1))  # a sample's own value
    table.outside = "raise"
    with pytest.raises(BrdftabError, match="outside the domain"):
        table.eval(wi, wo)


@pytest.mark.parametrize("ext", [".nc", ".zarr"])
def test_netcdf_and_zarr_store_the_samples_and_evaluate_exactly_as_the_table(tmp_path, ext):
    table = random_table(300, 5)
    brdftab.save(table, tmp_path / f"s{ext}")
    back = brdftab.open(tmp_path / f"s{ext}")
    assert back.grid.equals(table.grid) and np.array_equal(back.values, table.values)
    assert list(back.ds["theta_i"].dims) == ["sample"] and back.ds["theta_i"].attrs["units"] == "rad"
    rng = np.random.default_rng(2)
    wi = directions(rng.uniform(0, 1.3, 500), rng.uniform(-3, 3, 500))
    wo = directions(rng.uniform(0, 1.3, 500), rng.uniform(-3, 3, 500))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BrdftabWarning)
        assert np.array_equal(back.eval(wi, wo), table.eval(wi, wo), equal_nan=True)


def test_convert_resamples_onto_a_grid_and_reports_the_extrapolation(tmp_path):
    from brdftab.convert import convert

    table = random_table(1500, 9, top=70.0)
    brdftab.save(table, tmp_path / "s.nc")
    grid = {"type": "spherical", "theta_i_deg": [0, 30, 60, 80], "phi_i_deg": [0],
            "theta_o_deg": {"start": 0, "stop": 80, "step": 10}, "phi_o_deg": {"start": 0, "stop": 360, "step": 30,
                                                                              "endpoint": False}}
    from brdftab.convert import _build_grid

    g, _ = _build_grid(grid, "test")
    result = convert(tmp_path / "s.nc", tmp_path / "g.nc", grid=g, allow_invalid=True)
    x = result.extrapolated
    # nodes with θi or θo beyond the samples' 70°, or θi = 0 below their smallest incidence, are outside
    wi, wo = g.directions()
    beyond = (wi[:, 2] < np.cos(np.radians(70.0))) | (wo[:, 2] < np.cos(np.radians(70.0)))
    assert x["nodes"] == g.size and x["outside"] >= beyond.sum() and 0 < x["fraction"] < 1
    assert result.to_json()["extrapolated"]["outside"] == x["outside"]
    assert result.difference is not None
    assert "nearest sample" in brdftab.open(tmp_path / "g.nc").ds.attrs["extrapolation"]


def test_checks_say_what_the_samples_cover_and_pass_nothing_over_no_pairs():
    """Samples of one quarter of the outgoing azimuths (φo − φi in [0°, 90°], both sides of nothing):
    the bilateral check finds no pair whose mirror image the samples cover and skips (it passed over
    zero pairs before); the albedo check reports the small covered fraction and does not pass."""
    from brdftab.checks import run_checks

    quarter = SphericalGrid(np.radians([10.0, 30.0, 50.0]), [0.0], np.radians(np.arange(0, 81, 10.0)),
                            np.radians(np.arange(5, 90, 10.0)))
    grid = ScatteredGrid.from_grid(quarter)
    table = brdftab.tabulate(source(), grid, progress=False)
    report = run_checks(table, only=("bilateral", "albedo"))
    bilateral, albedo = report.get("bilateral"), report.get("albedo")
    assert bilateral.status == "skip" and "no random pair has data on both sides" in bilateral.detail
    assert albedo.status == "warn" and albedo.data["coverage_min"] < 0.3


def test_extrapolation_reported_for_a_bsdf_is_the_written_files(tmp_path):
    """An RGL file of a scattered table: the writer builds two candidate warps and evaluates
    the source again to choose (formats/rgl-bsdf.md, step 3), to place the lobe warp's samples
    (its steepness share) and to fit the values (step 4, asked for); the extrapolation convert
    reports counts the nodes of the file written only, as when its warp is asked for."""
    import json

    from brdftab.convert import convert

    brdftab.save(random_table(600, 2), tmp_path / "s.nc")
    got, warp = {}, "auto"
    for _ in range(2):  # auto, then the warp it chose, asked for
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            result = convert(tmp_path / "s.nc", tmp_path / f"s-{warp}.bsdf",
                             options={"warp": warp, "values": "fit", "n_theta_i": 9, "resolution": 24},  # small: fast
                             allow_invalid=True, progress=False)
        got[warp] = result.extrapolated
        warp = json.loads(bytes(brdftab.open(tmp_path / f"s-{warp}.bsdf").fields["provenance"]).decode())["warp"]
    assert got["auto"] == got[warp] and got["auto"]["outside"] > 0
    # the lobe warp's steepness queries (an even grid of half vectors) are not counted
    from brdftab.formats._rgl_warp import bilinear
    from brdftab.formats._rgl_write import _steepness

    table = brdftab.open(tmp_path / "s.nc")
    before = list(table.extrapolation)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # (the table's own warning about its extrapolated queries)
        _steepness(table, None, np.radians([0.0, 40.0, 80.0]), 16, bilinear(np.ones((2, 16), np.float32)))
    assert table.extrapolation == before and before[0] == 0
    assert json.loads(bytes(brdftab.open(tmp_path / "s-auto.bsdf").fields["provenance"]).decode())["values"] == "fit"
