"""The format options of RGL ``.bsdf`` files: names, defaults, validation, incident elevations."""

from __future__ import annotations

import math

import numpy as np

from ..errors import ParameterError
from ..params import Param, suggest

__all__ = ["BACKSCATTER_DEFAULTS", "DEFAULTS", "OPTIONS", "PARAMS", "NDF_CHOICES", "VALUES_CHOICES", "WARP_CHOICES",
           "MAX_RESOLUTION", "backscatter_defaults", "check_options", "theta_i_nodes"]

#: Default resolutions (format options).
DEFAULTS = {
    "n_theta_i": 17,           # incident elevations over [0, theta_i_max_deg] (theta_i_nodes)
    "theta_i_max_deg": 89.0,
    "n_phi_i": 17,             # anisotropic files: incident azimuths over [-180°, 180°]
    "resolution": 48,          # N × N stored samples per incident direction
    "vndf_resolution": 64,     # VNDF table per incident direction
    "ndf_resolution": 128,     # ndf / sigma along θ
    "ndf_phi_resolution": 256,  # ndf / sigma along φ (anisotropic files; isotropic files use 2 rows)
}
#: The defaults that differ for a D from the back-scattering (tables, measured data, Lambert),
#: per warp (option ``warp``): their structure is not in a D the warp can follow, so the file
#: holds more incidences and samples, and the ``ndf`` table keeps the back-scattering's D at
#: its own 1025 nodes (:func:`._rgl_ndf.backscatter_ndf`), fine enough for the half-vector
#: structure of a table (a table's θh nodes, the measured noise of a film's D) that 128 nodes
#: smooth. Measured on the real RGL files' netCDF conversions (formats/rgl-bsdf.md, options):
#: the ``ndf`` at 1025 nodes took a film from 2.4 / 17 % (median / p95) to 1.06 / 10.7 %, a car
#: paint from 0.87 / 7.0 % to 0.52 / 3.4 %; the lobe warp reads closer with more incidences
#: and samples and a coarser ``vndf`` table (23 incidences, 52 x 52, vndf 40 x 40: the film
#: 0.93 / 9.0 %, the flake paint 0.96 / 6.8 %, against 1.06 / 10.7 % and 1.05 / 8.4 % at 21,
#: 49 x 49, 64 x 64); the level warp of a Lambertian does not (worst error up to 80° 3.7 %
#: there, 1.8 % at 21, 49 x 49, 64 x 64). An RGB file is at most 1.86x the size of an RGL
#: database file (1.76x with the lobe warp).
BACKSCATTER_DEFAULTS = {
    "level": {"n_theta_i": 21, "resolution": 49, "vndf_resolution": 64, "ndf_resolution": 1025},
    "lobe": {"n_theta_i": 23, "resolution": 52, "vndf_resolution": 40, "ndf_resolution": 1025},
    # anisotropic files, either warp: their ndf and sigma hold ndf_phi_resolution rows of
    # ndf_resolution (1025 would make them 2 MB)
    "anisotropic": {"n_theta_i": 21, "resolution": 49, "vndf_resolution": 64, "ndf_resolution": 128},
}
MAX_RESOLUTION = 4096


def _backscatter_text(key: str) -> str:
    """``"49 (level warp), 52 (lobe warp) in isotropic files, 49 in anisotropic ones"``: the
    :data:`BACKSCATTER_DEFAULTS` of ``key``."""
    d = {kind: v[key] for kind, v in BACKSCATTER_DEFAULTS.items()}
    iso = str(d["level"]) if d["level"] == d["lobe"] else f"{d['level']} (level warp), {d['lobe']} (lobe warp)"
    return f"{iso} in isotropic files, {d['anisotropic']} in anisotropic ones"


NDF_CHOICES = ("auto", "model", "backscatter")
#: The warp of a file whose D comes from the back-scattering (tables, Lambert): ``level``
#: (sample columns along levels of cosθo: broad reflectance), ``lobe`` (the spread even in θm
#: beside the visible normals: lobes), or ``auto``, the one that reproduces the source better.
WARP_CHOICES = ("auto", "level", "lobe")
#: The stored values: ``nodes`` (the source sampled at the sample nodes: every reading exact
#: there), ``fit`` (least squares against the source between the nodes too: :mod:`._rgl_fit`),
#: ``auto`` (in isotropic RGB files whose D is from the back-scattering, ``fit`` where node
#: samples miss and it reads closer; otherwise ``nodes``).
VALUES_CHOICES = ("auto", "nodes", "fit")

