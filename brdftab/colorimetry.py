"""Spectra to colour through colour-science: CIE XYZ and linear RGB of spectral BRDF values.

A spectral BRDF value f(λ) [sr⁻¹] sampled at wavelengths λ₁…λ_L [nm] becomes tristimulus
values the way colour-science turns a reflectance spectrum into colour:

1. ``colour.sd_to_XYZ`` (its default method, ASTM E308) with an illuminant (default CIE D65)
   and an observer (default the CIE 1931 2° standard observer), divided by 100, so that a
   spectrum of constant value v has Y = v: a perfectly white Lambertian, f = 1/π, has Y = 1/π;
2. ``colour.XYZ_to_RGB`` to a linear RGB colourspace (default sRGB, no transfer function), with
   chromatic adaptation (colour-science's default, CAT02) from the illuminant's white to the
   colourspace's when they differ.

Both steps are linear in f, so the conversion of a table is one L × 3 matrix,
:meth:`Colorimetry.matrix`, computed once by colour-science itself from the L unit spectra
(tests/test_colorimetry.py holds it to colour-science's per-spectrum conversion to 1e-12). No
colour-matching table is written here. colour-science trims or extends the observer to the
spectrum's own range (ASTM E308), so a table sampled over 400–700 nm is integrated over
400–700 nm, as colour-science would integrate those spectra.

``colour`` takes about a second to import: it is imported on first use only.

References: CIE 015:2018 Colorimetry, 4th ed.; ASTM E308-22, Standard Practice for Computing the
Colors of Objects by Using the CIE System; IEC 61966-2-1:1999 (sRGB).
"""

from __future__ import annotations

import functools
import warnings
from dataclasses import dataclass

import numpy as np

from .brdf import BRDF
from .channels import Layout
from .errors import ParameterError
from .params import Param

__all__ = ["Colorimetry", "DEFAULT", "OBSERVERS", "COLOURSPACES", "spectral_to_xyz", "spectral_to_rgb",
           "luminance_weights", "sd_method", "spectral_distribution", "ColourView", "colour_view", "table_to_colour",
           "to_colour", "PARAMS", "from_options", "seen_as_written", "XYZView", "rgb_to_xyz", "convert_for_writer",
           "from_recorded"]

def _colour():
    """colour-science, imported keeping numpy's print options (its import switches the whole
    process to numpy 1.13's legacy printing)."""
    import sys

    if "colour" not in sys.modules:
        options = np.get_printoptions()
        import colour

        np.set_printoptions(**options)
    import colour

    return colour


#: Observers by their short names (the long names of colour-science are accepted too).
OBSERVERS = {
    "cie1931-2": "CIE 1931 2 Degree Standard Observer",
    "cie1964-10": "CIE 1964 10 Degree Standard Observer",
}
#: Format options of writers that store colour and convert a spectral source (MERL, EXR):
#: declared once here, validated by :func:`from_options`.
PARAMS = (
    Param("illuminant", "text", "Spectral sources: CIE illuminant of the conversion to colour through "
          "colour-science (default D65; A, D50, E, F2, ...).", default="D65"),
    Param("observer", "choice", "Spectral sources: CIE standard observer of the conversion to colour (default "
          "cie1931-2).", default="cie1931-2", choices=("cie1931-2", "cie1964-10")),
    Param("wavelengths_nm", "floats", "Spectral models: wavelengths in nm at which the spectrum is sampled for the "
          "conversion to colour (default: the model's or the spec's).", units="nm", default=None, minimum=0.0,
          exclusive_minimum=True),
)


def from_options(illuminant="D65", observer="cie1931-2", colourspace="sRGB", **_) -> "Colorimetry":
    """The :class:`Colorimetry` of a writer's options (:data:`PARAMS`)."""
    if not isinstance(illuminant, str):
        raise ParameterError("illuminant", f"expected the name of a CIE illuminant, got {illuminant!r}")
    if not isinstance(observer, str):
        raise ParameterError("observer", f"expected one of {', '.join(OBSERVERS)}, got {observer!r}")
    return Colorimetry(illuminant, observer, colourspace)


