"""Gonio grids over (θi, φi, θo, φo), optionally relative to the mirror direction.

With ``relative_to = "specular"`` the outgoing axes are ``dtheta_o`` and ``dphi_o``:
θo = θi + Δθo and φo = φi + π + Δφo (zoomed grids around the mirror direction). Azimuth axes
that go round the circle are periodic; others cover only their listed arc (queries outside
it are outside the table's domain).

``phi_d_fold = "bilateral"`` declares an isotropic table with mirror symmetry about the plane of
incidence: f depends on φo − φi only through |φo − φi| folded into [0, π] (the symmetry of
Rusinkiewicz's ``bilateral`` fold, φd ≡ −φd, for an isotropic BRDF). Such a grid has one φi node
and its φo nodes lie in [φi, φi + π]; a pair is rotated about the normal onto the φi node and
its azimuth difference folded into that half circle. This is the layout of an NVIDIA MDL
``.mbsdf`` file (θi × θo × Δφ, cell-centred).
"""

from __future__ import annotations

import numpy as np

from .._jit import kernel
from ..errors import ParameterError
from ..geometry import sph_to_vec, vec_to_sph
from ..params import Param
from .axis import HALF_PI, TWO_PI, Axis, check_range
from .base import Grid, choice_attr, read_coordinate, register, unravel4

__all__ = ["SphericalGrid"]

#: φ folds a spherical grid declares (``phi_d_fold``): none, or mirror symmetry of an isotropic BRDF.
FOLDS = ("none", "bilateral")


def _angles(name, doc, used_when=""):
    return Param(name, "angles", doc, default=None, angle=True, units="deg", used_when=used_when)


