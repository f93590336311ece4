"""Checks on any BRDF (model or table): registered parts run by one entry point.

A check is a small class (:class:`Check`) with a ``name``, a ``family`` (one module per
family in this package), declared ``thresholds`` (:class:`~brdftab.params.Param`, so specs,
the CLI and the reports describe them the same way) and a default ``level``:

``off``
    not run;
``warn``
    a figure beyond its threshold is reported as WARN and does not fail the run;
``error``
    a figure beyond its threshold is FAIL: export is refused and ``brdftab validate`` exits 1.

:func:`run_checks` runs the configured checks on a BRDF and returns a :class:`Report` (text,
JSON and JUnit XML forms). Configuration comes from defaults, then the spec's
``[validation]`` table (``[validation.<check>] level = "warn"``, thresholds by name; angles as
``<name>_deg``), then the command line, each overriding the one before (:func:`configure`).

Checks share what they compute — the albedo curve, the sampled direction pairs — through the
:class:`Context` they are given, so the energy and albedo checks integrate once.

Families (modules): ``samples`` (finite, non-negative, missing), ``reciprocity``, ``energy``
(energy, albedo), ``symmetry`` (isotropy, bilateral), ``conventions``, ``tabulation``, ``mueller``
(polarized BRDFs: realizability, bounds, polarized reciprocity, depolarization, M00 albedo).
"""

from __future__ import annotations

import importlib
import json
import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._version import __version__
from ..errors import BrdftabWarning, ParameterError, ValidationError
from ..params import parse_params, suggest
from ..registry import Registry

__all__ = ["Check", "ChecksFailed", "Context", "Outcome", "Report", "CHECKS", "LEVELS", "STATUSES", "SCHEMA_PATH",
           "SCHEMA_VERSION", "register", "run_checks", "configure", "guard", "stamp", "load_schema", "run_document",
           "junit_xml", "unstorable_report"]

LEVELS = ("off", "warn", "error")
STATUSES = ("pass", "warn", "fail", "skip")
#: Version of the report layout described by :data:`SCHEMA_PATH`.
SCHEMA_VERSION = 1
#: JSON Schema of ``brdftab validate --json`` output (``$defs/report``: one report).
SCHEMA_PATH = Path(__file__).with_name("report.schema.json")


def load_schema() -> dict:
    """The JSON Schema of validation reports (a dict)."""
    return json.loads(SCHEMA_PATH.read_text(encoding="utf-8"))


def _plain(x):
    """JSON-safe copy: numpy scalars/arrays to Python, non-finite floats to None."""
    if isinstance(x, dict):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    if isinstance(x, np.ndarray):
        return _plain(x.tolist())
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        x = float(x)
        return x if math.isfinite(x) else None
    if x is None or isinstance(x, str):
        return x
    return str(x)


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
    family: str = ""

    @property
    def passed(self) -> bool:
        return self.status != "fail"

    def to_json(self) -> dict:
        return {"name": self.name, "family": self.family, "status": self.status, "level": self.level,
                "figure": _plain(self.figure), "threshold": _plain(self.threshold), "detail": self.detail,
                "data": _plain(self.data)}


@dataclass
class Report:
    """The outcomes of a run of checks on one BRDF (``subject`` says which)."""

    outcomes: list = field(default_factory=list)
    subject: str = ""

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

    def counts(self) -> dict:
        return {s: sum(o.status == s for o in self.outcomes) for s in STATUSES}

    def summary(self) -> str:
        """The failed checks with their figures, or a count of what passed."""
        bad = self.failures
        if not bad:
            c = self.counts()
            return f"all checks passed ({c['pass']} pass, {c['warn']} warn, {c['skip']} skip)"
        return "; ".join(f"{o.name}: {o.detail}" for o in bad)

    def to_json(self) -> dict:
        """One report as ``$defs/report`` of :data:`SCHEMA_PATH` describes it."""
        return {"schema_version": SCHEMA_VERSION, "brdftab_version": __version__, "subject": self.subject,
                "passed": self.passed, "counts": self.counts(), "checks": [o.to_json() for o in self.outcomes]}

    def to_text(self) -> str:
        """One line per check: ``PASS  name  detail``; then a verdict line."""
        lines = [f"{self.subject}:" if self.subject else "validation:"]
        width = max([len(o.name) for o in self.outcomes] + [10])
        for o in self.outcomes:
            lines.append(f"  {o.status.upper():<4}  {o.name:<{width}}  {o.detail}")
        c = self.counts()
        verdict = "PASSED" if self.passed else "FAILED"
        lines.append(f"  {verdict}: {c['pass']} pass, {c['warn']} warn, {c['fail']} fail, {c['skip']} skip")
        return "\n".join(lines)

    def to_junit(self) -> str:
        """A JUnit XML document (one ``testsuite`` with a ``testcase`` per check)."""
        return junit_xml([self])


