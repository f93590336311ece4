"""Microfacet components: normal distributions D, shadowing–masking G and Fresnel F.

Each component is a small class with declared parameters (:class:`~brdftab.params.Param`),
registered by kind in :data:`COMPONENTS` — ``"distribution"``, ``"shadowing"``, ``"fresnel"``
— so every microfacet-like model composes the same parts (after Mitsuba 3's
``MicrofacetDistribution``: one distribution object with ``D``, ``G1``/``Λ``, ``sample``,
reused by every microfacet BSDF; Fresnel a free function wrapped by a component here).
A new D, G or F is one class here or in its own module, registered with :func:`register`.

* A **distribution** is built from the roughness parameters and offers ``D(h)`` [sr⁻¹]
  (area-normalized: ∫ D cosθh dω = 1), ``lambda_(w)`` (exact Smith Λ), ``G1(w)`` and
  ``sample(u1, u2)`` / ``pdf(h)`` (cosθh-weighted normal sampling).
* A **shadowing** term offers ``G(wi, wo, h, dist)``.
* A **Fresnel** term offers ``F(cos_d, lam, n_out)`` (per channel or per wavelength) and the
  channel ``layout`` its parameters imply. Models call ``F_pair(wi, wo, cos_d, lam, n_out)``,
  which is ``F(cos_d, …)`` for every term that depends on the microfacet angle only; a term
  that depends on the whole geometry (the Rayleigh–Rice factor Q of θi, θs and φs) overrides
  ``F_pair`` instead, so the simple terms stay as simple as they are. A **polarized** Fresnel
  term (``polarized = True``: ``dielectric``, ``conductor``, ``rayleigh-rice``) also gives its
  Mueller matrix ``F_mueller(wi, wo, cos_d, lam, n_out)`` ``(M, n, 4, 4)`` in the pair's
  ``mitsuba`` basis (:mod:`brdftab.polarization`), whose element (0, 0) is ``F_pair``: the facet
  terms compute it in the facet's s/p frame (s = normalize(h × k) per beam, the facet's plane of
  incidence) and rotate it into and out of that frame; the Rayleigh–Rice term converts its
  Jones matrix from SCATMECH's ``psps`` basis.

A distribution declares its own parameters; ``microfacet`` offers the union of every
registered distribution's parameters and accepts each only with the distribution that uses it.

**Compiled kernels.** Beside its array methods a component gives the scalar form of its
physics, which the models that compose it fuse into one compiled loop
(:mod:`brdftab.models.fused`); a component without one is evaluated by its array methods:

* a distribution: ``jit_D(hx, hy, hz, p)`` and ``jit_lambda(wx, wy, wz, p)`` with
  ``p = jit_params()`` (a float64 vector; [α_x, α_y] by default);
* a shadowing term: ``jit_G(wix, wiy, wiz, wox, woy, woz, hx, hy, hz, lam_i, lam_o)``, where
  ``lam_i``, ``lam_o`` are the distribution's Λ when ``jit_needs_lambda`` is True (else 0);
* a Fresnel term: ``jit_F(wix, wiy, wiz, wox, woy, woz, cos_d, p, c)`` for channel ``c`` of
  ``p = jit_params(lam, n)`` (by default one column per declared channel parameter, per channel).

Each also declares what it ``depends`` on — D the half vector, F θd unless it says
``"pair"`` — so a tabulation on a Rusinkiewicz grid evaluates D once per half-vector node and F
once per θd node (:func:`brdftab.models.fused.microfacet_tabulation`).

Each is a plain function (or a :func:`brdftab._jit.device` one) of floats, in the same
arithmetic as the array method it mirrors; the parity test holds the two to 1e-12.
"""

from __future__ import annotations

import numpy as np

from ..channels import ChannelValue, Layout, combine_layouts
from ..errors import ParameterError
from ..optical import MATERIAL, resolve_index
from ..params import Param, parse_params
from ..registry import Registry
from .distributions import (beckmann_D_scalar, beckmann_lambda_scalar, d_beckmann, d_ggx, ggx_D_scalar,
                            ggx_lambda_scalar, lambda_beckmann, lambda_ggx)
