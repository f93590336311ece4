"""Ansys Speos text ``.anisotropicbsdf`` and ``.brdf`` files: what is specific to the formats (the
format contract suite covers recognition, damage and options of every format).

Directions are built here from Speos' own description of its frame (Speos help, "Anisotropic BSDF
Surface Overview": Z the normal, X the projection of the incoming photon's direction on the
surface, Y from X and Z, the anisotropy angle from X to the anisotropy vector, the mirror direction
at (θo, φo) = (θi, 0)) with explicit vectors, and the files are read by a minimal parser of the
published layout written here, independent of brdftab's reader.
"""

from __future__ import annotations

import lzma
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from _mutate import mutations

import brdftab
from brdftab.errors import BrdftabWarning, FormatError

DATA = Path(__file__).parent / "data"
#: The Speos conversion of Radiant's measured file (tests/data/radiant-planesymmetric-brdf.bsdf)
#: from ansys/optical-automation, MIT (speos-planesymmetric-brdf.NOTICE).
REAL_ANISO = DATA / "speos-planesymmetric-brdf.anisotropicbsdf.xz"
#: An FDTD grating .brdf from ansys/optical-automation, every 5th row and column kept (the NOTICE).
REAL_BRDF = DATA / "speos-fdtd-grating-subsampled.brdf.xz"
RADIANT = DATA / "radiant-planesymmetric-brdf.bsdf"
SMALL = dict(incidences_deg=[0, 20, 45, 70], thetas_deg=list(range(0, 91, 3)), phis_deg=list(range(0, 361, 6)))


def unpack(src: Path, folder: Path) -> Path:
    out = folder / src.name.removesuffix(".xz")
    out.write_bytes(lzma.decompress(src.read_bytes()))
    return out


# --------------------------------------------------------------------------------------------
# An independent reader of the published layout, and the convention with explicit vectors


def _table(lines, k):
    nt, nphi = (int(x) for x in lines[k].split())
    phi = [float(x) for x in lines[k + 1].split()]
    rows = np.array([[float(x) for x in line.split()] for line in lines[k + 2:k + 2 + nt]])
    assert len(phi) == nphi and rows.shape == (nt, nphi + 1)
    return rows[:, 0], np.array(phi), rows[:, 1:], k + 2 + nt


def mini_aniso(text):
    """Rows 1-8, per side the anisotropy and incidence lists, per side the spectrum, then the
    reflection tables [rotation][incidence] (transmission tables are skipped)."""
    lines = text.splitlines()
    assert lines[0].startswith("OPTIS - Anisotropic BSDF surface file v8.0") and lines[1].strip() == "0"
    n_desc = int(lines[3])
    k, desc = 4, lines[4]
    while len(desc) < n_desc:
        k += 1
        desc += "\n" + lines[k]
    k += 1
    out = {"comment": lines[2], "description": desc, "vector": [float(x) for x in lines[k].split()]}
    refl, trans = (int(x) for x in lines[k + 1].split())
    out["bsdf"] = int(lines[k + 2])
    k += 3
    sides = []
    for _ in range(refl + trans):
        n_rot = int(lines[k])
        rot = [float(x) for x in lines[k + 1].split()]
        k += 2
        for _ in range(n_rot):
            inc = [float(x) for x in lines[k + 1].split()]
            k += 2
        sides.append((rot, inc))
    spectra = []
    for _ in range(refl + trans):
        ref = [float(x) for x in lines[k].split()]
        n = int(lines[k + 2])
        spectra.append((ref, np.array([[float(x) for x in lines[k + 3 + m].split()] for m in range(n)])))
        k += 3 + n
    rot, inc = sides[0]
    blocks = []
    for _ in rot:
        row = []
        for _ in inc:
            theta, phi, values, k = _table(lines, k)
            row.append(values)
        blocks.append(row)
    out.update(rotation=rot, incidence=inc, theta=theta, phi=phi, values=np.array(blocks), reference=spectra[0][0],
               spectrum=spectra[0][1])
    return out


