"""File formats: a registry of readers and writers, by name, extension and content.

Each format module registers one :class:`FileFormat`. The rest of brdftab reads and writes
only through :func:`read`, :func:`write` and :func:`target_grid`; it never imports a format
module directly (the modules listed in :data:`BUILTIN` are imported here, lazily where they
need an optional library, so ``import brdftab`` works without them).

A format states (after xarray's ``BackendEntrypoint`` and ALTA's data plug-ins):

* what it can open: ``extensions``, ``magic`` byte prefixes and an optional ``sniff(head,
  size)`` test on the first bytes and the file size (MERL has no magic number);
* which grid it stores: ``native_grid(requested, options)`` returns the grid the format
  writes for a requested grid (``None`` = any grid: the caller's). MERL answers the MERL grid
  whatever is asked; netCDF keeps the requested one;
* a format stored as a folder (zarr) says so with ``store(folder) -> bool``, which tells
  whether an existing folder is one of its stores: :func:`detect` recognises such a folder, and
  output paths with the format's extensions are folders (:func:`brdftab._locks.register_store`);
* which optional library it needs: ``requires`` (module names); when one is missing the
  format reports itself unavailable with one line, and every other format keeps working.

Writing is "tabulate if needed, then write atomically": ``prepare(brdf, grid, **options)``
turns any BRDF into what ``write`` takes. The default reuses a :class:`~brdftab.table.Table`
whose grid equals the target grid (values copied, never resampled) and otherwise tabulates
the BRDF on the target grid. A format that needs the model itself (the RGL ``.bsdf`` writer
samples D and the VNDF) supplies its own ``prepare``.

What is checked is what is stored: a format whose storage loses precision declares
``stored(payload, **options)``, the BRDF a reader of the written file gets back (netCDF
``dtype = "float32"`` and EXR round the samples to float32, values beyond its range becoming
infinite; an RGL ``.bsdf`` is read through its float32 fields). :func:`stored` gives it, and
the pipeline and ``convert`` run the checks on it — a value that is finite in float64 but not
as stored is a ``finite`` failure. A format that stores the samples exactly declares nothing.
"""

from __future__ import annotations

import contextlib
import importlib
import importlib.util
import os
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from .._atomic import atomic_path
from .._locks import check_target, register_store
from .._signals import held_signals
from ..errors import BrdftabError, BrdftabWarning, FormatError, ParameterError, shown
from ..params import parse_params
from ..registry import Registry

__all__ = ["FileFormat", "FORMATS", "register", "detect", "read", "write", "write_prepared", "format_for",
           "target_grid", "prepare", "stored", "cast_samples", "NotStorable", "available", "usable",
           "naming", "is_store"]

#: Bytes of a file's head passed to ``magic`` and ``sniff`` (enough for the comment lines that
#: start a Zemax ``.bsdf`` text file before its first keyword).
HEAD_BYTES = 4096


