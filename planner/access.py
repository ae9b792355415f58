"""Access windows of a satellite to a ground station: rise, culmination and set.

The elevation of the satellite above the station's mask is sampled on a grid,
its local maxima are refined (culminations), and every culmination above the
mask is bracketed by the grid minima on either side, inside which elevation is
monotonic, so rise and set are single sign changes refined by bisection. This
finds grazing passes shorter than the grid step, which a plain sign-change scan
misses, and times rise and set to ``tol_s`` (default 0.1 ms).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from planner.errors import SearchRangeError, StationError
from planner.propagation import EarthFrames, Station, Trajectory
from planner.search import _find_maxima_core, bisect_roots, time_grid

Vec = NDArray[np.float64]

MAX_SPAN_S = 30 * 86400.0


@dataclass(frozen=True, slots=True)
class LookAngles:
    """Azimuth (deg from north, through east), elevation (deg) and range (km), each shape (N,)."""

    azimuth_deg: Vec
    elevation_deg: Vec
    range_km: Vec


@dataclass(frozen=True, slots=True)
class AccessWindows:
    """Passes of a satellite over a station; every field has one entry a pass.

    ``rise_s`` and ``set_s`` are clipped to the search span, and ``rise_clipped`` /
    ``set_clipped`` say where that happened (a pass already in progress at the start).
    """

    rise_s: Vec
    culmination_s: Vec
    set_s: Vec
    max_elevation_deg: Vec
    rise_azimuth_deg: Vec
    culmination_azimuth_deg: Vec
    set_azimuth_deg: Vec
    min_range_km: Vec
    rise_clipped: NDArray[np.bool_]
    set_clipped: NDArray[np.bool_]

    def __len__(self) -> int:
        return int(self.rise_s.size)


def validate_station(station: Station) -> None:
    """Raise StationError naming the field for coordinates or masks out of range."""
    checks = (
        ("latitude_deg", station.latitude_deg, -90.0, 90.0),
        ("longitude_deg", station.longitude_deg, -180.0, 360.0),
        ("altitude_m", station.altitude_m, -500.0, 9000.0),
        ("min_elevation_deg", station.min_elevation_deg, -5.0, 89.0),
    )
    for name, value, lo, hi in checks:
        if not (math.isfinite(value) and lo <= value <= hi):
            raise StationError(f"{name} {value} is outside [{lo}, {hi}]", field=name)
    if station.max_range_km is not None and not (math.isfinite(station.max_range_km) and station.max_range_km > 0):
        raise StationError(f"max_range_km {station.max_range_km} must be positive", field="max_range_km")


def look_angles(r_sat_km: Vec, t_s: Vec, station: Station, frames: EarthFrames) -> LookAngles:
    """Return the look angles from ``station`` to GCRS positions ``r_sat_km`` (3, N) at ``t_s``."""
    r_itrs = frames.to_itrs(t_s, r_sat_km)
    rho = r_itrs - station.itrs_km()[:, None]
    enu = station.enu_itrs() @ rho
    rng = np.linalg.norm(rho, axis=0)
    el = np.degrees(np.arcsin(np.clip(enu[2] / rng, -1.0, 1.0)))
    az = np.mod(np.degrees(np.arctan2(enu[0], enu[1])), 360.0)
    return LookAngles(az, el, rng)


def elevation_function(traj: Trajectory, station: Station, frames: EarthFrames):  # type: ignore[no-untyped-def]
    """Return ``f(t_s)``: elevation above the station's mask, in degrees (the access g-function)."""
    up = station.enu_itrs()[2]
    site = station.itrs_km()
    mask = station.min_elevation_deg

    def f(t_s: Vec) -> Vec:
        r, _ = traj.state(t_s)
        rho = frames.to_itrs(t_s, r) - site[:, None]
        return np.degrees(np.arcsin(np.clip(up @ rho / np.linalg.norm(rho, axis=0), -1.0, 1.0))) - mask

    return f


def range_function(traj: Trajectory, station: Station, frames: EarthFrames, max_range_km: float):  # type: ignore[no-untyped-def]
    """Return ``f(t_s)``: ``max_range_km`` minus the slant range (positive when close enough)."""
    site = station.itrs_km()

    def f(t_s: Vec) -> Vec:
        r, _ = traj.state(t_s)
        rho = frames.to_itrs(t_s, r) - site[:, None]
        return max_range_km - np.linalg.norm(rho, axis=0)

    return f