def mini_brdf(text):
    lines = text.splitlines()
    assert lines[0].startswith("OPTIS - brdf surface file v8.0") and lines[1].strip() == "0"
    k = 5
    refl, trans = (int(x) for x in lines[k].split())
    n_inc, n_lam = (int(x) for x in lines[k + 2].split())
    inc = [float(x) for x in lines[k + 3].split()]
    lam = [float(x) for x in lines[k + 4].split()]
    k += 5
    percent, tables = [], []
    for _ in range(n_inc * n_lam):
        percent.append(float(lines[k]))
        theta, phi, values, k = _table(lines, k + 1)
        tables.append(values)
    return {"bsdf": int(lines[6]), "incidence": inc, "wavelength": lam, "theta": theta, "phi": phi,
            "percent": np.array(percent).reshape(n_inc, n_lam),
            "values": np.array(tables).reshape(n_inc, n_lam, len(theta), len(phi)), "transmission": trans}


def convention(theta_i_deg, rotation_deg, theta_o_deg, phi_deg):
    """(wi, wo) by Speos' description: the anisotropy vector is brdftab's tangent x, X is it turned
    by -rotation (the rotation goes from X to the vector, counter-clockwise), the photon travels
    along sinθi X - cosθi Z (wi points back to the light), Y = Z x X, and wo has spherical angles
    (θo, φ) in (X, Y, Z)."""
    ti, rot, to, ph = np.radians([theta_i_deg, rotation_deg, theta_o_deg, phi_deg])
    z = np.array([0.0, 0.0, 1.0])
    x = np.array([np.cos(-rot), np.sin(-rot), 0.0])
    y = np.cross(z, x)
    photon = np.sin(ti) * x - np.cos(ti) * z
    wi = -photon
    wo = np.sin(to) * (np.cos(ph) * x + np.sin(ph) * y) + np.cos(to) * z
    return wi, wo


def test_the_convention_in_plain_angles():
    # the mirror direction is (θo, φ) = (θi, 0) whatever the anisotropy angle; φ = 180 is back to the light
    for rot in (0.0, 35.0, 250.0):
        wi, wo = convention(30, rot, 30, 0)
        assert np.allclose(wo, [-wi[0], -wi[1], wi[2]])
        _, back = convention(30, rot, 30, 180)
        assert np.allclose(back, wi)
    # anisotropy angle 0: the light comes from -x (the vector lies in the plane of incidence, the
    # photon travelling along it); angle 90: X = -y, so the light comes from +y
    wi, _ = convention(40, 0, 0, 0)
    assert wi[0] < 0 and np.isclose(wi[1], 0)
    wi, _ = convention(40, 90, 0, 0)
    assert np.isclose(wi[0], 0) and wi[1] > 0
    # brdftab's grid maps nodes the same way, and back
    from brdftab.grids import SpeosGrid

    g = SpeosGrid(np.radians([0, 30, 60]), np.radians([0, 35, 250]), np.radians([0, 20, 50, 90]),
                  np.radians([0, 45, 180, 300, 360]))
    wi, wo = g.directions()
    idx = np.unravel_index(np.arange(g.size), g.shape)
    deg = [np.degrees(ax.values[i]) for ax, i in zip(g.axes, idx)]
    for n in range(g.size):
        a, b = convention(*(d[n] for d in deg))
        assert np.allclose(wi[n], a, atol=1e-12) and np.allclose(wo[n], b, atol=1e-12)
    frac, outside = g.locate(wi, wo)
    # φ is undefined at θo = 0, the rotation at θi = 0 (read as the first node), φ = 360 is φ = 0
    keep = (idx[2] > 0) & (idx[0] > 0) & (idx[3] < 4)
    for f, i in zip(frac, idx):
        assert np.allclose(np.asarray(f)[keep], i[keep], atol=1e-9)
    assert not outside.any()
    # a spec's [grid] builds the same grid (degrees at the surface)
    from brdftab.grids import grid_from_config

    cfg = grid_from_config({"type": "speos", "theta_i_deg": [0, 30, 60], "speos_rotation_deg": [0, 35, 250],
                            "theta_o_deg": [0, 20, 50, 90], "speos_phi_deg": [0, 45, 180, 300, 360]})
    assert cfg.equals(g)


