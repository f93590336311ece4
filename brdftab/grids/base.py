"""The grid base class, the grid-type registry, and building grids from specs and files."""

from __future__ import annotations

import math

import numpy as np

from .._jit import device
from ..errors import ParameterError
from ..registry import Registry
from ..params import Kind, Param, _show, as_float, register_kind, suggest
from .axis import LONG_NAMES, NODE_RULES, Axis, expand_range

__all__ = ["Grid", "GRIDS", "register", "grid_from_config", "grid_from_dataset", "grid_wavelengths", "COMMON_PARAMS",
           "read_coordinate", "choice_attr"]

#: Grid types by spec name (``[grid] type = ...``).
GRIDS = Registry("grid type", attr="type_name")

class WavelengthsKind(Kind):
    """Wavelengths [nm], positive and strictly increasing: a list of numbers and/or ranges
    ``{start, stop, step|num[, endpoint]}`` (the range syntax of angle lists), in nm."""

    name = "wavelengths"

    def expected(self, p):
        return "a list of positive wavelengths in nm, increasing (numbers and/or ranges {start, stop, step|num})"

    def convert(self, p, value):
        if isinstance(value, np.ndarray):
            value = value.tolist()
        items = [value] if isinstance(value, dict) else value
        if not isinstance(items, (list, tuple)) or len(items) == 0:
            raise ParameterError(p.name, f"expected {self.expected(p)}, got {_show(value)}")
        out = []
        for item in items:
            if isinstance(item, dict):
                out.extend(expand_range(p.name, item))
            elif isinstance(item, bool) or not isinstance(item, (int, float, np.number)):
                raise ParameterError(p.name, f"expected {self.expected(p)}, got {_show(item)}")
            else:
                x = as_float(item)
                out.append(np.nan if x is None else x)
        lam = np.asarray(out, float)
        if not np.all(np.isfinite(lam)) or np.any(lam <= 0):
            raise ParameterError(p.name, f"expected positive, finite wavelengths in nm, got {_show(value)}")
        if np.any(np.diff(lam) <= 0):
            k = int(np.flatnonzero(np.diff(lam) <= 0)[0])
            raise ParameterError(p.name, f"wavelengths must increase strictly: {lam[k]:g} nm is followed by "
                                 f"{lam[k + 1]:g} nm")
        return lam

    def to_json(self, value):
        return np.asarray(value, float).tolist()


def grid_wavelengths(cfg: dict):
    """The spectral axis of a ``[grid]`` table: ``wavelengths_nm`` [nm] as an array, or None.
    Raises :class:`ParameterError` (key ``wavelengths_nm``)."""
    if "wavelengths_nm" not in cfg:
        return None
    return COMMON_PARAMS[0].convert(cfg["wavelengths_nm"])


register_kind(WavelengthsKind())

#: Keys every ``[grid]`` table accepts besides the type's own.
COMMON_PARAMS = (
    Param("wavelengths_nm", "wavelengths", "Wavelengths to sample a spectral model at [nm]: a list of numbers "
          "and/or ranges {start, stop, step|num}.", units="nm",
          default=None, used_when="spectral models"),
    Param("polarized", "bool", "Tabulate the Mueller matrix of a polarized model too (variable mueller over "
          "mueller_row, mueller_col; needs phi_d_fold = 'none'). A .pbsdf output always holds it.", default=False,
          used_when="polarized models"),
)


def register(cls):
    """Add a grid class to :data:`GRIDS` under ``cls.type_name`` (usable as a decorator)."""
    return GRIDS.register(cls)


