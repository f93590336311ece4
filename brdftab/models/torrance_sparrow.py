"""Torrance–Sparrow 1967: V-groove facets with Gaussian slopes plus a diffuse component.

The absolute BRDF (Eqs. 2, 4 and 12 of [Torrance1967])::

    f(ωi, ωo) = (ρd / π) · [1 + g · F(ψ′, n̂) · G(ψp, θp) · exp(−c²α²) / (cosψ cosθ)]

with ψ = θi, θ = θo; α the angle between the facet normal h = normalize(ωi + ωo) and the mean
surface normal (in **degrees** in exp(−c²α²): ``c_per_deg`` is per degree, as Fig. 8 implies
— with α in radians the ψ = 10° curve of Fig. 8 would peak at 1.55 at the horizon instead of
1.0021 at 13.3°); ψ′ the angle between ωi and h (cosψ′ = ωi·h); F the Fresnel reflectance of
the configured Fresnel component (``fresnel = "none"`` is F = 1, Fig. 8's "material-free"
case; ``"conductor"`` with n, k is F(ψ′, n̂) for the complex index n̂ = n − ik of the paper,
written n + ik here: |r|² is the same). How the paper's constants map: Eq. 4's diffuse radiance
a N_i cosψ gives the BRDF a = ρd/π (ρd the diffuse reflectance), and Eq. 12's specular constant
b f N_i dω_i / 4 is g·a, so ``g`` is the specular-to-diffuse ratio of Eq. 13. The paper's
relative form (Eq. 23, the ratio to the mirror direction of the mean surface) is
:meth:`TorranceSparrow1967.relative`.

**Masking and shadowing.** G is the V-groove factor of Table I (Eqs. 16–21) evaluated at the
projected angles ψp, θp of ωi and ωo in the plane spanned by the mean-surface normal and the
facet normal (the plane perpendicular to the V-groove axis). Eq. 14 as printed takes the wrong
branch of its inverse trigonometry (in the plane of incidence it gives ψp = −ψ), so the
projected angles are computed here by projecting the vectors (:func:`projected_angles`),
signed so that ψp ≥ 0. Table I with those angles (:func:`g_table1`) equals the vector form
min(1, 2(n·h)(n·ωo)/(ωo·h), 2(n·h)(n·ωi)/(ωo·h)) of [Blinn1977]/[Cook1982] — the registered
``v-groove`` shadowing component the model uses — to rounding (tested), so brdftab has one G.
G/cosθ stays finite as θ → 90°, tending to 2(n·h)/(ωo·h) = 2cosα/cosψ′; Eq. 22's 2cotα/cos(β2 − φ)
agrees with it only with β2 on the corrected branch.

**Slope distribution.** The ``torrance-sparrow`` distribution component is the facet-normal
density D(h) = exp(−c²α²)/N, normalized so that ∫ D(h) cosα dω_h = 1 over the hemisphere of
facet normals: N = 2π ∫₀^{π/2} exp(−c²α²) cosα sinα dα (computed by Gauss–Legendre quadrature
at construction, c in rad⁻¹ = c_per_deg · 180/π). It is usable in ``microfacet`` as any D
(Smith Λ by quadrature of the projected-area integral, sampling by its inverse CDF); the
``torrance-sparrow-1967`` model uses its unnormalized exp(−c²α²) = N·D(h), as the paper does.
Its scalar forms (``jit_D``; ``jit_lambda`` evaluates the projected-area spline from the
coefficients in ``jit_params``) let compiled microfacet kernels compose it like any D; the
``torrance-sparrow-1967`` model fuses exp(−c²α²), the V-groove G and its Fresnel term in one
compiled loop of its own.

The model is reciprocal (G and F(ψ′) are symmetric in ωi, ωo) and isotropic. It does not
conserve energy in general: with Fig. 8's constants its albedo is about 1.29 ρd at every θi.
"""

from __future__ import annotations

import math

import numpy as np

from .._jit import device
from ..brdf import Model
from ..params import Param
from ..quadrature import gauss_legendre
from . import components as C
from .microfacet import ComposedParams, split_components
from ._registry import register

__all__ = ["GaussianAngle", "TorranceSparrow1967", "projected_angles", "g_table1"]

HALF_PI = 0.5 * np.pi


