"""Mitsuba 3 / RGL tabulated ``.bsdf`` files: brdftab's writer and reader against Mitsuba itself.

Independent references used here:

* Mitsuba 3's ``measured`` plugin (``scalar_rgb``, ``scalar_spectral``) loads our files; its
  ``eval`` is compared with the analytic source model (f·cosθo) and with brdftab's reader;
  its ``sample`` gives the directional albedo, compared with brdftab's hemisphere quadrature
  of the analytic model;
* Mitsuba's own Python ``tensor_io`` reads our container;
* the microfacet D and Smith Λ of :mod:`brdftab.models.distributions` (closed forms) check the
  ``ndf`` and ``sigma`` tables and the power-iteration NDF.

Every accuracy number of formats/rgl-bsdf.md (and of the docstrings in brdftab/formats/rgl*.py)
is asserted by a test here, which names the claim; the tests print what they measure
(``pytest -s tests/test_rgl.py``), and the documented "measured" values are those lines.

Mitsuba is a declared test dependency: it is imported unconditionally, and a missing variant
fails the run. Directions are rounded to float32 before both libraries see them.
"""

from __future__ import annotations

import importlib
import json
import struct
from pathlib import Path

import mitsuba as mi
import numpy as np
from _directions import direction_pairs as shared_pairs
from _directions import f32 as _f32
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import brdftab
from brdftab import formats
from brdftab.brdf import BRDF
from brdftab.channels import Layout
from brdftab.errors import BrdftabError, FormatError, ParameterError
from brdftab.formats import rgl
from brdftab.formats._tensor import encode_tensor, parse_tensor
from brdftab.models.distributions import d_ggx, lambda_ggx
from _quadrature import fixed_albedo as directional_albedo

# Both variants must exist: fail loudly at import otherwise.
for _variant in ("scalar_rgb", "scalar_spectral"):
    assert _variant in mi.variants(), f"Mitsuba variant {_variant} is missing"
if mi.variant() is None:
    mi.set_variant("scalar_rgb")

MIN_COS = 0.05
N_PAIRS = 600


def create(name, **kw):
    return brdftab.models.create(name, **kw)


def recipe_model():
    """GGX α = 0.3 with Schlick F0 = (0.9, 0.6, 0.3) and height-correlated G2, plus Lambert."""
    return create("sum", terms=[
        create("lambert", albedo=[0.05, 0.1, 0.2]),
        create("microfacet", alpha=0.3, fresnel="schlick", f0=[0.9, 0.6, 0.3], shadowing="smith-height-correlated"),
    ])


def direction_pairs(seed, alpha_x, alpha_y, n=N_PAIRS):
    """Seeded pairs with cosθ >= MIN_COS, half near the mirror direction (see _directions);
    renormalized after float32 rounding so both libraries see the same unit vectors."""
    return shared_pairs(seed, alpha_x, alpha_y, n, MIN_COS, renormalize=True)


def mitsuba_eval(path, wi, wo, wavelengths=None):
    """Mitsuba's ``measured`` eval (f·cosθo) in the current variant, ``[N, channels]``."""
    bsdf = mi.load_dict({"type": "measured", "filename": str(path)})
    ctx, si = mi.BSDFContext(), mi.SurfaceInteraction3f()
    if wavelengths is not None:
        si.wavelengths = mi.Spectrum(*[float(x) for x in wavelengths])
    out = []
    for a, b in zip(wi, wo):
        si.wi = mi.Vector3f(*a)
        out.append(np.array(bsdf.eval(ctx, si, mi.Vector3f(*b)), dtype=np.float64))
    return np.array(out)


def mitsuba_albedo(path, wi, n=64):
    """∫ f cosθo dωo by Mitsuba's own importance sampling (n × n stratified samples)."""
    bsdf = mi.load_dict({"type": "measured", "filename": str(path)})
    ctx, si = mi.BSDFContext(), mi.SurfaceInteraction3f()
    si.wi = mi.Vector3f(*wi)
    g = (np.arange(n) + 0.5) / n
    acc = np.zeros(3)
    for a in g:
        for b in g:
            _, weight = bsdf.sample(ctx, si, 0.5, mi.Point2f(float(a), float(b)))
            acc += np.array(weight, dtype=np.float64)
    return acc / (n * n)


def rel_errors(got, ref, small):
    big = np.abs(ref) > small
    assert big.mean() > 0.5, f"only {big.mean():.0%} of the reference values exceed {small}"
    return np.abs(got[big] - ref[big]) / np.abs(ref[big]), np.abs(got[~big] - ref[~big])


def assert_percentiles(label, rel, bounds):
    """Each percentile q of ``rel`` (fractions) below ``bounds[q]``; prints what it measured
    (``pytest -s``): the numbers of formats/rgl-bsdf.md come from these lines."""
    got = {q: float(np.percentile(rel, q)) for q in bounds}
    print(f"{label} (n = {rel.size}): " + ", ".join(f"p{q} {100 * v:.2f} %" for q, v in got.items()))
    bad = {f"p{q}": f"{100 * v:.2f} % >= {100 * bounds[q]:g} %" for q, v in got.items() if not v < bounds[q]}
    assert not bad, f"{label}: {bad}"


def assert_reader_is_mitsuba(ours, ref):
    """brdftab's reader against Mitsuba's eval of the same file: below 5e-5 relative (float32
    arithmetic in Mitsuba, float64 here) and 1e-6 absolute where Mitsuba's value is tiny."""
    rel, absolute = rel_errors(ours, ref, 1e-6)
    print(f"reader vs Mitsuba: max relative {rel.max():.2g}")
    assert rel.max() < 5e-5, f"our reader vs Mitsuba: max relative error {rel.max():.3g}"
    assert np.max(absolute, initial=0.0) < 1e-6


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    return tmp_path_factory.mktemp("rgl")


@pytest.fixture(scope="module")
def rgb_file(files):
    """The recipe model written with the default options."""
    path = files / "recipe.bsdf"
    brdftab.save(recipe_model(), path)
    return path


# ---------------------------------------------------------------------------------------------
# Mitsuba accepts our files and evaluates them like the source model


def test_mitsuba_rgb_matches_model_and_our_reader(rgb_file):
    model = recipe_model()
    wi, wo = direction_pairs(1, 0.3, 0.3)
    with mi.variant_context("scalar_rgb"):
        ref = mitsuba_eval(rgb_file, wi, wo)
    analytic = model.eval(wi, wo) * wo[:, 2:3]
    rel, _ = rel_errors(ref, analytic, 1e-4)
    # formats/rgl-bsdf.md, Guarantees, table row "GGX α = 0.3 ... RGB"
    assert_percentiles("recipe RGB, Mitsuba vs model", rel, {50: 0.002, 75: 0.005, 90: 0.012, 95: 0.03})

    ours = brdftab.open(rgb_file)
    assert isinstance(ours, rgl.RGLBSDF) and ours.isotropic and ours.channels == ("R", "G", "B")
    assert_reader_is_mitsuba(ours.eval_cos(wi, wo), ref)  # formats/rgl-bsdf.md: "evaluates like Mitsuba"


def file_albedo(bsdf, wi, n=300):
    """∫ f·cosθo dωo of a file as Mitsuba evaluates it (``eval_cos``, no hold): Gauss–Legendre
    in cosθo × the midpoint rule in φo."""
    from brdftab.quadrature import gauss_legendre

    mu, wmu = gauss_legendre(n, 0.0, 1.0)
    ph = (np.arange(2 * n) + 0.5) * np.pi / n
    wo = rgl.sph(np.arccos(mu)[:, None], ph[None, :]).reshape(-1, 3)
    w = (wmu[:, None] * np.full(2 * n, np.pi / n)).ravel()
    return bsdf.eval_cos(np.broadcast_to(wi, wo.shape), wo).T @ w


def test_mitsuba_albedo_matches_quadrature_of_the_model(rgb_file):
    """Mitsuba's sample() (luminance and vndf warps of our file, 64 × 64 stratified samples)
    integrates to the file's own albedo (a fine quadrature of its eval) and to the model's
    (formats/rgl-bsdf.md, Guarantees, "Albedo"). brdftab's reader, which holds f beyond
    θ_hold, gives the model's albedo too."""
    model = recipe_model()
    ours = brdftab.open(rgb_file)
    sampling, tabulation, total, held = [], [], [], []
    for theta in np.radians([20.0, 47.0, 70.0]):  # 47° lies between two stored θi
        wi = _f32([np.sin(theta), 0.0, np.cos(theta)])
        with mi.variant_context("scalar_rgb"):
            got = mitsuba_albedo(rgb_file, wi)
        ref = directional_albedo(model, wi, lobe_width=0.3, n_theta=128, n_phi=128)
        own = file_albedo(ours, wi)
        sampling.append(got / own - 1)
        tabulation.append(own / ref - 1)
        total.append(got / ref - 1)
        held.append(directional_albedo(ours, wi, n_theta=128, n_phi=256) / ref - 1)
    for label, err, bound in (("Mitsuba's sampled albedo vs the file's", sampling, 0.005),
                              ("the file's albedo vs the model's", tabulation, 0.002),
                              ("Mitsuba's sampled albedo vs the model's", total, 0.005),
                              ("albedo of brdftab's reader (held f) vs the model's", held, 0.002)):
        err = np.array(err)
        print(f"{label}: {np.array2string(100 * err, precision=2)} %")
        assert np.all(np.abs(err) < bound), (label, err)


def spectral_model():
    lam = [400.0, 450.0, 500.0, 550.0, 600.0, 650.0, 700.0]
    return create("sum", terms=[
        create("lambert", albedo={"wavelengths_nm": lam, "values": [0.2, 0.17, 0.15, 0.12, 0.1, 0.07, 0.05]}),
        create("microfacet", alpha=0.3, fresnel="schlick",
               f0={"wavelengths_nm": lam, "values": [0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9]}),
    ])


def test_mitsuba_spectral_matches_model_and_our_reader(files):
    model = spectral_model()
    path = files / "spectral.bsdf"
    brdftab.save(model, path)
    raw = parse_tensor(path.read_bytes())
    assert "rgb" not in raw and raw["spectra"].shape == (1, 17, 7, 48, 48)
    np.testing.assert_array_equal(raw["wavelengths"], np.float32([400, 450, 500, 550, 600, 650, 700]))

    wi, wo = direction_pairs(2, 0.3, 0.3, n=500)
    lam = [425.0, 500.0, 555.0, 690.0]  # on and between the stored wavelengths
    with mi.variant_context("scalar_spectral"):
        ref = mitsuba_eval(path, wi, wo, lam)
    analytic = model.eval(wi, wo, lam) * wo[:, 2:3]
    rel, _ = rel_errors(ref, analytic, 1e-4)
    # formats/rgl-bsdf.md, Guarantees, table row "the same, spectral"
    assert_percentiles("recipe spectral, Mitsuba vs model", rel, {50: 0.002, 75: 0.005, 90: 0.012, 95: 0.02})
    ours = brdftab.open(path)
    assert ours.spectral and ours.channels is None
    assert_reader_is_mitsuba(ours.eval_cos(wi, wo, lam), ref)
    with pytest.raises(ParameterError, match="outside the file's wavelengths"):
        ours.eval(wi[:1], wo[:1], [380.0])


def test_mitsuba_refuses_the_other_kind_of_file(rgb_file, files):
    """An RGB file holds 'rgb' and no 'wavelengths' (RGB variants only) and a spectral file the
    opposite: Mitsuba itself tells them apart."""
    path = files / "spectral-only.bsdf"
    brdftab.save(spectral_model(), path, resolution=8, n_theta_i=3)
    with mi.variant_context("scalar_rgb"):
        mi.load_dict({"type": "measured", "filename": str(rgb_file)})
        with pytest.raises(RuntimeError, match="spectral"):
            mi.load_dict({"type": "measured", "filename": str(path)})
    with mi.variant_context("scalar_spectral"):
        mi.load_dict({"type": "measured", "filename": str(path)})
        with pytest.raises(RuntimeError, match="RGB"):
            mi.load_dict({"type": "measured", "filename": str(rgb_file)})


def test_mitsuba_anisotropic_matches_model_and_our_reader(files):
    """φi spans [−π, π]; Mitsuba's alpha_u/alpha_v convention is brdftab's alpha_x/alpha_y."""
    model = create("microfacet", alpha_x=0.15, alpha_y=0.4, fresnel="schlick", f0=[0.9, 0.6, 0.3])
    path = files / "aniso.bsdf"
    brdftab.save(model, path)
    raw = parse_tensor(path.read_bytes())
    assert raw["phi_i"].size == 17 and raw["phi_i"][0] == np.float32(-np.pi) and raw["phi_i"][-1] == np.float32(np.pi)
    assert raw["ndf"].shape == (256, 128)
    wi, wo = direction_pairs(3, 0.15, 0.4, n=500)
    with mi.variant_context("scalar_rgb"):
        ref = mitsuba_eval(path, wi, wo)
    analytic = model.eval(wi, wo) * wo[:, 2:3]
    rel, _ = rel_errors(ref, analytic, 1e-4)
    # formats/rgl-bsdf.md, Guarantees, table row "GGX αx = 0.15, αy = 0.4"
    assert_percentiles("GGX 0.15/0.4, Mitsuba vs model", rel, {50: 0.0025, 75: 0.01, 90: 0.05, 95: 0.09})
    swapped = create("microfacet", alpha_x=0.4, alpha_y=0.15, fresnel="schlick", f0=[0.9, 0.6, 0.3])
    rel_sw, _ = rel_errors(ref, swapped.eval(wi, wo) * wo[:, 2:3], 1e-4)
    assert np.median(rel_sw) > 0.1  # the test tells the axes apart
    ours = brdftab.open(path)
    assert not ours.isotropic
    assert_reader_is_mitsuba(ours.eval_cos(wi, wo), ref)