from .fresnel import (INDEX_MAX, INDEX_MIN, conductor_scalar, dielectric_scalar, fresnel_conductor,
                      fresnel_dielectric, fresnel_schlick, schlick_scalar)
from ..polarization import basis_frames, convert_basis, fresnel_mueller, rotate_frames
from .rayleigh_rice import q_mueller, q_unpolarized, q_unpolarized_scalar

__all__ = ["COMPONENTS", "Component", "register", "get", "create", "Distribution", "Shadowing", "Fresnel"]

#: Components by kind, then by name (one :class:`~brdftab.registry.Registry` per kind).
COMPONENTS: dict = {kind: Registry(kind) for kind in ("distribution", "shadowing", "fresnel")}


def register(cls):
    """Register a component class under ``COMPONENTS[cls.kind][cls.name]`` (a decorator)."""
    return COMPONENTS[cls.kind].register(cls)


def get(kind: str, name: str):
    """The component class ``name`` of ``kind`` (:class:`~brdftab.registry.UnknownName` if none)."""
    return COMPONENTS[kind].get(name)


def create(kind: str, name: str, **params):
    return get(kind, name)(**params)


class Component:
    """Base of D, G and F components: declared ``params``, validated on construction."""

    kind = ""
    name = ""
    summary = ""
    reference = ""
    params: tuple = ()

    def __init__(self, **params):
        self.values = parse_params(self.params, params, f"{self.kind} '{self.name}'")
        self._setup(**self.values)

    def _setup(self, **values):
        pass

    def to_json(self) -> dict:
        return {p.name: p.to_json(self.values[p.name]) for p in self.params if self.values[p.name] is not None}


# --------------------------------------------------------------------------------------------
# Distributions

#: Smallest roughness accepted: below it α² underflows in D's normalization (the model would
#: not be finite).
MIN_ALPHA = 1e-6


class Distribution(Component):
    """A microfacet normal distribution with roughness α (isotropic) or α_x, α_y."""

    kind = "distribution"
    #: What D depends on: the half vector alone (structured tabulation evaluates it once per
    #: (θh, φh) node).
    depends = "half"
    params = (
        Param("alpha", "float", "Isotropic roughness α (slope parameter of D).", default=None,
              minimum=MIN_ALPHA, used_when="unless alpha_x/alpha_y"),
        Param("alpha_x", "float", "Roughness along the frame's x axis (anisotropic).", default=None,
              minimum=MIN_ALPHA, used_when="with alpha_y, instead of alpha"),
        Param("alpha_y", "float", "Roughness along the frame's y axis (anisotropic).", default=None,
              minimum=MIN_ALPHA, used_when="with alpha_x, instead of alpha"),
    )

    def _setup(self, alpha, alpha_x, alpha_y):
        if alpha is not None and (alpha_x is not None or alpha_y is not None):
            raise ParameterError("alpha", "give either alpha or alpha_x and alpha_y, not both")
        if alpha is None:
            if alpha_x is None or alpha_y is None:
                raise ParameterError("alpha", "missing roughness: give alpha (isotropic) or alpha_x and alpha_y")
            self.alpha_x, self.alpha_y = alpha_x, alpha_y
        else:
            self.alpha_x = self.alpha_y = alpha

    @property
    def isotropic(self) -> bool:
        return self.alpha_x == self.alpha_y

    @property
    def width(self) -> float:
        """Angular width [rad, roughly] of the narrowest axis of the lobe (a quadrature hint)."""
        return min(self.alpha_x, self.alpha_y)

    @property
    def axes(self):
        """Widths along the frame's x and y axes of an anisotropic lobe, else None."""
        return None if self.isotropic else (self.alpha_x, self.alpha_y)

    #: Scalar forms for the compiled kernels (see the module docstring); None: not compiled.
    jit_D = None
    jit_lambda = None

    def jit_params(self) -> np.ndarray:
        """The parameter vector ``p`` of :attr:`jit_D` and :attr:`jit_lambda`: [α_x, α_y]."""
        return np.array([self.alpha_x, self.alpha_y], float)

    def D(self, h):
        raise NotImplementedError

    def lambda_(self, w):
        raise NotImplementedError

    def G1(self, w):
        """Smith masking of direction ``w`` (for normals on its side): 1 / (1 + Λ(w))."""
        return 1.0 / (1.0 + self.lambda_(w))

    def pdf(self, h):
        """Density of :meth:`sample` over solid angle: D(h) cosθh."""
        return self.D(h) * np.maximum(np.asarray(h)[..., 2], 0.0)

    def sample(self, u1, u2):
        """Normals distributed as D(h) cosθh from uniform numbers ``u1, u2`` in [0, 1)."""
        raise NotImplementedError

    def _stretch(self, tan_theta, phi):
        # anisotropic α: sample isotropically with α = 1, stretch the slopes by (α_x, α_y)
        sx = tan_theta * np.cos(phi) * self.alpha_x
        sy = tan_theta * np.sin(phi) * self.alpha_y
        h = np.stack([-sx, -sy, np.ones_like(sx)], axis=-1)
        return h / np.linalg.norm(h, axis=-1, keepdims=True)