def _panels(lo, hi, edges, nodes=24):
    """Gauss–Legendre nodes and weights on [lo, hi] split at ``edges``."""
    e = np.unique(np.clip(np.concatenate([[lo, hi], edges]), lo, hi))
    x, w = gauss_legendre(nodes, 0.0, 1.0)
    pts = (e[:-1, None] + (e[1:] - e[:-1])[:, None] * x).ravel()
    wts = ((e[1:] - e[:-1])[:, None] * w).ravel()
    return pts, wts


@C.register
class GaussianAngle(C.Distribution):
    """Torrance–Sparrow's Gaussian distribution of facet angles, exp(−c²α²), α in degrees."""

    name = "torrance-sparrow"
    summary = "Torrance–Sparrow Gaussian distribution of facet angles exp(−c²α²) (c per degree), area-normalized."
    reference = "Torrance1967"
    params = (
        Param("c_per_deg", "float", "Slope constant c of exp(−c²α²), per degree of the facet angle α.",
              units="1/deg", default=0.05, minimum=1e-5, maximum=50.0),
    )

    def _setup(self, c_per_deg):
        self.c_per_deg = c_per_deg
        self.c = c_per_deg * 180.0 / np.pi                       # per radian
        self.alpha_x = self.alpha_y = 1.0 / self.c              # roughly the lobe's width [rad]
        s = 1.0 / self.c
        edges = np.clip(s * 2.0 ** np.arange(-4, 8), 0, HALF_PI)
        a, w = _panels(0.0, HALF_PI, edges)
        self.norm = float(2 * np.pi * np.sum(np.exp(-(self.c * a) ** 2) * np.cos(a) * np.sin(a) * w))
        # projected area P(θ) = ∫ D(h) max(0, ω·h) dω_h on a θ table (Smith Λ = P/cosθ − 1)
        self._theta = np.linspace(0.0, HALF_PI, 257)
        from scipy.interpolate import CubicSpline  # (here: scipy.interpolate takes 0.2 s to import)

        self._proj = CubicSpline(self._theta, self._projected_area(self._theta, a, w))
        # inverse CDF of the facet angle for sampling (density D cosα over solid angle)
        pdf = np.exp(-(self.c * a) ** 2) * np.cos(a) * np.sin(a) * w * 2 * np.pi / self.norm
        self._cdf_a = np.concatenate([[0.0], a, [HALF_PI]])
        cdf = np.concatenate([[0.0], np.cumsum(pdf) - 0.5 * pdf, [1.0]])
        self._cdf = np.maximum.accumulate(np.minimum(cdf, 1.0))

    def _projected_area(self, theta, a, w):
        """∫ D(h) max(0, ω·h) dω_h for directions at polar angles ``theta`` (closed-form azimuth)."""
        A = np.cos(theta)[:, None] * np.cos(a)[None, :]
        B = np.sin(theta)[:, None] * np.sin(a)[None, :]
        with np.errstate(divide="ignore", invalid="ignore"):
            x = np.clip(-A / np.where(B > 0, B, 1.0), -1.0, 1.0)
            part = 2.0 * (A * np.arccos(x) + np.sqrt(np.maximum(B * B - A * A, 0.0)))
        inner = np.where(A >= B, 2 * np.pi * A, np.where(A <= -B, 0.0, part))
        d = np.exp(-(self.c * a) ** 2) / self.norm
        return inner @ (d * np.sin(a) * w)

    @property
    def isotropic(self) -> bool:
        return True

    def jit_params(self) -> np.ndarray:
        """``p`` of :attr:`jit_D` and :attr:`jit_lambda`: [c (rad⁻¹), N, knots of the projected-area
        spline, 1/knot spacing, knots..., then the spline's 4 coefficients per interval]."""
        x = self._proj.x
        coef = np.ascontiguousarray(self._proj.c.T).ravel()  # interval by interval, highest power first
        return np.concatenate([[self.c, self.norm, x.size, (x.size - 1) / x[-1]], x, coef])

    @staticmethod
    @device
    def jit_D(hx, hy, hz, p):
        return slope_term_scalar(hx, hy, hz, p[0]) / p[1]

    @staticmethod
    @device
    def jit_lambda(wx, wy, wz, p):
        if not wz > 0.0:
            return math.inf
        theta = min(max(math.atan2(math.sqrt(wx * wx + wy * wy), wz), 0.0), HALF_PI)
        lam = _spline_scalar(theta, p) / wz - 1.0
        return max(lam, 0.0)

    def D(self, h):
        h = np.asarray(h, float)
        hz = h[..., 2]
        alpha = np.arctan2(np.hypot(h[..., 0], h[..., 1]), hz)
        return np.where(hz > 0, np.exp(-(self.c * alpha) ** 2) / self.norm, 0.0)

    def slope_term(self, h):
        """exp(−c²α²) of the paper (unnormalized; = N·D(h))."""
        h = np.asarray(h, float)
        alpha = np.arctan2(np.hypot(h[..., 0], h[..., 1]), h[..., 2])
        return np.where(h[..., 2] > 0, np.exp(-(self.c * alpha) ** 2), 0.0)

    def lambda_(self, w):
        w = np.asarray(w, float)
        theta = np.arctan2(np.hypot(w[..., 0], w[..., 1]), w[..., 2])
        with np.errstate(divide="ignore", invalid="ignore"):
            lam = self._proj(np.clip(theta, 0.0, HALF_PI)) / w[..., 2] - 1.0
        return np.maximum(np.where(w[..., 2] > 0, lam, np.inf), 0.0)

    def sample(self, u1, u2):
        a = np.interp(np.asarray(u1, float), self._cdf, self._cdf_a)
        phi = 2 * np.pi * np.asarray(u2, float)
        return np.stack([np.sin(a) * np.cos(phi), np.sin(a) * np.sin(phi), np.cos(a)], axis=-1)


