"""LightTools text ``.bsdf`` files: read and write (``formats/lighttools.md``).

``.bsdf`` is shared with RGL's binary tensor files and Zemax/Radiant text files; a LightTools
file is told apart by its content (:func:`brdftab.formats.zemax.classify`: ``AOI`` blocks after
the header, no ``AngleOfIncidence``). Writing one takes ``format = "lighttools"``.

Layout (formats.md §4.2, after libbsdf's ``LightToolsBsdfReader``)::

    # comment lines
    Symmetry  Asymmetric | PlaneSymmetrical
    SpectralContent  Monochrome | XYZ
    ScatterAzimuth  <n>  <n angles, deg>
    ScatterRadial  <n>  <n angles, deg>
    DataBegin
    AOI <deg>  POI <deg>  Side Front|Back  ScatterType BRDF|BTDF  [Wavelength <nm>]
    [TristimulusValue TrisX|TrisY|TrisZ]  TIS <v>  then nAzimuth rows of nRadial values
    ...                                   (one block per incidence, plane and channel)
    DataEnd

The values are f_r [1/sr] (not multiplied by cosθo). ScatterRadial and ScatterAzimuth are the
outgoing direction's ordinary polar angle and azimuth about the normal (not about the mirror
direction, unlike Zemax files). In the file's frame the incident direction lies at azimuth
90° + POI (libbsdf: "an incoming azimuthal angle of an isotropic LightTools BSDF is 90
degrees"); brdftab's frame is the file's turned by −90° about the normal, so

    θi = AOI,  φi = POI,  θo = ScatterRadial,  φo = ScatterAzimuth − 90°

and the mirror direction of a block is at ScatterAzimuth = POI + 270°. The table's grid is a
:class:`~brdftab.grids.SphericalGrid` with these coordinates, which netCDF and zarr store as
they are; ``PlaneSymmetrical`` files hold one side of the plane of incidence and their grid
declares the mirror symmetry (``phi_d_fold = "bilateral"``). TIS per block is the directional
albedo at its incidence, as in Zemax files (the writer writes brdftab's, the reader compares).
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np

from ..colorimetry import PARAMS as COLOUR_PARAMS
from ..errors import BrdftabWarning, FormatError, ParameterError
from ..params import Param, deg_list
from . import FileFormat, read_bytes, register
from .zemax import (CLASSIFY_BYTES, DIGITS, PRECISION, _text, _Tokens, classify, compare_tis,
                    monochrome_or_xyz, rounded, text_bsdf, tis_albedo)

__all__ = ["sniff", "parse_lighttools", "read_lighttools", "write_lighttools", "prepare_lighttools",
           "AZIMUTH_OFFSET_DEG"]

#: File azimuth of brdftab's φ = 0: ScatterAzimuth = φo + 90°, and the incident direction of a
#: block lies at file azimuth POI + 90°.
AZIMUTH_OFFSET_DEG = 90.0
#: Spellings of the Symmetry values read (libbsdf's ``Asymmetric``, Zemax's ``Asymmetrical``).
SYMMETRIES = {"Asymmetric": "none", "Asymmetrical": "none", "ASymmetrical": "none", "PlaneSymmetrical": "plane"}
CONTENTS = {"Monochrome": ("mono",), "XYZ": ("X", "Y", "Z")}
TRIS = {"TrisX": 0, "TrisY": 1, "TrisZ": 2}
HEADER = ("Symmetry", "SpectralContent", "ScatterAzimuth", "ScatterRadial")
BLOCK_KEYS = ("AOI", "POI", "Side", "ScatterType", "Wavelength", "TristimulusValue")
DEFAULT_INCIDENCES_DEG = tuple(float(x) for x in range(0, 90, 5))
DEFAULT_AZIMUTHS_DEG = tuple(float(x) for x in range(0, 360, 5))
DEFAULT_RADIALS_DEG = tuple(float(x) for x in np.arange(0.0, 90.1, 2.5))


def sniff(head: bytes, size: int) -> bool:
    """True for a text ``.bsdf`` file whose head is LightTools' (``AOI`` blocks, no Zemax
    ``AngleOfIncidence``)."""
    return text_bsdf(head) and classify(head)[0] == "lighttools"


# --------------------------------------------------------------------------------------------
# Reading


def parse_lighttools(path, text: str) -> dict:
    """The content of a LightTools file: the header (``symmetry``, ``content``, ``azimuth``,
    ``radial`` in degrees) and ``blocks``, each ``{"AOI", "POI", "Side", "ScatterType",
    "Wavelength", "channel", "tis", "values" [nAz, nRad], "line"}``; a :class:`FormatError`
    naming the file and line for anything missing, miscounted, not a number or cut short."""
    tok = _Tokens(path, text)
    head, angles = {}, {}
    while True:
        word = tok.peek()
        if word is None:
            raise tok.error("the file ends before its data (no DataBegin)")
        _, line = tok.take("a keyword")
        if word == "DataBegin":
            break
        if word in ("Symmetry", "SpectralContent"):
            if word in head:
                raise tok.error(f"{word} given twice", line)
            value, vline = tok.take(f"the value of {word}")
            if value in HEADER or value == "DataBegin":
                raise tok.error(f"{word} has no value", line)
            head[word] = (value, vline)
        elif word in ("ScatterAzimuth", "ScatterRadial"):
            if word in angles:
                raise tok.error(f"{word} given twice", line)
            vals = tok.numbers(tok.count(word), f"{word} angles (degrees)")
            if np.any(np.diff(vals) <= 0):
                raise tok.error(f"{word} angles must increase strictly", line)
            angles[word] = (vals, line)
        elif word in BLOCK_KEYS or word == "TIS":
            raise tok.error(f"{word} before DataBegin (the header ends with DataBegin)", line)
        else:
            raise tok.error(f"unknown keyword {word!r} in the header (expected Symmetry, SpectralContent, "
                            "ScatterAzimuth, ScatterRadial, DataBegin)", line)
    for key in ("Symmetry", "SpectralContent"):
        if key not in head:
            raise tok.error(f"missing keyword {key} before the data")
    for key in ("ScatterAzimuth", "ScatterRadial"):
        if key not in angles:
            raise tok.error(f"missing keyword {key} before the data")
    sym, line = head["Symmetry"]
    if sym not in SYMMETRIES:
        raise tok.error(f"Symmetry {sym!r}: expected Asymmetric or PlaneSymmetrical", line)
    content, line = head["SpectralContent"]
    if content not in CONTENTS:
        raise tok.error(f"SpectralContent {content!r}: expected Monochrome or XYZ", line)
    az, line = angles["ScatterAzimuth"]
    if az[0] < -360 or az[-1] > 360 or az[-1] - az[0] > 360:
        raise tok.error("ScatterAzimuth angles must lie in [-360, 360] degrees and span at most 360", line)
    rad, line = angles["ScatterRadial"]
    if rad[0] < 0 or rad[-1] > 90:
        raise tok.error("ScatterRadial angles (polar angles from the normal) must lie in [0, 90] degrees", line)

    per = az.size * rad.size
    blocks = []
    block: dict = {}
    while True:
        word = tok.peek()
        if word is None:
            raise tok.error("the file ends before DataEnd (truncated?)")
        _, line = tok.take("a block keyword")
        if word == "DataEnd":
            if block:
                raise tok.error(f"a block without its TIS and values before DataEnd (block {len(blocks) + 1})", line)
            break
        block.setdefault("line", line)
        if word in ("AOI", "POI", "Wavelength"):
            if word in block:
                raise tok.error(f"{word} given twice in block {len(blocks) + 1} (a block ends with TIS and its "
                                "values)", line)
            block[word] = tok.number(f"the {word} value")
        elif word == "Side":
            value, vline = tok.take("the value of Side")
            if value not in ("Front", "Back"):
                raise tok.error(f"Side {value!r}: expected Front or Back", vline)
            block[word] = value
        elif word == "ScatterType":
            value, vline = tok.take("the value of ScatterType")
            if value not in ("BRDF", "BTDF"):
                raise tok.error(f"ScatterType {value!r}: expected BRDF or BTDF", vline)
            block[word] = value
        elif word == "TristimulusValue":
            value, vline = tok.take("the value of TristimulusValue")
            if value not in TRIS:
                raise tok.error(f"TristimulusValue {value!r}: expected TrisX, TrisY or TrisZ", vline)
            block["channel"] = TRIS[value]
        elif word == "TIS":
            n = len(blocks) + 1
            if "AOI" not in block:
                raise tok.error(f"block {n} has no AOI before its TIS", line)
            if content == "XYZ" and "channel" not in block:
                raise tok.error(f"block {n} of an XYZ file has no TristimulusValue before its TIS", line)
            block["tis"] = tok.number("the TIS value")
            block["values"] = tok.numbers(per, f"BSDF values (block {n}: {az.size} azimuths x {rad.size} radial "
                                               "angles)").reshape(az.size, rad.size)
            block.setdefault("POI", 0.0)
            block.setdefault("Side", "Front")
            block.setdefault("ScatterType", "BRDF")
            block.setdefault("channel", 0)
            blocks.append(block)
            block = {}
        else:
            raise tok.error(f"unexpected {word!r} in block {len(blocks) + 1} (expected AOI, POI, Side, ScatterType, "
                            "Wavelength, TristimulusValue, TIS or DataEnd)", line)
    if tok.peek() is not None:
        raise tok.error(f"unexpected {tok.peek()!r} after DataEnd")
    if not blocks:
        raise tok.error("no data blocks between DataBegin and DataEnd")
    return {"symmetry": sym, "fold": SYMMETRIES[sym], "content": content, "channels": CONTENTS[content],
            "azimuth": az, "radial": rad, "blocks": blocks}


def _gather(path, parsed: dict) -> dict:
    """The reflection blocks of one side on a full (POI, AOI) grid: ``data [θi, φi, az, rad, C]``,
    ``tis [θi, φi, C]``, the angles and what was skipped."""
    blocks = parsed["blocks"]
    kinds = {}
    for b in blocks:
        kinds.setdefault((b["Side"], b["ScatterType"]), []).append(b)
    side = "Front" if ("Front", "BRDF") in kinds else "Back" if ("Back", "BRDF") in kinds else None
    if side is None:
        raise FormatError(f"{path}: a LightTools file with transmission (BTDF) blocks only; brdftab holds reflection "
                          "(BRDF) only")
    kept = kinds[(side, "BRDF")]
    skipped = {f"{s} {t}": len(v) for (s, t), v in kinds.items() if (s, t) != (side, "BRDF")}
    for b in kept:
        if not 0.0 <= b["AOI"] <= 90.0:
            raise FormatError(f"{path}: line {b['line']}: AOI {b['AOI']:g}: expected an angle of incidence in [0, 90] "
                              "degrees")
        if not -360.0 <= b["POI"] <= 360.0:
            raise FormatError(f"{path}: line {b['line']}: POI {b['POI']:g}: expected a plane of incidence in "
                              "[-360, 360] degrees")
    aoi = np.array(sorted({b["AOI"] for b in kept}))
    poi = np.array(sorted({b["POI"] for b in kept}))
    waves = sorted({b["Wavelength"] for b in kept if "Wavelength" in b})
    if parsed["content"] == "Monochrome" and len(waves) > 1:
        raise FormatError(f"{path}: {side} BRDF blocks at {len(waves)} wavelengths ({waves[0]:g} to {waves[-1]:g} nm): "
                          "spectral LightTools data is not supported (Monochrome or XYZ files are)")
    nc = len(parsed["channels"])
    naz, nrad = parsed["azimuth"].size, parsed["radial"].size
    data = np.full((aoi.size, poi.size, naz, nrad, nc), np.nan)
    tis = np.full((aoi.size, poi.size, nc), np.nan)
    for b in kept:
        i, j, c = int(np.searchsorted(aoi, b["AOI"])), int(np.searchsorted(poi, b["POI"])), b["channel"]
        if not np.isnan(tis[i, j, c]):
            chan = "" if nc == 1 else f" {parsed['channels'][c]}"
            raise FormatError(f"{path}: line {b['line']}: a second {side} BRDF{chan} block at AOI {b['AOI']:g}, "
                              f"POI {b['POI']:g}")
        data[i, j, ..., c] = b["values"]
        tis[i, j, c] = b["tis"]
    missing = np.argwhere(np.isnan(tis))
    if missing.size:
        i, j, c = missing[0]
        chan = "" if nc == 1 else f" {parsed['channels'][c]}"
        raise FormatError(f"{path}: no {side} BRDF{chan} block at AOI {aoi[i]:g}, POI {poi[j]:g} ({len(missing)} of "
                          f"{tis.size} (AOI, POI, channel) blocks missing: every AOI needs a block for every POI)")
    return {"side": side, "aoi": aoi, "poi": poi, "data": data, "tis": tis, "skipped": skipped,
            "wavelength": waves[0] if waves else None}


def _outgoing_axis(path, parsed, poi, data):
    """brdftab's φo nodes [deg] of the file's azimuths and the data on them (``[..., az, rad, C]``):
    φo = azimuth − 90°; a list that goes once round (first and last 360° apart) keeps its first
    node; a PlaneSymmetrical file's azimuths must lie on one side of the plane of incidence and
    become |φo − φi| ∈ [0, 180°] from the plane (φi = POI)."""
    az = parsed["azimuth"]
    phi = az - AZIMUTH_OFFSET_DEG
    if parsed["fold"] == "none":
        if az.size > 1 and math.isclose(az[-1] - az[0], 360.0, abs_tol=1e-9):
            same = np.array_equal(data[..., 0, :, :], data[..., -1, :, :], equal_nan=True)
            if not same:
                warnings.warn(f"{path}: ScatterAzimuth {az[0]:g} and {az[-1]:g} deg are one direction but hold "
                              f"different values; the values at {az[0]:g} deg are kept", BrdftabWarning, stacklevel=4)
            return phi[:-1], data[..., :-1, :, :]
        return phi, data
    if poi.size != 1:
        raise FormatError(f"{path}: a PlaneSymmetrical file describes an isotropic surface (one POI), not {poi.size} "
                          f"planes of incidence")
    rel = np.mod(phi - poi[0] + 180.0, 360.0) - 180.0  # φo − φi in [−180, 180)
    side = np.abs(rel)  # a node on the other side holds the values of its mirror image
    off = (side > 1e-9) & (side < 180.0 - 1e-9)  # nodes off the plane of incidence
    if np.any(rel[off] > 0) and np.any(rel[off] < 0):
        raise FormatError(f"{path}: a PlaneSymmetrical file holds one side of the plane of incidence: ScatterAzimuth "
                          f"angles in [{AZIMUTH_OFFSET_DEG + poi[0]:g}, {AZIMUTH_OFFSET_DEG + poi[0] + 180:g}] or "
                          f"[{AZIMUTH_OFFSET_DEG + poi[0] - 180:g}, {AZIMUTH_OFFSET_DEG + poi[0]:g}] deg (the incident "
                          f"direction lies at azimuth POI + 90), got {az[0]:g} to {az[-1]:g}")
    order = np.argsort(side, kind="stable")
    side = side[order]
    if np.any(np.diff(side) <= 0):
        raise FormatError(f"{path}: PlaneSymmetrical ScatterAzimuth angles that are mirror images of each other")
    return poi[0] + side, data[..., order, :, :]


def read_lighttools(path):
    """Read a LightTools text ``.bsdf`` file into a :class:`~brdftab.table.Table` on a
    :class:`~brdftab.grids.SphericalGrid` holding the file's nodes (see the module docstring for
    the angles). The front side's reflection (BRDF) blocks are read, or the back side's when the
    file has no front ones; other blocks are skipped with one warning and a note in
    ``lighttools_skipped``."""
    path = Path(path)
    raw = read_bytes(path)
    text = _text(raw)
    if text is None or classify(raw[:CLASSIFY_BYTES])[0] != "lighttools":
        raise FormatError(f"{path}: not a LightTools text .bsdf file" + (" (binary bytes in it)" if text is None else
                                                                          " (no AOI blocks after its header)"))
    parsed = parse_lighttools(path, text)
    got = _gather(path, parsed)
    table = _table(path, parsed, got)
    compare_tis(table, got["tis"], parsed["channels"], path, "lighttools", ("AOI", got["aoi"]), ("POI", got["poi"]))
    if got["skipped"]:
        what = ", ".join(f"{n} {k}" for k, n in got["skipped"].items())
        warnings.warn(f"{path}: read the {got['side']} BRDF blocks; skipped {what} block(s) (brdftab holds one "
                      "side's reflection)", BrdftabWarning, stacklevel=2)
    return table


def _table(path, parsed, got):
    from ..channels import Layout
    from ..grids import SphericalGrid
    from ..table import Table, make_table

    phi_o, data = _outgoing_axis(path, parsed, got["poi"], got["data"])
    fold = "bilateral" if parsed["fold"] == "plane" else "none"
    grid = SphericalGrid(np.radians(got["aoi"]), np.radians(got["poi"]), np.radians(parsed["radial"]),
                         np.radians(phi_o), phi_d_fold=fold)
    # file order [az, rad] per block -> grid order [θi, φi, θo (radial), φo (azimuth), C]
    values = np.ascontiguousarray(np.swapaxes(data, 2, 3))
    name = path.name
    skipped = ", ".join(f"{n} {k}" for k, n in got["skipped"].items())
    provenance = {
        "title": f"LightTools BSDF {name}",
        "model": "unknown",
        "parameters": "{}",
        "isotropic": int(got["poi"].size == 1),
        "source_file": name,
        "source_format": "lighttools",
        "lighttools_symmetry": parsed["symmetry"],
        "lighttools_spectral_content": parsed["content"],
        "lighttools_side": got["side"],
        "lighttools_skipped": f"{skipped} block(s) skipped" if skipped else "none",
        "lighttools_quantity": "the file holds f_r [1/sr] (BSDF, not multiplied by cos(theta_o)); stored as read",
        "lighttools_angles": (f"theta_i = AOI, phi_i = POI, theta_o = ScatterRadial, phi_o = ScatterAzimuth - "
                              f"{AZIMUTH_OFFSET_DEG:g} deg (the file's incident direction lies at azimuth POI + "
                              f"{AZIMUTH_OFFSET_DEG:g} deg)"),
    }
    if got["wavelength"] is not None:
        provenance["lighttools_wavelength_nm"] = float(got["wavelength"])
    table = make_table(values, grid, Layout(parsed["channels"]), provenance=provenance)
    ds = table.ds
    ds.attrs["origin"] = "unknown"  # the format does not say whether its data were measured
    # nor whether they are reciprocal: the checks judge them as data (reported, never refused)
    for key in ("created", "brdftab_version", "history", "source", "reciprocal"):
        ds.attrs.pop(key, None)
    ds["lighttools_tis"] = (("theta_i", "phi_i", ds["brdf"].dims[-1]), got["tis"],
                            {"long_name": "TIS written in the LightTools file per incidence (total integrated "
                                          "scatter)"})
    out = Table(ds)
    out.origin = "unknown"
    return out


# --------------------------------------------------------------------------------------------
# Writing

_SYMMETRY_CHOICES = ("auto", "Asymmetric", "PlaneSymmetrical")
_CONTENT_CHOICES = ("auto", "Monochrome", "XYZ")
_GRID_OPTIONS = ("incidences_deg", "poi_deg", "azimuths_deg", "radials_deg")


def _plane_azimuths(az, poi):
    """φo − φi [deg] of PlaneSymmetrical azimuths, refused off the side [POI + 90, POI + 270]
    (mod 360) of the plane of incidence."""
    rel = np.mod(az - AZIMUTH_OFFSET_DEG - poi + 1e-9, 360.0) - 1e-9
    if rel.max() > 180 + 1e-9:
        raise ParameterError("azimuths_deg", f"PlaneSymmetrical holds one side of the plane of incidence: azimuths in "
                             f"[{poi + 90:g}, {poi + 270:g}] degrees (POI + 90 to POI + 270, modulo 360), got "
                             f"{az.min():g} to {az.max():g}")
    return np.clip(rel, 0.0, 180.0)


def check_options(symmetry="auto", spectral_content="auto", incidences_deg=None, poi_deg=None,
                  azimuths_deg=None, radials_deg=None, illuminant="D65", observer="cie1931-2", wavelengths_nm=None):
    """The writer's options checked (one :class:`ParameterError` naming the option)."""
    if symmetry not in _SYMMETRY_CHOICES:
        raise ParameterError("symmetry", f"expected 'auto', 'Asymmetric' or 'PlaneSymmetrical', got {symmetry!r}")
    if spectral_content not in _CONTENT_CHOICES:
        raise ParameterError("spectral_content", f"expected 'auto', 'Monochrome' or 'XYZ', got {spectral_content!r}")
    deg_list("incidences_deg", incidences_deg, 0, 90)
    poi = deg_list("poi_deg", poi_deg, -360, 360)
    az = deg_list("azimuths_deg", azimuths_deg, 0, 360)
    deg_list("radials_deg", radials_deg, 0, 90)
    if symmetry == "PlaneSymmetrical":
        if poi is not None and poi.size != 1:
            raise ParameterError("poi_deg", "PlaneSymmetrical describes an isotropic surface: one POI")
        if az is not None:
            _plane_azimuths(az, 0.0 if poi is None else float(poi[0]))
    if (illuminant, observer) != ("D65", "cie1931-2"):
        from ..colorimetry import from_options

        from_options(illuminant, observer)


