"""Mitsuba 3 ``measured_polarized`` tables (``.pbsdf``, the KAIST pBRDF layout), read and written.

A tensor file (:mod:`brdftab.formats._tensor`) with the fields

``theta_h``, ``theta_d``, ``phi_d``
    float32 ``[1, N]`` node angles in radians (Mitsuba takes the count from ``shape[1]``);
``wvls``
    uint16 ``[5]`` wavelengths in nm — Mitsuba copies exactly five entries, so a file holds five;
``M``
    float32 ``[Nφd, Nθd, Nθh, 5, 4, 4]`` (C order), ``M[..., i, j]`` = row i, column j of the
    Mueller matrix in sr⁻¹ without a cosine, in the frame where both beams share
    x = normalize(ω_light × ω_view) and +S3 is right circular (brdftab's ``mitsuba`` basis, so
    the table's ``mueller`` variable is copied as it is);

and brdftab's provenance in an extra ``description`` field (JSON text; readers ignore fields
they do not know). The coordinates are isotropic Rusinkiewicz angles with i the direction
towards the light — brdftab's (θh, θd, φd) with φd taken into (−π, π].

Mitsuba interpolates the table multilinearly in (φd, θd, θh, λ) and clamps outside the nodes,
so the writer stores φd nodes at both −π and π (the seam value, by brdftab's periodic
interpolation between the nodes either side: Mitsuba then interpolates across the seam as
brdftab does), and the nodes below the horizon hold the ghost values brdftab's own
interpolation uses there (0 where it has none). A NaN M00 marks a missing sample (Mitsuba
returns 0 there; brdftab reads it as missing). See ``formats/pbsdf.md``.

Reference: mitsuba-renderer/mitsuba3 ``src/bsdfs/measured_polarized.cpp``; Baek et al.,
"Image-Based Acquisition and Modeling of Polarimetric Reflectance", SIGGRAPH 2020.
"""

from __future__ import annotations

import json
import os
import struct

import numpy as np

from ..errors import BrdftabError, FormatError, ParameterError
from ..params import Param
from . import FileFormat, register
from ._tensor import MAGIC, encode_tensor, parse_tensor

__all__ = ["read_pbsdf", "write_pbsdf", "stream_pbsdf", "prepare_pbsdf", "pbsdf_fields", "table_from_fields", "default_grid",
           "KAIST_WAVELENGTHS_NM", "N_WAVELENGTHS"]

#: Wavelengths of the KAIST pBRDF dataset [nm]; a grey table is written at these.
KAIST_WAVELENGTHS_NM = (450, 500, 550, 600, 650)
#: Mitsuba's plugin reads exactly this many wavelengths.
N_WAVELENGTHS = 5
#: Node angles read from float32 within this of a range end [rad] are taken at the end.
END_TOL = 1e-6

PARAMS = (
    Param("wavelengths_nm", "floats", "Spectral models: the five wavelengths [nm, whole numbers] to tabulate (default: "
          "the model's own, else 450-650 nm in steps of 50).", units="nm", default=None, minimum=0.0,
          exclusive_minimum=True),
)


def default_grid():
    """The grid a ``.pbsdf`` stores when none is asked (the KAIST layout): θh and θd every 1°
    from 0 to 90° inclusive, φd every 1° (written as 361 nodes from −180° to 180°)."""
    from ..grids import RusinkiewiczGrid

    deg = np.radians(np.arange(91.0))
    return RusinkiewiczGrid(deg, deg, 360, phi_d_fold="none", sample_position="lower-edge", name="pbsdf")


def _native_grid(requested, options):
    from ..grids import RusinkiewiczGrid

    if not isinstance(requested, RusinkiewiczGrid) or requested.anisotropic:
        return default_grid()
    th, td, pd = requested.axes
    if requested.phi_d_fold == "none" and requested.theta_h_spacing != "merl":
        return requested
    theta_h = th.values if requested.theta_h_spacing == "merl" else (len(th) if th.rule != "explicit" else th.values)
    theta_d = len(td) if td.rule != "explicit" else td.values
    if requested.phi_d_fold == "none":
        phi_d = len(pd) if pd.rule != "explicit" else pd.values
    else:  # the same node spacing over the whole circle
        phi_d = 360 if pd.rule == "explicit" else int(round(len(pd) * 2 * np.pi / (pd.domain[1] - pd.domain[0])))
    return RusinkiewiczGrid(theta_h, theta_d, phi_d, phi_d_fold="none", sample_position=requested.sample_position,
                            name="pbsdf")


