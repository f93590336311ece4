"""The normal distribution an RGL ``.bsdf`` writer stores, and its projected area.

D is the model's own (:func:`model_ndf`), or one extracted from the back-scattering f(ω, ω)
by power iteration (:func:`backscatter_ndf`, Dupuy et al., CGF 34(4), 2015); the ``ndf`` table
is the model's D raised where another term dominates the back-scattering
(:func:`backscatter_bound`); ``sigma`` is the projected area σ(ω) = ∫ D(m) ⟨ω·m⟩₊ dm
(:func:`sigma_table`).
"""

from __future__ import annotations

import numpy as np

from ..brdf import BRDF
from ..channels import luminance_weights as _luminance_weights
from ._rgl_warp import TWO_PI, bilinear, elevation, phi2u, sph, theta2u, u2theta

__all__ = ["BACKSCATTER_BOUND", "model_ndf", "backscatter_ndf", "backscatter_bound", "sigma_table"]

#: The ``ndf`` table is raised to this fraction of what the back-scattering needs
#: (:func:`backscatter_bound`).
BACKSCATTER_BOUND = 0.3


def model_ndf(brdf):
    """The model's own normal distribution as a callable ``h[..., 3] -> D [sr⁻¹]``, or None.

    Asks by duck typing: ``brdf.ndf(h)``; a sum (``terms``) gives the narrowest lobe among
    its terms that have one (largest D at the normal); a scaled model (``term``) its term's.
    """
    ndf = getattr(brdf, "ndf", None)
    if callable(ndf):
        return ndf
    terms = getattr(brdf, "terms", None)
    if isinstance(terms, (list, tuple)):
        found = [f for f in (model_ndf(t) for t in terms) if f is not None]
        if found:
            z = np.array([[0.0, 0.0, 1.0]])
            return max(found, key=lambda f: float(np.nan_to_num(np.asarray(f(z), float).ravel()[0])))
        return None
    term = getattr(brdf, "term", None)
    if isinstance(term, BRDF):
        return model_ndf(term)
    return None


