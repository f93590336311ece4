"""Zemax / Radiant Imaging "BSDF Data Interchange" text ``.bsdf`` files: read and write
(``formats/zemax.md``). LightTools text ``.bsdf`` files are read by :mod:`brdftab.formats.lighttools`.

Three unrelated formats share the ``.bsdf`` extension (formats.md §2, §4): RGL's binary tensor
files (:mod:`brdftab.formats.rgl`, which owns the extension when writing), the ASCII files of
Zemax OpticStudio and Radiant Imaging, and LightTools' ASCII files. A file is told apart by its
content: the text dialects by their keywords, as libbsdf's ``classifyFile`` does
(``AngleOfIncidence`` → Zemax, ``AOI`` → LightTools). Writing a Zemax file takes
``format = "zemax"``.

Layout::

    # comment lines
    Source  Measured
    Symmetry  PlaneSymmetrical | Asymmetrical
    SpectralContent  Monochrome | XYZ
    ScatterType  BRDF | BTDF
    SampleRotation  <n>  <n angles, deg>
    AngleOfIncidence  <n>  <n angles, deg>
    ScatterAzimuth  <n>  <n angles, deg>
    ScatterRadial  <n>  <n angles, deg>
    Monochrome | TristimulusX (… TristimulusY, TristimulusZ)
    DataBegin
    TIS <v>  then nAzimuth rows of nRadial values   (per sample rotation, per incidence)
    DataEnd

The values are f_r [1/sr] (not multiplied by cosθo). ScatterAzimuth and ScatterRadial are
angles about the mirror direction; the table's grid is
:class:`~brdftab.grids.SpecularPolarGrid` (its docstring states the mapping to directions),
which netCDF and zarr store as they are. The sample rotation is the incident azimuth φi.
TIS is the directional albedo at each block's incidence: the writer writes brdftab's
(:func:`brdftab.integrate.directional_albedo` of the values as written), the reader compares
the file's with the albedo of its data and warns on a mismatch.
"""

from __future__ import annotations

import math
import re
import warnings
from pathlib import Path

import numpy as np

from ..colorimetry import PARAMS as COLOUR_PARAMS
from ..errors import BrdftabWarning, FormatError, ParameterError
from ..params import Param, deg_list
from . import FileFormat, read_bytes, register

__all__ = ["sniff", "classify", "read_zemax", "write_zemax", "prepare_zemax", "parse_zemax", "tis_albedo",
           "DEFAULT_RADIALS_DEG", "TIS_TOLERANCE"]

#: Header keywords of the Zemax / Radiant "BSDF Data Interchange" format and of LightTools files.
ZEMAX_KEYWORDS = ("Source", "Symmetry", "SpectralContent", "ScatterType", "SampleRotation", "AngleOfIncidence",
                  "ScatterAzimuth", "ScatterRadial", "DataBegin", "TIS", "Monochrome", "TristimulusX")
LIGHTTOOLS_KEYWORDS = ("AOI", "POI", "Side", "Wavelength", "TristimulusValue")
#: Bytes of a file read to classify it.
CLASSIFY_BYTES = 1 << 16
#: Spellings of the Symmetry keyword's values (libbsdf's, and the 2008 specification's notes).
SYMMETRIES = {"PlaneSymmetrical": "plane", "Asymmetrical": "none", "ASymmetrical": "none",
              "Asymmetrical4D": "none", "ASymmetrical4D": "none"}
BLOCKS = {"Monochrome": ("Monochrome",), "XYZ": ("TristimulusX", "TristimulusY", "TristimulusZ")}
#: Significant digits of the values and TIS the writer writes (``%.6E``: 7 digits).
DIGITS = 7
#: Largest relative rounding of a written value: half a unit in the 7th significant digit.
PRECISION = 0.5 * 10.0 ** (1 - DIGITS)
#: A file's TIS and the albedo of its data differ "visibly" beyond this (relative, and 1e-3 absolute).
TIS_TOLERANCE = 0.05
DEFAULT_INCIDENCES_DEG = tuple(float(x) for x in range(0, 90, 5))
DEFAULT_AZIMUTHS_DEG = tuple(float(x) for x in range(0, 360, 5))
DEFAULT_RADIALS_DEG = tuple([float(x) for x in range(0, 10)] + [float(x) for x in range(10, 30, 2)]
                            + [float(x) for x in range(30, 181, 5)])


