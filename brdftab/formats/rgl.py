"""Mitsuba 3 / RGL tabulated BSDF files (``.bsdf``, Dupuy & Jakob 2018), read and written.

The file is a Mitsuba ``tensor_file`` (:mod:`._tensor`) with the fields of Mitsuba 3's
``measured`` plugin (see ``formats/rgl-bsdf.md``):

``description`` uint8 text · ``jacobian`` uint8[1] · ``theta_i`` f32[Nθi] · ``phi_i`` f32[Nφi]
· ``ndf`` / ``sigma`` f32[Ny, Nx] · ``vndf`` f32[Nφi, Nθi, Hv, Wv] · ``luminance``
f32[Nφi, Nθi, N, N] · ``rgb`` f32[Nφi, Nθi, 3, N, N] (RGB files) or ``spectra``
f32[Nφi, Nθi, Nλ, N, N] + ``wavelengths`` f32[Nλ] (spectral files).

A reader maps a direction pair to the unit square through the VNDF warp and interpolates the
stored values there (:class:`RGLBSDF` does exactly what Mitsuba does)::

    m = normalize(wi + wo);  u(θ) = sqrt(2θ/π),  u(φ) = (φ + π)/(2π)
    u_m = (u(θm), u(φm − φi) [isotropic] or u(φm))          u_wi = (u(θi), u(φi))
    s = vndf.invert(u_m | φi, θi)
    f·cosθo = spectra(s | φi, θi, λ) · ndf(u_m) / (4 sigma(u_wi))       (jacobian = 1)

Writing samples any BRDF (:func:`prepare_rgl`): the NDF is the model's own D when it has one
(:func:`model_ndf`), otherwise one extracted from the back-scattering f(ω, ω) by power
iteration (:func:`backscatter_ndf`); sigma is its projected area ∫ D(m) ⟨ω·m⟩ dm; the VNDF is
D(m)⟨ωi·m⟩/σ(ωi) times the Jacobian of the u → m map; the stored values are
f(ωi, ωo)·cosθo·4σ̂/D̂ at the warped nodes, with σ̂, D̂ the interpolants the readers evaluate,
so every reader returns f·cosθo exactly at the nodes. Isotropic files have φi = [0];
anisotropic ones φi over [−π, π].

References: J. Dupuy, W. Jakob, "An adaptive parameterization for efficient material
acquisition and rendering", ACM TOG 37(6) (2018); J. Dupuy et al., "Extracting
microfacet-based BRDF parameters from arbitrary materials with power iterations", CGF 34(4)
(2015); mitsuba-renderer/mitsuba3 ``src/bsdfs/measured.cpp``,
``include/mitsuba/core/distr_2d.h``.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import os
from dataclasses import dataclass

import numpy as np

from .._version import __version__
from ..brdf import BRDF, ORIGINS
from ..channels import luminance_weights as _luminance_weights
from ..channels import Layout
from ..errors import BrdftabError, FormatError, ParameterError
from ..params import suggest
from . import FileFormat, register
from ._marginal2d import Marginal2D
from ._tensor import MAGIC, parse_tensor, read_tensor_file, write_tensor_file

__all__ = ["RGLBSDF", "RGLPayload", "read_rgl", "read_rgl_bytes", "write_rgl", "prepare_rgl", "check_options",
           "model_ndf", "backscatter_ndf", "sigma_table", "DEFAULTS", "OPTIONS"]

HALF_PI = 0.5 * np.pi
TWO_PI = 2.0 * np.pi

#: Default resolutions (format options).
DEFAULTS = {
    "n_theta_i": 9,            # incident elevations, evenly spaced in cosθi over [0, theta_i_max_deg]
    "theta_i_max_deg": 89.0,
    "n_phi_i": 17,             # anisotropic files: incident azimuths over [-180°, 180°]
    "resolution": 32,          # N × N stored samples per incident direction
    "vndf_resolution": 64,     # VNDF table per incident direction
    "ndf_resolution": 128,     # ndf / sigma along θ
    "ndf_phi_resolution": 64,  # ndf / sigma along φ (anisotropic files; isotropic files use 2 rows)
}
#: D is floored at this fraction of its maximum: f·cosθo > 0 needs D > 0 (the stored values
#: are f·cosθo·4σ/D), and Beckmann-type D underflow to 0 far from the normal.
NDF_FLOOR = 1e-4
#: Channels of RGB files (their luminance map uses Rec. 709 Y: channels.luminance_weights).
RGB = ("R", "G", "B")
MAX_RESOLUTION = 4096

OPTIONS = {
    "theta_i_deg": "incident elevations in degrees, ascending in [0, 90) (default: n_theta_i values)",
    "n_theta_i": f"number of incident elevations, evenly spaced in cos(theta_i) from 0 to theta_i_max_deg "
                 f"(default {DEFAULTS['n_theta_i']})",
    "theta_i_max_deg": f"largest incident elevation in degrees (default {DEFAULTS['theta_i_max_deg']:g})",
    "n_phi_i": f"anisotropic files: incident azimuths over [-180, 180] degrees, >= 3 (default {DEFAULTS['n_phi_i']})",
    "resolution": f"stored samples per incident direction, N x N (default {DEFAULTS['resolution']})",
    "vndf_resolution": f"VNDF table per incident direction, n x n (default {DEFAULTS['vndf_resolution']})",
    "ndf_resolution": f"ndf and sigma tables along theta (default {DEFAULTS['ndf_resolution']})",
    "ndf_phi_resolution": f"anisotropic files: ndf and sigma tables along phi (default "
                          f"{DEFAULTS['ndf_phi_resolution']})",
    "anisotropic": "true: phi_i over [-180, 180] degrees; false: phi_i = [0] (default: the model's isotropy)",
    "ndf": "auto (the model's own D, else from back-scattering) | model | backscatter",
    "wavelengths_nm": "spectral models: wavelengths of the 'spectra' field in nm (default: the model's own)",
    "description": "text of the 'description' field (default: the model)",
}
NDF_CHOICES = ("auto", "model", "backscatter")


# ---------------------------------------------------------------------------------------------
# coordinate maps (measured.cpp)


def theta2u(theta):
    return np.sqrt(np.maximum(theta, 0.0) * (2.0 / np.pi))


def u2theta(u):
    return u * u * HALF_PI


def phi2u(phi):
    return (phi + np.pi) / TWO_PI


def u2phi(u):
    return (2.0 * u - 1.0) * np.pi


def elevation(d):
    """Polar angle of unit vectors ``d[..., 3]``, computed as Mitsuba does (2·asin(|d − z|/2))."""
    dist = np.sqrt(d[..., 0] ** 2 + d[..., 1] ** 2 + (d[..., 2] - 1.0) ** 2)
    return 2.0 * np.arcsin(np.clip(0.5 * dist, -1.0, 1.0))


def sph(theta, phi):
    theta, phi = np.broadcast_arrays(np.asarray(theta, float), np.asarray(phi, float))
    s = np.sin(theta)
    return np.stack([s * np.cos(phi), s * np.sin(phi), np.cos(theta)], axis=-1)


# ---------------------------------------------------------------------------------------------
# options


def _int(key, value, lo, hi=MAX_RESOLUTION):
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ParameterError(key, f"expected a whole number, got {value!r}")
    if not lo <= value <= hi:
        raise ParameterError(key, f"expected a whole number in [{lo}, {hi}], got {value}")
    return int(value)


def _number(key, value):
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not math.isfinite(value):
        raise ParameterError(key, f"expected a number, got {value!r}")
    return float(value)


def _numbers(key, value):
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        value = [value]
    if not isinstance(value, (list, tuple, np.ndarray)) or len(value) == 0:
        raise ParameterError(key, f"expected a non-empty list of numbers, got {value!r}")
    return np.array([_number(key, v) for v in value])


def theta_i_nodes(n: int, top: float) -> np.ndarray:
    """``n`` incident elevations [rad] from 0 to ``top``, evenly spaced in cosθi (denser towards
    grazing, where the reflectance changes fastest with θi)."""
    if n == 1:
        return np.zeros(1)
    return np.arccos(np.linspace(1.0, math.cos(top), n))


def check_options(**options) -> dict:
    """Validate the format options (names, types, ranges); returns them resolved (defaults filled in)."""
    for key in options:
        if key not in OPTIONS:
            raise ParameterError(key, f"unknown option for format rgl{suggest(key, OPTIONS)}; "
                                      f"valid: {', '.join(OPTIONS)}")
    return _resolve_options(**options)


def _resolve_options(theta_i_deg=None, n_theta_i=None, theta_i_max_deg=None, n_phi_i=None, resolution=None,
                  vndf_resolution=None, ndf_resolution=None, ndf_phi_resolution=None, anisotropic=None, ndf="auto",
                  wavelengths_nm=None, description=None):
    out = {}
    if theta_i_deg is not None:
        if n_theta_i is not None or theta_i_max_deg is not None:
            raise ParameterError("theta_i_deg", "give either theta_i_deg or n_theta_i / theta_i_max_deg, not both")
        t = _numbers("theta_i_deg", theta_i_deg)
        if np.any(t < 0) or np.any(t >= 90):
            raise ParameterError("theta_i_deg", "incident elevations must lie in [0, 90) degrees")
        if np.any(np.diff(t) <= 0):
            raise ParameterError("theta_i_deg", "incident elevations must increase strictly")
        if np.any(np.diff(np.radians(t).astype(np.float32)) <= 0):
            raise ParameterError("theta_i_deg", "incident elevations are too close to tell apart in float32")
        out["theta_i"] = np.radians(t)
    else:
        n = _int("n_theta_i", DEFAULTS["n_theta_i"] if n_theta_i is None else n_theta_i, 1, 1024)
        top = DEFAULTS["theta_i_max_deg"] if theta_i_max_deg is None else _number("theta_i_max_deg", theta_i_max_deg)
        if not 0 < top < 90:
            raise ParameterError("theta_i_max_deg", f"expected a number in (0, 90) degrees, got {top:g}")
        out["theta_i"] = theta_i_nodes(n, math.radians(top))
    if anisotropic is not None and not isinstance(anisotropic, (bool, np.bool_)):
        raise ParameterError("anisotropic", f"expected true or false, got {anisotropic!r}")
    out["anisotropic"] = None if anisotropic is None else bool(anisotropic)
    if n_phi_i is not None:
        if anisotropic is False:
            raise ParameterError("n_phi_i", "only used for anisotropic files (anisotropic is false)")
        out["n_phi_i"] = _int("n_phi_i", n_phi_i, 3, 1024)
    else:
        out["n_phi_i"] = DEFAULTS["n_phi_i"]
    for key, value in (("resolution", resolution), ("vndf_resolution", vndf_resolution),
                       ("ndf_resolution", ndf_resolution), ("ndf_phi_resolution", ndf_phi_resolution)):
        out[key] = DEFAULTS[key] if value is None else _int(key, value, 2)
    if ndf not in NDF_CHOICES:
        raise ParameterError("ndf", f"expected one of {', '.join(NDF_CHOICES)}, got {ndf!r}")
    out["ndf"] = ndf
    if wavelengths_nm is not None:
        lam = _numbers("wavelengths_nm", wavelengths_nm)
        if np.any(lam <= 0) or np.any(np.diff(lam) <= 0):
            raise ParameterError("wavelengths_nm", "expected positive wavelengths in nm, increasing strictly")
        out["wavelengths"] = lam
    else:
        out["wavelengths"] = None
    if description is not None and not isinstance(description, str):
        raise ParameterError("description", f"expected a string, got {description!r}")
    out["description"] = description
    return out


# ---------------------------------------------------------------------------------------------
# the NDF: the model's own, or one extracted from back-scattering


def model_ndf(brdf):
    """The model's own normal distribution as a callable ``h[..., 3] -> D [sr⁻¹]``, or None.

    Asks by duck typing: ``brdf.ndf(h)``; a sum (``terms``) gives the narrowest lobe among
    its terms that have one (largest D at the normal); a scaled model (``term``) its term's.
    """
    ndf = getattr(brdf, "ndf", None)
    if callable(ndf):
        return ndf
    terms = getattr(brdf, "terms", None)
    if isinstance(terms, (list, tuple)):
        found = [f for f in (model_ndf(t) for t in terms) if f is not None]
        if found:
            z = np.array([[0.0, 0.0, 1.0]])
            return max(found, key=lambda f: float(np.nan_to_num(np.asarray(f(z), float).ravel()[0])))
        return None
    term = getattr(brdf, "term", None)
    if isinstance(term, BRDF):
        return model_ndf(term)
    return None


def _azimuthal_kernel(theta_a, theta_b):
    """∫₀^{2π} max(0, ω(θa, 0)·ω(θb, φ)) dφ, closed form, for all pairs ``[A, B]``."""
    a = np.sin(theta_a)[:, None] * np.sin(theta_b)[None, :]
    b = np.cos(theta_a)[:, None] * np.cos(theta_b)[None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        phi_c = np.arccos(np.clip(-b / a, -1.0, 1.0))
        partial = 2.0 * (b * phi_c + a * np.sin(phi_c))
    return np.where(b >= a, TWO_PI * b, np.where(b <= -a, 0.0, partial))


def _theta_nodes(n=512):
    """Gauss–Legendre nodes in u = sqrt(2θ/π) (dense near the normal); θ and sinθ dθ weights."""
    from ..quadrature import gauss_legendre

    u, wu = gauss_legendre(n, 0.0, 1.0)
    theta = u2theta(u)
    return theta, np.sin(theta) * np.pi * u * wu


def backscatter_ndf(brdf, wavelengths=None, *, n_theta=256, n_phi=8, max_iter=500, tol=1e-10):
    """An isotropic NDF from the back-scattering of ``brdf``, by power iteration.

    For a microfacet BRDF, f(ω, ω) = D(ω)·G1(ω)·F/(4cos²θ) with G1 = cosθ/σ(ω) and
    σ(ω) = ∫ D(m)⟨ω·m⟩ dm, so D(ω) ∝ f(ω, ω)·cosθ·σ(ω): D is the positive eigenvector of
    that linear map (Dupuy et al. 2015). f(ω, ω) is averaged over ``n_phi`` azimuths and
    weighted to a luminance. Returns a callable ``h[..., 3] -> D [sr⁻¹]`` normalized so that
    ∫ D cosθ dω = 1.
    """
    theta, area = _theta_nodes(n_theta)
    lam = brdf.layout.resolve(wavelengths)
    lw = _luminance_weights(brdf.channels, lam)

    def backscatter(th):
        phis = (np.arange(n_phi) + 0.5) * (TWO_PI / n_phi)
        w = sph(th[:, None], phis[None, :]).reshape(-1, 3)
        f = brdf.eval(w, w, lam) @ lw
        return np.maximum(np.nan_to_num(f.reshape(th.size, n_phi).mean(axis=1)), 0.0)

    fb = backscatter(theta)
    if not np.any(fb > 0):
        raise BrdftabError(f"cannot derive an NDF for {brdf.name!r}: its back-scattering f(w, w) is zero everywhere")
    kernel = _azimuthal_kernel(theta, theta) * area[None, :]
    weight = fb * np.cos(theta)
    d = np.ones_like(theta)
    norm = TWO_PI * np.sum(area * np.cos(theta) * d)
    d /= norm
    scale = 1.0
    for _ in range(max_iter):
        new = weight * (kernel @ d)
        scale = TWO_PI * np.sum(area * np.cos(theta) * new)
        new /= scale
        done = np.max(np.abs(new - d)) <= tol * np.max(new)
        d = new
        if done:
            break
    # D anywhere from the fixed point: D(θ) = f(θ, θ)·cosθ·σ(θ)/scale, tabulated finely in u.
    u_fine = np.linspace(0.0, 1.0, 1025)
    th_fine = u2theta(u_fine)
    sigma_fine = (_azimuthal_kernel(th_fine, theta) * area[None, :]) @ d
    d_fine = backscatter(th_fine) * np.cos(th_fine) * sigma_fine / scale

    def ndf(h):
        h = np.asarray(h, float)
        u = theta2u(np.arccos(np.clip(h[..., 2], -1.0, 1.0)))
        return np.where(h[..., 2] > 0, np.interp(u, u_fine, d_fine), 0.0)

    return ndf


def sigma_table(ndf, nx: int, ny: int, isotropic: bool, *, n_theta: int = 512) -> np.ndarray:
    """The projected area σ(ω) = ∫ D(m) max(0, ω·m) dm on the ndf grid, ``[ny, nx]``.

    Node (x, y) is ω = sph(u2theta(x/(nx−1)), u2phi(y/(ny−1))). Quadrature over m: Gauss–Legendre
    in u = sqrt(2θm/π) (dense near the normal) × a periodic rule in φm. For an isotropic D the
    φm integral is done in closed form; otherwise it is a circular convolution in φ (FFT), with
    4·(ny−1) or more azimuths. Equals cosθ·(1 + Λ(ω)) for a Smith microfacet D.
    """
    theta_w = u2theta(np.linspace(0.0, 1.0, nx))
    if isotropic:
        theta, area = _theta_nodes(n_theta)
        d = ndf(sph(theta, 0.0))
        return np.tile((_azimuthal_kernel(theta_w, theta) * area[None, :]) @ d, (ny, 1))
    theta, area = _theta_nodes(n_theta // 2)
    step = -(-256 // (ny - 1))  # quadrature azimuths per table interval
    p = step * (ny - 1)
    phi = -np.pi + np.arange(p) * (TWO_PI / p)
    d = ndf(sph(theta[:, None], phi[None, :])) * (area[:, None] * (TWO_PI / p))  # [K, P]
    d_hat = np.fft.rfft(d, axis=1)
    delta = np.arange(p) * (TWO_PI / p)
    out = np.empty((ny, nx))
    for j, tw in enumerate(theta_w):
        # g(Δφ) = max(0, ω(θw, φ)·m(θk, φ − Δφ)) for every θk: [K, P]
        g = np.maximum(0.0, np.sin(tw) * np.sin(theta)[:, None] * np.cos(delta)[None, :]
                       + np.cos(tw) * np.cos(theta)[:, None])
        conv = np.fft.irfft(np.sum(d_hat * np.fft.rfft(g, axis=1), axis=0), n=p)  # σ at φ = −π + l·2π/P
        out[:, j] = np.append(conv[::step], conv[0])
    return out


# ---------------------------------------------------------------------------------------------
# the warp geometry shared by writer and reader


def _bilinear(table):
    return Marginal2D(table, normalize=False, sampling=False)


def _node_geometry(vndf: Marginal2D, theta_i, phi_i, n, isotropic):
    """Directions of the stored sample nodes: wi, wo, u_m, each ``[Nφi, Nθi, N, N, ...]``.

    Node (k, l) of slice (a, b) sits at the unit-square point (k/(N−1), l/(N−1)); the VNDF warp
    of that slice maps it to the half-vector coordinates u_m, hence m and ωo = 2(m·ωi)m − ωi.
    """
    n_phi, n_theta = phi_i.size, theta_i.size
    grid = np.arange(n) / (n - 1)
    uy, ux = np.meshgrid(grid, grid, indexing="ij")
    shape = (n_phi, n_theta, n, n)
    nodes = np.stack([np.broadcast_to(ux, shape), np.broadcast_to(uy, shape)], axis=-1).reshape(-1, 2)
    ph = np.broadcast_to(phi_i[:, None, None, None], shape).ravel()
    th = np.broadcast_to(theta_i[None, :, None, None], shape).ravel()
    u_m, _ = vndf.sample(nodes, (ph, th))
    phi_m = u2phi(u_m[:, 1]) + (ph if isotropic else 0.0)
    m = sph(u2theta(u_m[:, 0]), phi_m)
    wi = sph(th, ph)
    wo = 2.0 * np.sum(m * wi, axis=-1, keepdims=True) * m - wi
    return wi, wo, u_m, (th, ph), shape


# ---------------------------------------------------------------------------------------------
# writing


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


def _ndf_tables(ndf, nx, ny, anisotropic, name):
    """Floored D as a callable, and the float32 ``ndf`` and ``sigma`` tables ``[ny, nx]``."""
    ux, uy = np.linspace(0.0, 1.0, nx), np.linspace(0.0, 1.0, ny)
    with np.errstate(all="ignore"):
        if anisotropic:
            table = np.asarray(ndf(sph(u2theta(ux)[None, :], u2phi(uy)[:, None])), float)
        else:
            table = np.tile(np.asarray(ndf(sph(u2theta(ux), 0.0)), float), (ny, 1))
    if table.shape != (ny, nx) or not np.all(np.isfinite(table)) or np.any(table < 0) or not np.any(table > 0):
        raise BrdftabError(f"the normal distribution of {name!r} is not finite and positive")
    floor = NDF_FLOOR * table.max()

    def d_floored(h):
        with np.errstate(all="ignore"):
            return np.maximum(np.nan_to_num(np.asarray(ndf(h), float)), floor)

    ndf32 = np.maximum(table, floor).astype(np.float32)
    sigma = sigma_table(d_floored, nx, ny, isotropic=not anisotropic)
    sigma32 = np.maximum(sigma, np.finfo(np.float32).tiny).astype(np.float32)
    return d_floored, ndf32, sigma32


def _vndf_table(d, sigma_interp, th_i, ph_i, nv):
    """``vndf[Nφi, Nθi, nv, nv]`` = D(m)⟨ωi·m⟩/σ(ωi) × 2π² u_x sinθm (Jacobian of u -> m), float32.

    m = sph(u2theta(x), u2phi(y)): φm relative to φi (= 0) for isotropic files, absolute for
    anisotropic ones.
    """
    g = np.linspace(0.0, 1.0, nv)
    vy, vx = np.meshgrid(g, g, indexing="ij")
    th_m = u2theta(vx)
    m = sph(th_m, u2phi(vy))
    dm = d(m) * (2.0 * np.pi ** 2) * vx * np.sin(th_m)
    wi = sph(th_i[None, :], ph_i[:, None])  # [Nφi, Nθi, 3]
    u_wi = np.stack(np.broadcast_arrays(theta2u(th_i)[None, :], phi2u(ph_i)[:, None]), axis=-1)
    sig = sigma_interp.eval(u_wi.reshape(-1, 2)).reshape(ph_i.size, th_i.size)
    vndf = np.maximum(np.einsum("yxk,abk->abyx", m, wi), 0.0) * dm[None, None] / sig[:, :, None, None]
    return vndf.astype(np.float32)


def _luminance(spectra32, lam):
    """Non-negative luminance of the stored values (plus a tiny floor: no empty slice), float32."""
    weights = _luminance_weights(RGB, lam)
    lum = np.maximum(np.einsum("abcyx,c->abyx", spectra32.astype(np.float64), weights), 0.0)
    top = lum.max(axis=(2, 3), keepdims=True)
    return (lum + np.where(top > 0, 1e-6 * top, 1.0)).astype(np.float32)


def _check_size(brdf, n_slices, opts, n_chan):
    """Refuse a file whose working arrays would not fit in this machine's memory."""
    n, nv = opts["resolution"], opts["vndf_resolution"]
    need = 8.0 * n_slices * (n * n * (n_chan + 24) + 2 * nv * nv)  # float64 values + node geometry
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

    ``options`` are the format options (:data:`OPTIONS`). A :class:`RGLBSDF` read from a file
    and written with no options is copied as it is.
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
    ndf, source = _choose_ndf(brdf, opts["ndf"], lam)

    theta_i = opts["theta_i"].astype(np.float32)
    phi_i = (np.linspace(-np.pi, np.pi, opts["n_phi_i"]) if anisotropic else np.zeros(1)).astype(np.float32)
    _check_size(brdf, phi_i.size * theta_i.size, opts, 3 if lam is None else lam.size)
    th_i, ph_i = theta_i.astype(np.float64), phi_i.astype(np.float64)

    ny = opts["ndf_phi_resolution"] if anisotropic else 2
    d, ndf32, sigma32 = _ndf_tables(ndf, opts["ndf_resolution"], ny, anisotropic, brdf.name)
    ndf_interp, sigma_interp = _bilinear(ndf32), _bilinear(sigma32)
    vndf32 = _vndf_table(d, sigma_interp, th_i, ph_i, opts["vndf_resolution"])
    warp = Marginal2D(vndf32, (phi_i, theta_i))

    # f·cosθo·4σ̂/D̂ at the warped nodes (0 where ωo is below the horizon)
    wi, wo, u_m, (th, ph), shape = _node_geometry(warp, th_i, ph_i, opts["resolution"], not anisotropic)
    valid = wo[:, 2] > 0
    n_out = len(brdf.channels) if lam is None else lam.size
    values = np.zeros((wi.shape[0], n_out))
    if valid.any():
        f = brdf.eval(wi[valid], wo[valid], lam)
        d_hat = ndf_interp.eval(u_m[valid])
        s_hat = sigma_interp.eval(np.stack([theta2u(th[valid]), phi2u(ph[valid])], axis=-1))
        values[valid] = f * (wo[valid, 2] * 4.0 * s_hat / d_hat)[:, None]
    if not np.all(np.isfinite(values)):
        bad = int((~np.isfinite(values)).sum())
        raise BrdftabError(f"{brdf.name!r} gave {bad} non-finite samples while writing an RGL .bsdf file")
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
        "isotropic": bool(brdf.isotropic),
        "reciprocal": bool(brdf.reciprocal),
        "origin": str(getattr(brdf, "origin", "analytic")),
        "convention": "rgb/spectra = f(wi, wo) cos(theta_o) 4 sigma(wi) / D(m); wi = incident (conditioning) "
                      "direction, m = normalize(wi + wo)",
    }
    fields = {
        "description": _text(description),
        "jacobian": np.ones(1, np.uint8),
        "theta_i": theta_i,
        "phi_i": phi_i,
        "ndf": ndf32,
        "sigma": sigma32,
        "vndf": vndf32,
        "luminance": _luminance(spectra32, lam),
    }
    if lam is None:
        fields["rgb"] = spectra32
    else:
        fields["spectra"] = spectra32
        fields["wavelengths"] = lam.astype(np.float32)
    fields["provenance"] = _text(json.dumps(provenance, sort_keys=True, default=_json_default))
    return RGLPayload(fields)


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


