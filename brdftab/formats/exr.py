"""BRDF slices as OpenEXR images (``.exr``), through the OpenEXR 3.x ``OpenEXR.File`` API.

One image per φd value of an isotropic Rusinkiewicz table (see ``formats/exr.md``):
x = θh (column 0 = first θh node), y = θd (the bottom scanline = first θd node, θd = 0 at the
bottom as in the BRDF Explorer), the centre of pixel (i, j) is node (θh_i, θd_j). Values are
f_r in sr⁻¹ (no cosine) as float32, in channels R, G, B, Y (grey) or one channel per
wavelength (``550nm``). A file with one φd is a single-part image; a file with several is a
multi-part file with one part per φd. The first part's header records the table once: the
parameterization, the θh warp and nodes, units, whether the cosine is included, and the model
and its parameters (numbers as doubles: 1-element float64 arrays); every part records its φd
(and, for RGB, the Rec. 709 ``chromaticities``). Layout attributes of other writers are
honoured (transposed or top-origin images, a declared θh warp) or refused with one line.

Converting a table to ``.exr`` writes all of its φd nodes by default, and reading the file
gives the table back (values exact at float32, grid equal). ``phi_d_deg`` chooses slices.

OpenEXR is optional: it is imported inside the functions that need it.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np
import xarray as xr

from ..colorimetry import PARAMS as COLOUR_PARAMS
from ..channels import Layout
from ..params import Param
from ..errors import BrdftabError, FormatError, ParameterError, shown
from ..grids import RusinkiewiczGrid, merl_grid
from . import FileFormat, cast_samples, read_head, register

__all__ = ["read_exr", "write_exr", "native_grid", "check_options", "MAGIC"]

MAGIC = b"\x76\x2f\x31\x01"
AXES = ("theta_h", "theta_d", "phi_d")
_LONG_NAMES = {"theta_h": "polar angle of the half vector", "theta_d": "polar angle of the difference vector",
               "phi_d": "azimuth of the difference vector"}
#: Attribute names the EXR format defines itself; table attributes never take these names.
_EXR_STANDARD = frozenset((
    "channels", "compression", "dataWindow", "displayWindow", "lineOrder", "pixelAspectRatio",
    "screenWindowCenter", "screenWindowWidth", "name", "type", "version", "chunkCount", "tiles", "view",
    "multiView", "comments", "owner", "capDate", "utcOffset", "chromaticities", "whiteLuminance",
    "adoptedNeutral", "envmap", "wrapmodes", "framesPerSecond", "preview", "deepImageState",
    "originalDataWindow", "dwaCompressionLevel", "zipCompressionLevel", "xDensity", "longitude", "latitude",
    "altitude", "focus", "expTime", "aperture", "isoSpeed", "keyCode", "timeCode",
))
#: Attributes describing the slice layout (not copied back into the table's attributes).
_LAYOUT = frozenset(
    ["slice_layout", "x_axis", "y_axis", "y_origin", "pixel_position", "theta_h_warp", "units", "angle_units",
     "cosine_included", "quantity", "channel_names", "wavelengths_nm", "valid_min", "valid_max", "missing_value",
     "phi_d_rad",
     "phi_d_deg", "phi_d_index", "n_phi_d"]
    + [f"{a}_{s}" for a in AXES for s in ("rad", "node_rule", "domain_rad")])
#: Table attributes that describe a netCDF file, not an EXR image (not written to EXR headers).
_NETCDF_ONLY = frozenset(("Conventions",))
#: The primaries and white point of brdftab's RGB (Rec. 709 / sRGB, D65; the luminance weights of
#: :data:`brdftab.channels.RGB_LUMINANCE`): (red x, y, green x, y, blue x, y, white x, y).
REC709 = (0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127, 0.3290)
#: Largest number of ``param.*`` attributes per part.
MAX_PARAM_ATTRS = 256
#: Largest φd slice count and image side a file may declare.
MAX_PARTS = 100_000
MAX_SIDE = 1_000_000


def _openexr():
    import OpenEXR

    if not hasattr(OpenEXR, "File"):
        raise BrdftabError(f"format exr needs OpenEXR >= 3.3 (the OpenEXR.File API); installed: "
                           f"{getattr(OpenEXR, '__version__', 'an older version')} (pip install -U OpenEXR)")
    return OpenEXR


# --------------------------------------------------------------------------------------------
# Grids and options


_COLOUR = ("rgb", "spectral")


def check_options(phi_d_deg=None, colour="rgb", illuminant="D65", observer="cie1931-2"):
    _slices(phi_d_deg)
    if not isinstance(colour, str) or colour not in _COLOUR:
        raise ParameterError("colour", f"expected 'rgb' or 'spectral', got {colour!r}")
    if (illuminant, observer) != ("D65", "cie1931-2"):
        from ..colorimetry import from_options

        from_options(illuminant, observer)


def _in_colour(table, colour="rgb", illuminant="D65", observer="cie1931-2"):
    """The table an EXR file holds: a spectral table converted to linear sRGB through
    colour-science (:mod:`brdftab.colorimetry`, recorded in the header) unless ``colour`` is
    ``"spectral"`` (one channel per wavelength, named like ``550nm``)."""
    if not table.spectral or colour == "spectral":
        return table
    from ..colorimetry import from_options, table_to_colour

    return table_to_colour(table, from_options(illuminant, observer))


def stored_exr(table, phi_d_deg=None, colour="rgb", illuminant="D65", observer="cie1931-2"):
    """What a reader of the EXR file gets back: the table in colour (:func:`_in_colour`), its
    samples rounded to float32 pixels."""
    return cast_samples(_in_colour(table, colour, illuminant, observer), np.float32)


def _slices(phi_d_deg):
    """φd values [rad] from the ``phi_d_deg`` option (None: every φd node of the grid)."""
    if phi_d_deg is None:
        return None
    items = phi_d_deg if isinstance(phi_d_deg, (list, tuple)) else [phi_d_deg]
    if not items or len(items) > MAX_PARTS or any(
            isinstance(x, bool) or not isinstance(x, (int, float, np.integer, np.floating)) or not np.isfinite(x)
            for x in items):
        raise ParameterError("phi_d_deg", f"expected a list of phi_d angles in degrees, got {phi_d_deg!r}")
    deg = np.asarray(items, float)
    if np.unique(deg).size != deg.size:
        raise ParameterError("phi_d_deg", "phi_d angles must be distinct")
    return np.radians(np.sort(deg))


def native_grid(requested, options: dict):
    """An isotropic Rusinkiewicz grid: the requested one (the MERL grid when none is asked for),
    with the φd nodes replaced by the ``phi_d_deg`` slices when given."""
    base = merl_grid() if requested is None else requested
    if not _is_isotropic_rusinkiewicz(base):
        raise ParameterError("grid", f"EXR slices are theta_h x theta_d images of an isotropic Rusinkiewicz grid, "
                             f"not of {base.describe()}; use a 'merl' or isotropic 'rusinkiewicz' grid")
    phi = _slices(options.get("phi_d_deg"))
    if phi is None:
        return base
    return _slice_grid(base, phi)


def _is_isotropic_rusinkiewicz(grid) -> bool:
    return (isinstance(grid, RusinkiewiczGrid) and grid.attrs().get("parameterization") == "rusinkiewicz"
            and grid.dims == AXES)


def _slice_grid(base, phi):
    th, td, _ = base.axes
    pos = base.sample_position

    def spec(ax):
        return len(ax) if ax.rule == pos else ax.values

    spacing = base.theta_h_spacing if th.rule == pos else "linear"
    try:
        return RusinkiewiczGrid(spec(th), spec(td), phi, theta_h_spacing=spacing, phi_d_fold=base.phi_d_fold,
                                sample_position=pos, name="rusinkiewicz")
    except ParameterError as exc:
        raise ParameterError("phi_d_deg", exc.detail) from None


# --------------------------------------------------------------------------------------------
# Writing


def _number_text(x: float) -> str:
    s = repr(float(x))
    return s[:-2] if s.endswith(".0") else s


def _exr_channels(table) -> list:
    if table.spectral:
        return [f"{_number_text(lam)}nm" for lam in table.wavelengths]
    if table.channels == ("mono",):
        return ["Y"]
    return list(table.channels)


def _double(x) -> np.ndarray:
    return np.array([float(x)], dtype=np.float64)


def _attr_value(v):
    """A table attribute as an EXR header value (None: not representable)."""
    if isinstance(v, np.ndarray) and v.ndim == 0:
        v = v.item()
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, bool):
        return int(v)
    if isinstance(v, int):
        return v if -2**31 <= v < 2**31 else _double(v)
    if isinstance(v, float):
        return _double(v)
    if isinstance(v, str):
        return shown(v)  # a file name's bytes that are not UTF-8 as \xNN escapes
    return None


def _param_attrs(params: dict) -> dict:
    """Numbers and strings of the (nested) model parameters as ``param.<path>`` attributes."""
    out = {}

    def walk(key, v):
        if len(out) >= MAX_PARAM_ATTRS:
            return
        if isinstance(v, bool):
            out[key] = int(v)
        elif isinstance(v, (int, float)):
            out[key] = _double(v)
        elif isinstance(v, str):
            out[key] = shown(v)
        elif isinstance(v, dict):
            for k, x in v.items():
                walk(f"{key}.{k}", x)
        elif isinstance(v, list) and len(v) <= 16:
            for i, x in enumerate(v):
                walk(f"{key}.{i}", x)

    if isinstance(params, dict):
        for k, v in params.items():
            walk(f"param.{k}", v)
    return out


def _header(table, names) -> dict:
    """Attributes every part carries (the per-part φd is added by the caller)."""
    grid = table.grid
    hdr = {}
    for key, v in table.ds.attrs.items():
        val = _attr_value(v)
        if val is not None and key not in _EXR_STANDARD and key not in _LAYOUT and key not in _NETCDF_ONLY:
            hdr[key] = val
    th = grid.axes[0]
    hdr.update({
        "slice_layout": "x = theta_h (column 0 = first node), y = theta_d (bottom row = first node, theta_d = 0 "
                        "at the bottom); pixel centres sit at the nodes; one image (part) per phi_d",
        "x_axis": "theta_h",
        "y_axis": "theta_d",
        "y_origin": "bottom",
        "pixel_position": "centre",
        "theta_h_warp": "sqrt" if th.warp == "sqrt" else "linear",
        "units": "sr-1",
        "angle_units": "rad",
        "cosine_included": 0,
        "quantity": "f_r = dL_o / dE_i (not multiplied by cos(theta_o), not a reflectance factor)",
        "channel_names": list(names),
    })
    for ax in grid.axes:
        ca = grid.coord_attrs(ax.name)
        hdr[f"{ax.name}_node_rule"] = str(ca.get("node_rule", getattr(ax, "rule", "explicit")))
        if "domain" in ca:
            hdr[f"{ax.name}_domain_rad"] = np.asarray(ca["domain"], np.float64).reshape(2)
    hdr["theta_h_rad"] = json.dumps([float(x) for x in grid.axes[0].values])
    hdr["theta_d_rad"] = json.dumps([float(x) for x in grid.axes[1].values])
    if table.spectral:
        hdr["wavelengths_nm"] = json.dumps([float(x) for x in table.wavelengths])
    for key in ("valid_min", "valid_max"):
        if key in table.ds["brdf"].attrs:
            hdr[key] = _double(np.asarray(table.ds["brdf"].attrs[key]).ravel()[0])
    if "missing_value" in table.ds["brdf"].attrs:  # CF missing markers (a netCDF's _FillValue): still missing
        markers = np.asarray(table.ds["brdf"].attrs["missing_value"], np.float64).ravel()
        hdr["missing_value"] = json.dumps([None if np.isnan(x) else float(x) for x in markers])
    hdr.update(_param_attrs(table.parameters))
    hdr.update(_albedo_attrs(table.ds))
    return hdr


def _albedo_attrs(ds) -> dict:
    """The stored albedo curve (variables ``albedo``, ``albedo_white_sky``) as JSON text
    attributes, the form EXR headers hold lists in; read back into the variables."""
    from ..table import ALBEDO_DIM, ALBEDO_VAR, ALBEDO_WHITE_SKY

    if ALBEDO_VAR not in ds.data_vars or ALBEDO_DIM not in ds.variables:
        return {}
    var = ds[ALBEDO_VAR]
    labels = [str(x) for x in np.asarray(ds[var.dims[1]].values)] if var.dims[1] in ds.variables else []
    if var.dims[1] == "wavelength":
        labels = [f"{float(x):g} nm" for x in ds["wavelength"].values]

    def plain(a):
        return [None if not np.isfinite(x) else float(x) for x in np.asarray(a, float).ravel()]

    theta = np.degrees(np.asarray(ds[ALBEDO_DIM].values, float)).round(9)
    out = {"albedo_theta_i_deg": json.dumps(theta.tolist()),
           "albedo_values": json.dumps([plain(row) for row in np.asarray(var.values, float)]),
           "albedo_channels": json.dumps(labels)}
    if ALBEDO_WHITE_SKY in ds.data_vars:
        out["albedo_white_sky"] = json.dumps(plain(ds[ALBEDO_WHITE_SKY].values))
    return out


def write_exr(table, path, phi_d_deg=None, colour="rgb", illuminant="D65", observer="cie1931-2"):
    """Write ``table`` (an isotropic Rusinkiewicz table) as one EXR image per φd node; a
    spectral table in linear sRGB unless ``colour = "spectral"`` (:func:`_in_colour`)."""
    from ..table import warn_specular_dropped

    check_options(phi_d_deg, colour, illuminant, observer)
    table = _in_colour(table, colour, illuminant, observer)
    OpenEXR = _openexr()
    if not _is_isotropic_rusinkiewicz(table.grid):
        raise FormatError(f"EXR slices need a table on an isotropic Rusinkiewicz grid, not on "
                          f"{table.grid.describe()}")
    warn_specular_dropped(table, "the EXR format")
    names = _exr_channels(table)
    if len(set(names)) != len(names) or not all(names):
        raise FormatError(f"EXR channel names must be distinct and non-empty, got {names}")
    meta = _header(table, names)
    image = {"compression": OpenEXR.ZIP_COMPRESSION}  # what every part has
    if names == ["R", "G", "B"]:
        image["chromaticities"] = REC709
    with np.errstate(over="ignore"):
        v32 = np.asarray(table.values).astype(np.float32)
    phi = table.grid.axes[2].values
    parts = []
    for k, p in enumerate(phi):
        # the table's metadata once, in the first part; the others say only which phi_d they hold
        hdr = {**(meta if k == 0 else {}), **image}
        hdr.update({"phi_d_rad": _double(p), "phi_d_deg": _double(np.degrees(p)), "phi_d_index": k,
                    "n_phi_d": int(phi.size)})
        # image row 0 is the top scanline: the last theta_d node
        chans = {name: np.ascontiguousarray(v32[:, ::-1, k, c].T) for c, name in enumerate(names)}
        parts.append((hdr, chans))
    try:
        if len(parts) == 1:
            hdr, chans = parts[0]
            hdr["type"] = OpenEXR.scanlineimage
            out = OpenEXR.File(hdr, chans)
        else:
            width = len(str(len(parts) - 1))
            out = OpenEXR.File([OpenEXR.Part(hdr, chans, f"phi_d {k:0{width}d}") for k, (hdr, chans)
                                in enumerate(parts)])
        with out:
            out.write(str(path))
    except (RuntimeError, ValueError, TypeError) as exc:
        raise FormatError(f"{path}: cannot write the EXR file ({_first_line(str(exc))})") from None


# --------------------------------------------------------------------------------------------
# Reading


@contextlib.contextmanager
def _quiet():
    """Collect what the OpenEXR library prints (on the C stderr and Python's stdout) into a list
    instead of showing it; the list is filled when the block ends."""
    log = []
    buf = io.StringIO()
    saved = tmp = None
    try:
        sys.stderr.flush()
        tmp = tempfile.TemporaryFile()
        saved = os.dup(2)
        os.dup2(tmp.fileno(), 2)
    except (OSError, ValueError, AttributeError):
        if tmp is not None:
            tmp.close()
        saved = tmp = None
    try:
        with contextlib.redirect_stdout(buf):
            yield log
    finally:
        err = ""
        if saved is not None:
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            err = tmp.read(4096).decode("utf-8", "replace")
            tmp.close()
        log.extend(line.strip() for line in (err + "\n" + buf.getvalue()).splitlines() if line.strip())


def _first_line(text: str) -> str:
    text = text.strip()
    line = text.splitlines()[0] if text else ""
    return line[:200]


def _reason(exc, log, path) -> str:
    """The library's first message (without the file name it repeats), else the exception's."""
    for line in list(log) + [str(exc) if exc is not None else ""]:
        line = line.replace(f" '{path}'", "").replace(f'"{path}"', "file")
        if line.startswith(f"{path}:"):
            line = line[len(str(path)) + 1:]
        if line.strip():
            return _first_line(line)
    return type(exc).__name__ if exc is not None else "unknown error"


def _call(path, what, fn):
    """Run ``fn`` quietly; a library failure becomes one FormatError line naming the file."""
    with _quiet() as log:
        try:
            result, err = fn(), None
        except (RuntimeError, ValueError, TypeError, KeyError, IndexError, UnicodeError, MemoryError,
                OverflowError, AttributeError) as exc:
            result, err = None, exc
    if err is not None:
        raise FormatError(f"{path}: {what} ({_reason(err, log, path)})") from None
    return result, log


def _markers(path, text) -> np.ndarray:
    """The ``missing_value`` header: a JSON list of marker values (null: NaN samples are missing)."""
    try:
        vals = json.loads(text) if isinstance(text, str) else None
    except ValueError:
        vals = None
    if (not isinstance(vals, list) or not vals
            or not all(x is None or (isinstance(x, (int, float)) and not isinstance(x, bool)) for x in vals)):
        raise FormatError(f"{path}: attribute missing_value must be a JSON list of numbers (null for NaN)")
    return np.asarray([np.nan if x is None else x for x in vals], np.float32)


def _scalar(v):
    """A number from an attribute value (1-element array, int or float), else None."""
    if isinstance(v, bool):
        return None
    if isinstance(v, (int, float)):
        return float(v)
    if isinstance(v, np.ndarray) and v.size == 1 and v.dtype.kind in "fi":
        return float(v.ravel()[0])
    return None


def _window(path, k, hdr):
    try:
        lo, hi = hdr["dataWindow"]
        lo = np.asarray(lo, np.int64).ravel()
        hi = np.asarray(hi, np.int64).ravel()
        w, h = int(hi[0] - lo[0] + 1), int(hi[1] - lo[1] + 1)
    except (KeyError, TypeError, ValueError, IndexError):
        raise FormatError(f"{path}: part {k}: missing or malformed dataWindow") from None
    if not (1 <= w <= MAX_SIDE and 1 <= h <= MAX_SIDE):
        raise FormatError(f"{path}: part {k}: image size {w} x {h} is out of range")
    return w, h


def _node_list(path, hdr, key, n, per):
    text = hdr.get(key)
    if text is None:
        return None
    try:
        vals = json.loads(text) if isinstance(text, str) else None
    except ValueError:
        vals = None
    if (not isinstance(vals, list) or len(vals) != n
            or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in vals)):
        raise FormatError(f"{path}: attribute {key} must be a JSON list of {n} angles in radians (one per {per})")
    return np.asarray(vals, float)


def _layout_of(path, hdr, present):
    """``(EXR channel names in table order, Layout)`` from the header and the channels present."""
    names = hdr.get("channel_names")
    if names is not None:
        if not isinstance(names, list) or not names or not all(isinstance(n, str) and n for n in names) \
                or len(set(names)) != len(names):
            raise FormatError(f"{path}: attribute channel_names must be a list of distinct channel names")
    elif {"R", "G", "B"} <= present:
        names = ["R", "G", "B"]
    elif "Y" in present:
        names = ["Y"]
    else:
        raise FormatError(f"{path}: cannot tell the BRDF channels (no channel_names attribute; channels "
                          f"{', '.join(sorted(present)) or 'none'})")
    if "wavelengths_nm" in hdr:
        try:
            lam = json.loads(hdr["wavelengths_nm"]) if isinstance(hdr["wavelengths_nm"], str) else None
        except ValueError:
            lam = None
        if (not isinstance(lam, list) or len(lam) != len(names)
                or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in lam)):
            raise FormatError(f"{path}: attribute wavelengths_nm must be a JSON list of {len(names)} wavelengths")
        return names, Layout(None, np.asarray(lam, float))
    if names == ["Y"]:
        return names, Layout(("mono",))
    return names, Layout(tuple(names))


def read_exr(path):
    """Read an EXR table (see :func:`_read_exr`); text attributes a damaged file cannot decode
    are one FormatError line, like any other damage."""
    try:
        return _read_exr(path)
    except UnicodeError as exc:
        raise FormatError(f"{path}: damaged EXR header (an attribute's text cannot be decoded: {exc.reason})") from None


def _read_exr(path):
    """Read BRDF slices (single- or multi-part EXR written by brdftab) into a table."""
    OpenEXR = _openexr()
    path = Path(path)
    head, size = read_head(path, len(MAGIC))
    if head != MAGIC:
        raise FormatError(f"{path}: not an OpenEXR file (it does not start with the EXR magic number)")

    def headers():  # plain Python values only: attributes decode lazily (and may fail) inside the call
        out = []
        with OpenEXR.File(str(path), header_only=True) as f:
            for p in f.parts:
                hdr = dict(p.header)
                hdr["channels"] = [str(c.name) for c in hdr.get("channels", [])]
                out.append(hdr)
        return out

    hdrs, _ = _call(path, "damaged or truncated OpenEXR file", headers)
    if not hdrs:
        raise FormatError(f"{path}: the EXR file has no image")
    if len(hdrs) > MAX_PARTS:
        raise FormatError(f"{path}: {len(hdrs)} parts, more than {MAX_PARTS}")
    first = hdrs[0]
    if first.get("parameterization") != "rusinkiewicz":
        raise FormatError(f"{path}: not a brdftab BRDF slice image (no attribute parameterization = "
                          "'rusinkiewicz')")
    w, h = _window(path, 0, first)
    phis = []
    for k, hdr in enumerate(hdrs):
        if _window(path, k, hdr) != (w, h):
            raise FormatError(f"{path}: part {k} is {_window(path, k, hdr)}, part 0 is {(w, h)}: all phi_d slices "
                              "must have the same size")
        phi = _scalar(hdr.get("phi_d_rad"))
        if phi is None and _scalar(hdr.get("phi_d_deg")) is not None:
            phi = float(np.radians(_scalar(hdr["phi_d_deg"])))
        if phi is None or not np.isfinite(phi):
            raise FormatError(f"{path}: part {k} has no phi_d_rad attribute (a double: the phi_d of the slice)")
        phis.append(phi)
    if len(set(phis)) != len(phis):
        raise FormatError(f"{path}: two parts have the same phi_d")
    names, layout = _layout_of(path, first, set(first["channels"]))
    _check_chromaticities(path, first, names)
    for k, hdr in enumerate(hdrs):
        gone = [n for n in names if n not in hdr["channels"]]
        if gone:
            raise FormatError(f"{path}: part {k}: missing EXR channel {gone[0]!r} (has "
                              f"{', '.join(sorted(hdr['channels'])) or 'none'})")
    decoded = float(w) * h * len(names) * len(hdrs) * 4
    if decoded > 2 ** 28 and decoded > 2048 * size:
        raise FormatError(f"{path}: the header declares {decoded / 2**20:.0f} MiB of pixels in a file of "
                          f"{size:,} bytes")
    swap, top, warp = _orientation(path, first)
    n_th, n_td = (h, w) if swap else (w, h)
    th = _node_list(path, first, "theta_h_rad", n_th, "row" if swap else "column")
    td = _node_list(path, first, "theta_d_rad", n_td, "column" if swap else "row")

    def pixels():
        with OpenEXR.File(str(path), separate_channels=True) as f:
            return [{str(name): c.pixels for name, c in p.channels.items()} for p in f.parts]

    parts, log = _call(path, "damaged EXR file", pixels)
    if len(parts) != len(hdrs):
        raise FormatError(f"{path}: damaged EXR pixel data ({_reason(None, log, path)})")

    order = np.argsort(phis)
    try:
        values = np.empty((w, h, len(hdrs), len(names)), np.float32)
    except MemoryError:
        raise FormatError(f"{path}: {w} x {h} x {len(hdrs)} x {len(names)} samples do not fit in memory") from None
    for slot, k in enumerate(order):
        chans = parts[k]
        for c, name in enumerate(names):
            img = chans.get(name)
            if img is None:
                raise FormatError(f"{path}: part {k}: missing EXR channel {name!r} (has "
                                  f"{', '.join(sorted(chans)) or 'none'})")
            if not isinstance(img, np.ndarray) or img.dtype not in (np.float32, np.float16) or img.shape != (h, w):
                what = getattr(img, "dtype", type(img).__name__)
                raise FormatError(f"{path}: part {k}: channel {name!r} must be a {w} x {h} float image, got "
                                  f"{what} {getattr(img, 'shape', '')}")
            values[:, :, slot, c] = (img if top else img[::-1, :]).T  # [x, y from the first y node]
    if swap:  # x = theta_d, y = theta_h
        values = np.ascontiguousarray(values.transpose(1, 0, 2, 3))
    return _table(path, first, values, th, td, np.asarray(phis)[order], layout, warp)


def _check_chromaticities(path, hdr, names) -> None:
    """RGB values are read as Rec. 709 (OpenEXR's default when an image declares none); other
    primaries would need a colour conversion brdftab does not make, so they are refused."""
    chroma = hdr.get("chromaticities")
    if chroma is None or names != ["R", "G", "B"]:
        return
    try:
        xy = np.asarray(chroma, float).ravel()
    except (TypeError, ValueError, UnicodeError, OverflowError):  # a damaged attribute (fuzzed files)
        xy = np.zeros(0)
    if xy.size != 8 or not np.allclose(xy, REC709, rtol=0, atol=1e-4):
        try:
            shown = ", ".join(f"{x:.4g}" for x in xy) if xy.size else repr(chroma)
        except Exception:  # noqa: BLE001 - a value that cannot even be shown
            shown = "unreadable"
        raise FormatError(f"{path}: attribute chromaticities = ({shown}): brdftab reads RGB in Rec. 709 primaries "
                          "with a D65 white (0.64, 0.33, 0.3, 0.6, 0.15, 0.06, 0.3127, 0.329) only")


def _text_attr(path, hdr, key, default):
    v = hdr.get(key, default)
    if not isinstance(v, str):
        raise FormatError(f"{path}: attribute {key} = {v!r}: expected text such as {default!r}")
    return v.strip()


def _orientation(path, hdr):
    """``(swap, top, theta_h_warp)`` from the layout attributes of a slice image: whether x is
    θd (and y θh), whether the first y node is the top scanline, and the declared θh warp (or
    None). A value brdftab cannot honour is refused with one line naming the attribute, never
    read as if it were absent."""
    from ..table import PER_STERADIAN

    x = _text_attr(path, hdr, "x_axis", "theta_h")
    y = _text_attr(path, hdr, "y_axis", "theta_h" if x == "theta_d" else "theta_d")
    if (x, y) not in (("theta_h", "theta_d"), ("theta_d", "theta_h")):
        raise FormatError(f"{path}: attributes x_axis = {x!r}, y_axis = {y!r}: brdftab reads theta_h x theta_d "
                          "slices (x_axis and y_axis 'theta_h' and 'theta_d', either way round)")
    origin = _text_attr(path, hdr, "y_origin", "bottom")
    if origin not in ("bottom", "top"):
        raise FormatError(f"{path}: attribute y_origin = {origin!r}: expected 'bottom' (the first {y} node is the "
                          "bottom scanline) or 'top'")
    pos = _text_attr(path, hdr, "pixel_position", "centre")
    if pos not in ("centre", "center"):
        raise FormatError(f"{path}: attribute pixel_position = {pos!r}: brdftab reads images whose pixel centres "
                          "sit at the nodes ('centre')")
    angles = _text_attr(path, hdr, "angle_units", "rad")
    if angles.lower() not in ("rad", "radian", "radians"):
        raise FormatError(f"{path}: attribute angle_units = {angles!r}: brdftab reads node angles in radians "
                          "('rad'; the *_rad attributes)")
    units = _text_attr(path, hdr, "units", "sr-1")
    if units.lower().replace(" ", "") not in PER_STERADIAN:
        raise FormatError(f"{path}: attribute units = {units!r}: brdftab reads f_r in 'sr-1' only (a dimensionless "
                          "or percent value is a reflectance factor or a reflectance, not f_r)")
    cos = hdr.get("cosine_included", 0)
    flag = _scalar(cos) if not isinstance(cos, str) else {"0": 0.0, "false": 0.0, "no": 0.0}.get(cos.strip().lower())
    if flag != 0.0:
        raise FormatError(f"{path}: attribute cosine_included = {_shown(cos)}: the values are f_r times a cosine; "
                          "brdftab reads f_r only (cosine_included = 0)")
    warp = hdr.get("theta_h_warp")
    if warp is not None:
        warp = _text_attr(path, hdr, "theta_h_warp", "linear")
        if warp not in ("linear", "sqrt"):
            raise FormatError(f"{path}: attribute theta_h_warp = {warp!r}: expected 'linear' or 'sqrt' (x uniform "
                              "in sqrt(theta_h / (pi/2)))")
    return x == "theta_d", origin == "top", warp


def _shown(v):
    x = _scalar(v)
    return f"{x:g}" if x is not None else repr(v)


def _coord(hdr, name, vals):
    attrs = {"units": "rad", "long_name": _LONG_NAMES[name]}
    rule = hdr.get(f"{name}_node_rule")
    if isinstance(rule, str):
        attrs["node_rule"] = rule
    dom = hdr.get(f"{name}_domain_rad")
    if isinstance(dom, np.ndarray) and dom.size == 2:
        attrs["domain"] = np.asarray(dom, np.float64).ravel()
    return xr.Variable((name,), vals, attrs=attrs)


def _table(path, hdr, values, th, td, phi, layout, warp=None):
    from ..table import Table

    attrs = {}
    for key, v in hdr.items():
        if key in _EXR_STANDARD or key in _LAYOUT or key.startswith("param."):
            continue
        if isinstance(v, str):
            attrs[key] = v
        elif isinstance(v, (int, np.integer)) and not isinstance(v, bool):
            attrs[key] = int(v)
        elif _scalar(v) is not None and isinstance(v, (float, np.ndarray)):
            attrs[key] = _scalar(v)
    if warp == "sqrt" and "theta_h_spacing" not in attrs:
        attrs["theta_h_spacing"] = "merl"  # x uniform in sqrt(theta_h / (pi/2)): MERL's warp
    w, h = values.shape[:2]
    if th is None or td is None:  # nodes not listed: uniform nodes of the declared spacing and position
        try:
            uniform = RusinkiewiczGrid(w, h, 1, theta_h_spacing=str(attrs.get("theta_h_spacing", "linear")),
                                       sample_position=str(attrs.get("sample_position", "bin-centre")))
        except ParameterError as exc:
            raise FormatError(f"{path}: {exc}") from None
        th = uniform.axes[0].values if th is None else th
        td = uniform.axes[1].values if td is None else td
    coords = {"theta_h": _coord(hdr, "theta_h", th), "theta_d": _coord(hdr, "theta_d", td),
              "phi_d": _coord(hdr, "phi_d", phi)}
    if layout.spectral:
        coords["wavelength"] = xr.Variable(("wavelength",), layout.wavelengths,
                                           attrs={"units": "nm", "long_name": "vacuum wavelength"})
        chan = "wavelength"
    else:
        coords["channel"] = xr.Variable(("channel",), np.array(layout.channels, dtype=object),
                                        attrs={"long_name": "colour channel"})
        chan = "channel"
    var_attrs = {"units": "sr-1", "long_name": "bidirectional reflectance distribution function",
                 "quantity": "f_r = dL_o / dE_i (not multiplied by cos(theta_o), not a reflectance factor)"}
    for key in ("valid_min", "valid_max"):
        x = _scalar(hdr.get(key))
        if x is not None:
            var_attrs[key] = x
    if "missing_value" in hdr:
        var_attrs["missing_value"] = _markers(path, hdr["missing_value"])
    ds = xr.Dataset({"brdf": xr.Variable(AXES + (chan,), values, attrs=var_attrs)}, coords=coords, attrs=attrs)
    try:
        table = Table(ds)
    except BrdftabError as exc:
        raise FormatError(f"{path}: {exc}") from None
    except (KeyError, ValueError, TypeError, IndexError) as exc:
        raise FormatError(f"{path}: not a brdftab BRDF slice image ({_first_line(str(exc))})") from None
    if warp is not None and table.grid.axes[0].warp != warp:
        raise FormatError(f"{path}: attribute theta_h_warp = {warp!r} contradicts the theta_h nodes "
                          f"(theta_h_spacing = {table.grid.theta_h_spacing!r})")
    return table


register(FileFormat(
    name="exr",
    extensions=(".exr",),
    description="OpenEXR theta_h x theta_d float32 slices, one part per phi_d (isotropic Rusinkiewicz grids): "
                "f_r [sr-1] pixels, no cosine, not a reflectance factor",
    read=read_exr,
    write=write_exr,
    magic=(MAGIC,),
    requires=("OpenEXR",),
    utf8_paths=True,
    native_grid=native_grid,
    check_options=check_options,
    params=(Param("phi_d_deg", "floats", "phi_d slices in degrees, one part each (default: every phi_d node of the "
                  "grid).", units="deg", default=None),
            Param("colour", "choice", "Spectral tables: rgb (linear sRGB through colour-science, recorded in the "
                  "header) or spectral (one channel per wavelength, e.g. 550nm).", default="rgb", choices=_COLOUR),
            ) + tuple(p for p in COLOUR_PARAMS if p.name != "wavelengths_nm"),
    colour=True,
    precision=1e-6,  # float32 pixels
    stored=stored_exr,  # the pixels are float32, a spectral table in colour
))
