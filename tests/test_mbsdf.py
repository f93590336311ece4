"""NVIDIA MDL ``.mbsdf`` files: the writer's bytes read by a minimal parser written here from the
published layout, values at cell centres placed by directions built here, float32 round trips,
``.mbsdf`` → netCDF → ``.mbsdf``, a real file from NVIDIA's MDL SDK, spec outputs validated
before export, refusals and damaged files.

Layout (formats.md §3, the MDL SDK's ``bsdf_measurement.cpp``): ``NVIDIA ARC MBSDF V1\\n``, metadata
lines, ``MBSDF_DATA_REFLECTION=\\n`` (or ``MBSDF_DATA=\\n``), uint32 type (0 scalar, 1 RGB),
res_theta, res_phi, float32 samples at index ``(i_in · res_theta + i_out) · res_phi + k`` (RGB
interleaved); sample (i, j, k) sits at θi = (i + ½)π/(2n), θo = (j + ½)π/(2n),
|φo − φi| = (k + ½)π/res_phi.
"""

from __future__ import annotations

import lzma
import struct
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import brdftab
from brdftab import formats, models, pipeline
from brdftab.convert import convert
from brdftab.errors import BrdftabError, BrdftabWarning, FormatError

from _cli import cli, one_error

GOLD = dict(n=[0.143119, 0.374957, 1.44248], k=[3.98316, 2.38572, 1.60322])
GGX = models.create("microfacet", distribution="ggx", alpha=0.2, shadowing="smith", fresnel="conductor", **GOLD)
#: NVIDIA MDL SDK examples/mdl/nvidia/sdk_examples/resources/example_modules.mbsdf (CC0 1.0, "MDL
#: Example Resources" in the SDK's LICENSE_IMAGES.md), xz-compressed; sha256 of the file below.
REAL = Path(__file__).parent / "data" / "mdl-sdk-example_modules.mbsdf.xz"
REAL_SHA256 = "106ae24a1faeddbf1e621b69856d82d0857eee6d4a7fbb9cbf19436c938832b2"
F32_ROUNDING = 2.0 ** -24  # round to nearest float32: relative error at most half an ulp


# -- an independent minimal parser and writer, from the published layout -------------------------------

def parse(data: bytes) -> dict:
    """The reflection block of an .mbsdf file: metadata lines, type, resolutions, samples[i, j, k, c]."""
    assert data.startswith(b"NVIDIA ARC MBSDF V1\n")
    lines = data.split(b"\n")
    meta, offset = [], len(lines[0]) + 1
    for line in lines[1:]:
        offset += len(line) + 1
        if line in (b"MBSDF_DATA_REFLECTION=", b"MBSDF_DATA="):
            break
        meta.append(line.decode())
    kind, rt, rp = struct.unpack("<III", data[offset:offset + 12])
    c = 3 if kind == 1 else 1
    n = rt * rt * rp * c
    samples = np.frombuffer(data[offset + 12:offset + 12 + 4 * n], "<f4")
    assert offset + 12 + 4 * n == len(data), "bytes after the reflection block"
    return {"meta": meta, "type": kind, "res": (rt, rp), "v": samples.reshape(rt, rt, rp, c)}


def build(values, meta=(), marker=b"MBSDF_DATA_REFLECTION=\n", transmission=None) -> bytes:
    """An .mbsdf file of ``values[i, j, k, c]`` (c = 1 or 3), written here from the layout."""
    def block(v):
        kind = 1 if v.shape[-1] == 3 else 0
        return struct.pack("<III", kind, v.shape[0], v.shape[2]) + np.ascontiguousarray(v, "<f4").tobytes()
    out = b"NVIDIA ARC MBSDF V1\n" + b"".join((m if isinstance(m, bytes) else m.encode()) + b"\n" for m in meta) + marker + block(values)
    if transmission is not None:
        out += b"MBSDF_DATA_TRANSMISSION=\n" + block(transmission)
    return out


def cell_pairs(i, j, k, n, m, rng, u=0.5):
    """(wi, wo) of cells (i, j, k) built here: θ = (i + u)π/(2n), Δφ = ±(k + u)π/m about a random φi
    (u = ½: the cell centres)."""
    ti = (np.asarray(i) + u) * np.pi / (2 * n)
    to = (np.asarray(j) + u) * np.pi / (2 * n)
    dphi = (np.asarray(k) + u) * np.pi / m * rng.choice([-1.0, 1.0], np.shape(i))
    pi_ = rng.uniform(0, 2 * np.pi, np.shape(i))
    po = pi_ + dphi
    sph = lambda t, p: np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1)  # noqa: E731
    return sph(ti, pi_), sph(to, po)


