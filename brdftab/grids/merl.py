"""The exact MERL 90×90×180 grid: a Rusinkiewicz grid with MERL's warp, bins and fold.

θh nodes on the square-root warp θh = (u/90)²·π/2, 90 θd nodes of 1°, 180 φd nodes of 1° over
[0, π) folded by reciprocity; node u = i + ½ (``bin-centre``, default) or u = i
(``lower-edge``). Tables on it are stored as Rusinkiewicz tables with ``grid = "merl"``.

Reference: W. Matusik et al., SIGGRAPH (2003), ``BRDFRead.cpp`` [Matusik2003].
"""

from __future__ import annotations

from ..params import Param
from .axis import SAMPLE_POSITIONS
from .base import Grid, register
from .rusinkiewicz import RusinkiewiczGrid

__all__ = ["merl_grid", "MerlGridType"]


def merl_grid(sample_position: str = "bin-centre") -> RusinkiewiczGrid:
    """The exact MERL 90×90×180 grid (θh square-root warp, φd over [0, π) by reciprocity)."""
    return RusinkiewiczGrid(90, 90, 180, theta_h_spacing="merl", phi_d_fold="reciprocity",
                            sample_position=sample_position, name="merl")


@register
class MerlGridType(Grid):
    """Spec entry ``type = "merl"``: builds a :class:`RusinkiewiczGrid` (see :func:`merl_grid`); never
    instantiated itself."""

    type_name = "merl"
    summary = "The exact MERL 90 x 90 x 180 grid (sqrt theta_h warp, phi_d folded by reciprocity)."
    parameterizations = ()
    params = (Param("sample_position", "choice", "Where nodes sit in MERL's bins.", default="bin-centre",
                    choices=SAMPLE_POSITIONS),)

    @classmethod
    def from_config(cls, v: dict) -> RusinkiewiczGrid:
        return merl_grid(v.get("sample_position", "bin-centre"))
