"""Ansys Speos BSDF tables, text variants: ``*.anisotropicbsdf`` ("Anisotropic BSDF surface",
format ``speos``) and ``*.brdf`` ("Complete scattering surface", format ``speos-brdf``); read
and write (``formats/speos.md``).

``*.anisotropicbsdf`` (one line each)::

    OPTIS - Anisotropic BSDF surface file v8.0
    0                                  text (1: binary, not read)
    comment
    N                                  characters of the description (which may span lines)
    description
    ax ay az                           anisotropy vector (global coordinates)
    bReflection bTransmission
    1                                  values proportional to the BSDF (0: to the intensity)
    per side present (reflection first):
        nRotations / rotations (deg) / per rotation: nIncidences / incidences (deg)
    per side present:
        theta_ref phi_ref              incidence of the spectrum measurement (deg)
        comment
        nLambda / nLambda lines "lambda percent"
    per side, per rotation, per incidence:
        nTheta nPhi / the phi header (deg) / nTheta rows "theta v(phi_1) ... v(phi_n)"
    End of file

``*.brdf`` (isotropic): the same first six lines without the anisotropy vector, then
``nIncidences nLambda``, the incidences, the wavelengths, and per side, incidence and wavelength
a table preceded by its percentage: ``percent`` / ``nTheta nPhi`` / phi header / rows.

**Angles** (the grid :class:`~brdftab.grids.SpeosGrid`, whose docstring states the mapping): φ
is measured from the mirror side — the mirror direction is (θo, φ) = (θi, 0) — so brdftab's
φo = φi + π + φ, and the anisotropy angle is φi = π − rotation. Reflection rows hold θo 0…90°.

**Quantity and scale.** With the flag 1 the values are proportional to the BSDF f_r [1/sr]; with
0 to the intensity f_r·cosθo, and the reader divides by cosθo (0 at θo = 90°, where the table
holds no sample above the horizon). Speos scales the values so that the directional albedo equals
the file's percentages: for ``*.anisotropicbsdf``, f_r(λ) = v · P(λ) / (100 · A), A the
directional albedo of the values at the reference incidence (θref, φref) (linear between the two
incidences around θref, the first one below it; the nearest rotation); for ``*.brdf`` each table
by its own percentage. The reader applies that scale and records it (``speos_normalization``);
one percentage (or equal ones) gives a grey table, different ones a spectral table. The writer
writes f_r (flag 1) and percentages of 100 × brdftab's directional albedo of the values as
written, so the scale it reads back is 1 within the 9 written digits. A spectral source fills a
``.brdf`` file with one table per wavelength; an ``.anisotropicbsdf`` file holds one
distribution (the mean over the wavelengths) and the spectrum of the source's albedo at the
reference incidence, and the table written is that separable approximation (what the checks
judge). RGB and XYZ sources are written as their luminance Y.

A transmission side is skipped with a warning (brdftab holds reflection only); a file without
reflection data is refused. The origin is ``measured`` when the comment or description says so,
else ``unknown``.
"""

from __future__ import annotations

import math
import re
import warnings
from pathlib import Path

import numpy as np

from .. import __version__
from ..errors import BrdftabWarning, FormatError, ParameterError
from ..params import Param, deg_list
from . import FileFormat, read_bytes, register

__all__ = ["read_anisotropicbsdf", "read_brdf", "write_anisotropicbsdf", "write_brdf", "node_albedo",
           "sniff_anisotropic", "sniff_brdf", "DIGITS", "PRECISION"]

ANISO_HEADER = "OPTIS - Anisotropic BSDF surface file"
BRDF_HEADER = "OPTIS - brdf surface file"
VERSION = "v8.0"
#: Significant digits of the values and percentages the writer writes.
DIGITS = 9
#: Largest relative difference between the written values and what the reader returns: the
#: rounding of the percentage to DIGITS digits (the values are read as written).
PRECISION = 1e-8
DEFAULT_INCIDENCES_DEG = tuple(float(x) for x in range(0, 90, 5))
DEFAULT_THETAS_DEG = tuple(float(x) for x in range(0, 91))
DEFAULT_PHIS_DEG = tuple(float(x) for x in range(0, 361, 2))
DEFAULT_WAVELENGTHS_NM = (360.0, 830.0)
_NUMBER = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$")


# --------------------------------------------------------------------------------------------
# Recognising


def _first_line(head: bytes) -> str:
    return head.removeprefix(b"\xef\xbb\xbf").split(b"\n", 1)[0].decode("latin-1").strip()


def sniff_anisotropic(head: bytes, size: int) -> bool:
    """True for a file whose first line is the Speos anisotropic BSDF header."""
    return _first_line(head).startswith(ANISO_HEADER)


def sniff_brdf(head: bytes, size: int) -> bool:
    """True for a file whose first line is the Speos complete-scattering (``.brdf``) header."""
    return _first_line(head).startswith(BRDF_HEADER)


# --------------------------------------------------------------------------------------------
# Reading


