"""Fit a model's parameters to a table: from measured (or tabulated) data to a spec.

``brdftab.fit(table, model, free=["alpha", "n"])`` adjusts the named parameters of ``model``
so that it reproduces ``table`` at the table's own nodes (no interpolation), and returns a
:class:`FitResult`: the fitted model, its parameters with uncertainties and correlations,
the residual figures, and a spec (``[model]`` the fitted model, ``[grid]`` the table's grid)
whose tabulation reproduces the table. ``brdftab fit`` is the same on the command line.

Keys
    Parameters are named by their spec keys (``alpha``, ``p3_deg``: angles in degrees, as in a
    spec file); the terms of a ``sum`` are numbered from 0, as in a ``[sweep]``:
    ``terms.1.alpha`` (or ``terms[1].alpha``). A key whose value is a list (one number per
    channel) frees every element (``terms.0.albedo[0]``, ...).

Tables
    A table on a brdftab grid (its nodes), or an RGL ``.bsdf`` file (its stored sample nodes,
    where the reader is exact; its fitted spec gets the MERL grid, or an unfolded
    Rusinkiewicz grid of the same resolution for a non-reciprocal or anisotropic fit).

Samples
    Every node of the table where both directions are above the horizon, θi and θo are at
    most ``max_theta_deg`` (default 80°: near grazing, measurements are least reliable and
    f·cos is small while f itself can be large) and the value is finite and not declared
    missing. Measured tables keep their own noise (negative values included: the log metric
    floors them).

Metrics
    ``log`` (default): r = ln max(f, floor) − ln max(t, floor), floor = 10⁻³ × the median of
    the positive samples; every order of magnitude weighs alike, as in the papers'
    log-scale comparisons of measured and fitted curves, so a specular peak does not drown
    the diffuse and grazing parts (and a relative noise is uniform noise). ``cos``:
    r = (f − t) cosθi cosθo, the error in reflected radiance (what energy and rendering
    judge); it is dominated by the brightest samples. ``residual`` is the rms of r over the
    samples, comparable between fits of the same table with the same metric.

Search
    :func:`scipy.optimize.least_squares` (trust-region reflective) with the ``soft_l1`` loss
    (scale ``f_scale``: 0.1 for ``log``, the median |r| at the start for ``cos``), which keeps
    outliers from pulling the fit: on a measured-like file with 200 negative noise samples
    (floored by the log metric, so residuals of several units) the Lambert albedo comes out
    within 1.1 % of the model's, against 9 to 13 % low with the plain (``linear``) loss (a
    test holds them within 3 % and beyond 10 %). Within bounds: each parameter's declared range (an exclusive minimum
    nudged up by 10⁻⁹ relative), a range open at one end is closed at the start value ± 10 ×
    max(|start|, 1) (documented practical bounds; give ``bounds`` to choose others). These
    problems are not convex: by default ``starts`` = 16 starts — the start value and points of
    a Latin hypercube (seeded) spread over the bounds — each run on a random subset
    of at most ``search_samples`` (20 000) nodes and at most ``SEARCH_STEPS`` (50) steps; the
    best is refined (to tolerance 10⁻⁸, without a step cap) on at most
    ``refine_samples`` (200 000) nodes, on which the figures are computed. With an ``engine``
    (:class:`brdftab.batch.Engine` on dask.distributed) the starts run in parallel.

Uncertainties
    From the Jacobian J of the residuals at the solution: covariance s² (JᵀJ)⁻¹ with
    s² = Σ r² / (m − p) (m residuals, p free parameters); one standard deviation per
    parameter, and the correlation matrix. They describe the fit's statistics (noise that
    is independent between samples), not a model's systematic mismatch.
"""

from __future__ import annotations

import json
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import BrdftabError
from .params import suggest, toml_value

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

__all__ = ["fit", "FitResult", "model_table", "grid_table", "METRICS", "MAX_THETA_DEG", "MAX_STARTS"]

