"""Albedo integrals (brdftab.integrate) against closed forms and independent Monte Carlo.

The Monte Carlo references are written here from the papers, not from brdftab's models:
GGX visible-normal sampling (E. Heitz, "Sampling the GGX distribution of visible normals",
JCGT 7(4), 2018), whose estimator of the single-scattering albedo with F = 1 is
G2(wi, wo) / G1(wi); Beckmann normals sampled from D cosθm (B. Walter et al., EGSR 2007,
Eq. 28), estimator G (wo·m) / (cosθi cosθm). The random numbers are randomized quasi-Monte
Carlo (8 independently scrambled Sobol' sets of 2^16 points, scipy.stats.qmc), so each
reference carries a standard error from the spread of the 8 replicate means (A. B. Owen,
"Scrambled net variance for integrals of smooth functions", Ann. Stat. 25 (1997)); the tests
bound it before comparing.
"""

import numpy as np
import pytest
from scipy.special import erfc
from scipy.stats import qmc

from brdftab import models
from brdftab.brdf import BRDF
from brdftab.integrate import albedo_curve, directional_albedo, outgoing_rule, white_sky_albedo

R = np.radians


# -- independent references ---------------------------------------------------------------------

def ggx_lambda(w, a):
    t2 = (w[..., 0] ** 2 + w[..., 1] ** 2) / w[..., 2] ** 2
    return 0.5 * (np.sqrt(1.0 + a * a * t2) - 1.0)


def beckmann_lambda(w, a):
    t = np.sqrt(w[..., 0] ** 2 + w[..., 1] ** 2) / w[..., 2]
    with np.errstate(divide="ignore"):
        x = 1.0 / (a * t)
        lam = 0.5 * (np.exp(-x * x) / (x * np.sqrt(np.pi)) - erfc(x))
    return np.where(t > 0, lam, 0.0)


def vndf_ggx(wi, a, u1, u2):
    """Heitz 2018, listing 1: visible normals of isotropic GGX for directions wi[N, 3]."""
    vh = np.stack([a * wi[:, 0], a * wi[:, 1], wi[:, 2]], axis=-1)
    vh /= np.linalg.norm(vh, axis=-1, keepdims=True)
    lensq = vh[:, 0] ** 2 + vh[:, 1] ** 2
    inv = np.where(lensq > 0, 1.0 / np.sqrt(np.where(lensq > 0, lensq, 1.0)), 0.0)
    t1v = np.where(lensq[:, None] > 0, np.stack([-vh[:, 1] * inv, vh[:, 0] * inv, 0 * inv], -1), [1.0, 0.0, 0.0])
    t2v = np.cross(vh, t1v)
    r, phi = np.sqrt(u1), 2 * np.pi * u2
    t1, t2 = r * np.cos(phi), r * np.sin(phi)
    s = 0.5 * (1.0 + vh[:, 2])
    t2 = (1.0 - s) * np.sqrt(1.0 - t1 * t1) + s * t2
    nh = t1[:, None] * t1v + t2[:, None] * t2v + np.sqrt(np.maximum(0.0, 1 - t1 * t1 - t2 * t2))[:, None] * vh
    ne = np.stack([a * nh[:, 0], a * nh[:, 1], np.maximum(0.0, nh[:, 2])], axis=-1)
    return ne / np.linalg.norm(ne, axis=-1, keepdims=True)


def rqmc(estimator, dim, seed, reps=8, m=16):
    """(mean, standard error) of ``estimator(u[N, dim])`` over ``reps`` scrambled Sobol' sets."""
    means = [estimator(qmc.Sobol(dim, scramble=True, seed=seed * 100 + r).random_base2(m)).mean()
             for r in range(reps)]
    return float(np.mean(means)), float(np.std(means, ddof=1) / np.sqrt(reps))


def ggx_weights(wi, a, u):
    """G2/G1 per visible normal sampled with u[N, 2] (0 where wo is below the horizon)."""
    m = vndf_ggx(wi, a, u[:, 0], u[:, 1])
    wo = 2 * np.sum(wi * m, -1)[:, None] * m - wi
    li, lo = ggx_lambda(wi, a), ggx_lambda(np.where(wo[:, 2:] > 0, wo, [0, 0, 1.0]), a)
    return np.where(wo[:, 2] > 0, (1 + li) / (1 + li + lo), 0.0)


def mc_ggx_albedo(theta_i, a, seed):
    """Single-scattering albedo of GGX with F = 1 and height-correlated Smith G; (mean, stderr)."""
    wi = np.array([np.sin(theta_i), 0.0, np.cos(theta_i)])
    return rqmc(lambda u: ggx_weights(np.broadcast_to(wi, (u.shape[0], 3)), a, u), 2, seed)


