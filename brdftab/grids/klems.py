"""Klems angle bases (LBNL WINDOW / Radiance BSDF matrices, ``formats/radiance.md``).

A Klems basis divides the hemisphere into rings of patches: ring ``r`` spans polar angles
``[lo_r, lo_{r+1})`` and holds ``n_r`` patches, patch ``k`` centred at azimuth ``360° k / n_r``
(spanning ±half a patch). The bases are Radiance's ``abase_list`` (``bsdf_m.c`` revision 3.46, 2022, the library
``pyradiance`` ships; revisions before it listed other half and quarter rings):

==================  =====================================================================  =======
basis               rings (lower θ in degrees, patches)                                     patches
==================  =====================================================================  =======
LBNL/Klems Full     (0,1) (5,8) (15,16) (25,20) (35,24) (45,24) (55,24) (65,16) (75,12)      145
LBNL/Klems Half     (0,1) (6.5,8) (19.5,12) (32.5,16) (45.5,20) (58.5,12) (71.5,8)           77
LBNL/Klems Quarter  (0,1) (9,8) (27,12) (45,12) (63,8)                                       41
==================  =====================================================================  =======

A :class:`KlemsGrid` has two axes of patch indices, ``klems_i`` (incident patch) and
``klems_o`` (outgoing patch). The outgoing patch of ωo is the patch holding ωo; the incident
patch of ωi is the patch holding (−x, −y, z) of ωi (Radiance's ``fi_getndx``: incident vectors
are the outgoing ones with x and y negated, so the diagonal i = o of a reflection matrix is the
mirror direction). A table on this grid is constant over each pair of patches: it returns the
value of the pair of patches holding (ωi, ωo), as Radiance's BSDF library does. The node
directions (used to tabulate on the grid and by the checks) are the patch centres: polar angle
the middle of the ring's bounds (the ``<Theta>`` a WINDOW file lists; the normal for the polar
cap), azimuth ``360° k / n_r``; an incident node is the away-pointing direction whose
(−x, −y, z) is that centre.

The projected solid angle of a patch is ``π (cos² lo − cos² hi) / n`` (Radiance's ``io_getohm``).
"""

from __future__ import annotations

import numpy as np

from ..errors import ParameterError
from ..params import Param
from .axis import LONG_NAMES, Axis
from .base import Grid, choice_attr, register

__all__ = ["KlemsGrid", "KLEMS_BASES", "BASIS_NAMES", "klems_index", "klems_rings"]

#: (lower polar angle in degrees, patches) per ring, and the upper bound 90°, per basis.
KLEMS_BASES = {
    "full": ((0.0, 1), (5.0, 8), (15.0, 16), (25.0, 20), (35.0, 24), (45.0, 24), (55.0, 24), (65.0, 16), (75.0, 12)),
    "half": ((0.0, 1), (6.5, 8), (19.5, 12), (32.5, 16), (45.5, 20), (58.5, 12), (71.5, 8)),
    "quarter": ((0.0, 1), (9.0, 8), (27.0, 12), (45.0, 12), (63.0, 8)),
}
#: The names files give the bases.
BASIS_NAMES = {"full": "LBNL/Klems Full", "half": "LBNL/Klems Half", "quarter": "LBNL/Klems Quarter"}

LONG_NAMES.setdefault("klems_i", "Klems patch of the incident direction (the patch holding (-x, -y, z) of wi)")
LONG_NAMES.setdefault("klems_o", "Klems patch of the outgoing direction")


def klems_rings(basis: str):
    """``(lower bounds [deg], upper bounds [deg], patches per ring, first patch index per ring)``."""
    rings = KLEMS_BASES[basis]
    lo = np.array([r[0] for r in rings])
    hi = np.append(lo[1:], 90.0)
    n = np.array([r[1] for r in rings])
    first = np.concatenate([[0], np.cumsum(n)[:-1]])
    return lo, hi, n, first


def klems_index(v, basis: str = "full"):
    """Patch index of away-pointing directions ``v[..., 3]`` (Radiance's ``fo_getndx``: the ring
    from the polar angle, the patch ``int(azimuth · n / 360 + 0.5) mod n``); −1 below the horizon."""
    lo, _, n, first = klems_rings(basis)
    v = np.asarray(v, float)
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    with np.errstate(invalid="ignore"):
        pol = np.degrees(np.arccos(np.clip(z, -1.0, 1.0)))
    azi = np.degrees(np.arctan2(y, x))
    azi = np.where(azi < 0.0, azi + 360.0, azi)
    ring = np.searchsorted(lo, pol, side="right") - 1
    ring = np.clip(ring, 0, lo.size - 1)
    k = np.floor(azi * n[ring] / 360.0 + 0.5).astype(np.intp)
    k = np.where(k >= n[ring], 0, k)
    idx = first[ring] + k
    return np.where((z >= 0.0) & (pol < 90.0) & np.isfinite(pol), idx, -1)


