"""One contract over every registered model (and every model registered later).

Parameters are drawn from each model's declared parameters — ranges, choices, kinds — so a
new model is covered without a line here. The contract: f broadcasts over leading shapes; is
0 at and below the horizon; is finite and >= 0 above it; is reciprocal to 1e-12 where the
model declares reciprocity; and its directional albedo is <= 1 + 1e-3 where it declares
energy conservation. A polarized model's Mueller matrix broadcasts the same way, is 0 below the
horizon, finite above it, has f (``eval``) as its element (0, 0) in every basis, and obeys
polarized reciprocity M(wi → wo) = Q·Mᵀ(wo → wi)·Q (Q = diag(1, 1, −1, 1)) in Mitsuba's basis
where declared. Deliberately broken toy models prove the contract can fail.
"""

import zlib
from pathlib import Path

import numpy as np
import pytest

from brdftab import models
from brdftab.brdf import BRDF, Model, numpy_reference
from brdftab.errors import ParameterError
from brdftab.geometry import sph_to_vec
from brdftab.params import REQUIRED, Param
from brdftab.integrate import directional_albedo
from brdftab.polarization import BASES, reciprocity_transform

N_CONFIGS = 6
_ROOT = Path(__file__).resolve().parents[1]
#: Coefficient files for parameters of kind zernike-coefficients.
_COEFFICIENT_FILES = (_ROOT / "tests" / "data" / "zernike-synthetic.coeff.csv",
                      _ROOT / "data" / "ptfe" / "PTFE.coeff.csv")


def _draw_value(p: Param, rng, depth):
    lo = p.minimum if p.minimum is not None else 0.0
    if p.kind in ("float", "channel"):
        hi = p.maximum if p.maximum is not None else max(lo + 1.0, 4.0)
        if lo > 0 and hi / lo > 100:
            draw = lambda: float(np.exp(rng.uniform(np.log(lo), np.log(hi))))  # noqa: E731
        else:
            draw = lambda: float(rng.uniform(lo, hi))  # noqa: E731
        if p.kind == "float":
            return draw()
        return draw() if rng.random() < 0.5 else [draw() for _ in range(3)]
    if p.kind == "int":
        hi = p.maximum if p.maximum is not None else lo + 10
        return int(rng.integers(int(lo), int(min(hi, lo + 10)) + 1))
    if p.kind == "choice":
        return str(rng.choice(p.choices))
    if p.kind == "bool":
        return bool(rng.random() < 0.5)
    if p.kind == "brdf":
        return _leaf(rng)
    if p.kind == "brdfs":
        return [_leaf(rng) for _ in range(int(rng.integers(1, 3)))]
    if p.kind == "zernike-coefficients":  # a synthetic file or Germer's PTFE fit
        return str(_COEFFICIENT_FILES[int(rng.integers(len(_COEFFICIENT_FILES)))])
    if p.kind == "material":  # a bare name: a bulk source of the refractiveindex.info database
        from brdftab.optical import BULK_SOURCES

        return str(rng.choice(sorted(BULK_SOURCES)))
    raise AssertionError(f"the contract test cannot draw parameter kind {p.kind!r}: teach it")


def _default(params, name):
    return next((p.default for p in params if p.name == name), None)


def _leaf(rng):
    if rng.random() < 0.5:
        return models.create("lambert", albedo=float(rng.uniform(0, 0.5)))
    return models.create("microfacet", alpha=float(rng.uniform(0.05, 0.8)))


