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

from . import (bitterling, combinators, he_torrance, lambert, microfacet, pyramid,  # noqa: F401 (register)
               small2021, torrance_sparrow, zernike)
from ._registry import MODELS, register

__all__ = ["MODELS", "create", "register", "get"]


def get(name: str):
    """The model class called ``name`` (:class:`~brdftab.registry.UnknownName`, a
    :class:`~brdftab.errors.ParameterError`, when there is none)."""
    return MODELS.get(name)


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
