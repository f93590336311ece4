"""The BRDF protocol: anything that evaluates f(wi, wo, λ) vectorized, in sr⁻¹.

``brdf.eval(wi, wo, wavelengths=None)`` takes unit direction vectors ``wi``, ``wo`` of any
broadcastable leading shape (trailing axis 3; pointing away from the surface; normal +z) and
returns ``ndarray[..., n_channels]``. The result is 0 wherever either direction is at or below
the horizon (z <= ``HORIZON`` = 1e-12, so θ = 90° exactly counts as the horizon). One input
rule holds for every BRDF, model or table: directions are normalized on entry (a zero vector
is an error), and a non-finite component gives NaN, never 0. Analytic
models (:mod:`brdftab.models`) and tables (:class:`brdftab.table.Table`) are both
:class:`BRDF` objects.

Metadata every BRDF carries:

* ``name`` and ``parameters`` (JSON-able; angles in radians) — provenance of tables;
* ``channels`` (names) or, for spectral BRDFs, ``wavelengths`` [nm] (see
  :mod:`brdftab.channels`);
* ``isotropic`` (invariant under rotation about the normal) and ``reciprocal``
  (f(wi, wo) = f(wo, wi)) as *declared* by the model; :mod:`brdftab.checks` checks them;
* ``origin`` — where the values come from: ``"analytic"`` (a model, or a table of one),
  ``"measured"`` (data), or ``"unknown"`` (a file that does not say). Recorded with every table
  in the formats that can hold it and never re-derived from the values; the checks give
  measured and unknown data the measured-data defaults (no reciprocity assumed unless
  declared, negative samples reported, not refused).

Polarization (optional): a BRDF with ``polarized = True`` also evaluates its Mueller matrix,
``brdf.eval_mueller(wi, wo, wavelengths=None, basis="mitsuba")`` → ``ndarray[..., n_channels, 4, 4]``
in sr⁻¹ (without the cosine), in one of the Stokes bases of :mod:`brdftab.polarization` (Mitsuba's
by default). ``eval`` stays f_r,11, the unpolarized BRDF, and equals the Mueller matrix's element
(0, 0) (the model contract test checks both on every polarized model). The same input rules as
``eval`` hold: 0 at and below the horizon, NaN for non-finite directions.
"""

from __future__ import annotations

import contextlib

import numpy as np

from .channels import Layout
from .errors import ParameterError
from .geometry import as_directions, normalize
from .params import Kind, parse_params, register_kind
from .polarization import DEFAULT_BASIS, check_basis, convert_basis

__all__ = ["BRDF", "Model", "EVAL_CHUNK", "ORIGINS", "numpy_reference", "compiled_enabled"]

#: The values of :attr:`BRDF.origin`.
ORIGINS = ("analytic", "measured", "unknown")

#: Direction pairs evaluated at once by :meth:`BRDF.eval`.
EVAL_CHUNK = 1 << 16
#: Directions with z at or below this are on or below the horizon (f = 0). ``sph_to_vec(π/2, φ)``
#: has z ≈ 6e-17, not 0; without the margin a grazing node would be evaluated with cosθ ≈ 1e-17.
HORIZON = 1e-12


#: Whether :meth:`BRDF.eval` runs compiled kernels where a BRDF has them (see
#: :func:`numpy_reference`).
_COMPILED = [True]


@contextlib.contextmanager
def numpy_reference():
    """Evaluate every BRDF by its numpy code inside the block (not by its compiled kernel): the
    reference the parity tests and the benchmarks compare the kernels with."""
    _COMPILED.append(False)
    try:
        yield
    finally:
        _COMPILED.pop()


def compiled_enabled() -> bool:
    """False inside :func:`numpy_reference` (BRDFs with their own compiled evaluation check it)."""
    return _COMPILED[-1]