#: The format options, declared once: names, kinds, ranges and documentation (``brdftab formats
#: rgl``); :func:`check_options` adds the rules between them and fills in the defaults.
PARAMS = (
    Param("theta_i_deg", "floats", "Incident elevations in degrees, ascending in [0, 90) (default: n_theta_i "
          "values).", units="deg", default=None, minimum=0.0, maximum=90.0),
    Param("n_theta_i", "int", "Number of incident elevations from 0 to theta_i_max_deg, closer together towards "
          f"grazing (default {DEFAULTS['n_theta_i']}; for a D from the back-scattering: tables, Lambert, "
          f"{_backscatter_text('n_theta_i')}).", default=None, minimum=1, maximum=1024),
    Param("theta_i_max_deg", "float", f"Largest incident elevation in degrees (default "
          f"{DEFAULTS['theta_i_max_deg']:g}).", units="deg", default=None, minimum=0.0, maximum=90.0,
          exclusive_minimum=True),
    Param("n_phi_i", "int", f"Anisotropic files: incident azimuths over [-180, 180] degrees (default "
          f"{DEFAULTS['n_phi_i']}).", default=None, minimum=3, maximum=1024),
    Param("resolution", "int", f"Stored samples per incident direction, N x N (default {DEFAULTS['resolution']}; "
          f"for a D from the back-scattering {_backscatter_text('resolution')}).",
          default=None, minimum=2, maximum=MAX_RESOLUTION),
    Param("vndf_resolution", "int", f"vndf (warp) table per incident direction, n x n (default "
          f"{DEFAULTS['vndf_resolution']}; for a D from the back-scattering "
          f"{_backscatter_text('vndf_resolution')}; at least 3: with 2 every node lies on an edge, where the warp "
          "vanishes).", default=None, minimum=3, maximum=MAX_RESOLUTION),
    Param("ndf_resolution", "int", f"ndf and sigma tables along theta (default {DEFAULTS['ndf_resolution']}; "
          f"for a D from the back-scattering {_backscatter_text('ndf_resolution')}).",
          default=None, minimum=2, maximum=MAX_RESOLUTION),
    Param("ndf_phi_resolution", "int", f"Anisotropic files: ndf and sigma tables along phi (default "
          f"{DEFAULTS['ndf_phi_resolution']}).", default=None, minimum=2, maximum=MAX_RESOLUTION),
    Param("anisotropic", "bool", "true: phi_i over [-180, 180] degrees; false: phi_i = [0] (default: the model's "
          "isotropy).", default=None),
    Param("ndf", "choice", "auto (the model's own D, else from back-scattering) | model | backscatter.",
          default="auto", choices=NDF_CHOICES),
    Param("warp", "choice", "A D from the back-scattering (tables, Lambert): auto (the warp that reproduces the "
          "source better at check pairs) | level (broad reflectance; anisotropic files: the continuous spread) | "
          "lobe (lobes). Not used for a model's own D.",
          default="auto", choices=WARP_CHOICES),
    Param("values", "choice", "The stored values: auto (isotropic RGB files with a D from the back-scattering: "
          "the fit where node samples miss and it reads closer; else nodes) | nodes (the source at the sample nodes) "
          "| fit (least squares against the source between the nodes too).",
          default="auto", choices=VALUES_CHOICES),
    Param("wavelengths_nm", "floats", "Spectral models: wavelengths of the 'spectra' field in nm (default: the "
          "model's own).", units="nm", default=None, minimum=0.0, exclusive_minimum=True),
    Param("description", "text", "Text of the 'description' field (default: the model).", default=None),
)
#: ``{name: description}`` of the options.
OPTIONS = {p.name: p.doc for p in PARAMS}



def _int(key, value, lo, hi=MAX_RESOLUTION):
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ParameterError(key, f"expected a whole number, got {value!r}")
    if not lo <= value <= hi:
        raise ParameterError(key, f"expected a whole number in [{lo}, {hi}], got {value}")
    return int(value)


def _number(key, value):
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not math.isfinite(value):
        raise ParameterError(key, f"expected a number, got {value!r}")
    return float(value)


def _numbers(key, value):
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        value = [value]
    if not isinstance(value, (list, tuple, np.ndarray)) or len(value) == 0:
        raise ParameterError(key, f"expected a non-empty list of numbers, got {value!r}")
    return np.array([_number(key, v) for v in value])


def theta_i_nodes(n: int, top: float) -> np.ndarray:
    """``n`` incident elevations [rad] from 0 to ``top``: θ_k = top·(1 − (1 − k/(n−1))^1.5),
    closer together towards grazing, where the reflectance changes fastest with θi (for 9
    nodes to 89°: 0, 16.2, 31.2, 45.0, 57.5, 68.6, 77.9, 85.1, 89.0°)."""
    if n == 1:
        return np.zeros(1)
    return top * (1.0 - (1.0 - np.linspace(0.0, 1.0, n)) ** 1.5)


def check_options(**options) -> dict:
    """Validate the format options (names, types, ranges); returns them resolved (defaults filled in)."""
    for key in options:
        if key not in OPTIONS:
            raise ParameterError(key, f"unknown option for format rgl{suggest(key, OPTIONS)}; "
                                      f"valid: {', '.join(OPTIONS)}")
    return _resolve_options(**options)