class _Lines:
    """The file's lines with their numbers, read one after another."""

    def __init__(self, path, text: str):
        self.path = path
        self.lines = text.splitlines()
        self.k = 0

    def error(self, msg, line=None):
        return FormatError(f"{self.path}: line {self.k if line is None else line}: {msg}")

    def line(self, what):
        if self.k >= len(self.lines):
            raise FormatError(f"{self.path}: line {self.k + 1}: the file ends where {what} should be (truncated?)")
        self.k += 1
        return self.lines[self.k - 1]

    def numbers(self, what, count=None, minimum=None):
        """The numbers of the next line (exactly ``count`` of them when given)."""
        words = self.line(what).split()
        if not all(_NUMBER.match(w) for w in words):
            bad = next(w for w in words if not _NUMBER.match(w))
            raise self.error(f"expected {what}, got {bad!r}")
        vals = np.array([float(w) for w in words])
        if not np.all(np.isfinite(vals)):
            raise self.error(f"{what}: a value beyond the range of a float64")
        if count is not None and vals.size != count:
            raise self.error(f"expected {count} value{'s' if count != 1 else ''} ({what}), got {vals.size}"
                             + (" (truncated?)" if vals.size < count else ""))
        if minimum is not None and vals.size < minimum:
            raise self.error(f"expected at least {minimum} value(s) ({what}), got {vals.size}")
        return vals

    def count(self, what, n_values=1):
        vals = self.line(what).split()
        if len(vals) != n_values or not all(re.fullmatch(r"\+?\d+", w) for w in vals):
            raise self.error(f"expected {what} (whole number{'s' if n_values > 1 else ''}), got {' '.join(vals)!r}")
        return [int(w) for w in vals] if n_values > 1 else int(vals[0])

    def angles(self, what, n, lo, hi):
        vals = self.numbers(what, n)
        if np.any(np.diff(vals) <= 0):
            raise self.error(f"{what} must increase strictly")
        if vals[0] < lo or vals[-1] > hi:
            raise self.error(f"{what} must lie in [{lo:g}, {hi:g}] degrees, got {vals[0]:g} .. {vals[-1]:g}")
        return vals


def _head(tok: _Lines, header: str, kind: str) -> dict:
    """Rows 1-5 (header, mode, comment, description): the file's identity."""
    first = tok.line("the header").lstrip("\ufeff").strip()
    if not first.startswith(header):
        raise tok.error(f"expected the header '{header} v8.0', got {first[:60]!r}")
    m = re.fullmatch(r"v?(\d+(?:\.\d+)?)", first[len(header):].strip())
    if m is None:
        raise tok.error(f"the header gives no version (expected '{header} v8.0')")
    if float(m.group(1)) < 8.0:
        raise tok.error(f"a {kind} file of version {m.group(1)}; brdftab reads version 8.0 (open and save it in the "
                        "Speos BSDF viewer to update it)")
    mode = tok.line("the text/binary flag").strip()
    if mode == "1":
        raise tok.error(f"a binary {kind} file; brdftab reads the text variant (flag 0)")
    if mode != "0":
        raise tok.error(f"expected the text/binary flag 0 or 1, got {mode[:40]!r}")
    comment = tok.line("the comment")
    n = tok.count("the number of characters of the description")
    desc = tok.line("the description")
    while len(desc) < n and tok.k < len(tok.lines):
        desc += "\n" + tok.line("the description")
    return {"comment": comment.strip(), "description": desc[:n]}


def _sides(tok: _Lines):
    words = tok.line("bReflection bTransmission").split()
    if len(words) != 2 or any(w not in ("0", "1") for w in words):
        raise tok.error(f"expected bReflection bTransmission (two flags 0 or 1), got {' '.join(words)[:40]!r}")
    refl, trans = (w == "1" for w in words)
    if not refl:
        raise FormatError(f"{tok.path}: a Speos {'transmission (BTDF) only' if trans else 'empty'} file: no "
                          "reflection data; brdftab holds reflection (BRDF) only")
    flag = tok.line("the BSDF/intensity flag").strip()
    if flag not in ("0", "1"):
        raise tok.error(f"expected the BSDF/intensity flag 0 or 1, got {flag[:40]!r}")
    return trans, flag == "1"


def _block(tok: _Lines, where: str, lo: float, hi: float):
    """One ``nTheta nPhi`` table: ``(theta, phi, values[nTheta, nPhi], line)``."""
    nt, nphi = tok.count(f"nTheta nPhi of {where}", 2)
    line = tok.k
    if nt < 1 or nphi < 1:
        raise tok.error(f"{where}: {nt} x {nphi} values; at least one angle is needed")
    phi = tok.angles(f"the phi angles of {where}", nphi, 0.0, 360.0)
    rows = np.empty((nt, nphi + 1))
    for r in range(nt):
        rows[r] = tok.numbers(f"row {r + 1} of {nt} of {where} (theta, then {nphi} values)", nphi + 1)
    theta = rows[:, 0]
    if np.any(np.diff(theta) <= 0):
        raise tok.error(f"the theta angles of {where} must increase strictly", line)
    if theta[0] < lo or theta[-1] > hi:
        raise tok.error(f"the theta angles of {where} must lie in [{lo:g}, {hi:g}] degrees, got {theta[0]:g} .. "
                        f"{theta[-1]:g}", line)
    return theta, phi, rows[:, 1:], line


