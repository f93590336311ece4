"""Reading RGL ``.bsdf`` files: validation of the fields and :class:`RGLBSDF`, a BRDF that
evaluates a file exactly as Mitsuba 3's ``measured`` plugin does::

    m = normalize(wi + wo);  u(θ) = sqrt(2θ/π),  u(φ) = (φ + π)/(2π)
    u_m = (u(θm), u(φm − φi) [isotropic] or u(φm))          u_wi = (u(θi), u(φi))
    s = vndf.invert(u_m | φi, θi)
    f·cosθo = spectra(s | φi, θi, λ) · ndf(u_m) / (4 sigma(u_wi))       (jacobian = 1)
"""

from __future__ import annotations

import json

import numpy as np

from ..brdf import BRDF, ORIGINS
from ..channels import Layout
from ..errors import FormatError, ParameterError
from ._marginal2d import Marginal2D
from ._rgl_warp import HALF_PI, TWO_PI, bilinear, elevation, node_geometry, phi2u, sph, theta2u, u2phi, u2theta
from ._tensor import parse_tensor, read_tensor_file

__all__ = ["RGB", "RGLBSDF", "RGLGrid", "read_rgl", "read_rgl_bytes"]

#: Channels of RGB files (their luminance map uses Rec. 709 Y: channels.luminance_weights).
RGB = ("R", "G", "B")


def _field(fields, name, where, ndim, dtype):
    if name not in fields:
        raise FormatError(f"{where}: missing field {name!r} (not an RGL .bsdf file?)")
    a = fields[name]
    if a.ndim != ndim or a.dtype != np.dtype(dtype):
        raise FormatError(f"{where}: field {name!r} must be {ndim}-D {np.dtype(dtype).name}, got "
                          f"{a.ndim}-D {a.dtype.name} of shape {a.shape}")
    return a