def run_document(reports, errors=()) -> dict:
    """The ``brdftab validate --json`` document: reports, unreadable inputs, overall verdict."""
    errs = [{"subject": s, "error": str(e)} for s, e in errors]
    return {"schema_version": SCHEMA_VERSION, "brdftab_version": __version__,
            "passed": all(r.passed for r in reports) and not errs,
            "reports": [r.to_json() for r in reports], "errors": errs}


def junit_xml(reports, errors=()) -> str:
    """JUnit XML for CI dashboards: ``testsuites/testsuite/testcase`` with ``failure`` for
    FAIL, ``skipped`` for SKIP, ``system-out`` carrying WARN details, and an ``error`` test
    case per unreadable input."""
    import xml.etree.ElementTree as ET

    root = ET.Element("testsuites", name="brdftab validate")
    totals = {"tests": 0, "failures": 0, "errors": 0, "skipped": 0}
    for r in reports:
        suite = ET.SubElement(root, "testsuite", name=r.subject or "brdf")
        n = {"tests": 0, "failures": 0, "errors": 0, "skipped": 0}
        for o in r.outcomes:
            n["tests"] += 1
            case = ET.SubElement(suite, "testcase", classname=f"brdftab.checks.{o.family or 'check'}", name=o.name)
            case.set("time", "0")
            if o.status == "fail":
                n["failures"] += 1
                el = ET.SubElement(case, "failure", message=o.detail, type=o.name)
                el.text = json.dumps(o.to_json(), indent=1)
            elif o.status == "skip":
                n["skipped"] += 1
                ET.SubElement(case, "skipped", message=o.detail)
            else:
                out = ET.SubElement(case, "system-out")
                out.text = f"{o.status.upper()}: {o.detail}"
        for k, v in n.items():
            suite.set(k, str(v))
            totals[k] += v
    for subject, err in errors:
        suite = ET.SubElement(root, "testsuite", name=str(subject), tests="1", failures="0", errors="1", skipped="0")
        case = ET.SubElement(suite, "testcase", classname="brdftab.input", name="read")
        ET.SubElement(case, "error", message=str(err), type="bad input")
        totals["tests"] += 1
        totals["errors"] += 1
    for k, v in totals.items():
        root.set(k, str(v))
    ET.indent(root)
    return ET.tostring(root, encoding="unicode", xml_declaration=True) + "\n"


