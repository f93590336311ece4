"""Polarized test models whose Mueller matrices are known in closed form (Mitsuba's basis:
both beams share x = normalize(wi × wo), wi towards the light; +S3 right circular).

* :class:`GGXConductor`: D·G·F/(4 cosθi cosθo) with GGX D, separable Smith G and the
  conductor Fresnel Mueller matrix of the facet angle θd. For a mirror facet with normal h the
  s direction is normalize(wi × wo) for both beams, so the Fresnel matrix of s/p polarization
  is the Mueller matrix in this basis as it stands. Optical constants vary with wavelength so
  the five channels differ.
* :class:`DepolarizingLambert`: diag(ρ/π, 0, 0, 0).
* :class:`Scaled`: any of them with its Mueller matrix multiplied by a fixed 4×4 matrix (right)
  — e.g. diag(1, 1, 1, −1), which is not a physical Mueller matrix.
"""

from __future__ import annotations

import numpy as np

from brdftab.brdf import BRDF, HORIZON
from brdftab.channels import Layout

KAIST_NM = np.array([450.0, 500.0, 550.0, 600.0, 650.0])


def fresnel_mueller(cos_t, eta):
    """Mueller matrix [..., 4, 4] of reflection at an interface of complex relative index
    ``eta`` (n + ik) at incidence cosine ``cos_t``, in the s/p basis (x = s for both beams)."""
    c = np.asarray(cos_t, float)
    eta = np.asarray(eta, complex)
    s2 = 1.0 - c * c
    root = np.sqrt(eta * eta - s2)
    rs = (c - root) / (c + root)
    rp = (eta * eta * c - root) / (eta * eta * c + root)
    a = 0.5 * (np.abs(rs) ** 2 + np.abs(rp) ** 2)
    b = 0.5 * (np.abs(rs) ** 2 - np.abs(rp) ** 2)
    x = rs * np.conj(rp)
    cr, ci = x.real, x.imag
    z = np.zeros_like(a)
    return np.stack([np.stack([a, b, z, z], -1), np.stack([b, a, z, z], -1),
                     np.stack([z, z, cr, -ci], -1), np.stack([z, z, ci, cr], -1)], -2)


class _Polarized(BRDF):
    polarized = True
    reciprocal = True
    isotropic = True

    def _resolve(self, wavelengths):
        lam = self.layout.resolve(wavelengths)
        return lam, self.layout.n_out(lam)

    def eval_mueller(self, wi, wo, wavelengths=None, basis="mitsuba"):
        if basis != "mitsuba":
            raise ValueError("test model: mitsuba basis only")
        wi, wo = np.broadcast_arrays(np.asarray(wi, float), np.asarray(wo, float))
        wi = wi / np.linalg.norm(wi, axis=-1, keepdims=True)
        wo = wo / np.linalg.norm(wo, axis=-1, keepdims=True)
        lam, n = self._resolve(wavelengths)
        out = np.zeros(wi.shape[:-1] + (n, 4, 4))
        up = (wi[..., 2] > HORIZON) & (wo[..., 2] > HORIZON)
        with np.errstate(all="ignore"):
            out[up] = self._mueller(wi[up], wo[up], lam)
        return out

    def _eval(self, wi, wo, lam, n):
        return self._mueller(wi, wo, lam)[..., 0, 0]


class GGXConductor(_Polarized):
    name = "test_ggx_conductor"

    def __init__(self, alpha=0.3, wavelengths=KAIST_NM):
        self.alpha = float(alpha)
        self.layout = Layout(None, np.asarray(wavelengths, float))

    @staticmethod
    def eta(lam):
        lam = np.asarray(lam, float)
        return (0.2 + (lam - 450.0) / 1000.0) + 1j * (3.0 + (lam - 450.0) / 200.0)

    @property
    def parameters(self):
        return {"alpha": self.alpha}

    def _d(self, cos_h):
        a2 = self.alpha ** 2
        c2 = cos_h * cos_h
        return a2 / (np.pi * (c2 * (a2 - 1.0) + 1.0) ** 2)

    def _g1(self, cos_v):
        t2 = (1.0 - cos_v * cos_v) / (cos_v * cos_v)
        return 2.0 / (1.0 + np.sqrt(1.0 + self.alpha ** 2 * t2))

    def _mueller(self, wi, wo, lam):
        h = wi + wo
        h = h / np.linalg.norm(h, axis=-1, keepdims=True)
        ci, co = wi[..., 2], wo[..., 2]
        cd = np.clip(np.sum(wi * h, axis=-1), 0.0, 1.0)
        scalar = self._d(h[..., 2]) * self._g1(ci) * self._g1(co) / (4.0 * ci * co)
        lam = self.layout.wavelengths if lam is None else lam
        f = fresnel_mueller(cd[..., None], self.eta(lam))  # [..., n, 4, 4]
        return scalar[..., None, None, None] * f


class DepolarizingLambert(_Polarized):
    name = "test_depolarizing_lambert"

    def __init__(self, albedo=0.5):
        self.albedo = float(albedo)

    def _mueller(self, wi, wo, lam):
        n = self.layout.n_out(lam)
        out = np.zeros(wi.shape[:-1] + (n, 4, 4))
        out[..., 0, 0] = self.albedo / np.pi
        return out


class Scaled(_Polarized):
    """``term``'s Mueller matrix times a fixed 4×4 ``right`` (M·right)."""

    def __init__(self, term, right, name="test_scaled"):
        self.term, self.right, self.name = term, np.asarray(right, float), name
        self.layout = term.layout
        self.polarized = True

    def _mueller(self, wi, wo, lam):
        return self.term._mueller(wi, wo, lam) @ self.right