def _validate(fields: dict, where: str):
    """Check the fields as Mitsuba's ``measured`` plugin does, and more (values)."""
    f = {}
    f["description"] = _field(fields, "description", where, 1, np.uint8)
    f["jacobian"] = _field(fields, "jacobian", where, 1, np.uint8)
    if f["jacobian"].shape != (1,):
        raise FormatError(f"{where}: field 'jacobian' must have shape [1], got {list(f['jacobian'].shape)}")
    for name in ("theta_i", "phi_i"):
        f[name] = _field(fields, name, where, 1, np.float32)
    spectral = "wavelengths" in fields
    key = "spectra" if spectral else "rgb"
    if spectral:
        f["wavelengths"] = _field(fields, "wavelengths", where, 1, np.float32)
    for name in ("ndf", "sigma"):
        f[name] = _field(fields, name, where, 2, np.float32)
    f["vndf"] = _field(fields, "vndf", where, 4, np.float32)
    f["luminance"] = _field(fields, "luminance", where, 4, np.float32)
    if not spectral and "rgb" not in fields and "spectra" in fields:
        raise FormatError(f"{where}: field 'spectra' without 'wavelengths' (a spectral file needs both)")
    f[key] = _field(fields, key, where, 5, np.float32)
    n_phi, n_theta = f["phi_i"].size, f["theta_i"].size
    n_chan = f["wavelengths"].size if spectral else 3
    if n_phi < 1 or n_theta < 1 or n_chan < 1:
        raise FormatError(f"{where}: theta_i, phi_i{' and wavelengths' if spectral else ''} need at least one value")
    spec = f[key]
    checks = [
        ("vndf", f["vndf"].shape[:2] == (n_phi, n_theta), f"[{n_phi}, {n_theta}, H, W]"),
        ("luminance", f["luminance"].shape[:2] == (n_phi, n_theta)
         and f["luminance"].shape[2] == f["luminance"].shape[3], f"[{n_phi}, {n_theta}, N, N]"),
        (key, spec.shape[:3] == (n_phi, n_theta, n_chan) and spec.shape[3:] == f["luminance"].shape[2:],
         f"[{n_phi}, {n_theta}, {n_chan}, N, N] with N as in luminance"),
    ]
    for name, ok, expected in checks:
        if not ok:
            raise FormatError(f"{where}: field {name!r} has shape {list(fields[name].shape)}, expected {expected}")
    for name in ("ndf", "sigma", "vndf", "luminance", key):
        if min(f[name].shape[-2:]) < 2:
            raise FormatError(f"{where}: field {name!r} needs at least 2 x 2 values per table, got shape "
                              f"{list(f[name].shape)}")
    for name in ("theta_i", "phi_i", "ndf", "sigma", "vndf", "luminance", key) + (("wavelengths",) if spectral else ()):
        if not np.all(np.isfinite(f[name])):
            raise FormatError(f"{where}: field {name!r} has {int((~np.isfinite(f[name])).sum())} non-finite values")
    th, ph = f["theta_i"].astype(np.float64), f["phi_i"].astype(np.float64)
    if np.any(np.diff(th) <= 0) or th[0] < 0 or th[-1] > HALF_PI + 1e-6:
        raise FormatError(f"{where}: theta_i must increase strictly within [0, 90] degrees")
    if np.any(np.diff(ph) <= 0):
        raise FormatError(f"{where}: phi_i must increase strictly")
    if np.any(np.abs(ph) > np.pi + 1e-5):
        raise FormatError(f"{where}: phi_i must lie within [-180, 180] degrees")
    reduction = 0
    if n_phi > 2:
        # Mitsuba: reduction = rint(2π / (φi[-1] − φi[0])); it mirrors wi into
        # φ ∈ [−π, −π + 2π/reduction], so the stored φi must cover exactly that.
        ratio = TWO_PI / (ph[-1] - ph[0])
        reduction = int(np.rint(ratio)) if 0.5 <= ratio < 4.5 else 0
        ok = (reduction in (1, 2, 4) and abs(ph[0] + np.pi) < 1e-3
              and abs(ph[-1] - (TWO_PI / max(reduction, 1) - np.pi)) < 1e-3)
        if not ok:
            raise FormatError(f"{where}: phi_i covers [{np.degrees(ph[0]):.6g}, {np.degrees(ph[-1]):.6g}] degrees; an "
                              "anisotropic file must cover [-180, 180], [-180, 0] or [-180, -90] degrees")
    if spectral:
        lam = f["wavelengths"].astype(np.float64)
        if np.any(lam <= 0) or np.any(np.diff(lam) <= 0):
            raise FormatError(f"{where}: wavelengths must be positive and increase strictly")
    if np.any(f["ndf"] < 0):
        raise FormatError(f"{where}: field 'ndf' has negative values")
    if not np.all(f["sigma"] > 0):
        raise FormatError(f"{where}: field 'sigma' must be positive (it divides)")
    for name in ("vndf", "luminance"):
        a = f[name].astype(np.float64).reshape(n_phi * n_theta, -1)
        top = a.max(axis=1)
        # rounding-sized negatives (1e-6 of the slice's largest value; the RGL database has
        # some of -4e-10) are accepted, as Mitsuba accepts them
        if np.any(a < -1e-6 * np.maximum(top, 0.0)[:, None]):
            raise FormatError(f"{where}: field {name!r} has negative values (it is a density)")
        if np.any(top <= 0):
            raise FormatError(f"{where}: field {name!r} has an all-zero slice (it is a density)")
    return f, spectral, key, reduction


class _Axis:
    def __init__(self, name, values):
        self.name = name
        self.values = np.asarray(values, float)

    def __len__(self):
        return self.values.size


class RGLGrid:
    """The sample layout of an RGL file (not a brdftab grid: the samples sit on the ``vndf`` warp).

    ``axes`` are the incident directions (φi, θi); each carries ``N × N`` warped samples.
    """

    def __init__(self, bsdf: "RGLBSDF"):
        self.axes = (_Axis("phi_i", bsdf.phi_i), _Axis("theta_i", bsdf.theta_i))
        self.dims = ("phi_i", "theta_i", "sample_y", "sample_x")
        n = bsdf.resolution
        self.shape = (bsdf.phi_i.size, bsdf.theta_i.size, n, n)
        self.size = int(np.prod(self.shape))
        self._text = (f"RGL adaptive parameterization: {bsdf.phi_i.size} phi_i x {bsdf.theta_i.size} theta_i x "
                      f"{n}x{n} warped samples (vndf {bsdf.fields['vndf'].shape[3]}x{bsdf.fields['vndf'].shape[2]}, "
                      f"ndf {bsdf.fields['ndf'].shape[1]}x{bsdf.fields['ndf'].shape[0]})"
                      f"{'' if bsdf.isotropic else ', anisotropic'}")

    def describe(self) -> str:
        return self._text

    def equals(self, other) -> bool:
        return other is self