class Grid:
    """Base class: a tuple of axes plus conversions between indices and direction pairs.

    Subclasses set ``type_name`` (spec name), ``summary``, ``params`` (the ``[grid]`` keys
    they accept, as :class:`~brdftab.params.Param`), ``parameterizations`` (the table
    attribute values they reconstruct) and implement ``from_config``, ``from_dataset``,
    ``attrs``, ``_directions`` and ``_coordinates``.
    """

    type_name = ""
    summary = ""
    params: tuple = ()
    parameterizations: tuple = ()

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        if "name" not in cls.__dict__:
            cls.name = cls.type_name  # the attribute every registry member has (models, formats, checks)
    parameterization = "grid"
    axes: tuple = ()
    #: A table on the grid evaluates through the compiled kernels (False: through :meth:`locate`).
    compiled = True
    #: The checks know this grid's node partners (reciprocity, isotropy, mirror pairs) and node
    #: weights; False: they compare interpolated pairs instead.
    node_checks = True

    # -- shape ---------------------------------------------------------------------------------
    @property
    def dims(self) -> tuple:
        return tuple(a.name for a in self.axes)

    @property
    def shape(self) -> tuple:
        return tuple(len(a) for a in self.axes)

    @property
    def size(self) -> int:
        return math.prod(self.shape)

    @property
    def coords(self) -> dict:
        return {a.name: a.values for a in self.axes}

    def attrs(self) -> dict:
        """Dataset attributes that, with the coordinates, reconstruct this grid."""
        raise NotImplementedError

    def coord_attrs(self, name) -> dict:
        ax = self.axes[self.dims.index(name)]
        out = {"units": "rad", "long_name": LONG_NAMES.get(name, name), "node_rule": ax.rule}
        if ax.period is None:
            out["domain"] = np.asarray(ax.domain, float)
        return out

    # -- index <-> directions ------------------------------------------------------------------
    def directions(self, start: int = 0, stop: int | None = None):
        """``(wi, wo)`` of flat sample indices ``start..stop`` (C order), each ``(m, 3)``."""
        stop = self.size if stop is None else stop
        idx = np.unravel_index(np.arange(start, stop), self.shape)
        return self._directions(idx)

    def _directions(self, idx):
        raise NotImplementedError

    def directions_into(self, start: int, stop: int, wi: np.ndarray, wo: np.ndarray) -> None:
        """Write the directions of flat sample indices ``start..stop`` into ``wi``, ``wo[m, 3]``
        (float64, C order): :meth:`directions` without its temporaries. Grids with a compiled
        form override it; the results are the same bits."""
        wi[:], wo[:] = self.directions(start, stop)

    def _coordinates(self, wi, wo, isotropic: bool = False) -> list:
        """Per-axis coordinates [rad] of direction pairs (folds applied)."""
        raise NotImplementedError

    def locate(self, wi, wo, isotropic: bool = False):
        """``(fractional indices per axis, outside mask)`` of direction pairs ``[..., 3]``."""
        coords = self._coordinates(wi, wo, isotropic)
        outside = np.zeros(np.shape(coords[0]), bool)
        for a, x in zip(self.axes, coords):
            outside |= a.outside(x)
        return [a.fractional_index(x) for a, x in zip(self.axes, coords)], outside

    def fractional_index(self, wi, wo, isotropic: bool = False):
        """Fractional index per axis of direction pairs ``[..., 3]`` (list of arrays)."""
        return self.locate(wi, wo, isotropic)[0]

    def node_above_horizon(self) -> np.ndarray:
        """Bool array ``shape``: True where both directions of the node are above the horizon.

        Below-horizon nodes hold no data (f is 0 there by definition); interpolation leaves
        them out. Computed once per grid, in chunks.
        """
        cached = getattr(self, "_above", None)
        if cached is not None:
            return cached
        from ..brdf import HORIZON

        out = np.empty(self.size, bool)
        step = 1 << 18
        for s in range(0, self.size, step):
            wi, wo = self.directions(s, min(s + step, self.size))
            out[s:s + wi.shape[0]] = (wi[:, 2] > HORIZON) & (wo[:, 2] > HORIZON)
        out = out.reshape(self.shape)
        self._above = out
        return out

    def sliced(self, lo: int, hi: int) -> "Grid":
        """The same grid with only nodes ``lo:hi`` of its first (non-periodic) axis; the axis
        keeps its domain. Lets a table too large to load evaluate from a slab of it."""
        if self.axes[0].period is not None:
            raise ValueError("the first axis is periodic")
        return self.block((slice(lo, hi),))

    def block(self, key) -> "Grid":
        """The nodes ``key`` (a tuple of slices over the leading axes) as a grid of their own:
        the same node coordinates, bit for bit, each axis keeping its warp, period and domain.
        A table larger than memory is tabulated, written and checked block by block on these."""
        import copy

        axes = list(self.axes)
        for k, s in enumerate(key):
            a = axes[k]
            axes[k] = Axis(a.name, a.values[s], a.warp, a.period, a.wrap, a.domain, a.rule)
        g = copy.copy(self)
        g.axes = tuple(axes)
        g._trig = [(np.cos(x.values), np.sin(x.values)) for x in g.axes]
        g._above = None
        g._direction_tables = None
        return g

    def domain_text(self) -> str:
        return ", ".join(a.domain_text() for a in self.axes if a.period is None)

    def equals(self, other) -> bool:
        """Same parameterization, conventions and node coordinates (values can be copied)."""
        return (type(self) is type(other) and self.attrs() == other.attrs()
                and len(self.axes) == len(other.axes)
                and all(a.equals(b) for a, b in zip(self.axes, other.axes)))

    def describe(self) -> str:
        return f"{self.attrs().get('grid', self.parameterization)} " + " x ".join(
            f"{a.name}[{len(a)}]" for a in self.axes)

    # -- construction --------------------------------------------------------------------------
    @classmethod
    def from_config(cls, values: dict) -> "Grid":
        """Build from validated ``[grid]`` values (parameter names, angles in radians)."""
        raise NotImplementedError

    @classmethod
    def from_dataset(cls, ds, attrs: dict) -> "Grid":
        raise NotImplementedError