def _wavelengths(brdf, wavelengths_nm=None):
    """The five wavelengths [nm] a file of ``brdf`` holds and those to evaluate it at (None for
    a grey BRDF, written at :data:`KAIST_WAVELENGTHS_NM`); one-line errors for what a file
    cannot hold."""
    layout = brdf.layout
    if not layout.spectral:
        if not layout.grey:
            raise BrdftabError(f"a .pbsdf holds five wavelengths, not the colour channels {list(layout.channels)} of "
                               f"{brdf.describe()}")
        if wavelengths_nm is not None:
            lam = _check_lam(wavelengths_nm)
            return lam, lam
        return np.asarray(KAIST_WAVELENGTHS_NM, float), None
    lam = brdf.layout.resolve(wavelengths_nm)
    return _check_lam(lam), lam


def _check_lam(lam):
    lam = np.atleast_1d(np.asarray(lam, float))
    if lam.size != N_WAVELENGTHS:
        raise ParameterError("wavelengths_nm", f"a .pbsdf holds exactly {N_WAVELENGTHS} wavelengths (Mitsuba's "
                             f"measured_polarized reads five), not {lam.size}")
    if np.any(lam != np.round(lam)) or np.any(lam < 1) or np.any(lam > 65535):
        raise ParameterError("wavelengths_nm", f"a .pbsdf stores wavelengths as whole nanometres (uint16), not "
                             f"{', '.join(f'{x:g}' for x in lam)}")
    if np.any(np.diff(lam) <= 0):
        raise ParameterError("wavelengths_nm", "wavelengths must increase strictly")
    return lam


def prepare_pbsdf(brdf, grid, wavelengths_nm=None, **_):
    """A polarized table on ``grid`` (the source's own when it is one already)."""
    from ..mueller_table import is_polarized
    from ..table import Table, tabulate

    if not is_polarized(brdf):
        raise BrdftabError(f"a .pbsdf holds a Mueller matrix: {brdf.describe()} is not polarized (use a polarized "
                           "model, or a table tabulated with polarized = true in [grid])")
    grid = default_grid() if grid is None else grid
    _, lam = _wavelengths(brdf, wavelengths_nm)
    if isinstance(brdf, Table) and grid.equals(brdf.grid) and (lam is None or not brdf.spectral
                                                                or np.array_equal(lam, brdf.layout.wavelengths)):
        return brdf
    return tabulate(brdf, grid, lam, polarized=True)


def _seam(values, phi):
    """``(phi_nodes in [-π, π], values along φd)`` with nodes at both −π and π: ``values[..., k]``
    at the periodic nodes ``phi`` [0, 2π); the seam value is the periodic linear interpolation
    between the nodes either side of π (one of them itself when a node sits at π)."""
    p = np.where(phi > np.pi + 1e-12, phi - 2 * np.pi, phi)  # (-π, π]
    order = np.argsort(p, kind="stable")
    p, values = p[order], values[..., order]
    at_pi = np.abs(p - np.pi) <= 1e-12
    if at_pi.any():
        seam = values[..., np.flatnonzero(at_pi)[0]]
        keep = ~at_pi
    elif p.size == 1:
        seam, keep = values[..., 0], np.ones(1, bool)
    else:
        lo, hi = p[-1], p[0] + 2 * np.pi  # last node below π, first above −π (wrapped)
        t = (np.pi - lo) / (hi - lo)
        seam = (1 - t) * values[..., -1] + t * values[..., 0]
        keep = np.ones(p.size, bool)
    nodes = np.concatenate([[-np.pi], p[keep], [np.pi]])
    vals = np.concatenate([seam[..., None], values[..., keep], seam[..., None]], axis=-1)
    return nodes, vals


