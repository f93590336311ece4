"""Declared model parameters: type, units, default, range, documentation.

Every model lists its parameters as :class:`Param` objects. The same declaration validates
Python-API keyword arguments, validates spec-file keys (with file and key context added by the
spec loader), and is printed by ``brdftab models NAME``.

Angles are radians in code. A parameter declared with ``angle=True`` is written
``<name>_deg`` (degrees) in spec files and on the CLI.
"""

from __future__ import annotations

import difflib
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .channels import ChannelValue
from .errors import ParameterError

__all__ = ["Param", "Kind", "KINDS", "REQUIRED", "parse_params", "register_kind", "suggest", "unknown", "deg_list",
           "as_float"]


class _Required:
    def __repr__(self):
        return "REQUIRED"


#: Marks a parameter without a default.
REQUIRED = _Required()


def suggest(word: str, choices) -> str:
    """`` (did you mean 'x'?)`` for the nearest valid choice, or an empty string."""
    if not isinstance(word, str):
        return ""
    close = difflib.get_close_matches(word, [c for c in choices if isinstance(c, str)], n=1, cutoff=0.6)
    return f" (did you mean '{close[0]}'?)" if close else ""


def toml_value(v, finite: bool = False) -> str:
    """``v`` written as a TOML value that reads back the same: floats by their shortest exact
    text (``nan``, ``inf``, ``-inf`` as TOML spells them, or a ValueError with ``finite``),
    strings and table keys JSON-quoted (valid TOML basic strings), lists and dicts inline."""
    import json
    import math

    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        if not math.isfinite(v):
            if finite:
                raise ValueError(f"cannot write the non-finite value {v} to a spec")
            return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf")
        return repr(v)
    if isinstance(v, int):
        return str(v)
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(toml_value(x, finite) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{json.dumps(str(k))} = {toml_value(x, finite)}" for k, x in v.items()) + "}"
    return str(v)


def unknown(kind: str, name, valid) -> str:
    """The one wording for a name that is not among ``valid`` (registries, choices)::

        unknown distribution 'ggxx' (did you mean 'ggx'?); valid: beckmann, ggx, ...
    """
    valid = [str(v) for v in valid]
    return f"unknown {kind} {_show(name)}{suggest(name, valid)}; valid: {', '.join(valid) or 'none'}"


class Kind:
    """A kind of parameter value: how to check and convert it, and how to describe it.

    Kinds are registered by name (:func:`register_kind`) by the module that owns the values
    they accept — ``brdf``/``brdfs`` by :mod:`brdftab.brdf` — so this module imports nothing
    of brdftab's models. A new kind (a coefficient file, a spectrum file, a length in µm) is
    one subclass.
    """

    name: str = ""

    def expected(self, p: "Param") -> str:
        """What ``p`` accepts, as a phrase."""
        return self.name

    def convert(self, p: "Param", value):
        """Validate ``value`` for ``p``; return the internal form or raise ParameterError."""
        raise NotImplementedError

    def to_json(self, value):
        """A JSON-able form of a converted value (provenance, ``brdftab models --json``)."""
        return value.to_json() if hasattr(value, "to_json") else value


#: Parameter kinds by name.
KINDS: dict = {}


def register_kind(kind: Kind) -> Kind:
    KINDS[kind.name] = kind
    return kind


def _bad(p, value, why=""):
    if p.angle and isinstance(value, (int, float, np.number)) and not isinstance(value, bool):
        x = as_float(value)
        if x is not None:
            value = float(np.degrees(x))  # angles reach Params in radians; users wrote degrees
    return ParameterError(p.name, f"expected {p.expected()}, got {_show(value)}{why}")


def deg_list(name, value, lo, hi):
    """An option's angles in degrees (a number or a list), strictly increasing within
    [``lo``, ``hi``], as a float array (None when not given); else a ParameterError naming
    ``name``."""
    if value is None:
        return None
    vals = np.asarray(value if isinstance(value, (list, tuple, np.ndarray)) else [value], float)
    if vals.size == 0 or not np.all(np.isfinite(vals)) or vals.min() < lo or vals.max() > hi:
        raise ParameterError(name, f"expected angles in [{lo:g}, {hi:g}] degrees, got {value!r}")
    if np.any(np.diff(vals) <= 0):
        raise ParameterError(name, "angles must increase strictly")
    return vals