@register
class Beckmann(Distribution):
    name = "beckmann"
    summary = "Beckmann (Gaussian slopes) distribution, exact Smith Λ (erfc form)."
    reference = "Beckmann1963; Walter2007; Heitz2014"
    jit_D = staticmethod(beckmann_D_scalar)
    jit_lambda = staticmethod(beckmann_lambda_scalar)

    def D(self, h):
        return d_beckmann(h, self.alpha_x, self.alpha_y)

    def lambda_(self, w):
        return lambda_beckmann(w, self.alpha_x, self.alpha_y)

    def sample(self, u1, u2):
        tan_theta = np.sqrt(-np.log1p(-np.asarray(u1, float)))
        return self._stretch(tan_theta, 2 * np.pi * np.asarray(u2, float))


@register
class GGX(Distribution):
    name = "ggx"
    summary = "GGX (Trowbridge–Reitz) distribution, exact Smith Λ."
    reference = "Trowbridge1975; Walter2007; Heitz2014"
    jit_D = staticmethod(ggx_D_scalar)
    jit_lambda = staticmethod(ggx_lambda_scalar)

    def D(self, h):
        return d_ggx(h, self.alpha_x, self.alpha_y)

    def lambda_(self, w):
        return lambda_ggx(w, self.alpha_x, self.alpha_y)

    def sample(self, u1, u2):
        u1 = np.asarray(u1, float)
        tan_theta = np.sqrt(u1 / (1.0 - u1))
        return self._stretch(tan_theta, 2 * np.pi * np.asarray(u2, float))


# --------------------------------------------------------------------------------------------
# Shadowing–masking. With h = normalize(wi + wo) both wi·h and wo·h equal |wi + wo|/2 > 0
# above the horizon, so the χ⁺ factors of the Smith forms are 1 for reflection.


class Shadowing(Component):
    kind = "shadowing"
    #: Scalar form for the compiled kernels (see the module docstring); None: not compiled.
    jit_G = None
    #: Whether :attr:`jit_G` takes the distribution's Λ of wi and wo.
    jit_needs_lambda = False

    def G(self, wi, wo, h, dist: Distribution):
        raise NotImplementedError


@register
class SmithSeparable(Shadowing):
    name = "smith"
    summary = "Separable Smith G = G1(wi) G1(wo)."
    reference = "Smith1967; Walter2007"

    def G(self, wi, wo, h, dist):
        return 1.0 / ((1.0 + dist.lambda_(wi)) * (1.0 + dist.lambda_(wo)))

    jit_needs_lambda = True

    @staticmethod
    def jit_G(wix, wiy, wiz, wox, woy, woz, hx, hy, hz, lam_i, lam_o):
        return 1.0 / ((1.0 + lam_i) * (1.0 + lam_o))


@register
class SmithHeightCorrelated(Shadowing):
    name = "smith-height-correlated"
    summary = "Height-correlated Smith G2 = 1 / (1 + Λ(wi) + Λ(wo))."
    reference = "Heitz2014"

    def G(self, wi, wo, h, dist):
        return 1.0 / (1.0 + dist.lambda_(wi) + dist.lambda_(wo))

    jit_needs_lambda = True

    @staticmethod
    def jit_G(wix, wiy, wiz, wox, woy, woz, hx, hy, hz, lam_i, lam_o):
        return 1.0 / (1.0 + lam_i + lam_o)