class Context:
    """What a check is given: the BRDF, the wavelengths to evaluate it at, the model a table
    was made from (when known) and a cache shared by all checks of one run."""

    def __init__(self, brdf, wavelengths=None, reference=None, origin=None):
        self.brdf = brdf
        self.wavelengths = None if wavelengths is None else np.asarray(wavelengths, float)
        self.reference = reference
        self._origin = origin
        self.cache: dict = {}

    @property
    def origin(self) -> str:
        """Where the values come from: the user's word (``origin=``), else what the BRDF
        records (:attr:`brdftab.brdf.BRDF.origin`); a BRDF that records nothing is "unknown"."""
        return self._origin or getattr(self.brdf, "origin", "unknown")

    @property
    def measured(self) -> bool:
        """Measured-data defaults apply (origin "measured" or "unknown")."""
        return self.origin != "analytic"

    @property
    def is_table(self) -> bool:
        """The BRDF holds samples (``values``) on some ``grid`` (asked without reading them: a
        table's ``values`` property loads its samples)."""
        b = self.brdf
        has_values = hasattr(type(b), "values") or "values" in getattr(b, "__dict__", {})
        return has_values and hasattr(b, "grid")

    @property
    def on_grid(self) -> bool:
        """A table on one of brdftab's grids (node pairs, domains and node positions are known)."""
        from ..grids import Grid

        return self.is_table and isinstance(self.brdf.grid, Grid)

    def memo(self, key, compute):
        """``compute()`` once per ``key`` for this run."""
        if key not in self.cache:
            self.cache[key] = compute()
        return self.cache[key]

    def eval(self, brdf, wi, wo):
        return brdf.eval(wi, wo, self.wavelengths)

    def labels(self) -> list:
        """Names of the output channels (wavelengths as 'λ nm')."""
        b = self.brdf
        lam = self.wavelengths if self.wavelengths is not None else b.wavelengths
        if b.spectral or self.wavelengths is not None:
            return [f"{x:g} nm" for x in lam]
        return list(b.channels)


class Check:
    """Base class of a registered check. Subclasses set the class attributes and ``run``."""

    name: str = ""
    family: str = ""
    #: ``(lower, upper)`` threshold pairs: a layer that sets ``upper`` alone resets ``lower``
    #: set by a lower layer (e.g. expected values and the angles they belong to).
    replaces: tuple = ()
    summary: str = ""
    level: str = "error"
    thresholds: tuple = ()

    def applies(self, ctx: Context) -> str | None:
        """None when the check can run, else the reason it is skipped."""
        return None

    def check_config(self, cfg: dict) -> None:
        """Raise :class:`ParameterError` for thresholds that do not fit together."""

    def run(self, ctx: Context, **thresholds) -> Outcome:
        """Measure ``ctx.brdf``; return an Outcome with status "pass", "fail" or "skip" — or
        "warn" for a finding that must be reported but never blocks (levels are applied by
        :func:`run_checks`: "fail" becomes "warn" at level warn)."""
        raise NotImplementedError

    def outcome(self, passed: bool, figure=None, threshold=None, detail="", **data) -> Outcome:
        return Outcome(self.name, "pass" if passed else "fail", _plain(figure), _plain(threshold), detail,
                       data=data, family=self.family)

    def skip(self, why: str, **data) -> Outcome:
        return Outcome(self.name, "skip", detail=why, data=data, family=self.family)


#: Registered checks by name, in the order they run (instances).
CHECKS = Registry("check")


def register(cls):
    """Register a :class:`Check` subclass (usable as a decorator; the registry holds an instance)."""
    CHECKS.register(cls(), name=cls.name)
    return cls


def _convert(check, name, key, value):
    params = {p.name: p for p in check.thresholds}
    by_key = {p.spec_key: p for p in check.thresholds}
    p = by_key.get(key) or params.get(key)
    if p is None:
        valid = ["level", *by_key]
        raise ParameterError(f"{name}.{key}", f"unknown threshold of check '{name}'{suggest(key, valid)}; valid: "
                                              f"{', '.join(valid)}")
    if p.angle and key == p.spec_key:
        if isinstance(value, bool) or not isinstance(value, (int, float, list)):
            raise ParameterError(f"{name}.{key}", f"expected an angle in degrees, got {value!r}")
        try:
            value = (np.radians(np.asarray(value, float))).tolist()
        except (TypeError, ValueError, OverflowError):
            raise ParameterError(f"{name}.{key}", f"expected angles in degrees, got {value!r}") from None
    try:
        return p.name, parse_params(check.thresholds, {p.name: value}, f"check {name}", fill=False)[p.name]
    except ParameterError as exc:
        raise ParameterError(f"{name}.{key}", exc.detail) from None