def pbsdf_fields(table) -> dict:
    """The tensor-file fields of a polarized ``table`` on an isotropic Rusinkiewicz grid without
    a φd fold (see the module docstring)."""
    from ..grids import RusinkiewiczGrid
    from ..mueller_table import ghosted_mueller, is_polarized

    if not is_polarized(table):
        raise BrdftabError(f"a .pbsdf holds a Mueller matrix: {table.describe()} holds none")
    grid = table.grid
    if not isinstance(grid, RusinkiewiczGrid) or grid.anisotropic or grid.phi_d_fold != "none":
        raise BrdftabError(f"a .pbsdf holds an isotropic Rusinkiewicz grid over the whole φd circle, not "
                           f"{grid.describe()}")
    th, td, pd = grid.axes
    if pd.period is None:
        raise BrdftabError("a .pbsdf covers φd over (-180°, 180°] (Mitsuba clamps outside its nodes); the table's φd "
                           f"nodes cover only {np.degrees(pd.domain[0]):g}° to {np.degrees(pd.domain[1]):g}°")
    if th.warp != "linear":
        raise BrdftabError("a .pbsdf interpolates linearly in θh; a table whose θh nodes are warped (MERL spacing) is "
                           "written through a grid with the same nodes taken as a list")
    file_lam, _ = _wavelengths(table)
    m = _file_slab(ghosted_mueller(table), grid.node_above_horizon())  # [θh, θd, φd, λ, 4, 4]
    # [θh, θd, φd, λ, 4, 4] -> [φd, θd, θh, λ, 4, 4], φd with both seam nodes
    m = np.moveaxis(m, 2, -1)
    phi, m = _seam(m, pd.values)
    m = np.ascontiguousarray(np.moveaxis(m, -1, 0).transpose(0, 2, 1, 3, 4, 5))
    with np.errstate(over="ignore", invalid="ignore"):
        m32 = m.astype(np.float32)
    big = np.isinf(m32) & ~np.isinf(m)
    if big.any():
        raise BrdftabError(f"{int(big.sum())} Mueller elements exceed the float32 range of a .pbsdf "
                           f"(largest {np.nanmax(np.abs(m)):.3g})")
    desc = {"format": "brdftab pbsdf", **{k: _plain(table.ds.attrs[k]) for k in _PROVENANCE if k in table.ds.attrs}}
    if not table.spectral:
        desc["grey"] = 1
    return {
        "theta_h": th.values.astype(np.float32)[None, :],
        "theta_d": td.values.astype(np.float32)[None, :],
        "phi_d": phi.astype(np.float32)[None, :],
        "wvls": file_lam.astype(np.uint16),
        "M": m32,
        "description": np.frombuffer(json.dumps(desc, sort_keys=True).encode("utf-8"), np.uint8),
    }


_PROVENANCE = ("model", "parameters", "origin", "reciprocal", "spec_sha256", "spec_file", "comment", "brdftab_version",
               "created")


def _plain(v):
    if isinstance(v, (bytes, np.bytes_)):
        return bytes(v).decode("utf-8", "replace")
    if hasattr(v, "item"):
        return v.item()
    return v


def _file_slab(m, above):
    """Mueller values ``[..., C, 4, 4]`` (ghosted, NaN where unknown) as a file stores them: 0
    below the horizon where no ghost exists, a grey channel repeated to five wavelengths."""
    unknown = np.isnan(m[..., 0, 0]) & ~np.asarray(above)[..., None]
    m = np.where(unknown[..., None, None], 0.0, m)
    return np.repeat(m, N_WAVELENGTHS, axis=-3) if m.shape[-3] == 1 else m