def _grid(options, anisotropic):
    from ..grids import SphericalGrid

    plane = options.get("symmetry", "auto") == "PlaneSymmetrical"
    inc = deg_list("incidences_deg", options.get("incidences_deg"), 0, 90)
    poi = deg_list("poi_deg", options.get("poi_deg"), -360, 360)
    az = deg_list("azimuths_deg", options.get("azimuths_deg"), 0, 360)
    rad = deg_list("radials_deg", options.get("radials_deg"), 0, 90)
    inc = np.array(DEFAULT_INCIDENCES_DEG) if inc is None else inc
    if poi is None:
        poi = np.arange(0.0, 360.0, 30.0) if anisotropic and not plane else np.zeros(1)
    rad = np.array(DEFAULT_RADIALS_DEG) if rad is None else rad
    if plane:
        rel = np.arange(0.0, 181.0, 5.0) if az is None else np.sort(_plane_azimuths(az, float(poi[0])))
        phi_o = poi[0] + rel
    else:
        phi_o = (np.array(DEFAULT_AZIMUTHS_DEG) if az is None else az) - AZIMUTH_OFFSET_DEG
    return SphericalGrid(np.radians(inc), np.radians(poi), np.radians(rad), np.radians(phi_o),
                         phi_d_fold="bilateral" if plane else "none")