def configure(*layers) -> dict:
    """Merge configuration layers ``{check: {"level": ..., threshold: ...}}`` (later wins) and
    validate every key against the registered checks; returns ``{check: {level, thresholds}}``.

    A layer may also be a list of layers (nested lists are flattened). Angle thresholds are given in radians under their
    name or in degrees under ``<name>_deg``.
    """
    flat = []

    def add(layer):
        if isinstance(layer, (list, tuple)):
            for sub in layer:
                add(sub)
        else:
            flat.append(layer)
    add(layers)
    out = {}
    for name, check in CHECKS.items():
        out[name] = {"level": check.level, **{p.name: p.default for p in check.thresholds}}
    for layer in flat:
        for name, cfg in (layer or {}).items():
            if name not in CHECKS:
                raise ParameterError(name, CHECKS.message(name))
            if not isinstance(cfg, dict):
                raise ParameterError(name, "expected a table of level and thresholds")
            check = CHECKS[name]
            given = {_convert(check, name, k, v)[0] for k, v in cfg.items() if k != "level"}
            for lower, upper in check.replaces:
                # a layer that sets `upper` without `lower` replaces the pair a lower layer set
                if upper in given and lower not in given:
                    out[name][lower] = next(p.default for p in check.thresholds if p.name == lower)
            for key, value in cfg.items():
                if key == "level":
                    if value not in LEVELS:
                        raise ParameterError(f"{name}.level", f"expected one of {', '.join(map(repr, LEVELS))}, got "
                                             f"{value!r}{suggest(value, LEVELS)}")
                    out[name]["level"] = value
                    continue
                pname, converted = _convert(check, name, key, value)
                out[name][pname] = converted
    for name, check in CHECKS.items():
        try:
            check.check_config(out[name])
        except ParameterError as exc:
            raise ParameterError(f"{name}.{exc.key}", exc.detail) from None
    return out


def run_checks(brdf, config=None, *, only=None, wavelengths=None, reference=None, subject: str = "",
               origin: str | None = None, progress: bool = False) -> Report:
    """Run the configured checks on ``brdf`` (a model or a table).

    ``config`` is one layer as :func:`configure` takes it, or a list of layers (later wins);
    ``only`` restricts the run to the named checks; ``wavelengths`` [nm] are those to evaluate
    a spectral BRDF at; ``reference`` is the model a table was tabulated from (else the model
    named in the table's provenance is used where available); ``subject`` names what is
    checked in the report; ``origin`` ("analytic", "measured", "unknown") overrides what the
    BRDF records about where its values come from (measured and unknown data get the
    measured-data defaults of the reciprocity and non-negative checks); ``progress`` shows a bar
    on stderr, one step per check, once the run has taken more than a second.

    >>> from brdftab import models
    >>> from brdftab.checks import run_checks
    >>> report = run_checks(models.create("lambert", albedo=0.5), only=("energy", "reciprocity"))
    >>> report.passed, [o.status for o in report.outcomes]
    (True, ['pass', 'pass'])
    >>> round(report.get("energy").figure, 6)          # the largest directional albedo
    0.5
    >>> bright = models.create("scale", factor=2.5, term=models.create("lambert", albedo=0.5))
    >>> run_checks(bright, only=("energy",)).summary()
    'energy: max a(θi) = 1.25 at θi = 0°, channel mono (accepted ≤ 1.01); ...'
    """
    merged = configure(config)
    if origin is not None:
        from ..brdf import ORIGINS

        if origin not in ORIGINS:
            raise ParameterError("origin", f"expected one of {', '.join(map(repr, ORIGINS))}, got {origin!r}")
    ctx = Context(brdf, wavelengths, reference, origin)
    report = Report(subject=subject or brdf.describe())
    todo = [n for n in CHECKS if (only is None or n in only) and merged[n]["level"] != "off"]
    bar = None
    if progress and todo:
        import sys

        from tqdm import tqdm

        bar = tqdm(total=len(todo), desc=f"checking {subject or brdf.name}"[:60], unit="check", delay=1.0,
                   file=sys.stderr, leave=False)
    for name, check in CHECKS.items():
        if name not in todo:
            continue
        cfg = dict(merged[name])
        level = cfg.pop("level")
        if bar is not None:
            bar.set_postfix_str(name, refresh=False)
        with warnings.catch_warnings():
            # quadrature and random pairs reach outside a table's domain on purpose: those
            # points evaluate to NaN and are left out (and counted) by the checks
            warnings.simplefilter("ignore", BrdftabWarning)
            why = check.applies(ctx)
            outcome = check.skip(why) if why else check.run(ctx, **cfg)
        outcome.level = level
        outcome.family = check.family
        if outcome.status == "fail" and level == "warn":
            outcome.status = "warn"
        report.outcomes.append(outcome)
        if bar is not None:
            bar.update(1)
    if bar is not None:
        bar.close()
    return report