def _stack(tok, blocks, where):
    """The blocks' values as one array, after checking they share their theta and phi lists."""
    theta, phi = blocks[0][0], blocks[0][1]
    for k, (t, p, _, line) in enumerate(blocks):
        if t.size != theta.size or p.size != phi.size or np.any(t != theta) or np.any(p != phi):
            raise tok.error(f"{where} {k + 1} has other theta/phi angles than the first; brdftab reads tables whose "
                            "blocks share one theta/phi grid", line)
    return theta, phi, np.stack([b[2] for b in blocks])


def _end(tok: _Lines):
    rest = [(n, s.strip()) for n, s in enumerate(tok.lines[tok.k:], tok.k + 1) if s.strip()]
    if rest and rest[0][1].lower() != "end of file":
        raise tok.error(f"unexpected {rest[0][1][:40]!r} after the last table (more values than the header counts?)",
                        rest[0][0])


def parse_anisotropicbsdf(path, text: str) -> dict:
    """The content of a ``*.anisotropicbsdf`` text file: its header fields, the reflection side's
    rotations, incidences, spectrum and ``values[rotation, incidence, theta, phi]``."""
    tok = _Lines(path, text)
    head = _head(tok, ANISO_HEADER, "Speos anisotropic BSDF")
    head["vector"] = tok.numbers("the anisotropy vector (x y z)", 3)
    trans, bsdf = _sides(tok)
    lists = []
    for side in ("reflection", "transmission")[:1 + trans]:
        n_rot = tok.count(f"the number of anisotropy angles ({side})")
        if n_rot < 1:
            raise tok.error(f"{side}: no anisotropy angle")
        rot = tok.angles(f"the anisotropy angles ({side})", n_rot, 0.0, 360.0)
        inc = None
        for j in range(n_rot):
            n_inc = tok.count(f"the number of incidences ({side}, anisotropy angle {rot[j]:g})")
            if n_inc < 1:
                raise tok.error(f"{side}: no incidence angle")
            this = tok.angles(f"the incidence angles ({side}, anisotropy angle {rot[j]:g})", n_inc, 0.0, 90.0)
            if inc is not None and (this.size != inc.size or np.any(this != inc)):
                raise tok.error("the incidence angles must be the same for every anisotropy angle")
            inc = this
        lists.append((rot, inc))
    spectra = []
    for side in ("reflection", "transmission")[:1 + trans]:
        ref = tok.numbers(f"theta phi of the {side} spectrum measurement (degrees)", 2)
        tok.line("the comment of the spectrum")
        n = tok.count(f"the number of wavelengths ({side})")
        if n < 1:
            raise tok.error(f"{side}: a spectrum of no wavelength")
        spec = np.array([tok.numbers(f"wavelength (nm) and percentage ({side})", 2) for _ in range(n)])
        spectra.append((ref, spec))
    blocks = []
    for s, side in enumerate(("reflection", "transmission")[:1 + trans]):
        rot, inc = lists[s]
        lo, hi = (0.0, 90.0) if side == "reflection" else (90.0, 180.0)
        side_blocks = [_block(tok, f"{side} table {j * inc.size + i + 1} (anisotropy angle {rot[j]:g}, incidence "
                                   f"{inc[i]:g})", lo, hi) for j in range(rot.size) for i in range(inc.size)]
        blocks.append(side_blocks)
    _end(tok)
    rot, inc = lists[0]
    theta, phi, values = _stack(tok, blocks[0], "reflection table")
    (ref, spec) = spectra[0]
    lam = spec[:, 0]
    if np.any(lam <= 0) or np.any(np.diff(lam) <= 0):
        raise FormatError(f"{path}: the wavelengths of the reflection spectrum must be positive and increase strictly")
    return {**head, "transmission": trans, "bsdf": bsdf, "rotation": rot, "incidence": inc, "theta": theta,
            "phi": phi, "values": values.reshape(rot.size, inc.size, theta.size, phi.size), "reference": ref,
            "wavelength": lam, "percent": spec[:, 1]}


def parse_brdf(path, text: str) -> dict:
    """The content of a ``*.brdf`` text file: header fields, incidences, wavelengths, the
    reflection tables' percentages ``[incidence, λ]`` and ``values[incidence, λ, theta, phi]``."""
    tok = _Lines(path, text)
    head = _head(tok, BRDF_HEADER, "Speos .brdf")
    trans, bsdf = _sides(tok)
    n_inc, n_lam = tok.count("the number of incidences and of wavelengths", 2)
    if n_inc < 1 or n_lam < 1:
        raise tok.error("at least one incidence and one wavelength are needed")
    inc = tok.angles("the incidence angles", n_inc, 0.0, 90.0)
    lam = tok.numbers("the wavelengths (nm)", n_lam)
    if np.any(lam <= 0) or np.any(np.diff(lam) <= 0):
        raise tok.error("the wavelengths must be positive and increase strictly")
    blocks, percent = [], []
    for side in ("reflection", "transmission")[:1 + trans]:
        lo, hi = (0.0, 90.0) if side == "reflection" else (90.0, 180.0)
        for i in range(n_inc):
            for m in range(n_lam):
                where = f"{side} table (incidence {inc[i]:g}, {lam[m]:g} nm)"
                p = tok.numbers(f"the percentage of the {where}", 1)[0]
                b = _block(tok, where, lo, hi)
                if side == "reflection":
                    percent.append(p)
                    blocks.append(b)
    _end(tok)
    theta, phi, values = _stack(tok, blocks, "reflection table")
    return {**head, "transmission": trans, "bsdf": bsdf, "incidence": inc, "wavelength": lam,
            "percent": np.array(percent).reshape(n_inc, n_lam), "theta": theta, "phi": phi,
            "values": values.reshape(n_inc, n_lam, theta.size, phi.size)}


