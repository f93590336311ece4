"""Spec files (TOML): what to tabulate, on which grid, into which files.

Layout::

    description = "optional free text"

    [model]                  # name + parameters; angles in degrees only, as <name>_deg
    name = "microfacet"
    distribution = "ggx"
    alpha = 0.3
    fresnel = "conductor"
    n = [0.143, 0.374, 1.442]        # one value per channel (R, G, B) ...
    k = [3.983, 2.385, 1.603]        # ... or a spectrum {wavelengths_nm = [...], values = [...]}

    [grid]                   # see brdftab.grids.grid_from_config
    type = "merl"            # merl | rusinkiewicz | spherical
    # wavelengths_nm = [450, 550, 650]   (spectral models)
    # polarized = true       (polarized models, phi_d_fold = "none": the Mueller matrix too;
    #                         a .pbsdf output always holds it)

    [[output]]               # one table per output; path relative to this file's folder
    path = "ggx-gold.nc"
    # format = "netcdf"      (default: from the extension); other keys are format options
    dtype = "float32"

    [validation]             # thresholds for the checks run before export
    allow_invalid = false

Combinators nest: ``name = "sum"`` with ``[[model.terms]]`` tables; ``name = "scale"`` with
``factor`` and a ``[model.term]`` table.

A parameter that names a file (``coefficients = "ptfe.coeff.csv"`` of ``zernike-expansion``,
``material = "nk.csv"`` of a conductor Fresnel term) is read relative to the spec's folder; it
is among the spec's inputs, so no output may overwrite it.

Everything is checked strictly: an unknown key, unknown model, missing, mistyped or
out-of-range value raises :class:`~brdftab.errors.SpecError` with one line naming the file,
the key and what is expected.
"""

from __future__ import annotations

import hashlib
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .brdf import BRDF
from .errors import BrdftabError, ParameterError, SpecError
from .grids import Grid, check_grid, grid_from_config, grid_wavelengths
from .params import _show, as_float, suggest

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

__all__ = ["Spec", "Output", "load_spec", "build_model", "model_inputs"]

TOP_KEYS = ("description", "model", "grid", "output", "validation", "sweep")


@dataclass
class Output:
    """One ``[[output]]``: target path (resolved against the spec's folder), format name (or
    None), format options, and the path as the spec wrote it (for ``--out`` folders)."""

    path: Path
    format: str | None = None
    options: dict = field(default_factory=dict)
    as_written: Path | None = None

    def target(self, out_dir=None) -> Path:
        """Where to write: ``path``, or the written path placed in ``out_dir``."""
        rel = self.as_written if self.as_written is not None else self.path
        if out_dir is None or rel.is_absolute():
            return self.path
        return Path(out_dir) / rel


@dataclass
class Spec:
    """A validated spec file."""

    path: Path
    sha256: str
    model: BRDF
    grid: Grid
    wavelengths: np.ndarray | None
    outputs: list
    validation: dict
    description: str = ""
    raw: dict = field(default_factory=dict)
    #: For a member of a ``[sweep]`` (:mod:`brdftab.sweep`): ``{"member": index, "values": {key: value}}``.
    sweep: dict | None = None
    #: ``[grid] polarized = true``: the tables hold the model's Mueller matrix too
    #: (:mod:`brdftab.mueller_table`).
    polarized: bool = False

    @property
    def provenance(self) -> dict:
        """What a file written from this spec records of it: the spec file's name and SHA-256,
        its description, and for a sweep member its index and swept values (JSON)."""
        import json

        out = {"spec_sha256": self.sha256, "spec_file": self.path.name}
        if self.description:
            out["comment"] = self.description
        if self.sweep is not None:
            out["sweep_member"] = int(self.sweep["member"])
            out["sweep_values"] = json.dumps(self.sweep["values"], ensure_ascii=False)
        return out

    @property
    def inputs(self) -> list:
        """The files a run of this spec reads, as ``(path, what)``: the spec file itself and any
        file its model reads (a model lists those in ``input_files``). No output may be one."""
        out = [(self.path, "the spec file")]
        out += [(Path(p), "an input file of the model") for p in model_inputs(self.model)]
        return out


