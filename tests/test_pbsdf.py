"""Mitsuba 3 ``measured_polarized`` tables (``.pbsdf``): brdftab's writer and reader against
Mitsuba itself (``scalar_spectral_polarized``).

Independent references:

* the test model's Fresnel Mueller matrix (a textbook closed form, :mod:`_polarized`) equals
  ``mitsuba.mueller.specular_reflection`` — this pins the S3 sign and the s/p frame;
* the test model (GGX, separable Smith G, conductor Fresnel Mueller matrix in the frame
  x = normalize(ω_light × ω_view)) equals Mitsuba's own polarized ``roughconductor`` once
  Mitsuba's output is rotated into that frame with ``mitsuba.mueller.rotate_mueller_basis``;
* Mitsuba's ``measured_polarized`` loads the files brdftab writes; its ``eval`` (÷ cosθ of the
  light direction, rotated into the table frame) equals brdftab's interpolation of the file
  and approaches the model as the grid is refined;
* a minimal tensor-file writer written here from the layout description (not brdftab's)
  produces a file brdftab reads.

Mitsuba's variant is global: each test sets the polarized variant and restores the previous one.
"""

from __future__ import annotations

import json
import struct

import mitsuba as mi
import numpy as np
import pytest
from _cli import cli, one_error, run
from _polarized import KAIST_NM, DepolarizingLambert, GGXConductor, fresnel_mueller

import brdftab
from brdftab import formats
from brdftab.errors import BrdftabError, FormatError, ParameterError
from brdftab.formats._tensor import parse_tensor
from brdftab.geometry import sph_to_vec
from brdftab.grids import RusinkiewiczGrid
from brdftab.table import tabulate

assert "scalar_spectral_polarized" in mi.variants(), "Mitsuba variant scalar_spectral_polarized is missing"

GRID = RusinkiewiczGrid(30, 30, 72, phi_d_fold="none")


@pytest.fixture
def polarized_variant():
    before = mi.variant()
    mi.set_variant("scalar_spectral_polarized")
    yield mi
    if before is not None:
        mi.set_variant(before)


def random_pairs(n, seed=0, min_cos=0.15):
    rng = np.random.default_rng(seed)
    mu = rng.uniform(min_cos, 1.0, (2, n))
    phi = rng.uniform(-np.pi, np.pi, (2, n))
    return sph_to_vec(np.arccos(mu[0]), phi[0]), sph_to_vec(np.arccos(mu[1]), phi[1])


def in_table_frame(value, light, view):
    """A Mueller matrix Mitsuba's ``eval`` returned (in its implicit Stokes bases of the incident
    beam −light and the outgoing beam view) in the frame where both beams share
    x = normalize(light × view), as ``numpy [λ, 4, 4]``."""
    x = np.cross(light, view)
    x /= np.linalg.norm(x)
    V = mi.Vector3f
    back = mi.mueller.rotate_mueller_basis(value, V(*(-light)), mi.mueller.stokes_basis(V(*(-light))), V(*x),
                                           V(*view), mi.mueller.stokes_basis(V(*view)), V(*x))
    return np.moveaxis(np.array(back), -1, 0)


def mitsuba_mueller(bsdf, wi, wo, wavelengths):
    """f's Mueller matrix by Mitsuba, ``[n, len(wavelengths), 4, 4]``: ``bsdf.eval`` with the
    camera along brdftab's wo and the light along wi (Radiance mode), ÷ cosθ of the light,
    in the table frame; four wavelengths per call."""
    lam = [float(x) for x in wavelengths]
    out = np.zeros((len(wi), len(lam), 4, 4))
    for k, (light, view) in enumerate(zip(wi, wo)):
        for s in range(0, len(lam), 4):
            part = lam[s:s + 4]
            si = mi.SurfaceInteraction3f()
            si.wi = mi.Vector3f(*view)
            si.wavelengths = mi.UnpolarizedSpectrum(part + [part[-1]] * (4 - len(part)))
            value = bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(*light))
            out[k, s:s + len(part)] = in_table_frame(value, light, view)[:len(part)] / light[2]
    return out