@device
def slope_term_scalar(hx, hy, hz, c):
    """:meth:`GaussianAngle.slope_term` exp(−c²α²) of one unit normal (``c`` per radian; α from
    sqrt(x² + y²), within an ulp of the array form's hypot at a tenth of its cost)."""
    if not hz > 0.0:
        return 0.0
    t = c * math.atan2(math.sqrt(hx * hx + hy * hy), hz)
    return math.exp(-(t * t))


@device
def _spline_scalar(x, p):
    """The projected-area spline of :meth:`GaussianAngle.jit_params` at ``x`` in [0, π/2] (scipy's
    interval choice, x[i] <= x < x[i + 1], closed at the last knot; its evaluation order)."""
    nk = int(p[2])
    knots = p[4:4 + nk]
    i = min(max(int(x * p[3]), 0), nk - 2)
    while i > 0 and x < knots[i]:
        i -= 1
    while i < nk - 2 and x >= knots[i + 1]:
        i += 1
    cf = p[4 + nk + 4 * i: 8 + nk + 4 * i]
    s = x - knots[i]
    z = s
    res = 0.0 + cf[3]
    res = res + cf[2] * z
    z = z * s
    res = res + cf[1] * z
    z = z * s
    return res + cf[0] * z


def projected_angles(wi, wo):
    """(ψp, θp) [rad]: ωi and ωo projected onto the plane spanned by the mean-surface normal
    and the facet normal h = normalize(ωi + ωo), as polar angles in that plane.

    Sign convention of [Torrance1967] Fig. 4: ψp ≥ 0 on the side of the source; θp is positive
    on the other side of the normal (forward scattering in the plane of incidence gives
    ψp = ψ, θp = θ; back-scattering gives θp < 0). Where h is the normal (no azimuth) the plane
    is taken through ωi.
    """
    wi = np.asarray(wi, float)
    wo = np.asarray(wo, float)
    h = wi + wo
    e = h[..., :2]
    r = np.hypot(e[..., 0], e[..., 1])
    ri = np.hypot(wi[..., 0], wi[..., 1])
    use_h = r > 1e-12 * np.linalg.norm(h, axis=-1)
    ex = np.where(use_h, e[..., 0] / np.where(use_h, r, 1.0), np.where(ri > 0, -wi[..., 0] / np.where(ri > 0, ri, 1), 1.0))
    ey = np.where(use_h, e[..., 1] / np.where(use_h, r, 1.0), np.where(ri > 0, -wi[..., 1] / np.where(ri > 0, ri, 1), 0.0))
    ui = wi[..., 0] * ex + wi[..., 1] * ey
    uo = wo[..., 0] * ex + wo[..., 1] * ey
    s = np.where(ui > 0, -1.0, 1.0)          # ψp = atan2(−s·ui, zi) ≥ 0
    psi_p = np.arctan2(-s * ui, wi[..., 2])
    theta_p = np.arctan2(s * uo, wo[..., 2])
    return psi_p, theta_p