def _azimuthal_kernel(theta_a, theta_b):
    """∫₀^{2π} max(0, ω(θa, 0)·ω(θb, φ)) dφ, closed form, for all pairs ``[A, B]``."""
    a = np.sin(theta_a)[:, None] * np.sin(theta_b)[None, :]
    b = np.cos(theta_a)[:, None] * np.cos(theta_b)[None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        phi_c = np.arccos(np.clip(-b / a, -1.0, 1.0))
        partial = 2.0 * (b * phi_c + a * np.sin(phi_c))
    return np.where(b >= a, TWO_PI * b, np.where(b <= -a, 0.0, partial))


def _theta_nodes(n=512):
    """Gauss–Legendre nodes in u = sqrt(2θ/π) (dense near the normal); θ and sinθ dθ weights."""
    from ..quadrature import gauss_legendre

    u, wu = gauss_legendre(n, 0.0, 1.0)
    theta = u2theta(u)
    return theta, np.sin(theta) * np.pi * u * wu


def _typical_scale(brdf, lam, lw, n=512):
    """The largest luminance of f at ``n`` seeded pairs (half of them near the mirror direction)."""
    rng = np.random.default_rng(0)
    z = rng.uniform(0.05, 1.0, (2, n))
    phi = rng.uniform(-np.pi, np.pi, (2, n))
    wi = sph(np.arccos(z[0]), phi[0])
    wo = sph(np.arccos(z[1]), phi[1])
    wo[: n // 2] = wi[: n // 2] * np.array([-1.0, -1.0, 1.0])
    with np.errstate(all="ignore"):
        f = np.nan_to_num(np.asarray(brdf.eval(wi, wo, lam), float) @ lw)
    return float(np.max(np.abs(f), initial=0.0))


def backscatter_ndf(brdf, wavelengths=None, *, n_theta=256, n_phi=8, max_iter=500, tol=1e-10):
    """An isotropic NDF from the back-scattering of ``brdf``, by power iteration.

    For a microfacet BRDF, f(ω, ω) = D(ω)·G1(ω)·F/(4cos²θ) with G1 = cosθ/σ(ω) and
    σ(ω) = ∫ D(m)⟨ω·m⟩ dm, so D(ω) ∝ f(ω, ω)·cosθ·σ(ω): D is the positive eigenvector of
    that linear map (Dupuy et al. 2015). f(ω, ω) is averaged over ``n_phi`` azimuths and
    weighted to a luminance. Returns a callable ``h[..., 3] -> D [sr⁻¹]`` normalized so that
    ∫ D cosθ dω = 1; a BRDF whose back-scattering is nowhere above 1e-6 of its largest value at a
    few hundred seeded pairs (half of them mirror pairs) gets the flat D = 1/π.
    """
    theta, area = _theta_nodes(n_theta)
    lam = brdf.layout.resolve(wavelengths)
    lw = _luminance_weights(brdf.channels, lam)

    def backscatter(th):
        phis = (np.arange(n_phi) + 0.5) * (TWO_PI / n_phi)
        w = sph(th[:, None], phis[None, :]).reshape(-1, 3)
        f = brdf.eval(w, w, lam) @ lw
        return np.maximum(np.nan_to_num(f.reshape(th.size, n_phi).mean(axis=1)), 0.0)

    fb = backscatter(theta)
    if not np.any(fb > 1e-6 * _typical_scale(brdf, lam, lw)):
        # (next to) nothing is scattered back (e.g. mirror facets that never face the light and
        # the eye at once): no lobe to follow, so the flat D = 1/π (∫ D cosθ dω = 1)
        def flat(h):
            h = np.asarray(h, float)
            return np.where(h[..., 2] > 0, 1.0 / np.pi, 0.0)

        flat.no_backscatter = True  # no diffuse-like lobe: the writer uses its general warp
        return flat
    kernel = _azimuthal_kernel(theta, theta) * area[None, :]
    weight = fb * np.cos(theta)
    d = np.ones_like(theta)
    norm = TWO_PI * np.sum(area * np.cos(theta) * d)
    d /= norm
    scale = 1.0
    for _ in range(max_iter):
        new = weight * (kernel @ d)
        scale = TWO_PI * np.sum(area * np.cos(theta) * new)
        new /= scale
        done = np.max(np.abs(new - d)) <= tol * np.max(new)
        d = new
        if done:
            break
    # D anywhere from the fixed point: D(θ) = f(θ, θ)·cosθ·σ(θ)/scale, tabulated finely in u.
    u_fine = np.linspace(0.0, 1.0, 1025)
    th_fine = u2theta(u_fine)
    sigma_fine = (_azimuthal_kernel(th_fine, theta) * area[None, :]) @ d
    d_fine = backscatter(th_fine) * np.cos(th_fine) * sigma_fine / scale

    def ndf(h):
        h = np.asarray(h, float)
        u = theta2u(np.arccos(np.clip(h[..., 2], -1.0, 1.0)))
        return np.where(h[..., 2] > 0, np.interp(u, u_fine, d_fine), 0.0)

    return ndf


def sigma_table(ndf, nx: int, ny: int, isotropic: bool, *, n_theta: int = 512) -> np.ndarray:
    """The projected area σ(ω) = ∫ D(m) max(0, ω·m) dm on the ndf grid, ``[ny, nx]``.

    Node (x, y) is ω = sph(u2theta(x/(nx−1)), u2phi(y/(ny−1))). Quadrature over m: Gauss–Legendre
    in u = sqrt(2θm/π) (dense near the normal) × a periodic rule in φm. For an isotropic D the
    φm integral is done in closed form; otherwise it is a circular convolution in φ (FFT), with
    4·(ny−1) or more azimuths. For a GGX D it equals the Smith form cosθ·(1 + Λ(ω)) to 1e-6
    (isotropic) and 5e-4 (anisotropic, αx = 0.05, αy = 0.3): tests/test_rgl.py,
    ``test_ndf_and_sigma_tables_are_the_models``.
    """
    theta_w = u2theta(np.linspace(0.0, 1.0, nx))
    if isotropic:
        theta, area = _theta_nodes(n_theta)
        d = ndf(sph(theta, 0.0))
        return np.tile((_azimuthal_kernel(theta_w, theta) * area[None, :]) @ d, (ny, 1))
    theta, area = _theta_nodes(n_theta // 2)
    step = -(-256 // (ny - 1))  # quadrature azimuths per table interval
    p = step * (ny - 1)
    phi = -np.pi + np.arange(p) * (TWO_PI / p)
    d = ndf(sph(theta[:, None], phi[None, :])) * (area[:, None] * (TWO_PI / p))  # [K, P]
    d_hat = np.fft.rfft(d, axis=1)
    delta = np.arange(p) * (TWO_PI / p)
    out = np.empty((ny, nx))
    for j, tw in enumerate(theta_w):
        # g(Δφ) = max(0, ω(θw, φ)·m(θk, φ − Δφ)) for every θk: [K, P]
        g = np.maximum(0.0, np.sin(tw) * np.sin(theta)[:, None] * np.cos(delta)[None, :]
                       + np.cos(tw) * np.cos(theta)[:, None])
        conv = np.fft.irfft(np.sum(d_hat * np.fft.rfft(g, axis=1), axis=0), n=p)  # σ at φ = −π + l·2π/P
        out[:, j] = np.append(conv[::step], conv[0])
    return out


def backscatter_bound(brdf, ndf, lam, nx, ny, anisotropic):
    """The model's D raised to what its back-scattering needs: max(D(ω), 4 f(ω, ω) cosθ σ(ω)).

    For a microfacet lobe f(ω, ω) = D·F·G2(ω, ω)/(4cos²θ) with G2 ≤ cosθ/σ(ω) and F ≤ 1, so
    the bound is at most D and D is kept. Where another term (a Lambertian, a broader lobe)
    dominates f, D alone would make the stored values f·cosθo·4σ/D huge and the file's
    interpolation poor; the bound keeps them of the order of the lobe's own. f is the largest
    channel; σ is the projected area of the model's D.
    """
    sig = bilinear(sigma_table(lambda h: np.maximum(np.nan_to_num(np.asarray(ndf(h), float)), 0.0),
                                nx, ny, isotropic=not anisotropic))

    def raised(h):
        h = np.asarray(h, float)
        lead = h.shape[:-1]
        h2 = h.reshape(-1, 3)
        with np.errstate(all="ignore"):
            d = np.asarray(ndf(h2), float).reshape(-1)
        out = np.zeros(h2.shape[0])
        ok = h2[:, 2] > 1e-6
        if ok.any():
            w = h2[ok]
            with np.errstate(all="ignore"):
                f = np.nan_to_num(np.asarray(brdf.eval(w, w, lam), float)).max(axis=-1)
            u = np.stack([theta2u(elevation(w)), phi2u(np.arctan2(w[:, 1], w[:, 0]))], axis=-1)
            out[ok] = np.maximum(BACKSCATTER_BOUND * 4.0 * f * w[:, 2] * sig.eval(u), 0.0)
        return np.maximum(d, out).reshape(lead)

    return raised