def as_float(value) -> float | None:
    """``value`` as a float, or None when it has none (an integer of hundreds of digits, as a
    spec may hold, overflows float: it is out of every range, not an internal error)."""
    try:
        return float(value)
    except (OverflowError, TypeError, ValueError):
        return None


def _too_large(value) -> str:
    return " (too large)" if isinstance(value, (int, np.integer)) and as_float(value) is None else ""


class FloatKind(Kind):
    name = "float"

    def expected(self, p):
        rng = p.range_text()
        return f"a number{' ' + rng if rng else ''}"

    def convert(self, p, value):
        if isinstance(value, bool) or not isinstance(value, (int, float, np.number)) or np.iscomplexobj(value):
            raise _bad(p, value)
        x = as_float(value)
        if x is None or not p.in_range(np.array([x])):
            raise _bad(p, value, _too_large(value))
        return x


class IntKind(Kind):
    name = "int"

    def expected(self, p):
        rng = p.range_text()
        return f"a whole number{' ' + rng if rng else ''}"

    def convert(self, p, value):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
            raise _bad(p, value)
        x = as_float(value)
        if x is None or not p.in_range(np.array([x])):
            raise _bad(p, value, _too_large(value))
        return int(value)


class ChannelKind(Kind):
    name = "channel"

    def expected(self, p):
        rng = p.range_text()
        rng = f" {rng}" if rng else ""
        return f"a number{rng}, a list of such numbers (one per channel) or a spectrum {{wavelengths_nm, values}}"

    def convert(self, p, value):
        try:
            cv = ChannelValue.parse(value)
        except ValueError as exc:
            raise _bad(p, value, "" if isinstance(value, (bool, str)) else f" ({exc})") from None
        if not p.in_range(cv.values):
            raise _bad(p, value)
        return cv


class ChoiceKind(Kind):
    name = "choice"

    def expected(self, p):
        return "one of " + ", ".join(repr(c) for c in p.choices)

    def convert(self, p, value):
        if not isinstance(value, str) or value not in p.choices:
            raise ParameterError(p.name, unknown(p.name, value, p.choices))
        return value


class BoolKind(Kind):
    name = "bool"

    def expected(self, p):
        return "true or false"

    def convert(self, p, value):
        if not isinstance(value, (bool, np.bool_)):
            raise _bad(p, value)
        return bool(value)


class FloatsKind(Kind):
    """A number or a non-empty list of finite numbers (stored as a tuple)."""

    name = "floats"

    def expected(self, p):
        rng = p.range_text()
        return f"a number or a list of numbers{' ' + rng if rng else ''}"

    def convert(self, p, value):
        vals = value if isinstance(value, (list, tuple)) else [value]
        if not vals or any(isinstance(v, bool) or not isinstance(v, (int, float, np.number)) for v in vals):
            raise ParameterError(p.name, f"expected {self.expected(p)}, got {_show(value)}")
        floats = [as_float(v) for v in vals]
        arr = np.asarray([np.nan if v is None else v for v in floats], float)
        if not np.all(np.isfinite(arr)) or not p.in_range(arr):
            rng = p.range_text()
            raise ParameterError(p.name, f"expected finite numbers{' ' + rng if rng else ''}, got {_show(value)}")
        return tuple(float(v) for v in arr)

    def to_json(self, value):
        return list(value)


class TextKind(Kind):
    """A string."""

    name = "text"

    def expected(self, p):
        return "a string"

    def convert(self, p, value):
        if not isinstance(value, str):
            raise _bad(p, value)
        return value


for _k in (FloatKind(), IntKind(), ChannelKind(), ChoiceKind(), BoolKind(), FloatsKind(), TextKind()):
    register_kind(_k)


