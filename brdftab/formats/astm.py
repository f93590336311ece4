"""ASTM E1392 gonioreflectometer text files, Cornell dialect (``.astm``): read and write.

Layout (see ``formats/astm.md``): header lines ``KEY value`` (``SAMPLE_NAME Cayman Metallic``,
``MEAS_NAME BRDF``, ``NUM_POINTS 1439``), ended by ``VARS theta_i,phi_i,theta_s,phi_s,<channels>``;
then one comma-separated line per sample: θi, φi, θs, φs in **radians**, then the values. The
channels are ``R,G,B``, ``X,Y,Z``, wavelengths ``400nm,410nm,…`` or a single value (grey).

The samples are scattered direction pairs: brdftab holds them on a
:class:`~brdftab.grids.ScatteredGrid` (netCDF and zarr store it sample for sample) and
interpolates them linearly on their Delaunay triangulation (:mod:`brdftab.grids.scattered`).
The angles are the spherical angles of the away-pointing directions, as in brdftab: the mirror
direction of (θi, φi) is (θi, φi + π) (Cornell's files have φi = 0 and their specular peak at
φs = π).

The writer adds the header line ``ISOTROPIC 1`` (or ``0``), which the reader honours: whether
the samples are interpolated as an isotropic surface's (without it, a file whose samples share
one incident azimuth is read as isotropic).

Quantity: ``MEAS_NAME BRDF`` (and a file without MEAS_NAME) holds f_r in sr⁻¹, read as it is;
``CCBRDF`` (cosine-corrected BRDF, f_r cosθs) is divided by cosθs; ``BRF`` (reflectance
factor, π f_r) is divided by π. The table records which (``source_quantity``). Readers set
``origin = "measured"``; a file holding one incident azimuth is declared isotropic (it is read
as a measurement of an isotropic surface at that azimuth; other azimuths are answered by
rotation about the normal) and no reciprocity is declared.

The writer writes ``MEAS_NAME BRDF`` (f_r in sr⁻¹), every number as the shortest text that
reads back as the same float64 (the samples, and the angles in radians, are exact), and the
header lines of the file a table was read from (its ``astm_header``), else ``SOURCE brdftab``,
``SAMPLE_NAME`` and the model. Its samples are the table's own when it is scattered, else the
nodes of the grid it is written on (both directions above the horizon).
"""

from __future__ import annotations

import math
import re
import warnings
from pathlib import Path

import numpy as np

from .. import __version__
from ..channels import Layout
from ..errors import BrdftabWarning, FormatError
from . import FileFormat, read_bytes, register

__all__ = ["read_astm", "write_astm", "parse_channels", "scattered_target", "prepare_scattered", "QUANTITIES",
           "HEADER_ATTR"]

#: Table attribute holding the header lines of the file a table was read from (without
#: NUM_POINTS and VARS, which the writer makes).
HEADER_ATTR = "astm_header"
ANGLE_VARS = ("theta_i", "phi_i", "theta_s", "phi_s")
#: The most samples a scattered writer writes from a grid's nodes: the table written is
#: triangulated (Delaunay) to be checked and read back, which a dense grid (the 1.46 million
#: nodes of the MERL grid) makes take minutes and gigabytes.
MAX_WRITTEN_SAMPLES = 200_000
#: MEAS_NAME values and what the reader does with them: (description, factor(θs) to f_r).
QUANTITIES = {
    "BRDF": ("f_r [sr-1] (ASTM E1392 BRDF), read as it is", None),
    "CCBRDF": ("cosine-corrected BRDF f_r cos(theta_s), divided by cos(theta_s) to f_r", "cos"),
    "BRF": ("reflectance factor pi f_r, divided by pi to f_r", "pi"),
}
_VARS = re.compile(rb"(?mi)^\s*VARS\s+theta_i\s*,\s*phi_i\s*,\s*theta_s\s*,\s*phi_s\b")


def sniff(head: bytes, size: int) -> bool:
    """A ``VARS theta_i,phi_i,theta_s,phi_s`` line in the head of the file."""
    return _VARS.search(head) is not None


