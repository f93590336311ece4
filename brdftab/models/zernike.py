"""Zernike-polynomial BRDF expansion (SCATMECH ``ZernikeExpansion_BRDF_Model``): f_r,11 and the Mueller matrix.

Koenderink and van Doorn [Koenderink1998] expand a reciprocal, isotropic BRDF in products of
Zernike polynomials on the Lambert azimuthal equal-area map of the hemisphere onto the unit
disk, ρ = √2 sin(θ/2). Germer [Germer2017] fitted the full Mueller-matrix BRDF of sintered PTFE
with this basis; SCATMECH [SCATMECH2021] evaluates it from a coefficient file. ``eval`` is
the unpolarized element (``zernikeexpansion.cpp``, ``mueller()``)::

    f_r,11 = r(λ) Σ_rows a λ^p (1/2π) [(n+1)(m+1)/A]^½ [R_n^l(ρi) R_m^l(ρr) + R_m^l(ρi) R_n^l(ρr)] cos(l Δφ)

over the rows of the file with i = j = 1, where

* R_n^l is the radial Zernike polynomial (R_n^l(1) = 1; 0 when n − |l| is odd or |l| > n);
* A = 4 if n = 0 or (n = m and l = 0), else 2 if n = m or l = 0, else 1 — evaluated, as in
  SCATMECH, on the file's n (column 3);
* λ is the wavelength in µm and λ^p is a true power (SCATMECH's code computes λ² for p = 3,
  a bug not reproduced here; Germer's files only use p ∈ {0, 1});
* r(λ) is the parameter ``scale`` (SCATMECH's name; "usually the diffuse reflectance");
* **azimuth convention**: SCATMECH sets φi = π − rotation and φr = φs − rotation, so
  Δφ = φr − φi = φs − π with SCATMECH's φs = 0 on the specular (forward) side. In brdftab's
  convention (wi and wo both point away from the surface, azimuths φ_wi, φ_wo, mirror direction
  at φ_wo = φ_wi + π) φs = φ_wo − φ_wi − π, so Δφ = φ_wo − φ_wi − 2π ≡ φ_wo − φ_wi: cos(l Δφ)
  is computed from the angle between the projections of wi and wo on the surface (backscatter
  at Δφ = 0, specular at Δφ = π). Using φs itself for Δφ flips every odd-l term.

Coefficient file
----------------
Eight comma- or whitespace-separated columns per line, ``i, j, n, m, k, l, p, a`` (Mueller
indices, radial orders, azimuthal orders, power of λ, coefficient); blank lines are skipped and
``;`` starts a comment, as in SCATMECH's reader. For the 11 rows the code uses **column 6 (l)**
as the azimuthal order of both radial orders and of cos(lΔφ), and ignores column 5; for the
other rows (the polarized elements, see below) column 5 goes
with column 3 and column 6 with column 4. Each line is checked; a bad line (wrong column count,
a non-numeric or non-integer field, a non-finite coefficient, i or j outside 1…4, i > j, a
negative radial order, an order n, m, k or l above 100 in magnitude (:data:`MAX_ORDER`; Germer's
files use up to 7), a power p of the wavelength beyond ±16 (:data:`MAX_POWER`), or an odd n − l /
m − l (11 rows) or n − k / m − l (other rows), which makes the term identically zero) is one
error naming the file and the line. Evaluation holds the radial and azimuthal factors of a
bounded number of direction pairs at a time (:data:`EXPANSION_BYTES`), so memory does not grow
with the number of rows or the orders. |l| > n is allowed:
Germer's ``PTFE.coeff.csv`` has 60 such off-diagonal rows, whose R_n^l is 0 in SCATMECH too.

Full Mueller matrix
-------------------
The model is polarized: ``eval_mueller`` gives the whole matrix from the file's other rows, as
SCATMECH's ``mueller()`` builds it, in SCATMECH's ``xyxy`` basis (:mod:`brdftab.polarization`;
converted to any other on request). With K_n^k(ρ, φ) = R_n^|k|(ρ) az_k(φ), az_k = cos kφ (k > 0),
sin |k|φ (k < 0), 1/√2 (k = 0), and c = a λ^p √((n+1)(m+1)) / π per row (columns 3–6: n, m, k, l):

* diagonal rows (i = j > 1): m_ii += c [K_n^k(i) K_m^l(r) + K_m^l(i) K_n^k(r)] / √(2 + 2 δ_nm δ_kl)
  — written out as SCATMECH has it: R_n^k(ρi) R_m^l(ρr) az_k(φi) az_l(φr) + R_m^l(ρi) R_n^k(ρr)
  az_k(φr) az_l(φi);
* off-diagonal rows (i < j): m_ij += c R_n^k(ρi) R_m^l(ρr) az_k(φi) az_l(φr) and
  m_ji += c R_n^k(ρr) R_m^l(ρi) az_k(φr) az_l(φi);

then m_11 = 1, m_31, m_32 and m_43 change sign, and M = f_r,11 · m (so M00 is ``eval``, clamped
as it is). The polarized terms depend on φi and φr apart, not only on their difference, so the
azimuth frame is a parameter, ``frame``:

* ``"incidence"`` (default): every pair is evaluated as Germer measured, in its own plane of
  incidence with SCATMECH's rotation 0 — φi = π, φr = φs (SCATMECH's scattering azimuth, 0 on the
  specular side) — in the ``xyxy`` basis of that plane. Isotropic by construction; the polarized
  reciprocity M(wi → wo) = Q·Mᵀ(wo → wi)·Q then holds only for f_r,11: PTFE.coeff.csv departs
  from it by up to 0.06·M00 (``mueller_reciprocal`` is False).
* ``"sample"``: fixed sample axes (brdftab's x, y): φi, φr the azimuths of wi and wo, the ``xyxy``
  basis built on x̂. Germer's construction (m_ji from m_ij with i ↔ r, the three sign changes) is
  then exactly reciprocal (to 1e-13 in Mitsuba's basis), but the polarized elements change when
  the pair turns about the normal (by up to 0.5·M00 for PTFE.coeff.csv), so it is not isotropic.

The two agree at Germer's geometries (source at azimuth 180°). Germer's ``PTFE.coeff.csv`` at
532 nm reproduces his measured normalized elements at 532 nm (``PTFE.data.csv``, 1824 geometries,
``basis="xyxy"``) to an rms of 0.011 per element at most (m42), and his data at 351, 633 and
1064 nm to 0.018, 0.013 and 0.017; its coherency eigenvalues are all
≥ 0.03·M00 (realizable) and its median depolarization index is 0.04 (tests/test_polarization.py).

Wavelength
----------
The model is grey (one channel, ``mono``) but depends on λ through λ^p and ``scale``:
``eval(wi, wo)`` evaluates at ``wavelength_nm``; ``eval(wi, wo, wavelengths=[...])`` once per
requested wavelength. A wavelength outside the coefficients' fitted range
[``fit_min_nm``, ``fit_max_nm``] (Germer's files: 351–1064 nm, the defaults) gives one
:class:`~brdftab.errors.BrdftabWarning` per wavelength.

Negative values: clamped
------------------------
A truncated expansion can go negative: Germer's ``PTFE.coeff.csv`` at 1064 nm reaches
−0.22 sr⁻¹ near grazing. A BRDF cannot be negative, and brdftab's tables must not be, so this
model returns max(expansion, 0). It reports the clamping twice: once per wavelength, a
:class:`~brdftab.errors.BrdftabWarning` from a scan of (θi, θr, Δφ) giving how many scanned pairs
are negative and the lowest value; and in the counters ``clamped`` / ``evaluated`` (values
clamped / values evaluated by this instance). :meth:`ZernikeExpansion.expansion` returns the
unclamped sum, as SCATMECH does. Clamping keeps the model reciprocal and isotropic.

Compiled evaluation
-------------------
``eval`` and :meth:`ZernikeExpansion.expansion` run one compiled loop (:func:`_expansion_rows`)
over blocks of pairs: per block, every radial polynomial the terms need by the Jacobi
recurrence (:func:`jacobi_next`, ρ^l carried along), cos(lΔφ) by the Chebyshev recurrence,
then the terms in the order of the numpy code (``_expansion``, the reference inside
:func:`brdftab.brdf.numpy_reference`), with the coefficients of each wavelength summed over p
once per wavelength. The two agree to 1e-12 relative, the clamping and the counters exactly
(tests/test_kernels.py), and ``eval`` is max(``expansion``, 0) bit for bit.

Accuracy against measurement
----------------------------
With Germer's ``PTFE.coeff.csv`` (scale 1) at 532 nm, against his measured f_r,11 at 532 nm
(``PTFE.data.csv``, 1824 directions, θi = 0…75°), the rms log error is 2.2 % (median ratio model /
measured 1.019); the same comparison with the source azimuth taken as 0° instead of 180° (the
convention error) gives 11.5 %. The directional albedo is 0.9999 / 1.0024 / 1.0063 at θi = 0° /
30° / 60° (tests/test_zernike.py measures all of these).
"""

