"""Conventions: the declared φd fold and sample position must be consistent with the data.

A table's fold is a claim about its source: ``reciprocity`` stores only half of φd because
f(wi, wo) = f(wo, wi), ``bilateral`` because f(φd) = f(−φd) (isotropic sources only). Failures:

* a reciprocity fold on a table whose source is declared non-reciprocal (``reciprocal = 0``),
  or whose model (the caller's, or the one in its provenance) is declared or measured
  non-reciprocal (max relative asymmetry above ``source_asymmetry`` on random pairs);
* a bilateral fold on a table whose source is anisotropic;
* φd coordinates outside the fold's stored range;
* with a model available: the samples at the nodes do not match the model at the node
  positions the table's conventions give (median relative error above ``node_error``; the
  median, so that a few corrupt samples — the sample audit's business — do not count), or they
  match the other sample position (``bin-centre`` ↔ ``lower-edge``, half a cell away along
  every axis whose nodes follow that rule) clearly better — the data were sampled elsewhere
  than declared. A table ``convert`` resampled from another (attribute ``resampled_from``)
  holds interpolations of that table at its nodes, not samples of the model: it is not
  compared node by node (the tabulation check measures how far it is from the model).
"""

from __future__ import annotations

import numpy as np

from ..grids import PHI_D_FOLDS
from ..params import Param
from . import Check, register
from ._pairs import asymmetry, sample_pairs
from ._reference import reference
from ._tables import axis_coordinate, missing_mask, pair_directions, uniform_axis

__all__ = ["Conventions"]

NODES = 2048


def _median_error(t, m):
    t, m = np.broadcast_arrays(np.asarray(t, float), np.asarray(m, float))  # a grey model under RGB data
    ok = np.isfinite(t) & np.isfinite(m)
    top = float(np.abs(m[ok]).max()) if ok.any() else 0.0
    sig = ok & (np.abs(m) > 1e-3 * top) & (top > 0)
    if not sig.any():
        return None
    return float(np.median(np.abs(t[sig] - m[sig]) / np.abs(m[sig])))


def _node_errors(ctx, model, seed):
    """Median relative error of the table at random nodes against the model at the declared
    node positions and at the other sample position (or None where it does not apply)."""
    t = ctx.brdf
    grid = t.grid
    rng = np.random.default_rng(seed)
    flat = rng.integers(0, grid.size, min(NODES, grid.size))
    idx = np.unravel_index(flat, grid.shape)
    if hasattr(t, "node_values"):
        values = t.node_values(flat)
    else:
        values = np.asarray(t.values, float).reshape(grid.size, -1)[flat]
        values = np.where(missing_mask(t).reshape(grid.size, -1)[flat], np.nan, values)
    lam = ctx.wavelengths if ctx.wavelengths is not None else (t.wavelengths if t.spectral else None)

    def err(shift):
        coords = [axis_coordinate(ax, i, shift if (shift and _follows_rule(ax)) else 0.0)
                  for ax, i in zip(grid.axes, idx)]
        wi, wo = pair_directions(grid, coords)
        keep = (wi[:, 2] > 1e-9) & (wo[:, 2] > 1e-9)
        if not keep.any():
            return None
        return _median_error(values[keep], model.eval(wi[keep], wo[keep], lam))

    cells = t.ds.attrs.get("cell_samples") if hasattr(t, "ds") else None
    if cells is not None and hasattr(grid, "outgoing_samples"):
        # samples that are cell averages (Klems, tensor tree) are compared with the model's averages
        from ..grids.cells import cell_averages

        return _median_error(values, cell_averages(model, grid, int(cells), flat, lam)), None, None
    declared = err(0.0)
    pos = t.ds.attrs.get("sample_position", "explicit") if hasattr(t, "ds") else "explicit"
    if grid.parameterization != "rusinkiewicz" or pos not in ("bin-centre", "lower-edge"):
        return declared, None, None
    other = "lower-edge" if pos == "bin-centre" else "bin-centre"
    return declared, err(-0.5 if pos == "bin-centre" else 0.5), (pos, other)


def _follows_rule(ax) -> bool:
    """True for an axis whose nodes were placed by a sample-position rule (uniform bins)."""
    rule = getattr(ax, "rule", None)
    if rule is not None:
        return rule in ("bin-centre", "lower-edge")
    return uniform_axis(ax)