def _model():
    m = brdftab.models
    return m.create("sum", terms=[m.create("lambert", albedo=0.2), m.create("microfacet", alpha=0.25)])


def _check_nodes(model, parsed, n=40, seed=3, rotation_axis=True):
    rng = np.random.default_rng(seed)
    vals = parsed["values"]
    checked = 0
    for _ in range(400):
        j, i, t, p = (int(rng.integers(s)) for s in vals.shape)
        rot = parsed["rotation"][j] if rotation_axis else 0.0
        wi, wo = convention(parsed["incidence"][i], rot, parsed["theta"][t], parsed["phi"][p])
        if wo[2] < 0.05:
            continue
        assert vals[j, i, t, p] == pytest.approx(model.eval(wi, wo)[0], rel=6e-9, abs=1e-15)
        checked += 1
        if checked == n:
            return
    raise AssertionError("too few nodes above the horizon")


def test_anisotropicbsdf_round_trip_and_an_independent_parser(tmp_path):
    from brdftab.integrate import directional_albedo

    path = tmp_path / "m.anisotropicbsdf"
    model = _model()
    written = brdftab.save(model, path, reference_incidence_deg=20, **SMALL)
    table = brdftab.open(path)
    assert table.origin == "unknown" and table.channels == ("mono",) and table.grid.type_name == "speos"
    v, w = np.asarray(table.values), np.asarray(written.values)
    assert np.max(np.abs(v - w) / np.maximum(w, 1e-300)) <= 1e-8  # the percentage's 9 digits
    p = mini_aniso(path.read_text())
    assert p["bsdf"] == 1 and p["rotation"] == [0.0] and p["incidence"] == [0, 20, 45, 70]
    _check_nodes(model, {**p, "values": p["values"]})
    # the spectrum: 100 x the directional albedo at the reference incidence (20 deg), flat
    assert p["reference"] == [20.0, 0.0] and np.all(p["spectrum"][:, 1] == p["spectrum"][0, 1])
    a_table = directional_albedo(written, np.radians(20.0), np.pi)[0]
    assert p["spectrum"][0, 1] == pytest.approx(100 * a_table, rel=1e-8)
    # against the model's albedo (the table's resolution: 3 deg x 6 deg holds it to 0.5 %)
    a_model = directional_albedo(model, np.radians(20.0), 0.0)[0]
    assert p["spectrum"][0, 1] == pytest.approx(100 * a_model, rel=0.005)
    assert table.ds.attrs["speos_normalization"][0] == pytest.approx(1.0, abs=1e-8)


def test_an_anisotropic_source_is_written_with_anisotropy_angles(tmp_path):
    model = brdftab.models.create("microfacet", alpha_x=0.15, alpha_y=0.4)
    path = tmp_path / "a.anisotropicbsdf"
    with pytest.raises(FormatError, match="anisotropic.*anisotropy_angles_deg"):
        brdftab.save(model, path, anisotropy_angles_deg=[0], **SMALL)
    brdftab.save(model, path, anisotropy_angles_deg=list(range(10, 360, 45)),
                 **{**SMALL, "incidences_deg": [0, 30, 60]})
    p = mini_aniso(path.read_text())
    _check_nodes(model, p, n=30, seed=11)
    table = brdftab.open(path)
    assert not table.isotropic and len(table.grid.axes[1]) == 8
    # the energy and albedo checks sweep its incident azimuths, phi_i = 180 - angle
    from brdftab.checks import run_checks

    report = {o.name: o for o in run_checks(table, only=["energy", "albedo"]).outcomes}
    assert report["energy"].status == "pass"
    assert np.allclose(report["albedo"].data["phi_i_deg"], sorted((180 - r) % 360 for r in range(10, 360, 45)))
    # the table answers at the file's own directions (a node at rotation 55 deg, incidence 30)
    wi, wo = convention(30, 55, 42, 60)
    assert table.eval(wi, wo)[0] == pytest.approx(p["values"][1, 1, 14, 10], rel=1e-8)