@dataclass(frozen=True)
class FileFormat:
    """A file format: how to recognise it, which grid it stores, how to read and write it.

    ``read(path) -> Table`` raises :class:`~brdftab.errors.FormatError` (one line) for
    damaged input. ``write(payload, path, **options)`` writes what ``prepare`` returned to
    ``path`` (a temporary the registry renames).
    """

    name: str
    extensions: tuple
    description: str
    read: Callable
    write: Callable
    magic: tuple = ()
    sniff: Callable | None = None
    requires: tuple = ()
    native_grid: Callable | None = None
    #: The format options, declared like model parameters (:class:`~brdftab.params.Param`):
    #: ``-o KEY=VALUE`` of convert and the keys of an ``[[output]]`` table are checked, typed
    #: and did-you-mean'd against them in one place (:meth:`validate_options`), and
    #: ``brdftab formats NAME`` lists them.
    params: tuple = ()
    prepare: Callable | None = None
    #: Rules between options that single declarations cannot say (one excludes another).
    check_options: Callable | None = None
    #: True when the format's library opens files by UTF-8 names only (netCDF/HDF5, OpenEXR): a
    #: path that is not valid UTF-8 (bytes such as 0xff in a name, as POSIX allows) is refused
    #: up front (:meth:`check_path`) instead of failing inside the library after the work.
    utf8_paths: bool = False
    #: True for a format brdftab recognises (to say what a file is) but neither reads nor
    #: writes: lists of usable formats leave it out.
    recognised_only: bool = False
    #: True for a format that stores colour channels: a spectral source is written converted
    #: to three colour channels through colour-science (:mod:`brdftab.colorimetry`).
    colour: bool = False
    #: Stated precision: the largest relative difference between what the writer wrote (the
    #: table, or its own sampling) and what the reader returns (the format contract tests it).
    precision: float = 0.0
    #: ``stored(payload, **options) -> BRDF``: what a reader of the written file gets back (the
    #: samples rounded to the storage type); a table it returns is also what is written. None:
    #: the format stores the payload's samples exactly (see :func:`stored`).
    stored: Callable | None = None
    #: ``stream(template, path, **options) -> writer`` for formats that can be written block by
    #: block, so a table larger than memory never exists as one array. ``template`` is the
    #: table's dataset (:func:`brdftab.table.make_table`) whose ``brdf`` variable has the final
    #: shape and dims but holds no data (a broadcast view: never read it). The writer creates the
    #: file with every coordinate, auxiliary variable and attribute, then takes
    #: ``writer.write(key, block)`` (``key`` a tuple of slices over ``brdf``'s dims, ``block`` float
    #: samples cast to the storage type by the writer) in any order, ``writer.close()`` and then
    #: ``writer.update(dataset)`` (after the pre-export checks: the variables of ``dataset`` the
    #: file lacks, e.g. the albedo curve, are added and its global attributes, e.g. the check
    #: report, are set); it is a context manager. ``writer.chunks`` is the storage chunk shape
    #: of ``brdf`` (writes aligned to it are fastest). None: the format is written whole.
    stream: Callable | None = None
    #: ``store(folder) -> bool`` for a format written as a folder (a directory store): True
    #: when an existing folder is one of its stores. None: the format is a file.
    store: Callable | None = None
    #: True for a format that stores a Mueller matrix (Mitsuba's ``.pbsdf``): it writes only
    #: polarized BRDFs (:func:`brdftab.mueller_table.is_polarized`).
    polarized: bool = False

    @property
    def options(self) -> dict:
        """``{name: description}`` of the declared options."""
        return {p.name: p.doc for p in self.params}

    @property
    def summary(self) -> str:
        """One line on the format (the attribute models, grids and checks call ``summary``)."""
        return self.description

    def missing(self) -> list:
        """Names of the optional libraries this format needs that are not installed."""
        return [m for m in self.requires if importlib.util.find_spec(m) is None]

    @property
    def available(self) -> bool:
        return not self.missing()

    def ensure_available(self) -> None:
        miss = self.missing()
        if miss:
            raise BrdftabError(f"format {self.name} needs the Python package {', '.join(miss)}, which is not "
                               f"installed (pip install {' '.join(miss)})")

    def check_path(self, path) -> None:
        """Refuse (one line) a path this format's library cannot open: not valid UTF-8."""
        if not self.utf8_paths:
            return
        text = os.fspath(path)
        try:
            text.encode("utf-8") if isinstance(text, str) else text.decode("utf-8")
        except UnicodeError:
            raise BrdftabError(f"{shown(text)}: the {self.name} library opens only paths "
                               "that are valid UTF-8; rename the file or folder (MERL .binary and RGL .bsdf "
                               "files take any name)") from None

    def validate_options(self, options: dict) -> dict:
        """The options checked against the declarations (unknown names with did-you-mean,
        types, ranges, choices) and then the format's cross-option rules; returns them typed.
        Raises :class:`~brdftab.errors.ParameterError` naming the bad option."""
        typed = parse_params(self.params, dict(options), f"format {self.name}", fill=False, noun="option")
        if self.check_options is not None:
            self.check_options(**options)
        return typed

    def opens(self, head: bytes, size: int) -> bool:
        """True when the content (first bytes, file size) is this format's."""
        if any(head.startswith(m) for m in self.magic):
            return True
        if self.sniff is not None:
            try:
                return bool(self.sniff(head, size))
            except Exception:  # a sniffer never decides by crashing
                return False
        return False