def _writable(grid, symmetry="auto") -> bool:
    """True for a spherical grid a LightTools file holds as it is (absolute outgoing angles,
    θo ≤ 90°): a mirror-symmetric grid (``phi_d_fold = "bilateral"``) as PlaneSymmetrical,
    another as Asymmetric (``symmetry = "auto"``: either)."""
    from ..grids import SphericalGrid

    if not isinstance(grid, SphericalGrid) or grid.relative_to != "none":
        return False
    if symmetry != "auto" and (grid.phi_d_fold == "bilateral") != (symmetry == "PlaneSymmetrical"):
        return False
    return True


def native_grid(requested, options: dict):
    """The spherical grid of the writer's options, or a requested one a LightTools file holds as
    it is (a table's own grid: a LightTools file read and converted is written on its nodes)."""
    if _writable(requested, options.get("symmetry", "auto")) and not any(k in options for k in _GRID_OPTIONS):
        return requested
    return _grid(options, anisotropic=False)


def prepare_lighttools(brdf, grid, symmetry="auto", spectral_content="auto", incidences_deg=None, poi_deg=None,
                       azimuths_deg=None, radials_deg=None, illuminant="D65", observer="cie1931-2",
                       wavelengths_nm=None):
    """The table (on a :class:`~brdftab.grids.SphericalGrid`) that :func:`write_lighttools`
    writes. Channels as in Zemax files (:func:`brdftab.formats.zemax.monochrome_or_xyz`): a grey
    source ``Monochrome``, RGB and spectral sources ``XYZ`` through colour-science. An
    anisotropic source needs several planes of incidence (default every 30°)."""
    from ..table import Table, tabulate, warn_specular_dropped

    options = dict(symmetry=symmetry, spectral_content=spectral_content, incidences_deg=incidences_deg,
                   poi_deg=poi_deg, azimuths_deg=azimuths_deg, radials_deg=radials_deg)
    check_options(**options, illuminant=illuminant, observer=observer)
    warn_specular_dropped(brdf, "a LightTools .bsdf file")
    explicit = any(v is not None for k, v in options.items() if k.endswith("_deg"))
    if _writable(grid, symmetry) and not explicit:
        target = grid
    else:
        target = _grid({k: v for k, v in options.items() if v is not None}, anisotropic=not brdf.isotropic)
    if not brdf.isotropic and len(target.axes[1]) == 1:
        raise FormatError(f"'{brdf.name}' is anisotropic and one plane of incidence would describe it at one incident "
                          "azimuth only; give poi_deg (e.g. every 30 degrees)")
    source, _ = monochrome_or_xyz(brdf, spectral_content, illuminant, observer, wavelengths_nm, "a LightTools file")
    if isinstance(source, Table) and source.grid.equals(target):
        return source
    return tabulate(source, target)