def test_narrow_anisotropic_lobe(files):
    """GGX αx = 0.05, αy = 0.3, default options (formats/rgl-bsdf.md, Guarantees, "Narrow
    anisotropic lobes"): Mitsuba's eval against the model, split where the tail begins (either
    direction beyond 80°). The 256 φ rows of the ndf table carry the median: with 64 rows it is
    4× larger."""
    model = create("microfacet", alpha_x=0.05, alpha_y=0.3, fresnel="schlick", f0=[0.9, 0.6, 0.3])
    path = files / "narrow.bsdf"
    brdftab.save(model, path)
    wi, wo = direction_pairs(11, 0.05, 0.3, n=600)
    with mi.variant_context("scalar_rgb"):
        ref = mitsuba_eval(path, wi, wo)
    analytic = model.eval(wi, wo) * wo[:, 2:3]
    big = np.abs(analytic) > 1e-4 * np.abs(analytic).max()
    rel = np.where(big, np.abs(ref - analytic) / np.where(big, analytic, 1.0), np.nan)
    steep = (np.minimum(wi[:, 2], wo[:, 2]) < np.cos(np.radians(80.0)))[:, None] & big
    assert_percentiles("narrow lobe, all pairs", rel[big], {50: 0.003, 95: 0.05})
    assert_percentiles("narrow lobe, θi, θo <= 80°", rel[big & ~steep], {50: 0.0025, 75: 0.005, 95: 0.013})
    assert_percentiles("narrow lobe, θi or θo > 80°", rel[steep], {50: 0.017, 95: 0.2})
    coarse = rgl.RGLBSDF(rgl.prepare_rgl(model, ndf_phi_resolution=64).fields)
    rel64 = np.abs(coarse.eval_cos(wi, wo) - analytic)[big] / analytic[big]
    print(f"narrow lobe, median with 64 ndf rows / with 256: {np.median(rel64) / np.median(rel[big]):.1f}")
    assert np.median(rel64) > 3 * np.median(rel[big])


def grazing_pairs(seed, which, lo, hi, n=400):
    """``n`` pairs with θo (``which = "o"``) or θi (``"i"``) uniform in [lo, hi] degrees and
    the other direction uniform over cosθ >= MIN_COS; float32-exact unit vectors."""
    rng = np.random.default_rng(seed)
    steep = rgl.sph(np.radians(rng.uniform(lo, hi, n)), rng.uniform(-np.pi, np.pi, n))
    c = rng.uniform(MIN_COS, 1.0, n)
    other = rgl.sph(np.arccos(c), rng.uniform(-np.pi, np.pi, n))
    wi, wo = (other, steep) if which == "o" else (steep, other)
    wi, wo = _f32(wi), _f32(wo)
    return wi / np.linalg.norm(wi, axis=-1, keepdims=True), wo / np.linalg.norm(wo, axis=-1, keepdims=True)


#: formats/rgl-bsdf.md, Guarantees, "Grazing directions": (direction, band in degrees) ->
#: tested bounds of the relative error of Mitsuba's f·cosθo, per source model.
GRAZING_BOUNDS = {
    ("o", 80.0, 87.0): {"recipe": {50: 0.02, 95: 0.09}, "lambert": {50: 0.005, 95: 0.03}},
    ("o", 87.0, 89.5): {"recipe": {50: 0.18, 95: 1.5}, "lambert": {50: 0.03, 95: 0.35}},
    ("i", 80.0, 87.0): {"recipe": {50: 0.002, 95: 0.03}, "lambert": {50: 0.002, 95: 0.02}},
    ("i", 87.0, 89.9): {"recipe": {50: 0.002, 95: 0.045}, "lambert": {50: 0.002, 95: 0.045}},
}


@pytest.mark.parametrize("source", ["recipe", "lambert"])
def test_grazing_directions(files, rgb_file, source):
    """Mitsuba's eval of our files against the model in bands of grazing θo and θi (the other
    direction uniform over cosθ >= 0.05). Grazing ωo is the format's weak spot: f·cosθo -> 0
    at the horizon, but the cell of N × N samples that straddles it interpolates towards a node
    below it, which stores 0. Grazing ωi alone (ωo within 70° of the normal) is accurate."""
    if source == "recipe":
        model, path = recipe_model(), rgb_file
    else:
        model, path = create("lambert", albedo=[0.2, 0.5, 0.8]), files / "lambert-grazing.bsdf"
        brdftab.save(model, path)
    for (which, lo, hi), bounds in GRAZING_BOUNDS.items():
        wi, wo = grazing_pairs(21 if which == "o" else 22, which, lo, hi)
        with mi.variant_context("scalar_rgb"):
            ref = mitsuba_eval(path, wi, wo)
        analytic = model.eval(wi, wo) * wo[:, 2:3]
        big = np.abs(analytic) > 1e-4 * np.abs(analytic).max()
        rel = np.abs(ref - analytic)[big] / analytic[big]
        assert_percentiles(f"{source}, θ{which} in [{lo:g}, {hi:g}]°", rel, bounds[source])
        if which == "i" and lo == 87.0:
            near = big & (wo[:, 2] >= np.cos(np.radians(70.0)))[:, None]
            rel = np.abs(ref - analytic)[near] / analytic[near]
            assert_percentiles(f"{source}, θi in [{lo:g}, {hi:g}]°, θo <= 70°", rel, {50: 0.002, 95: 0.025})


@pytest.mark.parametrize("reduction, keep", [(2, slice(0, 9)), (4, slice(0, 5))])
def test_reduced_anisotropic_files_are_mirrored_like_mitsuba(files, reduction, keep):
    """Files covering φi ∈ [−π, 0] or [−π, −π/2] (as in the RGL database): Mitsuba mirrors
    wi into the stored part; so does our reader. The model is symmetric under those mirrors."""
    model = create("microfacet", alpha_x=0.15, alpha_y=0.4, fresnel="schlick", f0=[0.9, 0.6, 0.3])
    fields = dict(rgl.prepare_rgl(model, n_theta_i=5, resolution=24, vndf_resolution=32).fields)
    for k in ("phi_i", "vndf", "luminance", "rgb"):
        fields[k] = np.ascontiguousarray(fields[k][keep])
    np.testing.assert_allclose(fields["phi_i"][[0, -1]], [-np.pi, -np.pi + 2 * np.pi / reduction], atol=1e-6)
    path = files / f"reduced{reduction}.bsdf"
    path.write_bytes(encode_tensor(fields))
    wi, wo = direction_pairs(6, 0.15, 0.4, n=300)
    with mi.variant_context("scalar_rgb"):
        ref = mitsuba_eval(path, wi, wo)
    ours = brdftab.open(path)
    assert ours.reduction == reduction
    assert_reader_is_mitsuba(ours.eval_cos(wi, wo), ref)
    rel, _ = rel_errors(ref, model.eval(wi, wo) * wo[:, 2:3], 1e-4)
    assert_percentiles(f"reduction {reduction}, Mitsuba vs model", rel, {50: 0.006})


class Chiral(BRDF):
    """Isotropic (rotation invariant) but not mirror symmetric: f depends on sin(φo − φi).
    Only such a BRDF shows the sign convention of the relative azimuth φm − φi."""

    name = "chiral"
    layout = Layout(("mono",))

    def _eval(self, wi, wo, lam, n):
        cross = wi[:, 0] * wo[:, 1] - wi[:, 1] * wo[:, 0]  # sinθi sinθo sin(φo − φi)
        return np.repeat(((1.0 + 0.8 * cross) / np.pi)[:, None], n, axis=1)


def _rotate_z(w, angle):
    c, s = np.cos(angle)[:, None], np.sin(angle)[:, None]
    return np.concatenate([c * w[:, :1] - s * w[:, 1:2], s * w[:, :1] + c * w[:, 1:2], w[:, 2:]], axis=1)


def test_relative_azimuth_convention_with_a_chiral_brdf(files):
    """Mitsuba leaves ``m_reduction`` unset for isotropic files (mitsuba3 PR #1850): a plugin
    allocated where an anisotropic one with reduction 4 lived mirrors wi with x >= 0 or
    y >= 0. Pairs are therefore rotated (f is isotropic) so that wi lies in the quadrant
    x < 0, y < 0, which no reduction touches."""
    model = Chiral()
    path = files / "chiral.bsdf"
    brdftab.save(model, path)
    wi, wo = direction_pairs(9, 1.0, 1.0, n=400)
    rng = np.random.default_rng(10)
    turn = rng.uniform(-np.pi + 0.05, -np.pi / 2 - 0.05, wi.shape[0]) - np.arctan2(wi[:, 1], wi[:, 0])
    wi, wo = _f32(_rotate_z(wi, turn)), _f32(_rotate_z(wo, turn))
    wi /= np.linalg.norm(wi, axis=-1, keepdims=True)
    wo /= np.linalg.norm(wo, axis=-1, keepdims=True)
    assert np.all(wi[:, 0] < 0) and np.all(wi[:, 1] < 0)
    with mi.variant_context("scalar_rgb"):
        ref = mitsuba_eval(path, wi, wo)
    analytic = np.repeat(model.eval(wi, wo) * wo[:, 2:3], 3, axis=1)  # grey: written as R = G = B
    rel, _ = rel_errors(ref, analytic, 1e-4)
    assert_percentiles("chiral, Mitsuba vs model", rel, {50: 0.004})
    mirrored = np.repeat(model.eval(wi * [1, -1, 1], wo * [1, -1, 1]) * wo[:, 2:3], 3, axis=1)
    assert np.median(rel_errors(ref, mirrored, 1e-4)[0]) > 0.05
    assert_reader_is_mitsuba(brdftab.open(path).eval_cos(wi, wo), ref)


def test_exact_at_the_stored_nodes(rgb_file):
    """At the nodes the reader returns the model's f, whatever D is: the stored values divide by
    the interpolants the reader multiplies by, and invert(sample(node)) is the node."""
    ours = brdftab.open(rgb_file)
    wi, wo, *_ = rgl.node_geometry(ours._vndf, ours.theta_i.astype(float), ours.phi_i.astype(float),
                                    ours.resolution, True)
    ok = wo[:, 2] > 1e-3
    ref = recipe_model().eval(wi[ok], wo[ok])
    # formats/rgl-bsdf.md, Guarantees, "Exact at the nodes". Measured: 2.6e-5 at edge nodes (the warp
    # clamps the unit square to [2^-24, 1 - 2^-24]), 3.0e-5 inside (float32 tables)
    np.testing.assert_allclose(ours.values.reshape(-1, 3)[ok], ref, rtol=1e-4)
    inside = np.zeros(ours.values.shape[:4], bool)
    inside[:, :, 1:-1, 1:-1] = True
    inside = inside.ravel()[ok]
    np.testing.assert_allclose(ours.values.reshape(-1, 3)[ok][inside], ref[inside], rtol=5e-5)


def test_lambert_without_ndf_uses_backscattering(files):
    """A model without a D of its own gets one by power iteration; Mitsuba still reproduces it."""
    model = create("lambert", albedo=[0.2, 0.5, 0.8])
    path = files / "lambert.bsdf"
    brdftab.save(model, path)
    ours = brdftab.open(path)
    assert ours.provenance["ndf_source"] == "backscatter"
    wi, wo = direction_pairs(4, 1.0, 1.0, n=500)
    with mi.variant_context("scalar_rgb"):
        ref = mitsuba_eval(path, wi, wo)
    rel, _ = rel_errors(ref, model.eval(wi, wo) * wo[:, 2:3], 1e-4)
    # formats/rgl-bsdf.md, Guarantees, table row "Lambert"
    assert_percentiles("Lambert, Mitsuba vs model", rel, {50: 0.002, 75: 0.004, 90: 0.008, 95: 0.012})


# ---------------------------------------------------------------------------------------------
# the NDF and sigma tables


#: formats/rgl-bsdf.md, "How brdftab writes a file", 2: the sigma table against the Smith
#: closed form cosθ (1 + Λ), largest relative difference per GGX roughness.
SIGMA_BOUNDS = {(0.3, 0.3): 1e-6, (0.15, 0.4): 1e-4, (0.05, 0.05): 1e-6, (0.05, 0.3): 5e-4}