def random_cells(count, n, m, seed):
    rng = np.random.default_rng(seed)
    return rng.integers(0, n, count), rng.integers(0, n, count), rng.integers(0, m, count), rng


# -- the writer ----------------------------------------------------------------------------------------

@pytest.mark.parametrize("model, kind", [(GGX, 1), (models.create("lambert", albedo=0.6), 0)], ids=["rgb", "grey"])
def test_writer_cells_hold_the_model_at_cell_centres(tmp_path, model, kind):
    """The independent parser reads the writer's file; 40 cells hold f at their centres (directions
    built here) to float32 rounding; RGB is type 1, grey type 0; metadata lines are key="value"."""
    path = tmp_path / "m.mbsdf"
    brdftab.save(model, path, res_theta=12, res_phi=20)
    f = parse(path.read_bytes())
    assert f["type"] == kind and f["res"] == (12, 20)
    assert f["meta"] and all(len(x) < 1024 and x.count("=") >= 1 and x.split("=", 1)[1].startswith('"')
                             for x in f["meta"])
    assert any(x.startswith('quantity="f_r') for x in f["meta"])
    i, j, k, rng = random_cells(40, 12, 20, 1)
    wi, wo = cell_pairs(i, j, k, 12, 20, rng)
    want = model.eval(wi, wo)[:, :f["v"].shape[-1]]
    got = f["v"][i, j, k].astype(float)
    assert np.all(want > 0)
    assert np.max(np.abs(got - want) / want) <= F32_ROUNDING * (1 + 1e-9)


def test_round_trip_within_float32(tmp_path):
    """Reading back gives the written table's samples rounded to float32 (exactly), and at random
    pairs its interpolation within the stated precision (measured: 5.9e-8 < 2**-24)."""
    path = tmp_path / "g.mbsdf"
    table = brdftab.save(GGX, path, res_theta=16, res_phi=24)
    back = brdftab.open(path)
    assert back.grid.equals(table.grid) and back.channels == ("R", "G", "B")
    assert np.array_equal(back.values, np.asarray(table.values).astype(np.float32).astype(float))
    rng = np.random.default_rng(2)
    mu = rng.uniform(0.05, 1.0, (2, 5000))
    phi = rng.uniform(0, 2 * np.pi, (2, 5000))
    wi, wo = (np.stack([np.sqrt(1 - u ** 2) * np.cos(p), np.sqrt(1 - u ** 2) * np.sin(p), u], -1)
              for u, p in zip(mu, phi))
    a, b = table.eval(wi, wo), back.eval(wi, wo)
    rel = np.abs(b - a) / a
    assert rel.max() <= formats.FORMATS["mbsdf"].precision and rel.max() < 5.2e-8  # measured 5.15e-8
    assert formats.FORMATS["mbsdf"].precision == pytest.approx(F32_ROUNDING, rel=0.01)


def test_spectral_source_is_written_in_rgb_with_a_metadata_line(tmp_path):
    spec = models.create("lambert", albedo={"wavelengths_nm": [400, 500, 600, 700], "values": [0.2, 0.4, 0.5, 0.7]})
    path = tmp_path / "s.mbsdf"
    with warnings.catch_warnings():
        warnings.simplefilter("error", BrdftabWarning)  # the file records the conversion: no warning
        brdftab.save(spec, path, res_theta=4, res_phi=4)
    f = parse(path.read_bytes())
    assert f["type"] == 1
    assert any(x.startswith('colour="') and "4 wavelengths (400-700 nm)" in x for x in f["meta"])
    v = f["v"].reshape(-1, 3)
    assert np.all(v == v[0]) and 0.4 / np.pi < v[0, 0] < 0.7 / np.pi  # constant, a reddish grey