@register
class VGroove(Shadowing):
    name = "v-groove"
    summary = "Torrance–Sparrow V-groove G = min(1, 2 cosθh cosθi / (wo·h), 2 cosθh cosθo / (wo·h))."
    reference = "Torrance1967; Blinn1977; Cook1982"

    def G(self, wi, wo, h, dist=None):
        hz = h[..., 2]
        wo_h = np.sum(wo * h, axis=-1)
        with np.errstate(divide="ignore", invalid="ignore"):
            g = np.minimum(1.0, 2.0 * hz * np.minimum(wo[..., 2], wi[..., 2]) / wo_h)
        return np.where(wo_h > 0, np.maximum(g, 0.0), 0.0)

    @staticmethod
    def jit_G(wix, wiy, wiz, wox, woy, woz, hx, hy, hz, lam_i, lam_o):
        wo_h = wox * hx + woy * hy + woz * hz
        if not wo_h > 0:
            return 0.0
        return max(min(1.0, 2.0 * hz * min(woz, wiz) / wo_h), 0.0)


@register
class NoShadowing(Shadowing):
    name = "none"
    summary = "No shadowing: G = 1."

    def G(self, wi, wo, h, dist=None):
        return np.ones(np.broadcast_shapes(wi.shape, wo.shape)[:-1])

    @staticmethod
    def jit_G(wix, wiy, wiz, wox, woy, woz, hx, hy, hz, lam_i, lam_o):
        return 1.0


# --------------------------------------------------------------------------------------------
# Fresnel


class Fresnel(Component):
    kind = "fresnel"
    #: What F depends on: ``"difference"`` — the microfacet angle θd alone (structured
    #: tabulation evaluates it once per θd node) — or ``"pair"``, the whole geometry (a term
    #: that overrides :meth:`F_pair` must say so; checked when the class is defined).
    depends = "difference"

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        if cls.F_pair is not Fresnel.F_pair and cls.depends != "pair":
            raise TypeError(f"{cls.__name__} overrides F_pair, so it depends on the whole pair: set depends = 'pair'")

    @property
    def layout(self) -> Layout:
        vals = {k: v for k, v in self.values.items() if isinstance(v, ChannelValue)}
        return combine_layouts([v.layout for v in vals.values()], names=vals) if vals else Layout()

    #: Scalar form for the compiled kernels (see the module docstring); None: not compiled.
    jit_F = None

    def jit_params(self, lam, n) -> np.ndarray:
        """``p[n, k]`` of :attr:`jit_F`: each declared parameter's value per channel, in order."""
        cols = [np.broadcast_to(np.asarray(self.values[p.name].at(lam, n), float), (n,)) for p in self.params
                if p.kind == "channel"]
        return np.stack(cols, axis=1) if cols else np.zeros((n, 0))

    def F(self, cos_d, lam, n):
        """Reflectance at ``cos_d[M]`` (cosine to the microfacet normal), shape ``(M, n)`` or scalar."""
        raise NotImplementedError

    def F_pair(self, wi, wo, cos_d, lam, n):
        """Reflectance for the pairs ``wi``, ``wo[M, 3]`` whose microfacet angle has cosine
        ``cos_d[M]``; shape ``(M, n)`` or scalar. Depends on ``cos_d`` only unless a term
        overrides it."""
        return self.F(cos_d, lam, n)

    #: Whether :meth:`F_mueller` is available.
    polarized = False

    def F_mueller(self, wi, wo, cos_d, lam, n):
        """The Mueller matrix ``(M, n, 4, 4)`` of the term for the pairs ``wi``, ``wo[M, 3]``, in
        their ``mitsuba`` basis (polarized terms only)."""
        raise NotImplementedError


