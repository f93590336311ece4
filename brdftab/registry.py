"""One small registry for every kind of plug-in: models, components, grids, formats, checks.

A :class:`Registry` maps names to members. A member registers itself in its own module with the
registry's decorator (``@MODELS.register``); :meth:`Registry.names` lists the names and
:meth:`Registry.get` looks one up, raising :class:`UnknownName` with one wording for every kind::

    unknown model 'microfacte' (did you mean 'microfacet'?); valid: lambert, microfacet, ...

(after colour-science's ``validate_method``: one lookup and one message for every registry).
A registry is a ``dict``, so ``name in REG``, ``REG[name]`` and iteration work as before.

>>> from brdftab.registry import Registry
>>> shapes = Registry("shape")
>>> @shapes.register
... class Square:
...     name = "square"
>>> shapes.names()
['square']
>>> shapes.get("sqare")
Traceback (most recent call last):
...
brdftab.registry.UnknownName: shape: unknown shape 'sqare' (did you mean 'square'?); valid: square
"""

from __future__ import annotations

from .errors import ParameterError
from .params import unknown

__all__ = ["Registry", "UnknownName"]

_MISSING = object()


class UnknownName(ParameterError):
    """A name no member of a registry has (``key`` is the registry's kind)."""


class Registry(dict):
    """Members of one ``kind`` by name; each member's name is its attribute ``attr``."""

    def __init__(self, kind: str, attr: str = "name"):
        super().__init__()
        self.kind = kind
        self.attr = attr

    def register(self, member=None, *, name: str | None = None):
        """Add ``member`` under its name (or ``name``); usable as a decorator."""
        def add(m):
            key = name if name is not None else getattr(m, self.attr)
            self[key] = m
            return m
        return add if member is None else add(member)

    def names(self) -> list:
        """The registered names, in registration order."""
        return list(self)

    def message(self, name, valid=None) -> str:
        """``unknown <kind> 'x' (did you mean 'y'?); valid: …`` — the one wording
        (:func:`brdftab.params.unknown`, also that of every choice parameter); ``valid``: the
        names to offer, when not all of them (default: every registered name)."""
        return unknown(self.kind, name, self.names() if valid is None else valid)

    def get(self, name, default=_MISSING):
        """The member called ``name``; an unknown name raises :class:`UnknownName` (unless a
        ``default`` is given, as for ``dict.get``)."""
        if isinstance(name, str) and name in self:
            return self[name]
        if default is not _MISSING:
            return default
        raise UnknownName(self.kind, self.message(name))
