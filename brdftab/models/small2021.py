"""The solar-cell BRDF of Small, Butler and Marciniak 2021: two specular peaks and a diffraction band.

Three terms, each a registered model usable on its own, summed by ``solar-cell-small2021``
(with an optional Lambertian ρd/π) [Small2021]:

``small2021-peak`` (Eq. 6, the center specular peak)
    f = ρs · Q(n̂; ωi, ωs) / (2 (cosθi + cosθs)²) · D(θh),
    D = exp(−tan²θh/m²)/(π m² cos⁴θh) the area-normalized Beckmann distribution (the
    registered ``beckmann`` component with α = m), Q the Rayleigh–Rice factor as the **plain
    sum** Q_ss + Q_sp + Q_ps + Q_pp (:func:`~brdftab.models.rayleigh_rice.q_sum`; this is the
    normalization that reproduces the paper's printed peak values — the half-sum would halve
    them). Reciprocal and isotropic. Its directional albedo is close to ρs·Q/2 (= ρs R_F(θi)
    for a narrow peak: 0.0048 at θi = 20° and 0.0049 at 60° with the §4.4.1 parameters).
the offset peak (Eqs. 7–8)
    the same peak in the frame of a normal tilted by (Δθ, Δφ0), with the sample turned by φ_ref:
    the ``rotated`` combinator around a ``small2021-peak``.
``small2021-diffraction`` (Eqs. 9–10, the Fraunhofer pattern of two stripes)
    f = ρs3 cos²(2π a ȳ cosθi/(λ z̄)) sinc²(2 b ȳ cosθi/(λ z̄)) exp(−x̄²/c²),
    x̄ = R sinθh cos(φh − φ_ref + π), ȳ = R sinθh sin(φh − φ_ref + π), z̄ = R,
    sinc(x) = sin(πx)/(πx). a (bar spacing), b (bar width) and λ are lengths in metres; x̄, ȳ,
    z̄ and c are in the units of R. R cancels in cos² and sinc² but **not** in the Gaussian, so
    it is an explicit parameter: R = 1 (the unit sphere) by default; the paper's detector
    distance, printed as "approximately 0.325 cm" (0.325 m is likely meant), would triple the
    band's width. The π in Eq. 10 (the paper measures azimuths from −x̂) only flips the signs of
    x̄ and ȳ, which the even functions of Eq. 9 do not see. The cosθi factors make the term
    **not reciprocal**: it declares so. Its albedo grows with ρs3 and R and is not bounded
    (ρs3 = 300 is a magnitude fit, not a reflectance), so it claims no energy conservation;
    for a narrow band it is close to ρs3 c √π λ cosθi / (b R) (0.0013 at 20°, 0.0007 at 60°).

Each term evaluates in a compiled kernel of its own (the offset peak through the ``rotated``
combinator's, around the peak's); the solar cell's kernel is its sum's.

Conventions: brdftab's frame is the paper's. The source lies in the −x half-plane for the
paper's geometry (φi = 180°: the in-plane forward-scatter direction is +x̂, "to the right",
and +ŷ is out of plane, "down" in the paper's figures); Δφ0 and φ_ref are measured from +x
towards +y, right-handed. φh is the azimuth of the half vector in that frame. The index n̂ is
n + ik (the paper's n − ik; |q|² is the same).

The paper's printed values are reproduced (tests, each within 1 %): the full model's value at
the exact specular direction (center peak plus the diffraction zeroth order ρs3) 1.11e4 sr⁻¹ at
θi = 20° and 3.91e4 at 60°; the offset-peak maximum 4.44e4 at 20° (θs ≈ 20.72°, φs ≈ +1.87°
from the specular azimuth) and 4.19e5 at 60°; diffraction orders ρs3·sinc²(k b/a): 300 at the
center falling to ≈ 209 at k = 26, spaced λ/a apart in direction-cosine space.
"""

from __future__ import annotations

import math

import numpy as np

