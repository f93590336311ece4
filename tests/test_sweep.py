"""Sweeps: a ``[sweep]`` table expands one spec into many tables (brdftab/sweep.py, ``brdftab
tabulate`` on a sweep spec). Members are compared with separate runs of specs written out by
hand with the same values; the summary's albedo with the Lambertian identity a(θi) = albedo."""

from __future__ import annotations

import csv
import hashlib
import json

import numpy as np
import pytest
import xarray as xr

from _cli import cli, names, one_error

GRID = '[grid]\ntype = "rusinkiewicz"\nn_theta_h = 4\nn_theta_d = 4\nn_phi_d = 6\n'
GGX = '[model]\nname = "microfacet"\nfresnel = "dielectric"\nalpha = {alpha}\nn = {n}\n'
QUIET = ("--level", "tabulation=off")  # the tabulation error of a coarse grid is beside the point here


def _values(path):
    with xr.open_dataset(path) as ds:
        return ds["brdf"].values.copy(), dict(ds.attrs)


def _rows(path):
    with open(path, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def test_a_product_sweep_gives_the_tables_of_separate_runs(tmp_path):
    alphas, ns = [0.1, 0.2, 0.3], [1.3, 1.4, 1.5, 1.6]
    sweep = tmp_path / "ggx.toml"
    sweep.write_text('[sweep]\n"model.alpha" = [0.1, 0.2, 0.3]\n"model.n" = [1.3, 1.4, 1.5, 1.6]\nmode = "product"\n'
                     + GGX.format(alpha=0.5, n=1.5) + GRID + '[[output]]\npath = "ggx-{model.alpha}-{model.n}.nc"\n')
    r = cli("tabulate", sweep, *QUIET)
    assert r.exit_code == 0, r.output
    expected = [f"ggx-{a}-{n}.nc" for a in alphas for n in ns]
    assert names(tmp_path) == sorted(expected + ["ggx-sweep.csv", "ggx.toml"])
    sha = hashlib.sha256(sweep.read_bytes()).hexdigest()
    hand = tmp_path / "hand"
    hand.mkdir()
    for i, (a, n) in enumerate((a, n) for a in alphas for n in ns):
        spec = hand / f"s{i}.toml"
        spec.write_text(GGX.format(alpha=a, n=n) + GRID + f'[[output]]\npath = "t{i}.nc"\n')
        assert cli("tabulate", spec, *QUIET).exit_code == 0
        got, attrs = _values(tmp_path / f"ggx-{a}-{n}.nc")
        want, _ = _values(hand / f"t{i}.nc")
        assert np.array_equal(got, want)
        assert json.loads(attrs["sweep_values"]) == {"model.alpha": a, "model.n": n}
        assert attrs["sweep_member"] == i and attrs["spec_sha256"] == sha and attrs["spec_file"] == "ggx.toml"
    info = cli("info", tmp_path / "ggx-0.3-1.6.nc").stdout
    assert "sweep_member:          11" in info and 'sweep_values:          {"model.alpha": 0.3, "model.n": 1.6}' in info
    rows = _rows(tmp_path / "ggx-sweep.csv")
    assert [(float(r["model.alpha"]), float(r["model.n"]), r["output"], r["status"]) for r in rows] == \
        [(a, n, f"ggx-{a}-{n}.nc", "written") for a in alphas for n in ns]
    assert all(r["check_energy"] == "pass" and r["check_reciprocity"] == "pass" for r in rows)
    # rougher and darker: the largest directional albedo falls with alpha at every n
    top = {(float(r["model.alpha"]), float(r["model.n"])): float(r["albedo_max"]) for r in rows}
    assert all(top[0.1, n] > top[0.2, n] > top[0.3, n] for n in ns)


def test_a_zip_sweep_of_a_sum_term_and_a_grid_key(tmp_path):
    """Zipped lists go together; a term of a sum is model.terms[i].KEY (or model.terms.i.KEY);
    a grid key can be swept."""
    body = ('[model]\nname = "sum"\n[[model.terms]]\nname = "lambert"\nalbedo = 0.3\n[[model.terms]]\n'
            'name = "microfacet"\nalpha = 0.2\nfresnel = "dielectric"\nn = 1.5\n' + GRID)
    spec = tmp_path / "coat.toml"
    spec.write_text('[sweep]\n"model.terms[1].alpha" = [0.15, 0.25]\n"model.terms.0.albedo" = [0.2, 0.4]\n'
                    '"grid.n_theta_h" = [3, 5]\nmode = "zip"\n' + body
                    + '[[output]]\npath = "coat-{model.terms[1].alpha}-{grid.n_theta_h}.nc"\n')
    r = cli("tabulate", spec, *QUIET)
    assert r.exit_code == 0, r.output
    assert names(tmp_path) == ["coat-0.15-3.nc", "coat-0.25-5.nc", "coat-sweep.csv", "coat.toml"]
    for alpha, albedo, nh in ((0.15, 0.2, 3), (0.25, 0.4, 5)):
        hand = tmp_path / f"h{nh}"
        hand.mkdir()
        text = body.replace("albedo = 0.3", f"albedo = {albedo}").replace("alpha = 0.2", f"alpha = {alpha}")
        (hand / "s.toml").write_text(text.replace("n_theta_h = 4", f"n_theta_h = {nh}") + '[[output]]\npath = "t.nc"\n')
        assert cli("tabulate", hand / "s.toml", *QUIET).exit_code == 0
        got, attrs = _values(tmp_path / f"coat-{alpha}-{nh}.nc")
        want, _ = _values(hand / "t.nc")
        assert got.shape[0] == nh and np.array_equal(got, want)


def test_a_bad_value_is_reported_and_the_other_members_are_written(tmp_path):
    spec = tmp_path / "lam.toml"
    spec.write_text('[sweep]\n"model.albedo" = [0.25, 1.2, 0.75]\nsummary = "table.csv"\n[model]\nname = "lambert"\n'
                    + GRID + '[[output]]\npath = "out/lam-{model.albedo}.nc"\n')
    r = cli("tabulate", spec)
    assert r.exit_code == 2  # bad input in a member
    errors = [line for line in r.stderr.splitlines() if line.startswith("brdftab: error:")]
    assert len(errors) == 1 and "lam.toml [model.albedo = 1.2]: model.albedo:" in errors[0], r.stderr
    assert names(tmp_path / "out") == ["lam-0.25.nc", "lam-0.75.nc"]
    rows = _rows(tmp_path / "table.csv")
    assert [(r["model.albedo"], r["output"], r["status"]) for r in rows] == [
        ("0.25", "out/lam-0.25.nc", "written"), ("1.2", "out/lam-1.2.nc", "error"),
        ("0.75", "out/lam-0.75.nc", "written")]
    assert "model.albedo" in rows[1]["error"] and rows[1]["albedo_max"] == ""
    for row, albedo in ((rows[0], 0.25), (rows[2], 0.75)):  # a Lambertian a(θi) is its albedo at every θi
        assert float(row["albedo_max"]) == pytest.approx(albedo, rel=1e-9)
        assert float(row["white_sky"]) == pytest.approx(albedo, rel=1e-9)
        assert row["check_energy"] == "pass" and row["error"] == ""


def test_a_member_refused_by_a_check_exits_1_with_its_verdicts(tmp_path):
    spec = tmp_path / "lam.toml"
    spec.write_text('[sweep]\n"model.albedo" = [0.5, 0.7]\n[model]\nname = "lambert"\n' + GRID
                    + '[[output]]\npath = "lam-{model.albedo}.nc"\n[validation.albedo]\nwhite_sky = 0.5\n'
                    'level = "error"\n')
    r = cli("tabulate", spec)
    assert r.exit_code == 1, r.output
    assert "lam.toml [model.albedo = 0.7]: refusing to export" in r.stderr
    assert names(tmp_path) == ["lam-0.5.nc", "lam-sweep.csv", "lam.toml"]
    rows = _rows(tmp_path / "lam-sweep.csv")
    assert [(r["status"], r["check_albedo"]) for r in rows] == [("written", "pass"), ("refused", "fail")]
    assert float(rows[1]["white_sky"]) == pytest.approx(0.7, rel=1e-9)


def test_a_misspelt_swept_key_is_the_spec_s_own_error(tmp_path):
    (tmp_path / "plain.toml").write_text(GGX.format(alpha=0.1, n=1.5).replace("alpha =", "alpah =") + GRID
                                         + '[[output]]\npath = "p.nc"\n')
    r = cli("tabulate", tmp_path / "plain.toml")
    plain = one_error(r.stderr, r.exit_code)
    spec = tmp_path / "s.toml"
    spec.write_text('[sweep]\n"model.alpah" = [0.1, 0.2]\n' + GGX.format(alpha=0.3, n=1.5) + GRID
                    + '[[output]]\npath = "g-{model.alpah}.nc"\n')
    r = cli("tabulate", spec)
    line = one_error(r.stderr, r.exit_code, "s.toml: model.alpah: unknown parameter for model 'microfacet'",
                     "(did you mean 'alpha'?)")
    assert line.split("s.toml: ")[1] == plain.split("plain.toml: ")[1]
    assert names(tmp_path) == ["plain.toml", "s.toml"]


@pytest.mark.parametrize("sweep, path, expected", [
    ('"model.alpha" = [0.1, 0.2]\n"model.n" = [1.3, 1.4, 1.5]\nmode = "zip"', "g-{model.alpha}-{model.n}.nc",
     'sweep: mode = "zip" takes lists of equal length: model.alpha has 2, model.n has 3 values'),
    ('"model.alpha" = [0.1, 0.2]\n"model.n" = [1.3, 1.4]', "g-{model.alpha}.nc",
     "output[0].path: 'g-{model.alpha}.nc' gives the same file g-0.1.nc to two members"),
    ('"model.alpha" = [0.1, 0.2]', "g.nc", "output[0].path: 'g.nc' gives the same file g.nc to two members"),
    ('"model.alpha" = [0.1, 0.2]', "g-{model.alhpa}.nc",
     "output[0].path: {model.alhpa} names no swept key (did you mean 'model.alpha'?)"),
    ('"model.alpha" = [0.1, 0.2]\nmdoe = "zip"', "g-{model.alpha}.nc",
     "sweep.mdoe: unknown key (did you mean 'mode'?)"),
    ('"model.alpha" = 0.1', "g.nc", "sweep.model.alpha: expected a non-empty list of values"),
    # more members than a sweep may have (25 million ran out of memory at 7.6 GB while they were listed)
    (f'"model.alpha" = [{", ".join(str(0.1 + k * 1e-4) for k in range(400))}]\n'
     f'"model.n" = [{", ".join(str(1.3 + k * 1e-4) for k in range(400))}]', "g-{model.alpha}-{model.n}.nc",
     "sweep: 160000 members; at most 100000 (split the sweep into several specs)"),
])
def test_a_sweep_that_cannot_run_is_one_line_before_any_work(tmp_path, sweep, path, expected):
    spec = tmp_path / "s.toml"
    spec.write_text(f"[sweep]\n{sweep}\n" + GGX.format(alpha=0.3, n=1.5) + GRID + f'[[output]]\npath = "{path}"\n')
    r = cli("tabulate", spec)
    one_error(r.stderr, r.exit_code, f"s.toml: {expected}")
    assert names(tmp_path) == ["s.toml"]


def test_validate_checks_every_member_of_a_sweep_spec(tmp_path):
    spec = tmp_path / "lam.toml"
    spec.write_text('[sweep]\n"model.albedo" = [0.5, 0.7]\n[model]\nname = "lambert"\n' + GRID
                    + '[[output]]\npath = "lam-{model.albedo}.nc"\n[validation.albedo]\nwhite_sky = 0.5\n'
                    'level = "error"\n')
    r = cli("validate", spec, "--json")
    assert r.exit_code == 1
    doc = json.loads(r.stdout)
    assert [(rep["subject"].split(" (")[0], rep["passed"]) for rep in doc["reports"]] == [
        (f"{spec} [model.albedo = 0.5]", True), (f"{spec} [model.albedo = 0.7]", False)]
    assert names(tmp_path) == ["lam.toml"]


def test_a_sweep_spec_does_not_stand_for_one_model(tmp_path):
    spec = tmp_path / "s.toml"
    spec.write_text('[sweep]\n"model.albedo" = [0.5, 0.7]\n[model]\nname = "lambert"\n' + GRID
                    + '[[output]]\npath = "l-{model.albedo}.nc"\n')
    r = cli("eval", spec, "--wi-deg", "0,0", "--wo-deg", "0,0")
    one_error(r.stderr, r.exit_code, "s.toml: sweep: this spec describes 2 tables")


def test_a_netcdf_summary_member_numbers_and_members_written_despite_failed_checks(tmp_path):
    spec = tmp_path / "lam.toml"
    spec.write_text('[sweep]\n"model.albedo" = [0.5, 0.7]\nsummary = "sub/table.nc"\n[model]\nname = "lambert"\n'
                    + GRID + '[[output]]\npath = "sub/m{member}.nc"\n[validation.albedo]\nwhite_sky = 0.5\n'
                    'level = "error"\n')
    r = cli("tabulate", spec, "--allow-invalid")
    assert r.exit_code == 0, r.output  # --allow-invalid: written, the failure recorded
    assert names(tmp_path / "sub") == ["m0.nc", "m1.nc", "table.nc"]
    with xr.open_dataset(tmp_path / "sub" / "table.nc") as ds:
        assert list(ds["output"].values) == ["m0.nc", "m1.nc"]
        assert list(ds["status"].values) == ["written", "written, checks failed"]
        assert list(ds["check_albedo"].values) == ["pass", "fail"]
        assert np.allclose(ds["model.albedo"].values, [0.5, 0.7], rtol=0, atol=0)
        assert np.allclose(ds["albedo_max"].values, [0.5, 0.7], rtol=1e-9)
        assert ds.attrs["spec_sha256"] == hashlib.sha256(spec.read_bytes()).hexdigest()
    _, attrs = _values(tmp_path / "sub" / "m1.nc")
    assert attrs["validation_passed"] == 0 and json.loads(attrs["sweep_values"]) == {"model.albedo": 0.7}
