"""ASTM E1392 (Cornell dialect) and scattered CSV files: a real Cornell measurement read, checked
and converted against an independent parser of the file; writers read back by their readers and
by minimal parsers written here from the layout; seed specs tabulated to both; bad files refused
with one line."""

from __future__ import annotations

import lzma
import warnings
from pathlib import Path

import numpy as np
import pytest

import brdftab
from brdftab import pipeline
from brdftab.checks import run_checks
from brdftab.errors import BrdftabWarning, FormatError

from _cli import cli, one_error

DATA = Path(__file__).parent / "data"


def cornell(tmp_path) -> Path:
    path = tmp_path / "cayman.astm"
    path.write_bytes(lzma.decompress((DATA / "cornell-cayman.astm.xz").read_bytes()))
    return path


def parse_astm(text: str):
    """Minimal ASTM parser from the layout: header until VARS, then comma-separated numbers."""
    lines = text.splitlines()
    k = next(i for i, line in enumerate(lines) if line.startswith("VARS "))
    names = lines[k][5:].split(",")
    rows = np.array([[float(x) for x in line.split(",")] for line in lines[k + 1:] if line.strip()])
    header = {line.split(" ", 1)[0]: line.split(" ", 1)[1] for line in lines[:k] if line.strip()}
    return header, names, rows


def unit(theta, phi):
    return np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=-1)


def test_cornell_file_reads_validates_and_converts_to_netcdf_value_for_value(tmp_path):
    """The Cayman lacquer (1439 samples, 31 wavelengths): 24 samples evaluate, before and after
    `brdftab convert` to netCDF, to the file's numbers at the directions its radians give (the
    mirror direction of (θi, 0) at φs = 180°: the file's peak); the checks judge it as measured data."""
    path = cornell(tmp_path)
    header, names, rows = parse_astm(path.read_text())
    assert header["NUM_POINTS"] == "1439" and names[4] == "400nm" and rows.shape == (1439, 35)
    t = brdftab.open(path)
    assert t.origin == "measured" and t.spectral and t.wavelengths[0] == 400 and t.wavelengths[-1] == 700
    assert "f_r [sr-1]" in t.ds.attrs["source_quantity"] and t.ds.attrs["material"] == "Cayman Metallic"
    assert t.grid.phi_d_fold == "bilateral"  # Cornell measured one side of the plane of incidence
    pick = np.random.default_rng(0).choice(rows.shape[0], 24, replace=False)
    wi, wo = unit(rows[pick, 0], rows[pick, 1]), unit(rows[pick, 2], rows[pick, 3])
    assert np.allclose(t.eval(wi, wo), rows[pick, 4:], rtol=1e-12, atol=1e-15)
    out = tmp_path / "cayman.nc"
    r = cli("info", path)
    assert r.exit_code == 0 and "theta_i    1439 samples  10 .. 80 deg" in r.stdout, r.stdout
    r = cli("convert", path, out)
    assert r.exit_code == 0, r.stderr
    assert "copied: same grid as the input" in r.stdout
    nc = brdftab.open(out)
    assert np.allclose(nc.eval(wi, wo), rows[pick, 4:], rtol=1e-12, atol=1e-15)
    assert np.array_equal(np.asarray(nc.values), rows[:, 4:])
    rng = np.random.default_rng(1)
    qi = unit(rng.uniform(0, 1.5, 300), rng.uniform(-3, 3, 300))
    qo = unit(rng.uniform(0, 1.5, 300), rng.uniform(-3, 3, 300))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BrdftabWarning)
        assert np.array_equal(nc.eval(qi, qo), t.eval(qi, qo), equal_nan=True)
    # the specular peak: at θi = 10° the sample at (8.1°, 180°) holds more than its backscatter twin
    peak = np.flatnonzero(np.isclose(rows[:, 0], np.radians(10.0), atol=1e-6) & np.isclose(rows[:, 3], np.pi, atol=1e-5)
                          & np.isclose(rows[:, 2], np.radians(8.11), atol=1e-3))[0]
    assert rows[peak, 4:].max() == rows[np.isclose(rows[:, 0], rows[peak, 0]), 4:].max()  # the file's own peak
    mirror = t.eval(unit(rows[peak, 0], 0.0), unit(rows[peak, 2], np.pi))
    back = t.eval(unit(rows[peak, 0], 0.0), unit(rows[peak, 2], 0.0))
    assert np.all(mirror > back)
    report = run_checks(t, only=("finite", "non-negative", "energy", "albedo", "bilateral"))
    energy = report.get("energy")
    assert energy.status == "warn" and "measured data" in energy.detail  # the data's own excess, reported
    assert "10..80°" in report.get("albedo").detail  # swept at the measured incidences only
    assert abs(report.get("albedo").data["coverage_min"] - 0.94) < 0.005  # (at θi = 80°; formats/astm.md)


