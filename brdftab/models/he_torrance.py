"""He–Torrance–Sillion–Greenberg (HTSG) physical-optics reflection, and Bitterling's modified HT.

``he-torrance-1991`` [He1991] is the sum of three parts,

    f = f_sp + ρ_dd + R_dh,Lam / π,

with the formulas of Radiance's ``He.cal`` (the complete transcription of the paper, Greg Ward)
as collected in ``shared/reference/models.md`` §3.2. σ0 (rms height) and τ (autocorrelation
length) are in µm, the wavelength λ in nm (a model parameter, ``wavelength_nm``), the index
n + ik is complex:

* **Shadowing** (Smith [Smith1967], bistatic numerator): S(θ) = [1 − ½ erfc c] / (1 + Λ(c)),
  c = τ cotθ / (2σ0), Λ = ½ [e^{−c²}/(√π c) − erfc c]; the pair gets S(θi) S(θr). He.cal's
  cut-offs (S = 0 within 1e-4 rad of the horizon, S = 1 below 0.01 rad) are not copied: the
  formula itself goes to 0 and 1 there, continuously.
* **Effective roughness**: σ = σ0 / √(1 + z0²/σ0²) with z0 the root of
  √(π/2) z0 = (σ0/4)(K_i + K_r) e^{−z0²/(2σ0²)}, K(θ) = tanθ erfc(c). With y = z0²/σ0² and
  u = ln y this is e^u + u = 2 ln(K / (4√(π/2))), whose left side is convex and increasing in u:
  Newton's method started to the right of the root (u0 = L for L < 1, ln L otherwise)
  converges monotonically for every K ≥ 0 — it is run over whole arrays until every
  |Δu| ≤ :data:`NEWTON_TOL` (1e-13): y agrees with the closed form y = W(A²) (Lambert W) to
  1e-12 for K from 1e-12 to 1e12, in at most 12 steps (tested). (He.cal's Newton on z0 itself,
  from z0 = 0.1 with tolerance 1e-4, is not used.)
* **Roughness function** g = [(2π/λ) σ (cosθi + cosθr)]² with the *effective* σ of the pair.
* **Distribution** D = (π²τ²/(4λ²)) Σ_{m≥1} g^m e^{−g} / (m! m) · exp(−τ² v_xy² / (4m)),
  v_xy² = (2π/λ)² (|v|² − v_z²), v = ω̂i + ω̂r. The terms are summed in log space
  (:func:`htsg_series`) outward from the largest one until the remainder, bounded by a
  geometric series (the term ratio decreases with m: the sequence is log-concave), is below
  :data:`SERIES_TOL` (1e-12) of the sum — no fixed cut: for g from 0.5 to 10⁴ the sum agrees
  with a term-by-term sum to 1e-9 (tested), where He.cal's cut at m = 200 would lose all of it
  for g ≳ 600 (the Poisson weights sit at m ≈ g ± √g).
* **Directional diffuse** ρ_dd = |F(θ_loc)|²/π · G · S(θi)S(θr) · D / (cosθi cosθr), F the
  unpolarized complex Fresnel reflectance at the local angle, cosθ_loc = |ω̂i + ω̂r|/2, and
  G = (v·v / v_z)² (unit vectors; the paper's polarization brackets cancel, as noted in
  He.cal). ρ_dd is reciprocal by construction (every factor is symmetric; tested to 1e-12).
* **Specular**: an ideal mirror lobe, f_sp = |F(θi)|² e^{−g} S / (cosθi dω_i) · Δ. Without a
  cone half-width (the default) Δ is a delta: a table cannot hold it, so the model exposes the
  **specular reflectance** ρ_s(θi) = |F(θi)|² e^{−g(θi, θi)} S(θi)² (He.cal's ``s``) through
  :meth:`specular_delta` — tables store it as their ``specular_reflectance`` variable, the
  albedo integrals add it. The model is then reciprocal. With ``cone_half_width = w``
  (Bitterling et al.'s fitted variant, [Bitterling2024] Eq. 17) Δ is the unit function of the
  cone of half-width w about the mirror direction, dω_i = 2π(1 − cos w) its solid angle, and
  inside it F is taken at the local angle (Eq. 17's F((θi − θr)/2)), g and S at the actual
  pair. The factor 1/cosθi is not symmetric: the cone variant declares itself
  non-reciprocal.
* **Uniform diffuse** R_dh,Lam / π ([Bitterling2024] Eq. 9: models.md's a(λ) is that value).

``he-torrance-modified`` is Bitterling et al.'s §4 model ([Bitterling2024] Eqs. 22–24): the
unit cone is replaced by a Gaussian profile Γ = exp(−Δφ²/(2w_φ)²) exp(−(θr − θi)²/(2w_θ)²)
(Δφ = φr − φi − π wrapped into (−π, π], not [0, 2π) as "mod 2π" would read), normalized by its
solid angle dω_i,g(θi) = ∫∫ Γ sinθr dθr dφr over the hemisphere (Eq. 23: per incidence angle,
by Gauss–Legendre quadrature, cached), the specular shadowing is dropped (G_HT = 1; ρ_dd keeps
S(θi)S(θr)) and cosθi in the denominator becomes cosθm, θm = arccos(ω̂r·ω̂i)/2 (Eq. 24).
The paper leaves open where the roughness function g is evaluated off the mirror direction;
this model evaluates it **at the local half-vector**, i.e. from the actual pair exactly as in
ρ_dd: g = [(2π/λ) σ(θi, θr) v_z]² with v = ω̂i + ω̂r = |v| h and the effective σ of the pair
(v_z = cosθi + cosθr), not at the incidence's mirror geometry g(θi, θi). On the mirror
direction the two agree. With the paper's fit this choice gives the directional-hemispherical
reflectance that rises monotonically from 0.037 at normal incidence to 0.66 at 89° (tested).
Γ/dω_i,g(θi) is not reciprocal: the model declares it.

**Compiled evaluation.** ``eval`` runs one compiled loop (:func:`_htsg_rows`) over the pairs,
built from scalar forms of the functions above (``*_scalar``): the same shadowing, the same
Newton iteration for the effective roughness (start, steps and stopping rule per pair), the
same m-series (the same peak — its bisection replaced by Halley's method wherever that gives
the same rounded peak, the bisection itself elsewhere — and the same walks and stopping rule),
with the per-wavelength constants and the series' tables set up once per model and wavelength
list. It agrees with the numpy code (the reference inside :func:`brdftab.brdf.numpy_reference`)
to 1e-12 relative for g up to a few hundred, and to 6e-12 at g of a few thousand, where the
numpy series itself moves by 5e-12 for one unit in the last place of g (tests/test_kernels.py).

Parameters outside the range where HTSG holds are refused with one line: the Kirchhoff
(tangent-plane) approximation under it needs surface radii of curvature larger than the
wavelength [Beckmann1963] — for a Gaussian surface the rms radius is τ²/(√12 σ0) — and for
g beyond :data:`G_MAX` (σ0/λ above ≈ 8) the surface is in the geometric-optics limit, where a
microfacet model describes it (and the m-series' length grows with √g).

Quadrature hints (:mod:`brdftab.integrate`): the cone and the Gaussian profile are separate
:meth:`quadrature_parts`, each with its own ``albedo_rule`` (Gauss–Legendre in cosψ about the
mirror direction for the cone; panels graded about the profile's centre by w_θ and w_φ), so
the albedo and energy checks resolve them; against quadratures written in the tests the
Pyromark fits' directional albedo agrees to 1e-4 from 0° to 89° (tested).

References: [He1991]; [Bitterling2024] Eqs. 8, 9, 16–18, 22–24; [Smith1967]; [Beckmann1963].
"""