# --------------------------------------------------------------------------------------------
# Recognising


def _text(data: bytes) -> str | None:
    """``data`` as text, or None when it is binary (a NUL, or many control bytes)."""
    if b"\0" in data:
        return None
    text = data.removeprefix(b"\xef\xbb\xbf").decode("latin-1")  # a UTF-8 byte-order mark
    bad = sum(1 for c in text if ord(c) < 32 and c not in "\t\r\n\f\v")
    return None if bad > len(text) // 100 + 1 else text


def text_bsdf(head: bytes) -> bool:
    """True for text whose first token that is not a ``#`` comment is a Zemax or LightTools
    header keyword (a spec file, also text with ``#`` comments, starts otherwise)."""
    text = _text(head)
    if text is None:
        return False
    for line in text.splitlines():
        word = line.strip()
        if not word or word.startswith("#"):
            continue
        return word.split()[0] in ZEMAX_KEYWORDS + LIGHTTOOLS_KEYWORDS
    return False


def sniff(head: bytes, size: int) -> bool:
    """True for a Zemax text file, and for a text ``.bsdf`` file whose dialect its head does not
    settle (the reader classifies the whole start and hands a LightTools file to its reader)."""
    return text_bsdf(head) and classify(head)[0] != "lighttools"


def classify(data: bytes):
    """``(dialect, {keyword: value})`` of a text ``.bsdf`` file's start: dialect ``"zemax"``,
    ``"lighttools"`` or None (not one of them)."""
    text = _text(data)
    if text is None:
        return None, {}
    header = {}
    dialect = None
    for line in text.splitlines():
        words = line.split()
        if not words or words[0].startswith("#"):
            continue
        key = words[0]
        if key in ZEMAX_KEYWORDS + LIGHTTOOLS_KEYWORDS and key not in header:
            header[key] = " ".join(words[1:2])
        if key == "AngleOfIncidence":
            dialect = "zemax"
        elif key == "AOI" and dialect is None:
            dialect = "lighttools"
        if key == "DataBegin" and dialect is None and "Symmetry" in header and "ScatterRadial" in header:
            dialect = "lighttools" if "SampleRotation" not in header else "zemax"
    if dialect is None and header.get("Symmetry") and ("ScatterType" in header or "SpectralContent" in header):
        dialect = "zemax"
    return dialect, header


# --------------------------------------------------------------------------------------------
# Reading

_NUMBER = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$")


class _Tokens:
    """The file's whitespace-separated tokens with their line numbers (``#`` lines skipped)."""

    def __init__(self, path, text: str):
        self.path = path
        self.items = []
        for n, line in enumerate(text.splitlines(), 1):
            if line.lstrip().startswith("#"):
                continue
            self.items.extend((w, n) for w in line.split())
        self.k = 0
        self.last_line = text.count("\n") + 1

    def error(self, msg, line=None):
        if line is None:
            line = self.items[self.k][1] if self.k < len(self.items) else self.last_line
        return FormatError(f"{self.path}: line {line}: {msg}")

    def peek(self):
        return self.items[self.k][0] if self.k < len(self.items) else None

    def take(self, what):
        if self.k >= len(self.items):
            raise self.error(f"the file ends where {what} should be (truncated?)")
        tok = self.items[self.k]
        self.k += 1
        return tok

    def number(self, what):
        tok, line = self.take(what)
        if not _NUMBER.match(tok):
            raise self.error(f"expected {what}, got {tok!r}", line)
        if not math.isfinite(float(tok)):
            raise self.error(f"{what}: {tok!r} is beyond the range of a float64", line)
        return float(tok)

    def count(self, key):
        tok, line = self.take(f"the number of {key} values")
        if not re.fullmatch(r"\+?\d+", tok):
            raise self.error(f"{key}: expected a count (a whole number >= 1), got {tok!r}", line)
        n = int(tok)
        if n < 1:
            raise self.error(f"{key}: a count of {n}; at least one angle is needed", line)
        return n

    def numbers(self, n, what):
        """``n`` numbers (fast path: a slice converted at once)."""
        chunk = self.items[self.k:self.k + n]
        if len(chunk) < n:
            self.k += len(chunk)
            raise self.error(f"the file ends after {len(chunk)} of {n} {what} (truncated?)")
        try:
            vals = np.array([float(t) for t, _ in chunk])
        except ValueError:
            vals = None
        if vals is None or not all(_NUMBER.match(t) for t, _ in chunk):
            bad = next((t, ln) for t, ln in chunk if not _NUMBER.match(t))
            raise self.error(f"expected {what}, got {bad[0]!r}", bad[1])
        if not np.all(np.isfinite(vals)):
            t, ln = chunk[int(np.flatnonzero(~np.isfinite(vals))[0])]
            raise self.error(f"{what}: {t!r} is beyond the range of a float64", ln)
        self.k += n
        return vals


