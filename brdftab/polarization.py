"""Mueller matrices of BRDFs: Stokes bases, conversions between them, Fresnel, Jones, checks.

A Mueller-matrix BRDF M (sr⁻¹, without the cosine) maps the Stokes vector of the light arriving
from ``wi`` to that of the light leaving along ``wo`` (both unit, pointing away from the surface;
the incident beam propagates along −wi, the outgoing one along wo). M means nothing without the
reference frame of each beam and the sign of S3, so every matrix here carries its **basis**.

Stokes frames
-------------
Every basis gives each beam (propagation direction k) a reference vector e1 ⟂ k and takes
e2 = k × e1, so (e1, e2, k) is right-handed. S1 = +1 is light polarized along e1, S2 = +1 along
e1 + e2 (as Mitsuba 3's and SCATMECH's conventions both have it). The bases differ in e1 and in
the sign of S3 (``circular``: +1 when S3 = +1 is right circular — clockwise looking towards the
source, Chipman's and Mitsuba's convention; −1 when it is left circular — SCATMECH's, whose
exp(−iωt) Jones calculus makes (1, i) left circular):

``mitsuba`` (the default)
    e1 = normalize(wi × wo) for both beams, perpendicular to the scattering plane; circular +1.
    It is the frame of Mitsuba's ``measured_polarized`` tables (x = normalize(ω_light × ω_view)):
    a ``.pbsdf`` holding one generic constant matrix C evaluates, rotated into these frames, to
    C·cosθi (Mitsuba's eval includes the cosine of the light's direction; tested).
``plane``
    SCATMECH's ``BRDF_Model::plane``: e1 = normalize(k_in × k_out) = −(the ``mitsuba`` e1), a
    180° turn that leaves Stokes vectors unchanged; circular −1. So ``plane`` and ``mitsuba``
    differ by diag(1, 1, 1, −1) on both sides (tested against ``mitsuba.mueller.specular_reflection``
    and SCATMECH's own Jones-to-Mueller conversion of the Rayleigh–Rice amplitudes).
``psps``
    SCATMECH's ``psps``: e1 = s = normalize(ẑ × k) per beam (perpendicular to the plane of the
    normal and the beam), e2 = p; circular −1.
``xyxy``
    SCATMECH's ``xyxy`` (``GetBasisVectorsXY``), the basis of the Zernike expansion and of
    Germer's PTFE data: per beam, x is the vector of the beam's frame that lies closest to the
    sample axis x̂ of the plane of incidence (x̂ points away from the source's azimuth, along
    the specular azimuth), e1 = y = normalize(x × k) and e2 = x; circular −1. Near the normal
    it is close to the fixed sample axes, so it has no singularity there.
``meridian``
    The meridian-plane basis of remote-sensing radiative-transfer codes: e1 = p = normalize(k ×
    (ẑ × k)) in the plane of the normal and the beam, e2 = −s; circular +1 (codes that count V
    positive for left-handed light differ by diag(1, 1, 1, −1)).

Degenerate geometry: where wi ∥ wo the scattering plane is undefined and ``mitsuba``/``plane``
take e1 = normalize(ẑ × wi) (the ``psps`` s of the incident beam up to sign); where a beam is
along the normal, ``psps``/``meridian`` take the plane of incidence's ŷ = ẑ × x̂, and the plane
of incidence itself takes wi's azimuth as 0 when θi = 0 (as :mod:`brdftab.geometry` does for φh).

Conversions
-----------
Re-expressing a beam's Stokes vector in another frame turned by θ about k (positive when
k · (e1_from × e1_to) > 0) is Mitsuba's rotator R(θ) (rows [1 0 0 0; 0 c s 0; 0 −s c 0; 0 0 0 1],
c = cos 2θ, s = sin 2θ); a change of circular sign is diag(1, 1, 1, −1). With T the product of the
two for a beam, ``M_to = T_out · M_from · T_in⁻¹`` (:func:`convert_basis`; tested against
``mitsuba.mueller.rotate_mueller_basis``).

Checks on matrices (arrays ``[..., 4, 4]``)
-------------------------------------------
* :func:`coherency_eigenvalues` — the eigenvalues of Cloude's coherency matrix; a physically
  realizable Mueller matrix (a sum of non-depolarizing ones) has all four ≥ 0;
* :func:`element_ratio` — max |M_ij| / M00 (≤ 1 for a realizable matrix);
* :func:`reciprocity_transform` — Q·Mᵀ·Q with Q = diag(1, 1, −1, 1): in matching frames (e1 the
  same vector for the reversed beams, as every basis above gives) a reciprocal medium has
  M(wi → wo) = reciprocity_transform(M(wo → wi));
* :func:`depolarization_index` — Gil and Bernabeu's DI = √(Σ M_ij² − M00²) / (√3 M00), 0 for an
  ideal depolarizer, 1 for a non-depolarizing matrix.

References: R. A. Chipman, W. S. T. Lam, G. Young, *Polarized Light and Optical Systems* (2018)
ch. 6 (Mueller matrices, rotators); S. R. Cloude, "Group theory and polarisation algebra",
Optik 75 (1986) (coherency matrix); J. J. Gil, E. Bernabeu, Optica Acta 33 (1986)
(depolarization index); C. F. Bohren, D. R. Huffman (1983) (Jones to Mueller, as SCATMECH's
``MuellerMatrix(const JonesMatrix&)``); NIST SCATMECH ``code/brdf.cpp``, ``code/jmatrix.cpp``
(the psps, xyxy and plane bases); Mitsuba 3 ``include/mitsuba/render/mueller.h``.
"""

