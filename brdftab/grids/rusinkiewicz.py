"""Rusinkiewicz half/difference grids, isotropic (θh, θd, φd) and anisotropic (θh, φh, θd, φd).

θh nodes are uniform in θh (``theta_h_spacing = "linear"``), uniform in sqrt(θh/(π/2)) (``"merl"``,
MERL's warp), or an explicit list; θd is uniform or explicit; φd is stored over the range of
its fold (see :mod:`brdftab.grids.axis`). Uniform axes place node i at the centre (default)
or the lower edge of bin i (``sample_position``).

Reference: S. M. Rusinkiewicz, EGWR (1998) [Rusinkiewicz1998]; MERL ``BRDFRead.cpp``
[Matusik2003].
"""

from __future__ import annotations

import numpy as np

from .._jit import kernel
from ..errors import ParameterError
from ..geometry import _hd_to_io_trig, hd_to_io_scalar, io_to_hd
from ..params import Param, unknown
from .axis import (HALF_PI, MAX_AXIS_NODES, PHI_D_FOLDS, SAMPLE_POSITIONS, TWO_PI, Axis, angle_axis, check_range,
                   count, fold_phi_d, uniform_values)
from .base import Grid, choice_attr, read_coordinate, register, unravel4

__all__ = ["RusinkiewiczGrid"]

_SPACINGS = ("linear", "merl")
_DEFAULT_COUNTS = {"theta_h": 90, "theta_d": 90, "phi_d": 180, "phi_h": 360}


def _n(axis, default):
    return Param(f"n_{axis}", "int", f"Number of uniform {axis} nodes (default {default}).", default=default,
                 minimum=1, maximum=MAX_AXIS_NODES)


def _list(axis):
    return Param(axis, "angles", f"Explicit {axis} nodes instead of n_{axis}.", default=None, angle=True,
                 units="deg")