def test_anisotropic_and_non_reciprocal_sources_are_refused_unless_averaged(tmp_path):
    from _measured import Asymmetric

    aniso = models.create("microfacet", alpha_x=0.1, alpha_y=0.4)
    with pytest.raises(FormatError, match="anisotropic; pass phi_h_average") as e:
        brdftab.save(aniso, tmp_path / "a.mbsdf", res_theta=4, res_phi=6)
    assert "\n" not in str(e.value) and not (tmp_path / "a.mbsdf").exists()
    brdftab.save(aniso, tmp_path / "a.mbsdf", res_theta=4, res_phi=6, phi_h_average=8)
    assert parse((tmp_path / "a.mbsdf").read_bytes())["res"] == (4, 6)

    skew = Asymmetric(models.create("lambert", albedo=0.5), 0.6)
    with pytest.raises(FormatError, match="not reciprocal.*symmetrize = true"):
        brdftab.save(skew, tmp_path / "r.mbsdf", res_theta=6, res_phi=4)
    brdftab.save(skew, tmp_path / "r.mbsdf", res_theta=6, res_phi=4, symmetrize=True)
    v = parse((tmp_path / "r.mbsdf").read_bytes())["v"]
    # the reciprocal part of base·(1 + a(cosθi − cosθo)) is the base, 0.5/π
    np.testing.assert_allclose(v, 0.5 / np.pi, rtol=F32_ROUNDING, atol=0)


def test_spec_output_tabulates_to_mbsdf_validated_before_export(tmp_path):
    """A spec's [[output]] path = "x.mbsdf" (the ggx-gold seed model) is tabulated on the .mbsdf grid and
    validated as stored; a model finite in float64 but beyond float32 is refused (exit 1, no file)."""
    seed = Path(__file__).parents[1].joinpath("specs", "ggx-gold.toml").read_text().split("[grid]")[0]
    spec = tmp_path / "gold.toml"
    spec.write_text(seed + '[grid]\ntype = "merl"\n[[output]]\npath = "gold.mbsdf"\nres_theta = 32\nres_phi = 64\n')
    result = pipeline.run(brdftab.load_spec(spec), progress=False)
    f = parse((tmp_path / "gold.mbsdf").read_bytes())
    assert f["type"] == 1 and f["res"] == (32, 64)
    assert 'model="microfacet"' in f["meta"]
    statuses = {o.name: o.status for o in result.report.outcomes}
    assert statuses["finite"] == "pass" and statuses["energy"] == "pass" and statuses["reciprocity"] == "pass"
    tab = result.report.get("tabulation")
    assert tab.status == "pass" and "rms relative error of f cosθi cosθo 0.0101 " in tab.detail
    coarse = tmp_path / "coarse.toml"
    coarse.write_text(spec.read_text().replace("gold.mbsdf", "coarse.mbsdf").replace("res_theta = 32\nres_phi = 64",
                                                                                    "res_theta = 10\nres_phi = 16"))
    with pytest.raises(BrdftabError, match="mbsdf samples misrepresent the model microfacet"):
        pipeline.run(brdftab.load_spec(coarse), progress=False)
    assert not (tmp_path / "coarse.mbsdf").exists()

    big = tmp_path / "big.toml"
    big.write_text('[model]\nname = "scale"\nfactor = 2e40\n[model.term]\nname = "lambert"\nalbedo = 0.5\n'
                   '[grid]\ntype = "merl"\n[[output]]\npath = "big.mbsdf"\nres_theta = 4\nres_phi = 4\n')
    r = cli("tabulate", big, "--level", "energy=off")
    assert r.exit_code == 1, r.stderr
    assert "finite: 64 of 64 samples are NaN or infinite (0 NaN, 64 infinite)" in r.stderr
    assert not (tmp_path / "big.mbsdf").exists()


# -- the reader ----------------------------------------------------------------------------------------

