"""The Mueller checks (:mod:`brdftab.checks.mueller`) on polarized models and tables, and how
they are reported (text, JSON, JUnit, HTML) and plotted.

References: closed forms — a Fresnel (Jones) matrix has coherency eigenvalues (M00, 0, 0, 0)
and depolarization index 1; the ideal depolarizer diag(1, 0, 0, 0) has eigenvalues M00/4 and
index 0; diag(1, 1, 1, −1) (a sign flip of S3 alone, which no optical element does) has an
eigenvalue −M00/2; exchanging S1 and S2 (a 45° frame mix-up) is not a Mueller matrix either.
"""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from _polarized import DepolarizingLambert, GGXConductor, Scaled, fresnel_mueller

import brdftab
from brdftab.checks import run_checks
from brdftab.checks.mueller import coherency_eigenvalues, depolarization_index, reciprocity_transform
from brdftab.grids import RusinkiewiczGrid
from brdftab.table import tabulate

MUELLER = ("mueller_realizability", "mueller_bounds", "polarized_reciprocity", "depolarization", "mueller_albedo")
FLIP_S3 = np.diag([1.0, 1.0, 1.0, -1.0])
SWAP_S1_S2 = np.array([[1.0, 0, 0, 0], [0, 0, 1, 0], [0, 1, 0, 0], [0, 0, 0, 1]])
GRID = RusinkiewiczGrid(10, 10, 24, phi_d_fold="none")


def test_helpers_against_closed_forms():
    f = fresnel_mueller(np.array([0.2, 0.6, 1.0]), 0.3 + 3j)
    lam = coherency_eigenvalues(f)
    assert np.allclose(lam[:, :3], 0.0, atol=1e-12) and np.allclose(lam[:, 3], f[:, 0, 0], rtol=1e-12)
    assert np.allclose(depolarization_index(f), 1.0, rtol=1e-12)
    assert np.allclose(coherency_eigenvalues(np.diag([2.0, 0, 0, 0])), 0.5)
    assert depolarization_index(np.diag([2.0, 0, 0, 0])) == 0.0
    assert np.isclose(coherency_eigenvalues(FLIP_S3)[0], -0.5)
    assert coherency_eigenvalues(SWAP_S1_S2)[0] < -0.4
    # the reversed path of a Fresnel reflection is itself (Q Mᵀ Q = M for this matrix)
    assert np.allclose(reciprocity_transform(f), f, atol=1e-15)


def test_physical_models_pass_every_mueller_check():
    for model in (GGXConductor(0.3), DepolarizingLambert(0.5)):
        report = run_checks(model, only=MUELLER)
        assert [o.status for o in report.outcomes] == ["pass"] * 5, report.to_text()
    dep = run_checks(DepolarizingLambert(0.5), only=("depolarization",)).get("depolarization")
    assert dep.figure == 0.0


def test_unpolarized_brdfs_skip_them():
    report = run_checks(brdftab.models.create("microfacet", distribution="ggx", alpha=0.3, fresnel="schlick", f0=0.9), only=MUELLER)
    assert {o.status for o in report.outcomes} == {"skip"}
    assert "not polarized" in report.outcomes[0].detail


@pytest.mark.parametrize("right, what", [(FLIP_S3, "S3 sign flipped"), (SWAP_S1_S2, "S1/S2 swapped")])
def test_a_non_physical_table_fails_realizability_with_place_and_figure(right, what, tmp_path):
    bad = Scaled(GGXConductor(0.3), right)
    table = tabulate(bad, GRID, polarized=True, progress=False)
    report = run_checks(table, only=MUELLER)
    real = report.get("mueller_realizability")
    assert real.status == "fail", what
    assert real.figure == pytest.approx(-0.5, abs=0.05)
    assert set(real.data["where"]) == {"theta_h_deg", "theta_d_deg", "phi_d_deg", "channel"}
    assert "theta_h = " in real.detail and "channel" in real.detail
    assert report.get("polarized_reciprocity").status == "fail", what
    # reported in JSON, JUnit and text like every check
    doc = json.loads(json.dumps(report.to_json()))
    entry = next(o for o in doc["checks"] if o["name"] == "mueller_realizability")
    assert entry["status"] == "fail" and entry["family"] == "mueller" and entry["data"]["where"]["channel"]
    junit = ET.fromstring(report.to_junit().encode("utf-8"))
    failures = [tc.get("name") for tc in junit.iter("testcase") if tc.find("failure") is not None]
    assert any("mueller_realizability" in n for n in failures)
    assert "FAIL  mueller_realizability" in report.to_text()
    # and the export is refused from the command line, naming the check and its figure
    out = tmp_path / "bad.nc"
    with pytest.raises(brdftab.checks.ChecksFailed, match="mueller_realizability"):
        brdftab.checks.guard(table, what=str(out))


def test_measured_non_physical_data_is_reported_not_refused():
    table = tabulate(Scaled(GGXConductor(0.3), FLIP_S3), GRID, polarized=True, progress=False)
    table.origin = "measured"
    out = run_checks(table, only=("mueller_realizability",)).get("mueller_realizability")
    assert out.status == "warn" and "measured data" in out.detail


