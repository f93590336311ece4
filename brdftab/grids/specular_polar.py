"""Polar angles about the mirror direction: the layout of Zemax / Radiant "BSDF Data
Interchange" files (``formats/zemax.md``).

Axes ``theta_i`` (the file's AngleOfIncidence), ``phi_i`` (its SampleRotation),
``spec_azimuth`` and ``spec_radial`` (its ScatterAzimuth and ScatterRadial). The outgoing
direction of a node is the direction at polar angle ``spec_radial`` and azimuth
``spec_azimuth`` in a frame whose pole is the mirror direction of ωi:

    ωi = sph(θi, φi),   ωo = Rz(φi) · Rxz(θi) · sph(radial, azimuth)

where sph(θ, φ) = (sinθ cosφ, sinθ sinφ, cosθ), Rxz(θ) turns the (x, z) plane by θ
(x' = x cosθ − z sinθ, z' = x sinθ + z cosθ) and Rz(φ) turns about the normal. Radial 0 is
the mirror direction sph(θi, φi + π); azimuth 0 points from it towards the normal and the
azimuth turns counter-clockwise seen from the mirror direction's outside (towards +y at
φi = 0). At θi = 0 the frame is the surface's own: azimuth a, radial r is (θo, φo) = (r, φi + a),
so azimuth 0 is φo = φi (the limit of the mapping as θi → 0). This is libbsdf's
``SpecularCoordinateSystem``.

``azimuth_fold = "plane"`` (PlaneSymmetrical files) stores azimuths 0…π only: a query at
azimuth a > π reads the node at 2π − a (the mirror image across the plane of incidence).
Between nodes a table on this grid interpolates multilinearly in (θi, φi, azimuth, radial).
"""

from __future__ import annotations

import numpy as np

from ..errors import ParameterError
from ..geometry import sph_to_vec, vec_to_sph
from ..params import Param
from .axis import HALF_PI, LONG_NAMES, TWO_PI, Axis, check_range
from .base import Grid, choice_attr, read_coordinate, register

__all__ = ["SpecularPolarGrid", "specular_polar_out", "specular_polar_coords"]

FOLDS = ("none", "plane")
LONG_NAMES.setdefault("spec_azimuth", "azimuth about the mirror direction (0: towards the normal)")
LONG_NAMES.setdefault("spec_radial", "angle from the mirror direction")


def specular_polar_out(theta_i, phi_i, radial, azimuth):
    """ωo of (θi, φi, radial, azimuth) [rad] (broadcast): Rz(φi)·Rxz(θi)·sph(radial, azimuth)."""
    s = sph_to_vec(radial, azimuth)
    ct, st = np.cos(theta_i), np.sin(theta_i)
    x1 = ct * s[..., 0] - st * s[..., 2]
    z1 = st * s[..., 0] + ct * s[..., 2]
    y1 = s[..., 1]
    cp, sp = np.cos(phi_i), np.sin(phi_i)
    return np.stack(np.broadcast_arrays(cp * x1 - sp * y1, sp * x1 + cp * y1, z1), axis=-1)


def specular_polar_coords(wi, wo, phi_at_pole=0.0):
    """``(θi, φi, radial, azimuth ∈ [0, 2π))`` [rad] of direction pairs: the inverse of
    :func:`specular_polar_out`. At normal incidence ωi does not say φi: ``phi_at_pole`` is
    used (the azimuth origin there is φo = φi)."""
    ti, pi_ = vec_to_sph(wi)
    pi_ = np.where(ti == 0.0, phi_at_pole, pi_)
    wo = np.asarray(wo, float)
    x, y, z = wo[..., 0], wo[..., 1], wo[..., 2]
    cp, sp = np.cos(pi_), np.sin(pi_)
    x1, y1 = cp * x + sp * y, -sp * x + cp * y
    ct, st = np.cos(ti), np.sin(ti)
    sx, sz = ct * x1 + st * z, -st * x1 + ct * z
    radial = np.arctan2(np.hypot(sx, y1), sz)
    azimuth = np.mod(np.arctan2(y1, sx), TWO_PI)
    return ti, pi_, radial, azimuth


def _angles(name, doc):
    return Param(name, "angles", doc, default=None, angle=True, units="deg")


def _circle_axis(name, values, domain=None):
    """An azimuth axis over [0, 2π]: periodic when its nodes go round the circle; a list from
    a to a + 2π (both ends, as files often write 0 … 360) covers the circle with both end
    nodes kept; otherwise it covers its listed arc only."""
    v = np.asarray(values, float)
    if v.ndim != 1 or v.size == 0:
        raise ParameterError(name, "an axis needs at least one value")
    check_range(name, v, -TWO_PI, TWO_PI, closed=True)
    if v.size > 1 and np.isclose(v[-1] - v[0], TWO_PI, rtol=0, atol=1e-9):
        return Axis(name, v, "linear", None, TWO_PI, domain=domain or (float(v[0]), float(v[-1])))
    if v[-1] - v[0] > TWO_PI:
        raise ParameterError(name, "azimuths must span at most 360 degrees")
    if v.size > 1 and v[0] + TWO_PI - v[-1] <= np.diff(v).max() * (1 + 1e-9):
        return Axis(name, v, "linear", TWO_PI)
    return Axis(name, v, "linear", None, TWO_PI, domain=domain)