def parse_zemax(path, text: str) -> dict:
    """The content of a Zemax file as ``{keyword: value, "angles": {...}, "data": [C, rot, aoi,
    az, rad], "tis": [C, rot, aoi]}``; a :class:`FormatError` naming the file and line for
    anything missing, miscounted, not a number or cut short."""
    tok = _Tokens(path, text)
    head = {}
    angles = {}
    keys = {"SampleRotation": "phi_i", "AngleOfIncidence": "theta_i", "ScatterAzimuth": "spec_azimuth",
            "ScatterRadial": "spec_radial"}
    while True:
        word = tok.peek()
        if word is None:
            raise tok.error("the file ends before its data (no DataBegin)")
        if word in ("Monochrome", "TristimulusX", "TristimulusY", "TristimulusZ", "DataBegin"):
            break
        _, line = tok.take("a keyword")
        if word in ("Source", "Symmetry", "SpectralContent", "ScatterType"):
            value, vline = tok.take(f"the value of {word}")
            if value in ("Source", "Symmetry", "SpectralContent", "ScatterType", "DataBegin") or value in keys:
                raise tok.error(f"{word} has no value", line)
            head[word] = (value, vline)
        elif word in keys:
            if word in angles:
                raise tok.error(f"{word} given twice", line)
            n = tok.count(word)
            vals = tok.numbers(n, f"{word} angles (degrees)")
            if np.any(np.diff(vals) <= 0):
                raise tok.error(f"{word} angles must increase strictly", line)
            angles[word] = (vals, line)
        else:
            raise tok.error(f"unknown keyword {word!r} in the header (expected Source, Symmetry, SpectralContent, "
                            "ScatterType, SampleRotation, AngleOfIncidence, ScatterAzimuth, ScatterRadial)", line)
    for key in ("Symmetry", "SpectralContent", "ScatterType"):
        if key not in head:
            raise tok.error(f"missing keyword {key} before the data")
    for key in ("AngleOfIncidence", "ScatterAzimuth", "ScatterRadial"):
        if key not in angles:
            raise tok.error(f"missing keyword {key} before the data")
    sym, line = head["Symmetry"]
    if sym not in SYMMETRIES:
        raise tok.error(f"Symmetry {sym!r}: expected PlaneSymmetrical or Asymmetrical", line)
    content, line = head["SpectralContent"]
    if content not in BLOCKS:
        raise tok.error(f"SpectralContent {content!r}: expected Monochrome or XYZ (a spectral Zemax file is not "
                        "supported)", line)
    scatter, line = head["ScatterType"]
    if scatter == "BTDF":
        raise FormatError(f"{path}: a Zemax BTDF (transmission) file; brdftab holds reflection (BRDF) only")
    if scatter != "BRDF":
        raise tok.error(f"ScatterType {scatter!r}: expected BRDF or BTDF", line)
    rot = angles.get("SampleRotation", (np.zeros(1), None))[0]
    aoi, line = angles["AngleOfIncidence"]
    if aoi[0] < 0 or aoi[-1] > 90:
        raise tok.error("AngleOfIncidence angles must lie in [0, 90] degrees", line)
    az, line = angles["ScatterAzimuth"]
    fold = SYMMETRIES[sym]
    hi = 180.0 if fold == "plane" else 360.0
    if az[0] < 0 or az[-1] > hi:
        raise tok.error(f"ScatterAzimuth angles must lie in [0, {hi:g}] degrees"
                        + (" in a PlaneSymmetrical file" if fold == "plane" else ""), line)
    rad, line = angles["ScatterRadial"]
    if rad[0] < 0 or rad[-1] > 180:
        raise tok.error("ScatterRadial angles must lie in [0, 180] degrees", line)
    if rot[0] < -360 or rot[-1] > 360:
        raise tok.error("SampleRotation angles must lie in [-360, 360] degrees", angles["SampleRotation"][1])

    names = BLOCKS[content]
    shape = (rot.size, aoi.size, az.size, rad.size)
    per = az.size * rad.size
    data = np.empty((len(names),) + shape)
    tis = np.empty((len(names), rot.size, aoi.size))
    for c, name in enumerate(names):
        word, line = tok.take(f"the {name} block")
        if len(names) == 1 and word == "DataBegin":
            tok.k -= 1  # libbsdf accepts Monochrome data without its label
        elif word != name:
            raise tok.error(f"expected {name} before its data, got {word!r}", line)
        word, line = tok.take("DataBegin")
        if word != "DataBegin":
            raise tok.error(f"expected DataBegin, got {word!r}", line)
        for j in range(rot.size):
            for i in range(aoi.size):
                word, line = tok.take(f"TIS (block {j * aoi.size + i + 1} of {rot.size * aoi.size} of {name})")
                if word != "TIS":
                    raise tok.error(f"expected TIS starting block {j * aoi.size + i + 1} of {rot.size * aoi.size} "
                                    f"of {name} ({az.size} x {rad.size} values each), got {word!r}", line)
                tis[c, j, i] = tok.number("the TIS value")
                data[c, j, i] = tok.numbers(per, f"BSDF values (block {j * aoi.size + i + 1}: {az.size} azimuths x "
                                                 f"{rad.size} radial angles)").reshape(az.size, rad.size)
        word, line = tok.take("DataEnd")
        if word != "DataEnd":
            raise tok.error(f"expected DataEnd after {rot.size * aoi.size} blocks of {az.size} x {rad.size} values, "
                            f"got {word!r} (more values than the header counts?)", line)
    if tok.peek() is not None:
        raise tok.error(f"unexpected {tok.peek()!r} after DataEnd")
    return {"source": head.get("Source", (None,))[0], "symmetry": sym, "fold": fold, "content": content,
            "rotation": rot, "aoi": aoi, "azimuth": az, "radial": rad, "data": data, "tis": tis,
            "channels": ("mono",) if content == "Monochrome" else ("X", "Y", "Z")}