#: Registered formats by name.
FORMATS = Registry("format")


def register(fmt: FileFormat) -> FileFormat:
    """Add a format (each format module registers its own on import)."""
    if fmt.store is not None:
        for ext in fmt.extensions:
            register_store(ext, fmt.name, fmt.store)
    return FORMATS.register(fmt)


def usable() -> list:
    """Names of the formats brdftab reads and writes (not those it only recognises)."""
    return [n for n, f in FORMATS.items() if not f.recognised_only]


def _recognised_note() -> str:
    only = [f"{n} ({'/'.join(f.extensions)})" for n, f in FORMATS.items() if f.recognised_only]
    return f"; {', '.join(only)} recognised only, neither read nor written" if only else ""


def available() -> dict:
    """``{name: FileFormat}`` of the formats whose optional libraries are installed."""
    return {n: f for n, f in FORMATS.items() if f.available}


def read_head(path, n: int = HEAD_BYTES):
    """``(first n bytes, file size)`` of ``path``; an unreadable file is a FormatError."""
    try:
        with open(path, "rb") as fh:
            return fh.read(n), os.fstat(fh.fileno()).st_size
    except OSError as exc:
        raise FormatError(f"{path}: cannot read ({exc.strerror})") from None


def read_bytes(path) -> bytes:
    """The whole of the file ``path``; an unreadable file is a FormatError (one line)."""
    try:
        return Path(path).read_bytes()
    except OSError as exc:
        raise FormatError(f"{path}: cannot read ({exc.strerror})") from None


def format_for(path=None, format: str | None = None) -> FileFormat:
    """The format named ``format``, else the one registered for the extension of ``path``."""
    if format is not None:
        if not isinstance(format, str):
            raise BrdftabError(f"format must be a name such as {', '.join(map(repr, sorted(FORMATS)))}, got {format!r}")
        if format not in FORMATS:
            raise ParameterError("format", f"{FORMATS.message(format, usable())}{_recognised_note()}")
        return FORMATS[format]
    suffix = "".join(Path(path).suffixes[-1:]).lower()
    for fmt in FORMATS.values():
        if suffix in fmt.extensions:
            return fmt
    known = ", ".join(dict.fromkeys(e for n in usable() for e in FORMATS[n].extensions))
    raise BrdftabError(f"{path}: cannot tell the format from the extension {suffix!r} (known: {known})")


def is_store(path) -> bool:
    """True when ``path`` is a folder that a format stored as folders reads (a zarr store)."""
    path = Path(path)
    return path.is_dir() and any(f.store is not None and f.store(path) for f in FORMATS.values())


def detect(path) -> FileFormat:
    """Format of an existing file: by content (magic bytes, sniffers), then by extension; a
    folder by the formats stored as folders (:attr:`FileFormat.store`)."""
    path = Path(path)
    if path.is_dir():
        for fmt in FORMATS.values():
            if fmt.store is not None and fmt.store(path):
                return fmt
        stores = " or ".join(f.name for f in FORMATS.values() if f.store is not None)
        raise FormatError(f"{path}: is a folder, neither a table file nor a {stores} store")
    try:
        with open(path, "rb") as fh:
            head = fh.read(HEAD_BYTES)
            size = fh.seek(0, 2)
    except FileNotFoundError:
        raise BrdftabError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise BrdftabError(f"{path}: is a folder, not a file") from None
    except OSError as exc:
        raise BrdftabError(f"{path}: cannot read ({exc.strerror})") from None
    for fmt in FORMATS.values():
        if fmt.opens(head, size):
            return fmt
    try:
        return format_for(path)
    except BrdftabError:
        raise FormatError(f"{path}: not a file format brdftab reads (known: {', '.join(sorted(usable()))})") from None


def read(path):
    """Read a table from ``path`` (any registered format)."""
    fmt = detect(path)
    fmt.ensure_available()
    fmt.check_path(path)
    try:
        return fmt.read(Path(path))
    except BrdftabError as exc:
        if not str(exc).startswith(str(path)):
            exc.args = (f"{path}: {exc}",)  # same error type, now naming the file
        raise