def test_reader_places_file_values_at_cell_centres(tmp_path):
    """A file written here with distinct values: the table evaluates each of 60 cells at its centre
    (random φi, either sign of Δφ) to exactly the file's number; attributes say what was read."""
    rng = np.random.default_rng(4)
    n, m = 7, 11
    v = rng.uniform(0.01, 3.0, (n, n, m, 3)).astype(np.float32)
    path = tmp_path / "x.mbsdf"
    path.write_bytes(build(v, meta=['description="a test file"', "free text = as it comes"]))
    t = brdftab.open(path)
    assert t.channels == ("R", "G", "B") and t.origin == "unknown" and t.isotropic
    assert not t.reciprocal and "reciprocal" not in t.ds.attrs  # reciprocity is not declared
    assert t.ds.attrs["mbsdf_metadata"] == 'description="a test file"\nfree text = as it comes\n'
    assert t.ds.attrs["source_quantity"].startswith("f_r [sr-1] as stored")
    i, j, k, rng = random_cells(60, n, m, 5)
    wi, wo = cell_pairs(i, j, k, n, m, rng)
    np.testing.assert_allclose(t.eval(wi, wo), v[i, j, k].astype(float), rtol=1e-12, atol=0)
    # between a domain edge and the first or last cell centre the table holds the end value (θ
    # and Δφ within the first or last half cell), as the MDL runtime's clamped lookup does
    zero, last = np.zeros(60, int), np.full(60, n - 1)
    np.testing.assert_allclose(t.eval(*cell_pairs(zero, zero, zero, n, m, rng, u=0.2)),
                               np.broadcast_to(v[0, 0, 0], (60, 3)), rtol=1e-12)
    np.testing.assert_allclose(t.eval(*cell_pairs(last, last, zero + m - 1, n, m, rng, u=0.9)),
                               np.broadcast_to(v[-1, -1, -1], (60, 3)), rtol=1e-12)
    grey = build(v[..., :1], marker=b"MBSDF_DATA=\n")
    (tmp_path / "g.mbsdf").write_bytes(grey)
    g = brdftab.open(tmp_path / "g.mbsdf")
    assert g.channels == ("mono",) and g.ds.attrs["mbsdf_data_marker"] == "MBSDF_DATA="
    assert np.array_equal(g.values[:, 0, ..., 0], v[..., 0])


def texture_lookup(v, wi, wo):
    """The MDL SDK runtime's lookup, written here from its published form: u = Δφ/π (Δφ = φo − φi
    folded into [0, π]), v = θo/(π/2), w = θi/(π/2) into a 3-D texture of cell-centred texels with
    linear filtering and clamped addressing (exact weights: CUDA's 8-bit ones aside)."""
    n, m = v.shape[0], v.shape[2]
    ti, to = np.arccos(wi[:, 2]), np.arccos(wo[:, 2])
    d = np.mod(np.arctan2(wo[:, 1], wo[:, 0]) - np.arctan2(wi[:, 1], wi[:, 0]), 2 * np.pi)
    d = np.where(d > np.pi, 2 * np.pi - d, d)
    out = np.zeros((len(wi), v.shape[3]))
    texel = []
    for coord, size in ((ti / (np.pi / 2), n), (to / (np.pi / 2), n), (d / np.pi, m)):
        x = np.clip(coord * size - 0.5, 0.0, size - 1)
        lo = np.minimum(np.floor(x).astype(int), max(size - 2, 0))
        texel.append((lo, np.minimum(lo + 1, size - 1), x - lo))
    (a0, a1, fa), (b0, b1, fb), (c0, c1, fc) = texel
    for ia, wa in ((a0, 1 - fa), (a1, fa)):
        for ib, wb in ((b0, 1 - fb), (b1, fb)):
            for ic, wc in ((c0, 1 - fc), (c1, fc)):
                out += (wa * wb * wc)[:, None] * v[ia, ib, ic]
    return out


def test_table_evaluates_as_the_mdl_runtime_lookup(tmp_path):
    """Between the cell centres too: a table read from a file evaluates, at 3000 random pairs over
    the whole hemisphere (grazing ones included), as the runtime's trilinear, clamped texture lookup."""
    rng = np.random.default_rng(9)
    v = rng.uniform(0.01, 2.0, (6, 6, 10, 3)).astype(np.float32)
    path = tmp_path / "l.mbsdf"
    path.write_bytes(build(v))
    t = brdftab.open(path)
    mu = rng.uniform(1e-3, 1.0, (2, 3000))
    phi = rng.uniform(-np.pi, np.pi, (2, 3000))
    wi, wo = (np.stack([np.sqrt(1 - x ** 2) * np.cos(p), np.sqrt(1 - x ** 2) * np.sin(p), x], -1)
              for x, p in zip(mu, phi))
    np.testing.assert_allclose(t.eval(wi, wo), texture_lookup(v.astype(float), wi, wo), rtol=1e-12, atol=0)