def stream_pbsdf(brdf, grid, path, wavelengths_nm=None, progress=None) -> None:
    """Write a ``.pbsdf`` of the polarized model ``brdf`` on ``grid`` one φd slab at a time (a
    slab of θh × θd nodes in memory, never the table): the file :func:`write_pbsdf` writes from
    ``tabulate(brdf, grid, polarized=True)``, bit for bit (tested), for grids too large for
    memory such as the KAIST layout. ``path`` is written as it is (no temporary, no checks):
    the caller writes to a temporary and judges the file. ``progress``: a callable given the
    slabs done and their count."""
    from ..grids import RusinkiewiczGrid
    from ..mueller_table import ghosted, ghosted_nan, mueller_at_nodes, require_polarized
    from ._tensor import tensor_header

    require_polarized(brdf)
    if not isinstance(grid, RusinkiewiczGrid) or grid.anisotropic or grid.phi_d_fold != "none" \
            or grid.axes[0].warp != "linear" or grid.axes[2].period is None:
        raise BrdftabError(f"a .pbsdf is streamed on an isotropic Rusinkiewicz grid over the whole φd circle with "
                           f"linear θh, not {grid.describe()}")
    file_lam, lam = _wavelengths(brdf, wavelengths_nm)
    th, td, pd = grid.axes
    n = brdf.layout.n_out(lam)

    def slab(phi):
        g = RusinkiewiczGrid(th.values, td.values, [phi], phi_d_fold="none")
        g._set_axes((th, td, g.axes[2]))
        out = np.empty(g.shape + (n, 4, 4))
        mueller_at_nodes(brdf, g, lam, out, chunk=4096)
        values, valid = ghosted(out.reshape(g.shape + (n * 16,)), g)
        return _file_slab(ghosted_nan(values, valid, g), g.node_above_horizon())[:, :, 0]  # [θh, θd, λ, 4, 4]

    p = np.where(pd.values > np.pi + 1e-12, pd.values - 2 * np.pi, pd.values)
    order = np.argsort(p, kind="stable")
    at_pi = np.abs(p[order] - np.pi) <= 1e-12
    inner = order[~at_pi]
    if at_pi.any():
        seam = slab(pd.values[order[at_pi][0]])
    elif len(p) == 1:
        seam = slab(pd.values[0])
    else:
        lo, hi = p[order[-1]], p[order[0]] + 2 * np.pi
        t = (np.pi - lo) / (hi - lo)
        seam = (1 - t) * slab(pd.values[order[-1]]) + t * slab(pd.values[order[0]])
    phi_nodes = np.concatenate([[-np.pi], p[inner], [np.pi]])
    desc = {"format": "brdftab pbsdf", "model": brdf.name, "parameters": json.dumps(brdf.parameters, sort_keys=True),
            "origin": str(getattr(brdf, "origin", "analytic")), "reciprocal": int(bool(brdf.reciprocal))}
    if not brdf.spectral:
        desc["grey"] = 1
    small = {"theta_h": th.values.astype(np.float32)[None, :], "theta_d": td.values.astype(np.float32)[None, :],
             "phi_d": phi_nodes.astype(np.float32)[None, :], "wvls": file_lam.astype(np.uint16),
             "description": np.frombuffer(json.dumps(desc, sort_keys=True).encode("utf-8"), np.uint8)}
    shape = (phi_nodes.size, len(td.values), len(th.values), N_WAVELENGTHS, 4, 4)
    layout = {k: (a.dtype, a.shape) for k, a in small.items()}
    layout["M"] = (np.dtype("<f4"), shape)
    header, offsets = tensor_header(layout)
    rows = [seam] + [None] * inner.size + [seam]

    def row32(m):
        with np.errstate(over="ignore", invalid="ignore"):
            out = np.ascontiguousarray(m.transpose(1, 0, 2, 3, 4)).astype("<f4")  # [θd, θh, λ, 4, 4]
        if (np.isinf(out) & ~np.isinf(m.transpose(1, 0, 2, 3, 4))).any():
            raise BrdftabError("Mueller elements exceed the float32 range of a .pbsdf")
        return out.tobytes()

    with open(path, "wb") as fh:
        fh.write(header)
        for k, a in small.items():
            fh.seek(offsets[k])
            fh.write(np.ascontiguousarray(a).tobytes())
        fh.seek(offsets["M"])
        for r in range(len(rows)):
            m = rows[r] if rows[r] is not None else slab(pd.values[inner[r - 1]])
            fh.write(row32(m))
            if progress is not None:
                progress(r + 1, len(rows))


def write_pbsdf(table, path, **options):
    """Write the polarized ``table`` (what :func:`prepare_pbsdf` returned) to ``path``."""
    data = encode_tensor(pbsdf_fields(table))
    with open(path, "wb") as fh:
        fh.write(data)