def target_grid(fmt: FileFormat, requested, options: dict | None = None):
    """The grid ``fmt`` stores when asked for ``requested`` (None: the format's own, if any)."""
    if fmt.native_grid is None:
        return requested
    return fmt.native_grid(requested, dict(options or {}))


def _default_prepare(brdf, grid, **options):
    from ..table import Table, tabulate

    if isinstance(brdf, Table) and (grid is None or grid.equals(brdf.grid)):
        return brdf
    if grid is None:
        raise BrdftabError(f"a grid is needed to write {brdf.name!r} (pass grid=...)")
    polarized = isinstance(brdf, Table) and brdf.polarized
    if polarized and getattr(grid, "phi_d_fold", "none") != "none":
        warnings.warn(f"{brdf.describe()} holds a Mueller matrix; {grid.describe()} folds phi_d, so only f_r "
                      "(its M00) is written", BrdftabWarning, stacklevel=4)
        polarized = False
    return tabulate(brdf, grid, polarized=polarized)  # a polarized table resampled stays polarized


def prepare(fmt: FileFormat, brdf, grid, options: dict | None = None):
    """What ``fmt.write`` takes for ``brdf`` on ``grid`` (reusing a table already on it)."""
    return (fmt.prepare or _default_prepare)(brdf, grid, **dict(options or {}))


class NotStorable(FormatError):
    """What a format would store cannot be read back as a BRDF: ``count`` of ``total`` stored
    values are NaN or infinite (``detail`` says which and where). The checks report it as a
    ``finite`` failure of the output."""

    def __init__(self, detail: str, count: int, total: int):
        super().__init__(detail)
        self.detail, self.count, self.total = detail, int(count), int(total)


def stored(fmt: FileFormat, payload, options: dict | None = None):
    """The BRDF a reader of the file ``fmt`` writes from ``payload`` gets back: the values as
    stored, which is what the checks judge (``payload`` itself for a format that stores its
    samples exactly; None when the payload is not a BRDF and the format says nothing). A
    :class:`~brdftab.table.Table` returned is what :func:`write_prepared` should write (its
    samples equal what the file will hold). Raises :class:`NotStorable` when the stored values
    are not finite in a way no reader accepts."""
    from ..brdf import BRDF

    if fmt.stored is None:
        return payload if isinstance(payload, BRDF) else None
    return fmt.stored(payload, **dict(options or {}))


def averaged(brdf, n_phi_h: int = 0, symmetrize: bool = False):
    """``(source, provenance)`` a writer of an isotropic, reciprocal-folded format tabulates:
    ``brdf`` averaged over ``n_phi_h`` rotations about the normal (0: not) and/or over swapping
    wi and wo (``symmetrize``), with what it did recorded (``phi_h_averaged``,
    ``symmetrized``) beside a source table's spec provenance. An average of measured data is
    measured data (it keeps ``brdf``'s origin)."""
    from ..models.combinators import Average
    from ..table import Table

    source, provenance = brdf, {}
    if isinstance(brdf, Table):
        provenance.update({k: v for k, v in brdf.ds.attrs.items() if k in ("spec_sha256", "spec_file", "comment")})
    if n_phi_h:
        source = Average(term=source, rotations=n_phi_h)
        provenance["phi_h_averaged"] = n_phi_h
    if symmetrize:
        source = Average(term=source, swap=True)
        provenance["symmetrized"] = 1
    if source is not brdf:
        source.origin = getattr(brdf, "origin", "analytic")
    return source, provenance


