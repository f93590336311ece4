"""Convert a table file to another format or grid: ``brdftab convert IN OUT``.

Any readable format to any writable one (:mod:`brdftab.formats`; nothing here names a
format). The steps:

1. the output is checked and claimed before any work (:func:`brdftab._locks.claim`): it may
   not be the input (through links either), may not exist unless ``overwrite``, and may not be
   claimed by another run;
2. the input is read and checked (:func:`brdftab.checks.run_checks`); its findings do not
   refuse the conversion: they travel with the output as the input's report (in the
   report, and as ``input_validation_*`` attributes of a netCDF/EXR output);
3. the target grid is the one asked for (``grid``); else one rule for every input
   (:func:`default_grid`): the input's own brdftab grid, or for an input in a format's own
   layout (an RGL ``.bsdf``) a Rusinkiewicz grid that keeps the input's symmetries — φh when
   it is anisotropic, φd over the full turn — as the output format stores it (:func:`brdftab.formats.target_grid`: MERL always stores the MERL
   grid); on that grid θh is refined (:data:`REFINED_THETA_H`) while the resampled table
   misrepresents the input beyond :data:`RESAMPLING_BOUND` (lobes narrower than its θh nodes:
   mirror-like films), and the conversion says so;
4. if the input has fewer symmetries than the target grid assumes (an anisotropic table onto
   an isotropic grid, one not known to be reciprocal onto a grid folded by reciprocity), it
   must be averaged into them: refused unless ``fold`` is given, which averages over
   rotations about the normal and/or over swapping wi and wo;
5. a table whose grid equals the target grid is copied; otherwise it is tabulated (resampled)
   on the target grid, and the conversion reports how far the written table is from the
   input at a few thousand random direction pairs in the written table's domain
   (:class:`Difference`);
6. **what is written is validated** before it is written: an output that fails a check, or
   a resampled output whose relative error of f at θi, θo ≤ 80° exceeds
   :data:`RESAMPLING_BOUND` in its median or its 95th percentile, is refused (exit code 1,
   the figures named, nothing written) unless ``allow_invalid``, which writes it (with
   ``validation_passed = 0`` when a check failed);
7. the output is written atomically (:func:`brdftab.formats.write_prepared`).
"""

from __future__ import annotations

import sys
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import formats
from ._locks import check_target, claim
from ._progress import write_progress
from ._signals import terminate_as_interrupt
from .colorimetry import seen_as_written
from .models.combinators import Average
from .errors import BrdftabError, ParameterError, ValidationError, shown
from .grids import Grid

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

__all__ = ["Conversion", "Difference", "InvalidOutput", "convert", "grid_option", "grid_file",
           "format_option", "difference", "check_points", "default_grid", "CHECK_POINTS", "PHI_H_SAMPLES",
           "RESAMPLING_BOUND", "REFINED_THETA_H"]

#: Random direction pairs at which a resampled table is compared with its source.
CHECK_POINTS = 4096
#: The most a resampled output may misrepresent its source, as relative errors of f at the
#: check points with θi, θo ≤ 80° (:class:`Difference`): the median and the 95th percentile.
#: Beyond either, the conversion is refused (exit code 1, nothing written) unless
#: ``allow_invalid``. The default conversion of a real measured RGL file to netCDF stays well
#: inside (tests/test_convert.py::test_resampling_bound_is_met_by_a_measured_file).
RESAMPLING_BOUND = {"median": 0.02, "p95": 0.10}
#: θh node counts the default grid of an isotropic source in a format's own layout is refined
#: to, in turn, while the resampled table exceeds :data:`RESAMPLING_BOUND` (its 90 MERL-spaced
#: θh nodes are 0.15-0.2° apart at 0.5°: a lobe under a degree falls between them). A GGX
#: α = 0.01 film needs 180
#: (tests/test_convert.py::test_default_grid_refines_theta_h_for_a_narrow_lobe).
REFINED_THETA_H = (180, 360)
#: Rotations about the normal averaged when an anisotropic source without a uniform φh axis is
#: folded onto an isotropic grid.
PHI_H_SAMPLES = 36


