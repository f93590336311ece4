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

from _kernels import assert_parity as _assert_parity

from brdftab import models
from brdftab._jit import cache_dir
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