def draw_models(cls, seed, n=N_CONFIGS, depth=0):
    """``n`` valid instances of ``cls`` with parameters drawn from its declarations."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(400):
        kwargs = {}
        params = list(cls.params)
        # choices first: a parameter that `requires` a choice is drawn only with it
        for p in sorted(params, key=lambda p: bool(p.requires)):
            if any(kwargs.get(k, _default(params, k)) not in users for k, users in p.requires):
                continue
            if p.default is REQUIRED or rng.random() < 0.6:
                kwargs[p.name] = _draw_value(p, rng, depth)
        try:
            out.append(cls(**kwargs))
        except ParameterError:
            continue  # parameters that depend on each other: draw again
        if len(out) == n:
            return out
    raise AssertionError(f"could not draw {n} valid parameter sets for model {cls.name!r} in 400 tries")


def _directions(rng, n, theta_max=np.radians(89.9)):
    mu = rng.uniform(np.cos(theta_max), 1.0, n)
    return sph_to_vec(np.arccos(mu), rng.uniform(0, 2 * np.pi, n))


def check_contract(m: BRDF, seed=0):
    """Assert the BRDF contract on ``m`` (AssertionError naming the broken clause)."""
    rng = np.random.default_rng(seed)
    lam = None if not m.spectral else (m.wavelengths if m.wavelengths is not None else [500.0])
    nc = m.layout.n_out(m.layout.resolve(lam))
    # broadcasting over leading shapes
    wi = _directions(rng, 4).reshape(4, 1, 3)
    wo = _directions(rng, 5).reshape(1, 5, 3)
    f = m.eval(wi, wo, lam)
    assert f.shape == (4, 5, nc), f"{m.describe()}: shape {f.shape}, expected (4, 5, {nc})"
    flat = m.eval(np.broadcast_to(wi, (4, 5, 3)).reshape(-1, 3), np.broadcast_to(wo, (4, 5, 3)).reshape(-1, 3), lam)
    assert np.array_equal(f.reshape(-1, nc), flat), f"{m.describe()}: broadcasting changes values"
    # 0 at and below the horizon
    below = sph_to_vec(np.radians([90.0, 90.0, 95.0, 120.0, 179.0]), rng.uniform(0, 6, 5))
    above = _directions(rng, 5)
    for a, b in ((below, above), (above, below)):
        z = m.eval(a, b, lam)
        assert np.all(z == 0), f"{m.describe()}: f = {z.ravel()[:4]} at or below the horizon, expected 0"
    # finite and non-negative above the horizon, grazing included
    wi = _directions(rng, 4000)
    wo = _directions(rng, 4000)
    f = m.eval(wi, wo, lam)
    assert np.all(np.isfinite(f)), f"{m.describe()}: non-finite values above the horizon"
    assert np.all(f >= 0), f"{m.describe()}: negative values above the horizon (min {f.min():.3g})"
    # reciprocity where declared
    if m.reciprocal:
        g = m.eval(wo, wi, lam)
        rel = np.abs(f - g) / np.maximum(np.abs(f), 1e-300)
        worst = float(np.max(np.where(f > 0, rel, np.abs(g))))
        assert worst <= 1e-12, f"{m.describe()}: declared reciprocal, relative asymmetry {worst:.3g}"
    if m.polarized:
        check_mueller(m, f[:1000], wi[:1000], wo[:1000], lam, nc, rng)
    else:
        with pytest.raises(ParameterError, match="not polarized"):
            m.eval_mueller(wi[:2], wo[:2], lam)
    # energy conservation where declared
    if m.energy_conserving:
        # brdftab's adaptive quadrature (nodes follow the lobe, however narrow)
        a = directional_albedo(m, np.radians([0.0, 30.0, 60.0, 80.0, 89.0]), 0.4, lam)
        assert np.all(a <= 1 + 1e-3), f"{m.describe()}: declared energy-conserving, albedo up to {a.max():.6g}"


def check_mueller(m: BRDF, f, wi, wo, lam, nc, rng):
    """The polarized clauses of :func:`check_contract`, on the pairs ``wi``, ``wo`` where ``eval``
    gave ``f``."""
    a = _directions(rng, 3).reshape(3, 1, 3)
    b = _directions(rng, 2).reshape(1, 2, 3)
    M = m.eval_mueller(a, b, lam)
    assert M.shape == (3, 2, nc, 4, 4), f"{m.describe()}: Mueller shape {M.shape}, expected (3, 2, {nc}, 4, 4)"
    below = sph_to_vec(np.radians([90.0, 95.0, 179.0]), rng.uniform(0, 6, 3))
    assert np.all(m.eval_mueller(below, _directions(rng, 3), lam) == 0), f"{m.describe()}: Mueller not 0 below the horizon"
    scale = max(float(np.max(np.abs(f))), 1e-300)
    for basis in BASES:
        M = m.eval_mueller(wi, wo, lam, basis=basis)
        assert np.all(np.isfinite(M)), f"{m.describe()}: non-finite Mueller elements above the horizon ({basis})"
        worst = float(np.max(np.abs(M[..., 0, 0] - f))) / scale
        assert worst <= 1e-12, f"{m.describe()}: eval differs from M00 in basis {basis} by {worst:.3g} (relative)"
    declared = m.reciprocal if m.mueller_reciprocal is None else m.mueller_reciprocal
    if declared:
        M = m.eval_mueller(wi, wo, lam)
        back = reciprocity_transform(m.eval_mueller(wo, wi, lam))
        worst = float(np.max(np.abs(M - back))) / scale
        assert worst <= 1e-12, f"{m.describe()}: declared reciprocal, polarized asymmetry {worst:.3g} (M00 scale)"


@pytest.mark.parametrize("name", sorted(models.MODELS))
def test_every_registered_model_keeps_the_contract(name):
    for i, m in enumerate(draw_models(models.MODELS[name], seed=zlib.crc32(name.encode()))):
        check_contract(m, seed=i)


def test_every_polarized_fresnel_term_keeps_the_contract():
    """Each polarized Fresnel component inside ``microfacet``, its parameters drawn from its
    declarations (the polarized clauses; the rest is the models' contract above)."""
    from brdftab.models.components import COMPONENTS

    wanted = {name: cls for name, cls in COMPONENTS["fresnel"].items() if cls.polarized}
    assert set(wanted) >= {"dielectric", "conductor", "rayleigh-rice"}
    rng = np.random.default_rng(0)
    wi, wo = _directions(rng, 1000), _directions(rng, 1000)
    for name, cls in sorted(wanted.items()):
        for _ in range(2):
            kwargs = {p.name: _draw_value(p, rng, 0) for p in cls.params if p.kind != "material"}
            m = models.create("microfacet", alpha=float(rng.uniform(0.05, 0.8)), fresnel=name, **kwargs)
            assert m.polarized
            lam = m.wavelengths if m.spectral else None
            with numpy_reference():  # no kernel to compile for the comparison
                f = m.eval(wi, wo, lam)
            check_mueller(m, f, wi, wo, lam, f.shape[-1], rng)


class _Negative(Model):
    name = "toy-negative"
    summary = "broken on purpose: negative near grazing"
    params = (Param("albedo", "float", "albedo", default=0.5, minimum=0.0, maximum=1.0),)

    def _setup(self, albedo):
        self.albedo = albedo

    def _eval(self, wi, wo, lam, n):
        f = np.full((wi.shape[0], n), self.albedo / np.pi)
        f[wo[:, 2] < 0.1] = -0.01
        return f


class _FakeReciprocal(Model):
    name = "toy-nonreciprocal"
    summary = "broken on purpose: depends on cosθi only but declares reciprocity"
    params = (Param("albedo", "float", "albedo", default=0.5, minimum=0.0, maximum=1.0),)

    def _setup(self, albedo):
        self.albedo = albedo

    def _eval(self, wi, wo, lam, n):
        return np.repeat((self.albedo / np.pi * (0.5 + 0.5 * wi[:, 2]))[:, None], n, axis=1)


class _Hot(Model):
    name = "toy-hot"
    summary = "broken on purpose: claims energy conservation with albedo 1.5"
    params = ()
    energy_conserving = True

    def _setup(self):
        pass

    def _eval(self, wi, wo, lam, n):
        return np.full((wi.shape[0], n), 1.5 / np.pi)


class _Polarizer(Model):
    name = "toy-polarizer"
    summary = "broken on purpose: a Mueller matrix whose M00 is not eval"
    params = (Param("albedo", "float", "albedo", default=0.5, minimum=0.0, maximum=1.0),)
    polarized = True

    def _setup(self, albedo):
        self.albedo = albedo

    def _eval(self, wi, wo, lam, n):
        return np.full((wi.shape[0], n), self.albedo / np.pi)

    def _mueller(self, wi, wo, lam, n):
        out = np.zeros((wi.shape[0], n, 4, 4))
        out[:, :, :2, :2] = 0.5 * self.albedo / np.pi  # an ideal polarizer's half: M00 is f/2
        return out


class _Retarder(_Polarizer):
    name = "toy-retarder"
    summary = "broken on purpose: a symmetric S2/S3 coupling, not polarized-reciprocal"

    def _mueller(self, wi, wo, lam, n):
        out = np.zeros((wi.shape[0], n, 4, 4))
        out[:, :, 0, 0] = self.albedo / np.pi
        out[:, :, 2, 3] = out[:, :, 3, 2] = 0.5 * self.albedo / np.pi * wi[:, 2:3]
        return out


@pytest.mark.parametrize("toy, clause", [(_Negative, "negative"), (_FakeReciprocal, "reciprocal"),
                                         (_Hot, "energy-conserving"), (_Polarizer, "M00"),
                                         (_Retarder, "polarized asymmetry")])
def test_contract_catches_broken_models(monkeypatch, toy, clause):
    monkeypatch.setitem(models.MODELS, toy.name, toy)
    assert toy.name in models.MODELS  # registered like any model, so the contract test above would run it
    with pytest.raises(AssertionError, match=clause):
        for i, m in enumerate(draw_models(models.MODELS[toy.name], seed=1, n=2)):
            check_contract(m, seed=i)
