"""Lambert's problem by Izzo's method (Izzo 2015, "Revisiting Lambert's problem", CMDA 121).

Householder iterations on Lagrange's time-of-flight equation in Izzo's x variable,
with Halley iterations for the minimum time of the multi-revolution branches. A
port of the algorithm as published, checked against Vallado's example 7-5 and by
round trips through two-body propagation (tests/planner/test_lambert.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from planner.constants import MU_EARTH_KM3_S2
from planner.errors import LambertError

Vec = NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class LambertSolution:
    """Departure and arrival velocities (km/s) of one branch, with its revolution count."""

    v1_km_s: Vec
    v2_km_s: Vec
    revolutions: int
    low_path: bool


def lambert(
    r1_km: ArrayLike,
    r2_km: ArrayLike,
    tof_s: float,
    revolutions: int = 0,
    low_path: bool = True,
    prograde_normal: ArrayLike = (0.0, 0.0, 1.0),
    mu_km3_s2: float = MU_EARTH_KM3_S2,
    max_iter: int = 35,
    rtol: float = 1e-10,
) -> LambertSolution:
    """Solve Lambert's problem: the conic from ``r1`` to ``r2`` in ``tof_s`` with ``revolutions`` full turns.

    The transfer runs in the sense of ``prograde_normal`` (the z axis by default;
    pass the departure orbit's angular momentum to stay in its sense). With
    ``revolutions`` > 0 there are two solutions; ``low_path`` picks one.

    >>> s = lambert([15945.34, 0, 0], [12214.83899, 10249.46731, 0], 76 * 60.0)
    >>> np.round(s.v1_km_s, 4).tolist()
    [2.0589, 2.916, 0.0]
    """
    r1 = np.asarray(r1_km, float)
    r2 = np.asarray(r2_km, float)
    if not (tof_s > 0.0 and math.isfinite(tof_s)):
        raise LambertError(f"time of flight {tof_s} s must be positive", field="tof_s")
    if revolutions < 0:
        raise LambertError(f"revolutions {revolutions} must be >= 0", field="revolutions")
    c = r2 - r1
    c_norm, r1_norm, r2_norm = float(np.linalg.norm(c)), float(np.linalg.norm(r1)), float(np.linalg.norm(r2))
    s = 0.5 * (r1_norm + r2_norm + c_norm)
    i_r1, i_r2 = r1 / r1_norm, r2 / r2_norm
    i_h = np.cross(i_r1, i_r2)
    h_norm = float(np.linalg.norm(i_h))
    if h_norm < 1e-12:
        raise LambertError("r1 and r2 are collinear: the transfer plane is undefined", field="r2_km")
    i_h = i_h / h_norm
    lam = math.sqrt(max(0.0, 1.0 - min(1.0, c_norm / s)))
    if float(np.dot(i_h, np.asarray(prograde_normal, float))) < 0.0:
        lam = -lam
        i_h = -i_h
    i_t1, i_t2 = np.cross(i_h, i_r1), np.cross(i_h, i_r2)
    t_nd = math.sqrt(2.0 * mu_km3_s2 / s**3) * tof_s
    x = _find_x(lam, t_nd, revolutions, low_path, max_iter, rtol)
    y = math.sqrt(1.0 - lam**2 * (1.0 - x**2))
    gamma = math.sqrt(mu_km3_s2 * s / 2.0)
    rho = (r1_norm - r2_norm) / c_norm
    sigma = math.sqrt(max(0.0, 1.0 - rho**2))
    vr1 = gamma * ((lam * y - x) - rho * (lam * y + x)) / r1_norm
    vr2 = -gamma * ((lam * y - x) + rho * (lam * y + x)) / r2_norm
    vt1 = gamma * sigma * (y + lam * x) / r1_norm
    vt2 = gamma * sigma * (y + lam * x) / r2_norm
    return LambertSolution(vr1 * i_r1 + vt1 * i_t1, vr2 * i_r2 + vt2 * i_t2, revolutions, low_path)


def max_revolutions(r1_km: ArrayLike, r2_km: ArrayLike, tof_s: float, mu_km3_s2: float = MU_EARTH_KM3_S2) -> int:
    """Return the largest number of full revolutions for which a transfer in ``tof_s`` exists."""
    r1 = np.asarray(r1_km, float)
    r2 = np.asarray(r2_km, float)
    c = float(np.linalg.norm(r2 - r1))
    s = 0.5 * (float(np.linalg.norm(r1)) + float(np.linalg.norm(r2)) + c)
    lam = math.sqrt(max(0.0, 1.0 - min(1.0, c / s)))
    t_nd = math.sqrt(2.0 * mu_km3_s2 / s**3) * tof_s
    m_max = int(t_nd // math.pi)
    t00 = math.acos(lam) + lam * math.sqrt(1.0 - lam**2)
    if m_max > 0 and t_nd < t00 + m_max * math.pi:
        x_min = _halley_tmin(0.1, lam, m_max, 1e-12, 50)
        if t_nd < _tof(x_min, lam, m_max):
            m_max -= 1
    return m_max


def _hyp2f1b(x: float) -> float:
    """Return the hypergeometric function 2F1(3, 1, 5/2, x) by its series."""
    if x >= 1.0:
        return math.inf
    res, term, k = 1.0, 1.0, 0
    while True:
        term = term * (3 + k) * (1 + k) / (2.5 + k) * x / (k + 1)
        old = res
        res += term
        if res == old:
            return res
        k += 1


def _tof(x: float, lam: float, m: int) -> float:
    """Return the non-dimensional time of flight at ``x`` (Izzo's eq. 18, series near x = 1)."""
    y = math.sqrt(1.0 - lam**2 * (1.0 - x**2))
    if m == 0 and math.sqrt(0.6) < x < math.sqrt(1.4):
        eta = y - lam * x
        s1 = 0.5 * (1.0 - lam - x * eta)
        q = 4.0 / 3.0 * _hyp2f1b(s1)
        return 0.5 * (eta**3 * q + 4.0 * lam * eta)
    if -1.0 <= x < 1.0:
        psi = math.acos(max(-1.0, min(1.0, x * y + lam * (1.0 - x**2))))
    elif x > 1.0:
        psi = math.asinh((y - x * lam) * math.sqrt(x**2 - 1.0))
    else:
        psi = 0.0
    return ((psi + m * math.pi) / math.sqrt(abs(1.0 - x**2)) - x + lam * y) / (1.0 - x**2)


def _derivatives(x: float, t: float, lam: float) -> tuple[float, float, float]:
    y = math.sqrt(1.0 - lam**2 * (1.0 - x**2))
    d1 = (3.0 * t * x - 2.0 + 2.0 * lam**3 * x / y) / (1.0 - x**2)
    d2 = (3.0 * t + 5.0 * x * d1 + 2.0 * (1.0 - lam**2) * lam**3 / y**3) / (1.0 - x**2)
    d3 = (7.0 * x * d2 + 8.0 * d1 - 6.0 * (1.0 - lam**2) * lam**5 * x / y**5) / (1.0 - x**2)
    return d1, d2, d3


def _halley_tmin(x0: float, lam: float, m: int, tol: float, max_iter: int) -> float:
    """Return x of the minimum time of flight of the ``m``-revolution branch (Halley on dT/dx = 0)."""
    x = x0
    for _ in range(max_iter):
        t = _tof(x, lam, m)
        d1, d2, d3 = _derivatives(x, t, lam)
        if d2 == 0.0:
            break
        x_new = x - 2.0 * d1 * d2 / (2.0 * d2**2 - d1 * d3)
        if abs(x_new - x) < tol:
            return x_new
        x = x_new
    raise LambertError("minimum-time iteration did not converge", field="revolutions")


def _find_x(lam: float, t_nd: float, m: int, low_path: bool, max_iter: int, rtol: float) -> float:
    m_max = int(t_nd // math.pi)
    t00 = math.acos(lam) + lam * math.sqrt(1.0 - lam**2)
    if m_max > 0 and t_nd < t00 + m_max * math.pi:
        x_min = _halley_tmin(0.1, lam, m_max, 1e-13, 50)
        if t_nd < _tof(x_min, lam, m_max):
            m_max -= 1
    if m > m_max:
        raise LambertError(
            f"no transfer with {m} revolutions in this time of flight; at most {m_max}", field="revolutions"
        )
    if m == 0:
        t0 = t00
        t1 = 2.0 * (1.0 - lam**3) / 3.0
        if t_nd >= t0:
            x = (t0 / t_nd) ** (2.0 / 3.0) - 1.0
        elif t_nd < t1:
            x = 2.5 * t1 / t_nd * (t1 - t_nd) / (1.0 - lam**5) + 1.0
        else:
            x = math.exp(math.log(2.0) * math.log(t_nd / t0) / math.log(t1 / t0)) - 1.0
    else:
        left = ((m * math.pi + math.pi) / (8.0 * t_nd)) ** (2.0 / 3.0)
        right = ((8.0 * t_nd) / (m * math.pi)) ** (2.0 / 3.0)
        x_l = (left - 1.0) / (left + 1.0)
        x_r = (right - 1.0) / (right + 1.0)
        x = max(x_l, x_r) if low_path else min(x_l, x_r)
    for _ in range(max_iter):
        f = _tof(x, lam, m) - t_nd
        t = f + t_nd
        d1, d2, d3 = _derivatives(x, t, lam)
        x_new = x - f * ((d1**2 - f * d2 / 2.0) / (d1 * (d1**2 - f * d2) + d3 * f**2 / 6.0))
        if abs(x_new - x) < rtol:
            return x_new
        x = x_new
    raise LambertError("Lambert iteration did not converge", field="tof_s")