class InvalidOutput(ValidationError):
    """What a conversion would write failed a validation check (exit code 1, nothing written)."""

    exit_code = 1


def default_grid(source, theta_h: int = 90):
    """The grid a conversion writes on when none is asked for — one rule for every input: the
    source's own brdftab grid; else (a format's own layout, e.g. an RGL file) a Rusinkiewicz
    grid with MERL's θh warp and φd over the full turn (no fold: such a file is conditioned on
    wi, so its interpolant is not exactly reciprocal even when its source was): 90 × 90 × 180
    for an isotropic source, 48 × 32 × 96 with 96 φh nodes for an anisotropic one. ``theta_h``:
    the θh node count of an isotropic source's grid (:data:`REFINED_THETA_H` when
    :func:`convert` refines it)."""
    from .grids.rusinkiewicz import RusinkiewiczGrid

    g = getattr(source, "grid", None)
    if isinstance(g, Grid):
        return g
    if source.isotropic:
        return RusinkiewiczGrid(theta_h, 90, 180, theta_h_spacing="merl", phi_d_fold="none")
    return RusinkiewiczGrid(48, 32, 96, 96, theta_h_spacing="merl", phi_d_fold="none")


@dataclass
class Difference:
    """How far the written table is from the source, on the radiometric quantity f cosθi cosθo
    (as the tabulation check measures it): ``rms_rel`` = sqrt(Σ (Δf μi μo)² / Σ (f μi μo)²) and
    ``max_rel`` the largest |Δf| / f where f μi μo exceeds 1e-3 of its largest value, over
    ``points`` check points (pairs where either is NaN — outside a domain or missing — are
    left out). Weighting by the cosines keeps grazing pairs, where formats that store f·cos
    (RGL) cannot resolve f, from dominating the figure. ``median_rel`` and ``p95_rel`` are the
    median and 95th percentile of |Δf| / f over the check points with θi, θo ≤ 80° (where f is
    above 1e-3 of its 99th percentile there); :data:`RESAMPLING_BOUND` judges these two."""

    max_rel: float
    rms_rel: float
    points: int
    requested: int
    #: median |Δf| / f over check points with θi, θo ≤ 80° (where f is not negligible)
    median_rel: float = float("nan")
    #: 95th percentile of the same
    p95_rel: float = float("nan")

    def exceeds(self, bound=None) -> list:
        """The figures beyond ``bound`` (default :data:`RESAMPLING_BOUND`), as text; empty if none."""
        bound = RESAMPLING_BOUND if bound is None else bound
        out = []
        for name, value in (("median", self.median_rel), ("p95", self.p95_rel)):
            if np.isfinite(value) and value > bound[name]:
                out.append(f"{name} {100 * value:.3g} % (bound {100 * bound[name]:g} %)")
        return out

    def to_json(self) -> dict:
        return {"max_relative_difference": self.max_rel, "rms_relative_difference": self.rms_rel,
                "median_relative_difference_80deg": self.median_rel,
                "p95_relative_difference_80deg": self.p95_rel,
                "check_points": self.points, "check_points_requested": self.requested}


@dataclass
class Conversion:
    """What :func:`convert` did."""

    source: Path
    target: Path
    format: str
    source_grid: str
    target_grid: str
    resampled: bool
    folded: list = field(default_factory=list)
    difference: Difference | None = None
    note: str = ""
    report: object = None
    written: object = None
    input_report: object = None
    input_table: object = None
    #: a scattered source resampled: ``{"nodes", "outside", "fraction", "max_distance"}`` — how
    #: many nodes of the written table lay outside the hull of the source's samples and took
    #: their nearest sample's value (:mod:`brdftab.grids.scattered`)
    extrapolated: dict | None = None
    #: the default grid's θh refined (:data:`REFINED_THETA_H`): to what, and why; empty if not
    refined: str = ""

    def to_json(self) -> dict:
        return {"source": str(self.source), "target": str(self.target), "format": self.format,
                "source_grid": self.source_grid, "target_grid": self.target_grid, "resampled": self.resampled,
                "extrapolated": self.extrapolated, "refined": self.refined or None,
                "folded": list(self.folded), "difference": self.difference.to_json() if self.difference else None,
                "note": self.note, "checks": _checks_json(self.report),
                "input_checks": _checks_json(self.input_report)}