def parse_channels(names, where: str) -> Layout:
    """The layout of the value columns: R,G,B / X,Y,Z / wavelengths ``<number>nm`` / one grey value."""
    names = [n.strip() for n in names]
    if not names:
        raise FormatError(f"{where}: VARS names no value column after theta_i,phi_i,theta_s,phi_s")
    if names in (["R", "G", "B"], ["X", "Y", "Z"]):
        return Layout(tuple(names))
    nm = [re.fullmatch(r"([0-9]*\.?[0-9]+(?:[eE][+-]?[0-9]+)?)\s*nm", n) for n in names]
    if all(nm):
        lam = np.array([float(m.group(1)) for m in nm])
        if np.any(lam <= 0) or np.any(np.diff(lam) <= 0):
            raise FormatError(f"{where}: the wavelengths of VARS must be positive and increase strictly")
        return Layout(None, lam)
    if len(names) == 1:
        return Layout(("mono",))
    if any(nm):
        raise FormatError(f"{where}: VARS mixes wavelengths and other names ({', '.join(names)})")
    if len(set(names)) != len(names):
        raise FormatError(f"{where}: VARS names a channel twice ({', '.join(names)})")
    return Layout(tuple(names))


def read_astm(path):
    """Read an ASTM E1392 (Cornell dialect) file into a scattered :class:`~brdftab.table.Table`."""
    path = Path(path)
    try:
        text = read_bytes(path).decode("utf-8")
    except UnicodeDecodeError:
        raise FormatError(f"{path}: not an ASTM text file (not UTF-8 text)") from None
    lines = text.splitlines()
    header, keys, vars_at = [], {}, None
    for k, line in enumerate(lines):
        s = line.strip()
        if not s:
            header.append(line)
            continue
        key, _, value = s.partition(" ")
        if key.upper() == "VARS":
            vars_at = k
            break
        if not re.fullmatch(r"[A-Za-z][A-Za-z0-9_]*", key):
            raise FormatError(f"{path}: line {k + 1}: expected a header line 'KEY value' before VARS, got "
                              f"{s[:40]!r}")
        keys[key.upper()] = value.strip()
        header.append(line)
    if vars_at is None:
        raise FormatError(f"{path}: not an ASTM E1392 file: no line 'VARS theta_i,phi_i,theta_s,phi_s,...'")
    names = [n.strip() for n in lines[vars_at].strip()[4:].split(",")]
    if [n.lower() for n in names[:4]] != list(ANGLE_VARS):
        raise FormatError(f"{path}: line {vars_at + 1}: VARS must start with theta_i,phi_i,theta_s,phi_s, got "
                          f"{','.join(names[:4])}")
    layout = parse_channels(names[4:], f"{path}: line {vars_at + 1}")
    width = len(names)
    rows, where = [], []
    for k in range(vars_at + 1, len(lines)):
        s = lines[k].strip()
        if not s:
            continue
        parts = s.split(",")
        if len(parts) != width:
            raise FormatError(f"{path}: line {k + 1}: {len(parts)} numbers, VARS names {width}")
        try:
            rows.append([float(x) for x in parts])
        except ValueError:
            raise FormatError(f"{path}: line {k + 1}: not a number in {s[:60]!r}") from None
        where.append(k + 1)
    if not rows:
        raise FormatError(f"{path}: no data lines after VARS")
    data = np.array(rows)
    if "NUM_POINTS" in keys:
        try:
            declared = int(keys["NUM_POINTS"])
        except ValueError:
            raise FormatError(f"{path}: NUM_POINTS {keys['NUM_POINTS']!r} is not a whole number") from None
        if declared != len(rows):
            raise FormatError(f"{path}: NUM_POINTS says {declared} samples, the file holds {len(rows)} data lines "
                              "(truncated or damaged?)")
    bad = ~np.isfinite(data)
    if bad.any():
        r = int(np.flatnonzero(bad.any(axis=1))[0])
        raise FormatError(f"{path}: line {where[r]}: a value is not finite")
    ang = data[:, :4]
    for col, name in ((0, "theta_i"), (2, "theta_s")):
        off = np.flatnonzero((ang[:, col] < 0) | (ang[:, col] >= np.pi / 2))
        if off.size:
            r = int(off[0])
            raise FormatError(f"{path}: line {where[r]}: {name} = {ang[r, col]:g} rad; ASTM angles are radians and a "
                              "polar angle lies in [0, pi/2)")
    _, first, inverse = np.unique(ang, axis=0, return_index=True, return_inverse=True)
    if first.size < len(rows):
        dup = np.flatnonzero(np.bincount(inverse.ravel()) > 1)
        warnings.warn(f"{path}: {len(rows) - first.size} data line(s) repeat the angles of an earlier one (first: line "
                      f"{where[int(np.flatnonzero(inverse.ravel() == dup[0])[1])]}); the first of each is kept",
                      BrdftabWarning, stacklevel=3)
        keep = np.sort(first)
        data, ang = data[keep], ang[keep]
    meas = keys.get("MEAS_NAME", "BRDF").strip().upper().replace(" ", "").replace("_", "")
    if meas not in QUANTITIES:
        raise FormatError(f"{path}: MEAS_NAME {keys.get('MEAS_NAME')!r}: brdftab reads BRDF (f_r), CCBRDF (f_r "
                          "cos theta_s) or BRF (pi f_r)")
    text_q, factor = QUANTITIES[meas]
    values = data[:, 4:]
    if factor == "cos":
        values = values / np.cos(ang[:, 2])[:, None]
    elif factor == "pi":
        values = values / math.pi
    single_phi = np.ptp(ang[:, 1]) == 0.0
    declared = keys.get("ISOTROPIC", "").strip()
    if declared not in ("", "0", "1"):
        raise FormatError(f"{path}: ISOTROPIC {declared!r}: expected 0 or 1")
    isotropic = single_phi if not declared else declared == "1"
    provenance = {
        "title": f"ASTM E1392 gonioreflectometer data {path.name}",
        "model": "unknown",
        "material": keys.get("SAMPLE_NAME", path.stem),
        "parameters": "{}",
        "isotropic": int(isotropic),
        "origin": "measured",
        "source_file": path.name,
        "source_format": "astm",
        "source_quantity": text_q if "MEAS_NAME" in keys else text_q + " (no MEAS_NAME: BRDF assumed)",
        HEADER_ATTR: "\n".join(h for h in header if not h.strip().upper().startswith("NUM_POINTS")).strip("\n"),
    }
    if single_phi and not declared:
        provenance["isotropy"] = ("assumed: the file measures one incident azimuth; other azimuths are answered by "
                                  "rotation about the normal")
    return _table(ang, values, layout, provenance)


