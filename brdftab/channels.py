"""Per-channel and spectral parameter values, and how channels combine.

A BRDF's output has a trailing *channel axis*. It is one of

* **named channels** — ``("mono",)`` for a grey model, ``("R", "G", "B")`` for three values, or
  ``("c0", "c1", …)`` for other counts; evaluated with ``wavelengths=None``;
* **spectral** — one output per requested wavelength (nm); evaluated with ``wavelengths=[…]``.

A model parameter that may vary per channel is a :class:`ChannelValue`: a grey scalar (valid in
both modes), a list with one value per channel, or a sampled spectrum
``{"wavelengths_nm": [...], "values": [...]}`` interpolated linearly in wavelength (no
extrapolation: requesting a wavelength outside the samples is an error).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import ParameterError

__all__ = ["ChannelValue", "Layout", "default_channel_names", "combine_layouts", "luminance_weights", "RGB_LUMINANCE",
           "RGB_WAVELENGTHS_NM"]


def default_channel_names(n: int) -> tuple[str, ...]:
    """Channel names for ``n`` per-channel values: mono, RGB or c0…c{n−1}."""
    if n == 1:
        return ("mono",)
    if n == 3:
        return ("R", "G", "B")
    return tuple(f"c{i}" for i in range(n))


@dataclass(frozen=True)
class Layout:
    """The channel axis a BRDF produces.

    ``channels`` is a tuple of names, or None when the BRDF is spectral; ``wavelengths`` are
    the default sample wavelengths [nm] of a spectral BRDF (None when it has none of its own).
    """

    channels: tuple[str, ...] | None = ("mono",)
    wavelengths: np.ndarray | None = None
    #: ``(lo, hi, what)`` when the BRDF's values come from a spectrum it can sample at any
    #: wavelength in [lo, hi] nm (a material's optical constants, :mod:`brdftab.optical`), so
    #: it accepts wavelengths though it has named channels (R, G, B sampled at
    #: :data:`RGB_WAVELENGTHS_NM`); ``what`` names the data in the out-of-range error.
    sampled: tuple | None = None

    def __post_init__(self):
        if self.channels is None:
            return
        seen = set()
        for name in self.channels:
            if name in seen:
                raise ParameterError("channels", f"duplicate channel name {name!r} (channels "
                                     f"{', '.join(map(str, self.channels))}): each channel needs its own name")
            seen.add(name)

    @property
    def spectral(self) -> bool:
        return self.channels is None

    @property
    def grey(self) -> bool:
        return self.channels == ("mono",)

    def resolve(self, wavelengths=None):
        """Validate an eval request; returns the wavelength array or None (channel mode)."""
        if wavelengths is None:
            if self.spectral:
                if self.wavelengths is None:
                    raise ParameterError("wavelengths", "this BRDF is spectral: pass wavelengths in nm")
                return np.asarray(self.wavelengths, float)
            return None
        lam = np.atleast_1d(np.asarray(wavelengths, float))
        if lam.ndim != 1 or not np.all(np.isfinite(lam)) or np.any(lam <= 0):
            raise ParameterError("wavelengths", "expected a 1-D list of positive wavelengths in nm")
        if not self.spectral and not self.grey and self.sampled is None:
            raise ParameterError(
                "wavelengths",
                f"this BRDF has channels {list(self.channels)}, not a spectrum; evaluate it without wavelengths",
            )
        if self.sampled is not None:
            lo, hi, what = self.sampled
            out = lam[(lam < lo) | (lam > hi)]
            if out.size:
                raise ParameterError("wavelengths", f"{out[0]:g} nm is outside {lo:g}-{hi:g} nm, the range of "
                                     f"{what} (no extrapolation)")
        return lam

    def n_out(self, lam) -> int:
        return len(self.channels) if lam is None else len(lam)


def combine_layouts(layouts, names=None) -> Layout:
    """Layout of a combination (sum, product) of terms: grey terms broadcast to the others.

    ``names`` label the layouts (the parameters or terms they come from, e.g. ``("n", "k")``):
    a conflict is then a :class:`ParameterError` keyed by the second of the two, naming both."""
    layouts = list(layouts)
    names = list(names) if names is not None else None
    spectral = [l for l in layouts if l.spectral]
    named = [l for l in layouts if not l.spectral and not l.grey]
    if names is not None:
        first, second = None, None
        for name, l in zip(names, layouts):
            if l.grey:
                continue
            if first is None:
                first = (name, l)
            elif not _compatible(first[1], l):
                second = (name, l)
                break
        if second is not None:
            def what(l):
                return "is a spectrum" if l.spectral else \
                    f"has {len(l.channels)} channel values ({', '.join(l.channels)})"
            raise ParameterError(second[0], f"{what(second[1])}, but {first[0]} {what(first[1])}: give both the same "
                                 "channels, both spectra, or one a single number")
    spans = [l.sampled for l in layouts if l.sampled is not None]
    sampled = None
    if spans:
        lo, hi = max(s[0] for s in spans), min(s[1] for s in spans)
        if lo > hi:
            raise ParameterError("wavelengths", "the terms' optical constants share no common wavelength range")
        sampled = (lo, hi, " and ".join(dict.fromkeys(s[2] for s in spans)))
    if spectral and named and all(l.sampled is not None for l in named):
        named = []  # channels that sample a spectrum: evaluated at the spectral terms' wavelengths
    if spectral and named:
        raise ParameterError(
            "terms", f"cannot combine a spectral term with a term of channels {list(named[0].channels)}"
        )
    if spectral:
        wl = [l.wavelengths for l in spectral if l.wavelengths is not None]
        if not wl:
            return Layout(None, None, sampled)
        # every term is defined only over its own range: keep the common range
        lo = max(w[0] for w in wl)
        hi = min(w[-1] for w in wl)
        if lo > hi:
            raise ParameterError("wavelengths", "the spectral parameters share no common wavelength range")
        union = np.unique(np.concatenate(wl))
        return Layout(None, union[(union >= lo) & (union <= hi)], sampled)
    if named:
        first = named[0].channels
        for l in named[1:]:
            if l.channels != first:
                raise ParameterError("terms", f"terms have different channels: {list(first)} and {list(l.channels)}")
        return Layout(first, sampled=sampled if all(l.sampled is not None for l in named) else None)
    return Layout()


def _compatible(a: Layout, b: Layout) -> bool:
    """Whether two non-grey layouts combine: both spectra, the same channels, or a spectrum and
    channels that sample a spectrum (:attr:`Layout.sampled`)."""
    if a.spectral and b.spectral:
        return True
    if not a.spectral and not b.spectral:
        return a.channels == b.channels
    return (b if a.spectral else a).sampled is not None


class ChannelValue:
    """A parameter value that may differ per channel or vary with wavelength.

    Parameters
    ----------
    values : float, sequence of float, or mapping
        A scalar (grey), a sequence (one value per channel) or
        ``{"wavelengths_nm": [...], "values": [...]}`` (a sampled spectrum).
    wavelengths : sequence of float, optional
        Sample wavelengths [nm] when ``values`` is a spectrum given as two arrays.
    """

    def __init__(self, values, wavelengths=None):
        if wavelengths is None:
            arr = np.atleast_1d(np.asarray(values, float))
            if arr.ndim != 1 or arr.size == 0:
                raise ValueError("expected a number or a non-empty list of numbers")
            self.values = arr
            self.wavelengths = None
        else:
            wl = np.asarray(wavelengths, float)
            arr = np.asarray(values, float)
            if wl.ndim != 1 or arr.shape != wl.shape or wl.size == 0:
                raise ValueError("wavelengths_nm and values must be lists of the same length")
            if not np.all(np.isfinite(wl)):
                raise ValueError("wavelengths_nm must be finite")
            if np.any(np.diff(wl) <= 0):
                raise ValueError("wavelengths_nm must increase strictly")
            if np.any(wl <= 0):
                raise ValueError("wavelengths_nm must be positive")
            self.values = arr
            self.wavelengths = wl

    @classmethod
    def parse(cls, raw) -> "ChannelValue":
        """From a spec/API value: number, list of numbers, or a spectrum mapping."""
        if isinstance(raw, ChannelValue):
            return raw
        if isinstance(raw, dict):
            extra = set(raw) - {"wavelengths_nm", "values"}
            if extra or "wavelengths_nm" not in raw or "values" not in raw:
                raise ValueError("a spectrum needs exactly the keys wavelengths_nm and values")
            return cls(_numbers(raw["values"]), _numbers(raw["wavelengths_nm"]))
        if isinstance(raw, bool) or np.iscomplexobj(raw):
            raise ValueError("expected real numbers")
        if isinstance(raw, np.ndarray) and raw.ndim == 0:
            raw = raw.item()
        if isinstance(raw, (int, float, np.number)):
            return cls(_real(raw))
        if isinstance(raw, (list, tuple, np.ndarray)):
            return cls(_numbers(raw))
        raise ValueError(f"expected a number, a list of numbers or a spectrum, got {type(raw).__name__}")

    @property
    def kind(self) -> str:
        if self.wavelengths is not None:
            return "spectral"
        return "grey" if self.values.size == 1 else "channels"

    @property
    def layout(self) -> Layout:
        if self.kind == "spectral":
            return Layout(None, self.wavelengths)
        return Layout(default_channel_names(self.values.size))

    def at(self, lam, n_out: int) -> np.ndarray:
        """Values on the output channel axis (length ``n_out``) for wavelengths ``lam`` or None."""
        if self.kind == "spectral":
            if lam is None:
                raise ParameterError("wavelengths", "a spectral parameter needs wavelengths")
            lo, hi = self.wavelengths[0], self.wavelengths[-1]
            if np.any(lam < lo - 1e-9) or np.any(lam > hi + 1e-9):
                raise ParameterError(
                    "wavelengths", f"requested wavelengths outside the parameter's spectrum [{lo:g}, {hi:g}] nm"
                )
            return np.interp(lam, self.wavelengths, self.values)
        if self.values.size == 1:
            return np.full(n_out, self.values[0])
        if self.values.size != n_out:
            raise ParameterError("channels", f"parameter has {self.values.size} channel values, output has {n_out}")
        return self.values

    def check(self, predicate) -> bool:
        return bool(np.all(predicate(self.values)))

    def to_json(self):
        if self.kind == "spectral":
            return {"wavelengths_nm": self.wavelengths.tolist(), "values": self.values.tolist()}
        return float(self.values[0]) if self.values.size == 1 else self.values.tolist()

    def __repr__(self):
        return f"ChannelValue({self.to_json()!r})"


def _real(x) -> float:
    if isinstance(x, bool) or not isinstance(x, (int, float, np.number)) or np.iscomplexobj(x):
        raise ValueError("expected a list of numbers")
    try:
        return float(x)
    except OverflowError:
        raise ValueError("number too large") from None


def _numbers(seq):
    if isinstance(seq, (str, bytes, dict)) or not hasattr(seq, "__len__"):
        raise ValueError("expected a list of numbers")
    return [_real(x) for x in seq]


#: The wavelengths [nm] the R, G, B channels stand for where a spectrum is sampled per channel
#: (a material's optical constants, :mod:`brdftab.optical`): the dominant wavelengths of the
#: Rec. 709 / sRGB primaries (brdftab's RGB) with respect to the D65 white point, CIE 1931 2°
#: observer (CIE 15:2004 §9.1), as ``colour.dominant_wavelength`` gives them (tested).
RGB_WAVELENGTHS_NM = np.array([611.0, 549.0, 464.0])

#: Rec. 709 relative luminance weights of linear R, G, B.
RGB_LUMINANCE = np.array([0.2126, 0.7152, 0.0722])


def luminance_weights(channels, lam=None) -> np.ndarray:
    """Weights (summing to 1) that turn a channel axis into a relative luminance: Rec. 709 Y
    for channels R, G, B, CIE Y under D65 for wavelengths ``lam`` [nm] (through colour-science:
    :func:`brdftab.colorimetry.luminance_weights`), the mean otherwise."""
    if lam is None:
        channels = tuple(channels or ())
        return RGB_LUMINANCE.copy() if channels == ("R", "G", "B") else np.full(len(channels), 1.0 / len(channels))
    lam = np.atleast_1d(np.asarray(lam, float))
    if lam.size == 1:
        return np.ones(1)
    from .colorimetry import luminance_weights as cie_y

    return cie_y(lam)
