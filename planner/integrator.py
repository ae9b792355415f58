"""Two-body + J2 motion integrated by DOP853 in compiled code (numba): the force model and the stepping alike.

scipy's Fortran DOP853 steps in compiled code but calls the right-hand side in Python, 2.5 us a call and ~12
calls a step: a 30-day LEO integration cost about half a second, and a plan makes several. Here the whole
integration is one compiled call: 9 ms for those 30 days (design/measurements.md, "A compiled J2 integrator").

The method is Dormand and Prince's 8(5,3) pair as Hairer, Norsett and Wanner give it (Solving Ordinary
Differential Equations I, 2nd ed., section II.10), with its coefficients from scipy
(``scipy.integrate._ivp.dop853_coefficients``), and the step control of scipy's ``solve_ivp(method="DOP853")``:
the error norm of the 5th- and 3rd-order estimates combined, scaled by ``atol + rtol |y|``; a safety factor
0.9 and a step change between 0.2x and 10x (never up after a rejected step); the first step by Hairer's rule.
J2 acts about a pole that moves as a quadratic in time (``planner.propagation.Pole``). Every accepted step's
time and state are returned, for dense output by quintic Hermite interpolation.
"""

from __future__ import annotations

import math
import threading
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.integrate._ivp import dop853_coefficients as _dop

from planner.constants import J2, MU_EARTH_KM3_S2, R_EARTH_KM

Vec = NDArray[np.float64]

_STAGES = _dop.N_STAGES
_A = np.ascontiguousarray(_dop.A[:_STAGES, :_STAGES])
_B = np.ascontiguousarray(_dop.B)
_C = np.ascontiguousarray(_dop.C[:_STAGES])
_E3 = np.ascontiguousarray(_dop.E3)
_E5 = np.ascontiguousarray(_dop.E5)
_F = 1.5 * J2 * MU_EARTH_KM3_S2 * R_EARTH_KM**2
_MU = MU_EARTH_KM3_S2
SAFETY, MIN_FACTOR, MAX_FACTOR = 0.9, 0.2, 10.0
ERROR_EXPONENT = -1.0 / 8.0  # the error estimator's order is 7


def _rhs(t: float, y: Vec, pole: Vec, t_mid: float, out: Vec) -> None:  # pragma: no cover - compiled
    dt = t - t_mid
    px = pole[0, 0] + dt * (pole[0, 1] + dt * pole[0, 2])
    py = pole[1, 0] + dt * (pole[1, 1] + dt * pole[1, 2])
    pz = pole[2, 0] + dt * (pole[2, 1] + dt * pole[2, 2])
    inv = 1.0 / math.sqrt(px * px + py * py + pz * pz)
    px, py, pz = px * inv, py * inv, pz * inv
    x, yy, z = y[0], y[1], y[2]
    r2 = x * x + yy * yy + z * z
    r = math.sqrt(r2)
    k = -_MU / (r2 * r)
    f = _F / (r2 * r2 * r)
    zp = px * x + py * yy + pz * z
    q = 5.0 * zp * zp / r2 - 1.0
    n = 2.0 * zp
    out[0], out[1], out[2] = y[3], y[4], y[5]
    out[3] = k * x + f * (q * x - n * px)
    out[4] = k * yy + f * (q * yy - n * py)
    out[5] = k * z + f * (q * z - n * pz)


def _norm(v: Vec, scale: Vec) -> float:  # pragma: no cover - compiled
    s = 0.0
    for i in range(v.size):
        s += (v[i] / scale[i]) ** 2
    return math.sqrt(s / v.size)