@register
class SphericalGrid(Grid):
    """Gonio grid over (θi, φi, θo, φo), optionally relative to the mirror direction."""

    type_name = "spherical"
    summary = "Gonio angles (theta_i, phi_i, theta_o, phi_o), absolute or relative to the mirror direction."
    parameterizations = ("spherical",)
    parameterization = "spherical"
    params = (
        Param("relative_to", "choice", "Outgoing angles absolute ('none') or offsets from the mirror direction.",
              default="none", choices=("none", "specular")),
        _angles("theta_i", "Incident polar angles (required)."),
        _angles("phi_i", "Incident azimuths (required)."),
        _angles("theta_o", "Outgoing polar angles.", "relative_to = 'none'"),
        _angles("phi_o", "Outgoing azimuths.", "relative_to = 'none'"),
        _angles("dtheta_o", "theta_o - theta_i.", "relative_to = 'specular'"),
        _angles("dphi_o", "phi_o - (phi_i + 180 deg).", "relative_to = 'specular'"),
        Param("phi_d_fold", "choice", "'bilateral': isotropic and mirror-symmetric, f depends on |phi_o - phi_i| "
              "folded into [0, 180] deg (one phi_i node, phi_o nodes in [phi_i, phi_i + 180] deg).",
              default="none", choices=FOLDS),
    )

    def __init__(self, theta_i, phi_i, theta_o, phi_o, *, relative_to="none", phi_d_fold="none", domains=None):
        if relative_to not in ("none", "specular"):
            raise ParameterError("relative_to", f"expected 'none' or 'specular', got {relative_to!r}")
        if phi_d_fold not in FOLDS:
            raise ParameterError("phi_d_fold", f"expected 'none' or 'bilateral' on a spherical grid, got "
                                 f"{phi_d_fold!r}")
        domains = domains or {}
        self.relative_to = relative_to
        self.phi_d_fold = phi_d_fold
        rel = relative_to == "specular"
        ti = np.asarray(theta_i, float)
        check_range("theta_i", ti, 0.0, HALF_PI, closed=True)
        to = np.asarray(theta_o, float)
        if rel:
            check_range("dtheta_o", to, -HALF_PI, np.pi, closed=True)
            if ti.size and to.size and ti[0] + to[0] < -1e-12:
                raise ParameterError("dtheta_o", f"theta_i + dtheta_o must be >= 0 (a negative theta_o is the same "
                                     f"direction as its mirror across the normal); the smallest is "
                                     f"{np.degrees(ti[0] + to[0]):g} degrees")
        else:
            check_range("theta_o", to, 0.0, HALF_PI, closed=True)
        o_names = ("dtheta_o", "dphi_o") if rel else ("theta_o", "phi_o")
        self.axes = (
            Axis("theta_i", ti, domain=domains.get("theta_i")),
            _phi_axis("phi_i", phi_i, domain=domains.get("phi_i")),
            Axis(o_names[0], to, domain=domains.get(o_names[0])),
            _phi_axis(o_names[1], phi_o, centred=rel, domain=domains.get(o_names[1])),
        )
        self._trig = [(np.cos(a.values), np.sin(a.values)) for a in self.axes]
        if phi_d_fold == "bilateral":
            self._check_bilateral()

    def _check_bilateral(self):
        if self.relative_to != "none":
            raise ParameterError("phi_d_fold", "a bilateral fold needs absolute outgoing angles (relative_to = 'none')")
        a_pi, a_po = self.axes[1], self.axes[3]
        if len(a_pi) != 1:
            raise ParameterError("phi_i", f"a bilateral fold holds phi_o - phi_i of an isotropic BRDF: one phi_i node, "
                                 f"not {len(a_pi)}")
        p0 = a_pi.values[0]
        if a_po.values[0] < p0 - 1e-12 or a_po.values[-1] > p0 + np.pi + 1e-12:
            raise ParameterError("phi_o", f"with a bilateral fold the phi_o nodes lie in [phi_i, phi_i + 180] degrees "
                                 f"([{np.degrees(p0):g}, {np.degrees(p0) + 180:g}]), got {np.degrees(a_po.values[0]):g}"
                                 f" .. {np.degrees(a_po.values[-1]):g}")

    def attrs(self) -> dict:
        return {"parameterization": "spherical", "grid": "spherical", "relative_to": self.relative_to,
                "sample_position": "explicit", "phi_d_fold": self.phi_d_fold}

    def _directions(self, idx):
        i_ti, i_pi, i_to, i_po = idx
        ti = self.axes[0].values[i_ti]
        pi_ = self.axes[1].values[i_pi]
        to = self.axes[2].values[i_to]
        po = self.axes[3].values[i_po]
        if self.relative_to == "specular":
            to = ti + to
            po = pi_ + np.pi + po
        return sph_to_vec(ti, pi_), sph_to_vec(to, po)

    def directions_into(self, start, stop, wi, wo):
        tables = getattr(self, "_direction_tables", None)
        if tables is None:
            # sines and cosines of every θi, φi and (absolute) θo, φo the nodes use: the values
            # sph_to_vec takes per pair in :meth:`_directions`, by the same functions
            ti, pi_, to, po = (a.values for a in self.axes)
            if self.relative_to == "specular":
                to = ti[:, None] + to[None, :]
                po = pi_[:, None] + np.pi + po[None, :]
            else:
                to = np.broadcast_to(to, (len(ti), len(to)))
                po = np.broadcast_to(po, (len(pi_), len(po)))
            tables = [np.ascontiguousarray(t) for t in (np.sin(ti), np.cos(ti), np.cos(pi_), np.sin(pi_), np.sin(to),
                                                        np.cos(to), np.cos(po), np.sin(po))]
            self._direction_tables = tables
        _spherical_into(*tables, start, stop, wi, wo)

    def _coordinates(self, wi, wo, isotropic: bool = False):
        ti, pi_ = vec_to_sph(wi)
        to, po = vec_to_sph(wo)
        bilateral = self.phi_d_fold == "bilateral"
        if isotropic or bilateral:
            # An isotropic BRDF depends on φo − φi only: rotate pairs whose φi the table does
            # not cover onto its first φi node.
            ax = self.axes[1]
            off = ax.outside(pi_) if len(ax) > 1 else np.ones(np.shape(pi_), bool)
            shift = np.where(off, ax.values[0] - pi_, 0.0)
            pi_ = pi_ + shift
            po = po + shift
        if bilateral:  # mirror symmetry: |φo − φi| folded into [0, π]
            po = pi_ + np.abs(np.mod(po - pi_ + np.pi, TWO_PI) - np.pi)
        if self.relative_to == "specular":
            to = to - ti
            po = np.mod(po - pi_, TWO_PI) - np.pi  # wrap(φo − φi − π) into [−π, π)
        return [ti, pi_, to, po]

    @classmethod
    def from_config(cls, v: dict) -> "SphericalGrid":
        rel = v.get("relative_to", "none")
        o_names = ("dtheta_o", "dphi_o") if rel == "specular" else ("theta_o", "phi_o")
        wrong = ("theta_o", "phi_o") if rel == "specular" else ("dtheta_o", "dphi_o")
        for w in wrong:
            if v.get(w) is not None:
                raise ParameterError(f"{w}_deg", f"not used with relative_to = '{rel}'; give "
                                     f"{o_names[0]}_deg and {o_names[1]}_deg")
        vals = []
        for ax in ("theta_i", "phi_i") + o_names:
            if v.get(ax) is None:
                raise ParameterError(f"{ax}_deg", "missing: a spherical grid needs angles in degrees for "
                                     f"theta_i, phi_i, {o_names[0]}, {o_names[1]}")
            vals.append(v[ax])
        return cls(*vals, relative_to=rel, phi_d_fold=v.get("phi_d_fold", "none"))

    @classmethod
    def from_dataset(cls, ds, attrs):
        rel = choice_attr(attrs, "relative_to", ("none", "specular"), default="none") == "specular"
        fold = choice_attr(attrs, "phi_d_fold", FOLDS, default="none")
        names = ("theta_i", "phi_i", "dtheta_o" if rel else "theta_o", "dphi_o" if rel else "phi_o")
        vals, domains = [], {}
        for n in names:
            v, _, domain = read_coordinate(ds, n)
            vals.append(v)
            if domain is not None:
                domains[n] = domain
        try:
            return cls(*vals, relative_to="specular" if rel else "none", phi_d_fold=fold, domains=domains)
        except ParameterError as exc:
            raise ParameterError(exc.key, f"coordinate '{exc.key}': {exc.detail}") from None