def mc_ggx_white_sky(a, seed):
    """The same averaged over cosine-weighted incident directions (u[:, 2:] picks wi)."""
    def est(u):
        r, phi = np.sqrt(u[:, 2]), 2 * np.pi * u[:, 3]
        wi = np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(1 - u[:, 2])], -1)
        return ggx_weights(wi, a, u[:, :2])
    return rqmc(est, 4, seed)


def mc_beckmann_albedo(theta_i, a, seed):
    """Beckmann, F = 1, height-correlated Smith G; normals sampled from D cosθm; (mean, stderr)."""
    wi = np.array([np.sin(theta_i), 0.0, np.cos(theta_i)])

    def est(u):
        tan2 = -a * a * np.log(1.0 - u[:, 0])
        ct = 1 / np.sqrt(1 + tan2)
        st = np.sqrt(tan2) * ct
        phi = 2 * np.pi * u[:, 1]
        m = np.stack([st * np.cos(phi), st * np.sin(phi), ct], -1)
        c = m @ wi
        wo = 2 * c[:, None] * m - wi
        ok = (c > 0) & (wo[:, 2] > 0)
        wo_ok = np.where(ok[:, None], wo, [0, 0, 1.0])
        g = 1.0 / (1.0 + beckmann_lambda(wi[None, :], a) + beckmann_lambda(wo_ok, a))
        return np.where(ok, g * c / (wi[2] * ct), 0.0)
    return rqmc(est, 2, seed)


# -- tests ---------------------------------------------------------------------------------------

def test_lambert_albedo_is_its_rho_at_every_angle():
    lam = models.create("lambert", albedo=0.8)
    theta = R(np.linspace(0.0, 89.9, 40))
    a = directional_albedo(lam, theta)[:, 0]
    assert np.all(np.abs(a - 0.8) < 1e-4)
    c = albedo_curve(lam, R(np.arange(0.0, 90.0)))
    assert abs(c.white_sky[0] - 0.8) < 1e-4
    assert np.all(c.coverage == pytest.approx(1.0, abs=1e-9))


@pytest.mark.parametrize("theta_i_deg", [0.0, 45.0, 89.0])
@pytest.mark.parametrize("width", [1.0, 0.01])
def test_rule_integrates_smooth_functions_over_the_hemisphere(theta_i_deg, width):
    # ∫ cosθ dω = π (to rounding: the horizon is a panel edge), ∫ cos^3 θ dω = π/2 and
    # ∫ x² cosθ dω = π/4 over the upper hemisphere
    wo, w = outgoing_rule(R(theta_i_deg), 0.3, width)
    assert np.all(wo[:, 2] >= -1e-12) and np.all(w > 0)
    assert np.sum(w * wo[:, 2]) == pytest.approx(np.pi, abs=1e-10)
    assert np.sum(w * wo[:, 2] ** 3) == pytest.approx(np.pi / 2, abs=1e-6)
    assert np.sum(w * wo[:, 0] ** 2 * wo[:, 2]) == pytest.approx(np.pi / 4, abs=1e-6)


@pytest.mark.parametrize("alpha", [0.1, 0.3, 0.6, 1.0])
def test_ggx_albedo_matches_visible_normal_monte_carlo(alpha):
    ggx = models.create("microfacet", distribution="ggx", alpha=alpha, shadowing="smith-height-correlated")
    for k, t in enumerate((0.0, 30.0, 60.0, 80.0)):
        ref, err = mc_ggx_albedo(R(t), alpha, seed=k)
        assert err < 1e-4  # the stated error bar of the reference
        a = directional_albedo(ggx, R(t))[0]
        assert abs(a - ref) < 1e-3, (alpha, t, a, ref, err)


def test_narrow_beckmann_lobe_integrates_to_one():
    beck = models.create("microfacet", distribution="beckmann", alpha=0.01, shadowing="smith-height-correlated")
    a0 = directional_albedo(beck, 0.0)[0]
    assert abs(a0 - 1.0) < 1e-3
    for k, t in enumerate((0.0, 40.0, 70.0)):
        ref, err = mc_beckmann_albedo(R(t), 0.01, seed=10 + k)
        assert err < 1e-4
        assert abs(directional_albedo(beck, R(t))[0] - ref) < 1e-3


def test_ggx_white_sky_albedo_matches_monte_carlo_over_both_hemispheres():
    alpha = 0.3
    ggx = models.create("microfacet", distribution="ggx", alpha=alpha, shadowing="smith-height-correlated")
    c = albedo_curve(ggx, R(np.arange(0.0, 90.0)))
    # white-sky albedo = E[a(wi)] for wi cosine-weighted
    ref, err = mc_ggx_white_sky(alpha, seed=8)
    assert err < 1e-4
    assert abs(c.white_sky[0] - ref) < 1e-3
    # and the spline rule itself: a curve a(θ) = cos²θ has white-sky 2∫cos³θ sinθ dθ = 1/2
    th = R(np.arange(0.0, 90.0))
    assert white_sky_albedo(th, np.cos(th)[:, None] ** 2)[0] == pytest.approx(0.5, abs=1e-5)