def test_brdf_round_trip_and_an_independent_parser(tmp_path):
    path = tmp_path / "m.brdf"
    model = _model()
    brdftab.save(model, path, **SMALL)
    p = mini_brdf(path.read_text())
    assert p["bsdf"] == 1 and p["incidence"] == [0, 20, 45, 70] and p["wavelength"] == [550.0]
    _check_nodes(model, {**p, "rotation": [0.0], "values": p["values"][:, 0][None]}, rotation_axis=False)
    # each percentage: 100 x brdftab's albedo of the values written at its incidence, which
    # holds the model's albedo to 0.5 % on this 3 x 6 deg grid
    from brdftab.integrate import directional_albedo

    a = directional_albedo(model, np.radians(p["incidence"]), 0.0)[:, 0]
    assert np.allclose(p["percent"][:, 0], 100 * a, rtol=0.005)
    table = brdftab.open(path)
    assert np.allclose(table.ds.attrs["speos_normalization"], 1.0, atol=1e-8)
    with pytest.raises(FormatError, match="isotropic"):
        brdftab.save(brdftab.models.create("microfacet", alpha_x=0.15, alpha_y=0.4), tmp_path / "a.brdf", **SMALL)


def _synthetic_brdf(tmp_path, flag, percents, transmission=False):
    """A .brdf text written here: two incidences, two wavelengths, f = 0.1 + 0.2 cos(θo) sin²(φ/2)."""
    theta, phi = np.arange(0, 91, 10.0), np.arange(0, 361, 30.0)
    f = 0.1 + 0.2 * np.cos(np.radians(theta))[:, None] * np.sin(np.radians(phi) / 2)[None] ** 2
    stored = f * np.cos(np.radians(theta))[:, None] if flag == 0 else f
    lines = ["OPTIS - brdf surface file v8.0", "0", "synthetic", "4", "test", f"1 {int(transmission)}", str(flag),
             "2 2", "10 40", "400 700"]

    def table(rows_theta, values):
        out = [f"{len(rows_theta)} {len(phi)}", "\t" + "\t".join(f"{x:g}" for x in phi)]
        return out + [f"{t:g}\t" + "\t".join(repr(float(x)) for x in row) for t, row in zip(rows_theta, values)]

    for pc in percents:
        lines += [repr(pc)] + table(theta, stored)
    if transmission:
        for _ in percents:
            lines += ["3.5"] + table(theta + 90, stored)
    lines.append("End of file")
    path = tmp_path / "s.brdf"
    path.write_text("\n".join(lines) + "\n")
    return path, f


def test_intensity_files_are_divided_by_cos_theta_and_scaled_to_their_percentages(tmp_path):
    from brdftab.formats.speos import node_albedo

    bsdf, f = _synthetic_brdf(tmp_path, 1, [10.0, 10.0, 20.0, 20.0])
    a = brdftab.open(bsdf)
    (tmp_path / "b").mkdir()
    inten, _ = _synthetic_brdf(tmp_path / "b", 0, [10.0, 10.0, 20.0, 20.0])
    b = brdftab.open(inten)
    above = np.cos(a.grid.axes[2].values) > 1e-9
    assert np.allclose(np.asarray(a.values)[:, :, above], np.asarray(b.values)[:, :, above], rtol=1e-12)
    assert "intensity" in b.ds.attrs["source_quantity"] and "divided by cos(theta_o)" in b.ds.attrs["source_quantity"]
    # the albedo of each table is its percentage / 100 (Speos' normalization)
    alb = node_albedo(a)[:, 0]
    assert np.allclose(alb, [[0.1, 0.1], [0.2, 0.2]], rtol=1e-9)
    assert a.spectral and list(a.ds["wavelength"].values) == [400.0, 700.0]
    # and the shape is the file's: value / file value is one number per table
    ratio = np.asarray(a.values)[0, 0, :, :, 0] / f
    assert np.allclose(ratio, ratio[0, 0], rtol=1e-12)