def _phi_axis(name, values, centred=False, domain=None):
    """An azimuth axis: periodic when its nodes go round the circle without a wider gap at the
    seam than between them; otherwise wrapped, covering only its listed arc."""
    v = np.asarray(values, float)
    if v.ndim != 1 or v.size == 0:
        raise ParameterError(name, "an axis needs at least one value")
    lo, hi = (-np.pi, np.pi) if centred else (-TWO_PI, TWO_PI)
    check_range(name, v, lo, hi, closed=True)
    if v.size > 1 and np.isclose(v[-1] - v[0], TWO_PI, rtol=0, atol=1e-9):
        v = v[:-1]  # 0° and 360° are one azimuth: keep the first
    if v[-1] - v[0] >= TWO_PI:
        raise ParameterError(name, "azimuths must span less than 360 degrees")
    if v.size > 1:
        seam = v[0] + TWO_PI - v[-1]
        if seam <= np.diff(v).max() * (1 + 1e-9):
            return Axis(name, v, "linear", TWO_PI)
    return Axis(name, v, "linear", None, TWO_PI, domain=domain)


@kernel
def _spherical_into(sti, cti, cpi, spi, sto, cto, cpo, spo, start, stop, wi, wo):
    """:meth:`SphericalGrid.directions_into`: sph_to_vec's products from the node tables
    (θo and φo per (θi, θo) and (φi, φo), relative to the mirror direction or not)."""
    npi, nto, npo = cpi.shape[0], sto.shape[1], cpo.shape[1]
    for k in range(stop - start):
        iti, ipi, ito, ipo = unravel4(start + k, npi, nto, npo)
        wi[k, 0] = sti[iti] * cpi[ipi]
        wi[k, 1] = sti[iti] * spi[ipi]
        wi[k, 2] = cti[iti]
        wo[k, 0] = sto[iti, ito] * cpo[ipi, ipo]
        wo[k, 1] = sto[iti, ito] * spo[ipi, ipo]
        wo[k, 2] = cto[iti, ito]
