"""Fitting a model to a table (brdftab.fit, ``brdftab fit``): known-parameter recovery with noise,
Bitterling's published fit from the bounds' centres, the fitted spec, bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest

import brdftab
from brdftab import models
from brdftab.errors import BrdftabError
from brdftab.grids import grid_from_config
from brdftab.table import tabulate

from _cli import cli, one_error

GRID = {"type": "rusinkiewicz", "n_theta_h": 24, "n_theta_d": 12, "n_phi_d": 12}
#: Bitterling's Cook–Torrance fit (specs/pyromark-cook-torrance.toml), spec units.
BITTERLING = {"n": 1.43, "r_dh_lam": 0.0110, "p1": 0.1012, "p2": 2.661, "p3_deg": 51.51, "p4": 0.2199}


def noisy(model, grid_cfg=GRID, noise=0.01, seed=1):
    table = tabulate(model, grid_from_config(grid_cfg))
    rng = np.random.default_rng(seed)
    table.values[...] *= 1.0 + noise * rng.standard_normal(table.values.shape)
    return table


def assert_recovered(result, truth, rel, sigmas=4.0):
    for key, want in truth.items():
        got, sd = result.parameters[key], result.uncertainties[key]
        assert abs(got / want - 1) < rel, (key, got, want)
        assert abs(got - want) < sigmas * sd, (key, got, want, sd)  # the reported uncertainty is honest
        assert sd < 0.2 * rel * abs(want), (key, sd)  # ... and not inflated to pass


def test_microfacet_alpha_and_n_from_a_noisy_table():
    truth = models.create("microfacet", alpha=0.2, fresnel="dielectric", n=1.5)
    table = noisy(truth)
    result = brdftab.fit(table, "microfacet", free=["alpha", "n"], params={"fresnel": "dielectric", "alpha": 0.5,
                                                                          "n": 1.2}, starts=4, albedo=False)
    assert_recovered(result, {"alpha": 0.2, "n": 1.5}, 0.005)
    # 1 % multiplicative noise is a log residual of 0.01 (rms): the fit is at the noise
    assert result.residual == pytest.approx(0.01, rel=0.05)
    assert result.residual_by_theta_i[0][:2] == [0.0, 10.0]
    assert all(r == pytest.approx(0.01, rel=0.2) for _, _, r, _ in result.residual_by_theta_i)
    assert np.asarray(result.correlations).shape == (2, 2)
    assert result.correlations[0][0] == pytest.approx(1.0)


def test_lambert_plus_ggx_sum_from_a_noisy_table():
    truth = models.create("sum", terms=[models.create("lambert", albedo=0.3),
                                        models.create("microfacet", alpha=0.15, fresnel="schlick", f0=0.6)])
    table = noisy(truth, seed=2)
    start = {"name": "sum", "terms": [{"name": "lambert", "albedo": 0.5}, {"name": "microfacet", "alpha": 0.4}]}
    result = brdftab.fit(table, start, free=["terms.0.albedo", "terms.1.alpha", "terms[1].f0"], starts=4,
                         params={"terms.1.fresnel": "schlick", "terms.1.f0": 0.2}, albedo=False)
    assert result.free == ["terms.0.albedo", "terms.1.alpha", "terms[1].f0"]
    assert_recovered(result, {"terms.0.albedo": 0.3, "terms.1.alpha": 0.15, "terms[1].f0": 0.6}, 0.005)
    assert result.model.terms[1].parameters["alpha"] == result.parameters["terms.1.alpha"]


def test_cos_metric_recovers_a_noise_free_table():
    truth = models.create("microfacet", alpha=0.3)
    table = tabulate(truth, grid_from_config(GRID))
    result = brdftab.fit(table, "microfacet", free=["alpha"], params={"alpha": 0.1}, metric="cos", starts=2,
                         albedo=False)
    assert result.metric == "cos"
    assert result.parameters["alpha"] == pytest.approx(0.3, rel=1e-6)


def bitterling_table():
    spec = brdftab.load_spec("specs/pyromark-cook-torrance.toml")
    grid = grid_from_config({"type": "rusinkiewicz", "theta_h_spacing": "merl", "n_theta_h": 16, "n_theta_d": 16,
                             "n_phi_d": 16, "phi_d_fold": "none"})
    return tabulate(spec.model, grid)


def centres():
    cls = models.get("cook-torrance-alpha-theta")
    out = {}
    for p in cls.params:
        if p.spec_key in BITTERLING:
            lo, hi = p.minimum, p.maximum
            out[p.spec_key] = float(np.degrees(0.5 * (lo + hi))) if p.angle else 0.5 * (lo + hi)
    return out


def test_bitterling_fit_recovered_from_the_bounds_centres():
    table = bitterling_table()
    start = centres()
    assert start == {"n": 0.5 * (1e-6 + 10), "r_dh_lam": 0.5, "p1": 0.5, "p2": 50.0, "p3_deg": 45.0,
                     "p4": 0.5005}
    free = list(BITTERLING)
    one = brdftab.fit(table, "cook-torrance-alpha-theta", free=free, params=start, starts=1, albedo=False)
    off = max(abs(one.parameters[k] / v - 1) for k, v in BITTERLING.items())
    assert off > 1.0  # a single start from the centres misses: the problem is not convex
    result = brdftab.fit(table, "cook-torrance-alpha-theta", free=free, params=start, starts=4, albedo=False)
    for key, want in BITTERLING.items():
        assert result.parameters[key] == pytest.approx(want, rel=0.01), key


def test_fitted_spec_tabulates_to_the_fitted_model(tmp_path):
    truth = models.create("microfacet", alpha=0.25)
    table = noisy(truth, seed=3)
    brdftab.save(table, tmp_path / "t.nc")
    r = cli("fit", tmp_path / "t.nc", "--model", "microfacet", "--param", "alpha=0.6", "--free", "alpha",
            "--starts", "2", "-o", tmp_path / "fit.toml", "--json")
    assert r.exit_code == 0, r.output
    doc = json.loads(r.output)
    for key in ("parameters", "uncertainties", "metric", "residual", "residual_by_theta_i", "albedo",
                "correlations"):
        assert key in doc
    assert doc["metric"] == "log" and doc["parameters"]["alpha"] == pytest.approx(0.25, rel=0.005)
    spec = brdftab.load_spec(tmp_path / "fit.toml")
    assert spec.grid.equals(table.grid)
    assert spec.model.parameters["alpha"] == doc["parameters"]["alpha"]  # written exactly (repr)
    r = cli("tabulate", tmp_path / "fit.toml")
    assert r.exit_code == 0, r.output
    written = brdftab.open(tmp_path / "fit.nc")
    fitted = models.create("microfacet", alpha=doc["parameters"]["alpha"])
    assert np.array_equal(written.values, tabulate(fitted, table.grid).values)
    # the albedo of the fit is the truth's to the fit's accuracy; the table's (interpolated on
    # a coarse grid, with noise) to a few per cent
    from brdftab.integrate import directional_albedo

    a_true = directional_albedo(truth, np.radians(doc["albedo"]["theta_i_deg"]))
    assert np.allclose(doc["albedo"]["fit"], a_true, rtol=0.005)
    assert np.allclose(doc["albedo"]["table"], a_true, rtol=0.05)


def test_grid_table_reproduces_each_grid_kind():
    from brdftab.fitting import grid_table

    for cfg in ({"type": "merl"}, GRID,
                {"type": "rusinkiewicz", "theta_h_deg": [0.5, 3, 10, 40, 80], "theta_d_deg": [1, 30, 60],
                 "n_phi_d": 4},
                {"type": "spherical", "theta_i_deg": [0, 30, 60], "phi_i_deg": [0], "theta_o_deg": [0, 45, 85],
                 "phi_o_deg": [0, 90, 180]},
                {"type": "klems", "basis": "half"}, {"type": "tensor-tree", "rank": 4, "level": 3},
                {"type": "tensor-tree"}):
        grid = grid_from_config(cfg)
        again = grid_from_config(grid_table(grid))
        assert again.equals(grid), cfg  # node for node, bit for bit (angles written in degrees)
    # nodes that were never degrees: the same to 1e-12 rad
    grid = grid_from_config({"type": "spherical", "theta_i_deg": [0, 30], "phi_i_deg": [0], "theta_o_deg": [10, 45],
                             "phi_o_deg": [0, 90]})
    grid.axes[0].values[1] = 0.5123456789012345
    again = grid_from_config(grid_table(grid))
    assert np.allclose(again.axes[0].values, grid.axes[0].values, rtol=0, atol=1e-12)


@pytest.fixture(scope="module")
def table_file(tmp_path_factory):
    folder = tmp_path_factory.mktemp("fit")
    brdftab.save(models.create("microfacet", alpha=0.3), folder / "t.nc",
                 grid={"type": "rusinkiewicz", "n_theta_h": 6, "n_theta_d": 6, "n_phi_d": 6})
    return folder / "t.nc"


@pytest.mark.parametrize("args, expected", [
    (["--free", "alpah"], ["unknown key 'alpah'", "did you mean 'alpha'"]),
    (["--free", "distribution"], ["'distribution' is not a number"]),
    (["--free", "alpha", "--param", "distribution=3"], ["distribution"]),
    (["--free", "alpha", "--bounds", "alpha=0.5,0.9"], ["start alpha = 0.3 is outside its bounds [0.5, 0.9]"]),
    (["--free", "alpha", "--bounds", "alpha=0.1"], ["--bounds alpha: expected LO,HI"]),
    (["--free", "alpha", "--metric", "abs"], ["--metric"]),
    (["--free", "alpha", "--param", "alpah=0.2"], ["'alpah' names no parameter", "did you mean 'alpha'"]),
    (["--free", "alpha", "--param", "fresnel=schlick", "--param", "f0=[0.5, 0.5, 0.5]"],
     ["the model gives 3 channels", "the table has 1"]),
    (["--free", "alpha", "--param", "alpha=abc"], ["alpha", "not a number"]),
    (["--free", "alpha", "--model", "microfacett"], ["did you mean 'microfacet'"]),
    # 10^8 starts ran out of memory at 7 GB: a limit, said before any work
    (["--free", "alpha", "--starts", "10001"], ["--starts", "10001 is not in the range 1<=x<=10000"]),
])
def test_bad_input_is_one_line(table_file, tmp_path, args, expected):
    argv = ["fit", table_file, "--model", "microfacet", "--param", "alpha=0.3", "-o", tmp_path / "fit.toml", *args]
    if "--model" in args:
        i = argv.index("--model")
        del argv[i:i + 2]
    r = cli(*argv)
    one_error(r.stderr if hasattr(r, "stderr") else r.output, r.exit_code, *expected)
    assert not (tmp_path / "fit.toml").exists()


def test_a_table_without_valid_samples_is_one_line(tmp_path):
    table = tabulate(models.create("lambert", albedo=0.5), grid_from_config(GRID))
    table.values[...] = np.nan
    brdftab.save(table, tmp_path / "nan.nc")
    r = cli("fit", tmp_path / "nan.nc", "--model", "lambert", "--free", "albedo", "-o", tmp_path / "fit.toml")
    one_error(r.stderr, r.exit_code, "no valid samples")
    assert not (tmp_path / "fit.toml").exists()
    with pytest.raises(BrdftabError, match="no valid samples"):
        brdftab.fit(tabulate(models.create("lambert"), grid_from_config(GRID)), "lambert", free=["albedo"],
                    max_theta_deg=0.01)


def test_running_out_of_memory_is_one_line_that_fits_the_verb(table_file, tmp_path, monkeypatch):
    # (it said "use a coarser grid or fewer channels" for a fit or a sweep too)
    from brdftab import fitting

    def exhausted(*args, **kwargs):
        raise MemoryError

    monkeypatch.setattr(fitting, "fit", exhausted)
    r = cli("fit", table_file, "--model", "microfacet", "--free", "alpha", "-o", tmp_path / "fit.toml")
    one_error(r.stderr if hasattr(r, "stderr") else r.output, r.exit_code,
              "out of memory: the run needs more than this machine has (a coarser grid, fewer channels, sweep "
              "members or fit starts need less)")
    assert not (tmp_path / "fit.toml").exists()


@pytest.mark.parametrize("starts", [0, 10_001, True, 2.0])
def test_the_number_of_starts_is_checked_in_the_api_too(table_file, starts):
    with pytest.raises(BrdftabError, match=r"starts: expected a whole number in \[1, 10000\]"):
        brdftab.fit(brdftab.open(table_file), "microfacet", free=["alpha"], params={"alpha": 0.3}, starts=starts)


def test_help_lists_the_metrics_of_the_fitting_module():
    from brdftab import cli_fit, fitting

    assert cli_fit.METRICS == fitting.METRICS
    assert cli_fit.MAX_STARTS == fitting.MAX_STARTS


def test_a_measured_rgl_file_lambert_plus_ggx_beats_lambert_and_its_spec_tabulates(tmp_path):
    """A measured-like RGL .bsdf (tests/_measured.py: an asymmetric Lambert + GGX, negative noise
    samples, incidence up to 80°), fitted at its stored sample nodes."""
    from _measured import measured_bsdf

    measured_bsdf(tmp_path / "m.bsdf")
    table = brdftab.open(tmp_path / "m.bsdf")
    lam = brdftab.fit(table, {"name": "lambert", "albedo": [0.5, 0.5, 0.5]}, free=["albedo"], starts=2,
                      albedo=False)
    start = tmp_path / "start.toml"
    start.write_text('[model]\nname = "sum"\n[[model.terms]]\nname = "lambert"\nalbedo = [0.5, 0.5, 0.5]\n'
                     '[[model.terms]]\nname = "microfacet"\nalpha = 0.5\nfresnel = "schlick"\nf0 = 0.5\n')
    r = cli("fit", tmp_path / "m.bsdf", "--model", start, "--free", "terms.0.albedo,terms.1.alpha,terms.1.f0",
            "--starts", "2", "-o", tmp_path / "fit.toml", "--json")
    assert r.exit_code == 0, r.output
    doc = json.loads(r.output)
    assert doc["residual"] < 0.5 * lam.residual
    assert doc["parameters"]["terms.1.alpha"] == pytest.approx(0.25, rel=0.05)  # the lobe it was made with
    r = cli("tabulate", tmp_path / "fit.toml")  # validates before writing: exit 0 only if every check passes
    assert r.exit_code == 0, r.output
    fitted = brdftab.open(tmp_path / "fit.nc")
    assert fitted.grid.describe() == "merl theta_h[90] x theta_d[90] x phi_d[180]"


def test_the_html_report_shows_the_fit(table_file, tmp_path):
    import base64
    import io
    import re

    from PIL import Image

    r = cli("fit", table_file, "--model", "microfacet", "--param", "alpha=0.6", "--free", "alpha", "--starts", "2",
            "--report", tmp_path / "fit.html", "--json")
    assert r.exit_code == 0, r.output
    doc = json.loads(r.output)
    page = (tmp_path / "fit.html").read_text(encoding="utf-8")
    assert page.startswith("<!DOCTYPE html>") and page.rstrip().endswith("</html>")
    assert f'<td>alpha</td><td class="num">{doc["parameters"]["alpha"]:.4g}</td>' in page
    assert "Residual per incidence angle" in page and "Directional albedo" in page
    images = re.findall(r'src="data:image/png;base64,([A-Za-z0-9+/=]+)"', page)
    assert len(images) == 1
    assert Image.open(io.BytesIO(base64.b64decode(images[0]))).size[0] > 100
    r = cli("fit", table_file, "--model", "microfacet", "--param", "alpha=0.6", "--free", "alpha",
            "--report", tmp_path / "fit.txt")
    one_error(r.stderr, r.exit_code, "name it *.html")
    assert not (tmp_path / "fit.txt").exists()


def test_a_grid_without_a_spec_form_is_refused_before_the_search(table_file, tmp_path, monkeypatch):
    from brdftab import fitting

    def no_form(grid):
        raise BrdftabError(f"the table's grid ({grid.describe()}) has no [grid] form that reproduces its nodes")

    monkeypatch.setattr(fitting, "grid_table", no_form)
    r = cli("fit", table_file, "--model", "microfacet", "--param", "alpha=0.6", "--free", "alpha",
            "-o", tmp_path / "fit.toml")
    one_error(r.stderr, r.exit_code, "no [grid] form")
    assert not (tmp_path / "fit.toml").exists()
    result = brdftab.fit(table_file, "microfacet", ["alpha"], params={"alpha": 0.6}, starts=1, albedo=False)
    assert result.grid_table is None and result.parameters["alpha"] == pytest.approx(0.3, rel=1e-6)
    with pytest.raises(BrdftabError, match="no \\[grid\\] form"):
        result.spec_text("fit.nc")


def test_the_robust_loss_keeps_negative_noise_samples_from_pulling_the_fit(tmp_path):
    """300 negative samples in a measured-like file: the log metric floors them (residuals of
    several units); soft_l1 (the default) still gives the Lambert albedo the file was made with
    to 3 %, the plain least-squares loss lets them pull it 10 % or more low (measured 1.9 % and
    -16 %). The file has the level warp: the fit weights the file's sample nodes, and this
    source is not reciprocal (tests/_measured.py), so where the nodes lie moves the albedo of
    a reciprocal fit; the lobe warp's steepness share puts more of them at grazing exits,
    where the asymmetry raises f, and soft_l1's albedo comes out 7 % high there."""
    from _measured import measured_bsdf

    measured_bsdf(tmp_path / "m.bsdf", negatives=300, warp="level")
    table = brdftab.open(tmp_path / "m.bsdf")
    start = {"name": "sum", "terms": [{"name": "lambert", "albedo": [0.5, 0.5, 0.5]},
                                      {"name": "microfacet", "alpha": 0.5, "fresnel": "schlick",
                                       "f0": [0.5, 0.5, 0.5]}]}
    free = ["terms.0.albedo", "terms.1.alpha", "terms.1.f0"]
    truth = np.array([0.2, 0.3, 0.4])  # tests/_measured.py's Lambert term

    def albedo(loss):
        r = brdftab.fit(table, start, free, starts=1, albedo=False, loss=loss)
        return np.array([r.parameters[f"terms.0.albedo[{i}]"] for i in range(3)])

    assert np.max(np.abs(albedo("soft_l1") / truth - 1)) < 0.03
    assert np.min(albedo("linear") / truth - 1) < -0.10


