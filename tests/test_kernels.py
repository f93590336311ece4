"""Compiled kernels against the numpy code they replace (:func:`brdftab.brdf.numpy_reference`).

Every registered D, G and F component that has a scalar form is fused into a kernel with
fixed partners and compared with the array methods to 1e-12 relative, over random pairs
plus the rows the BRDF protocol treats specially: below and exactly on the horizon,
non-unit, huge and tiny directions, NaN and inf (NaN in both), grey, RGB and spectral
channels. The models whose evaluation is compiled are listed, so a kernel that silently
stops being used (the numpy path taken instead) fails here.
"""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from _kernels import RTOL, assert_parity as _assert_parity

from brdftab import models
from brdftab._jit import cache_dir
from brdftab.brdf import numpy_reference
from brdftab.errors import ParameterError
from brdftab.models import components as C

ROOT = Path(__file__).resolve().parents[1]


def _compiled(kind):
    """The registered components of ``kind`` that have scalar forms."""
    need = {"distribution": ("jit_D", "jit_lambda"), "shadowing": ("jit_G",), "fresnel": ("jit_F",)}[kind]
    return sorted(n for n, cls in C.COMPONENTS[kind].items() if all(getattr(cls, a) is not None for a in need))


_FRESNEL_VALUES = {"schlick": dict(f0=[0.04, 0.5, 0.95]), "dielectric": dict(n=[1.2, 1.5, 0.7]),
                   "conductor": dict(n=[0.2, 0.45, 1.3], k=[3.4, 2.6, 1.8]),
                   "rayleigh-rice": dict(n=[0.2, 1.5, 1.3], k=[3.4, 0.0, 1.8]), "none": {}}


#: Parameters of the distributions that take other roughness parameters than α or α_x, α_y.
_DISTRIBUTION_VALUES = {"torrance-sparrow": [dict(c_per_deg=0.05), dict(c_per_deg=0.5), dict(c_per_deg=0.005)]}


@pytest.mark.parametrize("dist", _compiled("distribution"))
def test_every_compiled_distribution_matches_numpy(dist):
    for i, rough in enumerate(_DISTRIBUTION_VALUES.get(dist, [dict(alpha=0.3), dict(alpha_x=0.05, alpha_y=0.6)])):
        _assert_parity(models.create("microfacet", distribution=dist, shadowing="smith", fresnel="none", **rough),
                       seed=i)


@pytest.mark.parametrize("shadowing", _compiled("shadowing"))
def test_every_compiled_shadowing_matches_numpy(shadowing):
    _assert_parity(models.create("microfacet", distribution="beckmann", alpha_x=0.2, alpha_y=0.4, shadowing=shadowing,
                                 fresnel="none"), seed=3)


@pytest.mark.parametrize("fresnel", _compiled("fresnel"))
def test_every_compiled_fresnel_matches_numpy(fresnel):
    values = _FRESNEL_VALUES.get(fresnel)
    assert values is not None, f"teach this test the parameters of the Fresnel term {fresnel!r}"
    _assert_parity(models.create("microfacet", distribution="ggx", alpha=0.15, fresnel=fresnel, **values), seed=4)


def test_spectral_and_grey_channels_match_numpy():
    spectral = models.create("microfacet", distribution="ggx", alpha=0.2, fresnel="conductor",
                             n={"wavelengths_nm": [400, 550, 700], "values": [1.5, 0.4, 0.2]},
                             k={"wavelengths_nm": [400, 550, 700], "values": [1.9, 2.5, 4.0]})
    _assert_parity(spectral, wavelengths=np.linspace(400, 700, 7))
    _assert_parity(models.create("microfacet", distribution="ggx", alpha=0.2, fresnel="dielectric", n=1.5))


def test_combinators_and_lambert_match_numpy():
    gold = models.create("microfacet", distribution="ggx", alpha=0.2, fresnel="conductor", n=[0.2, 0.45, 1.3],
                         k=[3.4, 2.6, 1.8])
    white = models.create("lambert", albedo=0.7)
    pair = models.create("sum", terms=[white, gold])
    _assert_parity(white)
    _assert_parity(pair)
    _assert_parity(models.create("scale", factor=[0.2, 0.5, 0.9], term=pair))
    # a scaled term inside a sum adds to what the sum holds already
    _assert_parity(models.create("sum", terms=[gold, models.create("scale", factor=0.5, term=white)]))


def test_compiled_evaluation_keeps_the_input_rules():
    m = models.create("microfacet", distribution="ggx", alpha=0.3)
    with pytest.raises(ParameterError, match="zero length"):
        m.eval([[0.0, 0.0, 0.0]], [[0.0, 0.0, 1.0]])
    f = m.eval([[0.0, 0.0, 2.0], [np.nan, 0, 1], [0, 0, -1]], [[0.0, 0.0, 1.0]] * 3)
    assert f[0, 0] == pytest.approx(1.0 / (4 * np.pi * 0.09)) and np.isnan(f[1, 0]) and f[2, 0] == 0


#: Registered components that have no scalar form yet: their models are evaluated by numpy.
NOT_COMPILED = {("distribution", "pyramid"), ("shadowing", "pyramid")}


def test_every_component_but_the_listed_ones_has_a_kernel():
    missing = {(kind, n) for kind in C.COMPONENTS for n in C.COMPONENTS[kind] if n not in _compiled(kind)}
    assert missing == NOT_COMPILED


