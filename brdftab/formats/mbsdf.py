"""NVIDIA MDL measured BSDF files (``.mbsdf``, ``NVIDIA ARC MBSDF V1``): read and write reflection data.

Layout (see ``formats/mbsdf.md``): the line ``NVIDIA ARC MBSDF V1`` (LF), free metadata lines,
the line ``MBSDF_DATA_REFLECTION=`` (or the older ``MBSDF_DATA=``), then little-endian uint32
``type`` (0 scalar, 1 RGB), ``res_theta``, ``res_phi`` and ``res_theta² · res_phi`` float32
samples (RGB interleaved), index ``(i_theta_in · res_theta + i_theta_out) · res_phi + i_phi``;
optionally a ``MBSDF_DATA_TRANSMISSION=`` block of the same structure; nothing after.

The samples are f_r [sr⁻¹] (no cosine factor) at the centres of uniform cells:
θ = (i + ½)·(π/2)/res_theta for θi and θo, and Δφ = |φo − φi| folded into [0, π] at
(k + ½)·π/res_phi — the table is isotropic and mirror-symmetric by construction. brdftab holds it
on a :class:`~brdftab.grids.SphericalGrid` with one φi node at 0, φo = Δφ, the domains [0, π/2]
and [0, π], and ``phi_d_fold = "bilateral"`` (:func:`mbsdf_grid`): netCDF and zarr store that grid,
and a table on it evaluates as the reader's does. Between the domain edges and the first or last
cell centre the table holds the end value (as the MDL runtime's clamped texture lookup does).

Reading keeps the metadata lines byte for byte (attribute ``mbsdf_metadata``), sets ``origin = "unknown"``
and declares no reciprocity (measured files are not reciprocal); a transmission block is skipped
with a warning (brdftab holds reflection only). Writing copies a table already on an ``.mbsdf``
grid value for value (with its metadata lines: ``.mbsdf`` → netCDF → ``.mbsdf`` is byte-identical)
and tabulates anything else at the cell centres; a grey source is written as type 0, an RGB one
as type 1, a spectral one in linear sRGB through colour-science. An anisotropic source needs
``phi_h_average`` and a non-reciprocal one ``symmetrize`` (as for MERL files): MDL renderers
symmetrize measured data on load, so the file would not render as written.
"""

from __future__ import annotations

import struct
import warnings
from pathlib import Path

import numpy as np

from .. import __version__
from ..colorimetry import PARAMS as COLOUR_PARAMS
from ..channels import Layout
from ..errors import BrdftabWarning, FormatError, ParameterError
from ..grids import SphericalGrid
from ..grids.axis import HALF_PI, uniform_values
from ..params import Param
from . import FileFormat, averaged, cast_samples, read_bytes, register
from .merl import _phi_h_samples

__all__ = ["read_mbsdf", "write_mbsdf", "prepare_mbsdf", "mbsdf_grid", "MAGIC", "REFLECTION", "LEGACY",
           "TRANSMISSION", "DEFAULT_RES_THETA", "DEFAULT_RES_PHI"]

MAGIC = b"NVIDIA ARC MBSDF V1\n"
REFLECTION = b"MBSDF_DATA_REFLECTION=\n"
LEGACY = b"MBSDF_DATA=\n"
TRANSMISSION = b"MBSDF_DATA_TRANSMISSION=\n"
#: The MDL SDK reads lines into a 1024-byte buffer: a longer line is split.
MAX_LINE = 1023
#: The resolution of NVIDIA's example files (MDL SDK ``examples/mdl/nvidia/sdk_examples/resources``).
DEFAULT_RES_THETA, DEFAULT_RES_PHI = 45, 90
#: Largest resolution accepted from a file or an option (a guard against a corrupted header).
MAX_RES = 4096
RGB = ("R", "G", "B")
GREY = ("mono",)
#: Table attribute holding the file's metadata lines, each ending in a newline, written back as they are.
METADATA_ATTR = "mbsdf_metadata"
#: Table attribute naming the encoding of metadata lines that are not UTF-8 (kept byte for byte).
ENCODING_ATTR = "mbsdf_metadata_encoding"
QUANTITY = ("f_r [sr-1] as stored: the file holds BSDF values without the cosine factor (no conversion), at cell "
            "centres theta = (i + 0.5) * 90 deg / res_theta and |phi_o - phi_i| = (k + 0.5) * 180 deg / res_phi")