def test_fresnel_mueller_closed_form_is_mitsubas_specular_reflection(polarized_variant):
    import drjit as dr

    worst = 0.0
    for cos_t in (0.05, 0.2, 0.5, 0.7, 0.95, 1.0):
        for eta in (1.5 + 0j, 0.3 + 3j, 0.2 + 3.5j, 1.33 + 0j):
            ref = np.array(mi.mueller.specular_reflection(cos_t, dr.scalar.Complex2f(eta.real, eta.imag)))
            worst = max(worst, np.abs(ref - fresnel_mueller(cos_t, eta)).max())
    assert worst < 1e-6
    # the circular sign: a sign flip of S3 (diag(1, 1, 1, -1) conjugation) is caught
    flip = np.diag([1.0, 1.0, 1.0, -1.0])
    ref = np.array(mi.mueller.specular_reflection(0.7, dr.scalar.Complex2f(0.3, 3.0)))
    assert np.abs(ref - flip @ fresnel_mueller(0.7, 0.3 + 3j) @ flip).max() > 0.5


def test_the_test_model_is_mitsubas_polarized_roughconductor(polarized_variant):
    model = GGXConductor(0.3)
    wi, wo = random_pairs(60, seed=1)
    worst = 0.0
    for lam in KAIST_NM:
        eta = model.eta(lam)
        rc = mi.load_dict({"type": "roughconductor", "distribution": "ggx", "alpha": 0.3, "eta": float(eta.real),
                           "k": float(eta.imag), "sample_visible": False})
        got = mitsuba_mueller(rc, wi, wo, [lam])[:, 0]
        ref = model.eval_mueller(wi, wo, [lam])[:, 0]
        worst = max(worst, float((np.abs(got - ref) / ref[:, :1, :1]).max()))
    print(f"test model vs Mitsuba roughconductor: max |ΔM_ij| / M00 = {worst:.2g}")
    assert worst < 1e-5


@pytest.fixture(scope="module")
def ggx_table():
    return tabulate(GGXConductor(0.3), GRID, polarized=True, progress=False)


def test_mitsuba_loads_the_written_file_and_evaluates_what_brdftab_interpolates(polarized_variant, ggx_table,
                                                                                 tmp_path):
    path = tmp_path / "ggx.pbsdf"
    brdftab.save(ggx_table, path)
    bsdf = mi.load_dict({"type": "measured_polarized", "filename": str(path)})
    wi, wo = random_pairs(150, seed=3)
    got = mitsuba_mueller(bsdf, wi, wo, KAIST_NM)
    assert not np.isnan(got).any()
    back = brdftab.open(path)
    assert back.polarized and formats.detect(path).name == "pbsdf"
    ours = back.eval_mueller(wi, wo)
    rel = np.abs(got - ours) / ours[..., :1, :1]
    print(f"Mitsuba measured_polarized vs brdftab's interpolation of the file: max |ΔM_ij|/M00 = {rel.max():.2g}")
    assert rel.max() < 1e-5  # float32 interpolation weights (measured 2.5e-6)
    # and brdftab's interpolation of the file is that of the table written (float32 samples)
    src = ggx_table.eval_mueller(wi, wo)
    assert (np.abs(src - ours) / src[..., :1, :1]).max() < 1e-6
    # against the model, and against Mitsuba's own polarized roughconductor: the interpolation
    # error of a 3°/5° grid (formats/pbsdf.md; benchmarks/bench_pbsdf_mitsuba.py on finer grids)
    model = GGXConductor(0.3)
    ref = model.eval_mueller(wi, wo)
    m00 = np.abs(got[..., 0, 0] - ref[..., 0, 0]) / ref[..., 0, 0]
    rc = np.zeros_like(got)
    for k, lam in enumerate(KAIST_NM):
        eta = model.eta(lam)
        bsdf_rc = mi.load_dict({"type": "roughconductor", "distribution": "ggx", "alpha": 0.3, "eta": float(eta.real),
                                "k": float(eta.imag), "sample_visible": False})
        rc[:, k] = mitsuba_mueller(bsdf_rc, wi, wo, [lam])[:, 0]
    rc00 = np.abs(got[..., 0, 0] - rc[..., 0, 0]) / rc[..., 0, 0]
    norm = np.abs(got / got[..., :1, :1] - rc / rc[..., :1, :1]).max(axis=(-2, -1))
    print(f"on {GRID.describe()}: median |dM00|/M00 vs the model {np.median(m00):.2g}, vs Mitsuba's roughconductor "
          f"{np.median(rc00):.2g}; median max |d(Mij/M00)| {np.median(norm):.2g}")
    assert np.median(m00) < 0.01 and np.median(rc00) < 0.01 and np.median(norm) < 1.5e-3


