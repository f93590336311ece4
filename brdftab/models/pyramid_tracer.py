"""Ray tracer of a random array of equal, overlapping upright pyramids (no mesh, no height-field
sampling): it makes the sequence table of the ``pyramid-microfacet`` model's ``walk = "traced"``
(``tools/make_pyramid_walk.py``, fields and rays from seeds of their own) and is the oracle
the tests measure the model against (other seeds: independent fields and rays).

The surface is the one de Haas simulates (thesis §4.1): ``n_pyramids`` equal upright pyramids
with facet tilt θp = arctan √2 (KOH-etched (100) silicon), apexes uniformly random in a
periodic square tile, overlapping. The bases are infinite, so the surface is fully covered
(no flat floor shows) and the height field is the upper envelope of the pyramids,

    z(x, y) = −tanθp · min_k L∞((x, y) − apex_k),

whose face normals point along ±x and ±y (the model's ``phi0 = 0``). Each pyramid is the
convex solid z ≤ −tanθp · L∞((x, y) − apex); a ray enters the union of the solids first at
the smallest entry parameter over the pyramids (slab test against each pyramid's 4 planes).

Candidate culling: the K pyramids whose apexes are nearest (L∞, periodic) to the ray's
current point q are tested exactly. A pyramid whose apex is farther than r_K (the K-th
distance) can only be entered after a parameter

    Δ_safe = (q_z + tanθp · r_K) / (tanθp · |d_xy|∞ − d_z)

(its surface lies below −tanθp (r_K − |d_xy|∞ Δ) along the ray), so a candidate hit before
Δ_safe is the first hit; otherwise the ray advances by Δ_safe and the query is repeated. All
rays are traced together (numpy), the tile's apexes are in a periodic ``cKDTree`` queried
with the L∞ norm.

Polarization: with ``eta`` (complex index n + ik of the facets) two orthogonal Jones fields
are carried along each ray as complex 3-vectors (s = d × n, p = s × d at each bounce;
E' = r_s E_s s + r_p E_p p'), and the unpolarized reflectance is the mean of their
intensities; the product of the unpolarized facet reflectances is recorded alongside.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

TAN_P = np.sqrt(2.0)
#: Outward normals of an upright pyramid's faces, by face index m (azimuth m · 90°):
#: the solid is n_m · (p − apex) <= 0 for all m.
NORMALS = np.array([[TAN_P, 0.0, 1.0], [0.0, TAN_P, 1.0], [-TAN_P, 0.0, 1.0], [0.0, -TAN_P, 1.0]]) / np.sqrt(3.0)
K_NEAREST = 12
EPS = 1e-10


def _amplitudes(cos_i, eta):
    """Fresnel amplitude coefficients (r_s, r_p) for a complex relative index ``eta``
    (convention: a perfect conductor gives r_s = −1, r_p = +1 with p = s × d)."""
    cos_t = np.sqrt(1.0 - (1.0 - cos_i ** 2) / eta ** 2 + 0j)
    rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    return rs, rp


@dataclass
class Traced:
    """What became of each ray: ``bounces`` (−1: still inside after ``max_bounces``),
    ``exit`` directions (rows of escaped rays), ``faces`` (face index per bounce, −1 padded),
    ``intensity`` (polarization-tracked reflectance) and ``unpolarized`` (product of the
    unpolarized facet reflectances), both 1 for mirror facets."""

    bounces: np.ndarray
    exit: np.ndarray
    faces: np.ndarray
    intensity: np.ndarray
    unpolarized: np.ndarray


class PyramidField:
    """``n_pyramids`` equal pyramids (apex height 0) at uniform random positions in the
    periodic unit tile, from ``seed``."""

    def __init__(self, n_pyramids: int = 1000, seed: int = 0):
        rng = np.random.default_rng(seed)
        self.apex = rng.uniform(0.0, 1.0, (n_pyramids, 2))
        self.tree = cKDTree(self.apex, boxsize=1.0)

    def height(self, xy):
        """The height field z(x, y) (the tracer's surface)."""
        d, _ = self.tree.query(np.mod(xy, 1.0), k=1, p=np.inf)
        return -TAN_P * d

    def _next_hit(self, q, d):
        """(s, face) of the first entry of rays q + s d into the pyramids (s = inf: none,
        the ray escapes upwards)."""
        n = q.shape[0]
        s_hit = np.full(n, np.inf)
        face = np.full(n, -1)
        todo = np.arange(n)
        base = np.zeros(n)  # parameter already advanced
        q = q.copy()
        dxy = np.max(np.abs(d[:, :2]), axis=1)
        denom = TAN_P * dxy - d[:, 2]
        while todo.size:
            qq, dd = q[todo], d[todo]
            dist, idx = self.tree.query(np.mod(qq[:, :2], 1.0), k=K_NEAREST, p=np.inf)
            c = self.apex[idx]                                               # [R, K, 2]
            delta = np.mod(c - qq[:, None, :2] + 0.5, 1.0) - 0.5
            rel = np.concatenate([-delta, qq[:, None, 2:3].repeat(K_NEAREST, 1)], axis=2)   # q − apex
            a = np.einsum("rkc,mc->rkm", rel, NORMALS)
            b = (dd @ NORMALS.T)[:, None, :]
            with np.errstate(divide="ignore", invalid="ignore"):
                t = -a / b
            enter = np.where(b < 0, t, -np.inf).max(axis=2)
            leave = np.where(b > 0, t, np.inf).min(axis=2)
            miss = np.any((b == 0) & (a > 0), axis=2) | (enter > leave) | (enter <= EPS)
            enter = np.where(miss, np.inf, enter)
            best = np.argmin(enter, axis=1)
            s_star = enter[np.arange(todo.size), best]
            tb = np.where(b < 0, t, -np.inf)[np.arange(todo.size), best]       # [R, 4]
            m_star = np.argmax(tb, axis=1)
            with np.errstate(divide="ignore"):
                safe = np.where(denom[todo] > 0, (qq[:, 2] + TAN_P * dist[:, -1]) / denom[todo], np.inf)
            up = dd[:, 2] > 0
            with np.errstate(divide="ignore"):
                t_top = np.where(up, -qq[:, 2] / np.where(up, dd[:, 2], 1.0), np.inf)
            hit = s_star <= safe
            gone = ~hit & (t_top <= safe)          # reaches z = 0 upwards before anything else
            s_hit[todo[hit]] = base[todo[hit]] + s_star[hit]
            face[todo[hit]] = m_star[hit]
            more = ~hit & ~gone
            if np.any(more & ~np.isfinite(safe)):
                raise AssertionError("a ray neither hits nor escapes")
            adv = todo[more]
            q[adv] += safe[more, None] * d[adv]
            base[adv] += safe[more]
            todo = adv
        return s_hit, face

    def trace(self, wi, n_rays: int, seed: int = 0, max_bounces: int = 40, eta=None) -> Traced:
        """Trace ``n_rays`` rays arriving from direction ``wi`` (unit, pointing toward the
        source) at uniform random points of the tile."""
        rng = np.random.default_rng(seed)
        wi = np.asarray(wi, float) / np.linalg.norm(wi)
        d = np.broadcast_to(-wi, (n_rays, 3)).copy()
        q = np.concatenate([rng.uniform(0, 1, (n_rays, 2)), np.zeros((n_rays, 1))], axis=1)
        bounces = np.full(n_rays, -1)
        exit_dir = np.zeros((n_rays, 3))
        faces = np.full((n_rays, max_bounces), -1)
        # two orthogonal polarizations (unit Jones fields) perpendicular to the ray
        ref = np.array([0.0, 0.0, 1.0]) if abs(wi[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
        e1 = np.cross(-wi, ref)
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(e1, -wi)
        E = [np.broadcast_to(e.astype(complex), (n_rays, 3)).copy() for e in (e1, e2)]
        unpol = np.ones(n_rays)
        alive = np.arange(n_rays)
        for k in range(max_bounces + 1):
            s, m = self._next_hit(q[alive], d[alive])
            out = ~np.isfinite(s)
            done = alive[out]
            bounces[done] = k
            exit_dir[done] = d[done]
            alive = alive[~out]
            if k == max_bounces or alive.size == 0:
                break
            s, m = s[~out], m[~out]
            q[alive] += s[:, None] * d[alive]
            n = NORMALS[m]
            dd = d[alive]
            cos_l = -np.einsum("ij,ij->i", dd, n)
            new = dd + 2.0 * cos_l[:, None] * n
            if eta is not None:
                rs, rp = _amplitudes(cos_l, eta)
                unpol[alive] *= 0.5 * (np.abs(rs) ** 2 + np.abs(rp) ** 2)
                sv = np.cross(dd, n)
                sv /= np.linalg.norm(sv, axis=1, keepdims=True)
                p_in = np.cross(sv, dd)
                p_out = np.cross(sv, new)
                for F in E:
                    f = F[alive]
                    es = np.einsum("ij,ij->i", f, sv)
                    ep = np.einsum("ij,ij->i", f, p_in)
                    F[alive] = (rs * es)[:, None] * sv + (rp * ep)[:, None] * p_out
            d[alive] = new
            faces[alive, k] = m
        inten = 0.5 * (np.sum(np.abs(E[0]) ** 2, axis=1) + np.sum(np.abs(E[1]) ** 2, axis=1))
        escaped = bounces >= 0
        return Traced(bounces, exit_dir, faces, np.where(escaped, inten, 0.0), np.where(escaped, unpol, 0.0))


def sequence_codes(faces: np.ndarray, bounces: np.ndarray, depth: int) -> np.ndarray:
    """Code of each ray's face sequence for a table of ``depth`` bounces: rays escaping after
    L <= ``depth`` bounces get ``offset(L) + Σ_i faces[i] 4^(L−1−i)``, rays still inside after
    ``depth`` bounces (escaped later or not at all) ``offset(depth + 1) + code of their first
    ``depth`` faces``, rays that never hit −1 (offset(L) = (4^L − 4)/3: 0, 4, 20, 84, …)."""
    faces = np.asarray(faces)
    bounces = np.asarray(bounces)
    inside = (bounces > depth) | (bounces < 0)
    length = np.where(inside, depth, bounces)
    code = np.zeros(bounces.shape, int)
    for i in range(depth):
        code = np.where(i < length, 4 * code + np.maximum(faces[:, i], 0), code)
    offset = (4 ** (np.where(inside, depth + 1, length)) - 4) // 3
    return np.where(bounces == 0, -1, offset + code)


def fractions(traced: Traced, max_bounces: int) -> np.ndarray:
    """Fractions of the rays escaping after exactly 1 … ``max_bounces`` bounces, then the
    fraction not escaped by then."""
    b = traced.bounces
    n = b.size
    out = [np.count_nonzero(b == k) / n for k in range(1, max_bounces + 1)]
    return np.array(out + [1.0 - sum(out)])