def cast_samples(table, dtype):
    """``table`` with its samples as a file of storage type ``dtype`` holds them: rounded to
    ``dtype`` (values beyond its range become ±inf) and held in the table's own type. The table
    itself when the cast changes nothing; the same copy for repeated calls (outputs of one
    table in one storage type share their checks)."""
    from ..table import Table

    dtype = np.dtype(dtype)
    var = table.ds["brdf"]
    if np.can_cast(var.dtype, dtype, "safe"):
        return table
    cache = table.__dict__.setdefault("_stored_casts", {})
    if dtype.str in cache:
        return cache[dtype.str]
    v = np.asarray(table.values)
    with np.errstate(over="ignore", invalid="ignore"):
        back = v.astype(dtype).astype(v.dtype)
    out = table
    if not np.array_equal(back, v, equal_nan=True):
        ds = table.ds.copy(deep=False)
        ds["brdf"] = var.copy(data=back)
        if "mueller" in ds.data_vars:  # a polarized table's Mueller matrix is stored like its M00
            m = ds["mueller"]
            with np.errstate(over="ignore", invalid="ignore"):
                ds["mueller"] = m.copy(data=np.asarray(m.values).astype(dtype).astype(v.dtype))
        out = Table(ds)
        out.origin = table.origin
        out.stored_dtype = dtype.name  # the checks say the values are judged as stored
    cache[dtype.str] = out
    return out


def write(brdf, path, grid=None, *, format: str | None = None, overwrite: bool = False, **options):
    """Write ``brdf`` to ``path`` atomically; returns what was written (usually the table).

    ``grid`` None means the table's own grid (or the format's native grid); a grid may also
    be given by type name (``"merl"``) or as a ``[grid]`` table (a dict, angles in degrees).
    A table whose grid equals the target grid is copied, anything else is tabulated on it.
    """
    fmt = format_for(path, format)
    fmt.ensure_available()
    fmt.check_path(path)
    try:
        fmt.validate_options(options)
    except BrdftabError as exc:
        raise BrdftabError(f"{path}: {exc}") from None
    check_target(path, overwrite)
    from ..brdf import BRDF
    from ..grids import Grid, grid_from_config
    from ..table import Table

    if not isinstance(brdf, BRDF):
        raise BrdftabError(f"{path}: expected a BRDF (a model or a table) to write, got {type(brdf).__name__}")
    if isinstance(grid, str):
        grid = {"type": grid}
    if isinstance(grid, dict):
        with naming(path):
            grid = grid_from_config(grid)
    elif grid is not None and not isinstance(grid, Grid):
        raise BrdftabError(f"{path}: grid must be a Grid, a grid type such as 'merl' or a [grid] table (dict), "
                           f"got {type(grid).__name__}")

    requested = grid if grid is not None else (brdf.grid if isinstance(brdf, Table) else None)
    target = target_grid(fmt, requested, options)
    if grid is not None and (target is None or not (target.equals(grid) or getattr(target, "made_from", None) is grid)):
        stored = f"its own grid, {target.describe()}" if target is not None else "its own sampling"
        warnings.warn(f"{path}: the {fmt.name} format stores {stored}; the grid given ({grid.describe()}) is not used",
                      BrdftabWarning, stacklevel=3)
    with naming(path):
        payload = prepare(fmt, brdf, target, options)
    write_prepared(fmt, payload, path, overwrite=overwrite, options=options)
    return payload


@contextlib.contextmanager
def naming(path):
    """Errors raised inside the block name ``path`` (same error type)."""
    try:
        yield
    except BrdftabError as exc:
        if not str(exc).startswith(str(path)):
            exc.args = (f"{path}: {exc}",)
        raise


def write_prepared(fmt: FileFormat, payload, path, *, overwrite: bool = False, options: dict | None = None):
    """Write what :func:`prepare` returned to ``path`` atomically (no tabulation here)."""
    fmt.check_path(path)
    with atomic_path(path, overwrite=overwrite) as tmp:
        with held_signals(writing=Path(path).name):
            fmt.write(payload, tmp, **dict(options or {}))


#: Format modules shipped with brdftab (each registers itself on import). A module whose
#: optional library is missing must still import: it imports that library inside functions.
#: Content detection tries them in this order: pbsdf (a tensor file with Mueller fields)
#: before rgl (any other tensor file).
BUILTIN = ("netcdf", "zarr", "merl", "pbsdf", "rgl", "exr", "zemax", "lighttools", "mbsdf", "speos", "radiance",
           "astm", "csv")

for _name in BUILTIN:
    importlib.import_module(f"{__name__}.{_name}")
