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

__all__ = ["Param", "REQUIRED", "parse_params", "suggest"]


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


@dataclass(frozen=True)
class Param:
    """One declared parameter.

    kind: ``float`` (a real number), ``channel`` (number, list per channel or spectrum —
    :class:`~brdftab.channels.ChannelValue`), ``choice`` (one of ``choices``), ``bool``,
    ``brdf`` (a BRDF object) or ``brdfs`` (a non-empty list of BRDF objects).
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

    @property
    def required(self) -> bool:
        return self.default is REQUIRED

    @property
    def spec_key(self) -> str:
        """The key a spec file uses (``<name>_deg`` for angles)."""
        return f"{self.name}_deg" if self.angle else self.name

    def range_text(self) -> str:
        parts = []
        if self.minimum is not None:
            parts.append(f"{'>' if self.exclusive_minimum else '>='} {_fmt(self.minimum)}")
        if self.maximum is not None:
            parts.append(f"<= {_fmt(self.maximum)}")
        return " and ".join(parts)

    def expected(self) -> str:
        """What this parameter accepts, as a phrase."""
        rng = self.range_text()
        rng = f" {rng}" if rng else ""
        if self.kind == "float":
            return f"a number{rng}"
        if self.kind == "channel":
            return f"a number{rng}, a list of such numbers (one per channel) or a spectrum {{wavelengths_nm, values}}"
        if self.kind == "choice":
            return "one of " + ", ".join(repr(c) for c in self.choices)
        if self.kind == "bool":
            return "true or false"
        if self.kind == "brdf":
            return "a model"
        if self.kind == "brdfs":
            return "a non-empty list of models"
        return self.kind

    def _in_range(self, x: np.ndarray) -> bool:
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
        bad = ParameterError(self.name, f"expected {self.expected()}, got {_show(value)}")
        if self.kind == "float":
            if isinstance(value, bool) or not isinstance(value, (int, float, np.number)) or np.iscomplexobj(value):
                raise bad
            try:
                x = float(value)
            except OverflowError:
                raise bad from None
            if not self._in_range(np.array([x])):
                raise bad
            return x
        if self.kind == "channel":
            try:
                cv = ChannelValue.parse(value)
            except ValueError as exc:
                why = "" if isinstance(value, (bool, str)) else f" ({exc})"
                raise ParameterError(self.name, f"expected {self.expected()}, got {_show(value)}{why}") from None
            if not self._in_range(cv.values):
                raise bad
            return cv
        if self.kind == "choice":
            if not isinstance(value, str) or value not in self.choices:
                hint = suggest(value, self.choices)
                raise ParameterError(self.name, f"expected {self.expected()}, got {_show(value)}{hint}")
            return value
        if self.kind == "bool":
            if not isinstance(value, (bool, np.bool_)):
                raise bad
            return bool(value)
        if self.kind == "brdf":
            from .brdf import BRDF

            if not isinstance(value, BRDF):
                raise bad
            return value
        if self.kind == "brdfs":
            from .brdf import BRDF

            if not isinstance(value, (list, tuple)) or not value or not all(isinstance(v, BRDF) for v in value):
                raise bad
            return tuple(value)
        raise AssertionError(f"unknown parameter kind {self.kind}")


def parse_params(declared, given: dict, model: str) -> dict:
    """Validate keyword arguments against declarations; fill defaults.

    Unknown names and missing required parameters raise :class:`ParameterError` naming the
    parameter, the model and what is expected.
    """
    by_name = {p.name: p for p in declared}
    out = {}
    for key, value in given.items():
        if key not in by_name:
            raise ParameterError(
                key, f"unknown parameter for model '{model}'{suggest(key, by_name)}; valid: {', '.join(by_name)}"
            )
        out[key] = by_name[key].convert(value)
    for p in declared:
        if p.name not in out:
            if p.required:
                raise ParameterError(p.name, f"missing required parameter of model '{model}': expected {p.expected()}")
            out[p.name] = None if p.default is None else p.convert(p.default)
    return out


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