from __future__ import annotations

import hashlib
import math
import os
import re
import threading
import warnings
from pathlib import Path

import numpy as np
from scipy.special import eval_jacobi

from .._jit import device, kernel
from ..brdf import _COMPILED, Model
from ..channels import Layout
from ..errors import BrdftabWarning, ParameterError
from ..geometry import as_directions
from ..params import Kind, Param, register_kind
from ._registry import register

__all__ = ["ZernikeExpansion", "ZernikeCoefficients", "radial_zernike", "CoefficientFileKind"]

#: Column names of a coefficient file, in order.
COLUMNS = ("i", "j", "n", "m", "k", "l", "p", "a")
_SEP = re.compile(r"[\s,]+")
_INT = re.compile(r"^[+-]?[0-9]+$")


def radial_zernike(n: int, l: int, rho) -> np.ndarray:
    """Radial Zernike polynomial R_n^l(ρ) (R_n^l(1) = 1), 0 when n − |l| is odd or |l| > n.

    Evaluated as (−1)^s ρ^|l| P_s^(|l|, 0)(1 − 2ρ²), s = (n − |l|)/2 (a Jacobi polynomial,
    stable for any order) — the same polynomial as SCATMECH's factorial sum.
    """
    rho = np.asarray(rho, float)
    l = abs(int(l))
    n = int(n)
    if n < l or (n - l) % 2:
        return np.zeros_like(rho)
    s = (n - l) // 2
    return (-1.0) ** s * rho ** l * eval_jacobi(s, l, 0.0, 1.0 - 2.0 * rho * rho)