class RGLBSDF(BRDF):
    """A BRDF read from an RGL ``.bsdf`` file; evaluates as Mitsuba 3's ``measured`` plugin.

    ``eval`` returns f = (Mitsuba's f·cosθo) / cosθo. Spectral files evaluate at wavelengths
    within their ``wavelengths`` range (linear in between); RGB files have channels R, G, B.

    Table-like views for ``brdftab info``: ``grid`` (:class:`RGLGrid`), ``values`` (f at the
    stored sample nodes, ``[Nφi, Nθi, N, N, C]``, 0 where ωo is below the horizon) and ``ds``
    (an ``xarray.Dataset`` of those values with the file's description and provenance).
    """

    name = "rgl-bsdf"

    def __init__(self, fields: dict, source: str = "<fields>"):
        f, spectral, key, reduction = _validate(fields, source)
        self.fields = {k: fields[k] for k in fields}
        self.source = source
        self.theta_i = f["theta_i"]
        self.phi_i = f["phi_i"]
        self.isotropic = self.phi_i.size <= 2
        self.reduction = reduction
        self.jacobian = bool(f["jacobian"][0])
        self.description = bytes(f["description"]).decode("utf-8", errors="replace")
        self.provenance = self._provenance(fields)
        # brdftab records origin and reciprocity in its files; a file without them (the RGL
        # database's measurements) is of unknown origin and declares no reciprocity. Even the
        # file of a reciprocal model is not: it is conditioned on wi (f·cosθo tabulated per
        # incident direction), so its interpolant is reciprocal only approximately — it declares
        # itself non-reciprocal and keeps the source's word in `source_reciprocal`.
        self.source_reciprocal = self.provenance.get("reciprocal")
        self.reciprocity_declared = "reciprocal" in self.provenance
        self.reciprocal = False
        origin = self.provenance.get("origin", "analytic" if "model" in self.provenance else "unknown")
        self.origin = origin if origin in ORIGINS else "unknown"
        self.resolution = f[key].shape[-1]
        if spectral:
            self._lam = f["wavelengths"].astype(np.float64)
            self.layout = Layout(None, self._lam)
        else:
            self._lam = None
            self.layout = Layout(RGB)
        params = (self.phi_i, self.theta_i)
        self._ndf = bilinear(f["ndf"])
        self._sigma = bilinear(f["sigma"])
        self._vndf = Marginal2D(f["vndf"], params)
        spec = f[key]
        # [slices, N, N, C] for one gather of all channels (parameter strides as the vndf's)
        self._spectra = np.moveaxis(spec.reshape((-1,) + spec.shape[2:]), 1, -1).astype(np.float64)
        self._values = None
        self._ds = None

    @staticmethod
    def _provenance(fields):
        raw = fields.get("provenance")
        if raw is None or raw.dtype != np.uint8 or raw.ndim != 1:
            return {}
        try:
            out = json.loads(bytes(raw).decode("utf-8"))
        except (UnicodeDecodeError, ValueError):
            return {}
        return out if isinstance(out, dict) else {}

    @property
    def parameters(self) -> dict:
        out = {"description": self.description}
        if "model" in self.provenance:
            out["source_model"] = {"model": self.provenance.get("model"),
                                   "parameters": self.provenance.get("parameters", {})}
        return out

    def describe(self) -> str:
        return f"RGL .bsdf ({self.description})"

    # --------------------------------------------------------------------------------
    def _channel_weights(self, lam, n):
        """(stored channel index lo, hi, weight of hi) per output channel."""
        if lam is None:
            idx = np.arange(3)
            return idx, idx, np.zeros(3)
        stored = self._lam
        lo_, hi_ = stored[0], stored[-1]
        if np.any(lam < lo_ - 1e-9) or np.any(lam > hi_ + 1e-9):
            raise ParameterError("wavelengths", f"outside the file's wavelengths [{lo_:g}, {hi_:g}] nm")
        if stored.size == 1:
            z = np.zeros(lam.size, np.intp)
            return z, z, np.zeros(lam.size)
        j = np.clip(np.searchsorted(stored, lam, side="left") - 1, 0, stored.size - 2)
        t = np.clip((lam - stored[j]) / (stored[j + 1] - stored[j]), 0.0, 1.0)
        return j, j + 1, t

    @property
    def theta_hold(self) -> float:
        """Elevation [rad] beyond which f is held (see :meth:`_eval`): 90° − 180°/resolution
        (86.25° for the default 48 × 48 samples, 84.4° for 32 × 32)."""
        return float(np.pi / 2 - np.pi / self.resolution)

    def eval(self, wi, wo, wavelengths=None, *, assume_unit: bool = False) -> np.ndarray:
        """f(wi, wo) [sr⁻¹] (see :meth:`_eval_numpy` for the hold near the horizon), in one compiled
        pass per pair written into the result (:func:`brdftab._interp_kernels.rgl_eval`), with
        the normalization, NaN and horizon rules of every BRDF (numpy inside
        :func:`brdftab.brdf.numpy_reference`)."""
        from ..brdf import BRDF, compiled_enabled
        from ..geometry import as_directions

        if not compiled_enabled():
            return BRDF.eval(self, wi, wo, wavelengths, assume_unit=assume_unit)

        wi, wo = as_directions(wi, wo)
        lam = self.layout.resolve(wavelengths)
        lo, hi, t = self._channel_weights(lam, self.layout.n_out(lam))
        lead = wi.shape[:-1]
        out = self._compiled(wi.reshape(-1, 3), wo.reshape(-1, 3), lo, hi, t, check=not assume_unit, hold=True)
        return out.reshape(lead + (lo.size,))

    def _eval(self, wi, wo, lam, n):
        from ..brdf import compiled_enabled

        if not compiled_enabled():
            return self._eval_numpy(wi, wo, lam, n)
        lo, hi, t = self._channel_weights(lam, n)
        return self._compiled(wi, wo, lo, hi, t, check=False, hold=True)

    def _kernel_data(self):
        """The file's tables as the compiled evaluation reads them (contiguous float64); cached."""
        if getattr(self, "_kernel_tables", None) is None:
            v = self._vndf
            self._kernel_tables = dict(
                p_phi=np.ascontiguousarray(v.params[0]), p_theta=np.ascontiguousarray(v.params[1]),
                st_phi=int(v.strides[0]), st_theta=int(v.strides[1]),
                data=np.ascontiguousarray(v.data), cond=np.ascontiguousarray(v.cond),
                marg=np.ascontiguousarray(v.marg), spectra=np.ascontiguousarray(self._spectra),
                ndf=np.ascontiguousarray(self._ndf.data[0]), sigma=np.ascontiguousarray(self._sigma.data[0]))
        return self._kernel_tables

    def _compiled(self, wi, wo, lo, hi, t, check, hold):
        """f (``hold``: with the hold of :meth:`_eval_numpy`) or, without it, f·cosθo at
        ``(M, 3)`` pairs, compiled (one range of rows per thread); 0 at and below the horizon."""
        from .._interp_kernels import contiguous_pairs, rgl_eval
        from .._jit import parallel_rows

        k = self._kernel_data()
        out = np.empty((wi.shape[0], lo.size))
        lo, hi, t = (np.ascontiguousarray(lo, np.int64), np.ascontiguousarray(hi, np.int64),
                     np.ascontiguousarray(t, np.float64))
        zero_i = zero_o = 0
        for rows, a, b in contiguous_pairs(wi, wo):
            o = out[rows]

            def run(r0, r1, a=a, b=b, o=o):
                return rgl_eval(a[r0:r1], b[r0:r1], check, hold, hold, self.isotropic, self.reduction, self.jacobian,
                                self.theta_hold, k["p_phi"], k["p_theta"], k["st_phi"], k["st_theta"], k["data"],
                                k["cond"], k["marg"], k["spectra"], k["ndf"], k["sigma"], lo, hi, t, o[r0:r1])

            for zi, zo in parallel_rows(run, a.shape[0]):
                zero_i, zero_o = zero_i + zi, zero_o + zo
        if zero_i or zero_o:
            raise ParameterError("wi" if zero_i else "wo", "a direction has zero length")
        return out

    def _eval_numpy(self, wi, wo, lam, n):
        """f = (f·cosθo)/cosθo, with f **held** beyond the last well-conditioned elevation.

        The file stores f·cosθo on N × N (``resolution``) warped samples; in the cells that
        straddle the horizon the interpolated f·cosθo does not vanish as cosθo does, so the
        quotient grows without bound at grazing ωo (a Lambertian's file written with the
        default 48 × 48 samples, median over θi and azimuths: 1.36× its f at 89°, 7.8× at
        89.9°). Beyond θ_hold = 90° − 180°/resolution (:attr:`theta_hold`) f is therefore taken
        at θ_hold with the same azimuth (a Lambertian's file then reads within 20 % of its f;
        tests/test_rgl.py::test_f_is_held_near_the_horizon). Renderers use f·cosθo
        (:meth:`eval_cos`, as Mitsuba evaluates the file, and as brdftab's albedo integrals
        do); a fine quadrature of the held f is within 0.5 % of that albedo. Both measured in
        tests/test_rgl.py: ``test_f_is_held_near_the_horizon``,
        ``test_albedo_of_a_file_matches_mitsubas_and_a_resolved_quadrature``."""
        lo, hi, t = self._channel_weights(lam, n)
        out = np.empty((wi.shape[0], lo.size))
        c0 = np.cos(self.theta_hold)
        s0 = np.sin(self.theta_hold)
        for start in range(0, wi.shape[0], 1 << 14):
            sl = slice(start, start + (1 << 14))
            w = wo[sl]
            low = w[:, 2] < c0
            if low.any():
                w = w.copy()
                r = np.hypot(w[low, 0], w[low, 1])
                w[low, 0] *= s0 / r
                w[low, 1] *= s0 / r
                w[low, 2] = c0
            out[sl] = self._eval_cos(wi[sl], w, lo, hi, t) / w[:, 2:3]
        return out

    def eval_cos(self, wi, wo, wavelengths=None):
        """f·cosθo exactly as Mitsuba 3's ``measured`` plugin evaluates the file (no hold), compiled
        (numpy inside :func:`brdftab.brdf.numpy_reference`)."""
        from ..brdf import compiled_enabled
        from ..geometry import as_directions

        if not compiled_enabled():
            return self._eval_cos_numpy(wi, wo, wavelengths)

        wi, wo = as_directions(wi, wo)
        lead = wi.shape[:-1]
        lam = self.layout.resolve(wavelengths)
        lo, hi, t = self._channel_weights(lam, self.layout.n_out(lam))
        out = self._compiled(wi.reshape(-1, 3), wo.reshape(-1, 3), lo, hi, t, check=False, hold=False)
        return out.reshape(lead + (lo.size,))

    def _eval_cos_numpy(self, wi, wo, wavelengths=None):
        """:meth:`eval_cos` in numpy (the reference of the compiled evaluation)."""
        from ..geometry import as_directions

        wi, wo = as_directions(wi, wo)
        lead = wi.shape[:-1]
        wi, wo = wi.reshape(-1, 3), wo.reshape(-1, 3)
        lam = self.layout.resolve(wavelengths)
        lo, hi, t = self._channel_weights(lam, self.layout.n_out(lam))
        out = np.zeros((wi.shape[0], lo.size))
        # a non-finite component reads NaN, as in the compiled evaluation
        finite = np.isfinite(wi).all(axis=-1) & np.isfinite(wo).all(axis=-1)
        out[~finite] = np.nan
        above = finite & (wi[:, 2] > 1e-12) & (wo[:, 2] > 1e-12)
        if above.any():
            out[above] = self._eval_cos(wi[above], wo[above], lo, hi, t)
        return out.reshape(lead + (lo.size,))

    def _eval_cos(self, wi, wo, lo, hi, t):
        """Mitsuba's ``eval``: f·cosθo at ``(M, 3)`` pairs above the horizon."""
        u_m, u_wi, params = self._coordinates(wi, wo)
        sample, _ = self._vndf.invert(u_m, params)
        spec = self._lookup_spectra(sample, params)  # [M, C stored]
        out = spec[:, lo] * (1.0 - t) + spec[:, hi] * t
        if self.jacobian:
            out = out * (self._ndf.eval(u_m) / (4.0 * self._sigma.eval(u_wi)))[:, None]
        return out

    def stored_weights(self, wi, wo):
        """The reading as a linear map of the stored values: a sparse ``[M, S·N·N]`` matrix A
        with ``eval_cos(wi, wo)[:, c] == A @ stored[c]`` for every stored channel c, where
        ``stored[c]`` is the ``rgb``/``spectra`` field's channel c flattened in (φi, θi, y, x)
        order (S = Nφi·Nθi slices). Its rows hold the bilinear weights of the 4 sample nodes
        around the warped point in each of the 2 (isotropic) or 4 slices the reader blends,
        times D̂/(4σ̂); 0 rows where ωi or ωo is at or below the horizon or not finite. (The
        writer's least-squares values: :mod:`._rgl_fit`.)"""
        import scipy.sparse as sparse

        from ..geometry import as_directions

        wi, wo = as_directions(wi, wo)
        wi, wo = wi.reshape(-1, 3), wo.reshape(-1, 3)
        n, n_rows = self.resolution, wi.shape[0]
        size = self._spectra.shape[0] * n * n
        finite = np.isfinite(wi).all(axis=-1) & np.isfinite(wo).all(axis=-1)
        above = np.flatnonzero(finite & (wi[:, 2] > 1e-12) & (wo[:, 2] > 1e-12))
        if above.size == 0:
            return sparse.csr_matrix((n_rows, size))
        wi_a, wo_a = wi[above], wo[above]
        wi_a = wi_a / np.linalg.norm(wi_a, axis=-1, keepdims=True)
        wo_a = wo_a / np.linalg.norm(wo_a, axis=-1, keepdims=True)
        u_m, u_wi, params = self._coordinates(wi_a, wo_a)
        sample, _ = self._vndf.invert(u_m, params)
        factor = self._ndf.eval(u_m) / (4.0 * self._sigma.eval(u_wi)) if self.jacobian else np.ones(above.size)
        sl, wt = self._vndf._corners(params)
        ix, iy, tx, ty = self._cells(sample)
        cols, vals = [], []
        for c in range(sl.shape[0]):
            base = sl[c] * (n * n) + iy * n + ix
            w = wt[c] * factor
            corners = ((0, (1.0 - tx) * (1.0 - ty)), (1, tx * (1.0 - ty)), (n, (1.0 - tx) * ty), (n + 1, tx * ty))
            for offset, wc in corners:
                cols.append(base + offset)
                vals.append(w * wc)
        k = len(cols)
        rows = np.tile(above, k)
        return sparse.csr_matrix((np.concatenate(vals), (rows, np.concatenate(cols))), shape=(n_rows, size))

    def _coordinates(self, wi, wo):
        """The reader's coordinates of unit pairs above the horizon: u_m, u_wi and the
        parameters (φi, θi) of the slices (after the reduction's turn of anisotropic files)."""
        if not self.isotropic and self.reduction >= 2:
            # mulsign_neg(v, s) = v · (s >= 0 ? −1 : 1): wi goes to y <= 0 (and x <= 0 for a
            # quarter); reduction 2 turns both axes by the sign of y (a rotation by π).
            sy = wi[:, 1]
            sx = wi[:, 0] if self.reduction == 4 else sy
            flip = np.stack([np.where(sx >= 0, -1.0, 1.0), np.where(sy >= 0, -1.0, 1.0), np.ones_like(sy)], axis=-1)
            wi, wo = wi * flip, wo * flip
        m = wi + wo
        m = m / np.linalg.norm(m, axis=-1, keepdims=True)
        th_i, ph_i = elevation(wi), np.arctan2(wi[:, 1], wi[:, 0])
        th_m, ph_m = elevation(m), np.arctan2(m[:, 1], m[:, 0])
        u_wi = np.stack([theta2u(th_i), phi2u(ph_i)], axis=-1)
        uy = phi2u(ph_m - ph_i if self.isotropic else ph_m)
        u_m = np.stack([theta2u(th_m), uy - np.floor(uy)], axis=-1)
        return u_m, u_wi, (ph_i, th_i)

    #: The albedo integrals of :mod:`brdftab.integrate` use :meth:`albedo_rule` over the whole
    #: hemisphere (their coverage is the hemisphere's).
    rule_coverage = "hemisphere"
    #: Quadrature points of :meth:`albedo_rule` per sample cell and axis.
    RULE_PER_CELL = 4

    def albedo_rule(self, wi):
        """The file's own outgoing quadrature at ``wi`` (a hint for :mod:`brdftab.integrate`):
        midpoints of the warped sample square, RULE_PER_CELL per sample cell and axis, mapped to
        ωo through the file's ``vndf`` warp, weight dωo = 8π² u_θ sinθm (ωi·m) / pdf(u_m) per unit
        area of the square. The warp places the samples where the file's lobes are (a pyramid's
        facet peaks, a narrow gloss), and the stored values are bilinear in the square, so the
        integrand is smooth there: a half-vector rule graded about the mirror direction missed
        peaks away from it (a pyramid file's albedo came out 1.26 instead of 0.40).
        tests/test_rgl.py::test_albedo_rule_follows_the_files_own_lobes."""
        wi = np.asarray(wi, float).reshape(3)
        flip = np.ones(3)
        if not self.isotropic and self.reduction >= 2:  # the frame _eval_cos turns wi into
            sy, sx = wi[1], (wi[0] if self.reduction == 4 else wi[1])
            flip = np.array([-1.0 if sx >= 0 else 1.0, -1.0 if sy >= 0 else 1.0, 1.0])
        w_in = wi * flip
        n = self.resolution * self.RULE_PER_CELL
        g = (np.arange(n) + 0.5) / n
        s = np.stack(np.meshgrid(g, g, indexing="xy"), axis=-1).reshape(-1, 2)
        th_i, ph_i = float(elevation(w_in[None])[0]), float(np.arctan2(w_in[1], w_in[0]))
        u_m, pdf = self._vndf.fixed((ph_i, th_i)).sample(s)
        th_m = u2theta(u_m[:, 0])
        m = sph(th_m, u2phi(u_m[:, 1]) + (ph_i if self.isotropic else 0.0))
        cos_im = m @ w_in
        wo = 2.0 * cos_im[:, None] * m - w_in
        ok = (pdf > 0) & (cos_im > 0) & (wo[:, 2] > 1e-12) & np.isfinite(pdf)
        weight = np.zeros(s.shape[0])
        weight[ok] = 8.0 * np.pi ** 2 * u_m[ok, 0] * np.sin(th_m[ok]) * cos_im[ok] / (pdf[ok] * n * n)
        return (wo * flip)[ok], weight[ok]

    def _cells(self, sample):
        """The cell of the N × N stored values holding each point of the unit square: its lower
        node (ix, iy) and the fractions (tx, ty) within it."""
        n = self.resolution
        x = np.clip(sample[:, 0], 0.0, 1.0) * (n - 1)
        y = np.clip(sample[:, 1], 0.0, 1.0) * (n - 1)
        ix = np.minimum(x.astype(np.intp), n - 2)
        iy = np.minimum(y.astype(np.intp), n - 2)
        return ix, iy, x - ix, y - iy

    def _lookup_spectra(self, sample, params):
        sl, wt = self._vndf._corners(params)
        ix, iy, tx, ty = self._cells(sample)
        tx, ty = tx[:, None], ty[:, None]
        out = 0.0
        for c in range(sl.shape[0]):
            s = sl[c]
            v00 = self._spectra[s, iy, ix]
            v10 = self._spectra[s, iy, ix + 1]
            v01 = self._spectra[s, iy + 1, ix]
            v11 = self._spectra[s, iy + 1, ix + 1]
            v0 = v00 + tx * (v10 - v00)
            v1 = v01 + tx * (v11 - v01)
            out = out + wt[c][:, None] * (v0 + ty * (v1 - v0))
        return out

    def ndf(self, h):
        """The file's own normal distribution (its ``ndf`` table, bilinear) at unit normals
        ``h[..., 3]``: a file written again with other resolutions keeps it."""
        h = np.asarray(h, float)
        lead = h.shape[:-1]
        h = h.reshape(-1, 3)
        u = np.stack([theta2u(elevation(h)), phi2u(np.arctan2(h[:, 1], h[:, 0]))], axis=-1)
        return np.where(h[:, 2] > 0, self._ndf.eval(u), 0.0).reshape(lead)

    # --------------------------------------------------------------------------------
    # table-like views

    @property
    def grid(self) -> RGLGrid:
        return RGLGrid(self)

    @property
    def values(self) -> np.ndarray:
        """f [sr⁻¹] at the stored sample nodes, ``[Nφi, Nθi, N, N, C]`` (0 below the horizon)."""
        if self._values is None:
            wi, wo, u_m, (th, ph), shape = node_geometry(self._vndf, self.theta_i.astype(np.float64),
                                                          self.phi_i.astype(np.float64), self.resolution,
                                                          self.isotropic)
            out = np.zeros((wi.shape[0], len(self.layout.channels) if self._lam is None else self._lam.size))
            ok = wo[:, 2] > 1e-12
            with np.errstate(all="ignore"):
                # at the stored nodes the quotient is exact (no hold: the node is data)
                out[ok] = self.eval_cos(wi[ok], wo[ok]) / wo[ok, 2:3]
            self._values = out.reshape(shape + (out.shape[1],))
        return self._values

    def statistics(self) -> dict:
        """Count and range of :attr:`values` (as :meth:`brdftab.table.Table.statistics`)."""
        v = self.values
        fin = np.isfinite(v)
        good = v[fin]
        return {"dtype": str(v.dtype), "samples": int(v.size), "min": float(good.min()) if good.size else None,
                "max": float(good.max()) if good.size else None, "nonfinite": int(v.size - fin.sum()),
                "negative": int((good < 0).sum()), "missing": 0}

    @property
    def ds(self):
        if self._ds is None:
            import xarray as xr

            chan = ("wavelength", self._lam) if self._lam is not None else ("channel", np.array(RGB, dtype=object))
            coords = {"phi_i": ("phi_i", self.phi_i.astype(np.float64), {"units": "rad"}),
                      "theta_i": ("theta_i", self.theta_i.astype(np.float64), {"units": "rad"}),
                      chan[0]: (chan[0], chan[1], {"units": "nm"} if self._lam is not None else {})}
            var = xr.Variable(("phi_i", "theta_i", "sample_y", "sample_x", chan[0]), self.values,
                              attrs={"units": "sr-1", "long_name": "f_r at the stored (warped) sample nodes"})
            attrs = {"format": "rgl", "parameterization": "rgl-adaptive (Dupuy & Jakob 2018)",
                     "description": self.description, "grid": self.grid.describe(),
                     "isotropic": int(self.isotropic), "reciprocal": int(self.reciprocal),
                     "origin": self.origin,
                     "jacobian": int(self.jacobian)}
            for k in ("model", "brdftab_version", "created", "ndf_source"):
                if k in self.provenance:
                    attrs[k] = str(self.provenance[k])
            if "parameters" in self.provenance:
                attrs["parameters"] = json.dumps(self.provenance["parameters"], sort_keys=True, default=str)
            self._ds = xr.Dataset({"brdf": var}, coords=coords, attrs=attrs)
        return self._ds


def read_rgl(path) -> RGLBSDF:
    """Read an RGL ``.bsdf`` file (RGB or spectral, isotropic or anisotropic)."""
    fields = read_tensor_file(path)
    return RGLBSDF(fields, str(path))


def read_rgl_bytes(data: bytes, where: str = "<bytes>") -> RGLBSDF:
    return RGLBSDF(parse_tensor(data, where), where)