def test_bounds_and_albedo_catch_what_they_name():
    bright = Scaled(DepolarizingLambert(0.5), np.diag([3.0, 0, 0, 0]))  # albedo 1.5
    r = run_checks(bright, only=("mueller_albedo", "energy"))
    # M00 is eval here: one verdict on its albedo (energy's), the Mueller check reports it
    assert r.get("energy").status == "fail" and r.get("energy").figure == pytest.approx(1.5, rel=1e-3)
    m = r.get("mueller_albedo")
    assert m.status == "pass" and "max albedo of M00 = 1.5" in m.detail and "energy check" in m.detail

    class Apart(Scaled):  # eval (the unscaled term's) is not M00
        def _eval(self, wi, wo, lam, n):
            return self.term._eval(wi, wo, lam, n)

    apart = run_checks(Apart(DepolarizingLambert(0.5), np.diag([3.0, 0, 0, 0])), only=("mueller_albedo",))
    a = apart.get("mueller_albedo")
    assert a.status == "fail" and a.figure == pytest.approx(1.5, rel=1e-3) and "eval is not M00" in a.detail
    over = Scaled(DepolarizingLambert(0.5), np.array([[1.0, 2.0, 0, 0], [0, 0, 0, 0], [0, 0, 0, 0], [0, 0, 0, 0]]))
    b = run_checks(over, only=("mueller_bounds", "depolarization"))
    assert b.get("mueller_bounds").status == "fail" and b.get("mueller_bounds").figure == pytest.approx(1.0)
    assert b.get("depolarization").status == "fail" and b.get("depolarization").figure == pytest.approx(2 / 3 ** 0.5)


def test_polarized_reciprocity_on_table_node_pairs():
    table = tabulate(GGXConductor(0.3), GRID, polarized=True, progress=False)
    r = run_checks(table, only=("polarized_reciprocity",)).get("polarized_reciprocity")
    assert r.status == "pass" and r.figure < 1e-12 and "node pairs" in r.detail
    assert r.data["compared"] > 1000


def test_mueller_plot_draws_every_element(tmp_path):
    from brdftab import plot

    fig = plot.figure("mueller", GGXConductor(0.3), theta_i_deg=[30.0], wavelengths=[550.0])
    arts = plot.artists(fig)
    assert len(arts) == 16
    m01 = arts["theta_i=30|channel=550 nm|element=m01"]
    theta_o, y = m01.get_xdata(), m01.get_ydata()
    wi, wo = plot.in_plane_directions([30.0], theta_o)
    ref = GGXConductor(0.3).eval_mueller(wi[0], wo[0], [550.0])[:, 0]
    np.testing.assert_allclose(y, ref[:, 0, 1] / ref[:, 0, 0], rtol=1e-12)
    with pytest.raises(brdftab.errors.BrdftabError, match="not polarized"):
        plot.figure("mueller", brdftab.models.create("microfacet", distribution="ggx", alpha=0.3, fresnel="schlick", f0=0.9))


def test_the_html_report_draws_the_mueller_matrix_of_a_polarized_brdf():
    from brdftab.report_html import Entry, render

    model = DepolarizingLambert(0.5)  # grey: the report's figures draw one channel
    report = run_checks(model, only=("mueller_realizability",))
    page = render([Entry(report, model)])
    assert 'id="check-0-mueller_realizability"' in page and 'alt="Mueller matrix"' in page


def test_validate_reports_a_non_physical_pbsdf_in_json_and_junit(tmp_path):
    from _cli import cli

    path = tmp_path / "bad.pbsdf"
    brdftab.save(Scaled(GGXConductor(0.3), FLIP_S3), path, grid=RusinkiewiczGrid(6, 6, 12, phi_d_fold="none"))
    junit = tmp_path / "r.xml"
    only = [x for name in ("energy", "albedo", "tabulation", "reciprocity", "isotropy", "bilateral", "mueller_albedo")
            for x in ("--level", f"{name}=off")]
    result = cli("validate", path, "--json", "--junit", junit, *only)
    assert result.exit_code == 1, result.output
    doc = json.loads(result.stdout)
    checks = {c["name"]: c for c in doc["reports"][0]["checks"]}
    real = checks["mueller_realizability"]
    assert real["status"] == "fail" and real["figure"] == pytest.approx(-0.5, abs=0.05)
    assert set(real["data"]["where"]) == {"theta_h_deg", "theta_d_deg", "phi_d_deg", "channel"}
    assert checks["mueller_bounds"]["status"] == "pass"
    assert any(tc.get("name", "").endswith("mueller_realizability") and tc.find("failure") is not None
               for tc in ET.parse(junit).getroot().iter("testcase"))


def test_polarized_reciprocity_off_the_nodes_of_a_gonio_table_warns_instead_of_failing():
    from brdftab.grids import SphericalGrid

    # θi and θo on different nodes: a pair and its twin are interpolated from different nodes
    grid = SphericalGrid(np.radians(np.arange(0, 90, 15.0)), [0.0], np.radians(np.arange(0, 90, 10.0)),
                         np.radians(np.arange(0, 360, 30.0)))
    table = tabulate(GGXConductor(0.3), grid, polarized=True, progress=False)
    r = run_checks(table, only=("polarized_reciprocity",), config={"polarized_reciprocity": {"pairs": 512}})
    out = r.get("polarized_reciprocity")
    assert "interpolated pairs" in out.detail
    assert out.status == "warn" and "reported, not judged" in out.detail  # coarse: the twins differ
