"""Energy conservation and albedo integrals.

``energy``
    the directional-hemispherical reflectance a(θi) = ∫ f cosθo dωo (+ any ideal specular
    coefficient) must not exceed 1 + tolerance anywhere on a sweep of θi from 0 to 89° (and of
    φi over the circle when the BRDF is anisotropic). When a table exceeds it but the model it
    was made from (given, or named in its provenance) does not, and the table's figure is within
    :data:`INTERPOLATION_OVERSHOOT` (1.1×) of the model's plus the tolerance, the excess is the
    table's interpolation of a peaked lobe, not an energy gain of the source: the check then
    WARNs instead of failing (the tabulation check measures that error); beyond 1.1× it fails.
    An excess in measured data (or data of unknown origin) is the data's own — a measurement's
    calibration or noise, not an error of brdftab's: it is a WARN with its figure, never a
    refusal. Analytic models and tables of them keep the FAIL.
``albedo``
    reports the a(θi) curve and the white-sky (bihemispherical) albedo; with ``expected``
    values (a number for every θi, or a list at ``expected_theta_i_deg``) and/or
    ``white_sky``, compares them within ``tolerance``. Its JSON ``data`` has a stable shape:
    ``theta_i_deg`` [n_θ], ``channels`` [C], ``values`` [n_θ][C] (a(θi) averaged over φi),
    ``coverage`` [n_θ], ``white_sky`` [C] (null when the sweep does not reach 0…80°),
    ``coverage_min``; for an anisotropic BRDF also ``phi_i_deg`` [n_φ] and ``values_phi``
    [n_θ][n_φ][C] (a(θi, φi) at every incidence azimuth).

Both use :func:`brdftab.integrate.albedo_curve` on the same sweep and share the result.
Missing samples and directions outside a table's grid are left out of the integrals, which are
then lower bounds; the smallest covered fraction of the projected solid angle is reported —
as the grid's coverage when nothing is missing. A verdict needs the integrals to cover at
least ``min_coverage`` (default 90 %) of the projected solid angle at every θi of the sweep:
below it a pass is a WARN saying how little was covered (an excess over 1 still fails: a lower
bound above 1 is an excess). A table from which nothing can be integrated is SKIPped, saying so.
"""

from __future__ import annotations

import numpy as np

from ..errors import ParameterError
from ..integrate import DEFAULT_NODES, albedo_curve, directional_albedo
from ..params import Param
from . import Check, register
from ._reference import reference

__all__ = ["Energy", "Albedo", "sweep", "curve"]



_SWEEP = (
    Param("theta_i_max", "float", "Largest incidence angle of the sweep.", units="rad", default=float(np.radians(89.0)),
          minimum=0.0, maximum=float(np.radians(89.99)), angle=True),
    Param("n_theta_i", "int", "Incidence angles in the sweep (equally spaced from 0).", default=90, minimum=1,
          maximum=10_000),
    Param("n_phi_i", "int", "Incidence azimuths over the circle (anisotropic BRDFs only).", default=8, minimum=1,
          maximum=1000),
)


def sweep(ctx, theta_i_max, n_theta_i, n_phi_i):
    """Incidence angles and azimuths of the sweep [rad]. A table with incidence axes (a gonio
    table) is swept at its own incidence nodes (up to ``theta_i_max``): between them it holds
    interpolations of its slices, not measured incidences (and θi = 0 when its domain reaches
    it before the first node)."""
    theta = np.linspace(0.0, theta_i_max, n_theta_i)
    b = ctx.brdf
    phi = np.array([0.0]) if b.isotropic else np.arange(n_phi_i) * (2 * np.pi / n_phi_i)
    grid = b.grid if ctx.on_grid else None
    if grid is not None and getattr(grid, "scattered", False):
        # scattered samples: swept at their own incidence angles when they share a few (a gonio
        # measurement), else over the range they span
        nodes = grid.incidence_angles()
        nodes = nodes[nodes <= theta_i_max + 1e-12]
        if nodes.size == 0:
            nodes = grid.incidence_angles()[:1]
        theta = nodes if nodes.size <= n_theta_i else np.linspace(nodes[0], nodes[-1], n_theta_i)
        if not b.isotropic:
            phi = np.unique(np.round(grid.phi_i, 9))
            phi = phi if phi.size <= n_phi_i else np.arange(n_phi_i) * (2 * np.pi / n_phi_i)
    elif grid is not None and "theta_i" in grid.dims:
        ax = grid.axes[grid.dims.index("theta_i")]
        nodes = ax.values[ax.values <= theta_i_max + 1e-12]
        theta = nodes if nodes.size else ax.values[:1]
        if ax.domain[0] <= 1e-12 < theta[0]:
            # cell-centred nodes (an MDL .mbsdf table): the domain reaches normal incidence,
            # where the table holds its first incidence
            theta = np.concatenate([[0.0], theta])
        if not b.isotropic:
            # the grid's incident azimuth nodes (a grid whose axis is not φi itself says them)
            own = getattr(grid, "incident_azimuths", None)
            phi = np.asarray(own() if callable(own) else grid.axes[grid.dims.index("phi_i")].values, float)
    return theta, phi