from __future__ import annotations

import math

import numpy as np
from scipy.special import erf, erfc, gammaln

from .._jit import device
from ..brdf import BRDF, Model
from ..errors import BrdftabError, ParameterError
from ..params import Param
from ..quadrature import gauss_legendre
from .fresnel import INDEX_MIN, conductor_scalar, fresnel_conductor
from ._registry import register

__all__ = ["HeTorrance1991", "ModifiedHeTorrance", "smith_shadow", "shadow_k", "effective_roughness",
           "htsg_series", "NEWTON_TOL", "SERIES_TOL", "G_MAX"]

_SQRT_PI = np.sqrt(np.pi)
_SQRT_HALF_PI = np.sqrt(0.5 * np.pi)
#: Newton's method for the effective roughness stops when every |Δ ln(z0²/σ0²)| is below this.
NEWTON_TOL = 1e-13
NEWTON_MAX_ITER = 100
#: The m-series stops when its remainder (a geometric bound) is below this fraction of the sum.
SERIES_TOL = 1e-12
#: Largest roughness function g = (4π σ0/λ)² accepted (at normal incidence and reflection).
G_MAX = 1e4
#: The rms radius of curvature τ²/(√12 σ0) must be at least this many wavelengths.
MIN_CURVATURE_RADIUS = 1.0


# --------------------------------------------------------------------------------------------
# The HTSG building blocks (plain vectorized functions; lengths in one unit, e.g. µm)