METRICS = ("log", "cos")
#: The losses of :func:`scipy.optimize.least_squares`; ``soft_l1`` is the default (see Search).
LOSSES = ("soft_l1", "linear", "huber", "cauchy", "arctan")
#: Default cut-off of the samples: θi and θo at most this many degrees.
MAX_THETA_DEG = 80.0
#: The log metric's floor relative to the median of the positive samples.
LOG_FLOOR = 1e-3
DEFAULT_STARTS = 16
#: The most starts a fit takes: each is a search of its own, and their points are drawn at
#: once (10^8 starts ran out of memory at 7 GB; 3 million ran for minutes).
MAX_STARTS = 10_000
SEARCH_SAMPLES = 20_000
REFINE_SAMPLES = 200_000
#: Tolerance (ftol, xtol, gtol) of the search from each start; the refine uses 1e-8.
SEARCH_TOL = 1e-5
#: Most model evaluations (Jacobians apart) a search from one start may take: a start that
#: converges does so in a few tens; one that wanders is cut short (the refine has no such cap).
SEARCH_STEPS = 50
#: An open end of a range is closed at start ± OPEN_SPAN × max(|start|, 1).
OPEN_SPAN = 10.0
_BIN_DEG = 10.0


# --- models as spec tables ----------------------------------------------------------------
def model_table(model) -> dict:
    """The ``[model]`` table of a spec that builds ``model`` (angles in degrees under ``_deg``
    keys, the terms of a combinator as nested tables)."""
    from . import models

    cls = models.MODELS.get(model.name)
    declared = {p.name: p for p in cls.params}
    out = {"name": model.name}
    for key, value in model.parameters.items():
        p = declared[key]
        if p.kind == "brdf":
            out[p.spec_key] = model_table(model._values[p.name])
        elif p.kind == "brdfs":
            out[p.spec_key] = [model_table(m) for m in model._values[p.name]]
        elif p.angle and isinstance(value, (int, float)) and not isinstance(value, bool):
            out[p.spec_key] = math.degrees(value)
        else:
            out[p.spec_key] = value
    return out


def _params_of(table: dict) -> dict:
    from . import models

    return {p.spec_key: p for p in models.MODELS.get(table["name"]).params}