def test_astm_writer_is_read_back_exactly_by_a_minimal_parser_and_by_the_reader(tmp_path):
    from brdftab.grids import ScatteredGrid, SphericalGrid

    grid = SphericalGrid(np.radians([0.0, 30.0, 60.0]), [0.0], np.radians(np.arange(0, 76, 15.0)),
                         np.radians(np.arange(0, 360, 45.0)))
    m = brdftab.models.create("microfacet", alpha=0.25, fresnel="schlick", f0=[0.9, 0.6, 0.3])
    path = tmp_path / "m.astm"
    written = brdftab.save(m, path, grid=grid)
    header, names, rows = parse_astm(path.read_text())
    assert names == ["theta_i", "phi_i", "theta_s", "phi_s", "R", "G", "B"] and header["MEAS_NAME"] == "BRDF"
    assert int(header["NUM_POINTS"]) == rows.shape[0] == ScatteredGrid.from_grid(grid).size
    wi, wo = unit(rows[:, 0], rows[:, 1]), unit(rows[:, 2], rows[:, 3])
    assert np.array_equal(rows[:, 4:], m.eval(wi, wo))  # the model at the written angles, every digit
    back = brdftab.open(path)
    assert np.array_equal(back.values, written.values) and back.grid.equals(written.grid)


def test_csv_reads_quantities_and_writes_f_r_read_back_by_a_minimal_parser(tmp_path):
    text = ("# a measurement\n"
            "theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,wavelength_nm,reflectance_factor\n"
            + "".join(f"{ti},0,{to},{po},{lam},{0.5 + 0.001 * lam}\n" for ti in (10, 40) for to in (0, 20, 40)
                      for po in (0, 90, 180, 270) for lam in (500, 600)))
    path = tmp_path / "m.csv"
    path.write_text(text)
    t = brdftab.open(path)
    assert t.values.shape == (24, 2) and np.allclose(t.values[:, 0], 1.0 / np.pi) and t.origin == "measured"
    assert "divided by pi" in t.ds.attrs["source_quantity"]
    cos = path.with_name("c.csv")
    cos.write_text(text.replace("reflectance_factor", "f_r_cos_theta_o"))
    c = brdftab.open(cos)
    assert np.allclose(c.values[:, 0] * np.cos(c.grid.theta_o), 1.0)
    out = tmp_path / "w.csv"
    brdftab.save(t, out)
    lines = [line for line in out.read_text().splitlines() if not line.startswith("#")]
    assert lines[0] == "theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,wavelength_nm,f_r"
    rows = np.array([[float(x) for x in line.split(",")] for line in lines[1:]])
    assert rows.shape == (48, 6) and np.allclose(rows[rows[:, 4] == 500, 5], 1.0 / np.pi, rtol=1e-15)
    back = brdftab.open(out)
    assert np.array_equal(back.values, t.values) and back.grid.equals(t.grid)