def _cot_arg(cos_t, sigma0, tau):
    """c = τ cotθ / (2σ0) (inf at θ = 0)."""
    cos_t = np.asarray(cos_t, float)
    sin_t = np.sqrt(np.maximum(1.0 - cos_t * cos_t, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(sin_t > 0, tau * cos_t / (2.0 * sigma0 * np.where(sin_t > 0, sin_t, 1.0)), np.inf)


def smith_shadow(cos_t, sigma0, tau):
    """Smith's shadowing of one direction, S(θ) = [1 − ½ erfc c] / (1 + Λ), c = τ cotθ/(2σ0).

    Λ = ½ [e^{−c²}/(√π c) − erfc c] (the Beckmann Smith Λ with α = 2σ0/τ). S = 1 at the normal.
    """
    c = _cot_arg(cos_t, sigma0, tau)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        lam = np.where(np.isinf(c), 0.0, 0.5 * (np.exp(-c * c) / (_SQRT_PI * c) - erfc(c)))
        s = (1.0 - 0.5 * erfc(c)) / (1.0 + lam)
    return np.where(c > 0, s, 0.0)


def shadow_k(cos_t, sigma0, tau):
    """K(θ) = tanθ erfc(τ cotθ / (2σ0)) of the effective-roughness equation (0 at the normal)."""
    cos_t = np.asarray(cos_t, float)
    sin_t = np.sqrt(np.maximum(1.0 - cos_t * cos_t, 0.0))
    c = _cot_arg(cos_t, sigma0, tau)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(sin_t > 0, sin_t / cos_t * erfc(c), 0.0)


def effective_roughness(k_sum, tol: float = NEWTON_TOL, *, iterations: bool = False):
    """y = z0²/σ0² of the effective-roughness equation for ``k_sum`` = K_i + K_r (any shape).

    √(π/2) z0 = (σ0/4) K e^{−z0²/(2σ0²)} ⇔ y e^y = A², A = K/(4√(π/2)). Newton's method on
    u = ln y (e^u + u = 2 ln A, convex and increasing) from u0 = L if L < 1 else ln L — to the
    right of the root, so it converges monotonically — over the whole array until every
    |Δu| ≤ ``tol``. σ_eff = σ0 / √(1 + y). With ``iterations`` also returns the number of
    Newton steps taken. Raises :class:`BrdftabError` if it has not converged after
    :data:`NEWTON_MAX_ITER` steps (it always converges; the check guards the guarantee).
    """
    k_sum = np.asarray(k_sum, float)
    y = np.zeros(k_sum.shape)
    pos = k_sum > 0
    big = pos & np.isinf(k_sum)
    y[big] = np.inf
    idx = np.flatnonzero(pos & ~big)
    steps = 0
    if idx.size:
        L = 2.0 * np.log(k_sum.ravel()[idx] / (4.0 * _SQRT_HALF_PI))
        u = np.where(L < 1.0, L, np.log(np.maximum(L, 1.0)))
        active = np.arange(idx.size)
        while active.size:
            if steps >= NEWTON_MAX_ITER:
                raise BrdftabError(f"the effective-roughness equation did not converge in {NEWTON_MAX_ITER} "
                                   "Newton steps")
            ua, La = u[active], L[active]
            eu = np.exp(ua)
            du = (eu + ua - La) / (eu + 1.0)
            u[active] = ua - du
            steps += 1
            active = active[~(np.abs(du) <= tol * np.maximum(1.0, np.abs(ua)))]
        y.ravel()[idx] = np.exp(u)
    return (y, steps) if iterations else y


_TABLE = {"n": 0, "lgm": np.zeros(0), "lr": np.zeros(0), "lg1": np.zeros(0), "lm": np.zeros(0)}


def _tables(m_max: int, *, parts: bool = False):
    """ln m! + ln m and ln m − 2 ln(m + 1) for m = 0 … m_max (index m; grown on demand); with
    ``parts`` also ln m! and ln m apart (as :func:`_log_term` adds them)."""
    if _TABLE["n"] <= m_max:
        n = max(int(m_max) + 1, 2 * _TABLE["n"], 1024)
        m = np.arange(n, dtype=float)
        with np.errstate(divide="ignore"):
            _TABLE["lg1"] = gammaln(m + 1.0)
            _TABLE["lm"] = np.log(m)
            _TABLE["lgm"] = gammaln(m + 1.0) + np.log(m)
            _TABLE["lr"] = np.log(m) - 2.0 * np.log1p(m)
        _TABLE["n"] = n
    if parts:
        return _TABLE["lgm"], _TABLE["lr"], _TABLE["lg1"], _TABLE["lm"]
    return _TABLE["lgm"], _TABLE["lr"]


def _log_ratio(m, lg, e):
    """ln(t_{m+1}/t_m) of the m-series: ln g + ln m − 2 ln(m + 1) + E/(m(m + 1))."""
    return lg + np.log(m) - 2.0 * np.log1p(m) + e / (m * (m + 1.0))


def _log_term(m, lg, g, e):
    """ln t_m = m ln g − g − ln m! − ln m − E/m."""
    return m * lg - g - gammaln(m + 1.0) - np.log(m) - e / m


def _series_peak(lg, g, e):
    """The index m ≥ 1 of the largest term (the first m whose ratio t_{m+1}/t_m is ≤ 1), to ±1."""
    lo = np.ones_like(lg)
    up = lo.copy()
    first = _log_ratio(lo, lg, e) > 0
    if not first.any():
        return up
    hi = 3.0 * np.maximum(g, 1.0) + 2.0 * np.sqrt(e) + 2.0   # ln r(hi) < 0 (see htsg_series)
    lo_l, hi_l = np.zeros(int(first.sum())), np.log(hi[first])
    lgf, ef = lg[first], e[first]
    for _ in range(26):  # bisection in ln m (ln hi < 14 for accepted g): m to 1e-6 relative
        mid = 0.5 * (lo_l + hi_l)
        pos = _log_ratio(np.exp(mid), lgf, ef) > 0
        lo_l = np.where(pos, mid, lo_l)
        hi_l = np.where(pos, hi_l, mid)
    up[first] = np.maximum(1.0, np.round(np.exp(hi_l)))
    return up


def _walk(total, start, step, lg, g, e, a0, tol, count):
    """Add the terms from index ``start`` in direction ``step`` (±1) to ``total`` until the
    geometric bound on the remainder is below ``tol`` of the partial sum (whole arrays; the
    running set shrinks as samples finish)."""
    idx = np.arange(total.size)
    m = start.copy()
    run = m >= 1.0
    idx, m, lg, g, e, a0 = idx[run], m[run], lg[run], g[run], e[run], a0[run]
    while idx.size:
        mi = m.astype(np.int64)
        lgm, lr = _tables(int(mi.max()) + 1)
        t = np.exp(m * lg - g - lgm[mi] - e / m - a0)
        tot = total[idx] + t
        total[idx] = tot
        count[idx] += 1
        if step > 0:      # q = t_{m+1}/t_m = r(m), decreasing upward
            q = np.exp(lg + lr[mi] + e / (m * (m + 1.0)))
            done = (q < 1.0) & (t * q <= tol * tot * (1.0 - np.minimum(q, 1.0)))
        else:             # q = t_{m−1}/t_m = 1/r(m − 1), decreasing downward
            mm = np.maximum(m - 1.0, 1.0)
            q = np.where(m - 1.0 < 1.0, 0.0, np.exp(-(lg + lr[mm.astype(np.int64)] + e / (mm * (mm + 1.0)))))
            done = (m - 1.0 < 1.0) | ((q < 1.0) & (t * q <= tol * tot * (1.0 - np.minimum(q, 1.0))))
        m = m + step
        if done.any():
            keep = ~done
            idx, m, lg, g, e, a0 = idx[keep], m[keep], lg[keep], g[keep], e[keep], a0[keep]


def htsg_series(g, e, tol: float = SERIES_TOL, *, terms: bool = False):
    """Σ_{m≥1} g^m e^{−g} / (m! m) · e^{−E/m} for arrays ``g`` ≥ 0 and ``e`` = E ≥ 0.

    The terms t_m are formed in log space. Their ratio r(m) = g m/(m + 1)² · e^{E/(m(m+1))}
    decreases with m (the sequence is log-concave), so the largest term is near the first m
    with r(m) ≤ 1 (found by bisection) and the sum is built outward from it, upward and then
    downward, over whole arrays of the samples still running; a direction stops once the
    geometric bound on its remainder, t·q/(1 − q) with q the (decreasing) outward term ratio,
    is below ``tol`` of the partial sum. No fixed number of terms: the window follows the
    Poisson weights to m ≈ g ± several √g however large g is. With ``terms`` also returns the
    number of terms summed per sample.

    ln r(hi) < 0 at hi = 3 max(g, 1) + 2√E + 2: ln r(m) < ln g − ln m + E/m² ≤ −ln 3 + 1/4.
    """
    g = np.asarray(g, float)
    e = np.maximum(np.broadcast_to(np.asarray(e, float), g.shape), 0.0)
    out = np.zeros(g.shape)
    count = np.zeros(g.shape, np.int64)
    idx = np.flatnonzero(g > 0)
    if idx.size:
        gg = g.ravel()[idx]
        ee = e.ravel()[idx]
        lg = np.log(gg)
        peak = _series_peak(lg, gg, ee)
        a0 = _log_term(peak, lg, gg, ee)
        total = np.ones(idx.size)
        n = np.ones(idx.size, np.int64)
        _walk(total, peak + 1.0, 1, lg, gg, ee, a0, tol, n)
        _walk(total, peak - 1.0, -1, lg, gg, ee, a0, tol, n)
        out.ravel()[idx] = np.exp(a0) * total
        count.ravel()[idx] = n
    return (out, count) if terms else out


# --------------------------------------------------------------------------------------------
# Scalar forms of the building blocks above, for the compiled evaluation (:func:`_htsg_rows`):
# the same arithmetic, the same iterations and stopping rules, one pair at a time.


@device
def cot_arg_scalar(cos_t, sigma0, tau):
    """:func:`_cot_arg` of one cosine."""
    sin_t = math.sqrt(max(1.0 - cos_t * cos_t, 0.0))
    return tau * cos_t / (2.0 * sigma0 * sin_t) if sin_t > 0 else math.inf


#: Largest x² for which :func:`scipy.special.erfc` (cephes) returns a non-zero erfc(x): past it,
#: it returns 0 where the C library's erfc goes on with subnormal numbers.
_ERFC_UNDERFLOW = 7.09782712893383996843e2


@device
def erfc_scalar(x):
    """:func:`scipy.special.erfc` of one number (0 past its underflow, as there)."""
    return 0.0 if x * x > _ERFC_UNDERFLOW else math.erfc(x)


@device
def smith_shadow_scalar(c, erfc_c):
    """:func:`smith_shadow` from c = τ cotθ/(2σ0) and erfc(c)."""
    lam = 0.0 if math.isinf(c) else 0.5 * (math.exp(-c * c) / (_SQRT_PI * c) - erfc_c)
    s = (1.0 - 0.5 * erfc_c) / (1.0 + lam)
    return s if c > 0 else 0.0


@device
def shadow_k_scalar(cos_t, erfc_c):
    """:func:`shadow_k` from cosθ and erfc(c)."""
    sin_t = math.sqrt(max(1.0 - cos_t * cos_t, 0.0))
    return sin_t / cos_t * erfc_c if sin_t > 0 else 0.0


@device
def effective_roughness_scalar(k_sum, tol):
    """:func:`effective_roughness` of one K_i + K_r: (y, Newton steps), steps −1 when it has not
    converged in :data:`NEWTON_MAX_ITER` steps."""
    if not k_sum > 0:
        return 0.0, 0
    if math.isinf(k_sum):
        return math.inf, 0
    big_l = 2.0 * math.log(k_sum / (4.0 * _SQRT_HALF_PI))
    u = big_l if big_l < 1.0 else math.log(max(big_l, 1.0))
    steps = 0
    while True:
        if steps >= NEWTON_MAX_ITER:
            return math.nan, -1
        eu = math.exp(u)
        du = (eu + u - big_l) / (eu + 1.0)
        ua = u
        u = ua - du
        steps += 1
        if abs(du) <= tol * max(1.0, abs(ua)):
            return math.exp(u), steps


@device
def _log_ratio_scalar(m, lg, e):
    """:func:`_log_ratio` of one m."""
    return lg + math.log(m) - 2.0 * math.log1p(m) + e / (m * (m + 1.0))


@device
def _round_half_even(x):
    r = math.floor(x + 0.5)
    if r - x == 0.5 and r % 2.0 == 1.0:
        r -= 1.0
    return r


#: Width in ln m of the interval the 26 bisection steps of :func:`_series_peak` end on, per unit
#: of the starting width ln(hi).
_BISECTION_WIDTH = 2.0 ** -26


@device
def series_peak_scalar(lg, g, e):
    """:func:`_series_peak` of one (ln g, g, E), with the same result. The bisection there ends
    on ln m_hi ∈ [u*, u* + ln(hi)/2²⁶] (u* = ln m*, the root of the log ratio) and rounds
    m_hi: here m* is found by a safeguarded Halley's method (2 to 3 steps instead of 26), and
    when [m*, m* e^{ln(hi)/2²⁶}] (widened by 1e-8) holds no half-integer, round(m*) is that
    result; otherwise (a chance of about m*·2e-7) the bisection itself runs."""
    if not _log_ratio_scalar(1.0, lg, e) > 0:
        return 1.0
    hi = 3.0 * max(g, 1.0) + 2.0 * math.sqrt(e) + 2.0
    hl = math.log(hi)
    # Halley's method on the log ratio ψ(m) = ln g + ln m − 2 ln(m + 1) + E/(m(m + 1)) (its two
    # logarithms are independent; ψ', ψ'' rational), kept inside the bracket [a, b] (ψ(a) > 0 >
    # ψ(b)), bisecting when a step leaves it; a step below 1e-5 m leaves an error of ~1e-15 m
    a = 1.0
    b = hi
    m = min(max(max(g - 1.5, 1.5) + 0.5 * math.sqrt(e), 1.5), 0.5 * hi)
    for _ in range(100):
        f = lg + math.log(m) - 2.0 * math.log(1.0 + m) + e / (m * (m + 1.0))
        if f > 0:
            a = m
        else:
            b = m
        im = 1.0 / m
        ip = 1.0 / (m + 1.0)
        d1 = im - 2.0 * ip + e * (ip * ip - im * im)
        d2 = 2.0 * ip * ip - im * im + 2.0 * e * (im * im * im - ip * ip * ip)
        step = 2.0 * f * d1 / (2.0 * d1 * d1 - f * d2) if d1 < 0 else 0.0
        mn = m - step
        if d1 < 0 and abs(step) <= 1e-5 * m and a <= mn <= b:
            m = mn
            break
        if not (d1 < 0 and a < mn < b):
            mn = 0.5 * (a + b)
        m = mn
        if b - a <= 1e-12 * m:
            break
    lo_m = m * (1.0 - 1e-8)
    hi_m = m * (1.0 + 1.001 * hl * _BISECTION_WIDTH) * (1.0 + 1e-8)  # ≥ m e^{ln(hi)/2²⁶}
    k = math.floor(lo_m + 0.5)
    if k + 0.5 > hi_m:  # no half-integer in [lo_m, hi_m]
        return max(1.0, k)
    lo_l = 0.0
    hi_l = hl
    for _ in range(26):
        mid = 0.5 * (lo_l + hi_l)
        if _log_ratio_scalar(math.exp(mid), lg, e) > 0:
            lo_l = mid
        else:
            hi_l = mid
    return max(1.0, _round_half_even(math.exp(hi_l)))


#: Terms of the m-series formed at once by :func:`htsg_series_scalar` (their exponentials are
#: independent, so the processor overlaps them; a walk wastes fewer than this many).
SERIES_BATCH = 8


@device
def htsg_series_scalar(g, e, tol, lgm, lr, lg1, lm, buf):
    """:func:`htsg_series` of one (g, E), with the tables of :func:`_tables` (``parts``) and a
    scratch array ``buf[SERIES_BATCH]``: the same peak, then the walks up and down with the same
    geometric stopping rule. NaN when a walk would run past the tables (their length is chosen
    so that it cannot)."""
    e = max(e, 0.0)
    if not g > 0:
        return 0.0
    lg = math.log(g)
    peak = series_peak_scalar(lg, g, e)
    ip = int(peak)
    a0 = peak * lg - g - lg1[ip] - lm[ip] - e / peak
    total = 1.0
    nb = buf.size
    last = lgm.size - 1 - nb
    # each term t_m = exp(m ln g − g − ln m! − ln m − E/m − a0) as there, formed nb at a time;
    # the stopping rule's ratio q is t_{m±1}/t_m (multiplied out), not exp of ln r: the two
    # differ in the last digits, which could change where a walk stops only when it is within
    # rounding of the threshold, and then by a term below the tolerance
    m = peak + 1.0
    if int(m) > last:
        return math.nan
    t = math.exp(m * lg - g - lgm[int(m)] - e / m - a0)
    going = True
    while going:  # upward: q = t_{m+1}/t_m = r(m)
        mi = int(m)
        if mi > last:
            return math.nan
        for j in range(nb):
            mn = m + (j + 1.0)
            buf[j] = math.exp(mn * lg - g - lgm[mi + j + 1] - e / mn - a0)
        for j in range(nb):
            total = total + t
            tn = buf[j]
            if t > 0:  # q = tn/t < 1 and t q <= tol total (1 − q), multiplied out by t
                if tn < t and tn * t <= tol * total * (t - tn):
                    going = False
                    break
            else:
                q = math.exp(lg + lr[mi + j] + e / (m * (m + 1.0)))
                if q < 1.0 and t * q <= tol * total * (1.0 - min(q, 1.0)):
                    going = False
                    break
            m = m + 1.0
            t = tn
    m = peak - 1.0
    if m >= 1.0:
        t = math.exp(m * lg - g - lgm[int(m)] - e / m - a0)
    going = m >= 1.0
    while going:  # downward: q = t_{m−1}/t_m = 1/r(m − 1)
        mi = int(m)
        for j in range(min(nb, mi - 1)):
            mm = m - (j + 1.0)
            buf[j] = math.exp(mm * lg - g - lgm[mi - j - 1] - e / mm - a0)
        for j in range(nb):
            total = total + t
            if m - 1.0 < 1.0:
                going = False
                break
            mm = m - 1.0
            tn = buf[j]
            if t > 0:  # as upward
                if tn < t and tn * t <= tol * total * (t - tn):
                    going = False
                    break
            else:
                q = math.exp(-(lg + lr[int(mm)] + e / (mm * (mm + 1.0))))
                if q < 1.0 and t * q <= tol * total * (1.0 - min(q, 1.0)):
                    going = False
                    break
            m = mm
            t = tn
    return math.exp(a0) * total


@device
def _spline_scalar(x, c, t):
    """A scipy ``PPoly`` (breakpoints ``x``, coefficients ``c[4, len(x) − 1]``) at ``t`` within
    [x[0], x[−1]], summed as scipy sums it (lowest power first). The piece is the one with
    x[lo] <= t < x[lo + 1] (the last at t = x[−1]), found from a guess for evenly spaced
    breakpoints (the profile's spline) and a walk to it: one or two comparisons there, where a
    bisection of the ~2000 breakpoints mispredicts about half of its 11 branches."""
    last = x.size - 2
    lo = int((t - x[0]) * (last + 1) / (x[last + 1] - x[0])) if x[last + 1] > x[0] else 0
    lo = min(max(lo, 0), last)
    while lo > 0 and t < x[lo]:
        lo -= 1
    while lo < last and t >= x[lo + 1]:
        lo += 1
    d = t - x[lo]
    res = 0.0
    z = 1.0
    k = c.shape[0]
    for kp in range(k):
        res = res + c[k - kp - 1, lo] * z
        z *= d
    return res


#: :func:`_htsg_rows` variants: ρ_dd (and R_dh,Lam/π) only, plus the cone, plus the Gaussian profile.
_DIFFUSE, _CONE, _PROFILE = 0, 1, 2


@device
def _htsg_rows(wi, wo, state, out, add, variant, p, per_lam, spline_x, spline_c, lgm, lr, lg1, lm):
    """The compiled evaluation of both HTSG models, the arithmetic of their numpy code
    (:class:`_Pair`, :meth:`_HTSGBase._diffuse_parts`, :meth:`HeTorrance1991._cone`,
    :meth:`ModifiedHeTorrance._specular`) pair by pair: writes (``add``: adds) f into the rows of
    ``out`` whose ``state`` is 1. ``p`` = [σ0, τ, n, k, R_dh,Lam/π, cos w, dω_i, w_φ, w_θ,
    Newton tolerance, series tolerance, with the diffuse parts (1/0), with the specular part];
    ``per_lam[c]`` = [(kσ0)², ¼(τk)², π²τ²/(4λ²)] per
    wavelength (k = 2π/λ); ``spline_x``, ``spline_c``: the profile's solid angle dω_i,g(θi).
    Returns 0, or 1 when Newton's method did not converge, 2 when a series ran past the tables."""
    sigma0, tau, n_re, k_im, rdh = p[0], p[1], p[2], p[3], p[4]
    cone_cos, cone_sa, w_phi, w_theta, newton_tol, series_tol = p[5], p[6], p[7], p[8], p[9], p[10]
    with_diffuse = p[11] != 0.0
    with_lobe = p[12] != 0.0
    nc = out.shape[1]
    status = 0
    buf = np.empty(SERIES_BATCH)
    for i in range(wi.shape[0]):
        if state[i] != 1:
            continue
        ci = wi[i, 2]
        co = wo[i, 2]
        vx = wi[i, 0] + wo[i, 0]
        vy = wi[i, 1] + wo[i, 1]
        vz = ci + co
        vv = vx * vx + vy * vy + vz * vz
        vxy2 = vx * vx + vy * vy
        cos_loc = 0.5 * math.sqrt(vv)
        c_i = cot_arg_scalar(ci, sigma0, tau)
        c_o = cot_arg_scalar(co, sigma0, tau)
        erfc_i = erfc_scalar(c_i)
        erfc_o = erfc_scalar(c_o)
        shadow = smith_shadow_scalar(c_i, erfc_i) * smith_shadow_scalar(c_o, erfc_o)
        y, steps = effective_roughness_scalar(shadow_k_scalar(ci, erfc_i) + shadow_k_scalar(co, erfc_o), newton_tol)
        if steps < 0:
            status = 1
        ratio2 = 1.0 / (1.0 + y)
        fresnel = conductor_scalar(cos_loc, n_re, k_im)
        sq = vv / vz
        base = fresnel / np.pi * (sq * sq) * shadow / (ci * co)
        inside = False
        lobe = 0.0
        if not with_lobe:
            pass
        elif variant == _CONE:
            inside = -wi[i, 0] * wo[i, 0] - wi[i, 1] * wo[i, 1] + ci * co >= cone_cos
            lobe = fresnel * shadow / (ci * cone_sa)
        elif variant == _PROFILE:
            inside = True
            ix, iy, ox, oy = wi[i, 0], wi[i, 1], wo[i, 0], wo[i, 1]
            ti = math.atan2(math.sqrt(ix * ix + iy * iy), ci)
            to = math.atan2(math.sqrt(ox * ox + oy * oy), co)
            # φr − φi in (−π, π] as one angle (its sine and cosine times |wi_xy||wo_xy|), then
            # Δφ = φr − φi − π wrapped into (−π, π]: the profile's Δφ to rounding; the azimuths
            # one by one (atan2(0, 0) = 0 for a direction on the normal) where that product is
            # (nearly) 0
            sin_d = ix * oy - iy * ox
            cos_d = ix * ox + iy * oy
            if abs(sin_d) + abs(cos_d) > 1e-200:
                dphi = math.atan2(sin_d, cos_d)
                dphi = dphi + np.pi if dphi <= 0.0 else dphi - np.pi
            else:
                dphi = math.atan2(oy, ox) - math.atan2(iy, ix) - np.pi
                dphi = np.pi - (np.pi - dphi) % (2.0 * np.pi)
            a = dphi / (2.0 * w_phi)
            b = (to - ti) / (2.0 * w_theta)
            profile = math.exp(-(a * a)) * math.exp(-(b * b))
            lobe = fresnel * profile / (cos_loc * _spline_scalar(spline_x, spline_c, min(max(ti, 0.0), 0.5 * np.pi)))
        for c in range(nc):
            g = per_lam[c, 0] * ratio2 * vz * vz
            v = 0.0
            if with_diffuse:
                series = htsg_series_scalar(g, per_lam[c, 1] * vxy2, series_tol, lgm, lr, lg1, lm, buf)
                if math.isnan(series) and not math.isnan(g):
                    status = 2
                v = base * per_lam[c, 2] * series
                if rdh != 0.0:
                    v = v + rdh
            if inside:
                v = v + lobe * math.exp(-g)
            out[i, c] = out[i, c] + v if add else v
    return status


_GENERATED = '''\
# Generated by brdftab.models.he_torrance (do not edit): the HTSG kernel; sources {digest}, constants {constants}
import numba

from brdftab._jit import OPTIONS
from brdftab.models.fused import as_device
from brdftab.models.he_torrance import _htsg_rows

_rows = as_device(_htsg_rows)


@numba.njit(**OPTIONS)
def run(wi, wo, state, out, add, variant, p, per_lam, spline_x, spline_c, lgm, lr, lg1, lm):
    return _rows(wi, wo, state, out, add, variant, p, per_lam, spline_x, spline_c, lgm, lr, lg1, lm)
'''


def _htsg_kernel():
    """:func:`_htsg_rows` compiled, from a generated module named by a hash of its source and of
    every function it inlines (:func:`brdftab._jit.source_hash`: the Fresnel term lives in
    another file, whose edits numba's own cache would not see) and of the constants it reads."""
    from .._jit import generated_module, source_hash

    constants = repr((SERIES_BATCH, NEWTON_MAX_ITER, _ERFC_UNDERFLOW, _BISECTION_WIDTH, float(_SQRT_PI),
                      float(_SQRT_HALF_PI), _DIFFUSE, _CONE, _PROFILE))
    return generated_module("htsg", _GENERATED.format(digest=source_hash(_htsg_rows), constants=constants)).run


def _fresnel(cos_t, n, k):
    """Unpolarized reflectance |F|² of the complex index n + ik (models.md §4.3)."""
    return fresnel_conductor(cos_t, n, k)


# --------------------------------------------------------------------------------------------
# The models


#: Narrowest specular cone (0.001°): the cone's solid angle 2π(1 − cos w) is lost to rounding
#: below about 1e-8 rad (the lobe became infinite), and a cone far narrower than any grid step
#: cannot be tabulated anyway.
CONE_MIN = float(np.radians(1e-3))


def _common_params(wavelength_default: float):
    return (
        Param("n", "float", "Real part of the complex refractive index n + ik.", minimum=INDEX_MIN, maximum=10.0),
        Param("k", "float", "Imaginary part (extinction coefficient) of the index n + ik.", default=0.0, minimum=0.0,
              maximum=20.0),
        Param("sigma0", "float", "rms surface height σ0 (Bitterling's σ).", units="µm", minimum=1e-3, maximum=10.0),
        Param("tau", "float", "Autocorrelation length τ of the Gaussian surface.", units="µm", minimum=1e-2,
              maximum=100.0),
        Param("wavelength_nm", "float", "Wavelength the model evaluates at without a wavelength list.", units="nm",
              default=wavelength_default, minimum=200.0, maximum=20000.0),
        Param("r_dh_lam", "float", "Directional-hemispherical reflectance R_dh,Lam of the uniform diffuse part "
              "(the BRDF adds R_dh,Lam/π).", default=0.0, minimum=0.0, maximum=1.0),
    )


class _Part(BRDF):
    """One additive part of a model (for :meth:`quadrature_parts`): evaluates ``fn``."""

    def __init__(self, owner, fn, name, rule=None, reciprocal=True, part=None):
        self.name = f"{owner.name}:{name}"
        self.layout = owner.layout
        self.isotropic = owner.isotropic
        self.reciprocal = reciprocal
        self._fn = fn
        self._owner = owner
        self._part = part
        if rule is not None:
            self.albedo_rule = rule

    def _kernel(self, lam, n):
        """The owner's compiled evaluation of this part alone (``part`` "diffuse" or "specular")."""
        return None if self._part is None else self._owner._kernel(lam, n, part=self._part)

    def _eval(self, wi, wo, lam, n):
        return self._fn(wi, wo, lam, n)


class _HTSGBase(Model):
    """Shared parts of the HTSG models: shadowing, effective roughness, ρ_dd, Fresnel."""

    def _setup_common(self, n, k, sigma0, tau, wavelength_nm, r_dh_lam):
        self.n, self.k = n, k
        self.sigma0, self.tau = sigma0, tau
        self.wavelength_nm = wavelength_nm
        self.r_dh_lam = r_dh_lam
        self._check_wavelengths(np.array([wavelength_nm]), "wavelength_nm")

    def _check_wavelengths(self, lam_nm, key):
        """Refuse wavelengths at which HTSG does not hold for this surface (one line)."""
        lam_um = np.asarray(lam_nm, float) * 1e-3
        radius = self.tau ** 2 / (np.sqrt(12.0) * self.sigma0)
        worst = float(np.max(lam_um))
        if radius < MIN_CURVATURE_RADIUS * worst:
            raise ParameterError(key, f"the surface's rms radius of curvature τ²/(√12 σ0) = {radius:.3g} µm is "
                                 f"below the wavelength {worst * 1e3:g} nm: HTSG's Kirchhoff approximation needs "
                                 "smoother surfaces (larger τ or smaller σ0)")
        g_max = (4.0 * np.pi * self.sigma0 / float(np.min(lam_um))) ** 2
        if g_max > G_MAX:
            ratio = self.sigma0 / float(np.min(lam_um))
            raise ParameterError(key, f"σ0/λ = {ratio:.3g} gives a roughness function g up to {g_max:.3g} (accepted "
                                 f"≤ {G_MAX:g}, σ0/λ ≤ {np.sqrt(G_MAX) / (4 * np.pi):.3g}): the geometric-optics "
                                 "limit, use a microfacet model")

    def _lams_um(self, lam):
        """Wavelengths [µm] to evaluate at: the model's own (lam None) or the requested ones."""
        if lam is None:
            return np.array([self.wavelength_nm * 1e-3])
        self._check_wavelengths(lam, "wavelengths")
        return np.asarray(lam, float) * 1e-3

    # -- shared geometry ------------------------------------------------------------------------

    def _sigma_ratio2(self, k_sum):
        """(σ_eff/σ0)² for K_i + K_r = ``k_sum``."""
        return 1.0 / (1.0 + effective_roughness(k_sum))

    def _g(self, ratio2, cos_sum, lam_um):
        """g = [(2π/λ) σ_eff (cosθi + cosθr)]²."""
        kk = 2.0 * np.pi / lam_um
        return (kk * self.sigma0) ** 2 * ratio2 * cos_sum * cos_sum

    def _pair(self, wi, wo):
        """Quantities of a direction pair shared by ρ_dd and the specular parts."""
        return _Pair(self, wi, wo)

    def _kernel(self, lam, n, part=None):
        """The compiled evaluation (:func:`_htsg_rows`): per-wavelength constants and the
        series' tables set up here, once. ``part`` "diffuse" or "specular": that part alone
        (:meth:`quadrature_parts`)."""
        lams = self._lams_um(lam)
        per_lam = np.empty((lams.size, 3))
        for j, lam_um in enumerate(lams):  # as in _g, _directional_diffuse
            kk = 2.0 * np.pi / lam_um
            per_lam[j] = ((kk * self.sigma0) ** 2, 0.25 * (self.tau * kk) ** 2,
                          np.pi ** 2 * self.tau ** 2 / (4.0 * lam_um ** 2))
        # the series' terms: the peak is below 3 max(g, 1) + 2√E + 2, past which the term ratio
        # is below 0.43, so a walk stops within 35 terms of it (g ≤ 4(kσ0)², E ≤ (τk)²)
        g_max, e_max = 4.0 * float(per_lam[:, 0].max()), 4.0 * float(per_lam[:, 1].max())
        tables = tuple(np.ascontiguousarray(t) for t in _tables(int(3.0 * max(g_max, 1.0) + 2.0 * np.sqrt(e_max))
                                                                 + 64 + SERIES_BATCH, parts=True))
        variant, extra, spline_x, spline_c = self._kernel_part()
        p = np.array([self.sigma0, self.tau, self.n, self.k, self.r_dh_lam / np.pi if self.r_dh_lam else 0.0,
                      *extra, NEWTON_TOL, SERIES_TOL, part != "specular", part != "diffuse"], float)

        run = _htsg_kernel()

        def evaluate(wi, wo, state, out, add):
            status = run(wi, wo, state, out, add, variant, p, per_lam, spline_x, spline_c, *tables)
            if status == 1:
                raise BrdftabError(f"the effective-roughness equation did not converge in {NEWTON_MAX_ITER} "
                                   "Newton steps")
            if status == 2:
                raise BrdftabError("the HTSG series ran past its tables")
        return evaluate

    def _kernel_part(self):
        """The specular part of :func:`_htsg_rows`: (variant, [cos w, dω_i, w_φ, w_θ], spline
        breakpoints, spline coefficients)."""
        raise NotImplementedError

    def _directional_diffuse(self, wi, wo, lam, n, pair=None):
        """ρ_dd [sr⁻¹], shape (M, n)."""
        p = self._pair(wi, wo) if pair is None else pair
        base = p.fresnel / np.pi * (p.vv / p.vz) ** 2 * p.shadow / (p.ci * p.co)
        out = np.empty((wi.shape[0], n))
        for j, lam_um in enumerate(self._lams_um(lam)):
            kk = 2.0 * np.pi / lam_um
            g = self._g(p.ratio2, p.vz, lam_um)
            e = 0.25 * (self.tau * kk) ** 2 * p.vxy2
            pref = np.pi ** 2 * self.tau ** 2 / (4.0 * lam_um ** 2)
            out[:, j] = base * pref * htsg_series(g, e)
        return out

    def _diffuse_parts(self, wi, wo, lam, n, pair=None):
        out = self._directional_diffuse(wi, wo, lam, n, pair)
        if self.r_dh_lam:
            out += self.r_dh_lam / np.pi
        return out


class _Pair:
    """cosθi, cosθo, v = ω̂i + ω̂o (|v|², v_z, |v_xy|²), cosθ_loc = |v|/2, S(θi)S(θo), (σ_eff/σ0)²
    and |F(θ_loc)|² of the pairs ``wi``, ``wo`` (M, 3) for model ``m``."""

    def __init__(self, m, wi, wo):
        self.ci, self.co = wi[:, 2], wo[:, 2]
        v = wi + wo
        self.vv = np.einsum("ij,ij->i", v, v)
        self.vz = v[:, 2]
        # |v_xy|² directly, not |v|² − v_z²: no cancellation near the mirror direction
        self.vxy2 = v[:, 0] * v[:, 0] + v[:, 1] * v[:, 1]
        self.cos_loc = 0.5 * np.sqrt(self.vv)
        self.shadow = smith_shadow(self.ci, m.sigma0, m.tau) * smith_shadow(self.co, m.sigma0, m.tau)
        self.ratio2 = m._sigma_ratio2(shadow_k(self.ci, m.sigma0, m.tau) + shadow_k(self.co, m.sigma0, m.tau))
        self.fresnel = _fresnel(self.cos_loc, m.n, m.k)

    def take(self, idx):
        out = object.__new__(_Pair)
        out.__dict__ = {k: v[idx] for k, v in self.__dict__.items()}
        return out


def _mirror(w):
    return w * np.array([-1.0, -1.0, 1.0])


def _unit_dirs(wi):
    wi = np.asarray(wi, float)
    norm = np.linalg.norm(wi, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return wi / norm


@register
class HeTorrance1991(_HTSGBase):
    """He–Torrance–Sillion–Greenberg 1991 (see the module docstring)."""

    name = "he-torrance-1991"
    summary = ("He–Torrance–Sillion–Greenberg physical-optics BRDF: specular (ideal delta, or Bitterling's cone), "
               "directional-diffuse and uniform-diffuse parts.")
    reference = "He1991; Bitterling2024; Smith1967; Beckmann1963"
    params = _common_params(550.0) + (
        Param("cone_half_width", "float", "Half-width w of Bitterling's specular cone (Eq. 17); without it the "
              "specular part is an ideal delta (a reflectance per incidence angle, stored beside tables).",
              units="rad", default=None, minimum=CONE_MIN, maximum=float(np.radians(30.0)), angle=True),
    )

    def _setup(self, n, k, sigma0, tau, wavelength_nm, r_dh_lam, cone_half_width):
        self._setup_common(n, k, sigma0, tau, wavelength_nm, r_dh_lam)
        self.cone_half_width = cone_half_width
        if cone_half_width is not None:
            self.cone_cos = float(np.cos(cone_half_width))
            self.cone_solid_angle = float(2.0 * np.pi * (1.0 - np.cos(cone_half_width)))
        # the delta variant is reciprocal; the cone's 1/cosθi is not
        self.reciprocal = cone_half_width is None

    @property
    def lobe_width(self):
        return None if self.cone_half_width is None else 0.5 * self.cone_half_width

    # -- the ideal specular part ----------------------------------------------------------------

    @property
    def specular_delta(self):
        """ρ_s(wi, wavelengths) → [..., C] for the delta variant; None with a cone."""
        return self._specular_reflectance if self.cone_half_width is None else None

    def specular_reflectance(self, theta_i, wavelengths=None):
        """ρ_s(θi) = |F(θi)|² e^{−g(θi, θi)} S(θi)² for incidence angles ``theta_i`` [rad] → [..., C]."""
        theta_i = np.asarray(theta_i, float)
        return self._specular_from_cos(np.cos(theta_i), wavelengths)

    def _specular_reflectance(self, wi, wavelengths=None):
        w = _unit_dirs(wi)
        return self._specular_from_cos(w[..., 2], wavelengths)

    def _specular_from_cos(self, ci, wavelengths):
        lam = self.layout.resolve(wavelengths)
        ci = np.asarray(ci, float)
        shape = ci.shape
        ci = ci.ravel()
        above = ci > 1e-12
        c = np.where(above, ci, 1.0)
        s = smith_shadow(c, self.sigma0, self.tau)
        ratio2 = self._sigma_ratio2(2.0 * shadow_k(c, self.sigma0, self.tau))
        base = _fresnel(c, self.n, self.k) * s * s
        lams = self._lams_um(lam)
        out = np.empty((ci.size, lams.size))
        for j, lam_um in enumerate(lams):
            out[:, j] = np.where(above, base * np.exp(-self._g(ratio2, 2.0 * c, lam_um)), 0.0)
        return out.reshape(shape + (lams.size,))

    # -- the cone variant -----------------------------------------------------------------------

    def _kernel_part(self):
        none = (np.zeros(2), np.zeros((4, 1)))
        if self.cone_half_width is None:
            return _DIFFUSE, (1.0, 1.0, 1.0, 1.0), *none
        return _CONE, (self.cone_cos, self.cone_solid_angle, 1.0, 1.0), *none

    def _cone(self, wi, wo, lam, n, pair=None):
        """Bitterling's Eq. 17 inside the cone of half-width w about the mirror direction."""
        out = np.zeros((wi.shape[0], n))
        inside = np.flatnonzero(np.einsum("ij,ij->i", _mirror(wi), wo) >= self.cone_cos)
        if inside.size == 0:
            return out
        p = self._pair(wi[inside], wo[inside]) if pair is None else pair.take(inside)
        base = p.fresnel * p.shadow / (p.ci * self.cone_solid_angle)
        for j, lam_um in enumerate(self._lams_um(lam)):
            out[inside, j] = base * np.exp(-self._g(p.ratio2, p.vz, lam_um))
        return out

    def _cone_rule(self, wi, nodes: int = 24, azimuths: int = 64):
        """Outgoing rule resolving the hard-edged cone: Gauss–Legendre in cosψ ∈ [cos w, 1] about the
        mirror direction × uniform azimuth; nodes below the horizon dropped."""
        wi = np.asarray(wi, float).reshape(3)
        r = _mirror(wi / np.linalg.norm(wi))
        mu, wmu = gauss_legendre(nodes, self.cone_cos, 1.0)
        chi = (np.arange(azimuths) + 0.5) * (2.0 * np.pi / azimuths)
        # an orthonormal frame about r
        t = np.cross(r, [0.0, 0.0, 1.0]) if abs(r[2]) < 0.999 else np.array([1.0, 0.0, 0.0])
        t = t / np.linalg.norm(t)
        b = np.cross(r, t)
        s = np.sqrt(np.maximum(1.0 - mu * mu, 0.0))
        wo = (mu[:, None, None] * r + s[:, None, None] * (np.cos(chi)[None, :, None] * t
                                                          + np.sin(chi)[None, :, None] * b)).reshape(-1, 3)
        w = np.repeat(wmu, azimuths) * (2.0 * np.pi / azimuths)
        keep = wo[:, 2] > 1e-12
        return wo[keep], w[keep]

    def quadrature_parts(self):
        """The specular cone and the rest, each integrated on its own rule (cone variant); None for
        the delta variant (one smooth part; its delta is :attr:`specular_delta`)."""
        if self.cone_half_width is None:
            return None
        return [_Part(self, self._cone, "specular cone", rule=self._cone_rule, reciprocal=False, part="specular"),
                _Part(self, self._diffuse_parts, "diffuse", part="diffuse")]

    def _eval(self, wi, wo, lam, n):
        pair = self._pair(wi, wo)
        out = self._diffuse_parts(wi, wo, lam, n, pair)
        if self.cone_half_width is not None:
            out += self._cone(wi, wo, lam, n, pair)
        return out


@register
class ModifiedHeTorrance(_HTSGBase):
    """Bitterling et al.'s modified He–Torrance model (§4, Eqs. 22–24; see the module docstring)."""

    name = "he-torrance-modified"
    summary = ("Bitterling et al.'s modified He–Torrance BRDF: Gaussian specular profile (widths w_θ, w_φ) without "
               "specular shadowing, plus the HTSG directional-diffuse and a uniform-diffuse part.")
    reference = "Bitterling2024; He1991; Smith1967; Beckmann1963"
    params = _common_params(550.0) + (
        Param("width_theta", "float", "Width w_θ of the Gaussian specular profile in θr (Eq. 22).", units="rad",
              minimum=float(np.radians(0.1)), maximum=float(np.radians(45.0)), angle=True),
        Param("width_phi", "float", "Width w_φ of the Gaussian specular profile in φr (Eq. 22).", units="rad",
              minimum=float(np.radians(0.1)), maximum=float(np.radians(45.0)), angle=True),
    )
    reciprocal = False

    def _setup(self, n, k, sigma0, tau, wavelength_nm, r_dh_lam, width_theta, width_phi):
        self._setup_common(n, k, sigma0, tau, wavelength_nm, r_dh_lam)
        self.width_theta, self.width_phi = width_theta, width_phi
        # ∫_{−π}^{π} exp(−Δφ²/(2w_φ)²) dΔφ = 2√π w_φ erf(π/(2w_φ))
        self._phi_integral = float(2.0 * _SQRT_PI * width_phi * erf(np.pi / (2.0 * width_phi)))
        self._spline = None

    @property
    def lobe_width(self):
        return 0.5 * min(self.width_theta, self.width_phi)

    # -- Eq. 22 and Eq. 23 ----------------------------------------------------------------------

    def profile(self, wi, wo):
        """Γ(wi, wo) of Eq. 22, Δφ = φr − φi − π wrapped into (−π, π]."""
        ti = np.arctan2(np.hypot(wi[..., 0], wi[..., 1]), wi[..., 2])
        to = np.arctan2(np.hypot(wo[..., 0], wo[..., 1]), wo[..., 2])
        dphi = np.arctan2(wo[..., 1], wo[..., 0]) - np.arctan2(wi[..., 1], wi[..., 0]) - np.pi
        dphi = np.pi - np.mod(np.pi - dphi, 2.0 * np.pi)      # into (−π, π]
        return (np.exp(-(dphi / (2.0 * self.width_phi)) ** 2)
                * np.exp(-((to - ti) / (2.0 * self.width_theta)) ** 2))

    def solid_angle(self, theta_i):
        """dω_i,g(θi) = ∫∫ Γ sinθr dθr dφr over the hemisphere (Eq. 23) [sr], per incidence angle.

        Γ separates: the φ integral is 2√π w_φ erf(π/(2w_φ)); the θ integral
        ∫₀^{π/2} exp(−(θr − θi)²/(2w_θ)²) sinθr dθr is summed by Gauss–Legendre on panels
        graded about θi (:func:`_theta_integral`) once, at uniformly spaced incidence angles
        (every min(w_θ/16, 0.05°) from 0 to 90°), and cached as a cubic spline in θi: against
        the closed form (a complex error function) it is exact to 1e-9 relative for w_θ from
        0.1° to 45° (tested).
        """
        if self._spline is None:
            step = min(self.width_theta / 16.0, np.radians(0.05))
            nodes = np.linspace(0.0, 0.5 * np.pi, int(np.ceil(0.5 * np.pi / step)) + 1)
            from scipy.interpolate import CubicSpline  # (on first use: scipy.interpolate takes 0.15 s to import)

            self._spline = CubicSpline(nodes, self._phi_integral * _theta_integral(nodes, self.width_theta))
        return self._spline(np.clip(np.asarray(theta_i, float), 0.0, 0.5 * np.pi))

    def _kernel_part(self):
        self.solid_angle(0.0)  # builds the spline
        return (_PROFILE, (1.0, 1.0, self.width_phi, self.width_theta), np.ascontiguousarray(self._spline.x),
                np.ascontiguousarray(self._spline.c))

    def _specular(self, wi, wo, lam, n, pair=None):
        """f_sp,mod = |F(θm)|² e^{−g} Γ / (cosθm dω_i,g(θi)) (Eq. 24), g at the local half-vector
        (from the actual pair, as in ρ_dd)."""
        p = self._pair(wi, wo) if pair is None else pair
        theta_i = np.arctan2(np.hypot(wi[:, 0], wi[:, 1]), wi[:, 2])
        # cosθm = |ω̂i + ω̂r|/2: θm = arccos(r·i)/2, the local angle of F as well
        base = p.fresnel * self.profile(wi, wo) / (p.cos_loc * self.solid_angle(theta_i))
        out = np.empty((wi.shape[0], n))
        for j, lam_um in enumerate(self._lams_um(lam)):
            out[:, j] = base * np.exp(-self._g(p.ratio2, p.vz, lam_um))
        return out

    def _profile_rule(self, wi, nodes: int = 8):
        """Outgoing rule resolving Γ: Gauss–Legendre panels in θr ∈ [0, π/2] graded about θi by w_θ
        and in Δφ ∈ (−π, π] graded about 0 by w_φ; weights sinθr dθr dφr."""
        wi = np.asarray(wi, float).reshape(3)
        ti = float(np.arctan2(np.hypot(wi[0], wi[1]), wi[2]))
        pi_ = float(np.arctan2(wi[1], wi[0]))
        th, wth = _graded_panels(ti, self.width_theta, 0.0, 0.5 * np.pi, nodes)
        ph, wph = _graded_panels(0.0, self.width_phi, -np.pi, np.pi, nodes)
        tt, pp = np.meshgrid(th, ph, indexing="ij")
        w = (wth * np.sin(th))[:, None] * wph[None, :]
        phi_o = pi_ + np.pi + pp
        st = np.sin(tt)
        wo = np.stack([st * np.cos(phi_o), st * np.sin(phi_o), np.cos(tt)], axis=-1).reshape(-1, 3)
        w = w.ravel()
        keep = wo[:, 2] > 1e-12
        return wo[keep], w[keep]

    def quadrature_parts(self):
        return [_Part(self, self._specular, "specular profile", rule=self._profile_rule, reciprocal=False,
                      part="specular"),
                _Part(self, self._diffuse_parts, "diffuse", part="diffuse")]

    def _eval(self, wi, wo, lam, n):
        pair = self._pair(wi, wo)
        return self._diffuse_parts(wi, wo, lam, n, pair) + self._specular(wi, wo, lam, n, pair)


def _graded_panels(centre, width, lo, hi, nodes):
    """Gauss–Legendre nodes/weights on [lo, hi] with panel edges at centre ± width·2^j (j ≥ −2)."""
    steps = width * 2.0 ** np.arange(-2, 12)
    edges = np.concatenate([[lo, hi, centre], centre + steps, centre - steps])
    edges = np.unique(edges[(edges >= lo) & (edges <= hi)])
    x, wx = gauss_legendre(nodes, 0.0, 1.0)
    a, b = edges[:-1, None], edges[1:, None]
    return (a + (b - a) * x).ravel(), ((b - a) * wx).ravel()


def _theta_integral(theta_i, width, nodes: int = 16, block: int = 4096):
    """∫₀^{π/2} exp(−(θ − θi)²/(2w)²) sinθ dθ for each θi, vectorized: Gauss–Legendre (``nodes`` per
    panel) on panels with edges θi ± w·2^j (j ≥ −2) clipped to [0, π/2] (clipped panels have zero
    width and weight)."""
    theta_i = np.ravel(np.asarray(theta_i, float))
    steps = width * 2.0 ** np.arange(-2, 40)
    steps = steps[: int(np.searchsorted(steps, 0.5 * np.pi)) + 1]
    rel = np.concatenate([-steps[::-1], [0.0], steps])
    x, wx = gauss_legendre(nodes, 0.0, 1.0)
    out = np.empty(theta_i.size)
    for s in range(0, theta_i.size, block):
        t = theta_i[s:s + block, None]
        edges = np.clip(t + rel[None, :], 0.0, 0.5 * np.pi)                 # increasing: clip keeps order
        a, b = edges[:, :-1, None], edges[:, 1:, None]
        th = a + (b - a) * x
        w = (b - a) * wx
        out[s:s + block] = np.einsum("upn,upn->u", w, np.sin(th) * np.exp(-((th - t[..., None]) / (2.0 * width)) ** 2))
    return out
