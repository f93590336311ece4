"""Albedo integrals of any BRDF: directional-hemispherical and bihemispherical reflectance.

* :func:`directional_albedo` — a(wi) = ∫ f(wi, wo) cosθo dωo (+ the coefficient of an ideal
  specular component, when the BRDF carries one), per channel;
* :func:`albedo_curve` — a(θi, φi) on a sweep of incidence angles, with the covered fraction
  of each integral and the white-sky albedo;
* :func:`white_sky_albedo` — the bihemispherical (white-sky) albedo
  (1/π) ∫ a(wi) cosθi dωi from a curve a(θi).

Quadrature
----------
The outgoing hemisphere is integrated in half-vector space, dωo = 4 (wo·h) dωh (B. Walter et
al., EGSR 2007, Eq. 14), with h in polar coordinates (θh, ψ = φh − φi) about the normal. For
each ψ the mirrored wo stays above the horizon while θh < θh_max(ψ) =
(π/2 + atan2(sinθi cosψ, cosθi)) / 2; that bound is a panel end, so the horizon cut is exact
and diffuse integrands, smooth in h, converge fast (a Lambertian to ~1e-11). In θh the
Gauss–Legendre panels are graded geometrically, from a lobe's width / 8 by a factor of 2 up
to θh_max: a microfacet-type lobe is centred on h = n whatever θi, so it is covered by panels
no larger than itself at every distance from its centre — the hp-refinement of a point
singularity (C. Schwab, *p- and hp-Finite Element Methods*, Oxford (1998), §4.5). In ψ there
are four equal panels, with edges at ψ = ±π/2 where θh_max turns over at grazing incidence.
Against converged references for GGX and Beckmann lobes of α = 0.002 … 0.5 the error is
≤ 1e-5 for θi ≤ 60°, ≤ 1.1e-4 up to 85° and ≤ 9e-4 at 89°, with 700–1600 nodes per
incidence direction (6 nodes per panel).

An anisotropic lobe (a BRDF declaring ``lobe_axes = (a_x, a_y)``, e.g. a microfacet with α_x ≠
α_y, or a table or file that is not isotropic, whose axes are measured by :func:`probe_axes`)
is long and thin in half-vector azimuth: the azimuth panels are then graded geometrically
towards the lobe's long axis, from (a_min/a_max)/8 by a factor of 2, the same hp-refinement
as in θh (GGX α = 0.716 × 3e-5 and 0.05 × 0.5 agree with Monte Carlo references to their
error bars; a Lambertian declaring such axes still integrates to 1e-9).

The lobe width is measured (:func:`lobe_width`): the half vector is tilted away from the
normal towards four azimuths at 33 geometric offsets (1e-4 … 1 rad); the width is the
smallest offset at which the integrand falls below a tenth of its value at the mirror
direction (1 rad when it never does: a broad or diffuse BRDF). A width the BRDF declares
(``lobe_width``, e.g. a microfacet α) is used when it is smaller. Narrow features away from the
mirror direction are not searched for; pass ``lobe_width`` for them.

Ideal specular components are not sampled: a BRDF may expose
``specular_delta(wi, wavelengths) -> [..., C]``, the fraction of the incident flux sent into
the mirror direction, which is added to a(wi).

Lobe hints
----------
A BRDF whose lobes are not centred on the mirror direction of the surface tells the quadrature
where they are; the albedo is linear in f, so parts are integrated separately and added:

* ``quadrature_parts()`` → BRDFs whose sum is the BRDF (a ``sum``'s terms, a seed model's
  terms); each part is integrated on a rule that follows its own lobe (recursively). The parts
  carry everything, including their own ``specular_delta``;
* ``lobe_frame(wi)`` → a 3×3 rotation R: the part's lobe is a microfacet-type lobe about the
  normal of the rotated frame u = R w (the ``rotated`` combinator, a peak on a tilted facet
  population). The half-vector rule above is built in that frame (θi′, φi′ of R wi) and mapped
  back; nodes below the macro horizon are dropped (f = 0 there);
* ``albedo_rule(wi, wavelengths=None)`` → (wo[N, 3], w[N] in sr): an outgoing rule the part
  builds on its own features (a diffraction band's fringes, a gonio table's own cells), used
  instead of the generic one; with several wavelengths it is built and used once per
  wavelength. Its coverage is the fraction of its nodes with data, or — for a BRDF declaring
  ``rule_coverage = "hemisphere"`` (tables: the rule covers their domain) — the projected
  solid angle of the nodes with data over π.

Missing samples
---------------
A table evaluates to NaN where its samples are missing. Those quadrature nodes are left out
of the integral (they contribute nothing), and the *coverage* — the fraction ∫_valid cosθo dωo
/ π of the projected solid angle that had data — is returned alongside, so an integral over a
partly measured table is a lower bound whose completeness is known.

References: P. J. Davis, P. Rabinowitz, *Methods of Numerical Integration*, 2nd ed. (1984),
§2.7 (Gauss–Legendre), §5.6 (product rules); F. E. Nicodemus et al., NBS Monograph 160
(1977), §6 (directional-hemispherical and bihemispherical reflectance).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline

from .geometry import rot_z, sph_to_vec
from .quadrature import gauss_legendre

__all__ = ["AlbedoCurve", "albedo_curve", "directional_albedo", "lobe_width", "lobe_widths", "outgoing_rule",
           "white_sky_albedo", "DEFAULT_NODES", "DEFAULT_RATIO"]

HALF_PI = 0.5 * np.pi
#: Gauss–Legendre nodes per cell side.
DEFAULT_NODES = 6
#: Ratio of successive box half-widths of the geometric mesh.
DEFAULT_RATIO = 2.0
#: Equal panels in the half-vector azimuth.
PHI_PANELS = 4
#: Lobes whose axis widths differ by more than this factor get azimuth panels graded towards
#: their long axis.
ANISOTROPY = 1.5
#: Offsets [rad] at which the lobe width is probed.
PROBE_OFFSETS = np.geomspace(1e-4, 1.0, 33)
MIN_WIDTH = 1e-4
MAX_WIDTH = 1.0
#: Directions with z at or below this are not probed or integrated (the BRDF is 0 there).
_Z_MIN = 1e-12


# --------------------------------------------------------------------------------------------
# Lobe width


def _theta_h_max(theta_i, psi):
    """Largest θh at relative half-vector azimuth ψ = φh − φi whose mirrored wo is above the horizon.

    wo_z = 2 (wi·h) h_z − cosθi = sinθi cosψ sin2θh + cosθi cos2θh > 0 ⇔
    θh < (π/2 + atan2(sinθi cosψ, cosθi)) / 2.
    """
    return 0.5 * (HALF_PI + np.arctan2(np.sin(theta_i) * np.cos(psi), np.cos(theta_i)))


def _half_vectors(theta_i, psi, theta_h):
    """Half vectors at (θh, φh = φi + ψ) in the frame where φi = 0, and the mirrored wo."""
    h = sph_to_vec(theta_h, psi)
    wi = sph_to_vec(theta_i, 0.0)
    c = h @ wi
    return h, 2.0 * c[..., None] * h - wi, c


def lobe_width(brdf, theta_i: float, phi_i: float = 0.0, wavelengths=None) -> float:
    """Angular width [rad] of the BRDF's lobe about the mirror direction, in half-vector space.

    The half vector h is tilted from the normal by offsets δ (1e-4 … 1 rad) towards four
    azimuths (φi, φi ± π/2, φi + π); the width is the smallest δ at which the integrand
    f(wi, wo(h)) cosθo (wi·h) falls below a tenth of its value at h = n (wo the mirror
    direction), clipped to [1e-4, 1] (1 when it never does: a broad or diffuse BRDF). When the
    BRDF declares a ``lobe_width`` (a number, e.g. a microfacet α, or a method of wi) the
    smaller of the two is used.
    """
    return float(lobe_widths(brdf, np.atleast_1d(theta_i), np.atleast_1d(phi_i), wavelengths)[0])


def lobe_widths(brdf, theta_i, phi_i, wavelengths=None) -> np.ndarray:
    """:func:`lobe_width` for arrays of incidence angles (one evaluation of the BRDF)."""
    theta_i = np.asarray(theta_i, float).ravel()
    phi_i = np.asarray(phi_i, float).ravel()
    m = theta_i.size
    n = PROBE_OFFSETS.size
    psi = np.concatenate([[0.0], np.repeat(np.arange(4) * HALF_PI, n)])
    th = np.concatenate([[0.0], np.tile(PROBE_OFFSETS, 4)])
    k = psi.size
    wo = np.empty((m, k, 3))
    c = np.empty((m, k))
    for j in range(m):
        _, w, cc = _half_vectors(theta_i[j], psi, th)
        wo[j] = rot_z(w, phi_i[j])
        c[j] = cc
    wi = sph_to_vec(theta_i, phi_i)
    f = brdf.eval(np.broadcast_to(wi[:, None, :], wo.shape).reshape(-1, 3), wo.reshape(-1, 3), wavelengths)
    f = f.reshape(m, k, -1)
    g = np.nansum(np.where(np.isfinite(f), f, np.nan), axis=-1) * wo[..., 2] * c
    above = wo[..., 2] > _Z_MIN
    out = np.full(m, MAX_WIDTH)
    for j in range(m):
        g0 = g[j, 0]
        if not (np.isfinite(g0) and g0 > 0):
            continue
        for d in range(4):
            gk = g[j, 1 + d * n: 1 + (d + 1) * n]
            ok = above[j, 1 + d * n: 1 + (d + 1) * n]
            # stop at the horizon: beyond it the BRDF is 0 by definition, not by its shape
            stop = int(np.argmin(ok)) if not ok.all() else n
            low = np.flatnonzero(gk[:stop] < 0.1 * g0)
            if low.size:
                out[j] = min(out[j], PROBE_OFFSETS[low[0]])
    hint = getattr(brdf, "lobe_width", None)
    if callable(hint):
        hint = np.array([hint(w) for w in wi], float)
    if hint is not None:
        out = np.minimum(out, hint)
    return np.clip(out, MIN_WIDTH, MAX_WIDTH)


# --------------------------------------------------------------------------------------------
# The quadrature rule


def _gl_panels(edges, nodes):
    """Gauss–Legendre nodes and weights on consecutive panels; ``edges[..., P + 1]``."""
    x, wx = gauss_legendre(nodes, 0.0, 1.0)
    lo, hi = edges[..., :-1, None], edges[..., 1:, None]
    pts = lo + (hi - lo) * x
    wts = (hi - lo) * wx
    return pts.reshape(edges.shape[:-1] + (-1,)), wts.reshape(edges.shape[:-1] + (-1,))


def _phi_edges(panels):
    """Panel edges of ψ = φh − φi over [−π, π]: ``panels`` equal panels (with 4, edges at
    ψ = ±π/2, where the horizon cut θh_max(ψ) turns over at grazing incidence)."""
    return np.linspace(-np.pi, np.pi, panels + 1)


def _aniso_phi_edges(phi_i, ax, ay, long_axis=None):
    """Panel edges of ψ = φh − φi for an elliptical lobe with widths ``ax``, ``ay`` along the
    surface's x and y axes (or along its own axes, the long one at azimuth ``long_axis``):
    equal panels, the horizon turns ψ = ±π/2, and edges graded geometrically towards the lobe's
    long axis (both directions), from (a_min/a_max)/8 by a factor of 2 — at radius r the lobe's
    azimuthal width is ~ a_min / r."""
    if long_axis is None:
        long_axis = 0.0 if ax >= ay else HALF_PI      # azimuth of the long axis (absolute)
    ladder = (min(ax, ay) / max(ax, ay)) / 8.0 * 2.0 ** np.arange(40)
    ladder = ladder[ladder < HALF_PI]
    edges = [_phi_edges(PHI_PANELS * 4), [-HALF_PI, HALF_PI]]
    for centre in (long_axis - phi_i, long_axis + np.pi - phi_i):
        edges += [centre + ladder, centre - ladder, [centre]]
    e = np.concatenate(edges)
    e = np.mod(e + np.pi, 2 * np.pi) - np.pi                # into [−π, π)
    return np.unique(np.concatenate([e, [-np.pi, np.pi]]))


def outgoing_rule(theta_i: float, phi_i: float = 0.0, width: float = MAX_WIDTH, *, nodes: int = DEFAULT_NODES,
                  ratio: float = DEFAULT_RATIO, axes=None):
    """Quadrature over the outgoing hemisphere, in half-vector space about the normal.

    ``width`` [rad] is the lobe's width in half-vector space (see :func:`lobe_width`).
    Returns ``wo[N, 3]`` and weights ``w[N]`` [sr] such that Σ w g(wo) ≈ ∫ g dωo over the
    upper hemisphere. The half vector h = (θh, φh) is integrated with Gauss–Legendre panels:
    in θh graded from width/8 by ``ratio`` up to the horizon cut θh_max(φh) (where the mirrored
    wo reaches the horizon, a panel edge), in φh :data:`PHI_PANELS` equal panels.
    dωo = 4 (wo·h) dωh.

    ``axes = (a_x, a_y)``, the widths of an anisotropic lobe along the surface's x and y axes
    (e.g. a microfacet's α_x, α_y), or ``(a_long, a_short, azimuth of the long axis)``: the
    half-vector azimuth panels are then graded geometrically towards the lobe's long axis (see
    :func:`_aniso_phi_edges`), where the elliptical lobe is long and thin (at radius r its
    azimuthal width is ~ a_min / r).
    """
    theta_i = float(theta_i)
    w0 = float(np.clip(width, MIN_WIDTH, MAX_WIDTH)) / 8.0
    ladder = w0 * ratio ** np.arange(int(np.ceil(np.log(HALF_PI / w0) / np.log(ratio))) + 1)
    ladder = ladder[ladder < HALF_PI]
    if axes is not None and max(axes[:2]) > ANISOTROPY * min(axes[:2]):
        psi, wpsi = _gl_panels(_aniso_phi_edges(float(phi_i), *(float(a) for a in axes)), nodes)
    else:
        psi, wpsi = _gl_panels(_phi_edges(PHI_PANELS), nodes)            # [Np]
    tmax = _theta_h_max(theta_i, psi)                                     # [Np]
    edges = np.concatenate([np.zeros((psi.size, 1)), np.minimum(ladder[None, :], tmax[:, None]), tmax[:, None]],
                           axis=1)                                        # [Np, P + 1]
    th, wth = _gl_panels(edges, nodes)                                    # [Np, P * nodes]
    keep = wth > 0                                                        # empty panels past θh_max
    psi_b = np.broadcast_to(psi[:, None], th.shape)[keep]
    h, wo, c = _half_vectors(theta_i, psi_b, th[keep])
    w = (wth * np.sin(th) * wpsi[:, None])[keep] * 4.0 * c
    return rot_z(wo, float(phi_i)), w


# --------------------------------------------------------------------------------------------
# Directional and bihemispherical albedo


#: Quadrature nodes evaluated per call of the BRDF.
BATCH = 1 << 18


def _leaves(brdf) -> list:
    """The parts of ``brdf`` to integrate separately (``quadrature_parts``, recursively)."""
    fn = getattr(brdf, "quadrature_parts", None)
    parts = fn() if callable(fn) else None
    if not parts:
        return [brdf]
    out = []
    for p in parts:
        out.extend(_leaves(p))
    return out


def _integrate(brdf, theta_i, phi_i, wavelengths, width, nodes, ratio):
    """(a[M, C], coverage[M, C], widths[M]) for incidence angles ``theta_i[M]``, ``phi_i[M]``,
    part by part (see *Lobe hints* in the module docstring)."""
    leaves = _leaves(brdf)
    if len(leaves) == 1 and not _hinted(leaves[0]):
        return _integrate_plain(leaves[0], theta_i, phi_i, wavelengths, width, nodes, ratio)
    total = cover = wmin = None
    for leaf in leaves:
        if callable(getattr(leaf, "albedo_rule", None)):
            a, c, w = _integrate_rule(leaf, theta_i, phi_i, wavelengths)
        elif callable(getattr(leaf, "lobe_frame", None)):
            a, c, w = _integrate_framed(leaf, theta_i, phi_i, wavelengths, width, nodes, ratio)
        else:
            a, c, w = _integrate_plain(leaf, theta_i, phi_i, wavelengths, width, nodes, ratio)
        total = a if total is None else total + a
        cover = c if cover is None else np.minimum(cover, c)
        wmin = w if wmin is None else np.minimum(wmin, w)
    return total, cover, wmin


def _integrand(brdf, wi, wo, wavelengths):
    """f at the quadrature nodes — for a BRDF that evaluates f·cosθo itself (``eval_cos``: an
    RGL ``.bsdf`` file, read as Mitsuba reads it) that value over cosθo, so the albedo is the
    integral of what a renderer integrates (the file's own, not of f held near the horizon)."""
    fn = getattr(brdf, "eval_cos", None)
    if callable(fn):
        return np.asarray(fn(wi, wo, wavelengths), float) / wo[:, 2:3]
    return brdf.eval(wi, wo, wavelengths)


def _hinted(b) -> bool:
    return callable(getattr(b, "albedo_rule", None)) or callable(getattr(b, "lobe_frame", None))


def _accumulate(f, proj):
    """(Σ f w, coverage) of one rule: missing samples (NaN) are left out and counted."""
    valid = ~np.isnan(f)
    a = np.einsum("nc,n->c", np.where(valid, f, 0.0), proj)
    tot = float(proj.sum())
    bad = np.einsum("nc,n->c", (~valid).astype(float), proj)
    return a, (1.0 - bad / tot) if tot > 0 else np.ones_like(a)


def _delta(brdf, wi, wavelengths):
    fn = getattr(brdf, "specular_delta", None)
    if not callable(fn):
        return 0.0
    return np.asarray(fn(wi, wavelengths), float).reshape(-1)


def _integrate_rule(brdf, theta_i, phi_i, wavelengths):
    """A part that builds its own outgoing rule (``albedo_rule``)."""
    import inspect

    rule = brdf.albedo_rule
    takes_lam = "wavelengths" in inspect.signature(rule).parameters
    hemisphere = getattr(brdf, "rule_coverage", "rule") == "hemisphere"
    lams = [None] if wavelengths is None or np.ndim(wavelengths) == 0 or len(wavelengths) <= 1 or not takes_lam \
        else [[float(x)] for x in np.atleast_1d(wavelengths)]
    m = theta_i.size
    wi = sph_to_vec(theta_i, phi_i)
    a = c = None
    for j in range(m):
        cols_a, cols_c = [], []
        for lam in lams:
            use = wavelengths if lam is None else lam
            wo, w = rule(wi[j], wavelengths=use) if takes_lam else rule(wi[j])
            keep = wo[:, 2] > _Z_MIN
            wo, proj = wo[keep], w[keep] * wo[keep, 2]
            f = _integrand(brdf, np.broadcast_to(wi[j], wo.shape), wo, use)
            aj, cj = _accumulate(f, proj)
            if hemisphere:  # the rule covers the BRDF's domain: coverage of the hemisphere
                valid = ~np.isnan(f)
                cj = np.minimum(np.einsum("nc,n->c", valid.astype(float), proj) / np.pi, 1.0)
            cols_a.append(aj)
            cols_c.append(cj)
        aj, cj = np.concatenate(cols_a), np.concatenate(cols_c)
        if a is None:
            a, c = np.zeros((m, aj.size)), np.zeros((m, aj.size))
        a[j] = aj + _delta(brdf, wi[j], wavelengths)
        c[j] = cj
    return a, c, np.full(m, MIN_WIDTH)


class _Framed:
    """A part seen in its lobe's frame (u = R w): what the generic rule integrates."""

    def __init__(self, brdf, R):
        self.brdf, self.R = brdf, R
        self.lobe_width = getattr(brdf, "lobe_width", None)
        self.lobe_axes = getattr(brdf, "lobe_axes", None)

    def eval(self, ui, uo, wavelengths=None):
        return self.brdf.eval(np.asarray(ui) @ self.R, np.asarray(uo) @ self.R, wavelengths)


def _integrate_framed(brdf, theta_i, phi_i, wavelengths, width, nodes, ratio):
    """A part whose lobe lives about a tilted normal (``lobe_frame``)."""
    from .geometry import vec_to_sph

    m = theta_i.size
    wi = sph_to_vec(theta_i, phi_i)
    a = c = None
    widths = np.full(m, MAX_WIDTH)
    for j in range(m):
        R = np.asarray(brdf.lobe_frame(wi[j]), float)
        ui = R @ wi[j]
        f = None
        if ui[2] > _Z_MIN:
            view = _Framed(brdf, R)
            ti, pj = vec_to_sph(ui)
            wj = float(lobe_widths(view, [ti], [pj], wavelengths)[0]) if width is None else float(width)
            widths[j] = wj
            uo, w = outgoing_rule(float(ti), float(pj), wj, nodes=nodes, ratio=ratio, axes=view.lobe_axes)
            wo = uo @ R
            keep = wo[:, 2] > _Z_MIN
            wo, proj = wo[keep], w[keep] * wo[keep, 2]
            f = _integrand(brdf, np.broadcast_to(wi[j], wo.shape), wo, wavelengths)
            aj, cj = _accumulate(f, proj)
        if a is None:
            probe = brdf.eval(wi[j:j + 1], wi[j:j + 1], wavelengths) if f is None else f
            a, c = np.zeros((m, probe.shape[-1])), np.ones((m, probe.shape[-1]))
        if f is not None:
            a[j], c[j] = aj, cj
        a[j] = a[j] + _delta(brdf, wi[j], wavelengths)
    return a, c, widths


#: Azimuths at which the lobe of an anisotropic BRDF without declared axes is probed.
AXIS_PROBES = 32


def probe_axes(brdf, wavelengths=None):
    """``(a_long, a_short, azimuth of the long axis)`` of an anisotropic BRDF's lobe about the
    normal, measured at normal incidence (half vector tilted from the normal towards
    :data:`AXIS_PROBES` azimuths at the probe offsets of :func:`lobe_width`; the width along
    an azimuth is the offset where the integrand falls below a tenth of its peak), or None when
    the widths differ by less than :data:`ANISOTROPY` (or nothing was measured). Used for tables
    and files, which declare no ``lobe_axes``."""
    n = PROBE_OFFSETS.size
    psi = np.arange(AXIS_PROBES) * (np.pi / AXIS_PROBES)       # an axis and its opposite are one
    th = np.concatenate([[0.0], np.tile(PROBE_OFFSETS, AXIS_PROBES)])
    ps = np.concatenate([[0.0], np.repeat(psi, n)])
    h = sph_to_vec(th, ps)
    wi = np.array([0.0, 0.0, 1.0])
    wo = 2.0 * h[:, 2:3] * h - wi
    with np.errstate(all="ignore"):
        f = np.asarray(brdf.eval(np.broadcast_to(wi, wo.shape), wo, wavelengths), float)
    g = np.nansum(np.where(np.isfinite(f), f, 0.0), axis=-1) * wo[:, 2] * h[:, 2]
    g0 = g[0]
    if not (np.isfinite(g0) and g0 > 0):
        return None
    widths = np.full(AXIS_PROBES, MAX_WIDTH)
    for k in range(AXIS_PROBES):
        gk = g[1 + k * n: 1 + (k + 1) * n]
        low = np.flatnonzero(gk < 0.1 * g0)
        if low.size:
            widths[k] = PROBE_OFFSETS[low[0]]
    wmax, wmin = float(widths.max()), float(widths.min())
    if wmax <= ANISOTROPY * wmin:
        return None
    return wmax, wmin, float(psi[int(np.argmax(widths))])


def _integrate_plain(brdf, theta_i, phi_i, wavelengths, width, nodes, ratio):
    """(a[M, C], coverage[M, C], widths[M]) for incidence angles ``theta_i[M]``, ``phi_i[M]``."""
    m = theta_i.size
    widths = (lobe_widths(brdf, theta_i, phi_i, wavelengths) if width is None
              else np.broadcast_to(np.asarray(width, float), (m,)).copy())
    wi = sph_to_vec(theta_i, phi_i)
    axes = getattr(brdf, "lobe_axes", None)
    if axes is None and not getattr(brdf, "isotropic", True):
        axes = probe_axes(brdf, wavelengths)      # a table or file: measure its lobe's axes
    a = c = None
    start = 0
    while start < m:
        rules, count = [], 0
        stop = start
        batch = getattr(brdf, "eval_batch", None) or BATCH
        while stop < m and (count < batch or stop == start):
            wo, w = outgoing_rule(theta_i[stop], phi_i[stop], widths[stop], nodes=nodes, ratio=ratio, axes=axes)
            keep = wo[:, 2] > _Z_MIN
            rules.append((wo[keep], w[keep] * wo[keep, 2]))
            count += int(keep.sum())
            stop += 1
        seg = np.repeat(np.arange(start, stop), [r[0].shape[0] for r in rules])
        wo = np.concatenate([r[0] for r in rules])
        proj = np.concatenate([r[1] for r in rules])
        f = _integrand(brdf, wi[seg], wo, wavelengths)
        if a is None:
            a = np.zeros((m, f.shape[-1]))
            c = np.zeros((m, f.shape[-1]))
        valid = ~np.isnan(f)
        for ch in range(f.shape[-1]):
            a[:, ch] += np.bincount(seg, np.where(valid[:, ch], f[:, ch], 0.0) * proj, minlength=m)
            c[:, ch] += np.bincount(seg, valid[:, ch] * proj, minlength=m)
        start = stop
    fn = getattr(brdf, "specular_delta", None)
    if callable(fn):
        a = a + np.asarray(fn(wi, wavelengths), float).reshape(a.shape)
    return a, np.minimum(c / np.pi, 1.0), widths


def directional_albedo(brdf, theta_i, phi_i=0.0, wavelengths=None, *, lobe_width=None, nodes: int = DEFAULT_NODES,
                       ratio: float = DEFAULT_RATIO, coverage: bool = False):
    """Directional-hemispherical reflectance a(θi, φi) = ∫ f cosθo dωo (+ specular delta).

    ``theta_i``, ``phi_i`` [rad] broadcast against each other; returns ``[..., n_channels]``
    (and the coverage of the same shape when ``coverage`` is true). ``lobe_width`` [rad]
    overrides the measured width of the lobe about the mirror direction.
    """
    ti, pi_ = np.broadcast_arrays(np.asarray(theta_i, float), np.asarray(phi_i, float))
    a, c, _ = _integrate(brdf, ti.ravel(), pi_.ravel(), wavelengths, lobe_width, nodes, ratio)
    shape = ti.shape + (-1,)
    if coverage:
        return a.reshape(shape), c.reshape(shape)
    return a.reshape(shape)


def white_sky_albedo(theta_i, values, n: int = 64) -> np.ndarray:
    """Bihemispherical albedo 2 ∫₀^{π/2} a(θi) cosθi sinθi dθi from a curve ``values[n_θ, C]``.

    The curve is interpolated by a natural cubic spline in θi (extrapolated beyond its ends,
    e.g. to 90°) and integrated with ``n`` Gauss–Legendre nodes in μ = cosθi.
    """
    theta_i = np.asarray(theta_i, float)
    values = np.asarray(values, float)
    mu, wmu = gauss_legendre(n, 0.0, 1.0)
    if theta_i.size == 1:
        return values.reshape(1, -1)[0].copy()
    if not np.all(np.isfinite(values)):  # a curve with NaN/inf has no white-sky albedo
        return np.full(values.reshape(theta_i.size, -1).shape[1], np.nan)
    spline = CubicSpline(theta_i, values, axis=0, bc_type="natural", extrapolate=True)
    a = spline(np.arccos(mu))
    return 2.0 * np.einsum("nc,n->c", a.reshape(mu.size, -1), mu * wmu)


@dataclass
class AlbedoCurve:
    """a(θi, φi) on a sweep: ``values`` and ``coverage`` ``[n_θ, n_φ, C]``; ``white_sky[C]``."""

    theta_i: np.ndarray
    phi_i: np.ndarray
    values: np.ndarray
    coverage: np.ndarray
    white_sky: np.ndarray
    widths: np.ndarray

    @property
    def max(self) -> float:
        return float(np.nanmax(self.values)) if self.values.size else float("nan")

    def argmax(self):
        """(θi, φi, channel index) of the largest albedo (the first of equal ones, to rounding)."""
        top = np.nanmax(self.values)
        with np.errstate(invalid="ignore"):  # top = inf: inf − inf
            near = self.values >= top - 1e-12 * abs(top) if np.isfinite(top) else self.values == top
        first = int(np.argmax(near))
        i, j, c = np.unravel_index(first, self.values.shape)
        return float(self.theta_i[i]), float(self.phi_i[j]), int(c)


def albedo_curve(brdf, theta_i, phi_i=(0.0,), wavelengths=None, *, lobe_width=None, nodes: int = DEFAULT_NODES,
                 ratio: float = DEFAULT_RATIO) -> AlbedoCurve:
    """a(θi, φi) for every θi in ``theta_i`` and φi in ``phi_i`` [rad], with coverage and the
    white-sky albedo (averaged over the φi, which should then be uniform over the circle)."""
    theta_i = np.atleast_1d(np.asarray(theta_i, float))
    phi_i = np.atleast_1d(np.asarray(phi_i, float))
    tt, pp = np.meshgrid(theta_i, phi_i, indexing="ij")
    vals, covs, widths = _integrate(brdf, tt.ravel(), pp.ravel(), wavelengths, lobe_width, nodes, ratio)
    shape = (theta_i.size, phi_i.size, -1)
    vals = vals.reshape(shape)
    covs = covs.reshape(shape)
    ws = white_sky_albedo(theta_i, vals.mean(axis=1))
    return AlbedoCurve(theta_i, phi_i, vals, covs, ws, widths.reshape(theta_i.size, phi_i.size))