class MirrorPlusLambert(BRDF):
    """Lambert 0.3 plus an ideal mirror reflecting 0.5 of the flux (a delta the BRDF declares)."""

    def _eval(self, wi, wo, lam, n):
        return np.full((wi.shape[0], n), 0.3 / np.pi)

    def specular_delta(self, wi, wavelengths=None):
        return np.full(np.shape(wi)[:-1] + (1,), 0.5)


class HalfMissing(BRDF):
    """Lambert 0.8 whose samples are missing (NaN) wherever wo_x > 0."""

    def _eval(self, wi, wo, lam, n):
        f = np.full((wi.shape[0], n), 0.8 / np.pi)
        f[wo[:, 0] > 0] = np.nan
        return f


def test_specular_delta_coefficients_are_added():
    a = directional_albedo(MirrorPlusLambert(), R([0.0, 50.0, 85.0]))[:, 0]
    assert np.allclose(a, 0.8, atol=1e-9)


def test_missing_samples_are_left_out_and_coverage_reported():
    # the plane x = 0 halves the cosine-weighted hemisphere: coverage 1/2; the valid half of a
    # Lambert 0.8 reflects exactly 0.8 × coverage whatever the nodes (the cut is not a cell edge)
    a, cov = directional_albedo(HalfMissing(), R([0.0, 30.0, 60.0]), coverage=True)
    assert np.allclose(a, 0.8 * cov, rtol=1e-12)
    assert np.allclose(cov, 0.5, atol=5e-3)
    assert cov[0, 0] == pytest.approx(0.5, abs=1e-9)  # at normal incidence the cut is a panel edge


@pytest.mark.parametrize("ax, ay", [(0.05, 0.5), (0.716, 3e-5)])
@pytest.mark.parametrize("theta_i_deg", [0, 57, 80])
def test_anisotropic_lobe_albedo_against_monte_carlo(ax, ay, theta_i_deg):
    # reference: normals sampled ∝ D(h) cosθh (the distribution's own sampler, itself checked
    # against quadrature in test_microfacet); the estimator of ∫ f cosθo dωo is G (wi·h)/(cosθi cosθh)
    m = models.create("microfacet", alpha_x=ax, alpha_y=ay, shadowing="smith-height-correlated")
    d = m.dist
    rng = np.random.default_rng(theta_i_deg)
    n = 1_000_000
    h = d.sample(rng.random(n), rng.random(n))
    th = np.radians(theta_i_deg)
    wi = np.array([np.sin(th) * np.cos(0.4), np.sin(th) * np.sin(0.4), np.cos(th)])
    c = h @ wi
    wo = 2 * c[:, None] * h - wi
    ok = (c > 0) & (wo[:, 2] > 0)
    with np.errstate(all="ignore"):
        g = 1 / (1 + d.lambda_(wi[None, :]) + d.lambda_(wo))
        est = np.where(ok, g * c / (wi[2] * h[:, 2]), 0.0)
    ref, err = est.mean(), est.std() / np.sqrt(n)
    got = directional_albedo(m, th, 0.4)[0]
    assert abs(got - ref) < 4 * err + 2e-4, (got, ref, err)


@pytest.mark.parametrize("axes", [(0.05, 0.5), (0.716, 3e-5), (0.5, 0.05)])
def test_anisotropic_rule_integrates_a_lambertian_exactly(axes):
    class Declares(BRDF):  # a Lambertian that declares an anisotropic lobe: the rule changes, the value must not
        lobe_axes = axes
        lobe_width = min(axes)

        def _eval(self, wi, wo, lam, n):
            return np.full((wi.shape[0], n), 0.5 / np.pi)

    a = directional_albedo(Declares(), R([0.0, 60.0, 89.0])[:, None], (np.arange(8) * np.pi / 4)[None, :])
    np.testing.assert_allclose(a, 0.5, rtol=1e-8)


# -- anisotropic tables: axes measured, not declared --------------------------------------------