@register
class KlemsGrid(Grid):
    """Pairs of Klems patches (incident, outgoing): the layout of LBNL WINDOW / Radiance BSDF matrices."""

    type_name = "klems"
    summary = ("Klems angle basis (LBNL WINDOW / Radiance XML matrices): incident and outgoing patch indices, "
               "145 x 145 for the full basis; constant over each pair of patches.")
    parameterizations = ("klems",)
    parameterization = "klems"
    compiled = False
    node_checks = False
    params = (
        Param("basis", "choice", "Klems basis: full (145 patches), half (77) or quarter (41).", default="full",
              choices=tuple(KLEMS_BASES)),
    )

    def __init__(self, basis: str = "full"):
        if basis not in KLEMS_BASES:
            raise ParameterError("basis", f"expected one of {', '.join(KLEMS_BASES)}, got {basis!r}")
        self.basis = basis
        lo, hi, n, first = klems_rings(basis)
        self.n_patches = int(n.sum())
        idx = np.arange(float(self.n_patches))
        self.axes = (Axis("klems_i", idx), Axis("klems_o", idx))
        ring = np.repeat(np.arange(n.size), n)
        k = np.arange(self.n_patches) - first[ring]
        theta = np.radians(np.where(ring == 0, 0.0, 0.5 * (lo[ring] + hi[ring])))
        #: patch centres [rad] (polar angle, azimuth)
        self.theta_c, self.phi_c = theta, 2.0 * np.pi * k / n[ring]
        #: projected solid angle of each patch [sr]
        c_lo, c_hi = np.cos(np.radians(lo)), np.cos(np.radians(hi))
        self.lambdas = (np.pi * (c_lo ** 2 - c_hi ** 2) / n)[ring]

    @property
    def basis_name(self) -> str:
        return BASIS_NAMES[self.basis]

    def attrs(self) -> dict:
        return {"parameterization": "klems", "grid": "klems", "klems_basis": self.basis_name,
                "sample_position": "explicit", "phi_d_fold": "none"}

    def coord_attrs(self, name) -> dict:
        return {"units": "1", "long_name": LONG_NAMES[name], "node_rule": "explicit",
                "comment": f"{self.basis_name} patch index (formats/radiance.md)"}

    def patch_direction(self, idx):
        """Away-pointing unit vectors of the centres of patches ``idx`` (outgoing sense)."""
        from ..geometry import sph_to_vec

        idx = np.asarray(idx, np.intp)
        return sph_to_vec(self.theta_c[idx], self.phi_c[idx])

    def _directions(self, idx):
        i, o = idx
        wi = self.patch_direction(i)
        wi[..., :2] *= -1.0
        return wi, self.patch_direction(o)

    def pair_directions(self, coords):
        """``(wi, wo)`` of patch coordinates (the nodes: patch centres)."""
        return self._directions([np.rint(np.asarray(c, float)).astype(np.intp) for c in coords])

    def _coordinates(self, wi, wo, isotropic: bool = False):
        wi = np.array(wi, float)
        wi[..., :2] *= -1.0
        return [klems_index(wi, self.basis).astype(float), klems_index(wo, self.basis).astype(float)]

    def locate(self, wi, wo, isotropic: bool = False):
        i, o = self._coordinates(wi, wo)
        outside = (i < 0) | (o < 0)
        return [np.maximum(i, 0.0), np.maximum(o, 0.0)], outside

    def outgoing_rule(self, wi, wavelengths=None):
        """``(wo[N, 3], w[N] sr)``: one node per outgoing patch (its centre) weighted by the
        patch's projected solid angle over cos θ: exact for a table constant over patches."""
        wo = self.patch_direction(np.arange(self.n_patches))
        return wo, self.lambdas / wo[:, 2]

    def _patch_points(self, n: int):
        """``[P, n·n, 3]``: ``n × n`` points in each patch at the centres of equal cells in
        (cos²θ, φ), so each carries an equal share of the patch's projected solid angle."""
        cached = getattr(self, "_points", {})
        if n in cached:
            return cached[n]
        from ..geometry import sph_to_vec

        lo, hi, counts, first = klems_rings(self.basis)
        t = (np.arange(n) + 0.5) / n
        dirs = np.empty((self.n_patches, n * n, 3))
        for r in range(lo.size):
            c_lo, c_hi = np.cos(np.radians(lo[r])) ** 2, np.cos(np.radians(hi[r])) ** 2
            theta = np.arccos(np.sqrt(c_lo + t * (c_hi - c_lo)))
            width = 2.0 * np.pi / counts[r]
            for k in range(counts[r]):
                T, P = np.meshgrid(theta, width * (k - 0.5 + t), indexing="ij")
                dirs[first[r] + k] = sph_to_vec(T.ravel(), P.ravel())
        self._points = {**cached, n: dirs}
        return dirs

    def outgoing_samples(self, flat, n: int):
        """``(wi[m, 3], wo[m, n·n, 3])`` of flat node indices: the incident patch's centre and
        ``n × n`` points of equal projected solid angle in the outgoing patch (their mean is the
        patch average, :func:`brdftab.grids.cells.cell_averages`)."""
        i, o = np.unravel_index(np.asarray(flat, np.intp), self.shape)
        wi = self.patch_direction(i)
        wi[..., :2] *= -1.0
        return wi, self._patch_points(n)[o]

    @classmethod
    def from_config(cls, values: dict) -> "KlemsGrid":
        return cls(values.get("basis", "full"))

    @classmethod
    def from_dataset(cls, ds, attrs) -> "KlemsGrid":
        name = choice_attr(attrs, "klems_basis", tuple(BASIS_NAMES.values()))
        grid = cls(next(k for k, v in BASIS_NAMES.items() if v == name))
        for ax in grid.axes:
            if ax.name not in ds.variables:
                raise ParameterError(ax.name, f"missing coordinate '{ax.name}'")
            v = np.asarray(ds[ax.name].values, float)
            if v.shape != ax.values.shape or not np.array_equal(v, ax.values):
                raise ParameterError(ax.name, f"coordinate '{ax.name}' must hold the patch indices 0 .. "
                                     f"{grid.n_patches - 1} of the {name} basis")
        return grid
