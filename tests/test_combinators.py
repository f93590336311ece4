"""The rotated-frame combinator: Eq. 7's rotation, the tilted horizon, use from a spec, and the
albedo quadrature that follows a lobe about a tilted normal; the average combinator's closed
forms."""

import math

import numpy as np
import pytest

from brdftab import models
from brdftab.geometry import sph_to_vec
from brdftab.integrate import directional_albedo
from brdftab.quadrature import gauss_legendre
from brdftab.spec import parse_spec

R = np.radians


def test_rotation_is_eq7_and_the_tilted_normal():
    dtheta, dphi0, phi_ref = R(5.0), R(45.0), R(30.0)
    term = models.create("microfacet", alpha=0.3)
    m = models.create("rotated", term=term, tilt=dtheta, tilt_azimuth=dphi0, phi_ref=phi_ref)
    rng = np.random.default_rng(0)
    w = sph_to_vec(rng.uniform(0, 1.4, 5), rng.uniform(0, 6.28, 5))
    for v in w:
        # Ry(−Δθ) Rz(−Δφ0 − φref) written out with plain trigonometry
        a = -dphi0 - phi_ref
        x, y, z = v
        x, y = math.cos(a) * x - math.sin(a) * y, math.sin(a) * x + math.cos(a) * y
        b = -dtheta
        x, z = math.cos(b) * x + math.sin(b) * z, -math.sin(b) * x + math.cos(b) * z
        np.testing.assert_allclose(m.R @ v, [x, y, z], atol=1e-15)
    n2 = [math.sin(dtheta) * math.cos(dphi0 + phi_ref), math.sin(dtheta) * math.sin(dphi0 + phi_ref),
          math.cos(dtheta)]
    np.testing.assert_allclose(m.normal, n2, atol=1e-15)
    np.testing.assert_allclose(m.R @ m.normal, [0, 0, 1], atol=1e-15)


def test_values_symmetries_and_the_tilted_horizon():
    term = models.create("microfacet", alpha=0.2, fresnel="dielectric", n=1.5)
    m = models.create("rotated", term=term, tilt=R(10.0), tilt_azimuth=R(20.0), phi_ref=R(15.0))
    assert not m.isotropic and m.reciprocal and not m.energy_conserving
    rng = np.random.default_rng(1)
    wi = sph_to_vec(rng.uniform(0, 1.5, 3000), rng.uniform(0, 6.28, 3000))
    wo = sph_to_vec(rng.uniform(0, 1.5, 3000), rng.uniform(0, 6.28, 3000))
    f = m.eval(wi, wo)
    np.testing.assert_allclose(f, term.eval(wi @ m.R.T, wo @ m.R.T), rtol=1e-13)
    np.testing.assert_allclose(f, m.eval(wo, wi), rtol=1e-12)           # reciprocal when the term is
    below = ((wi @ m.R.T)[:, 2] <= 0) | ((wo @ m.R.T)[:, 2] <= 0)
    assert below.any() and np.all(f[below] == 0)                        # above the macro, below the tilt: 0
    # an isotropic term turned about the macro normal (no tilt) is unchanged
    turned = models.create("rotated", term=term, phi_ref=R(70.0))
    assert turned.isotropic
    np.testing.assert_allclose(turned.eval(wi, wo), term.eval(wi, wo), rtol=1e-12)


def test_rotated_from_a_spec(tmp_path):
    raw = {"model": {"name": "rotated", "tilt_deg": 0.5, "tilt_azimuth_deg": 45.0, "phi_ref_deg": 90.0,
                     "term": {"name": "small2021-peak", "m": 2e-4, "rho_s": 0.7, "n": 1.4}},
           "grid": {"type": "spherical", "relative_to": "specular", "theta_i_deg": [20.0], "phi_i_deg": [180.0],
                    "dtheta_o_deg": [0.0], "dphi_o_deg": [0.0]},
           "output": [{"path": "x.nc"}]}
    spec = parse_spec(raw, tmp_path / "s.toml")
    assert spec.model.tilt == pytest.approx(R(0.5)) and spec.model.phi_ref == pytest.approx(R(90.0))
    n2 = spec.model.normal
    assert math.degrees(math.atan2(n2[1], n2[0])) == pytest.approx(135.0)