@pytest.mark.parametrize("ax, ay", list(SIGMA_BOUNDS))
def test_ndf_and_sigma_tables_are_the_models(ax, ay):
    """ndf = the model's D at the nodes (x = u(θ) fastest, y = u(φ)) where D exceeds the floor;
    sigma = cosθ (1 + Λ), the projected area of the model's own (unfloored) D."""
    model = create("microfacet", alpha_x=ax, alpha_y=ay)
    fields = rgl.prepare_rgl(model, n_theta_i=2, resolution=4, vndf_resolution=8,
                             **({"n_phi_i": 5} if ax != ay else {})).fields
    ny, nx = fields["ndf"].shape
    assert (ny, nx) == ((256 if ax != ay else 2), 128)
    u = np.linspace(0, 1, nx)
    v = np.linspace(0, 1, ny)
    theta = (u * u * np.pi / 2)[None, :]
    phi = ((2 * v - 1) * np.pi)[:, None] if ax != ay else np.zeros((ny, 1))
    w = np.stack(np.broadcast_arrays(np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)),
                 axis=-1)
    d = d_ggx(w, ax, ay)
    keep = d > rgl.NDF_FLOOR * d.max()
    np.testing.assert_allclose(fields["ndf"][keep], d[keep], rtol=1e-6)
    np.testing.assert_allclose(fields["ndf"][~keep], np.float32(rgl.NDF_FLOOR * d.max()), rtol=1e-6)
    sigma = w[..., 2] * (1.0 + lambda_ggx(w, ax, ay))
    grazing = np.isclose(theta, np.pi / 2) & np.ones_like(phi, bool)
    sigma = np.where(grazing, 0.5 * np.sqrt((ax * np.cos(phi)) ** 2 + (ay * np.sin(phi)) ** 2), sigma)
    rel = np.abs(fields["sigma"] / sigma - 1)
    print(f"sigma vs cos(1 + Lambda), alpha {ax}/{ay}: max {rel.max():.2g}")
    assert rel.max() < SIGMA_BOUNDS[ax, ay], rel.max()


def test_sum_uses_the_narrowest_microfacet_lobe():
    broad = create("microfacet", alpha=0.6)
    narrow = create("microfacet", alpha=0.1)
    ndf = rgl.model_ndf(create("sum", terms=[create("lambert", albedo=0.5), broad, narrow]))
    h = rgl.sph(np.radians([0.0, 10.0, 40.0]), 0.2)
    np.testing.assert_allclose(ndf(h), d_ggx(h, 0.1), rtol=1e-12)
    assert rgl.model_ndf(create("lambert", albedo=0.5)) is None
    scaled = create("scale", factor=0.5, term=narrow)
    np.testing.assert_allclose(rgl.model_ndf(scaled)(h), d_ggx(h, 0.1), rtol=1e-12)


def test_backscatter_bound_for_a_lambertian_under_a_narrow_lobe(monkeypatch):
    """formats/rgl-bsdf.md, writer step 1: a sum's ndf table is the narrowest lobe's D, raised
    where the back-scattering needs more. For a Lambertian under a Beckmann α = 0.1 lobe the
    file's albedo (as Mitsuba evaluates it) is then within 0.5 % of the model's at θi <= 70°;
    without the bound the tails of D make it more than 10 % off."""
    from brdftab.formats import _rgl_ndf

    model = create("sum", terms=[create("lambert", albedo=[0.5, 0.5, 0.5]),
                                 create("microfacet", distribution="beckmann", alpha=0.1, fresnel="schlick",
                                        f0=[0.5, 0.5, 0.5])])
    wis = rgl.sph(np.radians([0.0, 10.0, 25.0, 45.0, 70.0]), 0.0)
    ref = np.array([directional_albedo(model, wi, lobe_width=0.1, n_theta=128, n_phi=128)[1] for wi in wis])

    def albedo_error():
        bsdf = rgl.RGLBSDF(rgl.prepare_rgl(model).fields)
        return np.array([file_albedo(bsdf, wi, n=150)[1] for wi in wis]) / ref - 1

    bounded = albedo_error()
    monkeypatch.setattr(_rgl_ndf, "BACKSCATTER_BOUND", 0.0)
    unbounded = albedo_error()
    print(f"Lambert + Beckmann 0.1, albedo error with the bound {np.array2string(100 * bounded, precision=2)} %, "
          f"without {np.array2string(100 * unbounded, precision=3)} %")
    assert np.all(np.abs(bounded) < 0.005), bounded
    assert np.max(np.abs(unbounded)) > 0.1, unbounded


class MinG1GGX(BRDF):
    """f = D(h) min(G1(wi), G1(wo)) / (4 cosθi cosθo): back-scattering D·G1/(4 cos²θ) exactly,
    the relation the power iteration inverts. It has no ``ndf`` attribute."""

    name = "min-g1-ggx"
    layout = Layout(("mono",))

    def __init__(self, alpha):
        self.alpha = alpha

    def _eval(self, wi, wo, lam, n):
        h = wi + wo
        h /= np.linalg.norm(h, axis=-1, keepdims=True)
        g = np.minimum(1 / (1 + lambda_ggx(wi, self.alpha)), 1 / (1 + lambda_ggx(wo, self.alpha)))
        return np.repeat((d_ggx(h, self.alpha) * g / (4 * wi[:, 2] * wo[:, 2]))[:, None], n, axis=1)


@pytest.mark.parametrize("alpha", [0.1, 0.4, 0.8])
def test_power_iteration_recovers_d_from_backscattering(alpha):
    ndf = rgl.backscatter_ndf(MinG1GGX(alpha))
    h = rgl.sph(np.radians(np.linspace(0, 85, 120)), 0.3)
    rel = np.abs(ndf(h) / d_ggx(h, alpha) - 1)
    assert rel.max() < 1e-3, rel.max()  # measured <= 4e-5


# ---------------------------------------------------------------------------------------------
# container, options, copies, conversion


def test_container_is_read_by_mitsubas_own_reader(rgb_file):
    """Mitsuba's Python tensor_io reads our container; data start on 8-byte boundaries."""
    tensor_io = importlib.import_module("mitsuba.tensor_io")
    theirs = tensor_io.read(str(rgb_file))
    ours = parse_tensor(rgb_file.read_bytes())
    assert list(theirs) == list(ours)
    for k in ours:
        np.testing.assert_array_equal(theirs[k], ours[k])
        assert theirs[k].dtype == ours[k].dtype
    data = rgb_file.read_bytes()
    pos, offsets = 18, []
    for _ in range(struct.unpack_from("<I", data, 14)[0]):
        (n,) = struct.unpack_from("<H", data, pos)
        ndim, code, offset = struct.unpack_from("<HBQ", data, pos + 2 + n)
        offsets.append(offset)
        pos += 2 + n + 11 + 8 * ndim
    assert all(o % 8 == 0 for o in offsets) and data[:14] == b"tensor_file\0\x01\x00"
    assert {k: v.dtype.name for k, v in ours.items() if k not in ("description", "jacobian", "provenance")} == \
        dict.fromkeys(["theta_i", "phi_i", "ndf", "sigma", "vndf", "luminance", "rgb"], "float32")
    assert ours["jacobian"].tolist() == [1] and ours["phi_i"].tolist() == [0.0]
    assert ours["ndf"].shape == ours["sigma"].shape == (2, 128) and ours["vndf"].shape == (1, 17, 64, 64)
    assert ours["rgb"].shape == (1, 17, 3, 48, 48) and ours["luminance"].shape == (1, 17, 48, 48)
    np.testing.assert_allclose(np.degrees(ours["theta_i"][[0, -1]]), [0, 89], rtol=1e-6)


def test_spec_output_with_format_options(files):
    """An [[output]] with a .bsdf path gets the model itself, with the options as written."""
    from brdftab.pipeline import run
    from brdftab.spec import load_spec

    spec = files / "recipe.toml"
    spec.write_text("""
[model]
name = "sum"
[[model.terms]]
name = "lambert"
albedo = [0.05, 0.1, 0.2]
[[model.terms]]
name = "microfacet"
alpha = 0.3
fresnel = "schlick"
f0 = [0.9, 0.6, 0.3]
[grid]
type = "merl"
[[output]]
path = "from-spec.bsdf"
resolution = 16
theta_i_deg = [0, 30, 60, 80]
""")
    result = run(load_spec(spec))
    assert result.written == [files / "from-spec.bsdf"]
    raw = parse_tensor((files / "from-spec.bsdf").read_bytes())
    assert raw["rgb"].shape == (1, 4, 3, 16, 16)
    assert json.loads(bytes(raw["provenance"]))["ndf_source"] == "model"
    spec.write_text(spec.read_text().replace("resolution = 16", "resolutoin = 16"))
    with pytest.raises(BrdftabError, match=r"output\[0\]\.resolutoin: unknown option for format rgl \(did you mean"):
        load_spec(spec)


def test_resolutions_are_format_options(files):
    path = files / "small.bsdf"
    brdftab.save(recipe_model(), path, resolution=16, vndf_resolution=24, ndf_resolution=40,
                 theta_i_deg=[0, 30, 60, 80], description="four angles")
    raw = parse_tensor(path.read_bytes())
    assert raw["rgb"].shape == (1, 4, 3, 16, 16) and raw["vndf"].shape == (1, 4, 24, 24)
    assert raw["ndf"].shape == (2, 40) and bytes(raw["description"]) == b"four angles"
    np.testing.assert_allclose(raw["theta_i"], np.radians([0, 30, 60, 80]).astype(np.float32))
    with mi.variant_context("scalar_rgb"):
        mi.load_dict({"type": "measured", "filename": str(path)})
    fmt = formats.FORMATS["rgl"]
    for bad in ({"resolution": 1}, {"resolution": 3.5}, {"theta_i_deg": [30, 10]}, {"theta_i_deg": [0, 95]},
                {"n_theta_i": 4, "theta_i_deg": [0, 10]}, {"ndf": "ggx"}, {"anisotropic": "yes"},
                {"n_phi_i": 2}, {"wavelengths_nm": [500, 400]}, {"resolutoin": 16}):
        with pytest.raises(ParameterError):
            fmt.validate_options(bad)
    aniso = create("microfacet", alpha_x=0.1, alpha_y=0.3)
    for model, options, match in ((aniso, {"anisotropic": False}, "anisotropic"),
                                  (create("lambert", albedo=0.5), {"ndf": "model"}, "normal distribution"),
                                  (recipe_model(), {"wavelengths_nm": [500, 600]}, "not a spectrum"),
                                  (create("lambert", albedo=[0.1, 0.2, 0.3, 0.4]), {}, "RGB or spectra")):
        with pytest.raises(ParameterError, match=match):
            rgl.prepare_rgl(model, **options)


def test_copy_is_exact_and_conversion_tabulates_the_reader(files, rgb_file):
    """A read file written again without options is copied byte for byte; written to netCDF it
    is tabulated by our reader on the target grid (and stays close to the source model)."""
    ours = brdftab.open(rgb_file)
    again = files / "again.bsdf"
    brdftab.save(ours, again)
    assert again.read_bytes() == rgb_file.read_bytes()
    resampled = rgl.prepare_rgl(ours, resolution=16).fields  # keeps the file's own D
    assert json.loads(bytes(resampled["provenance"]))["ndf_source"] == "model"
    np.testing.assert_allclose(resampled["ndf"], ours.fields["ndf"], rtol=1e-6)
    # an RGL file is conditioned on wi: not exactly reciprocal, so no reciprocity fold
    grid = brdftab.grids.grid_from_config({"type": "rusinkiewicz", "n_theta_h": 12, "n_theta_d": 10, "n_phi_d": 48,
                                           "phi_d_fold": "none"})
    table = brdftab.save(ours, files / "recipe.nc", grid=grid)
    back = brdftab.open(files / "recipe.nc")
    wi, wo = grid.directions(0, grid.size)
    np.testing.assert_allclose(back.values.reshape(-1, 3), ours.eval(wi, wo), rtol=1e-12, atol=0)
    np.testing.assert_array_equal(table.values, back.values)
    analytic = recipe_model().eval(wi, wo)
    ok = (wi[:, 2] > 0.1) & (wo[:, 2] > 0.1)
    rel, _ = rel_errors(back.values.reshape(-1, 3)[ok], analytic[ok], 1e-4)
    assert_percentiles(".bsdf -> netCDF vs model", rel, {50: 0.002})
    assert json.loads(back.ds.attrs["parameters"])["source_model"]["model"] == "sum"


