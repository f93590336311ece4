"""The HTML validation report (brdftab validate --html, brdftab.report_html): what it shows
for a failing and a passing table, the data behind its maps, and the page as a real browser
renders it (headless Chromium, installed by .ci/run)."""

from __future__ import annotations

import html.parser
import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from _cli import one_error, run

import brdftab
from brdftab import plot
from brdftab.brdf import BRDF
from brdftab.checks import run_checks
from brdftab.grids.rusinkiewicz import RusinkiewiczGrid
from brdftab.models import create
from brdftab.table import tabulate


class LeansOnTheSource(BRDF):
    """f = (1 + cosθi) / (2π): declared reciprocal, but it depends on the incident direction only."""

    name = "leans-on-the-source"

    def _eval(self, wi, wo, lam, n):
        return np.repeat(((1.0 + wi[:, 2]) / (2.0 * np.pi))[:, None], n, axis=1)


class Page(html.parser.HTMLParser):
    """The report's sections: per h2, its check rows (name, class, cells) and images (alt)."""

    def __init__(self):
        super().__init__()
        self.sections, self._cell, self._row = [], None, None

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "h2":
            self.sections.append({"title": "", "rows": [], "images": [], "in_title": True})
        elif tag == "tr" and self.sections:
            self._row = {"class": a.get("class", ""), "cells": []}
        elif tag in ("td", "th") and self._row is not None:
            self._cell = ""
        elif tag == "img" and self.sections:
            self.sections[-1]["images"].append((a.get("alt"), a.get("src", "")))
        elif tag == "script" or (tag == "link") or (tag == "img" and not a.get("src", "").startswith("data:")):
            raise AssertionError(f"the report must be self-contained: <{tag} {a}>")

    def handle_endtag(self, tag):
        if tag == "h2":
            self.sections[-1]["in_title"] = False
        elif tag in ("td", "th") and self._cell is not None:
            self._row["cells"].append(self._cell.strip())
            self._cell = None
        elif tag == "tr" and self._row is not None:
            if self._row["cells"] and self._row["cells"][0] != "check":
                self.sections[-1]["rows"].append(self._row)
            self._row = None

    def handle_data(self, data):
        if self._cell is not None:
            self._cell += data
        elif self.sections and self.sections[-1]["in_title"]:
            self.sections[-1]["title"] += data


def parse(path) -> list:
    p = Page()
    p.feed(Path(path).read_text(encoding="utf-8"))
    return p.sections


@pytest.fixture(scope="module")
def tables(tmp_path_factory):
    d = tmp_path_factory.mktemp("report")
    brdftab.save(tabulate(LeansOnTheSource(), RusinkiewiczGrid(12, 12, 24, phi_d_fold="none"), progress=False),
                 d / "leaning.nc")
    brdftab.save(tabulate(create("scale", term=create("lambert", albedo=0.65), factor=2.0), RusinkiewiczGrid(6, 6, 8), progress=False),
                 d / "bright.nc")
    brdftab.save(tabulate(create("lambert", albedo=0.5), RusinkiewiczGrid(6, 6, 8), progress=False), d / "grey.nc")
    return d


@pytest.fixture(scope="module")
def failing(tables):
    out = tables / "failing.html"
    proc = run("validate", tables / "leaning.nc", tables / "bright.nc", "--html", out, "--json", cwd=tables)
    assert proc.returncode == 1, proc.stderr
    return out, json.loads(proc.stdout)


def test_a_failing_report_shows_every_check_its_failure_and_where(failing):
    """Each input's section lists every check of the JSON report with its status, figure and
    threshold; the failed check's row is marked, and the failure has its map: where the
    reciprocity asymmetry lies, and where the energy goes at the worst incidence."""
    path, doc = failing
    sections = parse(path)
    assert len(sections) == 2
    for section, report in zip(sections, doc["reports"]):
        assert section["title"].startswith(report["subject"]) and "FAILED" in section["title"]
        rows = {r["cells"][0]: r for r in section["rows"]}
        assert list(rows) == [c["name"] for c in report["checks"]]
        for c in report["checks"]:
            cells = rows[c["name"]]["cells"]
            assert cells[3] == c["status"].upper() and rows[c["name"]]["class"] == f"row-{c['status']}"
            if c["figure"] is not None:
                assert float(cells[4]) == pytest.approx(c["figure"], rel=1e-3, abs=1e-12)
        alts = [alt for alt, _ in section["images"]]
        assert {"albedo curve", "in-plane curves", "hemisphere map"} <= set(alts)
        failed = [c["name"] for c in report["checks"] if c["status"] == "fail"]
        for name in ("reciprocity", "energy"):
            assert (f"{name} failure map" in alts) == (name in failed), (report["subject"], failed, alts)
    assert "reciprocity" in [c["name"] for c in doc["reports"][0]["checks"] if c["status"] == "fail"]
    assert "energy" in [c["name"] for c in doc["reports"][1]["checks"] if c["status"] == "fail"]


