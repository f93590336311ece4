"""Analytic BRDF models and their registry.

``MODELS`` maps a model name to its class; :func:`create` builds one from keyword
parameters (angles in radians), validating every value against the model's declared
:class:`~brdftab.params.Param` list. One module per model family; shared physics lives once
and is imported: the microfacet components D, G, F in :mod:`~brdftab.models.components`
(over the plain functions of :mod:`~brdftab.models.distributions` and
:mod:`~brdftab.models.fresnel`), the Rayleigh–Rice factor in
:mod:`~brdftab.models.rayleigh_rice`, the combinators in :mod:`~brdftab.models.combinators`.
"""

from __future__ import annotations

from ..errors import BrdftabError
from ..params import suggest
from .bitterling import CookTorranceAlphaTheta
from .combinators import Average, Rotated, Scale, Sum
from .he_torrance import HeTorrance1991, ModifiedHeTorrance
from .lambert import Lambert
from .microfacet import Microfacet
from .pyramid import PyramidMicrofacet
from .small2021 import Small2021Diffraction, Small2021Peak, SolarCellSmall2021
from .torrance_sparrow import TorranceSparrow1967
from .zernike import ZernikeExpansion

__all__ = ["MODELS", "create", "register", "get"]

#: Model classes by name.
MODELS: dict = {}


def register(cls):
    """Add a model class to :data:`MODELS` under ``cls.name`` (usable as a decorator)."""
    MODELS[cls.name] = cls
    return cls


for _cls in (Lambert, Microfacet, Sum, Scale, Average, Rotated, TorranceSparrow1967, Small2021Peak,
             Small2021Diffraction, SolarCellSmall2021, ZernikeExpansion, CookTorranceAlphaTheta, HeTorrance1991,
             ModifiedHeTorrance, PyramidMicrofacet):
    register(_cls)


def get(name: str):
    """The model class called ``name``; an unknown name lists the valid ones."""
    if not isinstance(name, str) or name not in MODELS:
        hint = suggest(name, MODELS) if isinstance(name, str) else ""
        raise BrdftabError(f"unknown model {name!r}{hint}; valid models: {', '.join(sorted(MODELS))}")
    return MODELS[name]


def create(name: str, **params):
    """Build model ``name`` from keyword parameters (angles in radians), each checked against
    the model's declared parameters.

    >>> from brdftab import models
    >>> ggx = models.create("microfacet", distribution="ggx", alpha=0.3, fresnel="conductor", n=0.2, k=3.0)
    >>> ggx.eval([0, 0, 1], [0, 0, 1]).round(3)    # D(n) F(0) / 4 = F(0) / (4π α²) [1/sr]
    array([0.816])
    >>> models.create("microfacet", alpah=0.3)
    Traceback (most recent call last):
    ...
    brdftab.errors.ParameterError: alpah: unknown parameter for model 'microfacet' (did you mean 'alpha'?); valid: ...
    """
    return get(name)(**params)