def curve(ctx, theta_i_max, n_theta_i, n_phi_i):
    """The shared albedo curve of this run for a sweep (computed once). The white-sky albedo
    is NaN unless the sweep runs from 0 to at least 80°."""
    theta, phi = sweep(ctx, theta_i_max, n_theta_i, n_phi_i)
    key = ("albedo_curve", tuple(theta), tuple(phi), DEFAULT_NODES)

    def compute():
        c = albedo_curve(ctx.brdf, theta, phi, ctx.wavelengths)
        if theta[0] > 1e-9 or theta[-1] < np.radians(80.0):
            c.white_sky = np.full_like(c.white_sky, np.nan)
        return c
    return ctx.memo(key, compute)


def _ws_text(c):
    if np.all(np.isnan(c.white_sky)):
        return (f"white-sky albedo not computed (θi covers {np.degrees(c.theta_i[0]):.4g}.."
                f"{np.degrees(c.theta_i[-1]):.4g}° only)")
    return "white-sky albedo " + ", ".join(f"{x:.4g}" for x in c.white_sky)


#: A table's a(θi) may exceed its source model's by this factor before an excess over 1 is
#: the table's own (interpolation inflates narrow lobes by a few per cent).
INTERPOLATION_OVERSHOOT = 1.1


def _no_data(c) -> str:
    """Why the curve measures nothing (no valid sample under any integral), or ''."""
    if c.coverage.size == 0 or float(np.max(c.coverage)) <= 1e-9:
        return "no valid samples to integrate: every quadrature node is missing or outside the table's domain"
    return ""


_COVERAGE = (
    Param("min_coverage", "float", "Smallest fraction of the projected solid angle the integrals must cover at "
          "every θi for a verdict (missing samples and directions outside a table's grid are not covered): below "
          "it a pass is reported as WARN.", default=0.9, minimum=0.0, maximum=1.0),
)


def _missing_data(ctx) -> bool:
    """The table holds samples that are not data (declared missing, NaN): they, and not only
    its grid's extent, leave parts of the hemisphere out of the integrals."""
    def compute():
        from .samples import _table_audit

        b = ctx.brdf
        if not ctx.is_table or not hasattr(b, "ds"):
            return False
        a = _table_audit(ctx)  # (read block by block, shared with the sample checks)
        return bool(a["missing"] or a["nan"])
    return ctx.memo("energy_missing_data", compute)


def _coverage_note(ctx, c, min_coverage):
    """(smallest coverage, θi where it is, note for the detail, True when below ``min_coverage``)."""
    if c.coverage.size == 0:
        return 1.0, 0.0, "", False
    per_theta = c.coverage.min(axis=(1, 2))
    k = int(np.argmin(per_theta))
    cmin, at = float(per_theta[k]), float(np.degrees(c.theta_i[k]))
    if cmin >= 1.0 - 1e-9:
        return cmin, at, "", False
    if _missing_data(ctx) or not ctx.is_table:
        what = "missing samples and directions outside the table" if ctx.is_table else "directions it does not define"
        note = (f"; {what} left out: the integrals cover {100 * cmin:.3g} % of the projected solid angle at "
                f"θi = {at:.4g}° (the least)")
    else:
        note = (f"; nothing is missing, but the table's grid covers only {100 * cmin:.3g} % of the projected "
                f"solid angle at θi = {at:.4g}° (the least): the integrals are over that part")
    low = cmin < min_coverage
    if low:
        note += (f"; a verdict needs at least {100 * min_coverage:.3g} % (min_coverage), so the figures are lower "
                 "bounds, not a pass")
    return cmin, at, note, low