from .._jit import device, kernel
from ..brdf import Model
from ..errors import ParameterError
from ..optical import index_of, material_param
from ..params import REQUIRED, Param
from ..quadrature import gauss_legendre
from . import components as C
from .combinators import Rotated, Sum
from .fresnel import INDEX_MAX, INDEX_MIN
from .lambert import Lambert
from .distributions import beckmann_D_scalar
from .rayleigh_rice import q_mueller, q_sum, q_sum_scalar
from ._registry import register

__all__ = ["Small2021Peak", "Small2021Diffraction", "SolarCellSmall2021"]


def _peak_params(suffix="", m=REQUIRED, rho=REQUIRED, n=None):
    return (
        Param(f"m{suffix}", "float", "Beckmann width m of the peak (rms slope).", default=m, minimum=1e-6,
              maximum=1.0),
        Param(f"rho_s{suffix}", "channel", "Weight ρs of the peak.", default=rho, minimum=0.0, maximum=1e6),
        Param(f"n{suffix}", "channel", f"Real part of the index n + ik inside Q (or give material{suffix}).",
              default=n, minimum=INDEX_MIN, maximum=INDEX_MAX),
        Param(f"k{suffix}", "channel", f"Imaginary part k (>= 0) of the index inside Q (or give material{suffix}).",
              default=0.0, minimum=0.0, maximum=INDEX_MAX),
        material_param(suffix),
    )


class _GivenParams:
    """Records which parameters a model was given explicitly (a material replaces n and k that
    were not; giving both is an error)."""

    def __init__(self, **params):
        self._given = frozenset(params)
        super().__init__(**params)

    def _index(self, suffix, n, k, material):
        """n, k from the values or the material; provenance then records the material only."""
        n, k = index_of(material, n, k, given=self._given, suffix=suffix, where=f"model '{self.name}'")
        if material is not None:
            self._values[f"n{suffix}"] = self._values[f"k{suffix}"] = None
        return n, k


@register
class Small2021Peak(_GivenParams, Model):
    name = "small2021-peak"
    summary = "Small et al. 2021 Eq. 6: ρs Q/(2(cosθi + cosθs)²) · Beckmann D(m), Q the plain Rayleigh–Rice sum."
    reference = "Small2021; Stover2012"
    params = _peak_params()

    def _setup(self, m, rho_s, n, k, material):
        n, k = self._index("", n, k, material)
        self.m = m
        self.rho_s, self.n, self.k = rho_s, n, k
        self.dist = C.create("distribution", "beckmann", alpha=m)
        from ..channels import combine_layouts

        self.layout = combine_layouts([rho_s.layout, n.layout, k.layout], names=("rho_s", "n", "k"))

    @property
    def lobe_width(self) -> float:
        return self.m

    #: Polarized: Q's Jones matrix (SCATMECH's psps basis); M00 = ½ Σ Q_αβ, so the plain sum of
    #: Eq. 6 is 2·M00 of the Jones–Mueller matrix.
    polarized = True
    mueller_basis = "psps"

    def _mueller(self, wi, wo, lam, n):
        h = wi + wo
        h = h / np.linalg.norm(h, axis=-1, keepdims=True)
        eta = np.broadcast_to(np.asarray(self.n.at(lam, n), float), (n,))
        kap = np.broadcast_to(np.asarray(self.k.at(lam, n), float), (n,))
        m = q_mueller(wi[:, None, :], wo[:, None, :], eta[None, :], kap[None, :])
        base = self.dist.D(h) / (2.0 * (wi[:, 2] + wo[:, 2]) ** 2)
        rho = np.broadcast_to(np.asarray(self.rho_s.at(lam, n), float), (n,))
        return (2.0 * rho[None, :] * base[:, None])[:, :, None, None] * m

    def _kernel(self, lam, n):
        run = _peak_kernel()
        pd = self.dist.jit_params()
        rho, eta, kap = (np.ascontiguousarray(np.broadcast_to(np.asarray(v.at(lam, n), float), (n,)))
                         for v in (self.rho_s, self.n, self.k))

        def evaluate(wi, wo, state, out, add):
            run(wi, wo, state, out, pd, rho, eta, kap, add)
        return evaluate

    def _eval(self, wi, wo, lam, n):
        h = wi + wo
        h /= np.linalg.norm(h, axis=-1, keepdims=True)
        eta = np.broadcast_to(np.asarray(self.n.at(lam, n), float), (n,))
        kap = np.broadcast_to(np.asarray(self.k.at(lam, n), float), (n,))
        q = q_sum(wi[:, None, :], wo[:, None, :], eta[None, :], kap[None, :])
        base = self.dist.D(h) / (2.0 * (wi[:, 2] + wo[:, 2]) ** 2)
        return np.asarray(self.rho_s.at(lam, n), float) * q * base[:, None]