class ChecksFailed(ValidationError):
    """A BRDF failed a check at level ``error`` before export (the CLI exits with code 1);
    ``report`` is the :class:`Report` that refused it."""

    exit_code = 1

    def __init__(self, message: str = "", report: Report | None = None):
        super().__init__(message)
        self.report = report


def stamp(table, report: Report) -> None:
    """Store a report in a table's metadata: the global attributes ``validation_passed`` (0 or
    1), ``validation_summary`` and ``validation_report`` (the JSON report) and, when the albedo
    was computed, the albedo curve as numbers other tools can plot: the variables
    ``albedo[albedo_theta_i, channel]`` (a(θi), mean over φi; θi in rad) and
    ``albedo_white_sky[channel]`` (see :func:`brdftab.table.set_albedo_curve`)."""
    from ..table import set_albedo_curve

    attrs = table.ds.attrs
    attrs["validation_passed"] = int(report.passed)
    attrs["validation_summary"] = report.summary()
    attrs["validation_report"] = json.dumps(report.to_json(), separators=(",", ":"))
    alb = report.get("albedo")
    if alb is not None and alb.data.get("theta_i_deg") is not None:
        set_albedo_curve(table.ds, alb.data["theta_i_deg"], alb.data["values"], alb.data.get("white_sky"),
                         alb.data.get("channels"))


def guard(source, config=None, *, allow_invalid: bool = False, what: str = "", **kwargs) -> Report:
    """Validate ``source`` before export: run the checks, stamp a table's metadata with the
    report, and raise :class:`ChecksFailed` (a :class:`~brdftab.errors.ValidationError`, exit
    code 1) naming the failed checks and their figures unless ``allow_invalid``. ``kwargs`` go to :func:`run_checks`."""
    report = run_checks(source, config, **kwargs)
    if hasattr(source, "ds"):
        stamp(source, report)
    if not report.passed and not allow_invalid:
        where = f" {what}" if what else ""
        raise ChecksFailed(f"refusing to export{where}: {report.summary()} (pass --allow-invalid to write anyway)",
                           report)
    return report


def unstorable_report(exc, config=None, *, allow_invalid: bool = False, what: str = "", subject: str = "") -> Report:
    """The report on an output whose stored values no reader accepts (``exc``, a
    :class:`~brdftab.formats.NotStorable`: values that overflow the storage type): the
    ``finite`` check fails with its count (at its configured level); the other checks are
    skipped, there being nothing to evaluate. Raises :class:`ChecksFailed` like :func:`guard`
    unless ``allow_invalid``."""
    merged = configure(config)
    report = Report(subject=subject)
    for name, check in CHECKS.items():
        level = merged[name]["level"]
        if level == "off":
            continue
        if name == "finite":
            out = check.outcome(False, exc.count, 0, exc.detail, stored=exc.total)
            if level == "warn":
                out.status = "warn"
        else:
            out = check.skip("the stored values cannot be read back (see the finite check)")
        out.level, out.family = level, check.family
        report.outcomes.append(out)
    if not report.passed and not allow_invalid:
        where = f" {what}" if what else ""
        raise ChecksFailed(f"refusing to export{where}: {report.summary()} (pass --allow-invalid to write anyway)",
                           report)
    return report


#: Check modules shipped with brdftab (each registers its checks on import).
BUILTIN = ("samples", "reciprocity", "energy", "symmetry", "conventions", "tabulation", "mueller")

for _name in BUILTIN:
    importlib.import_module(f"{__name__}.{_name}")
