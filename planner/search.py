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
    """Refine sign changes of ``f`` inside brackets ``[lo, hi]`` (arrays) to ``tol_s``.

    Regula falsi with the Illinois modification, vectorised over brackets: the
    bracket always holds the root, and it usually converges in 5-8 calls of ``f``
    where bisection needs 20. Stops once every bracket is under ``tol_s`` or the
    last false-position step moved less than ``tol_s / 10`` (the convergence is
    superlinear, so the error is then far below ``tol_s``).
    """
    lo = np.array(lo, float)
    hi = np.array(hi, float)
    if lo.size == 0:
        return lo
    f_lo, f_hi = f(lo), f(hi)
    x = np.full(lo.size, np.nan)  # no previous estimate: the first step never counts as converged
    side = np.zeros(lo.size, int)
    done = np.zeros(lo.size, bool)
    for _ in range(100):
        denom = f_hi - f_lo
        safe = np.abs(denom) > 0
        x_new = np.where(safe, (lo * f_hi - hi * f_lo) / np.where(safe, denom, 1.0), 0.5 * (lo + hi))
        x_new = np.where((x_new > lo) & (x_new < hi), x_new, 0.5 * (lo + hi))
        x_new = np.where(f_lo == 0, lo, np.where(f_hi == 0, hi, x_new))
        moved = np.abs(x_new - x)
        x = np.where(done, x, x_new)
        # A bracket that has converged keeps its root: each root is what it would be refined alone, whatever
        # else is refined beside it (a station's passes come out the same in a network).
        done |= (hi - lo <= tol_s) | (moved < tol_s * 0.1) | (f_lo == 0) | (f_hi == 0)
        if np.all(done):
            break
        f_x = f(x)
        left = (np.sign(f_x) == np.sign(f_lo)) & ~done
        right = ~left & ~done
        # Illinois: halve the stale end's value when the same side moves twice running.
        f_hi = np.where(left & (side == 1), 0.5 * f_hi, f_hi)
        f_lo = np.where(right & (side == -1), 0.5 * f_lo, f_lo)
        lo = np.where(left, x, lo)
        f_lo = np.where(left, f_x, f_lo)
        hi = np.where(right, x, hi)
        f_hi = np.where(right, f_x, f_hi)
        side = np.where(left, 1, np.where(right, -1, side))
    return x


def bisect_maxima(
    f: TimeFunction | Callable[[Vec, NDArray[np.int64]], Vec],
    lo: Vec,
    hi: Vec,
    tol_s: float,
    h_s: float = 1e-3,
    key: NDArray[np.int64] | None = None,
) -> Vec:
    """Refine maxima of ``f`` inside brackets where it rises then falls, to ``tol_s``.

    The slope is read from a central difference of half-width ``h_s`` seconds, and
    its zero found by ``bisect_roots`` (so in a handful of calls of ``f``). With
    ``key``, ``f(t, key)`` is a family of functions, bracket ``m`` being of member
    ``key[m]`` (a station of a network, say), all refined together.
    """
    lo = np.array(lo, float)
    hi = np.array(hi, float)
    if lo.size == 0:
        return lo

    def slope(t: Vec) -> Vec:
        at = np.concatenate([t + h_s, t - h_s])
        both = f(at) if key is None else f(at, np.concatenate([key, key]))  # type: ignore[call-arg]
        return both[: t.size] - both[t.size :]

    return bisect_roots(slope, lo, hi, tol_s)


def _find_roots_core(f: TimeFunction, t_s: Vec, values: Vec, tol_s: float) -> tuple[Vec, NDArray[np.bool_]]:
    """Algorithm core for callers that already have ``f`` on a grid ``t_s``.

    Returns ``(t, rising)``: the root times and whether ``f`` goes from negative to
    positive there.
    """
    positive = values > 0.0
    idx = np.flatnonzero(positive[1:] != positive[:-1])
    roots = bisect_roots(f, t_s[idx], t_s[idx + 1], tol_s)
    return roots, ~positive[idx]


def find_roots(
    f: TimeFunction, t0_s: float, t1_s: float, step_s: float, tol_s: float = 1e-4
) -> tuple[Vec, NDArray[np.bool_]]:
    """Return the times where ``f`` changes sign in ``[t0_s, t1_s]`` and the direction of each.

    >>> t, rising = find_roots(np.sin, 0.5, 10.0, 0.5, tol_s=1e-9)
    >>> np.round(t / np.pi, 6).tolist(), rising.tolist()
    ([1.0, 2.0, 3.0], [False, True, False])
    """
    t = time_grid(t0_s, t1_s, step_s)
    return _find_roots_core(f, t, f(t), tol_s)