def _read_text(path) -> str:
    raw = read_bytes(path)
    if b"\0" in raw:
        raise FormatError(f"{path}: a Speos file with binary bytes in it (a binary variant, or damaged); brdftab "
                          "reads the text variant")
    return raw.decode("latin-1")


def node_albedo(table) -> np.ndarray:
    """brdftab's directional albedo ``[θi, rotation, C]`` of a table on a Speos grid at each of
    its incidence nodes (directions outside the table's domain count as 0): the percentages the
    writer writes and the reader's scale."""
    from ..geometry import vec_to_sph
    from ..grids.speos import speos_directions
    from ..integrate import directional_albedo

    g = table.grid
    ti, rot = np.meshgrid(g.axes[0].values, g.axes[1].values, indexing="ij")
    wi, _ = speos_directions(ti, rot, 0.0, 0.0)
    _, phi_i = vec_to_sph(wi)
    old = table.outside
    try:
        table.outside = "nan"
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", BrdftabWarning)
            return directional_albedo(table, ti, phi_i)
    finally:
        table.outside = old


def _reference_albedo(albedo, incidence, rotation, ref):
    """Speos' α0: the albedo at (θref, φref), linear between the two incidences around θref (the
    first incidence when θref is below it, the last above), at the rotation nearest φref."""
    t = float(np.clip(ref[0], incidence[0], incidence[-1]))
    d = np.abs(np.mod(rotation - ref[1] + 180.0, 360.0) - 180.0)
    j = int(np.argmin(d))
    return np.array([np.interp(t, incidence, albedo[:, j, c]) for c in range(albedo.shape[-1])])


def _make(content, values, name, fmt, layout_wavelengths=None, rotation=(0.0,)):
    """A Table of Speos content ``values[θi, rotation, θo, φ, C]`` (f_r) with its provenance."""
    from ..channels import Layout
    from ..grids import SpeosGrid
    from ..table import Table, make_table

    grid = SpeosGrid(np.radians(content["incidence"]), np.radians(np.asarray(rotation, float)),
                     np.radians(content["theta"]), np.radians(content["phi"]))
    layout = Layout(None, np.asarray(layout_wavelengths, float)) if layout_wavelengths is not None else Layout()
    text = f"{content['comment']} {content['description']}".lower()
    measured = "measur" in text
    provenance = {
        "title": f"Speos {name}",
        "model": "unknown",
        "parameters": "{}",
        "isotropic": int(len(rotation) == 1),
        "reciprocal": 0,
        "source_file": name,
        "source_format": fmt,
        "speos_comment": content["comment"],
        "speos_description": content["description"],
    }
    table = make_table(values, grid, layout, provenance=provenance)
    ds = table.ds
    ds.attrs["origin"] = "measured" if measured else "unknown"
    for key in ("created", "brdftab_version", "history", "source"):
        ds.attrs.pop(key, None)
    out = Table(ds)
    out.origin = ds.attrs["origin"]
    return out