# ---------------------------------------------------------------------------------------------
# reading


def _field(fields, name, where, ndim, dtype):
    if name not in fields:
        raise FormatError(f"{where}: missing field {name!r} (not an RGL .bsdf file?)")
    a = fields[name]
    if a.ndim != ndim or a.dtype != np.dtype(dtype):
        raise FormatError(f"{where}: field {name!r} must be {ndim}-D {np.dtype(dtype).name}, got "
                          f"{a.ndim}-D {a.dtype.name} of shape {a.shape}")
    return a


def _validate(fields: dict, where: str):
    """Check the fields as Mitsuba's ``measured`` plugin does, and more (values)."""
    f = {}
    f["description"] = _field(fields, "description", where, 1, np.uint8)
    f["jacobian"] = _field(fields, "jacobian", where, 1, np.uint8)
    if f["jacobian"].shape != (1,):
        raise FormatError(f"{where}: field 'jacobian' must have shape [1], got {list(f['jacobian'].shape)}")
    for name in ("theta_i", "phi_i"):
        f[name] = _field(fields, name, where, 1, np.float32)
    spectral = "wavelengths" in fields
    key = "spectra" if spectral else "rgb"
    if spectral:
        f["wavelengths"] = _field(fields, "wavelengths", where, 1, np.float32)
    for name in ("ndf", "sigma"):
        f[name] = _field(fields, name, where, 2, np.float32)
    f["vndf"] = _field(fields, "vndf", where, 4, np.float32)
    f["luminance"] = _field(fields, "luminance", where, 4, np.float32)
    if not spectral and "rgb" not in fields and "spectra" in fields:
        raise FormatError(f"{where}: field 'spectra' without 'wavelengths' (a spectral file needs both)")
    f[key] = _field(fields, key, where, 5, np.float32)
    n_phi, n_theta = f["phi_i"].size, f["theta_i"].size
    n_chan = f["wavelengths"].size if spectral else 3
    if n_phi < 1 or n_theta < 1 or n_chan < 1:
        raise FormatError(f"{where}: theta_i, phi_i{' and wavelengths' if spectral else ''} need at least one value")
    spec = f[key]
    checks = [
        ("vndf", f["vndf"].shape[:2] == (n_phi, n_theta), f"[{n_phi}, {n_theta}, H, W]"),
        ("luminance", f["luminance"].shape[:2] == (n_phi, n_theta)
         and f["luminance"].shape[2] == f["luminance"].shape[3], f"[{n_phi}, {n_theta}, N, N]"),
        (key, spec.shape[:3] == (n_phi, n_theta, n_chan) and spec.shape[3:] == f["luminance"].shape[2:],
         f"[{n_phi}, {n_theta}, {n_chan}, N, N] with N as in luminance"),
    ]
    for name, ok, expected in checks:
        if not ok:
            raise FormatError(f"{where}: field {name!r} has shape {list(fields[name].shape)}, expected {expected}")
    for name in ("ndf", "sigma", "vndf", "luminance", key):
        if min(f[name].shape[-2:]) < 2:
            raise FormatError(f"{where}: field {name!r} needs at least 2 x 2 values per table, got shape "
                              f"{list(f[name].shape)}")
    for name in ("theta_i", "phi_i", "ndf", "sigma", "vndf", "luminance", key) + (("wavelengths",) if spectral else ()):
        if not np.all(np.isfinite(f[name])):
            raise FormatError(f"{where}: field {name!r} has {int((~np.isfinite(f[name])).sum())} non-finite values")
    th, ph = f["theta_i"].astype(np.float64), f["phi_i"].astype(np.float64)
    if np.any(np.diff(th) <= 0) or th[0] < 0 or th[-1] > HALF_PI + 1e-6:
        raise FormatError(f"{where}: theta_i must increase strictly within [0, 90] degrees")
    if np.any(np.diff(ph) <= 0):
        raise FormatError(f"{where}: phi_i must increase strictly")
    if np.any(np.abs(ph) > np.pi + 1e-5):
        raise FormatError(f"{where}: phi_i must lie within [-180, 180] degrees")
    reduction = 0
    if n_phi > 2:
        # Mitsuba: reduction = rint(2π / (φi[-1] − φi[0])); it mirrors wi into
        # φ ∈ [−π, −π + 2π/reduction], so the stored φi must cover exactly that.
        ratio = TWO_PI / (ph[-1] - ph[0])
        reduction = int(np.rint(ratio)) if 0.5 <= ratio < 4.5 else 0
        ok = (reduction in (1, 2, 4) and abs(ph[0] + np.pi) < 1e-3
              and abs(ph[-1] - (TWO_PI / max(reduction, 1) - np.pi)) < 1e-3)
        if not ok:
            raise FormatError(f"{where}: phi_i covers [{np.degrees(ph[0]):.6g}, {np.degrees(ph[-1]):.6g}] degrees; an "
                              "anisotropic file must cover [-180, 180], [-180, 0] or [-180, -90] degrees")
    if spectral:
        lam = f["wavelengths"].astype(np.float64)
        if np.any(lam <= 0) or np.any(np.diff(lam) <= 0):
            raise FormatError(f"{where}: wavelengths must be positive and increase strictly")
    if np.any(f["ndf"] < 0):
        raise FormatError(f"{where}: field 'ndf' has negative values")
    if not np.all(f["sigma"] > 0):
        raise FormatError(f"{where}: field 'sigma' must be positive (it divides)")
    for name in ("vndf", "luminance"):
        a = f[name].astype(np.float64)
        if np.any(a < 0):
            raise FormatError(f"{where}: field {name!r} has negative values (it is a density)")
        if np.any(a.reshape(n_phi * n_theta, -1).max(axis=1) <= 0):
            raise FormatError(f"{where}: field {name!r} has an all-zero slice (it is a density)")
    return f, spectral, key, reduction