def read_zemax(path):
    """Read a Zemax / Radiant text ``.bsdf`` file into a :class:`~brdftab.table.Table` on its own
    :class:`~brdftab.grids.SpecularPolarGrid`; a LightTools file goes to its own reader. A text
    file that is neither is read by the format its extension names (which says what is wrong)."""
    path = Path(path)
    raw = read_bytes(path)
    dialect, header = classify(raw[:CLASSIFY_BYTES])
    if dialect == "lighttools":
        from .lighttools import read_lighttools

        return read_lighttools(path)
    if dialect != "zemax":
        from . import FORMATS, format_for, usable

        try:
            fmt = format_for(path)
        except Exception:  # noqa: BLE001 - no format for the extension: say what the file is
            fmt = None
        if fmt is None or fmt is FORMATS.get("zemax", None):
            raise FormatError(f"{path}: a text file, not a table format brdftab reads (known: "
                              f"{', '.join(sorted(usable()))})")
        fmt.ensure_available()
        return fmt.read(path)
    text = _text(raw)
    if text is None:
        raise FormatError(f"{path}: a Zemax .bsdf file with binary bytes in it (damaged)")
    content = parse_zemax(path, text)
    table = _table(content, path.name)
    _compare_tis(table, content, path)
    return table


def _table(content: dict, name: str):
    from ..channels import Layout
    from ..grids import SpecularPolarGrid
    from ..table import Table, make_table

    grid = SpecularPolarGrid(np.radians(content["aoi"]), np.radians(content["rotation"]),
                             np.radians(content["azimuth"]), np.radians(content["radial"]),
                             azimuth_fold=content["fold"])
    # file order [C, rotation, AOI, az, radial] -> grid order [θi, φi, az, radial, C]
    values = np.ascontiguousarray(np.moveaxis(content["data"], (0, 1, 2), (4, 1, 0)))
    measured = content["source"] == "Measured"
    provenance = {
        "title": f"Zemax BSDF {name}",
        "model": "unknown",
        "parameters": "{}",
        "isotropic": int(content["rotation"].size == 1),
        "source_file": name,
        "source_format": "zemax",
        "zemax_symmetry": content["symmetry"],
        "zemax_spectral_content": content["content"],
        "zemax_source": content["source"] or "",
        "zemax_quantity": "the file holds f_r [1/sr] (BSDF, not multiplied by cos(theta_o)); stored as read",
    }
    table = make_table(values, grid, Layout(content["channels"]), provenance=provenance)
    ds = table.ds
    ds.attrs["origin"] = "measured" if measured else "unknown"
    # the file does not say whether its data are reciprocal: the checks judge them as data
    for key in ("created", "brdftab_version", "history", "source", "reciprocal"):
        ds.attrs.pop(key, None)
    ds["zemax_tis"] = (("theta_i", "phi_i", table.ds["brdf"].dims[-1]),
                       np.moveaxis(content["tis"], (0, 1), (2, 1)),
                       {"long_name": "TIS written in the Zemax file per incidence (total integrated scatter)"})
    out = Table(ds)
    out.origin = ds.attrs["origin"]
    return out


