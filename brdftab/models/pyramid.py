"""Pyramidal microfacets: KOH-textured crystalline silicon (random upright pyramids), with
multiple bounces.

Implements the model de Haas derives and leaves as future work [DeHaas2024] (§5.2.1), with
the corrections its printed formulas need (``shared/reference/models.md`` §5.6), as three
registered parts:

* the ``pyramid`` **distribution** (:class:`PyramidDistribution`) — four facet normals
  f_k = (sinθp cosφk, sinθp sinφk, cosθp), θp = arctan √2 = 54.7356° (the (111) planes of
  (100) silicon), φk = φ0 + k·90°. ``phi0`` is the azimuth of a face *normal* (default 0: face
  normals along ±x, ±y). Facet k has weight a_k = 1/(4 cosθp) in D (thesis Eq. 3.2), so
  Σ a_k f_k = ẑ and ∫ D cosθh dω = 1. A Dirac NDF cannot be tabulated, so each facet is
  given a narrow Beckmann lobe of slope parameter α = ``facet_roughness`` about its normal
  (our extension; D tends to the thesis' NDF as α → 0):

      D(h) = Σk a_k · D_Beckmann,α(h in the frame of f_k),   zero for h_z <= 0.

* the ``pyramid`` **shadowing** (:class:`PyramidShadowing`) — the projected-area-consistent
  masking

      G1(o) = min(1, cosθo / Σk a_k T_k(o)),   T_k(o) = ∫ lobe_k(h) ⟨o, h⟩⁺ dω,

  with the *actual* direction o. T_k is the area of facet k visible from o; for Dirac facets
  T_k(o) = max(0, ⟨o, f_k⟩), which is the corrected thesis formula (zero for back-facing
  facets). With the Beckmann spread T_k(o) = ½ c (1 + erf a) + α s e^{−a²}/(2√π),
  c = ⟨o, f_k⟩, s = √(1 − c²), a = c/(α s) (Smith's Λ of the facet lobe, written for both
  signs of c), and the projected-area identity (Eq. 3.5) ∫ D ⟨o, h⟩⁺ G1(o) dω = cosθo holds
  for every o above the horizon (tests: to 1e-6). G1 is the Smith G1 = 1/(1 + Λ) of the
  pyramid NDF with Λ(o) = Σ a_k T_k(o) / cosθo − 1, so the distribution also serves the Smith
  shadowing terms. Two directions combine in the height-correlated form
  G = 1/(1 + Λ(ωi) + Λ(ωo)) [Heitz2014], closer to the ray tracer than G1(ωi) G1(ωo).

* the ``pyramid-microfacet`` **model** (:class:`PyramidMicrofacet`) — the single-bounce
  microfacet term D·G·F/(4 cosθi cosθo) (reciprocal) plus the multiple bounces of §3.3: exit
  directions by successive mirror reflections about the facet normals (Eq. 3.9) over face
  sequences up to ``max_bounces`` (default 3, at most 6; 1 keeps the single-bounce term only),
  pruning back-face hits (face j is hit only when ⟨d, f_j⟩ < 0 for the travelling direction d,
  which also excludes repeats). How much energy each sequence carries is a random walk over
  the faces: ``walk = "traced"`` (default) takes it from a ray tracer of the random array,
  ``"height-correlated"`` and ``"uncorrelated"`` from a Smith microsurface (below).

Corrections of the thesis' formulas [DeHaas2024] (models.md §5.6)
-----------------------------------------------------------------
* Eq. 3.6 lacks the D(f_s) factor in its denominator, and the rotation of o to a face frame of
  Eq. 3.7 breaks the projected-area identity (tests: by −9 % … +40 %): G1 above uses the actual
  direction and the facet weights a_k, and satisfies Eq. 3.5 for any direction.
* The sequence weights of §3.3.2 (a product of cosines times the final G1) are not energies.
  Here they are the probabilities of a random walk: the first face k is hit with probability
  a_k T_k(ωi) / Σ_j a_j T_j(ωi) (Dirac facets: ∝ a_k ⟨ωi, f_k⟩⁺); after a reflection into o
  the ray escapes with some probability, else it hits face j with probability ∝ a_j T_j(−o)
  over the faces it can hit. The escape probability is, with ``walk = "uncorrelated"`` (the
  thesis' rule made a probability), G1(o) (0 if o_z <= 0); with
  ``walk = "height-correlated"`` the walk follows the height of the hit point as in
  the Smith microsurface [Heitz2016]: in the height's cumulative probability U ∈ (0, 1] the
  first hit lies at U with density μ0 U^{μ0 − 1} (μ0 = 1 + Λ(ωi): first-hit points sit
  high), a ray going up from U escapes with probability U^{Λ(o)}, else hits at U' > U with
  density Λ U^Λ U'^{−Λ−1}, and a ray going down hits at U' < U with density μ U'^{μ−1} / U^μ
  (μ = 1 + Λ(−o)). Every density stays a short sum of powers of U, so each sequence's
  probability is exact in closed form (where two exponents come within 1e-7 one is moved by
  3e-7).
* The thesis' "20 of 64" surviving 3-bounce sequences hold only at normal incidence: with this
  pruning 20 survive at normal incidence, 8 at 45°/0° and 7 at 45°/25° (tests, every walk).

The traced walk (default)
-------------------------
A Smith microsurface is not the random pyramid array: the two walks above miss the tracer's
energy of some exit clusters by up to a factor 2 at the thesis' incidences, and 4.3 elsewhere
(table below). ``walk = "traced"`` keeps the first hit (face k with probability
a_k T_k(ωi) / S(ωi), which the tracer's first hits match within 0.005 up to θi = 87°, 0.01 at
89°: tests) and takes every later branch — escape right after the sequence s, or go on to face
j — from the ray tracer of the random array (:mod:`~brdftab.models.pyramid_tracer`).
``pyramid_walk.npz`` (16 kB), made by ``tools/make_pyramid_walk.py`` (16 tiles of 1000
pyramids, 160 000 rays per node, fields and rays of seeds of their own; about 17 minutes on one
core), holds the fractions of the rays escaping after each sequence of up to 3 bounces at
incidence nodes θ = 0, 3.5, …, 84, 87, 89° and φ = 0, 9, …, 45° from a face normal's azimuth
(other azimuths by the array's symmetries: 90° turns and the mirrors about a face normal's
azimuth and the diagonal). Between nodes (:class:`~brdftab.models.pyramid_walk.WalkTable`)
the tracer's branching is interpolated relative to the uncorrelated walk's, whose branches
open at the same incidences as the tracer's, so a branch opening between two nodes is not
smeared over the step; branches the geometry closes at the query get nothing. Past 3 bounces
the tracer's escape probability after the third bounce holds, and the later branches follow
the uncorrelated rule. The single-bounce term takes G = G1(ωi) G1(ωo) √(r_k(ωi) r_k(ωo)),
at most min(G1(ωi), G1(ωo)), on facet k's lobe, r_k(ω) the tracer's probability of escaping
right after a first hit on k over the uncorrelated G1(o_k) (o_k: ω mirrored on f_k): the term
stays reciprocal (r_k(ωi) = r_k(o_k) on the true surface, by reciprocity) and, for mirror
facets, sends out what the tracer sees escape after one bounce.

Energy. The single-bounce term is the microfacet integral of each facet's lobe; the walk goes on
from the first hit on facet k with what that lobe does not send out (P_k minus its integral,
the walk's state rescaled; :func:`_share`; when evaluating f, the walk takes those integrals
from a coarser rule, 4e-5 off at most, 6e-4 with the traced walk, whose G follows its table's
bilinear interpolation across a lobe: tests), so the two terms share the energy: for mirror
facets the energies escaping after 1, 2, … bounces plus the energy still inside after
``max_bounces`` sum to 1 (tests, to 1e-12), and the directional albedo is 1 minus what is still
inside (tests: to 1e-4). The walk's own sequence energies are reciprocal: E(ωi → e)/cosθe equals
E(e → ωi)/cosθi for the reversed sequence (tests: 1e-12, the height-correlated and the
uncorrelated walk); with the single-bounce integrals of facet_roughness = 1e-4 the model's are
(tests: 1e-4). Each bounce multiplies the
unpolarized Fresnel reflectance of the facet at its local angle (``fresnel``, with n, k per
channel or spectrum; ``"none"`` gives mirror facets; a term's ``F(cos)``, so
``"rayleigh-rice"`` gives its mirror-direction value, the Fresnel reflectance). The unpolarized product is an
approximation: against polarization-tracked light on the random array it is −0.3 % (normal
incidence) … +0.6 % (45°) off (tests, silicon at 632.8 nm [Aspnes1983]).

Exit lobes. A sequence of two or more bounces leaving in direction e with energy E adds
f = E · L(ωo; e) / (N(e) cosθo), L the facet lobe about e: a Beckmann lobe of slope parameter
2α in e's frame (L = exp(−tan²ρ/(2α)²) / (π (2α)² cos³ρ), ρ the angle from e — the width of a
single-bounce lobe; a normalized distribution on the sphere). The part of L below the horizon
is **renormalized**, not dropped: N(e) = 1 − ½ erfc(tanε/(2α)) is the fraction of L above it
(ε the elevation of e; exact: the horizon is a straight line in L's gnomonic plane), so
∫ f cosθo dωo = E for every exit. The part of a single-bounce lobe below the horizon is not in
f (as in every microfacet model) but not lost either: its integral excludes it, so the walk
carries it on to the next bounce. The spread lobes carry the energy of their centre, so with
``max_bounces`` > 1 the model is not reciprocal and declares it (``brdftab validate`` reports
the measured asymmetry as WARN).

Quadrature. ``albedo_rule(ωi)`` gives each lobe a rule of its own (a facet's lobe: a polar rule
in its slope plane, each ray cut into smooth panels at the horizon; an exit lobe: a product
rule in its gnomonic plane, cut exactly at the horizon), weighted by the partition of unity
g_m / Σ g_l of the lobes' own values; against a 0.2° brute-force grid it agrees to 1e-5
(tests). ``quadrature_parts()`` gives the two terms, each with its rule. The distribution's own
``albedo_rule(ωi)`` (the facet lobes, partitioned by D_k/D) integrates any microfacet BRDF with
this D (tests: to 1e-5 against a grid).

Measured against the ray tracer (:mod:`~brdftab.models.pyramid_tracer`: 8 random tiles of
1000 equal overlapping pyramids with infinite bases, 20 000 rays each, on seeds independent of
the traced walk's table; mirror facets, facet_roughness → 0), the fractions of the incident
energy escaping after 1 / 2 / 3 bounces:

    ===========  =====================  =====================  =====================  =====================
    incidence    tracer                 traced walk            height-correlated      uncorrelated
    ===========  =====================  =====================  =====================  =====================
    0°           0.000 / 0.659 / 0.280  0.000 / 0.656 / 0.284  0.000 / 0.676 / 0.264  0.000 / 0.690 / 0.269
    45° / 0°     0.407 / 0.491 / 0.100  0.405 / 0.491 / 0.101  0.379 / 0.521 / 0.098  0.367 / 0.555 / 0.076
    45° / 25°    0.382 / 0.520 / 0.092  0.385 / 0.518 / 0.092  0.370 / 0.539 / 0.087  0.360 / 0.565 / 0.074
    ===========  =====================  =====================  =====================  =====================

The tests hold every walk within 0.05 / 0.07 / 0.04 of the tracer, the traced walk within
0.005, the height-correlated walk within 0.035, and the largest deviations in that order at
every incidence (the uncorrelated walk is 0.064 high on the 2-bounce fraction at 45°/0°: it
ignores that first-hit points sit high).

Per exit cluster (a face sequence; no two share an exit direction), the largest relative
deviation from the tracer over the clusters that carry at least 1 % of the energy in the
tracer or the model, with the traced walk the single-bounce energy within 0.003 (tests; the
tracer's standard errors are 0.3–3 % of such a cluster; none of these incidences is a node of
the table but normal incidence, its pole):

    =========  ===========  =======================================
    incidence  traced walk  height-correlated walk
    =========  ===========  =======================================
    0°         6 %          34 % (3-bounce back-and-forth clusters)
    45° / 0°   3 %          17 %
    45° / 25°  5 %          97 %
    30° / 10°  4 %          45 %
    60° / 40°  3 %          46 %
    20° / 30°  7 %          332 %
    52° / 5°   8 %          151 %
    =========  ===========  =======================================

The tests hold the traced walk's within 9 % at each.
Every traced exit after up to 3 bounces lies within 1e-6° of a model exit of the same sequence.
With silicon's Fresnel (n + ik = 3.882 + 0.019i) the total reflectance agrees within 0.01
(tracer / model: 0.097 / 0.095 at normal incidence, 0.206 / 0.207 at 45°/0°, 0.203 / 0.204 at
45°/25°).

Compiled evaluation. With the traced walk, ``eval`` is one compiled loop over the pairs (numba,
see :mod:`brdftab._jit`; :func:`_pair_rows`, generated per Fresnel term): per incidence direction
(kept while consecutive pairs share it, as a grid's do) its walk-table cell, G1, Λ and the face
sequences its walk can take, found by geometry alone; per pair the single-bounce term, then the
exit lobes that reach ωo, the walk's probabilities computed only along their sequences and the
facet energy (the coarse rule) of a sequence's first facet only when one is needed. The terms
(``quadrature_parts``) evaluate the same way. The Smith walks compile the helpers (walk-table
interpolation, visible areas, facet energies, exit lobes' sums) around numpy sequences; the fine
rule stays numpy, and so does a Fresnel term that depends on the whole pair. Inside
:func:`brdftab.brdf.numpy_reference` the numpy code runs throughout; the two agree to 2e-12
relative on the tests' pairs (numpy's exp, arccos and arctan2 and scipy's erf differ from libm's
in the last digit, and the walk's share P_k − E_k of a facet whose lobe sends out most magnifies
it).

Limits: equal pyramid heights only; random heights (the Procel distribution of the thesis'
§4.1) are future work, as are the bevelled edges of real pyramids. The surface is fully
covered (no flat floor). Incidence directions point toward the source, so "45°/25°" is a
source 45° above the surface in the azimuth 25° from a face normal's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import erf, erfc

from .._jit import device, kernel
from ..brdf import BRDF, Model
from ..errors import ParameterError
from ..params import Param
from ..quadrature import gauss_legendre
from . import components as C
from . import pyramid_walk
from .pyramid_walk import _axis_index, _domain, bilinear_ratio, cell_of, corner_weights, ratio_in_cell
from ._registry import register
from .combinators import Sum
from .distributions import d_beckmann
from .microfacet import ComposedParams

__all__ = ["THETA_P", "FACET_WEIGHT", "facet_normals", "visible_area", "PyramidDistribution", "PyramidShadowing",
           "PyramidMicrofacet", "Exits"]

#: Facet tilt θp = arctan √2 (the (111) planes of (100) silicon) [rad].
THETA_P = float(np.arctan(np.sqrt(2.0)))
_COS_P = 1.0 / np.sqrt(3.0)
_SIN_P = np.sqrt(2.0 / 3.0)
#: Weight a_k = 1/(4 cosθp) of each facet in D (thesis Eq. 3.2): Σ a_k f_k = ẑ.
FACET_WEIGHT = 0.25 / _COS_P
_SQRT_PI = np.sqrt(np.pi)
#: Sequences whose probability falls below this are pruned.
MIN_PROBABILITY = 1e-14
#: Exponents of the height-correlated walk closer than this are moved apart (by 3×).
_EXP_GAP = 1e-7
#: Beckmann lobes are cut where tan²ρ / β² exceeds this (e^-40 of the peak).
_CUT = 40.0


def facet_normals(phi0: float = 0.0) -> np.ndarray:
    """The four facet normals [4, 3]: tilt θp, azimuths ``phi0`` + k·90° (k = 0…3)."""
    phi = phi0 + 0.5 * np.pi * np.arange(4)
    return np.stack([_SIN_P * np.cos(phi), _SIN_P * np.sin(phi), np.full(4, _COS_P)], axis=-1)


def _facet_frames(phi0: float) -> np.ndarray:
    """Rows (u1, u2, f_k) of each facet's frame [4, 3, 3]: ``frames[k] @ w`` is w in facet k's
    frame (u1 in the plane of f_k and the normal, u2 horizontal)."""
    phi = phi0 + 0.5 * np.pi * np.arange(4)
    c, s = np.cos(phi), np.sin(phi)
    u1 = np.stack([_COS_P * c, _COS_P * s, -np.full(4, _SIN_P)], axis=-1)
    u2 = np.stack([-s, c, np.zeros(4)], axis=-1)
    return np.stack([u1, u2, facet_normals(phi0)], axis=1)


def visible_area(c, alpha):
    """T(c) = ∫ lobe(h) ⟨o, h⟩⁺ dω for a Beckmann facet lobe of slope parameter ``alpha`` and
    c = ⟨o, f⟩: ½ c (1 + erf a) + α s e^{−a²}/(2√π), s = √(1 − c²), a = c/(α s).
    Tends to max(0, c) as α → 0 (it is max(0, c) to 1e-17 where |a| > 6); T(c) − T(−c) = c."""
    c = np.asarray(c, float)
    shape = c.shape
    c = c.reshape(-1)
    if pyramid_walk.compiled():
        out = np.empty(c.shape)
        _visible_area_rows(np.ascontiguousarray(c), float(alpha), out)
        return out.reshape(shape)
    out = np.maximum(c, 0.0)
    s = np.sqrt(np.maximum(1.0 - c * c, 0.0))
    near = np.abs(c) < 6.0 * alpha * s
    if np.any(near):
        cn, sn = c[near], s[near]
        a = cn / (alpha * sn)
        out[near] = 0.5 * cn * (1.0 + erf(a)) + alpha * sn * np.exp(-a * a) / (2.0 * _SQRT_PI)
    return out.reshape(shape)


@device
def _visible_area1(c, alpha):
    """:func:`visible_area` of one cosine."""
    out = c if not c < 0.0 else 0.0
    if c * c > (36.0 * alpha * alpha) * (1.0 - c * c) * (1.0 + 1e-9):
        return out        # |c| >= 6 α s for sure (a margin for the rounding): no square root
    s = math.sqrt(max(1.0 - c * c, 0.0))
    if abs(c) < 6.0 * alpha * s:
        a = c / (alpha * s)
        out = 0.5 * c * (1.0 + math.erf(a)) + alpha * s * math.exp(-a * a) / (2.0 * _SQRT_PI)
    return out


@kernel
def _visible_area_rows(c, alpha, out):
    for i in range(c.shape[0]):
        out[i] = _visible_area1(c[i], alpha)


def _lobe(cos_rho, beta):
    """Beckmann lobe about an axis, as a density on the sphere [sr⁻¹]:
    exp(−tan²ρ/β²) / (π β² cos³ρ) for cosρ > 0 (∫ over the sphere = 1)."""
    c = np.asarray(cos_rho, float)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        t2 = (1.0 - c * c) / (c * c * beta * beta)
        v = np.exp(-t2) / (np.pi * beta * beta * c * c * c)
    return np.where(c > 0, v, 0.0)


def _above_horizon(ez, beta):
    """Fraction of :func:`_lobe` about a direction of height ``ez`` that lies above the
    horizon: 1 − ½ erfc(tanε/β) (the horizon is a straight line in the lobe's gnomonic plane,
    where the lobe is an isotropic Gaussian of variance β²/2 per axis)."""
    ez = np.asarray(ez, float)
    with np.errstate(divide="ignore"):
        tan_e = ez / np.sqrt(np.maximum(1.0 - ez * ez, 0.0))
    return 1.0 - 0.5 * erfc(tan_e / beta)


# --------------------------------------------------------------------------------------------
# Components


@C.register
class PyramidDistribution(C.Distribution):
    """Four facets of random upright pyramids, each a narrow Beckmann lobe (see the module)."""

    name = "pyramid"
    summary = ("Random upright pyramids (KOH-textured Si): four facets at θp = arctan √2, each a narrow "
               "Beckmann lobe; D → the thesis' four Dirac peaks as facet_roughness → 0.")
    reference = "DeHaas2024; Beckmann1963"
    params = (
        Param("facet_roughness", "float", "Beckmann slope parameter α of each facet's lobe about its normal "
              "(rms facet tilt ≈ atan(α/√2) per axis; our extension: a Dirac NDF cannot be tabulated).",
              default=0.02, minimum=1e-4, maximum=0.05),
        Param("phi0", "float", "Azimuth of a facet normal (the others at +90°, +180°, +270°); 0: normals along "
              "±x, ±y.", units="rad", default=0.0, minimum=-2 * np.pi, maximum=2 * np.pi, angle=True),
    )

    def _setup(self, facet_roughness, phi0):
        self.alpha = facet_roughness
        self.alpha_x = self.alpha_y = facet_roughness  # quadrature hints of the base class
        self.phi0 = phi0
        self.normals = facet_normals(phi0)
        self.frames = _facet_frames(phi0)

    @property
    def isotropic(self) -> bool:
        return False

    @property
    def width(self) -> float:
        """Width of each facet's lobe (a quadrature hint): α."""
        return self.alpha

    @property
    def axes(self):
        """None: the lobes are not an elliptical lobe about the normal (see :meth:`albedo_rule`)."""
        return None

    def local(self, w):
        """``w[..., 3]`` in each facet's frame: ``[..., 4, 3]``."""
        return np.einsum("kij,...j->...ki", self.frames, np.asarray(w, float))

    def D(self, h):
        h = np.asarray(h, float)
        d = d_beckmann(self.local(h), self.alpha).sum(axis=-1) * FACET_WEIGHT
        return np.where(h[..., 2] > 0, d, 0.0)

    def facet_areas(self, w):
        """a_k T_k(w) [..., 4]: the projected area of facet k seen from ``w`` (per unit
        macrosurface area); Σ_k is the projected microsurface area S(w)."""
        return FACET_WEIGHT * visible_area(np.einsum("...j,kj->...k", np.asarray(w, float), self.normals), self.alpha)

    def projected_area(self, w):
        """S(w) = Σ_k a_k T_k(w) >= max(w_z, 0)."""
        return self.facet_areas(w).sum(axis=-1)

    def lambda_(self, w):
        """Smith Λ of the pyramid NDF: S(w)/cosθ − 1 (∞ at and below the horizon)."""
        w = np.asarray(w, float)
        wz = w[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            lam = self.projected_area(w) / wz - 1.0
        return np.where(wz > 0, np.maximum(lam, 0.0), np.inf)

    def G1(self, w):
        """G1(w) = min(1, cosθ / Σ_k a_k T_k(w)) (0 at and below the horizon)."""
        w = np.asarray(w, float)
        wz = w[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            g = np.minimum(1.0, wz / self.projected_area(w))
        return np.where(wz > 0, g, 0.0)

    def sample(self, u1, u2):
        """Facet k = ⌊4 u1⌋ (each facet holds ¼ of ∫ D cosθh), then a Beckmann normal about f_k
        with density D_k(h) ⟨h, f_k⟩ (see :meth:`pdf`)."""
        u1 = np.asarray(u1, float)
        k = np.minimum((4.0 * u1).astype(int), 3)
        u = 4.0 * u1 - k
        tan_t = self.alpha * np.sqrt(-np.log1p(-u))
        phi = 2.0 * np.pi * np.asarray(u2, float)
        loc = np.stack([tan_t * np.cos(phi), tan_t * np.sin(phi), np.ones_like(tan_t)], axis=-1)
        loc /= np.linalg.norm(loc, axis=-1, keepdims=True)
        return np.einsum("...j,...ji->...i", loc, self.frames[k])

    def pdf(self, h):
        """Density of :meth:`sample` [sr⁻¹]: ¼ Σ_k D_Beckmann(h_k) cosθ_k in each facet's frame
        (tends to D(h) cosθh as facet_roughness → 0)."""
        loc = self.local(h)
        return 0.25 * (d_beckmann(loc, self.alpha) * np.maximum(loc[..., 2], 0.0)).sum(axis=-1)

    def albedo_rule(self, wi):
        """Outgoing directions and weights [sr] for ∫ f cosθo dωo of a microfacet BRDF with this
        D at incidence ``wi[3]``: each facet's lobe on its own rule (a polar rule in the facet's
        slope plane mapped through the half vector, cut into smooth panels at the horizon),
        weighted by D_k(h)/D(h) so every facet counts once."""
        wi = np.asarray(wi, float).reshape(3)
        wi = wi / np.linalg.norm(wi)
        kk = np.flatnonzero(self.facet_areas(wi) > 1e-12)
        if wi[2] <= 1e-12 or kk.size == 0:
            return np.zeros((0, 3)), np.zeros(0)
        owner, wo, w, _ = _facet_rule(self, np.broadcast_to(wi, (kk.size, 3)), kk, _FINE)
        h = wi + wo
        h /= np.linalg.norm(h, axis=1, keepdims=True)
        dk = d_beckmann(self.local(h), self.alpha)
        tot = dk.sum(axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            psi = np.where(tot > 0, dk[np.arange(wo.shape[0]), kk[owner]] / tot, 0.0)
        keep = psi > 0
        return wo[keep], (w * psi)[keep]


@C.register
class PyramidShadowing(C.Shadowing):
    """Height-correlated form 1/(1 + Λ(wi) + Λ(wo)) of the pyramid masking G1."""

    name = "pyramid"
    summary = ("Pyramid masking G1(o) = min(1, cosθo / Σ a_k T_k(o)) (de Haas Eq. 3.6 corrected), combined "
               "height-correlated: G = 1/(1 + Λ(wi) + Λ(wo)).")
    reference = "DeHaas2024; Heitz2014"

    def G(self, wi, wo, h, dist):
        # The pyramid G1 is the Smith G1 of the pyramid NDF (Λ = S/cosθ − 1), so the same form
        # with another distribution's Λ is that distribution's height-correlated Smith G.
        return 1.0 / (1.0 + dist.lambda_(wi) + dist.lambda_(wo))


# --------------------------------------------------------------------------------------------
# Quadrature nodes about a facet's single-bounce lobe and about an exit lobe


_X_EDGES = np.array([-6.4, -3.2, -1.6, 0.0, 1.6, 3.2, 6.4])   # gnomonic offsets / β of exit lobes
_NODES = 6
_N_Y = 20


def _panels(edges):
    x, w = gauss_legendre(_NODES, 0.0, 1.0)
    lo, hi = edges[:-1, None], edges[1:, None]
    return (lo + (hi - lo) * x).ravel(), ((hi - lo) * w).ravel()


def _facet_rays(dist, wi, k, n_psi, t_edges):
    """Panels of the rays of a polar rule about facet k's normal, for pairs ``wi[P, 3]``, ``k[P]``.

    The rule lives in the facet's slope plane: radius t = tanθ'/α up to ``t_edges[-1]``,
    ``n_psi`` azimuths ψ; h ∝ f + α t (cosψ u1 + sinψ u2) and ωo = 2 ⟨ωi, h⟩ h − ωi. Along a ray
    the integrand is cut where ωo crosses the horizon (ωo_z (1 + α²t²) = q0 + q1 t + q2 t²) and
    where ⟨ωi, h⟩ or h_z changes sign (linear in t): those roots are panel ends (with
    ``t_edges``), so the integrand is smooth on every panel. Returns the valid panels as flat
    arrays (pair, ray azimuth index, t_lo, t_hi) and whether a cut crosses each pair's lobe."""
    psi = 2.0 * np.pi * (np.arange(n_psi) + 0.5) / n_psi
    a = dist.alpha
    fr = dist.frames[k]                                                        # [P, 3, 3]
    u1, f = fr[:, 0], fr[:, 2]
    cf = np.einsum("pj,pj->p", wi, f)[:, None]                                # [P, 1]
    c1 = np.einsum("pj,pj->p", wi, u1)[:, None]
    c2 = np.einsum("pj,pj->p", wi, fr[:, 1])[:, None]
    cv = np.cos(psi) * c1 + np.sin(psi) * c2                                   # ⟨ωi, v⟩ [P, R]
    fz = f[:, 2, None]
    vz = np.cos(psi)[None, :] * u1[:, 2, None]                                 # u2 is horizontal
    iz = wi[:, 2, None]
    q0 = 2.0 * cf * fz - iz
    q1 = 2.0 * a * (cf * vz + cv * fz)
    q2 = a * a * (2.0 * cv * vz - iz)
    top = t_edges[-1]
    with np.errstate(divide="ignore", invalid="ignore"):
        disc = np.sqrt(q1 * q1 - 4.0 * q0 * q2)
        roots = [-cf / (a * cv), -fz / (a * vz), (-q1 - disc) / (2.0 * q2), (-q1 + disc) / (2.0 * q2)]
    roots = np.stack([np.broadcast_to(np.where(np.isfinite(r) & (r > 0) & (r < top), r, top), cv.shape)
                      for r in roots], axis=-1)
    cut = np.any(roots[..., [0, 2, 3]] < top, axis=(1, 2))
    edges = np.sort(np.concatenate([np.broadcast_to(t_edges, cv.shape + (t_edges.size,)), roots], axis=-1), axis=-1)
    lo, hi = edges[..., :-1], edges[..., 1:]
    mid = 0.5 * (lo + hi)
    ok = ((hi > lo) & (cf[..., None] + a * mid * cv[..., None] > 0) & (fz[..., None] + a * mid * vz[..., None] > 0)
          & (q0[..., None] + (q1[..., None] + q2[..., None] * mid) * mid > 0))
    p, r, j = np.nonzero(ok)
    return p, r, lo[p, r, j], hi[p, r, j], cut


def _facet_nodes(dist, wi, k, p, r, lo, hi, n_psi, nodes):
    """Nodes of the panels of :func:`_facet_rays`: (owner pair [N], wo [N, 3], solid-angle weight
    of ωo [N] (dωo = 4 ⟨ωi, h⟩ dωh; 0 where ⟨ωi, h⟩ <= 0 or ωo is at the horizon), cos_d [N])."""
    a = dist.alpha
    x, wx = gauss_legendre(nodes, 0.0, 1.0)
    t = (lo[:, None] + (hi - lo)[:, None] * x).ravel()
    wt = ((hi - lo)[:, None] * wx).ravel()
    p = np.repeat(p, nodes)
    psi = 2.0 * np.pi * (np.repeat(r, nodes) + 0.5) / n_psi
    fr = dist.frames[k[p]]
    rr = a * t
    inv = 1.0 / np.sqrt(1.0 + rr * rr)
    h = (fr[:, 2] + rr[:, None] * (np.cos(psi)[:, None] * fr[:, 0] + np.sin(psi)[:, None] * fr[:, 1])) * inv[:, None]
    w_i = wi[p]
    c = np.einsum("nj,nj->n", h, w_i)
    wo = 2.0 * c[:, None] * h - w_i
    dwh = wt * (2.0 * np.pi / n_psi) * a * a * t * inv ** 3
    ok = (c > 0) & (wo[:, 2] > 1e-12)
    return p[ok], wo[ok], (4.0 * c * dwh)[ok], c[ok]


#: Facet-lobe rules: (azimuths of a lobe no cut crosses, azimuths of a cut lobe, Gauss–Legendre
#: nodes per panel, panel edges in t = tanθ'/α). The integrand is smooth on each ray's panels,
#: but where a ray grazes a cut its integral has a square-root point in ψ: cut lobes get more
#: azimuths.
_FINE = (24, 96, 6, np.array([0.0, 0.8, 1.6, 2.6, 4.0, 6.4]))
_COARSE = (12, 32, 4, np.array([0.0, 1.2, 2.4, 4.0, 6.4]))


def _facet_rule(dist, wi, k, level):
    """Flat nodes of facet k's lobe for pairs (``wi[P, 3]``, ``k[P]``) at ``level`` (:data:`_FINE`
    or :data:`_COARSE`): (owner pair [N], wo [N, 3], weight [N], cos_d [N])."""
    n_whole, n_cut, nodes, t_edges = level
    p, r, lo, hi, cut = _facet_rays(dist, wi, k, n_whole, t_edges)
    keep = ~cut[p]
    parts = [_facet_nodes(dist, wi, k, p[keep], r[keep], lo[keep], hi[keep], n_whole, nodes)]
    if cut.any():
        idx = np.flatnonzero(cut)
        p, r, lo, hi, _ = _facet_rays(dist, wi[idx], k[idx], n_cut, t_edges)
        o, wo, w, c = _facet_nodes(dist, wi[idx], k[idx], p, r, lo, hi, n_cut, nodes)
        parts.append((idx[o], wo, w, c))
    return tuple(np.concatenate([q[j] for q in parts]) for j in range(4))


# The compiled facet-lobe rule: _facet_rays, _facet_nodes and SingleBounce.own_facet fused, one
# (incidence, facet) pair at a time, summing the nodes in the order numpy's bincount does.

#: Forms of G in the compiled facet energies: the traced walk's, height-correlated, uncorrelated.
_G_TRACED, _G_CORRELATED, _G_UNCORRELATED = 0, 1, 2


@device(inline=True)
def _projected_area1(wx, wy, wz, normals, alpha):
    """:meth:`PyramidDistribution.projected_area` of one direction."""
    tot = 0.0
    for j in range(4):
        tot += FACET_WEIGHT * _visible_area1(wx * normals[j, 0] + wy * normals[j, 1] + wz * normals[j, 2], alpha)
    return tot


@device
def _root_or(r, top):
    return r if (math.isfinite(r) and r > 0.0 and r < top) else top


@device(inline=True)
def _ray_roots(iz, fr, a, cp, sp, cf, c1, c2, top, roots):
    """The cuts of one ray of :func:`_facet_rays` (azimuth ψ: ``cp``, ``sp`` = cosψ, sinψ) into
    ``roots[4]``; returns (q0, q1, q2, ⟨ωi, v⟩, v_z)."""
    cv = cp * c1 + sp * c2
    fz = fr[2, 2]
    vz = cp * fr[0, 2]
    q0 = 2.0 * cf * fz - iz
    q1 = 2.0 * a * (cf * vz + cv * fz)
    q2 = a * a * (2.0 * cv * vz - iz)
    disc = math.sqrt(q1 * q1 - 4.0 * q0 * q2) if q1 * q1 - 4.0 * q0 * q2 >= 0.0 else math.nan
    roots[0] = _root_or(-cf / (a * cv), top)
    roots[1] = _root_or(-fz / (a * vz), top)
    roots[2] = _root_or((-q1 - disc) / (2.0 * q2), top)
    roots[3] = _root_or((-q1 + disc) / (2.0 * q2), top)
    return q0, q1, q2, cv, vz


@kernel
def _facet_energy_rows(wi, kk, lam_i, r_i, frames, normals, alpha, g_form, n_whole, n_cut, gx, gw, t_edges,
                       rot_c, rot_s, theta, phi, esc_perm, flat, out):
    """``out[P]``: :meth:`SingleBounce.facet_energy` (grey) of the pairs (``wi[P, 3]``, facet
    ``kk[P]``) given Λ(ωi) ``lam_i[P]`` and, for the traced G, r_k(ωi) ``r_i[P]``; the rule of
    :func:`_facet_rule` (``n_whole``/``n_cut`` azimuths, Gauss–Legendre ``gx``, ``gw`` on [0, 1],
    panel edges ``t_edges``), the walk table's escape parts for r_k(ωo)."""
    roots = np.empty(4)
    edges = np.empty(t_edges.shape[0] + 4)
    trig = _psi_trig(n_whole, n_cut)
    cell_i = np.zeros(3, np.int64)
    cell_v = np.empty(8)
    for p in range(wi.shape[0]):
        out[p] = _facet_energy1(wi[p, 0], wi[p, 1], wi[p, 2], kk[p], lam_i[p], r_i[p], frames, normals, alpha, g_form,
                                n_whole, n_cut, trig, gx, gw, t_edges, rot_c, rot_s, theta, phi, esc_perm, flat, roots,
                                edges, cell_i, cell_v)


@device
def _psi_trig(n_whole, n_cut):
    """cosψ and sinψ of the rays of :func:`_facet_energy1` [2, n_whole + n_cut]: the n_whole
    azimuths of a whole lobe, then the n_cut of a cut one."""
    trig = np.empty((2, n_whole + n_cut))
    for r in range(n_whole):
        psi = 2.0 * np.pi * (r + 0.5) / n_whole
        trig[0, r] = math.cos(psi)
        trig[1, r] = math.sin(psi)
    for r in range(n_cut):
        psi = 2.0 * np.pi * (r + 0.5) / n_cut
        trig[0, n_whole + r] = math.cos(psi)
        trig[1, n_whole + r] = math.sin(psi)
    return trig


@device
def _facet_energy1(w0, w1, w2, k, lam_i, r_i, frames, normals, alpha, g_form, n_whole, n_cut, trig, gx, gw, t_edges,
                   rot_c, rot_s, theta, phi, esc_perm, flat, roots, edges, cell_i, cell_v):
    """One energy of :func:`_facet_energy_rows`: incidence (``w0``, ``w1``, ``w2``), facet ``k``
    (``trig``: :func:`_psi_trig`; ``roots[4]``, ``edges[len(t_edges) + 4]``, ``cell_i[3]`` (int),
    ``cell_v[8]``: scratch)."""
    cell_i[0], cell_i[1], cell_i[2] = -1, 0, 0      # no cell yet for r_k(ωo)
    nt, n_phi, n_codes = theta.shape[0], phi.shape[0], esc_perm.shape[1]
    a = alpha
    ne = t_edges.shape[0]
    top = t_edges[ne - 1]
    fr = frames[k]
    cf = w0 * fr[2, 0] + w1 * fr[2, 1] + w2 * fr[2, 2]
    c1 = w0 * fr[0, 0] + w1 * fr[0, 1] + w2 * fr[0, 2]
    c2 = w0 * fr[1, 0] + w1 * fr[1, 1] + w2 * fr[1, 2]
    n_psi = n_whole
    first = 0                              # the rays' column in trig
    for r in range(n_whole):
        _ray_roots(w2, fr, a, trig[0, r], trig[1, r], cf, c1, c2, top, roots)
        if roots[0] < top or roots[2] < top or roots[3] < top:
            n_psi = n_cut
            first = n_whole
            break
    g1i = 1.0 / (1.0 + lam_i)
    acc = 0.0
    for r in range(n_psi):
        cp, sp = trig[0, first + r], trig[1, first + r]
        q0, q1, q2, cv, vz = _ray_roots(w2, fr, a, cp, sp, cf, c1, c2, top, roots)
        # the panel ends: the rule's edges (sorted) and the ray's cuts, in order
        for j in range(ne):
            edges[j] = t_edges[j]
        n_e = ne
        for j in range(4):
            v = roots[j]
            x = n_e
            while x > 0 and edges[x - 1] > v:
                edges[x] = edges[x - 1]
                x -= 1
            edges[x] = v
            n_e += 1
        for j in range(ne + 3):
            lo, hi = edges[j], edges[j + 1]
            mid = 0.5 * (lo + hi)
            if not (hi > lo and cf + a * mid * cv > 0.0 and fr[2, 2] + a * mid * vz > 0.0
                    and q0 + (q1 + q2 * mid) * mid > 0.0):
                continue
            for g in range(gx.shape[0]):
                t = lo + (hi - lo) * gx[g]
                wt = (hi - lo) * gw[g]
                rr = a * t
                inv = 1.0 / math.sqrt(1.0 + rr * rr)
                hx = (fr[2, 0] + rr * (cp * fr[0, 0] + sp * fr[1, 0])) * inv
                hy = (fr[2, 1] + rr * (cp * fr[0, 1] + sp * fr[1, 1])) * inv
                hz = (fr[2, 2] + rr * (cp * fr[0, 2] + sp * fr[1, 2])) * inv
                c = hx * w0 + hy * w1 + hz * w2
                ox = 2.0 * c * hx - w0
                oy = 2.0 * c * hy - w1
                oz = 2.0 * c * hz - w2
                if not (c > 0.0 and oz > 1e-12):
                    continue
                dwh = wt * (2.0 * np.pi / n_psi) * a * a * t * (inv * inv * inv)
                weight = 4.0 * c * dwh
                # own_facet at (ωi, ωo)
                bx, by, bz = w0 + ox, w1 + oy, w2 + oz
                norm = math.sqrt(bx * bx + by * by + bz * bz)
                bx, by, bz = bx / norm, by / norm, bz / norm
                if not bz > 0.0:
                    continue
                lx = fr[0, 0] * bx + fr[0, 1] * by + fr[0, 2] * bz
                ly = fr[1, 0] * bx + fr[1, 1] * by + fr[1, 2] * bz
                lz = fr[2, 0] * bx + fr[2, 1] * by + fr[2, 2] * bz
                dk = _beckmann1(lx, ly, lz, a) * FACET_WEIGHT
                area_o = _projected_area1(ox, oy, oz, normals, a)
                if g_form == _G_TRACED:
                    g1o = min(1.0, oz / area_o) if oz > 0.0 else 0.0
                    # r_k(ωo): ratio_in_cell at cell_of, trying the previous node's cell first and keeping its
                    # nodes' parts (the same arithmetic; written out here, where a call that
                    # takes the table's arrays would count their references at every node)
                    op, p_w = _domain(math.atan2(rot_c * oy - rot_s * ox, rot_c * ox + rot_s * oy))
                    x = min(max(math.acos(min(max(oz, -1.0), 1.0)), theta[0]), theta[nt - 1])
                    i = cell_i[1]
                    if not (theta[i] <= x and (x < theta[i + 1] or i == nt - 2)):
                        i = _axis_index(theta, x)
                    s_w = (x - theta[i]) / (theta[i + 1] - theta[i])
                    y = min(max(p_w, phi[0]), phi[n_phi - 1])
                    j = cell_i[2]
                    if not (phi[j] <= y and (y < phi[j + 1] or j == n_phi - 2)):
                        j = _axis_index(phi, y)
                    t_w = (y - phi[j]) / (phi[j + 1] - phi[j])
                    if op != cell_i[0] or i != cell_i[1] or j != cell_i[2]:
                        b = (i * n_phi + j) * n_codes + esc_perm[op, k]
                        for q in range(2):
                            cell_v[4 * q] = flat[b, q]
                            cell_v[4 * q + 1] = flat[b + n_codes, q]
                            cell_v[4 * q + 2] = flat[b + n_phi * n_codes, q]
                            cell_v[4 * q + 3] = flat[b + n_phi * n_codes + n_codes, q]
                        cell_i[0], cell_i[1], cell_i[2] = op, i, j
                    w00, w01, w10, w11 = corner_weights(s_w, t_w)
                    r_o = bilinear_ratio(w00, w01, w10, w11, cell_v[0], cell_v[1], cell_v[2], cell_v[3], cell_v[4],
                                         cell_v[5], cell_v[6], cell_v[7])
                    gg = min(g1i * g1o * math.sqrt(r_i * r_o), min(g1i, g1o))
                else:
                    lam_o = max(area_o / oz - 1.0, 0.0) if oz > 0.0 else math.inf
                    if g_form == _G_CORRELATED:
                        gg = 1.0 / (1.0 + lam_i + lam_o)
                    else:
                        gg = 1.0 / ((1.0 + lam_i) * (1.0 + lam_o))
                acc += dk * gg / (4.0 * w2) * weight
    return acc


@device
def _beckmann1(lx, ly, lz, a):
    """:func:`d_beckmann` of an isotropic lobe, one local normal."""
    if lz <= 0.0:
        return 0.0
    c2 = lz * lz
    u = lx / a
    v = ly / a
    x = -(u * u + v * v) / c2
    if x < -746.0:              # exp(x) is 0 (below half the least subnormal): no call into exp's slow path
        return 0.0
    return math.exp(x) / (np.pi * a * a * c2 * c2)


def _exit_nodes(e, beta):
    """A product rule in the gnomonic plane of exit ``e``: x (towards the zenith) Gauss–Legendre
    panels from the horizon (x = −tanε, exactly) or −6.4β to 6.4β, y Gauss–Hermite."""
    ez = e[2]
    s = np.sqrt(max(1.0 - ez * ez, 0.0))
    if s < 1e-12:
        u1 = np.array([1.0, 0.0, 0.0])
        x_lo = -np.inf
    else:
        u1 = np.array([-e[0] * ez / s, -e[1] * ez / s, s])     # towards the zenith
        x_lo = -ez / s                                           # the horizon: x = −tanε
    u2 = np.cross(e, u1)
    edges = _X_EDGES * beta
    edges = np.unique(np.clip(edges, max(x_lo, edges[0]), edges[-1]))
    x, wx = _panels(edges)
    yh, wy = np.polynomial.hermite.hermgauss(_N_Y)
    y = beta * yh
    wy = beta * wy * np.exp(yh * yh)
    xx, yy = np.meshgrid(x, y, indexing="ij")
    r2 = 1.0 + xx * xx + yy * yy
    w = (e + xx[..., None] * u1 + yy[..., None] * u2) / np.sqrt(r2)[..., None]
    weights = wx[:, None] * wy[None, :] * r2 ** -1.5                # dω = dx dy / (1 + x² + y²)^(3/2)
    ok = w[..., 2] > 1e-12
    return w[ok], weights[ok]


# --------------------------------------------------------------------------------------------
# The random walk over face sequences


@dataclass
class Exits:
    """Surviving face sequences for one incidence direction: exit ``directions`` [S, 3],
    ``energy`` [S] (grey) or [S, C], ``bounces`` [S], ``faces`` [S, max_bounces] (index k of
    the facet of azimuth φ0 + k·90° at each bounce, −1 after the last) and the local
    ``cosines`` [S, max_bounces] (NaN after the last)."""

    directions: np.ndarray
    energy: np.ndarray
    bounces: np.ndarray
    faces: np.ndarray
    cosines: np.ndarray


@dataclass
class _Walk:
    # exits (flat over all incidence directions): incidence index, direction, probability,
    # bounce count, faces and local cosines
    u: np.ndarray
    dirs: np.ndarray
    prob: np.ndarray
    bounces: np.ndarray
    faces: np.ndarray
    cosines: np.ndarray
    # paths still inside after max_bounces: incidence index, probability, local cosines
    in_u: np.ndarray
    in_prob: np.ndarray
    in_cosines: np.ndarray
    # first hits: probability [U, 4] and what the walk continues with after them [U, 4]
    p_first: np.ndarray
    first_cont: np.ndarray
    # probability that cannot go on after the first bounce [U, 4] (first hits on a facet seen
    # edge-on through its lobe's spread; with :func:`_share`, also what a facet's lobe does not
    # send out but nothing can hit next)
    lost: np.ndarray
    in_faces0: np.ndarray = None


def _record_exits(ex, depth, u, d, esc, faces, cosines) -> None:
    """Append the walk's exits after ``depth`` bounces (those carrying more than
    MIN_PROBABILITY) to the lists of ``ex``."""
    keep = esc > MIN_PROBABILITY
    for key, val in (("u", u), ("dirs", d), ("prob", esc), ("faces", faces), ("cosines", cosines)):
        ex[key].append(val[keep])
    ex["bounces"].append(np.full(int(keep.sum()), depth))


def _advance(pi, kj, depth, d, faces, cosines, cd, F):
    """The walk's states ``pi`` reflected off their next faces ``kj`` (bounce ``depth`` + 1):
    directions, face sequences and incidence cosines."""
    d = _reflect_dir(d[pi], F[kj])
    faces = faces[pi].copy()
    faces[:, depth] = kj
    cosines = cosines[pi].copy()
    cosines[:, depth] = -cd[pi, kj]
    return d, faces, cosines


def _reflect_dir(d, f):
    """Travelling direction d after a mirror reflection on a facet of normal f."""
    return d - 2.0 * np.sum(d * f, axis=-1, keepdims=True) * f


def _walk(dist: PyramidDistribution, wi, max_bounces: int, correlated: bool) -> _Walk:
    """All face sequences of up to ``max_bounces`` bounces for incidence directions ``wi[U, 3]``
    (unit, above the horizon), with their probabilities (mirror facets), the walk's own escape
    after the first bounce included (see :func:`_share` for the model's)."""
    wi = np.asarray(wi, float).reshape(-1, 3)
    nu = wi.shape[0]
    F = dist.normals
    mb = max_bounces
    c0 = wi @ F.T                                                     # ⟨ωi, f_k⟩ [U, 4]
    area = dist.facet_areas(wi)                                       # a_k T_k(ωi)
    p_first = area / area.sum(axis=1, keepdims=True)
    front = (c0 > 0) & (p_first > MIN_PROBABILITY)
    first_cont = np.zeros((nu, 4))
    uu, kk = np.nonzero(front)
    u = uu
    d = _reflect_dir(-wi[uu], F[kk])
    faces = np.full((u.size, mb), -1)
    faces[:, 0] = kk
    cosines = np.full((u.size, mb), np.nan)
    cosines[:, 0] = c0[uu, kk]
    if correlated:
        mu0 = dist.projected_area(wi) / wi[:, 2]                      # 1 + Λ(ωi) >= 1
        exps = (mu0[uu] - 1.0)[:, None]
        coefs = (p_first[uu, kk] * mu0[uu])[:, None]                  # density μ0 U^(μ0−1), mass p
    else:
        mass = p_first[uu, kk]
    ex = {k: [] for k in ("u", "dirs", "prob", "bounces", "faces", "cosines")}
    for depth in range(1, mb + 1):
        # d: travelling direction after bounce `depth`
        cd = d @ F.T
        hit_w = np.where(cd < 0, FACET_WEIGHT * visible_area(-cd, dist.alpha), 0.0)   # a_j T_j(−d), faces d can hit
        tot = hit_w.sum(axis=1)
        none = tot <= 0
        up = d[:, 2] > 0
        with np.errstate(divide="ignore", invalid="ignore"):
            lam_up = np.where(up & ~none, dist.projected_area(d) / d[:, 2] - 1.0, 0.0)
        lam_up = np.maximum(lam_up, 0.0)
        if correlated:
            den = exps + lam_up[:, None] + 1.0
            esc = np.where(up, (coefs / den).sum(axis=1), 0.0)
            cont_up = coefs * (lam_up[:, None] / den)                 # hit again above: c Λ/(a + Λ + 1) U^a
            with np.errstate(divide="ignore", invalid="ignore"):
                mu = np.where(up, 1.0, dist.projected_area(-d) / -d[:, 2])
            gap = exps - mu[:, None] + 1.0
            close = np.any((np.abs(gap) < _EXP_GAP) & (coefs != 0), axis=1) & ~up
            mu = np.where(close, mu + 3 * _EXP_GAP, mu)
            gap = exps - mu[:, None] + 1.0
            with np.errstate(divide="ignore", invalid="ignore"):
                fdown = np.where((coefs != 0) & ~up[:, None], coefs * mu[:, None] / gap, 0.0)
            # going down from U: hit at U' < U, density Σ f_i (U'^(μ−1) − U'^(a_i))
            exps = np.concatenate([exps, (mu - 1.0)[:, None]], axis=1)
            coefs = np.concatenate([np.where(up[:, None], cont_up, -fdown), fdown.sum(axis=1)[:, None]], axis=1)
            mass_cont = (coefs / (exps + 1.0)).sum(axis=1)
        else:
            with np.errstate(divide="ignore", invalid="ignore"):
                g1 = np.where(up, np.where(none, 1.0, d[:, 2] / dist.projected_area(d)), 0.0)
            esc = mass * np.minimum(g1, 1.0)
            mass_cont = mass - esc
        if depth == 1:
            first_cont[u, faces[:, 0]] = np.where(none, 0.0, mass_cont)
        _record_exits(ex, depth, u, d, esc, faces, cosines)
        go = (mass_cont > MIN_PROBABILITY) & ~none
        if depth == mb:
            break
        # next faces
        pj = np.where(go[:, None], hit_w / np.where(none, 1.0, tot)[:, None], 0.0)
        pi, kj = np.nonzero(pj > 0)
        pk = pj[pi, kj]
        u = u[pi]
        d, faces, cosines = _advance(pi, kj, depth, d, faces, cosines, cd, F)
        if correlated:
            exps = exps[pi]
            coefs = coefs[pi] * pk[:, None]
            m = (coefs / (exps + 1.0)).sum(axis=1)
        else:
            mass = mass_cont[pi] * pk
            m = mass
        ok = m > MIN_PROBABILITY
        u, d, faces, cosines = u[ok], d[ok], faces[ok], cosines[ok]
        if correlated:
            exps, coefs = exps[ok], coefs[ok]
        else:
            mass = mass[ok]
    cat = {k: np.concatenate(v) for k, v in ex.items()}
    return _Walk(cat["u"], cat["dirs"], cat["prob"], cat["bounces"], cat["faces"], cat["cosines"],
                 u[go], mass_cont[go], cosines[go], p_first, first_cont, np.where(front, 0.0, p_first),
                 faces[go, 0])


def _facet_frame(dist: PyramidDistribution, w):
    """Directions ``w[U, 3]`` with azimuths measured from facet 0's normal (turned by −φ0)."""
    c, s = np.cos(dist.phi0), np.sin(dist.phi0)
    return np.stack([c * w[:, 0] + s * w[:, 1], c * w[:, 1] - s * w[:, 0], w[:, 2]], axis=-1)


def _traced_walk(dist: PyramidDistribution, wi, max_bounces: int, tab=None) -> _Walk:
    """The walk over the same face sequences as :func:`_walk` with the ray tracer's branching
    probabilities (:mod:`~brdftab.models.pyramid_walk`): the first face k with probability
    a_k T_k(ωi) / Σ_j a_j T_j(ωi); after the sequence s (up to the table's depth) the ray
    escapes or goes on to face j in proportion to the uncorrelated walk's probabilities of
    those branches (escape with G1(d), else face j ∝ a_j T_j(−d), over the branches the
    geometry allows: escape only upwards, face j only when ⟨d, f_j⟩ < 0) times the table's
    interpolated ratios of the tracer's to them (:meth:`.WalkTable.ratios`; 1 where it has no
    rays). After the table's last bounce only the escape is the tracer's; later branches follow
    the uncorrelated rule."""
    tab = pyramid_walk.table() if tab is None else tab
    wi = np.asarray(wi, float).reshape(-1, 3)
    nu = wi.shape[0]
    F = dist.normals
    mb, depth_t = max_bounces, tab.depth
    c0 = wi @ F.T
    area = dist.facet_areas(wi)
    p_first = area / area.sum(axis=1, keepdims=True)
    front = (c0 > 0) & (p_first > MIN_PROBABILITY)
    if pyramid_walk.compiled():
        return _traced_walk_compiled(dist, wi, mb, tab, c0, p_first, front)
    r_esc, r_hit = tab.ratios(_facet_frame(dist, wi))
    r_esc, r_hit = np.nan_to_num(r_esc, nan=1.0), np.nan_to_num(r_hit, nan=1.0)
    first_cont = np.zeros((nu, 4))
    uu, kk = np.nonzero(front)
    u, code, mass = uu, kk, p_first[uu, kk]
    d = _reflect_dir(-wi[uu], F[kk])
    faces = np.full((u.size, mb), -1)
    faces[:, 0] = kk
    cosines = np.full((u.size, mb), np.nan)
    cosines[:, 0] = c0[uu, kk]
    ex = {k: [] for k in ("u", "dirs", "prob", "bounces", "faces", "cosines")}
    for depth in range(1, mb + 1):
        cd = d @ F.T
        can_hit = cd < 0
        hit_w = np.where(can_hit, FACET_WEIGHT * visible_area(-cd, dist.alpha), 0.0)
        tot = hit_w.sum(axis=1)
        none = tot <= 0
        up = d[:, 2] > 0
        # the uncorrelated rule
        with np.errstate(divide="ignore", invalid="ignore"):
            g1 = np.where(up, np.where(none, 1.0, np.minimum(d[:, 2] / dist.projected_area(d), 1.0)), 0.0)
            split = np.where(none[:, None], 0.0, hit_w / np.where(none, 1.0, tot)[:, None])
        p_esc, p_hit = g1, (1.0 - g1)[:, None] * split
        if depth <= depth_t:
            w_esc = p_esc * r_esc[u, pyramid_walk.offset(depth) + code]
            if depth < depth_t:
                w_hit = p_hit * r_hit[u[:, None], pyramid_walk.offset(depth + 1) + 4 * code[:, None] + np.arange(4)]
                t_tot = w_esc + w_hit.sum(axis=1)
                known = t_tot > 0
                with np.errstate(divide="ignore", invalid="ignore"):
                    p_esc = np.where(known, w_esc / t_tot, p_esc)
                    p_hit = np.where(known[:, None], w_hit / t_tot[:, None], p_hit)
            else:   # past the table: only the escape is the tracer's (a ray with no face to hit escapes)
                p_esc = np.where(none, p_esc, np.minimum(w_esc, 1.0))
                p_hit = (1.0 - p_esc)[:, None] * split
        esc = mass * p_esc
        mass_cont = mass - esc
        if depth == 1:
            # the continuing state: its scale is the single-bounce term's to set (_share), so a
            # first hit the tracer sees always escape still goes on (with the hit split) with
            # what a facet's lobe leaves below the horizon
            full = (mass_cont <= 1e-9 * mass) & ~none
            split_sum = p_hit.sum(axis=1)
            p_hit = np.where((full & (split_sum <= 0))[:, None], split, p_hit)
            p_hit = np.where(full[:, None], p_hit / np.where(full, p_hit.sum(axis=1), 1.0)[:, None], p_hit)
            mass_cont = np.where(full, mass, mass_cont)
            first_cont[u, faces[:, 0]] = np.where(none, 0.0, mass_cont)
        _record_exits(ex, depth, u, d, esc, faces, cosines)
        go = (mass_cont > MIN_PROBABILITY) & ~none
        if depth == mb:
            break
        pi, kj = np.nonzero((p_hit > 0) & go[:, None])
        nxt = mass[pi] * p_hit[pi, kj]
        ok = nxt > MIN_PROBABILITY
        pi, kj, nxt = pi[ok], kj[ok], nxt[ok]
        u, code, mass = u[pi], 4 * code[pi] + kj, nxt
        d, faces, cosines = _advance(pi, kj, depth, d, faces, cosines, cd, F)
    cat = {k: np.concatenate(v) for k, v in ex.items()}
    return _Walk(cat["u"], cat["dirs"], cat["prob"], cat["bounces"], cat["faces"], cat["cosines"],
                 u[go], mass_cont[go], cosines[go], p_first, first_cont, np.where(front, 0.0, p_first),
                 faces[go, 0])


def _traced_walk_compiled(dist, wi, mb, tab, c0, p_first, front) -> _Walk:
    """:func:`_traced_walk` by the compiled :func:`_traced_walk_rows` (one incidence direction per
    row, its states breadth first, the table's ratios of the sequences it reaches), in the numpy
    code's order (bounce count, then incidence, then face sequence)."""
    from .._jit import parallel_rows

    nu = wi.shape[0]
    theta_w, phi_w = tab.angles(_facet_frame(dist, wi))
    rows_args = (np.ascontiguousarray(wi), np.ascontiguousarray(c0), np.ascontiguousarray(p_first),
                 np.ascontiguousarray(front), theta_w, phi_w)
    args = (*tab.ratio_arrays(hit=True), dist.normals, float(dist.alpha), mb, tab.depth)
    n_ex = np.zeros(nu, np.int64)
    n_in = np.zeros(nu, np.int64)
    first_cont = np.zeros((nu, 4))
    max_ex, max_in = 2 * (3 ** mb - 1), 4 * 3 ** (mb - 1)      # states of one incidence direction, at most

    def run(lo, hi):
        parts = []
        while lo < hi:
            cap_e, cap_q = max(16 * (hi - lo), max_ex), max(8 * (hi - lo), max_in)
            bufs = (np.empty(cap_e, np.int64), np.empty((cap_e, 3)), np.empty(cap_e), np.empty(cap_e, np.int64),
                    np.empty((cap_e, mb), np.int64), np.empty((cap_e, mb)), np.empty(cap_q), np.empty((cap_q, mb)),
                    np.empty(cap_q, np.int64))
            done, ne, nq = _traced_walk_rows(*(x[lo:hi] for x in rows_args), *args, n_ex[lo:hi], n_in[lo:hi],
                                             first_cont[lo:hi], *bufs)
            parts.append(tuple(x[:ne] for x in bufs[:6]) + tuple(x[:nq] for x in bufs[6:]))
            lo += done
        return parts

    parts = [p for chunk in parallel_rows(run, nu, min_rows=1024) for p in chunk]
    depth, dirs, prob, _, faces, cosines, in_prob, in_cosines, in_faces0 = (
        np.concatenate([p[j] for p in parts]) for j in range(9))
    order = np.argsort(depth, kind="stable")
    u = np.repeat(np.arange(nu), n_ex)
    in_u = np.repeat(np.arange(nu), n_in)
    return _Walk(u[order], dirs[order], prob[order], depth[order], faces[order], cosines[order],
                 in_u, in_prob, in_cosines, p_first, first_cont, np.where(front, 0.0, p_first), in_faces0)


@device
def _branch(dx, dy, dz, mass, code, depth, F, alpha, depth_t, op, cell, w00, w01, w10, w11, phi, perm, esc_parts,
            hit_parts, cd, hit_w, split, p_hit, w_hit):
    """One state of :func:`_traced_walk`: the ray travelling along (``dx``, ``dy``, ``dz``) after
    bounce ``depth`` on the face sequence ``code`` with probability ``mass``, the incidence
    direction's cell of the walk table (:func:`~brdftab.models.pyramid_walk.cell_of`). Returns
    (escaping probability, continuing probability, whether no face can be hit) and fills
    ``p_hit[4]`` (the branch to each face) and ``cd[4]`` (⟨d, f_j⟩); ``hit_w``, ``split``,
    ``w_hit``: scratch [4]."""
    tot = 0.0
    for j in range(4):
        cd[j] = dx * F[j, 0] + dy * F[j, 1] + dz * F[j, 2]
        hit_w[j] = FACET_WEIGHT * _visible_area1(-cd[j], alpha) if cd[j] < 0.0 else 0.0
        tot += hit_w[j]
    none = not tot > 0.0
    if dz > 0.0:
        g1 = 1.0 if none else min(dz / _projected_area1(dx, dy, dz, F, alpha), 1.0)
    else:
        g1 = 0.0
    for j in range(4):
        split[j] = 0.0 if none else hit_w[j] / tot
        p_hit[j] = (1.0 - g1) * split[j]
    p_esc = g1
    if depth <= depth_t:
        w_esc = p_esc * ratio_in_cell(op, cell, w00, w01, w10, w11, (4 ** depth - 4) // 3 + code, phi, perm,
                                      esc_parts)
        if depth < depth_t:
            s_hit = 0.0
            for j in range(4):
                w_hit[j] = p_hit[j] * ratio_in_cell(op, cell, w00, w01, w10, w11,
                                                    (4 ** (depth + 1) - 4) // 3 + 4 * code + j, phi, perm, hit_parts)
                s_hit += w_hit[j]
            t_tot = w_esc + s_hit
            if t_tot > 0.0:
                p_esc = w_esc / t_tot
                for j in range(4):
                    p_hit[j] = w_hit[j] / t_tot
        else:
            p_esc = p_esc if none else min(w_esc, 1.0)
            for j in range(4):
                p_hit[j] = (1.0 - p_esc) * split[j]
    esc = mass * p_esc
    cont = mass - esc
    if depth == 1 and cont <= 1e-9 * mass and not none:
        # the first hit goes on with what its facet's lobe leaves (_share): the hit split
        ssum = 0.0
        for j in range(4):
            ssum += p_hit[j]
        if ssum <= 0.0:
            for j in range(4):
                p_hit[j] = split[j]
        ssum = 0.0
        for j in range(4):
            ssum += p_hit[j]
        for j in range(4):
            p_hit[j] = p_hit[j] / ssum
        cont = mass
    return esc, cont, none


@kernel
def _traced_walk_rows(wi, c0, p_first, front, theta_w, phi_w, theta, phi, perm, esc_parts, hit_parts, F, alpha, mb,
                      depth_t, n_ex, n_in, first_cont, ex_depth, ex_dirs, ex_prob, ex_code, ex_faces, ex_cos, in_prob,
                      in_cos, in_face0):
    """The states of :func:`_traced_walk` per incidence direction ``wi[u]``, breadth first in
    the numpy code's order: the exits and the states still inside written one row after the
    other (``n_ex[u]``, ``n_in[u]`` of them), ``first_cont`` filled. Stops before a row whose
    states might not fit in the buffers; returns (rows done, exits written, inside written)."""
    max_ex = 2 * (3 ** mb - 1)
    max_in = 4 * 3 ** (mb - 1)
    e = 0
    q = 0
    cap = 4
    for _ in range(1, mb):
        cap *= 3
    sd = np.empty((cap, 3))
    sm = np.empty(cap)
    sc = np.empty(cap, np.int64)
    sf = np.empty((cap, mb), np.int64)
    sk = np.empty((cap, mb))
    nd = np.empty((cap, 3))
    nm = np.empty(cap)
    nc = np.empty(cap, np.int64)
    nf = np.empty((cap, mb), np.int64)
    nk = np.empty((cap, mb))
    cd = np.empty(4)
    hit_w = np.empty(4)
    split = np.empty(4)
    p_hit = np.empty(4)
    w_hit = np.empty(4)
    for u in range(wi.shape[0]):
        if e + max_ex > ex_prob.shape[0] or q + max_in > in_prob.shape[0]:
            return u, e, q
        op, cell, w00, w01, w10, w11 = cell_of(theta_w[u], phi_w[u], theta, phi)
        ns = 0
        for k in range(4):
            if front[u, k]:
                dot = -wi[u, 0] * F[k, 0] + -wi[u, 1] * F[k, 1] + -wi[u, 2] * F[k, 2]
                for j in range(3):
                    sd[ns, j] = -wi[u, j] - 2.0 * dot * F[k, j]
                sm[ns] = p_first[u, k]
                sc[ns] = k
                for j in range(mb):
                    sf[ns, j] = -1
                    sk[ns, j] = math.nan
                sf[ns, 0] = k
                sk[ns, 0] = c0[u, k]
                ns += 1
        ne = 0
        nq = 0
        for depth in range(1, mb + 1):
            nn = 0
            for i in range(ns):
                code = sc[i]
                mass = sm[i]
                esc, cont, none = _branch(sd[i, 0], sd[i, 1], sd[i, 2], mass, code, depth, F, alpha, depth_t, op, cell,
                                          w00, w01, w10, w11, phi, perm, esc_parts, hit_parts, cd, hit_w, split, p_hit,
                                          w_hit)
                if depth == 1:
                    first_cont[u, sf[i, 0]] = 0.0 if none else cont
                if esc > MIN_PROBABILITY:
                    ex_depth[e + ne] = depth
                    for j in range(3):
                        ex_dirs[e + ne, j] = sd[i, j]
                    ex_prob[e + ne] = esc
                    ex_code[e + ne] = code
                    for j in range(mb):
                        ex_faces[e + ne, j] = sf[i, j]
                        ex_cos[e + ne, j] = sk[i, j]
                    ne += 1
                go = cont > MIN_PROBABILITY and not none
                if depth == mb:
                    if go:
                        in_prob[q + nq] = cont
                        for j in range(mb):
                            in_cos[q + nq, j] = sk[i, j]
                        in_face0[q + nq] = sf[i, 0]
                        nq += 1
                    continue
                if not go:
                    continue
                for j in range(4):
                    if not p_hit[j] > 0.0:
                        continue
                    nxt = mass * p_hit[j]
                    if not nxt > MIN_PROBABILITY:
                        continue
                    dot = sd[i, 0] * F[j, 0] + sd[i, 1] * F[j, 1] + sd[i, 2] * F[j, 2]
                    for x in range(3):
                        nd[nn, x] = sd[i, x] - 2.0 * dot * F[j, x]
                    nm[nn] = nxt
                    nc[nn] = 4 * code + j
                    for x in range(mb):
                        nf[nn, x] = sf[i, x]
                        nk[nn, x] = sk[i, x]
                    nf[nn, depth] = j
                    nk[nn, depth] = -cd[j]
                    nn += 1
            sd, nd = nd, sd
            sm, nm = nm, sm
            sc, nc = nc, sc
            sf, nf = nf, sf
            sk, nk = nk, sk
            ns = nn
        n_ex[u] = ne
        n_in[u] = nq
        e += ne
        q += nq
    return wi.shape[0], e, q


def _run_walk(dist: PyramidDistribution, wi, max_bounces: int, walk: str) -> _Walk:
    """The walk called ``walk`` ('traced', 'height-correlated' or 'uncorrelated')."""
    if walk == "traced":
        return _traced_walk(dist, wi, max_bounces)
    return _walk(dist, wi, max_bounces, walk == "height-correlated")


def _share(w: _Walk, first_escape, rows=None) -> _Walk:
    """The walk ``w`` continuing from what the single-bounce term leaves: ``first_escape[U', 4]``
    is the energy each facet's lobe in the microfacet term sends out (its integral) for the
    incidence directions ``rows`` (all when None). The first hit on facet k goes on with
    P_k − first_escape[k] (the walk's continuing state rescaled, every later bounce being
    linear in it), single bounces get ``first_escape``, and what cannot go on (no face to hit,
    or a facet seen edge-on) counts as lost — so the single-bounce term and the walk share the
    energy exactly."""
    rows = np.arange(w.p_first.shape[0]) if rows is None else np.asarray(rows)
    e1 = np.zeros_like(w.p_first)
    e1[rows] = first_escape
    todo = np.zeros(w.p_first.shape[0], bool)
    todo[rows] = True
    left = np.maximum(w.p_first - e1, 0.0)
    go = w.first_cont > 0
    scale = np.where(go, left / np.where(go, w.first_cont, 1.0), 0.0)
    scale[~todo] = 1.0
    k_ex = w.faces[:, 0]
    prob = w.prob * np.where(w.bounces >= 2, scale[w.u, k_ex], 1.0)
    one = (w.bounces == 1) & todo[w.u]
    prob[one] = e1[w.u[one], k_ex[one]]
    in_prob = w.in_prob * scale[w.in_u, w.in_faces0]
    lost = np.where(todo[:, None], np.where(go, 0.0, left), w.lost)
    return _Walk(w.u, w.dirs, prob, w.bounces, w.faces, w.cosines, w.in_u, in_prob, w.in_cosines,
                 w.p_first, w.first_cont, lost, w.in_faces0)


def _distinct_rows(w):
    """``np.unique(w, axis=0, return_inverse=True)`` (distinct rows, sorted, and each row's
    index among them), found over the runs of equal rows when there are few (a grid's pairs
    come in runs of one incidence direction; sorting every row is the slow part)."""
    m = w.shape[0]
    same = np.all(w[1:] == w[:-1], axis=1)
    if same.all():
        return w[:1].copy(), np.zeros(m, np.int64)
    heads = np.flatnonzero(np.concatenate([[True], ~same]))
    if 8 * heads.size < m:
        uniq, at = np.unique(w[heads], axis=0, return_inverse=True)
        return uniq, np.repeat(at.ravel(), np.diff(np.append(heads, m)))
    uniq, inv = np.unique(w, axis=0, return_inverse=True)
    return uniq, inv.ravel()


def _fresnel_product(fres, cosines, lam, n):
    """Π_j F(cos_j) over the bounces (NaN cosines: no bounce) → [S, n]."""
    s = cosines.shape[0]
    out = np.ones((s, n))
    for j in range(cosines.shape[1]):
        c = cosines[:, j]
        ok = np.isfinite(c)
        if not ok.any():
            continue
        f = fres.F(c[ok], lam, n)
        if np.ndim(f):
            out[ok] *= f
    return out


# --------------------------------------------------------------------------------------------
# The two terms


class _Term(BRDF):
    isotropic = False
    energy_conserving = True

    def __init__(self, dist, fres):
        self.dist = dist
        self.fres = fres
        self.layout = fres.layout

    @property
    def lobe_width(self) -> float:
        return self.dist.alpha


class SingleBounce(_Term):
    """D·G·F/(4 cosθi cosθo) with the pyramid D, a shadowing component G and Fresnel F."""

    name = "pyramid-single-bounce"
    reciprocal = True

    def __init__(self, dist, shadow, fres, walk: str):
        super().__init__(dist, fres)
        self.shadow = shadow
        # the form of G: 1/(1 + Λi + Λo) (height-correlated), G1 G1 (the uncorrelated walk's) or
        # per facet √(g_k(ωi) g_k(ωo)) (the traced walk's, :meth:`traced_g`)
        self.walk = walk
        self.correlated = walk == "height-correlated"

    def traced_ratio(self, w, k=None):
        """r_k(w) [..., 4] (or, given the facet ``k[N]`` of each of ``w[N, 3]``, [N]): the
        tracer's probability that a ray from w whose first hit is facet k escapes right after
        it, over the uncorrelated walk's G1(o_k) (o_k: w reflected on f_k;
        :meth:`~brdftab.models.pyramid_walk.WalkTable.ratios`; 1 where the table has no rays)."""
        w = np.asarray(w, float)
        flat = w.reshape(-1, 3)
        if k is None and flat.shape[0] > 1 and np.all(flat == flat[0]):          # one incidence direction
            return np.broadcast_to(self.traced_ratio(flat[:1]), w.shape[:-1] + (4,))
        cols = slice(0, 4) if k is None else np.asarray(k)[:, None]
        r, _ = pyramid_walk.table().ratios(_facet_frame(self.dist, w.reshape(-1, 3)), cols, hit=False)
        r = np.nan_to_num(r, nan=1.0)
        return r.reshape(w.shape[:-1] + (4,)) if k is None else r[:, 0]

    def traced_G(self, wi, wo):
        """The traced walk's G [..., 4] on facet k's lobe: G1(ωi) G1(ωo) √(r_k(ωi) r_k(ωo)) (the
        uncorrelated walk's G times the tracer's correction), at most min(G1(ωi), G1(ωo)) (so a
        lobe never sends out more than its facet's first hits, a_k T_k / S(ωi)). Reciprocal, and
        for mirror facets the lobe of facet k sends out what the tracer sees escape from it
        (r_k(ωi) = r_k(o_k) on the true surface, by reciprocity)."""
        g1i, g1o = self.dist.G1(wi)[..., None], self.dist.G1(wo)[..., None]
        return np.minimum(g1i * g1o * np.sqrt(self.traced_ratio(wi) * self.traced_ratio(wo)), np.minimum(g1i, g1o))

    def facet_terms(self, wi, wo):
        """Grey f cosθo of each facet's lobe [..., 4] (no Fresnel), and cos_d = ⟨ωi, h⟩ [...]."""
        h = wi + wo
        norm = np.sqrt(np.einsum("...i,...i->...", h, h))
        h = h / norm[..., None]
        dk = d_beckmann(self.dist.local(h), self.dist.alpha) * FACET_WEIGHT
        dk = np.where((h[..., 2] > 0)[..., None], dk, 0.0)
        if self.walk == "traced":
            g = self.traced_G(wi, wo)
            return dk * g / (4.0 * wi[..., 2])[..., None], 0.5 * norm
        g = self.shadow.G(wi, wo, h, self.dist)
        return dk * (g / (4.0 * wi[..., 2]))[..., None], 0.5 * norm

    def _eval(self, wi, wo, lam, n):
        if self.walk == "traced" and pyramid_walk.compiled():
            base, cos_d = self._traced_base(wi, wo)
        else:
            fk, cos_d = self.facet_terms(wi, wo)
            base = fk.sum(axis=1) / wo[:, 2]
        f = self.fres.F(cos_d, lam, n)
        return base[:, None] * f if np.ndim(f) else np.repeat(base[:, None], n, axis=1)

    def _kernel(self, lam, n):
        return _pair_kernel(self.dist, self.fres, self.walk, 1, lam, n, True, False)

    def _traced_base(self, wi, wo):
        """Σ_k f_k cosθo / cosθo (no Fresnel) and cos_d of :meth:`facet_terms` with the traced
        walk's G, compiled (:func:`_traced_single_rows`; the table's angles from numpy)."""
        from .._jit import parallel_rows

        tab = pyramid_walk.table()
        wi = np.ascontiguousarray(wi, dtype=float)
        wo = np.ascontiguousarray(wo, dtype=float)
        ti, pi = tab.angles(_facet_frame(self.dist, wi))
        to, po = tab.angles(_facet_frame(self.dist, wo))
        theta, phi, perm, flat = tab.ratio_arrays()
        base = np.empty(wi.shape[0])
        cos_d = np.empty(wi.shape[0])

        def run(lo, hi):
            _traced_single_rows(wi[lo:hi], wo[lo:hi], ti[lo:hi], pi[lo:hi], to[lo:hi], po[lo:hi], self.dist.frames,
                                self.dist.normals, float(self.dist.alpha), theta, phi, perm, flat, base[lo:hi],
                                cos_d[lo:hi])

        parallel_rows(run, wi.shape[0])
        return base, cos_d

    def own_facet(self, wi, wo, k, lam_i, r_i=None):
        """Grey f cosθo of facet k's lobe alone (no Fresnel) at pairs ``wi[N, 3]``, ``wo[N, 3]``,
        ``k[N]`` given Λ(ωi) [N] (and, for the traced walk, r_k(ωi) [N]), and cos_d [N]."""
        h = wi + wo
        norm = np.sqrt(np.einsum("ij,ij->i", h, h))
        h = h / norm[:, None]
        loc = np.einsum("nij,nj->ni", self.dist.frames[k], h)
        dk = d_beckmann(loc, self.dist.alpha) * FACET_WEIGHT
        if self.walk == "traced":
            g1i, g1o = 1.0 / (1.0 + lam_i), self.dist.G1(wo)
            g = np.minimum(g1i * g1o * np.sqrt(r_i * self.traced_ratio(wo, k)), np.minimum(g1i, g1o))
        else:
            lam_o = self.dist.lambda_(wo)
            g = 1.0 / (1.0 + lam_i + lam_o) if self.correlated else 1.0 / ((1.0 + lam_i) * (1.0 + lam_o))
        return np.where(h[:, 2] > 0, dk * g / (4.0 * wi[:, 2]), 0.0), 0.5 * norm

    def facet_energy(self, wi, lam=None, n=1, fresnel=False, fine=False, only=None):
        """∫ f_k cosθo dωo of each facet's lobe for ``wi[U, 3]``: [U, 4] (grey, no Fresnel) or
        with ``fresnel`` [U, 4, n]. ``fine``: the albedo rule's nodes (:data:`_FINE`); else the
        coarse rule the walk uses (:data:`_COARSE`). ``only`` [U, 4]: the facets wanted (the
        others are left 0)."""
        wi = np.asarray(wi, float).reshape(-1, 3)
        nu = wi.shape[0]
        seen = self.dist.facet_areas(wi) > MIN_PROBABILITY
        uu, kk = np.nonzero(seen if only is None else seen & only)
        if not fresnel and not fine and pyramid_walk.compiled():
            # (the fine rule stays numpy: bounce_fractions pairs it with its Fresnel-weighted twin,
            # and the two sum to the incident energy to the last digits only by the same arithmetic)
            out = np.zeros((nu, 4))
            out[uu, kk] = self._facet_energy_compiled(wi[uu], kk, self.dist.lambda_(wi)[uu], _COARSE)
            return out
        owner, wo, w, _ = _facet_rule(self.dist, wi[uu], kk, _FINE if fine else _COARSE)
        lam_i = self.dist.lambda_(wi)
        r_i = self.traced_ratio(wi[uu], kk)[owner] if self.walk == "traced" else None
        val, cos_d = self.own_facet(wi[uu[owner]], wo, kk[owner], lam_i[uu[owner]], r_i)
        val = val * w
        if not fresnel:
            out = np.zeros((nu, 4))
            out[uu, kk] = np.bincount(owner, val, minlength=uu.size)
            return out
        fr = self.fres.F(cos_d, lam, n)
        fr = np.broadcast_to(fr, (val.size, n)) if np.ndim(fr) else np.ones((val.size, n))
        out = np.zeros((nu, 4, n))
        for ch in range(n):
            out[uu, kk, ch] = np.bincount(owner, val * fr[:, ch], minlength=uu.size)
        return out

    def _facet_energy_compiled(self, wi, k, lam_i, level):
        """The grey energies of :meth:`facet_energy` of the pairs (``wi[P, 3]``, facet ``k[P]``)
        given Λ(ωi) ``lam_i[P]``, by the compiled rule (:func:`_facet_energy_rows`)."""
        from .._jit import parallel_rows

        n_whole, n_cut, nodes, t_edges = level
        gx, gw = gauss_legendre(nodes, 0.0, 1.0)
        wi = np.ascontiguousarray(wi, dtype=float)
        k = np.ascontiguousarray(k, dtype=np.int64)
        lam_i = np.ascontiguousarray(lam_i, dtype=float)
        if self.walk == "traced":
            r_i = np.ascontiguousarray(self.traced_ratio(wi, k), dtype=float)
            g_form = _G_TRACED
        else:
            r_i = np.ones(wi.shape[0])
            g_form = _G_CORRELATED if self.correlated else _G_UNCORRELATED
        theta, phi, esc_perm, flat = pyramid_walk.table().ratio_arrays()
        out = np.empty(wi.shape[0])
        dist = self.dist
        args = (dist.frames, dist.normals, float(dist.alpha), g_form, n_whole, n_cut, np.ascontiguousarray(gx),
                np.ascontiguousarray(gw), np.ascontiguousarray(t_edges, dtype=float), float(np.cos(dist.phi0)),
                float(np.sin(dist.phi0)), theta, phi, esc_perm, flat)

        def run(lo, hi):
            _facet_energy_rows(wi[lo:hi], k[lo:hi], lam_i[lo:hi], r_i[lo:hi], *args, out[lo:hi])

        # a pair's rule has hundreds of nodes: worth a thread from a few hundred pairs on
        parallel_rows(run, wi.shape[0], min_rows=256)
        return out

    def albedo_rule(self, wi):
        """Outgoing directions and weights [sr] resolving the four facet lobes for ``wi[3]``."""
        return _albedo_rule(self, np.asarray(wi, float), single=True, multi=False)


class MultiBounce(_Term):
    """Σ over sequences of >= 2 bounces of E · L(ωo; e) / (N(e) cosθo) (see the module)."""

    name = "pyramid-multi-bounce"
    reciprocal = False

    def __init__(self, single, max_bounces, walk):
        super().__init__(single.dist, single.fres)
        self.single = single
        self.max_bounces = max_bounces
        self.walk_name = walk
        self.beta = 2.0 * self.dist.alpha
        self.cos_cut = 1.0 / np.sqrt(1.0 + _CUT * self.beta ** 2)

    def walk(self, wi) -> _Walk:
        """The walk from incidence directions ``wi[U, 3]``, sharing the energy with the
        single-bounce term (:func:`_share`)."""
        wi = np.asarray(wi, float).reshape(-1, 3)
        return _share(_run_walk(self.dist, wi, self.max_bounces, self.walk_name), self.single.facet_energy(wi))

    def _kernel(self, lam, n):
        return _pair_kernel(self.dist, self.fres, self.walk_name, self.max_bounces, lam, n, False, True)

    def lobes(self, wo, e, energy_grey, norm):
        """Grey f cosθo of each exit lobe at directions ``wo[M, 3]`` → [M, S]."""
        return energy_grey[None, :] * _lobe(wo @ e.T, self.beta) / norm[None, :]

    def _eval(self, wi, wo, lam, n):
        uniq, inv = _distinct_rows(wi)
        w = _run_walk(self.dist, uniq, self.max_bounces, self.walk_name)
        sel = np.flatnonzero(w.bounces >= 2)
        out = np.zeros((wi.shape[0], n))
        if sel.size == 0:
            return out
        sel = sel[np.argsort(w.u[sel], kind="stable")]
        u, e = w.u[sel], w.dirs[sel]
        counts = np.bincount(u, minlength=uniq.shape[0])
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        if pyramid_walk.compiled():
            return self._lobes_compiled(wi, wo, uniq, inv, w, sel, starts, counts, lam, n)
        per_pair = counts[inv]
        # (pair, exit) entries near an exit, in bounded batches
        limit = 1 << 21
        cum = np.cumsum(per_pair)
        lo = 0
        found = []
        while lo < wi.shape[0]:
            hi = int(np.searchsorted(cum, (cum[lo - 1] if lo else 0) + limit, side="right"))
            hi = max(hi, lo + 1)
            rows = np.arange(lo, hi)
            rep = per_pair[rows]
            pair = np.repeat(rows, rep)
            offs = np.arange(pair.size) - np.repeat(np.cumsum(rep) - rep, rep)
            ex = starts[inv[pair]] + offs
            c = np.einsum("ij,ij->i", wo[pair], e[ex])
            near = c > self.cos_cut
            found.append((pair[near], ex[near], c[near]))
            lo = hi
        pair, ex, c = (np.concatenate([f[j] for f in found]) for j in range(3))
        if pair.size == 0:
            return out
        # the single-bounce energies only where a lobe is seen
        # (the energies of the facets that begin a seen exit's sequence: the others scale nothing here)
        rows, at = np.unique(u[ex], return_inverse=True)
        only = np.zeros((rows.size, 4), bool)
        only[at.ravel(), w.faces[sel[ex], 0]] = True
        w = _share(w, self.single.facet_energy(uniq[rows], only=only), rows)
        energy = w.prob[sel, None] * _fresnel_product(self.fres, w.cosines[sel], lam, n)
        val = _lobe(c, self.beta) / (_above_horizon(e[ex, 2], self.beta) * wo[pair, 2])
        for ch in range(n):
            out[:, ch] = np.bincount(pair, val * energy[ex, ch], minlength=wi.shape[0])
        return out

    def _lobes_compiled(self, wi, wo, uniq, inv, w, sel, starts, counts, lam, n):
        """The rest of :meth:`_eval` compiled: the exits each pair sees (:func:`_exits_seen`), the
        facet energies of their rows, and the lobes' sum (:func:`_exit_lobe_rows`)."""
        from .._jit import parallel_rows

        m = wi.shape[0]
        e = np.ascontiguousarray(w.dirs[sel])
        wo = np.ascontiguousarray(wo)
        inv = np.ascontiguousarray(inv, dtype=np.int64)
        starts = np.ascontiguousarray(starts, dtype=np.int64)
        counts = np.ascontiguousarray(counts, dtype=np.int64)
        seen = np.zeros(e.shape[0], np.uint8)
        cos_cut = float(self.cos_cut)

        def mark(lo, hi):
            _exits_seen(wo[lo:hi], inv[lo:hi], starts, counts, e, cos_cut, seen)

        parallel_rows(mark, m)      # (threads mark the same exits with the same value)
        out = np.zeros((m, n))
        ex = np.flatnonzero(seen)
        if ex.size == 0:
            return out
        u = w.u[sel]
        rows, at = np.unique(u[ex], return_inverse=True)
        only = np.zeros((rows.size, 4), bool)
        only[at.ravel(), w.faces[sel[ex], 0]] = True
        w = _share(w, self.single.facet_energy(uniq[rows], only=only), rows)
        energy = np.zeros((e.shape[0], n))
        energy[ex] = w.prob[sel[ex], None] * _fresnel_product(self.fres, w.cosines[sel[ex]], lam, n)
        norm = _above_horizon(e[:, 2], self.beta)

        def lobes(lo, hi):
            _exit_lobe_rows(wo[lo:hi], inv[lo:hi], starts, counts, e, norm, energy, cos_cut, float(self.beta),
                            out[lo:hi])

        parallel_rows(lobes, m)
        return out

    def albedo_rule(self, wi):
        """Outgoing directions and weights [sr] resolving every exit lobe for ``wi[3]``."""
        return _albedo_rule(self, np.asarray(wi, float), single=False, multi=True)


@kernel
def _traced_single_rows(wi, wo, ti, pi, to, po, frames, normals, alpha, theta, phi, perm, flat, base, cos_d):
    """:meth:`SingleBounce.facet_terms` with the traced walk's G (:meth:`SingleBounce.traced_G`),
    summed over the facets and divided by cosθo (``base``), and cos_d, per pair; ``ti``, ``pi``,
    ``to``, ``po``: the table's angles of ωi and ωo (numpy's)."""
    ri = np.empty(4)
    ro = np.empty(4)
    dk = np.empty(4)
    for m in range(wi.shape[0]):
        g1i = _g1(wi[m, 0], wi[m, 1], wi[m, 2], normals, alpha)
        g1o = _g1(wo[m, 0], wo[m, 1], wo[m, 2], normals, alpha)
        _escape_ratios(ti[m], pi[m], theta, phi, perm, flat, ri)
        _escape_ratios(to[m], po[m], theta, phi, perm, flat, ro)
        cos_d[m] = _facet_lobes(wi[m, 0], wi[m, 1], wi[m, 2], wo[m, 0], wo[m, 1], wo[m, 2], frames, alpha, dk)
        base[m] = _traced_single_sum(dk, wi[m, 2], wo[m, 2], g1i, g1o, ri, ro)


@device(inline=True)
def _g1(wx, wy, wz, normals, alpha):
    """:meth:`PyramidDistribution.G1` of one direction (0 at and below the horizon)."""
    return min(1.0, wz / _projected_area1(wx, wy, wz, normals, alpha)) if wz > 0.0 else 0.0


@device(inline=True)
def _escape_ratios(theta_w, phi_w, theta, phi, perm, flat, r):
    """r_k of :meth:`SingleBounce.traced_ratio` for the four facets into ``r[4]``, at the table
    angles ``theta_w``, ``phi_w`` of a direction (``flat``: the escape parts)."""
    op, cell, w00, w01, w10, w11 = cell_of(theta_w, phi_w, theta, phi)
    for k in range(4):
        r[k] = ratio_in_cell(op, cell, w00, w01, w10, w11, k, phi, perm, flat)


@device(inline=True)
def _facet_lobes(wix, wiy, wiz, wox, woy, woz, frames, alpha, dk):
    """D_k(h) a_k of the four facets at the pair's half vector into ``dk[4]`` (0 where h_z <= 0);
    returns cos_d."""
    hx, hy, hz = wix + wox, wiy + woy, wiz + woz
    norm = math.sqrt(hx * hx + hy * hy + hz * hz)
    hx, hy, hz = hx / norm, hy / norm, hz / norm
    for k in range(4):
        fr = frames[k]
        lx = fr[0, 0] * hx + fr[0, 1] * hy + fr[0, 2] * hz
        ly = fr[1, 0] * hx + fr[1, 1] * hy + fr[1, 2] * hz
        lz = fr[2, 0] * hx + fr[2, 1] * hy + fr[2, 2] * hz
        dk[k] = _beckmann1(lx, ly, lz, alpha) * FACET_WEIGHT if hz > 0.0 else 0.0
    return 0.5 * norm


@device(inline=True)
def _traced_single_sum(dk, wiz, woz, g1i, g1o, ri, ro):
    """Σ_k f_k cosθo / cosθo of :func:`_traced_single_rows` given :func:`_facet_lobes`' D_k a_k and
    G1 and r_k of both directions."""
    tot = 0.0
    for k in range(4):
        g = min(g1i * g1o * math.sqrt(ri[k] * ro[k]), min(g1i, g1o))
        tot += dk[k] * g / (4.0 * wiz)
    return tot / woz


@kernel
def _exits_seen(wo, inv, starts, counts, e, cos_cut, seen):
    """Mark ``seen[x]`` the exits x (``e[X, 3]``, those of incidence u at ``starts[u]``, ``counts[u]``)
    whose lobe reaches a pair's ``wo`` (cosine above ``cos_cut``; pair i has incidence ``inv[i]``)."""
    for i in range(wo.shape[0]):
        a = starts[inv[i]]
        for x in range(a, a + counts[inv[i]]):
            if wo[i, 0] * e[x, 0] + wo[i, 1] * e[x, 1] + wo[i, 2] * e[x, 2] > cos_cut:
                seen[x] = 1


@kernel
def _exit_lobe_rows(wo, inv, starts, counts, e, norm, energy, cos_cut, beta, out):
    """``out[i]`` = Σ over the exits x of pair i's incidence whose lobe reaches ``wo[i]`` of
    L(⟨ωo, e_x⟩) / (N(e_x) cosθo) · energy[x] (:meth:`MultiBounce._eval`, in its order)."""
    nc = out.shape[1]
    for i in range(wo.shape[0]):
        a = starts[inv[i]]
        for x in range(a, a + counts[inv[i]]):
            c = wo[i, 0] * e[x, 0] + wo[i, 1] * e[x, 1] + wo[i, 2] * e[x, 2]
            if not c > cos_cut:
                continue
            t2 = (1.0 - c * c) / (c * c * beta * beta)
            lobe = math.exp(-t2) / (np.pi * beta * beta * c * c * c) if c > 0.0 else 0.0
            val = lobe / (norm[x] * wo[i, 2])
            for ch in range(nc):
                out[i, ch] += val * energy[x, ch]


# --------------------------------------------------------------------------------------------
# The compiled evaluation: every term of one pair in one loop (BRDF.kernel)
#
# Per incidence direction (reused while consecutive pairs share it, as a grid's do): its cell of
# the walk table, G1, Λ and r_k, and the face sequences its walk can take, by geometry alone
# (a face j is a branch only where ⟨d, f_j⟩ < 0). Per pair: the single-bounce term, then the
# sequences of two or more bounces whose exit lobe reaches ωo; the walk's probabilities are
# computed only along the sequences a pair sees (each state once per incidence, with
# :func:`_branch`, the compiled walk's arithmetic), and the facet energies of their first
# facets (:func:`_facet_energy1`, the coarse rule) only when one is needed (:func:`_share`).

#: Stands for the Fresnel term's scalar form (``jit_F``) in :func:`_pair_rows`, which is compiled
#: in a generated module that binds it (:func:`_pair_run`).
_F = None


@device
def _same(a, b):
    """Whether two finite floats are the same number, sign of zero included."""
    return a == b and math.copysign(1.0, a) == math.copysign(1.0, b)


@device(inline=True)
def _incidence_cell(wix, wiy, wiz, rot_c, rot_s, theta, phi, perm, esc_parts, ri):
    """The walk-table cell of an incidence direction (:func:`~brdftab.models.pyramid_walk.cell_of`,
    its azimuth from facet 0's normal), and r_k of :meth:`SingleBounce.traced_ratio` into ``ri[4]``."""
    op, cell, w00, w01, w10, w11 = cell_of(math.acos(min(max(wiz, -1.0), 1.0)),
                                           math.atan2(rot_c * wiy - rot_s * wix, rot_c * wix + rot_s * wiy), theta, phi)
    for k in range(4):
        ri[k] = ratio_in_cell(op, cell, w00, w01, w10, w11, k, phi, perm, esc_parts)
    return op, cell, w00, w01, w10, w11


def _pair_rows(wi, wo, state, out, add, frames, normals, alpha, beta, cos_cut, mb, depth_t, theta, phi, perm,
               esc_parts, hit_parts, rot_c, rot_s, n_whole, n_cut, gx, gw, t_edges, pf, single_on, multi_on):
    """f of the pairs ``wi``, ``wo[M, 3]`` whose ``state`` is 1 into ``out[M, C]`` (or added, with
    ``add``): the traced walk's single-bounce term (``single_on``) plus its exit lobes
    (``multi_on``), as :meth:`PyramidMicrofacet._eval` computes them."""
    nc = out.shape[1]
    cap = 0                                 # states of one incidence: 4 first hits, then <= 3 faces each
    level = 4
    for _ in range(mb):
        cap += level
        level *= 3
    sd = np.empty((cap, 3))                 # travelling direction after the state's bounce
    parent = np.empty(cap, np.int64)
    root = np.empty(cap, np.int64)          # the state of the sequence's first hit
    face = np.empty(cap, np.int64)
    sdepth = np.empty(cap, np.int64)
    scode = np.empty(cap, np.int64)
    scos = np.empty(cap)                    # local cosine of the state's bounce
    status = np.zeros(cap, np.int64)        # 0: not evaluated, 1: on the walk, 2: not on it
    smass = np.empty(cap)
    sesc = np.empty(cap)
    sgo = np.zeros(cap, np.bool_)
    sphit = np.empty((cap, 4))
    snorm = np.empty(cap)
    cand = np.empty(cap, np.int64)          # exits of two or more bounces, in the walk's order
    chain = np.empty(mb, np.int64)
    c0 = np.empty(4)
    area = np.empty(4)
    p_first = np.empty(4)
    first_cont = np.zeros(4)
    energy1 = np.zeros(4)
    have_e = np.zeros(4, np.bool_)
    ri = np.empty(4)
    ro = np.empty(4)
    dk = np.empty(4)
    cd = np.empty(4)
    hit_w = np.empty(4)
    split = np.empty(4)
    p_hit = np.empty(4)
    w_hit = np.empty(4)
    roots = np.empty(4)
    edges = np.empty(t_edges.shape[0] + 4)
    trig = _psi_trig(n_whole, n_cut)
    cell_i = np.zeros(3, np.int64)
    cell_v = np.empty(8)
    single = np.zeros(nc)
    multi = np.zeros(nc)
    have = False
    px, py, pz = 0.0, 0.0, 0.0
    op, cell, w00, w01, w10, w11 = 0, 0, 0.0, 0.0, 0.0, 0.0
    g1i, lam_i = 0.0, 0.0
    n_cand = 0
    have_cell = False
    for i in range(wi.shape[0]):
        if state[i] != 1:
            continue
        wix, wiy, wiz = wi[i, 0], wi[i, 1], wi[i, 2]
        wox, woy, woz = wo[i, 0], wo[i, 1], wo[i, 2]
        if not (have and _same(wix, px) and _same(wiy, py) and _same(wiz, pz)):
            have = True
            px, py, pz = wix, wiy, wiz
            have_cell = False       # the incidence's table cell and r_k: on first need
            s_tot = _projected_area1(wix, wiy, wiz, normals, alpha)
            g1i = min(1.0, wiz / s_tot) if wiz > 0.0 else 0.0
            lam_i = max(s_tot / wiz - 1.0, 0.0)
            n_cand = 0
            if multi_on:
                s_tot = 0.0
                for k in range(4):
                    c0[k] = wix * normals[k, 0] + wiy * normals[k, 1] + wiz * normals[k, 2]
                    area[k] = FACET_WEIGHT * _visible_area1(c0[k], alpha)
                    s_tot += area[k]
                n = 0
                for k in range(4):
                    p_first[k] = area[k] / s_tot
                    first_cont[k] = 0.0
                    have_e[k] = False
                    if c0[k] > 0.0 and p_first[k] > MIN_PROBABILITY:
                        dot = -wix * normals[k, 0] + -wiy * normals[k, 1] + -wiz * normals[k, 2]
                        sd[n, 0] = -wix - 2.0 * dot * normals[k, 0]
                        sd[n, 1] = -wiy - 2.0 * dot * normals[k, 1]
                        sd[n, 2] = -wiz - 2.0 * dot * normals[k, 2]
                        parent[n] = -1
                        root[n] = n
                        face[n] = k
                        sdepth[n] = 1
                        scode[n] = k
                        scos[n] = c0[k]
                        n += 1
                a = 0
                for depth in range(1, mb):
                    b = n
                    for s in range(a, b):
                        for j in range(4):
                            dot = sd[s, 0] * normals[j, 0] + sd[s, 1] * normals[j, 1] + sd[s, 2] * normals[j, 2]
                            if dot < 0.0:
                                for x in range(3):
                                    sd[n, x] = sd[s, x] - 2.0 * dot * normals[j, x]
                                parent[n] = s
                                root[n] = root[s]
                                face[n] = j
                                sdepth[n] = depth + 1
                                scode[n] = 4 * scode[s] + j
                                scos[n] = -dot
                                n += 1
                    a = b
                for s in range(n):
                    status[s] = 0
                    snorm[s] = math.nan
                    if sdepth[s] >= 2 and sd[s, 2] > 0.0:
                        cand[n_cand] = s
                        n_cand += 1
        if single_on:
            cos_d = _facet_lobes(wix, wiy, wiz, wox, woy, woz, frames, alpha, dk)
            base = 0.0
            if dk[0] != 0.0 or dk[1] != 0.0 or dk[2] != 0.0 or dk[3] != 0.0:
                # (else every lobe is 0 here, whatever G: the sum is 0 without ωo's G1 and r_k)
                if not have_cell:
                    have_cell = True
                    op, cell, w00, w01, w10, w11 = _incidence_cell(wix, wiy, wiz, rot_c, rot_s, theta, phi, perm,
                                                                   esc_parts, ri)
                _escape_ratios(math.acos(min(max(woz, -1.0), 1.0)),
                               math.atan2(rot_c * woy - rot_s * wox, rot_c * wox + rot_s * woy), theta, phi, perm,
                               esc_parts, ro)
                g1o = _g1(wox, woy, woz, normals, alpha)
                base = _traced_single_sum(dk, wiz, woz, g1i, g1o, ri, ro)
            for c in range(nc):
                single[c] = base * _F(wix, wiy, wiz, wox, woy, woz, cos_d, pf, c)
        for c in range(nc):
            multi[c] = 0.0
        for q in range(n_cand):
            x = cand[q]
            cc = wox * sd[x, 0] + woy * sd[x, 1] + woz * sd[x, 2]
            if not cc > cos_cut:
                continue
            if not have_cell:
                have_cell = True
                op, cell, w00, w01, w10, w11 = _incidence_cell(wix, wiy, wiz, rot_c, rot_s, theta, phi, perm,
                                                               esc_parts, ri)
            # the walk's states down to x, the unevaluated ones from the top
            n = 0
            y = x
            while y >= 0:
                chain[n] = y
                n += 1
                y = parent[y]
            for t in range(n - 1, -1, -1):
                y = chain[t]
                if status[y] != 0:
                    continue
                p = parent[y]
                if p < 0:
                    mass = p_first[face[y]]
                    on = True
                else:
                    mass = smass[p] * sphit[p, face[y]]
                    on = status[p] == 1 and sgo[p] and sphit[p, face[y]] > 0.0 and mass > MIN_PROBABILITY
                if not on:
                    status[y] = 2
                    continue
                esc, cont, none = _branch(sd[y, 0], sd[y, 1], sd[y, 2], mass, scode[y], sdepth[y], normals, alpha,
                                          depth_t, op, cell, w00, w01, w10, w11, phi, perm, esc_parts, hit_parts, cd,
                                          hit_w, split, p_hit, w_hit)
                status[y] = 1
                smass[y] = mass
                sesc[y] = esc
                sgo[y] = cont > MIN_PROBABILITY and not none
                for j in range(4):
                    sphit[y, j] = p_hit[j]
                if p < 0:
                    first_cont[face[y]] = 0.0 if none else cont
            if status[x] != 1 or not sesc[x] > MIN_PROBABILITY:
                continue
            # the walk goes on from the first hit with what its facet's lobe leaves (_share)
            k0 = face[root[x]]
            if not have_e[k0]:
                have_e[k0] = True
                energy1[k0] = 0.0
                if area[k0] > MIN_PROBABILITY:
                    energy1[k0] = _facet_energy1(wix, wiy, wiz, k0, lam_i, ri[k0], frames, normals, alpha, _G_TRACED,
                                                 n_whole, n_cut, trig, gx, gw, t_edges, rot_c, rot_s, theta, phi, perm,
                                                 esc_parts, roots, edges, cell_i, cell_v)
            left = max(p_first[k0] - energy1[k0], 0.0)
            scale = left / first_cont[k0] if first_cont[k0] > 0.0 else 0.0
            prob = sesc[x] * scale
            if math.isnan(snorm[x]):
                ez = sd[x, 2]
                snorm[x] = 1.0 - 0.5 * math.erfc(ez / math.sqrt(max(1.0 - ez * ez, 0.0)) / beta)
            t2 = (1.0 - cc * cc) / (cc * cc * beta * beta)
            lobe = math.exp(-t2) / (np.pi * beta * beta * cc * cc * cc) if cc > 0.0 else 0.0
            val = lobe / (snorm[x] * woz)
            for c in range(nc):
                fp = 1.0
                for t in range(n - 1, -1, -1):
                    fp = fp * _F(wix, wiy, wiz, wox, woy, woz, scos[chain[t]], pf, c)
                multi[c] += val * (prob * fp)
        for c in range(nc):
            if single_on and multi_on:
                v = single[c] + multi[c]
            elif single_on:
                v = single[c]
            else:
                v = multi[c]
            out[i, c] = out[i, c] + v if add else v


_PAIR_MODULE = '''\
# Generated by brdftab.models.pyramid (do not edit): the pyramid model with the {fres!r} Fresnel term;
# sources {digest}; constants {constants}
import math

import numba
import numpy as np

from brdftab._jit import OPTIONS
from brdftab.models import pyramid as _pyramid
from brdftab.models.components import get
from brdftab.models.fused import as_device

_F = as_device(get("fresnel", {fres!r}).jit_F)
{bindings}


@numba.njit(**OPTIONS)
{body}'''

_PAIR_RUNS: dict = {}


def _pair_run(fres):
    """:func:`_pair_rows` compiled with the Fresnel term ``fres``'s scalar form, from a generated
    module named by a hash of its text (the sources of every function it inlines and the
    constants they read: numba's cache alone sees only the generated file)."""
    key = type(fres)
    if key not in _PAIR_RUNS:
        import dis
        import inspect

        from .._jit import _Lazy, generated_module, source_hash

        g = globals()
        bindings = []
        names = (ins.argval for ins in dis.get_instructions(_pair_rows) if ins.opname == "LOAD_GLOBAL")
        for name in dict.fromkeys(names):
            value = g.get(name)
            if name in ("math", "np", "_F") or name not in g:
                continue
            if isinstance(value, _Lazy) or hasattr(value, "py_func"):
                bindings.append(f"{name} = as_device(_pyramid.{name})")
            else:   # a constant: its value is part of the text
                bindings.append(f"{name} = {float(value) if isinstance(value, float) else int(value)!r}")
        constants = repr(tuple(float(v) for v in (FACET_WEIGHT, MIN_PROBABILITY, _SQRT_PI, _G_TRACED, _G_CORRELATED)))
        source = _PAIR_MODULE.format(fres=fres.name, digest=source_hash(_pair_rows, fres.jit_F), constants=constants,
                                     bindings="\n".join(bindings), body=inspect.getsource(_pair_rows))
        _PAIR_RUNS[key] = generated_module("pyramid", source)._pair_rows
    return _PAIR_RUNS[key]


def _pair_kernel(dist, fres, walk, max_bounces, lam, n, single, multi):
    """The compiled evaluation (:meth:`~brdftab.brdf.BRDF.kernel`) of the pyramid model's
    single-bounce term (``single``) and/or its exit lobes (``multi``), or None: for the Smith
    walks (numpy), and for a Fresnel term that depends on the whole pair or has no scalar form."""
    if walk != "traced" or fres.depends == "pair" or fres.jit_F is None:
        return None
    run = _pair_run(fres)
    theta, phi, perm, esc_parts, hit_parts = pyramid_walk.table().ratio_arrays(hit=True)
    n_whole, n_cut, nodes, t_edges = _COARSE
    gx, gw = gauss_legendre(nodes, 0.0, 1.0)
    beta = 2.0 * dist.alpha                                   # as MultiBounce's
    cos_cut = 1.0 / np.sqrt(1.0 + _CUT * beta ** 2)
    args = (np.ascontiguousarray(dist.frames), np.ascontiguousarray(dist.normals), float(dist.alpha), float(beta),
            float(cos_cut), int(max_bounces if multi else 1), int(pyramid_walk.table().depth), theta, phi, perm,
            esc_parts, hit_parts, float(np.cos(dist.phi0)), float(np.sin(dist.phi0)), int(n_whole), int(n_cut),
            np.ascontiguousarray(gx), np.ascontiguousarray(gw), np.ascontiguousarray(t_edges, dtype=float),
            np.ascontiguousarray(fres.jit_params(lam, n)), bool(single), bool(multi))

    def evaluate(wi, wo, state, out, add):
        run(wi, wo, state, out, add, *args)
    return evaluate


# --------------------------------------------------------------------------------------------
# Quadrature: a rule per lobe, partitioned by the lobes' own values


def _albedo_rule(model, wi, single: bool, multi: bool, min_energy: float = 1e-12):
    """(wo[N, 3], weights[N]) integrating the BRDF's own lobes over the upper hemisphere.

    Each lobe m (a facet's single-bounce lobe: a polar rule in the facet's slope plane, mapped
    to ωo through the half vector; an exit lobe: a product rule in its gnomonic plane, cut
    exactly at the horizon) has its own rule, whose weights are multiplied by the partition
    ψ_m = g_m / Σ_l g_l of the lobes' grey values g_l (f cosθo without Fresnel): Σ_m ψ_m = 1
    wherever a lobe is non-zero, so Σ_m ∫ f ψ_m = ∫ f counts every lobe once. Lobes below
    ``min_energy`` get no rule of their own."""
    wi = wi / np.linalg.norm(wi)
    if wi[2] <= 1e-12:
        return np.zeros((0, 3)), np.zeros(0)
    s_term = model if isinstance(model, SingleBounce) else getattr(model, "single", None)
    m_term = model if isinstance(model, MultiBounce) else getattr(model, "multi", None)
    s_term = s_term if single else None
    m_term = m_term if multi else None
    dist = (s_term or m_term).dist
    rules, facets = [], []
    if s_term is not None:
        areas = dist.facet_areas(wi)
        facets = [k for k in range(4) if areas[k] > min_energy]
        kk = np.array(facets, int)
        owner, wo, w, _ = _facet_rule(dist, np.broadcast_to(wi, (kk.size, 3)), kk, _FINE)
        rules += [(wo[owner == j], w[owner == j]) for j in range(kk.size)]
    e = np.zeros((0, 3))
    if m_term is not None:
        walk = m_term.walk(wi[None, :])
        sel = (walk.bounces >= 2) & (walk.prob > min_energy)
        e, grey = walk.dirs[sel], walk.prob[sel]
        norm = _above_horizon(e[:, 2], m_term.beta)
        rules += [_exit_nodes(x, m_term.beta) for x in e]
    if not rules:
        return np.zeros((0, 3)), np.zeros(0)
    wo = np.concatenate([r[0] for r in rules])
    wts = np.concatenate([r[1] for r in rules])
    owner = np.repeat(np.arange(len(rules)), [r[0].shape[0] for r in rules])
    vals = []
    if facets:
        fk, _ = s_term.facet_terms(np.broadcast_to(wi, wo.shape), wo)
        vals.append(fk[:, facets])
    if e.shape[0]:
        vals.append(m_term.lobes(wo, e, grey, norm))
    vals = np.concatenate(vals, axis=1)
    tot = vals.sum(axis=1)
    own = vals[np.arange(wo.shape[0]), owner]
    with np.errstate(divide="ignore", invalid="ignore"):
        psi = np.where(tot > 0, own / tot, 0.0)
    keep = psi > 0
    return wo[keep], (wts * psi)[keep]


# --------------------------------------------------------------------------------------------
# The model


def _params():
    return (
        *PyramidDistribution.params,
        Param("max_bounces", "int", "Bounces followed (face sequences up to this length; 1: single-bounce "
              "microfacet model only).", default=3, minimum=1, maximum=6),
        Param("walk", "choice", "Probabilities of the face sequences: 'traced' (a ray tracer's of the random array, "
              "tabulated over incidence), 'height-correlated' (Smith walk with hit heights) or 'uncorrelated' "
              "(de Haas §3.3.2 made a probability: escape with G1).",
              default="traced", choices=("traced", "height-correlated", "uncorrelated")),
        C.component_param("fresnel", "none", "Fresnel reflectance of each facet, per bounce ('none': mirror "
                          "facets)."),
        *C.member_params("fresnel"),
    )


@register
class PyramidMicrofacet(Model):
    name = "pyramid-microfacet"
    summary = ("Random upright pyramids (textured c-Si): pyramid microfacet term plus exit lobes of multiple "
               "bounces (de Haas 2024, corrected).")
    reference = "DeHaas2024; Heitz2016; Heitz2014; Beckmann1963"
    params = ComposedParams(_params)
    isotropic = False
    energy_conserving = True

    def _setup(self, facet_roughness, phi0, max_bounces, walk, fresnel, **fresnel_values):
        self.dist = C.build("distribution", "pyramid", {"facet_roughness": facet_roughness, "phi0": phi0})
        self.walk = walk
        self.correlated = walk == "height-correlated"
        self.shadow = C.build("shadowing", "smith" if walk == "uncorrelated" else "pyramid", {})
        self.fres = C.build("fresnel", fresnel, fresnel_values)
        self.layout = self.fres.layout
        self.max_bounces = max_bounces
        self.single = SingleBounce(self.dist, self.shadow, self.fres, walk)
        self.multi = MultiBounce(self.single, max_bounces, walk) if max_bounces > 1 else None
        self.terms = Sum(terms=[self.single, self.multi]) if self.multi is not None else self.single
        self.reciprocal = self.multi is None

    @property
    def lobe_width(self) -> float:
        return self.dist.alpha

    def quadrature_parts(self):
        """The single-bounce term and the multi-bounce term (each with its own ``albedo_rule``)."""
        return [self.single] if self.multi is None else [self.single, self.multi]

    def albedo_rule(self, wi):
        """Outgoing directions and weights [sr] resolving every lobe for incidence ``wi[3]``."""
        return _albedo_rule(self, np.asarray(wi, float), single=True, multi=True)

    def _eval(self, wi, wo, lam, n):
        return self.terms._eval(wi, wo, lam, n)

    def _kernel(self, lam, n):
        """Both terms of a pair in one compiled loop (:func:`_pair_rows`; the traced walk)."""
        return _pair_kernel(self.dist, self.fres, self.walk, self.max_bounces, lam, n, True, self.multi is not None)

    # -- sequences ---------------------------------------------------------------------------

    def _one(self, wi):
        wi = np.asarray(wi, float).reshape(3)
        norm = np.linalg.norm(wi)
        if not np.isfinite(norm) or norm == 0 or wi[2] / norm <= 1e-12:
            raise ParameterError("wi", "expected a direction above the horizon")
        return wi / norm

    def _channels(self, wavelengths):
        lam = self.layout.resolve(wavelengths)
        return lam, self.layout.n_out(lam)

    def _walk(self, wi):
        w = _run_walk(self.dist, wi[None, :], self.max_bounces, self.walk)
        return _share(w, self.single.facet_energy(wi[None, :], fine=True))

    def exit_directions(self, wi, wavelengths=None) -> Exits:
        """Every surviving face sequence for incidence ``wi[3]`` (toward the source): exit
        direction, energy (after Fresnel; per channel unless the model is grey), bounce count,
        faces and local cosines. A single bounce's energy is that of its facet's lobe in the
        microfacet term (Fresnel at the lobe's centre)."""
        wi = self._one(wi)
        lam, n = self._channels(wavelengths)
        w = self._walk(wi)
        energy = w.prob[:, None] * _fresnel_product(self.fres, w.cosines, lam, n)
        if self.layout.grey and lam is None:
            energy = energy[:, 0]
        return Exits(w.dirs, energy, w.bounces, w.faces, w.cosines)

    def bounce_fractions(self, wi, wavelengths=None) -> np.ndarray:
        """Energy escaping after exactly 1, 2, …, ``max_bounces`` bounces, then the energy still
        inside after ``max_bounces`` (not yet absorbed; what the model drops), for incidence
        ``wi[3]``: shape (max_bounces + 1,) for a grey model, (max_bounces + 1, C) otherwise.
        The single-bounce entry is the microfacet term's integral (Fresnel across its lobes);
        the rest of the first hits goes on (or, when it cannot, counts as inside). For mirror
        facets the entries sum to 1."""
        wi = self._one(wi)
        lam, n = self._channels(wavelengths)
        w = self._walk(wi)
        out = np.zeros((self.max_bounces + 1, n))
        out[0] = self.single.facet_energy(wi[None, :], lam, n, fresnel=True, fine=True)[0].sum(axis=0)
        energy = w.prob[:, None] * _fresnel_product(self.fres, w.cosines, lam, n)
        for b in range(2, self.max_bounces + 1):
            out[b - 1] = energy[w.bounces == b].sum(axis=0)
        c0 = np.abs(self.dist.normals @ wi)
        out[-1] = (w.in_prob[:, None] * _fresnel_product(self.fres, w.in_cosines, lam, n)).sum(axis=0) \
            + (w.lost[0][:, None] * _fresnel_product(self.fres, c0[:, None], lam, n)).sum(axis=0)
        return out[:, 0] if self.layout.grey and lam is None else out