class _Axis:
    def __init__(self, name, values):
        self.name = name
        self.values = np.asarray(values, float)

    def __len__(self):
        return self.values.size


class RGLGrid:
    """The sample layout of an RGL file (not a brdftab grid: the samples sit on the VNDF warp).

    ``axes`` are the incident directions (φi, θi); each carries ``N × N`` warped samples.
    """

    def __init__(self, bsdf: "RGLBSDF"):
        self.axes = (_Axis("phi_i", bsdf.phi_i), _Axis("theta_i", bsdf.theta_i))
        self.dims = ("phi_i", "theta_i", "sample_y", "sample_x")
        n = bsdf.resolution
        self.shape = (bsdf.phi_i.size, bsdf.theta_i.size, n, n)
        self.size = int(np.prod(self.shape))
        self._text = (f"RGL adaptive parameterization: {bsdf.phi_i.size} phi_i x {bsdf.theta_i.size} theta_i x "
                      f"{n}x{n} warped samples (vndf {bsdf.fields['vndf'].shape[3]}x{bsdf.fields['vndf'].shape[2]}, "
                      f"ndf {bsdf.fields['ndf'].shape[1]}x{bsdf.fields['ndf'].shape[0]})"
                      f"{'' if bsdf.isotropic else ', anisotropic'}")

    def describe(self) -> str:
        return self._text

    def equals(self, other) -> bool:
        return other is self