def tis_albedo(table, coverage: bool = False):
    """brdftab's directional albedo of ``table`` at each of its grid's incidences ``[θi, φi, C]``
    (the TIS the writer writes): directions outside the table's domain hold no data and count
    as 0. ``coverage``: also the fraction of the projected hemisphere the data cover."""
    from ..integrate import directional_albedo

    g = table.grid
    ti, pi_ = np.meshgrid(g.axes[0].values, g.axes[1].values, indexing="ij")
    old = table.outside
    try:
        table.outside = "nan"
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", BrdftabWarning)
            a = directional_albedo(table, ti, pi_, coverage=coverage)
    finally:
        table.outside = old
    return a


def _compare_tis(table, content, path) -> None:
    compare_tis(table, np.moveaxis(content["tis"], (0, 1), (2, 1)), content["channels"], path, "zemax",
                ("incidence", content["aoi"]), ("rotation", content["rotation"]))


def compare_tis(table, tis, channels, path, prefix, incidence, azimuth) -> None:
    """One warning when a file's TIS ``[θi, φi, C]`` and the albedo of its data differ by more
    than :data:`TIS_TOLERANCE` (relative) and 1e-3: the worst block, both figures, and how many.
    ``incidence``/``azimuth``: ``(label, file angles in degrees)`` of the axes for the message;
    the largest difference is recorded in the attribute ``{prefix}_tis_vs_albedo``."""
    albedo, cover = tis_albedo(table, coverage=True)
    diff = np.abs(tis - albedo)
    bad = (diff > TIS_TOLERANCE * np.maximum(np.abs(albedo), np.abs(tis))) & (diff > 1e-3)
    table.ds.attrs[f"{prefix}_tis_vs_albedo"] = (f"largest |TIS - albedo| {float(diff.max()):.4g} (TIS of the file "
                                                 "vs brdftab's directional albedo of its data)")
    if not bad.any():
        return
    i, j, c = np.unravel_index(int(np.argmax(np.where(bad, diff, -1))), bad.shape)
    chan = "" if len(channels) == 1 else f" {channels[c]}"
    warnings.warn(f"{path}: TIS{chan} {tis[i, j, c]:.6g} in the file at {incidence[0]} {incidence[1][i]:g} deg, "
                  f"{azimuth[0]} {azimuth[1][j]:g} deg, but the directional albedo of its data is "
                  f"{albedo[i, j, c]:.6g} (its data cover {cover[i, j, c]:.1%} of the projected hemisphere there; "
                  f"{int(bad.sum())} of {bad.size} "
                  f"blocks differ by more than {TIS_TOLERANCE:.0%})",
                  BrdftabWarning, stacklevel=5)


# --------------------------------------------------------------------------------------------
# Writing

_SYMMETRY_CHOICES = ("Asymmetrical", "PlaneSymmetrical")
_CONTENT_CHOICES = ("auto", "Monochrome", "XYZ")