def _above_horizon(wi, wo, out, assume_unit):
    """``(wi, wo, rows)``: the ``(M, 3)`` directions normalized (unless ``assume_unit``: grid
    nodes, unit and finite by construction) and the rows of the pairs above the horizon, the
    rows of ``out`` whose pairs are not finite set to NaN (the rest stay 0: below the horizon)."""
    if assume_unit:
        return wi, wo, np.flatnonzero((wi[:, 2] > HORIZON) & (wo[:, 2] > HORIZON))
    wi = _unit(wi, "wi")
    wo = _unit(wo, "wo")
    finite = np.isfinite(wi).all(axis=1) & np.isfinite(wo).all(axis=1)
    out[~finite] = np.nan
    with np.errstate(invalid="ignore"):
        return wi, wo, np.flatnonzero(finite & (wi[:, 2] > HORIZON) & (wo[:, 2] > HORIZON))

def _unit(w, name):
    """Directions normalized on entry (exactly unit ones are left untouched); non-finite rows
    stay non-finite (they evaluate to NaN); a zero vector is an error."""
    with np.errstate(invalid="ignore", over="ignore", under="ignore"):
        norm = np.sqrt(np.einsum("ij,ij->i", w, w))
        off = np.abs(norm - 1.0) > 1e-12
    if not off.any():
        return w
    if np.any(np.max(np.abs(w[off]), axis=1) == 0):
        raise ParameterError(name, "a direction has zero length")
    w = w.copy()
    w[off] = normalize(w[off])  # scaled first: huge and tiny finite directions keep their direction
    return w