@dataclass(frozen=True)
class Param:
    """One declared parameter.

    ``kind`` names a registered :class:`Kind`: ``float``, ``int``, ``channel`` (number, list
    per channel or spectrum — :class:`~brdftab.channels.ChannelValue`), ``choice`` (one of
    ``choices``), ``bool``; ``brdf`` and ``brdfs`` (registered by :mod:`brdftab.brdf`); and
    the component kinds of :mod:`brdftab.models.components`.
    """

    name: str
    kind: str
    doc: str
    units: str = "1"
    default: Any = REQUIRED
    minimum: float | None = None
    maximum: float | None = None
    exclusive_minimum: bool = False
    choices: tuple = ()
    angle: bool = False
    used_when: str = ""
    #: ``((param, (values…)), …)``: the parameter is used only when each named choice
    #: parameter has one of the values (e.g. ``n`` only with ``fresnel = 'conductor'``).
    requires: tuple = ()

    @property
    def required(self) -> bool:
        return self.default is REQUIRED

    @property
    def spec_key(self) -> str:
        """The key a spec file uses (``<name>_deg`` for angles)."""
        return f"{self.name}_deg" if self.angle else self.name

    @property
    def kind_object(self) -> Kind:
        try:
            return KINDS[self.kind]
        except KeyError:
            raise AssertionError(f"unknown parameter kind {self.kind!r}") from None

    def range_text(self) -> str:
        """The accepted range, in the units a user writes (degrees for angles)."""
        conv = (lambda x: float(np.degrees(x))) if self.angle else (lambda x: x)  # noqa: E731
        unit = " deg" if self.angle else ""
        parts = []
        if self.minimum is not None:
            parts.append(f"{'>' if self.exclusive_minimum else '>='} {_fmt(conv(self.minimum))}{unit}")
        if self.maximum is not None:
            parts.append(f"<= {_fmt(conv(self.maximum))}{unit}")
        return " and ".join(parts)

    def expected(self) -> str:
        """What this parameter accepts, as a phrase."""
        return self.kind_object.expected(self)

    def in_range(self, x: np.ndarray) -> bool:
        if not np.all(np.isfinite(x)):
            return False
        if self.minimum is not None:
            if self.exclusive_minimum and np.any(x <= self.minimum):
                return False
            if not self.exclusive_minimum and np.any(x < self.minimum):
                return False
        if self.maximum is not None and np.any(x > self.maximum):
            return False
        return True

    def convert(self, value):
        """Validate ``value`` and return the internal form; raises :class:`ParameterError`."""
        return self.kind_object.convert(self, value)

    def to_json(self, value):
        return None if value is None else self.kind_object.to_json(value)


def parse_params(declared, given: dict, model: str, fill: bool = True, noun: str = "parameter") -> dict:
    """Validate keyword arguments against declarations; fill defaults (unless ``fill`` is false).

    Unknown names and missing required parameters raise :class:`ParameterError` naming the
    parameter, the model and what is expected.
    """
    by_name = {p.name: p for p in declared}
    out = {}
    for key, value in given.items():
        if key not in by_name:
            raise ParameterError(
                key, f"unknown {noun} for {_owner(model)}{suggest(key, by_name)}; valid: {', '.join(by_name) or 'none'}"
            )
        out[key] = by_name[key].convert(value)
    if not fill:
        return out
    for p in declared:
        if p.name not in out:
            if p.required:
                raise ParameterError(p.name, f"missing required parameter of {_owner(model)}: expected {p.expected()}")
            out[p.name] = None if p.default is None else p.convert(p.default)
    return out


def _owner(model: str) -> str:
    return model if " " in model else f"model '{model}'"


def _fmt(x) -> str:
    return f"{x:g}" if isinstance(x, float) and math.isfinite(x) else str(x)


def _show(value) -> str:
    if isinstance(value, str):
        return repr(value)
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return f"{value:g}"
    text = repr(value)
    return text if len(text) < 60 else text[:57] + "..."
