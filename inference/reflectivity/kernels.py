"""The map's compiled kernels (numba): the depth buffer, splatting sites through the point spread, and its adjoint."""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import NDArray

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]


@numba.njit(cache=True, nogil=True)
def soft_visibility(depth, across, front, cell_m, tol_m, out):  # type: ignore[no-untyped-def]
    """Each site's visibility in [0, 1]: 1 within ``tol_m`` of the nearest front site of its cell (cells of ``cell_m``
    over the plane across the line of sight), falling linearly to 0 a further ``tol_m`` behind it; 0 for sites not
    ``front`` (facing away). ``depth``: larger is nearer the radar."""
    n = depth.shape[0]
    lo0 = np.inf
    lo1 = np.inf
    hi0 = -np.inf
    hi1 = -np.inf
    for i in range(n):
        lo0 = min(lo0, across[i, 0])
        lo1 = min(lo1, across[i, 1])
        hi0 = max(hi0, across[i, 0])
        hi1 = max(hi1, across[i, 1])
    n0 = int((hi0 - lo0) / cell_m) + 1
    n1 = int((hi1 - lo1) / cell_m) + 1
    nearest = np.full(n0 * n1, -np.inf)
    key = np.empty(n, np.int64)
    for i in range(n):
        k = int((across[i, 0] - lo0) / cell_m) * n1 + int((across[i, 1] - lo1) / cell_m)
        key[i] = k
        if front[i] and depth[i] > nearest[k]:
            nearest[k] = depth[i]
    for i in range(n):
        if not front[i]:
            out[i] = 0.0
            continue
        gap = nearest[key[i]] - tol_m - depth[i]
        out[i] = 1.0 if gap <= 0.0 else max(0.0, 1.0 - gap / tol_m)


@numba.njit(cache=True, nogil=True, inline="always")
def _taps(x0, half, over, table, n, out):  # type: ignore[no-untyped-def]
    """The point spread's samples at the pixels within ``half`` of ``x0`` (clipped to 0..n-1) into ``out``; returns
    the first pixel and the count."""
    i0 = max(int(math.ceil(x0 - half)), 0)
    i1 = min(int(math.floor(x0 + half)), n - 1)
    count = max(i1 - i0 + 1, 0)
    last = table.shape[0] - 2
    for t in range(count):
        x = (i0 + t - x0 + half) * over
        m = min(int(x), last)
        f = x - m
        out[t] = (1.0 - f) * table[m] + f * table[m + 1]
    return i0, count


@numba.njit(cache=True, nogil=True)
def splat(u, v, value, table_r, table_a, half_r, half_a, over, r0, c0, out):  # type: ignore[no-untyped-def]
    """Add each site's ``value`` times the separable point spread (``table_r`` x ``table_a``, sampled every
    1/``over`` pixel from -half to +half) about its fractional pixel (u, v) into ``out`` (h, w), whose first pixel is
    (r0, c0) of the frame."""
    h, w = out.shape
    wr = np.empty(int(2 * half_r) + 2)
    wa = np.empty(int(2 * half_a) + 2)
    for k in range(u.shape[0]):
        val = value[k]
        if val == 0.0:
            continue
        i0, ni = _taps(u[k] - r0, half_r, over, table_r, h, wr)
        j0, nj = _taps(v[k] - c0, half_a, over, table_a, w, wa)
        for i in range(ni):
            a = val * wr[i]
            row = out[i0 + i]
            for j in range(nj):
                row[j0 + j] += a * wa[j]


@numba.njit(cache=True, nogil=True)
def gather(u, v, table_r, table_a, half_r, half_a, over, r0, c0, q1, q2, out1, out2):  # type: ignore[no-untyped-def]
    """The adjoint of ``splat`` for two images at once: each site's point spread summed against ``q1`` and ``q2``."""
    h, w = q1.shape
    wr = np.empty(int(2 * half_r) + 2)
    wa = np.empty(int(2 * half_a) + 2)
    for k in range(u.shape[0]):
        i0, ni = _taps(u[k] - r0, half_r, over, table_r, h, wr)
        j0, nj = _taps(v[k] - c0, half_a, over, table_a, w, wa)
        s1 = 0.0
        s2 = 0.0
        for i in range(ni):
            t1 = 0.0
            t2 = 0.0
            for j in range(nj):
                t1 += wa[j] * q1[i0 + i, j0 + j]
                t2 += wa[j] * q2[i0 + i, j0 + j]
            s1 += wr[i] * t1
            s2 += wr[i] * t2
        out1[k] = s1
        out2[k] = s2


@numba.njit(cache=True, nogil=True)
def site_geometry(  # type: ignore[no-untyped-def]
    rot, points, normals, two_sided, los, across, height, cells, centre, u, v, c, depth, plane
):
    """Per site at rotation ``rot`` (body -> observation): fractional pixels ``u``, ``v``; the cosine ``c`` of its
    normal with the line of sight (its magnitude where two-sided); its ``depth`` along the line of sight and its
    coordinates across it (``plane``, for the depth buffer)."""
    lb0 = rot[0, 0] * los[0] + rot[1, 0] * los[1] + rot[2, 0] * los[2]  # the line of sight in the body: R^T los
    lb1 = rot[0, 1] * los[0] + rot[1, 1] * los[1] + rot[2, 1] * los[2]
    lb2 = rot[0, 2] * los[0] + rot[1, 2] * los[1] + rot[2, 2] * los[2]
    for k in range(points.shape[0]):
        p0, p1, p2 = points[k, 0], points[k, 1], points[k, 2]
        o0 = rot[0, 0] * p0 + rot[0, 1] * p1 + rot[0, 2] * p2
        o1 = rot[1, 0] * p0 + rot[1, 1] * p1 + rot[1, 2] * p2
        o2 = rot[2, 0] * p0 + rot[2, 1] * p1 + rot[2, 2] * p2
        d = o0 * los[0] + o1 * los[1] + o2 * los[2]
        a = o0 * across[0] + o1 * across[1] + o2 * across[2]
        depth[k] = d
        plane[k, 0] = a
        plane[k, 1] = o0 * height[0] + o1 * height[1] + o2 * height[2]
        u[k] = d / cells[0] + centre[0]
        v[k] = a / cells[1] + centre[1]
        ck = normals[k, 0] * lb0 + normals[k, 1] * lb1 + normals[k, 2] * lb2
        c[k] = abs(ck) if two_sided[k] else ck