from __future__ import annotations

import numpy as np

from .errors import ParameterError

__all__ = ["BASES", "DEFAULT_BASIS", "CIRCULAR", "CONJUGATE", "check_basis", "basis_frames", "incidence_axes",
           "xyxy_frames", "convert_basis", "rotate_frames", "rotator", "fresnel_mueller", "mueller_from_jones",
           "coherency_matrix", "coherency_eigenvalues", "element_ratio", "reciprocity_transform",
           "depolarization_index"]

#: The named Stokes bases (see the module docstring), in the order they are documented.
BASES = ("mitsuba", "plane", "psps", "xyxy", "meridian")
#: The basis :meth:`brdftab.brdf.BRDF.eval_mueller` returns unless told otherwise.
DEFAULT_BASIS = "mitsuba"
#: Sign of S3 for right circular light, per basis (+1: Mitsuba/Chipman, −1: SCATMECH).
CIRCULAR = {"mitsuba": 1, "plane": -1, "psps": -1, "xyxy": -1, "meridian": 1}

_Z = np.array([0.0, 0.0, 1.0])
_TINY = 1e-12


def check_basis(basis) -> str:
    """``basis`` if it is one of :data:`BASES`, else a :class:`ParameterError` listing them."""
    if basis not in BASES:
        from .params import unknown

        raise ParameterError("basis", unknown("basis", basis, list(BASES)))
    return basis


def _dot(a, b):
    return np.sum(a * b, axis=-1)


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _unit_or(v, fallback):
    """normalize(v), or ``fallback`` (unit, broadcastable) where |v| is ~0."""
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    ok = n > _TINY
    return np.where(ok, v / np.where(ok, n, 1.0), fallback)


def incidence_axes(wi):
    """x̂ (away from the source's azimuth: the specular side) and ŷ = ẑ × x̂ of the plane of
    incidence of unit ``wi [..., 3]`` (wi's azimuth taken as 0 where θi = 0): SCATMECH's frame, in
    which its scattering azimuth φs is measured."""
    h = np.concatenate([wi[..., :2], np.zeros(wi.shape[:-1] + (1,))], axis=-1)
    x = -_unit_or(h, np.array([1.0, 0.0, 0.0]))
    y = np.cross(_Z, x)
    return x, y


def _s_axis(k, y_fallback):
    """SCATMECH's s = normalize(ẑ × k), or the plane of incidence's ŷ where k is along ẑ."""
    return _unit_or(np.cross(_Z, k), y_fallback)


