"""Zemax / Radiant Imaging and LightTools ``.bsdf`` text files: recognised, not read (yet).

Three unrelated formats share the ``.bsdf`` extension (formats.md §2, §4): RGL's binary tensor
files (which brdftab reads, :mod:`brdftab.formats.rgl`), the ASCII "BSDF Data Interchange"
files of Zemax OpticStudio and Radiant Imaging, and LightTools' ASCII files. This module
tells the text dialects apart by their keywords, as libbsdf's ``classifyFile`` does
(``AngleOfIncidence`` → Zemax, ``AOI`` → LightTools), and refuses them with one line that
names the format, instead of "not a tensor file".

A Zemax file starts with ``#`` comment lines and the header keywords ``Source``,
``Symmetry``, ``SpectralContent``, ``ScatterType``, ``SampleRotation``, ``AngleOfIncidence``,
``ScatterAzimuth``, ``ScatterRadial``, then ``DataBegin`` … ``DataEnd``.
"""

from __future__ import annotations

from pathlib import Path

from ..errors import FormatError
from . import FileFormat, register

__all__ = ["sniff", "classify", "read_zemax"]

#: Header keywords of the Zemax / Radiant "BSDF Data Interchange" format and of LightTools files.
ZEMAX_KEYWORDS = ("Source", "Symmetry", "SpectralContent", "ScatterType", "SampleRotation", "AngleOfIncidence",
                  "ScatterAzimuth", "ScatterRadial", "DataBegin", "TIS", "Monochrome", "TristimulusX")
LIGHTTOOLS_KEYWORDS = ("AOI", "POI", "Side", "Wavelength", "TristimulusValue")
#: Bytes of a file read to classify it.
CLASSIFY_BYTES = 1 << 16


def _text(data: bytes) -> str | None:
    """``data`` as text, or None when it is binary (a NUL, or many control bytes)."""
    if b"\0" in data:
        return None
    text = data.removeprefix(b"\xef\xbb\xbf").decode("latin-1")  # a UTF-8 byte-order mark
    bad = sum(1 for c in text if ord(c) < 32 and c not in "\t\r\n\f\v")
    return None if bad > len(text) // 100 + 1 else text


def sniff(head: bytes, size: int) -> bool:
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


def read_zemax(path):
    """Refuse a Zemax / Radiant or LightTools text ``.bsdf`` file with one line naming it. A text
    file that is neither is read by the format its extension names (which says what is wrong)."""
    path = Path(path)
    try:
        with open(path, "rb") as fh:
            data = fh.read(CLASSIFY_BYTES)
    except OSError as exc:
        raise FormatError(f"{path}: cannot read ({exc.strerror})") from None
    dialect, header = classify(data)
    details = ", ".join(f"{k} {header[k]}" for k in ("ScatterType", "Symmetry", "SpectralContent") if header.get(k))
    details = f" ({details})" if details else ""
    if dialect == "zemax":
        raise FormatError(f"{path}: a Zemax/Radiant 'BSDF Data Interchange' text file{details}, not an RGL tensor "
                          ".bsdf file; brdftab does not read this format yet")
    if dialect == "lighttools":
        raise FormatError(f"{path}: a LightTools BSDF text file{details}, not an RGL tensor .bsdf file; brdftab "
                          "does not read this format yet")
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


def check_options(**options):
    raise FormatError("Zemax/Radiant and LightTools .bsdf text files can be recognised but not written; write an "
                      "RGL tensor .bsdf (format rgl) or a netCDF table instead")


register(FileFormat(
    name="zemax",
    extensions=(".bsdf",),
    description="Zemax/Radiant and LightTools .bsdf text files: recognised and refused (not read or written yet)",
    read=read_zemax,
    write=None,
    sniff=sniff,
    check_options=check_options,
    recognised_only=True,
))