def convert_for_writer(brdf, fmt_name: str, illuminant="D65", observer="cie1931-2", wavelengths_nm=None,
                       colourspace="sRGB", announce=True):
    """What a writer that stores colour is given for ``brdf``: ``brdf`` itself unless it is
    spectral; a spectral one converted by :func:`to_colour`, saying so in one warning line when
    ``announce`` (a file with no metadata to record it, such as MERL's)."""
    if not brdf.spectral:
        return brdf
    c = from_options(illuminant, observer, colourspace)
    out = to_colour(brdf, c, wavelengths_nm)
    if announce:
        import warnings as _w

        from .errors import BrdftabWarning

        lam = out.wavelengths_nm if isinstance(out, ColourView) else _attr_wavelengths(out)
        _w.warn(f"'{brdf.name}' is spectral: its {len(lam)} wavelengths ({min(lam):g}-{max(lam):g} nm) are written to "
                f"{fmt_name} as {c.describe()}, through colour-science (the file records no colour metadata)",
                BrdftabWarning, stacklevel=3)
    return out


def seen_as_written(source, written, options: dict | None = None, wavelengths=None):
    """``source`` as a file written from it holds it: converted to colour (with the writer's
    ``illuminant``/``observer`` options) when ``source`` is spectral and ``written`` is not, so
    that the two can be compared; otherwise ``source`` itself."""
    from .brdf import BRDF

    if (isinstance(written, BRDF) and isinstance(source, BRDF) and not source.spectral and not written.spectral
            and source.channels in (("R", "G", "B"), ("mono",)) and source.channels != written.channels
            and written.channels in (("X", "Y", "Z"), ("mono",))):
        return XYZView(source, luminance_only=written.channels == ("mono",))
    if not getattr(source, "spectral", False) or not isinstance(written, BRDF) or written.spectral:
        return source
    opts = {k: v for k, v in (options or {}).items() if k in ("illuminant", "observer")}
    return to_colour(source, from_options(**opts), (options or {}).get("wavelengths_nm", wavelengths))


def _attr_wavelengths(table):
    return [float(x) for x in str(table.ds.attrs["colour_wavelengths_nm"]).split(",")]


#: The observers' range as colour-science aligns them by default (its SPECTRAL_SHAPE_DEFAULT), nm.
VISIBLE_NM = (360.0, 780.0)
#: Output colourspaces: ``"XYZ"`` (CIE XYZ) or a linear RGB colourspace of colour-science.
COLOURSPACES = ("sRGB", "XYZ", "ACEScg", "Display P3", "ITU-R BT.2020", "Adobe RGB (1998)")


@dataclass(frozen=True)
class Colorimetry:
    """How spectra become colour: illuminant, observer and output colourspace (linear)."""

    illuminant: str = "D65"
    observer: str = "CIE 1931 2 Degree Standard Observer"
    colourspace: str = "sRGB"

    def __post_init__(self):
        colour = _colour()

        obs = OBSERVERS.get(self.observer, self.observer)
        if obs not in OBSERVERS.values():
            raise ParameterError("observer", f"unknown observer {self.observer!r}; expected one of "
                                 f"{', '.join(OBSERVERS)}")
        object.__setattr__(self, "observer", obs)
        if self.illuminant not in colour.SDS_ILLUMINANTS:
            names = [n for n in colour.SDS_ILLUMINANTS if n[0].isupper()][:12]
            raise ParameterError("illuminant", f"unknown illuminant {self.illuminant!r}; expected one of "
                                 f"{', '.join(names)}, …")
        if self.colourspace not in COLOURSPACES:
            raise ParameterError("colourspace", f"unknown colourspace {self.colourspace!r}; expected one of "
                                 f"{', '.join(COLOURSPACES)}")

    @property
    def channels(self) -> tuple[str, str, str]:
        return ("X", "Y", "Z") if self.colourspace == "XYZ" else ("R", "G", "B")

    def matrix(self, wavelengths) -> np.ndarray:
        """The ``[L, 3]`` matrix M with colour = f(λ) @ M for spectra sampled at ``wavelengths`` [nm]."""
        lam = np.asarray(wavelengths, float)
        if lam.ndim != 1 or not np.all(np.isfinite(lam)) or np.any(lam <= 0) or np.any(np.diff(lam) <= 0):
            raise ParameterError("wavelengths", "expected increasing positive wavelengths in nm")
        if lam.size < 2:
            raise ParameterError("wavelengths", f"a spectrum of {lam.size} sample has no colour: at least two "
                                 "wavelengths are needed to convert to colour")
        if lam[-1] <= VISIBLE_NM[0] or lam[0] >= VISIBLE_NM[1]:
            raise ParameterError("wavelengths", f"the spectrum ({lam[0]:g}-{lam[-1]:g} nm) lies outside the observer's "
                                 f"{VISIBLE_NM[0]:g}-{VISIBLE_NM[1]:g} nm: it has no colour")
        return _matrix(tuple(float(x) for x in lam), self.illuminant, self.observer, self.colourspace).copy()

    def white(self) -> np.ndarray:
        """CIE xy chromaticity of the illuminant for the observer."""
        return _white(self.illuminant, self.observer)

    def attrs(self) -> dict:
        """The conversion as metadata (netCDF/EXR attributes)."""
        colour = _colour()

        return {
            "colour_illuminant": self.illuminant,
            "colour_observer": self.observer,
            "colour_space": self.colourspace + ("" if self.colourspace == "XYZ" else " (linear)"),
            "colour_conversion": (f"colour-science {colour.__version__}: sd_to_XYZ / 100"
                                  + ("" if self.colourspace == "XYZ"
                                     else f", XYZ_to_RGB to linear {self.colourspace} (CAT02)")),
        }

    def describe(self) -> str:
        return (f"{self.colourspace}{'' if self.colourspace == 'XYZ' else ' (linear)'} under {self.illuminant}, "
                f"{self.observer}")