def check_options(symmetry="Asymmetrical", spectral_content="auto", incidences_deg=None, sample_rotations_deg=None,
                  azimuths_deg=None, radials_deg=None, illuminant="D65", observer="cie1931-2", wavelengths_nm=None):
    """The writer's options checked (one :class:`ParameterError` naming the option)."""
    if symmetry not in _SYMMETRY_CHOICES:
        raise ParameterError("symmetry", f"expected 'Asymmetrical' or 'PlaneSymmetrical', got {symmetry!r}")
    if spectral_content not in _CONTENT_CHOICES:
        raise ParameterError("spectral_content", f"expected 'auto', 'Monochrome' or 'XYZ', got {spectral_content!r}")
    deg_list("incidences_deg", incidences_deg, 0, 90)
    deg_list("sample_rotations_deg", sample_rotations_deg, -360, 360)
    deg_list("azimuths_deg", azimuths_deg, 0, 180 if symmetry == "PlaneSymmetrical" else 360)
    deg_list("radials_deg", radials_deg, 0, 180)
    if (illuminant, observer) != ("D65", "cie1931-2"):
        from ..colorimetry import from_options

        from_options(illuminant, observer)


def native_grid(requested, options: dict):
    """The specular-polar grid of the writer's options (or a requested one of that type)."""
    from ..grids import SpecularPolarGrid

    if isinstance(requested, SpecularPolarGrid) and not any(
            k in options for k in ("incidences_deg", "sample_rotations_deg", "azimuths_deg", "radials_deg",
                                   "symmetry")):
        return requested
    return _grid(options, anisotropic=False)


def _grid(options, anisotropic):
    from ..grids import SpecularPolarGrid

    plane = options.get("symmetry", "Asymmetrical") == "PlaneSymmetrical"
    inc = deg_list("incidences_deg", options.get("incidences_deg"), 0, 90)
    rot = deg_list("sample_rotations_deg", options.get("sample_rotations_deg"), -360, 360)
    az = deg_list("azimuths_deg", options.get("azimuths_deg"), 0, 180 if plane else 360)
    rad = deg_list("radials_deg", options.get("radials_deg"), 0, 180)
    if inc is None:
        inc = np.array(DEFAULT_INCIDENCES_DEG)
    if rot is None:
        rot = np.arange(0.0, 360.0, 30.0) if anisotropic else np.zeros(1)
    if az is None:
        az = np.arange(0.0, 181.0, 5.0) if plane else np.array(DEFAULT_AZIMUTHS_DEG)
    if rad is None:
        rad = np.array(DEFAULT_RADIALS_DEG)
    return SpecularPolarGrid(np.radians(inc), np.radians(rot), np.radians(az), np.radians(rad),
                             azimuth_fold="plane" if plane else "none")


def prepare_zemax(brdf, grid, symmetry="Asymmetrical", spectral_content="auto", incidences_deg=None,
                  sample_rotations_deg=None, azimuths_deg=None, radials_deg=None, illuminant="D65",
                  observer="cie1931-2", wavelengths_nm=None):
    """The table (on a :class:`~brdftab.grids.SpecularPolarGrid`) that :func:`write_zemax` writes.

    Channels: a grey source is written ``Monochrome``; RGB (linear sRGB) and spectral sources
    ``XYZ``, through colour-science (RGB by ``colour.RGB_to_XYZ``, spectra by
    :mod:`brdftab.colorimetry` with ``illuminant``/``observer``); ``spectral_content =
    "Monochrome"`` of a colour source writes its Y. An anisotropic source needs several sample
    rotations (default every 30°)."""
    from ..grids import SpecularPolarGrid
    from ..table import Table, tabulate, warn_specular_dropped

    options = dict(symmetry=symmetry, spectral_content=spectral_content, incidences_deg=incidences_deg,
                   sample_rotations_deg=sample_rotations_deg, azimuths_deg=azimuths_deg, radials_deg=radials_deg)
    check_options(**options, illuminant=illuminant, observer=observer)
    warn_specular_dropped(brdf, "a Zemax .bsdf file")
    explicit = any(v is not None for k, v in options.items() if k.endswith("_deg")) or symmetry != "Asymmetrical"
    if isinstance(grid, SpecularPolarGrid) and not explicit:
        target = grid
    else:
        target = _grid({k: v for k, v in options.items() if v is not None}, anisotropic=not brdf.isotropic)
    if not brdf.isotropic and len(target.axes[1]) == 1:
        raise FormatError(f"'{brdf.name}' is anisotropic and one sample rotation would describe it at one incident "
                          "azimuth only; give sample_rotations_deg (e.g. every 30 degrees)")
    source, _ = monochrome_or_xyz(brdf, spectral_content, illuminant, observer, wavelengths_nm, "a Zemax file")
    if isinstance(source, Table) and source.grid.equals(target):
        return source
    return tabulate(source, target)