class BRDF:
    """Base class of everything that evaluates a BRDF. Subclasses implement :meth:`_eval`."""

    name: str = "brdf"
    layout: Layout = Layout()
    isotropic: bool = True
    reciprocal: bool = True
    #: "analytic", "measured" or "unknown" (see the module docstring).
    origin: str = "analytic"
    #: Declared: directional albedo ≤ 1 for every incident direction (checked by the contract
    #: test and the energy check). Off unless a model says so.
    energy_conserving: bool = False

    @property
    def lobe_width(self) -> float | None:
        """Angular width [rad, roughly] of the narrowest lobe, or None for smooth BRDFs; a hint
        for quadrature that must place nodes on peaked lobes."""
        return None

    @property
    def lobe_axes(self) -> tuple | None:
        """Widths of an anisotropic lobe along the surface's x and y axes (e.g. a microfacet's
        α_x, α_y), or None; lets quadrature follow elongated lobes."""
        return None

    @property
    def channels(self):
        """Channel names, or None for a spectral BRDF."""
        return self.layout.channels

    @property
    def wavelengths(self):
        """Default wavelengths [nm] of a spectral BRDF (None otherwise)."""
        return self.layout.wavelengths

    #: Pairs per evaluation call a caller should batch (None: :data:`EVAL_CHUNK`): set by BRDFs
    #: whose every call costs a pass over data on disk (a table over the memory budget).
    eval_batch = None

    @property
    def spectral(self) -> bool:
        return self.layout.spectral

    @property
    def parameters(self) -> dict:
        return {}

    def eval(self, wi, wo, wavelengths=None, *, assume_unit: bool = False) -> np.ndarray:
        """f(wi, wo) in sr⁻¹, shape ``broadcast(wi, wo).shape[:-1] + (n_channels,)``.

        ``wavelengths`` [nm] selects spectral evaluation (required for spectral BRDFs unless
        they carry default wavelengths; allowed for grey BRDFs, which broadcast). A BRDF with
        named channels (R, G, B) has no spectrum: wavelengths are refused with a
        :class:`~brdftab.errors.ParameterError`, for models and tables alike.
        ``assume_unit`` skips normalizing and the finiteness check, for callers whose
        directions are unit and finite by construction (grid nodes).
        """
        wi, wo = as_directions(wi, wo)
        lam = self.layout.resolve(wavelengths)
        n = self.layout.n_out(lam)
        lead = wi.shape[:-1]
        wi = wi.reshape(-1, 3)
        wo = wo.reshape(-1, 3)
        run = self.kernel(lam, n)
        if run is not None:
            return _eval_compiled(run, wi, wo, n, assume_unit).reshape(lead + (n,))
        out = np.zeros((wi.shape[0], n))
        wi, wo, above = _above_horizon(wi, wo, out, assume_unit)
        # Bounded chunks keep the temporaries of long evaluations to a few tens of MB (a BRDF
        # whose every call costs a pass over its data takes larger ones: eval_batch).
        step = self.eval_batch or EVAL_CHUNK
        with np.errstate(all="ignore"):
            for start in range(0, above.size, step):
                sel = above[start:start + step]
                if sel.size == wi.shape[0]:
                    sel = slice(None)
                out[sel] = self._eval(wi[sel], wo[sel], lam, n)
        return out.reshape(lead + (n,))

    #: Whether :meth:`eval_mueller` is available (a subclass that sets it implements :meth:`_mueller`).
    polarized: bool = False
    #: The basis :meth:`_mueller` returns its matrices in (one of :data:`brdftab.polarization.BASES`).
    mueller_basis: str = DEFAULT_BASIS
    #: Declared polarized reciprocity M(wi → wo) = Q·Mᵀ(wo → wi)·Q in matching frames
    #: (:func:`brdftab.polarization.reciprocity_transform`); None: as :attr:`reciprocal`.
    mueller_reciprocal: bool | None = None

    def eval_mueller(self, wi, wo, wavelengths=None, basis: str = DEFAULT_BASIS, *,
                     assume_unit: bool = False) -> np.ndarray:
        """The Mueller-matrix BRDF in sr⁻¹ (without the cosine), shape ``broadcast(wi, wo).shape[:-1]
        + (n_channels, 4, 4)``, in the Stokes ``basis`` (:data:`brdftab.polarization.BASES`; the
        incident beam propagates along −wi, the outgoing one along wo). Its element (0, 0) is
        :meth:`eval`. ``wavelengths`` and ``assume_unit`` as for :meth:`eval`. A BRDF that is not
        ``polarized`` raises a :class:`~brdftab.errors.ParameterError`."""
        check_basis(basis)
        if not self.polarized:
            raise ParameterError("eval_mueller", f"{self.describe()} is not polarized: it has no Mueller matrix, only "
                                 "f_r,11 (eval)")
        wi, wo = as_directions(wi, wo)
        lam = self.layout.resolve(wavelengths)
        n = self.layout.n_out(lam)
        lead = wi.shape[:-1]
        wi = wi.reshape(-1, 3)
        wo = wo.reshape(-1, 3)
        out = np.zeros((wi.shape[0], n, 4, 4))
        wi, wo, above = _above_horizon(wi, wo, out, assume_unit)
        step = max(1, (self.eval_batch or EVAL_CHUNK) // 16)
        with np.errstate(all="ignore"):
            for start in range(0, above.size, step):
                sel = above[start:start + step]
                out[sel] = self._mueller_in(wi[sel], wo[sel], lam, n, basis)
        return out.reshape(lead + (n, 4, 4))

    def _mueller_in(self, wi, wo, lam, n, basis) -> np.ndarray:
        """:meth:`_mueller` re-expressed in ``basis``: ``(M, n, 4, 4)``."""
        return convert_basis(self._mueller(wi, wo, lam, n), wi, wo, self.mueller_basis, basis)

    def _mueller(self, wi, wo, lam, n) -> np.ndarray:
        """The Mueller matrices at ``(M, 3)`` unit above-horizon pairs in :attr:`mueller_basis`:
        ``(M, n, 4, 4)`` (polarized BRDFs implement it)."""
        raise NotImplementedError

    def _eval(self, wi, wo, lam, n) -> np.ndarray:
        """Evaluate at ``(M, 3)`` above-horizon pairs; return ``(M, n)``.

        ``lam`` is None (channel mode) or the wavelengths [nm] (length n).
        """
        raise NotImplementedError

    def kernel(self, lam, n):
        """The compiled evaluation at wavelengths ``lam`` (None: channels) with ``n`` outputs, or
        None (numpy, :meth:`_eval`): a function ``run(wi, wo, state, out, add)`` that writes (or,
        with ``add``, adds) f of the pairs ``wi``, ``wo[M, 3]`` (unit, C-contiguous float64) into
        the rows of ``out[M, n]`` whose ``state`` is 1 (above the horizon; see
        :mod:`brdftab._brdf_kernels`), leaving the others as they are. Built once per (λ, n)
        by :meth:`_kernel`; None inside :func:`numpy_reference`."""
        if not _COMPILED[-1]:
            return None
        key = (None if lam is None else np.asarray(lam, float).tobytes(), n)
        cache = self.__dict__.setdefault("_kernels", {})
        if key not in cache:
            cache[key] = self._kernel(lam, n)
        return cache[key]

    def _kernel(self, lam, n):
        """Build :meth:`kernel`'s function (None: this BRDF has no compiled form)."""
        return None

    def __getstate__(self):
        # the compiled evaluations built by kernel() are closures: rebuilt after unpickling
        state = dict(self.__dict__)
        state.pop("_kernels", None)
        return state

    def tabulate_into(self, grid, lam, n, values, bar=None) -> bool:
        """Fill ``values[grid.shape + (n,)]`` with f at ``grid``'s nodes by a method that uses
        the grid's structure (e.g. a term that depends on θh alone evaluated once per θh node),
        updating the progress ``bar``; False (nothing written) when this BRDF has none for this
        grid, and :func:`brdftab.table.tabulate` evaluates pair by pair."""
        return False

    def describe(self) -> str:
        return f"{self.name}({', '.join(f'{k}={v!r}' for k, v in self.parameters.items())})"

    def __repr__(self):
        return self.describe()


def _eval_compiled(run, wi, wo, n, assume_unit):
    """:meth:`BRDF.eval` through a compiled ``run`` (one pass sorts the pairs, one evaluates;
    memory beyond the output: one byte per pair, plus normalized copies of directions that
    are not unit)."""
    from ._brdf_kernels import prepare
    from ._jit import parallel_rows

    wi = np.ascontiguousarray(wi)
    wo = np.ascontiguousarray(wo)
    m = wi.shape[0]
    out = np.zeros((m, n))
    state = np.empty(m, np.uint8)

    def sort(lo, hi):
        return prepare(wi[lo:hi], wo[lo:hi], state[lo:hi], out[lo:hi], assume_unit, HORIZON)

    if any(parallel_rows(sort, m)):
        wi = _unit(wi, "wi")
        wo = _unit(wo, "wo")
        parallel_rows(sort, m)

    def evaluate(lo, hi):
        run(wi[lo:hi], wo[lo:hi], state[lo:hi], out[lo:hi], False)

    parallel_rows(evaluate, m)
    return out


class Model(BRDF):
    """An analytic model with declared parameters (:class:`~brdftab.params.Param`).

    Subclasses set ``name``, ``summary``, ``reference`` and ``params`` and implement
    :meth:`_setup` (called with the validated values) and :meth:`_eval`.
    """

    summary: str = ""
    reference: str = ""
    params: tuple = ()

    def __init__(self, **params):
        values = parse_params(self.params, params, self.name)
        self._values = values
        self._setup(**values)

    def _setup(self, **values):
        raise NotImplementedError

    @property
    def parameters(self) -> dict:
        out = {}
        for p in self.params:
            v = self._values[p.name]
            if v is not None:
                out[p.name] = p.to_json(v)
        return out


def _brdf_json(v):
    return {"model": v.name, "parameters": v.parameters}


class _BRDFKind(Kind):
    name = "brdf"

    def expected(self, p):
        return "a model"

    def convert(self, p, value):
        if not isinstance(value, BRDF):
            raise ParameterError(p.name, f"expected {self.expected(p)}, got {type(value).__name__}")
        return value

    def to_json(self, value):
        return _brdf_json(value)


class _BRDFsKind(Kind):
    name = "brdfs"

    def expected(self, p):
        return "a non-empty list of models"

    def convert(self, p, value):
        if not isinstance(value, (list, tuple)) or not value or not all(isinstance(v, BRDF) for v in value):
            raise ParameterError(p.name, f"expected {self.expected(p)}")
        return tuple(value)

    def to_json(self, value):
        return [_brdf_json(v) for v in value]


register_kind(_BRDFKind())
register_kind(_BRDFsKind())
