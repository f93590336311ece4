"""The angles of Ansys Speos BSDF tables (``*.anisotropicbsdf``, ``*.brdf``; ``formats/speos.md``).

Axes ``theta_i`` (the file's incidence angles), ``speos_rotation`` (its anisotropy angles),
``theta_o`` (the rows) and ``speos_phi`` (the columns). Speos measures the outgoing direction
in a frame built per incident photon (Speos help, "Anisotropic BSDF Surface Overview"): Z the
normal, X the projection on the surface of the photon's direction of travel, Y = Z × X, and
(θo, φ) ordinary spherical angles in (X, Y, Z), so that the mirror direction is always
(θo, φ) = (θi, 0). The anisotropy angle is the angle from X to the anisotropy vector,
counter-clockwise seen from above (trigonometric); brdftab's tangent x axis is the anisotropy
vector. In brdftab's convention (ωi points towards the light, φ counter-clockwise from x) this is

    φi = π − rotation,      ωi = sph(θi, φi),      ωo = sph(θo, φi + π + φ)

— :func:`speos_directions` and its inverse :func:`speos_coords`, the one place the convention is
written. X is the azimuth φi + π (the photon travels away from the light), so a Speos φ is
brdftab's φo − φi − π: φ = 0 on the mirror side, φ = 180° back towards the light. At normal
incidence X is the anisotropy vector turned by −rotation (the limit of the same formula).

An isotropic table (one rotation) answers every incident azimuth from its rotation node: its φ is
relative to the plane of incidence. Between nodes a table on this grid interpolates
multilinearly in (θi, rotation, θo, φ).
"""

from __future__ import annotations

import numpy as np

from ..errors import ParameterError
from ..geometry import sph_to_vec, vec_to_sph
from .axis import HALF_PI, LONG_NAMES, TWO_PI, Axis, check_range
from .base import Grid, read_coordinate, register
from .specular_polar import _angles, _circle_axis

__all__ = ["SpeosGrid", "speos_directions", "speos_coords"]

LONG_NAMES.setdefault("speos_rotation", "Speos anisotropy angle: from the photon's in-plane direction to the "
                                        "anisotropy vector (phi_i = pi - rotation)")
LONG_NAMES.setdefault("speos_phi", "Speos outgoing azimuth: phi_o - phi_i - pi (0 on the mirror side)")


def speos_directions(theta_i, rotation, theta_o, phi):
    """``(ωi, ωo)`` of Speos angles [rad] (broadcast): φi = π − rotation, φo = φi + π + φ."""
    phi_i = np.pi - np.asarray(rotation, float)
    return sph_to_vec(theta_i, phi_i), sph_to_vec(theta_o, phi_i + np.pi + np.asarray(phi, float))


def speos_coords(wi, wo, rotation_at_pole=0.0):
    """``(θi, rotation ∈ [0, 2π), θo, φ ∈ [0, 2π))`` [rad] of direction pairs: the inverse of
    :func:`speos_directions`. At normal incidence ωi does not say the rotation:
    ``rotation_at_pole`` is used."""
    ti, pi_ = vec_to_sph(wi)
    pi_ = np.where(ti == 0.0, np.pi - rotation_at_pole, pi_)
    to, po = vec_to_sph(wo)
    return ti, np.mod(np.pi - pi_, TWO_PI), to, np.mod(po - pi_ - np.pi, TWO_PI)