def test_a_transmission_side_is_skipped_with_a_warning_and_a_btdf_file_refused(tmp_path):
    path, _ = _synthetic_brdf(tmp_path, 1, [10.0, 10.0, 20.0, 20.0], transmission=True)
    with pytest.warns(BrdftabWarning, match="transmission.*skipped"):
        t = brdftab.open(path)
    assert t.shape[:4] == (2, 1, 10, 13)
    path.write_text(path.read_text().replace("\n1 1\n", "\n0 1\n", 1))
    with pytest.raises(FormatError, match="transmission.*reflection") as info:
        brdftab.open(path)
    assert "\n" not in str(info.value)


def _real_nodes(parsed, n=30, seed=1, rotation=True):
    rng = np.random.default_rng(seed)
    vals = parsed["values"]
    out = []
    while len(out) < n:
        idx = tuple(int(rng.integers(s)) for s in vals.shape)
        j, i, t, p = idx
        rot = parsed["rotation"][j] if rotation else 0.0
        wi, wo = convention(parsed["incidence"][i], rot, parsed["theta"][t], parsed["phi"][p])
        if wo[2] > 0.02 and parsed["theta"][t] > 0 and vals[idx] > 0:
            out.append((wi, wo, vals[idx], i))
    return out


def _trapezoid_albedo(theta_deg, phi_deg, values):
    """∫ f cosθ dω of one table by the trapezoid rule over its own nodes (independent of brdftab)."""
    t, p = np.radians(theta_deg), np.radians(phi_deg)
    inner = np.trapezoid(values, p, axis=1)
    return np.trapezoid(inner * np.cos(t) * np.sin(t), t)


def test_a_real_anisotropicbsdf_reads_validates_and_converts_to_netcdf(tmp_path):
    path = unpack(REAL_ANISO, tmp_path)
    p = mini_aniso(path.read_text())
    table = brdftab.open(path)
    assert table.origin == "measured" and table.grid.type_name == "speos" and table.shape == (13, 1, 19, 37, 1)
    # 30 nodes: the table at the file's directions is the file's number times one scale, Speos'
    # normalization P / (100 A): A, the albedo at the reference incidence (15 deg), computed here
    # by the trapezoid rule (within 0.5 % of brdftab's quadrature on this 5 x 10 deg table)
    nodes = _real_nodes(p)
    wi = np.array([x[0] for x in nodes])
    wo = np.array([x[1] for x in nodes])
    file_values = np.array([x[2] for x in nodes])
    got = table.eval(wi, wo)[:, 0]
    scale = got / file_values
    assert np.allclose(scale, scale[0], rtol=1e-12)
    assert p["reference"] == [15.0, 0.0]
    a = _trapezoid_albedo(p["theta"], p["phi"], p["values"][0, 0])
    assert scale[0] == pytest.approx(p["spectrum"][0, 1] / (100 * a), rel=0.005)
    # (formats/speos.md quotes these: the data's albedo 0.424 at 15 deg, a percentage of 13.45)
    assert round(table.ds.attrs["speos_albedo_of_the_data"], 3) == 0.424 and round(scale[0], 3) == 0.317
    # the checks judge it as measured data: no failure, and its albedo at the reference incidence
    # is the file's percentage / 100 (the normalization)
    from brdftab.checks import run_checks

    report = {o.name: o for o in run_checks(table).outcomes}
    assert not [o.name for o in report.values() if o.status == "fail"]
    assert report["albedo"].data["values"][0][0] == pytest.approx(p["spectrum"][0, 1] / 100, rel=1e-12)
    # convert copies value for value
    proc = subprocess.run([sys.executable, "-m", "brdftab", "convert", str(path), str(tmp_path / "r.nc")],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and "copied" in proc.stdout, proc.stderr
    nc = brdftab.open(tmp_path / "r.nc")
    assert type(nc.grid).__name__ == "SpeosGrid" and nc.origin == "measured"
    assert np.array_equal(nc.values, table.values)
    assert np.array_equal(nc.eval(wi, wo)[:, 0], got)
    brdftab.save(table, tmp_path / "r.zarr")
    assert np.array_equal(brdftab.open(tmp_path / "r.zarr").values, table.values)
    rng = np.random.default_rng(0)
    from brdftab.geometry import sph_to_vec

    x = sph_to_vec(rng.uniform(0.0, 1.4, 400), rng.uniform(0, 6.3, 400))
    y = sph_to_vec(rng.uniform(0.0, 1.5, 400), rng.uniform(0, 6.3, 400))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BrdftabWarning)
        assert np.array_equal(nc.eval(x, y), table.eval(x, y), equal_nan=True)
    # and back: the netCDF table written as Speos holds the file's nodes, its numbers times the
    # scale, and the file's percentage (the albedo at 15 deg of what it holds)
    from brdftab.convert import convert

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BrdftabWarning)
        convert(tmp_path / "r.nc", tmp_path / "back.anisotropicbsdf", progress=False)
    q = mini_aniso((tmp_path / "back.anisotropicbsdf").read_text())
    assert q["incidence"] == p["incidence"] and q["rotation"] == p["rotation"] and q["reference"] == p["reference"]
    assert np.array_equal(q["theta"], p["theta"]) and np.array_equal(q["phi"], p["phi"])
    assert np.allclose(q["values"], p["values"] * scale[0], rtol=1e-8, atol=0)
    assert np.allclose(q["spectrum"][:, 1], p["spectrum"][0, 1], rtol=1e-8)


