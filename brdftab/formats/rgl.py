"""Mitsuba 3 / RGL tabulated BSDF files (``.bsdf``, Dupuy & Jakob 2018): the format's
registration and public names.

The file is a Mitsuba ``tensor_file`` (:mod:`._tensor`) with the fields of Mitsuba 3's
``measured`` plugin (see ``formats/rgl-bsdf.md``):

``description`` uint8 text · ``jacobian`` uint8[1] · ``theta_i`` f32[Nθi] · ``phi_i`` f32[Nφi]
· ``ndf`` / ``sigma`` f32[Ny, Nx] · ``vndf`` f32[Nφi, Nθi, Hv, Wv] · ``luminance``
f32[Nφi, Nθi, N, N] · ``rgb`` f32[Nφi, Nθi, 3, N, N] (RGB files) or ``spectra``
f32[Nφi, Nθi, Nλ, N, N] + ``wavelengths`` f32[Nλ] (spectral files).

The work is done by modules of one job each, which import nothing from this one:

* :mod:`._rgl_options` — the format options (defaults, validation, incident elevations);
* :mod:`._rgl_warp` — the coordinate maps u(θ), u(φ) and the warped sample nodes;
* :mod:`._rgl_ndf` — the normal distribution a writer stores (the model's own, or one from
  the back-scattering by power iteration) and its projected area σ;
* :mod:`._rgl_write` — :func:`prepare_rgl` samples any BRDF into the fields;
* :mod:`._rgl_read` — validation of the fields and :class:`RGLBSDF`, a BRDF that evaluates a
  file exactly as Mitsuba does.

A reader maps a direction pair to the unit square through the ``vndf`` warp and interpolates
the stored values there; the writer stores f(ωi, ωo)·cosθo·4σ̂/D̂ at the warped nodes, with
σ̂, D̂ the interpolants the readers evaluate, so every reader returns f·cosθo exactly at the
nodes. Isotropic files have φi = [0]; anisotropic ones φi over [−π, π].

References: J. Dupuy, W. Jakob, "An adaptive parameterization for efficient material
acquisition and rendering", ACM TOG 37(6) (2018); J. Dupuy et al., "Extracting
microfacet-based BRDF parameters from arbitrary materials with power iterations", CGF 34(4)
(2015); mitsuba-renderer/mitsuba3 ``src/bsdfs/measured.cpp``,
``include/mitsuba/core/distr_2d.h``.
"""

from __future__ import annotations

import numpy as np

from . import FileFormat, NotStorable, register
from ._rgl_ndf import BACKSCATTER_BOUND, backscatter_bound, backscatter_ndf, model_ndf, sigma_table
from ._rgl_options import DEFAULTS, MAX_RESOLUTION, NDF_CHOICES, OPTIONS, PARAMS, check_options, theta_i_nodes
from ._rgl_read import RGB, RGLBSDF, RGLGrid, read_rgl, read_rgl_bytes
from ._rgl_warp import HALF_PI, TWO_PI, elevation, node_geometry, phi2u, sph, theta2u, u2phi, u2theta
from ._rgl_write import NDF_FLOOR, WARP_UNIFORM, RGLPayload, prepare_rgl, write_rgl
from ._tensor import MAGIC

__all__ = ["RGLBSDF", "RGLGrid", "RGLPayload", "read_rgl", "read_rgl_bytes", "write_rgl", "prepare_rgl",
           "check_options", "model_ndf", "backscatter_ndf", "backscatter_bound", "sigma_table", "theta_i_nodes",
           "node_geometry", "theta2u", "u2theta", "phi2u", "u2phi", "elevation", "sph", "DEFAULTS", "OPTIONS",
           "NDF_CHOICES", "NDF_FLOOR", "WARP_UNIFORM", "BACKSCATTER_BOUND", "RGB", "MAX_RESOLUTION", "HALF_PI",
           "TWO_PI"]


def _native_grid(requested, options):
    return None  # the file has its own sample layout; resolutions are format options


def _stored(payload, **_):
    """The file as a reader sees it: its float32 fields, evaluated as Mitsuba does. Fields that
    overflow float32 (or hold NaN) make no readable file: :class:`~brdftab.formats.NotStorable`."""
    bad = {name: int(np.count_nonzero(~np.isfinite(a))) for name, a in payload.fields.items()
           if isinstance(a, np.ndarray) and a.dtype.kind == "f"}
    bad = {name: n for name, n in bad.items() if n}
    if bad:
        count, total = sum(bad.values()), sum(payload.fields[name].size for name in bad)
        where = ", ".join(f"{n} of {payload.fields[name].size} in '{name}'" for name, n in bad.items())
        raise NotStorable(f"{count} of {total} values of the file's float32 fields are NaN or infinite ({where}; "
                          f"largest finite float32 {float(np.finfo(np.float32).max):.4g})", count, total)
    return payload.bsdf


register(FileFormat(
    name="rgl",
    extensions=(".bsdf",),
    description="Mitsuba 3 / RGL tabulated BSDF (tensor file for the 'measured' plugin; RGB or spectral, "
                "isotropic or anisotropic): f_r cos(theta_o) 4 sigma(wi) / D(m) at the warped samples, as "
                "Mitsuba's reader expects; read back as f_r [sr-1]",
    read=read_rgl,
    write=write_rgl,
    magic=(MAGIC,),
    requires=(),
    native_grid=_native_grid,
    params=PARAMS,
    prepare=prepare_rgl,
    check_options=check_options,
    precision=1e-9,  # the written float32 fields, read by the same reader
    stored=_stored,
))