def test_a_passing_report_lists_every_check(tables):
    out = tables / "passing.html"
    proc = run("validate", tables / "grey.nc", "--html", out, cwd=tables)
    assert proc.returncode == 0, proc.stderr
    (section,) = parse(out)
    assert "PASSED" in section["title"]
    report = run_checks(brdftab.open(tables / "grey.nc"))
    assert [r["cells"][0] for r in section["rows"]] == [o.name for o in report.outcomes]
    assert all(r["cells"][3] in ("PASS", "WARN", "SKIP") for r in section["rows"])
    assert not any("failure" in alt for alt, _ in section["images"])


def test_the_maps_hold_the_brdfs_values(tables):
    """The reciprocity map plots |f(wi, wo) − f(wo, wi)| / mean at its directions (recomputed
    here from the model's formula) and the albedo curve the albedo check's own numbers."""
    from brdftab.report_html import _reciprocity_map

    table = brdftab.open(tables / "leaning.nc")
    report = run_checks(table)
    fig, _ = _reciprocity_map(table, report.get("reciprocity"))
    dots = plot.artists(fig)["values"]
    xy = dots.get_offsets()
    theta, phi = plot.equal_area_inverse(xy[:, 0], xy[:, 1])
    where = report.get("reciprocity").data.get("where") or {}
    ti = np.radians(where.get("theta_i_deg", 45.0))
    f_io = 1.0 + np.cos(ti)          # f(wi, wo) ∝ 1 + cosθi; f(wo, wi) ∝ 1 + cosθo
    f_oi = 1.0 + np.cos(theta)
    expected = np.abs(f_io - f_oi) / (0.5 * (f_io + f_oi))
    err = np.abs(np.asarray(dots.get_array()) - expected)  # the asymmetry reaches 0.5 on this map
    # the coarse table's interpolation: median 0.001, 99th percentile 0.005, largest 0.05 (by the
    # direction where wo = wi, on which the Rusinkiewicz angles turn)
    assert np.percentile(err, 99) < 0.01 and err.max() < 0.08 and expected.max() > 0.4
    alb = report.get("albedo")
    fig = plot.albedo_values(alb.data["theta_i_deg"], alb.data["values"], alb.data["channels"], limit=1.01)
    line = plot.artists(fig)["albedo|channel=mono"]
    np.testing.assert_array_equal(line.get_ydata(), np.asarray(alb.data["values"], float).reshape(-1))
    theta_i = np.radians(np.asarray(alb.data["theta_i_deg"], float))
    np.testing.assert_allclose(line.get_ydata(), (1.0 + np.cos(theta_i)) / 2.0, atol=3e-3)  # a = ∫ f cosθo dωo
    # (the coarse table near grazing incidence: largest difference 0.0022)


def chromium_loads(page: Path, tmp_path: Path) -> tuple:
    """Render ``page`` in headless Chromium: (per image (complete, naturalWidth), console lines)."""
    exe = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
    assert exe, "Chromium is needed for this test: apt-get install chromium (.ci/run installs it)"
    wrapper = tmp_path / f"wrap-{page.stem}.html"
    wrapper.write_text(f"""<!DOCTYPE html><html><body><iframe id="r" src="{page.as_uri()}"></iframe><script>
const f = document.getElementById("r");
f.addEventListener("load", () => {{
  const imgs = Array.from(f.contentDocument.images);
  document.body.setAttribute("data-result", JSON.stringify(imgs.map(i => [i.complete, i.naturalWidth])));
}});
</script></body></html>""")
    proc = subprocess.run([exe, "--headless", "--no-sandbox", "--disable-gpu", "--allow-file-access-from-files",
                           "--enable-logging=stderr", "--v=0", "--virtual-time-budget=10000", "--dump-dom",
                           wrapper.as_uri()], capture_output=True, text=True, timeout=120)
    import re

    m = re.search(r'data-result="([^"]*)"', proc.stdout)
    assert m, f"the page did not load: {proc.stderr[-2000:]}"
    images = json.loads(html.unescape(m.group(1)))
    console = [line for line in proc.stderr.splitlines() if "CONSOLE" in line]
    return images, console


def test_the_report_renders_in_a_real_browser(failing, tmp_path):
    """Headless Chromium loads the failing report without a console message and decodes every
    image (natural width > 0); the same harness catches a broken image and a script error."""
    path, _ = failing
    images, console = chromium_loads(path, tmp_path)
    assert len(images) == sum(len(s["images"]) for s in parse(path)) >= 8
    assert all(done and width > 0 for done, width in images), images
    assert console == []
    broken = tmp_path / "broken.html"
    broken.write_text('<!DOCTYPE html><html><body><img alt="x" src="data:image/png;base64,AAAA">'
                      '<script>console.error("boom")</script></body></html>')
    images, console = chromium_loads(broken, tmp_path)
    assert images == [[True, 0]] and len(console) == 1 and "boom" in console[0]


def test_html_to_a_missing_folder_is_refused_before_any_check(tables):
    proc = run("validate", tables / "grey.nc", "--html", tables / "nowhere" / "r.html")
    one_error(proc.stderr, proc.returncode, "--html", "no such folder")