DEFAULT = Colorimetry.__new__(Colorimetry)
object.__setattr__(DEFAULT, "illuminant", "D65")
object.__setattr__(DEFAULT, "observer", "CIE 1931 2 Degree Standard Observer")
object.__setattr__(DEFAULT, "colourspace", "sRGB")


@functools.lru_cache(maxsize=64)
def _white(illuminant, observer):
    colour = _colour()

    ccs = colour.CCS_ILLUMINANTS.get(observer, {})
    if illuminant in ccs:
        return np.asarray(ccs[illuminant], float)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        xyz = colour.sd_to_XYZ(colour.SDS_ILLUMINANTS[illuminant], colour.MSDS_CMFS[observer])
    return np.asarray(colour.XYZ_to_xy(xyz), float)


def _xyz_to_space(xyz, illuminant, observer, colourspace):
    colour = _colour()

    if colourspace == "XYZ":
        return np.asarray(xyz, float)
    return np.asarray(colour.XYZ_to_RGB(xyz, colourspace, illuminant=_white(illuminant, observer),
                                        chromatic_adaptation_transform="CAT02", apply_cctf_encoding=False), float)


@functools.lru_cache(maxsize=64)
def _matrix(lam, illuminant, observer, colourspace):
    """colour-science's conversion of the L unit spectra (one per wavelength): the rows of M."""
    colour = _colour()

    lam = np.asarray(lam, float)
    basis = np.eye(lam.size)
    # the observer and illuminant as colour-science's own defaults build them from their names
    # (aligned to its default shape, 360-780 nm in 1 nm steps)
    cmfs, sds = colour.colorimetry.handle_spectral_arguments(cmfs_default=observer, illuminant_default=illuminant,
                                                              issue_runtime_warnings=False)
    with warnings.catch_warnings():
        # colour-science reports that it trims the observer to the spectrum's range and
        # interpolates irregular samples; both are part of its conversion
        warnings.simplefilter("ignore")
        rows = [colour.sd_to_XYZ(spectral_distribution(basis[i], lam), cmfs, sds, method=sd_method(lam))
                for i in range(lam.size)]
    xyz = np.asarray(rows, float) / 100.0
    out = _xyz_to_space(xyz, illuminant, observer, colourspace)
    out.setflags(write=False)
    return out


def spectral_distribution(values, wavelengths):
    """A colour-science ``SpectralDistribution`` of one spectrum, as this module converts it:
    colour-science's default interpolator, or linear interpolation for spectra of fewer than six
    samples (its default, Sprague's, needs six)."""
    colour = _colour()

    lam = np.asarray(wavelengths, float)
    if lam.size < 6:
        return colour.SpectralDistribution(values, lam, interpolator=colour.LinearInterpolator)
    return colour.SpectralDistribution(values, lam)


def sd_method(wavelengths) -> str:
    """colour-science's ``sd_to_XYZ`` method for spectra at ``wavelengths`` [nm]: ASTM E308 (its
    default) for samples every 1, 5, 10 or 20 nm, which that practice requires; otherwise
    ``"Integration"`` (the spectrum interpolated onto the observer's 1 nm samples by
    colour-science and summed)."""
    lam = np.asarray(wavelengths, float)
    if lam.size >= 2:
        step = np.diff(lam)
        if np.allclose(step, step[0], rtol=0, atol=1e-9) and any(abs(step[0] - s) < 1e-9 for s in (1, 5, 10, 20)):
            return "ASTM E308"
    return "Integration"


def spectral_to_xyz(values, wavelengths, illuminant="D65", observer="CIE 1931 2 Degree Standard Observer"):
    """CIE XYZ of spectra ``values[..., L]`` sampled at ``wavelengths`` [nm] (Y = v for a constant v)."""
    return _apply(values, Colorimetry(illuminant, observer, "XYZ").matrix(wavelengths))


