"""Access windows of a satellite to a ground station: rise, culmination and set.

Elevation (and, with a range limit, slant range) is sampled on a grid; the
extrema between samples that could cross the mask unseen are refined and merged
into the samples, so each function is monotonic between neighbours and every
rise and set is one sign change, refined by vectorised regula falsi to ``tol_s``
(default 0.1 ms). This finds grazing passes shorter than the grid step, which a
plain sign-change scan misses, and passes that enter and leave range inside one
elevation pass (tests/planner/test_access.py checks both against a 1-s skyfield scan).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from planner.errors import SearchRangeError, StationError
from planner.propagation import EarthFrames, Station, Trajectory
from planner.radar import validate_radar
from planner.search import TimeFunction, bisect_roots, grid_maxima, time_grid

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
    # How fast the radar must turn to follow the pass (deg/s): the azimuth's rate at the culmination, where a pass
    # turns it fastest, and the elevation's largest rate within 3 minutes of it; ``keyhole`` where the azimuth rate
    # is over the station's ``max_azimuth_rate_deg_s`` (the radar loses the target near the zenith).
    max_azimuth_rate_deg_s: Vec = field(default_factory=lambda: np.empty(0))
    max_elevation_rate_deg_s: Vec = field(default_factory=lambda: np.empty(0))
    keyhole: NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, bool))
    # Which station of a network each pass is over (its index in the plan's stations; ``merge_windows``): empty
    # for one station's own windows, where every pass is over it.
    station: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))

    def __len__(self) -> int:
        return int(self.rise_s.size)

    def station_of(self, k: int) -> int:
        """The index of the station pass ``k`` is over (0 for one station's own windows)."""
        return int(self.station[k]) if self.station.size else 0


def merge_windows(parts: list[AccessWindows]) -> AccessWindows:
    """The windows of several stations as one set in time order (by rise, stable), each pass naming its station's
    index in ``parts`` (``station``)."""
    station = (
        np.concatenate([np.full(len(w), j, np.int64) for j, w in enumerate(parts)]) if parts else np.zeros(0, np.int64)
    )
    order = np.argsort(np.concatenate([w.rise_s for w in parts]) if parts else np.empty(0), kind="stable")

    def joined(name: str, dtype: type) -> NDArray[Any]:
        values: list[NDArray[Any]] = [np.asarray(getattr(w, name), dtype) for w in parts]
        return (np.concatenate(values) if values else np.zeros(0, dtype))[order]

    floats = (
        "rise_s",
        "culmination_s",
        "set_s",
        "max_elevation_deg",
        "rise_azimuth_deg",
        "culmination_azimuth_deg",
        "set_azimuth_deg",
        "min_range_km",
        "max_azimuth_rate_deg_s",
        "max_elevation_rate_deg_s",
    )
    flags = ("rise_clipped", "set_clipped", "keyhole")
    return AccessWindows(
        **{name: joined(name, float) for name in floats},
        **{name: joined(name, bool) for name in flags},
        station=station[order],
    )


MAX_MASK_POINTS = 720
# Saemundsson's refraction (Meeus, Astronomical Algorithms, eq. 16.4) is for 10 C and 1010 hPa.
REFRACTION_CONDITIONS = "10 C, 1010 hPa (Saemundsson 1986)"


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
    rate = station.max_azimuth_rate_deg_s
    if not (math.isfinite(rate) and 0.001 <= rate <= 360.0):
        raise StationError(
            f"max_azimuth_rate_deg_s {rate} must be between 0.001 and 360", field="max_azimuth_rate_deg_s"
        )
    if station.max_range_km is not None and not (math.isfinite(station.max_range_km) and station.max_range_km >= 0.001):
        raise StationError(f"max_range_km {station.max_range_km} must be at least 0.001 km", field="max_range_km")
    validate_mask(station.mask)
    validate_radar(station.radar)


def validate_mask(mask: tuple[tuple[float, float], ...]) -> None:
    """Refuse a mask whose azimuths do not increase within [0, 360) or whose elevations are out of range."""
    if len(mask) > MAX_MASK_POINTS:
        raise StationError(f"mask has {len(mask)} points; at most {MAX_MASK_POINTS}", field="mask")
    previous = -math.inf
    for k, (az, el) in enumerate(mask):
        if not (math.isfinite(az) and 0.0 <= az < 360.0):
            raise StationError(f"mask point {k}: azimuth {az} is outside [0, 360)", field="mask")
        if not (math.isfinite(el) and -5.0 <= el <= 89.0):
            raise StationError(f"mask point {k}: elevation {el} is outside [-5, 89]", field="mask")
        if az <= previous:
            raise StationError(
                f"mask point {k}: azimuth {az} does not increase on {previous}; list the points from north through east",
                field="mask",
            )
        previous = az


def refraction_deg(elevation_deg: Vec) -> Vec:
    """Atmospheric refraction (deg) to add to geometric elevations (deg): Saemundsson's formula.

    R = 1.02' / tan(h + 10.3 / (h + 5.11)) at 10 C and 1010 hPa, 0.48 deg at the horizon and
    under 0.01 deg above 80 deg; zero below -1 deg, as skyfield's own refraction is. That is the
    optical refraction: a radar's (radio) bending also depends on humidity and is larger near the
    horizon, which this does not model.
    """
    h = np.asarray(elevation_deg, float)
    hh = np.clip(h, -1.0, 90.0)
    r = 1.02 / 60.0 / np.tan(np.radians(hh + 10.3 / (hh + 5.11)))
    return np.where((h >= -1.0) & (h <= 89.9), r, 0.0)


def mask_deg(station: Station, azimuth_deg: Vec) -> Vec:
    """The lowest elevation (deg) in view at each azimuth: the station's mask, and never below its minimum."""
    az = np.asarray(azimuth_deg, float)
    if not station.mask:
        return np.full(az.shape, station.min_elevation_deg)
    pts = np.asarray(station.mask, float)
    return np.maximum(station.min_elevation_deg, np.interp(az, pts[:, 0], pts[:, 1], period=360.0))


def _look(rho_itrs: Vec, station: Station) -> LookAngles:
    enu = station.enu_itrs() @ rho_itrs
    rng = np.linalg.norm(rho_itrs, axis=0)
    el = np.degrees(np.arcsin(np.clip(enu[2] / rng, -1.0, 1.0)))
    if station.refraction:
        el = el + refraction_deg(el)
    az = np.mod(np.degrees(np.arctan2(enu[0], enu[1])), 360.0)
    return LookAngles(az, el, rng)


def look_angles(r_sat_km: Vec, t_s: Vec, station: Station, frames: EarthFrames) -> LookAngles:
    """Return the look angles from ``station`` to GCRS positions ``r_sat_km`` (3, N) at ``t_s``.

    Elevations are as the station sees them: refracted when ``station.refraction`` is on.
    """
    return _look(frames.to_itrs(t_s, r_sat_km) - station.itrs_km()[:, None], station)


def look_function(traj: Trajectory, station: Station, frames: EarthFrames, above_mask: bool = True):  # type: ignore[no-untyped-def]
    """Return ``f(t_s) -> (elevation in deg, slant range in km)``, both shape (N,).

    The elevation is measured from the mask at the satellite's azimuth (``above_mask``), or from
    the horizon; refracted when the station asks for it.
    """
    site = station.itrs_km()

    def f(t_s: Vec) -> tuple[Vec, Vec]:
        r, _ = traj.state(t_s)
        look = _look(frames.to_itrs(t_s, r) - site[:, None], station)
        el = look.elevation_deg - mask_deg(station, look.azimuth_deg) if above_mask else look.elevation_deg
        return el, look.range_km

    return f


@dataclass(frozen=True, slots=True)
class Intervals:
    """Where a function of time is positive: ``start``/``end`` (N,), and whether each lies on the span's edge."""

    start: Vec
    end: Vec
    start_clipped: NDArray[np.bool_]
    end_clipped: NDArray[np.bool_]


def positive_intervals(f: TimeFunction, t: Vec, g: Vec, extrema_t: Vec, extrema_g: Vec, tol_s: float) -> Intervals:
    """Return the intervals of ``[t[0], t[-1]]`` where ``f > 0``.

    ``g`` is ``f`` on the grid ``t``; ``extrema_t`` / ``extrema_g`` are the refined
    extrema between grid points that could cross zero unseen (a grazing maximum, a
    shallow minimum). Merged into the grid, they leave ``f`` monotonic between
    neighbouring samples, so every crossing is one sign change, refined to ``tol_s``.
    """
    tt = np.concatenate([t, extrema_t])
    gg = np.concatenate([g, extrema_g])
    order = np.argsort(tt, kind="stable")
    tt, gg = tt[order], gg[order]
    keep = np.concatenate([[True], np.diff(tt) > 0.0])
    tt, gg = tt[keep], gg[keep]
    positive = gg > 0.0
    idx = np.flatnonzero(positive[1:] != positive[:-1])
    roots = bisect_roots(f, tt[idx], tt[idx + 1], tol_s)
    rising = ~positive[idx]
    start, end = roots[rising], roots[~rising]
    start_clipped = np.zeros(start.size, bool)
    end_clipped = np.zeros(end.size, bool)
    if positive[0]:
        start = np.concatenate([[tt[0]], start])
        start_clipped = np.concatenate([[True], start_clipped])
    if positive[-1]:
        end = np.concatenate([end, [tt[-1]]])
        end_clipped = np.concatenate([end_clipped, [True]])
    return Intervals(start, end, start_clipped, end_clipped)


def intersect(a: Intervals, b: Intervals) -> Intervals:
    """Return the intervals where both ``a`` and ``b`` hold (each sorted and disjoint)."""
    start: list[float] = []
    end: list[float] = []
    sc: list[bool] = []
    ec: list[bool] = []
    i = j = 0
    while i < a.start.size and j < b.start.size:
        lo = max(a.start[i], b.start[j])
        hi = min(a.end[i], b.end[j])
        if lo < hi:
            start.append(float(lo))
            end.append(float(hi))
            sc.append(bool((a.start_clipped[i] and lo == a.start[i]) or (b.start_clipped[j] and lo == b.start[j])))
            ec.append(bool((a.end_clipped[i] and hi == a.end[i]) or (b.end_clipped[j] and hi == b.end[j])))
        if a.end[i] < b.end[j]:
            i += 1
        else:
            j += 1
    return Intervals(np.array(start), np.array(end), np.array(sc, bool), np.array(ec, bool))


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

    A window is where the elevation is above the mask and, with
    ``station.max_range_km`` set, the slant range is within it: a highly eccentric
    pass can enter and leave range inside one elevation pass. Elevation and range
    are sampled every ``step_s``; their extrema between samples are refined and
    merged into the samples, so each function is monotonic between neighbours and
    every crossing (a grazing pass shorter than the step included) is one sign
    change, refined to ``tol_s``. ``step_s`` must be shorter than half the time
    between a culmination and the next elevation minimum (over ten minutes for any
    Earth orbit), which 120 s is. The culmination is the highest point and
    ``min_range_km`` the least range inside each window.
    """
    validate_station(station)
    if t1_s - t0_s > MAX_SPAN_S:
        raise SearchRangeError(f"span of {(t1_s - t0_s) / 86400.0:.2f} days is over the 30-day limit", field="end")
    look = look_function(traj, station, frames)

    def f_el(t_s: Vec) -> Vec:
        return look(t_s)[0]

    def f_near(t_s: Vec) -> Vec:
        return -look(t_s)[1]

    t = time_grid(t0_s, t1_s, step_s)
    g, rng = look(t)
    # Every sampled maximum is refined (one or two an orbit, so cheap): near a high
    # culmination elevation curves by tens of degrees within one step, so no margin
    # below the mask is safe. A sampled minimum only matters if it is above the mask.
    # Extrema to 1 ms: the function is flat there, so a finer time buys nothing.
    ext_tol = max(tol_s, 1e-3)
    t_max, g_max = grid_maxima(f_el, t, g, ext_tol, include_ends=True)
    t_min, g_min = grid_maxima(lambda x: -f_el(x), t, -g, ext_tol, select=g > 0.0, include_ends=True)
    windows = positive_intervals(f_el, t, g, np.concatenate([t_max, t_min]), np.concatenate([g_max, -g_min]), tol_s)
    # Range minima: for the least range in each window and for a range limit.
    t_near, near = grid_maxima(f_near, t, -rng, ext_tol, include_ends=True)
    if station.max_range_km is not None and windows.start.size:
        limit = station.max_range_km

        def f_in(t_s: Vec) -> Vec:
            return limit - look(t_s)[1]

        t_far, far = grid_maxima(
            lambda x: -f_in(x), t, rng - limit, ext_tol, select=limit - rng > 0.0, include_ends=True
        )
        in_range = positive_intervals(
            f_in, t, limit - rng, np.concatenate([t_near, t_far]), np.concatenate([limit + near, -far]), tol_s
        )
        windows = intersect(windows, in_range)
    t_peaks = t_max[g_max > 0.0]
    if station.mask:  # above a mask that varies in azimuth the highest point is not the furthest above it
        sky = look_function(traj, station, frames, above_mask=False)

        def f_sky(t_s: Vec) -> Vec:
            return sky(t_s)[0]

        t_peaks, _ = grid_maxima(f_sky, t, sky(t)[0], ext_tol, include_ends=True)
    return _describe(traj, station, frames, windows, t_peaks, t_near)


def _inside(times: Vec, start: float, end: float) -> Vec:
    return times[(times >= start) & (times <= end)]


def _describe(
    traj: Trajectory, station: Station, frames: EarthFrames, w: Intervals, t_peaks: Vec, t_near: Vec
) -> AccessWindows:
    n = w.start.size
    if n == 0:
        empty = np.empty(0)
        return AccessWindows(
            empty, empty, empty, empty, empty, empty, empty, empty, np.zeros(0, bool), np.zeros(0, bool)
        )
    # Each window's highest point and least range lie at an interior extremum or at an end:
    # one look at those moments gives both.
    look = look_function(traj, station, frames, above_mask=False)
    culm = np.empty(n)
    nearest = np.empty(n)
    for k in range(n):
        s, e = float(w.start[k]), float(w.end[k])
        cand = np.concatenate([[s, e], _inside(t_peaks, s, e), _inside(t_near, s, e)])
        el, rg = look(cand)
        culm[k] = cand[int(np.argmax(el))]
        nearest[k] = float(rg.min())
    t_all = np.concatenate([w.start, culm, w.end])
    r, _ = traj.state(t_all)
    angles = look_angles(r, t_all, station, frames)
    az_rate, el_rate = _peak_rates(traj, station, frames, w.start, culm, w.end)
    return AccessWindows(
        rise_s=w.start,
        culmination_s=culm,
        set_s=w.end,
        max_elevation_deg=angles.elevation_deg[n : 2 * n],
        rise_azimuth_deg=angles.azimuth_deg[:n],
        culmination_azimuth_deg=angles.azimuth_deg[n : 2 * n],
        set_azimuth_deg=angles.azimuth_deg[2 * n :],
        min_range_km=nearest,
        rise_clipped=np.asarray(w.start_clipped, bool),
        set_clipped=np.asarray(w.end_clipped, bool),
        max_azimuth_rate_deg_s=az_rate,
        max_elevation_rate_deg_s=el_rate,
        keyhole=az_rate > station.max_azimuth_rate_deg_s,
    )


RATE_HALF_SPAN_S = 180.0  # the elevation's rate is sought this far either side of the culmination, every second
RATE_DT_S = 0.05  # the central difference's half step


def pointing_rates(traj: Trajectory, station: Station, frames: EarthFrames, t_s: Vec) -> tuple[Vec, Vec]:
    """Return the azimuth and elevation rates (deg/s) the radar turns at, at ``t_s``: central differences over
    0.1 s of the look angles (the azimuth's wrapped through north)."""
    t = np.asarray(t_s, float)
    ahead = look_angles(traj.state(t + RATE_DT_S)[0], t + RATE_DT_S, station, frames)
    behind = look_angles(traj.state(t - RATE_DT_S)[0], t - RATE_DT_S, station, frames)
    d_az = (ahead.azimuth_deg - behind.azimuth_deg + 180.0) % 360.0 - 180.0
    return d_az / (2 * RATE_DT_S), (ahead.elevation_deg - behind.elevation_deg) / (2 * RATE_DT_S)


def _peak_rates(
    traj: Trajectory, station: Station, frames: EarthFrames, start: Vec, culm: Vec, end: Vec
) -> tuple[Vec, Vec]:
    """Each window's azimuth rate at its culmination and largest elevation rate near it (deg/s, magnitudes)."""
    offsets = np.arange(-RATE_HALF_SPAN_S, RATE_HALF_SPAN_S + 0.5, 1.0)
    lo = start + RATE_DT_S  # the differences stay inside the window (a window clipped at the span's end included)
    hi = np.maximum(end - RATE_DT_S, lo)
    grid = np.clip(culm[:, None] + offsets, lo[:, None], hi[:, None])
    az, el = pointing_rates(traj, station, frames, np.concatenate([np.clip(culm, lo, hi), grid.ravel()]))
    n = culm.size
    return np.abs(az[:n]), np.abs(el[n:]).reshape(n, -1).max(axis=1)