def mbsdf_grid(res_theta: int = DEFAULT_RES_THETA, res_phi: int = DEFAULT_RES_PHI) -> SphericalGrid:
    """The grid of an ``.mbsdf`` file: θi, θo at the centres of ``res_theta`` cells over [0, π/2],
    one φi node at 0, φo = |φo − φi| at the centres of ``res_phi`` cells over [0, π] (bilateral fold)."""
    for name, n in (("res_theta", res_theta), ("res_phi", res_phi)):
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not 1 <= n <= MAX_RES:
            raise ParameterError(name, f"expected a whole number from 1 to {MAX_RES}, got {n!r}")
    theta = uniform_values(int(res_theta), 0.0, HALF_PI, "bin-centre")
    phi = uniform_values(int(res_phi), 0.0, np.pi, "bin-centre")
    return SphericalGrid(theta, [0.0], theta, phi, phi_d_fold="bilateral",
                         domains={"theta_i": (0.0, HALF_PI), "theta_o": (0.0, HALF_PI), "phi_o": (0.0, np.pi)})


def _grid_res(grid):
    """``(res_theta, res_phi)`` when ``grid`` is an ``.mbsdf`` grid, else None."""
    if not isinstance(grid, SphericalGrid) or grid.phi_d_fold != "bilateral":
        return None
    n, m = len(grid.axes[0]), len(grid.axes[3])
    if not (1 <= n <= MAX_RES and 1 <= m <= MAX_RES):
        return None
    return (n, m) if grid.equals(mbsdf_grid(n, m)) else None


# --------------------------------------------------------------------------------------------
# Reading


def _block(path, data: bytes, pos: int, what: str):
    """``(type, res_theta, res_phi, samples, end)`` of the block whose header starts at ``pos``."""
    if len(data) < pos + 12:
        raise FormatError(f"{path}: truncated .mbsdf file: the {what} block has {len(data) - pos} of its 12 header "
                          "bytes (type, res_theta, res_phi)")
    kind, rt, rp = struct.unpack_from("<3I", data, pos)
    if kind > 1:
        raise FormatError(f"{path}: .mbsdf {what} block of type {kind}; the format knows 0 (scalar) and 1 (RGB)")
    if rt == 0 or rp == 0:
        raise FormatError(f"{path}: .mbsdf {what} block with resolution res_theta = {rt}, res_phi = {rp}; both "
                          "must be at least 1")
    count = rt * rt * rp * (3 if kind else 1)  # Python integers: no overflow
    start, end = pos + 12, pos + 12 + 4 * count
    if end > len(data):
        raise FormatError(f"{path}: truncated .mbsdf file: the {what} block ({'RGB' if kind else 'scalar'}, "
                          f"res_theta = {rt}, res_phi = {rp}) needs {4 * count:,} bytes of samples, "
                          f"{len(data) - start:,} remain")
    if rt > MAX_RES or rp > MAX_RES:
        raise FormatError(f"{path}: .mbsdf {what} block resolution {rt} x {rp} exceeds {MAX_RES}")
    return kind, rt, rp, np.frombuffer(data, "<f4", count, start), end


def _text(lines: list) -> tuple:
    """``(text, encoding)`` of the metadata lines, each ending in a newline: UTF-8, else Latin-1
    (free bytes, kept one to one)."""
    raw = b"".join(lines)
    try:
        return raw.decode("utf-8"), "utf-8"
    except UnicodeDecodeError:
        return raw.decode("latin-1"), "latin-1"


