"""An independent two-body + J2 integrator: J2 in skyfield's true-of-date frame, integrated by solve_ivp.

Nothing of planner.propagation is used but its time conversion: the precession-nutation
matrix comes from skyfield at every step (a cubic spline of it on a 10-minute grid).
"""

import numpy as np
from scipy.integrate import solve_ivp
from scipy.interpolate import CubicSpline

from planner.propagation import skyfield_times

MU_KM3_S2 = 398600.4418  # EGM96 / WGS-84
J2_EARTH = 1.08262668e-3
RE_KM = 6378.137


def _tod_rhs(epoch, lo, hi):
    """The two-body + J2 right-hand side with J2 about skyfield's true-of-date axis, over ``[lo, hi]``."""
    grid = np.linspace(lo - 3600.0, hi + 3600.0, max(8, int((hi - lo) / 600.0) + 13))
    m_spline = CubicSpline(grid, skyfield_times(epoch, grid).M.reshape(9, -1).T)

    def rhs(t, y):
        m = m_spline(t).reshape(3, 3)
        x, yy, z = m @ y[:3]  # true of date: z along the Earth's axis
        r2 = x * x + yy * yy + z * z
        r = np.sqrt(r2)
        c = 1.5 * J2_EARTH * MU_KM3_S2 * RE_KM**2 / r**5
        q = 5.0 * z * z / r2
        a_tod = -MU_KM3_S2 / r**3 * np.array([x, yy, z]) + c * np.array([x * (q - 1), yy * (q - 1), z * (q - 3)])
        return np.concatenate([y[3:], m.T @ a_tod])

    return rhs


def fly_tod_j2(epoch, r0_km, v0_km_s, t0_s, burns, t_eval_s, rtol=1e-11):
    """Fly ``(r0, v0)`` from ``t0_s`` through impulsive ``burns`` (``(t_s, dv_km_s)``, time order); return
    positions and velocities (3, N) at ``t_eval_s`` (a time at a burn: just after it)."""
    t_eval_s = np.atleast_1d(np.asarray(t_eval_s, float))
    hi = max(t_eval_s.max(), max((b[0] for b in burns), default=t0_s))
    rhs = _tod_rhs(epoch, t0_s, hi)
    y = np.concatenate([np.asarray(r0_km, float), np.asarray(v0_km_s, float)])
    t = t0_s
    out = np.full((6, t_eval_s.size), np.nan)
    for t_next, dv in [*burns, (np.inf, None)]:
        end = min(t_next, t_eval_s.max())
        sel = (t_eval_s >= t) & (t_eval_s < t_next)
        if end > t:
            sol = solve_ivp(rhs, (t, end), y, method="DOP853", rtol=rtol, atol=rtol, dense_output=True)
            if sel.any():
                out[:, sel] = sol.sol(t_eval_s[sel])
            y = sol.y[:, -1]
        elif sel.any():
            out[:, sel] = y[:, None]
        if dv is None or t_next > t_eval_s.max():
            break
        y = y + np.concatenate([np.zeros(3), np.asarray(dv, float)])
        t = t_next
    return out[:3], out[3:]


def propagate_tod_j2(epoch, r0_km, v0_km_s, t0_s, t_eval_s):
    """Return positions (3, N) at ``t_eval_s`` (seconds after ``epoch``) from ``(r0, v0)`` at ``t0_s``."""
    t_eval_s = np.atleast_1d(np.asarray(t_eval_s, float))
    lo, hi = min(t0_s, t_eval_s.min()), max(t0_s, t_eval_s.max())
    rhs = _tod_rhs(epoch, lo, hi)
    y0 = np.concatenate([np.asarray(r0_km, float), np.asarray(v0_km_s, float)])
    out = np.empty((3, t_eval_s.size))
    for sign in (1.0, -1.0):
        sel = (t_eval_s - t0_s) * sign >= 0 if sign > 0 else t_eval_s < t0_s
        if not sel.any():
            continue
        ts = t_eval_s[sel]
        end = ts.max() if sign > 0 else ts.min()
        if end == t0_s:
            out[:, sel] = y0[:3, None]
            continue
        order = np.argsort(ts * sign)
        sol = solve_ivp(rhs, (t0_s, end), y0, method="DOP853", rtol=1e-12, atol=1e-12, t_eval=ts[order])
        res = np.empty((3, ts.size))
        res[:, order] = sol.y[:3]
        out[:, sel] = res
    return out
