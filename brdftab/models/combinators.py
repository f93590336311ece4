"""Combinators: build a BRDF out of other BRDFs.

* ``sum`` — f = Σ f_k (e.g. a diffuse base plus a specular lobe);
* ``scale`` — f = s · f_term with s per channel or spectral;
* ``average`` — the mean of a term over rotations about the normal (its isotropic part)
  and/or over swapping wi and wo (its reciprocal part), for grids and formats that store
  only isotropic or reciprocal BRDFs (MERL);
* ``rotated`` — a term evaluated with its normal tilted by (Δθ, Δφ0) and the sample turned
  by φ_ref about the macro normal (a facet population with its own mean normal: the offset
  specular peak of Small et al. 2021, Eqs. 7–8).

Channels combine as in :func:`brdftab.channels.combine_layouts`: grey terms broadcast to the
others; RGB and spectral terms cannot be mixed. A combination is isotropic (reciprocal) when
every term is. ``sum`` and ``scale`` are polarized when every term is: their Mueller matrices
add (each term's converted to Mitsuba's basis first) and scale like f.

Reference: F. E. Nicodemus et al., NBS Monograph 160 (1977) — BRDFs of independent
scattering mechanisms add.
"""

from __future__ import annotations

import numpy as np

from .._jit import kernel
from ..brdf import HORIZON, Model
from ..channels import combine_layouts
from ..params import Param
from ._registry import register

__all__ = ["Sum", "Scale", "Average", "Rotated", "rotated_frame"]


@register
class Sum(Model):
    name = "sum"
    summary = "Sum of terms, f = Σ f_k."
    reference = "Nicodemus1977"
    params = (Param("terms", "brdfs", "The BRDFs to add ([[model.terms]] tables in a spec); a term's key, numbered "
                    "from 0, is terms.0.KEY, terms.1.KEY, … (brdftab fit --free; in a [sweep] model.terms.1.KEY).",
                    units=""),)

    def _setup(self, terms):
        self.terms = terms
        self.layout = combine_layouts([t.layout for t in terms], names=[f"terms[{i}]" for i in range(len(terms))])
        self.isotropic = all(t.isotropic for t in terms)
        self.reciprocal = all(t.reciprocal for t in terms)
        self.polarized = all(t.polarized for t in terms)
        self.mueller_reciprocal = all(_mueller_reciprocal(t) for t in terms)
        # a sum of energy-conserving terms may exceed 1: nothing is claimed

    @property
    def lobe_width(self):
        widths = [t.lobe_width for t in self.terms if t.lobe_width is not None]
        return min(widths) if widths else None

    @property
    def lobe_axes(self):
        # the narrowest term's lobe decides where the nodes must be
        terms = [t for t in self.terms if t.lobe_width is not None]
        return min(terms, key=lambda t: t.lobe_width).lobe_axes if terms else None

    def quadrature_parts(self):
        """The terms: each is integrated on a rule that follows its own lobe."""
        return list(self.terms)

    def _kernel(self, lam, n):
        runs = [t.kernel(lam, n) for t in self.terms]
        if any(r is None for r in runs):
            return None

        def evaluate(wi, wo, state, out, add):
            for k, run in enumerate(runs):  # in order, as the numpy sum adds them
                run(wi, wo, state, out, add or k > 0)
        return evaluate

    def _eval(self, wi, wo, lam, n):
        out = self.terms[0]._eval(wi, wo, lam, n)
        for t in self.terms[1:]:
            out = out + t._eval(wi, wo, lam, n)
        return out

    def _mueller(self, wi, wo, lam, n):
        out = self.terms[0]._mueller_in(wi, wo, lam, n, self.mueller_basis)
        for t in self.terms[1:]:
            out = out + t._mueller_in(wi, wo, lam, n, self.mueller_basis)
        return out


def _mueller_reciprocal(brdf) -> bool:
    """Declared polarized reciprocity (:attr:`~brdftab.brdf.BRDF.mueller_reciprocal`, else
    ``reciprocal``)."""
    return brdf.reciprocal if brdf.mueller_reciprocal is None else brdf.mueller_reciprocal


class _OneTerm(Model):
    """A combinator of one ``term``: its lobe is the term's (quadrature hints)."""

    @property
    def lobe_width(self):
        return self.term.lobe_width

    @property
    def lobe_axes(self):
        return self.term.lobe_axes