@register
class Small2021Diffraction(Model):
    name = "small2021-diffraction"
    summary = ("Small et al. 2021 Eqs. 9–10: two-stripe Fraunhofer band ρs3 cos²·sinc²·exp(−x̄²/c²) in half-vector "
               "coordinates (not reciprocal).")
    reference = "Small2021; Goodman2005"
    params = (
        Param("a", "float", "Bar spacing a.", units="m", default=8e-4, minimum=1e-9, maximum=1.0),
        Param("b", "float", "Bar width b.", units="m", default=1e-5, minimum=1e-9, maximum=1.0),
        Param("c", "float", "Gaussian width c of the band across the bars (units of R).", default=4e-5,
              minimum=1e-9, maximum=10.0),
        Param("rho_s", "float", "Magnitude ρs3 of the pattern (its zeroth-order peak value, sr⁻¹).", default=300.0,
              minimum=0.0, maximum=1e6),
        Param("R", "float", "Radius R of Eq. 10 (units of c; 1: the unit sphere).", default=1.0, minimum=1e-6,
              maximum=1e3),
        Param("wavelength_nm", "float", "Wavelength λ of model.eval(wi, wo) without wavelengths.", units="nm",
              default=632.8, minimum=1.0, maximum=1e6),
        Param("phi_ref", "float", "φ_ref: orientation of the bars about the normal, from +x towards +y.",
              units="rad", default=0.0, minimum=float(-2 * np.pi), maximum=float(2 * np.pi), angle=True),
    )
    reciprocal = False
    isotropic = False

    def _setup(self, a, b, c, rho_s, R, wavelength_nm, phi_ref):
        if b > a:
            raise ParameterError("b", f"the bar width must not exceed the bar spacing a (b = {b:g} m > a = {a:g} m: "
                                 "the two stripes would overlap)")
        self.a, self.b, self.c, self.rho_s, self.R = a, b, c, rho_s, R
        self.wavelength_nm = wavelength_nm
        self.phi_ref = phi_ref
        self.e1 = np.array([np.cos(phi_ref), np.sin(phi_ref), 0.0])    # along the bars (x̄ = −R h·e1)
        self.e2 = np.array([-np.sin(phi_ref), np.cos(phi_ref), 0.0])   # across the bars (ȳ = −R h·e2)

    @property
    def lobe_width(self) -> float:
        # the band's Gaussian half-width in sinθh (across its length)
        return min(self.c / self.R, 1.0)

    def _lambda_m(self, lam, n):
        return (np.full(1, self.wavelength_nm) if lam is None else np.asarray(lam, float)) * 1e-9

    def coordinates(self, wi, wo):
        """(x̄, ȳ, z̄) of Eq. 10 for pairs ``wi``, ``wo[..., 3]`` (units of R)."""
        h = np.asarray(wi, float) + np.asarray(wo, float)
        h = h / np.linalg.norm(h, axis=-1, keepdims=True)
        # h·e written out (e_z = 0): the same arithmetic as the compiled kernel, whatever BLAS does
        he1 = h[..., 0] * self.e1[0] + h[..., 1] * self.e1[1]
        he2 = h[..., 0] * self.e2[0] + h[..., 1] * self.e2[1]
        return -self.R * he1, -self.R * he2, np.full(h.shape[:-1], self.R)

    def _kernel(self, lam, n):
        lm = np.ascontiguousarray(np.broadcast_to(self._lambda_m(lam, n), (n,)))
        # constants of the pattern: the products of _eval's first factors, as numpy forms them
        consts = np.array([self.e1[0], self.e1[1], self.e2[0], self.e2[1], -self.R, self.R, self.c,
                           2 * np.pi * self.a, 2 * self.b, self.rho_s])

        def evaluate(wi, wo, state, out, add):
            _diffraction_rows(wi, wo, state, out, consts, lm, add)
        return evaluate

    def _eval(self, wi, wo, lam, n):
        xb, yb, zb = self.coordinates(wi, wo)
        lm = self._lambda_m(lam, n)[None, :]
        u = (yb / zb * wi[:, 2])[:, None] / lm
        f = np.cos(2 * np.pi * self.a * u) ** 2 * np.sinc(2 * self.b * u)
        f = f * np.sinc(2 * self.b * u) * np.exp(-(xb / self.c) ** 2)[:, None]
        return self.rho_s * f

    def albedo_rule(self, wi, wavelengths=None):
        """Outgoing quadrature resolved on the band (a hint for :mod:`brdftab.integrate`).

        In half-vector coordinates across (y) and along (x) the bars, (h·e2, h·e1) on the unit
        disk, dωo = 4 (wo·h) dx dy / h_z. Along x: Gauss–Hermite nodes on the Gaussian of width
        c/R (Gauss–Legendre over the disk when the band is wide). Across y the cos² fringes
        (period P = λ/(2a cosθi)) are integrated exactly by node pairs P/2 apart (cos²u +
        cos²(u + π/2) = 1), the sinc² envelope (zeros every w = λ/(2b cosθi)) by Gauss–Legendre
        panels of w/4 out to 8w, and beyond that, where sinc² oscillates too, by node quads
        (pairs P/2 and w/2 apart) on graded panels to the rim. Exact to the envelope's curvature
        over P/2 at the wavelength the rule is built for (the model's, or the one given).
        """
        wi = np.asarray(wi, float).reshape(3)
        lam_nm = self.wavelength_nm if wavelengths is None else float(np.atleast_1d(wavelengths)[0])
        lam = lam_nm * 1e-9
        ci = max(float(wi[2]), 1e-12)
        P = lam / (2 * self.a * ci)
        w = lam / (2 * self.b * ci)
        # across the bars
        xg, wg = gauss_legendre(6, 0.0, 1.0)
        near = min(8 * w, 1.0)
        e = np.arange(0.0, near + 1e-15, w / 4)
        e = np.unique(np.append(e[e < near], near))
        y1 = (e[:-1, None] + np.diff(e)[:, None] * xg).ravel()
        v1 = (np.diff(e)[:, None] * wg).ravel()
        ys, vs = [y1[:, None] + np.array([-P / 4, P / 4])], [np.repeat(v1[:, None] / 2, 2, axis=1)]
        if near < 1.0:
            ef = np.unique(np.append(near * 1.5 ** np.arange(0, 40), 1.0))
            ef = ef[ef <= 1.0]
            y2 = (ef[:-1, None] + np.diff(ef)[:, None] * xg).ravel()
            v2 = (np.diff(ef)[:, None] * wg).ravel()
            d = np.array([-P / 4 - w / 4, -P / 4 + w / 4, P / 4 - w / 4, P / 4 + w / 4])
            ys.append(y2[:, None] + d)
            vs.append(np.repeat(v2[:, None] / 4, 4, axis=1))
        y = np.concatenate([a.ravel() for a in ys])
        vy = np.concatenate([a.ravel() for a in vs])
        y = np.concatenate([y, -y])
        vy = np.concatenate([vy, vy])
        # along the bars
        s = self.c / self.R
        if s < 0.05:
            t, wt = np.polynomial.hermite.hermgauss(12)
            x, vx = s * t, s * wt * np.exp(t * t)
        else:
            x, vx = gauss_legendre(96, -1.0, 1.0)
        X, Y = np.meshgrid(x, y, indexing="ij")
        W = vx[:, None] * vy[None, :]
        r2 = X * X + Y * Y
        keep = r2 < 1.0
        X, Y, W = X[keep], Y[keep], W[keep]
        hz = np.sqrt(1.0 - X * X - Y * Y)
        h = X[:, None] * self.e1 + Y[:, None] * self.e2 + hz[:, None] * np.array([0.0, 0.0, 1.0])
        c = h @ wi
        wo = 2.0 * c[:, None] * h - wi
        weight = W * 4.0 * c / hz
        ok = (c > 0) & (wo[:, 2] > 1e-12)
        return wo[ok], weight[ok]