@register
class Conventions(Check):
    name = "conventions"
    family = "conventions"
    summary = "The declared φd fold and sample position are consistent with the source and the data."
    thresholds = (
        Param("node_error", "float", "Largest accepted median relative error of the samples against the source "
              "model at the declared node positions.", default=1e-3, minimum=0.0),
        Param("source_asymmetry", "float", "Largest relative asymmetry of the source model under which a "
              "reciprocity fold is accepted.", default=1e-6, minimum=0.0),
        Param("seed", "int", "Seed of the random nodes and pairs.", default=0, minimum=0),
    )

    def applies(self, ctx):
        if not ctx.is_table:
            return "not a table"
        return None if ctx.on_grid else "the table is not on a brdftab grid"

    def run(self, ctx, node_error, source_asymmetry, seed):
        t = ctx.brdf
        grid = t.grid
        fold = getattr(grid, "phi_d_fold", "none")
        pos = str(t.ds.attrs.get("sample_position", "explicit")) if hasattr(t, "ds") else "explicit"
        problems, notes, data = [], [], {"phi_d_fold": fold, "sample_position": pos}
        model, why = reference(ctx)
        data["source_model"] = model.name if model is not None else None
        if "reciprocity" in fold:
            if not t.reciprocal:
                problems.append(f"phi_d_fold = '{fold}' but the table's source is declared non-reciprocal "
                                "(reciprocal = 0)")
            if model is not None:
                if not model.reciprocal:
                    problems.append(f"phi_d_fold = '{fold}' but the source model '{model.name}' is declared "
                                    "non-reciprocal")
                else:
                    wi, wo, w = ctx.memo(("pairs", 4096, seed), lambda: sample_pairs(4096, seed))
                    lam = ctx.wavelengths if ctx.wavelengths is not None else (t.wavelengths if t.spectral else None)
                    s = asymmetry(model.eval(wi, wo, lam), model.eval(wo, wi, lam), w)
                    data["source_max_relative_asymmetry"] = s["max_relative"]
                    if s["max_relative"] > source_asymmetry:
                        problems.append(f"phi_d_fold = '{fold}' but the source model '{model.name}' is not "
                                        f"reciprocal (max relative asymmetry {s['max_relative']:.3g})")
        if "bilateral" in fold:
            if not t.isotropic or (model is not None and not model.isotropic):
                problems.append(f"phi_d_fold = '{fold}' assumes an isotropic source, but it is anisotropic")
        if grid.parameterization == "rusinkiewicz" and fold in PHI_D_FOLDS:
            length, periodic = PHI_D_FOLDS[fold]
            pd = grid.axes[grid.dims.index("phi_d")].values
            hi_ok = pd[-1] < length - 1e-9 if periodic else pd[-1] <= length + 1e-9
            if pd[0] < -1e-9 or not hi_ok:
                problems.append(f"phi_d nodes span {np.degrees(pd[0]):.4g}..{np.degrees(pd[-1]):.4g}°, outside the "
                                f"stored range of phi_d_fold = '{fold}' ([0, {np.degrees(length):g}"
                                f"{')' if periodic else ']'})")
        resampled = str(t.ds.attrs.get("resampled_from", "")) if hasattr(t, "ds") else ""
        if model is not None and resampled:
            # a table resampled from another: its nodes hold interpolations of that table, so
            # their distance from the model measures the resampling, not a fold or a position
            notes.append(f"resampled from {resampled}: its nodes hold interpolations of that table, not samples "
                         f"of {model.name} (the tabulation check measures how far they are)")
        elif model is not None:
            declared, other, names = _node_errors(ctx, model, seed)
            data["node_error"] = declared
            if declared is not None:
                notes.append(f"samples match {model.name} at the nodes to {declared:.3g} (median relative error)")
                if other is not None:
                    data["node_error_other_position"] = other
                    if other < 0.5 * declared and declared > node_error:
                        problems.append(f"the samples match sample_position = '{names[1]}' (median relative error "
                                        f"{other:.3g}) better than the declared '{names[0]}' ({declared:.3g})")
                if declared > node_error and not any("sample_position" in p for p in problems):
                    problems.append(f"the samples differ from {model.name} at the declared node positions by "
                                    f"{declared:.3g} (median relative error; accepted {node_error:g}): fold or "
                                    "sample position do not match the data")
        else:
            notes.append(f"no source model to compare the data with ({why})")
        ok = not problems
        figure = float(len(problems))
        head = "; ".join(problems) if problems else f"phi_d_fold = '{fold}', sample_position = '{pos}' consistent"
        detail = head + ("; " + "; ".join(notes) if notes else "")
        return self.outcome(ok, figure, 0.0, detail, problems=problems, **data)