def monochrome_or_xyz(brdf, spectral_content="auto", illuminant="D65", observer="cie1931-2", wavelengths_nm=None,
                      what="a Zemax file"):
    """``(source, content)``: ``brdf`` as the one (``Monochrome``) or three (``XYZ``) channels a
    Zemax or LightTools file holds. ``auto``: Monochrome for a grey source, XYZ for RGB (linear
    sRGB, by ``colour.RGB_to_XYZ``) and spectral ones (by :mod:`brdftab.colorimetry` with
    ``illuminant``/``observer``); Monochrome of a colour source is its Y."""
    from ..colorimetry import XYZView, from_options, to_colour

    content = spectral_content
    if content == "auto":
        content = "Monochrome" if (not brdf.spectral and brdf.channels == ("mono",)) else "XYZ"
    source = brdf
    if brdf.spectral:
        source = to_colour(brdf, from_options(illuminant, observer, "XYZ"), wavelengths_nm)
        if content == "Monochrome":
            source = _Y(source)
    elif brdf.channels in (("R", "G", "B"), ("mono",)):
        if not (content == "Monochrome" and brdf.channels == ("mono",)):
            source = XYZView(brdf, luminance_only=content == "Monochrome")
    elif brdf.channels != ("X", "Y", "Z"):
        raise FormatError(f"{what} stores Monochrome or XYZ data; '{brdf.name}' has channels "
                          f"{', '.join(brdf.channels)}")
    elif content == "Monochrome":
        source = _Y(source)
    return source, content


def _Y(base):
    """The Y channel of an XYZ BRDF, as a grey BRDF (a Monochrome file of a colour source)."""
    from ..brdf import BRDF
    from ..channels import Layout

    class LuminanceY(BRDF):
        layout = Layout(("mono",))

        def __init__(self):
            self.name, self.base = base.name, base
            self.isotropic, self.reciprocal, self.origin = base.isotropic, base.reciprocal, base.origin

        @property
        def parameters(self):
            return dict(getattr(base, "parameters", {}))

        def _eval(self, wi, wo, lam, n):
            return np.asarray(base.eval(wi, wo, assume_unit=True), float)[..., 1:2]

    return LuminanceY()


def rounded(table, what="a Zemax file"):
    """``table`` with its values as a text file of :data:`DIGITS` significant digits holds them;
    NaN (no data) as 0 with one warning (the text formats have no missing marker)."""
    from ..table import Table

    v = np.asarray(table.values, float)
    nan = ~np.isfinite(v)
    if nan.any():
        warnings.warn(f"{int(nan.sum())} of {v.size} samples hold no data (NaN or infinite); {what} has no "
                      "missing marker: written as 0", BrdftabWarning, stacklevel=4)
    text = np.char.mod(f"%.{DIGITS - 1}E", np.where(nan, 0.0, v))
    back = text.astype(float)
    if np.array_equal(back, v):
        return table
    ds = table.ds.copy(deep=False)
    ds["brdf"] = ds["brdf"].copy(data=back)
    out = Table(ds)
    out.origin = table.origin
    return out


def _stored(payload, **_):
    return rounded(payload)