class RGLBSDF(BRDF):
    """A BRDF read from an RGL ``.bsdf`` file; evaluates as Mitsuba 3's ``measured`` plugin.

    ``eval`` returns f = (Mitsuba's f·cosθo) / cosθo. Spectral files evaluate at wavelengths
    within their ``wavelengths`` range (linear in between); RGB files have channels R, G, B.

    Table-like views for ``brdftab info``: ``grid`` (:class:`RGLGrid`), ``values`` (f at the
    stored sample nodes, ``[Nφi, Nθi, N, N, C]``, 0 where ωo is below the horizon) and ``ds``
    (an ``xarray.Dataset`` of those values with the file's description and provenance).
    """

    name = "rgl-bsdf"

    def __init__(self, fields: dict, source: str = "<fields>"):
        f, spectral, key, reduction = _validate(fields, source)
        self.fields = {k: fields[k] for k in fields}
        self.source = source
        self.theta_i = f["theta_i"]
        self.phi_i = f["phi_i"]
        self.isotropic = self.phi_i.size <= 2
        self.reduction = reduction
        self.jacobian = bool(f["jacobian"][0])
        self.description = bytes(f["description"]).decode("utf-8", errors="replace")
        self.provenance = self._provenance(fields)
        # brdftab records origin and reciprocity in its files; a file without them (the RGL
        # database's measurements) is of unknown origin and declares no reciprocity. Even the
        # file of a reciprocal model is not: it is conditioned on wi (f·cosθo tabulated per
        # incident direction), so its interpolant is reciprocal only approximately — it declares
        # itself non-reciprocal and keeps the source's word in `source_reciprocal`.
        self.source_reciprocal = self.provenance.get("reciprocal")
        self.reciprocity_declared = "reciprocal" in self.provenance
        self.reciprocal = False
        origin = self.provenance.get("origin", "analytic" if "model" in self.provenance else "unknown")
        self.origin = origin if origin in ORIGINS else "unknown"
        self.resolution = f[key].shape[-1]
        if spectral:
            self._lam = f["wavelengths"].astype(np.float64)
            self.layout = Layout(None, self._lam)
        else:
            self._lam = None
            self.layout = Layout(RGB)
        params = (self.phi_i, self.theta_i)
        self._ndf = _bilinear(f["ndf"])
        self._sigma = _bilinear(f["sigma"])
        self._vndf = Marginal2D(f["vndf"], params)
        spec = f[key]
        # [slices, N, N, C] for one gather of all channels (parameter strides as the vndf's)
        self._spectra = np.moveaxis(spec.reshape((-1,) + spec.shape[2:]), 1, -1).astype(np.float64)
        self._values = None
        self._ds = None

    @staticmethod
    def _provenance(fields):
        raw = fields.get("provenance")
        if raw is None or raw.dtype != np.uint8 or raw.ndim != 1:
            return {}
        try:
            out = json.loads(bytes(raw).decode("utf-8"))
        except (UnicodeDecodeError, ValueError):
            return {}
        return out if isinstance(out, dict) else {}

    @property
    def parameters(self) -> dict:
        out = {"description": self.description}
        if "model" in self.provenance:
            out["source_model"] = {"model": self.provenance.get("model"),
                                   "parameters": self.provenance.get("parameters", {})}
        return out

    def describe(self) -> str:
        return f"RGL .bsdf ({self.description})"

    # --------------------------------------------------------------------------------
    def _channel_weights(self, lam, n):
        """(stored channel index lo, hi, weight of hi) per output channel."""
        if lam is None:
            idx = np.arange(3)
            return idx, idx, np.zeros(3)
        stored = self._lam
        lo_, hi_ = stored[0], stored[-1]
        if np.any(lam < lo_ - 1e-9) or np.any(lam > hi_ + 1e-9):
            raise ParameterError("wavelengths", f"outside the file's wavelengths [{lo_:g}, {hi_:g}] nm")
        if stored.size == 1:
            z = np.zeros(lam.size, np.intp)
            return z, z, np.zeros(lam.size)
        j = np.clip(np.searchsorted(stored, lam, side="left") - 1, 0, stored.size - 2)
        t = np.clip((lam - stored[j]) / (stored[j + 1] - stored[j]), 0.0, 1.0)
        return j, j + 1, t

    @property
    def theta_hold(self) -> float:
        """Elevation [rad] beyond which f is held (see :meth:`_eval`): 90° − 180°/resolution
        (84.4° for 32 × 32 samples, 87.2° for 64 × 64)."""
        return float(np.pi / 2 - np.pi / self.resolution)

    def _eval(self, wi, wo, lam, n):
        """f = (f·cosθo)/cosθo, with f **held** beyond the last well-conditioned elevation.

        The file stores f·cosθo on 32 × 32 (``resolution``) warped samples; in the cells that
        straddle the horizon the interpolated f·cosθo does not vanish as cosθo does, so the
        quotient grows without bound at grazing ωo (about 2× a Lambertian's f at 88°, 9× at
        89.9°). Beyond θ_hold = 90° − 180°/resolution (:attr:`theta_hold`) f is therefore
        taken at θ_hold with the same azimuth. Renderers use f·cosθo (:meth:`eval_cos`, as
        Mitsuba evaluates the file); the hold changes the directional albedo by the part of the
        band θo > θ_hold only (tested against Mitsuba's own albedo of the same file)."""
        lo, hi, t = self._channel_weights(lam, n)
        out = np.empty((wi.shape[0], lo.size))
        c0 = np.cos(self.theta_hold)
        s0 = np.sin(self.theta_hold)
        for start in range(0, wi.shape[0], 1 << 14):
            sl = slice(start, start + (1 << 14))
            w = wo[sl]
            low = w[:, 2] < c0
            if low.any():
                w = w.copy()
                r = np.hypot(w[low, 0], w[low, 1])
                w[low, 0] *= s0 / r
                w[low, 1] *= s0 / r
                w[low, 2] = c0
            out[sl] = self._eval_cos(wi[sl], w, lo, hi, t) / w[:, 2:3]
        return out

    def eval_cos(self, wi, wo, wavelengths=None):
        """f·cosθo exactly as Mitsuba 3's ``measured`` plugin evaluates the file (no hold)."""
        from ..geometry import as_directions

        wi, wo = as_directions(wi, wo)
        lead = wi.shape[:-1]
        wi, wo = wi.reshape(-1, 3), wo.reshape(-1, 3)
        lam = self.layout.resolve(wavelengths)
        lo, hi, t = self._channel_weights(lam, self.layout.n_out(lam))
        out = np.zeros((wi.shape[0], lo.size))
        above = (wi[:, 2] > 1e-12) & (wo[:, 2] > 1e-12)
        if above.any():
            out[above] = self._eval_cos(wi[above], wo[above], lo, hi, t)
        return out.reshape(lead + (lo.size,))

    def _eval_cos(self, wi, wo, lo, hi, t):
        """Mitsuba's ``eval``: f·cosθo at ``(M, 3)`` pairs above the horizon."""
        if not self.isotropic and self.reduction >= 2:
            # mulsign_neg(v, s) = v · (s >= 0 ? −1 : 1): wi goes to y <= 0 (and x <= 0 for a
            # quarter); reduction 2 turns both axes by the sign of y (a rotation by π).
            sy = wi[:, 1]
            sx = wi[:, 0] if self.reduction == 4 else sy
            flip = np.stack([np.where(sx >= 0, -1.0, 1.0), np.where(sy >= 0, -1.0, 1.0), np.ones_like(sy)], axis=-1)
            wi, wo = wi * flip, wo * flip
        m = wi + wo
        m = m / np.linalg.norm(m, axis=-1, keepdims=True)
        th_i, ph_i = elevation(wi), np.arctan2(wi[:, 1], wi[:, 0])
        th_m, ph_m = elevation(m), np.arctan2(m[:, 1], m[:, 0])
        u_wi = np.stack([theta2u(th_i), phi2u(ph_i)], axis=-1)
        uy = phi2u(ph_m - ph_i if self.isotropic else ph_m)
        u_m = np.stack([theta2u(th_m), uy - np.floor(uy)], axis=-1)
        params = (ph_i, th_i)
        sample, _ = self._vndf.invert(u_m, params)
        spec = self._lookup_spectra(sample, params)  # [M, C stored]
        out = spec[:, lo] * (1.0 - t) + spec[:, hi] * t
        if self.jacobian:
            out = out * (self._ndf.eval(u_m) / (4.0 * self._sigma.eval(u_wi)))[:, None]
        return out

    def _lookup_spectra(self, sample, params):
        sl, wt = self._vndf._corners(params)
        n = self.resolution
        x = np.clip(sample[:, 0], 0.0, 1.0) * (n - 1)
        y = np.clip(sample[:, 1], 0.0, 1.0) * (n - 1)
        ix = np.minimum(x.astype(np.intp), n - 2)
        iy = np.minimum(y.astype(np.intp), n - 2)
        tx, ty = (x - ix)[:, None], (y - iy)[:, None]
        out = 0.0
        for c in range(sl.shape[0]):
            s = sl[c]
            v00 = self._spectra[s, iy, ix]
            v10 = self._spectra[s, iy, ix + 1]
            v01 = self._spectra[s, iy + 1, ix]
            v11 = self._spectra[s, iy + 1, ix + 1]
            v0 = v00 + tx * (v10 - v00)
            v1 = v01 + tx * (v11 - v01)
            out = out + wt[c][:, None] * (v0 + ty * (v1 - v0))
        return out

    def ndf(self, h):
        """The file's own normal distribution (its ``ndf`` table, bilinear) at unit normals
        ``h[..., 3]``: a file written again with other resolutions keeps it."""
        h = np.asarray(h, float)
        lead = h.shape[:-1]
        h = h.reshape(-1, 3)
        u = np.stack([theta2u(elevation(h)), phi2u(np.arctan2(h[:, 1], h[:, 0]))], axis=-1)
        return np.where(h[:, 2] > 0, self._ndf.eval(u), 0.0).reshape(lead)

    # --------------------------------------------------------------------------------
    # table-like views

    @property
    def grid(self) -> RGLGrid:
        return RGLGrid(self)

    @property
    def values(self) -> np.ndarray:
        """f [sr⁻¹] at the stored sample nodes, ``[Nφi, Nθi, N, N, C]`` (0 below the horizon)."""
        if self._values is None:
            wi, wo, u_m, (th, ph), shape = _node_geometry(self._vndf, self.theta_i.astype(np.float64),
                                                          self.phi_i.astype(np.float64), self.resolution,
                                                          self.isotropic)
            out = np.zeros((wi.shape[0], len(self.layout.channels) if self._lam is None else self._lam.size))
            ok = wo[:, 2] > 1e-12
            with np.errstate(all="ignore"):
                # at the stored nodes the quotient is exact (no hold: the node is data)
                out[ok] = self.eval_cos(wi[ok], wo[ok]) / wo[ok, 2:3]
            self._values = out.reshape(shape + (out.shape[1],))
        return self._values

    def statistics(self) -> dict:
        """Count and range of :attr:`values` (as :meth:`brdftab.table.Table.statistics`)."""
        v = self.values
        fin = np.isfinite(v)
        good = v[fin]
        return {"dtype": str(v.dtype), "samples": int(v.size), "min": float(good.min()) if good.size else None,
                "max": float(good.max()) if good.size else None, "nonfinite": int(v.size - fin.sum()),
                "negative": int((good < 0).sum()), "missing": 0}

    @property
    def ds(self):
        if self._ds is None:
            import xarray as xr

            chan = ("wavelength", self._lam) if self._lam is not None else ("channel", np.array(RGB, dtype=object))
            coords = {"phi_i": ("phi_i", self.phi_i.astype(np.float64), {"units": "rad"}),
                      "theta_i": ("theta_i", self.theta_i.astype(np.float64), {"units": "rad"}),
                      chan[0]: (chan[0], chan[1], {"units": "nm"} if self._lam is not None else {})}
            var = xr.Variable(("phi_i", "theta_i", "sample_y", "sample_x", chan[0]), self.values,
                              attrs={"units": "sr-1", "long_name": "f_r at the stored (warped) sample nodes"})
            attrs = {"format": "rgl", "parameterization": "rgl-adaptive (Dupuy & Jakob 2018)",
                     "description": self.description, "grid": self.grid.describe(),
                     "isotropic": int(self.isotropic), "reciprocal": int(self.reciprocal),
                     "origin": self.origin,
                     "jacobian": int(self.jacobian)}
            for k in ("model", "brdftab_version", "created", "ndf_source"):
                if k in self.provenance:
                    attrs[k] = str(self.provenance[k])
            if "parameters" in self.provenance:
                attrs["parameters"] = json.dumps(self.provenance["parameters"], sort_keys=True, default=str)
            self._ds = xr.Dataset({"brdf": var}, coords=coords, attrs=attrs)
        return self._ds


def read_rgl(path) -> RGLBSDF:
    """Read an RGL ``.bsdf`` file (RGB or spectral, isotropic or anisotropic)."""
    fields = read_tensor_file(path)
    return RGLBSDF(fields, str(path))


def read_rgl_bytes(data: bytes, where: str = "<bytes>") -> RGLBSDF:
    return RGLBSDF(parse_tensor(data, where), where)


def _native_grid(requested, options):
    return None  # the file has its own sample layout; resolutions are format options


register(FileFormat(
    name="rgl",
    extensions=(".bsdf",),
    description="Mitsuba 3 / RGL tabulated BSDF (tensor file for the 'measured' plugin; RGB or spectral, "
                "isotropic or anisotropic)",
    read=read_rgl,
    write=write_rgl,
    magic=(MAGIC,),
    requires=(),
    native_grid=_native_grid,
    options=OPTIONS,
    prepare=prepare_rgl,
    check_options=check_options,
))