@register
class RusinkiewiczGrid(Grid):
    """Half/difference grid (isotropic or anisotropic). See the module docstring."""

    type_name = "rusinkiewicz"
    summary = "Rusinkiewicz half/difference angles (theta_h, [phi_h,] theta_d, phi_d)."
    parameterizations = ("rusinkiewicz", "rusinkiewicz-anisotropic")
    parameterization = "rusinkiewicz"
    params = (
        Param("anisotropic", "bool", "Add the phi_h axis (for anisotropic models).", default=False),
        Param("theta_h_spacing", "choice", "theta_h nodes uniform in theta_h (linear) or in sqrt(theta_h) (merl).",
              default="linear", choices=_SPACINGS),
        Param("phi_d_fold", "choice", "Symmetry the phi_d axis is folded by.", default="reciprocity",
              choices=tuple(PHI_D_FOLDS)),
        Param("sample_position", "choice", "Where uniform nodes sit in their bins.", default="bin-centre",
              choices=SAMPLE_POSITIONS),
        _n("theta_h", 90), _n("theta_d", 90), _n("phi_d", 180), _n("phi_h", 360),
        _list("theta_h"), _list("theta_d"), _list("phi_d"), _list("phi_h"),
    )

    def __init__(self, theta_h=90, theta_d=90, phi_d=180, phi_h=None, *, theta_h_spacing="linear",
                 phi_d_fold="reciprocity", sample_position="bin-centre", name="rusinkiewicz"):
        if not isinstance(phi_d_fold, str) or phi_d_fold not in PHI_D_FOLDS:
            raise ParameterError("phi_d_fold", unknown("phi_d_fold", phi_d_fold, PHI_D_FOLDS))
        if not isinstance(sample_position, str) or sample_position not in SAMPLE_POSITIONS:
            raise ParameterError("sample_position", unknown("sample_position", sample_position, SAMPLE_POSITIONS))
        if not isinstance(theta_h_spacing, str) or theta_h_spacing not in ("linear", "merl", "explicit"):
            raise ParameterError("theta_h_spacing", f"expected 'linear', 'merl' or an explicit list, got "
                                 f"{theta_h_spacing!r}")
        self.anisotropic = phi_h is not None
        if self.anisotropic and "bilateral" in phi_d_fold:
            raise ParameterError("phi_d_fold", "a bilateral fold assumes isotropy; use 'none' or 'reciprocity' "
                                 "with an anisotropic grid")
        self.theta_h_spacing = "explicit" if not np.isscalar(theta_h) else theta_h_spacing
        self.phi_d_fold = phi_d_fold
        self.sample_position = sample_position
        self.name = name
        specs = {"theta_h": theta_h, "theta_d": theta_d, "phi_d": phi_d, "phi_h": phi_h}
        axes = {}
        for label in self._names(self.anisotropic):
            spec = specs[label]
            lo, length, periodic = self._natural(label, phi_d_fold)
            warp = "sqrt" if (label == "theta_h" and self.theta_h_spacing == "merl") else "linear"
            if np.isscalar(spec):
                vals = uniform_values(count(label, spec), lo, length, sample_position, warp)
                axes[label] = Axis(label, vals, warp, length if periodic else None, domain=(lo, lo + length),
                                   rule=sample_position)
            else:
                vals = np.asarray(spec, float)
                why = f" (phi_d_fold = '{phi_d_fold}')" if label == "phi_d" else ""
                check_range(label, vals, lo, lo + length, closed=not periodic, why=why)
                axes[label] = angle_axis(label, vals, length) if periodic else Axis(label, vals, "linear", None)
        self._set_axes(tuple(axes[n] for n in self._names(self.anisotropic)))

    @staticmethod
    def _names(aniso):
        return ("theta_h", "phi_h", "theta_d", "phi_d") if aniso else ("theta_h", "theta_d", "phi_d")

    @staticmethod
    def _natural(label, fold):
        """(lower end, length, periodic) of an axis' natural range."""
        if label in ("theta_h", "theta_d"):
            return 0.0, HALF_PI, False
        if label == "phi_h":
            return 0.0, TWO_PI, True
        length, periodic = PHI_D_FOLDS[fold]
        return 0.0, length, periodic

    def _set_axes(self, axes):
        self.axes = axes
        self._trig = [(np.cos(a.values), np.sin(a.values)) for a in self.axes]

    def attrs(self) -> dict:
        explicit = all(a.rule == "explicit" for a in self.axes)
        return {
            "parameterization": "rusinkiewicz-anisotropic" if self.anisotropic else "rusinkiewicz",
            "grid": self.name,
            "theta_h_spacing": self.theta_h_spacing,
            "phi_d_fold": self.phi_d_fold,
            "sample_position": "explicit" if explicit else self.sample_position,
        }

    def _directions(self, idx):
        if self.anisotropic:
            (cth, sth), (cph, sph), (ctd, std), (cpd, spd) = self._trig
            ih, iph, itd, ipd = idx
            return _hd_to_io_trig(cth[ih], sth[ih], cph[iph], sph[iph], ctd[itd], std[itd], cpd[ipd], spd[ipd])
        (cth, sth), (ctd, std), (cpd, spd) = self._trig
        ih, itd, ipd = idx
        return _hd_to_io_trig(cth[ih], sth[ih], 1.0, 0.0, ctd[itd], std[itd], cpd[ipd], spd[ipd])

    def node_trig(self):
        """``(cosθh, sinθh, cosφh, sinφh, cosθd, sinθd, cosφd, sinφd)`` of the axes' nodes (an
        isotropic grid's φh: the single node 0), the per-axis tables of :meth:`directions`."""
        if self.anisotropic:
            (cth, sth), (cph, sph), (ctd, std), (cpd, spd) = self._trig
        else:
            (cth, sth), (ctd, std), (cpd, spd) = self._trig
            cph, sph = np.ones(1), np.zeros(1)
        return tuple(np.ascontiguousarray(a, float) for a in (cth, sth, cph, sph, ctd, std, cpd, spd))

    def directions_into(self, start, stop, wi, wo):
        _directions_into(*self.node_trig(), start, stop, wi, wo)

    def node_above_horizon(self) -> np.ndarray:
        """Both directions above the horizon, from the node angles (φh does not change z):
        wi_z = cosθh cosθd − sinθh sinθd cosφd, wo_z = cosθh cosθd + sinθh sinθd cosφd."""
        cached = getattr(self, "_above", None)
        if cached is not None:
            return cached
        from ..brdf import HORIZON

        th, td, pd = (self.axes[i] for i in ((0, 2, 3) if self.anisotropic else (0, 1, 2)))
        a = (np.cos(th.values)[:, None, None] * np.cos(td.values)[None, :, None])
        b = np.abs(np.sin(th.values)[:, None, None] * np.sin(td.values)[None, :, None]
                   * np.cos(pd.values)[None, None, :])
        above = (a - b) > HORIZON  # the lower of wi_z and wo_z
        if self.anisotropic:
            above = np.broadcast_to(above[:, None], self.shape)
        self._above = above
        return above

    def _coordinates(self, wi, wo, isotropic: bool = False):
        th, ph, td, pd = io_to_hd(wi, wo)
        pd = fold_phi_d(pd, self.phi_d_fold)
        return [th, ph, td, pd] if self.anisotropic else [th, td, pd]

    # -- construction --------------------------------------------------------------------------
    @classmethod
    def from_config(cls, v: dict) -> "RusinkiewiczGrid":
        aniso = v.get("anisotropic", False)
        axes = {}
        for ax in ("theta_h", "theta_d", "phi_d", "phi_h"):
            given_n, given_list = f"n_{ax}" in v, v.get(ax) is not None
            if ax == "phi_h" and not aniso:
                if given_n or given_list:
                    raise ParameterError(f"n_{ax}" if given_n else f"{ax}_deg",
                                         "phi_h is only sampled with anisotropic = true")
                continue
            if given_n and given_list:
                raise ParameterError(f"{ax}_deg", f"give either n_{ax} or {ax}_deg, not both")
            axes[ax] = v[ax] if given_list else v.get(f"n_{ax}", _DEFAULT_COUNTS[ax])
        if v.get("theta_h") is not None and "theta_h_spacing" in v:
            raise ParameterError("theta_h_spacing", "not used with an explicit theta_h_deg list")
        return cls(axes["theta_h"], axes["theta_d"], axes["phi_d"], axes.get("phi_h"),
                   theta_h_spacing=v.get("theta_h_spacing", "linear"),
                   phi_d_fold=v.get("phi_d_fold", "reciprocity"),
                   sample_position=v.get("sample_position", "bin-centre"))

    @classmethod
    def from_dataset(cls, ds, attrs):
        aniso = choice_attr(attrs, "parameterization", cls.parameterizations) == "rusinkiewicz-anisotropic"
        fold = choice_attr(attrs, "phi_d_fold", tuple(PHI_D_FOLDS))
        # Files from other writers may leave out the spacing and node positions: they are
        # inferred from the coordinates (a value that is present must be a known one).
        if "theta_h_spacing" in attrs or "sample_position" in attrs:
            spacing = choice_attr(attrs, "theta_h_spacing", ("linear", "merl", "explicit"),
                                  default=_infer(ds, fold)[0] if "theta_h_spacing" not in attrs else None)
            pos = choice_attr(attrs, "sample_position", SAMPLE_POSITIONS + ("explicit",),
                              default=_infer(ds, fold)[1] if "sample_position" not in attrs else None)
        else:
            spacing, pos = _infer(ds, fold)
        grid = cls.__new__(cls)
        grid.anisotropic = aniso
        grid.theta_h_spacing = spacing
        grid.phi_d_fold = fold
        grid.sample_position = "bin-centre" if pos == "explicit" else pos
        name = attrs.get("grid", "rusinkiewicz")
        grid.name = str(name.item() if hasattr(name, "item") else name)
        axes = []
        for label in cls._names(aniso):
            vals, rule, domain = read_coordinate(ds, label)
            if rule is None:  # files written before node rules were recorded per axis
                rule = "explicit" if (pos == "explicit" or (label == "theta_h" and spacing == "explicit")) else pos
            lo, length, periodic = cls._natural(label, fold)
            warp = "sqrt" if (label == "theta_h" and spacing == "merl") else "linear"
            if label == "theta_h" and (spacing == "explicit") != (rule == "explicit"):
                raise ParameterError(label, f"coordinate 'theta_h': node_rule {rule!r} contradicts theta_h_spacing "
                                     f"{spacing!r}")
            if rule == "explicit":
                why = f" (phi_d_fold = '{fold}')" if label == "phi_d" else ""
                try:
                    check_range(label, vals, lo, lo + length, closed=not periodic, why=why)
                except ParameterError as exc:
                    raise ParameterError(label, f"coordinate '{label}': {exc.detail}") from None
                if domain is not None and (domain[0] < lo - 1e-9 or domain[1] > lo + length + 1e-9):
                    raise ParameterError(label, f"coordinate '{label}': domain outside the axis range")
                axes.append(angle_axis(label, vals, length, domain) if periodic else
                            Axis(label, vals, warp, None, domain=domain, rule="explicit"))
            else:
                expect = uniform_values(vals.size, lo, length, rule, warp)
                diff = float(np.max(np.abs(expect - vals)))
                if diff > 1e-9:
                    what = f"theta_h_spacing = '{spacing}', " if label == "theta_h" else ""
                    what += f"phi_d_fold = '{fold}', " if label == "phi_d" else ""
                    raise ParameterError(label, f"coordinate '{label}' does not match the declared grid ({what}"
                                         f"{vals.size} nodes at '{rule}'): off by up to {np.degrees(diff):.3g} deg")
                axes.append(Axis(label, expect, warp, length if periodic else None, domain=(lo, lo + length),
                                 rule=rule))
        grid._set_axes(tuple(axes))
        if "grid" not in attrs and not aniso and spacing == "merl" and fold == "reciprocity" \
                and grid.shape == (90, 90, 180) and pos in SAMPLE_POSITIONS:
            grid.name = "merl"  # MERL's grid, written by a tool that does not name it
        return grid


