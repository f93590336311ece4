"""Tensor-tree grids (Radiance XML ``TensorTree3`` / ``TensorTree4``, ``formats/radiance.md``).

Radiance's variable-resolution BSDFs (``bsdf_t.c``) index a tree over [0, 1)^nd. Directions
map to square coordinates through Shirley and Chiu's concentric ``disk2square`` of the
projected direction (x, y), which keeps projected solid angle (equal squares, equal projected
solid angles):

* ``TensorTree4`` (anisotropic): ``disk2square(−wi.x, −wi.y)`` for the incident direction and
  ``disk2square(wo.x, wo.y)`` for the outgoing one (axes ``tt_ix, tt_iy, tt_ox, tt_oy``);
* ``TensorTree3`` (isotropic): the first coordinate is ``0.5 − 10⁻⁶ − 0.5 sinθi`` (in [0, 0.5)),
  the other two are ``disk2square`` of ωo turned about the normal by ``−atan2(−wi.y, −wi.x)``,
  which puts the mirror direction on +x (axes ``tt_i, tt_ox, tt_oy``).

A :class:`TensorTreeGrid` of ``level`` L is the full-resolution tree: 2^L cells per coordinate
(2^(L−1) along ``tt_i``, which covers [0, 0.5) only), each node at its cell's centre in square
coordinates. A tree read from a file is expanded to the grid of its deepest leaf, each leaf's
value repeated over the cells it covers. A table on this grid is constant over each cell: it
returns the value of the cell holding the query's square coordinates, as Radiance's
``SDlookupTre`` does ("no interpolation").
"""

from __future__ import annotations

import numpy as np

from ..errors import ParameterError
from ..params import Param
from .axis import LONG_NAMES, Axis
from .base import Grid, register

__all__ = ["TensorTreeGrid", "disk2square", "square2disk", "MAX_LEVEL", "FTINY"]

#: Radiance's FTINY (``fvect.h``), subtracted from the first coordinate of an isotropic tree.
FTINY = 1e-6
#: The deepest tree brdftab builds (2^MAX_LEVEL cells per coordinate).
MAX_LEVEL = 10
#: Radiance's guard factor in ``square2disk`` / ``disk2square``.
_SHRINK = 0.9999999999999
_NAMES = {3: ("tt_i", "tt_ox", "tt_oy"), 4: ("tt_ix", "tt_iy", "tt_ox", "tt_oy")}
for _n, _doc in (("tt_i", "0.5 - 0.5 sin(theta_i) (isotropic tensor tree)"),
                 ("tt_ix", "Shirley-Chiu square x of (-wi.x, -wi.y)"), ("tt_iy", "Shirley-Chiu square y of (-wi.x, -wi.y)"),
                 ("tt_ox", "Shirley-Chiu square x of the outgoing (x, y)"),
                 ("tt_oy", "Shirley-Chiu square y of the outgoing (x, y)")):
    LONG_NAMES.setdefault(_n, _doc)


def disk2square(x, y):
    """Shirley-Chiu concentric map of unit-disk points to [0, 1]² (Radiance's ``disk2square``)."""
    x, y = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float))
    r = np.hypot(x, y)
    phi = np.arctan2(y, x)
    phi = np.where(phi < -np.pi / 4, phi + 2 * np.pi, phi)
    q = np.pi / 4
    a = np.select([phi < q, phi < 3 * q, phi < 5 * q],
                  [r, -(phi - np.pi / 2) * r / q, -r], -(phi - 3 * np.pi / 2) * (-r) / q)
    b = np.select([phi < q, phi < 3 * q, phi < 5 * q],
                  [phi * r / q, r, (phi - np.pi) * (-r) / q], -r)
    return a * (0.5 / _SHRINK) + 0.5, b * (0.5 / _SHRINK) + 0.5


def square2disk(sx, sy):
    """The inverse of :func:`disk2square` (Radiance's ``square2disk``): [0, 1]² to the unit disk."""
    a = 2.0 * np.asarray(sx, float) - 1.0
    b = 2.0 * np.asarray(sy, float) - 1.0
    a, b = np.broadcast_arrays(a, b)
    q = np.pi / 4
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.select([(a > -b) & (a > b), a > -b, a < b], [a, b, -a], -b)
        phi = np.select([(a > -b) & (a > b), a > -b, a < b],
                        [q * (b / a), q * (2.0 - a / b), q * (4.0 + b / a)],
                        np.where(b != 0.0, q * (6.0 - a / b), 0.0))
    r = r * _SHRINK
    return r * np.cos(phi), r * np.sin(phi)