KeyedFunction = Callable[[Vec, NDArray[np.int64]], Vec]
Keys = NDArray[np.int64]


def grid_maxima(
    f: TimeFunction,
    t_s: Vec,
    values: Vec,
    tol_s: float,
    select: NDArray[np.bool_] | None = None,
    include_ends: bool = False,
    h_s: float = 1e-3,
) -> tuple[Vec, Vec]:
    """Refine the local maxima of ``f`` sampled as ``values`` on the grid ``t_s``; return ``(t, f(t))``.

    Algorithm core of find_maxima, for callers that already have ``f`` on a grid: ``keyed_maxima`` of one row. An
    interior maximum is bracketed by its grid neighbours; only grid points where ``select`` holds are refined. With
    ``include_ends``, a maximum hiding inside the first (last) step while the grid falls away from it is found from
    the one-sided slope there (a pass peaking just after the span starts).
    """
    one = np.zeros(1, np.int64)
    t_max, _, v_max = keyed_maxima(
        lambda t, _k: f(t),
        t_s,
        np.asarray(values, float)[None, :],
        one,
        tol_s,
        None if select is None else np.asarray(select, bool)[None, :],
        include_ends,
        h_s,
    )
    return t_max, v_max


def keyed_maxima(
    f: KeyedFunction,
    t: Vec,
    g: Vec,
    keys: Keys,
    tol_s: float,
    select: NDArray[np.bool_] | None = None,
    include_ends: bool = True,
    h_s: float = 1e-3,
) -> tuple[Vec, Keys, Vec]:
    """The local maxima of ``f`` sampled as ``g`` (rows: members ``keys`` of the family ``f(t, key)``, a network's
    stations) on the grid ``t``: ``(t, key, f)``.

    An interior maximum is bracketed by its grid neighbours (only where ``select`` holds), and, with
    ``include_ends``, a maximum hiding in the first or last step while the grid falls away from it is found from the
    one-sided slope there. Every bracket of every row is refined in one vectorised search (``bisect_maxima``).
    """
    if t.size < 2:
        return np.empty(0), np.zeros(0, np.int64), np.empty(0)
    select = np.ones(g.shape, bool) if select is None else select
    rows, i = np.nonzero((g[:, 1:-1] >= g[:, :-2]) & (g[:, 1:-1] > g[:, 2:]) & select[:, 1:-1])
    lo, hi, key = [t[i]], [t[i + 2]], [keys[rows]]
    for end, inner, sign in ((0, 1, 1.0), (-1, -2, -1.0)) if include_ends else ():
        edge = keys[(g[:, end] > g[:, inner]) & select[:, end]]
        if edge.size:
            at = np.concatenate([np.full(edge.size, t[end]), np.full(edge.size, t[end] + sign * 2.0 * h_s)])
            s = f(at, np.concatenate([edge, edge]))
            rising_inward = s[edge.size :] > s[: edge.size]
            edge = edge[rising_inward]
            near, far = np.full(edge.size, t[end] + sign * h_s), np.full(edge.size, t[inner])
            lo.append(near if sign > 0 else far)
            hi.append(far if sign > 0 else near)
            key.append(edge)
    lo_a, hi_a, key_a = np.concatenate(lo), np.concatenate(hi), np.concatenate(key).astype(np.int64)
    if not lo_a.size:
        return np.empty(0), np.zeros(0, np.int64), np.empty(0)
    t_max = bisect_maxima(f, lo_a, hi_a, tol_s, h_s=h_s, key=key_a)
    return t_max, key_a, f(t_max, key_a)


def find_maxima(f: TimeFunction, t0_s: float, t1_s: float, step_s: float, tol_s: float = 1e-4) -> tuple[Vec, Vec]:
    """Return the times and values of the local maxima of ``f`` strictly inside ``[t0_s, t1_s]``.

    >>> t, v = find_maxima(np.cos, 1.0, 20.0, 0.5, tol_s=1e-7)
    >>> np.round(t / np.pi, 5).tolist(), np.round(v, 9).tolist()
    ([2.0, 4.0, 6.0], [1.0, 1.0, 1.0])
    """
    t = time_grid(t0_s, t1_s, step_s)
    return grid_maxima(f, t, f(t), tol_s)