def test_a_composition_compiles_once_per_machine(tmp_path):
    """A second process loads the fused kernel from the on-disk caches: nothing compiles."""
    code = ("import numpy as np, sys\n"
            "from brdftab import models\n"
            "m = models.create('microfacet', distribution='beckmann', alpha=0.37, shadowing='smith-height-correlated',"
            " fresnel='schlick', f0=0.25)\n"
            "m.eval([0.1, 0.2, 0.9], [0.3, -0.1, 0.8])\n"
            "mod = next(v for k, v in sys.modules.items() if k.startswith('_brdftab_microfacet_'))\n"
            "s = mod.run.stats\n"
            "print(sum(s.cache_hits.values()), sum(s.cache_misses.values()))\n")
    env = dict(os.environ, BRDFTAB_CACHE_DIR=str(tmp_path / "kernels"), NUMBA_CACHE_DIR=str(tmp_path / "numba"),
               PYTHONPATH=str(ROOT))
    first = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    second = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert first.stdout.split() == ["0", "1"], first.stdout + first.stderr
    assert second.stdout.split() == ["1", "0"], second.stdout + second.stderr


def test_the_kernel_cache_falls_back_when_its_folder_cannot_be_written(tmp_path, monkeypatch):
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    monkeypatch.setenv("BRDFTAB_CACHE_DIR", str(blocker / "kernels"))  # under a file: never a folder
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cache_dir() == tmp_path / "xdg" / "brdftab" / "kernels"


def _assert_tabulation_parity(m, grid, wavelengths=None, dtype="float64"):
    """Structured tabulation against pair-by-pair numpy evaluation of the grid's nodes, leaving
    out nodes within 1e-9 of the horizon (where the last digit of cosθ decides)."""
    from brdftab import tabulate

    lam = m.layout.resolve(wavelengths)
    values = np.empty(grid.shape + (m.layout.n_out(lam),), dtype)
    assert m.tabulate_into(grid, lam, values.shape[-1], values), f"{m.describe()}: no structured tabulation"
    got = tabulate(m, grid, wavelengths, dtype=dtype, progress=False).values
    np.testing.assert_array_equal(got, values)
    with numpy_reference():
        assert not m.tabulate_into(grid, lam, values.shape[-1], values)
        ref = tabulate(m, grid, wavelengths, dtype=dtype, progress=False).values
    wi, wo = grid.directions()
    far = (np.minimum(wi[:, 2], wo[:, 2]) > 1e-9).reshape(grid.shape)
    g, r = got[far], ref[far]
    assert np.array_equal(g == 0, r == 0)
    rel = np.abs(g - r) / np.maximum(np.abs(r), 1e-300)
    # float32 tables: values 1e-12 apart round to the same float32 or to neighbours (2⁻²⁴)
    tol = RTOL if np.dtype(dtype) == np.float64 else 2.0 ** -23
    assert rel.max() <= tol, f"{m.describe()}: {rel.max():.3g}"


def test_structured_tabulation_matches_pair_by_pair_evaluation():
    from brdftab.grids import RusinkiewiczGrid, merl_grid

    gold = models.create("microfacet", distribution="ggx", alpha=0.25, fresnel="conductor", n=[0.2, 0.45, 1.3],
                         k=[3.4, 2.6, 1.8])
    _assert_tabulation_parity(gold, merl_grid())
    _assert_tabulation_parity(gold, RusinkiewiczGrid(12, 15, 20, phi_d_fold="none"), dtype="float32")
    aniso = models.create("microfacet", distribution="beckmann", alpha_x=0.1, alpha_y=0.4, shadowing="v-groove",
                          fresnel="rayleigh-rice", n=[1.5, 0.2, 1.3], k=[0.0, 3.0, 1.0])
    _assert_tabulation_parity(aniso, RusinkiewiczGrid(16, 20, 24, phi_h=12))
    spectral = models.create("microfacet", distribution="ggx", alpha=0.4, shadowing="smith-height-correlated",
                             fresnel="dielectric", n={"wavelengths_nm": [400, 700], "values": [1.6, 1.4]})
    _assert_tabulation_parity(spectral, RusinkiewiczGrid(10, 12, 14), wavelengths=[400.0, 550.0, 700.0])


@pytest.mark.parametrize("grid", ["merl", "aniso", "gonio", "gonio-specular"])
def test_compiled_grid_directions_are_the_same_bits(grid):
    from brdftab.grids import RusinkiewiczGrid, SphericalGrid, merl_grid

    r = np.radians
    g = {"merl": lambda: merl_grid(), "aniso": lambda: RusinkiewiczGrid(7, 8, 9, phi_h=5, phi_d_fold="none"),
         "gonio": lambda: SphericalGrid(r([0, 30, 60, 89]), r([0, 45]), r(np.linspace(0, 90, 7)),
                                        r(np.linspace(-180, 170, 9))),
         "gonio-specular": lambda: SphericalGrid(r([10, 30, 60, 89]), r([0, 45]), r(np.linspace(-10, 10, 7)),
                                                 r(np.linspace(-5, 5, 9)), relative_to="specular")}[grid]()
    wi_ref, wo_ref = g.directions()
    for lo, hi in ((0, g.size), (3, 8), (g.size - 5, g.size)):
        wi, wo = np.empty((hi - lo, 3)), np.empty((hi - lo, 3))
        g.directions_into(lo, hi, wi, wo)
        assert np.array_equal(wi, wi_ref[lo:hi]) and np.array_equal(wo, wo_ref[lo:hi])