def _parse_keys(cls, cfg: dict) -> dict:
    declared = tuple(cls.params) + COMMON_PARAMS
    by_key = {p.spec_key: p for p in declared}
    values = {}
    for key, raw in cfg.items():
        if key == "type":
            continue
        p = by_key.get(key)
        if p is None:
            valid = ["type", *by_key]
            raise ParameterError(key, f"unknown key for a '{cls.type_name}' grid{suggest(key, valid)}; valid: "
                                 f"{', '.join(sorted(valid))}")
        if p.name in ("wavelengths_nm", "polarized"):
            continue  # read by the spec loader (the spectral axis, the Mueller matrix)
        try:
            values[p.name] = p.convert(raw)
        except ParameterError as exc:
            raise ParameterError(exc.key if exc.key.startswith(key) else key, exc.detail) from None
    for p in cls.params:
        if p.name not in values and p.required:
            raise ParameterError(p.spec_key, f"missing: expected {p.expected()}")
    return values


def grid_from_config(cfg: dict) -> Grid:
    """Build a grid from a ``[grid]`` table (angles in degrees under ``*_deg`` keys).

    ``wavelengths_nm`` is allowed in the table (the spectral axis); it is read by the caller.
    Raises :class:`ParameterError` naming the offending key.
    """
    kind = cfg.get("type")
    if "type" not in cfg:
        raise ParameterError("type", f"missing: say which grid, one of {', '.join(GRIDS.names())}")
    if not isinstance(kind, str) or kind not in GRIDS:
        raise ParameterError("type", GRIDS.message(kind))
    cls = GRIDS[kind]
    values = _parse_keys(cls, cfg)
    try:
        return cls.from_config(values)
    except ParameterError as exc:
        # axis errors name the axis; the spec key of an explicit list is <axis>_deg
        if exc.key in LONG_NAMES and f"{exc.key}_deg" in cfg:
            raise ParameterError(f"{exc.key}_deg", exc.detail) from None
        raise