def test_the_reported_uncertainties_are_the_spread_of_repeated_fits():
    """Monte Carlo: 30 tables, each with its own 1 % noise; the standard deviation of the 30
    fitted values is the uncertainty each fit reports (to the sampling error of a standard
    deviation from 30 values, about 13 %)."""
    truth = models.create("microfacet", alpha=0.2, fresnel="dielectric", n=1.5)
    clean = tabulate(truth, grid_from_config(GRID))
    fitted, reported = [], []
    for seed in range(30):
        table = tabulate(truth, grid_from_config(GRID))
        table.values[...] = clean.values * (1.0 + 0.01 * np.random.default_rng(100 + seed).standard_normal(
            clean.values.shape))
        r = brdftab.fit(table, "microfacet", free=["alpha", "n"], starts=1, albedo=False,
                        params={"fresnel": "dielectric", "alpha": 0.25, "n": 1.4})
        fitted.append([r.parameters["alpha"], r.parameters["n"]])
        reported.append([r.uncertainties["alpha"], r.uncertainties["n"]])
    ratio = np.std(fitted, axis=0, ddof=1) / np.mean(reported, axis=0)
    assert np.all((ratio > 0.65) & (ratio < 1.5)), ratio


def test_a_spectral_fit_writes_its_wavelengths_and_material(tmp_path):
    """A spectral table (aluminium's optical constants, from the BRDF object rather than a spec):
    the spec keeps the material inline and the table's wavelengths, and tabulates the fit exactly."""
    truth = models.create("microfacet", alpha=0.25, fresnel="conductor", material="Al")
    lam = np.array([450.0, 550.0, 650.0])
    table = tabulate(truth, grid_from_config(GRID), lam)
    result = brdftab.fit(table, truth, ["alpha"], params={"alpha": 0.5}, starts=2, albedo=False)
    assert result.parameters["alpha"] == pytest.approx(0.25, rel=1e-6)
    (tmp_path / "fit.toml").write_text(result.spec_text("fit.nc"))
    spec = brdftab.load_spec(tmp_path / "fit.toml")
    assert np.array_equal(spec.wavelengths, lam) and spec.grid.equals(table.grid)
    assert np.array_equal(tabulate(spec.model, spec.grid, spec.wavelengths).values,
                          tabulate(result.model, table.grid, lam).values)


