"""Exceptions brdftab raises for bad input.

Every error a user can cause by what they pass (a spec file, a table file, a CLI option,
a parameter value) is a :class:`BrdftabError`. The CLI prints its message as one line on
stderr and exits with code 2; the Python API lets it propagate.
"""

from __future__ import annotations

import os

#: What a run that ran out of memory says (one line, exit code 2).
OUT_OF_MEMORY = ("out of memory: the run needs more than this machine has (a coarser grid, fewer channels, "
                 "sweep members or fit starts need less)")


class BrdftabError(Exception):
    """Bad input: a user-facing message, one line, no traceback needed."""

    exit_code = 2


class ParameterError(BrdftabError, ValueError):
    """A model parameter is missing, unknown, mistyped or out of range.

    ``key`` names the parameter (a dotted path once the spec loader adds context) and
    ``expected`` says what would have been accepted.
    """

    def __init__(self, key: str, message: str):
        self.key = key
        self.detail = message
        super().__init__(f"{key}: {message}" if key else message)


class SpecError(BrdftabError):
    """A spec file is unreadable or does not follow the schema."""


class FormatError(BrdftabError):
    """A table file cannot be read or written in the requested format."""


class ValidationError(BrdftabError):
    """A BRDF failed a check that export requires (exit code 1: the input was readable, the
    data is not acceptable)."""

    exit_code = 1


class BrdftabWarning(UserWarning):
    """Something a user should know that does not stop the work (e.g. queries outside a
    table's domain evaluated to NaN)."""


def shown(text) -> str:
    """``text`` (a str or a path) as valid UTF-8 text: bytes of a file name that are not UTF-8,
    which Python keeps as lone surrogates, become ``\\xNN`` escapes (``g\\xff.binary``), so the
    name can go into file metadata, reports and messages."""
    text = os.fsdecode(text) if not isinstance(text, str) else text
    try:
        return text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")
    except UnicodeEncodeError:  # a lone surrogate that was never a byte
        return text.encode("utf-8", "backslashreplace").decode("utf-8")


#: Characters shown escaped: they would move the cursor, recolour the terminal or reorder the
#: text around them (bidirectional controls) instead of being seen.
_BIDI = frozenset("\u061c\u200e\u200f\u202a\u202b\u202c\u202d\u202e\u2066\u2067\u2068\u2069")


def printable(text: str) -> str:
    """``text`` with control, format (e.g. bidirectional) and separator characters escaped as
    ``\\xNN`` / ``\\uNNNN``, so that what a file stores is shown, not acted on by the terminal."""
    import unicodedata

    out = []
    for ch in str(text):
        if ch in _BIDI or (ch != " " and unicodedata.category(ch) in ("Cc", "Cf", "Zl", "Zp", "Cs")):
            code = ord(ch)
            out.append(f"\\x{code:02x}" if code < 0x100 else f"\\u{code:04x}" if code < 0x10000 else f"\\U{code:08x}")
        else:
            out.append(ch)
    return "".join(out)