def _solar_params():
    return (
        *_peak_params("1", m=2e-4, rho=0.015, n=3.6),
        *_peak_params("2", m=2e-4, rho=0.7, n=1.4),
        Param("tilt", "float", "Δθ: tilt of the offset peak's normal.", units="rad", default=float(np.radians(0.5)),
              minimum=0.0, maximum=float(np.radians(89.0)), angle=True),
        Param("tilt_azimuth", "float", "Δφ0: azimuth of that tilt, from +x towards +y.", units="rad",
              default=float(np.radians(45.0)), minimum=float(-2 * np.pi), maximum=float(2 * np.pi), angle=True),
        *(p for p in Small2021Diffraction.params if p.name != "rho_s"),
        Param("rho_s3", "float", "Magnitude ρs3 of the diffraction pattern (sr⁻¹).", default=300.0, minimum=0.0,
              maximum=1e6),
        Param("rho_d", "channel", "Diffuse reflectance ρd of an optional Lambertian term ρd/π.", default=0.0,
              minimum=0.0, maximum=1.0),
    )


@register
class SolarCellSmall2021(_GivenParams, Model):
    name = "solar-cell-small2021"
    summary = ("Small et al. 2021 solar cell: center peak (Eq. 6) + offset peak in a tilted frame (Eqs. 7–8) + "
               "two-stripe diffraction (Eqs. 9–10) + optional ρd/π; defaults are the paper's §4.4.1 values.")
    reference = "Small2021"
    params = _solar_params()

    def _setup(self, m1, rho_s1, n1, k1, material1, m2, rho_s2, n2, k2, material2, tilt, tilt_azimuth, a, b, c, R,
               wavelength_nm, phi_ref, rho_s3, rho_d):
        n1, k1 = self._index("1", n1, k1, material1)
        n2, k2 = self._index("2", n2, k2, material2)
        self.center = Small2021Peak(m=m1, rho_s=rho_s1, n=n1, k=k1)
        self.offset = Rotated(term=Small2021Peak(m=m2, rho_s=rho_s2, n=n2, k=k2), tilt=tilt,
                              tilt_azimuth=tilt_azimuth, phi_ref=phi_ref)
        self.diffraction = Small2021Diffraction(a=a, b=b, c=c, rho_s=rho_s3, R=R, wavelength_nm=wavelength_nm,
                                                phi_ref=phi_ref)
        terms = [self.center, self.offset, self.diffraction]
        if np.any(rho_d.values > 0):
            terms.append(Lambert(albedo=rho_d))
        self.terms = terms
        self._sum = Sum(terms=terms)
        self.layout = self._sum.layout
        self.isotropic = False
        self.reciprocal = False      # the diffraction term's cosθi factors
        self.energy_conserving = False

    @property
    def lobe_width(self) -> float:
        return self._sum.lobe_width

    def quadrature_parts(self):
        return list(self.terms)

    def _kernel(self, lam, n):
        return self._sum.kernel(lam, n)   # each term's kernel, added in order

    def _eval(self, wi, wo, lam, n):
        return self._sum._eval(wi, wo, lam, n)