@register
class Scale(_OneTerm):
    name = "scale"
    summary = "A term multiplied by a per-channel or spectral factor, f = s · f_term."
    reference = "Nicodemus1977"
    params = (
        Param("factor", "channel", "Multiplier s (per channel or spectrum).", minimum=0.0),
        Param("term", "brdf", "The BRDF to scale ([model.term] table in a spec).", units=""),
    )

    def _setup(self, factor, term):
        self.factor = factor
        self.term = term
        self.layout = combine_layouts([factor.layout, term.layout], names=("factor", "term"))
        self.isotropic = term.isotropic
        self.reciprocal = term.reciprocal
        self.polarized = term.polarized
        self.mueller_basis = term.mueller_basis
        self.mueller_reciprocal = _mueller_reciprocal(term)
        self.energy_conserving = term.energy_conserving and bool(np.all(factor.values <= 1.0))

    def quadrature_parts(self):
        fn = getattr(self.term, "quadrature_parts", None)
        parts = fn() if callable(fn) else None
        if not parts:
            return None
        return [Scale(factor=self.factor, term=p) for p in parts]

    def _kernel(self, lam, n):
        run = self.term.kernel(lam, n)
        if run is None:
            return None
        from .._brdf_kernels import add_scaled, scale_rows

        s = np.ascontiguousarray(np.broadcast_to(np.asarray(self.factor.at(lam, n), float), (n,)))

        def evaluate(wi, wo, state, out, add):
            if add:  # the term's values are needed apart from what out holds
                part = np.zeros_like(out)
                run(wi, wo, state, part, False)
                add_scaled(state, out, part, s)
            else:
                run(wi, wo, state, out, False)
                scale_rows(state, out, s)
        return evaluate

    def _eval(self, wi, wo, lam, n):
        return self.term._eval(wi, wo, lam, n) * np.asarray(self.factor.at(lam, n))[None, :]

    def _mueller(self, wi, wo, lam, n):
        s = np.broadcast_to(np.asarray(self.factor.at(lam, n), float), (n,))
        return self.term._mueller(wi, wo, lam, n) * s[None, :, None, None]


@register
class Average(_OneTerm):
    name = "average"
    summary = "Mean of a term over rotations about the normal and/or over swapping wi and wo."
    reference = "Nicodemus1977"
    params = (
        Param("term", "brdf", "The BRDF to average ([model.term] table in a spec).", units=""),
        Param("rotations", "int", "Rotations about the normal, equally spaced (0: none).", default=0, minimum=0,
              maximum=3600),
        Param("swap", "bool", "Also average f(wi, wo) with f(wo, wi) (the reciprocal part).", default=False),
    )

    def _setup(self, term, rotations, swap):
        self.term = term
        self.rotations = rotations
        self.swap = swap
        self.layout = term.layout
        # n rotations give n-fold symmetry: isotropic as far as a tabulation at φh = 0 sees
        self.isotropic = term.isotropic or rotations > 1
        self.reciprocal = term.reciprocal or swap
        # the swapped half of a non-reciprocal term need not conserve energy
        self.energy_conserving = term.energy_conserving and (term.reciprocal or not swap)

    def _eval(self, wi, wo, lam, n):
        angles = 2.0 * np.pi * np.arange(self.rotations) / self.rotations if self.rotations > 1 else [0.0]
        acc = np.zeros((wi.shape[0], n))
        count = np.zeros((wi.shape[0], n))
        for a in angles:
            c, s = np.cos(a), np.sin(a)
            rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
            ri, ro = wi @ rot.T, wo @ rot.T
            for x, y in ((ri, ro), (ro, ri)) if self.swap else ((ri, ro),):
                f = self.term.eval(x, y, lam)
                ok = np.isfinite(f)  # a table's NaN (missing, outside) is left out of the mean
                acc += np.where(ok, f, 0.0)
                count += ok
        return np.where(count > 0, acc / np.maximum(count, 1), np.nan)


def rotated_frame(tilt: float, tilt_azimuth: float = 0.0, phi_ref: float = 0.0) -> np.ndarray:
    """The rotation R = Ry(−Δθ) · Rz(−Δφ0 − φ_ref) of Small et al. 2021, Eqs. 7a/7b: a
    direction w (macro frame) has coordinates R @ w in the frame of the tilted normal
    n2 = Rᵀ ẑ = (sinΔθ cos(Δφ0 + φ_ref), sinΔθ sin(Δφ0 + φ_ref), cosΔθ). Rotations are
    right-handed; Δφ0 and φ_ref are measured from +x towards +y."""
    a = -(tilt_azimuth + phi_ref)
    ca, sa = np.cos(a), np.sin(a)
    rz = np.array([[ca, -sa, 0.0], [sa, ca, 0.0], [0.0, 0.0, 1.0]])
    cb, sb = np.cos(-tilt), np.sin(-tilt)
    ry = np.array([[cb, 0.0, sb], [0.0, 1.0, 0.0], [-sb, 0.0, cb]])
    return ry @ rz


