"""Writing RGL ``.bsdf`` files: any BRDF sampled into the fields of Mitsuba 3's ``measured``
plugin (:func:`prepare_rgl`, :func:`write_rgl`).

Steps (formats/rgl-bsdf.md, "How brdftab writes a file"): the ``ndf`` table is the model's own
D or one from its back-scattering (:mod:`._rgl_ndf`), raised where another term dominates the
back-scattering and floored at :data:`NDF_FLOOR`; ``sigma`` is its projected area (for a D
from the back-scattering, blended between the θi nodes as the readers blend the slices:
:func:`_sigma_between_incidences`); the ``vndf`` field, the warp that places the N × N
samples, mixes row by row the visible normals of D with an even spread over the half vectors
whose ωo is above the horizon (share :data:`WARP_UNIFORM`; for a D from the back-scattering
either :func:`_broad_spread`, and in isotropic files :func:`_level_warp` up to
:data:`LEVEL_MAX_THETA_I`, with one more θi slice: :func:`_level_incidences`, or the lobe
warp of :func:`_vndf_table`, whichever reproduces the source better: option ``warp``,
:func:`_closest`); the stored values are f(ωi, ωo)·cosθo·4σ̂/D̂ at the warped nodes, with
σ̂, D̂ the interpolants the readers evaluate, so that every reader returns f·cosθo exactly at
the nodes, or (option ``values``; for a D from the back-scattering where those node samples
miss: :data:`FIT_WHEN_SCORE`) values solved by least squares against the source between the
nodes too (:mod:`._rgl_fit`); a D from the back-scattering also gets more θi nodes and samples
and a finer ``ndf`` table by default, per warp (:data:`._rgl_options.BACKSCATTER_DEFAULTS`);
``luminance`` is the luminance of f·cosθo per unit area of the unit square, so that Mitsuba
samples ωo in proportion to f·cosθo.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
from dataclasses import dataclass

import numpy as np

from .._version import __version__
from ..brdf import BRDF
from ..channels import luminance_weights as _luminance_weights
from ..errors import BrdftabError, ParameterError
from ._marginal2d import Marginal2D
from ._rgl_ndf import backscatter_bound, backscatter_ndf, model_ndf, sigma_table
from ._rgl_fit import FIT_MAX_QUERIES, FIT_QUERIES_PER_VALUE, fit_values
from ._rgl_options import backscatter_defaults, check_options
from ._rgl_read import RGB, RGLBSDF
from ._rgl_warp import bilinear, node_geometry, phi2u, sph, theta2u, u2phi, u2theta
from ._tensor import write_tensor_file

__all__ = ["NDF_FLOOR", "WARP_UNIFORM", "RGLPayload", "prepare_rgl", "write_rgl"]

#: D is floored at this fraction of its maximum: f·cosθo > 0 needs D > 0 (the stored values
#: are f·cosθo·4σ/D), and Beckmann-type D underflow to 0 far from the normal.
NDF_FLOOR = 1e-6
#: Share ε of the warp (the ``vndf`` field), in every row and in the marginal over the rows,
#: spread evenly over the half vectors whose ωo is above the horizon; the rest follows the
#: visible normals. The VNDF alone leaves the tails of D, hence grazing ωo, with a few wide
#: cells of the N × N samples.
WARP_UNIFORM = 0.5
#: Of that even share, the part even in the unit square (:data:`WARP_SQUARE`), the part in
#: equal steps of cosθo along each row (:data:`WARP_COS`: f·cosθo of a diffuse surface is then
#: linear in the sample coordinate, which a grazing ωi near the mirror direction needs), and
#: the rest even in ωo. Even in ωo alone starves the half vectors near the normal at grazing
#: incidence (|dωo/du_m| vanishes there like u³ and with ⟨ωi·m⟩).
WARP_SQUARE = 0.375
WARP_COS = 0.25
#: For a D from the back-scattering (broad: tables, Lambert), the share of the even spread's
#: marginal over the rows (φm) placed in equal steps of cosθo between rows
#: (:func:`_vndf_table`, ``broad``).
WARP_ROWS_COS = 0.5
#: For a D from the back-scattering, the even spread continues below the horizon, falling
#: linearly to 0 at cosθo = −WARP_BELOW (:func:`_broad_spread`).
WARP_BELOW = 0.5
#: For a D from the back-scattering, the part of the rows' density that follows the change of
#: cosθo between rows has this floor, relative to its change along the rows (:func:`_broad_spread`).
WARP_ROWS_FLOOR = 0.1
#: For a D from the back-scattering (isotropic files), the incidences up to this elevation
#: [rad] get the level warp (:func:`_level_warp`), those above it the spread with
#: :data:`GRAZING_UNIFORM` and :data:`GRAZING_ROWS_COS`; the file gets a twin of the last
#: level incidence :data:`LEVEL_TWIN` rad above it, with the grazing warp
#: (:func:`_level_incidences`).
LEVEL_MAX_THETA_I = np.radians(63.5)
LEVEL_TWIN = 1e-6
#: The lobe warp of a D from the back-scattering in isotropic files: a share STEEP_SHARE of
#: every row's columns, and a share STEEP_ROWS of that part's marginal over the rows, follow
#: how fast the stored values, f·cosθo/D̂, change at that incidence, along the row and between
#: rows, in log (:func:`_steepness`). One D serves every incidence, so a lobe that is dim in the
#: back-scattering D comes from and bright at grazing incidence (a measured film's or a glossy
#: coating's mirror peak: f/D rising 20-60x within 1-2° of the mirror direction at θi 70-75°; a
#: haze lobe whose Fresnel factor rises towards grazing) is where the visible normals put few
#: samples, and the stored values change there by decades from one sample to the next: this
#: part puts samples on it. The log is taken of |f|·cosθo plus STEEP_FLOOR times its largest
#: value at the incidence (values below that are not judged as relative errors), evaluated on
#: a grid STEEP_SUPERSAMPLE times finer than the ``vndf`` table and averaged over each node's
#: cell; the change between rows has a floor of WARP_ROWS_FLOOR times the change along them,
#: as the even spread's has (at normal incidence it is rounding noise). The share was chosen
#: on the 22 real files (formats/rgl-bsdf.md, "Tables"; by a script): at 0.2 convert's check
#: refused cg_sunflower (p95 10.3 %, 9.4 % at 0.3), at 0.5 the flake paint's median error at
#: uniform pairs rose to 1.06 % (0.95 % at 0.3).
STEEP_SHARE = 0.3
#: (the part of that share's marginal over the rows that follows the change between rows)
STEEP_ROWS = 0.5
#: (the floor ε of the log, relative to the largest |f|·cosθo at the incidence)
STEEP_FLOOR = 1e-4
#: (how many times finer than the ``vndf`` table the steepness is evaluated, and the largest
#: grid, in nodes a side, that the factor is lowered to keep within where it can: at least 1)
STEEP_SUPERSAMPLE = 4
STEEP_MAX_NODES = 257
#: Level warp: the share of every row per unit of cosθo in its band (κ); the band has full
#: weight below LEVEL_TOP·cosθi and fades to 0 at min(LEVEL_FADE, LEVEL_FADE_REL·cosθi)
#: above (below cosθi, where every row starts, so that every row crosses the band once,
#: falling); below the horizon it fades to 0 at −min(:data:`WARP_BELOW`, cosθi).
LEVEL_KAPPA = 0.5
LEVEL_TOP = 0.6
LEVEL_FADE, LEVEL_FADE_REL = 0.8, 0.9
#: For a D from the back-scattering, above :data:`LEVEL_MAX_THETA_I`: the share ε of the
#: spread, and the share of its marginal over the rows in equal steps of cosθo between rows.
GRAZING_UNIFORM = 0.7
GRAZING_ROWS_COS = 1.0


@dataclass
class RGLPayload:
    """What :func:`write_rgl` writes: the tensor fields, in file order.

    It also describes itself like a table (``grid``, ``channels``, ``spectral``,
    ``wavelengths``) through :attr:`bsdf`, the :class:`RGLBSDF` those fields make.
    """

    fields: dict

    @property
    def bsdf(self) -> "RGLBSDF":
        if "_bsdf" not in self.__dict__:
            self.__dict__["_bsdf"] = RGLBSDF(self.fields, "<prepared .bsdf>")
        return self.__dict__["_bsdf"]

    @property
    def grid(self):
        return self.bsdf.grid

    @property
    def channels(self):
        return self.bsdf.channels

    @property
    def spectral(self) -> bool:
        return self.bsdf.spectral

    @property
    def wavelengths(self):
        return self.bsdf.wavelengths


def _plan_layout(brdf, wavelengths):
    """The wavelengths [nm] to store (None for an RGB file)."""
    if brdf.spectral:
        lam = wavelengths if wavelengths is not None else brdf.wavelengths
        if lam is None:
            raise ParameterError("wavelengths_nm", f"model '{brdf.name}' is spectral: list the wavelengths to store")
        lam = np.asarray(lam, float)
        brdf.layout.resolve(lam)
        if np.any(np.diff(lam.astype(np.float32)) <= 0):
            raise ParameterError("wavelengths_nm", "wavelengths must increase strictly (also in float32)")
        return lam
    if wavelengths is not None:
        raise ParameterError("wavelengths_nm", f"model '{brdf.name}' has channels {list(brdf.channels)}, not a "
                             "spectrum; an RGB file is written (remove wavelengths_nm)")
    if brdf.channels not in (RGB, ("mono",)):
        raise ParameterError("channels", f"the RGL format stores RGB or spectra; model '{brdf.name}' has channels "
                             f"{list(brdf.channels)}")
    return None


def _choose_ndf(brdf, which, lam):
    """(callable D, 'model' | 'backscatter')."""
    ndf = model_ndf(brdf) if which in ("auto", "model") else None
    if ndf is None and which == "model":
        raise ParameterError("ndf", f"model '{brdf.name}' has no normal distribution of its own (use 'auto' or "
                             "'backscatter')")
    if ndf is not None:
        return ndf, "model"
    return backscatter_ndf(brdf, lam), "backscatter"


def _ndf_tables(ndf, warp_ndf, nx, ny, anisotropic, name):
    """The float32 ``ndf`` and ``sigma`` tables ``[ny, nx]`` of ``ndf``, and the D the warp follows.

    ``ndf`` holds D floored at :data:`NDF_FLOOR` of its maximum (the stored values divide by
    it); ``sigma`` is the projected area of the unfloored D. The warp follows ``warp_ndf``
    (the model's own D; ``ndf`` may be raised in its tails by :func:`backscatter_bound`),
    floored the same way.
    """
    ux, uy = np.linspace(0.0, 1.0, nx), np.linspace(0.0, 1.0, ny)
    with np.errstate(all="ignore"):
        if anisotropic:
            table = np.asarray(ndf(sph(u2theta(ux)[None, :], u2phi(uy)[:, None])), float)
        else:
            table = np.tile(np.asarray(ndf(sph(u2theta(ux), 0.0)), float), (ny, 1))
    if table.shape != (ny, nx) or not np.all(np.isfinite(table)) or np.any(table < 0) or not np.any(table > 0):
        raise BrdftabError(f"the normal distribution of {name!r} is not finite and positive")
    floor = NDF_FLOOR * table.max()

    def positive(fn):
        def d(h):
            with np.errstate(all="ignore"):
                return np.maximum(np.nan_to_num(np.asarray(fn(h), float)), 0.0)
        return d

    def d_warp(h):
        return np.maximum(positive(warp_ndf)(h), floor)

    ndf32 = np.maximum(table, floor).astype(np.float32)
    sigma = sigma_table(positive(ndf), nx, ny, isotropic=not anisotropic)
    sigma32 = np.maximum(sigma, np.finfo(np.float32).tiny).astype(np.float32)
    return d_warp, ndf32, sigma32


def _vndf_table(d, th_i, ph_i, nv, uniform=None, broad=False, level=None, lobe=False, steep=None):
    """The ``vndf`` field ``[Nφi, Nθi, nv, nv]``, float32: the density over u_m of the warp.

    The visible normals V = D(m)⟨ωi·m⟩₊ J, with J = 2π² u_x sinθm (the Jacobian of u -> m),
    mixed row by row (:func:`_mix_per_row`, share ε = ``uniform``, default
    :data:`WARP_UNIFORM`) with an even spread E over the part of the unit square whose ωo is
    above the horizon: a share :data:`WARP_SQUARE` of E even in the square, a share
    :data:`WARP_COS` in equal steps of cosθo along each row (|∂cosθo/∂x|), the rest even in ωo
    (⟨ωi·m⟩₊ J; dωo = 4⟨ωi·m⟩ dm). m = sph(u2theta(x), u2phi(y)): φm relative to φi (= 0)
    for isotropic files, absolute for anisotropic ones.

    ``broad`` (a D from the back-scattering, whose visible normals do not concentrate the
    samples where f·cosθo changes): :func:`_broad_spread` instead of E; with ``level`` (bool
    ``[Nθi]``, isotropic files) the θi slices where it is true get :func:`_level_warp` of that
    mix, the others the mix with ε = :data:`GRAZING_UNIFORM` and :data:`GRAZING_ROWS_COS`.
    ``broad`` and ``lobe`` (the ``lobe`` warp): E over the nodes above the horizon, with its
    share :data:`WARP_SQUARE` even in θm rather than in the square (θm, hence ωo, linear in
    the sample coordinate in the first column) and a share :data:`WARP_ROWS_COS` of its
    marginal over the rows in equal steps of cosθo between rows; it keeps more samples on a
    lobe than the level warp, whose band of cosθo takes half of every row. ``steep`` (the
    densities of :func:`_steepness`) then takes a share :data:`STEEP_SHARE` of that warp.
    """
    eps = WARP_UNIFORM if uniform is None else uniform
    g = np.linspace(0.0, 1.0, nv)
    vy, vx = np.meshgrid(g, g, indexing="ij")
    th_m = u2theta(vx)
    m = sph(th_m, u2phi(vy))
    jac = (2.0 * np.pi ** 2) * vx * np.sin(th_m)
    wi = sph(th_i[None, :], ph_i[:, None])  # [Nφi, Nθi, 3]
    cos_im = np.einsum("yxk,abk->abyx", m, wi)
    dot = np.maximum(cos_im, 0.0)
    vndf = _unit_mean(dot * (d(m) * jac)[None, None])
    if eps <= 0:
        return vndf.astype(np.float32)
    if broad and not lobe:
        even, rows_b = _broad_spread(cos_im, m, wi, vx, jac)
        if level is None:
            return _mix_per_row(vndf, even, eps, rows_b).astype(np.float32)
        lev = np.asarray(level, bool)
        grazing = ~lev[None, :, None, None]
        rows_b = (np.where(grazing, GRAZING_ROWS_COS, rows_b[0]), rows_b[1])
        out = _mix_per_row(vndf, even, np.where(grazing, GRAZING_UNIFORM, eps), rows_b)
        if lev.any():
            out[:, lev] = _level_warp(out[:, lev], cos_im[:, lev], m, wi[:, lev], vx)
        return out.astype(np.float32)
    wo_z = 2.0 * dot * m[None, None, :, :, 2] - wi[:, :, 2][:, :, None, None]
    above = (wo_z > 0) & (dot > 0)
    in_wo = _unit_mean(np.where(above, dot * jac[None, None], 0.0))
    even = WARP_SQUARE * _unit_mean(np.where(above, vx if broad else 1.0, 0.0)) \
        + (1.0 - WARP_SQUARE - WARP_COS) * in_wo
    # equal steps of cosθo along each row (rows where it does not change: even)
    dc = np.where(above, np.abs(np.gradient(np.where(above, wo_z, 0.0), axis=3)), 0.0)
    rows = dc.mean(axis=3, keepdims=True)
    even = even + WARP_COS * _unit_mean(np.where(rows > 0, dc, np.where(above, 1.0, 0.0)))
    rows_b = None
    if broad:  # the lobe warp: equal steps of cosθo between rows (where it does not change: even)
        dy = np.where(above, np.abs(np.gradient(np.where(above, wo_z, 0.0), axis=2)), 0.0)
        dy = dy.mean(axis=3, keepdims=True)
        mean = dy.mean(axis=2, keepdims=True)
        rows_b = (WARP_ROWS_COS, np.where(mean > 0, dy / np.where(mean > 0, mean, 1.0), 1.0))
    out = _mix_per_row(vndf, even, eps, rows_b)
    if steep is not None:
        out = _mix_per_row(out / out.mean(axis=(2, 3), keepdims=True), steep[0], STEEP_SHARE, (STEEP_ROWS, steep[1]))
    return out.astype(np.float32)


def _steepness(brdf, lam, th_i, nv, ndf_interp):
    """How fast the stored values f·cosθo/D̂ change over the ``vndf`` table's domain at each
    incidence (isotropic: φi = 0), where ``ndf_interp`` is D̂, the file's ``ndf`` as the readers
    interpolate it: ``(cols [1, Nθi, nv, nv], rows [1, Nθi, nv, 1])``, each of mean 1 per slice:
    the largest over channels of |∂ log((|f|·cosθo + ε)/D̂)/∂x| (along the rows: θm) and the row
    means of |∂ log(...)/∂y| (between rows: φm), with ε = :data:`STEEP_FLOOR` times the slice's
    largest |f|·cosθo, on a grid :data:`STEEP_SUPERSAMPLE` times finer than the table, averaged
    over each node's cell by the trapezoid rule (a smaller factor for a fine table, down to 1,
    to keep the grid within :data:`STEEP_MAX_NODES` nodes a side where it can). The row means
    get a floor of :data:`WARP_ROWS_FLOOR` times the mean change along the rows: at normal
    incidence the change between rows is rounding noise, which would otherwise set the row
    density (as :func:`_broad_spread` says, the readers blend the first two θi slices). f·cosθo
    is 0 beyond the horizon, so the horizon counts as a step. A slice where the source is 0
    everywhere, or not finite somewhere, gets even densities. The queries are not counted
    among a scattered table's extrapolated ones (those of the file written)."""
    from scipy.ndimage import correlate1d

    ss = max(1, min(STEEP_SUPERSAMPLE, (STEEP_MAX_NODES - 1) // (nv - 1)))
    # a node's cell average: the trapezoid rule over the ss + 1 fine nodes around it
    tent = np.ones(2 * (ss // 2) + 1) if ss % 2 == 0 else np.ones(ss + 2)
    tent[0] = tent[-1] = 0.5
    if ss % 2:  # odd: the cell ends half-way along a fine step
        tent[0] = tent[-1] = 0.125
        tent[1] = tent[-2] = 0.875
    tent /= tent.sum()
    n = (nv - 1) * ss + 1
    counts = getattr(brdf, "extrapolation", None)
    before = list(counts) if isinstance(counts, list) else None
    g = np.linspace(0.0, 1.0, n)
    vy, vx = np.meshgrid(g, g, indexing="ij")
    m = sph(u2theta(vx), u2phi(vy)).reshape(-1, 3)
    d_hat = ndf_interp.eval(np.stack([vx.ravel(), vy.ravel()], axis=-1)).reshape(n, n, 1)
    log_d = np.log(np.maximum(d_hat, np.finfo(np.float64).tiny))
    cols = np.ones((1, th_i.size, nv, nv))
    rows = np.ones((1, th_i.size, nv, 1))
    for a, t in enumerate(th_i):
        wi = sph(np.float64(t), np.float64(0.0))
        cos_im = m @ wi
        wo = 2.0 * cos_im[:, None] * m - wi
        ok = (wo[:, 2] > 0) & (cos_im > 0)
        if not ok.any():
            continue
        f = np.asarray(brdf.eval(np.broadcast_to(wi, (int(ok.sum()), 3)), wo[ok], lam), float)
        vals = np.zeros((m.shape[0], f.shape[-1]))
        vals[ok] = np.abs(f) * wo[ok, 2:3]
        vals = vals.reshape(n, n, -1)
        top = vals.max()
        if not (np.isfinite(top) and top > 0):
            continue
        log = np.log(vals + STEEP_FLOOR * top) - log_d
        gy, gx = np.gradient(log, 1.0 / (n - 1), axis=(0, 1))
        live = ok.reshape(n, n)
        gx = np.where(live, np.abs(gx).max(axis=-1), 0.0)
        gy = np.where(live, np.abs(gy).max(axis=-1), 0.0)
        if ss > 1:  # (non-negative weights of non-negative values: no rounding below 0)
            gx, gy = (correlate1d(correlate1d(grad, tent, axis=0, mode="nearest"), tent, axis=1,
                                  mode="nearest")[::ss, ::ss] for grad in (gx, gy))
        cx = gx
        cy = gy.mean(axis=1, keepdims=True) + WARP_ROWS_FLOOR * cx.mean()
        if cx.mean() > 0:
            cols[0, a] = cx / cx.mean()
        if cy.mean() > 0:
            rows[0, a] = cy / cy.mean()
    if before is not None:
        counts[:] = before
    return cols, rows


def _unit_mean(a):
    """``a`` scaled to mean 1 over each slice (the last two axes)."""
    return a / a.mean(axis=(2, 3), keepdims=True)


def _broad_spread(cos_im, m, wi, vx, jac):
    """The even spread E of a warp for a D from the back-scattering, and its row density.

    Every part is a continuous function of the half vector, so that the bilinear ``vndf``
    table changes smoothly from row to row. A mask of the nodes whose ωo is above the horizon
    (what the spread of a model's own D uses) moves by whole columns from one row to the next:
    the conditional along x of the rows on either side of such a row differ by a node's share,
    and the warp bends at every such ``vndf`` row, by the same angle at any resolution.

    Weight a = clip(1 + cosθo/:data:`WARP_BELOW`, 0, 1) on ωo = reflect(ωi, m), continued
    below the horizon (cosθo computed from the signed ωi·m): full above the horizon, falling to
    0 at cosθo = −WARP_BELOW. E is a share :data:`WARP_SQUARE` of a·x (even in θm, so that θm
    and hence ωo are linear in the sample coordinate in the first column), :data:`WARP_COS` of
    a·|∂cosθo/∂x| (equal steps of cosθo along each row) and the rest a·⟨ωi·m⟩₊ J (even in ωo).
    Its marginal over the rows takes a share :data:`WARP_ROWS_COS` in proportion to the row
    mean of a·|∂cosθo/∂y| plus :data:`WARP_ROWS_FLOOR` times the slice mean of a·|∂cosθo/∂x|
    (equal steps of cosθo between rows; the floor makes it even as θi -> 0, where ∂cosθo/∂y
    vanishes, rather than a |sin φm| shape at any θi > 0 and even at θi = 0, which the reader's
    blending between the first two θi slices does not follow).
    """
    wo_z = 2.0 * cos_im * m[None, None, :, :, 2] - wi[:, :, 2][:, :, None, None]
    a = np.clip(1.0 + wo_z / WARP_BELOW, 0.0, 1.0)
    dc = a * np.abs(np.gradient(wo_z, axis=3))
    even = WARP_SQUARE * _unit_mean(a * vx) + WARP_COS * _unit_mean(dc) \
        + (1.0 - WARP_SQUARE - WARP_COS) * _unit_mean(a * np.maximum(cos_im, 0.0) * jac[None, None])
    dy = (a * np.abs(np.gradient(wo_z, axis=2))).mean(axis=3, keepdims=True)
    dy = dy + WARP_ROWS_FLOOR * dc.mean(axis=(2, 3), keepdims=True)
    return even, (WARP_ROWS_COS, dy / dy.mean(axis=2, keepdims=True))


def _trapezoid_rows(a):
    """The integral over x of every row of ``a`` (``[..., H, W]`` -> ``[..., H, 1]``), by the
    trapezoid rule on the table's nodes, as the reader's warp integrates it."""
    return (a[..., 1:] + a[..., :-1]).sum(axis=-1, keepdims=True) * (0.5 / (a.shape[-1] - 1))


def _level_warp(base, cos_im, m, wi, vx):
    """The warp of an incidence up to :data:`LEVEL_MAX_THETA_I` for a D from the back-scattering
    (``base``: the mix of :func:`_vndf_table`): every row ends with cosθo in equal steps.

    Along a row (φm fixed) cosθo = P sin2θm + cosθi cos2θm (P = ωi,x cosφm + ωi,y sinφm)
    starts at cosθi, rises to its peak (when P > 0), then falls once, to its trough. Each row is
    [head | band | rest]: the band is the falling part from c_top = :data:`LEVEL_TOP`·cosθi
    (faded in from c_fade) down to −min(:data:`WARP_BELOW`, cosθi) (faded out), a share
    :data:`LEVEL_KAPPA` of the row per unit of cosθo; the head (all before it) holds ``base``'s
    density with the same share in every row; the rest (after the band, below the horizon) what
    remains. The sample coordinate x of a level of cosθo in the band is then the same in every
    row, and from one incidence to the next it shifts by an offset only (the same share per
    unit of cosθo): lines of equal cosθo are sample columns, f·cosθo of a diffuse surface is
    linear in x there, and the reader's linear blending of two incidences is affine in cosθo.
    The rows are even in φm: row densities that differ between incidences weight the two
    slices' conditionals unequally in the reader's blend. (A warp whose sample columns crossed
    the levels of cosθo, with rows that differed between incidences, read a Lambertian table
    5.2 % off at θo = 80°: tests/test_rgl.py::test_lambert_table_to_bsdf_up_to_grazing.)
    """
    wo_z = 2.0 * cos_im * m[None, None, :, :, 2] - wi[:, :, 2][:, :, None, None]
    th_m = u2theta(vx)[None, None]
    sin_m = np.sin(th_m)
    with np.errstate(divide="ignore", invalid="ignore"):
        p = (wi[:, :, 0][:, :, None, None] * m[None, None, :, :, 0]
             + wi[:, :, 1][:, :, None, None] * m[None, None, :, :, 1]) / sin_m
    p[..., 0] = p[..., 1]  # θm = 0: the azimuth of the next column
    cz = wi[:, :, 2][:, :, None, None]
    psi = np.arctan2(p, cz)
    after = th_m >= 0.5 * np.maximum(psi, 0.0)  # past the peak
    falling = after & (th_m <= 0.5 * (psi + np.pi))  # and before the trough
    c_top = LEVEL_TOP * cz
    c_fade = np.minimum(LEVEL_FADE, LEVEL_FADE_REL * cz)
    below = np.minimum(WARP_BELOW, cz)
    top = np.clip((c_fade - wo_z) / (c_fade - c_top), 0.0, 1.0)
    bottom = np.clip(1.0 + wo_z / below, 0.0, 1.0)
    slope = np.abs(np.gradient(wo_z, 1.0 / (vx.shape[1] - 1), axis=3))
    band = LEVEL_KAPPA * np.where(falling, top * bottom, 0.0) * slope
    head = base * np.where(after, 1.0 - top, 1.0)
    rest = base * np.where(after, top, 0.0) * (1.0 - np.where(falling, bottom, 0.0))
    # the band of a row that spans it all, and the head's share (the same in every row)
    head_share = 1.0 - LEVEL_KAPPA * (0.5 * (c_fade - c_top) + c_top + 0.5 * below)[..., :1, :1]
    band_share = _trapezoid_rows(band)
    rest_share = np.maximum(1.0 - head_share - band_share, 0.0)

    def scaled(a, share):
        total = _trapezoid_rows(a)
        return np.where(total > 0, a * share / np.where(total > 0, total, 1.0), 0.0)

    cond = scaled(head, head_share) + band + scaled(rest, rest_share)
    return cond / cond.mean(axis=(2, 3), keepdims=True)


def _mix_per_row(a, b, eps, rows_b=None):
    """The density whose marginal over rows (φm) is (1 − ε)·a's + ε·b's and whose conditional
    along each row (θm) is (1 − ε)·a's + ε·b's: every row keeps the share ε of its columns
    spread as ``b`` spreads them, however much ``a`` concentrates elsewhere in the row.
    ``rows_b`` = (share s, row density r ``[..., H, 1]`` of mean 1): b's marginal over the
    rows is then (1 − s)·b's own + s·r."""
    def split(t):
        row = t.mean(axis=3, keepdims=True)
        cond = np.where(row > 0, t / np.where(row > 0, row, 1.0), 0.0)
        return row / row.mean(axis=2, keepdims=True), cond

    ra, ca = split(a)
    rb, cb = split(b)
    if rows_b is not None:
        rb = (1.0 - rows_b[0]) * rb + rows_b[0] * rows_b[1]
    has_b = rb > 0
    cond = np.where(has_b, (1.0 - eps) * ca + eps * cb, ca)
    return ((1.0 - eps) * ra + eps * rb) * cond


def _sigma_between_incidences(sigma32, th_i):
    """The ``sigma`` table of an isotropic D, linear in θi between the file's θi nodes (and σ
    itself outside them), float32.

    The reader blends two θi slices linearly and divides by 4σ̂ at the θi it evaluates: the
    stored values hold 4σ̂ at their own node, so that the value read is the true one times
    lerp(σ)/σ̂, which for σ itself (concave in θi, like cosθi) is 0.2 % low halfway between
    the default nodes near the normal. It is further multiplied by (1 − w)·cos(wΔ) +
    w·cos((1 − w)Δ) between nodes Δ apart (w the blending weight): the ratio of the linear blend
    of cos(θi − α) to its value, whatever α. At a fixed half vector cosθo is such a sinusoid of
    θi, so the reader's blend of f·cosθo falls short by that ratio (0.2 % halfway between the
    default nodes near the normal), and dividing by a σ̂ lowered by it makes up for it. Any
    positive ``sigma`` is valid: the readers use it only to divide the stored values, which the
    writer made with it. (Without both, the albedo of a Lambertian's file was 0.28 % low at
    θi = 20°: tests/test_rgl.py::test_lambert_file_albedo_up_to_grazing_incidence.)"""
    if th_i.size < 2:  # one θi node: nothing is blended
        return sigma32
    nx = sigma32.shape[1]
    theta = u2theta(np.linspace(0.0, 1.0, nx))
    true = sigma32[0].astype(np.float64)
    at_nodes = np.interp(theta2u(th_i), np.linspace(0.0, 1.0, nx), true)
    inside = (theta >= th_i[0]) & (theta <= th_i[-1])
    row = np.where(inside, np.interp(theta, th_i, at_nodes), true)
    k = np.clip(np.searchsorted(th_i, theta, side="right") - 1, 0, th_i.size - 2)
    step = th_i[k + 1] - th_i[k]
    w = np.clip((theta - th_i[k]) / step, 0.0, 1.0)
    row = row * np.where(inside, (1.0 - w) * np.cos(w * step) + w * np.cos((1.0 - w) * step), 1.0)
    return np.broadcast_to(row, sigma32.shape).astype(np.float32)


def _level_incidences(theta_i):
    """The θi nodes of a file whose D is from the back-scattering, float32, and which of them
    get the level warp (:func:`_level_warp`): those up to :data:`LEVEL_MAX_THETA_I`. When
    nodes lie on both sides, a twin of the last level node, :data:`LEVEL_TWIN` above it, gets
    the grazing warp, so that the reader's blending between the two kinds of slice (whose
    sample coordinates mean different directions) is confined to that sliver of θi."""
    th = theta_i.astype(np.float64)
    level = th <= LEVEL_MAX_THETA_I
    if level.any() and not level.all():
        k = int(np.flatnonzero(level)[-1])
        twin = np.float32(th[k] + LEVEL_TWIN)
        if twin < theta_i[k + 1]:
            theta_i = np.insert(theta_i, k + 1, twin)
            level = np.insert(level, k + 1, False)
    return theta_i, level


def _luminance(spectra32, lam, weight):
    """The ``luminance`` field: the density of Mitsuba's first warp over the unit square, float32.

    The luminance of the stored values times ``weight`` = D̂/(4σ̂)·|dωo/ds| (``[Nφi, Nθi, N,
    N]``), i.e. the luminance of f·cosθo per unit area of the square: the luminance warp
    followed by the ``vndf`` warp then samples ωo in proportion to f·cosθo whatever density the
    ``vndf`` warp has. Non-negative, plus 1e-6 of each slice's maximum (no empty slice).
    """
    weights = _luminance_weights(RGB, lam)
    lum = np.maximum(np.einsum("abcyx,c->abyx", spectra32.astype(np.float64), weights), 0.0) * weight
    top = lum.max(axis=(2, 3), keepdims=True)
    return (lum + np.where(top > 0, 1e-6 * top, 1.0)).astype(np.float32)


def _edge_weight(weight):
    """The luminance weights with the column x = 0 of each slice replaced by its neighbour's.

    The warp maps x = 0 to θm = 0, where the bilinear ``vndf`` table vanishes linearly while
    |dωo/du_m| vanishes as u³: the weight drops to 0 in a sliver of the first cell only, and a
    0 at the node would starve the whole first column of samples (biasing Mitsuba's sampled
    albedo low: about 1 % at 64 × 64 samples, more than 0.5 % in
    tests/test_rgl.py::test_mitsuba_albedo_matches_quadrature_of_the_model).
    """
    out = weight.copy()
    out[..., 0] = weight[..., 1]
    return out


def _check_coverage(brdf, theta_i):
    """Refuse a table whose grid does not hold the incidences the file stores (a table on a
    spherical grid with one incidence, or with a θi range short of the file's: it has no
    values there). A file in a format's own layout (an RGL file read back) evaluates at every
    incidence and is not judged here."""
    from ..grids import Grid

    grid = getattr(brdf, "grid", None)
    if not isinstance(grid, Grid):
        return
    axis = next((a for a in grid.axes if getattr(a, "name", "") == "theta_i"), None)
    if axis is None:
        return
    values = np.degrees(np.asarray(axis.values, float))
    want = np.degrees(theta_i)
    if values.size < 2:
        raise BrdftabError(f"the table holds a single incidence (theta_i = {values[0]:g} deg); an RGL .bsdf file "
                           f"stores the reflectance for every incidence from {want.min():g} to {want.max():g} deg, "
                           "so it cannot be written from this table")
    if want.min() < values.min() - 1e-6 or want.max() > values.max() + 1e-6:
        raise BrdftabError(f"the table holds incidences theta_i = {values.min():g} to {values.max():g} deg only; the "
                           f"RGL file would store {want.min():g} to {want.max():g} deg (set theta_i_deg within the "
                           "table's range)")


def _check_size(brdf, n_slices, opts, n_chan, fit=False, anisotropic=False):
    """Refuse a file whose working arrays would not fit in this machine's memory (with ``fit``,
    also those of the least-squares values: the sparse map of the query pairs, about 100 bytes
    per non-zero with its scaled copies, 8 or 16 non-zeros per pair, and the source's values)."""
    n, nv = opts["resolution"], opts["vndf_resolution"]
    need = 8.0 * n_slices * (n * n * (n_chan + 24) + 2 * nv * nv)  # float64 values + node geometry
    if fit:
        queries = min(FIT_MAX_QUERIES, FIT_QUERIES_PER_VALUE * n_slices * n * n)
        need += queries * (100.0 * (16 if anisotropic else 8) + 8.0 * (n_chan + 20))
    try:
        have = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):  # pragma: no cover - non-POSIX
        return
    if need > 0.5 * have:
        raise BrdftabError(f"an RGL file of {n_slices} incident directions x {n}x{n} samples x {n_chan} channels "
                           f"would need about {need / 2**30:.3g} GiB while writing, more than this machine's "
                           f"{have / 2**30:.3g} GiB allows; lower resolution, n_theta_i or n_phi_i")


def prepare_rgl(brdf, grid=None, **options) -> RGLPayload:
    """Sample ``brdf`` into the fields of an RGL ``.bsdf`` file (``grid`` is not used).

    ``options`` are the format options (:data:`._rgl_options.OPTIONS`). A :class:`RGLBSDF`
    read from a file and written with no options is copied as it is.
    """
    opts = check_options(**options)
    if isinstance(brdf, RGLBSDF) and not options:
        return RGLPayload(dict(brdf.fields))
    if not isinstance(brdf, BRDF):
        raise BrdftabError(f"cannot write {type(brdf).__name__} as an RGL .bsdf file: expected a BRDF")
    from ..table import warn_specular_dropped

    warn_specular_dropped(brdf, "the RGL .bsdf format")
    anisotropic = opts["anisotropic"]
    if anisotropic is None:
        anisotropic = not brdf.isotropic
    elif not anisotropic and not brdf.isotropic:
        raise ParameterError("anisotropic", f"model '{brdf.name}' is anisotropic; an isotropic file would keep "
                             "only phi_i = 0 (remove anisotropic = false)")
    lam = _plan_layout(brdf, opts["wavelengths"])
    _check_coverage(brdf, opts["theta_i"])
    ndf, source = _choose_ndf(brdf, opts["ndf"], lam)

    # a D from the back-scattering (with a lobe: not the flat D of a BRDF that scatters nothing
    # back) gets a spread for broad reflectance: the level warp or the lobe warp in isotropic
    # files (option warp; auto: the one that reproduces the source better), the smooth spread
    # or the lobe warp in anisotropic ones
    broad = source == "backscatter" and not getattr(ndf, "no_backscatter", False)
    if not broad:
        kinds = ("model",)
    else:
        first = "smooth" if anisotropic else "level"
        kinds = (first, "lobe") if opts["warp"] == "auto" else ("lobe" if opts["warp"] == "lobe" else first,)
    # a scattered table counts its extrapolated queries (reported by convert): keep the counts
    # of the candidate written, not of every candidate and of the choice
    counts = getattr(brdf, "extrapolation", None)
    before = list(counts) if isinstance(counts, list) else None
    candidates, tallies = [], []
    for k in kinds:
        if before is not None:
            counts[:] = before
        candidates.append(_fields(brdf, backscatter_defaults(opts, k, anisotropic) if broad else opts, lam, ndf, source,
                                  anisotropic, k))
        tallies.append(list(counts) if before is not None else None)
    mode = _fit_mode(opts, broad, anisotropic, 3 if lam is None else lam.size)
    if len(candidates) == 1 and mode is None:
        best, score = candidates[0], None
    else:
        best, score = _closest(brdf, lam, candidates)
    tally = tallies[next(i for i, c in enumerate(candidates) if c is best)]
    if mode == "fit" and score < np.inf:
        # (a candidate no reader takes, e.g. values beyond float32, is written with its node
        # samples: the checks of the file say why, as for values = "nodes")
        best = _fit(brdf, best, lam)
    elif mode == "try" and FIT_WHEN_SCORE < score < np.inf:
        # auto: fitted values where the node samples miss, kept where they read closer to the
        # source at the check pairs and not much farther at grazing ones
        fitted = _fit(brdf, best, lam)
        near = _scores(brdf, lam, [best, fitted], *_check_pairs())
        far, c85 = [], np.cos(np.radians(85.0))
        for which in ("i", "o"):  # grazing ωi, grazing ωo: 80-85° and 85-89° apart
            wi, wo = _check_pairs(which)
            cos = (wi if which == "i" else wo)[:, 2]
            far += _scores(brdf, lam, [best, fitted], wi, wo, groups=(cos >= c85, cos < c85))
        if near[1] < near[0] and all(s[1] <= FIT_GRAZING_TOLERANCE * s[0] for s in far):
            best = fitted
    if before is not None:
        counts[:] = tally
    return RGLPayload(best.fields)


#: ``values = "auto"``: the least-squares values (:mod:`._rgl_fit`) are tried, in isotropic
#: RGB or grey files, when the candidate with node samples scores above this at the check
#: pairs of :func:`_closest` (max(median / 1 %, p95 / 10 %): median above 0.2 % or p95 above
#: 2 %), and kept if they score lower there and at most :data:`FIT_GRAZING_TOLERANCE` times
#: as high at grazing pairs (θi in 80-85° and in 85-89° with θo within 80°, and the same
#: with ωi and ωo swapped, each judged apart: :func:`_check_pairs`). Where the node samples
#: are that close the fit gains little and loses the exactness at the nodes (a Lambertian
#: table: worst error at 85° 6.6 % instead of 3.7 %). Spectral files (a table at 31
#: wavelengths: 2.2 → 23 s to write, median 1.005 → 0.974 %) and anisotropic ones (4.2 →
#: 24 s; fewer query pairs than stored values) keep their node samples unless
#: ``values = "fit"``.
FIT_WHEN_SCORE = 0.2
#: The fit scores lower at the check pairs but may read farther off at grazing ones, where the
#: queries are few and the format is weakest: fitted values are kept only if no grazing band's
#: score rises by more than this factor. Measured (fit / node samples, the four bands): the
#: real car paints 0.59-0.99, the flake paint 0.38-1.17, a rough table 0.81-1.16; a Lambertian
#: at 16 x 16 samples with the lobe warp without its steepness share, whose fit reads 2.4x
#: closer up to 80°, 2.9x and 4.8x at grazing ωi (p95 at θi 85-89° 2.4 → 22 %; kept with node
#: samples; with the share the fit reads closer there too, 4.1 → 2.6 %, and is kept).
FIT_GRAZING_TOLERANCE = 1.2


def _fit_mode(opts, broad, anisotropic, n_chan):
    """``"fit"`` (option ``values = "fit"``), ``"try"`` (``auto`` in an isotropic RGB or grey
    file whose D is from the back-scattering: :data:`FIT_WHEN_SCORE`) or None (node samples)."""
    if opts["values"] == "fit":
        return "fit"
    if opts["values"] == "auto" and broad and not anisotropic and n_chan <= 3:
        return "try"
    return None


@dataclass(eq=False)
class _Candidate:
    """A candidate file: its fields, and the weights of its luminance map (D̂/(4σ̂)·|dωo/ds|)."""

    fields: dict
    lum_weight: np.ndarray
    n_source: int


def _fit(brdf, cand: _Candidate, lam) -> _Candidate:
    """``cand`` with least-squares stored values (:func:`._rgl_fit.fit_values`) and the
    luminance map of those values; the provenance says ``values: fit``."""
    key = "rgb" if lam is None else "spectra"
    fields = dict(cand.fields)
    fields[key] = fit_values(brdf, fields, key, lam, cand.n_source)
    fields["luminance"] = _luminance(fields[key], lam, cand.lum_weight)
    prov = json.loads(bytes(fields["provenance"]).decode("utf-8"))
    prov["values"] = "fit"
    fields["provenance"] = _text(json.dumps(prov, sort_keys=True, default=_json_default))
    return _Candidate(fields, cand.lum_weight, cand.n_source)


def _fields(brdf, opts, lam, ndf, source, anisotropic, kind) -> _Candidate:
    """The fields of a file of ``brdf`` with the warp ``kind``: ``model`` (a model's own D, or
    the flat D of a BRDF without back-scattering), ``level`` / ``lobe`` (a D from the
    back-scattering in an isotropic file: :func:`_level_warp` with a twin θi slice, or the
    lobe spread of :func:`_vndf_table`) or ``smooth`` (a D from the back-scattering in an
    anisotropic file: :func:`_broad_spread`)."""
    theta_i = opts["theta_i"].astype(np.float32)
    broad = kind in ("level", "lobe", "smooth")
    level = None
    if kind == "level":
        theta_i, level = _level_incidences(theta_i)
    phi_i = (np.linspace(-np.pi, np.pi, opts["n_phi_i"]) if anisotropic else np.zeros(1)).astype(np.float32)
    n_chan = 3 if lam is None else lam.size
    _check_size(brdf, phi_i.size * theta_i.size, opts, n_chan, _fit_mode(opts, broad, anisotropic, n_chan) is not None,
                anisotropic)
    th_i, ph_i = theta_i.astype(np.float64), phi_i.astype(np.float64)

    ny = opts["ndf_phi_resolution"] if anisotropic else 2
    table_ndf = backscatter_bound(brdf, ndf, lam, opts["ndf_resolution"], ny, anisotropic) \
        if source == "model" else ndf
    d, ndf32, sigma32 = _ndf_tables(table_ndf, ndf, opts["ndf_resolution"], ny, anisotropic, brdf.name)
    if level is not None:
        sigma32 = _sigma_between_incidences(sigma32, th_i)
    ndf_interp, sigma_interp = bilinear(ndf32), bilinear(sigma32)
    steep = _steepness(brdf, lam, th_i, opts["vndf_resolution"], ndf_interp) \
        if kind == "lobe" and not anisotropic else None
    vndf32 = _vndf_table(d, th_i, ph_i, opts["vndf_resolution"], broad=broad, level=level, lobe=kind == "lobe",
                         steep=steep)
    warp = Marginal2D(vndf32, (phi_i, theta_i))

    # f·cosθo·4σ̂/D̂ at the warped nodes (0 where ωo is below the horizon)
    wi, wo, u_m, (th, ph), shape = node_geometry(warp, th_i, ph_i, opts["resolution"], not anisotropic)
    valid = wo[:, 2] > 0
    n_out = len(brdf.channels) if lam is None else lam.size
    values = np.zeros((wi.shape[0], n_out))
    lum_weight = np.zeros(wi.shape[0])  # D̂/(4σ̂)·|dωo/ds|: |dωo/ds| = 4⟨ωi·m⟩·2π²u sinθm / pdf(u_m)
    if valid.any():
        f = brdf.eval(wi[valid], wo[valid], lam)
        d_hat = ndf_interp.eval(u_m[valid])
        s_hat = sigma_interp.eval(np.stack([theta2u(th[valid]), phi2u(ph[valid])], axis=-1))
        # the stored values v = f·cosθo·4σ̂/D̂, so that v·D̂/(4σ̂) is f·cosθo at the nodes
        values[valid] = f * (wo[valid, 2] * 4.0 * s_hat / d_hat)[:, None]
        m = wi[valid] + wo[valid]
        m /= np.linalg.norm(m, axis=-1, keepdims=True)
        pdf = warp.eval(u_m[valid], (ph[valid], th[valid]))
        dwo = (8.0 * np.pi ** 2) * u_m[valid, 0] * np.sqrt(np.maximum(1.0 - m[:, 2] ** 2, 0.0)) \
            * np.maximum(np.sum(wi[valid] * m, axis=-1), 0.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            lum_weight[valid] = np.where(pdf > 0, d_hat / (4.0 * s_hat) * dwo / pdf, 0.0)
    if not np.all(np.isfinite(values)):
        bad = int((~np.isfinite(values)).sum())
        missing = getattr(brdf, "missing", None)
        why = (f" (it has {int(np.asarray(missing).sum())} missing samples, which read as NaN: an RGL file "
               "stores no missing samples; fill them or convert to a format that keeps them)"
               if missing is not None and np.asarray(missing).any() else "")
        raise BrdftabError(f"{brdf.name!r} gave {bad} non-finite samples while writing an RGL .bsdf file{why}")
    if n_out == 1:  # grey: the same values in R, G and B
        values = np.repeat(values, 3, axis=1)
    spectra32 = np.moveaxis(values.reshape(shape + (values.shape[1],)), -1, 2).astype(np.float32)

    description = opts["description"] or f"{brdf.describe()} (brdftab {__version__})"
    provenance = {
        "model": brdf.name,
        "parameters": brdf.parameters,
        "brdftab_version": __version__,
        "created": _dt.datetime.now(_dt.timezone.utc).replace(microsecond=0).isoformat(),
        "ndf_source": source,
        "warp": kind,
        "values": "nodes",
        "isotropic": bool(brdf.isotropic),
        "reciprocal": bool(brdf.reciprocal),
        "origin": str(getattr(brdf, "origin", "analytic")),
        "convention": "rgb/spectra = f(wi, wo) cos(theta_o) 4 sigma(wi) / D(m); wi = incident (conditioning) "
                      "direction, m = normalize(wi + wo)",
    }
    lum_weight = _edge_weight(lum_weight.reshape(shape))
    fields = {
        "description": _text(description),
        "jacobian": np.ones(1, np.uint8),
        "theta_i": theta_i,
        "phi_i": phi_i,
        "ndf": ndf32,
        "sigma": sigma32,
        "vndf": vndf32,
        "luminance": _luminance(spectra32, lam, lum_weight),
    }
    fields["rgb" if lam is None else "spectra"] = spectra32
    if lam is not None:
        fields["wavelengths"] = lam.astype(np.float32)
    fields["provenance"] = _text(json.dumps(provenance, sort_keys=True, default=_json_default))
    return _Candidate(fields, lum_weight, n_out)


#: Direction pairs at which ``warp = "auto"`` compares the candidate warps with the source.
WARP_CHECK_PAIRS = 4000


def _closest(brdf, lam, candidates) -> tuple:
    """Of candidate files (:class:`_Candidate`), the one whose reading (brdftab's reader, Mitsuba's to float32)
    reproduces ``brdf`` best at :data:`WARP_CHECK_PAIRS` pairs with θi, θo ≤ 80° (half uniform
    in solid angle, half near the mirror direction, reflected about normals whose slopes have a
    standard deviation log-uniform in [0.01, 0.5]): the lowest of max(median / 1 %, 95th
    percentile / 10 %) of the relative error of f where f is above 1e-3 of its 99th
    percentile, the targets of a table's round trip (formats/rgl-bsdf.md, "Tables"), and that
    score. Seeded: the same source gives the same file."""
    scores = _scores(brdf, lam, candidates, *_check_pairs())
    k = int(np.argmin(scores))
    return candidates[k], scores[k]


def _check_pairs(grazing: str = ""):
    """The seeded pairs of :func:`_closest` (θi, θo ≤ 80°), or with ``grazing`` = ``"i"``
    (``"o"``) as many pairs with θi (θo) in [80°, 89°] and the other direction within 80°
    (half of those near the mirror direction where it lies within 80°)."""
    from ..geometry import mirror_biased_pairs

    c80, c89 = np.cos(np.radians(80.0)), np.cos(np.radians(89.0))
    if not grazing:
        return mirror_biased_pairs(WARP_CHECK_PAIRS, np.random.default_rng(0), z_low=c80, z_span=1.0 - c80)
    wi, wo = mirror_biased_pairs(WARP_CHECK_PAIRS, np.random.default_rng(1), z_low=c80, z_span=1.0 - c80,
                                 wi_z=(c89, c80))
    return (wi, wo) if grazing == "i" else (wo, wi)


def _scores(brdf, lam, candidates, wi, wo, groups=None) -> list:
    """max(median / 1 %, p95 / 10 %) of the relative error of each candidate's f·cosθo (as
    Mitsuba evaluates it: no hold near the horizon) at the pairs where the source's is above
    1e-3 of its 99th percentile; inf for fields no reader takes or non-finite readings. With
    ``groups`` (boolean masks of the pairs): a list of such lists, one per group."""
    ref = np.asarray(brdf.eval(wi, wo, lam), float) * wo[:, 2:3]
    ok = np.isfinite(ref).all(axis=-1)
    big = np.zeros(ref.shape, bool)
    if ok.any():
        big[ok] = np.abs(ref[ok]) > 1e-3 * np.percentile(np.abs(ref[ok]), 99)
    masks = [np.ones(ok.shape, bool)] if groups is None else list(groups)
    out = [[] for _ in masks]
    for cand in candidates:
        got = None
        try:
            got = np.asarray(RGLBSDF(cand.fields, "<candidate>").eval_cos(wi[ok], wo[ok], lam), float)
        except BrdftabError:  # fields a reader refuses (e.g. values beyond float32): the checks of
            pass              # the file written say so, not this choice
        if got is not None and got.shape[-1] != ref.shape[-1]:  # a grey source written to R, G and B
            got = got[..., :ref.shape[-1]]
        for k, mask in enumerate(masks):
            if got is None or not np.isfinite(got).all():
                out[k].append(np.inf)
                continue
            sel = big[ok] & mask[ok][:, None]
            rel = np.abs(got[sel] - ref[ok][sel]) / np.abs(ref[ok][sel])
            out[k].append(max(np.median(rel) / 0.01, np.percentile(rel, 95) / 0.10) if rel.size else 0.0)
    return out[0] if groups is None else out


def _text(s: str) -> np.ndarray:
    return np.frombuffer(s.encode("utf-8"), dtype=np.uint8).copy()


def _json_default(v):
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, (np.floating, np.integer)):
        return v.item()
    return str(v)


def write_rgl(payload, path, **options):
    if not isinstance(payload, RGLPayload):
        payload = prepare_rgl(payload, None, **options)
    write_tensor_file(path, payload.fields)