def model_inputs(model) -> list:
    """Files ``model`` and the models nested in it read (their ``input_files``)."""
    found, stack, seen = [], [model], set()
    while stack:
        m = stack.pop()
        if id(m) in seen:
            continue
        seen.add(id(m))
        found += [Path(p) for p in getattr(m, "input_files", ()) or ()]
        for v in getattr(m, "_values", {}).values():  # a material's n, k file (brdftab.optical)
            if getattr(v, "is_file", False):
                found.append(Path(v.source))
        for p in getattr(m, "params", ()):  # nested models are parameters of kind brdf / brdfs
            if getattr(p, "kind", None) not in ("brdf", "brdfs"):
                continue
            sub = getattr(m, p.name, None)
            if isinstance(sub, BRDF):
                stack.append(sub)
            elif isinstance(sub, (list, tuple)):
                stack.extend(x for x in sub if isinstance(x, BRDF))
    return found


def load_spec(path) -> Spec:
    """Read and validate the spec file at ``path`` (a spec with a ``[sweep]`` table describes
    several: :func:`brdftab.sweep.load` reads those)."""
    path = Path(path)
    raw, sha = read_spec(path)
    return parse_spec(raw, path, sha)


def read_spec(path) -> tuple:
    """``(raw mapping, SHA-256 of the file)`` of the TOML spec file at ``path``, not yet validated."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise SpecError(f"{path}: no such spec file") from None
    except OSError as exc:
        raise SpecError(f"{path}: cannot read ({exc.strerror})") from None
    try:
        text = data.decode("utf-8-sig")  # a byte-order mark, as some editors write, is accepted
    except UnicodeDecodeError:
        raise SpecError(f"{path}: not a UTF-8 text file") from None
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SpecError(f"{path}: invalid TOML: {exc}") from None
    except RecursionError:
        raise SpecError(f"{path}: values nested too deeply (at most {MAX_DEPTH} levels)") from None
    if _depth(raw) > MAX_DEPTH:
        raise SpecError(f"{path}: values nested too deeply (at most {MAX_DEPTH} levels)")
    return raw, hashlib.sha256(data).hexdigest()


#: Deepest nesting of tables and arrays a spec may have (models nest a few levels at most).
MAX_DEPTH = 64


def _depth(value) -> int:
    """Nesting depth of tables and arrays in ``value`` (iterative: no recursion limit)."""
    deepest = 0
    stack = [(value, 1)]
    while stack:
        v, d = stack.pop()
        if isinstance(v, dict):
            items = v.values()
        elif isinstance(v, list):
            items = v
        else:
            continue
        deepest = max(deepest, d)
        if d > MAX_DEPTH:
            return d
        stack.extend((x, d + 1) for x in items)
    return deepest


def _fail(path, key, message):
    return SpecError(f"{path}: {key}: {message}" if key else f"{path}: {message}")


def parse_spec(raw: dict, path: Path, sha256: str = "") -> Spec:
    """Validate an already-parsed spec mapping (paths resolve against ``path``'s folder)."""
    for key in raw:
        if key not in TOP_KEYS:
            raise _fail(path, key, f"unknown top-level key{suggest(key, TOP_KEYS)}; valid: {', '.join(TOP_KEYS)}")
    if "sweep" in raw:
        from .sweep import count

        raise _fail(path, "sweep", f"this spec describes {count(raw, path)} tables (a [sweep]): tabulate or validate "
                    "it (brdftab.sweep.load reads its members); it does not stand for one model")
    description = raw.get("description", "")
    if not isinstance(description, str):
        raise _fail(path, "description", "expected a string")
    for section in ("model", "grid"):
        if section not in raw:
            raise _fail(path, f"[{section}]", "missing section")
        if not isinstance(raw[section], dict):
            raise _fail(path, section, "expected a table [" + section + "]")
    model = build_model(raw["model"], "model", path)
    grid_cfg = raw["grid"]
    try:
        grid = grid_from_config(grid_cfg)
    except ParameterError as exc:
        raise _fail(path, f"grid.{exc.key}", exc.detail) from None
    wavelengths = _wavelengths(grid_cfg, model, path)
    try:
        check_grid(model, grid)
    except ParameterError as exc:
        raise _fail(path, f"grid.{exc.key}" if exc.key else "grid", exc.detail) from None
    polarized = _polarized(grid_cfg, model, grid, path)
    outputs = _outputs(raw.get("output"), path)
    _polarized_outputs(outputs, model, path)
    validation = _validation(raw.get("validation", {}), path)
    return Spec(path=path, sha256=sha256, model=model, grid=grid, wavelengths=wavelengths, outputs=outputs,
                validation=validation, description=description, raw=raw, polarized=polarized)


def _polarized(grid_cfg, model, grid, path) -> bool:
    """``[grid] polarized``: a bool, for a polarized model on a grid without a φd fold."""
    if "polarized" not in grid_cfg:
        return False
    value = grid_cfg["polarized"]
    if not isinstance(value, bool):
        raise _fail(path, "grid.polarized", f"expected true or false, got {value!r}")
    if value:
        from .mueller_table import is_polarized

        if not is_polarized(model):
            raise _fail(path, "grid.polarized", f"the model {model.name!r} has no Mueller matrix (not polarized)")
        fold = getattr(grid, "phi_d_fold", "none")
        if fold != "none":
            raise _fail(path, "grid.polarized", f"a polarized table needs phi_d_fold = 'none', not {fold!r} (a "
                        "fold's symmetry acts on the Mueller matrix too)")
    return value


def build_model(table, where: str, path) -> BRDF:
    """Build a model from a spec table (``name`` + parameters; ``*_deg`` angles)."""
    from . import models

    if not isinstance(table, dict):
        raise _fail(path, where, "expected a table with a model name and its parameters")
    name = table.get("name")
    if name is None:
        raise _fail(path, f"{where}.name", f"missing model name; valid models: {', '.join(sorted(models.MODELS))}")
    if not isinstance(name, str) or name not in models.MODELS:
        raise _fail(path, f"{where}.name", models.MODELS.message(name))
    cls = models.MODELS[name]
    declared = {p.name: p for p in cls.params}
    by_spec_key = {p.spec_key: p for p in cls.params}
    kwargs = {}
    for key, value in table.items():
        if key == "name":
            continue
        p = by_spec_key.get(key)
        if p is None:
            if key in declared and declared[key].angle:
                raise _fail(path, f"{where}.{key}", f"angles are given in degrees in spec files: write {key}_deg")
            raise _fail(path, f"{where}.{key}", f"unknown parameter for model '{name}'{suggest(key, by_spec_key)};"
                        f" valid: {', '.join(by_spec_key)}")
        if p.kind == "brdf":
            value = build_model(value, f"{where}.{key}", path)
        elif p.kind == "brdfs":
            if not isinstance(value, list) or not value:
                raise _fail(path, f"{where}.{key}", f"expected one or more [[{where}.{key}]] tables")
            value = [build_model(v, f"{where}.{key}[{i}]", path) for i, v in enumerate(value)]
        elif p.angle:
            deg = None if isinstance(value, bool) or not isinstance(value, (int, float)) else as_float(value)
            if deg is None:
                raise _fail(path, f"{where}.{key}", f"expected an angle in degrees, got {_show(value)}")
            value = math.radians(deg)
        elif hasattr(p.kind_object, "from_spec"):  # a file parameter: relative to the spec's folder
            value = p.kind_object.from_spec(p, value, Path(path).parent)
        kwargs[p.name] = value
    try:
        return cls(**kwargs)
    except ParameterError as exc:
        key = _spec_key(cls, exc.key)
        raise _fail(path, f"{where}.{key}" if key else where, exc.detail) from None
    except BrdftabError as exc:
        raise _fail(path, where, str(exc)) from None


def _spec_key(cls, name: str) -> str:
    for p in cls.params:
        if p.name == name:
            return p.spec_key
    return name


def _wavelengths(grid_cfg, model, path):
    if "wavelengths_nm" not in grid_cfg:
        if model.spectral and model.wavelengths is None:
            raise _fail(path, "grid.wavelengths_nm", "the model is spectral: list the wavelengths to sample")
        return None
    try:
        lam = grid_wavelengths(grid_cfg)
    except ParameterError as exc:
        raise _fail(path, "grid.wavelengths_nm", exc.detail) from None
    if not model.spectral and not model.layout.grey and model.layout.sampled is None:
        raise _fail(path, "grid.wavelengths_nm", f"the model has channels {list(model.channels)}, not a "
                    "spectrum; remove wavelengths_nm or give its parameters as spectra")
    try:
        model.layout.resolve(lam)  # within the range of a material's optical constants
    except ParameterError as exc:
        raise _fail(path, "grid.wavelengths_nm", exc.detail) from None
    if model.spectral and model.wavelengths is not None:
        lo, hi = model.wavelengths[0], model.wavelengths[-1]
        if lam[0] < lo or lam[-1] > hi:
            raise _fail(path, "grid.wavelengths_nm", f"outside the model's spectral data [{lo:g}, {hi:g}] nm")
    return lam


def _outputs(raw, path):
    from . import formats

    if raw is None:
        raise _fail(path, "[[output]]", "missing: add at least one [[output]] with a path")
    if not isinstance(raw, list) or not raw:
        raise _fail(path, "output", "expected one or more [[output]] tables")
    outs = []
    for i, item in enumerate(raw):
        where = f"output[{i}]"
        if not isinstance(item, dict):
            raise _fail(path, where, "expected a table with a path")
        if "path" not in item or not isinstance(item["path"], str) or not item["path"]:
            raise _fail(path, f"{where}.path", "missing or not a string")
        if "\x00" in item["path"]:
            raise _fail(path, f"{where}.path", "a path cannot contain a NUL character")
        fmt_name = item.get("format")
        try:
            fmt = formats.format_for(item["path"], fmt_name)
        except BrdftabError as exc:
            key = "format" if fmt_name is not None else "path"
            raise _fail(path, f"{where}.{key}", getattr(exc, "detail", str(exc))) from None
        options = {k: v for k, v in item.items() if k not in ("path", "format")}
        try:
            fmt.validate_options(options)
        except ParameterError as exc:
            raise _fail(path, f"{where}.{exc.key}", exc.detail) from None
        target = Path(item["path"])
        if not target.is_absolute():
            target = path.parent / target
        outs.append(Output(path=target, format=fmt.name, options=options, as_written=Path(item["path"])))
    return outs


def _polarized_outputs(outputs, model, path) -> None:
    """An output in a format that holds a Mueller matrix (.pbsdf) needs a polarized model."""
    from . import formats
    from .mueller_table import is_polarized

    for i, o in enumerate(outputs):
        if formats.FORMATS[o.format].polarized and not is_polarized(model):
            raise _fail(path, f"output[{i}].path", f"{o.as_written} holds a Mueller matrix (format {o.format}): the "
                        f"model {model.name!r} is not polarized")


def _validation(raw, path):
    from .checks import CHECKS, configure

    if not isinstance(raw, dict):
        raise _fail(path, "validation", "expected a table [validation]")
    out = {"allow_invalid": False}
    layer = {}
    for key, value in raw.items():
        if key == "allow_invalid":
            if not isinstance(value, bool):
                raise _fail(path, "validation.allow_invalid", "expected true or false")
            out[key] = value
        elif key in CHECKS:
            layer[key] = value
        else:
            valid = ["allow_invalid", *CHECKS]
            raise _fail(path, f"validation.{key}", f"unknown key{suggest(key, valid)}; valid: {', '.join(valid)}")
    try:
        configure(layer)
    except ParameterError as exc:
        raise _fail(path, f"validation.{exc.key}", exc.detail) from None
    out.update(layer)
    return out
