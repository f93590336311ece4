"""The spec -> table -> validate -> write pipeline: refusal of invalid tables; one tabulation
per target grid."""

from pathlib import Path

import numpy as np
import pytest

import brdftab
from brdftab import formats
from brdftab.brdf import BRDF
from brdftab.errors import ValidationError
from brdftab.grids import RusinkiewiczGrid, merl_grid
from brdftab.pipeline import run
from brdftab.spec import Output, Spec, load_spec


class Broken(BRDF):
    """Returns NaN where wi is steeper than 45° and −1 elsewhere in a small patch."""

    name = "broken"

    def _eval(self, wi, wo, lam, n):
        f = np.full((wi.shape[0], n), 0.1)
        f[wi[:, 2] > np.cos(np.radians(45))] = np.nan
        f[(wo[:, 2] < 0.2)] = -1.0
        return f


def make_spec(tmp_path, allow=False):
    return Spec(path=tmp_path / "s.toml", sha256="", model=Broken(), grid=RusinkiewiczGrid(6, 6, 6),
                wavelengths=None, outputs=[Output(tmp_path / "x.nc", "netcdf", {})],
                validation={"allow_invalid": allow}, raw={"output": [{"path": "x.nc"}]})


def test_invalid_table_is_refused_with_counts(tmp_path):
    with pytest.raises(ValidationError) as exc:
        run(make_spec(tmp_path), progress=False)
    msg = str(exc.value)
    assert "finite" in msg and "NaN" in msg and "negative" in msg and "of 216 samples" in msg
    assert "lowest -1 sr-1" in msg
    assert list(tmp_path.iterdir()) == []


def test_invalid_table_written_when_allowed(tmp_path):
    result = run(make_spec(tmp_path), allow_invalid=True, progress=False)
    assert not result.report.passed
    assert (tmp_path / "x.nc").exists()
    result = run(make_spec(tmp_path, allow=True), overwrite=True, progress=False)
    assert not result.report.passed


# -- one tabulation per target grid -------------------------------------------------------------

def _npz_write(table, path, **options):
    np.save(open(path, "wb"), table.values)


@pytest.fixture
def merl_grid_format():
    """A stand-in format whose native grid is the MERL grid (values in an .npy file)."""
    fmt = formats.FileFormat(name="merlgrid-test", extensions=(".mgt",), description="test", read=None,
                             write=_npz_write, native_grid=lambda requested, options: merl_grid())
    formats.register(fmt)
    yield fmt
    del formats.FORMATS[fmt.name]


def test_each_output_tabulates_the_model_on_its_own_grid(tmp_path, merl_grid_format, monkeypatch):
    spec = tmp_path / "two.toml"
    spec.write_text('[model]\nname = "microfacet"\nalpha = 0.3\nfresnel = "conductor"\nn = 0.2\nk = 3.0\n'
                    '[grid]\ntype = "rusinkiewicz"\nn_theta_h = 30\nn_theta_d = 30\nn_phi_d = 60\n'
                    '[[output]]\npath = "rus.nc"\n[[output]]\npath = "merl.mgt"\n')
    from brdftab import pipeline

    calls = []
    real = pipeline.tabulate
    monkeypatch.setattr(pipeline, "tabulate", lambda brdf, grid, *a, **k: calls.append(grid) or real(brdf, grid, *a,
                                                                                                         **k))
    s = load_spec(spec)
    pipeline.run(s, progress=False)
    assert len(calls) == 2 and calls[1].equals(merl_grid())
    stored = np.load(tmp_path / "merl.mgt")
    # the model itself at MERL bin centres (from the formula), not an interpolated table
    i, j, k = np.meshgrid(np.arange(90), np.arange(90), np.arange(180), indexing="ij")
    th = ((i + 0.5) / 90) ** 2 * np.pi / 2
    td, pd = np.radians(j + 0.5), np.radians(k + 0.5)
    wi, wo = brdftab.geometry.hd_to_io(th, 0.0, td, pd)
    expected = s.model.eval(wi.reshape(-1, 3), wo.reshape(-1, 3)).reshape(stored.shape)
    assert np.allclose(stored, expected, rtol=1e-12, atol=0)
    rus = brdftab.open(tmp_path / "rus.nc")
    assert rus.grid.shape == (30, 30, 60)