def read_mbsdf(path):
    """Read the reflection block of an ``.mbsdf`` file into a :class:`~brdftab.table.Table`."""
    from ..table import Table, make_table

    path = Path(path)
    data = read_bytes(path)
    if not data.startswith(MAGIC):
        if data.startswith(MAGIC[:-1] + b"\r\n"):
            raise FormatError(f"{path}: .mbsdf lines end in CRLF; the format (and the MDL SDK) needs LF line ends")
        raise FormatError(f"{path}: not an NVIDIA MDL .mbsdf file (its first line is not 'NVIDIA ARC MBSDF V1')")
    pos, meta, marker = len(MAGIC), [], None
    while marker is None:
        nl = data.find(b"\n", pos)
        if nl < 0:
            raise FormatError(f"{path}: .mbsdf file without reflection data (no line MBSDF_DATA_REFLECTION=); "
                              "brdftab reads the reflection block")
        line = data[pos:nl + 1]
        pos = nl + 1
        if line in (REFLECTION, LEGACY):
            marker = line
        elif line == TRANSMISSION:
            raise FormatError(f"{path}: .mbsdf file with transmission data only; brdftab reads the reflection "
                              "block (a BRDF), which this file lacks")
        elif line.endswith(b"\r\n") and line[:-2] + b"\n" in (REFLECTION, LEGACY, TRANSMISSION):
            raise FormatError(f"{path}: .mbsdf lines end in CRLF; the format (and the MDL SDK) needs LF line ends")
        else:
            meta.append(line)
    kind, rt, rp, samples, end = _block(path, data, pos, "reflection")
    rest = data[end:]
    if rest.startswith(TRANSMISSION):
        tk, trt, trp, _, tend = _block(path, data, end + len(TRANSMISSION), "transmission")
        if tend != len(data):
            raise FormatError(f"{path}: {len(data) - tend:,} bytes after the transmission block; an .mbsdf file ends "
                              "there")
        warnings.warn(f"{path}: transmission block ({'RGB' if tk else 'scalar'}, {trt} x {trt} x {trp}) skipped: "
                      "brdftab holds reflection (a BRDF) only", BrdftabWarning, stacklevel=3)
    elif rest:
        raise FormatError(f"{path}: {len(rest):,} bytes after the reflection block; an .mbsdf file ends there or "
                          "with a MBSDF_DATA_TRANSMISSION= block")
    values = samples.reshape(rt, 1, rt, rp, 3 if kind else 1).astype(np.float64)
    provenance = {
        "title": f"NVIDIA MDL measured BSDF {path.name}",
        "model": "unknown",  # an .mbsdf file names no model: it is data
        "material": path.stem,
        "parameters": "{}",
        "isotropic": 1,
        "origin": "unknown",
        "source_file": path.name,
        "source_format": "mbsdf",
        "source_quantity": QUANTITY,
        "mbsdf_type": "rgb" if kind else "scalar",
    }
    provenance[METADATA_ATTR], encoding = _text(meta)
    if encoding != "utf-8":
        provenance[ENCODING_ATTR] = encoding
    if marker == LEGACY:
        provenance["mbsdf_data_marker"] = LEGACY[:-1].decode()
    table = make_table(values, mbsdf_grid(rt, rp), Layout(RGB if kind else GREY), provenance=provenance)
    for key in ("created", "brdftab_version", "history", "source", "reciprocal", "spec_sha256"):
        table.ds.attrs.pop(key, None)  # a file records none of them; reciprocity is not declared
    return Table(table.ds)


def sniff(head: bytes, size: int) -> bool:
    """The magic line, also with a CRLF end (read to say what is wrong with it)."""
    return head.startswith(MAGIC) or head.startswith(MAGIC[:-1] + b"\r\n")


# --------------------------------------------------------------------------------------------
# Writing


def _quoted(value) -> str:
    text = str(value).replace("\\", "\\\\").replace('"', '\\"').replace("\r", "\\r").replace("\n", "\\n")
    return f'"{text}"'