def _dop853(
    y0: Vec,
    t0: float,
    t1: float,
    rtol: float,
    atol: float,
    pole: Vec,
    t_mid: float,
    max_steps: int,
    a: Vec,
    b: Vec,
    c: Vec,
    e3: Vec,
    e5: Vec,
) -> tuple[Vec, Vec, int]:  # pragma: no cover - compiled
    n = y0.size
    stages = b.size
    direction = 1.0 if t1 >= t0 else -1.0
    k = np.zeros((stages + 1, n))
    y = y0.copy()
    f0 = np.empty(n)
    _rhs(t0, y, pole, t_mid, f0)
    # Hairer's first step: from the sizes of y and f, then of the second derivative over one trial step.
    scale = atol + np.abs(y) * rtol
    d0, d1 = _norm(y, scale), _norm(f0, scale)
    h0 = 1e-6 if (d0 < 1e-5 or d1 < 1e-5) else 0.01 * d0 / d1
    y1 = y + direction * h0 * f0
    f1 = np.empty(n)
    _rhs(t0 + direction * h0, y1, pole, t_mid, f1)
    d2 = _norm(f1 - f0, scale) / h0
    h1 = max(1e-6, h0 * 1e-3) if (d1 <= 1e-15 and d2 <= 1e-15) else (0.01 / max(d1, d2)) ** (1.0 / 8.0)
    h_abs = min(100.0 * h0, h1, abs(t1 - t0))

    cap = 1024
    ts = np.empty(cap)
    ys = np.empty((cap, n))
    ts[0] = t0
    ys[0] = y
    count = 1
    t = t0
    f = f0
    y_new = np.empty(n)
    f_new = np.empty(n)
    stage_y = np.empty(n)
    err3 = np.empty(n)
    err5 = np.empty(n)
    steps = 0
    while direction * (t1 - t) > 0.0:
        if steps >= max_steps:
            return ts[:count].copy(), ys[:count].copy(), 1
        steps += 1
        rejected = False
        while True:
            remaining = abs(t1 - t)
            h_abs = min(h_abs, remaining)
            h = direction * h_abs
            # The error control shrank the step below what the times can hold (the end's own short step is fine).
            if h_abs < remaining and h_abs < 1e-12 * max(1.0, abs(t)):
                return ts[:count].copy(), ys[:count].copy(), 2
            k[0] = f
            for s in range(1, stages):
                for i in range(n):
                    acc = 0.0
                    for j in range(s):
                        acc += a[s, j] * k[j, i]
                    stage_y[i] = y[i] + h * acc
                _rhs(t + c[s] * h, stage_y, pole, t_mid, k[s])
            for i in range(n):
                acc = 0.0
                for j in range(stages):
                    acc += b[j] * k[j, i]
                y_new[i] = y[i] + h * acc
            _rhs(t + h, y_new, pole, t_mid, f_new)
            k[stages] = f_new
            for i in range(n):
                sc = atol + max(abs(y[i]), abs(y_new[i])) * rtol
                a3 = 0.0
                a5 = 0.0
                for j in range(stages + 1):
                    a3 += e3[j] * k[j, i]
                    a5 += e5[j] * k[j, i]
                err3[i] = a3 / sc
                err5[i] = a5 / sc
            e5n = 0.0
            e3n = 0.0
            for i in range(n):
                e5n += err5[i] * err5[i]
                e3n += err3[i] * err3[i]
            if e5n == 0.0 and e3n == 0.0:
                error = 0.0
            else:
                error = h_abs * e5n / math.sqrt((e5n + 0.01 * e3n) * n)
            if error < 1.0:
                factor = MAX_FACTOR if error == 0.0 else min(MAX_FACTOR, SAFETY * error**ERROR_EXPONENT)
                if rejected:
                    factor = min(1.0, factor)
                t = t + h
                y[:] = y_new
                f = f_new.copy()
                h_abs *= factor
                break
            h_abs *= max(MIN_FACTOR, SAFETY * error**ERROR_EXPONENT)
            rejected = True
        if count == cap:
            cap *= 2
            ts2 = np.empty(cap)
            ys2 = np.empty((cap, n))
            ts2[:count] = ts[:count]
            ys2[:count] = ys[:count]
            ts, ys = ts2, ys2
        ts[count] = t
        ys[count] = y
        count += 1
    return ts[:count].copy(), ys[:count].copy(), 0