def test_seed_spec_tabulates_to_scattered_files_validated_before_export(tmp_path):
    """ggx-gold's model on a 5° gonio grid, written to .astm and .csv from one spec: the files hold that
    grid's nodes as samples, every sample has its reverse among them (reciprocity judged on node
    pairs), and the checks and the pre-export comparison with the model pass."""
    seed = Path(__file__).parents[1].joinpath("specs", "ggx-gold.toml").read_text().split("[grid]")[0]
    spec = tmp_path / "gold.toml"
    spec.write_text(seed + '[grid]\ntype = "spherical"\ntheta_i_deg = {start = 0, stop = 80, step = 5}\n'
                    'phi_i_deg = [0]\ntheta_o_deg = {start = 0, stop = 80, step = 5}\n'
                    'phi_o_deg = {start = 0, stop = 360, step = 5, endpoint = false}\n'
                    '[[output]]\npath = "gold.astm"\n[[output]]\npath = "gold.csv"\n')
    result = pipeline.run(brdftab.load_spec(spec), progress=False)
    statuses = {o.name: o.status for o in result.report.outcomes}
    assert statuses["finite"] == statuses["energy"] == statuses["reciprocity"] == "pass", result.report.summary()
    assert "node pairs" in result.report.get("reciprocity").detail
    m = brdftab.load_spec(spec).model
    for ext in (".astm", ".csv"):
        t = brdftab.open(tmp_path / f"gold{ext}")
        assert t.grid.size == 17 * (16 * 72 + 1)  # the 72 nodes at θo = 0 of an incidence are one sample
        wi, wo = t.grid.directions()
        assert np.allclose(t.values, m.eval(wi, wo), rtol=1e-12)


def test_a_dense_grid_is_refused_before_any_work(tmp_path):
    """The MERL grid's 1.46 million nodes as scattered samples would take minutes to triangulate:
    one line, exit 2, nothing written."""
    spec = tmp_path / "big.toml"
    spec.write_text('[model]\nname = "lambert"\nalbedo = 0.5\n[grid]\ntype = "merl"\n[[output]]\npath = "x.astm"\n')
    r = cli("tabulate", spec)
    one_error(r.stderr, r.exit_code, "would hold up to 1,458,000 samples; brdftab writes at most 200,000")
    assert not (tmp_path / "x.astm").exists()


@pytest.mark.parametrize("name,text,expected", [
    ("no-vars.astm", "SAMPLE_NAME x\nNUM_POINTS 1\n", "no line 'VARS"),
    ("count.astm", "NUM_POINTS 2\nVARS theta_i,phi_i,theta_s,phi_s,R,G,B\n0.1,0,0.2,3,1,1,1\n", "NUM_POINTS says 2"),
    ("degrees.astm", "VARS theta_i,phi_i,theta_s,phi_s,R,G,B\n30,0,20,180,1,1,1\n", "angles are radians"),
    ("width.astm", "VARS theta_i,phi_i,theta_s,phi_s,R,G,B\n0.1,0,0.2,3,1,1\n", "line 2: 6 numbers"),
    ("quantity.astm", "MEAS_NAME BTDF\nVARS theta_i,phi_i,theta_s,phi_s,R\n0.1,0,0.2,3,1\n", "MEAS_NAME 'BTDF'"),
    ("gap.csv", "theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,channel,f_r\n10,0,10,180,R,1\n10,0,10,180,G,1\n"
                "10,0,20,180,R,1\n", "has no row for G"),
    ("twice.csv", "theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,channel,f_r\n10,0,10,180,R,1\n10,0,10,180,R,2\n",
     "lines 2 and 3"),
    ("column.csv", "theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,channel,brdf\n10,0,10,180,R,1\n", "column 6"),
])
def test_bad_files_give_one_error_line(tmp_path, name, text, expected):
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(FormatError):
        brdftab.open(path)
    r = cli("info", path)
    one_error(r.stderr, r.exit_code, expected)