@register
class Energy(Check):
    name = "energy"
    family = "energy"
    summary = "Energy conservation: a(θi) = ∫ f cosθo dωo ≤ 1 + tolerance on a sweep of θi (and φi)."
    thresholds = (
        Param("tolerance", "float", "Accepted excess of a(θi) over 1 (tables interpolate peaked lobes with some "
              "overshoot: a Beckmann α = 0.05 lobe on the MERL grid integrates to 1.006).", default=0.01, minimum=0.0),
    ) + _COVERAGE + _SWEEP

    def run(self, ctx, tolerance, min_coverage, theta_i_max, n_theta_i, n_phi_i):
        c = curve(ctx, theta_i_max, n_theta_i, n_phi_i)
        if _no_data(c):
            return self.skip(_no_data(c))
        labels = ctx.labels()
        top = c.max
        ti, pi_, ch = c.argmax()
        cmin, _, note, low = _coverage_note(ctx, c, min_coverage)
        limit = 1.0 + tolerance
        bad = int(np.sum(c.values > limit))
        az = f", φi = {np.degrees(pi_):.4g}°" if c.phi_i.size > 1 else ""
        over = f"; {bad} of {c.values.size} values above" if bad else ""
        data = dict(theta_i_deg=round(float(np.degrees(ti)), 6), phi_i_deg=round(float(np.degrees(pi_)), 6),
                    channel=labels[ch], above=bad, coverage_min=cmin, min_coverage=min_coverage, origin=ctx.origin,
                    sweep={"theta_i_max_deg": float(np.degrees(theta_i_max)), "n_theta_i": n_theta_i,
                           "n_phi_i": int(c.phi_i.size)})
        detail = (f"max a(θi) = {top:.6g} at θi = {np.degrees(ti):.4g}°{az}, channel {labels[ch]} "
                  f"(accepted ≤ {limit:.6g}){over}; {_ws_text(c)}{note}")
        out = self.outcome(top <= limit, top, limit, detail, **data)
        source_exceeds = True  # unless the table's source model is known to stay within the limit
        if top > limit and ctx.is_table:
            # Is the excess the source's, or the table's interpolation of it?
            model, _ = reference(ctx)
            if model is not None:
                lam = ctx.wavelengths if ctx.wavelengths is not None else (
                    ctx.brdf.wavelengths if ctx.brdf.spectral else None)
                mc = ctx.memo(("albedo_curve_source", tuple(c.theta_i), tuple(c.phi_i)),
                              lambda: albedo_curve(model, c.theta_i, c.phi_i, lam))
                out.data["source_max"] = mc.max
                # interpolation overshoot of a peaked lobe is a few per cent; more is not it
                if mc.max <= limit and top <= INTERPOLATION_OVERSHOOT * mc.max + tolerance:
                    out.status = "warn"
                    out.detail = (f"the table's interpolation gives {detail}, but its source model {model.name} "
                                  f"reaches only {mc.max:.6g}: tabulation error, not an energy gain of the source "
                                  "(see the tabulation check; a finer grid reduces it)")
                    return out
                source_exceeds = mc.max > limit
                out.detail += f"; the source model {model.name} reaches {mc.max:.6g}"
        if top > limit and ctx.measured and source_exceeds:
            # the data's own excess (calibration, noise): reported with its figure, not refused
            out.status = "warn"
            out.detail += f" ({ctx.origin} data: an excess of the data itself, reported, not refused)"
        elif top <= limit and low:
            out.status = "warn"  # a lower bound within the limit says nothing about the rest
        return out


