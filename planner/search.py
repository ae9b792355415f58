"""Generic event searches over a vectorised function of time (skyfield's find_discrete pattern).

``f(t_s)`` takes an array of seconds and returns an array of values. A search
samples ``f`` on a grid of ``step_s`` (which must be shorter than the shortest
feature to be found), brackets events on that grid, then refines every bracket
at once by vectorised bisection, so the cost is a few dozen calls of ``f`` on
arrays, whatever the number of events.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from planner.errors import SearchRangeError

Vec = NDArray[np.float64]
TimeFunction = Callable[[Vec], Vec]


def time_grid(t0_s: float, t1_s: float, step_s: float) -> Vec:
    """Return a grid from ``t0_s`` to ``t1_s`` inclusive with spacing at most ``step_s``."""
    if not (math.isfinite(t0_s) and math.isfinite(t1_s)) or t1_s <= t0_s:
        raise SearchRangeError(f"search span {t0_s}..{t1_s} s is empty or inverted", field="end")
    if not step_s > 0.0:
        raise SearchRangeError(f"step {step_s} s must be positive", field="step_s")
    n = int(math.ceil((t1_s - t0_s) / step_s)) + 1
    return np.linspace(t0_s, t1_s, n)


def bisect_roots(f: TimeFunction, lo: Vec, hi: Vec, tol_s: float) -> Vec:
    """Refine sign changes of ``f`` inside brackets ``[lo, hi]`` (arrays) to ``tol_s``."""
    lo = np.array(lo, float)
    hi = np.array(hi, float)
    if lo.size == 0:
        return lo
    f_lo = f(lo)
    while np.max(hi - lo) > tol_s:
        mid = 0.5 * (lo + hi)
        f_mid = f(mid)
        same = np.sign(f_mid) == np.sign(f_lo)
        lo = np.where(same, mid, lo)
        f_lo = np.where(same, f_mid, f_lo)
        hi = np.where(same, hi, mid)
    return 0.5 * (lo + hi)


def bisect_maxima(f: TimeFunction, lo: Vec, hi: Vec, tol_s: float, h_s: float = 1e-3) -> Vec:
    """Refine maxima of ``f`` inside brackets where it rises then falls, to ``tol_s``.

    The slope is read from a central difference of half-width ``h_s`` seconds.
    """
    lo = np.array(lo, float)
    hi = np.array(hi, float)
    if lo.size == 0:
        return lo
    while np.max(hi - lo) > tol_s:
        mid = 0.5 * (lo + hi)
        both = f(np.concatenate([mid + h_s, mid - h_s]))
        rising = both[: mid.size] > both[mid.size :]
        lo = np.where(rising, mid, lo)
        hi = np.where(rising, hi, mid)
    return 0.5 * (lo + hi)


def _find_roots_core(f: TimeFunction, t_s: Vec, values: Vec, tol_s: float) -> tuple[Vec, Vec]:
    """Algorithm core for callers that already have ``f`` on a grid ``t_s``.

    Returns ``(t, rising)``: the root times and whether ``f`` goes from negative to
    positive there.
    """
    positive = values > 0.0
    idx = np.flatnonzero(positive[1:] != positive[:-1])
    roots = bisect_roots(f, t_s[idx], t_s[idx + 1], tol_s)
    return roots, ~positive[idx]


def find_roots(f: TimeFunction, t0_s: float, t1_s: float, step_s: float, tol_s: float = 1e-4) -> tuple[Vec, Vec]:
    """Return the times where ``f`` changes sign in ``[t0_s, t1_s]`` and the direction of each.

    >>> t, rising = find_roots(np.sin, 0.5, 10.0, 0.5, tol_s=1e-9)
    >>> np.round(t / np.pi, 6).tolist(), rising.tolist()
    ([1.0, 2.0, 3.0], [False, True, False])
    """
    t = time_grid(t0_s, t1_s, step_s)
    return _find_roots_core(f, t, f(t), tol_s)


def _find_maxima_core(f: TimeFunction, t_s: Vec, values: Vec, tol_s: float) -> tuple[Vec, Vec]:
    """Algorithm core of find_maxima for callers that already have ``f`` on a grid."""
    if t_s.size < 3:
        return np.empty(0), np.empty(0)
    interior = np.flatnonzero((values[1:-1] >= values[:-2]) & (values[1:-1] > values[2:])) + 1
    t_max = bisect_maxima(f, t_s[interior - 1], t_s[interior + 1], tol_s)
    return t_max, f(t_max) if t_max.size else np.empty(0)


def find_maxima(f: TimeFunction, t0_s: float, t1_s: float, step_s: float, tol_s: float = 1e-4) -> tuple[Vec, Vec]:
    """Return the times and values of the local maxima of ``f`` strictly inside ``[t0_s, t1_s]``.

    >>> t, v = find_maxima(np.cos, 1.0, 20.0, 0.5, tol_s=1e-7)
    >>> np.round(t / np.pi, 5).tolist(), np.round(v, 9).tolist()
    ([2.0, 4.0, 6.0], [1.0, 1.0, 1.0])
    """
    t = time_grid(t0_s, t1_s, step_s)
    return _find_maxima_core(f, t, f(t), tol_s)
