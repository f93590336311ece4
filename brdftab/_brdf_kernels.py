"""The compiled prologue every compiled BRDF evaluation shares (:meth:`brdftab.brdf.BRDF.eval`).

One pass over the pairs sorts them into the three cases of the BRDF protocol: above the
horizon (evaluated), at or below it (0) and non-finite (NaN), and counts the directions that
are not unit (normalized by :func:`brdftab.brdf._unit`, the numpy rule, before the model's kernel
runs; exactly unit ones are left untouched, as there).
"""

from __future__ import annotations

import math

from ._jit import kernel

#: ``state`` values: the pair is at or below the horizon (f = 0), above it (evaluated), or has a
#: non-finite component (f = NaN).
BELOW, ABOVE, NONFINITE = 0, 1, 2


@kernel
def prepare(wi, wo, state, out, assume_unit, horizon):
    """Fill ``state[M]`` for the pairs ``wi``, ``wo[M, 3]``, NaN the rows of ``out`` whose
    directions are not finite, and return how many rows are not unit (0 with ``assume_unit``,
    which also skips the finiteness test: grid nodes)."""
    off = 0
    nc = out.shape[1]
    for i in range(wi.shape[0]):
        if assume_unit:
            state[i] = 1 if (wi[i, 2] > horizon and wo[i, 2] > horizon) else 0
            continue
        finite = True
        for j in range(3):
            if not (math.isfinite(wi[i, j]) and math.isfinite(wo[i, j])):
                finite = False
        if not finite:
            state[i] = 2
            for c in range(nc):
                out[i, c] = math.nan
            continue
        ni = math.sqrt(wi[i, 0] * wi[i, 0] + wi[i, 1] * wi[i, 1] + wi[i, 2] * wi[i, 2])
        no = math.sqrt(wo[i, 0] * wo[i, 0] + wo[i, 1] * wo[i, 1] + wo[i, 2] * wo[i, 2])
        if abs(ni - 1.0) > 1e-12 or abs(no - 1.0) > 1e-12:
            off += 1
        state[i] = 1 if (wi[i, 2] > horizon and wo[i, 2] > horizon) else 0
    return off


@kernel
def scale_rows(state, out, s):
    """``out[i] *= s`` on the evaluated rows (``s[n]`` per channel)."""
    nc = out.shape[1]
    for i in range(state.shape[0]):
        if state[i] == 1:
            for c in range(nc):
                out[i, c] *= s[c]


@kernel
def add_scaled(state, out, part, s):
    """``out[i] += part[i] * s`` on the evaluated rows."""
    nc = out.shape[1]
    for i in range(state.shape[0]):
        if state[i] == 1:
            for c in range(nc):
                out[i, c] += part[i, c] * s[c]


@kernel
def constant_rows(state, out, value, add):
    """``out[i] = value`` (or ``+=`` with ``add``) on the evaluated rows (``value[n]``)."""
    nc = out.shape[1]
    for i in range(state.shape[0]):
        if state[i] == 1:
            for c in range(nc):
                if add:
                    out[i, c] += value[c]
                else:
                    out[i, c] = value[c]