@register
class Albedo(Check):
    name = "albedo"
    family = "energy"
    summary = ("Albedo integrals: the a(θi) curve and the white-sky albedo; optional expected values compared "
               "within a tolerance.")
    replaces = (("expected_theta_i", "expected"),)
    thresholds = (
        Param("expected", "floats", "Expected a(θi): one number for every θi of the sweep, or a list at "
              "expected_theta_i_deg.", default=None, minimum=0.0),
        Param("expected_theta_i", "floats", "Incidence angles of a list of expected values.", units="rad",
              default=None, minimum=0.0, maximum=float(np.pi / 2), angle=True),
        Param("white_sky", "float", "Expected white-sky (bihemispherical) albedo.", default=None, minimum=0.0),
        Param("tolerance", "float", "Accepted absolute difference from the expected values.", default=0.01,
              minimum=0.0),
    ) + _COVERAGE + _SWEEP

    def check_config(self, cfg):
        exp, at = cfg.get("expected"), cfg.get("expected_theta_i")
        if at is not None and exp is None:
            raise ParameterError("expected_theta_i_deg", "given without expected values")
        if exp is not None and len(exp) > 1 and (at is None or len(at) != len(exp)):
            raise ParameterError("expected", "a list of expected values needs expected_theta_i_deg of the same "
                                 "length")
        if exp is not None and at is not None and len(exp) == 1 and len(at) != 1:
            raise ParameterError("expected", "give one expected value per angle of expected_theta_i_deg")

    def run(self, ctx, expected, expected_theta_i, white_sky, tolerance, min_coverage, theta_i_max, n_theta_i,
            n_phi_i):
        c = curve(ctx, theta_i_max, n_theta_i, n_phi_i)
        if _no_data(c):
            return self.skip(_no_data(c))
        labels = ctx.labels()
        mean_phi = c.values.mean(axis=1)
        cmin, _, note, low = _coverage_note(ctx, c, min_coverage)
        data = {"theta_i_deg": np.degrees(c.theta_i).round(6).tolist(), "channels": labels,
                "values": mean_phi.tolist(), "coverage": c.coverage.min(axis=(1, 2)).tolist(),
                "white_sky": c.white_sky.tolist(), "coverage_min": cmin, "min_coverage": min_coverage}
        if c.phi_i.size > 1:
            data["phi_i_deg"] = np.degrees(c.phi_i).tolist()
            data["values_phi"] = c.values.tolist()
        a0 = ", ".join(f"{x:.4g}" for x in mean_phi[0])
        text = f"{_ws_text(c)}; a({np.degrees(c.theta_i[0]):.4g}°) = {a0}"
        if expected is None and white_sky is None:
            top = float(np.max(c.white_sky)) if not np.all(np.isnan(c.white_sky)) else None
            return self._covered(self.outcome(True, top, None, text + note, **data), low)
        devs = []
        parts = []
        if expected is not None:
            if expected_theta_i is None:
                got = c.values
                exp = np.asarray(expected[0])
                at_deg = np.degrees(c.theta_i)
                where = "every θi of the sweep"
            else:
                th = np.asarray(expected_theta_i, float)
                phi = c.phi_i
                got = ctx.memo(("albedo_at", tuple(th), tuple(phi)), lambda: directional_albedo(
                    ctx.brdf, th[:, None], phi[None, :], ctx.wavelengths))
                exp = np.asarray(expected, float)[:, None, None]
                at_deg = np.degrees(th)
                where = f"θi = {', '.join(f'{x:g}' for x in at_deg)}°"
            dev = np.abs(got - exp)
            i = np.unravel_index(int(np.nanargmax(dev)), dev.shape)
            devs.append(float(dev[i]))
            data["expected_theta_i_deg"] = np.asarray(at_deg).tolist()
            data["expected"] = list(expected)
            parts.append(f"a(θi) differs from the expected values at {where} by up to {dev[i]:.3g} "
                         f"(at θi = {at_deg[i[0]]:.4g}°, channel {labels[i[-1]]})")
        if white_sky is not None:
            if np.all(np.isnan(c.white_sky)):
                return self.skip(f"expected white-sky albedo given, but {_ws_text(c)}", **data)
            dev = np.abs(c.white_sky - white_sky)
            devs.append(float(dev.max()))
            data["expected_white_sky"] = white_sky
            parts.append(f"white-sky albedo differs from {white_sky:g} by up to {dev.max():.3g}")
        top = max(devs)
        return self._covered(self.outcome(top <= tolerance, top, tolerance,
                                          "; ".join(parts) + f" (accepted {tolerance:g}); {text}{note}", **data), low)

    @staticmethod
    def _covered(out, low):
        """A pass over too small a part of the hemisphere is a WARN (the note says why)."""
        if low and out.status == "pass":
            out.status = "warn"
        return out