def _xy_axis(k, xhat, yhat):
    """SCATMECH's ``GetBasisVectorsXY`` x for a beam ``k`` in the plane-of-incidence axes."""
    s = _s_axis(k, yhat)
    p = _unit(np.cross(k, s))
    kx = _dot(k, xhat)
    ky = _dot(k, yhat)
    norm = np.hypot(kx, ky)
    ok = norm > 1e-10
    safe = np.where(ok, norm, 1.0)
    kx, ky = (kx / safe)[..., None], (ky / safe)[..., None]
    up = (k[..., 2] > 0)[..., None]
    x = np.where(up, -p * kx - s * ky, p * kx - s * ky)
    return np.where(ok[..., None], x, xhat)


def basis_frames(basis: str, wi, wo):
    """``(e_in, e_out)``: the reference vectors e1 ``[..., 3]`` of the incident beam (propagating
    along −wi) and of the outgoing beam (along wo) in ``basis``, for unit ``wi``, ``wo``."""
    check_basis(basis)
    wi, wo = np.broadcast_arrays(np.asarray(wi, float), np.asarray(wo, float))
    k_in, k_out = -wi, wo
    xhat, yhat = incidence_axes(wi)
    if basis in ("mitsuba", "plane"):
        e = _unit_or(np.cross(wi, wo), _s_axis(wi, yhat))
        if basis == "plane":
            e = -e
        return e, e
    if basis == "psps":
        return _s_axis(k_in, yhat), _s_axis(k_out, yhat)
    if basis == "meridian":
        return tuple(_unit(np.cross(k, _s_axis(k, yhat))) for k in (k_in, k_out))
    return xyxy_frames(wi, wo, xhat, yhat)


def xyxy_frames(wi, wo, xhat, yhat):
    """SCATMECH's ``xyxy`` reference vectors (e1 = y = normalize(x × k)) of the two beams for sample
    axes ``xhat``, ``yhat`` (the ``xyxy`` basis uses those of the plane of incidence,
    :func:`incidence_axes`)."""
    return tuple(_unit(np.cross(_xy_axis(k, xhat, yhat), k)) for k in (-wi, wo))


def rotator(theta) -> np.ndarray:
    """Mitsuba's Stokes rotator R(θ) ``[..., 4, 4]``: re-expresses a Stokes vector in a frame
    turned by θ about the propagation direction (right-handed)."""
    theta = np.asarray(theta, float)
    c, s = np.cos(2.0 * theta), np.sin(2.0 * theta)
    r = np.zeros(theta.shape + (4, 4))
    r[..., 0, 0] = r[..., 3, 3] = 1.0
    r[..., 1, 1] = r[..., 2, 2] = c
    r[..., 1, 2] = s
    r[..., 2, 1] = -s
    return r


def _angle(k, a, b):
    """Signed angle from unit ``a`` to unit ``b`` about ``k`` (both ⟂ k)."""
    return np.arctan2(_dot(k, np.cross(a, b)), _dot(a, b))


def _lift(t, m):
    """Broadcast per-pair matrices ``t[lead..., 4, 4]`` against ``m[lead..., extra..., 4, 4]``."""
    extra = m.ndim - t.ndim
    return t.reshape(t.shape[:-2] + (1,) * extra + (4, 4)) if extra > 0 else t


def rotate_frames(M, k_in, e_in_from, e_in_to, k_out, e_out_from, e_out_to):
    """Re-express ``M [..., (channels,) 4, 4]`` from reference vectors ``e_*_from`` to ``e_*_to``
    (unit, ⟂ to the propagation directions ``k_in``, ``k_out``): R(θ_out)·M·R(θ_in)ᵀ, as
    Mitsuba's ``rotate_mueller_basis``. The circular sign is left alone."""
    M = np.asarray(M, float)
    r_in = rotator(_angle(k_in, e_in_from, e_in_to))
    r_out = rotator(_angle(k_out, e_out_from, e_out_to))
    return _lift(r_out, M) @ M @ np.swapaxes(_lift(r_in, M), -1, -2)