def _stored(table, **_):
    """The table a reader of the written file gets back (float32, seam and ghost nodes as
    written): the file's own fields read back."""
    return table_from_fields(pbsdf_fields(table), "the .pbsdf")


def _axis_values(fields, name, where):
    a = fields.get(name)
    if a is None:
        raise FormatError(f"{where}: not a measured_polarized file (no field {name!r})")
    if a.ndim != 2 or a.dtype != np.float32 or a.shape[1] < 1:
        raise FormatError(f"{where}: field {name!r} must be 2-D float32 with the node count in shape[1], not "
                          f"{a.dtype} {list(a.shape)}")
    v = a.reshape(-1)[:a.shape[1]].astype(float)
    if not np.all(np.isfinite(v)) or np.any(np.diff(v) <= 0):
        raise FormatError(f"{where}: field {name!r} must hold finite, strictly increasing angles [rad]")
    return v


def table_from_fields(fields: dict, where: str):
    """A polarized :class:`~brdftab.table.Table` from the fields of a ``.pbsdf``."""
    from ..grids import RusinkiewiczGrid
    from ..grids.axis import HALF_PI, Axis, angle_axis
    from ..table import Table, make_table
    from ..channels import Layout

    th = _axis_values(fields, "theta_h", where)
    td = _axis_values(fields, "theta_d", where)
    pd = _axis_values(fields, "phi_d", where)
    wv = fields.get("wvls")
    m = fields.get("M")
    if wv is None or m is None:
        raise FormatError(f"{where}: not a measured_polarized file (no field {'wvls' if wv is None else 'M'!r})")
    if wv.ndim != 1 or wv.dtype != np.uint16:
        raise FormatError(f"{where}: field 'wvls' must be 1-D uint16 [nm], not {wv.dtype} {list(wv.shape)}")
    if wv.size != N_WAVELENGTHS:
        raise FormatError(f"{where}: field 'wvls' holds {wv.size} wavelengths; Mitsuba's measured_polarized reads "
                          f"exactly {N_WAVELENGTHS}")
    lam = wv.astype(float)
    if np.any(lam <= 0) or np.any(np.diff(lam) <= 0):
        raise FormatError(f"{where}: field 'wvls' must hold positive, strictly increasing wavelengths")
    shape = (pd.size, td.size, th.size, wv.size, 4, 4)
    if m.dtype != np.float32 or m.shape != shape:
        raise FormatError(f"{where}: field 'M' must be float32 {list(shape)} ([phi_d, theta_d, theta_h, wvls, 4, 4]), "
                          f"not {m.dtype} {list(m.shape)}")
    for name, v, hi in (("theta_h", th, HALF_PI), ("theta_d", td, HALF_PI)):
        if v[0] < -END_TOL or v[-1] > hi + END_TOL:
            raise FormatError(f"{where}: field {name!r} has nodes outside [0, 90] degrees")
    if abs(pd[0] + np.pi) > END_TOL or abs(pd[-1] - np.pi) > END_TOL:
        raise FormatError(f"{where}: field 'phi_d' must run from -pi to pi (Mitsuba clamps outside its nodes), not "
                          f"{np.degrees(pd[0]):.6g} to {np.degrees(pd[-1]):.6g} degrees")
    th = np.clip(th, 0.0, HALF_PI)
    td = np.clip(td, 0.0, HALF_PI)
    # φd: the two seam nodes are one node (their mean: a measurement may differ at ±180°), kept
    # as the last row; then [φd, θd, θh, λ, 4, 4] -> [θh, θd, φd, λ, 4, 4] in φd order, one copy
    if not m.flags.writeable:
        m = m.copy()
    m[-1] = (0.5 * (m[0].astype(float) + m[-1].astype(float))).astype(np.float32)
    phi = np.concatenate([pd[1:-1], [np.pi]])
    phi = np.where(phi < 0, phi + 2 * np.pi, phi)
    order = np.argsort(phi, kind="stable")
    phi = phi[order]
    mueller = np.ascontiguousarray(m.transpose(2, 1, 0, 3, 4, 5)[:, :, 1 + order])
    try:
        grid = RusinkiewiczGrid(th, td, phi, phi_d_fold="none", name="pbsdf")
    except ParameterError as exc:
        raise FormatError(f"{where}: node angles do not make a grid ({exc.detail})") from None
    a_th, a_td, a_pd = grid.axes
    # Mitsuba clamps beyond the end nodes: the table holds its end values out to 0° and 90°
    grid._set_axes((Axis("theta_h", a_th.values, "linear", None, domain=(0.0, HALF_PI), rule="explicit"),
                    Axis("theta_d", a_td.values, "linear", None, domain=(0.0, HALF_PI), rule="explicit"),
                    angle_axis("phi_d", a_pd.values, 2 * np.pi)))
    desc = {}
    raw = fields.get("description")
    if raw is not None and raw.dtype == np.uint8 and raw.ndim == 1:
        try:
            desc = json.loads(bytes(raw).decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError):
            desc = {"comment": bytes(raw).decode("utf-8", "replace")}
        if not isinstance(desc, dict):
            desc = {}
    grey = bool(desc.get("grey")) and np.all(mueller == mueller[..., :1, :, :], axis=None)
    if grey:
        mueller = mueller[..., :1, :, :]
    values = np.ascontiguousarray(mueller[..., 0, 0])
    layout = Layout(("mono",)) if grey else Layout(None, lam)
    table = make_table(values, grid, layout, mueller=mueller)
    ds = table.ds
    ds.attrs.update({"model": str(desc.get("model", "measured_polarized")), "parameters": str(desc.get("parameters", "{}")),
                     "isotropic": 1, "origin": str(desc.get("origin", "unknown")), "title": "BRDF table: .pbsdf"})
    if "reciprocal" in desc:
        ds.attrs["reciprocal"] = int(desc["reciprocal"])
    else:
        ds.attrs.pop("reciprocal", None)
    for k in ("spec_sha256", "spec_file", "comment"):
        if k in desc:
            ds.attrs[k] = str(desc[k])
    ds.attrs["history"] = f"read from a Mitsuba measured_polarized file ({where})"
    if np.isnan(values).any():
        ds["brdf"].attrs["missing_value"] = np.float32(np.nan)
    return Table(ds)