def spectral_to_rgb(values, wavelengths, illuminant="D65", observer="CIE 1931 2 Degree Standard Observer",
                    colourspace="sRGB"):
    """Linear RGB (default sRGB, no transfer function) of spectra ``values[..., L]`` at ``wavelengths`` [nm]."""
    return _apply(values, Colorimetry(illuminant, observer, colourspace).matrix(wavelengths))


def _apply(values, m):
    v = np.asarray(values, float)
    if v.shape[-1] != m.shape[0]:
        raise ParameterError("wavelengths", f"{m.shape[0]} wavelengths for spectra of {v.shape[-1]} samples")
    return v @ m


def luminance_weights(wavelengths, colorimetry: Colorimetry | None = None) -> np.ndarray:
    """Weights (summing to 1) of the CIE Y of spectra sampled at ``wavelengths`` [nm]."""
    c = colorimetry or DEFAULT
    lam = np.atleast_1d(np.asarray(wavelengths, float))
    if lam.size < 2 or lam[-1] <= VISIBLE_NM[0] or lam[0] >= VISIBLE_NM[1]:
        return np.full(lam.size, 1.0 / lam.size)  # no colour (one sample, or outside the visible)
    y = Colorimetry(c.illuminant, c.observer, "XYZ").matrix(lam)[:, 1]
    return y / y.sum() if y.sum() > 0 else np.full(y.size, 1.0 / y.size)


class _View(BRDF):
    """A BRDF seen through a fixed linear map of its channels: its symmetries, name, origin,
    parameters and lobes are the base's (a fixed combination of channels keeps every symmetry);
    energy conservation is not declared (a channel can exceed every input channel's albedo)."""

    def __init__(self, base: BRDF, layout: Layout):
        self.base = base
        self.layout = layout
        self.name = base.name
        self.isotropic, self.reciprocal, self.origin = base.isotropic, base.reciprocal, base.origin
        self.energy_conserving = False

    @property
    def parameters(self):
        return dict(getattr(self.base, "parameters", {}))

    @property
    def lobe_width(self):
        return self.base.lobe_width

    @property
    def lobe_axes(self):
        return self.base.lobe_axes


class ColourView(_View):
    """A spectral BRDF seen in colour: ``eval`` returns its spectrum at ``wavelengths`` [nm]
    converted by ``colorimetry`` (channels R, G, B or X, Y, Z). Not reciprocal-breaking: a
    fixed linear combination of wavelengths keeps every symmetry of the spectral BRDF."""

    def __init__(self, base: BRDF, wavelengths, colorimetry: Colorimetry | None = None):
        if not base.spectral and getattr(base.layout, "sampled", None) is None:
            raise ParameterError("colourspace", f"'{base.name}' is not spectral: nothing to convert")
        self.colorimetry = colorimetry or DEFAULT
        super().__init__(base, Layout(self.colorimetry.channels))
        self.wavelengths_nm = np.asarray(wavelengths, float)
        self._m = self.colorimetry.matrix(self.wavelengths_nm)

    def describe(self) -> str:
        return f"{self.base.describe()} in {self.colorimetry.describe()}"

    def _eval(self, wi, wo, lam, n):
        return np.asarray(self.base.eval(wi, wo, self.wavelengths_nm, assume_unit=True), float) @ self._m


class XYZView(_View):
    """An RGB (linear sRGB) or grey BRDF seen in CIE XYZ through colour-science's
    ``RGB_to_XYZ`` (the sRGB colourspace and its D65 white; a grey f is the RGB (f, f, f)), or
    its Y alone (``luminance_only``): what a writer that stores XYZ writes of it."""

    def __init__(self, base: BRDF, luminance_only: bool = False):
        if base.spectral or base.channels not in (("R", "G", "B"), ("mono",)):
            raise ParameterError("channels", f"'{base.name}' is not RGB or grey: nothing to convert to XYZ")
        super().__init__(base, Layout(("mono",) if luminance_only else ("X", "Y", "Z")))
        self.luminance_only = luminance_only

    def describe(self) -> str:
        return f"{self.base.describe()} in CIE XYZ (from linear sRGB)"

    def _eval(self, wi, wo, lam, n):
        xyz = rgb_to_xyz(np.asarray(self.base.eval(wi, wo, assume_unit=True), float), self.base.channels)
        return xyz[..., 1:2] if self.luminance_only else xyz