def _stored(payload, **_):
    return rounded(payload, "a LightTools file")


def write_lighttools(table, path, symmetry="auto", spectral_content="auto", incidences_deg=None, poi_deg=None,
                     azimuths_deg=None, radials_deg=None, illuminant="D65", observer="cie1931-2",
                     wavelengths_nm=None):
    """Write ``table`` (from :func:`prepare_lighttools`) as a LightTools text file: one block
    per (POI, AOI, channel), TIS = brdftab's directional albedo of the values as written."""
    grid = table.grid
    if not _writable(grid):
        raise FormatError(f"a LightTools file needs a table on a spherical grid with absolute outgoing angles, not on "
                          f"{grid.describe()}")
    if table.channels not in (("mono",), ("X", "Y", "Z")):
        raise FormatError(f"a LightTools file stores Monochrome or X, Y, Z channels, not {table.channels}")
    table = rounded(table, "a LightTools file")
    tis = tis_albedo(table)  # [θi, φi, C]
    ti, pi_, to, po = (np.degrees(a.values) for a in grid.axes)
    if to.max() > 90.0 + 1e-9:
        raise FormatError(f"a LightTools file holds reflection: theta_o up to 90 degrees, not {to.max():g}")
    plane = grid.phi_d_fold == "bilateral"
    az = np.mod(po + AZIMUTH_OFFSET_DEG, 360.0)
    az = np.where(np.isclose(az, 360.0, rtol=0, atol=1e-9), 0.0, az)
    order = np.argsort(az, kind="stable")
    az = az[order]
    values = np.asarray(table.values, float)[:, :, :, order, :]  # [θi, φi, θo, az, C]
    names = (None,) if table.channels == ("mono",) else ("TrisX", "TrisY", "TrisZ")
    fmt = f"%.{DIGITS - 1}E"

    def angles(vals):
        return "\t".join(f"{x:.10g}" for x in vals)

    lines = [f"# Written by brdftab from {table.name}: BRDF f_r [1/sr]; TIS = brdftab's directional albedo",
             "# angles: ScatterRadial = theta_o, ScatterAzimuth = phi_o + 90 deg; the incident direction lies at "
             "azimuth POI + 90 deg (formats/lighttools.md)",
             f"Symmetry  {'PlaneSymmetrical' if plane else 'Asymmetric'}",
             f"SpectralContent  {'Monochrome' if names == (None,) else 'XYZ'}",
             f"ScatterAzimuth  {az.size}", angles(az),
             f"ScatterRadial  {to.size}", angles(to),
             "DataBegin"]
    with open(path, "w", encoding="ascii", newline="\n") as fh:
        fh.write("\n".join(lines) + "\n")
        for j in range(pi_.size):
            for i in range(ti.size):
                for c, name in enumerate(names):
                    fh.write(f"AOI {ti[i]:.10g}\nPOI {pi_[j]:.10g}\nSide Front\nScatterType BRDF\n")
                    if name is not None:
                        fh.write(f"TristimulusValue {name}\n")
                    fh.write(f"TIS {tis[i, j, c]:.{DIGITS - 1}E}\n")
                    block = values[i, j, :, :, c].T  # rows: azimuths, columns: radial angles
                    fh.write("\n".join("\t".join(r) for r in np.char.mod(fmt, block)) + "\n")
        fh.write("DataEnd\n")