def test_compiled_tabulation_of_any_compiled_model_matches_numpy():
    """A model with a kernel but no structured tabulation (a sum) is tabulated through the grid's
    compiled directions, in float64 and float32, on a gonio grid and a Rusinkiewicz grid."""
    from brdftab import tabulate
    from brdftab.grids import RusinkiewiczGrid, SphericalGrid

    r = np.radians
    m = models.create("sum", terms=[models.create("lambert", albedo=[0.1, 0.2, 0.3]),
                                    models.create("microfacet", alpha=0.2, fresnel="schlick", f0=0.5)])
    for grid in (RusinkiewiczGrid(20, 22, 24), SphericalGrid(r([0, 40, 80]), r([0, 90]), r(np.linspace(0, 90, 31)),
                                                             r(np.linspace(-180, 180, 37)))):
        for dtype in ("float64", "float32"):
            got = tabulate(m, grid, dtype=dtype, chunk_size=1000, progress=False).values
            with numpy_reference():
                ref = tabulate(m, grid, dtype=dtype, progress=False).values
            assert np.array_equal(got == 0, ref == 0)
            tol = RTOL if dtype == "float64" else 2.0 ** -23
            assert np.max(np.abs(got - ref) / np.where(ref > 0, ref, 1.0)) <= tol


def test_compiled_evaluation_needs_little_beyond_its_output():
    """Peak memory of model.eval on many pairs: within 2x the output array (numpy's chunked
    path kept its temporaries to a few tens of MB; the kernels keep none)."""
    import tracemalloc

    m = models.create("microfacet", distribution="ggx", alpha=0.3, fresnel="conductor", n=[0.2, 0.45, 1.3],
                      k=[3.4, 2.6, 1.8])
    rng = np.random.default_rng(5)
    wi = rng.normal(size=(1_000_000, 3))
    wi[:, 2] = np.abs(wi[:, 2])
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo = wi[::-1].copy()
    m.eval(wi[:10], wo[:10])  # compiled and loaded before measuring
    tracemalloc.start()
    try:
        out = m.eval(wi, wo)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak <= 2 * out.nbytes, f"peak {peak / 1e6:.1f} MB for a {out.nbytes / 1e6:.1f} MB result"


# -- Torrance–Sparrow, Bitterling's α(θi), Small 2021 -----------------------------------------

_RGB_CONDUCTOR = dict(n=[0.2, 0.45, 1.3], k=[3.4, 2.6, 1.8])
_SPECTRUM = {"wavelengths_nm": [400, 550, 700], "values": [1.6, 1.4, 1.3]}


def test_torrance_sparrow_matches_numpy():
    ts = "torrance-sparrow-1967"
    _assert_parity(models.create(ts, rho_d=0.5))                                  # Fig. 8: F = 1, grey
    _assert_parity(models.create(ts, rho_d=[0.2, 0.5, 0.9], g=5.0, c_per_deg=0.2, fresnel="conductor",
                                 **_RGB_CONDUCTOR), seed=1)
    _assert_parity(models.create(ts, rho_d=0.3, c_per_deg=0.005, fresnel="dielectric", n=1.5), seed=2)
    _assert_parity(models.create(ts, rho_d={"wavelengths_nm": [400, 700], "values": [0.2, 0.6]}, g=0.0,
                                 fresnel="schlick", f0=_SPECTRUM | {"values": [0.04, 0.5, 0.9]}),
                   wavelengths=np.linspace(400, 700, 4), seed=3)
    _assert_parity(models.create(ts, rho_d=0.4, c_per_deg=2.0, fresnel="rayleigh-rice", n=_SPECTRUM, k=0.1),
                   wavelengths=np.linspace(400, 700, 5), seed=4)


def test_cook_torrance_alpha_theta_matches_numpy():
    fit = dict(n=1.43, p1=0.1012, p2=2.661, p3=np.radians(51.51), p4=0.2199)
    ct = "cook-torrance-alpha-theta"
    _assert_parity(models.create(ct, r_dh_lam=0.011, **fit))                      # the paper's fit
    _assert_parity(models.create(ct, distribution="beckmann", **fit), seed=1)     # no diffuse part
    _assert_parity(models.create(ct, distribution="beckmann", r_dh_lam=0.3, **dict(fit, n=1.05, p1=0.4, p4=0.01)),
                   seed=2)
    _assert_parity(models.create(ct, **dict(fit, p2=0.0, n=3.0)), wavelengths=[450.0, 600.0], seed=3)


def _tilted_pairs(normal, spread, seed, n=4000):
    """Pairs about the mirror directions of a tilted normal (where narrow peaks are not 0)."""
    rng = np.random.default_rng(seed)
    wi = rng.normal(size=(n, 3)) * [0.5, 0.5, 1.0]
    wi[:, 2] = np.abs(wi[:, 2])
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    h = np.asarray(normal) + spread * rng.normal(size=(n, 3))
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    wo = 2 * np.sum(wi * h, axis=1, keepdims=True) * h - wi
    return wi, wo