def convert_basis(M, wi, wo, from_basis: str, to_basis: str) -> np.ndarray:
    """The Mueller matrices ``M [..., (n_channels,) 4, 4]`` at pairs ``wi``, ``wo [..., 3]``
    (unit, pointing away from the surface; leading shapes broadcast), given in ``from_basis``,
    re-expressed in ``to_basis`` (both of :data:`BASES`): frame rotations of both beams and the
    circular sign (see the module docstring)."""
    check_basis(from_basis)
    check_basis(to_basis)
    M = np.asarray(M, float)
    if from_basis == to_basis:
        return M.copy()
    wi, wo = np.broadcast_arrays(np.asarray(wi, float), np.asarray(wo, float))
    fi, fo = basis_frames(from_basis, wi, wo)
    ti, to = basis_frames(to_basis, wi, wo)
    out = rotate_frames(M, -wi, fi, ti, wo, fo, to)
    if CIRCULAR[from_basis] != CIRCULAR[to_basis]:
        out = out * CONJUGATE
    return out


#: Multiplying elementwise by this is D·M·D with D = diag(1, 1, 1, −1) (S3's sign on both sides).
CONJUGATE = np.array([[1, 1, 1, -1], [1, 1, 1, -1], [1, 1, 1, -1], [-1, -1, -1, 1]], float)


# --------------------------------------------------------------------------------------------
# Fresnel and Jones


