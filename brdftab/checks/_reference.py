"""The model a table was tabulated from: given by the caller, or rebuilt from its provenance."""

from __future__ import annotations

import json

from ..errors import BrdftabError

__all__ = ["reference", "model_from_provenance"]


def model_from_provenance(name: str, parameters: dict):
    """Rebuild a model from a table's ``model`` and ``parameters`` attributes (angles in
    radians; nested models as ``{"model": ..., "parameters": ...}``)."""
    from .. import models

    cls = models.get(name)
    declared = {p.name: p for p in cls.params}
    kwargs = {}
    for key, value in parameters.items():
        p = declared.get(key)
        if p is None:
            raise BrdftabError(f"unknown parameter {key!r} of model {name!r}")
        if p.kind == "brdf":
            value = model_from_provenance(value["model"], value.get("parameters", {}))
        elif p.kind == "brdfs":
            value = [model_from_provenance(v["model"], v.get("parameters", {})) for v in value]
        kwargs[key] = value
    return cls(**kwargs)


def reference(ctx):
    """``(model, None)`` for the table of ``ctx``, or ``(None, reason)``."""
    def compute():
        if ctx.reference is not None:
            return ctx.reference, None
        ds = getattr(ctx.brdf, "ds", None)
        if ds is None:
            return None, "not a table"
        name = str(ds.attrs.get("model", ""))
        if not name or name == "unknown":
            return None, "the table names no model in its provenance"
        try:
            params = json.loads(ds.attrs.get("parameters", "{}"))
            model = model_from_provenance(name, params)
            if "colour_illuminant" in ds.attrs and "colour_wavelengths_nm" in ds.attrs:
                # spectra converted to colour (brdftab.colorimetry): the model seen the same way
                from ..colorimetry import from_recorded

                model = from_recorded(model, ds.attrs)
            return model, None
        except (BrdftabError, KeyError, TypeError, ValueError, AttributeError) as exc:
            return None, f"the model in the table's provenance ({name!r}) is not available: {exc}"
    return ctx.memo("reference", compute)