def test_small2021_terms_match_numpy():
    peak = models.create("small2021-peak", m=0.05, rho_s=[0.7, 0.5, 0.2], n=[3.6, 3.5, 1.4], k=[0.0, 0.1, 2.0])
    _assert_parity(peak)
    narrow = models.create("small2021-peak", m=2e-4, rho_s=0.7, n=1.4)              # the paper's width
    _assert_parity(narrow, wi=_tilted_pairs([0, 0, 1], 4e-4, 0)[0], wo=_tilted_pairs([0, 0, 1], 4e-4, 0)[1])
    _assert_parity(models.create("small2021-peak", m=0.1, rho_s=1.0, n=_SPECTRUM, k=0.2),
                   wavelengths=np.linspace(400, 700, 4), seed=1)
    # the band: the paper's (narrow) and a wide one whose fringes many random pairs see
    _assert_parity(models.create("small2021-diffraction"), seed=2)
    wide = models.create("small2021-diffraction", c=0.2, a=2e-5, b=5e-6, phi_ref=0.7, R=2.0)
    _assert_parity(wide, seed=3)
    _assert_parity(wide, wavelengths=[400.0, 632.8, 900.0], seed=4)
    # the rotated frame, around a Small 2021 peak and around any compiled term
    for k, (tilt, azimuth, phi_ref) in enumerate([(0.3, 0.8, -0.4), (np.radians(80), 2.0, 0.0)]):
        rot = models.create("rotated", term=peak, tilt=tilt, tilt_azimuth=azimuth, phi_ref=phi_ref)
        _assert_parity(rot, seed=5 + k)
        wi, wo = _tilted_pairs(rot.normal, 0.05, 5 + k)
        _assert_parity(rot, wi=wi, wo=wo)
    ggx = models.create("microfacet", distribution="ggx", alpha=0.2, fresnel="conductor", **_RGB_CONDUCTOR)
    _assert_parity(models.create("sum", terms=[models.create("lambert", albedo=0.2),
                                               models.create("rotated", term=ggx, tilt=0.6, tilt_azimuth=1.0)]),
                   seed=7)


def test_solar_cell_small2021_matches_numpy():
    paper = models.create("solar-cell-small2021")                                    # §4.4.1 values
    _assert_parity(paper, seed=0)
    wi, wo = _tilted_pairs(paper.offset.normal, 4e-4, 1)
    _assert_parity(paper, wi=wi, wo=wo)
    wi, wo = _tilted_pairs([0, 0, 1], 4e-4, 2)
    _assert_parity(paper, wi=wi, wo=wo)
    wide = models.create("solar-cell-small2021", m1=0.05, m2=0.08, c=0.05, tilt=0.3, phi_ref=0.4,
                         rho_d=[0.1, 0.2, 0.3], n1=[3.6, 3.5, 3.4], k2=[0.1, 0.0, 0.2])
    _assert_parity(wide, seed=3)
    _assert_parity(models.create("solar-cell-small2021", m1=0.05, m2=0.08, c=0.05, tilt=0.3, n1=_SPECTRUM,
                                 rho_d=0.1), wavelengths=np.linspace(400, 700, 5), seed=4)


# --------------------------------------------------------------------------------------------
# zernike-expansion: the radial polynomials by the Jacobi recurrence, per block of pairs


def _zernike(coefficients, **kw):
    import warnings

    from brdftab.errors import BrdftabWarning

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BrdftabWarning)  # 1064 nm: clamping reported (tests/test_zernike.py)
        return models.create("zernike-expansion", coefficients=str(coefficients), **kw)


def test_zernike_expansion_matches_numpy(tmp_path):
    """The shipped PTFE spec (Germer's coefficients), the synthetic file at one wavelength and
    at several with a spectral r(λ), and a file of high orders with a term whose n < l (R = 0)."""
    import brdftab

    _assert_parity(brdftab.from_spec(ROOT / "specs" / "ptfe-zernike.toml"))
    synthetic = ROOT / "tests" / "data" / "zernike-synthetic.coeff.csv"
    _assert_parity(_zernike(synthetic), seed=1)
    _assert_parity(_zernike(synthetic, scale={"wavelengths_nm": [400.0, 700.0], "values": [0.5, 1.0]}),
                   wavelengths=[400.0, 532.0, 633.0, 700.0], seed=2)
    rows = ["1, 1, 0, 0, 0, 0, 0, 0.3", "1, 1, 1, 3, 0, 3, 0, 0.05", "1, 1, 40, 38, 0, 2, 1, 1e-3",
            "1, 1, 99, 97, 0, 1, 0, -2e-4"] + [f"1, 1, {n}, {n}, 0, {n}, 0, 1e-4" for n in range(2, 101, 7)]
    high = tmp_path / "high.csv"
    high.write_text("\n".join(rows) + "\n")
    _assert_parity(_zernike(high), seed=3)