def _metadata_lines(table) -> list:
    """The metadata lines (bytes, without their newline) written for ``table``: those of the file
    it was read from, else what brdftab knows of its source (``key="quoted value"``, the MDL
    convention)."""
    attrs = table.ds.attrs
    if METADATA_ATTR in attrs:
        encoding = "latin-1" if attrs.get(ENCODING_ATTR) == "latin-1" else "utf-8"
        raw = str(attrs[METADATA_ATTR]).encode(encoding)
        return raw[:-1].split(b"\n") if raw.endswith(b"\n") else raw.split(b"\n") if raw else []
    items = [("description", attrs.get("title", table.name)), ("model", attrs.get("model")),
             ("parameters", attrs.get("parameters")), ("spec_sha256", attrs.get("spec_sha256")),
             ("origin", getattr(table, "origin", None)), ("quantity", QUANTITY),
             ("colour", attrs.get("mbsdf_colour")), ("creator", f"brdftab {__version__}")]
    lines = []
    for key, value in items:
        if value in (None, "", "{}"):
            continue
        line = f"{key}={_quoted(value)}".encode("utf-8")
        if len(line) > MAX_LINE:
            continue  # the MDL SDK reads 1024-byte lines: a longer one would be split
        lines.append(line)
    return lines


def write_mbsdf(table, path, res_theta=None, res_phi=None, phi_h_average=False, symmetrize=False, **colour):
    """Write ``table`` (on an ``.mbsdf`` grid, grey or R, G, B; see :func:`prepare_mbsdf`) to ``path``."""
    res = _grid_res(table.grid)
    if res is None:
        raise FormatError(f"an .mbsdf file needs a table on the .mbsdf grid, not on {table.grid.describe()}")
    if table.channels not in (GREY, RGB):
        raise FormatError(f"an .mbsdf file stores one grey channel or R, G, B, not {table.channels or 'a spectrum'}")
    lines = _metadata_lines(table)
    for k, line in enumerate(lines):
        if line + b"\n" in (REFLECTION, LEGACY, TRANSMISSION):
            raise FormatError(f"metadata line {k + 1} ({line[:40]!r}) would be read as a data marker")
    marker = LEGACY if table.ds.attrs.get("mbsdf_data_marker") == LEGACY[:-1].decode() else REFLECTION
    kind = int(table.channels == RGB)
    values = np.asarray(table.values)[:, 0]  # [θi, θo, Δφ, C]
    samples = np.ascontiguousarray(values if kind else values[..., 0], dtype="<f4")
    with open(path, "wb") as fh:
        fh.write(MAGIC)
        for line in lines:
            fh.write(line + b"\n")
        fh.write(marker)
        fh.write(struct.pack("<3I", kind, *res))
        fh.write(memoryview(samples).cast("B"))


def native_grid(requested, options: dict):
    """The ``.mbsdf`` grid of the requested resolution, else the requested ``.mbsdf`` grid, else 45 x 90."""
    res = _grid_res(requested)
    rt, rp = options.get("res_theta"), options.get("res_phi")
    if res is not None and rt in (None, res[0]) and rp in (None, res[1]):
        return requested
    return mbsdf_grid(DEFAULT_RES_THETA if rt is None else rt, DEFAULT_RES_PHI if rp is None else rp)


def check_options(res_theta=None, res_phi=None, phi_h_average=False, symmetrize=False, illuminant="D65",
                  observer="cie1931-2", wavelengths_nm=None):
    mbsdf_grid(DEFAULT_RES_THETA if res_theta is None else res_theta, DEFAULT_RES_PHI if res_phi is None else res_phi)
    _phi_h_samples(phi_h_average)
    if not isinstance(symmetrize, bool):
        raise ParameterError("symmetrize", f"expected true or false, got {symmetrize!r}")
    if (illuminant, observer) != ("D65", "cie1931-2"):
        from ..colorimetry import from_options

        from_options(illuminant, observer)