def read_pbsdf(path):
    """Read a ``.pbsdf`` into a polarized table (see the module docstring)."""
    import mmap

    try:
        with open(path, "rb") as fh:
            size = os.fstat(fh.fileno()).st_size
            if size == 0:
                return table_from_fields(parse_tensor(b"", str(path)), str(path))
            with mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as data:  # (a KAIST file is ~1 GB)
                fields = parse_tensor(data, str(path))
    except OSError as exc:
        raise FormatError(f"{path}: cannot read ({exc.strerror or exc})") from None
    return table_from_fields(fields, str(path))


def _field_names(head: bytes) -> set:
    """Names in the field table of a tensor file's first bytes (those that fit)."""
    names = set()
    if len(head) < 18 or not head.startswith(MAGIC):
        return names
    (n,) = struct.unpack_from("<I", head, 14)
    pos = 18
    for _ in range(min(n, 64)):
        if pos + 2 > len(head):
            break
        (k,) = struct.unpack_from("<H", head, pos)
        pos += 2
        if pos + k + 11 > len(head):
            break
        names.add(head[pos:pos + k].decode("utf-8", "replace"))
        pos += k
        ndim, = struct.unpack_from("<H", head, pos)
        pos += 11 + 8 * ndim
    return names


def _sniff(head, size):
    return {"M", "wvls", "theta_h"} <= _field_names(head)


register(FileFormat(
    name="pbsdf",
    extensions=(".pbsdf",),
    description="Mitsuba 3 measured_polarized table (tensor file, the KAIST pBRDF layout): the Mueller matrix of "
                "f_r [sr-1, no cosine] on an isotropic (theta_h, theta_d, phi_d) grid at five whole-nanometre "
                "wavelengths, both beams' Stokes x = normalize(w_light x w_view), +S3 right circular",
    read=read_pbsdf,
    write=write_pbsdf,
    sniff=_sniff,
    native_grid=_native_grid,
    params=PARAMS,
    prepare=prepare_pbsdf,
    precision=1e-6,  # float32 storage
    stored=_stored,
    polarized=True,
))
