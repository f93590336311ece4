"""The model registry (:data:`MODELS`), apart from the package so each model module can
register itself with ``@register`` without importing the package that imports it."""

from __future__ import annotations

from ..registry import Registry

__all__ = ["MODELS", "register"]

#: Model classes by name.
MODELS = Registry("model")


def register(cls):
    """Add a model class to :data:`MODELS` under ``cls.name`` (a decorator)."""
    return MODELS.register(cls)