def rgb_to_xyz(values, channels=("R", "G", "B")) -> np.ndarray:
    """``values[..., 3]`` in linear sRGB (or ``[..., 1]`` grey, as (f, f, f)) to CIE XYZ by
    colour-science's ``RGB_to_XYZ`` (sRGB colourspace, its D65 white, no transfer function)."""
    colour = _colour()

    v = np.asarray(values, float)
    if tuple(channels) == ("mono",):
        v = np.repeat(v, 3, axis=-1)
    with np.errstate(invalid="ignore"):
        out = colour.RGB_to_XYZ(v.reshape(-1, 3), "sRGB", apply_cctf_decoding=False)
    return np.asarray(out, float).reshape(v.shape)


def colour_view(brdf: BRDF, colorimetry: Colorimetry | None = None, wavelengths=None) -> ColourView:
    """``brdf`` (spectral) in colour, at ``wavelengths`` or its own stored/default wavelengths."""
    lam = wavelengths if wavelengths is not None else brdf.layout.wavelengths
    if lam is None:
        raise ParameterError("wavelengths", f"'{brdf.name}' is spectral with no wavelengths of its own: give the "
                             "wavelengths to convert at")
    return ColourView(brdf, lam, colorimetry)


def table_to_colour(table, colorimetry: Colorimetry | None = None):
    """A spectral :class:`~brdftab.table.Table` converted to colour: every variable along its
    ``wavelength`` axis (the samples, and the albedo curve or specular reflectance stored beside
    them, all linear in f) becomes R, G, B (or X, Y, Z) by :meth:`Colorimetry.matrix`; the
    conversion is recorded in the attributes and the history. Missing samples (NaN in any
    wavelength) stay missing."""
    import datetime as _dt

    import xarray as xr

    from ._version import __version__
    from .table import Table

    c = colorimetry or DEFAULT
    ds = table.ds
    lam = np.asarray(ds["wavelength"].values, float)
    m = c.matrix(lam)
    channel = xr.Variable(("channel",), np.array(c.channels, dtype=object), attrs={"long_name": "colour channel"})
    out = xr.Dataset(attrs=dict(ds.attrs))
    for name, var in ds.data_vars.items():
        if "wavelength" not in var.dims:
            out[name] = var
            continue
        v = np.moveaxis(np.asarray(var.values, float), var.dims.index("wavelength"), -1)
        with np.errstate(invalid="ignore"):
            conv = (v.reshape(-1, lam.size) @ m).reshape(v.shape[:-1] + (3,))
        dims = tuple(d for d in var.dims if d != "wavelength") + ("channel",)
        attrs = {k: a for k, a in var.attrs.items() if k not in ("valid_min", "valid_max")}
        out[name] = xr.Variable(dims, conv.astype(var.dtype if var.dtype.kind == "f" else np.float64), attrs=attrs)
    out = out.assign_coords({k: v for k, v in ds.coords.items() if "wavelength" not in v.dims})
    out = out.assign_coords(channel=channel)
    out.attrs.update(c.attrs())
    out.attrs["colour_wavelengths_nm"] = ", ".join(f"{x:g}" for x in lam)
    stamp = _dt.datetime.now(_dt.timezone.utc).replace(microsecond=0).isoformat()
    out.attrs["history"] = (str(ds.attrs.get("history", "")).rstrip("\n") + "\n" if ds.attrs.get("history") else "") \
        + f"{stamp} brdftab {__version__}: spectra ({lam.size} wavelengths, {lam[0]:g}-{lam[-1]:g} nm) converted to " \
        + c.describe()
    new = Table(out)
    new.origin = getattr(table, "origin", new.origin)
    return new


_OBSERVER_NAMES = {v: k for k, v in OBSERVERS.items()}


def from_recorded(model, attrs) -> "ColourView":
    """``model`` seen as a table converted by :func:`table_to_colour` records it (its
    ``colour_*`` attributes: illuminant, observer, colourspace and the wavelengths)."""
    space = str(attrs.get("colour_space", "sRGB (linear)")).removesuffix(" (linear)")
    c = Colorimetry(str(attrs["colour_illuminant"]), str(attrs.get("colour_observer", DEFAULT.observer)), space)
    lam = [float(x) for x in str(attrs["colour_wavelengths_nm"]).split(",")]
    return ColourView(model, lam, c)


def to_colour(brdf, colorimetry: Colorimetry | None = None, wavelengths=None):
    """A spectral BRDF in colour: a table converted sample by sample (:func:`table_to_colour`),
    anything else evaluated at ``wavelengths`` (or its own) and converted (:class:`ColourView`).
    A BRDF that is not spectral is returned as it is."""
    from .table import Table

    if not brdf.spectral:
        return brdf
    if isinstance(brdf, Table):
        return table_to_colour(brdf, colorimetry)
    return colour_view(brdf, colorimetry, wavelengths)