def test_a_fitted_spec_written_elsewhere_reads_the_start_s_files(tmp_path):
    """The start file names a material CSV relative to its folder; the fitted spec, written in
    another folder, reads the same file."""
    start = tmp_path / "start"
    start.mkdir()
    (start / "nk.csv").write_text("400,0.5,4.0\n550,0.9,5.0\n700,1.5,6.0\n")
    (start / "start.toml").write_text('[model]\nname = "microfacet"\nalpha = 0.5\nfresnel = "conductor"\n'
                                      'material = "nk.csv"\n')
    truth = brdftab.spec.build_model({"name": "microfacet", "alpha": 0.2, "fresnel": "conductor",
                                      "material": str(start / "nk.csv")}, "model", tmp_path / "x.toml")
    brdftab.save(tabulate(truth, grid_from_config(GRID), [450.0, 600.0]), tmp_path / "t.nc")
    r = cli("fit", tmp_path / "t.nc", "--model", start / "start.toml", "--free", "alpha", "--starts", "2",
            "-o", tmp_path / "out" / "fit.toml")
    assert r.exit_code == 0, r.output
    spec = brdftab.load_spec(tmp_path / "out" / "fit.toml")
    assert spec.model.parameters["alpha"] == pytest.approx(0.2, rel=1e-6)
    wi, wo, lam = [0, 0, 1], [0.6, 0, 0.8], [450.0, 600.0]  # the CSV's n, k: the truth's f
    assert np.allclose(spec.model.eval(wi, wo, lam), truth.eval(wi, wo, lam), rtol=1e-5)