@register
class SpeosGrid(Grid):
    """Speos BSDF table angles: incidence, anisotropy angle, θo and φ from the mirror side."""

    type_name = "speos"
    summary = ("Incidence theta_i, Speos anisotropy angle (phi_i = 180 deg - rotation), outgoing theta_o and the "
               "Speos azimuth phi = phi_o - phi_i - 180 deg (0 on the mirror side): the Ansys Speos "
               ".anisotropicbsdf/.brdf layout.")
    parameterizations = ("speos",)
    parameterization = "speos"
    #: Tables on this grid interpolate through :meth:`locate` (numpy), not the compiled kernels.
    compiled = False
    #: The checks compare interpolated pairs on this grid (its nodes have no reciprocal partners).
    node_checks = False
    params = (
        _angles("theta_i", "Angles of incidence (required)."),
        _angles("speos_rotation", "Anisotropy angles (default [0]; phi_i = 180 - rotation)."),
        _angles("theta_o", "Outgoing polar angles (required)."),
        _angles("speos_phi", "Speos outgoing azimuths, 0 on the mirror side (required)."),
    )

    def __init__(self, theta_i, speos_rotation, theta_o, speos_phi, *, domains=None):
        domains = domains or {}
        ti = np.asarray(theta_i, float)
        check_range("theta_i", ti, 0.0, HALF_PI, closed=True)
        to = np.asarray(theta_o, float)
        check_range("theta_o", to, 0.0, HALF_PI, closed=True)
        rot = np.asarray(speos_rotation, float)
        check_range("speos_rotation", rot, 0.0, TWO_PI, closed=True)
        ph = np.asarray(speos_phi, float)
        check_range("speos_phi", ph, 0.0, TWO_PI, closed=True)
        self.axes = (
            Axis("theta_i", ti, domain=domains.get("theta_i")),
            _circle_axis("speos_rotation", rot, domain=domains.get("speos_rotation")),
            Axis("theta_o", to, domain=domains.get("theta_o")),
            _circle_axis("speos_phi", ph, domain=domains.get("speos_phi")),
        )

    def attrs(self) -> dict:
        return {"parameterization": "speos", "grid": "speos", "sample_position": "explicit", "phi_d_fold": "none",
                "speos_convention": "phi_i = pi - speos_rotation; phi_o = phi_i + pi + speos_phi (the mirror "
                                    "direction is speos_phi = 0, theta_o = theta_i)"}

    def coord_attrs(self, name) -> dict:
        out = super().coord_attrs(name)
        if name == "speos_phi":
            out["comment"] = "phi_o - phi_i - pi: 0 on the mirror side, counter-clockwise seen from above"
        return out

    def incident_azimuths(self) -> np.ndarray:
        """brdftab's φi [rad] of the rotation nodes (π − rotation, in [0, 2π), increasing)."""
        return np.sort(np.mod(np.pi - self.axes[1].values, TWO_PI))

    def _directions(self, idx):
        return self.pair_directions([a.values[i] for a, i in zip(self.axes, idx)])

    def pair_directions(self, coords):
        """``(wi, wo)`` of coordinates (one array per axis, in axis order)."""
        return speos_directions(*coords)

    def _coordinates(self, wi, wo, isotropic: bool = False):
        ti, rot, to, ph = speos_coords(wi, wo, self.axes[1].values[0])
        ax = self.axes[1]
        if isotropic:
            # φ is relative to the plane of incidence: an isotropic table answers any incident
            # azimuth it does not cover from its first rotation node
            off = ax.outside(rot) if len(ax) > 1 else np.ones(np.shape(rot), bool)
            rot = np.where(off, ax.values[0], rot)
        return [ti, rot, to, ph]

    @classmethod
    def from_config(cls, v: dict) -> "SpeosGrid":
        for key in ("theta_i", "theta_o", "speos_phi"):
            if v.get(key) is None:
                raise ParameterError(f"{key}_deg", "missing: a speos grid needs theta_i_deg, theta_o_deg and "
                                     "speos_phi_deg")
        rot = v.get("speos_rotation")
        return cls(v["theta_i"], [0.0] if rot is None else rot, v["theta_o"], v["speos_phi"])

    @classmethod
    def from_dataset(cls, ds, attrs):
        vals, domains = [], {}
        for n in ("theta_i", "speos_rotation", "theta_o", "speos_phi"):
            v, _, domain = read_coordinate(ds, n)
            vals.append(v)
            if domain is not None:
                domains[n] = domain
        try:
            return cls(*vals, domains=domains)
        except ParameterError as exc:
            raise ParameterError(exc.key, f"coordinate '{exc.key}': {exc.detail}") from None