# --------------------------------------------------------------------------------------------
# Compiled forms (the arithmetic of the _eval methods above, in the same order; parity tests
# hold them to 1e-12)

_PEAK = '''\
# Generated by brdftab.models.small2021 (do not edit): small2021-peak; sources {digest}
import numba

from brdftab._jit import OPTIONS
from brdftab.models.fused import as_device
from brdftab.models.rayleigh_rice import q_sum_scalar
from brdftab.models.small2021 import peak_base_scalar

_Q = as_device(q_sum_scalar)
_BASE = as_device(peak_base_scalar)


@numba.njit(**OPTIONS)
def run(wi, wo, state, out, pd, rho, eta, kap, add):
    nc = out.shape[1]
    for i in range(wi.shape[0]):
        if state[i] != 1:
            continue
        b = _BASE(wi[i, 0], wi[i, 1], wi[i, 2], wo[i, 0], wo[i, 1], wo[i, 2], pd)
        for c in range(nc):
            if b == 0.0:   # D underflows off a narrow peak: Q (finite) is not needed
                v = 0.0
            else:
                v = rho[c] * _Q(wi[i, 0], wi[i, 1], wi[i, 2], wo[i, 0], wo[i, 1], wo[i, 2], eta[c], kap[c]) * b
            out[i, c] = out[i, c] + v if add else v
'''