def _eq21(psi_p, theta_p):
    """Eqs. 21a/21b: G = 1 − [1 − (1 − A²)^½]/A (G = 1 where A = 0)."""
    half = np.cos(0.5 * (theta_p - psi_p)) ** 2
    s2 = np.sin(theta_p) ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        A = (s2 - half) / (half - np.cos(theta_p - psi_p) * s2)
        A = np.clip(A, -1.0, 1.0)
        g = 1.0 - (1.0 - np.sqrt(1.0 - A * A)) / A
    return np.where(np.abs(A) < 1e-12, 1.0 - 0.5 * A, g)   # the L'Hospital limit near A = 0


def g_table1(psi_p, theta_p):
    """The geometrical attenuation factor G(ψp, θp) of [Torrance1967] Table I (Eqs. 16–21), for
    0 ≤ ψp ≤ π/2 and −π/2 ≤ θp ≤ π/2."""
    psi_p, theta_p = np.broadcast_arrays(np.asarray(psi_p, float), np.asarray(theta_p, float))
    g = np.ones(psi_p.shape)
    masked = _eq21(psi_p, theta_p)
    shadowed = _eq21(theta_p, psi_p)                   # Eqs. 21 with ψp and θp interchanged
    low = psi_p <= np.pi / 4
    upper = theta_p >= (psi_p + np.pi) / 3             # masking beyond θp* (Eq. 17), both ranges
    g = np.where(upper, masked, g)
    g = np.where(low & (theta_p <= (psi_p - np.pi) / 3), masked, g)           # Eq. 18
    high = ~low
    g = np.where(high & (theta_p <= -psi_p), masked, g)                       # masking-shadowing
    g = np.where(high & (theta_p > -psi_p) & (theta_p <= 3 * psi_p - np.pi), shadowed, g)  # Eq. 19
    return np.clip(g, 0.0, 1.0)


def _ts_params():
    return (
        Param("rho_d", "channel", "Diffuse reflectance ρd: the diffuse BRDF is ρd/π (Eq. 4's constant a).",
              minimum=0.0, maximum=1.0),
        Param("g", "float", "Specular-to-diffuse ratio g of Eq. 13 (0: diffuse only).", default=2.0 / 3.0,
              minimum=0.0, maximum=1e6),
        Param("c_per_deg", "float", "Slope constant c of exp(−c²α²), per degree of the facet angle α.",
              units="1/deg", default=0.05, minimum=1e-5, maximum=50.0),
        C.component_param("fresnel", "none", "Fresnel term F(ψ′) ('none' is F = 1, Fig. 8's material-free case)."),
        *C.member_params("fresnel"),
    )