def _infer(ds, fold):
    """``(theta_h_spacing, sample_position)`` that reproduce a file's θh coordinate, else explicit."""
    if "theta_h" not in ds.variables:
        return "explicit", "explicit"
    vals, _, _ = read_coordinate(ds, "theta_h")
    for spacing, warp in (("linear", "linear"), ("merl", "sqrt")):
        for pos in SAMPLE_POSITIONS:
            if np.allclose(uniform_values(vals.size, 0.0, HALF_PI, pos, warp), vals, rtol=0, atol=1e-9):
                return spacing, pos
    return "explicit", "explicit"


@kernel
def _directions_into(cth, sth, cph, sph, ctd, std, cpd, spd, start, stop, wi, wo):
    """:meth:`RusinkiewiczGrid.directions_into`: :func:`brdftab.geometry.hd_to_io_scalar` per
    node, from the per-axis cosines and sines."""
    nph, ntd, npd = cph.shape[0], ctd.shape[0], cpd.shape[0]
    for k in range(stop - start):
        ih, iph, itd, ipd = unravel4(start + k, nph, ntd, npd)
        wi[k, 0], wi[k, 1], wi[k, 2], wo[k, 0], wo[k, 1], wo[k, 2] = hd_to_io_scalar(
            cth[ih], sth[ih], cph[iph], sph[iph], ctd[itd], std[itd], cpd[ipd], spd[ipd])
