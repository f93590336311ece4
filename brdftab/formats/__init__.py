"""File formats: a registry of readers and writers, by name, extension and magic bytes.

Each format module registers a :class:`FileFormat`. The rest of brdftab reads and writes
only through :func:`read` and :func:`write`; it never imports a format module directly.

Writing is "tabulate if needed, then write atomically": a :class:`~brdftab.table.Table`
whose grid equals the target grid is written as it is (values copied, not resampled); any
other BRDF is sampled on the target grid first.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from .._atomic import atomic_path, check_target, deferred_signals
from ..errors import BrdftabError, FormatError
from ..params import suggest

__all__ = ["FileFormat", "FORMATS", "register", "detect", "read", "write", "format_for"]


@dataclass(frozen=True)
class FileFormat:
    """A file format: how to recognise it, read it into a table and write a table to it.

    ``write(table, path, **options)`` writes to ``path`` (a temporary the registry renames);
    ``prepare(brdf, grid)`` returns the table to write, tabulating when needed (the default
    needs a grid for anything that is not already a table).
    """

    name: str
    extensions: tuple
    description: str
    read: Callable
    write: Callable
    magic: tuple = ()
    options: dict = field(default_factory=dict)
    prepare: Callable | None = None
    check_options: Callable | None = None

    def validate_options(self, options: dict) -> None:
        """Raise :class:`~brdftab.errors.ParameterError` naming a bad option or value."""
        from ..errors import ParameterError

        for key in options:
            if key not in self.options:
                raise ParameterError(key, f"unknown option for format {self.name}{suggest(key, self.options)}; "
                                     f"valid: {', '.join(self.options) or 'none'}")
        if self.check_options is not None:
            self.check_options(**options)


#: Registered formats by name.
FORMATS: dict = {}


def register(fmt: FileFormat) -> FileFormat:
    FORMATS[fmt.name] = fmt
    return fmt


def format_for(path=None, format: str | None = None) -> FileFormat:
    """The format named ``format``, else the one registered for the extension of ``path``."""
    if format is not None:
        if not isinstance(format, str):
            raise BrdftabError(f"format must be a name such as {', '.join(map(repr, sorted(FORMATS)))}, got {format!r}")
        if format not in FORMATS:
            raise BrdftabError(f"unknown format {format!r}{suggest(format, FORMATS)}; known formats: "
                               f"{', '.join(sorted(FORMATS))}")
        return FORMATS[format]
    suffix = "".join(Path(path).suffixes[-1:]).lower()
    for fmt in FORMATS.values():
        if suffix in fmt.extensions:
            return fmt
    known = ", ".join(e for f in FORMATS.values() for e in f.extensions)
    raise BrdftabError(f"{path}: cannot tell the format from the extension {suffix!r} (known: {known})")


def detect(path) -> FileFormat:
    """Format of an existing file: by magic bytes, then by extension."""
    path = Path(path)
    try:
        with open(path, "rb") as fh:
            head = fh.read(16)
    except FileNotFoundError:
        raise BrdftabError(f"{path}: no such file") from None
    except OSError as exc:
        raise BrdftabError(f"{path}: cannot read ({exc.strerror})") from None
    for fmt in FORMATS.values():
        if any(head.startswith(m) for m in fmt.magic):
            return fmt
    return format_for(path)


def read(path):
    """Read a table from ``path`` (any registered format)."""
    fmt = detect(path)
    try:
        return fmt.read(Path(path))
    except BrdftabError as exc:
        msg = str(exc)
        raise FormatError(msg if msg.startswith(str(path)) else f"{path}: {msg}") from None


def _default_prepare(brdf, grid):
    from ..table import Table, tabulate

    if isinstance(brdf, Table) and (grid is None or grid.equals(brdf.grid)):
        return brdf
    if grid is None:
        raise BrdftabError(f"a grid is needed to write {brdf.name!r} (pass grid=...)")
    return tabulate(brdf, grid)


def write(brdf, path, grid=None, *, format: str | None = None, overwrite: bool = True, **options):
    """Write ``brdf`` to ``path`` atomically; returns the table written."""
    fmt = format_for(path, format)
    try:
        fmt.validate_options(options)
    except BrdftabError as exc:
        raise BrdftabError(f"{path}: {exc}") from None
    check_target(path, overwrite)
    table = (fmt.prepare or _default_prepare)(brdf, grid)
    with atomic_path(path, overwrite=overwrite) as tmp:
        with deferred_signals():
            fmt.write(table, tmp, **options)
    return table


# Built-in formats register themselves on import.
from . import netcdf  # noqa: E402,F401