@pytest.mark.parametrize("store", [".nc", ".zarr"])
def test_mbsdf_to_netcdf_and_back_is_byte_identical(tmp_path, store):
    """.mbsdf → .nc (or .zarr) → .mbsdf keeps every byte (metadata lines, the older data marker,
    float32 samples); the netCDF or zarr table evaluates exactly as the .mbsdf reader's."""
    rng = np.random.default_rng(6)
    for marker, c in ((b"MBSDF_DATA_REFLECTION=\n", 3), (b"MBSDF_DATA=\n", 1)):
        v = rng.uniform(0.0, 2.0, (5, 5, 8, c)).astype(np.float32)
        src = tmp_path / "src.mbsdf"
        meta = ['description="round trip"', 'quoted="a \\"b\\" c"', ""] if c == 3 else [b'name="caf\xe9"', ""]  # Latin-1, an empty line
        src.write_bytes(build(v, meta=meta, marker=marker))
        nc, back = tmp_path / f"t{store}", tmp_path / "back.mbsdf"
        convert(src, nc, overwrite=True, progress=False)
        convert(nc, back, overwrite=True, progress=False)
        assert back.read_bytes() == src.read_bytes()
        a, b = brdftab.open(src), brdftab.open(nc)
        assert b.grid.equals(a.grid) and b.grid.phi_d_fold == "bilateral"
        assert [x.domain for x in b.grid.axes] == [x.domain for x in a.grid.axes]
        i, j, k, rng2 = random_cells(200, 5, 8, 7)
        wi, wo = cell_pairs(i, j, k, 5, 8, rng2)
        wo = wo + 0.05 * rng2.normal(size=wo.shape)  # between nodes too
        wo[:, 2] = np.abs(wo[:, 2])
        assert np.array_equal(a.eval(wi, wo), b.eval(wi, wo))


def test_real_file_from_the_mdl_sdk(tmp_path):
    """NVIDIA's example_modules.mbsdf (RGB, 45 x 45 x 90): read, validated and converted to netCDF;
    30 cells evaluate to the file's numbers (offsets computed here from the layout) at centre
    directions built here; .mbsdf → .nc → .mbsdf gives the file back byte for byte."""
    import hashlib

    data = lzma.decompress(REAL.read_bytes())
    assert hashlib.sha256(data).hexdigest() == REAL_SHA256
    src = tmp_path / "example_modules.mbsdf"
    src.write_bytes(data)
    t = brdftab.open(src)
    assert t.values.shape == (45, 1, 45, 90, 3) and t.origin == "unknown"
    head = data.index(b"MBSDF_DATA_REFLECTION=\n") + len(b"MBSDF_DATA_REFLECTION=\n")
    assert struct.unpack("<III", data[head:head + 12]) == (1, 45, 90)
    i, j, k, rng = random_cells(30, 45, 90, 8)
    want = np.array([struct.unpack_from("<3f", data, head + 12 + 12 * ((a * 45 + b) * 90 + c))
                     for a, b, c in zip(i, j, k)])
    wi, wo = cell_pairs(i, j, k, 45, 90, rng)
    np.testing.assert_allclose(t.eval(wi, wo), want, rtol=1e-12, atol=0)
    nc = tmp_path / "example_modules.nc"
    conv = convert(src, nc, progress=False)
    status = {r.name: r.status for r in conv.report.outcomes}
    assert status["finite"] == "pass" and status["energy"] == "pass" and "fail" not in status.values()
    assert status["non-negative"] == "warn"  # 480 measured samples below 0: reported, not refused
    recip = next(r for r in conv.report.outcomes if r.name == "reciprocity")
    assert recip.status == "warn" and recip.data["mode"] == "nodes" and recip.figure == pytest.approx(0.0911, abs=5e-5)
    energy = next(r for r in conv.report.outcomes if r.name == "energy")
    assert "white-sky albedo 0.2012, 0.176, 0.1372" in energy.detail  # the domain reaches θi = 0
    assert np.array_equal(brdftab.open(nc).values, t.values)
    back = tmp_path / "back.mbsdf"
    convert(nc, back, progress=False)
    assert back.read_bytes() == data