def access_windows(
    traj: Trajectory,
    station: Station,
    frames: EarthFrames,
    t0_s: float,
    t1_s: float,
    step_s: float = 120.0,
    tol_s: float = 1e-4,
) -> AccessWindows:
    """Find every pass of ``traj`` above the station's elevation mask in ``[t0_s, t1_s]``.

    ``step_s`` must be shorter than half the time between a culmination and the
    next elevation minimum (over ten minutes for any Earth orbit), which 120 s is.
    With ``station.max_range_km`` set, each window is narrowed to where the slant
    range is within it (passes never inside it are dropped).
    """
    validate_station(station)
    if t1_s - t0_s > MAX_SPAN_S:
        raise SearchRangeError(f"span of {(t1_s - t0_s) / 86400.0:.2f} days is over the 30-day limit", field="end")
    f = elevation_function(traj, station, frames)
    t = time_grid(t0_s, t1_s, step_s)
    g = f(t)
    # Only culminations that can reach the mask are refined. Near a culmination an Earth
    # satellite's elevation curves by at most ~2.5 deg within 60 s (a 200-km orbit seen
    # at the horizon: (v / range)^2 t^2 / 2), so 15 deg below the mask at a 120-s step is safe.
    margin_deg = max(5.0, 15.0 * (step_s / 120.0) ** 2)
    # Culminations to 1 ms: elevation is flat there, so a finer time buys nothing.
    t_max, g_max = _find_maxima_core(f, t, g, max(tol_s, 1e-3), floor=-margin_deg)
    # Maxima at the ends of the span (a pass in progress at the start or end).
    edges_t, edges_g = [], []
    if g.size > 1 and g[0] > g[1]:
        edges_t.append(t[0])
        edges_g.append(g[0])
    if g.size > 1 and g[-1] > g[-2]:
        edges_t.append(t[-1])
        edges_g.append(g[-1])
    t_max = np.concatenate([t_max, edges_t])
    g_max = np.concatenate([g_max, edges_g])
    keep = g_max > 0.0
    t_max, g_max = t_max[keep], g_max[keep]
    order = np.argsort(t_max)
    t_max, g_max = t_max[order], g_max[order]

    # Grid minima bound each culmination; elevation is monotonic in between.
    i_max = np.clip(np.searchsorted(t, t_max), 0, t.size - 1)
    minima = np.flatnonzero((g[1:-1] <= g[:-2]) & (g[1:-1] < g[2:])) + 1
    bounds = np.concatenate([[0], minima, [t.size - 1]])
    k = np.searchsorted(minima, i_max)
    lo_t, hi_t = t[bounds[k]], t[bounds[k + 1]]
    n = t_max.size
    ends = f(np.concatenate([lo_t, hi_t])) > 0.0 if n else np.zeros(0, bool)
    rise_clipped, set_clipped = ends[:n], ends[n:]
    # Narrow each bracket to the grid step where the elevation crosses the mask (for a
    # grazing pass with no grid crossing, to the step beside the culmination), then refine
    # rise and set of every pass together in one vectorised root search. An end still above
    # the mask at the span's edge (clipped) has no crossing to refine.
    idx = np.arange(t.size)
    last_below = np.maximum.accumulate(np.where(g <= 0.0, idx, 0))
    next_below = np.minimum.accumulate(np.where(g <= 0.0, idx, t.size - 1)[::-1])[::-1]
    i_lo = np.maximum(last_below[i_max], bounds[k])
    i_hi = np.minimum(next_below[np.minimum(i_max + 1, t.size - 1)], bounds[k + 1])
    lo_all = np.concatenate([t[i_lo], np.maximum(t_max, t[np.maximum(i_hi - 1, 0)])])
    hi_all = np.concatenate([np.minimum(t_max, t[np.minimum(i_lo + 1, t.size - 1)]), t[i_hi]])
    lo_all = np.minimum(lo_all, hi_all)
    open_end = ~ends if n else np.zeros(0, bool)
    crossing = np.concatenate([lo_t, hi_t])
    crossing[open_end] = bisect_roots(f, lo_all[open_end], hi_all[open_end], tol_s)
    rise, sets = crossing[:n], crossing[n:]

    if station.max_range_km is not None and rise.size:
        rf = range_function(traj, station, frames, station.max_range_km)
        inside = rf(t_max) > 0.0
        rise, sets, t_max = rise[inside], sets[inside], t_max[inside]
        rise_clipped, set_clipped = rise_clipped[inside], set_clipped[inside]
        far_rise = rf(rise) < 0.0
        far_set = rf(sets) < 0.0
        rise = np.where(far_rise, bisect_roots(rf, rise, t_max, tol_s) if rise.size else rise, rise)
        sets = np.where(far_set, bisect_roots(rf, t_max, sets, tol_s) if sets.size else sets, sets)

    return _describe(traj, station, frames, rise, t_max, sets, rise_clipped, set_clipped)


def _describe(
    traj: Trajectory,
    station: Station,
    frames: EarthFrames,
    rise: Vec,
    culm: Vec,
    sets: Vec,
    rise_clipped: NDArray[np.bool_],
    set_clipped: NDArray[np.bool_],
) -> AccessWindows:
    n = rise.size
    if n == 0:
        empty = np.empty(0)
        return AccessWindows(
            empty, empty, empty, empty, empty, empty, empty, empty, np.zeros(0, bool), np.zeros(0, bool)
        )
    t_all = np.concatenate([rise, culm, sets])
    r, _ = traj.state(t_all)
    look = look_angles(r, t_all, station, frames)
    return AccessWindows(
        rise_s=rise,
        culmination_s=culm,
        set_s=sets,
        max_elevation_deg=look.elevation_deg[n : 2 * n],
        rise_azimuth_deg=look.azimuth_deg[:n],
        culmination_azimuth_deg=look.azimuth_deg[n : 2 * n],
        set_azimuth_deg=look.azimuth_deg[2 * n :],
        min_range_km=look.range_km[n : 2 * n],
        rise_clipped=np.asarray(rise_clipped, bool),
        set_clipped=np.asarray(set_clipped, bool),
    )