@register
class SpecularPolarGrid(Grid):
    """Polar angles about the mirror direction (Zemax / Radiant ``.bsdf`` layout)."""

    type_name = "specular-polar"
    summary = ("Incidence (theta_i, phi_i) and the outgoing direction's radial angle and azimuth about the mirror "
               "direction (the Zemax/Radiant .bsdf layout).")
    parameterizations = ("specular-polar",)
    parameterization = "specular-polar"
    #: Tables on this grid interpolate through :meth:`locate` (numpy), not the compiled kernels.
    compiled = False
    #: The checks compare interpolated pairs on this grid (its nodes have no reciprocal partners).
    node_checks = False
    params = (
        _angles("theta_i", "Angles of incidence (required)."),
        _angles("phi_i", "Incident azimuths = sample rotations (default [0])."),
        _angles("spec_azimuth", "Azimuths about the mirror direction, 0 = towards the normal (required)."),
        _angles("spec_radial", "Angles from the mirror direction (required)."),
        Param("azimuth_fold", "choice", "'plane': azimuths 0..180 deg, mirrored across the plane of incidence.",
              default="none", choices=FOLDS),
    )

    def __init__(self, theta_i, phi_i, spec_azimuth, spec_radial, *, azimuth_fold="none", domains=None):
        if azimuth_fold not in FOLDS:
            raise ParameterError("azimuth_fold", f"expected 'none' or 'plane', got {azimuth_fold!r}")
        domains = domains or {}
        self.azimuth_fold = azimuth_fold
        ti = np.asarray(theta_i, float)
        check_range("theta_i", ti, 0.0, HALF_PI, closed=True)
        rad = np.asarray(spec_radial, float)
        check_range("spec_radial", rad, 0.0, np.pi, closed=True)
        az = np.asarray(spec_azimuth, float)
        if azimuth_fold == "plane":
            check_range("spec_azimuth", az, 0.0, np.pi, closed=True, why=" with azimuth_fold = 'plane'")
            a_az = Axis("spec_azimuth", az, domain=domains.get("spec_azimuth"))
        else:
            a_az = _circle_axis("spec_azimuth", az, domain=domains.get("spec_azimuth"))
        self.axes = (
            Axis("theta_i", ti, domain=domains.get("theta_i")),
            _circle_axis("phi_i", np.asarray(phi_i, float), domain=domains.get("phi_i")),
            a_az,
            Axis("spec_radial", rad, domain=domains.get("spec_radial")),
        )

    def attrs(self) -> dict:
        return {"parameterization": "specular-polar", "grid": "specular-polar", "azimuth_fold": self.azimuth_fold,
                "sample_position": "explicit", "phi_d_fold": "none"}

    def coord_attrs(self, name) -> dict:
        out = super().coord_attrs(name)
        if name == "spec_azimuth":
            out["comment"] = ("omega_o = Rz(phi_i) Rxz(theta_i) sph(spec_radial, spec_azimuth); azimuth 0 points from "
                              "the mirror direction towards the normal")
        return out

    def _directions(self, idx):
        i_ti, i_pi, i_az, i_r = idx
        ti = self.axes[0].values[i_ti]
        pi_ = self.axes[1].values[i_pi]
        az = self.axes[2].values[i_az]
        r = self.axes[3].values[i_r]
        return sph_to_vec(ti, pi_), specular_polar_out(ti, pi_, r, az)

    def pair_directions(self, coords):
        """``(wi, wo)`` of coordinates (one array per axis, in axis order; azimuth folded or not)."""
        ti, pi_, az, r = coords
        return sph_to_vec(ti, pi_), specular_polar_out(ti, pi_, r, az)

    def _coordinates(self, wi, wo, isotropic: bool = False):
        # normal incidence is read in the frame of the first sample rotation (φi node)
        ti, pi_, r, az = specular_polar_coords(wi, wo, self.axes[1].values[0])
        if isotropic:
            # the radial/azimuth frame turns with φi: an isotropic table answers a φi it does
            # not cover from its first φi node
            ax = self.axes[1]
            off = ax.outside(pi_) if len(ax) > 1 else np.ones(np.shape(pi_), bool)
            pi_ = np.where(off, ax.values[0], pi_)
        if self.azimuth_fold == "plane":
            az = np.where(az > np.pi, TWO_PI - az, az)
        return [ti, pi_, az, r]

    @classmethod
    def from_config(cls, v: dict) -> "SpecularPolarGrid":
        for key in ("theta_i", "spec_azimuth", "spec_radial"):
            if v.get(key) is None:
                raise ParameterError(f"{key}_deg", "missing: a specular-polar grid needs theta_i_deg, "
                                     "spec_azimuth_deg and spec_radial_deg")
        phi_i = v.get("phi_i")
        return cls(v["theta_i"], [0.0] if phi_i is None else phi_i, v["spec_azimuth"], v["spec_radial"],
                   azimuth_fold=v.get("azimuth_fold", "none"))

    @classmethod
    def from_dataset(cls, ds, attrs):
        fold = choice_attr(attrs, "azimuth_fold", FOLDS, default="none")
        vals, domains = [], {}
        for n in ("theta_i", "phi_i", "spec_azimuth", "spec_radial"):
            v, _, domain = read_coordinate(ds, n)
            vals.append(v)
            if domain is not None:
                domains[n] = domain
        try:
            return cls(*vals, azimuth_fold=fold, domains=domains)
        except ParameterError as exc:
            raise ParameterError(exc.key, f"coordinate '{exc.key}': {exc.detail}") from None