def test_theta_d_zero_nodes_hold_the_limit_along_phi_d_and_mitsuba_gives_no_nan(polarized_variant, ggx_table,
                                                                                 tmp_path):
    # a grid with nodes at θd = 0 (wi = wo: the scattering plane is undefined) and at θh = 0
    grid = RusinkiewiczGrid(np.radians(np.arange(0, 91, 5.0)), np.radians(np.arange(0, 91, 5.0)), 36,
                            phi_d_fold="none", sample_position="lower-edge")
    model = GGXConductor(0.3)
    table = tabulate(model, grid, polarized=True, progress=False)
    m = table.ds["mueller"].values
    assert np.isfinite(m).all()
    # the θd = 0 nodes hold the limit along their φd: the model a hair away
    from brdftab.geometry import hd_to_io

    th, pd = np.radians(30.0), grid.axes[2].values
    wi, wo = hd_to_io(th, 0.0, 1e-3, pd)
    near = model.eval_mueller(wi, wo)
    assert np.abs(m[6, 0] - near).max() / near[..., 0, 0].max() < 1e-4
    path = tmp_path / "nodes.pbsdf"
    brdftab.save(table, path)
    bsdf = mi.load_dict({"type": "measured_polarized", "filename": str(path)})
    # queries near retro-reflection and near the normal
    a, b = hd_to_io(np.radians([0.5, 2, 20, 40]), 0.3, np.radians([0.2, 0.5, 1.0, 0.3]), np.radians([10, 100, 200, 300]))
    got = mitsuba_mueller(bsdf, a, b, KAIST_NM)
    assert not np.isnan(got).any()
    ours = brdftab.open(path).eval_mueller(a, b)
    assert (np.abs(got - ours) / ours[..., :1, :1]).max() < 2e-5


def test_a_grey_polarized_model_is_written_at_the_kaist_wavelengths(polarized_variant, tmp_path):
    path = tmp_path / "lambert.pbsdf"
    brdftab.save(DepolarizingLambert(0.6), path, grid=RusinkiewiczGrid(6, 6, 12, phi_d_fold="none"))
    fields = parse_tensor(path.read_bytes())
    assert fields["wvls"].tolist() == [450, 500, 550, 600, 650] and fields["wvls"].dtype == np.uint16
    assert fields["M"].shape == (14, 6, 6, 5, 4, 4)  # 12 bin-centre nodes and the two seam nodes
    assert fields["phi_d"][0, 0] == np.float32(-np.pi) and fields["phi_d"][0, -1] == np.float32(np.pi)
    back = brdftab.open(path)
    assert back.channels == ("mono",)
    wi, wo = random_pairs(20)
    assert np.allclose(back.eval_mueller(wi, wo)[..., 0, 0], 0.6 / np.pi, rtol=1e-6)
    bsdf = mi.load_dict({"type": "measured_polarized", "filename": str(path)})
    got = mitsuba_mueller(bsdf, wi, wo, [500.0])
    expect = np.zeros((4, 4))
    expect[0, 0] = 0.6 / np.pi
    assert np.abs(got - expect).max() < 1e-6