def test_anisotropic_table_albedo_is_invariant_as_phi_i_turns_at_normal_incidence():
    """A table declares no lobe axes: they are probed. At θi = 0 every φi is the same incidence,
    so a(0, φi) must not depend on φi; each value and the white-sky albedo are compared with an
    independent fine product quadrature of the same table."""
    import brdftab
    from brdftab.geometry import sph_to_vec
    from brdftab.grids import RusinkiewiczGrid
    from brdftab.integrate import probe_axes
    from brdftab.quadrature import gauss_legendre

    m = models.create("microfacet", alpha_x=0.05, alpha_y=0.3)
    t = brdftab.tabulate(m, RusinkiewiczGrid(32, 32, 64, 64, theta_h_spacing="merl", phi_d_fold="none"),
                         progress=False)
    assert t.lobe_axes is None and not t.isotropic
    axes = probe_axes(t)
    assert axes is not None and axes[0] > 3 * axes[1] and abs(np.sin(axes[2])) > 0.99   # long along y
    mu, wmu = gauss_legendre(200, 0.0, 1.0)
    ph = (np.arange(900) + 0.5) * 2 * np.pi / 900
    wo = sph_to_vec(np.arccos(mu)[:, None], ph[None, :]).reshape(-1, 3)
    w = (wmu[:, None] * np.full(900, 2 * np.pi / 900)).ravel() * wo[:, 2]

    def fine(theta, phi):
        f = t.eval(sph_to_vec(theta, phi), wo)[:, 0]
        return float(np.nansum(f * w))

    ref0 = fine(0.0, 0.0)
    phis = R(np.arange(0, 360, 22.5))
    a0 = directional_albedo(t, 0.0, phis)[:, 0]
    assert np.all(np.abs(a0 / ref0 - 1) < 0.005), (a0, ref0)
    # white-sky: (1/π) ∫ a(θi, φi) cosθi dωi, a from the fine rule on a Gauss–Legendre μi × φi product
    mi_, wmi = gauss_legendre(6, 0.0, 1.0)
    phi_i = (np.arange(6) + 0.5) * 2 * np.pi / 6
    ref_ws = sum(wa * wb * fine(np.arccos(x), p) * x * 2 for x, wa in zip(mi_, wmi) for p, wb in
                 zip(phi_i, np.full(6, 1 / 6)))
    curve = albedo_curve(t, R(np.linspace(0, 89, 46)), phi_i)
    assert curve.white_sky[0] == pytest.approx(ref_ws, rel=0.005)


def test_gonio_table_albedo_is_integrated_on_its_own_cells():
    """A gonio table's lobe can sit anywhere (here a narrow peak 20° off the mirror direction):
    the albedo integrals use the table's own cells, so they agree with the model's albedo
    (computed with the model's lobe hints) to the table's interpolation error."""
    import brdftab
    from brdftab.grids import grid_from_config

    peak = models.create("rotated", term=models.create("microfacet", alpha=0.03), tilt=R(10.0), tilt_azimuth=R(60.0))
    grid = grid_from_config({"type": "spherical", "theta_i_deg": [30.0], "phi_i_deg": [0.0],
                             "theta_o_deg": {"start": 0, "stop": 90, "step": 0.25},
                             "phi_o_deg": {"start": 0, "stop": 360, "step": 0.25, "endpoint": False}})
    t = brdftab.tabulate(peak, grid, progress=False)
    a_table = directional_albedo(t, R(30.0), 0.0)[0]
    a_model = directional_albedo(peak, R(30.0), 0.0)[0]
    assert a_table == pytest.approx(a_model, rel=5e-3)
    # the generic half-vector rule about the normal does not see this lobe on the table
    wo, w = outgoing_rule(R(30.0), 0.0, 0.03)
    keep = wo[:, 2] > 0
    wi = np.array([np.sin(R(30.0)), 0.0, np.cos(R(30.0))])
    generic = float(np.nansum(t.eval(wi, wo[keep])[:, 0] * w[keep] * wo[keep, 2]))
    assert abs(generic - a_model) > 0.03 * a_model     # measured: 7 % off


def test_gonio_table_rule_integrates_its_interpolant():
    """The own-cell rule against a fine product quadrature of the same interpolant, on a
    coarse table (10° steps) whose lobe meets the pole at normal incidence."""
    import brdftab
    from brdftab.geometry import sph_to_vec
    from brdftab.quadrature import gauss_legendre

    ggx = models.create("microfacet", alpha=0.1)
    grid = brdftab.grids.SphericalGrid(R([0, 30, 60]), [0.0], R(np.arange(0, 81, 10.0)), R(np.arange(0, 360, 10.0)))
    t = brdftab.tabulate(ggx, grid, progress=False)
    th, wt = gauss_legendre(2000, 0, R(80))
    ph = (np.arange(720) + 0.5) * 2 * np.pi / 720
    wo = sph_to_vec(th[:, None], ph[None, :]).reshape(-1, 3)
    w = ((wt * np.sin(th))[:, None] * np.full(720, 2 * np.pi / 720)).ravel() * wo[:, 2]
    for ti in (0.0, 30.0, 60.0):
        wi = sph_to_vec(R(ti), 0.0)
        fine = float(np.nansum(t.eval(np.broadcast_to(wi, wo.shape), wo)[:, 0] * w))
        assert directional_albedo(t, R(ti), 0.0)[0] == pytest.approx(fine, rel=1e-3)