def _to_fr(content, values):
    """Values as f_r: intensity (flag 0) divided by cosθo (0 at the horizon); the quantity note."""
    if content["bsdf"]:
        return values, "the file holds values proportional to f_r [1/sr] (BSDF flag 1)"
    cos = np.cos(np.radians(content["theta"]))[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        fr = np.where(cos > 1e-12, values / np.where(cos > 1e-12, cos, 1.0), 0.0)
    return fr, ("the file holds values proportional to the intensity f_r cos(theta_o) (flag 0): divided by "
                "cos(theta_o) on reading (0 at theta_o = 90 deg)")


def _warn_transmission(path, content):
    if content["transmission"]:
        warnings.warn(f"{path}: the file also holds transmission (BTDF) data, skipped: brdftab holds reflection only",
                      BrdftabWarning, stacklevel=4)


def read_anisotropicbsdf(path):
    """Read a Speos ``*.anisotropicbsdf`` text file into a Table on a :class:`~brdftab.grids.SpeosGrid`."""
    from ..table import Table

    path = Path(path)
    content = parse_anisotropicbsdf(path, _read_text(path))
    _warn_transmission(path, content)
    raw = np.moveaxis(content["values"], 0, 1)  # [θi, rotation, θo, φ]
    fr, quantity = _to_fr(content, raw)
    unit = _make(content, fr[..., None], path.name, "speos", rotation=content["rotation"])
    albedo = node_albedo(unit)
    a0 = float(_reference_albedo(albedo, content["incidence"], content["rotation"], content["reference"])[0])
    if not (math.isfinite(a0) and a0 > 0):
        raise FormatError(f"{path}: the reflection data integrate to {a0:g} at the reference incidence "
                          f"{content['reference'][0]:g} deg: they cannot be scaled to the file's spectrum")
    scale = content["percent"] / (100.0 * a0)
    flat = np.all(content["percent"] == content["percent"][0])
    if flat:
        table = _make(content, fr[..., None] * scale[0], path.name, "speos", rotation=content["rotation"])
    else:
        table = _make(content, fr[..., None] * scale, path.name, "speos", content["wavelength"], content["rotation"])
    ds = table.ds
    ds.attrs.update({
        "source_quantity": quantity + "; scaled so that the directional albedo at the reference incidence equals the "
                                     "file's percentage / 100 (Speos' normalization)",
        "speos_reference_incidence_deg": np.asarray(content["reference"], float),
        "speos_albedo_of_the_data": a0,
        "speos_normalization": np.asarray(scale, float),
        "speos_spectrum_wavelength_nm": np.asarray(content["wavelength"], float),
        "speos_spectrum_percent": np.asarray(content["percent"], float),
        "speos_anisotropy_vector": np.asarray(content["vector"], float),
    })
    out = Table(ds)
    out.origin = ds.attrs["origin"]
    return out


def read_brdf(path):
    """Read a Speos ``*.brdf`` text file into a Table on a :class:`~brdftab.grids.SpeosGrid` (one rotation)."""
    from ..table import Table

    path = Path(path)
    content = parse_brdf(path, _read_text(path))
    _warn_transmission(path, content)
    raw = np.moveaxis(content["values"], 1, -1)[:, None]  # [θi, 1, θo, φ, λ]
    fr, quantity = _to_fr(content, np.moveaxis(raw, -1, 0))
    fr = np.moveaxis(fr, 0, -1)
    unit = _make(content, fr, path.name, "speos-brdf", content["wavelength"] if fr.shape[-1] > 1 else None)
    albedo = node_albedo(unit)[:, 0]  # [θi, λ]
    percent = content["percent"]
    scale = np.zeros_like(percent)
    bad = (albedo <= 0) | ~np.isfinite(albedo)
    if np.any(bad & (percent != 0)):
        i, m = np.argwhere(bad & (percent != 0))[0]
        raise FormatError(f"{path}: the reflection table at incidence {content['incidence'][i]:g} deg, "
                          f"{content['wavelength'][m]:g} nm integrates to {albedo[i, m]:g}: it cannot be scaled to "
                          f"its percentage {percent[i, m]:g}")
    np.divide(percent, 100.0 * albedo, out=scale, where=~bad)
    values = fr * scale[:, None, None, None, :]
    table = _make(content, values, path.name, "speos-brdf", content["wavelength"] if fr.shape[-1] > 1 else None)
    ds = table.ds
    ds.attrs.update({
        "source_quantity": quantity + "; each table scaled so that its directional albedo equals its percentage / 100 "
                                     "(Speos' normalization)",
        "speos_normalization": scale.ravel(),
        "speos_percent": percent.ravel(),
        "speos_wavelength_nm": np.asarray(content["wavelength"], float),
    })
    out = Table(ds)
    out.origin = ds.attrs["origin"]
    return out


# --------------------------------------------------------------------------------------------
# Writing


def check_options(incidences_deg=None, anisotropy_angles_deg=None, thetas_deg=None, phis_deg=None,
                  reference_incidence_deg=None, spectrum_wavelengths_nm=None):
    """The writer's options checked (one :class:`ParameterError` naming the option)."""
    deg_list("incidences_deg", incidences_deg, 0, 90)
    deg_list("anisotropy_angles_deg", anisotropy_angles_deg, 0, 360)
    deg_list("thetas_deg", thetas_deg, 0, 90)
    deg_list("phis_deg", phis_deg, 0, 360)
    if reference_incidence_deg is not None and not 0 <= float(reference_incidence_deg) <= 90:
        raise ParameterError("reference_incidence_deg", f"expected an angle in [0, 90] degrees, got "
                             f"{reference_incidence_deg!r}")
    if spectrum_wavelengths_nm is not None:
        lam = np.asarray(spectrum_wavelengths_nm, float).ravel()
        if lam.size == 0 or not np.all(np.isfinite(lam)) or np.any(lam <= 0) or np.any(np.diff(lam) <= 0):
            raise ParameterError("spectrum_wavelengths_nm", "expected positive wavelengths in nm, increasing")


def _grid(options, anisotropic, brdf_file):
    from ..grids import SpeosGrid

    inc = deg_list("incidences_deg", options.get("incidences_deg"), 0, 90)
    rot = None if brdf_file else deg_list("anisotropy_angles_deg", options.get("anisotropy_angles_deg"), 0, 360)
    th = deg_list("thetas_deg", options.get("thetas_deg"), 0, 90)
    ph = deg_list("phis_deg", options.get("phis_deg"), 0, 360)
    inc = np.array(DEFAULT_INCIDENCES_DEG) if inc is None else inc
    if rot is None:
        rot = np.arange(0.0, 360.0, 30.0) if anisotropic and not brdf_file else np.zeros(1)
    th = np.array(DEFAULT_THETAS_DEG) if th is None else th
    ph = np.array(DEFAULT_PHIS_DEG) if ph is None else ph
    return SpeosGrid(np.radians(inc), np.radians(rot), np.radians(th), np.radians(ph))


_GRID_KEYS = ("incidences_deg", "anisotropy_angles_deg", "thetas_deg", "phis_deg")


def _native(brdf_file):
    def native_grid(requested, options: dict):
        """The Speos grid of the writer's options (or a requested one of that type)."""
        from ..grids import SpeosGrid

        if (isinstance(requested, SpeosGrid) and not any(k in options for k in _GRID_KEYS)
                and (not brdf_file or len(requested.axes[1]) == 1)):
            return requested
        return _grid(options, anisotropic=False, brdf_file=brdf_file)
    return native_grid


def _grey(brdf, where):
    """A colour (RGB or XYZ) ``brdf`` as one grey channel, its luminance Y through colour-science
    (a Speos table holds grey or spectral data, not colour channels); a grey one as it is."""
    from ..colorimetry import XYZView
    from .zemax import _Y

    if brdf.channels == ("mono",):
        return brdf
    warnings.warn(f"a {where} holds grey or spectral data: '{brdf.name}' ({', '.join(brdf.channels)}) is written as "
                  "its luminance Y (CIE 1931, through colour-science)", BrdftabWarning, stacklevel=5)
    if brdf.channels == ("R", "G", "B"):
        return XYZView(brdf, luminance_only=True)
    if brdf.channels == ("X", "Y", "Z"):
        return _Y(brdf)
    raise FormatError(f"a {where} holds grey or spectral data; '{brdf.name}' has channels {', '.join(brdf.channels)}")


def _prepare(brdf_file):
    where = "Speos .brdf file" if brdf_file else "Speos .anisotropicbsdf file"

    def prepare(brdf, grid, incidences_deg=None, anisotropy_angles_deg=None, thetas_deg=None, phis_deg=None,
                reference_incidence_deg=None, spectrum_wavelengths_nm=None):
        """The grey table on a Speos grid that the writer writes (values rounded as written)."""
        from ..grids import SpeosGrid
        from ..table import Table, tabulate, warn_specular_dropped

        options = dict(incidences_deg=incidences_deg, anisotropy_angles_deg=anisotropy_angles_deg,
                       thetas_deg=thetas_deg, phis_deg=phis_deg)
        check_options(**options, reference_incidence_deg=reference_incidence_deg,
                      spectrum_wavelengths_nm=spectrum_wavelengths_nm)
        if brdf_file and not brdf.isotropic:
            raise FormatError(f"a Speos .brdf file holds isotropic data; '{brdf.name}' is anisotropic (write a "
                              ".anisotropicbsdf file)")
        warn_specular_dropped(brdf, f"a {where}")
        explicit = any(v is not None for v in options.values())
        if isinstance(grid, SpeosGrid) and not explicit and (not brdf_file or len(grid.axes[1]) == 1):
            target = grid
        else:
            target = _grid({k: v for k, v in options.items() if v is not None}, not brdf.isotropic, brdf_file)
        if not brdf.isotropic and len(target.axes[1]) == 1:
            raise FormatError(f"'{brdf.name}' is anisotropic and one anisotropy angle would describe it at one "
                              "incident azimuth only; give anisotropy_angles_deg (e.g. every 30 degrees)")
        if brdf.spectral:
            lam = spectrum_wavelengths_nm if spectrum_wavelengths_nm is not None else brdf.layout.wavelengths
            if lam is None:
                raise FormatError(f"'{brdf.name}' is spectral: give spectrum_wavelengths_nm, the wavelengths of the "
                                  f"{where}")
            lam = np.asarray(lam, float).ravel()
            if (isinstance(brdf, Table) and brdf.grid.equals(target)
                    and np.array_equal(np.asarray(brdf.layout.wavelengths, float), lam)):
                table = brdf
            else:
                table = tabulate(brdf, target, wavelengths=lam)
            if not brdf_file:
                ref = (float(np.degrees(target.axes[0].values[0])) if reference_incidence_deg is None
                       else float(reference_incidence_deg), float(np.degrees(target.axes[1].values[0])))
                table = _separable(table, ref)
            return _rounded(table)
        source = _grey(brdf, where)
        if isinstance(source, Table) and source.grid.equals(target):
            table = source
        else:
            table = tabulate(source, target)
        return _rounded(table)

    return prepare


def _with_values(table, values):
    from ..table import Table

    ds = table.ds.copy(deep=False)
    ds["brdf"] = ds["brdf"].copy(data=values)
    out = Table(ds)
    out.origin = table.origin
    return out


def _separable(table, ref):
    """A spectral table as an ``.anisotropicbsdf`` holds it: one angular distribution S (the mean
    over the wavelengths) scaled per wavelength to the table's directional albedo at the reference
    incidence, S · a(λ) / A(S) (what the reader returns)."""
    g = table.grid
    inc, rot = np.degrees(g.axes[0].values), np.degrees(g.axes[1].values)
    v = np.asarray(table.values, float)
    a_lam = _reference_albedo(node_albedo(table), inc, rot, ref)
    shape = v.mean(axis=-1, keepdims=True)
    a_shape = _reference_albedo(node_albedo(_with_values(table, np.repeat(shape, v.shape[-1], axis=-1))), inc, rot,
                                ref)[0]
    if not (math.isfinite(a_shape) and a_shape > 0):
        raise FormatError(f"'{table.name}' reflects nothing at the reference incidence {ref[0]:g} deg: a Speos "
                          ".anisotropicbsdf file scales its table to the albedo there")
    return _with_values(table, shape * (a_lam / a_shape))


def _rounded(table):
    """``table`` with its values as the file holds them (DIGITS significant digits; NaN as 0)."""
    v = np.asarray(table.values, float)
    bad = ~np.isfinite(v)
    if bad.any():
        warnings.warn(f"{int(bad.sum())} of {v.size} samples hold no data (NaN or infinite); a Speos file has no "
                      "missing marker: written as 0", BrdftabWarning, stacklevel=4)
    back = np.char.mod(f"%.{DIGITS}g", np.where(bad, 0.0, v)).astype(float)
    if np.array_equal(back, v):
        return table
    return _with_values(table, back)


def _stored(payload, **_):
    return _rounded(payload)


def _num(x) -> str:
    return f"{x:.{DIGITS}g}"


def _angles(vals) -> str:
    return "\t".join(f"{x:.12g}" for x in np.degrees(vals))


def _check_table(table, where):
    from ..grids import SpeosGrid

    if not isinstance(table.grid, SpeosGrid):
        raise FormatError(f"a {where} needs a table on a speos grid, not on {table.grid.describe()}")
    if not table.spectral and table.channels != ("mono",):
        raise FormatError(f"a {where} stores a grey or spectral distribution, not channels {table.channels}")


def _head_lines(table, header):
    origin = getattr(table, "origin", "unknown")
    comment = f"Written by brdftab {__version__} from {table.name}: BSDF f_r [1/sr], phi = 0 on the mirror side"
    desc = "Measured data" if origin == "measured" else f"brdftab table ({origin})"
    return [f"{header} {VERSION}", "0", comment, str(len(desc)), desc]


def _table_lines(theta, phi, block):
    rows = np.char.mod(f"%.{DIGITS}g", block)
    return ([f"{theta.size}\t{phi.size}", "\t" + _angles(phi)]
            + [_num(t) + "\t" + "\t".join(r) for t, r in zip(np.degrees(theta), rows)])


def write_anisotropicbsdf(table, path, incidences_deg=None, anisotropy_angles_deg=None, thetas_deg=None,
                          phis_deg=None, reference_incidence_deg=None, spectrum_wavelengths_nm=None):
    """Write ``table`` (from the format's prepare) as a text ``*.anisotropicbsdf`` file: f_r
    (flag 1), the spectrum 100 × brdftab's directional albedo at the reference incidence."""
    _check_table(table, "Speos .anisotropicbsdf file")
    table = _rounded(table)
    g = table.grid
    inc, rot, theta, phi = (a.values for a in g.axes)
    ref = float(np.degrees(inc[0])) if reference_incidence_deg is None else float(reference_incidence_deg)
    ref_rot = float(np.degrees(rot[0]))
    a_ref = _reference_albedo(node_albedo(table), np.degrees(inc), np.degrees(rot), (ref, ref_rot))
    if table.spectral:
        # one distribution (the wavelength reflecting most: the table is separable) and the
        # spectrum of albedos at the reference incidence
        lam = np.asarray(table.layout.wavelengths, float)
        percent = 100.0 * a_ref
        values = np.asarray(table.values, float)[..., int(np.argmax(a_ref))]
    else:
        lam = DEFAULT_WAVELENGTHS_NM if spectrum_wavelengths_nm is None else np.asarray(spectrum_wavelengths_nm, float)
        percent = np.full(len(lam), 100.0 * a_ref[0])
        values = np.asarray(table.values, float)[..., 0]
    lines = _head_lines(table, ANISO_HEADER) + [
        "1\t0\t0", "1\t0", "1", str(rot.size), _angles(rot)]
    for _ in range(rot.size):
        lines += [str(inc.size), _angles(inc)]
    lines += [f"{ref:.12g}\t{ref_rot:.12g}", "wavelength (nm)\tcoefficient (%)", str(len(lam))]
    lines += [f"{float(x)!r}\t{_num(p)}" for x, p in zip(lam, percent)]
    with open(path, "w", encoding="ascii", newline="\n") as fh:
        fh.write("\n".join(lines) + "\n")
        for j in range(rot.size):
            for i in range(inc.size):
                fh.write("\n".join(_table_lines(theta, phi, values[i, j])) + "\n")
        fh.write("End of file\n")


def write_brdf(table, path, incidences_deg=None, anisotropy_angles_deg=None, thetas_deg=None, phis_deg=None,
               reference_incidence_deg=None, spectrum_wavelengths_nm=None):
    """Write ``table`` (from the format's prepare) as a text ``*.brdf`` file: f_r (flag 1), each
    table's percentage 100 × brdftab's directional albedo at its incidence."""
    _check_table(table, "Speos .brdf file")
    table = _rounded(table)
    g = table.grid
    if len(g.axes[1]) != 1:
        raise FormatError("a Speos .brdf file holds isotropic data: one anisotropy angle, not "
                          f"{len(g.axes[1])}")
    inc, _, theta, phi = (a.values for a in g.axes)
    albedo = node_albedo(table)[:, 0]  # [θi, C]
    values = np.asarray(table.values, float)[:, 0]  # [θi, θo, φ, C]
    if table.spectral:  # one table per wavelength
        lam = np.asarray(table.layout.wavelengths, float)
    else:  # the same table at each wavelength
        lam = (550.0,) if spectrum_wavelengths_nm is None else np.asarray(spectrum_wavelengths_nm, float)
        albedo = np.repeat(albedo, len(lam), axis=1)
        values = np.repeat(values, len(lam), axis=-1)
    lines = _head_lines(table, BRDF_HEADER) + ["1\t0", "1", f"{inc.size}\t{len(lam)}", _angles(inc),
                                                "\t".join(repr(float(x)) for x in lam)]
    with open(path, "w", encoding="ascii", newline="\n") as fh:
        fh.write("\n".join(lines) + "\n")
        for i in range(inc.size):
            for m in range(len(lam)):
                fh.write(_num(100.0 * albedo[i, m]) + "\n" + "\n".join(_table_lines(theta, phi, values[i, ..., m]))
                         + "\n")
        fh.write("End of file\n")


_GRID_PARAMS = (
    Param("incidences_deg", "floats", "Angles of incidence in degrees (default 0 to 85 every 5).", default=None,
          minimum=0.0, maximum=90.0),
    Param("thetas_deg", "floats", "Outgoing polar angles theta_o in degrees, the rows (default 0 to 90 every 1).",
          default=None, minimum=0.0, maximum=90.0),
    Param("phis_deg", "floats", "Outgoing Speos azimuths in degrees, 0 on the mirror side, the columns (default 0 "
          "to 360 every 2).", default=None, minimum=0.0, maximum=360.0),
)

register(FileFormat(
    name="speos",
    extensions=(".anisotropicbsdf",),
    description="Ansys Speos 'Anisotropic BSDF surface' text file v8.0: f_r [1/sr] on (anisotropy angle, incidence, "
                "theta_o, phi) with phi = 0 on the mirror side (phi_o = phi_i + 180 deg + phi, phi_i = 180 deg - "
                "anisotropy angle); values proportional to f_r (flag 1) or to the intensity f_r cos(theta_o) (flag 0, "
                "divided by cos(theta_o) on reading), scaled on reading so that the directional albedo at the "
                "reference incidence equals the spectrum's percentage / 100; writes f_r (flag 1) of one "
                "distribution and a spectrum of 100 x brdftab's directional albedo at the reference incidence "
                "(flat for grey sources; per wavelength for spectral ones, the distribution their mean; RGB and XYZ "
                "sources as their luminance Y) (read and write; reflection only)",
    read=read_anisotropicbsdf,
    write=write_anisotropicbsdf,
    sniff=sniff_anisotropic,
    native_grid=_native(False),
    prepare=_prepare(False),
    check_options=check_options,
    stored=_stored,
    params=_GRID_PARAMS + (
        Param("anisotropy_angles_deg", "floats", "Anisotropy angles in degrees, phi_i = 180 - angle (default [0]; "
              "anisotropic sources every 30).", default=None, minimum=0.0, maximum=360.0),
        Param("reference_incidence_deg", "float", "Incidence of the spectrum measurement in degrees (default the "
              "first incidence).", default=None, minimum=0.0, maximum=90.0),
        Param("spectrum_wavelengths_nm", "floats", "Wavelengths of the spectrum in nm (default: 360, 830 for a grey "
              "source, a spectral source's own).", units="nm", default=None, minimum=0.0),
    ),
    precision=PRECISION,
))

register(FileFormat(
    name="speos-brdf",
    extensions=(".brdf",),
    description="Ansys Speos 'brdf surface' (complete scattering) text file v8.0, isotropic: f_r [1/sr] on "
                "(incidence, theta_o, phi) with phi = 0 on the mirror side (phi_o = phi_i + 180 deg + phi) per "
                "wavelength; values proportional to f_r (flag 1) or to the intensity f_r cos(theta_o) (flag 0, "
                "divided by cos(theta_o) on reading), each table scaled on reading so that its directional albedo "
                "equals its percentage / 100; writes f_r (flag 1), one table per wavelength (spectral sources) or "
                "the same at each (grey sources; RGB and XYZ ones as their luminance Y), each table's percentage "
                "100 x brdftab's directional albedo (read and write; reflection only)",
    read=read_brdf,
    write=write_brdf,
    sniff=sniff_brdf,
    native_grid=_native(True),
    prepare=_prepare(True),
    check_options=check_options,
    stored=_stored,
    params=_GRID_PARAMS + (
        Param("spectrum_wavelengths_nm", "floats", "Wavelengths of the tables in nm (default: 550 for a grey source, "
              "the same table at each; a spectral source's own).", units="nm", default=None, minimum=0.0),
    ),
    precision=PRECISION,
))
