"""``brdftab validate`` and validation before export (``brdftab tabulate``), end to end.

Exit codes: 0 every check passed (warnings allowed), 1 a check failed, 2 bad input. The JSON
output is checked against the schema shipped in the package, the JUnit XML by its structure
(testsuites / testsuite / testcase / failure).
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import brdftab
from brdftab import models
from brdftab.checks import CHECKS, load_schema
from brdftab.cli import main
from brdftab.grids import RusinkiewiczGrid

from test_checks import jsonschema_errors, validate_json

ROOT = Path(__file__).resolve().parent.parent
GRID = RusinkiewiczGrid(10, 10, 20)

BAD_SPEC = """\
description = "Lambert scaled to an albedo of 1.2: not energy conserving."
[model]
name = "scale"
factor = 1.5
[model.term]
name = "lambert"
albedo = 0.8
[grid]
type = "rusinkiewicz"
n_theta_h = 10
n_theta_d = 10
n_phi_d = 20
[[output]]
path = "bright.nc"
"""


def cli(*args):
    result = CliRunner().invoke(main, [str(a) for a in args])
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    return result


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("tables")
    brdftab.save(models.create("lambert", albedo=0.8), d / "good.nc", grid=GRID)
    bright = models.create("scale", factor=1.5, term=models.create("lambert", albedo=0.8))
    brdftab.save(bright, d / "bad.nc", grid=GRID)
    (d / "junk").mkdir()
    (d / "junk" / "garbage.nc").write_bytes(b"\x89HDF\r\n\x1a\n" + bytes(range(256)) * 4)
    return d


def status_lines(text):
    return {m.group(2): m.group(1) for m in re.finditer(r"^\s+(PASS|WARN|FAIL|SKIP)\s+(\S+)\s", text, re.M)}


def test_exit_code_0_for_a_valid_table_with_one_line_per_check(files):
    r = cli("validate", files / "good.nc")
    assert r.exit_code == 0, r.output
    lines = status_lines(r.stdout)
    assert set(lines) == set(CHECKS)
    assert lines["energy"] == "PASS" and lines["missing"] == "PASS"
    assert re.search(r"PASS\s+energy\s+max a\(θi\) = 0\.8", r.stdout)


def test_exit_code_1_when_a_check_fails(files):
    r = cli("validate", files / "bad.nc")
    assert r.exit_code == 1
    assert status_lines(r.stdout)["energy"] == "FAIL"
    assert re.search(r"FAIL\s+energy\s+max a\(θi\) = 1\.2", r.stdout)


def test_exit_code_2_for_bad_input(files):
    r = cli("validate", files / "junk" / "garbage.nc")
    assert r.exit_code == 2 and "garbage.nc" in r.stderr and "Traceback" not in r.stderr
    assert cli("validate", files / "nope.nc").exit_code == 2
    assert cli("validate", str(files / "none-*.nc")).exit_code == 2
    assert cli("validate", files / "good.nc", "--set", "energy.tolerence=0.1").exit_code == 2
    # a readable file is still reported next to an unreadable one; bad input wins the exit code
    r = cli("validate", files / "good.nc", files / "junk" / "garbage.nc")
    assert r.exit_code == 2 and "PASSED" in r.stdout
    # the same through the installed entry point, as CI runs it
    proc = subprocess.run([sys.executable, "-m", "brdftab", "validate", str(files / "junk" / "garbage.nc")],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and proc.stderr.startswith("brdftab: error:")


def test_several_paths_and_globs(files):
    r = cli("validate", str(files / "*.nc"))
    assert r.exit_code == 1
    assert r.stdout.count("PASSED") == 1 and r.stdout.count("FAILED") == 1
    assert "2 checked: 1 passed, 1 failed; 0 could not be read" in r.stdout
    r = cli("validate", str(files / "**" / "*.nc"))  # recursive: finds the garbage file too
    assert r.exit_code == 2


def test_json_output_matches_the_schema_and_junit_its_structure(files, tmp_path):
    junit = tmp_path / "report.xml"
    r = cli("validate", files / "good.nc", files / "bad.nc", files / "junk" / "garbage.nc", "--json",
            "--junit", junit)
    assert r.exit_code == 2
    doc = json.loads(r.stdout)
    schema = load_schema()
    assert validate_json(doc, schema) == [] and jsonschema_errors(doc, schema) == []
    assert doc["passed"] is False
    assert [rep["passed"] for rep in doc["reports"]] == [True, False]
    assert len(doc["errors"]) == 1 and "garbage.nc" in doc["errors"][0]["subject"]
    energy = next(c for c in doc["reports"][1]["checks"] if c["name"] == "energy")
    assert energy["status"] == "fail" and energy["figure"] == pytest.approx(1.2, abs=1e-4)
    root = ET.parse(junit).getroot()
    assert root.tag == "testsuites" and root.get("errors") == "1"
    suites = root.findall("testsuite")
    assert len(suites) == 3
    good, bad, junk = suites
    assert good.get("failures") == "0" and int(good.get("tests")) == len(good.findall("testcase"))
    failing = [c.get("name") for c in bad.findall("testcase") if c.find("failure") is not None]
    assert failing == ["energy"]
    assert junk.find("testcase").find("error") is not None


def test_thresholds_defaults_then_spec_then_command_line(tmp_path):
    spec = tmp_path / "bright.toml"
    spec.write_text(BAD_SPEC + "[validation.energy]\ntolerance = 0.5\n")
    r = cli("validate", spec)
    assert r.exit_code == 0, r.output              # 1.2 <= 1 + 0.5 from the spec
    assert not (tmp_path / "bright.nc").exists()   # validate writes nothing
    r = cli("validate", spec, "--set", "energy.tolerance=0.01")
    assert r.exit_code == 1                        # the command line overrides the spec
    r = cli("validate", spec, "--set", "energy.tolerance=0.01", "--level", "energy=warn")
    assert r.exit_code == 0 and status_lines(r.stdout)["energy"] == "WARN"
    config = tmp_path / "ci.toml"
    config.write_text("[validation.energy]\ntolerance = 0.01\n")
    assert cli("validate", spec, "--config", config).exit_code == 1
    r = cli("validate", spec, "--set", "albedo.expected=1.2", "--set", "albedo.tolerance=1e-3")
    assert r.exit_code == 0 and status_lines(r.stdout)["albedo"] == "PASS"
    r = cli("validate", spec, "--set", "albedo.expected=[1.0, 1.2]", "--set", "albedo.expected_theta_i_deg=[0, 45]")
    assert r.exit_code == 1 and status_lines(r.stdout)["albedo"] == "FAIL"


def test_cli_expected_albedo_replaces_the_spec_pair(tmp_path):
    spec = tmp_path / "l.toml"
    spec.write_text('[model]\nname = "lambert"\nalbedo = 0.8\n[grid]\ntype = "rusinkiewicz"\nn_theta_h = 8\n'
                    'n_theta_d = 8\nn_phi_d = 16\n[[output]]\npath = "l.nc"\n[validation.albedo]\n'
                    'expected = [0.8, 0.79]\nexpected_theta_i_deg = [0, 60]\n')
    run = lambda *a: subprocess.run([sys.executable, "-m", "brdftab", "validate", str(spec), *a],  # noqa: E731
                                    capture_output=True, text=True)
    assert run().returncode == 0
    p = run("--set", "albedo.expected=0.7")
    assert p.returncode == 1 and "FAIL  albedo" in p.stdout and "every θi" in p.stdout, p.stdout + p.stderr


def test_tabulate_refuses_an_invalid_model_and_writes_it_with_allow_invalid(tmp_path):
    spec = tmp_path / "bright.toml"
    spec.write_text(BAD_SPEC)
    r = cli("tabulate", spec)
    assert r.exit_code == 1
    assert "energy" in r.stderr and "1.2" in r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bright.toml"]
    r = cli("tabulate", spec, "--allow-invalid")
    assert r.exit_code == 0 and (tmp_path / "bright.nc").exists()
    t = brdftab.open(tmp_path / "bright.nc")
    attrs = t.ds.attrs
    assert int(attrs["validation_passed"]) == 0 and "energy" in attrs["validation_summary"]
    report = json.loads(attrs["validation_report"])
    sub = {"$ref": "#/$defs/report", "$defs": load_schema()["$defs"]}
    assert validate_json(report, sub) == [] and jsonschema_errors(report, sub) == []
    assert [c["status"] for c in report["checks"] if c["name"] == "energy"] == ["fail"]
    theta = np.degrees(t.ds["albedo_theta_i"].values)  # the albedo curve: numbers, not JSON text
    assert len(theta) == 90 and theta[-1] == pytest.approx(89.0)
    assert np.allclose(t.ds["albedo"].values, 1.2, atol=1e-4)


def test_a_valid_export_stores_the_validation_summary_and_albedo_curve(tmp_path):
    spec = tmp_path / "white.toml"
    spec.write_text(BAD_SPEC.replace("factor = 1.5", "factor = 1.0").replace("bright.nc", "white.nc"))
    assert cli("tabulate", spec).exit_code == 0
    ds = brdftab.open(tmp_path / "white.nc").ds
    attrs = ds.attrs
    assert int(attrs["validation_passed"]) == 1 and attrs["validation_summary"].startswith("all checks passed")
    assert np.allclose(ds["albedo"].values, 0.8, atol=1e-4)
    assert ds["albedo_white_sky"].values.tolist() == pytest.approx([0.8], abs=1e-4)


def test_list_checks_and_the_pre_commit_hook(files):
    r = cli("validate", "--list-checks")
    assert r.exit_code == 0 and all(re.search(rf"^{n} \[", r.stdout, re.M) for n in CHECKS)
    hooks = (ROOT / ".pre-commit-hooks.yaml").read_text()
    entries = re.findall(r"^\s+entry:\s*(.+)$", hooks, re.M)
    ids = re.findall(r"^- id:\s*(\S+)$", hooks, re.M)
    assert ids == ["brdftab-validate", "brdftab-validate-specs"] and set(entries) == {"brdftab validate"}
    pattern = re.search(r"^\s+files:\s*(.+)$", hooks, re.M).group(1)
    assert re.search(pattern, "tables/gold.nc") and not re.search(pattern, "pyproject.toml")
    # the hook's entry with staged file names appended, as pre-commit calls it
    r = cli(*entries[0].split()[1:], files / "good.nc", files / "bad.nc")
    assert r.exit_code == 1


# --------------------------------------------------------------------------------------------
# Inputs and outputs are checked before any checking work

def _no_checks(monkeypatch):
    import brdftab.checks
    import brdftab.pipeline

    def refuse(*args, **kwargs):
        raise AssertionError("a check ran before the inputs and outputs were checked")

    monkeypatch.setattr(brdftab.checks, "run_checks", refuse)
    monkeypatch.setattr(brdftab.pipeline, "validate", refuse)


def test_a_missing_input_or_a_glob_matching_nothing_is_refused_before_any_check(tmp_path, monkeypatch):
    spec = tmp_path / "bright.toml"
    spec.write_text(BAD_SPEC)
    _no_checks(monkeypatch)
    r = CliRunner().invoke(main, ["validate", str(spec), str(tmp_path / "tables" / "**" / "*.nc"),
                                  str(tmp_path / "gone.nc"), str(tmp_path), "--junit", str(tmp_path / "v.xml")])
    assert r.exception is None or isinstance(r.exception, SystemExit), repr(r.exception)
    assert r.exit_code == 2 and r.stdout == ""
    lines = r.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("brdftab: error: "), lines
    assert "*.nc: no file matches" in lines[0] and "gone.nc: no such file" in lines[0]
    assert f"{tmp_path}: is a folder" in lines[0] and "nothing checked" in lines[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bright.toml"]  # no report written


def test_an_unwritable_junit_folder_is_refused_before_any_check(tmp_path, monkeypatch):
    import os

    from brdftab import _locks

    spec = tmp_path / "bright.toml"
    spec.write_text(BAD_SPEC)
    real_open = os.open

    def read_only_folder(path, *args, **kw):  # what a folder without write permission answers
        if str(path).startswith(str(tmp_path / "ro")):
            raise PermissionError(13, "Permission denied", str(path))
        return real_open(path, *args, **kw)

    (tmp_path / "ro").mkdir()
    monkeypatch.setattr(_locks.os, "open", read_only_folder)
    _no_checks(monkeypatch)
    r = CliRunner().invoke(main, ["validate", str(spec), "--junit", str(tmp_path / "ro" / "v.xml")])
    assert r.exception is None or isinstance(r.exception, SystemExit), repr(r.exception)
    assert r.exit_code == 2 and r.stdout == ""
    lines = r.stderr.splitlines()
    expected = (f"brdftab: error: {tmp_path / 'ro' / 'v.xml'}: cannot write in folder {tmp_path / 'ro'} "
                "(Permission denied)")
    assert lines == [expected]


def test_text_from_a_file_is_shown_escaped_in_validate_and_eval(tmp_path):
    """Channel names are a file's data: a bidi override (U+202E) or an escape sequence in one is
    printed escaped by validate and eval (as info does), not acted on by the terminal."""
    import xarray as xr
    from click.testing import CliRunner

    import brdftab
    from brdftab.cli import main

    grid = {"type": "rusinkiewicz", "n_theta_h": 4, "n_theta_d": 4, "n_phi_d": 8}
    brdftab.save(brdftab.models.create("lambert", albedo=[0.8, 0.5, 0.2]), tmp_path / "a.nc", grid=grid)
    with xr.open_dataset(tmp_path / "a.nc") as ds:
        ds = ds.load()
    ds = ds.assign_coords(channel=np.array(["R\u202eX", "G\x1b[31m", "B"], dtype=object))
    ds.to_netcdf(tmp_path / "odd.nc")
    for args in (["validate", str(tmp_path / "odd.nc")],
                 ["eval", str(tmp_path / "odd.nc"), "--wi-deg", "10,0", "--wo-deg", "20,180"]):
        out = CliRunner().invoke(main, args).stdout
        assert "\u202e" not in out and "\x1b" not in out, out
        assert "R\\u202eX" in out or "G\\x1b[31m" in out, out