def _resolve_options(theta_i_deg=None, n_theta_i=None, theta_i_max_deg=None, n_phi_i=None, resolution=None,
                  vndf_resolution=None, ndf_resolution=None, ndf_phi_resolution=None, anisotropic=None, ndf="auto",
                  wavelengths_nm=None, description=None, warp="auto", values="auto"):
    out = {"defaulted": frozenset(
        k for k, v in (("n_theta_i", theta_i_deg is None and n_theta_i is None), ("resolution", resolution is None),
                       ("vndf_resolution", vndf_resolution is None), ("ndf_resolution", ndf_resolution is None))
        if v), "theta_i_max": None}
    if theta_i_deg is not None:
        if n_theta_i is not None or theta_i_max_deg is not None:
            raise ParameterError("theta_i_deg", "give either theta_i_deg or n_theta_i / theta_i_max_deg, not both")
        t = _numbers("theta_i_deg", theta_i_deg)
        if np.any(t < 0) or np.any(t >= 90):
            raise ParameterError("theta_i_deg", "incident elevations must lie in [0, 90) degrees")
        if np.any(np.diff(t) <= 0):
            raise ParameterError("theta_i_deg", "incident elevations must increase strictly")
        if np.any(np.diff(np.radians(t).astype(np.float32)) <= 0):
            raise ParameterError("theta_i_deg", "incident elevations are too close to tell apart in float32")
        out["theta_i"] = np.radians(t)
    else:
        n = _int("n_theta_i", DEFAULTS["n_theta_i"] if n_theta_i is None else n_theta_i, 1, 1024)
        top = DEFAULTS["theta_i_max_deg"] if theta_i_max_deg is None else _number("theta_i_max_deg", theta_i_max_deg)
        if not 0 < top < 90:
            raise ParameterError("theta_i_max_deg", f"expected a number in (0, 90) degrees, got {top:g}")
        out["theta_i"] = theta_i_nodes(n, math.radians(top))
        out["theta_i_max"] = math.radians(top)
    if anisotropic is not None and not isinstance(anisotropic, (bool, np.bool_)):
        raise ParameterError("anisotropic", f"expected true or false, got {anisotropic!r}")
    out["anisotropic"] = None if anisotropic is None else bool(anisotropic)
    if n_phi_i is not None:
        if anisotropic is False:
            raise ParameterError("n_phi_i", "only used for anisotropic files (anisotropic is false)")
        out["n_phi_i"] = _int("n_phi_i", n_phi_i, 3, 1024)
    else:
        out["n_phi_i"] = DEFAULTS["n_phi_i"]
    for key, value in (("resolution", resolution), ("vndf_resolution", vndf_resolution),
                       ("ndf_resolution", ndf_resolution), ("ndf_phi_resolution", ndf_phi_resolution)):
        out[key] = DEFAULTS[key] if value is None else _int(key, value, 3 if key == "vndf_resolution" else 2)
    if ndf not in NDF_CHOICES:
        raise ParameterError("ndf", f"expected one of {', '.join(NDF_CHOICES)}, got {ndf!r}")
    out["ndf"] = ndf
    if warp not in WARP_CHOICES:
        raise ParameterError("warp", f"expected one of {', '.join(WARP_CHOICES)}, got {warp!r}")
    out["warp"] = warp
    if values not in VALUES_CHOICES:
        raise ParameterError("values", f"expected one of {', '.join(VALUES_CHOICES)}, got {values!r}")
    out["values"] = values
    if wavelengths_nm is not None:
        lam = _numbers("wavelengths_nm", wavelengths_nm)
        if np.any(lam <= 0) or np.any(np.diff(lam) <= 0):
            raise ParameterError("wavelengths_nm", "expected positive wavelengths in nm, increasing strictly")
        out["wavelengths"] = lam
    else:
        out["wavelengths"] = None
    if description is not None and not isinstance(description, str):
        raise ParameterError("description", f"expected a string, got {description!r}")
    out["description"] = description
    return out


def backscatter_defaults(opts: dict, warp: str, anisotropic: bool) -> dict:
    """``opts`` (resolved) with :data:`BACKSCATTER_DEFAULTS` for the options not given: those of
    ``warp`` (``level`` or ``lobe``) in an isotropic file, of ``anisotropic`` otherwise."""
    out, defaults = dict(opts), BACKSCATTER_DEFAULTS["anisotropic" if anisotropic else warp]
    if "n_theta_i" in opts["defaulted"]:
        out["theta_i"] = theta_i_nodes(defaults["n_theta_i"], opts["theta_i_max"])
    for key in ("resolution", "vndf_resolution", "ndf_resolution"):
        if key in opts["defaulted"]:
            out[key] = defaults[key]
    return out