@device
def jacobi_next(n, l, x, p1, p2):
    """P_n^(l, 0)(x) from P_{n−1} = ``p1`` and P_{n−2} = ``p2`` (n ≥ 2): the three-term recurrence
    2n(n+l)(2n+l−2) P_n = (2n+l−1)[(2n+l)(2n+l−2)x + l²] P_{n−1} − 2(n+l−1)(n−1)(2n+l) P_{n−2}
    (P_0 = 1, P_1 = ((l+2)x + l)/2): the scalar form of :func:`radial_zernike`'s Jacobi polynomial."""
    t = 2.0 * n + l
    return ((t - 1.0) * ((t * (t - 2.0)) * x + l * l) * p1 - 2.0 * (n + l - 1.0) * (n - 1.0) * t * p2) / (
        2.0 * n * (n + l) * (t - 2.0))


def _a_factor(n: int, m: int, l: int) -> float:
    """SCATMECH's A_nm^l: 4 if n = 0 or (n = m and l = 0), 2 if n = m or l = 0, else 1."""
    if n == 0 or (n == m and l == 0):
        return 4.0
    if n == m or l == 0:
        return 2.0
    return 1.0


class ZernikeCoefficients:
    """A parsed coefficient file: ``rows`` (int ``[N, 7]``: i, j, n, m, k, l, p), ``a`` ``[N]``,
    the source ``lines`` (1-based), the absolute ``path`` and its ``sha256``."""

    def __init__(self, path: Path, rows: np.ndarray, a: np.ndarray, lines: np.ndarray, sha256: str):
        self.path = path
        self.rows = rows
        self.a = a
        self.lines = lines
        self.sha256 = sha256
        i, j, n, m, _k, l, p = rows.T
        u = (i == 1) & (j == 1)
        self._n, self._m, self._l, self._p = n[u], m[u], np.abs(l[u]), p[u]
        self._a11 = a[u]
        self._pre = np.array([0.5 / np.pi * math.sqrt((nn + 1.0) * (mm + 1.0) / _a_factor(nn, mm, ll))
                              for nn, mm, ll in zip(self._n, self._m, l[u])])
        # rows with the same (n, m, |l|) differ only in p: one term per key at a given λ
        keys = np.stack([self._n, self._m, self._l], axis=1)
        self._keys, self._key_of_row = np.unique(keys, axis=0, return_inverse=True)
        self._key_of_row = self._key_of_row.ravel()

    @property
    def name(self) -> str:
        return self.path.name

    @property
    def n_f11(self) -> int:
        """Rows of the unpolarized element (i = j = 1)."""
        return int(self._a11.size)

    @classmethod
    def load(cls, path, sha256: str | None = None) -> "ZernikeCoefficients":
        """Read and check a coefficient file; errors are :class:`ParameterError` naming the
        file (as given) and the line."""
        shown = str(path)
        try:
            data = Path(path).read_bytes()
        except FileNotFoundError:
            raise ParameterError("coefficients", f"{shown}: no such coefficient file") from None
        except IsADirectoryError:
            raise ParameterError("coefficients", f"{shown}: is a folder, not a coefficient file") from None
        except OSError as exc:
            raise ParameterError("coefficients", f"{shown}: cannot read ({exc.strerror})") from None
        digest = hashlib.sha256(data).hexdigest()
        if sha256 is not None and sha256.lower() != digest:
            raise ParameterError("coefficients", f"{shown}: content changed (sha256 {digest[:12]}…, expected "
                                 f"{sha256[:12]}…)")
        try:
            text = data.decode("utf-8-sig")
        except UnicodeDecodeError:
            raise ParameterError("coefficients", f"{shown}: not a UTF-8 text coefficient file") from None
        rows, coef, lines = [], [], []
        for no, raw in enumerate(text.splitlines(), start=1):
            body = raw.split(";", 1)[0].strip()
            if not body:
                continue
            ints, a = _parse_line(body, lambda msg, no=no: ParameterError("coefficients", f"{shown}, line {no}: {msg}"))
            rows.append(ints)
            coef.append(a)
            lines.append(no)
        if not rows or not any(r[0] == 1 and r[1] == 1 for r in rows):
            raise ParameterError("coefficients", f"{shown}: no rows for the unpolarized element (i = j = 1), "
                                 "so f_r,11 would be 0")
        return cls(Path(os.path.abspath(path)), np.array(rows, dtype=np.int64).reshape(-1, 7),
                   np.array(coef, float), np.array(lines), digest)

    def f11_terms(self, lam_um: float):
        """``(keys[K, 3], c[K])``: the 11 terms at wavelength ``lam_um`` [µm], one per (n, m, |l|),
        with c = Σ_p a λ^p (1/2π) [(n+1)(m+1)/A]^½."""
        lam_pow = np.array([float(lam_um) ** int(p) for p in self._p])  # a true power (no p = 3 bug)
        c = np.zeros(len(self._keys))
        np.add.at(c, self._key_of_row, self._a11 * lam_pow * self._pre)
        return self._keys, c

    def normalized_mueller(self, rho_i, rho_r, phi_i, phi_r, lam_um: float) -> np.ndarray:
        """SCATMECH's normalized Mueller matrix ``[M, 4, 4]`` (m_11 = 1, the sign changes of m_31,
        m_32, m_43 applied; see the module docstring) from every row but the 11 ones, at
        ``ρi, ρr`` and SCATMECH's azimuths ``φi, φr`` ``[M]`` [rad], wavelength ``lam_um`` [µm]."""
        out = np.zeros(np.shape(rho_i) + (4, 4))
        radial = {}

        def R(order, az, rho, key):
            got = radial.get((order, abs(az), key))
            if got is None:
                got = radial[(order, abs(az), key)] = radial_zernike(order, az, rho)
            return got

        def az(k, phi):
            return np.cos(k * phi) if k > 0 else (np.sin(-k * phi) if k < 0 else np.full(np.shape(phi), 0.5 ** 0.5))

        terms = {}
        for (i, j, n, m, k, l, p), a in zip(self.rows.tolist(), self.a):
            if i == 1 and j == 1:
                continue
            terms[(i, j, n, m, k, l)] = terms.get((i, j, n, m, k, l), 0.0) + a * float(lam_um) ** p
        for (i, j, n, m, k, l), a in terms.items():
            c = a * math.sqrt((n + 1.0) * (m + 1.0)) / math.pi
            if i == j:
                c /= math.sqrt(2.0 + 2.0 * (n == m and k == l))
                out[:, i - 1, j - 1] += c * (R(n, k, rho_i, 0) * R(m, l, rho_r, 1) * az(k, phi_i) * az(l, phi_r)
                                             + R(m, l, rho_i, 0) * R(n, k, rho_r, 1) * az(k, phi_r) * az(l, phi_i))
            else:
                out[:, i - 1, j - 1] += c * R(n, k, rho_i, 0) * R(m, l, rho_r, 1) * az(k, phi_i) * az(l, phi_r)
                out[:, j - 1, i - 1] += c * R(n, k, rho_r, 1) * R(m, l, rho_i, 0) * az(k, phi_r) * az(l, phi_i)
        out[:, 0, 0] = 1.0
        out[:, 2, 0] *= -1.0
        out[:, 2, 1] *= -1.0
        out[:, 3, 2] *= -1.0
        return out

    def to_json(self):
        return {"path": str(self.path), "sha256": self.sha256}

    def __repr__(self):
        return f"ZernikeCoefficients({str(self.path)!r}, {len(self.a)} rows, {self.n_f11} for f_r,11)"