def _table(ang, values, layout, provenance):
    """A scattered table of samples ``ang[N, 4]`` (θi, φi, θo, φo [rad]) and ``values[N, C]``."""
    from ..grids import ScatteredGrid
    from ..table import Table, make_table

    fold = "bilateral" if ScatteredGrid.one_sided(*ang.T) else "none"
    try:
        grid = ScatteredGrid(ang[:, 0], ang[:, 1], ang[:, 2], ang[:, 3], phi_d_fold=fold)
    except Exception as exc:  # a ParameterError naming the sample
        raise FormatError(str(exc)) from None
    table = make_table(np.ascontiguousarray(values, float), grid, layout, provenance=provenance)
    for key in ("created", "brdftab_version", "history", "source", "reciprocal", "spec_sha256"):
        table.ds.attrs.pop(key, None)  # a file records none of them; reciprocity is not declared
    return Table(table.ds)


# --------------------------------------------------------------------------------------------
# Writing


def scattered_target(requested):
    """The scattered samples a scattered format writes: the requested grid's own samples when it
    is scattered, else the nodes of the requested grid (both directions above the horizon); for
    a source in a format's own layout, :func:`default_samples`."""
    from ..errors import ParameterError
    from ..grids import Grid, ScatteredGrid

    if isinstance(requested, ScatteredGrid):
        return requested
    if isinstance(requested, Grid):
        if requested.size > MAX_WRITTEN_SAMPLES:
            raise ParameterError("grid", f"a scattered file of the nodes of {requested.describe()} would hold up to "
                                 f"{requested.size:,} samples; brdftab writes at most {MAX_WRITTEN_SAMPLES:,} (a "
                                 "scattered table is triangulated to be interpolated): give a gonio grid ([grid] or --grid), e.g. "
                                 "'{type = \"spherical\", theta_i_deg = {start = 0, stop = 80, step = 5}, phi_i_deg = [0], "
                                 "theta_o_deg = {start = 0, stop = 85, step = 5}, phi_o_deg = {start = 0, stop = 360, "
                                 "step = 5, endpoint = false}}'")
        return ScatteredGrid.from_grid(requested)
    return default_samples()