def prepare_mbsdf(brdf, grid, res_theta=None, res_phi=None, phi_h_average=False, symmetrize=False, illuminant="D65",
                  observer="cie1931-2", wavelengths_nm=None):
    """The grey or RGB table on an ``.mbsdf`` grid that :func:`write_mbsdf` writes for ``brdf``.

    A table already on the target grid is copied (its values as they are, asymmetry included).
    Anything else is tabulated at the cell centres; an anisotropic source needs ``phi_h_average``
    (its mean over rotations about the normal is written) and a non-reciprocal one ``symmetrize``
    (``(f(wi, wo) + f(wo, wi)) / 2``). A spectral source is written in linear sRGB converted
    through colour-science (:func:`brdftab.colorimetry.convert_for_writer`), recorded in a
    metadata line.
    """
    from ..colorimetry import convert_for_writer, from_options
    from ..table import Table, tabulate, warn_specular_dropped

    check_options(res_theta, res_phi, phi_h_average, symmetrize, illuminant, observer, wavelengths_nm)
    warn_specular_dropped(brdf, "the MDL .mbsdf format")
    colour_note = None
    if brdf.spectral:
        converted = convert_for_writer(brdf, "MDL .mbsdf", illuminant, observer, wavelengths_nm, announce=False)
        lam = getattr(converted, "wavelengths_nm", None)
        if lam is None:
            lam = [float(x) for x in str(converted.ds.attrs.get("colour_wavelengths_nm", "")).split(",") if x.strip()]
        colour_note = (f"{from_options(illuminant, observer).describe()} from {len(lam)} wavelengths "
                       f"({min(lam):g}-{max(lam):g} nm) through colour-science")
        brdf = converted
    target = native_grid(grid, {"res_theta": res_theta, "res_phi": res_phi})
    if brdf.spectral or brdf.channels not in (GREY, RGB):
        raise FormatError(f"an .mbsdf file stores one grey channel or R, G, B; '{brdf.name}' has channels "
                          f"{', '.join(brdf.channels or ('a spectrum',))}")
    n_phi_h = _phi_h_samples(phi_h_average)
    if isinstance(brdf, Table) and target.equals(brdf.grid) and not n_phi_h and not symmetrize:
        return brdf
    if not brdf.isotropic and not n_phi_h:
        raise FormatError(f".mbsdf files are isotropic (they hold |phi_o - phi_i|) and '{brdf.name}' is anisotropic; "
                          "pass phi_h_average = true (or a number of rotations) to write its average over rotations "
                          "about the normal")
    if not brdf.reciprocal and not symmetrize:
        raise FormatError(f"'{brdf.name}' is not reciprocal and MDL renderers symmetrize .mbsdf data when they load "
                          "it; pass symmetrize = true to write (f(wi, wo) + f(wo, wi)) / 2")
    source, provenance = averaged(brdf, n_phi_h, symmetrize)
    if colour_note:
        provenance["mbsdf_colour"] = colour_note
    return tabulate(source, target, provenance=provenance or None)


def stored_mbsdf(table, **options):
    """The table as the file holds it: samples rounded to float32."""
    return cast_samples(table, np.float32)


register(FileFormat(
    name="mbsdf",
    extensions=(".mbsdf",),
    description="NVIDIA MDL measured BSDF: writes and reads f_r [sr-1, no cosine] at cell centres of "
                "theta_i x theta_o x |phi_o - phi_i|, grey or RGB float32 (reflection; a transmission block is "
                "skipped on read)",
    read=read_mbsdf,
    write=write_mbsdf,
    magic=(MAGIC,),
    sniff=sniff,
    native_grid=native_grid,
    prepare=prepare_mbsdf,
    check_options=check_options,
    colour=True,
    params=(
        Param("res_theta", "int", f"theta_i and theta_o cells over [0, 90) deg (default {DEFAULT_RES_THETA}, as "
              "NVIDIA's example files; a table already on an .mbsdf grid keeps its own).", default=None, minimum=1,
              maximum=MAX_RES),
        Param("res_phi", "int", f"|phi_o - phi_i| cells over [0, 180] deg (default {DEFAULT_RES_PHI}).", default=None,
              minimum=1, maximum=MAX_RES),
        Param("phi_h_average", "count", "Write the average of an anisotropic BRDF over rotations about the normal: "
              "true (36 rotations) or a count.", default=False, minimum=2, maximum=3600),
        Param("symmetrize", "bool", "Write (f(wi, wo) + f(wo, wi)) / 2 of a non-reciprocal BRDF.", default=False),
    ) + COLOUR_PARAMS,
    precision=6e-8,  # float32 samples: 2**-24 relative, kept by interpolation of positive values
    stored=stored_mbsdf,
))