def facet_to_pair(F, wi, wo):
    """Mueller matrices ``F (M, n, 4, 4)`` of reflection on the facet with normal h = normalize(wi
    + wo), given in the facet's s/p frame (e1 = normalize(h × k) for each beam), rotated into the
    pair's ``mitsuba`` basis."""
    h = wi + wo
    h = h / np.linalg.norm(h, axis=-1, keepdims=True)
    e_in, e_out = basis_frames("mitsuba", wi, wo)
    s_in = np.cross(h, -wi)
    s_out = np.cross(h, wo)
    norm_in = np.linalg.norm(s_in, axis=-1, keepdims=True)
    norm_out = np.linalg.norm(s_out, axis=-1, keepdims=True)
    # wi = wo: the facet's plane of incidence is undefined; take the basis's own vector
    s_in = np.where(norm_in > 1e-12, s_in / np.where(norm_in > 0, norm_in, 1.0), e_in)
    s_out = np.where(norm_out > 1e-12, s_out / np.where(norm_out > 0, norm_out, 1.0), e_out)
    return rotate_frames(F, -wi, s_in, e_in, wo, s_out, e_out)


@register
class NoFresnel(Fresnel):
    name = "none"
    summary = "F = 1 (reflects everything; for tests and normalized lobes)."

    def F(self, cos_d, lam, n):
        return 1.0

    @staticmethod
    def jit_F(wix, wiy, wiz, wox, woy, woz, cos_d, p, c):
        return 1.0


@register
class Schlick(Fresnel):
    name = "schlick"
    summary = "Schlick's approximation F0 + (1 − F0)(1 − cosθ)⁵."
    reference = "Schlick1994"
    params = (Param("f0", "channel", "Reflectance at normal incidence (Schlick).", minimum=0.0, maximum=1.0),)

    def F(self, cos_d, lam, n):
        return fresnel_schlick(cos_d[:, None], self.values["f0"].at(lam, n))

    @staticmethod
    def jit_F(wix, wiy, wiz, wox, woy, woz, cos_d, p, c):
        return schlick_scalar(cos_d, p[c, 0])


@register
class Dielectric(Fresnel):
    name = "dielectric"
    summary = "Unpolarized Fresnel reflectance of a dielectric with real relative index n."
    reference = "BornWolf1999"
    params = (Param("n", "channel", "Real part of the relative refractive index.", minimum=INDEX_MIN,
                    maximum=INDEX_MAX),)

    def F(self, cos_d, lam, n):
        return fresnel_dielectric(cos_d[:, None], self.values["n"].at(lam, n))

    polarized = True

    def F_mueller(self, wi, wo, cos_d, lam, n):
        eta = np.broadcast_to(np.asarray(self.values["n"].at(lam, n), float), (n,))
        return facet_to_pair(fresnel_mueller(cos_d[:, None], eta[None, :]), wi, wo)

    @staticmethod
    def jit_F(wix, wiy, wiz, wox, woy, woz, cos_d, p, c):
        return dielectric_scalar(cos_d, p[c, 0])


@register
class Conductor(Fresnel):
    name = "conductor"
    summary = "Unpolarized Fresnel reflectance of an absorbing medium with index n + ik."
    reference = "BornWolf1999"
    params = (
        Param("n", "channel", "Real part of the relative refractive index (or give material).", default=None,
              minimum=INDEX_MIN, maximum=INDEX_MAX),
        Param("k", "channel", "Extinction coefficient (imaginary part of the index, n + ik; or give material).",
              default=None, minimum=0.0, maximum=INDEX_MAX),
        MATERIAL,
    )

    def _setup(self, **values):
        resolve_index(self.values, f"{self.kind} = '{self.name}'")

    def F(self, cos_d, lam, n):
        return fresnel_conductor(cos_d[:, None], self.values["n"].at(lam, n), self.values["k"].at(lam, n))

    polarized = True

    def F_mueller(self, wi, wo, cos_d, lam, n):
        eta = np.broadcast_to(np.asarray(self.values["n"].at(lam, n), float), (n,))
        kap = np.broadcast_to(np.asarray(self.values["k"].at(lam, n), float), (n,))
        return facet_to_pair(fresnel_mueller(cos_d[:, None], eta[None, :], kap[None, :]), wi, wo)

    @staticmethod
    def jit_F(wix, wiy, wiz, wox, woy, woz, cos_d, p, c):
        return conductor_scalar(cos_d, p[c, 0], p[c, 1])


