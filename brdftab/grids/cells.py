"""Cell averages of a BRDF on grids whose tables are constant over cells (Klems, tensor tree).

A Radiance Klems value or tensor-tree leaf is the BSDF of a pair of cells, not of a pair of
directions: brdftab writes the average of f over the outgoing cell (points of equal projected
solid angle, :meth:`outgoing_samples` of the grid) at the incident cell's centre direction. The
writer and the conventions check both use :func:`cell_averages`, so what a table declares
(``cell_samples``) is checked against what it was made from.
"""

from __future__ import annotations

import numpy as np

__all__ = ["cell_averages", "CHUNK"]

#: Direction pairs evaluated per call.
CHUNK = 1 << 20


def cell_averages(brdf, grid, n: int, flat=None, wavelengths=None) -> np.ndarray:
    """``[m, C]``: f of ``brdf`` averaged over the outgoing cell of each flat node (all nodes
    when ``flat`` is None) at the incident cell's centre, ``n × n`` points per cell."""
    flat = np.arange(grid.size) if flat is None else np.asarray(flat, np.intp).ravel()
    s = n * n
    out = None
    step = max(1, CHUNK // s)
    for lo in range(0, flat.size, step):
        wi, wo = grid.outgoing_samples(flat[lo:lo + step], n)
        m = wi.shape[0]
        a = np.repeat(wi, s, axis=0)
        f = np.asarray(brdf.eval(a, wo.reshape(-1, 3), wavelengths, assume_unit=True), float)
        f = f.reshape(m, s, -1).mean(axis=1)
        if out is None:
            out = np.empty((flat.size, f.shape[-1]))
        out[lo:lo + m] = f
    return out