# -- checks judge the values as stored -------------------------------------------------------------

#: A model whose values are finite in float64 but beyond float32's range above the horizon.
BEYOND_FLOAT32 = ('[model]\nname = "scale"\nfactor = 2e40\n[model.term]\nname = "lambert"\nalbedo = 0.5\n'
                  '[grid]\ntype = "rusinkiewicz"\nn_theta_h = 6\nn_theta_d = 5\nn_phi_d = 8\n'
                  '[validation.energy]\nlevel = "off"\n')


def _beyond_float32(tmp_path, output):
    path = tmp_path / "big.toml"
    path.write_text(BEYOND_FLOAT32 + f"[[output]]\n{output}\n")
    return path


def _overflowing_samples(spec_path):
    """How many samples of the spec's model at its grid nodes exceed the largest float32 (float64 values)."""
    from brdftab.table import tabulate

    s = load_spec(spec_path)
    v = np.asarray(tabulate(s.model, s.grid).values, np.float64)
    return int(np.count_nonzero(np.abs(v) > np.finfo(np.float32).max)), v.size


@pytest.mark.parametrize("output", ['path = "big.nc"\ndtype = "float32"', 'path = "big.exr"',
                                    'path = "big.bsdf"\nresolution = 8\ntheta_i_deg = [0, 40, 80]',
                                    'path = "big.bsdf"\nresolution = 8\ntheta_i_deg = [0, 40, 80]\nvalues = "fit"'],
                         ids=["netcdf-float32", "exr", "rgl", "rgl-fit"])