@device
def peak_base_scalar(wix, wiy, wiz, wox, woy, woz, pd):
    """D(h) / (2 (cosθi + cosθo)²) of :class:`Small2021Peak` for one pair (``pd`` = [m, m])."""
    hx = wix + wox
    hy = wiy + woy
    hz = wiz + woz
    norm = math.sqrt(hx * hx + hy * hy + hz * hz)
    s = wiz + woz
    return beckmann_D_scalar(hx / norm, hy / norm, hz / norm, pd) / (2.0 * (s * s))


def _peak_kernel():
    """The compiled loop of :class:`Small2021Peak` (generated so that an edit of the scalar
    forms it inlines compiles anew: numba's cache watches only the kernel's own file)."""
    from .._jit import generated_module, source_hash

    source = _PEAK.format(digest=source_hash(peak_base_scalar, q_sum_scalar))
    return generated_module("small2021_peak", source).run


@device
def _sinc(x):
    """numpy's ``sinc``: sin(πx)/(πx), with πx = 0 replaced by the float64 epsilon."""
    y = np.pi * x
    if y == 0.0:
        y = 2.220446049250313e-16
    return math.sin(y) / y


@kernel
def _diffraction_rows(wi, wo, state, out, k, lm, add):
    """:meth:`Small2021Diffraction._eval` on the evaluated rows; ``k`` = [e1x, e1y, e2x, e2y, −R, R, c,
    2πa, 2b, ρs3], ``lm`` the wavelengths [m] per channel."""
    nc = out.shape[1]
    for i in range(wi.shape[0]):
        if state[i] != 1:
            continue
        hx = wi[i, 0] + wo[i, 0]
        hy = wi[i, 1] + wo[i, 1]
        hz = wi[i, 2] + wo[i, 2]
        norm = math.sqrt(hx * hx + hy * hy + hz * hz)
        hx = hx / norm
        hy = hy / norm
        xb = k[4] * (hx * k[0] + hy * k[1])
        yb = k[4] * (hx * k[2] + hy * k[3])
        t = xb / k[6]
        g = math.exp(-(t * t))
        yz = yb / k[5] * wi[i, 2]
        for c in range(nc):
            if g == 0.0:   # off the band: the fringes (finite) are not needed
                v = 0.0
            else:
                u = yz / lm[c]
                cv = math.cos(k[7] * u)
                s = _sinc(k[8] * u)
                v = k[9] * (cv * cv * s * s * g)
            out[i, c] = out[i, c] + v if add else v