def _checks_json(report):
    if report is None:
        return None
    return {"passed": report.passed, "failed": [o.to_json() for o in report.failures],
            "warned": [o.to_json() for o in report.warnings]}


# --------------------------------------------------------------------------------------------
# command-line forms of a grid and of format options

GRID_HELP = ("a grid type ('merl', 'rusinkiewicz', ...) with its defaults, or a TOML inline table of [grid] keys "
             "such as '{type = \"rusinkiewicz\", n_theta_h = 45}' (the braces may be left out)")


def grid_option(text: str) -> dict:
    """The ``[grid]`` table that ``--grid TEXT`` describes (see :data:`GRID_HELP`)."""
    text = text.strip()
    if text.replace("-", "_").isidentifier():
        return {"type": text}
    body = text if text.startswith("{") else "{" + text + "}"
    try:
        return dict(tomllib.loads(f"grid = {body}")["grid"])
    except (tomllib.TOMLDecodeError, KeyError, TypeError) as exc:
        raise BrdftabError(f"--grid {text!r}: expected {GRID_HELP} ({exc})") from None


def grid_file(path) -> dict:
    """The ``[grid]`` table of a TOML file (a spec file works too: only ``[grid]`` is read)."""
    path = Path(path)
    try:
        raw = tomllib.loads(path.read_bytes().decode("utf-8-sig"))
    except FileNotFoundError:
        raise BrdftabError(f"{path}: no such grid file") from None
    except OSError as exc:
        raise BrdftabError(f"{path}: cannot read ({exc.strerror})") from None
    except UnicodeDecodeError:
        raise BrdftabError(f"{path}: not a UTF-8 text file") from None
    except tomllib.TOMLDecodeError as exc:
        raise BrdftabError(f"{path}: invalid TOML: {exc}") from None
    except RecursionError:
        raise BrdftabError(f"{path}: values nested too deeply") from None
    cfg = raw.get("grid")
    if not isinstance(cfg, dict):
        raise BrdftabError(f"{path}: no [grid] table")
    return cfg


def format_option(text: str) -> tuple:
    """``KEY=VALUE`` of ``--option``: VALUE is a TOML value (``9``, ``true``, ``[0, 90]``), else text."""
    key, sep, value = text.partition("=")
    key = key.strip()
    if not sep or not key:
        raise BrdftabError(f"--option {text!r}: expected KEY=VALUE, e.g. dtype=float32")
    value = value.strip()
    try:
        parsed = tomllib.loads(f"v = {value}")["v"]
    except (tomllib.TOMLDecodeError, RecursionError):
        parsed = value
    return key, parsed


def _build_grid(cfg: dict, where: str):
    from .grids import grid_from_config, grid_wavelengths

    try:
        grid = grid_from_config(cfg)
    except ParameterError as exc:
        raise BrdftabError(f"{where}: {exc.key}: {exc.detail}" if exc.key else f"{where}: {exc.detail}") from None
    try:
        lam = grid_wavelengths(cfg)
    except ParameterError as exc:
        raise BrdftabError(f"{where}: wavelengths_nm: {exc.detail}") from None
    return grid, lam


# --------------------------------------------------------------------------------------------
# folding a source into the symmetries of the target grid

def _fold_reasons(source, grid) -> list:
    """Why ``source`` must be averaged to fit ``grid`` (empty: it fits as it is)."""
    reasons = []
    src_fold = getattr(getattr(source, "grid", None), "phi_d_fold", "none")
    fold = getattr(grid, "phi_d_fold", "none")
    if not source.isotropic and (getattr(grid, "anisotropic", True) is False or "bilateral" in fold):
        reasons.append("azimuth")
    if "reciprocity" in fold and not (source.reciprocal or "reciprocity" in src_fold):
        reasons.append("reciprocity")
    return reasons


