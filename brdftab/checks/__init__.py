"""Checks on any BRDF (model or table): registered parts run by one entry point.

A check is a small class (:class:`Check`) with a ``name``, a ``family`` (one module per
family in this package), declared ``thresholds`` (:class:`~brdftab.params.Param`, so specs,
the CLI and ``brdftab checks`` describe them the same way) and a default ``level``:

``off``
    not run;
``warn``
    a figure beyond its threshold is reported as WARN and does not fail the run;
``error``
    a figure beyond its threshold is FAIL: export is refused and ``brdftab validate`` exits 1.

:func:`run_checks` runs the configured checks on a BRDF. Configuration comes from defaults,
then the spec's ``[validation]`` table (``[validation.<check>] level = "warn"``, thresholds by
name), then the command line, each overriding the one before.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field

from ..errors import ParameterError
from ..params import Param, parse_params, suggest

__all__ = ["Check", "Outcome", "Report", "CHECKS", "LEVELS", "register", "run_checks", "configure"]

LEVELS = ("off", "warn", "error")
STATUSES = ("pass", "warn", "fail", "skip")


@dataclass
class Outcome:
    """What one check found: status, its figure against its threshold, a one-line detail."""

    name: str
    status: str
    figure: float | None = None
    threshold: float | None = None
    detail: str = ""
    level: str = "error"
    data: dict = field(default_factory=dict)

    @property
    def passed(self) -> bool:
        return self.status != "fail"

    def to_json(self) -> dict:
        return {"name": self.name, "status": self.status, "level": self.level, "figure": self.figure,
                "threshold": self.threshold, "detail": self.detail, "data": self.data}


@dataclass
class Report:
    """The outcomes of a run of checks."""

    outcomes: list = field(default_factory=list)

    @property
    def passed(self) -> bool:
        return all(o.passed for o in self.outcomes)

    @property
    def failures(self) -> list:
        return [o for o in self.outcomes if o.status == "fail"]

    @property
    def warnings(self) -> list:
        return [o for o in self.outcomes if o.status == "warn"]

    def get(self, name: str) -> Outcome | None:
        return next((o for o in self.outcomes if o.name == name), None)

    def summary(self) -> str:
        bad = self.failures
        if not bad:
            return "all checks passed"
        return "; ".join(f"{o.name}: {o.detail}" for o in bad)

    def to_json(self) -> dict:
        return {"passed": self.passed, "checks": [o.to_json() for o in self.outcomes]}


class Check:
    """Base class of a registered check. Subclasses set the class attributes and ``run``."""

    name: str = ""
    family: str = ""
    summary: str = ""
    level: str = "error"
    thresholds: tuple = ()

    def applies(self, brdf) -> str | None:
        """None when the check can run on ``brdf``, else the reason it is skipped."""
        return None

    def run(self, brdf, **thresholds) -> Outcome:
        """Measure ``brdf``; return an Outcome with status "pass" or "fail" (levels are applied
        by :func:`run_checks`)."""
        raise NotImplementedError


#: Registered checks by name, in the order they run.
CHECKS: dict = {}


def register(cls):
    """Register a :class:`Check` subclass (usable as a decorator)."""
    CHECKS[cls.name] = cls()
    return cls


def configure(*layers) -> dict:
    """Merge configuration layers ``{check: {"level": ..., threshold: ...}}`` (later wins) and
    validate every key against the registered checks; returns ``{check: {level, thresholds}}``."""
    out = {}
    for name, check in CHECKS.items():
        out[name] = {"level": check.level, **{p.name: p.default for p in check.thresholds}}
    for layer in layers:
        for name, cfg in (layer or {}).items():
            if name not in CHECKS:
                raise ParameterError(name, f"unknown check{suggest(name, CHECKS)}; valid: {', '.join(CHECKS)}")
            if not isinstance(cfg, dict):
                raise ParameterError(name, "expected a table of level and thresholds")
            check = CHECKS[name]
            for key, value in cfg.items():
                if key == "level":
                    if value not in LEVELS:
                        raise ParameterError(f"{name}.level", f"expected one of {', '.join(map(repr, LEVELS))}, got "
                                             f"{value!r}{suggest(value, LEVELS)}")
                    out[name]["level"] = value
                    continue
                try:
                    out[name].update(parse_params(check.thresholds, {key: value}, f"check {name}", fill=False))
                except ParameterError as exc:
                    raise ParameterError(f"{name}.{exc.key}", exc.detail) from None
    return out


def run_checks(brdf, config: dict | None = None, *, only=None) -> Report:
    """Run the configured checks on ``brdf`` (a model or a table).

    ``config`` is one layer as :func:`configure` takes it (or an already merged one);
    ``only`` restricts the run to the named checks.
    """
    merged = configure(config)
    report = Report()
    for name, check in CHECKS.items():
        if only is not None and name not in only:
            continue
        cfg = dict(merged[name])
        level = cfg.pop("level")
        if level == "off":
            continue
        why = check.applies(brdf)
        if why:
            report.outcomes.append(Outcome(name, "skip", detail=why, level=level))
            continue
        outcome = check.run(brdf, **cfg)
        outcome.level = level
        if outcome.status == "fail" and level == "warn":
            outcome.status = "warn"
        report.outcomes.append(outcome)
    return report


#: Check modules shipped with brdftab (each registers its checks on import).
BUILTIN = ("samples",)

for _name in BUILTIN:
    importlib.import_module(f"{__name__}.{_name}")