def _numeric(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def free_keys(table: dict, prefix: str = "") -> list:
    """The keys of ``table`` (a ``[model]`` table) that hold numbers: what ``free`` may name."""
    out = []
    params = _params_of(table)
    for key, value in table.items():
        if key == "name":
            continue
        p = params.get(key)
        if p is not None and p.kind == "brdfs":
            for i, sub in enumerate(value):
                out += free_keys(sub, f"{prefix}{key}.{i}.")
        elif p is not None and p.kind == "brdf":
            out += free_keys(value, f"{prefix}{key}.")
        elif _numeric(value) or (isinstance(value, list) and value and all(map(_numeric, value))):
            out.append(prefix + key)
    out += [prefix + k for k, p in params.items() if k not in table and p.kind in _REAL_KINDS]
    return out


_REAL_KINDS = ("float", "channel", "floats")


def _add_declared(table: dict, key: str) -> bool:
    """Put a start value for ``key`` into ``table`` when the model declares it but the table
    does not hold it: its default, else the centre of its declared range. False when ``key``
    names no declared real parameter, or it has no start (an open range and no default)."""
    from .params import REQUIRED

    owner = _owner(table, key)
    if owner is None:
        return False
    node, name = owner
    p = _params_of(node)[name]
    parts = [name]
    if p.kind not in _REAL_KINDS:
        raise BrdftabError(f"--free: '{key}' is not a number (a {p.kind} parameter: {p.expected()}); only "
                           "real-valued parameters can be fitted")
    if _numeric(p.default) and p.default is not REQUIRED:
        node[parts[-1]] = math.degrees(p.default) if p.angle else p.default
        return True
    lower, upper = _declared_bounds(p, 0.0)
    if p.minimum is None or p.maximum is None:
        raise BrdftabError(f"--free: {key} has no start value (no default and an open range): give one with "
                           f"--param {key}=VALUE")
    node[parts[-1]] = 0.5 * (lower + upper)
    return True


def _walk(table: dict, key: str):
    """``(container, index, Param, value)`` of ``key`` in a ``[model]`` table; None when it
    names nothing."""
    from .sweep import parse_key

    parts = parse_key(key)
    node, param = table, None
    for i, part in enumerate(parts):
        last = i == len(parts) - 1
        if isinstance(node, dict) and isinstance(part, str) and "name" in node:
            param = _params_of(node).get(part)
            if param is None or part not in node:
                return None
        elif isinstance(node, list) and isinstance(part, int) and part < len(node):
            pass
        else:
            return None
        if last:
            return node, part, param, node[part]
        node = node[part]
    return None


def _set(table: dict, key: str, value) -> None:
    from .sweep import parse_key

    parts = parse_key(key)
    node = table
    for part in parts[:-1]:
        node = node[part]
    node[parts[-1]] = value


def _parse_value(text: str):
    """A ``--param`` value as TOML reads it (a number, a list, a string in quotes); bare text
    is a string."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


# --- grids as spec tables ----------------------------------------------------------------
def grid_table(grid) -> dict:
    """The ``[grid]`` table of a spec whose grid has ``grid``'s nodes: the same node for node
    (the same bits when its angles were written in degrees, else to 10⁻¹² rad). Raises
    :class:`~brdftab.errors.BrdftabError` when no ``[grid]`` table gives them."""
    from .grids import GRIDS, grid_from_config

    attrs = grid.attrs() if hasattr(grid, "attrs") else {}
    candidates = []
    if attrs.get("grid") == "merl":
        candidates.append({"type": "merl", "sample_position": attrs.get("sample_position")})
    types = [t for t, cls in GRIDS.items() if attrs.get("parameterization") in cls.parameterizations]
    types = ([attrs["grid"]] if attrs.get("grid") in types else []) + types
    for name in dict.fromkeys(types):
        declared = {p.name: p for p in GRIDS[name].params}
        base = {"type": name}
        for key, p in declared.items():  # the choices the grid records (folds, spacing, node positions)
            value = attrs.get(key, getattr(grid, key, None))
            if p.kind == "choice" and value in p.choices and value != p.default:
                base[p.spec_key] = value
            elif p.kind == "bool" and isinstance(value, (bool, np.bool_)) and bool(value) != p.default:
                base[p.spec_key] = bool(value)
            elif p.kind == "int" and isinstance(value, (int, np.integer)) and not isinstance(value, bool) \
                    and value != p.default:
                base[p.spec_key] = int(value)
        if not any(a.name in declared or f"n_{a.name}" in declared for a in grid.axes):
            candidates.append(dict(base))  # a grid its choices alone determine (Klems basis, tree rank and level)
        counts = {f"n_{a.name}": len(a) for a in grid.axes if f"n_{a.name}" in declared}
        if len(counts) == len(grid.axes):
            candidates.append(dict(base, **counts))
        lists = {declared[a.name].spec_key: [round(math.degrees(x), 12) for x in a.values] for a in grid.axes
                 if a.name in declared}
        if len(lists) == len(grid.axes):
            mixed = {}  # uniform axes by count, explicit ones by list
            for a, (key, values) in zip(grid.axes, lists.items()):
                explicit = getattr(a, "rule", "explicit") == "explicit" or f"n_{a.name}" not in declared
                mixed.update({key: values} if explicit else {f"n_{a.name}": len(a)})
            candidates.append(dict(base, **mixed))
            candidates.append(dict(base, **lists))
            spacing = {k: v for k, v in base.items() if k != "theta_h_spacing"}  # not with explicit lists
            candidates.append(dict(spacing, **lists))
    close = None
    for cfg in candidates:
        try:
            g = grid_from_config(cfg)
        except BrdftabError:
            continue
        if g.shape != grid.shape or [a.name for a in g.axes] != [a.name for a in grid.axes]:
            continue
        if g.equals(grid) or all(a.equals(b) for a, b in zip(g.axes, grid.axes)):
            return cfg
        if close is None and all(np.allclose(a.values, b.values, rtol=0, atol=1e-12)
                                 for a, b in zip(g.axes, grid.axes)):
            close = cfg
    if close is not None:
        return close
    raise BrdftabError(f"the table's grid ({grid.describe()}) has no [grid] form that reproduces its nodes: "
                       "a fitted spec cannot be written for it")


# --- the samples ---------------------------------------------------------------------------
@dataclass
class _Samples:
    wi: np.ndarray
    wo: np.ndarray
    target: np.ndarray  # [m, C], NaN where not used
    cos: np.ndarray      # cosθi cosθo [m]
    theta_i: np.ndarray  # [m] rad


class _Nodes:
    """The stored samples of a table as flat nodes: a brdftab grid's nodes, or an RGL file's
    warped sample nodes (where its reader is exact)."""

    def __init__(self, table):
        self.table = table
        grid = table.grid
        self.values = table.values.reshape(-1, table.values.shape[-1])
        miss = getattr(table, "missing", None)
        self.missing = None if miss is None else miss.reshape(self.values.shape)
        if hasattr(grid, "directions_into"):
            self.grid, self._wi, self._wo = grid, None, None
        elif hasattr(table, "_vndf"):  # an RGL .bsdf: the nodes its reader returns exactly
            from .formats.rgl import node_geometry

            wi, wo, *_ = node_geometry(table._vndf, table.theta_i.astype(np.float64),
                                       table.phi_i.astype(np.float64), table.resolution, table.isotropic)
            self.grid, self._wi, self._wo = None, np.ascontiguousarray(wi), np.ascontiguousarray(wo)
        else:
            raise BrdftabError(f"cannot fit a table whose samples are laid out as {grid.describe()}")
        self.size = self.values.shape[0]

    def directions(self, idx):
        if self.grid is None:
            return self._wi[idx], self._wo[idx]
        wi, wo = self.grid._directions(np.unravel_index(idx, self.grid.shape))
        return np.ascontiguousarray(wi, float), np.ascontiguousarray(wo, float)

    def valid(self, max_theta_deg: float) -> np.ndarray:
        """Flat indices of the usable nodes: both directions above the horizon and within the
        cut-off, a finite value not declared missing in at least one channel."""
        from .brdf import HORIZON

        c_min = math.cos(math.radians(max_theta_deg))
        keep = np.zeros(self.size, bool)
        step = 1 << 18
        for s in range(0, self.size, step):
            e = min(s + step, self.size)
            if self.grid is not None:
                wi, wo = np.empty((e - s, 3)), np.empty((e - s, 3))
                self.grid.directions_into(s, e, wi, wo)
            else:
                wi, wo = self._wi[s:e], self._wo[s:e]
            keep[s:e] = (wi[:, 2] >= c_min) & (wo[:, 2] >= c_min) & (wi[:, 2] > HORIZON) & (wo[:, 2] > HORIZON)
        finite = np.isfinite(self.values)
        if self.missing is not None:
            finite &= ~self.missing
        keep &= finite.any(axis=1)
        return np.flatnonzero(keep)

    def samples(self, idx) -> _Samples:
        wi, wo = self.directions(idx)
        target = np.array(self.values[idx], float)
        if self.missing is not None:
            target[self.missing[idx]] = np.nan
        target[~np.isfinite(target)] = np.nan
        return _Samples(wi, wo, target, wi[:, 2] * wo[:, 2], np.arccos(np.clip(wi[:, 2], -1.0, 1.0)))

    def grid_table(self, model) -> dict:
        """The ``[grid]`` of the fitted spec: the table's own, or for a file without a brdftab
        grid (RGL) the MERL grid when the fit is isotropic and reciprocal, else a Rusinkiewicz
        grid of the same resolution that does not fold φd (anisotropic when the fit is)."""
        if self.grid is not None:
            return grid_table(self.grid)
        if model.isotropic and model.reciprocal:
            return {"type": "merl"}
        cfg = {"type": "rusinkiewicz", "theta_h_spacing": "merl", "phi_d_fold": "none", "n_theta_h": 90,
               "n_theta_d": 90, "n_phi_d": 360}
        if not model.isotropic:
            cfg.update(anisotropic=True, n_phi_h=360)
        return cfg


# --- the result ----------------------------------------------------------------------------
@dataclass
class FitResult:
    """What :func:`fit` found. ``parameters``, ``uncertainties`` (one standard deviation) by
    free key in spec units; ``correlations[i][j]`` between ``free[i]`` and ``free[j]``;
    ``residual`` the rms of the metric over the refine samples; ``residual_by_theta_i`` the
    same per 10° bin of θi (``[θ lo, θ hi, rms, samples]``); ``albedo`` of table and fit at a
    few θi."""

    model: object
    model_table: dict
    grid_table: dict
    free: list
    parameters: dict
    uncertainties: dict
    correlations: list
    metric: str
    residual: float
    residual_by_theta_i: list
    samples: int
    starts: int
    start_results: list = field(default_factory=list)
    albedo: dict = field(default_factory=dict)
    bounds: dict = field(default_factory=dict)
    #: Why there is no ``grid_table`` (a table whose grid no ``[grid]`` table reproduces).
    grid_error: str = ""

    def to_json(self) -> dict:
        return {"model": self.model_table, "grid": self.grid_table, "free": list(self.free),
                "parameters": self.parameters, "uncertainties": self.uncertainties,
                "correlations": self.correlations, "metric": self.metric,
                "residual": self.residual, "residual_by_theta_i": self.residual_by_theta_i,
                "samples": self.samples, "starts": self.starts, "start_residuals": self.start_results,
                "bounds": {k: list(v) for k, v in self.bounds.items()}, "albedo": self.albedo}

    def spec_text(self, output: str, description: str = "") -> str:
        """A spec file (TOML) of the fitted model on the table's grid writing ``output``."""
        if self.grid_table is None:
            raise BrdftabError(self.grid_error)
        lines = []
        if description:
            lines.append(f"description = {json.dumps(description, ensure_ascii=False)}")
            lines.append("")
        _toml_table(lines, "model", self.model_table, model=True)
        lines.append("")
        _toml_table(lines, "grid", self.grid_table)
        lines += ["", "[[output]]", f"path = {json.dumps(output, ensure_ascii=False)}", ""]
        return "\n".join(lines)


def _toml_scalar(v) -> str:
    try:
        return toml_value(v, finite=True)
    except ValueError as exc:
        raise BrdftabError(str(exc)) from None


def _toml_table(lines, header, table, array=False, model=False) -> None:
    """``table`` as a TOML table ``[header]``; in a model's table the values of kind ``brdf``
    and ``brdfs`` (its terms) become sub-tables, everything else an inline value."""
    lines.append(f"[[{header}]]" if array else f"[{header}]")
    kinds = {k: p.kind for k, p in _params_of(table).items()} if model else {}
    subs = []
    for k, v in table.items():
        if kinds.get(k) in ("brdf", "brdfs"):
            subs.append((k, v))
        else:
            lines.append(f"{k} = {_toml_scalar(v)}")
    for k, v in subs:
        for item in (v if isinstance(v, list) else [v]):
            _toml_table(lines, f"{header}.{k}", item, array=isinstance(v, list), model=True)


# --- the fit ---------------------------------------------------------------------------------
def _start_model(model, params, where):
    """``(model table, folder for file parameters)`` of ``model``: a BRDF, a model name, a
    ``[model]`` table (dict) or a TOML file with a ``[model]`` table."""
    from . import models
    from .brdf import BRDF
    from .spec import read_spec

    folder = Path.cwd()
    if isinstance(model, BRDF):
        table = model_table(model)
    elif isinstance(model, dict):
        table = json.loads(json.dumps(model))
    elif isinstance(model, Path) or (isinstance(model, str) and model.lower().endswith(".toml")):
        raw, _ = read_spec(Path(model))
        if not isinstance(raw.get("model"), dict):
            raise BrdftabError(f"{model}: no [model] table")
        table, folder = raw["model"], Path(model).parent
    elif isinstance(model, str):
        table = {"name": model}
        models.get(model)  # an unknown name: the registry's one wording
    else:
        raise BrdftabError(f"expected a model, a model name or a spec file, got {type(model).__name__}")
    for key, value in (params or {}).items():
        if _walk(table, key) is None:
            owner = _owner(table, key)  # a key the model declares but the table does not hold yet
            if owner is None:
                raise BrdftabError(f"{where}: '{key}' names no parameter of the model"
                                   f"{suggest(key, _all_keys(table))}; valid: {', '.join(_all_keys(table))}")
            node, name = owner
            node[name] = value
            continue
        _set(table, key, value)
    return table, folder


def _owner(table: dict, key: str):
    """``(model table, spec key)`` when ``key`` names a parameter that model declares (held or
    not), else None."""
    from .sweep import parse_key

    parts = parse_key(key)
    if not parts or not isinstance(parts[-1], str):
        return None
    head = ".".join(str(x) for x in parts[:-1])
    node = table if not head else _walk(table, head)
    node = node if not head or node is None else node[3]
    if isinstance(node, dict) and "name" in node and parts[-1] in _params_of(node):
        return node, parts[-1]
    return None


def _all_keys(table: dict, prefix: str = "") -> list:
    """Every declared spec key of the model and its terms (``terms.1.alpha``)."""
    out = []
    for key, p in _params_of(table).items():
        value = table.get(key)
        if p.kind == "brdfs" and isinstance(value, list):
            for i, sub in enumerate(value):
                out += _all_keys(sub, f"{prefix}{key}.{i}.")
        elif p.kind == "brdf" and isinstance(value, dict):
            out += _all_keys(value, f"{prefix}{key}.")
        else:
            out.append(prefix + key)
    return out


def _resolve_files(table: dict, folder: Path) -> None:
    """Make the file values of a ``[model]`` table (a material's CSV, a coefficient file)
    absolute, as the spec loader resolves them against the start file's folder, so that the
    fitted spec reads the same files wherever it is written."""
    from .params import KINDS

    for key, p in _params_of(table).items():
        value = table.get(key)
        if p.kind == "brdfs" and isinstance(value, list):
            for sub in value:
                _resolve_files(sub, folder)
        elif p.kind == "brdf" and isinstance(value, dict):
            _resolve_files(value, folder)
        elif isinstance(value, str) and hasattr(KINDS.get(p.kind), "from_spec"):
            resolved = p.kind_object.from_spec(p, value, folder)
            table[key] = str(Path(resolved).resolve()) if resolved != value else value


def _build(table, folder):
    from .errors import SpecError
    from .spec import build_model

    where = folder / "<fit>"
    try:
        return build_model(table, "model", where)
    except SpecError as exc:
        raise BrdftabError(str(exc).replace(f"{where}: ", "the model: ", 1)) from None


def _free_vector(table, free, bounds):
    """Expanded free keys, start vector, lower and upper bounds (spec units)."""
    keys, x0, lo, hi = [], [], [], []
    valid = free_keys(table)
    for key in free:
        found = _walk(table, key)
        if found is None and _add_declared(table, key):
            found = _walk(table, key)
        if found is None:
            raise BrdftabError(f"--free: unknown key '{key}'{suggest(key, valid)}; free keys of this model: "
                               f"{', '.join(valid) or 'none'}")
        _, _, p, value = found
        if isinstance(value, list) and value and all(map(_numeric, value)):
            items = [(f"{key}[{i}]", v) for i, v in enumerate(value)]
        elif _numeric(value):
            items = [(key, value)]
        else:
            raise BrdftabError(f"--free: '{key}' is not a number (it is {json.dumps(value)}); only numeric "
                               f"parameters can be fitted")
        if p is not None and p.kind not in ("float", "channel", "floats"):
            raise BrdftabError(f"--free: '{key}' is a {p.kind} parameter; only real-valued parameters can be fitted")
        for k, v in items:
            lower, upper = _declared_bounds(p, float(v))
            if k in (bounds or {}) or key in (bounds or {}):
                lower, upper = (float(b) for b in (bounds.get(k) or bounds[key]))
            if not lower <= v <= upper:
                raise BrdftabError(f"--free: the start {k} = {v:g} is outside its bounds [{lower:g}, {upper:g}]")
            if not lower < upper:
                raise BrdftabError(f"--free: the bounds of {k} are empty ([{lower:g}, {upper:g}])")
            keys.append(k)
            x0.append(float(v))
            lo.append(lower)
            hi.append(upper)
    dup = {k for k in keys if keys.count(k) > 1}
    if dup:
        raise BrdftabError(f"--free: {', '.join(sorted(dup))} named twice")
    return keys, np.array(x0), np.array(lo), np.array(hi)


def _declared_bounds(p, start: float):
    """The bounds of a free parameter in spec units: its declared range (degrees for angles),
    an open end closed at start ± OPEN_SPAN·max(|start|, 1)."""
    conv = math.degrees if (p is not None and p.angle) else float
    span = OPEN_SPAN * max(abs(start), 1.0)
    lower = conv(p.minimum) if p is not None and p.minimum is not None else start - span
    upper = conv(p.maximum) if p is not None and p.maximum is not None else start + span
    if p is not None and p.minimum is not None and p.exclusive_minimum:
        lower += 1e-9 * max(abs(lower), 1.0)
    return float(lower), float(upper)


@dataclass
class _Problem:
    """One least-squares problem: the model to build from ``x``, its bounds, the metric and
    the samples. Plain data, so that a start can run on another process (an engine's worker)."""

    start_table: dict
    folder: str
    keys: list
    lo: np.ndarray
    hi: np.ndarray
    metric: str
    floor: float
    scale: float | None
    lam: object
    samples: _Samples
    loss: str = "soft_l1"

    def model_at(self, x):
        t = json.loads(json.dumps(self.start_table))
        for k, v in zip(self.keys, x):
            _set(t, k, float(v))
        return _build(t, Path(self.folder)), t

    def residuals(self, x):
        s = self.samples
        mask = np.isfinite(s.target)
        target = np.where(mask, s.target, 0.0)
        m, _ = self.model_at(x)
        f = np.broadcast_to(m.eval(s.wi, s.wo, self.lam, assume_unit=True), target.shape)
        if self.metric == "log":
            r = np.log(np.maximum(f, self.floor)) - np.log(np.maximum(target, self.floor))
        else:
            r = (f - target) * s.cos[:, None]
        return r[mask]

    def solve(self, x, tol, max_nfev=None):
        from scipy.optimize import least_squares

        fs = self.scale
        if fs is None:  # cos: the scale of the residuals at the start
            fs = max(float(np.median(np.abs(self.residuals(x)))), 1e-12)
        return least_squares(self.residuals, x, bounds=(self.lo, self.hi), loss=self.loss, f_scale=fs,
                             x_scale="jac", method="trf", max_nfev=max_nfev or 200 * (len(x) + 1), ftol=tol, xtol=tol,
                             gtol=tol)


def _search_one(problem: _Problem, x):
    """The search from one start: ``(x, cost, rms residual)``, or None when the model refuses
    a combination of values on the way."""
    try:
        r = problem.solve(x, SEARCH_TOL, SEARCH_STEPS)
    except BrdftabError:
        return None
    return r.x, float(r.cost), float(np.sqrt(np.mean(r.fun ** 2))) if r.fun.size else 0.0


def fit(table, model, free, *, params: dict | None = None, metric: str = "log", bounds: dict | None = None,
        starts: int = DEFAULT_STARTS, max_theta_deg: float = MAX_THETA_DEG, search_samples: int = SEARCH_SAMPLES,
        refine_samples: int = REFINE_SAMPLES, f_scale: float | None = None, seed: int = 0,
        albedo: bool = True, engine=None, loss: str = "soft_l1") -> FitResult:
    """Fit the ``free`` parameters of ``model`` to ``table`` (a :class:`~brdftab.table.Table` or
    a path). ``model``: a BRDF, a model name, a ``[model]`` table or a TOML file whose
    ``[model]`` is the starting model; ``params`` sets keys of it (spec units); ``bounds``
    ``{key: (lo, hi)}`` replaces a key's default bounds; ``engine`` (a started
    :class:`brdftab.batch.Engine`) runs the starts in parallel on its workers. See the module
    docstring for the samples, metrics, search and uncertainties.

    >>> import brdftab
    >>> truth = brdftab.models.create("microfacet", alpha=0.2)
    >>> grid = {"type": "rusinkiewicz", "n_theta_h": 24, "n_theta_d": 12, "n_phi_d": 12}
    >>> table = brdftab.tabulate(truth, brdftab.grids.grid_from_config(grid))
    >>> result = brdftab.fit(table, "microfacet", free=["alpha"], params={"alpha": 0.5}, starts=2)
    >>> round(result.parameters["alpha"], 6)
    0.2
    """
    from .params import unknown

    if metric not in METRICS:
        raise BrdftabError(unknown("metric", metric, METRICS))
    if loss not in LOSSES:
        raise BrdftabError(unknown("loss", loss, LOSSES))
    if isinstance(table, (str, Path)):
        from . import open as open_table

        table = open_table(table)
    if isinstance(free, str):
        free = [k for k in free.split(",") if k]
    if not free:
        raise BrdftabError("--free: name at least one parameter to fit")
    if isinstance(starts, bool) or not isinstance(starts, int) or not 1 <= starts <= MAX_STARTS:
        raise BrdftabError(f"starts: expected a whole number in [1, {MAX_STARTS}], got {starts!r}")
    if not 0 < max_theta_deg <= 90:
        raise BrdftabError(f"max_theta_deg: expected a number > 0 and <= 90, got {max_theta_deg!r}")
    start_table, folder = _start_model(model, params, "--param")
    keys, x0, lo, hi = _free_vector(start_table, free, bounds)
    first = _build(start_table, folder)  # the start itself must be a valid model

    source = _Nodes(table)
    nodes = source.valid(max_theta_deg)
    if nodes.size == 0:
        raise BrdftabError(f"the table has no valid samples to fit (every node is missing, not finite, below the "
                           f"horizon or beyond θ = {max_theta_deg:g}°)")
    rng = np.random.default_rng(seed)
    search_nodes = np.sort(rng.choice(nodes, min(nodes.size, search_samples), replace=False))
    refine_nodes = np.sort(rng.choice(nodes, min(nodes.size, refine_samples), replace=False))
    lam = table.wavelengths if table.spectral else None

    positive = source.values[nodes]
    positive = positive[np.isfinite(positive) & (positive > 0)]
    floor = LOG_FLOOR * float(np.median(positive)) if positive.size else 1e-12

    scale = f_scale if f_scale is not None else (0.1 if metric == "log" else None)
    problem = _Problem(start_table, str(folder), keys, lo, hi, metric, floor, scale, lam, source.samples(search_nodes),
                       loss)
    points = [x0]
    if starts > 1:
        from scipy.stats import qmc

        spread = qmc.LatinHypercube(len(keys), seed=seed).random(starts - 1)
        points += list(lo + spread * (hi - lo))
    got = first.eval(problem.samples.wi[:1], problem.samples.wo[:1], lam, assume_unit=True).shape[-1]
    want = problem.samples.target.shape[-1]
    if got not in (1, want):
        raise BrdftabError(f"the model gives {got} channels ({', '.join(first.channels or ())}), the table has "
                           f"{want}: give per-channel values that match the table's channels")
    calls = [(problem, np.clip(x, lo, hi)) for x in points]
    if engine is None:
        runs = [_search_one(*c) for c in calls]
    else:
        from .batch import ordered

        runs = [r for _, r in ordered(engine.map(_search_one, calls))]
    runs = [r for r in runs if r is not None]  # None: a combination of values the model refuses
    if not runs:
        raise BrdftabError("no start gave a valid model")
    runs.sort(key=lambda r: r[1])
    refine = source.samples(refine_nodes)
    problem.samples = refine
    best = problem.solve(runs[0][0], 1e-8)
    x = best.x
    r = problem.residuals(x)
    mask = np.isfinite(refine.target)
    m, n_par = r.size, len(x)
    jac = best.jac
    s2 = float(r @ r) / max(m - n_par, 1)
    try:
        cov = s2 * np.linalg.inv(jac.T @ jac)
        sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        with np.errstate(invalid="ignore", divide="ignore"):
            corr = cov / np.outer(sd, sd)
    except np.linalg.LinAlgError:
        sd = np.full(n_par, np.inf)
        corr = np.full((n_par, n_par), np.nan)
    fitted, fitted_table = problem.model_at(x)
    _resolve_files(fitted_table, folder)

    # residual per θi bin (over the refine samples)
    per_sample = np.zeros(mask.shape)
    per_sample[mask] = r
    by_theta = []
    deg = np.degrees(refine.theta_i)
    for b0 in np.arange(0.0, max_theta_deg, _BIN_DEG):
        b1 = min(b0 + _BIN_DEG, max_theta_deg)
        rows = (deg >= b0) & ((deg < b1) | ((b1 == max_theta_deg) & (deg <= b1)))
        n = int(mask[rows].sum())
        if n:
            rms = float(np.sqrt(np.sum(per_sample[rows] ** 2) / n))
            by_theta.append([float(b0), float(b1), rms, n])

    try:
        grid_cfg, grid_error = source.grid_table(fitted), ""
        if lam is not None:  # a spectral table: its wavelengths, written exactly
            grid_cfg["wavelengths_nm"] = [float(x) for x in lam]
    except BrdftabError as exc:
        grid_cfg, grid_error = None, str(exc)
    result = FitResult(
        model=fitted, model_table=fitted_table, grid_table=grid_cfg, grid_error=grid_error, free=keys,
        parameters={k: float(v) for k, v in zip(keys, x)},
        uncertainties={k: float(v) for k, v in zip(keys, sd)},
        correlations=[[None if not np.isfinite(c) else float(c) for c in row] for row in corr],
        metric=metric, residual=float(np.sqrt(np.mean(r ** 2))), residual_by_theta_i=by_theta,
        samples=int(refine_nodes.size), starts=len(points),
        start_results=[q[2] for q in runs],
        bounds={k: (float(a), float(b)) for k, a, b in zip(keys, lo, hi)})
    if albedo:
        result.albedo = _albedo(table, fitted, lam, max_theta_deg)
    return result


def _albedo(table, model, lam, max_theta_deg):
    """Directional albedo of table and fit at θi = 0, 15, … up to the cut-off (per channel)."""
    from .integrate import directional_albedo

    theta = np.radians(np.arange(0.0, max_theta_deg + 1e-9, 15.0))
    outside = getattr(table, "outside", None)
    try:
        if outside is not None:
            table.outside = "nan"
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            a_t = directional_albedo(table, theta, 0.0, lam)
            a_f = directional_albedo(model, theta, 0.0, lam)
    finally:
        if outside is not None:
            table.outside = outside

    def rows(a):
        return [[None if not np.isfinite(v) else float(v) for v in row]
                for row in np.asarray(a).reshape(theta.size, -1)]
    return {"theta_i_deg": [float(t) for t in np.degrees(theta)], "table": rows(a_t), "fit": rows(a_f)}