_FOLD_TEXT = {
    "azimuth": "the source is anisotropic and the target grid isotropic",
    "reciprocity": "the source is not reciprocal and the target grid is folded by reciprocity (phi_d ~ phi_d + pi)",
}


def _rotations(grid) -> int:
    """Rotations about the normal to average over: one per node of a uniform periodic φh axis
    (the mean of the table's interpolant over φh is then exact), else :data:`PHI_H_SAMPLES`."""
    for ax in getattr(grid, "axes", ()):
        if ax.name == "phi_h" and ax.period is not None and len(ax) > 1:
            steps = np.diff(np.append(ax.values, ax.values[0] + ax.period))
            if np.allclose(steps, steps[0], rtol=1e-9, atol=1e-12):
                return len(ax)
    return PHI_H_SAMPLES


# --------------------------------------------------------------------------------------------
# the resampling figures

def check_points(grid, n: int = CHECK_POINTS, seed: int = 0):
    """``n`` random direction pairs at which a written table is compared with its source: the
    centres of random cells of ``grid`` (the tabulation check's points, above the horizon);
    for a sample layout that is not a brdftab grid (a format's own), half pairs uniform over
    the hemisphere and half with wo near the mirror direction of wi (reflected about a normal
    whose slopes are normal with a standard deviation log-uniform in [0.01, 0.5]), so that
    narrow lobes are judged too."""
    from .checks.tabulation import cell_centres
    from .geometry import mirror_biased_pairs
    from .grids import Grid

    if isinstance(grid, Grid):
        return cell_centres(grid, n, seed)
    return mirror_biased_pairs(n, np.random.default_rng(seed))


def difference(source, written, n: int = CHECK_POINTS, seed: int = 0):
    """:class:`Difference` of ``written`` (a table) from ``source`` at check points of the
    written table's grid; None (with the reason) when they cannot be compared."""
    if written.spectral != source.spectral:
        return None, "the source and the written table differ in channels; no difference computed"
    lam = written.wavelengths if written.spectral else None
    wi, wo = check_points(getattr(written, "grid", None), n, seed)
    if wi.shape[0] == 0:
        return None, "no check points above the horizon"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        f_w = np.asarray(written.eval(wi, wo, lam), float)
        f_s = np.asarray(source.eval(wi, wo, lam), float)
    if f_s.shape[-1] != f_w.shape[-1]:
        if f_s.shape[-1] == 1:
            f_s = np.repeat(f_s, f_w.shape[-1], axis=-1)
        elif f_w.shape[-1] == 1:
            f_w = np.repeat(f_w, f_s.shape[-1], axis=-1)
        else:
            return None, "the source and the written table differ in channels; no difference computed"
    ok = np.isfinite(f_s).all(-1) & np.isfinite(f_w).all(-1)
    if not ok.any():
        return None, "no check points inside both the source's and the written table's domains"
    from .checks.tabulation import compare

    rms, top, _, count = compare(f_w[ok], f_s[ok], wi[ok, 2] * wo[ok, 2])
    inner = ok & (wi[:, 2] >= np.cos(np.radians(80.0))) & (wo[:, 2] >= np.cos(np.radians(80.0)))
    ref = np.abs(f_s[inner])
    # relative errors where f is not negligible (1e-3 of its 99th percentile: the tails of a
    # narrow lobe, many decades down, would otherwise be judged on noise-sized values)
    big = ref > 1e-3 * np.percentile(ref, 99) if ref.size else np.zeros(0, bool)
    with np.errstate(invalid="ignore", divide="ignore"):
        rel = np.abs(f_w[inner][big] - f_s[inner][big]) / ref[big]
    rel = rel[np.isfinite(rel)]
    median = float(np.median(rel)) if rel.size else float("nan")
    p95 = float(np.percentile(rel, 95)) if rel.size else float("nan")
    return Difference(top, rms, count, int(n), median, p95), ""


# --------------------------------------------------------------------------------------------