def test_the_real_speos_file_agrees_with_the_measurement_it_was_converted_from():
    """Ansys' converter wrote the Speos file from Radiant's Zemax file (read by brdftab's Zemax
    reader, convention tested in test_zemax): at one incidence the two differ by one scale (the
    converter scaled each block to its TIS); with the Speos azimuth turned by 180 deg they do not."""
    from brdftab.geometry import sph_to_vec

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BrdftabWarning)
        import tempfile

        with tempfile.TemporaryDirectory() as d:
            speos = brdftab.open(unpack(REAL_ANISO, Path(d)))
        zemax = brdftab.open(RADIANT)
    rng = np.random.default_rng(0)
    n = 600
    for inc, bound in ((15.0, 0.005), (45.0, 0.02)):  # measured: 0.39 % and 1.5 %
        wi = sph_to_vec(np.full(n, np.radians(inc)), rng.uniform(0, 2 * np.pi, n))
        wo = sph_to_vec(np.radians(rng.uniform(2, 70, n)), rng.uniform(0, 2 * np.pi, n))
        wo_turned = wo * [-1, -1, 1]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", BrdftabWarning)
            a, b, c = speos.eval(wi, wo)[:, 0], zemax.eval(wi, wo)[:, 0], speos.eval(wi, wo_turned)[:, 0]
        ok = np.isfinite(a) & np.isfinite(b) & np.isfinite(c) & (b > 0)
        assert ok.sum() > 400
        r = a[ok] / b[ok]
        assert np.percentile(np.abs(r / np.median(r) - 1), 95) < bound
        r_turned = c[ok] / b[ok]
        assert np.percentile(np.abs(r_turned / np.median(r_turned) - 1), 95) > 0.4  # measured: 52 % and 106 %


def test_a_real_brdf_reads_and_converts_to_netcdf(tmp_path):
    path = unpack(REAL_BRDF, tmp_path)
    p = mini_brdf(path.read_text())
    with pytest.warns(BrdftabWarning, match="transmission"):
        table = brdftab.open(path)
    assert table.origin == "unknown" and table.shape == (4, 1, 19, 73, 1)
    nodes = _real_nodes({**p, "rotation": [0.0], "values": p["values"][:, 0][None]}, rotation=False)
    wi = np.array([x[0] for x in nodes])
    wo = np.array([x[1] for x in nodes])
    file_values = np.array([x[2] for x in nodes])
    inc = np.array([x[3] for x in nodes])
    got = table.eval(wi, wo)[:, 0]
    # per incidence one scale, P / (100 A) with A the trapezoid albedo of that table (brdftab's
    # quadrature agrees within 2 % on this 5 x 5 deg grid of sharp grating orders: measured 1.7 % at
    # normal incidence, 0.5 % or less at the others)
    for i in np.unique(inc):
        s = got[inc == i] / file_values[inc == i]
        assert np.allclose(s, s[0], rtol=1e-12)
        a = _trapezoid_albedo(p["theta"], p["phi"], p["values"][i, 0])
        assert s[0] == pytest.approx(p["percent"][i, 0] / (100 * a), rel=0.02)
    # (formats/speos.md quotes the scales of the four incidences)
    assert np.allclose(table.ds.attrs["speos_normalization"], [33, 48, 4.1, 1.6], rtol=0.03)
    from brdftab.convert import convert

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BrdftabWarning)
        convert(path, tmp_path / "g.nc", progress=False)
    nc = brdftab.open(tmp_path / "g.nc")
    assert np.array_equal(nc.values, table.values) and np.array_equal(nc.eval(wi, wo)[:, 0], got)


