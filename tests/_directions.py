"""Direction sampling shared by the tests that compare brdftab with Mitsuba 3."""

import numpy as np


def f32(a):
    """Round to float32 and back: the values Mitsuba actually receives."""
    return np.asarray(a, np.float32).astype(np.float64)


def upper(rng, n, min_cos):
    """``n`` directions with cosθ uniform in [min_cos, 1] and uniform azimuth."""
    c = rng.uniform(min_cos, 1.0, n)
    phi = rng.uniform(-np.pi, np.pi, n)
    s = np.sqrt(1.0 - c * c)
    return np.stack([s * np.cos(phi), s * np.sin(phi), c], axis=-1)


def direction_pairs(seed, alpha_x, alpha_y, n, min_cos, renormalize=False):
    """Seeded (wi, wo) pairs, both with cosθ >= min_cos, float32-exact.

    Half are independent uniform pairs (tails of D), half put wo near the mirror direction
    of wi by reflecting about a normal drawn with slopes ~ 1.5·α·N(0, 1) (the peak of D).
    ``renormalize`` makes the float32-rounded vectors unit again in float64.
    """
    rng = np.random.default_rng(seed)
    n_uniform = n // 2
    wi_u, wo_u = upper(rng, n_uniform, min_cos), upper(rng, n_uniform, min_cos)
    wi_s, wo_s = [], []
    need = n - n_uniform
    while need > 0:
        wi = upper(rng, 4 * need, min_cos)
        sx = 1.5 * alpha_x * rng.normal(size=wi.shape[0])
        sy = 1.5 * alpha_y * rng.normal(size=wi.shape[0])
        m = np.stack([-sx, -sy, np.ones_like(sx)], axis=-1)
        m /= np.linalg.norm(m, axis=-1, keepdims=True)
        d = np.sum(wi * m, axis=-1, keepdims=True)
        wo = 2.0 * d * m - wi
        ok = (wo[:, 2] >= min_cos) & (d[:, 0] > 0)
        wi_s.append(wi[ok][:need])
        wo_s.append(wo[ok][:need])
        need -= min(need, int(ok.sum()))
    wi = f32(np.concatenate([wi_u] + wi_s))
    wo = f32(np.concatenate([wo_u] + wo_s))
    if renormalize:
        wi = wi / np.linalg.norm(wi, axis=-1, keepdims=True)
        wo = wo / np.linalg.norm(wo, axis=-1, keepdims=True)
    assert wi.shape == wo.shape == (n, 3)
    return wi, wo