@register
class TorranceSparrow1967(Model):
    name = "torrance-sparrow-1967"
    summary = ("Torrance–Sparrow 1967: (ρd/π)[1 + g F G exp(−c²α²)/(cosθi cosθo)], V-groove G (Table I), "
               "Gaussian facet angles (c per degree).")
    reference = "Torrance1967"
    params = ComposedParams(_ts_params)

    def _setup(self, rho_d, g, c_per_deg, fresnel, **values):
        self.rho_d = rho_d
        self.g = g
        self.dist = C.create("distribution", "torrance-sparrow", c_per_deg=c_per_deg)
        self.shadow = C.create("shadowing", "v-groove")
        self.fres = C.build("fresnel", fresnel, split_components(values, ("fresnel",))["fresnel"])
        from ..channels import combine_layouts

        self.layout = combine_layouts([rho_d.layout, self.fres.layout])
        self.energy_conserving = False

    @property
    def lobe_width(self) -> float:
        return self.dist.width

    def _kernel(self, lam, n):
        if self.fres.jit_F is None:
            return None
        run = _ts_kernel(self.fres)
        pf = np.ascontiguousarray(self.fres.jit_params(lam, n))
        rho_pi = np.ascontiguousarray(np.broadcast_to(np.asarray(self.rho_d.at(lam, n), float) / np.pi, (n,)))
        k = np.array([self.g, self.dist.c])

        def evaluate(wi, wo, state, out, add):
            run(wi, wo, state, out, k, pf, rho_pi, add)
        return evaluate

    def _eval(self, wi, wo, lam, n):
        h = wi + wo
        norm = np.sqrt(np.einsum("...i,...i->...", h, h))
        h /= norm[:, None]
        cos_d = 0.5 * norm
        spec = self.g * self.shadow.G(wi, wo, h) * self.dist.slope_term(h) / (wi[:, 2] * wo[:, 2])
        F = self.fres.F_pair(wi, wo, cos_d, lam, n)
        spec = spec[:, None] * (F if np.ndim(F) else np.ones((1, n)))
        rho = np.asarray(self.rho_d.at(lam, n), float)
        return rho / np.pi * (1.0 + spec)

    def relative(self, wi, wo, wavelengths=None):
        """Eq. 23: f(ωi, ωo) / f(ωi, ωr), ωr the mirror direction of ωi about the mean surface
        normal (the paper's plots). ``wi``, ``wo[..., 3]``; returns ``[..., C]``."""
        wi = np.asarray(wi, float)
        mirror = wi * np.array([-1.0, -1.0, 1.0])
        f = self.eval(wi, wo, wavelengths)
        with np.errstate(divide="ignore", invalid="ignore"):
            return f / self.eval(wi, np.broadcast_to(mirror, np.shape(wi)), wavelengths)


_KERNEL = '''\
# Generated by brdftab.models.torrance_sparrow (do not edit): torrance-sparrow-1967 with {fres}; sources {digest}
import math

import numba
import numpy as np

from brdftab._jit import OPTIONS
from brdftab.geometry import half_vector_scalar, pair_scalar
from brdftab.models.components import get
from brdftab.models.fused import as_device
from brdftab.models.torrance_sparrow import slope_term_scalar

_S = as_device(slope_term_scalar)
_H = as_device(half_vector_scalar)
_P = as_device(pair_scalar)
_G = as_device(get("shadowing", "v-groove").jit_G)
_F = as_device(get("fresnel", {fres!r}).jit_F)

#: Pairs per block: the geometry of a block in one loop, then F channel by channel in another.
BLOCK = 256


@numba.njit(**OPTIONS)
def run(wi, wo, state, out, k, pf, rho_pi, add):
    nc = out.shape[1]
    m = wi.shape[0]
    spec = np.empty(BLOCK)
    cosd = np.empty(BLOCK)
    for b in range((m + BLOCK - 1) // BLOCK):
        i0 = b * BLOCK
        size = min(BLOCK, m - i0)
        for j in range(size):
            i = i0 + j
            wix, wiy, wiz, wox, woy, woz = _P(wi, wo, i)
            hx, hy, hz, cosd[j] = _H(wix, wiy, wiz, wox, woy, woz)
            g = _G(wix, wiy, wiz, wox, woy, woz, hx, hy, hz, 0.0, 0.0)
            spec[j] = k[0] * g * _S(hx, hy, hz, k[1]) / (wiz * woz)
        for c in range(nc):
            for j in range(size):
                i = i0 + j
                if state[i] == 1:
                    v = rho_pi[c] * (1.0 + spec[j] * _F(wi[i, 0], wi[i, 1], wi[i, 2], wo[i, 0], wo[i, 1], wo[i, 2],
                                                         cosd[j], pf, c))
                    out[i, c] = out[i, c] + v if add else v
'''


def _ts_kernel(fres):
    """The compiled loop of :class:`TorranceSparrow1967` with the Fresnel component ``fres``
    (generated, like :func:`brdftab.models.fused.microfacet_kernel`, so that an edit of a scalar
    form it inlines compiles anew)."""
    from .._jit import generated_module, source_hash
    from ..geometry import half_vector_scalar, pair_scalar

    shadow = C.get("shadowing", "v-groove")
    digest = source_hash(slope_term_scalar, half_vector_scalar, pair_scalar, shadow.jit_G, fres.jit_F)
    source = _KERNEL.format(fres=fres.name, digest=digest)
    return generated_module("torrance_sparrow", source).run