@register
class RayleighRice(Fresnel):
    name = "rayleigh-rice"
    summary = ("Rayleigh–Rice polarization factor Q = ½(Q_ss + Q_pp + Q_ps + Q_sp) of θi, θs, φs for an index "
               "n + ik (equals the Fresnel reflectance at the mirror direction).")
    reference = "Stover2012; Butler2015"
    depends = "pair"
    params = (
        Param("n", "channel", "Real part of the relative refractive index (or give material).", default=None,
              minimum=INDEX_MIN, maximum=INDEX_MAX),
        Param("k", "channel", "Extinction coefficient (imaginary part of the index, n + ik): 0 unless given (or "
              "give material).", default=None, minimum=0.0, maximum=INDEX_MAX),
        MATERIAL,
    )

    def _setup(self, **values):
        resolve_index(self.values, f"{self.kind} = '{self.name}'", k_default=0.0)

    def F(self, cos_d, lam, n):
        # what Q equals at the mirror direction, where cos_d = cosθi
        return fresnel_conductor(cos_d[:, None], self.values["n"].at(lam, n), self.values["k"].at(lam, n))

    def F_pair(self, wi, wo, cos_d, lam, n):
        eta = np.broadcast_to(np.asarray(self.values["n"].at(lam, n), float), (n,))
        kap = np.broadcast_to(np.asarray(self.values["k"].at(lam, n), float), (n,))
        return q_unpolarized(wi[:, None, :], wo[:, None, :], eta[None, :], kap[None, :])

    @staticmethod
    def jit_F(wix, wiy, wiz, wox, woy, woz, cos_d, p, c):
        return q_unpolarized_scalar(wix, wiy, wiz, wox, woy, woz, p[c, 0], p[c, 1])

    polarized = True

    def F_mueller(self, wi, wo, cos_d, lam, n):
        eta = np.broadcast_to(np.asarray(self.values["n"].at(lam, n), float), (n,))
        kap = np.broadcast_to(np.asarray(self.values["k"].at(lam, n), float), (n,))
        m = q_mueller(wi[:, None, :], wo[:, None, :], eta[None, :], kap[None, :])
        return convert_basis(m, wi, wo, "psps", "mitsuba")



# --------------------------------------------------------------------------------------------
# Composing models: a model's flat spec keys for one component kind


def component_param(kind: str, default: str, doc: str) -> Param:
    """The ``choice`` parameter that selects a component of ``kind`` (choices: the registry)."""
    return Param(kind, "choice", doc, default=default, choices=tuple(COMPONENTS[kind]))


def member_params(kind: str, skip=()) -> tuple:
    """Union of the parameters of every registered component of ``kind`` (first declaration
    wins), with ``used_when`` saying which components use each and ``requires`` naming them
    (so tools that draw parameters, like the contract test, draw each only with its users)."""
    seen = {}
    users = {}
    for cname, cls in COMPONENTS[kind].items():
        for p in cls.params:
            if p.name in skip:
                continue
            seen.setdefault(p.name, p)
            users.setdefault(p.name, []).append(cname)
    out = []
    for name, p in seen.items():
        when = f"{kind} = " + " or ".join(repr(u) for u in users[name])
        out.append(Param(p.name, p.kind, p.doc, p.units, None, p.minimum, p.maximum, p.exclusive_minimum, p.choices,
                         p.angle, when, requires=((kind, tuple(users[name])),)))
    return tuple(out)


def build(kind: str, name: str, given: dict):
    """Build component ``name`` of ``kind`` from the model's flat values ``given`` (None = not
    given). A value given for a parameter the chosen component does not use is an error naming
    the components that do."""
    cls = get(kind, name)
    own = {p.name for p in cls.params}
    for key, value in given.items():
        if value is not None and key not in own:
            users = [c for c, k in COMPONENTS[kind].items() if any(p.name == key for p in k.params)]
            raise ParameterError(key, f"only used with {kind} = {' or '.join(repr(u) for u in users)} "
                                 f"({kind} is '{name}')")
    for p in cls.params:
        if p.required and given.get(p.name) is None:
            raise ParameterError(p.name, f"required when {kind} = '{name}'")
    return cls(**{k: v for k, v in given.items() if k in own and v is not None})