@kernel
def _expansion_rows(wi, wo, state, out, add, clamp, offset, smax, qn, qm, kl, coef, scale, block):
    """The compiled :meth:`ZernikeExpansion._eval`: writes (``add``: adds) max(f_r,11, 0) per
    wavelength (f_r,11 itself unless ``clamp``) into the rows of ``out`` whose ``state`` is 1
    and returns (values clamped, values evaluated). Pairs go in blocks of ``block``: per block the radial polynomials
    R_{l+2s}^l(ρ) = (−1)^s ρ^l P_s^(l,0)(1 − 2ρ²) of every (l, s) (row ``offset[l] + s``, s ≤
    ``smax[l]``; the last row is 0, for terms with n < l), cos(lΔφ) by the Chebyshev
    recurrence, then the terms ``coef[λ, k]`` of radial rows ``qn[k]``, ``qm[k]`` and azimuthal
    order ``kl[k]`` in the order of the numpy code, each loop over the pairs of the block."""
    m = wi.shape[0]
    nc = out.shape[1]
    lmax = offset.size - 1
    rows = offset[lmax] + smax[lmax] + 2
    ri = np.zeros((rows, block))
    ro = np.zeros((rows, block))
    cheb = np.empty((lmax + 1, block))
    rho_i = np.empty(block)
    rho_o = np.empty(block)
    xi = np.empty(block)
    xo = np.empty(block)
    pw_i = np.empty(block)
    pw_o = np.empty(block)
    total = np.empty(block)
    clamped = 0
    evaluated = 0
    for b0 in range(0, m, block):
        size = min(block, m - b0)
        for j in range(size):
            i = b0 + j
            si = math.hypot(wi[i, 0], wi[i, 1])
            so = math.hypot(wo[i, 0], wo[i, 1])
            # ρ = √2 sin(θ/2) = sinθ / √(1 + cosθ)
            rho_i[j] = si / math.sqrt(1.0 + wi[i, 2])
            rho_o[j] = so / math.sqrt(1.0 + wo[i, 2])
            xi[j] = 1.0 - 2.0 * rho_i[j] * rho_i[j]
            xo[j] = 1.0 - 2.0 * rho_o[j] * rho_o[j]
            pw_i[j] = 1.0
            pw_o[j] = 1.0
            den = si * so
            c = (wi[i, 0] * wo[i, 0] + wi[i, 1] * wo[i, 1]) / den if den > 0 else 1.0
            c = min(max(c, -1.0), 1.0)
            cheb[0, j] = 1.0
            if lmax > 0:
                cheb[1, j] = c
        for l in range(2, lmax + 1):
            for j in range(size):
                cheb[l, j] = 2.0 * cheb[1, j] * cheb[l - 1, j] - cheb[l - 2, j]
        for l in range(lmax + 1):
            if l > 0:
                for j in range(size):
                    pw_i[j] *= rho_i[j]
                    pw_o[j] *= rho_o[j]
            q = offset[l]
            if smax[l] < 0:
                continue
            for j in range(size):
                ri[q, j] = pw_i[j]
                ro[q, j] = pw_o[j]
            if smax[l] >= 1:
                for j in range(size):  # P_1 = ((l+2)x + l)/2, sign (−1)^1
                    ri[q + 1, j] = -pw_i[j] * (0.5 * ((l + 2.0) * xi[j] + l))
                    ro[q + 1, j] = -pw_o[j] * (0.5 * ((l + 2.0) * xo[j] + l))
            for s in range(2, smax[l] + 1):
                sign = 1.0 if s % 2 == 0 else -1.0
                for j in range(size):  # the rows hold ±ρ^l P: undo and redo the sign
                    pi1 = -ri[q + s - 1, j] * sign
                    pi2 = ri[q + s - 2, j] * sign
                    po1 = -ro[q + s - 1, j] * sign
                    po2 = ro[q + s - 2, j] * sign
                    ri[q + s, j] = sign * jacobi_next(s, l, xi[j], pi1, pi2)
                    ro[q + s, j] = sign * jacobi_next(s, l, xo[j], po1, po2)
        for col in range(nc):
            for j in range(size):
                total[j] = 0.0
            for k in range(qn.size):
                a = coef[col, k]
                if a == 0.0:
                    continue
                n_, m_, l = qn[k], qm[k], kl[k]
                for j in range(size):
                    # the symmetrized product: each term, hence the sum, is exactly reciprocal
                    total[j] += a * (ri[n_, j] * ro[m_, j] + ri[m_, j] * ro[n_, j]) * cheb[l, j]
            sc = scale[col]
            for j in range(size):
                i = b0 + j
                if state[i] == 1:
                    v = sc * total[j]
                    evaluated += 1
                    if clamp and v < 0:
                        v = 0.0
                        clamped += 1
                    out[i, col] = out[i, col] + v if add else v
    return clamped, evaluated