def _z(x, y):
    return np.sqrt(np.maximum(1.0 - x * x - y * y, 0.0))


@register
class TensorTreeGrid(Grid):
    """A full-resolution Radiance tensor tree: square coordinates of (ωi, ωo), 2^level cells each."""

    type_name = "tensor-tree"
    summary = ("Radiance tensor tree (XML TensorTree3 isotropic / TensorTree4 anisotropic): Shirley-Chiu square "
               "coordinates of the incident and outgoing directions, 2^level cells each; constant over each cell.")
    parameterizations = ("tensor-tree",)
    parameterization = "tensor-tree"
    compiled = False
    node_checks = False
    params = (
        Param("rank", "int", "3: isotropic tree (TensorTree3); 4: anisotropic (TensorTree4).", default=3, minimum=3,
              maximum=4),
        Param("level", "int", "Cells per coordinate = 2^level.", default=5, minimum=1, maximum=MAX_LEVEL),
    )

    def __init__(self, rank: int = 3, level: int = 5):
        if rank not in (3, 4):
            raise ParameterError("rank", f"expected 3 or 4, got {rank!r}")
        if isinstance(level, bool) or not isinstance(level, (int, np.integer)) or not 1 <= level <= MAX_LEVEL:
            raise ParameterError("level", f"expected a whole number from 1 to {MAX_LEVEL}, got {level!r}")
        self.rank, self.level = int(rank), int(level)
        res = 1 << self.level
        centres = (np.arange(res) + 0.5) / res
        names = _NAMES[self.rank]
        self.axes = tuple(Axis(n, centres[: res // 2] if (self.rank == 3 and k == 0) else centres,
                               domain=(0.0, 0.5) if (self.rank == 3 and k == 0) else (0.0, 1.0))
                          for k, n in enumerate(names))
        self.isotropic = self.rank == 3

    @property
    def resolution(self) -> int:
        return 1 << self.level

    def attrs(self) -> dict:
        return {"parameterization": "tensor-tree", "grid": "tensor-tree", "tree_rank": self.rank,
                "tree_level": self.level, "sample_position": "bin-centre", "phi_d_fold": "none"}

    def coord_attrs(self, name) -> dict:
        return {"units": "1", "long_name": LONG_NAMES[name], "node_rule": "bin-centre",
                "comment": "cell centres in Radiance's tensor-tree square coordinates (formats/radiance.md)"}

    def _directions(self, idx):
        vals = [ax.values[i] for ax, i in zip(self.axes, idx)]
        if self.rank == 4:
            dx, dy = square2disk(vals[0], vals[1])
            wi = np.stack([-dx, -dy, _z(dx, dy)], axis=-1)
            ox, oy = square2disk(vals[2], vals[3])
        else:
            s = np.clip(1.0 - 2.0 * vals[0], 0.0, 1.0)  # sin(theta_i) at the cell centre, wi at azimuth 0
            wi = np.stack([s, np.zeros_like(s), np.sqrt(1.0 - s * s)], axis=-1)
            ox, oy = square2disk(vals[1], vals[2])
            ox, oy = -ox, -oy  # turned back by atan2(-wi.y, -wi.x) = pi
        return wi, np.stack([ox, oy, _z(ox, oy)], axis=-1)

    def pair_directions(self, coords):
        """``(wi, wo)`` of square coordinates (one array per axis)."""
        res = self.resolution
        idx = [np.clip(np.floor(np.asarray(c, float) * res), 0, len(ax) - 1).astype(np.intp)
               for c, ax in zip(coords, self.axes)]
        return self._directions(idx)

    def square_coordinates(self, wi, wo):
        """Radiance's grid position of direction pairs (``SDqueryTre``): one array per axis."""
        wi, wo = np.asarray(wi, float), np.asarray(wo, float)
        if self.rank == 4:
            a, b = disk2square(-wi[..., 0], -wi[..., 1])
            c, d = disk2square(wo[..., 0], wo[..., 1])
            return [a, b, c, d]
        first = (0.5 - FTINY) - 0.5 * np.hypot(wi[..., 0], wi[..., 1])
        ang = -np.arctan2(-wi[..., 1], -wi[..., 0])
        ca, sa = np.cos(ang), np.sin(ang)
        rx = ca * wo[..., 0] - sa * wo[..., 1]
        ry = sa * wo[..., 0] + ca * wo[..., 1]
        c, d = disk2square(rx, ry)
        return [first, c, d]

    def locate(self, wi, wo, isotropic: bool = False):
        pos = self.square_coordinates(wi, wo)
        res = self.resolution
        idx, outside = [], np.zeros(np.shape(pos[0]), bool)
        for ax, p in zip(self.axes, pos):
            outside |= ~np.isfinite(p)
            k = np.floor(np.where(np.isfinite(p), p, 0.0) * res)
            idx.append(np.clip(k, 0.0, len(ax) - 1.0))
        return idx, outside

    def _coordinates(self, wi, wo, isotropic: bool = False):
        return self.square_coordinates(wi, wo)

    def outgoing_rule(self, wi, wavelengths=None):
        """``(wo[N, 3], w[N] sr)``: one node per outgoing cell (the centre of the cell in square
        coordinates, mapped back for this ``wi``), weighted by its projected solid angle π / 4^level
        over cos θ (the concentric map keeps area): exact for a table constant over cells."""
        res = self.resolution
        c = (np.arange(res) + 0.5) / res
        sx, sy = (a.ravel() for a in np.meshgrid(c, c, indexing="ij"))
        x, y = square2disk(sx, sy)
        if self.rank == 3:
            wi = np.asarray(wi, float)
            ang = np.arctan2(-wi[1], -wi[0])  # undo the turn by -atan2(-wi.y, -wi.x)
            x, y = np.cos(ang) * x - np.sin(ang) * y, np.sin(ang) * x + np.cos(ang) * y
        wo = np.stack([x, y, _z(x, y)], axis=-1)
        return wo, np.full(x.size, np.pi / res ** 2) / np.maximum(wo[:, 2], 1e-300)

    def outgoing_samples(self, flat, n: int):
        """``(wi[m, 3], wo[m, n·n, 3])`` of flat node indices: the incident cell's centre and
        ``n × n`` sub-cell centres of the outgoing cell (equal projected solid angles: the
        concentric map keeps area), turned as the isotropic tree turns them."""
        idx = np.unravel_index(np.asarray(flat, np.intp), self.shape)
        centre = [ax.values[i] for ax, i in zip(self.axes, idx)]
        wi, _ = self._directions(idx)
        res = self.resolution
        t = (np.arange(n) + 0.5) / n
        sx, sy = (a.ravel() for a in np.meshgrid(t, t, indexing="ij"))
        ox = (np.floor(centre[-2] * res)[:, None] + sx[None, :]) / res
        oy = (np.floor(centre[-1] * res)[:, None] + sy[None, :]) / res
        x, y = square2disk(ox, oy)
        if self.rank == 3:
            x, y = -x, -y  # the incident node lies at azimuth 0: turned back by pi
        return wi, np.stack([x, y, _z(x, y)], axis=-1)

    @classmethod
    def from_config(cls, values: dict) -> "TensorTreeGrid":
        return cls(values.get("rank", 3), values.get("level", 5))

    @classmethod
    def from_dataset(cls, ds, attrs) -> "TensorTreeGrid":
        try:
            rank, level = int(attrs.get("tree_rank")), int(attrs.get("tree_level"))
        except (TypeError, ValueError):
            raise ParameterError("tree_level", "a tensor-tree table needs integer attributes 'tree_rank' and "
                                 "'tree_level'") from None
        grid = cls(rank, level)
        for ax in grid.axes:
            if ax.name not in ds.variables:
                raise ParameterError(ax.name, f"missing coordinate '{ax.name}'")
            v = np.asarray(ds[ax.name].values, float)
            if v.shape != ax.values.shape or not np.allclose(v, ax.values, rtol=0, atol=1e-12):
                raise ParameterError(ax.name, f"coordinate '{ax.name}' must hold the cell centres of a level-{level} "
                                     "tensor tree")
        return grid