@register
class Rotated(_OneTerm):
    name = "rotated"
    summary = ("A term with its normal tilted by (tilt, tilt_azimuth) and the sample turned by phi_ref about the "
               "macro normal: f(wi, wo) = f_term(R wi, R wo), R = Ry(−Δθ) Rz(−Δφ0 − φref).")
    reference = "Small2021"
    params = (
        Param("term", "brdf", "The BRDF in the tilted frame ([model.term] table in a spec).", units=""),
        Param("tilt", "float", "Δθ: polar angle of the tilted normal from the macro normal.", units="rad",
              default=0.0, minimum=0.0, maximum=float(np.radians(89.0)), angle=True),
        Param("tilt_azimuth", "float", "Δφ0: azimuth of the tilt, from +x towards +y.", units="rad", default=0.0,
              minimum=float(-2 * np.pi), maximum=float(2 * np.pi), angle=True),
        Param("phi_ref", "float", "φ_ref: turn of the sample about the macro normal, from +x towards +y (added to "
              "the tilt azimuth).", units="rad", default=0.0, minimum=float(-2 * np.pi), maximum=float(2 * np.pi),
              angle=True),
    )

    def _setup(self, term, tilt, tilt_azimuth, phi_ref):
        """Directions above the macro surface but below the tilted one give 0 (the term is 0
        below its horizon); no projected-area factor is applied (as in Small et al. Eq. 8), so
        no energy conservation is claimed."""
        self.term = term
        self.tilt, self.tilt_azimuth, self.phi_ref = tilt, tilt_azimuth, phi_ref
        self.R = rotated_frame(tilt, tilt_azimuth, phi_ref)
        self.layout = term.layout
        self.isotropic = term.isotropic and tilt == 0.0
        self.reciprocal = term.reciprocal
        self.energy_conserving = False

    @property
    def normal(self) -> np.ndarray:
        """The tilted normal n2 in the macro frame."""
        return self.R[2].copy()

    @property
    def lobe_axes(self):
        return self.term.lobe_axes

    def lobe_frame(self, wi=None):
        """Quadrature hint: the term's lobe lives about the tilted normal (coordinates R @ w)."""
        return self.R

    def _kernel(self, lam, n):
        run = self.term.kernel(lam, n)
        if run is None:
            return None
        R = np.ascontiguousarray(self.R)

        def evaluate(wi, wo, state, out, add):
            m = wi.shape[0]
            size = min(m, ROTATE_BLOCK)
            ri, ro, st = np.empty((size, 3)), np.empty((size, 3)), np.empty(size, np.uint8)
            for lo in range(0, m, size):   # rotated copies of one block of rows at a time
                hi = min(lo + size, m)
                k = hi - lo
                _rotate_rows(wi[lo:hi], wo[lo:hi], state[lo:hi], R, ri[:k], ro[:k], st[:k], out[lo:hi], add,
                             HORIZON)
                run(ri[:k], ro[:k], st[:k], out[lo:hi], add)
        return evaluate

    def _eval(self, wi, wo, lam, n):
        return self.term.eval(_rotate(wi, self.R), _rotate(wo, self.R), lam, assume_unit=True)


def _rotate(w, R):
    """``w @ R.T`` for ``w[M, 3]``, written out (the compiled kernel's arithmetic, whatever BLAS does)."""
    out = np.empty_like(w)
    for k in range(3):
        out[:, k] = w[:, 0] * R[k, 0] + w[:, 1] * R[k, 1] + w[:, 2] * R[k, 2]
    return out


#: Rows a compiled :class:`Rotated` turns into its term's frame at once (bounded scratch memory).
ROTATE_BLOCK = 8192


@kernel
def _rotate_rows(wi, wo, state, R, ri, ro, st, out, add, horizon):
    """Directions of the evaluated rows in the term's frame (:func:`_rotate`) and their state
    there: evaluated when both are above the term's horizon, else f = 0 (written unless ``add``)."""
    nc = out.shape[1]
    for i in range(wi.shape[0]):
        st[i] = 0
        if state[i] != 1:
            continue
        for k in range(3):
            ri[i, k] = wi[i, 0] * R[k, 0] + wi[i, 1] * R[k, 1] + wi[i, 2] * R[k, 2]
            ro[i, k] = wo[i, 0] * R[k, 0] + wo[i, 1] * R[k, 1] + wo[i, 2] * R[k, 2]
        if ri[i, 2] > horizon and ro[i, 2] > horizon:
            st[i] = 1
        elif not add:
            for c in range(nc):
                out[i, c] = 0.0