def _refusal(report, source, target) -> str:
    parts = []
    for o in report.failures:
        fig = "" if o.figure is None else f" (figure {o.figure:.4g}" + (
            "" if o.threshold is None else f", threshold {o.threshold:.4g}") + ")"
        parts.append(f"{o.name}: {o.detail}{fig}")
    return (f"refusing to write {target}: the conversion of {source} fails {'; '.join(parts)} (nothing written; "
            "pass --allow-invalid to write it with validation_passed = 0)")


def convert(source, target, *, grid=None, wavelengths=None, format: str | None = None, options: dict | None = None,
            overwrite: bool = False, fold: bool = False, allow_invalid: bool = False, checks=None,
            progress: bool | None = None, inputs=(), n_check: int = CHECK_POINTS, origin: str | None = None) -> Conversion:
    """Convert the table file ``source`` into ``target`` (see the module docstring).

    ``grid``: a :class:`~brdftab.grids.Grid` to write on (None: :func:`default_grid`);
    ``wavelengths`` [nm] to resample a spectral source at; ``format``: an output format name
    (None: from ``target``'s extension); ``options``: format options; ``fold``: average the
    source into the target grid's symmetries when it has fewer; ``checks``: a configuration
    layer for the validation checks; ``allow_invalid``: write an output that fails a check
    (stamped ``validation_passed = 0``); ``origin``: the user's word on where the source's
    values come from ("analytic", "measured", "unknown"; default: what the file records);
    ``inputs``: further files the conversion reads (never overwritten).
    """
    started = time.monotonic()
    source, target = Path(source), Path(target)
    options = dict(options or {})
    fmt = formats.format_for(target, format)
    fmt.ensure_available()
    fmt.check_path(target)
    try:
        fmt.validate_options(options)
    except ParameterError as exc:
        raise BrdftabError(f"--option {exc.key}: {exc.detail}" if exc.key else str(exc)) from None
    inputs = [(source, "the input table"), *inputs]
    check_target(target, overwrite, inputs)
    with terminate_as_interrupt(), claim([target], overwrite, inputs):
        table = formats.read(source)
        if origin is not None:
            table.origin = origin
        report_in = _run_checks(table, checks, origin)
        src_grid = getattr(table, "grid", None)
        if not isinstance(src_grid, Grid):  # samples in a format's own layout (not a brdftab grid)
            src_grid = None
        requested = grid if grid is not None else src_grid
        if requested is None and fmt.prepare is None:
            requested = default_grid(table)
        try:
            out_grid = formats.target_grid(fmt, requested, options)
        except ParameterError as exc:
            key = f"{exc.key}: " if exc.key else ""
            raise BrdftabError(f"{target}: {key}{exc.detail}") from None
        if out_grid is None and grid is not None:
            raise BrdftabError(f"{target}: format {fmt.name} samples the source on its own parameterization; --grid "
                               f"is not used (set its sampling with -o format options)")
        same_grid = out_grid is not None and src_grid is not None and out_grid.equals(src_grid)
        same_lam = wavelengths is None or (table.spectral and np.array_equal(np.asarray(wavelengths, float),
                                                                              np.asarray(table.wavelengths, float)))
        if out_grid is None:  # the format samples the source its own way
            resampled = not (formats.detect(source).name == fmt.name and not options and grid is None)
        else:
            resampled = not (same_grid and same_lam)
        if (not resampled and out_grid is not None and fmt.prepare is None and fmt.stream is not None
                and getattr(table, "over_budget", False)):
            return _stream_copy(table, fmt, source, target, options, overwrite, inputs, checks, origin, report_in,
                                allow_invalid, progress, started)
        brdf, folded = table, []
        if out_grid is not None and resampled:
            reasons = _fold_reasons(table, out_grid)
            if reasons and not fold:
                why = "; ".join(_FOLD_TEXT[r] for r in reasons)
                raise BrdftabError(f"{source} must be averaged to fit {out_grid.describe()}: {why}; pass --fold to "
                                   "write its average, or choose a grid that keeps it (--grid)")
            folded = [_FOLD_TEXT[r] for r in reasons]
            # a table already folded by reciprocity holds reciprocal data whatever it declares
            src_fold = getattr(src_grid, "phi_d_fold", "none")
            if reasons or ("reciprocity" in src_fold and not table.reciprocal):
                brdf = Average(term=table, rotations=_rotations(src_grid) if "azimuth" in reasons else 0,
                               swap="reciprocity" in reasons)
                brdf.origin = table.origin
                if "reciprocity" in src_fold:  # a table folded by reciprocity holds reciprocal data
                    brdf.reciprocal = True
        scattered = resampled and getattr(getattr(table, "grid", None), "scattered", False)
        if scattered:  # outside the samples' hull: the nearest sample, counted and reported
            table.outside = "clamp"
            table.extrapolation[:] = [0, 0, 0.0]
        refined = ""
        if out_grid is not None and resampled and fmt.prepare is None:
            payload = _tabulate(brdf, out_grid, wavelengths, table, source, progress)
            if grid is None and src_grid is None and table.isotropic and out_grid.equals(requested):
                out_grid, payload, refined = _refine_theta_h(brdf, table, out_grid, payload, wavelengths, source,
                                                             progress, n_check)
            bad = int(np.isnan(payload.values).any(axis=-1).sum())
            if bad and not allow_invalid:
                raise BrdftabError(f"refusing to convert {source}: {bad} of {out_grid.size} nodes of "
                                      f"{out_grid.describe()} lie outside the source's domain or read missing "
                                      "samples (NaN); choose a grid inside it (--grid) or pass --allow-invalid")
        elif wavelengths is not None and not same_lam and out_grid is None:
            raise BrdftabError(f"--grid wavelengths_nm: format {fmt.name} samples the source itself; "
                               "it cannot resample wavelengths")
        else:
            with formats.naming(target):
                payload = formats.prepare(fmt, brdf, out_grid, options)
        extrapolated = None
        if scattered:
            n, k, dmax = table.extrapolation
            extrapolated = {"nodes": int(n), "outside": int(k), "fraction": k / n if n else 0.0,
                            "max_distance": float(dmax)}
            if hasattr(payload, "ds"):
                payload.ds.attrs["extrapolated_fraction"] = extrapolated["fraction"]
                payload.ds.attrs["extrapolation"] = (
                    f"{k} of {n} nodes lay outside the hull of the samples of {shown(source.name)} and took their "
                    f"nearest sample's value (up to {dmax:.3g} away in projected-hemisphere coordinates)")
        # validate what is written, as the file stores it (a copy is the input itself: its
        # report is the output's)
        from .table import Table

        try:
            checked = formats.stored(fmt, payload, options)
        except formats.NotStorable as exc:
            from .checks import unstorable_report

            checked, report_out = exc, unstorable_report(exc, checks, allow_invalid=True)
        else:
            if isinstance(checked, Table):
                payload = checked  # the samples the file holds: written, stamped and checked
                if resampled:  # its nodes hold interpolations of the source, not samples of a model
                    checked.ds.attrs["resampled_from"] = shown(source.name)
            if checked is table or checked is None:
                report_out = report_in
            else:
                # judged against what the output's own provenance names, as a later `brdftab
                # validate` of the file judges it (its report is the one stored in the file);
                # how far the output is from the input is the Difference below
                report_out = _run_checks(checked, checks, origin)
        if hasattr(payload, "ds"):
            from .checks import stamp

            stamp(payload, report_out)  # validation_passed: the output passed (or 0, written with --allow-invalid)
            if report_out is not report_in:
                _stamp_input(payload, report_in, source)
            _stamp_provenance(payload, table, source, target, out_grid if resampled else None)
        if not report_out.passed and not allow_invalid:
            raise InvalidOutput(_refusal(report_out, source, target))
        if (resampled or folded) and checked is not None and checked is not table and not allow_invalid:
            # judge the resampling before anything is written
            gate, _ = difference(seen_as_written(brdf, checked, options), checked, n_check)
            beyond = gate.exceeds() if gate is not None else []
            if beyond:
                raise InvalidOutput(f"refusing to write {target}: it misrepresents {source}: relative error of f at "
                                    f"θi, θo ≤ 80° {', '.join(beyond)} over {gate.points} check points (nothing "
                                    "written; choose a finer grid or format options, or pass --allow-invalid to "
                                    "write it anyway)")
        with write_progress(target.name, progress, _delay(started)):
            formats.write_prepared(fmt, payload, target, overwrite=overwrite, options=options)
        written = payload
        src_text = getattr(getattr(table, "grid", None), "describe", lambda: "")()
        result = Conversion(source, target, fmt.name, src_text,
                            out_grid.describe() if out_grid is not None else "", resampled, folded,
                            report=report_out, written=written, input_report=report_in, input_table=table,
                            extrapolated=extrapolated)
        result.refined = refined
        if resampled or folded:
            back = _read_back(fmt, target, written)
            if back is None:
                result.note = f"format {fmt.name} cannot be read back; no difference computed"
            else:
                # against what was resampled: the input, or its average when it was folded
                result.difference, result.note = difference(seen_as_written(brdf, back, options), back, n_check)
                if not result.target_grid and getattr(back, "grid", None) is not None:
                    result.target_grid = back.grid.describe()
    return result