def _parse_line(body: str, err):
    fields = [t for t in _SEP.split(body) if t]
    if len(fields) != 8:
        raise err(f"expected 8 columns ({', '.join(COLUMNS)}), got {len(fields)}")
    ints = []
    for name, tok in zip(COLUMNS[:7], fields[:7]):
        if not _INT.match(tok):
            raise err(f"column {COLUMNS.index(name) + 1} ({name}) must be a whole number, got {tok!r}")
        ints.append(int(tok))
    try:
        a = float(fields[7])
    except ValueError:
        raise err(f"column 8 (a) must be a number, got {fields[7]!r}") from None
    if not math.isfinite(a):
        raise err(f"column 8 (a) must be finite, got {fields[7]!r}")
    i, j, n, m, k, l, p = ints
    big = [f"{c} = {_short(v)}" for c, v in zip("nmkl", (n, m, k, l)) if abs(v) > MAX_ORDER]
    if big:
        raise err(f"orders above {MAX_ORDER} are not supported ({', '.join(big)}; the fitted files use orders "
                  "up to about 10)")
    if abs(p) > MAX_POWER:
        raise err(f"power of the wavelength p must lie in -{MAX_POWER}..{MAX_POWER}, got {_short(p)}")
    if not (1 <= i <= 4 and 1 <= j <= 4):
        raise err(f"Mueller indices i, j must be 1 to 4, got i = {_short(i)}, j = {_short(j)}")
    if i > j:
        raise err(f"i > j (i = {i}, j = {j}): the file lists each pair once with i <= j")
    if n < 0 or m < 0:
        raise err(f"radial orders n, m (columns 3, 4) must be >= 0, got n = {n}, m = {m}")
    if i == 1 and j == 1:  # column 6 is the azimuthal order of both radial orders
        pairs = (("n", n, "l", l), ("m", m, "l", l))
    else:  # column 5 goes with column 3, column 6 with column 4
        pairs = (("n", n, "k", k), ("m", m, "l", l))
    for rn, rv, an, av in pairs:
        if (rv - av) % 2:
            role = "the 11 rows use column 6 (l) for both radial orders" if (i, j) == (1, 1) else \
                   "rows other than 11 pair column 5 (k) with n and column 6 (l) with m"
            raise err(f"{rn} - {an} = {rv} - {av} is odd, so the term is identically zero ({role})")
    return ints, a


def _short(v: int) -> str:
    text = str(v)
    return text if len(text) <= 20 else f"{text[:8]}... ({len(text.lstrip('-'))} digits)"


class CoefficientFileKind(Kind):
    """A Zernike coefficient file: a path (relative to the current folder from Python, to the
    spec's folder in a spec file), ``{path, sha256}`` (as provenance records it), or a loaded
    :class:`ZernikeCoefficients`."""

    name = "zernike-coefficients"

    def expected(self, p):
        return "the path of a coefficient file (8 columns i, j, n, m, k, l, p, a)"

    def convert(self, p, value):
        if isinstance(value, ZernikeCoefficients):
            return value
        sha = None
        if isinstance(value, dict):
            extra = set(value) - {"path", "sha256"}
            if extra or "path" not in value or not isinstance(value.get("sha256", ""), str):
                raise ParameterError(p.name, f"expected {self.expected(p)} or {{path, sha256}}")
            value, sha = value["path"], value.get("sha256")
        if isinstance(value, os.PathLike):
            value = os.fspath(value)
        if not isinstance(value, str) or not value or "\x00" in value:
            raise ParameterError(p.name, f"expected {self.expected(p)}, got {value!r}")
        try:
            return ZernikeCoefficients.load(value, sha)
        except ParameterError as exc:
            raise ParameterError(p.name, exc.detail) from None

    def from_spec(self, p, value, folder: Path):
        """A spec's relative path resolves against the spec's folder."""
        if isinstance(value, str) and value and not Path(value).is_absolute():
            return str(folder / value)
        if isinstance(value, dict) and isinstance(value.get("path"), str) and not Path(value["path"]).is_absolute():
            return {**value, "path": str(folder / value["path"])}
        return value

    def to_json(self, value):
        return value.to_json()


register_kind(CoefficientFileKind())