def _hermite(grid: Vec, r: Vec, v: Vec, a: Vec, t: Vec, r_out: Vec, v_out: Vec) -> None:  # pragma: no cover - compiled
    """Quintic Hermite interpolation of position, velocity and acceleration between the integrator's steps."""
    n = grid.size
    for i in range(t.size):
        k = np.searchsorted(grid, t[i], side="right") - 1
        k = min(max(k, 0), n - 2)
        h = grid[k + 1] - grid[k]
        s = (t[i] - grid[k]) / h
        s2 = s * s
        s3 = s2 * s
        s4 = s3 * s
        s5 = s4 * s
        c_p0 = 1 - 10 * s3 + 15 * s4 - 6 * s5
        c_v0 = s - 6 * s3 + 8 * s4 - 3 * s5
        c_a0 = 0.5 * s2 - 1.5 * s3 + 1.5 * s4 - 0.5 * s5
        c_a1 = 0.5 * s3 - s4 + 0.5 * s5
        c_v1 = -4 * s3 + 7 * s4 - 3 * s5
        c_p1 = 10 * s3 - 15 * s4 + 6 * s5
        d_p0 = -30 * s2 + 60 * s3 - 30 * s4
        d_v0 = 1 - 18 * s2 + 32 * s3 - 15 * s4
        d_a0 = s - 4.5 * s2 + 6 * s3 - 2.5 * s4
        d_a1 = 1.5 * s2 - 4 * s3 + 2.5 * s4
        d_v1 = -12 * s2 + 28 * s3 - 15 * s4
        d_p1 = 30 * s2 - 60 * s3 + 30 * s4
        for j in range(3):
            p0, p1 = r[j, k], r[j, k + 1]
            v0, v1 = v[j, k] * h, v[j, k + 1] * h
            a0, a1 = a[j, k] * h * h, a[j, k + 1] * h * h
            r_out[j, i] = c_p0 * p0 + c_v0 * v0 + c_a0 * a0 + c_a1 * a1 + c_v1 * v1 + c_p1 * p1
            v_out[j, i] = (d_p0 * p0 + d_v0 * v0 + d_a0 * a0 + d_a1 * a1 + d_v1 * v1 + d_p1 * p1) / h


_KERNEL: Any = None
_HERMITE: Any = None
_COMPILE = threading.Lock()


def _compiled() -> Any:
    """The integrator compiled by numba (or loaded from numba's cache beside this module) on first use.

    Importing numba costs about 0.4 s that the service's light entry points (``gsa --help``, ``import app.main``)
    must not pay, so it is imported here; the helpers are compiled as module globals, which is how the
    integrator's own compiled code finds them. A lock makes the first use safe from the service's threads: two
    plans arriving together once both replaced ``_norm``, the second jitting the first's dispatcher (a 500).
    """
    global _KERNEL
    with _COMPILE:
        if _KERNEL is None:
            import numba

            jit = numba.njit(cache=True, nogil=True)
            here = globals()
            here["_rhs"] = jit(_rhs)
            here["_norm"] = jit(_norm)
            _KERNEL = jit(_dop853)
        return _KERNEL


def _hermite_kernel() -> Any:
    """The quintic Hermite interpolant compiled on first use, under the same lock as the integrator."""
    global _HERMITE
    with _COMPILE:
        if _HERMITE is None:
            import numba

            _HERMITE = numba.njit(cache=True, nogil=True)(_hermite)
        return _HERMITE


def hermite_state(grid: Vec, r: Vec, v: Vec, a: Vec, t: Vec) -> tuple[Vec, Vec]:
    """Position and velocity (3, N) at ``t`` (N,) between steps ``grid`` of states ``r``, ``v``, ``a`` (3, M): the
    quintic Hermite interpolant through position, velocity and acceleration at the step's two ends, compiled."""
    r_out = np.empty((3, t.size))
    v_out = np.empty((3, t.size))
    _hermite_kernel()(grid, r, v, a, np.ascontiguousarray(t, float), r_out, v_out)
    return r_out, v_out


NO_POLE = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])


def integrate_j2(
    y0: Vec,
    t0_s: float,
    t1_s: float,
    rtol: float,
    atol: float,
    pole_c: Vec | None = None,
    t_mid_s: float = 0.0,
    max_steps: int = 10**7,
) -> tuple[Vec, Vec, int]:
    """Integrate two-body + J2 from ``y0`` (km, km/s; shape (6,)) at ``t0_s`` to ``t1_s`` (either way).

    J2 acts about the pole ``c[:, 0] + c[:, 1] dt + c[:, 2] dt^2`` (``dt = t - t_mid_s``; GCRS z without one).
    Returns every accepted step's time (N,) and state (N, 6), with a status: 0 done, 1 too many steps, 2 the
    step fell under what the times can hold (the orbit decayed or diverged).
    """
    pole = NO_POLE if pole_c is None else np.ascontiguousarray(pole_c, float)
    result: tuple[Vec, Vec, int] = _compiled()(
        np.ascontiguousarray(y0, float),
        float(t0_s),
        float(t1_s),
        float(rtol),
        float(atol),
        pole,
        float(t_mid_s),
        int(max_steps),
        _A,
        _B,
        _C,
        _E3,
        _E5,
    )
    return result