def fresnel_mueller(cos_i, n, k=0.0) -> np.ndarray:
    """Mueller matrix ``[..., 4, 4]`` of specular reflection at an interface of relative index
    n + ik (k ≥ 0) for the cosine ``cos_i`` of the angle of incidence, in the s/p frame of the
    reflection (e1 = s for both beams, circular +1: Mitsuba's frame, in which it equals
    ``mitsuba.mueller.specular_reflection``)::

        ½ [R_s+R_p, R_s−R_p, 0, 0; R_s−R_p, R_s+R_p, 0, 0; 0, 0, 2C, −2S; 0, 0, 2S, 2C]

    with C + iS = r_s r_p* (Born and Wolf's amplitudes, :func:`~brdftab.models.fresnel.fresnel_amplitudes`).
    M00 is the unpolarized reflectance. ``cos_i``, ``n`` and ``k`` broadcast."""
    from .models.fresnel import fresnel_amplitudes

    cos_i = np.clip(np.asarray(cos_i, float), 0.0, 1.0)
    eta = np.asarray(n, float) + 1j * np.asarray(k, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        r_s, r_p = fresnel_amplitudes(cos_i, eta)
    # exactly grazing incidence (or an index-matched interface at grazing): 0/0 → total reflection
    r_s = np.where(np.isfinite(r_s), r_s, -1.0)
    r_p = np.where(np.isfinite(r_p), r_p, 1.0)
    rs2, rp2 = np.abs(r_s) ** 2, np.abs(r_p) ** 2
    cross = r_s * np.conj(r_p)
    out = np.zeros(np.shape(rs2) + (4, 4))
    out[..., 0, 0] = out[..., 1, 1] = 0.5 * (rs2 + rp2)
    out[..., 0, 1] = out[..., 1, 0] = 0.5 * (rs2 - rp2)
    out[..., 2, 2] = out[..., 3, 3] = cross.real
    out[..., 2, 3] = -cross.imag
    out[..., 3, 2] = cross.imag
    return out


# coherency vector (E1 E1*, E1 E2*, E2 E1*, E2 E2*) → Stokes, with S3 = −2 Im(E1 E2*): SCATMECH's sign
_A = np.array([[1, 0, 0, 1], [1, 0, 0, -1], [0, 1, 1, 0], [0, 1j, -1j, 0]])
_A_INV = np.linalg.inv(_A)


def mueller_from_jones(J, circular: int = -1) -> np.ndarray:
    """Mueller matrix ``[..., 4, 4]`` of Jones matrices ``J [..., 2, 2]`` acting on (E_1, E_2)
    (the components along e1, e2; ``J[..., 0, 0]`` is 1 → 1, ``J[..., 1, 0]`` is 1 → 2).
    ``circular`` = −1 is the exp(−iωt) Jones calculus of SCATMECH (S3 = −2 Im(E1 E2*): (1, i) is
    left circular; a SCATMECH Jones matrix {pp, ss, ps, sp} is ``[[ss, ps], [sp, pp]]``), +1 the
    opposite sign. M00 = ½ Σ |J_ab|²."""
    J = np.asarray(J, complex)
    K = np.einsum("...ab,...cd->...acbd", J, np.conj(J)).reshape(J.shape[:-2] + (4, 4))
    M = np.real(_A @ K @ _A_INV)
    return M if circular == -1 else M * CONJUGATE


# --------------------------------------------------------------------------------------------
# Checks on Mueller matrices

_PAULI = np.array([[[1, 0], [0, 1]], [[1, 0], [0, -1]], [[0, 1], [1, 0]], [[0, -1j], [1j, 0]]])
#: (σ_i ⊗ σ_j*) / 4 for every (i, j): the coherency matrix is Σ M_ij of these.
_COHERENCY_BASIS = np.einsum("iab,jcd->ijacbd", _PAULI, np.conj(_PAULI)).reshape(4, 4, 4, 4) / 4.0


def coherency_matrix(M) -> np.ndarray:
    """Cloude's coherency matrix H ``[..., 4, 4]`` (Hermitian, trace M00) of ``M [..., 4, 4]``:
    ¼ Σ_ij M_ij σ_i ⊗ σ_j* (Pauli matrices in the order of S0…S3)."""
    M = np.asarray(M, float)
    return np.einsum("...ij,ijab->...ab", M, _COHERENCY_BASIS)


def coherency_eigenvalues(M) -> np.ndarray:
    """The four real eigenvalues ``[..., 4]`` (ascending) of the coherency matrix of ``M``. A
    Mueller matrix is physically realizable (a convex sum of Jones–Mueller matrices) when all are
    ≥ 0 (to rounding: −ε·M00); a non-depolarizing matrix has one non-zero eigenvalue, M00. They
    do not depend on the basis (rotations and the circular sign are unitary on H). Computed
    :data:`EIGEN_BLOCK` matrices at a time (a table's worth bounds its complex temporaries)."""
    M = np.asarray(M, float)
    flat = M.reshape(-1, 4, 4)
    out = np.empty((flat.shape[0], 4))
    for a in range(0, flat.shape[0], EIGEN_BLOCK):
        out[a:a + EIGEN_BLOCK] = np.linalg.eigvalsh(coherency_matrix(flat[a:a + EIGEN_BLOCK]))
    return out.reshape(M.shape[:-2] + (4,))


#: Matrices per block of :func:`coherency_eigenvalues`.
EIGEN_BLOCK = 1 << 16


def element_ratio(M) -> np.ndarray:
    """max_ij |M_ij| / M00 ``[...]`` (≤ 1 for a realizable matrix; inf where M00 = 0 and another
    element is not; 0 where the matrix is 0)."""
    M = np.asarray(M, float)
    top = np.max(np.abs(M), axis=(-2, -1))
    m00 = M[..., 0, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(top == 0, 0.0, np.where(m00 > 0, top / np.where(m00 > 0, m00, 1.0), np.inf))


_Q = np.array([1.0, 1.0, -1.0, 1.0])


def reciprocity_transform(M) -> np.ndarray:
    """Q·Mᵀ·Q with Q = diag(1, 1, −1, 1) for ``M [..., 4, 4]``: what a reciprocal medium's
    M(wi → wo) equals when ``M`` is its M(wo → wi) in matching frames (module docstring)."""
    M = np.asarray(M, float)
    return np.swapaxes(M, -1, -2) * _Q[:, None] * _Q[None, :]


def depolarization_index(M) -> np.ndarray:
    """Gil and Bernabeu's depolarization index ``[...]``: √(Σ M_ij² − M00²) / (√3 M00), 0 for an
    ideal depolarizer, 1 for a non-depolarizing matrix (NaN where M00 = 0)."""
    M = np.asarray(M, float)
    m00 = M[..., 0, 0]
    rest = np.sum(M * M, axis=(-2, -1)) - m00 * m00
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(m00 > 0, np.sqrt(np.maximum(rest, 0.0)) / (np.sqrt(3.0) * m00), np.nan)