def test_zernike_clamping_and_counters_match_numpy():
    """At 1064 nm Germer's expansion is negative near grazing: the same values are clamped to 0
    and counted, and the unclamped ``expansion`` is the same sum as ``eval`` (bit for bit)."""
    from brdftab.brdf import numpy_reference
    from brdftab.geometry import sph_to_vec

    theta = np.radians(np.linspace(75.0, 89.99, 30))
    t1, t2, p = np.meshgrid(theta, theta, np.linspace(0.0, np.pi, 20), indexing="ij")
    wi, wo = sph_to_vec(t1.ravel(), 0.0), sph_to_vec(t2.ravel(), p.ravel())
    m = _zernike(ROOT / "data" / "ptfe" / "PTFE.coeff.csv", wavelength_nm=1064.0)
    _assert_parity(m, wi=wi, wo=wo)
    counts = []
    for reference in (False, True):
        before = (m.clamped, m.evaluated)
        if reference:
            with numpy_reference():
                f, raw = m.eval(wi, wo), m.expansion(wi, wo)
        else:
            f, raw = m.eval(wi, wo), m.expansion(wi, wo)
        np.testing.assert_array_equal(f, np.maximum(raw, 0.0))
        counts.append((m.clamped - before[0], m.evaluated - before[1]))
    assert counts[0] == counts[1] and counts[0][0] > 100 and counts[0][1] == wi.shape[0], counts


# --------------------------------------------------------------------------------------------
# he-torrance-1991 and he-torrance-modified: shadowing, Newton's method and the m-series per pair

#: HTSG surfaces: a metal and a dielectric with smooth-ish surfaces, Bitterling's Pyromark fits,
#: a smooth surface (g ≪ 1: the series' first term) and a moderately rough one (g up to 250).
_HTSG = {"metal": dict(n=0.77, k=6.08, sigma0=0.1, tau=1.0, wavelength_nm=500.0),
         "dielectric": dict(n=1.5, sigma0=0.1, tau=1.0, wavelength_nm=500.0, r_dh_lam=0.2),
         "pyromark": dict(n=1.32, sigma0=0.281, tau=1.635, r_dh_lam=0.0169, wavelength_nm=585.0),
         "smooth": dict(n=1.5, sigma0=0.002, tau=0.5, wavelength_nm=500.0),
         "rough": dict(n=1.4, k=0.5, sigma0=0.75, tau=3.0, wavelength_nm=600.0)}


@pytest.mark.parametrize("surface", sorted(_HTSG))
def test_he_torrance_matches_numpy(surface):
    """Both variants of he-torrance-1991 (ideal delta: ρ_dd and R_dh,Lam/π only; Bitterling's
    cone) and he-torrance-modified, at the model's wavelength and at three requested ones."""
    p = _HTSG[surface]
    _assert_parity(models.create("he-torrance-1991", **p), seed=5)
    _assert_parity(models.create("he-torrance-1991", cone_half_width=np.radians(4.5), **p), seed=6)
    _assert_parity(models.create("he-torrance-modified", width_theta=np.radians(14.9), width_phi=np.radians(3.2),
                                 **p), wavelengths=[p["wavelength_nm"], 650.0, 900.0], seed=7)


def test_series_peak_equals_the_bisection():
    """The compiled series starts at the same term as the numpy one: its root-then-round peak
    equals _series_peak's bisection, also where the root sits on a half-integer (e = 0,
    g = (k + 3/2)²/(k + 1/2): m* = k + 1/2, where the rounding is decided by the bisection)."""
    from brdftab.models import he_torrance as H

    rng = np.random.default_rng(11)
    k = np.arange(1.0, 400.0)
    g = np.concatenate([10 ** rng.uniform(-3, 4, 4000), (k + 1.5) ** 2 / (k + 0.5), (k + 1.5) ** 2 / (k + 0.5)])
    e = np.concatenate([10 ** rng.uniform(-3, 5, 4000), np.zeros(k.size), np.full(k.size, 1e-9)])
    lg = np.log(g)
    want = H._series_peak(lg, g, e)
    got = np.array([H.series_peak_scalar(a, b, c) for a, b, c in zip(lg, g, e)])
    np.testing.assert_array_equal(got, want)


def test_he_torrance_shipped_specs_match_numpy():
    import brdftab

    for name in ("pyromark-he-torrance", "pyromark-modified-ht"):
        m = brdftab.from_spec(ROOT / "specs" / f"{name}.toml")
        _assert_parity(m, seed=8)
        _assert_parity(m, wavelengths=[450.0, 585.0, 1000.0], seed=9)


def test_he_torrance_at_large_g_matches_numpy_as_far_as_numpy_itself_is_defined():
    """At g of a few thousand (σ0/λ ≈ 6, near :data:`~brdftab.models.he_torrance.G_MAX`) the
    numpy series forms each ln t_m = m ln g − g − ln m! − … from numbers of about 3e4, so its
    result moves by up to ~5e-12 when g moves by one unit in the last place (measured here).
    g comes from Newton's method and erfc, whose last digits differ between the C library the
    compiled code calls and numpy/scipy (erfc up to 8e-15 relative): the two evaluations then
    agree to 6e-12 (measured, seed 5), not 1e-12. Held to 2e-11 here; every surface with g up
    to a few hundred is held to 1e-12 above."""
    from _kernels import pairs

    from brdftab.brdf import numpy_reference
    from brdftab.models import he_torrance as H

    p = dict(n=1.4, k=0.5, sigma0=1.7, tau=1.5, wavelength_nm=300.0)
    wi, wo = pairs(5)
    for m in (models.create("he-torrance-1991", **p), models.create("he-torrance-1991", cone_half_width=0.08, **p)):
        got = m.eval(wi, wo)
        with numpy_reference():
            ref = m.eval(wi, wo)
        assert np.array_equal(np.isnan(got), np.isnan(ref)) and np.array_equal(got == 0, ref == 0)
        ok = np.isfinite(ref) & (ref != 0)
        rel = np.abs(got[ok] - ref[ok]) / np.abs(ref[ok])
        assert np.median(rel) < 1e-14 and rel.max() <= 2e-11, (np.median(rel), rel.max())
    # the reference's own spread: one unit in the last place of g
    g = np.linspace(2800.0, 3600.0, 41)
    moved = np.abs(H.htsg_series(np.nextafter(g, np.inf), 100.0) / H.htsg_series(g, 100.0) - 1.0)
    assert moved.max() > 4e-12, moved.max()