def test_bsdf_to_merl(files, rgb_file):
    """.bsdf -> MERL .binary tabulates our reader on the MERL grid (isotropic; reciprocal only
    when asked: the file is conditioned on wi, so it declares itself non-reciprocal and keeps its
    source's word)."""
    ours = brdftab.open(rgb_file)
    assert not ours.reciprocal and ours.source_reciprocal and ours.isotropic
    with pytest.raises(brdftab.errors.BrdftabError, match="symmetrize"):
        brdftab.save(ours, files / "refused.binary")
    brdftab.save(ours, files / "recipe.binary", symmetrize=True)
    merl = brdftab.open(files / "recipe.binary")
    grid = merl.grid
    start = grid.size // 3
    wi, wo = grid.directions(start, start + 20000)
    stored = merl.values.reshape(-1, 3)[start:start + 20000]
    ok = (wi[:, 2] > 1e-6) & (wo[:, 2] > 1e-6) & np.all(np.isfinite(stored), axis=1)
    assert ok.mean() > 0.5
    both = 0.5 * (ours.eval(wi[ok], wo[ok]) + ours.eval(wo[ok], wi[ok]))
    np.testing.assert_allclose(stored[ok], both, rtol=1e-12, atol=1e-12)
    model = recipe_model()
    wi, wo = direction_pairs(8, 0.3, 0.3, n=300)
    rel, _ = rel_errors(merl.eval(wi, wo), model.eval(wi, wo), 1e-4)
    assert_percentiles(".bsdf -> MERL vs model", rel, {50: 0.003})


def test_info_describes_the_file(rgb_file):
    from click.testing import CliRunner

    from brdftab.cli import main

    result = CliRunner().invoke(main, ["info", str(rgb_file), "--json"])
    assert result.exit_code == 0, result.output
    info = json.loads(result.output)
    assert info["format"] == "rgl" and info["channels"] == ["R", "G", "B"]
    assert "17 theta_i" in info["grid"] and info["negative"] == 0 and info["nonfinite"] == 0
    assert [a["name"] for a in info["axes"]] == ["phi_i", "theta_i"]
    assert info["attributes"]["model"] == "sum"


# ---------------------------------------------------------------------------------------------
# damaged input: one clear FormatError line, nothing else


SMALL = dict(n_theta_i=3, resolution=6, vndf_resolution=6, ndf_resolution=8)


@pytest.fixture(scope="module")
def small_fields():
    """A small valid RGB isotropic file's fields (3 θi, 6 × 6 samples): fast to read many times."""
    return rgl.prepare_rgl(recipe_model(), **SMALL).fields


@pytest.fixture(scope="module", params=["rgb-isotropic", "spectral-anisotropic"])
def fuzz_fields(request, small_fields):
    if request.param == "rgb-isotropic":
        return small_fields
    return rgl.prepare_rgl(spectral_model(), anisotropic=True, n_phi_i=3, ndf_phi_resolution=4, **SMALL).fields


def _mutate(fields, name, value=None, drop=False):
    out = dict(fields)
    if drop:
        del out[name]
    else:
        out[name] = value
    return encode_tensor(out)