register(FileFormat(
    name="lighttools",
    extensions=(".bsdf",),
    description="LightTools text .bsdf: BRDF f_r [1/sr] (not times cos theta_o) per AOI/POI block on the outgoing "
                "direction's polar angle (ScatterRadial) and azimuth (ScatterAzimuth = phi_o + 90 deg), Monochrome "
                "or XYZ (TristimulusValue blocks), Asymmetric or PlaneSymmetrical, TIS = directional albedo per "
                "block (read: the front side's BRDF blocks, stored as read; write: Side Front, ScatterType BRDF; "
                ".bsdf writes RGL unless format = 'lighttools')",
    read=read_lighttools,
    write=write_lighttools,
    sniff=sniff,
    native_grid=native_grid,
    prepare=prepare_lighttools,
    check_options=check_options,
    stored=_stored,
    colour=True,
    params=(
        Param("symmetry", "choice", "Asymmetric (azimuths round the circle) or PlaneSymmetrical (one side of the "
              "plane of incidence, mirrored); auto: PlaneSymmetrical for a table on a mirror-symmetric spherical grid "
              "(a PlaneSymmetrical file read), else Asymmetric.", default="auto", choices=_SYMMETRY_CHOICES),
        Param("spectral_content", "choice", "Monochrome or XYZ (auto: Monochrome for a grey source, XYZ for RGB "
              "and spectral ones, through colour-science).", default="auto", choices=_CONTENT_CHOICES),
        Param("incidences_deg", "floats", "AOI: angles of incidence in degrees (default 0 to 85 every 5).",
              default=None, minimum=0.0, maximum=90.0),
        Param("poi_deg", "floats", "POI: planes of incidence = incident azimuths in degrees (default [0]; "
              "anisotropic sources every 30).", default=None, minimum=-360.0, maximum=360.0),
        Param("azimuths_deg", "floats", "ScatterAzimuth in degrees, = phi_o + 90 (default 0..355 every 5; "
              "PlaneSymmetrical POI + 90 .. POI + 270).", default=None, minimum=0.0, maximum=360.0),
        Param("radials_deg", "floats", "ScatterRadial = theta_o in degrees (default 0..90 every 2.5).", default=None,
              minimum=0.0, maximum=90.0),
    ) + COLOUR_PARAMS,
    precision=PRECISION,
))