def test_he_torrance_quadrature_parts_match_numpy():
    """The albedo integrals evaluate the specular lobe and the diffuse parts apart
    (``quadrature_parts``): each part has the compiled evaluation too."""
    p = _HTSG["pyromark"]
    for m in (models.create("he-torrance-1991", cone_half_width=np.radians(4.5), **p),
              models.create("he-torrance-modified", width_theta=np.radians(14.9), width_phi=np.radians(3.2), **p)):
        for k, part in enumerate(m.quadrature_parts()):
            _assert_parity(part, seed=12 + k)


def test_modified_he_torrance_profile_on_the_normal_and_at_every_azimuth_matches_numpy():
    """The compiled Gaussian profile forms φr − φi as one angle: on the normal (whose azimuth
    is atan2(0, 0) = 0 in the numpy profile, with signed zeros), and at Δφ = 0 and ±π exactly,
    it is still the numpy profile (the specular part alone, where the profile is the value)."""
    m = models.create("he-torrance-modified", width_theta=np.radians(14.9), width_phi=np.radians(3.2),
                      **_HTSG["pyromark"])
    specular = m.quadrature_parts()[0]
    phi = np.linspace(-np.pi, np.pi, 73)
    th = np.radians(30.0)
    ring = np.stack([np.sin(th) * np.cos(phi), np.sin(th) * np.sin(phi), np.full(phi.size, np.cos(th))], axis=-1)
    normal = np.array([[0.0, 0.0, 1.0], [-0.0, 0.0, 1.0], [0.0, -0.0, 1.0], [-0.0, -0.0, 1.0]])
    mirror = ring * np.array([-1.0, -1.0, 1.0])     # Δφ = 0 (the profile's peak azimuth)
    forward = ring * np.array([1.0, 1.0, 0.5])      # Δφ = ±π
    forward /= np.linalg.norm(forward, axis=1, keepdims=True)
    wi = np.concatenate([np.repeat(normal, ring.shape[0], 0), np.tile(ring, (4, 1)), ring, ring])
    wo = np.concatenate([np.tile(ring, (4, 1)), np.repeat(normal, ring.shape[0], 0), mirror, forward])
    for brdf in (specular, m):
        _assert_parity(brdf, wi=wi, wo=wo)


def test_zernike_and_he_torrance_add_into_a_sum():
    """Inside a sum the kernels add to what the earlier terms wrote (their ``add`` mode)."""
    zernike = _zernike(ROOT / "tests" / "data" / "zernike-synthetic.coeff.csv")
    ht = models.create("he-torrance-1991", cone_half_width=np.radians(4.5), **_HTSG["pyromark"])
    white = models.create("lambert", albedo=0.3)
    _assert_parity(models.create("sum", terms=[white, zernike, ht]), seed=14)


def test_tables_and_rgl_files_take_the_numpy_path_inside_the_reference(tmp_path, monkeypatch):
    """numpy_reference() holds for tables and RGL files too (the benchmarks' and parity tests'
    reference), and a table read from a .bsdf file can be a term of a compiled sum."""
    import brdftab
    from brdftab.grids import RusinkiewiczGrid

    gold = models.create("microfacet", distribution="ggx", alpha=0.3, fresnel="conductor", n=[0.2, 0.45, 1.3],
                         k=[3.4, 2.6, 1.8])
    table = brdftab.tabulate(gold, RusinkiewiczGrid(30, 30, 60), progress=False)
    brdftab.save(gold, tmp_path / "g.bsdf")
    rgl = brdftab.open(tmp_path / "g.bsdf")
    wi, wo = _pairs_upper(4000)
    for brdf, compiled in ((table, "_interpolate"), (rgl, "_compiled")):
        got = brdf.eval(wi, wo)
        with monkeypatch.context() as mp, numpy_reference():
            mp.setattr(brdf, compiled, None)  # the compiled evaluation is not called
            ref = brdf.eval(wi, wo)
        assert np.array_equal(np.isnan(got), np.isnan(ref))
        ok = ~np.isnan(ref)
        assert np.max(np.abs(got[ok] - ref[ok]) / np.maximum(np.abs(ref[ok]), 1e-300)) <= 1e-10
        assert brdf.kernel(None, 3) is None
        both = models.create("sum", terms=[brdf, models.create("lambert", albedo=0.1)])
        np.testing.assert_allclose(both.eval(wi, wo), got + 0.1 / np.pi, rtol=1e-12)


def _pairs_upper(n, seed=9):
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(2, n, 3))
    v[..., 2] = np.abs(v[..., 2])
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    return v[0], v[1]