@pytest.mark.parametrize("alpha, tilt", [(0.01, 8.0), (0.002, 0.5), (0.2, 20.0)])
def test_albedo_follows_a_lobe_about_a_tilted_normal(alpha, tilt):
    term = models.create("microfacet", distribution="ggx", alpha=alpha, shadowing="smith")
    m = models.create("rotated", term=term, tilt=R(tilt), tilt_azimuth=R(60.0))
    for theta_i in (R(15.0), R(50.0)):
        wi = sph_to_vec(theta_i, R(200.0))
        # independent: polar rule in outgoing space about the lobe's peak (mirror of wi about n2),
        # radii to 25 lobe widths, plus a coarse whole-hemisphere rule for what lies outside
        n2 = m.normal
        c = 2 * (wi @ n2) * n2 - wi
        u = np.cross(c, [0, 0, 1.0])
        u /= np.linalg.norm(u)
        v = np.cross(c, u)
        rmax = min(25 * 2 * alpha, 0.5)
        r, wr = gauss_legendre(800, 0.0, rmax)
        ph = (np.arange(512) + 0.5) * 2 * np.pi / 512
        d = (np.cos(r)[:, None, None] * c + np.sin(r)[:, None, None]
             * (np.cos(ph)[None, :, None] * u + np.sin(ph)[None, :, None] * v)).reshape(-1, 3)
        w = ((wr * np.sin(r))[:, None] * np.full(512, 2 * np.pi / 512)).ravel()
        inner = float(np.sum(m.eval(wi, d)[:, 0] * np.maximum(d[:, 2], 0) * w))
        mu, wmu = gauss_legendre(400, 0.0, 1.0)
        ph2 = (np.arange(800) + 0.5) * 2 * np.pi / 800
        d2 = sph_to_vec(np.arccos(mu)[:, None], ph2[None, :]).reshape(-1, 3)
        w2 = (wmu[:, None] * np.full(800, 2 * np.pi / 800)).ravel()
        outside = np.arccos(np.clip(d2 @ c, -1, 1)) > rmax
        outer = float(np.sum((m.eval(wi, d2)[:, 0] * d2[:, 2] * w2)[outside]))
        ref = inner + outer
        got = directional_albedo(m, theta_i, R(200.0))[0]
        assert got == pytest.approx(ref, rel=2e-3)


# -- the average combinator ------------------------------------------------------------------------

def test_average_combinator_closed_forms():
    from brdftab.brdf import BRDF
    from brdftab.geometry import sph_to_vec

    class Toy(BRDF):  # f = (0.2 + 0.3 cosθi + 0.1 sin²θi cos 2φi) / π: not reciprocal, not isotropic
        name = "toy"
        reciprocal = False
        isotropic = False

        def _eval(self, wi, wo, lam, n):
            phi = np.arctan2(wi[:, 1], wi[:, 0])
            f = (0.2 + 0.3 * wi[:, 2] + 0.1 * (1 - wi[:, 2] ** 2) * np.cos(2 * phi)) / np.pi
            return np.repeat(f[:, None], n, axis=1)

    rng = np.random.default_rng(2)
    wi = sph_to_vec(np.arccos(rng.uniform(0.1, 1, 200)), rng.uniform(0, 6.3, 200))
    wo = sph_to_vec(np.arccos(rng.uniform(0.1, 1, 200)), rng.uniform(0, 6.3, 200))
    iso = models.create("average", term=Toy(), rotations=8)  # 8 rotations cancel cos 2φ exactly
    assert iso.isotropic and not iso.reciprocal
    np.testing.assert_allclose(iso.eval(wi, wo)[:, 0], (0.2 + 0.3 * wi[:, 2]) / np.pi, rtol=1e-12)
    both = models.create("average", term=Toy(), rotations=8, swap=True)
    assert both.reciprocal
    np.testing.assert_allclose(both.eval(wi, wo)[:, 0], (0.2 + 0.15 * (wi[:, 2] + wo[:, 2])) / np.pi, rtol=1e-12)