def grid_from_dataset(ds) -> Grid:
    """Reconstruct and check the grid of a stored table from its coordinates and attributes.

    Raises :class:`ParameterError` naming the attribute or coordinate that is missing, not
    finite, not strictly increasing, in unknown units, outside its range, or different from
    what the declared grid produces.
    """
    attrs = dict(ds.attrs)
    p = attrs.get("parameterization")
    for cls in GRIDS.values():
        if p in cls.parameterizations:
            return cls.from_dataset(ds, attrs)
    known = sorted({x for c in GRIDS.values() for x in c.parameterizations})
    raise ParameterError("parameterization", f"unknown table parameterization {p!r}{suggest(p, known)}; known: "
                         f"{', '.join(known)}")


_DEGREE_UNITS = ("degree", "degrees", "deg", "degree_east", "degrees_east", "arc_degree")
_RADIAN_UNITS = ("rad", "radian", "radians")


def read_coordinate(ds, name: str) -> tuple:
    """``(values [rad], node rule or None, domain or None)`` of coordinate ``name``, checked."""
    if name not in ds.variables:
        raise ParameterError(name, f"missing coordinate '{name}'")
    var = ds[name]
    if var.ndim != 1:
        raise ParameterError(name, f"coordinate '{name}' must be one-dimensional")
    if var.dtype.kind not in "fiu":
        raise ParameterError(name, f"coordinate '{name}' must be numeric, not {var.dtype}")
    vals = np.asarray(var.values, float)
    units = str(var.attrs.get("units", "")).strip().lower()
    if units in _DEGREE_UNITS:
        vals = np.radians(vals)
        scale = np.pi / 180
    elif units in _RADIAN_UNITS:
        scale = 1.0
    else:
        raise ParameterError(name, f"coordinate '{name}' has units {var.attrs.get('units')!r}; expected 'rad' "
                             "or 'degree'")
    if vals.size == 0 or not np.all(np.isfinite(vals)):
        raise ParameterError(name, f"coordinate '{name}' must hold finite values")
    if np.any(np.diff(vals) <= 0):
        raise ParameterError(name, f"coordinate '{name}' must increase strictly")
    rule = var.attrs.get("node_rule")
    if rule is not None:
        rule = str(rule)
        if rule not in NODE_RULES:
            raise ParameterError(name, f"coordinate '{name}': node_rule {rule!r} is not one of "
                                 f"{', '.join(map(repr, NODE_RULES))}{suggest(rule, NODE_RULES)}")
    domain = var.attrs.get("domain")
    if domain is not None:
        d = np.asarray(domain, float).ravel() * scale
        if d.size != 2 or not np.all(np.isfinite(d)) or d[0] > d[1]:
            raise ParameterError(name, f"coordinate '{name}': domain must be two finite increasing numbers")
        domain = (float(d[0]), float(d[1]))
    return vals, rule, domain


def choice_attr(attrs: dict, key: str, choices, default=None) -> str:
    """An enumerated table attribute, checked against its known values."""
    if key not in attrs:
        if default is None:
            raise ParameterError(key, f"missing attribute '{key}' (one of {', '.join(map(repr, choices))})")
        return default
    value = attrs[key]
    value = value.item() if hasattr(value, "item") else value
    if not isinstance(value, str) or value not in choices:
        raise ParameterError(key, f"attribute '{key}' = {value!r} is not one of {', '.join(map(repr, choices))}"
                             f"{suggest(value, choices) if isinstance(value, str) else ''}")
    return value


@device
def unravel4(f, n1, n2, n3):
    """The four C-order indices of flat index ``f`` in a grid of shape (·, n1, n2, n3) (the
    compiled direction loops' :func:`numpy.unravel_index`)."""
    i3 = f % n3
    f //= n3
    i2 = f % n2
    f //= n2
    return f // n1, f % n1, i2, i3