def test_compiled_asymmetry_statistics_match_numpy():
    """The reciprocity and symmetry checks' statistics, compiled, against their numpy form: the
    same counts and worst pair, the figures to 1e-12 (float64 values; sums in another order)."""
    from _kernels import asymmetry_numpy

    from brdftab.checks._pairs import asymmetry

    rng = np.random.default_rng(11)
    n = 100_000
    f1 = rng.lognormal(size=(n, 3))
    f2 = f1 * (1 + 1e-3 * rng.normal(size=(n, 3)))
    f1[5, 1] = np.nan
    f2[77, 0] = np.inf
    f1[1000:1010] = 0.0
    f2[2000, 2] = f1[2000, 2] * 3  # the worst pair
    w = rng.uniform(size=n)
    for a, b, weight in ((f1, f2, w), (f1[:, 0], f2[:, 0], None), (f1[:0], f2[:0], w[:0])):
        got, ref = asymmetry(a, b, weight), asymmetry_numpy(a, b, weight)
        assert got.keys() == ref.keys()
        for key in got:
            if isinstance(ref[key], float):
                assert got[key] == pytest.approx(ref[key], rel=RTOL, abs=0), key
            else:
                assert got[key] == ref[key], key
    same = asymmetry(f1, f1, w)
    assert same["max_relative"] == 0 and same["worst"] is None


def test_asymmetry_statistics_are_the_same_on_any_number_of_threads(monkeypatch):
    """Sums over the pairs are sums of fixed blocks' sums in block order: a run on one thread (a
    worker process of a cluster) and on three give the same figures to the last bit (they
    differed in the last digits of the rms, and a table's stored report with them)."""
    from brdftab.checks._pairs import asymmetry

    rng = np.random.default_rng(5)
    n = 300_001
    f1 = rng.lognormal(size=(n, 3))
    f2 = f1 * (1 + 1e-3 * rng.normal(size=(n, 3)))
    w = rng.uniform(size=n)
    got = {}
    for t in ("1", "2", "3"):
        monkeypatch.setenv("BRDFTAB_THREADS", t)
        got[t] = asymmetry(f1, f2, w)
    assert got["1"] == got["2"] == got["3"]


def test_tables_evaluate_from_threads_under_any_threading_layer(tmp_path):
    """Table interpolation is a numba parallel loop. Under numba's workqueue threading layer (the
    one it picks where neither OpenMP nor TBB is available) two threads launching parallel
    loops end the process; evaluated off the main thread a table takes the plain loop."""
    code = ("import numpy as np\n"
            "from concurrent.futures import ThreadPoolExecutor\n"
            "from brdftab import models, tabulate\n"
            "from brdftab.grids import RusinkiewiczGrid\n"
            "t = tabulate(models.create('microfacet', alpha=0.3), RusinkiewiczGrid(20, 20, 40), progress=False)\n"
            "rng = np.random.default_rng(0)\n"
            "v = rng.normal(size=(2, 50000, 3)); v[..., 2] = abs(v[..., 2]); v /= np.linalg.norm(v, axis=-1, "
            "keepdims=True)\n"
            "ref = t.eval(v[0], v[1])\n"
            "with ThreadPoolExecutor(4) as pool:\n"
            "    out = list(pool.map(lambda _: t.eval(v[0], v[1]), range(8)))\n"
            "print(all(np.array_equal(o, ref) for o in out))\n")
    env = dict(os.environ, NUMBA_THREADING_LAYER="workqueue", PYTHONPATH=str(ROOT))
    run = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0 and run.stdout.split() == ["True"], run.stdout + run.stderr[-500:]


@pytest.mark.parametrize("name, values", [
    ("microfacet", dict(distribution="ggx", alpha=0.3, fresnel="conductor", n=0.2, k=3.0)),
    ("pyramid-microfacet", dict(facet_roughness=0.02, fresnel="conductor", n=3.9, k=0.02)),
])
def test_a_model_pickles_after_its_kernel_was_built(name, values):
    """Models travel to worker processes by pickle: the compiled evaluation a model caches is
    left out of its state and rebuilt there (of the model and of its terms)."""
    import pickle

    m = models.create(name, **values)
    wi, wo = _pairs_upper(100)
    f = m.eval(wi, wo)
    for part in getattr(m, "quadrature_parts", lambda: [])() or []:
        part.eval(wi, wo)
    back = pickle.loads(pickle.dumps(m))
    np.testing.assert_array_equal(back.eval(wi, wo), f)
    assert back.kernel(None, 1) is not None


# a kernel and the device function it calls, compiled in this test only (module level: numba
# reads a kernel's device functions from its module's globals)
from brdftab._jit import device as _device, kernel as _kernel  # noqa: E402


@_device
def _race_twice(x):
    return 2.0 * x


@_kernel
def _race_kernel(a, out):
    for i in range(a.shape[0]):
        out[i] = _race_twice(a[i])


_RACE_TWICE_LAZY = _race_twice  # the lazy wrapper, before any compile swaps the global