def test_values_beyond_the_storage_type_fail_finite_and_nothing_is_written(tmp_path, output):
    from _cli import run as cli_run

    spec = _beyond_float32(tmp_path, output)
    r = cli_run("tabulate", spec)
    assert r.returncode == 1, r.stderr
    error = [line for line in r.stderr.splitlines() if line.startswith("brdftab: error:")]
    assert len(error) == 1 and "refusing to export" in error[0] and "finite:" in error[0], r.stderr
    assert "float32" in error[0]
    if "bsdf" not in output:  # a table: every sample beyond float32 is counted
        over, total = _overflowing_samples(spec)
        assert over > 0
        assert f"finite: {over} of {total} samples are NaN or infinite (0 NaN, {over} infinite)" in error[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["big.toml"]


def test_float64_output_of_the_same_values_passes(tmp_path):
    result = run(load_spec(_beyond_float32(tmp_path, 'path = "big.nc"')), progress=False)
    assert result.report.passed and result.report.get("finite").status == "pass"
    assert np.isfinite(brdftab.open(tmp_path / "big.nc").values).all()


def test_written_anyway_the_file_records_the_failure_a_later_validate_finds(tmp_path):
    import json

    from _cli import run as cli_run

    spec = _beyond_float32(tmp_path, 'path = "big.nc"\ndtype = "float32"')
    r = cli_run("tabulate", spec, "--allow-invalid")
    assert r.returncode == 0, r.stderr
    attrs = brdftab.open(tmp_path / "big.nc").ds.attrs
    assert attrs["validation_passed"] == 0 and attrs["validation_summary"].startswith("finite: ")
    stored = json.loads(attrs["validation_report"])
    over, _ = _overflowing_samples(spec)
    assert stored["checks"][0]["name"] == "finite" and stored["checks"][0]["figure"] == over
    v = cli_run("validate", tmp_path / "big.nc", "--level", "energy=off", "--json")
    assert v.returncode == 1
    later = json.loads(v.stdout)["reports"][0]
    assert later["counts"] == stored["counts"]
    assert {c["name"]: c["status"] for c in later["checks"]} == {c["name"]: c["status"] for c in stored["checks"]}


@pytest.mark.parametrize("verb", ["run", "validate"])
def test_memory_check_up_front_covers_the_checks(tmp_path, monkeypatch, verb):
    """Memory for the table (1.25x) but not for the checks (up to 8.8x measured): refused before
    anything is tabulated, naming the grid, instead of running out of memory in the checks."""
    from brdftab import pipeline, table as table_mod
    from brdftab.errors import BrdftabError

    spec_path = tmp_path / "s.toml"
    spec_path.write_text('[model]\nname = "lambert"\nalbedo = [0.2, 0.5, 0.8]\n[grid]\ntype = "rusinkiewicz"\n'
                         'n_theta_h = 20\nn_theta_d = 10\nn_phi_d = 16\n[[output]]\npath = "t.nc"\n')
    spec = load_spec(spec_path)
    nbytes = 20 * 10 * 16 * 3 * 8
    monkeypatch.setattr(table_mod, "available_memory", lambda: table_mod.CHUNK_OVERHEAD + 3 * nbytes)
    monkeypatch.setattr(pipeline, "tabulate", lambda *a, **k: pytest.fail("tabulated before the memory check"))
    with pytest.raises(BrdftabError, match=r"s.toml: tabulating and checking rusinkiewicz theta_h\[20\] x theta_d\[10\]"
                                           r" x phi_d\[16\] x 3 channels needs about"):
        getattr(pipeline, verb)(spec)
    assert not (tmp_path / "t.nc").exists()
    # with the measured peak available, the same run goes through
    monkeypatch.setattr(table_mod, "available_memory",
                        lambda: table_mod.CHUNK_OVERHEAD + table_mod.CHECKED_PEAK * nbytes + 1)
    monkeypatch.setattr(pipeline, "tabulate", table_mod.tabulate)
    getattr(pipeline, verb)(spec, progress=False)


def test_a_format_that_samples_the_model_is_judged_against_it(tmp_path):
    """The RGL writer samples the model on its own warped layout; a file that misrepresents the
    model (Small 2021's 2e-4-wide peaks and diffraction band: Mitsuba reads a quarter of the
    model's albedo from it) is refused as a resampled conversion is, naming the figures, and
    nothing is written; a smooth model's file passes the same judgement."""
    import re

    from _cli import run

    root = Path(__file__).resolve().parents[1]
    text = (root / "specs" / "solar-cell-small2021.toml").read_text()
    # a small file with node samples: fast checks
    text = re.sub(r'(?m)^path = .*$', 'path = "cell.bsdf"\nresolution = 24\nn_theta_i = 17\nvalues = "nodes"', text)
    text = re.sub(r'(?m)^dtype = .*$', '', text)
    spec = tmp_path / "cell.toml"
    spec.write_text(text)
    # the coarse file's energy and albedo are not the subject (and their integrals of the
    # file's warped samples are most of the run)
    proc = run("tabulate", spec, "--level", "energy=off", "--level", "albedo=off")
    assert proc.returncode == 1, proc.stderr
    line = proc.stderr.strip().splitlines()[-1]
    assert re.search(r"refusing to export .*cell\.bsdf: its rgl samples misrepresent the model "
                     r"solar-cell-small2021: relative error of f at θi, θo ≤ 80° median .* \(bound 2 %\)", line), line
    assert not (tmp_path / "cell.bsdf").exists()
    smooth = tmp_path / "gold.toml"
    smooth.write_text(re.sub(r'(?m)^(path = .*|dtype = .*)$', '',
                             (root / "specs" / "ggx-gold.toml").read_text()).replace("[[output]]", '[[output]]\npath = "gold.bsdf"'))
    proc = run("tabulate", smooth)
    assert proc.returncode == 0 and (tmp_path / "gold.bsdf").exists(), proc.stderr