DAMAGE = {
    "version": (lambda t: t.replace("file v8.0", "file v7.0", 1), "version 7.0"),
    "binary": (lambda t: t.replace("v8.0\n0\n", "v8.0\n1\n", 1), "binary"),
    "count": (lambda t: t.replace("\n13\n", "\n14\n", 1), "expected 14 values"),
    "not a number": (lambda t: t.replace("0.17944232155258916", "0.1794x", 1), "expected row"),
    "truncated": (lambda t: t[: len(t) * 2 // 3].rsplit("\n", 1)[0], "truncated"),
    "extra": (lambda t: t.replace("End of file", "1 2 3\nEnd of file"), "after the last table"),
}


@pytest.mark.parametrize("what", sorted(DAMAGE))
def test_damaged_files_are_refused_in_one_line_naming_file_and_line(tmp_path, what):
    cut, words = DAMAGE[what]
    text = lzma.decompress(REAL_ANISO.read_bytes()).decode()
    assert cut(text) != text
    path = tmp_path / "bad.anisotropicbsdf"
    path.write_text(cut(text))
    with pytest.raises(FormatError) as info:
        brdftab.open(path)
    msg = str(info.value)
    assert "\n" not in msg and str(path) in msg and words in msg and ": line " in msg


def test_a_damaged_file_on_the_command_line_is_one_line_and_exit_2(tmp_path):
    path = tmp_path / "bad.brdf"
    path.write_text("OPTIS - brdf surface file v8.0\n0\nc\n1\nd\n1 0\n1\n2 1\n10 x\n")
    proc = subprocess.run([sys.executable, "-m", "brdftab", "info", str(path)], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and "brdftab: error:" in proc.stderr
    assert "line 9" in proc.stderr and "Traceback" not in proc.stderr


@pytest.mark.parametrize("seed, fmt, incidences", [
    ("pyromark-cook-torrance", "anisotropicbsdf", [0, 15, 30, 45, 60]),
    # GGX alpha 0.2: its lobe moves with theta_i across these absolute theta_o rows, so the
    # incidences are 5 deg apart (15 deg apart the pre-export comparison refuses it: median 5.5 %)
    ("ggx-gold", "brdf", list(range(0, 45, 5)))])
def test_seed_specs_tabulate_to_speos_files_validated(tmp_path, seed, fmt, incidences):
    spec = (Path(__file__).parent.parent / "specs" / f"{seed}.toml").read_text()
    spec = spec[:spec.index("[[output]]")] + (
        f'[[output]]\npath = "{seed}.{fmt}"\nincidences_deg = {incidences}\n'
        f'thetas_deg = {list(range(0, 91, 2))}\nphis_deg = {list(range(0, 361, 4))}\n')
    (tmp_path / "s.toml").write_text(spec)
    from brdftab.pipeline import run
    from brdftab.spec import load_spec

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        run(load_spec(tmp_path / "s.toml"), progress=False)  # refuses (raises) when a check fails
    out = tmp_path / f"{seed}.{fmt}"
    assert out.exists()
    said = [str(w.message) for w in caught if issubclass(w.category, BrdftabWarning)]
    assert all("luminance Y" in m for m in said), said  # the RGB seed: written as its luminance
    parsed = (mini_aniso if fmt == "anisotropicbsdf" else mini_brdf)(out.read_text())
    assert parsed["incidence"] == incidences
    model = load_spec(tmp_path / "s.toml").model
    if model.channels == ("R", "G", "B"):
        from brdftab.colorimetry import XYZView

        model = XYZView(model, luminance_only=True)
    if fmt == "brdf":
        parsed = {**parsed, "rotation": [0.0], "values": parsed["values"][:, 0][None]}
    _check_nodes(model, parsed, n=25, seed=5)


@pytest.mark.parametrize("kind", ["anisotropicbsdf", "brdf"])
def test_mutated_files_give_a_format_error_or_a_table_never_a_crash(kind):
    """Words of the real files deleted, duplicated or replaced at random: the parser answers each
    with its content or one FormatError line naming the line."""
    from brdftab.formats.speos import parse_anisotropicbsdf, parse_brdf

    parse = parse_anisotropicbsdf if kind == "anisotropicbsdf" else parse_brdf
    lines = lzma.decompress((REAL_ANISO if kind == "anisotropicbsdf" else REAL_BRDF).read_bytes()).decode().splitlines()
    junk = ["", "-1", "0", "1", "2", "1e999", "nan", "x", "3.5", "999999", "End of file", "1 1", "19 37"]
    errors = 0
    for text in mutations(lines, junk, 50, head=40):
        try:
            parse(f"m.{kind}", text)
        except FormatError as exc:
            errors += 1
            assert "\n" not in str(exc) and str(exc).startswith(f"m.{kind}: ")
    assert errors > 20


def test_a_spectral_model_is_written_with_its_spectrum(tmp_path):
    """.brdf: one table per wavelength; .anisotropicbsdf: one distribution and the spectrum of
    100 x the albedo at the reference incidence (Speos' approximation, judged by the checks)."""
    from brdftab.integrate import directional_albedo

    al = {"n": {"wavelengths_nm": [400, 550, 700], "values": [0.490, 0.958, 1.83]},
          "k": {"wavelengths_nm": [400, 550, 700], "values": [4.86, 6.69, 8.31]}}
    model = brdftab.models.create("microfacet", alpha=0.3, fresnel="conductor", n=al["n"], k=al["k"])
    lam = [400.0, 550.0, 700.0]
    b = tmp_path / "s.brdf"
    brdftab.save(model, b, spectrum_wavelengths_nm=lam, **SMALL)
    p = mini_brdf(b.read_text())
    assert p["wavelength"] == lam and p["values"].shape[1] == 3
    rng = np.random.default_rng(2)
    for _ in range(20):
        i, m, t, f = (int(rng.integers(s)) for s in p["values"].shape)
        wi, wo = convention(p["incidence"][i], 0.0, p["theta"][t], p["phi"][f])
        assert p["values"][i, m, t, f] == pytest.approx(model.eval(wi, wo, [lam[m]])[0], rel=6e-9)
    a = directional_albedo(model, np.radians(p["incidence"]), 0.0, lam)
    assert np.allclose(p["percent"], 100 * a, rtol=0.005)
    t = brdftab.open(b)
    assert t.spectral and list(t.ds["wavelength"].values) == lam
    a_file = tmp_path / "s.anisotropicbsdf"
    brdftab.save(model, a_file, spectrum_wavelengths_nm=lam, reference_incidence_deg=20, **SMALL)
    q = mini_aniso(a_file.read_text())
    assert list(q["spectrum"][:, 0]) == lam
    assert np.allclose(q["spectrum"][:, 1], 100 * directional_albedo(model, np.radians(20.0), 0.0, lam), rtol=0.005)
    # read back: the one distribution scaled to each wavelength's albedo: at nodes near the mirror
    # direction within 0.1 % of the model for this aluminium-like conductor (measured: 0.011 %)
    t = brdftab.open(a_file)
    for theta_o, phi in ((21, 0), (30, 12), (9, 180)):
        wi, wo = convention(20, 0, theta_o, phi)
        assert np.allclose(t.eval(wi, wo)[0], model.eval(wi, wo, lam)[0], rtol=1e-3)