def test_a_kernel_is_published_only_with_its_device_functions_compiled(monkeypatch):
    """A kernel's dispatcher is created (and handed to any thread) only after the device
    functions it calls are numba's in its module: threads that called a kernel for the first
    time at once (parallel_rows) could take a dispatcher whose globals were still the lazy
    wrappers and fail with 'Untyped global name' (seen in CI: unravel4 in the Rusinkiewicz
    direction loop)."""
    import numba

    seen = []
    real = numba.njit

    def spy(*args, **options):
        decorate = real(*args, **options)

        def wrap(f):
            if f is _race_kernel.py_func:
                seen.append(type(f.__globals__["_race_twice"]).__name__)
            return decorate(f)
        return wrap

    monkeypatch.setitem(globals(), "_race_twice", _RACE_TWICE_LAZY)
    monkeypatch.setattr(_RACE_TWICE_LAZY, "_compiled", None)
    monkeypatch.setattr(_race_kernel, "_compiled", None)
    monkeypatch.setattr(numba, "njit", spy)
    out = np.empty(5)
    _race_kernel(np.arange(5.0), out)
    assert seen == ["CPUDispatcher"]
    assert np.array_equal(out, 2.0 * np.arange(5.0))


def test_undeclared_nan_samples_read_the_same_in_both_evaluations():
    """A table with NaN samples that are not declared missing: the compiled interpolation skips a
    corner of weight 0, so a NaN sample there does not reach the result; the numpy reference
    multiplied it by 0 (NaN) and read NaN where the compiled one read a value (13 of 20 000
    pairs). Both now read NaN at the same pairs and agree elsewhere."""
    from brdftab.geometry import mirror_biased_pairs
    from brdftab.grids.rusinkiewicz import RusinkiewiczGrid
    from brdftab.table import tabulate

    t = tabulate(models.create("microfacet", alpha=0.3), RusinkiewiczGrid(16, 16, 32), progress=False)
    v = t.ds["brdf"].values
    flat = v.reshape(-1, v.shape[-1])
    flat[np.random.default_rng(0).integers(0, flat.shape[0], 30)] = np.nan
    t.ds["brdf"].values = flat.reshape(v.shape)
    wi, wo = mirror_biased_pairs(20000, np.random.default_rng(1))
    compiled = np.asarray(t.eval(wi, wo))
    with numpy_reference():
        reference = np.asarray(t.eval(wi, wo))
    nan = np.isnan(compiled)
    assert nan.any() and np.array_equal(nan, np.isnan(reference))
    assert np.allclose(compiled[~nan], reference[~nan], rtol=RTOL, atol=0.0)


# --------------------------------------------------------------------------------------------
# numba's on-disk cache shared by processes that compile at once (brdftab._jit.safe_cache)

_RACE_MODULE = '''
from brdftab._jit import kernel


@kernel
def total(a):
    s = a[0] * 0
    for i in range(a.shape[0]):
        s += a[i]
    return s
'''

_RACER = '''
import json, sys, time
import numpy as np
sys.path.insert(0, sys.argv[1])
import racemod
start, dtypes = float(sys.argv[2]), sys.argv[3].split(",")
racemod.total.compiled()  # numba imported and brdftab's cache locks installed before the start
from numba.core import caching
save_index = caching.IndexDataCacheFile._save_index
def slow_save_index(self, overloads):  # widens numba's race window: unlocked saves all collide
    time.sleep(0.3)
    return save_index(self, overloads)
caching.IndexDataCacheFile._save_index = slow_save_index
while time.time() < start:  # every process calls at the same moment, its imports done
    time.sleep(0.001)
sums = [float(np.real(racemod.total(np.arange(5).astype(d)))) for d in dtypes]
stats = racemod.total.compiled().stats
print(json.dumps({"sums": sums, "misses": sum(stats.cache_misses.values()), "hits": sum(stats.cache_hits.values())}))
'''

_DTYPES = ["int32", "int64", "uint32", "uint64", "float32", "float64", "complex64", "complex128"]


def _race(tmp_path, groups):
    """Start one process per entry of ``groups`` (a list of dtype lists), all calling the kernel
    at the same moment with a fresh numba cache; their JSON reports."""
    import json
    import time

    (tmp_path / "racemod.py").write_text(_RACE_MODULE)
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba"))
    start = time.time() + 3.0
    procs = [subprocess.Popen([sys.executable, "-c", _RACER, str(tmp_path), str(start), ",".join(g)], env=env,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for g in groups]
    out = []
    for p in procs:
        stdout, stderr = p.communicate(timeout=300)
        assert p.returncode == 0, stderr[-1500:]
        out.append(json.loads(stdout.strip().splitlines()[-1]))
    return out


def test_processes_compiling_one_function_at_once_leave_a_consistent_cache(tmp_path):
    """Eight processes compile eight signatures of one kernel at the same moment into one
    fresh cache. numba names each signature's data file by the first free number in an index it
    rewrites without a lock: without brdftab's lock files two processes took the same file,
    and a later process loaded one signature's machine code for another's arguments ("can't
    unbox array") or missed entries. Each process here writes numba's index 0.3 s late, which
    widens that window so the unlocked saves collide every time (the race itself is narrow:
    without the widening, a run without the lock files failed in two of five). Here a later
    process finds all eight signatures in the cache, and each gives the right sum."""
    for report in _race(tmp_path, [[d] for d in _DTYPES]):
        assert report["sums"] == [10.0]
    (after,) = _race(tmp_path, [_DTYPES])
    assert after["sums"] == [10.0] * len(_DTYPES)
    assert after["misses"] == 0 and after["hits"] == len(_DTYPES), after
