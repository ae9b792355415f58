"""The simulator's compiled kernels (numba), imported only where they run: the physical-optics echo and the
multi-column NUFFT it uses. The default physics never imports this module, so it stays numpy and scipy only.
"""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def spread_columns(l_r0, l_a0, g_r, g_a, c, grid):  # type: ignore[no-untyped-def]
    """Add each source's columns ``c[k, :]`` times its separable Gaussian taps into ``grid`` (big_r, big_a, P)."""
    big_r, big_a, n_col = grid.shape
    taps = g_r.shape[1]
    for k in range(c.shape[0]):
        for i in range(taps):
            r = (l_r0[k] + i) % big_r
            wr = g_r[k, i]
            for j in range(taps):
                a = (l_a0[k] + j) % big_a
                w = wr * g_a[k, j]
                for p in range(n_col):
                    grid[r, a, p] += w * c[k, p]


@numba.njit(cache=True, nogil=True)
def node_integrals(rel, k0, dk_r, dk_a, nodes, weight, out):  # type: ignore[no-untyped-def]
    """``out[f, i * n + j] = weight[f] * triangle_integral(rel[f], k0 + nodes[i] dk_r + nodes[j] dk_a)``, compiled.

    The same formula as ``triangle_integral`` (divided difference of exp, the most different pair
    as the denominator), each facet's corner phases projected once and stepped to every node.
    """
    n = nodes.shape[0]
    t = np.empty(3)
    for f in range(rel.shape[0]):
        e1 = rel[f, 1] - rel[f, 0]
        e2 = rel[f, 2] - rel[f, 0]
        cx = e1[1] * e2[2] - e1[2] * e2[1]
        cy = e1[2] * e2[0] - e1[0] * e2[2]
        cz = e1[0] * e2[1] - e1[1] * e2[0]
        two_area = math.sqrt(cx * cx + cy * cy + cz * cz)
        base = -(rel[f] @ k0)
        step_r = -(rel[f] @ dk_r)
        step_a = -(rel[f] @ dk_a)
        for i in range(n):
            for j in range(n):
                for c in range(3):
                    t[c] = base[c] + nodes[i] * step_r[c] + nodes[j] * step_a[c]
                d01, d12, d20 = abs(t[0] - t[1]), abs(t[1] - t[2]), abs(t[2] - t[0])
                if d12 >= d01 and d12 >= d20:
                    r = 0
                elif d20 >= d01:
                    r = 1
                else:
                    r = 2
                tr = t[r]
                tp = t[(r + 1) % 3] - tr
                tq = t[(r + 2) % 3] - tr
                gap = tq - tp
                if abs(gap) < 1e-6:
                    dd = 0.5 + 1j * (tp + tq) / 6.0
                else:
                    dd = (phi1(tq) - phi1(tp)) / (1j * gap)
                out[f, i * n + j] = weight[f] * two_area * np.exp(1j * tr) * dd


@numba.njit(cache=True, nogil=True)
def phi1(t):  # type: ignore[no-untyped-def]
    half = 0.5 * t
    s = 1.0 if abs(half) < 1e-12 else math.sin(half) / half
    return np.exp(1j * half) * s
