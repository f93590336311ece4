"""Bad input on the command line: exit code 2, exactly one line on stderr, no traceback.

Every spec-file error names the spec file and the offending key; nothing is written.
Spec files are written into pytest's ``tmp_path``; the real CLI runs in-process through
``click.testing.CliRunner`` (stderr separated, click >= 8.2) and, for a subset, as a
subprocess (``python -m brdftab``) to prove that the process itself prints one line and no
traceback.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner

from brdftab.cli import main

SPECS = Path(__file__).resolve().parent.parent / "specs"
GGX_GOLD = SPECS / "ggx-gold.toml"

# A valid spec, in sections; each case replaces one section (or appends text).
BASE = {
    "top": 'description = "a spec with one mistake"\n',
    "model": '[model]\nname = "lambert"\nalbedo = 0.5\n',
    # A tiny grid, so that a case which wrongly passes validation still finishes fast.
    "grid": '[grid]\ntype = "rusinkiewicz"\nn_theta_h = 2\nn_theta_d = 2\nn_phi_d = 2\n',
    "output": '[[output]]\npath = "out.nc"\n',
    "extra": "",
}


def _spec_text(**override) -> str:
    parts = dict(BASE, **override)
    return "".join(parts[k] for k in ("top", "model", "grid", "output", "extra"))


def _microfacet(body: str) -> str:
    return '[model]\nname = "microfacet"\n' + body


def _rusi(body: str) -> str:
    return '[grid]\ntype = "rusinkiewicz"\n' + body


#: A model without a Mueller matrix (Schlick's Fresnel has no polarized form).
_UNPOLARIZED = _microfacet('alpha = 0.3\nfresnel = "schlick"\nf0 = 0.9\n')

# id -> (spec text or bytes, substrings the one error line must contain)
CASES = {
    # unknown keys and names
    "unknown-top-level-key": (_spec_text(top="colour = 3\n"), ["colour", "top-level"]),
    "unknown-model-key-alpah": (
        _spec_text(model=_microfacet("alpah = 0.3\n")),
        ["model.alpah", "did you mean 'alpha'"],
    ),
    "unknown-model-name": (
        _spec_text(model='[model]\nname = "microfacett"\nalpha = 0.3\n'),
        ["model.name", "microfacett", "did you mean 'microfacet'", "lambert", "microfacet", "sum", "scale"],
    ),
    # every misspelt registry name (models, components, grid types, formats, checks): one wording
    "unknown-distribution": (_spec_text(model=_microfacet('alpha = 0.3\ndistribution = "ggxx"\n')),
                             ["model.distribution: unknown distribution 'ggxx' (did you mean 'ggx'?); valid: beckmann, "
                              "ggx,"]),
    "unknown-fresnel": (_spec_text(model=_microfacet('alpha = 0.3\nfresnel = "conductr"\n')),
                        ["model.fresnel: unknown fresnel 'conductr' (did you mean 'conductor'?); valid: none, "]),
    "unknown-output-format": (_spec_text(output='[[output]]\npath = "out.nc"\nformat = "netcdff"\n'),
                              ["output[0].format: unknown format 'netcdff' (did you mean 'netcdf'?); valid: netcdf, "
                               "zarr, merl, pbsdf, rgl, exr, zemax, lighttools"]),
    # a grid no table can hold (10^24 samples): one line before any work, not "iterator is too large"
    "grid-beyond-any-table": (_spec_text(grid=_rusi("anisotropic = true\nn_theta_h = 1000000\nn_theta_d = 1000000\n"
                                                    "n_phi_d = 1000000\nn_phi_h = 1000000\n")),
                              ["x 1 channel(s) is 1e+24 samples, more than a table can hold (2^53 = 9.01e+15)"]),
    "unknown-grid-type-wording": (_spec_text(grid='[grid]\ntype = "rusinkiewiz"\n'),
                                  ["grid.type: unknown grid type 'rusinkiewiz' (did you mean 'rusinkiewicz'?); valid: "]),
    # channel layouts that do not combine: the error names the parameter or term, not "terms"
    "n-k-channels-differ-in-a-term": (
        _spec_text(model='[model]\nname = "sum"\n[[model.terms]]\nname = "lambert"\nalbedo = 0.1\n'
                         '[[model.terms]]\nname = "microfacet"\nalpha = 0.3\nfresnel = "conductor"\n'
                         'n = [0.2, 0.3, 0.4]\nk = [3, 3]\n'),
        ["model.terms[1].k: has 2 channel values (c0, c1), but n has 3 channel values (R, G, B)"]),
    "spectral-term-beside-rgb-term": (
        _spec_text(model='[model]\nname = "sum"\n[[model.terms]]\nname = "lambert"\nalbedo = [0.1, 0.2, 0.3]\n'
                         '[[model.terms]]\nname = "lambert"\nalbedo = {wavelengths_nm = [400, 700], '
                         'values = [0.2, 0.2]}\n'),
        ["model.terms[1]: is a spectrum, but terms[0] has 3 channel values (R, G, B)"]),
    # missing required parameters
    "microfacet-without-alpha": (_spec_text(model=_microfacet('distribution = "ggx"\n')), ["model.alpha"]),
    "conductor-without-k": (
        _spec_text(model=_microfacet('alpha = 0.3\nfresnel = "conductor"\nn = 0.2\n')),
        ["model.k", "conductor"],
    ),
    # mistyped values
    "alpha-string": (_spec_text(model=_microfacet('alpha = "rough"\n')), ["model.alpha", "rough"]),
    "albedo-bool": (_spec_text(model='[model]\nname = "lambert"\nalbedo = true\n'), ["model.albedo"]),
    "n-string": (
        _spec_text(model=_microfacet('alpha = 0.3\nfresnel = "dielectric"\nn = "gold"\n')),
        ["model.n"],
    ),
    # out of range
    "alpha-zero": (_spec_text(model=_microfacet("alpha = 0\n")), ["model.alpha", ">= 1e-06"]),
    "alpha-negative": (_spec_text(model=_microfacet("alpha = -0.1\n")), ["model.alpha", "-0.1"]),
    "albedo-negative": (_spec_text(model='[model]\nname = "lambert"\nalbedo = -0.2\n'), ["model.albedo", "-0.2"]),
    "albedo-above-one": (_spec_text(model='[model]\nname = "lambert"\nalbedo = 1.5\n'), ["model.albedo", "1.5"]),
    "n-zero": (
        _spec_text(model=_microfacet('alpha = 0.3\nfresnel = "dielectric"\nn = 0\n')),
        ["model.n", ">= 1e-06"],
    ),
    "k-negative": (
        _spec_text(model=_microfacet('alpha = 0.3\nfresnel = "conductor"\nn = 0.2\nk = -1\n')),
        ["model.k", ">= 0"],
    ),
    # a parameter the chosen fresnel does not use
    "k-with-dielectric": (
        _spec_text(model=_microfacet('alpha = 0.3\nfresnel = "dielectric"\nn = 1.5\nk = 1\n')),
        ["model.k", "dielectric"],
    ),
    # [grid]
    "unknown-grid-type": (_spec_text(grid='[grid]\ntype = "merll"\n'), ["grid.type", "merll", "did you mean 'merl'"]),
    "unknown-grid-key": (_spec_text(grid=_rusi("n_thetah = 4\n")), ["grid.n_thetah", "did you mean 'n_theta_h'"]),
    "unknown-merl-grid-key": (_spec_text(grid='[grid]\ntype = "merl"\nn_theta_h = 4\n'), ["grid.n_theta_h"]),
    "n-theta-h-zero": (_spec_text(grid=_rusi("n_theta_h = 0\n")), ["grid.n_theta_h"]),
    "phi-d-fold-foo": (_spec_text(grid=_rusi('phi_d_fold = "foo"\n')), ["grid.phi_d_fold", "foo"]),
    # The spec key is theta_h_deg; the message must name that key, not an internal axis name.
    "theta-h-deg-out-of-range": (_spec_text(grid=_rusi("theta_h_deg = [0, 45, 100]\n")), ["grid.theta_h_deg"]),
    # missing sections
    "missing-model": (_spec_text(model=""), ["[model]", "missing"]),
    "missing-grid": (_spec_text(grid=""), ["[grid]", "missing"]),
    "missing-output": (_spec_text(output=""), ["[[output]]", "missing"]),
    # [[output]]
    "unknown-output-extension": (
        _spec_text(output='[[output]]\npath = "out.xyz"\n'),
        ["output[0].path", ".xyz", "(known: .nc, .nc4, .netcdf, .zarr, .binary, .pbsdf, .bsdf, .exr, .mbsdf, "
         ".anisotropicbsdf, .brdf, .xml, .astm, .csv)"],
    ),
    "unknown-output-option": (
        _spec_text(output='[[output]]\npath = "out.nc"\ncompression = 4\n'),
        ["output[0].compression"],
    ),
    # A bad value of a known output option must be refused like any other spec error:
    # naming the spec file and the key (and before the tabulation runs).
    "bad-output-dtype": (
        _spec_text(output='[[output]]\npath = "out.nc"\ndtype = "float16"\n'),
        ["output[0].dtype", "float16"],
    ),
    # file level
    "invalid-toml": (_spec_text(extra="this is = = not toml\n"), ["invalid TOML", "line"]),
    "not-utf8": (_spec_text().replace("a spec with one mistake", "caf\udce9").encode("utf-8", "surrogateescape"),
                 ["UTF-8"]),
    # [validation]
    "validation-unknown-key": (
        _spec_text(extra="[validation]\nallow_invalids = true\n"),
        ["validation.allow_invalids", "did you mean 'allow_invalid'"],
    ),
    # values of the wrong TOML type where a name is expected (must not crash on unhashables)
    "grid-type-list": (_spec_text(grid='[grid]\ntype = ["merl"]\n'), ["grid.type"]),
    "fold-list": (_spec_text(grid=_rusi('phi_d_fold = ["none"]\n')), ["grid.phi_d_fold"]),
    "fold-table": (_spec_text(grid=_rusi("phi_d_fold = {a = 1}\n")), ["grid.phi_d_fold"]),
    "output-format-list": (_spec_text(output='[[output]]\npath = "out.nc"\nformat = ["netcdf"]\n'),
                           ["output[0].format"]),
    "output-format-number": (_spec_text(output='[[output]]\npath = "out.nc"\nformat = 3\n'), ["output[0].format"]),
    "output-path-nul": (_spec_text(output='[[output]]\npath = "a\\u0000b.nc"\n'), ["output[0].path", "NUL"]),
    # numbers TOML allows but no grid or model does
    "alpha-huge-int": (_spec_text(model=_microfacet("alpha = " + "9" * 400 + "\n")), ["model.alpha"]),
    "albedo-huge-int-list": (_spec_text(model='[model]\nname = "lambert"\nalbedo = [' + "9" * 400 + "]\n"),
                             ["model.albedo"]),
    "range-nan": (_spec_text(grid=_rusi("theta_h_deg = {start = nan, stop = 10, step = 1}\n")),
                  ["grid.theta_h_deg.start"]),
    "range-inf": (_spec_text(grid=_rusi("theta_h_deg = {start = 0, stop = inf, step = 1}\n")),
                  ["grid.theta_h_deg.stop"]),
    "range-tiny-step": (_spec_text(grid=_rusi("theta_h_deg = {start = 0, stop = 10, step = 1e-300}\n")),
                        ["grid.theta_h_deg.step"]),
    "range-negative-num": (_spec_text(grid=_rusi("theta_h_deg = {start = 0, stop = 10, num = -3}\n")),
                           ["grid.theta_h_deg.num"]),
    "axis-too-many-nodes": (_spec_text(grid=_rusi("n_theta_h = 1000000000\n")), ["grid.n_theta_h"]),
    # integers of hundreds of digits (TOML has no limit) where an int, an angle or a float goes
    "n-theta-h-huge-int": (_spec_text(grid=_rusi("n_theta_h = " + "9" * 400 + "\n")),
                           ["grid.n_theta_h", "whole number", "(too large)"]),
    "max-bounces-huge-int": (_spec_text(model='[model]\nname = "pyramid-microfacet"\nmax_bounces = -' + "9" * 400
                                        + "\n"), ["model.max_bounces", "(too large)"]),
    "angle-key-huge-int": (_spec_text(model='[model]\nname = "pyramid-microfacet"\nphi0_deg = ' + "9" * 400 + "\n"),
                           ["model.phi0_deg", "expected an angle in degrees"]),
    "angle-list-huge-int": (_spec_text(grid=_rusi("theta_h_deg = [0, " + "9" * 400 + "]\n")),
                            ["grid.theta_h_deg", "finite"]),
    "angle-range-huge-int": (_spec_text(grid=_rusi("theta_h_deg = {start = 0, stop = " + "9" * 400 + ", step = 1}\n")),
                             ["grid.theta_h_deg.stop", "finite"]),
    "wavelengths-huge-int": (_spec_text(grid=_rusi("wavelengths_nm = [" + "9" * 400 + "]\n")),
                             ["grid.wavelengths_nm", "finite"]),
    "check-angle-huge-int": (_spec_text(extra="[validation.energy]\ntheta_i_max_deg = " + "9" * 400 + "\n"),
                             ["validation.energy.theta_i_max_deg", "degrees"]),
    "grid-without-type": (_spec_text(grid="[grid]\nn_theta_h = 4\n"),
                          ["grid.type", "missing", "rusinkiewicz, merl, spherical"]),
    "wavelengths-decreasing": (_spec_text(grid=_rusi("wavelengths_nm = [500, {start = 400, stop = 450, num = 2}]\n")),
                               ["grid.wavelengths_nm", "increase strictly: 500 nm is followed by 400 nm"]),
    "spectrum-infinite-wavelength": (
        _spec_text(model='[model]\nname = "lambert"\nalbedo = {wavelengths_nm = [400, inf], values = [0.1, 0.2]}\n'),
        ["model.albedo", "finite"]),
    "wavelengths-nan": (_spec_text(grid=_rusi("wavelengths_nm = [nan]\n")), ["grid.wavelengths_nm"]),
    "relative-theta-o-below-zero": (
        _spec_text(grid='[grid]\ntype = "spherical"\nrelative_to = "specular"\ntheta_i_deg = [30]\n'
                        'phi_i_deg = [0]\ndtheta_o_deg = [-50, 0]\ndphi_o_deg = [0]\n'),
        ["grid.dtheta_o_deg", "theta_i + dtheta_o"]),
    "relative-dphi-beyond-180": (
        _spec_text(grid='[grid]\ntype = "spherical"\nrelative_to = "specular"\ntheta_i_deg = [30]\n'
                        'phi_i_deg = [0]\ndtheta_o_deg = [0]\ndphi_o_deg = [100, 200]\n'),
        ["grid.dphi_o_deg"]),
    "wavelengths-outside-common-range": (
        _spec_text(model=_microfacet('alpha = 0.3\nfresnel = "conductor"\n'
                                     "n = {wavelengths_nm = [400, 700], values = [1.0, 1.0]}\n"
                                     "k = {wavelengths_nm = [300, 800], values = [2.0, 2.0]}\n"),
                   grid=_rusi("n_theta_h = 2\nn_theta_d = 2\nn_phi_d = 2\nwavelengths_nm = [350, 750]\n")),
        ["grid.wavelengths_nm", "[400, 700]"]),
    # [grid] polarized: a bool, for a polarized model, on a grid without a φd fold
    "polarized-not-a-bool": (_spec_text(grid=_rusi('phi_d_fold = "none"\npolarized = "yes"\n')),
                             ["grid.polarized", "expected true or false"]),
    "polarized-unpolarized-model": (_spec_text(model=_UNPOLARIZED, grid=_rusi('phi_d_fold = "none"\npolarized = true\n')),
                                    ["grid.polarized", "the model 'microfacet' has no Mueller matrix"]),
    "pbsdf-of-an-unpolarized-model": (_spec_text(model=_UNPOLARIZED, output='[[output]]\npath = "out.pbsdf"\n'),
                                      ["output[0].path", "out.pbsdf", "the model 'microfacet' is not polarized"]),
}

#: Cases also run as a real subprocess (one line on stderr, no traceback).
SUBPROCESS_CASES = ["unknown-top-level-key", "unknown-model-name", "alpha-string", "theta-h-deg-out-of-range",
                    "invalid-toml", "not-utf8", "missing-output", "grid-type-list", "alpha-huge-int",
                    "range-tiny-step", "axis-too-many-nodes", "n-theta-h-huge-int", "angle-key-huge-int",
                    "pbsdf-of-an-unpolarized-model"]


def _write_spec(tmp_path: Path, case_id: str) -> Path:
    content, _ = CASES[case_id]
    spec = tmp_path / f"{case_id}.toml"
    if isinstance(content, bytes):
        spec.write_bytes(content)
    else:
        spec.write_text(content, encoding="utf-8")
    return spec


def _assert_one_error_line(stderr: str, code: int, *expected: str) -> str:
    assert code == 2, f"exit code {code}, stderr: {stderr!r}"
    assert "Traceback" not in stderr, stderr
    lines = stderr.splitlines()
    assert len(lines) == 1, f"expected one line on stderr, got {len(lines)}: {stderr!r}"
    line = lines[0]
    assert line.strip(), "empty error line"
    assert line.startswith("brdftab: error: "), line
    for text in expected:
        assert text in line, f"{text!r} missing from error line {line!r}"
    return line


def _assert_nothing_written(folder: Path, keep: set):
    left = sorted(p.name for p in folder.iterdir() if p.name not in keep)
    assert left == [], f"files left behind: {left}"


def _cli(args):
    result = CliRunner().invoke(main, [str(a) for a in args])
    assert result.exception is None or isinstance(result.exception, SystemExit), (
        f"exception escaped the CLI: {result.exception!r}")
    return result


def _subprocess(args, cwd=None):
    return subprocess.run([sys.executable, "-m", "brdftab", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd, timeout=120)


# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("case_id", list(CASES))
def test_spec_error_in_process(tmp_path, case_id):
    spec = _write_spec(tmp_path, case_id)
    result = _cli(["tabulate", spec])
    _assert_one_error_line(result.stderr, result.exit_code, spec.name, *CASES[case_id][1])
    assert result.stdout == ""
    _assert_nothing_written(tmp_path, {spec.name})


@pytest.mark.parametrize("case_id", SUBPROCESS_CASES)
def test_spec_error_subprocess(tmp_path, case_id):
    spec = _write_spec(tmp_path, case_id)
    proc = _subprocess(["tabulate", spec.name], cwd=tmp_path)
    _assert_one_error_line(proc.stderr, proc.returncode, spec.name, *CASES[case_id][1])
    assert proc.stdout == ""
    _assert_nothing_written(tmp_path, {spec.name})


def test_spec_error_with_out_folder_writes_nothing(tmp_path):
    spec = _write_spec(tmp_path, "alpha-negative")
    out = tmp_path / "out"
    out.mkdir()
    result = _cli(["tabulate", spec, "--out", out])
    _assert_one_error_line(result.stderr, result.exit_code, spec.name, "model.alpha")
    assert list(out.iterdir()) == []


def test_nonexistent_spec_file(tmp_path):
    spec = tmp_path / "no-such-spec.toml"
    proc = _subprocess(["tabulate", spec])
    _assert_one_error_line(proc.stderr, proc.returncode, spec.name)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("verb", ["tabulate", "eval"])
def test_spec_error_same_for_every_verb_reading_specs(tmp_path, verb):
    spec = _write_spec(tmp_path, "unknown-model-key-alpah")
    args = [verb, spec] + (["--wi-deg", "30,0", "--wo-deg", "30,180"] if verb == "eval" else [])
    result = _cli(args)
    _assert_one_error_line(result.stderr, result.exit_code, spec.name, "model.alpah", "did you mean 'alpha'")


@pytest.mark.parametrize("text", [
    "description = " + "[" * 2000 + "]" * 2000 + "\n",           # deeper than the TOML parser recurses
    "description = " + "[" * 100 + "]" * 100 + "\n",             # parsed, but deeper than any spec needs
    "".join(f"[model{'.term' * i}]\nname = 'scale'\nfactor = 1\n" for i in range(120)),
], ids=["arrays-2000", "arrays-100", "models-120"])
def test_deeply_nested_spec_is_one_clear_line(tmp_path, text):
    spec = tmp_path / "deep.toml"
    spec.write_text(text)
    proc = _subprocess(["tabulate", spec])
    line = _assert_one_error_line(proc.stderr, proc.returncode, "deep.toml", "nested too deeply")
    assert "internal error" not in line


# --------------------------------------------------------------------------------------------
# Errors in command-line arguments that brdftab itself checks.

@pytest.mark.parametrize("value, expected", [
    ("30", ["--wi-deg", "'30'", "theta,phi"]),
    ("100,0", ["--wi-deg", "[0, 90]", "100"]),
    ("90.0000001,0", ["--wi-deg", "[0, 90]", "got 90.0000001"]),
    ("-1e-9,0", ["--wi-deg", "[0, 90]", "got -1e-9"]),
    ("a,b", ["--wi-deg", "'a,b'"]),
    ("30,0,0", ["--wi-deg", "'30,0,0'"]),
    ("nan,0", ["--wi-deg", "'nan,0'"]),
])
def test_eval_bad_direction(value, expected):
    result = _cli(["eval", GGX_GOLD, "--wi-deg", value, "--wo-deg", "30,180"])
    _assert_one_error_line(result.stderr, result.exit_code, *expected)
    assert result.stdout == ""


def test_eval_bad_wo_direction_names_wo():
    result = _cli(["eval", GGX_GOLD, "--wi-deg", "30,0", "--wo-deg", "-5,180"])
    _assert_one_error_line(result.stderr, result.exit_code, "--wo-deg", "[0, 90]")


def test_eval_reduces_a_huge_azimuth_exactly():
    # 1e20 is a whole number of degrees, 280 beyond a whole number of turns; converted to
    # radians first, it gave another direction's value (R 0.0536 instead of 0.1670)
    assert 10 ** 20 % 360 == 280
    huge, same, other = (_cli(["eval", GGX_GOLD, "--wi-deg", f"30,{phi}", "--wo-deg", "30,180"])
                         for phi in ("1e20", "280", "0"))
    assert huge.exit_code == same.exit_code == other.exit_code == 0
    assert huge.stdout == same.stdout != other.stdout


@pytest.mark.parametrize("args, expected", [
    (["--phi-i-deg", "inf"], ["--phi-i-deg expects a finite angle in degrees, got inf"]),
    (["--kind", "slice", "--phi-d-deg", "nan"], ["--phi-d-deg expects a finite angle in degrees, got nan"]),
    # math text matplotlib cannot typeset: one line before the figure is drawn, not an internal error
    (["--title", "$\\undefinedmacro$"], ["--title: matplotlib cannot typeset '$\\undefinedmacro$' as math text",
                                           "write \\$ for a dollar sign"]),
    (["--title", "$^^$"], ["--title: matplotlib cannot typeset"]),
])
def test_plot_bad_argument_is_one_line_and_writes_nothing(tmp_path, args, expected):
    out = tmp_path / "p.png"
    result = _cli(["plot", GGX_GOLD, "-o", out, *args])
    _assert_one_error_line(result.stderr, result.exit_code, *expected)
    assert not out.exists()


@pytest.mark.parametrize("title", ["costs $5", "costs \\$5 or \\$6", "the slope $\\alpha$"])
def test_plot_titles_that_matplotlib_draws_are_drawn(tmp_path, title):
    # one $ (not math text), escaped ones, and math text matplotlib typesets
    out = tmp_path / "p.png"
    result = _cli(["plot", GGX_GOLD, "-o", out, "--title", title])
    assert result.exit_code == 0, result.stderr
    assert out.stat().st_size > 0


@pytest.mark.parametrize("size", ["1e400", "1e400G", "1e300T"])
def test_a_memory_budget_beyond_any_number_is_one_line(size, monkeypatch):
    monkeypatch.delenv("BRDFTAB_MEMORY", raising=False)  # (--memory sets it for the run)
    result = _cli(["validate", GGX_GOLD, "--memory", size])
    _assert_one_error_line(result.stderr, result.exit_code, f"--memory: '{size}' is too large a size")
    monkeypatch.setenv("BRDFTAB_MEMORY", size)
    proc = _subprocess(["validate", GGX_GOLD])
    _assert_one_error_line(proc.stderr, proc.returncode, f"BRDFTAB_MEMORY: '{size}' is too large a size")


@pytest.mark.parametrize("value", ["a,b", "100,0"])
def test_eval_bad_direction_subprocess(value):
    proc = _subprocess(["eval", GGX_GOLD, "--wi-deg", value, "--wo-deg", "30,180"])
    _assert_one_error_line(proc.stderr, proc.returncode, "--wi-deg")
    assert proc.stdout == ""


def test_info_nonexistent_file(tmp_path):
    path = tmp_path / "missing-table.nc"
    result = _cli(["info", path])
    _assert_one_error_line(result.stderr, result.exit_code, path.name)
    assert not path.exists()


def test_info_garbage_netcdf(tmp_path):
    path = tmp_path / "garbage.nc"
    path.write_bytes(b"this is not a netCDF file\n" * 20)
    proc = _subprocess(["info", path])
    _assert_one_error_line(proc.stderr, proc.returncode, path.name)
    assert proc.stdout == ""


def test_eval_garbage_netcdf(tmp_path):
    path = tmp_path / "garbage.nc"
    path.write_bytes(b"\x00\x01 definitely not netCDF" * 10)
    result = _cli(["eval", path, "--wi-deg", "30,0", "--wo-deg", "30,180"])
    _assert_one_error_line(result.stderr, result.exit_code, path.name)


@pytest.mark.parametrize("name, expected", [
    ("nosuchmodel", ["nosuchmodel", "lambert", "microfacet"]),
    ("microfacett", ["microfacett", "did you mean 'microfacet'"]),
])
def test_models_unknown_name(name, expected):
    result = _cli(["models", name])
    _assert_one_error_line(result.stderr, result.exit_code, *expected)
    assert result.stdout == ""


def test_models_unknown_name_subprocess():
    proc = _subprocess(["models", "nosuchmodel"])
    _assert_one_error_line(proc.stderr, proc.returncode, "nosuchmodel", "lambert", "microfacet")


def test_tabulate_out_folder_missing_is_created(tmp_path):
    missing = tmp_path / "no-such-folder" / "sub"
    result = _cli(["tabulate", GGX_GOLD, "--out", missing])
    assert result.exit_code == 0, result.stderr
    assert sorted(p.name for p in missing.iterdir()) == ["ggx-gold.nc"]


# --------------------------------------------------------------------------------------------
# click usage errors are one line with exit code 2

@pytest.mark.parametrize("args, expected", [
    (["eval", GGX_GOLD, "--wi-deg", "30,0"], ["--wo-deg"]),                                   # missing option
    (["eval", SPECS, "--wi-deg", "30,0", "--wo-deg", "30,180"], ["is a folder, neither a table file nor a zarr store"]),         # folder as spec
    (["tabulate", SPECS], ["is a directory"]),
    (["eval", GGX_GOLD, "--wi-deg", "30,0", "--wo-deg", "30,180", "--wavelength-nm", "abc"],
     ["--wavelength-nm", "abc"]),                                                            # not a number
    (["tabulate", GGX_GOLD, "--no-such-option"], ["--no-such-option"]),
    (["nosuchverb"], ["nosuchverb"]),
    (["tabulate"], ["SPEC"]),
])
def test_usage_errors_are_one_line(args, expected):
    result = _cli(args)
    _assert_one_error_line(result.stderr, result.exit_code, *expected)
    assert result.stdout == ""


def test_usage_error_subprocess():
    proc = _subprocess(["eval", GGX_GOLD, "--wi-deg", "30,0"])
    _assert_one_error_line(proc.stderr, proc.returncode, "--wo-deg")
    assert proc.stdout == ""
