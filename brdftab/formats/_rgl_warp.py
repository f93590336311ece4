"""Coordinates of RGL ``.bsdf`` files and the warped sample nodes, shared by reader and writer.

Mitsuba's ``measured`` plugin parameterizes directions by u(θ) = sqrt(2θ/π) and
u(φ) = (φ + π)/(2π) (``src/bsdfs/measured.cpp``); a file's N × N stored values of one incident
direction sit at the unit-square nodes (k/(N−1), l/(N−1)), which the ``vndf`` warp of that
direction maps to half vectors (:func:`node_geometry`).
"""

from __future__ import annotations

import numpy as np

from ._marginal2d import Marginal2D

__all__ = ["HALF_PI", "TWO_PI", "theta2u", "u2theta", "phi2u", "u2phi", "elevation", "sph", "bilinear",
           "node_geometry"]

HALF_PI = 0.5 * np.pi
TWO_PI = 2.0 * np.pi


def theta2u(theta):
    return np.sqrt(np.maximum(theta, 0.0) * (2.0 / np.pi))


def u2theta(u):
    return u * u * HALF_PI


def phi2u(phi):
    return (phi + np.pi) / TWO_PI


def u2phi(u):
    return (2.0 * u - 1.0) * np.pi


def elevation(d):
    """Polar angle of unit vectors ``d[..., 3]``, computed as Mitsuba does (2·asin(|d − z|/2))."""
    dist = np.sqrt(d[..., 0] ** 2 + d[..., 1] ** 2 + (d[..., 2] - 1.0) ** 2)
    return 2.0 * np.arcsin(np.clip(0.5 * dist, -1.0, 1.0))


def sph(theta, phi):
    theta, phi = np.broadcast_arrays(np.asarray(theta, float), np.asarray(phi, float))
    s = np.sin(theta)
    return np.stack([s * np.cos(phi), s * np.sin(phi), np.cos(theta)], axis=-1)


def bilinear(table):
    """A plain bilinear interpolant of a 2-D table on the unit square (the ``ndf``, ``sigma`` tables)."""
    return Marginal2D(table, normalize=False, sampling=False)


def node_geometry(vndf: Marginal2D, theta_i, phi_i, n, isotropic):
    """Directions of the stored sample nodes: wi, wo, u_m, each ``[Nφi, Nθi, N, N, ...]``.

    Node (k, l) of slice (a, b) sits at the unit-square point (k/(N−1), l/(N−1)); the ``vndf`` warp
    of that slice maps it to the half-vector coordinates u_m, hence m and ωo = 2(m·ωi)m − ωi.
    """
    n_phi, n_theta = phi_i.size, theta_i.size
    grid = np.arange(n) / (n - 1)
    uy, ux = np.meshgrid(grid, grid, indexing="ij")
    shape = (n_phi, n_theta, n, n)
    nodes = np.stack([np.broadcast_to(ux, shape), np.broadcast_to(uy, shape)], axis=-1).reshape(-1, 2)
    ph = np.broadcast_to(phi_i[:, None, None, None], shape).ravel()
    th = np.broadcast_to(theta_i[None, :, None, None], shape).ravel()
    u_m, _ = vndf.sample(nodes, (ph, th))
    phi_m = u2phi(u_m[:, 1]) + (ph if isotropic else 0.0)
    m = sph(u2theta(u_m[:, 0]), phi_m)
    wi = sph(th, ph)
    wo = 2.0 * np.sum(m * wi, axis=-1, keepdims=True) * m - wi
    return wi, wo, u_m, (th, ph), shape