def _damaged(fields):
    valid = encode_tensor(fields)
    th = fields["theta_i"]
    yield "truncated", valid[: len(valid) // 2], "run past the end"
    yield "empty", b"", "too short"
    yield "header only", valid[:17], "too short"
    yield "wrong magic", b"tensor_fiel\0" + valid[12:], "not a tensor file"
    yield "version 2.0", valid[:12] + b"\x02\x00" + valid[14:], "version 2.0"
    yield "version 1.1", valid[:12] + b"\x01\x01" + valid[14:], "version 1.1"
    yield "too many fields", valid[:14] + struct.pack("<I", 10 ** 6) + valid[18:], "room for at most"
    bad_offset = bytearray(valid)
    n = struct.unpack_from("<H", valid, 18)[0]
    struct.pack_into("<Q", bad_offset, 18 + 2 + n + 3, len(valid) + 100)
    yield "offset past the end", bytes(bad_offset), "run past the end"
    bad_code = bytearray(valid)
    bad_code[18 + 2 + n + 2] = 12
    yield "dtype code 12", bytes(bad_code), "invalid dtype code 12"
    yield "missing vndf", _mutate(fields, "vndf", drop=True), "missing field 'vndf'"
    yield "missing rgb", _mutate(fields, "rgb", drop=True), "missing field 'rgb'"
    yield "theta_i float64", _mutate(fields, "theta_i", th.astype(np.float64)), "'theta_i' must be 1-D float32"
    yield "jacobian int32", _mutate(fields, "jacobian", np.ones(1, np.int32)), "'jacobian' must be 1-D uint8"
    yield "ndf 1-D", _mutate(fields, "ndf", fields["ndf"].ravel()), "'ndf' must be 2-D float32"
    yield "luminance not square", _mutate(fields, "luminance", fields["luminance"][..., :-1]), "'luminance' has shape"
    yield "rgb 4 channels", _mutate(fields, "rgb", np.concatenate([fields["rgb"]] * 2, axis=2)[:, :, :4]), \
        "'rgb' has shape"
    yield "vndf wrong theta_i count", _mutate(fields, "vndf", fields["vndf"][:, :2]), "'vndf' has shape"
    yield "theta_i decreasing", _mutate(fields, "theta_i", th[::-1].copy()), "theta_i must increase"
    yield "nan in vndf", _mutate(fields, "vndf", np.where(fields["vndf"] > 0, np.float32(np.nan), fields["vndf"])), \
        "non-finite"
    yield "zero sigma", _mutate(fields, "sigma", np.zeros_like(fields["sigma"])), "'sigma' must be positive"
    yield "zero vndf slice", _mutate(fields, "vndf", np.zeros_like(fields["vndf"])), "all-zero slice"
    yield "negative luminance", _mutate(fields, "luminance", -fields["luminance"]), "negative"
    yield "phi_i spans 100 degrees", _mutate(fields, "phi_i", np.radians([0.0, 50.0, 100.0]).astype(np.float32)), \
        "'vndf' has shape"
    yield "spectra without wavelengths", _mutate(_without(fields, "rgb"), "spectra", fields["rgb"]), \
        "'spectra' without 'wavelengths'"


def _without(fields, name):
    out = dict(fields)
    del out[name]
    return out


def test_damaged_files_give_one_clear_line(files, small_fields):
    for label, data, phrase in _damaged(small_fields):
        path = files / "damaged.bsdf"
        path.write_bytes(data)
        with pytest.raises(FormatError) as info:
            formats.FORMATS["rgl"].read(path)
        msg = str(info.value)
        assert "\n" not in msg and msg.startswith(str(path)), (label, msg)
        assert phrase in msg, (label, msg)
        if data[:12] == b"tensor_file\0":  # detected by content, then refused with the same line
            with pytest.raises(FormatError, match="damaged.bsdf"):
                brdftab.open(path)


def test_anisotropic_phi_i_must_cover_the_circle(small_fields):
    f = dict(small_fields)
    n = 3
    f["phi_i"] = np.radians([0.0, 50.0, 100.0]).astype(np.float32)
    for k in ("vndf", "luminance", "rgb"):
        f[k] = np.concatenate([f[k]] * n, axis=0)
    for wrong in ([0.0, 50.0, 100.0], [0.0, 45.0, 90.0], [-180.0, 0.0, 170.0]):
        f["phi_i"] = np.radians(wrong).astype(np.float32)
        with pytest.raises(FormatError, match=r"must cover \[-180, 180\], \[-180, 0\] or \[-180, -90\] degrees"):
            rgl.read_rgl_bytes(encode_tensor(f), "x.bsdf")
    for right, reduction in (([-180.0, 0.0, 180.0], 1), ([-180.0, -90.0, 0.0], 2), ([-180.0, -135.0, -90.0], 4)):
        f["phi_i"] = np.radians(right).astype(np.float32)
        bsdf = rgl.read_rgl_bytes(encode_tensor(f), "x.bsdf")
        assert not bsdf.isotropic and bsdf.reduction == reduction


FUZZ = settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
PROBE_WI = rgl.sph(np.radians([10.0, 50.0, 80.0]), np.radians([0.0, 100.0, -60.0]))
PROBE_WO = rgl.sph(np.radians([20.0, 45.0, 5.0]), np.radians([180.0, -70.0, 30.0]))


def _read_or_refuse(data):
    """Reading either works (and the result evaluates) or raises brdftab's own error."""
    try:
        bsdf = rgl.read_rgl_bytes(data, "fuzz.bsdf")
    except BrdftabError as exc:
        assert "\n" not in str(exc) and str(exc).startswith("fuzz.bsdf")
        return None
    f = bsdf.eval(PROBE_WI, PROBE_WO, None if not bsdf.spectral else bsdf.wavelengths[:1])
    assert f.shape[0] == 3
    bsdf.statistics()
    return bsdf


@FUZZ
@given(st.binary(max_size=400), st.booleans())
def test_fuzz_random_bytes(data, with_header):
    if with_header:
        data = b"tensor_file\0\x01\x00" + data
    _read_or_refuse(data)


@FUZZ
@given(st.data())
def test_fuzz_mutated_valid_file(fuzz_fields, data):
    raw = bytearray(encode_tensor(fuzz_fields))
    header_end = min(len(raw), 400)  # the field table: most mutations go there
    for _ in range(data.draw(st.integers(1, 6))):
        kind = data.draw(st.sampled_from(["flip", "header", "truncate", "insert", "delete"]))
        if not raw:
            break
        if kind == "flip":
            raw[data.draw(st.integers(0, len(raw) - 1))] ^= 1 << data.draw(st.integers(0, 7))
        elif kind == "header":
            raw[data.draw(st.integers(0, min(header_end, len(raw)) - 1))] = data.draw(st.integers(0, 255))
        elif kind == "truncate":
            del raw[data.draw(st.integers(0, len(raw) - 1)):]
        elif kind == "insert":
            at = data.draw(st.integers(0, len(raw)))
            raw[at:at] = data.draw(st.binary(min_size=1, max_size=16))
        else:
            at = data.draw(st.integers(0, len(raw) - 1))
            del raw[at:at + data.draw(st.integers(1, 16))]
    _read_or_refuse(bytes(raw))


_FLOATS = st.floats(allow_nan=True, allow_infinity=True, width=32)


@FUZZ
@given(st.data())
def test_fuzz_mutated_fields(fuzz_fields, data):
    """Semantic damage: a field dropped, retyped, reshaped or given odd values."""
    fields = dict(fuzz_fields)
    name = data.draw(st.sampled_from(sorted(fields)))
    kind = data.draw(st.sampled_from(["drop", "dtype", "reshape", "values", "empty"]))
    a = fields[name]
    if kind == "drop":
        del fields[name]
    elif kind == "dtype":
        fields[name] = a.astype(data.draw(st.sampled_from(["u1", "i2", "u4", "i8", "f2", "f4", "f8"])))
    elif kind == "reshape":
        fields[name] = a.reshape(-1) if a.ndim > 1 else a.reshape(1, -1)
    elif kind == "empty":
        fields[name] = a[:0]
    else:
        b = a.copy().ravel()
        for _ in range(data.draw(st.integers(1, 4))):
            i = data.draw(st.integers(0, b.size - 1))
            b[i] = data.draw(st.integers(0, 255)) if b.dtype == np.uint8 else data.draw(_FLOATS)
        fields[name] = b.reshape(a.shape)
    _read_or_refuse(encode_tensor(fields))


def test_fuzz_through_the_registry(files, small_fields):
    """formats.read (detection by magic, then the reader) refuses damage with BrdftabError only."""
    rng = np.random.default_rng(5)
    valid = encode_tensor(small_fields)
    path = files / "registry.bsdf"
    for _ in range(60):
        raw = bytearray(valid)
        for i in rng.integers(0, len(raw), size=rng.integers(1, 8)):
            raw[i] = int(rng.integers(0, 256))
        path.write_bytes(bytes(raw[: int(rng.integers(1, len(raw) + 1))]))
        try:
            formats.read(path)
        except BrdftabError as exc:
            assert "\n" not in str(exc)


# -- f near the horizon, measured files -------------------------------------------------------

def test_f_is_held_near_the_horizon(files):
    """The quotient (f·cosθo)/cosθo grows without bound at grazing ωo; the reader holds f beyond
    θ_hold = 90° − 180°/resolution (formats/rgl-bsdf.md, Guarantees, "f near the horizon"): a
    Lambertian's file then reads within 20 % of its f at every θo, θi <= 80° and azimuth
    (the file's own error at θ_hold), where the quotient is right at 89° but about 1.8× too
    large at 89.9° and 10× at 89.99° (medians; the default 49 × 49 samples of a D from the
    back-scattering)."""
    path = files / "lambert-hold.bsdf"
    brdftab.save(create("lambert", albedo=0.99), path)
    ours = brdftab.open(path)
    assert ours.resolution == 49  # the default for a D from the back-scattering
    assert np.degrees(ours.theta_hold) == pytest.approx(90 - 180 / 49)
    f0 = 0.99 / np.pi
    th = np.radians(np.array([85.0, 88.0, 89.0, 89.5, 89.9, 89.99]))
    held, quotient = [], []
    for ti in np.arange(0.0, 81.0, 10.0):
        wi = rgl.sph(np.radians(ti), 0.3)
        for dphi in np.radians(np.arange(0.0, 181.0, 45.0)):
            wo = rgl.sph(th, 0.3 + dphi)
            wi_ = np.broadcast_to(wi, wo.shape)
            held.append(ours.eval(wi_, wo)[:, 1] / f0)
            quotient.append(ours.eval_cos(wi_, wo)[:, 1] / wo[:, 2] / f0)
    held, quotient = np.array(held), np.median(quotient, axis=0)
    print(f"held f / (rho/pi): [{held.min():.3f}, {held.max():.3f}]; quotient (median) at 89°, 89.9°: "
          f"{quotient[2]:.2f}, {quotient[4]:.2f}")
    assert np.all(np.abs(held - 1) < 0.2), (held.min(), held.max())
    # the blow-up the hold removes
    assert 0.97 < quotient[2] < 1.05 and 1.5 < quotient[4] < 2.2 and quotient[5] > 5.0, quotient


@pytest.mark.parametrize("theta_i", [30.0, 70.0, 89.0])
def test_albedo_of_a_file_matches_mitsubas_and_a_resolved_quadrature(files, theta_i):
    """brdftab's albedo of a file (f·cosθo as Mitsuba evaluates it, no hold) against Mitsuba's
    importance-sampled albedo of the same file (within 1 %) and against a fine product quadrature
    of brdftab's reader, which holds f beyond θ_hold (within 0.5 %): formats/rgl-bsdf.md,
    Guarantees, "f near the horizon"."""
    from brdftab.integrate import directional_albedo as albedo
    from brdftab.quadrature import gauss_legendre

    path = files / "measured-albedo.bsdf"
    if not path.exists():
        from _measured import measured_bsdf

        measured_bsdf(path, negatives=0)
    ours = brdftab.open(path)
    wi = rgl.sph(np.radians(theta_i), 0.0)
    got = albedo(ours, np.radians(theta_i), 0.0)
    with mi.variant_context("scalar_rgb"):
        mts = mitsuba_albedo(path, _f32(wi), n=48)
    print(f"albedo vs Mitsuba's, θi = {theta_i:g}°: {np.array2string(100 * (got / mts - 1), precision=2)} %")
    np.testing.assert_allclose(got, mts, rtol=0.01)
    mu, wmu = gauss_legendre(300, 0.0, 1.0)
    ph = (np.arange(600) + 0.5) * 2 * np.pi / 600
    wo = rgl.sph(np.arccos(mu)[:, None], ph[None, :]).reshape(-1, 3)
    w = (wmu[:, None] * np.full(600, 2 * np.pi / 600)).ravel() * wo[:, 2]
    fine = ours.eval(np.broadcast_to(wi, wo.shape), wo).T @ w
    print(f"albedo vs a fine quadrature of held f, θi = {theta_i:g}°: "
          f"{np.array2string(100 * (got / fine - 1), precision=2)} %")
    np.testing.assert_allclose(got, fine, rtol=0.005)


def test_a_measured_file_declares_nothing_it_does_not_record(files):
    from _measured import measured_bsdf

    path = files / "measured-origin.bsdf"
    measured_bsdf(path)
    ours = brdftab.open(path)
    assert ours.origin == "unknown" and not ours.reciprocal and not ours.reciprocity_declared
    mine = files / "ours-origin.bsdf"
    brdftab.save(recipe_model(), mine)
    back = brdftab.open(mine)
    # a brdftab file records its source; the file itself is conditioned on wi: not reciprocal
    assert back.origin == "analytic" and back.source_reciprocal is True and not back.reciprocal


def test_lambert_file_albedo_up_to_grazing_incidence(files):
    """formats/rgl-bsdf.md, Guarantees, "Grazing incidence": a Lambertian's albedo from its file,
    by brdftab's reader (held f) and as Mitsuba evaluates the file (eval_cos), is within 0.2 %
    up to θi = 80° and within 1 % at 85–89.5° (the default θi nodes reach 89°; beyond, Mitsuba
    clamps to the last node)."""
    from brdftab.integrate import directional_albedo as albedo

    path = files / "lambert-albedo.bsdf"
    brdftab.save(create("lambert", albedo=0.99), path)
    ours = brdftab.open(path)
    ths = np.array([0.0, 10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0, 80.0, 85.0, 87.0, 89.0, 89.5])
    held = albedo(ours, np.radians(ths))[:, 1] / 0.99 - 1
    own = np.array([file_albedo(ours, rgl.sph(np.radians(t), 0.0), n=200)[1] for t in ths]) / 0.99 - 1
    print(f"Lambert albedo error, held: {np.array2string(100 * held, precision=2)} %; "
          f"eval_cos: {np.array2string(100 * own, precision=2)} %")
    low = ths <= 80.0
    for err in (held, own):
        assert np.all(np.abs(err[low]) < 0.002), err
        assert np.all(np.abs(err[~low]) < 0.01), err


# ---------------------------------------------------------------------------------------------
# tables written to .bsdf: the file follows the table's own values


def _provenance(path):
    """The provenance brdftab's writer recorded in the file at ``path``."""
    return json.loads(bytes(brdftab.open(path).fields["provenance"]).decode())


def _json_provenance(payload):
    """The provenance in a prepared payload's fields."""
    return json.loads(bytes(payload.fields["provenance"]).decode())


def _warp(path):
    """The warp brdftab's writer chose for the file at ``path`` (its provenance)."""
    return _provenance(path)["warp"]


def _table(model, grid, path):
    from brdftab.table import tabulate

    t = tabulate(model, grid)
    t.save(path) if hasattr(t, "save") else brdftab.save(t, path)
    return brdftab.open(path)


def test_lambert_table_to_bsdf_up_to_grazing(files):
    """A Lambertian (albedo 0.99) *table* written to .bsdf and evaluated by Mitsuba at every θi
    from 0 to 85° in 1° steps (between the file's θi nodes too), azimuths 10° apart, θo in 1°
    steps from 70° to 80°: within 2 % of ρ/π at every θo ≤ 80° (worst 1.7 % at 73°), 6 % at
    85° (formats/rgl-bsdf.md, Guarantees, "Tables").
    A warp whose even spread was masked to the nodes above the horizon (a mask that moves by
    whole columns from row to row, bending the warp at those rows at any resolution), whose
    sample columns crossed the levels of cosθo, and whose row densities differed between θi
    slices read 1.7 % off at θo = 70°, 3.0 % at 75°, 5.2 % at 80° (worst at θi 5-25°) and
    14 % at 85°."""
    from brdftab.grids.rusinkiewicz import RusinkiewiczGrid

    table = _table(create("lambert", albedo=0.99), RusinkiewiczGrid(30, 30, 60), files / "lambert-table.nc")
    path = files / "lambert-table.bsdf"
    brdftab.save(table, path)
    f0 = 0.99 / np.pi
    tos = (0.0, 30.0, 45.0, 60.0, 65.0, 70.0, 71.0, 72.0, 73.0, 74.0, 75.0, 76.0, 77.0, 78.0, 79.0, 80.0, 85.0)
    ti, to, dphi = np.meshgrid(np.radians(np.arange(0.0, 85.1, 1.0)), np.radians(tos),
                               np.radians(np.arange(0.0, 181.0, 10.0)), indexing="ij")
    wi = _f32(rgl.sph(ti.ravel(), 0.3))
    wo = _f32(rgl.sph(to.ravel(), 0.3 + dphi.ravel()))
    with mi.variant_context("scalar_rgb"):
        got = mitsuba_eval(path, wi, wo)[:, 1] / wo[:, 2] / f0
    err = np.abs(got - 1).reshape(ti.shape).max(axis=(0, 2))
    worst = dict(zip(tos, err.tolist()))
    print("Lambert table, Mitsuba, worst |f/(rho/pi) - 1| by θo: "
          + ", ".join(f"{k:g}°: {100 * v:.2f} %" for k, v in worst.items()))
    assert all(v < (0.06 if k > 80.0 else 0.02) for k, v in worst.items()), worst
    # the 21 θi nodes of a D from the back-scattering and the twin of the last one up to 63.5°
    # (step 3), 1e-6 rad above it
    th = np.degrees(brdftab.open(path).theta_i.astype(float))
    assert th.size == 22 and np.count_nonzero(np.diff(th) < 1e-3) == 1
    assert np.diff(th).min() == pytest.approx(np.degrees(1e-6), rel=0.2) and th[np.argmin(np.diff(th))] <= 63.5


@pytest.mark.parametrize("spec, p95", [("torrance-sparrow-aluminum", 0.02), ("pyromark-he-torrance", 0.05)])
def test_shipped_tables_convert_to_bsdf(files, spec, p95):
    """The shipped Torrance-Sparrow and He-Torrance (4.5° cone) specs tabulated and converted to
    .bsdf: not refused (the Torrance-Sparrow file's albedo was 1.58 at 89° against the model's
    0.91), and Mitsuba's reading of the file reproduces the table at θi, θo ≤ 80°: median
    below 1 %, 95th percentile below the bound (He-Torrance was 143 %)."""
    import tomllib
    from pathlib import Path

    from brdftab.convert import convert
    from brdftab.grids import grid_from_config

    cfg = tomllib.loads((Path(__file__).parent.parent / "specs" / f"{spec}.toml").read_text())
    params = {(k[:-4] if k == "cone_half_width_deg" else k): (float(np.radians(v)) if k == "cone_half_width_deg"
                                                              else v)
              for k, v in cfg["model"].items() if k != "name"}
    model = create(cfg["model"]["name"], **params)
    table = _table(model, grid_from_config(cfg["grid"]), files / f"{spec}.nc")
    out = files / f"{spec}.bsdf"
    convert(files / f"{spec}.nc", out, overwrite=True, progress=False)  # raises when refused
    assert _warp(out) in ("level", "lobe")  # the warp that reproduces the table better (formats/rgl-bsdf.md, step 3)
    wi, wo = direction_pairs(7, 0.1, 0.1, 600)
    keep = (wi[:, 2] >= np.cos(np.radians(80.0))) & (wo[:, 2] >= np.cos(np.radians(80.0)))
    wi, wo = wi[keep], wo[keep]
    ref = np.asarray(table.eval(wi, wo), float)[:, :1] * wo[:, 2:3]
    with mi.variant_context("scalar_rgb"):
        got = mitsuba_eval(out, wi, wo)[:, :1]
    big = ref > 1e-3 * np.percentile(ref, 99)
    rel = np.abs(got[big] - ref[big]) / ref[big]
    assert_percentiles(f"{spec} table -> .bsdf, Mitsuba vs table", rel, {50: 0.006, 95: p95})


def test_single_incidence_table_is_refused(files):
    """A table at one incidence (a spherical grid with one θi) cannot fill an RGL file: one line,
    exit code 2, nothing written."""
    from _cli import one_error, run

    from brdftab.grids.spherical import SphericalGrid

    grid = SphericalGrid(np.radians([45.0]), [0.0], np.radians(np.arange(0.0, 90.0, 5.0)),
                         np.radians(np.arange(0.0, 360.0, 10.0)))
    _table(create("lambert", albedo=0.5), grid, files / "one-incidence.nc")
    target = files / "one-incidence.bsdf"
    result = run("convert", files / "one-incidence.nc", target)
    one_error(result.stderr, result.returncode, "single incidence")
    assert not target.exists()
    # incidences 20-60°: short of the file's 0-89°, refused naming the option that fits it
    grid = SphericalGrid(np.radians([20.0, 40.0, 60.0]), [0.0], np.radians(np.arange(0.0, 90.0, 5.0)),
                         np.radians(np.arange(0.0, 360.0, 10.0)))
    _table(create("lambert", albedo=0.5), grid, files / "three-incidences.nc")
    result = run("convert", files / "three-incidences.nc", target)
    one_error(result.stderr, result.returncode, "20 to 60 deg", "theta_i_deg")
    assert not target.exists()
    # an RGL file measured up to 80° evaluates at every incidence (clamped, as in Mitsuba):
    # written again with options, it is resampled, not refused
    from _measured import measured_bsdf

    measured_bsdf(files / "to-80.bsdf")
    rgl.prepare_rgl(brdftab.open(files / "to-80.bsdf"), resolution=16)


def test_a_model_without_back_scattering_gets_a_flat_ndf(files):
    """Upright mirror pyramids scatter next to nothing back (f(ω, ω) below 1e-6 of the BRDF's
    largest values: a power iteration on it gives a spike of D where the facet roughness leaks
    1e-11): the file gets the flat D = 1/π, and Mitsuba reads it."""
    model = create("pyramid-microfacet", facet_roughness=0.015, max_bounces=3, fresnel="none")
    payload = rgl.prepare_rgl(model, n_theta_i=4, n_phi_i=5, resolution=12, vndf_resolution=16, ndf_resolution=16,
                              ndf_phi_resolution=8)
    np.testing.assert_allclose(payload.fields["ndf"], 1.0 / np.pi, rtol=1e-6)
    path = files / "pyramids.bsdf"
    path.write_bytes(encode_tensor(payload.fields))
    wi, wo = direction_pairs(3, 0.3, 0.3, 40)
    with mi.variant_context("scalar_rgb"):
        ref = mitsuba_eval(path, wi, wo)
    assert_reader_is_mitsuba(brdftab.open(path).eval_cos(wi, wo), ref)


def test_measured_file_round_trip_through_netcdf(files):
    """A measured-like file in the RGL database's layout (8 θi, 32 × 32 samples, vndf 128 × 128;
    written back with the lobe warp, which the choice of formats/rgl-bsdf.md step 3 takes here) converted to
    netCDF and back to .bsdf with the default options: Mitsuba's reading of the new file
    reproduces the netCDF table at θi, θo ≤ 80° with a median below 1 % and a 95th percentile
    below 10 %, in a file no more than twice the size of a database file of that layout (the
    float32 tables alone of 8 θi: 640 kB) (formats/rgl-bsdf.md, Guarantees, "Tables")."""
    from _measured import measured_bsdf

    from brdftab.convert import convert

    src, nc, out = files / "rgl-like.bsdf", files / "rgl-like.nc", files / "rgl-like-again.bsdf"
    measured_bsdf(src, resolution=32, vndf_resolution=128)
    convert(src, nc, progress=False)
    convert(nc, out, progress=False)
    assert _warp(out) == "lobe"
    table = brdftab.open(nc)
    wi, wo = direction_pairs(11, 0.25, 0.25, 800)
    keep = (wi[:, 2] >= np.cos(np.radians(80.0))) & (wo[:, 2] >= np.cos(np.radians(80.0)))
    wi, wo = wi[keep], wo[keep]
    ref = np.asarray(table.eval(wi, wo), float) * wo[:, 2:3]
    with mi.variant_context("scalar_rgb"):
        got = mitsuba_eval(out, wi, wo)
    big = np.abs(ref) > 1e-3 * np.percentile(np.abs(ref), 99)
    rel = np.abs(got[big] - ref[big]) / np.abs(ref[big])
    size, source_size = out.stat().st_size, src.stat().st_size
    print(f"sizes: source {source_size} B, written {size} B")
    assert_percentiles("measured-like .bsdf -> .nc -> .bsdf, Mitsuba vs the netCDF table", rel, {50: 0.01, 95: 0.10})
    database_tables = 4 * 8 * (4 * 32 * 32 + 128 * 128)  # rgb + luminance, vndf: float32, 8 θi
    assert size <= 2 * min(source_size, database_tables)


def test_fine_structure_of_a_tables_d_is_kept_in_its_ndf(files):
    """A measured-like file whose D has structure at the scale of its own 128 ``ndf`` nodes (a
    ripple of ±10 % with a period of 4 nodes; the real films' D are noisy at that scale),
    converted to netCDF (written although the default grid misses the ripple: that is not what
    is judged here) and back to .bsdf with the default options: the new file keeps the
    table's D at 1025 nodes, and Mitsuba's reading of it reproduces the netCDF table at
    θi, θo <= 80° (pairs uniform in cosθ) with a median below 0.5 % and a 95th percentile
    below 5 %, half the issue's bounds (formats/rgl-bsdf.md, step 1; measured 0.30 % and
    1.3 %). The former defaults (``ndf`` at 128 nodes, 21 θi, 49 x 49, vndf 64 x 64) read
    0.70 % and 2.3 %; the ``ndf`` at 128 nodes with the lobe warp's present layout 3.7 % and
    10 % (by a script): the ripple falls into the stored values."""
    from _measured import Asymmetric

    from brdftab.convert import convert
    from brdftab.formats._tensor import write_tensor_file

    m = brdftab.models
    model = Asymmetric(m.create("sum", terms=[
        m.create("lambert", albedo=[0.02, 0.03, 0.04]),
        m.create("microfacet", alpha=0.05, fresnel="schlick", f0=[0.5, 0.4, 0.3])]), 0.3)
    fields = dict(rgl.prepare_rgl(model, n_theta_i=8, theta_i_max_deg=80.0, resolution=32,
                                  vndf_resolution=128, values="nodes").fields)
    fields.pop("provenance")
    ripple = 1.0 + 0.1 * np.sin(0.5 * np.pi * np.arange(fields["ndf"].shape[1]))
    fields["ndf"] = (fields["ndf"] * ripple[None, :]).astype(np.float32)
    src, nc, out = files / "rippled.bsdf", files / "rippled.nc", files / "rippled-again.bsdf"
    write_tensor_file(src, fields)
    convert(src, nc, progress=False, allow_invalid=True)
    convert(nc, out, progress=False)
    table = brdftab.open(nc)
    rng = np.random.default_rng(12)  # pairs uniform in cosθ up to 80°
    mu, phi = rng.uniform(np.cos(np.radians(80.0)), 1.0, (2, 1500)), rng.uniform(-np.pi, np.pi, (2, 1500))
    wi, wo = (_f32(rgl.sph(np.arccos(mu[k]), phi[k])) for k in (0, 1))
    ref = np.asarray(table.eval(wi, wo), float) * wo[:, 2:3]
    with mi.variant_context("scalar_rgb"):
        got = mitsuba_eval(out, wi, wo)
    big = np.abs(ref) > 1e-3 * np.percentile(np.abs(ref), 99)
    rel = np.abs(got[big] - ref[big]) / np.abs(ref[big])
    assert_percentiles("rippled D: .bsdf -> .nc -> .bsdf, Mitsuba vs the netCDF table", rel, {50: 0.005, 95: 0.05})
    assert parse_tensor(out.read_bytes())["ndf"].shape == (2, 1025)


_SPECS = Path(__file__).resolve().parent.parent / "specs"


@pytest.mark.parametrize("spec", sorted(p.stem for p in _SPECS.glob("*.toml")))
def test_every_shipped_spec_model_writes_a_bsdf(spec, tmp_path):
    """Every shipped spec's model can be written to .bsdf (small resolutions keep this fast): the
    fields are valid for brdftab's reader (Mitsuba's checks), every stored value is finite, and
    Mitsuba reads the file as brdftab's reader does (grey models in all three channels; measured
    ≤ 0.3 of the bound)."""
    from brdftab.formats._tensor import write_tensor_file
    from brdftab.spec import load_spec

    model = load_spec(_SPECS / f"{spec}.toml").model
    payload = rgl.prepare_rgl(model, n_theta_i=3, n_phi_i=3, resolution=6, vndf_resolution=8, ndf_resolution=8,
                              ndf_phi_resolution=4)
    bsdf = rgl.RGLBSDF(payload.fields, f"{spec}.bsdf")
    assert np.all(np.isfinite(bsdf.values))
    path = tmp_path / f"{spec}.bsdf"
    write_tensor_file(path, payload.fields)
    wi, wo = direction_pairs(11, 0.3, 0.3, n=200)
    ours = brdftab.open(path).eval_cos(wi, wo)
    with mi.variant_context("scalar_rgb"):
        ref = mitsuba_eval(path, _f32(wi), _f32(wo))
    ours = ours if ours.shape[-1] == 3 else np.repeat(ours, 3, axis=-1)
    # float32 arithmetic in Mitsuba: 5e-5 relative, and 1e-6 of the file's peak where f·cos is
    # tiny (a 2e-4-wide solar-cell peak leaves most pairs near 0)
    err = np.abs(ours - ref)
    bound = 5e-5 * np.abs(ref) + 1e-6 * np.abs(ref).max()
    print(f"{spec}: reader vs Mitsuba, worst error / bound {np.max(err / bound):.2g}")
    assert np.all(err <= bound), np.max(err / bound)


def test_a_table_with_missing_samples_is_refused_saying_so(tmp_path):
    """An RGL file stores no missing samples: a table with some (a netCDF's _FillValue) is refused
    in one line that names them as the cause."""
    import xarray as xr

    grid = {"type": "rusinkiewicz", "n_theta_h": 6, "n_theta_d": 5, "n_phi_d": 8}
    brdftab.save(brdftab.models.create("lambert", albedo=0.5), tmp_path / "a.nc", grid=grid)
    with xr.open_dataset(tmp_path / "a.nc") as ds:
        ds = ds.load()
    ds["brdf"].values[0, :, :, 0] = -999.0
    ds["brdf"].encoding["_FillValue"] = -999.0
    ds.to_netcdf(tmp_path / "fill.nc")
    with pytest.raises(BrdftabError, match=r"non-finite samples while writing an RGL \.bsdf file \(it has 40 missing "
                                           r"samples, which read as NaN"):
        brdftab.save(brdftab.open(tmp_path / "fill.nc"), tmp_path / "fill.bsdf")
    assert not (tmp_path / "fill.bsdf").exists()


def test_albedo_rule_follows_the_files_own_lobes(tmp_path):
    """A file's lobe away from the mirror direction (a GGX α = 0.05 lobe on facets tilted by 30°,
    as a pyramid's facets are) is integrated on the file's own warped samples: its albedo
    matches a fine product quadrature of the same file (Gauss–Legendre in cosθo × 1600
    azimuths) within 0.6 % (measured ≤ 0.41 %); the half-vector rule graded about the mirror
    direction was up to 14 % off (1.189 instead of 1.039 at θi = 60°)."""
    from brdftab.integrate import directional_albedo
    from brdftab.quadrature import gauss_legendre

    m = brdftab.models
    model = m.create("rotated", term=m.create("microfacet", alpha=0.05, fresnel="schlick", f0=0.9),
                     tilt=np.radians(30.0), tilt_azimuth=0.0)
    brdftab.save(model, tmp_path / "tilt.bsdf")
    b = brdftab.open(tmp_path / "tilt.bsdf")
    mu, wmu = gauss_legendre(400, 0.0, 1.0)
    ph = (np.arange(1600) + 0.5) * 2 * np.pi / 1600
    wo = rgl.sph(np.arccos(mu)[:, None], ph[None, :]).reshape(-1, 3)
    w = np.repeat(wmu, 1600) * 2 * np.pi / 1600
    for theta in (0.0, 20.0, 60.0):
        wi = rgl.sph(np.radians(theta), 0.0)
        fine = b.eval_cos(np.broadcast_to(wi, wo.shape), wo).T @ w
        got = directional_albedo(b, np.radians(theta), 0.0)
        np.testing.assert_allclose(got, fine, rtol=0.006, err_msg=f"θi = {theta}°")


# ---------------------------------------------------------------------------------------------
# The compiled evaluation is the numpy one


def _parity_excluded(bsdf, wi, wo):
    """Pairs within 1e-9 of where the last digit picks a branch: the horizon, the hold elevation
    (cosθo = cos θ_hold), the seam u = 0 ≡ 1 of the half vector's (relative) azimuth, and, for
    files mirrored into part of the φi circle, the mirror planes x = 0 and y = 0 of wi."""
    wi, wo = (np.array(w).reshape(-1, 3) for w in np.broadcast_arrays(wi, wo))
    wi = wi / np.linalg.norm(wi, axis=1, keepdims=True)
    wo = wo / np.linalg.norm(wo, axis=1, keepdims=True)
    eps = 1e-9
    out = (np.abs(wi[:, 2]) < 2 * eps) | (np.abs(wo[:, 2]) < 2 * eps)
    out |= np.abs(wo[:, 2] - np.cos(bsdf.theta_hold)) < eps
    if bsdf.reduction >= 2:
        out |= (np.abs(wi[:, 0]) < eps) | (np.abs(wi[:, 1]) < eps)
    m = wi + wo
    dphi = np.arctan2(m[:, 1], m[:, 0]) - (np.arctan2(wi[:, 1], wi[:, 0]) if bsdf.isotropic else 0.0)
    u = (dphi + np.pi) / (2 * np.pi)
    out |= np.abs(u - np.rint(u)) < eps
    return out


def _rgl_parity_pairs(n, seed):
    rng = np.random.default_rng(seed)
    wi, wo = (np.asarray(w, float) for w in direction_pairs(seed, 0.2, 0.3, n))
    k = n // 4
    wo[:k] = brdftab.geometry.sph_to_vec(np.radians(rng.uniform(80, 90, k)), rng.uniform(-np.pi, np.pi, k))
    wi[k:k + 5, 2] *= -1
    wi[k + 5:k + 10] *= 2.5
    wo[k + 10, 0] = np.nan
    # wi on the normal with each sign of its zeros (φi = atan2(±0, ±0): 0 or ±π)
    wi[k + 11:k + 27] = [[x, y, 1.0] for x in (0.0, -0.0) for y in (0.0, -0.0) for _ in range(4)]
    return wi, wo


@pytest.mark.parametrize("kind", ["rgb-isotropic", "one-slice", "anisotropic", "reduced-2", "reduced-4", "spectral"])
def test_compiled_evaluation_equals_numpy(kind):
    """The compiled evaluation is the numpy one (1e-12 relative) on every layout its passes
    tell apart: corners over θi only (isotropic), none (one slice), over φi and θi; mirrored
    files; RGB and spectral channels; inputs not unit, below the horizon, NaN, and wi on the
    normal with either sign of its zeros."""
    aniso = create("microfacet", alpha_x=0.15, alpha_y=0.4, fresnel="schlick", f0=[0.9, 0.6, 0.3])
    opts = dict(n_theta_i=5, resolution=24, vndf_resolution=32)
    lam = None
    if kind in ("rgb-isotropic", "one-slice"):
        fields = dict(rgl.prepare_rgl(recipe_model(), **opts).fields)
        if kind == "one-slice":
            # (the last θi: files of the second, third or fourth alone have a few pairs whose
            # f·cosθo, near a zero of the interpolant, moves by up to 3.3e-12 relative with the
            # last digit of an angle, in the earlier per-pair kernel as in this one)
            fields["theta_i"] = np.ascontiguousarray(fields["theta_i"][-1:])
            for k in ("vndf", "luminance", "rgb"):
                fields[k] = np.ascontiguousarray(fields[k][:, -1:])
    elif kind == "spectral":
        fields = dict(rgl.prepare_rgl(spectral_model(), **opts).fields)
        lam = [420.0, 500.0, 633.0]
    else:
        fields = dict(rgl.prepare_rgl(aniso, **opts).fields)
        if kind.startswith("reduced"):
            keep = slice(0, 9) if kind == "reduced-2" else slice(0, 5)
            for k in ("phi_i", "vndf", "luminance", "rgb"):
                fields[k] = np.ascontiguousarray(fields[k][keep])
    bsdf = rgl.RGLBSDF(fields)
    wi, wo = _rgl_parity_pairs(3000, 11)
    keep = ~_parity_excluded(bsdf, wi, wo)
    assert keep.mean() > 0.95
    got = bsdf.eval(wi, wo, lam)
    bsdf._eval = bsdf._eval_numpy
    try:
        want = BRDF.eval(bsdf, wi, wo, lam)
    finally:
        del bsdf._eval
    np.testing.assert_allclose(got[keep], want[keep], rtol=1e-12, atol=0)
    assert np.array_equal(np.isnan(got), np.isnan(want)) and np.all(got[(wi[:, 2] < 0)] == 0)
    ok = np.isfinite(wo).all(axis=1) & (wi[:, 2] > 0)
    a, b = wi[ok] / np.linalg.norm(wi[ok], axis=1, keepdims=True), wo[ok]
    k = keep[ok]
    np.testing.assert_allclose(bsdf.eval_cos(a, b, lam)[k], bsdf._eval_cos_numpy(a, b, lam)[k], rtol=1e-12, atol=0)
    # one direction against many (not contiguous in memory)
    lam_r = bsdf.layout.resolve(lam)
    want = bsdf._eval_numpy(np.broadcast_to(a[3], b.shape), b, lam_r, bsdf.layout.n_out(lam_r))
    keep = ~_parity_excluded(bsdf, a[3], b)
    np.testing.assert_allclose(bsdf.eval(a[3], b, lam)[keep], want[keep], rtol=1e-12, atol=0)


def test_compiled_parameter_cell_is_the_readers():
    """The compiled lookup of a parameter's cell (counting the values below p on axes of up to
    32 values, halving steps of a fixed count beyond; no branch on the value) is Marginal2D's:
    searchsorted(left) − 1 clipped to the cells, and its clamped weight, on grids of 1 to 90
    values, at nodes, their neighbours, the ends, beyond them and NaN."""
    import numba

    from brdftab._interp_kernels import COUNT_SEARCH, _param_cells
    from brdftab.models.fused import as_device

    cells = as_device(_param_cells)

    @numba.njit
    def run(vals, x):
        idx = np.empty(x.size, np.int64)
        wgt, lo, hi = np.empty(x.size), np.empty(x.size), np.empty(x.size)
        cells(vals, x, x.size, idx, wgt, lo, hi)
        return idx, wgt

    rng = np.random.default_rng(4)
    for n in (1, 2, 3, 5, 16, 17, COUNT_SEARCH, COUNT_SEARCH + 1, 33, 64, 90):
        vals = np.sort(rng.uniform(0.0, 1.5, n))
        x = np.concatenate([vals, np.nextafter(vals, -np.inf), np.nextafter(vals, np.inf), [-1.0, 2.0, np.nan],
                            rng.uniform(-0.1, 1.6, 300)])
        got_i, got_w = run(vals, x)
        if n == 1:
            assert np.all(got_i == 0) and np.all(got_w == 0.0)
            continue
        i = np.clip(np.searchsorted(vals, x, "left") - 1, 0, n - 2)
        with np.errstate(invalid="ignore"):
            w = np.clip((x - vals[i]) / (vals[i + 1] - vals[i]), 0.0, 1.0)
        np.testing.assert_array_equal(got_i, np.where(np.isnan(x), 0, i))
        np.testing.assert_array_equal(got_w, w)


def test_a_spectral_table_becomes_a_spectral_file_mitsuba_reads(files):
    """A spectral aluminium table (31 wavelengths, 400-700 nm) converted to .bsdf keeps its
    wavelengths ('spectra' + 'wavelengths'); Mitsuba's scalar_spectral variant loads the file and
    reproduces the table at wavelengths on and between the stored ones (θi, θo ≤ 80°): median
    0.10 %, 95th percentile 0.55 %."""
    from brdftab.grids.rusinkiewicz import RusinkiewiczGrid

    from brdftab.table import tabulate

    model = create("microfacet", alpha=0.3, fresnel="conductor", material="Al")  # n, k from the database
    lam31 = np.linspace(400.0, 700.0, 31)

    brdftab.save(tabulate(model, RusinkiewiczGrid(30, 30, 60), lam31, progress=False), files / "al-spectral.nc",
                 overwrite=True)
    table = brdftab.open(files / "al-spectral.nc")
    out = files / "al-spectral.bsdf"
    brdftab.save(table, out, overwrite=True)  # what convert writes (its checks are tested elsewhere)
    raw = parse_tensor(out.read_bytes())
    assert "rgb" not in raw and raw["spectra"].shape[2] == 31
    np.testing.assert_array_equal(raw["wavelengths"], lam31.astype(np.float32))
    wi, wo = direction_pairs(11, 0.3, 0.3, n=300)
    keep = (wi[:, 2] >= np.cos(np.radians(80.0))) & (wo[:, 2] >= np.cos(np.radians(80.0)))
    wi, wo = wi[keep], wo[keep]
    lam = [450.0, 555.0, 632.8, 690.0]  # Mitsuba's spectral variants carry four wavelengths
    with mi.variant_context("scalar_spectral"):
        got = mitsuba_eval(out, wi, wo, lam)
    ref = np.asarray(table.eval(wi, wo, lam), float) * wo[:, 2:3]
    rel, _ = rel_errors(got, ref, 1e-3 * ref.max())
    assert_percentiles("Al spectral table -> .bsdf, Mitsuba vs table", rel, {50: 0.005, 95: 0.02})


@pytest.mark.parametrize("anisotropic", [False, True])
def test_a_warp_fixed_at_one_incidence_is_the_same_warp(files, anisotropic):
    """Marginal2D.fixed (the warp of one incidence, tables interpolated once) samples, inverts
    and evaluates to the same bits as the warp interpolated at every point, at incidences on
    and between the file's nodes."""
    from brdftab.formats._marginal2d import Marginal2D

    model = create("microfacet", alpha_x=0.15, alpha_y=0.4 if anisotropic else 0.15, fresnel="schlick", f0=0.5)
    path = files / f"fixed-{anisotropic}.bsdf"
    brdftab.save(model, path, resolution=12, vndf_resolution=16, n_theta_i=5, **({"n_phi_i": 5} if anisotropic else {}))
    raw = parse_tensor(path.read_bytes())
    warp = Marginal2D(raw["vndf"], (raw["phi_i"], raw["theta_i"]))
    s = np.random.default_rng(0).random((4000, 2))
    for ph, th in ((0.0, 0.0), (float(raw["phi_i"][-1]), float(raw["theta_i"][2])), (0.7, 0.61), (-2.0, 1.5)):
        if not anisotropic:
            ph = 0.0
        params = (np.full(len(s), ph), np.full(len(s), th))
        one = warp.fixed((ph, th))
        for a, b in zip(warp.sample(s, params), one.sample(s)):
            np.testing.assert_array_equal(a, b)
        u, _ = warp.sample(s, params)
        for a, b in zip(warp.invert(u, params), one.invert(u)):
            np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(warp.eval(u, params), one.eval(u))


def test_auto_warp_writes_the_file_closer_to_the_table(files):
    """A table's D comes from its back-scattering; its file gets the level warp or the lobe warp
    (option ``warp``), ``auto`` the one whose reading reproduces the table better, with node
    samples or least-squares values (option ``values``; formats/rgl-bsdf.md, steps 3 and 4):
    judged at independent pairs by what ``auto`` minimizes, max(median / 1 %, p95 / 10 %) of
    the relative error of f, the file ``auto`` writes is within 5 % of the better of the level
    and lobe files with node samples or better. The Lambertian table gets the level warp and
    its node samples (the fit is tried only where node samples miss: FIT_WHEN_SCORE)."""
    from brdftab.grids.rusinkiewicz import RusinkiewiczGrid

    glossy = create("sum", terms=[create("lambert", albedo=0.1),
                                  create("microfacet", alpha=0.1, fresnel="schlick", f0=[0.9, 0.6, 0.3])])
    wi, wo = direction_pairs(23, 0.1, 0.1, 2000)
    keep = (wi[:, 2] >= np.cos(np.radians(80.0))) & (wo[:, 2] >= np.cos(np.radians(80.0)))
    wi, wo = wi[keep], wo[keep]
    for name, model in (("lambert", create("lambert", albedo=0.99)), ("glossy", glossy)):
        table = _table(model, RusinkiewiczGrid(30, 30, 60), files / f"warp-{name}.nc")
        ref = np.asarray(table.eval(wi, wo), float)
        big = ref > 1e-3 * np.percentile(ref, 99)
        score = {}
        for warp, values in (("auto", "auto"), ("level", "nodes"), ("lobe", "nodes")):
            path = files / f"warp-{name}-{warp}.bsdf"
            brdftab.save(table, path, warp=warp, values=values)
            got = np.asarray(brdftab.open(path).eval(wi, wo), float)[:, :ref.shape[1]]  # grey: R of R, G, B
            rel = np.abs(got[big] / ref[big] - 1)
            score[warp] = max(np.median(rel) / 0.01, np.percentile(rel, 95) / 0.1)
            if warp == "auto":
                chosen = (_warp(path), _provenance(path)["values"])
        print(f"{name}: auto chose {chosen}; score auto {score['auto']:.3f}, level {score['level']:.3f}, "
              f"lobe {score['lobe']:.3f}")
        assert score["auto"] <= 1.05 * min(score["level"], score["lobe"]), (chosen, score)
        if name == "lambert":
            assert chosen == ("level", "nodes") and score["level"] < score["lobe"]


def test_one_incidence_table_file_has_finite_sigma(files):
    """A table written with one θi node (the level warp's σ is blended between θi nodes: with
    one node there is nothing to blend) gives a finite σ and the table's value, not NaN samples
    blamed on the source."""
    from brdftab.grids.rusinkiewicz import RusinkiewiczGrid

    table = _table(create("lambert", albedo=0.5), RusinkiewiczGrid(10, 10, 20), files / "one-theta-i.nc")
    for warp in ("level", "auto"):
        path = files / f"one-theta-i-{warp}.bsdf"
        brdftab.save(table, path, theta_i_deg=[0.0], warp=warp)
        read = brdftab.open(path)
        assert np.isfinite(np.asarray(read.fields["sigma"])).all()
        wo = np.array([[0.3, 0.0, 0.95]]) / np.linalg.norm([0.3, 0.0, 0.95])
        assert np.asarray(read.eval(np.array([[0.0, 0.0, 1.0]]), wo))[0, 0] == pytest.approx(0.5 / np.pi, rel=0.02)


@pytest.mark.parametrize("anisotropic, reduction", [(False, 0), (True, 1), (True, 2), (True, 4)])
def test_stored_weights_are_the_readers_interpolation(anisotropic, reduction):
    """The reading as a linear map of the stored values (what the least-squares values of
    ``values = "fit"`` solve with) reproduces the reader's f·cosθo to 1e-12 at random pairs,
    in isotropic and anisotropic files, whole or reduced (φi mirrored into [−π, 0] or
    [−π, −π/2]), with 0 rows below the horizon."""
    if anisotropic:
        model = create("microfacet", alpha_x=0.15, alpha_y=0.4, fresnel="schlick", f0=[0.9, 0.6, 0.3])
        fields = dict(rgl.prepare_rgl(model, n_theta_i=5, n_phi_i=9, resolution=12, vndf_resolution=16).fields)
        keep = slice(0, {1: 9, 2: 5, 4: 3}[reduction])  # φi over [−π, π], [−π, 0], [−π, −π/2]
        for k in ("phi_i", "vndf", "luminance", "rgb"):
            fields[k] = np.ascontiguousarray(fields[k][keep])
    else:
        model = create("sum", terms=[create("lambert", albedo=0.2), create("microfacet", alpha=0.2, fresnel="schlick",
                                                                              f0=[0.9, 0.6, 0.3])])
        fields = dict(rgl.prepare_rgl(model, n_theta_i=6, resolution=12, vndf_resolution=16).fields)
    b = rgl.RGLBSDF(fields)
    assert b.reduction == reduction
    wi, wo = direction_pairs(5, 0.2, 0.2, 3000)
    wo[:50, 2] *= -1.0  # below the horizon
    a = b.stored_weights(wi, wo)
    stored = np.moveaxis(fields["rgb"], 2, -1).reshape(-1, 3).astype(np.float64)
    ref = b.eval_cos(wi, wo)
    assert a.shape == (wi.shape[0], stored.shape[0]) and a[:50].nnz == 0
    assert np.abs(a @ stored - ref).max() <= 1e-12 * np.abs(ref).max()


def test_fitted_values_read_a_rough_table_closer(files):
    """``values = "fit"`` (least-squares stored values, formats/rgl-bsdf.md step 4): a glossy table
    with 4 % sample noise (a measured table's roughness, finer than the file's sample cells)
    written with the fit reads closer to the table at independent pairs than with node samples
    (median relative error of f at θi, θo ≤ 80°, 9 θi x 24 x 24 samples: measured 1.70 % →
    1.51 %), the provenance says which; ``values = "auto"`` chooses the fit where it also passes
    the grazing bands (32 x 32 samples: 1.60 % → 1.46 %)."""
    from brdftab.grids.rusinkiewicz import RusinkiewiczGrid
    from brdftab.table import tabulate

    model = create("sum", terms=[create("lambert", albedo=0.3),
                                 create("microfacet", alpha=0.25, fresnel="schlick", f0=[0.9, 0.6, 0.3])])
    t = tabulate(model, RusinkiewiczGrid(24, 24, 48), progress=False)
    noise = np.exp(0.04 * np.random.default_rng(3).standard_normal(t.ds["brdf"].shape))
    t.ds["brdf"].values = t.ds["brdf"].values * noise
    path = files / "rough.nc"
    brdftab.save(t, path)
    table = brdftab.open(path)
    wi, wo = direction_pairs(11, 0.1, 0.1, 3000)
    keep = (wi[:, 2] >= np.cos(np.radians(80.0))) & (wo[:, 2] >= np.cos(np.radians(80.0)))
    wi, wo = wi[keep], wo[keep]
    ref = np.asarray(table.eval(wi, wo), float)
    med = {}
    for values, n in (("nodes", 24), ("fit", 24), ("nodes", 32), ("auto", 32)):
        out = files / f"rough-{values}-{n}.bsdf"
        brdftab.save(table, out, values=values, warp="lobe", n_theta_i=9, resolution=n, vndf_resolution=32)
        med[values, n] = float(np.median(np.abs(np.asarray(brdftab.open(out).eval(wi, wo), float) / ref - 1)))
        assert _provenance(out)["values"] == ("nodes" if values == "nodes" else "fit")
    print("rough table -> .bsdf, median error: " + ", ".join(f"{v} {n}: {100 * m:.2f} %" for (v, n), m in med.items()))
    assert med["fit", 24] < 0.95 * med["nodes", 24] and med["auto", 32] < med["nodes", 32]
    with pytest.raises(ParameterError, match="values"):
        rgl.prepare_rgl(table, values="lsq")


def test_fitted_values_keep_the_sources_negative_samples():
    """``values = "fit"`` sets only the negatives the fit makes beyond the node samples' own to
    their bound (formats/rgl-bsdf.md step 4): a measured RGB file may hold negative values in
    one channel (a colour conversion of noisy spectra: a real film's red is negative in its
    mirror peak), and the fit keeps them negative, so the file reads them with their sign. The
    former clamp at 0 turned every negative sample positive (the film's file read 100 % off)."""

    class RedBelowZero(BRDF):
        """A glossy base with its red lowered by a constant: negative where the base is dim."""

        name = "red-below-zero"

        def __init__(self, base):
            self.base, self.layout, self.isotropic, self.reciprocal = base, base.layout, True, True

        def _eval(self, wi, wo, lam, n):
            return self.base._eval(wi, wo, lam, n) - np.array([0.04, 0.0, 0.0])

    source = RedBelowZero(create("sum", terms=[create("lambert", albedo=[0.05, 0.3, 0.4]),
                                               create("microfacet", alpha=0.2, fresnel="schlick",
                                                      f0=[0.1, 0.6, 0.3])]))
    payload = rgl.prepare_rgl(source, ndf="backscatter", warp="lobe", values="fit", n_theta_i=9, resolution=24,
                              vndf_resolution=32)
    assert _json_provenance(payload)["values"] == "fit"
    assert (payload.fields["rgb"][:, :, 0] < 0).mean() > 0.2, "the source's negative red is not in the file"
    wi, wo = direction_pairs(31, 0.2, 0.2, 3000)
    keep = (wi[:, 2] >= np.cos(np.radians(80.0))) & (wo[:, 2] >= np.cos(np.radians(80.0)))
    ref = np.asarray(source.eval(wi[keep], wo[keep]), float)[:, 0]
    got = np.asarray(rgl.RGLBSDF(payload.fields).eval(wi[keep], wo[keep]), float)[:, 0]
    below = ref < -0.01
    rel = np.abs(got[below] / ref[below] - 1)
    print(f"red below -0.01 at {below.sum()} pairs; read negative at {(got[below] < 0).mean():.3f} of them, "
          f"median error {100 * np.median(rel):.2f} %")
    assert below.sum() > 100 and (got[below] < 0).mean() > 0.99 and np.median(rel) < 0.03


def test_lobe_warp_follows_a_lobe_that_brightens_towards_grazing(monkeypatch, tmp_path):
    """One D serves every incidence: a haze lobe whose Fresnel factor rises ~300x towards grazing
    (GGX α = 0.06, Schlick F0 = 0.001) under a clear coat (α = 0.01, F0 = 0.02) over a
    Lambertian is nearly absent from the back-scattering the file's D comes from, so near the
    mirror direction at grazing incidence the stored values f·cosθo·4σ/D change by decades from
    one sample to the next (as a real film's and a glossy coating's peaks do). The lobe warp's
    share that follows their steepness at each incidence (formats/rgl-bsdf.md step 3,
    ``STEEP_SHARE``) puts samples there: Mitsuba's reading of the file, at convert's check
    points (half near the mirror direction) with θi, θo <= 80°, is within a median of 3 % and
    a 95th percentile of 10 % of the model (measured 1.9 % and 6.1 %); the file written
    without that share reads 4.5 % and 30 % (brdftab's reader, Mitsuba's to float32)."""
    from brdftab.convert import check_points
    from brdftab.formats import _rgl_write

    model = create("sum", terms=[create("lambert", albedo=[0.05, 0.06, 0.08]),
                                 create("microfacet", alpha=0.01, fresnel="schlick", f0=[0.02] * 3),
                                 create("microfacet", alpha=0.06, fresnel="schlick", f0=[1e-3] * 3)])
    wi, wo = check_points(None, 4096, 0)
    keep = (wi[:, 2] >= np.cos(np.radians(80.0))) & (wo[:, 2] >= np.cos(np.radians(80.0)))
    wi, wo = _f32(wi[keep]), _f32(wo[keep])
    ref = np.asarray(model.eval(wi, wo), float) * wo[:, 2:3]
    big = ref > 1e-3 * np.percentile(ref, 99)

    def errors(fields=None, path=None):
        if path is not None:
            with mi.variant_context("scalar_rgb"):
                got = mitsuba_eval(path, wi, wo)
        else:
            got = np.asarray(rgl.RGLBSDF(fields).eval_cos(wi, wo), float)
        return np.abs(got[big] - ref[big]) / ref[big]

    path = tmp_path / "haze.bsdf"
    rgl.write_rgl(rgl.prepare_rgl(model, ndf="backscatter", warp="lobe", values="nodes"), path)
    rel = errors(path=path)
    assert_percentiles("haze lobe rising towards grazing, Mitsuba vs the model", rel, {50: 0.03, 95: 0.10})
    monkeypatch.setattr(_rgl_write, "STEEP_SHARE", 0.0)
    without = errors(rgl.prepare_rgl(model, ndf="backscatter", warp="lobe", values="nodes").fields)
    print(f"without the steepness share: median {100 * np.median(without):.2f} %, "
          f"p95 {100 * np.percentile(without, 95):.2f} %")
    assert np.percentile(without, 95) > 0.2


def test_auto_keeps_node_samples_where_the_fit_reads_farther_off_at_grazing_directions(monkeypatch):
    """``values = "auto"`` judges the fitted values up to 80° and in four grazing bands (θi in
    80-85° and 85-89° with θo within 80°, and swapped; formats/rgl-bsdf.md step 4): a
    Lambertian at 16 x 16 samples with the lobe warp without its steepness share, whose fit
    reads closer up to 80° but several times farther off at grazing incidence (measured 2.4 %
    -> 22 %), keeps its node samples; ``values = "fit"`` writes the fit, and at
    independent pairs with θi in 85-89° and θo within 80° it is the farther off of the two
    (95th percentile of the relative error of Mitsuba's f·cosθo). The share is off here because
    with it, which follows log cosθo towards the horizon, this Lambertian's fit reads closer at
    grazing directions too (p95 4.1 % -> 2.6 %) and is kept: the guard has nothing to refuse
    there. The guard itself does not depend on the warp."""
    from brdftab.formats import _rgl_write

    monkeypatch.setattr(_rgl_write, "STEEP_SHARE", 0.0)
    model = create("lambert", albedo=[0.2, 0.5, 0.8])
    rng = np.random.default_rng(8)
    n = 3000
    wi = rgl.sph(np.radians(rng.uniform(85.0, 89.0, n)), rng.uniform(-np.pi, np.pi, n))
    wo = rgl.sph(np.arccos(rng.uniform(np.cos(np.radians(80.0)), 1.0, n)), rng.uniform(-np.pi, np.pi, n))
    ref = model.eval(wi, wo) * wo[:, 2:3]
    p95 = {}
    for values in ("auto", "fit"):
        fields = rgl.prepare_rgl(model, resolution=16, values=values, warp="lobe").fields
        assert json.loads(bytes(fields["provenance"]).decode())["values"] == ("nodes" if values == "auto" else "fit")
        p95[values] = float(np.percentile(np.abs(rgl.RGLBSDF(fields).eval_cos(wi, wo) / ref - 1), 95))
    print(f"Lambert at 16 x 16, lobe warp, θi 85-89°: p95 node samples {100 * p95['auto']:.1f} %, "
          f"fit {100 * p95['fit']:.1f} %")
    assert p95["fit"] > 5.0 * p95["auto"]


def test_non_finite_direction_reads_nan_in_both_evaluations():
    """A direction with a NaN component reads NaN in the compiled evaluation and in its numpy
    reference alike (the numpy reference turned the NaN into an index and raised IndexError),
    and the other pairs are unchanged; the linear map of the stored values has a 0 row there."""
    from brdftab.brdf import numpy_reference

    b = rgl.RGLBSDF(rgl.prepare_rgl(create("microfacet", alpha=0.3), n_theta_i=5, resolution=12,
                                    vndf_resolution=16).fields)
    wi = np.array([[np.nan, 0.0, 1.0], [0.0, 0.0, 1.0], [0.2, 0.1, np.inf]])
    wo = np.array([[0.3, 0.0, 0.95], [0.3, 0.0, 0.95], [0.3, 0.0, 0.95]])
    compiled = b.eval_cos(wi, wo)
    with numpy_reference():
        reference = b.eval_cos(wi, wo)
    assert np.isnan(compiled[[0, 2]]).all() and np.isnan(reference[[0, 2]]).all()
    assert reference[1] == pytest.approx(compiled[1], rel=1e-12) and compiled[1, 0] > 0
    assert b.stored_weights(wi, wo)[[0, 2]].nnz == 0


def test_vndf_resolution_of_two_is_refused():
    """With a 2 x 2 vndf table every node lies on an edge of the square, where the warp vanishes
    (θm = 0 or 90°): the slices were all NaN. At least 3 is asked for, in one line."""
    with pytest.raises(ParameterError, match=r"vndf_resolution: expected a whole number in \[3, "):
        rgl.prepare_rgl(create("lambert", albedo=0.5), vndf_resolution=2)
    fields = rgl.prepare_rgl(create("lambert", albedo=0.5), n_theta_i=3, resolution=8, vndf_resolution=3).fields
    assert np.isfinite(fields["vndf"]).all() and (fields["vndf"] > 0).any()


def test_auto_fits_isotropic_rgb_files_only():
    """``values = "auto"`` leaves spectral and anisotropic files with their node samples
    (formats/rgl-bsdf.md step 4: the fit took a 31-wavelength table 2.2 → 23 s for a median of
    1.005 → 0.974 %, an anisotropic one 4.2 → 24 s), where the same source in an isotropic RGB
    file is fitted; ``values = "fit"`` fits them all."""
    rough = create("sum", terms=[create("lambert", albedo=0.3), create("microfacet", alpha=0.25)])
    small = dict(ndf="backscatter", n_theta_i=7, resolution=12, vndf_resolution=16)
    cases = ((recipe_model(), {}, "fit"), (spectral_model(), {}, "nodes"),
             (rough, {"anisotropic": True, "n_phi_i": 5, "ndf_phi_resolution": 16}, "nodes"))
    for model, extra, want in cases:
        for values, expect in (("auto", want), ("fit", "fit")):
            fields = rgl.prepare_rgl(model, values=values, **small, **extra).fields
            assert json.loads(bytes(fields["provenance"]).decode())["values"] == expect, (model.name, extra, values)
