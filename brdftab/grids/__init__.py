"""Sampling grids: parameterizations that map index space to direction pairs and back.

A :class:`Grid` is a tuple of :class:`Axis` objects. It turns flat sample indices into
``(wi, wo)`` pairs (for tabulation) and direction pairs into *fractional indices* (for
interpolating a table), and it knows its domain (what a table on it covers). One module per
parameterization, each registered in :data:`GRIDS` under its spec name with its ``[grid]``
keys declared as :class:`~brdftab.params.Param`:

``rusinkiewicz`` (:mod:`.rusinkiewicz`)
    half/difference axes ``theta_h, theta_d, phi_d``; with ``anisotropic = true`` also ``phi_h``.
``merl`` (:mod:`.merl`)
    the exact MERL 90×90×180 grid (a Rusinkiewicz grid with MERL's warp, bins and fold).
``spherical`` (:mod:`.spherical`)
    gonio axes ``theta_i, phi_i, theta_o, phi_o`` (or offsets from the mirror direction).
``specular-polar`` (:mod:`.specular_polar`)
    ``theta_i, phi_i, spec_azimuth, spec_radial``: polar angles about the mirror direction (Zemax .bsdf).
``speos`` (:mod:`.speos`)
    ``theta_i, speos_rotation, theta_o, speos_phi``: Ansys Speos tables (φ = 0 on the mirror side).
``klems`` (:mod:`.klems`)
    ``klems_i, klems_o``: Klems patch pairs (LBNL WINDOW / Radiance XML matrices, 145 × 145).
``tensor-tree`` (:mod:`.tensor_tree`)
    Radiance tensor-tree square coordinates (XML ``TensorTree3`` / ``TensorTree4``).
``scattered`` (:mod:`.scattered`)
    ``sample``: scattered direction pairs (ASTM, CSV), interpolated on their Delaunay triangulation.

Axes, the φd folds and angle lists live in :mod:`.axis`.
"""

from __future__ import annotations

from ..errors import ParameterError
from .axis import (NODE_RULES, PHI_D_FOLDS, SAMPLE_POSITIONS, Axis, expand_angles,  # noqa: F401
                   fold_phi_d)
from .base import COMMON_PARAMS, GRIDS, Grid, grid_from_config, grid_from_dataset, grid_wavelengths, register
from .merl import merl_grid
from .rusinkiewicz import RusinkiewiczGrid
from .spherical import SphericalGrid
from .specular_polar import SpecularPolarGrid
from .speos import SpeosGrid
from .klems import KlemsGrid
from .tensor_tree import TensorTreeGrid
from .scattered import ScatteredGrid

__all__ = ["Axis", "Grid", "GRIDS", "GRID_TYPES", "RusinkiewiczGrid", "SphericalGrid", "SpecularPolarGrid", "SpeosGrid",
           "KlemsGrid", "TensorTreeGrid", "ScatteredGrid", "merl_grid",
           "grid_from_config", "grid_from_dataset", "grid_wavelengths", "check_grid", "fold_phi_d", "PHI_D_FOLDS", "SAMPLE_POSITIONS",
           "COMMON_PARAMS", "register"]

GRID_TYPES = tuple(GRIDS)


def check_grid(brdf, grid: Grid) -> None:
    """Refuse grids that would silently lose part of ``brdf``.

    An anisotropic BRDF needs φh (an anisotropic Rusinkiewicz grid or a spherical grid); a
    non-reciprocal one cannot be folded by reciprocity; a bilateral fold needs isotropy.
    """
    fold = getattr(grid, "phi_d_fold", "none")
    if not brdf.isotropic and getattr(grid, "anisotropic", True) is False:
        raise ParameterError("anisotropic", f"model '{brdf.name}' is anisotropic; an isotropic grid would sample "
                             "only phi_h = 0 (use an anisotropic Rusinkiewicz grid or a spherical grid)")
    if not brdf.reciprocal and "reciprocity" in fold:
        raise ParameterError("phi_d_fold", f"model '{brdf.name}' is not reciprocal; folding phi_d by reciprocity "
                             "would discard half of it (use phi_d_fold = 'none')")
    if not brdf.isotropic and "bilateral" in fold:
        raise ParameterError("phi_d_fold", f"model '{brdf.name}' is anisotropic; a bilateral fold assumes isotropy")