def test_transmission_block_is_skipped_with_a_warning(tmp_path):
    v = np.full((3, 3, 4, 1), 0.25, np.float32)
    path = tmp_path / "rt.mbsdf"
    path.write_bytes(build(v, transmission=np.ones((2, 2, 5, 3), np.float32)))
    with pytest.warns(BrdftabWarning, match=r"transmission block \(RGB, 2 x 2 x 5\) skipped"):
        t = brdftab.open(path)
    assert np.all(t.values == 0.25)
    only = tmp_path / "t.mbsdf"
    only.write_bytes(b"NVIDIA ARC MBSDF V1\nMBSDF_DATA_TRANSMISSION=\n" + build(v)[44:])
    with pytest.raises(FormatError, match="transmission data only"):
        brdftab.open(only)


def _damaged():
    good = build(np.ones((2, 2, 3, 1), np.float32), meta=['description="x"'])
    marker = good.index(b"MBSDF_DATA_REFLECTION=\n") + len(b"MBSDF_DATA_REFLECTION=\n")

    def header(kind, rt, rp):
        return good[:marker] + struct.pack("<III", kind, rt, rp) + good[marker + 12:]
    return [
        ("truncated", good[:-5], "truncated .mbsdf file"),
        ("header cut", good[:marker + 6], "has 6 of its 12 header bytes"),
        ("bad magic", b"NVIDIA ARC MBSDF V2\n" + good[20:], "not an NVIDIA MDL .mbsdf file"),
        ("crlf", good.replace(b"\n", b"\r\n", 2)[:len(good) + 2], "CRLF"),
        ("type 2", header(2, 2, 3), "of type 2"),
        ("zero resolution", header(0, 0, 3), "res_theta = 0"),
        ("trailing bytes", good + b"\0\0\0\0", "4 bytes after the reflection block"),
        ("count overflows the file", header(1, 65535, 65535), f"needs {4 * 3 * 65535 ** 3:,} bytes"),
        ("no data", b"NVIDIA ARC MBSDF V1\ndescription=\"x\"\n", "without reflection data"),
    ]


@pytest.mark.parametrize("name, content, message", _damaged(), ids=[d[0] for d in _damaged()])
def test_damaged_files_give_one_line_naming_the_file(tmp_path, name, content, message):
    path = tmp_path / "bad.mbsdf"
    path.write_bytes(content)
    with pytest.raises(FormatError) as e:
        brdftab.open(path)
    text = str(e.value)
    assert "\n" not in text and text.startswith(str(path)) and message in text, text


def test_damaged_file_on_the_command_line(tmp_path):
    path = tmp_path / "bad.mbsdf"
    path.write_bytes(_damaged()[4][1])
    r = cli("info", path)
    one_error(r.stderr, r.exit_code, "bad.mbsdf", "of type 2")


def test_formats_command_says_what_the_writer_writes():
    r = cli("formats", "mbsdf")
    assert r.exit_code == 0, r.output
    assert "f_r [sr-1, no cosine] at cell centres" in r.stdout
    assert "stores spherical theta_i[45] x phi_i[1] x theta_o[45] x phi_o[90]" in r.stdout
    for key in ("res_theta", "res_phi", "phi_h_average", "symmetrize", "illuminant"):
        assert f"  {key}:" in r.stdout


def test_options_are_checked(tmp_path):
    with pytest.raises(BrdftabError, match="res_theta"):
        brdftab.save(GGX, tmp_path / "x.mbsdf", res_theta=0)
    with pytest.raises(BrdftabError, match="did you mean 'res_phi'"):
        brdftab.save(GGX, tmp_path / "x.mbsdf", res_ph=3)
    assert not (tmp_path / "x.mbsdf").exists()


@settings(deadline=None, database=None, max_examples=150, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.lists(st.tuples(st.integers(0, 400), st.integers(0, 255)), max_size=6), st.integers(0, 400),
       st.binary(max_size=8))
def test_mutated_files_give_a_table_or_one_line(tmp_path, edits, cut, tail):
    """Random byte changes, a cut and appended bytes: a table or one brdftab error line naming the file."""
    data = bytearray(build(np.arange(2 * 2 * 3 * 3, dtype=np.float32).reshape(2, 2, 3, 3) / 7,
                           meta=['description="x"']))
    for pos, byte in edits:
        data[pos % len(data)] = byte
    content = bytes(data[:max(cut, len(data) - 40)]) + tail
    path = tmp_path / "fuzz.mbsdf"
    path.write_bytes(content)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", BrdftabWarning)
            t = brdftab.open(path)
            t.values
    except BrdftabError as exc:
        assert "\n" not in str(exc) and str(path) in str(exc), str(exc)