#: Largest radial order (n, m) and azimuthal order (k, l) a coefficient file may use, and the
#: largest |p| (power of the wavelength in µm). Germer's PTFE files use orders up to 7 and
#: p ∈ {0, 1}; order 100 resolves features of about 1° on the hemisphere.
MAX_ORDER = 100
MAX_POWER = 16
#: Bytes of radial-polynomial and cos(lΔφ) tables held at once while evaluating.
EXPANSION_BYTES = 64 << 20

#: Guards the counters ``clamped`` / ``evaluated``, which the compiled evaluation updates from
#: several threads.
_COUNTS = threading.Lock()

#: The negativity scan: θi, θr [deg] and Δφ [deg] (Δφ ↔ −Δφ is a symmetry of f_r,11).
_SCAN_THETA = np.concatenate([np.arange(0.0, 89.0, 1.5), [89.0, 89.5, 89.9]])
_SCAN_DPHI = np.linspace(0.0, 180.0, 25)


@register
class ZernikeExpansion(Model):
    """SCATMECH's ZernikeExpansion_BRDF_Model: f_r,11 and the Mueller matrix (see the module docstring)."""

    name = "zernike-expansion"
    summary = ("Zernike-polynomial expansion of a reciprocal isotropic BRDF from a coefficient file "
               "(SCATMECH ZernikeExpansion_BRDF_Model, f_r,11 and the Mueller matrix; Germer's sintered PTFE).")
    reference = "Koenderink1998; Germer2017; SCATMECH2021"
    params = (
        Param("coefficients", "zernike-coefficients",
              "Coefficient file, 8 columns i, j, n, m, k, l, p, a (SCATMECH layout; λ in µm). In a spec, "
              "relative to the spec's folder."),
        Param("wavelength_nm", "float", "Wavelength evaluated when no wavelengths are requested.", units="nm",
              default=532.0, minimum=0.0, exclusive_minimum=True),
        Param("scale", "channel", "r(λ): factor of the whole expansion (SCATMECH 'scale'); a number or a "
              "spectrum {wavelengths_nm, values}.", default=1.0, minimum=0.0),
        Param("fit_min_nm", "float", "Shortest wavelength the coefficients were fitted at (warning below).",
              units="nm", default=351.0, minimum=0.0, exclusive_minimum=True),
        Param("fit_max_nm", "float", "Longest wavelength the coefficients were fitted at (warning above).",
              units="nm", default=1064.0, minimum=0.0, exclusive_minimum=True),
        Param("frame", "choice", "Azimuth frame of the polarized elements: 'incidence' (each pair in its plane "
              "of incidence, as measured: isotropic) or 'sample' (fixed sample axes x, y: exactly reciprocal, "
              "not isotropic). f_r,11 is the same in both.", default="incidence", choices=("incidence", "sample")),
    )
    isotropic = True
    reciprocal = True
    #: A fitted expansion does not guarantee albedo <= 1 (PTFE.coeff.csv: ~1.005 at 30°).
    energy_conserving = False

    def _setup(self, coefficients, wavelength_nm, scale, fit_min_nm, fit_max_nm, frame):
        if scale.kind == "channels":
            raise ParameterError("scale", "expected one number or a spectrum {wavelengths_nm, values}: the "
                                 f"model is grey, got {scale.values.size} channel values")
        if fit_min_nm > fit_max_nm:
            raise ParameterError("fit_min_nm", f"must not exceed fit_max_nm ({fit_min_nm:g} > {fit_max_nm:g})")
        self.coefficients = coefficients
        self.frame = frame
        # the polarized elements' azimuth frame (module docstring): native xyxy in the plane of
        # incidence; on the sample's axes the matrix is converted to Mitsuba's basis at once
        self.mueller_basis = "xyxy" if frame == "incidence" else "mitsuba"
        self.isotropic = frame == "incidence"
        self.mueller_reciprocal = frame == "sample"
        self.wavelength_nm = wavelength_nm
        self.scale = scale
        self.fit_range_nm = (fit_min_nm, fit_max_nm)
        self.layout = Layout()
        self.input_files = (coefficients.path,)
        #: Values clamped to 0 (negative expansion) and values evaluated, by this instance.
        self.clamped = 0
        self.evaluated = 0
        self._terms = {}
        self._checked = set()
        self._scale_at(np.array([wavelength_nm]))  # a spectral scale must cover wavelength_nm
        self._check_wavelengths([wavelength_nm])

    # -- per-wavelength data -------------------------------------------------------------

    def _scale_at(self, lam_nm):
        if self.scale.kind == "spectral":
            return self.scale.at(lam_nm, lam_nm.size)
        return np.full(lam_nm.size, float(self.scale.values[0]))

    def _f11_terms(self, lam_nm: float):
        t = self._terms.get(lam_nm)
        if t is None:
            if len(self._terms) > 64:
                self._terms.clear()
            t = self._terms[lam_nm] = self.coefficients.f11_terms(lam_nm / 1000.0)
        return t

    def _check_wavelengths(self, lam_nm):
        """Warn once per wavelength: outside the fitted range; expansion negative somewhere."""
        for lam in np.unique(np.asarray(lam_nm, float)):
            lam = float(lam)
            if lam in self._checked:
                continue
            self._checked.add(lam)
            lo, hi = self.fit_range_nm
            if not lo <= lam <= hi:
                warnings.warn(f"zernike-expansion: {lam:g} nm is outside the wavelength range the coefficients of "
                              f"{self.coefficients.name} were fitted over ({lo:g}-{hi:g} nm): an extrapolation",
                              BrdftabWarning, stacklevel=3)
            count, total, lowest, where = self.negative_scan(lam)
            if count:
                warnings.warn(f"zernike-expansion: {self.coefficients.name} at {lam:g} nm is negative at {count} of "
                              f"{total} scanned direction pairs (lowest {lowest:.3g} sr-1 at θi = {where[0]:g}°, "
                              f"θr = {where[1]:g}°, Δφ = {where[2]:g}°); negative values are clamped to 0",
                              BrdftabWarning, stacklevel=3)

    def negative_scan(self, wavelength_nm: float):
        """Scan the expansion (scale included) over θi, θr ∈ 0…89.9° (1.5° steps, then 89°, 89.5°,
        89.9°) and Δφ ∈ 0…180° (7.5° steps), 63 × 63 × 25 pairs. Returns ``(negative count,
        total, lowest value, (θi, θr, Δφ) [deg] of the lowest)``."""
        ti, tr, dp = np.meshgrid(np.radians(_SCAN_THETA), np.radians(_SCAN_THETA), np.radians(_SCAN_DPHI),
                                 indexing="ij")
        wi = np.stack([np.sin(ti), np.zeros_like(ti), np.cos(ti)], axis=-1).reshape(-1, 3)
        wo = np.stack([np.sin(tr) * np.cos(dp), np.sin(tr) * np.sin(dp), np.cos(tr)], axis=-1).reshape(-1, 3)
        f = self._expansion(wi, wo, np.array([float(wavelength_nm)]))[:, 0]
        neg = f < 0
        k = int(np.argmin(f))
        where = (float(np.degrees(ti.ravel()[k])), float(np.degrees(tr.ravel()[k])), float(np.degrees(dp.ravel()[k])))
        return int(neg.sum()), int(f.size), float(f[k]) if neg.any() else 0.0, where

    # -- evaluation ----------------------------------------------------------------------

    def _expansion(self, wi, wo, lam_nm) -> np.ndarray:
        """The unclamped f_r,11 at ``(M, 3)`` unit pairs for wavelengths ``lam_nm`` [nm]: ``(M, n)``.

        Every radial polynomial and every cos(lΔφ) is held once per pair, so pairs are taken in
        chunks that keep those tables within :data:`EXPANSION_BYTES`, whatever the file holds."""
        keys = self.coefficients._keys
        radials = len({(r, l) for n, m, l in keys for r in (n, m)})
        per_pair = 8 * (2 * radials + int(keys[:, 2].max()) + 8)
        step = max(1, EXPANSION_BYTES // per_pair)
        if wi.shape[0] <= step:
            return self._expansion_chunk(wi, wo, lam_nm)
        out = np.empty((wi.shape[0], lam_nm.size))
        for start in range(0, wi.shape[0], step):
            out[start:start + step] = self._expansion_chunk(wi[start:start + step], wo[start:start + step], lam_nm)
        return out

    def _expansion_chunk(self, wi, wo, lam_nm) -> np.ndarray:
        si = np.hypot(wi[:, 0], wi[:, 1])
        so = np.hypot(wo[:, 0], wo[:, 1])
        # ρ = √2 sin(θ/2) = sinθ / √(1 + cosθ) (no cancellation near the normal)
        rho_i = si / np.sqrt(1.0 + wi[:, 2])
        rho_o = so / np.sqrt(1.0 + wo[:, 2])
        # cos Δφ with Δφ = φ_wo − φ_wi ≡ SCATMECH's φs − π (module docstring); symmetric in wi ↔ wo
        # bit for bit. At the normal (s = 0) every l ≠ 0 term has R_n^l(0) = 0: any value will do.
        den = si * so
        with np.errstate(invalid="ignore", divide="ignore"):
            c = np.where(den > 0, (wi[:, 0] * wo[:, 0] + wi[:, 1] * wo[:, 1]) / den, 1.0)
        c = np.clip(c, -1.0, 1.0)
        keys = self.coefficients._keys
        radial_i, radial_o = {}, {}
        for n, m, l in keys:
            for r in (n, m):
                if (r, l) not in radial_i:
                    radial_i[(r, l)] = radial_zernike(r, l, rho_i)
                    radial_o[(r, l)] = radial_zernike(r, l, rho_o)
        # cos(l Δφ) = T_l(cos Δφ), Chebyshev recurrence
        cheb = [np.ones_like(c), c]
        for _ in range(2, int(keys[:, 2].max()) + 1):
            cheb.append(2.0 * c * cheb[-1] - cheb[-2])
        scale = self._scale_at(lam_nm)
        out = np.empty((wi.shape[0], lam_nm.size))
        for col, lam in enumerate(lam_nm):
            _, coef = self._f11_terms(float(lam))
            total = np.zeros(wi.shape[0])
            for (n, m, l), a in zip(keys, coef):
                if a == 0.0:
                    continue
                # the symmetrized product: each term, hence the sum, is exactly reciprocal
                total += a * (radial_i[(n, l)] * radial_o[(m, l)] + radial_i[(m, l)] * radial_o[(n, l)]) * cheb[l]
            out[:, col] = scale[col] * total
        return out

    def _kernel(self, lam, n):
        """The compiled evaluation (:func:`_expansion_rows`, set up by :meth:`_kernel_args`); the
        counters are updated as by :meth:`_eval`."""
        lam_nm = np.array([self.wavelength_nm]) if lam is None else np.asarray(lam, float)
        if lam is not None:
            self._check_wavelengths(lam_nm)
        args = self._kernel_args(lam_nm)

        def evaluate(wi, wo, state, out, add):
            clamped, evaluated = _expansion_rows(wi, wo, state, out, add, True, *args)
            with _COUNTS:
                self.clamped += clamped
                self.evaluated += evaluated
        return evaluate

    def _kernel_args(self, lam_nm):
        """The arguments of :func:`_expansion_rows` after the clamp flag, for wavelengths
        ``lam_nm`` [nm]: the radial rows of each (n, l) and (m, l) of the terms, the
        coefficients per wavelength, r(λ) and the block size."""
        keys = self.coefficients._keys
        lmax = int(keys[:, 2].max())
        smax = np.full(lmax + 1, -1, np.int64)
        for nn, mm, ll in keys:
            for r in (nn, mm):
                if r >= ll and (r - ll) % 2 == 0:
                    smax[ll] = max(smax[ll], (r - ll) // 2)
        offset = np.concatenate([[0], np.cumsum(smax + 1)[:-1]]).astype(np.int64)
        zero = int(offset[lmax] + smax[lmax] + 1)  # a row of zeros: R_n^l with n < l

        def row(r, ll):
            return int(offset[ll] + (r - ll) // 2) if r >= ll and (r - ll) % 2 == 0 else zero

        qn = np.array([row(nn, ll) for nn, mm, ll in keys], np.int64)
        qm = np.array([row(mm, ll) for nn, mm, ll in keys], np.int64)
        kl = np.ascontiguousarray(keys[:, 2], dtype=np.int64)
        coef = np.ascontiguousarray([self._f11_terms(float(x))[1] for x in lam_nm], dtype=float)
        scale = np.ascontiguousarray(self._scale_at(lam_nm), dtype=float)
        # the radial tables of a block (two of rows x block doubles) stay within about 1 MB
        block = int(min(256, max(16, (1 << 16) // (zero + 1))))
        return offset, smax, qn, qm, kl, coef, scale, block

    def _eval(self, wi, wo, lam, n):
        lam_nm = np.array([self.wavelength_nm]) if lam is None else np.asarray(lam, float)
        if lam is not None:
            self._check_wavelengths(lam_nm)
        f = self._expansion(wi, wo, lam_nm)
        neg = f < 0
        self.clamped += int(neg.sum())
        self.evaluated += f.size
        f[neg] = 0.0
        return f

    polarized = True

    def _mueller(self, wi, wo, lam, n):
        from .. import polarization as P

        f = self._eval(wi, wo, lam, n)
        lam_nm = np.array([self.wavelength_nm]) if lam is None else np.asarray(lam, float)
        rho_i = np.hypot(wi[:, 0], wi[:, 1]) / np.sqrt(1.0 + wi[:, 2])
        rho_r = np.hypot(wo[:, 0], wo[:, 1]) / np.sqrt(1.0 + wo[:, 2])
        if self.frame == "incidence":
            # SCATMECH's rotation 0: φi = π, φr = φs, wo's azimuth in the plane of incidence's axes
            xhat, yhat = P.incidence_axes(wi)
            phi_i = np.pi
            phi_r = np.arctan2(np.sum(wo * yhat, axis=-1), np.sum(wo * xhat, axis=-1))
        else:  # the sample's axes: φi, φr the azimuths of wi and wo (Germer's source at 180° is φi = π)
            phi_i = np.arctan2(wi[:, 1], wi[:, 0])
            phi_r = np.arctan2(wo[:, 1], wo[:, 0])
        out = np.empty((wi.shape[0], lam_nm.size, 4, 4))  # grey: one column per wavelength
        for col, lam_c in enumerate(lam_nm):
            m = self.coefficients.normalized_mueller(rho_i, rho_r, phi_i, phi_r, lam_c / 1000.0)
            out[:, col] = m * f[:, col, None, None]
        if self.frame == "sample":  # SCATMECH's xyxy on the fixed axes → Mitsuba's basis
            x, y = np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
            e_in, e_out = P.xyxy_frames(wi, wo, x, y)
            t_in, t_out = P.basis_frames("mitsuba", wi, wo)
            out = P.rotate_frames(out, -wi, e_in, t_in, wo, e_out, t_out) * P.CONJUGATE
        return out

    def expansion(self, wi, wo, wavelengths=None) -> np.ndarray:
        """The unclamped expansion (SCATMECH's value, possibly negative) at unit directions
        ``wi``, ``wo`` ``[..., 3]`` (0 at or below the horizon): ``[..., n]`` with n = 1 at
        ``wavelength_nm`` or one per wavelength [nm]. Nothing is counted or clamped."""
        wi, wo = as_directions(wi, wo)
        lam_nm = np.array([self.wavelength_nm]) if wavelengths is None else np.atleast_1d(np.asarray(wavelengths,
                                                                                                      float))
        lead = wi.shape[:-1]
        wi = wi.reshape(-1, 3)
        wo = wo.reshape(-1, 3)
        out = np.zeros((wi.shape[0], lam_nm.size))
        above = (wi[:, 2] > 1e-12) & (wo[:, 2] > 1e-12)
        if _COMPILED[-1]:  # the arithmetic of eval, so that eval is max(expansion, 0) bit for bit
            _expansion_rows(np.ascontiguousarray(wi, dtype=float), np.ascontiguousarray(wo, dtype=float),
                            above.astype(np.uint8), out, False, False, *self._kernel_args(lam_nm))
        else:
            out[above] = self._expansion(wi[above], wo[above], lam_nm)
        return out.reshape(lead + (lam_nm.size,))