def write_zemax(table, path, symmetry="Asymmetrical", spectral_content="auto", incidences_deg=None,
                sample_rotations_deg=None, azimuths_deg=None, radials_deg=None, illuminant="D65",
                observer="cie1931-2", wavelengths_nm=None):
    """Write ``table`` (from :func:`prepare_zemax`) as a Zemax text file; TIS per block is
    brdftab's directional albedo of the values as written."""
    from ..grids import SpecularPolarGrid

    grid = table.grid
    if not isinstance(grid, SpecularPolarGrid):
        raise FormatError(f"a Zemax file needs a table on a specular-polar grid, not on {grid.describe()}")
    if table.channels not in (("mono",), ("X", "Y", "Z")):
        raise FormatError(f"a Zemax file stores Monochrome or X, Y, Z channels, not {table.channels}")
    table = rounded(table)
    tis = tis_albedo(table)  # [θi, φi, C]
    ti, pi_, az, rad = (np.degrees(a.values) for a in grid.axes)
    values = np.asarray(table.values, float)
    names = BLOCKS["Monochrome" if table.channels == ("mono",) else "XYZ"]
    fmt = f"%.{DIGITS - 1}E"

    def angles(vals):
        return "\t".join(f"{x:.10g}" for x in vals)

    lines = [f"# Written by brdftab from {table.name}: BRDF f_r [1/sr]; TIS = brdftab's directional albedo",
             "# angles: radial and azimuth about the mirror direction, azimuth 0 towards the normal (formats/zemax.md)"]
    if getattr(table, "origin", "unknown") == "measured":
        lines.append("Source  Measured")
    lines += [f"Symmetry  {'PlaneSymmetrical' if grid.azimuth_fold == 'plane' else 'Asymmetrical'}",
              f"SpectralContent  {'Monochrome' if len(names) == 1 else 'XYZ'}",
              "ScatterType  BRDF",
              f"SampleRotation  {pi_.size}", angles(pi_),
              f"AngleOfIncidence  {ti.size}", angles(ti),
              f"ScatterAzimuth  {az.size}", angles(az),
              f"ScatterRadial  {rad.size}", angles(rad), ""]
    with open(path, "w", encoding="ascii", newline="\n") as fh:
        fh.write("\n".join(lines) + "\n")
        for c, name in enumerate(names):
            fh.write(f"{name}\nDataBegin\n")
            for j in range(pi_.size):
                for i in range(ti.size):
                    fh.write(f"TIS {tis[i, j, c]:.{DIGITS - 1}E}\n")
                    block = values[i, j, :, :, c]
                    rows = np.char.mod(fmt, block)
                    fh.write("\n".join("\t".join(r) for r in rows) + "\n")
            fh.write("DataEnd\n")


register(FileFormat(
    name="zemax",
    extensions=(".bsdf",),
    description="Zemax/Radiant 'BSDF Data Interchange' text .bsdf: BRDF f_r [1/sr] on radial/azimuth angles about "
                "the mirror direction, Monochrome or XYZ, PlaneSymmetrical or Asymmetrical, TIS = directional "
                "albedo per incidence (read and write; .bsdf writes RGL unless format = 'zemax')",
    read=read_zemax,
    write=write_zemax,
    sniff=sniff,
    native_grid=native_grid,
    prepare=prepare_zemax,
    check_options=check_options,
    stored=_stored,
    colour=True,
    params=(
        Param("symmetry", "choice", "Asymmetrical (azimuths 0..360 deg) or PlaneSymmetrical (0..180 deg, mirrored "
              "across the plane of incidence).", default="Asymmetrical", choices=_SYMMETRY_CHOICES),
        Param("spectral_content", "choice", "Monochrome or XYZ (auto: Monochrome for a grey source, XYZ for RGB "
              "and spectral ones, through colour-science).", default="auto", choices=_CONTENT_CHOICES),
        Param("incidences_deg", "floats", "Angles of incidence in degrees (default 0 to 85 every 5).", default=None,
              minimum=0.0, maximum=90.0),
        Param("sample_rotations_deg", "floats", "Sample rotations = incident azimuths in degrees (default [0]; "
              "anisotropic sources every 30).", default=None, minimum=-360.0, maximum=360.0),
        Param("azimuths_deg", "floats", "Scatter azimuths about the mirror direction in degrees (default every 5: "
              "0..355, or 0..180 PlaneSymmetrical).", default=None, minimum=0.0, maximum=360.0),
        Param("radials_deg", "floats", "Scatter radial angles from the mirror direction in degrees (default 0..9 by "
              "1, 10..28 by 2, 30..180 by 5).", default=None, minimum=0.0, maximum=180.0),
    ) + COLOUR_PARAMS,
    precision=PRECISION,
))
