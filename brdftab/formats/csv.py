"""A plain CSV table of scattered samples (``.csv``): one row per sample and channel.

Layout (see ``formats/csv.md``): optional comment lines starting with ``#``, a header row, then
rows of six comma-separated fields::

    theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,wavelength_nm,f_r
    30,0,30,180,550,3.0271

* the four angles of the away-pointing directions (the mirror direction of (θi, φi) is
  (θi, φi + 180°)), in degrees (``_deg``) or radians (``_rad``), each column saying which;
* ``wavelength_nm`` (a number) or ``channel`` (a name: ``R``, ``G``, ``B``, ``mono``…);
* the value, its column naming the quantity: ``f_r`` (sr⁻¹, read as it is), ``f_r_cos_theta_o``
  (f_r cosθo, divided by cosθo) or ``reflectance_factor`` (π f_r, divided by π). The table
  records which (``source_quantity``).

Every sample (a distinct angle quadruple, in order of first appearance) must have one row for
every channel or wavelength the file names, and no more. brdftab holds the samples on a
:class:`~brdftab.grids.ScatteredGrid` and interpolates them as every scattered table
(:mod:`brdftab.grids.scattered`). Read files get ``origin = "measured"`` unless a comment line
``# origin: analytic`` (which brdftab writes for tables of models) says otherwise; a file whose
samples share one incident azimuth is declared isotropic unless a comment ``# isotropic: 0``
says otherwise (brdftab writes ``# isotropic: 0|1``: how the samples interpolate).

The writer writes degrees and f_r, every number as the shortest text that reads back as the
same float64 (the values are exact; an angle read back differs from the table's radians by at
most one rounding of the degree conversion, ~1e-16 rad), samples in the table's order and
channels in its order within each sample.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from .. import __version__
from ..channels import Layout
from ..errors import FormatError
from . import FileFormat, read_bytes, register
from .astm import _number, _table, native_grid, prepare_scattered

__all__ = ["read_csv", "write_csv", "QUANTITY_COLUMNS"]

ANGLE_COLUMNS = ("theta_i", "phi_i", "theta_o", "phi_o")
#: Value columns and what the reader does: (description, conversion to f_r).
QUANTITY_COLUMNS = {
    "f_r": ("f_r [sr-1], read as it is", None),
    "f_r_cos_theta_o": ("f_r cos(theta_o), divided by cos(theta_o) to f_r", "cos"),
    "reflectance_factor": ("reflectance factor pi f_r, divided by pi to f_r", "pi"),
}
_HEADER = re.compile(rb"(?mi)^\s*theta_i_(deg|rad)\s*,\s*phi_i_(deg|rad)\s*,\s*theta_o_(deg|rad)\s*,\s*phi_o_(deg|rad)"
                     rb"\s*,\s*(wavelength_nm|channel)\s*,")


def sniff(head: bytes, size: int) -> bool:
    """The header row ``theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,wavelength_nm|channel,...``."""
    return _HEADER.search(head) is not None


def read_csv(path):
    """Read a CSV of scattered samples into a scattered :class:`~brdftab.table.Table`."""
    path = Path(path)
    try:
        text = read_bytes(path).decode("utf-8-sig")
    except UnicodeDecodeError:
        raise FormatError(f"{path}: not a CSV text file (not UTF-8 text)") from None
    lines = text.splitlines()
    comments, header_at = [], None
    for k, line in enumerate(lines):
        s = line.strip()
        if not s:
            continue
        if s.startswith("#"):
            comments.append(s[1:].strip())
            continue
        header_at = k
        break
    if header_at is None:
        raise FormatError(f"{path}: no header row (theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,wavelength_nm,f_r)")
    cols = [c.strip().lower() for c in lines[header_at].split(",")]
    where = f"{path}: line {header_at + 1}"
    if len(cols) != 6:
        raise FormatError(f"{where}: expected 6 columns theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,"
                          f"wavelength_nm|channel,f_r; got {len(cols)}")
    scale = []
    for name, col in zip(ANGLE_COLUMNS, cols[:4]):
        if col == f"{name}_deg":
            scale.append(math.pi / 180)
        elif col == f"{name}_rad":
            scale.append(1.0)
        else:
            raise FormatError(f"{where}: column {len(scale) + 1} must be {name}_deg or {name}_rad, got {col!r}")
    spectral = cols[4] == "wavelength_nm"
    if cols[4] not in ("wavelength_nm", "channel"):
        raise FormatError(f"{where}: column 5 must be wavelength_nm or channel, got {cols[4]!r}")
    if cols[5] not in QUANTITY_COLUMNS:
        raise FormatError(f"{where}: column 6 names the quantity: one of {', '.join(QUANTITY_COLUMNS)}; got "
                          f"{cols[5]!r}")
    quantity, conv = QUANTITY_COLUMNS[cols[5]]
    angles, labels, values, rows_at = [], [], [], []
    for k in range(header_at + 1, len(lines)):
        s = lines[k].strip()
        if not s or s.startswith("#"):
            continue
        parts = [p.strip() for p in s.split(",")]
        if len(parts) != 6:
            raise FormatError(f"{path}: line {k + 1}: {len(parts)} fields, the header names 6")
        try:
            a = [float(x) * f for x, f in zip(parts[:4], scale)]
            v = float(parts[5])
            lab = float(parts[4]) if spectral else parts[4]
        except ValueError:
            raise FormatError(f"{path}: line {k + 1}: not a number in {s[:60]!r}") from None
        if not (all(math.isfinite(x) for x in a) and math.isfinite(v)) or (spectral and not lab > 0):
            raise FormatError(f"{path}: line {k + 1}: angles, wavelength and value must be finite numbers "
                              "(wavelengths positive)")
        if not spectral and not lab:
            raise FormatError(f"{path}: line {k + 1}: empty channel name")
        angles.append(a)
        labels.append(lab)
        values.append(v)
        rows_at.append(k + 1)
    if not angles:
        raise FormatError(f"{path}: no data rows after the header")
    ang = np.array(angles)
    uniq, first, inv = np.unique(ang, axis=0, return_index=True, return_inverse=True)
    inv = inv.ravel()
    order = np.argsort(first, kind="stable")          # samples in order of first appearance
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    sample = rank[inv]
    if spectral:
        chans = np.unique(np.array(labels, float))
        chan_of = np.searchsorted(chans, np.array(labels, float))
        layout = Layout(None, chans)
    else:
        names = list(dict.fromkeys(labels))
        index = {n: i for i, n in enumerate(names)}
        chan_of = np.array([index[n] for n in labels])
        layout = Layout(tuple(names))
    n, c = order.size, (chans.size if spectral else len(names))
    out = np.full((n, c), np.nan)
    count = np.zeros((n, c), int)
    np.add.at(count, (sample, chan_of), 1)
    twice = np.argwhere(count > 1)
    if twice.size:
        s_, c_ = twice[0]
        r = [rows_at[i] for i in np.flatnonzero((sample == s_) & (chan_of == c_))]
        raise FormatError(f"{path}: lines {r[0]} and {r[1]}: the same sample and channel twice")
    out[sample, chan_of] = values
    lack = np.argwhere(count == 0)
    if lack.size:
        s_, c_ = lack[0]
        row = rows_at[int(np.flatnonzero(sample == s_)[0])]
        name = f"{chans[c_]:g} nm" if spectral else names[c_]
        raise FormatError(f"{path}: the sample of line {row} has no row for {name} ({lack.shape[0]} sample/channel "
                          "rows are missing): every sample needs a value for every channel")
    ang = uniq[order]
    for col, name in ((0, "theta_i"), (2, "theta_o")):
        off = np.flatnonzero((ang[:, col] < 0) | (ang[:, col] >= np.pi / 2))
        if off.size:
            row = rows_at[int(first[order][off[0]])]
            raise FormatError(f"{path}: line {row}: {name} = {np.degrees(ang[off[0], col]):.6g} deg; a polar angle "
                              "lies in [0, 90) deg")
    if conv == "cos":
        out = out / np.cos(ang[:, 2])[:, None]
    elif conv == "pi":
        out = out / math.pi
    origin = "measured"
    isotropic = np.ptp(ang[:, 1]) == 0.0  # one incident azimuth: read as an isotropic surface's
    for cm in comments:
        m = re.fullmatch(r"origin\s*:\s*(\w+)", cm)
        if m and m.group(1) in ("analytic", "measured", "unknown"):
            origin = m.group(1)
        m = re.fullmatch(r"isotropic\s*:\s*([01])", cm)
        if m:
            isotropic = m.group(1) == "1"
    provenance = {
        "title": f"scattered BRDF samples {path.name}",
        "model": "unknown",
        "material": path.stem,
        "parameters": "{}",
        "isotropic": int(isotropic),
        "origin": origin,
        "source_file": path.name,
        "source_format": "csv",
        "source_quantity": quantity,
    }
    if comments:
        provenance["comment"] = "\n".join(comments)
    return _table(ang, out, layout, provenance)


def write_csv(table, path, **_):
    """Write a scattered ``table`` to ``path`` (see the module docstring)."""
    from ..grids import ScatteredGrid

    grid = table.grid
    if not isinstance(grid, ScatteredGrid):
        raise FormatError(f"a scattered CSV holds scattered samples, not a table on {grid.describe()}")
    if table.missing is not None:
        raise FormatError(f"{int(table.missing.any(axis=-1).sum())} samples are declared missing; the CSV has no "
                          "missing marker")
    if table.spectral:
        labels, col = [_number(x) for x in table.wavelengths], "wavelength_nm"
    else:
        labels, col = list(table.channels), "channel"
        for n in labels:
            if "," in n or "\n" in n or n.startswith("#") or not n.strip():
                raise FormatError(f"channel name {n!r} cannot be written in a CSV field")
    values = np.asarray(table.values, float)
    attrs = table.ds.attrs
    deg = np.degrees(np.stack([grid.theta_i, grid.phi_i, grid.theta_o, grid.phi_o], axis=1))
    with open(path, "w", encoding="utf-8", newline="\n") as fh:
        fh.write(f"# brdftab {__version__}: f_r [sr-1] of {' '.join(str(attrs.get('model', table.name)).split())} at "
                 f"{grid.size} scattered direction pairs (degrees; directions point away from the surface)\n")
        fh.write(f"# origin: {table.origin}\n# isotropic: {int(table.isotropic)}\n")
        fh.write(f"theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,{col},f_r\n")
        for a, v in zip(deg, values):
            head = ",".join(_number(x) for x in a)
            for lab, x in zip(labels, v):
                fh.write(f"{head},{lab},{_number(x)}\n")


def prepare_csv(brdf, grid):
    return prepare_scattered(brdf, grid, "a scattered CSV file")


register(FileFormat(
    name="csv",
    extensions=(".csv",),
    description="CSV of scattered samples, one row per sample and channel: theta_i, phi_i, theta_o, phi_o (deg or "
                "rad), wavelength_nm or channel, and f_r [sr-1] (f_r cos(theta_o) and the reflectance factor pi f_r "
                "are converted to f_r on read); writes f_r and degrees; interpolated linearly on the samples' "
                "Delaunay triangulation",
    read=read_csv,
    write=write_csv,
    sniff=sniff,
    native_grid=native_grid,
    prepare=prepare_csv,
    precision=1e-12,  # values exact; angles through degrees (one rounding) move the interpolation by ~1e-15
))