def default_samples():
    """A gonio set: θi every 10° from 0 to 80°, θo every 5° from 0 to 85°, φo every 10°, φi = 0."""
    from ..grids import ScatteredGrid, SphericalGrid

    return ScatteredGrid.from_grid(SphericalGrid(np.radians(np.arange(0, 81, 10.0)), [0.0],
                                                 np.radians(np.arange(0, 86, 5.0)),
                                                 np.radians(np.arange(0, 360, 10.0))))


def native_grid(requested, options: dict):
    return scattered_target(requested)


def prepare_scattered(brdf, grid, what: str):
    """The scattered table a scattered writer writes for ``brdf`` on ``grid``: a scattered table
    on it is copied, anything else sampled at its samples (a spectral source keeps its
    wavelengths: both scattered formats store them)."""
    from ..table import Table, tabulate, warn_specular_dropped

    target = scattered_target(grid)
    warn_specular_dropped(brdf, what)
    if isinstance(brdf, Table) and target.equals(brdf.grid):
        return brdf
    return tabulate(brdf, target)


def _number(x: float) -> str:
    """The shortest text of a float64 that reads back as the same number."""
    return repr(float(x))


def write_astm(table, path, **_):
    """Write a scattered ``table`` (see :func:`prepare_astm`) to ``path``."""
    from ..grids import ScatteredGrid

    grid = table.grid
    if not isinstance(grid, ScatteredGrid):
        raise FormatError(f"an ASTM file holds scattered samples, not a table on {grid.describe()}")
    if table.spectral:
        names = [f"{_number(x).removesuffix('.0')}nm" for x in table.wavelengths]
    elif table.channels == ("mono",):
        names = ["BRDF"]
    else:
        names = list(table.channels)
    for n in names:
        if "," in n or "\n" in n or not n.strip():
            raise FormatError(f"channel name {n!r} cannot be written in an ASTM VARS line")
    attrs = table.ds.attrs
    header = str(attrs.get(HEADER_ATTR, "")).strip("\n")
    if header:
        # the source's header lines; MEAS_NAME says what is written now: f_r (converted on read)
        kept = [h for h in header.splitlines() if h.strip().upper().split(" ")[0] not in ("MEAS_NAME", "ISOTROPIC")]
        head = kept + ["MEAS_NAME BRDF"]
    else:
        head = [f"SOURCE brdftab {__version__}", f"SAMPLE_NAME {_one_line(attrs.get('material', table.name))}",
                f"SAMPLE_TYPE {_one_line(attrs.get('model', table.name))}", "MEAS_NAME BRDF"]
        params = str(attrs.get("parameters", ""))
        if params and params != "{}":
            head.append(f"LAB_COMMENTS {_one_line(params)}")
    head.append(f"ISOTROPIC {int(table.isotropic)}")  # (a brdftab key: how the samples interpolate)
    values = np.asarray(table.values, float)
    miss = table.missing
    if miss is not None:
        raise FormatError(f"{int(miss.any(axis=-1).sum())} samples are declared missing; an ASTM file has no "
                          "missing marker")
    with open(path, "w", encoding="utf-8", newline="\n") as fh:
        for line in head:
            fh.write(line + "\n")
        fh.write(f"NUM_POINTS {grid.size}\n")
        fh.write("VARS theta_i,phi_i,theta_s,phi_s," + ",".join(names) + "\n\n")
        ang = np.stack([grid.theta_i, grid.phi_i, grid.theta_o, grid.phi_o], axis=1)
        for a, v in zip(ang, values):
            fh.write(",".join(_number(x) for x in a) + "," + ",".join(_number(x) for x in v) + "\n")


def _one_line(value) -> str:
    return " ".join(str(value).split())


def prepare_astm(brdf, grid):
    return prepare_scattered(brdf, grid, "an ASTM E1392 file")


register(FileFormat(
    name="astm",
    extensions=(".astm",),
    description="ASTM E1392 gonioreflectometer text (Cornell dialect): writes and reads f_r [sr-1] (MEAS_NAME BRDF; "
                "CCBRDF f_r cos(theta_s) and BRF pi f_r are converted to f_r on read) at scattered samples theta_i, "
                "phi_i, theta_s, phi_s in radians, grey, R,G,B, X,Y,Z or wavelengths; interpolated linearly on the "
                "samples' Delaunay triangulation",
    read=read_astm,
    write=write_astm,
    sniff=sniff,
    native_grid=native_grid,
    prepare=prepare_astm,
    precision=0.0,  # every number written as the shortest text of its float64
))