def _stream_copy(table, fmt, source, target, options, overwrite, inputs, checks, origin, report_in, allow_invalid,
                 progress, started) -> Conversion:
    """Copy a table over the memory budget (:attr:`~brdftab.table.Table.over_budget`) into a
    format with a block writer (netCDF, zarr) block by block: at most a sixteenth of the budget
    of its samples is in memory at a time (cast to the output's storage type by the writer), the
    checks judge the written temporary as stored (read back lazily), their report and the
    provenance are added to it, and only then is it renamed into place; a failed check leaves
    nothing behind unless ``allow_invalid``."""
    from ._atomic import atomic_path
    from ._signals import checkpoint, held_signals
    from .checks import stamp
    from .table import memory_budget

    var = table.ds["brdf"]
    template = table.ds.copy(deep=False)  # the samples as a broadcast zero: nothing of their size
    template["brdf"] = var.copy(data=np.broadcast_to(np.zeros((), var.dtype), var.shape))
    with atomic_path(target, overwrite=overwrite, inputs=inputs) as tmp:
        with fmt.stream(template, tmp, **options) as writer:
            with write_progress(target.name, progress, _delay(started)):
                for key, block in table.iter_blocks(max(1 << 16, memory_budget() // 16), align=writer.chunks):
                    with held_signals(writing=target.name):
                        writer.write(key, block)
                    checkpoint()
            written = fmt.read(tmp)
            written.origin = table.origin
            report_out = _run_checks(written, checks, origin)
            stamp(written, report_out)
            if written.ds["brdf"].dtype != var.dtype:  # cast: the input's own findings travel with it
                _stamp_input(written, report_in, source)  # (an exact copy's report is the input's)
            _stamp_provenance(written, table, source, target, None)
            if not report_out.passed and not allow_invalid:
                written.close()
                raise InvalidOutput(_refusal(report_out, source, target))
            writer.update(written.ds.drop_vars("brdf"))
            written.close()
    src_text = table.grid.describe()
    return Conversion(source, target, fmt.name, src_text, src_text, False, [], report=report_out, written=written,
                      input_report=report_in, input_table=table)


def _stamp_input(table, report, source) -> None:
    """The input's check results, carried as information in the output's metadata."""
    import json

    attrs = table.ds.attrs
    attrs["input_validation_passed"] = int(report.passed)
    attrs["input_validation_summary"] = f"{shown(source.name)}: " + "; ".join(
        f"{o.status.upper()} {o.name}: {o.detail}" for o in report.outcomes if o.status in ("fail", "warn")) \
        if (report.failures or report.warnings) else f"{shown(source.name)}: {report.summary()}"
    attrs["input_validation_report"] = json.dumps(report.to_json(), separators=(",", ":"))


def _stamp_provenance(payload, table, source: Path, target: Path, grid) -> None:
    """What the output records of where it came from: the source file's name and SHA-256 (of a
    store: of its files, see below) (``converted_from``, ``converted_from_sha256``) and its
    ``history``: the source's steps, then this conversion (a convert of a convert keeps every
    step). ``grid``: the grid it was resampled onto (None: copied)."""
    import datetime as _dt
    import hashlib

    from ._signals import checkpoint
    from ._version import __version__

    digest = hashlib.sha256()
    # a store (a folder) is hashed file by file in the order of their paths in it: each path
    # (relative, UTF-8, "/"-separated), a NUL byte, then the file's bytes
    files = sorted(p for p in source.rglob("*") if p.is_file()) if source.is_dir() else [source]
    for path in files:
        if path != source:
            digest.update(path.relative_to(source).as_posix().encode("utf-8", "surrogateescape") + b"\0")
        with open(path, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 22), b""):
                digest.update(block)
                checkpoint()
    attrs = payload.ds.attrs
    before = getattr(table, "ds", None)
    steps = str(before.attrs.get("history", "") if before is not None else "").strip()
    now = _dt.datetime.now(_dt.timezone.utc).replace(microsecond=0).isoformat()
    how = f"resampled onto {grid.describe()}" if grid is not None else "copied"
    step = (f"{now} brdftab {__version__}: converted {shown(source.name)} (sha256 {digest.hexdigest()}) to "
            f"{shown(target.name)}, {how}")
    attrs["converted_from"] = shown(source.name)
    attrs["converted_from_sha256"] = digest.hexdigest()
    attrs["history"] = f"{steps}\n{step}" if steps else step
    if "created" not in attrs:  # a source that records no table of its own (a MERL file): made now
        attrs["created"] = now
        attrs["brdftab_version"] = __version__


def _delay(started: float) -> float:
    from . import table

    return max(0.0, table.PROGRESS_DELAY - (time.monotonic() - started))


def _run_checks(brdf, checks, origin=None, reference=None):
    from .checks import run_checks

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return run_checks(brdf, checks, origin=origin, reference=reference)


def _tabulate(brdf, grid, wavelengths, table, source: Path, progress):
    from .table import check_checked_memory, tabulate

    # the resampled table and the checks of it must fit, as for tabulate: refused before the work
    n = brdf.layout.n_out(brdf.layout.resolve(wavelengths))
    check_checked_memory([(grid, n)], f"{source.name}: resampling onto and checking {grid.describe()} x {n} channels")
    provenance = {k: v for k, v in getattr(table, "ds", None).attrs.items()
                  if k in ("spec_sha256", "spec_file", "comment")} if hasattr(table, "ds") else {}
    provenance["converted_from"] = shown(source.name)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # samples outside the source's domain: NaN, reported by the checks
            return tabulate(brdf, grid, wavelengths, progress=progress, provenance=provenance)
    except ParameterError as exc:
        raise BrdftabError(f"cannot resample {source} onto {grid.describe()}: {exc}") from None


def _refine_theta_h(brdf, table, grid, payload, wavelengths, source: Path, progress, n_check):
    """``(grid, payload, note)``: the default grid with θh refined to each of
    :data:`REFINED_THETA_H` in turn while the table resampled on it misrepresents the source
    beyond :data:`RESAMPLING_BOUND` (judged as the gate judges, at the grid's check points);
    the first that meets it, or the finest (the gate then refuses it). ``note`` says what was
    refined and why (empty: nothing was)."""
    first = grid
    figures = []
    for n in REFINED_THETA_H:
        gate, _ = difference(brdf, payload, n_check)
        beyond = gate.exceeds() if gate is not None else []
        if not beyond:
            break
        figures.append(f"{len(grid.axes[0])} θh nodes: {', '.join(beyond)}")
        finer = default_grid(table, theta_h=n)
        try:
            payload = _tabulate(brdf, finer, wavelengths, table, source, progress)
        except BrdftabError:  # a finer grid would not fit the memory budget: the gate judges this one
            break
        grid = finer
    if grid is first:
        return grid, payload, ""
    return grid, payload, (f"θh refined to {len(grid.axes[0])} nodes: the source's lobes are narrower than the "
                           f"default grid's ({'; '.join(figures)})")


def _read_back(fmt, target: Path, written):
    from .table import Table

    if fmt.read is not None:
        try:
            return formats.read(target)
        except BrdftabError:
            pass
    return written if isinstance(written, Table) else None