def minimal_tensor(fields):
    """A tensor file from the layout description (formats.md §2.1), independent of brdftab's."""
    codes = {np.dtype(t): c for c, t in enumerate(["u1", "i1", "u2", "i2", "u4", "i4", "u8", "i8", "f2", "f4",
                                                   "f8"], start=1)}
    arrs = {k: np.ascontiguousarray(v) for k, v in fields.items()}
    hdr = bytearray(b"tensor_file\0" + struct.pack("<BBI", 1, 0, len(arrs)))
    pos = len(hdr) + sum(13 + len(k) + 8 * a.ndim for k, a in arrs.items())
    offs = {}
    for k, a in arrs.items():
        pos = -(-pos // 8) * 8
        offs[k] = pos
        pos += a.nbytes
        hdr += struct.pack("<H", len(k)) + k.encode() + struct.pack("<HBQ", a.ndim, codes[a.dtype], offs[k])
        hdr += struct.pack(f"<{a.ndim}Q", *a.shape)
    out = bytearray(hdr)
    for k, a in arrs.items():
        out += b"\0" * (offs[k] - len(out))
        out += a.tobytes()
    return bytes(out)


def synthetic_fields(n_phi=9, n_td=4, n_th=5, wvls=KAIST_NM, seed=0):
    rng = np.random.default_rng(seed)
    m = rng.uniform(-0.1, 0.1, (n_phi, n_td, n_th, len(wvls), 4, 4)).astype(np.float32)
    m[..., 0, 0] = rng.uniform(0.5, 1.0, m.shape[:4])
    m[-1] = m[0]  # one seam value at ±180°
    return {"theta_h": np.linspace(0, np.pi / 2, n_th, dtype=np.float32)[None],
            "theta_d": np.linspace(0, np.pi / 2, n_td, dtype=np.float32)[None],
            "phi_d": np.linspace(-np.pi, np.pi, n_phi, dtype=np.float32)[None],
            "wvls": np.asarray(wvls, np.uint16), "M": m}


def test_reader_maps_a_file_written_elsewhere_onto_its_nodes(tmp_path):
    f = synthetic_fields()
    path = tmp_path / "kaist-like.pbsdf"
    path.write_bytes(minimal_tensor(f))
    t = brdftab.open(path)
    assert t.polarized and t.spectral and t.layout.wavelengths.tolist() == list(KAIST_NM)
    assert t.origin == "unknown" and not t.reciprocity_declared
    # node (φd index 6 = +90°, θd index 2 = 60°, θh index 1 = 22.5°) evaluated between nodes' directions
    from brdftab.geometry import hd_to_io

    th, td = np.float32(np.pi / 8), np.float32(np.pi / 3)
    wi, wo = hd_to_io(float(th), 0.3, float(td), float(np.float32(np.pi / 2)))
    got = t.eval_mueller(wi, wo)
    assert np.allclose(got, f["M"][6, 2, 1], rtol=0, atol=1e-6)
    assert np.allclose(t.eval(wi, wo), f["M"][6, 2, 1, :, 0, 0], rtol=1e-6)
    # a node at −90° (index 2) is φd = 270° in brdftab's [0, 2π)
    wi, wo = hd_to_io(float(th), 0.0, float(td), float(np.float32(-np.pi / 2)))
    assert np.allclose(t.eval_mueller(wi, wo), f["M"][2, 2, 1], atol=1e-6)


@pytest.mark.parametrize("change, message", [
    (lambda f: f.update(wvls=np.array([450, 500, 550, 600], np.uint16), M=f["M"][..., :4, :, :]),
     "holds 4 wavelengths; Mitsuba's measured_polarized reads exactly 5"),
    (lambda f: f.update(wvls=f["wvls"].astype(np.float32)), "'wvls' must be 1-D uint16"),
    (lambda f: f.update(M=f["M"][..., :3]), "field 'M' must be float32 [9, 4, 5, 5, 4, 4]"),
    (lambda f: f.update(phi_d=np.linspace(0, np.pi, 9, dtype=np.float32)[None]), "'phi_d' must run from -pi to pi"),
    (lambda f: f.update(theta_h=f["theta_h"][:, ::-1].copy()), "strictly increasing"),
    (lambda f: f.pop("M"), "no field 'M'"),
])
def test_reader_refuses_what_mitsuba_would_misread_with_one_line(tmp_path, change, message):
    f = synthetic_fields()
    change(f)
    path = tmp_path / "bad.pbsdf"
    path.write_bytes(minimal_tensor(f))
    with pytest.raises(FormatError) as info:
        formats.FORMATS["pbsdf"].read(path)
    assert message in str(info.value) and "\n" not in str(info.value)


def test_writer_refuses_what_a_file_cannot_hold(tmp_path, ggx_table):
    out = tmp_path / "x.pbsdf"
    with pytest.raises(BrdftabError, match="not polarized"):
        brdftab.save(brdftab.models.create("microfacet", distribution="ggx", alpha=0.3, fresnel="schlick", f0=0.9), out, grid=GRID)
    with pytest.raises(ParameterError, match="exactly 5 wavelengths"):
        brdftab.save(GGXConductor(0.3, wavelengths=[450, 550, 650]), out, grid=GRID)
    with pytest.raises(ParameterError, match="whole nanometres"):
        brdftab.save(GGXConductor(0.3, wavelengths=[450, 500.5, 550, 600, 650]), out, grid=GRID)
    assert not out.exists()


def test_cli_converts_between_netcdf_and_pbsdf_and_refuses_in_one_line(tmp_path):
    small = RusinkiewiczGrid(8, 8, 16, phi_d_fold="none")
    ggx_table = tabulate(GGXConductor(0.3), small, polarized=True, progress=False)
    nc = tmp_path / "ggx.nc"
    brdftab.save(ggx_table, nc)
    pb = tmp_path / "ggx.pbsdf"
    result = cli("convert", nc, pb)
    assert result.exit_code == 0, result.output
    back = tmp_path / "back.nc"
    result = cli("convert", pb, back)
    assert result.exit_code == 0, result.output
    wi, wo = random_pairs(50, seed=5)
    a = ggx_table.eval_mueller(wi, wo)
    b = brdftab.open(back).eval_mueller(wi, wo)
    assert (np.abs(a - b) / a[..., :1, :1]).max() < 1e-6
    assert json.loads(brdftab.open(back).ds.attrs["parameters"]) == {"alpha": 0.3}
    # an unpolarized table cannot be written
    plain = tmp_path / "plain.nc"
    brdftab.save(brdftab.models.create("microfacet", distribution="ggx", alpha=0.3, fresnel="schlick", f0=0.9), plain, grid=small)
    proc = run("convert", plain, tmp_path / "plain.pbsdf")
    one_error(proc.stderr, proc.returncode, "not polarized")
    assert not (tmp_path / "plain.pbsdf").exists()


@pytest.mark.parametrize("grid", [RusinkiewiczGrid(9, 7, 12, phi_d_fold="none"),
                                  RusinkiewiczGrid(np.radians(np.arange(0, 91, 10.0)), np.radians(np.arange(0, 91, 10.0)),
                                                   12, phi_d_fold="none", sample_position="lower-edge")],
                         ids=["bin-centre", "nodes-at-0-90-and-180"])
def test_the_streamed_writer_writes_the_in_memory_writers_file(grid, tmp_path):
    from brdftab.formats.pbsdf import stream_pbsdf, write_pbsdf

    model = GGXConductor(0.3)
    write_pbsdf(tabulate(model, grid, polarized=True, progress=False), tmp_path / "a.pbsdf")
    slabs = []
    stream_pbsdf(model, grid, tmp_path / "b.pbsdf", progress=lambda done, total: slabs.append((done, total)))
    a, b = (parse_tensor((tmp_path / f"{x}.pbsdf").read_bytes()) for x in "ab")
    for k in ("theta_h", "theta_d", "phi_d", "wvls", "M"):
        assert a[k].dtype == b[k].dtype and np.array_equal(a[k], b[k]), k
    assert slabs[-1] == (a["M"].shape[0], a["M"].shape[0])
    with pytest.raises(BrdftabError, match="not polarized"):
        stream_pbsdf(brdftab.models.create("microfacet", distribution="ggx", alpha=0.3, fresnel="schlick", f0=0.9), grid, tmp_path / "c.pbsdf")


def test_a_spec_of_the_registrys_microfacet_model_tabulates_to_a_file_mitsuba_reads(polarized_variant, tmp_path):
    """The registry's own polarized model (``microfacet``, GGX α 0.3, conductor Fresnel with
    its facet-frame Mueller matrix) through a spec and ``brdftab tabulate`` to a ``.pbsdf``:
    Mitsuba's ``measured_polarized`` reads the file as the model's Mueller matrix (times cosθ,
    in Mitsuba's frame) at random directions and the five wavelengths, within the
    interpolation error of a 30 × 30 × 72 grid, and as its own polarized ``roughconductor``."""
    from brdftab import models
    from brdftab.cli import main

    spec = tmp_path / "rc.toml"
    spec.write_text('[model]\nname = "microfacet"\ndistribution = "ggx"\nalpha = 0.3\nfresnel = "conductor"\n'
                    'n = 0.2\nk = 3.0\n\n[grid]\ntype = "rusinkiewicz"\nn_theta_h = 30\nn_theta_d = 30\n'
                    'n_phi_d = 72\nphi_d_fold = "none"\n\n[[output]]\npath = "rc.pbsdf"\n')
    try:
        main(["tabulate", str(spec), "--no-progress"])
    except SystemExit as exc:
        assert exc.code in (0, None), exc.code
    bsdf = mi.load_dict({"type": "measured_polarized", "filename": str(tmp_path / "rc.pbsdf")})
    wi, wo = random_pairs(120, seed=11)
    got = mitsuba_mueller(bsdf, wi, wo, KAIST_NM)
    assert not np.isnan(got).any()
    model = models.create("microfacet", distribution="ggx", alpha=0.3, fresnel="conductor", n=0.2, k=3.0)
    ref = model.eval_mueller(wi, wo, KAIST_NM)
    m00 = np.abs(got[..., 0, 0] - ref[..., 0, 0]) / ref[..., 0, 0]
    norm = np.abs(got / got[..., :1, :1] - ref / ref[..., :1, :1]).max(axis=(-2, -1))
    rc = mitsuba_mueller(mi.load_dict({"type": "roughconductor", "distribution": "ggx", "alpha": 0.3, "eta": 0.2,
                                       "k": 3.0, "sample_visible": False}), wi, wo, KAIST_NM[:1])[:, 0]
    rc_norm = np.abs(got[:, 0] / got[:, 0, :1, :1] - rc / rc[..., :1, :1]).max(axis=(-2, -1))
    print(f"registry microfacet -> .pbsdf, Mitsuba vs model: median |dM00|/M00 {np.median(m00):.2g}, median max "
          f"|d(Mij/M00)| {np.median(norm):.2g} (vs roughconductor {np.median(rc_norm):.2g})")
    assert np.median(m00) < 0.008 and np.median(norm) < 1.2e-3 and np.median(rc_norm) < 1.2e-3  # 0.52 %, 7.8e-4
