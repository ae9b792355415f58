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
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np
from numpy.typing import NDArray

from planner.constants import OMEGA_EARTH_RAD_S
from planner.errors import SearchRangeError, StationError
from planner.propagation import EarthFrames, Station, Trajectory
from planner.radar import validate_radar
from planner.search import KeyedFunction, Keys, bisect_roots, keyed_maxima, time_grid

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


def look_angles(r_sat_km: Vec, t_s: Vec, station: Station, frames: EarthFrames) -> LookAngles:
    """Return the look angles from ``station`` to GCRS positions ``r_sat_km`` (3, N) at ``t_s``.

    Elevations are as the station sees them: refracted when ``station.refraction`` is on.
    """
    t = np.atleast_1d(np.asarray(t_s, float))
    return Sites.of([station]).look(frames.to_itrs(t, r_sat_km), np.zeros(t.size, np.int64))


@dataclass(frozen=True, slots=True)
class Sites:
    """Stations as arrays, so one look serves many (moment, station) pairs: station ``k[m]`` at moment ``m``."""

    stations: tuple[Station, ...]
    itrs_km: Vec  # (S, 3)
    enu: Vec  # (S, 3, 3): each site's east, north, up rows
    min_elevation_deg: Vec  # (S,)
    refraction: NDArray[np.bool_]  # (S,)
    masked: NDArray[np.bool_]  # (S,): the station has an azimuth mask

    @classmethod
    def of(cls, stations: list[Station] | tuple[Station, ...]) -> Sites:
        st = tuple(stations)
        return cls(
            st,
            np.array([s.itrs_km() for s in st]).reshape(len(st), 3),
            np.array([s.enu_itrs() for s in st]).reshape(len(st), 3, 3),
            np.array([s.min_elevation_deg for s in st], float),
            np.array([s.refraction for s in st], bool),
            np.array([bool(s.mask) for s in st], bool),
        )

    def look(self, r_itrs_km: Vec, k: NDArray[np.int64]) -> LookAngles:
        """Look angles from station ``k[m]`` to the ITRS position ``r_itrs_km[:, m]``; refracted where asked."""
        rho = r_itrs_km - self.itrs_km[k].T
        enu = np.einsum("mij,jm->im", self.enu[k], rho)
        rng = np.sqrt(np.einsum("im,im->m", rho, rho))
        el = np.degrees(np.arcsin(np.clip(enu[2] / rng, -1.0, 1.0)))
        bent = self.refraction[k]
        if bent.any():
            el = np.where(bent, el + refraction_deg(el), el)
        az = np.mod(np.degrees(np.arctan2(enu[0], enu[1])), 360.0)
        return LookAngles(az, el, rng)

    def rates(self, r_itrs_km: Vec, v_itrs_km_s: Vec, k: NDArray[np.int64]) -> tuple[Vec, Vec]:
        """The azimuth and elevation rates (deg/s) station ``k[m]`` turns at to follow a satellite at ITRS
        position ``r_itrs_km[:, m]`` moving at ``v_itrs_km_s[:, m]`` (Earth-fixed): the look angles' time
        derivatives in closed form, refraction's bending included where the station asks for it."""
        rho = r_itrs_km - self.itrs_km[k].T
        enu = np.einsum("mij,jm->im", self.enu[k], rho)
        enu_dot = np.einsum("mij,jm->im", self.enu[k], v_itrs_km_s)
        rng = np.sqrt(np.einsum("im,im->m", rho, rho))
        rng_dot = np.einsum("im,im->m", rho, v_itrs_km_s) / rng
        horizontal_sq = enu[0] ** 2 + enu[1] ** 2
        el_dot = np.degrees((enu_dot[2] * rng - enu[2] * rng_dot) / (rng * np.sqrt(horizontal_sq)))
        bent = self.refraction[k]
        if bent.any():
            el = np.degrees(np.arcsin(np.clip(enu[2] / rng, -1.0, 1.0)))
            slope = (refraction_deg(el + 1e-3) - refraction_deg(el - 1e-3)) / 2e-3
            el_dot = np.where(bent, el_dot * (1.0 + slope), el_dot)
        az_dot = np.degrees((enu[1] * enu_dot[0] - enu[0] * enu_dot[1]) / horizontal_sq)
        return az_dot, el_dot

    def floor_deg(self, k: NDArray[np.int64], azimuth_deg: Vec) -> Vec:
        """The lowest elevation in view (``mask_deg``) for station ``k[m]`` at ``azimuth_deg[m]``."""
        out = self.min_elevation_deg[k]
        masked = self.masked[k]
        if masked.any():
            out = out.copy()
            for j in np.unique(k[masked]):
                at = k == j
                out[at] = mask_deg(self.stations[j], azimuth_deg[at])
        return out


# f(t, k): a function of the moment t[m] for station k[m], both shape (M,).


# state(t, j): the GCRS position and velocity (3, M) of satellite ``j[m]`` at ``t[m]``.
KeyedState = Callable[[Vec, NDArray[np.int64]], tuple[Vec, Vec]]


@dataclass(frozen=True, slots=True)
class _Pairs:
    """Every (satellite, station) pair of a search, pair ``k`` being satellite ``sat[k]`` over station ``site[k]``."""

    state: KeyedState
    sites: Sites
    frames: EarthFrames
    sat: Keys
    site: Keys

    def look(self, t_s: Vec, k: Keys) -> LookAngles:
        r, _ = self.state(t_s, self.sat[k])
        return self.sites.look(self.frames.to_itrs(t_s, r), self.site[k])

    def rates(self, t_s: Vec, k: Keys) -> tuple[Vec, Vec]:
        """Pair ``k[m]``'s azimuth and elevation rates (deg/s) at ``t[m]``, from the state.

        The Earth-fixed velocity is the rotated inertial one less the Earth's rotation, omega x r; the frame's own
        precession, nutation and polar motion turn it by under 1e-11 rad/s, which is left out.
        """
        r, v = self.state(t_s, self.sat[k])
        n = t_s.size
        both = self.frames.to_itrs(np.concatenate([t_s, t_s]), np.hstack([r, v]))
        r_itrs, v_itrs = both[:, :n], both[:, n:]
        v_fixed = v_itrs - OMEGA_EARTH_RAD_S * np.array([-r_itrs[1], r_itrs[0], np.zeros(n)])
        return self.sites.rates(r_itrs, v_fixed, self.site[k])


def one_state(traj: Trajectory) -> KeyedState:
    """One trajectory as the keyed state of a search over one satellite."""

    def state(t_s: Vec, _: Keys) -> tuple[Vec, Vec]:
        return traj.state(t_s)

    return state


@dataclass(frozen=True, slots=True)
class Intervals:
    """Where a function of time is positive: ``start``/``end`` (N,), and whether each lies on the span's edge;
    ``key`` names the station of each (sorted by station, then time)."""

    start: Vec
    end: Vec
    start_clipped: NDArray[np.bool_]
    end_clipped: NDArray[np.bool_]
    key: Keys


def _keyed_intervals(
    f: KeyedFunction, t: Vec, g: Vec, keys: Keys, ext_t: Vec, ext_k: Keys, ext_g: Vec, tol_s: float
) -> Intervals:
    """Where ``f > 0`` over ``[t[0], t[-1]]`` for each row (station ``keys``) of the grid values ``g``.

    The refined extrema between grid points that could cross zero unseen (``ext_*``: a grazing maximum, a
    shallow minimum) are merged into each row, so ``f`` is monotonic between neighbouring samples and every
    crossing is one sign change; all are refined to ``tol_s`` at once.
    """
    n = t.size
    tt = np.concatenate([np.tile(t, keys.size), ext_t])
    kk = np.concatenate([np.repeat(keys, n), ext_k]).astype(np.int64)
    gg = np.concatenate([g.ravel(), ext_g])
    order = np.lexsort((tt, kk))
    tt, kk, gg = tt[order], kk[order], gg[order]
    keep = np.concatenate([[True], (np.diff(tt) > 0.0) | (np.diff(kk) != 0)])
    tt, kk, gg = tt[keep], kk[keep], gg[keep]
    positive = gg > 0.0
    same = kk[1:] == kk[:-1]
    idx = np.flatnonzero((positive[1:] != positive[:-1]) & same)
    key = kk[idx]
    roots = bisect_roots(lambda x: f(x, key), tt[idx], tt[idx + 1], tol_s)
    rising = ~positive[idx]
    first = np.flatnonzero(np.concatenate([[True], ~same]))
    last = np.flatnonzero(np.concatenate([~same, [True]]))
    first, last = first[positive[first]], last[positive[last]]
    start = np.concatenate([roots[rising], tt[first]])
    start_k = np.concatenate([key[rising], kk[first]])
    start_c = np.concatenate([np.zeros(int(rising.sum()), bool), np.ones(first.size, bool)])
    end = np.concatenate([roots[~rising], tt[last]])
    end_k = np.concatenate([key[~rising], kk[last]])
    end_c = np.concatenate([np.zeros(int((~rising).sum()), bool), np.ones(last.size, bool)])
    s_order, e_order = np.lexsort((start, start_k)), np.lexsort((end, end_k))
    return Intervals(start[s_order], end[e_order], start_c[s_order], end_c[e_order], start_k[s_order])


def _take(a: Intervals, sel: NDArray[Any]) -> Intervals:
    return Intervals(a.start[sel], a.end[sel], a.start_clipped[sel], a.end_clipped[sel], a.key[sel])


def intersect(a: Intervals, b: Intervals) -> Intervals:
    """Return the intervals where both ``a`` and ``b`` hold, station by station (each sorted and disjoint)."""
    start: list[float] = []
    end: list[float] = []
    sc: list[bool] = []
    ec: list[bool] = []
    key: list[int] = []
    for k in np.unique(np.concatenate([a.key, b.key])):
        x, y = _take(a, a.key == k), _take(b, b.key == k)
        i = j = 0
        while i < x.start.size and j < y.start.size:
            lo = max(x.start[i], y.start[j])
            hi = min(x.end[i], y.end[j])
            if lo < hi:
                start.append(float(lo))
                end.append(float(hi))
                sc.append(bool((x.start_clipped[i] and lo == x.start[i]) or (y.start_clipped[j] and lo == y.start[j])))
                ec.append(bool((x.end_clipped[i] and hi == x.end[i]) or (y.end_clipped[j] and hi == y.end[j])))
                key.append(int(k))
            if x.end[i] < y.end[j]:
                i += 1
            else:
                j += 1
    return Intervals(np.array(start), np.array(end), np.array(sc, bool), np.array(ec, bool), np.array(key, np.int64))


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

    One station's ``network_access``: see there.
    """
    return network_access(traj, [station], frames, t0_s, t1_s, step_s, tol_s)[0]


def network_access(
    traj: Trajectory,
    stations: list[Station] | tuple[Station, ...],
    frames: EarthFrames,
    t0_s: float,
    t1_s: float,
    step_s: float = 120.0,
    tol_s: float = 1e-4,
) -> list[AccessWindows]:
    """Every pass of ``traj`` over each of ``stations`` in ``[t0_s, t1_s]``: one ``AccessWindows`` a station.

    A window is where the elevation is above the station's mask and, with ``max_range_km`` set, the slant range
    is within it: a highly eccentric pass can enter and leave range inside one elevation pass. The target is
    propagated once on a grid of ``step_s`` that every station shares; each station's elevation and range over
    the grid are array operations, and their extrema between samples are refined and merged into the samples,
    so each function is monotonic between neighbours and every crossing (a grazing pass shorter than the step
    included) is one sign change. Every station's extrema and crossings are refined together, to ``tol_s``, in
    one vectorised search. ``step_s`` must be shorter than half the time between a culmination and the next
    elevation minimum (over ten minutes for any Earth orbit), which 120 s is. The culmination is the highest
    point and ``min_range_km`` the least range inside each window.
    """
    return pair_access(one_state(traj), 1, stations, frames, t0_s, t1_s, step_s, tol_s)[0]


def pair_access(
    state: KeyedState,
    n_sat: int,
    stations: list[Station] | tuple[Station, ...],
    frames: EarthFrames,
    t0_s: float,
    t1_s: float,
    step_s: float = 120.0,
    tol_s: float = 1e-4,
    rates: bool = True,
) -> list[list[AccessWindows]]:
    """``network_access`` for ``n_sat`` satellites at once (``state(t, j)``: satellite ``j``'s GCRS state): the
    windows of satellite ``j`` over station ``s`` are ``[j][s]``. Every pair's extrema and crossings are refined
    together, so the search's fixed costs are paid once for the whole batch. Without ``rates`` the radar's turning
    rates are not sought (NaN, and no keyhole): they cost more than the rest of the search together."""
    for station in stations:
        validate_station(station)
    if t1_s - t0_s > MAX_SPAN_S:
        raise SearchRangeError(f"span of {(t1_s - t0_s) / 86400.0:.2f} days is over the 30-day limit", field="end")
    sites = Sites.of(stations)
    n_st = len(sites.stations)
    pairs = _Pairs(
        state,
        sites,
        frames,
        np.repeat(np.arange(n_sat, dtype=np.int64), n_st),
        np.tile(np.arange(n_st, dtype=np.int64), n_sat),
    )
    described, key = _search(pairs, t0_s, t1_s, step_s, tol_s, rates)
    out = [_station_windows(described, key == k) for k in range(n_sat * n_st)]
    return [out[j * n_st : (j + 1) * n_st] for j in range(n_sat)]


def _search(
    pairs: _Pairs, t0_s: float, t1_s: float, step_s: float, tol_s: float, rates: bool = True
) -> tuple[AccessWindows, Keys]:
    """Every pair's windows as one set (sorted by pair, then time) and the pair of each."""
    sites = pairs.sites
    n_pair = pairs.sat.size
    keys = np.arange(n_pair, dtype=np.int64)
    look = pairs.look
    station = [sites.stations[j] for j in pairs.site]

    def f_el(t_s: Vec, k: Keys) -> Vec:
        a = look(t_s, k)
        return a.elevation_deg - sites.floor_deg(pairs.site[k], a.azimuth_deg)

    def f_sky(t_s: Vec, k: Keys) -> Vec:
        return look(t_s, k).elevation_deg

    def f_near(t_s: Vec, k: Keys) -> Vec:
        return -look(t_s, k).range_km

    t = time_grid(t0_s, t1_s, step_s)
    n_sat = int(pairs.sat.max()) + 1
    sat_grid = np.repeat(np.arange(n_sat, dtype=np.int64), t.size)
    r_all, v_all = pairs.state(np.tile(t, n_sat), sat_grid)
    r_itrs = pairs.frames.to_itrs(np.tile(t, n_sat), r_all).reshape(3, n_sat, t.size)
    # Each pair's satellite on the grid, as one (3, pairs x grid) array for the pair's station.
    grid_k = np.repeat(pairs.site, t.size)
    grid = sites.look(r_itrs[:, pairs.sat, :].reshape(3, -1), grid_k)
    sky = grid.elevation_deg.reshape(n_pair, t.size)
    rng = grid.range_km.reshape(n_pair, t.size)
    g = (grid.elevation_deg - sites.floor_deg(grid_k, grid.azimuth_deg)).reshape(n_pair, t.size)
    # A sampled maximum is refined where the satellite could rise above the floor within a step of the sample:
    # its height over the site's horizon plane changes by at most its Earth-fixed speed times the step (the speed
    # bounded from the grid's, with a fifth to spare). Near a high culmination elevation curves by tens of degrees
    # within one step, so no margin in degrees would be safe; this one is in kilometres. A floor below the
    # horizon (a mask under 0 deg) refines every maximum. A sampled minimum only matters if it is above the mask.
    # Extrema to 1 ms: the function is flat there, so a finer time buys nothing.
    speed_sat = np.linalg.norm(v_all, axis=0).reshape(n_sat, t.size).max(axis=1) + OMEGA_EARTH_RAD_S * np.linalg.norm(
        r_all, axis=0
    ).reshape(n_sat, t.size).max(axis=1)
    height = rng * np.sin(np.radians(sky))
    below_horizon = np.array([_lowest_floor_deg(s) < 0.0 for s in station], bool)
    reach = 1.2 * speed_sat[pairs.sat] * float(np.max(np.diff(t)))
    could_see = (height + reach[:, None] >= 0.0) | below_horizon[:, None]
    ext_tol = max(tol_s, 1e-3)
    t_max, k_max, g_max = keyed_maxima(f_el, t, g, keys, ext_tol, select=could_see)
    t_min, k_min, g_min = keyed_maxima(lambda x, k: -f_el(x, k), t, -g, keys, ext_tol, select=g > 0.0)
    windows = _keyed_intervals(
        f_el,
        t,
        g,
        keys,
        np.concatenate([t_max, t_min]),
        np.concatenate([k_max, k_min]),
        np.concatenate([g_max, -g_min]),
        tol_s,
    )
    # Range minima: for the least range in each window and for a range limit.
    limited = keys[[s.max_range_km is not None for s in station]]
    near_select = could_see | np.isin(keys, limited)[:, None]  # a range limit needs every least range
    t_near, k_near, near = keyed_maxima(f_near, t, -rng, keys, ext_tol, select=near_select)
    if limited.size and windows.start.size:
        limit = np.array([s.max_range_km or 0.0 for s in station])

        def f_in(t_s: Vec, k: Keys) -> Vec:
            return limit[k] - look(t_s, k).range_km

        g_in = limit[limited, None] - rng[limited]
        t_far, k_far, far = keyed_maxima(lambda x, k: -f_in(x, k), t, -g_in, limited, ext_tol, select=g_in > 0.0)
        ours = np.isin(k_near, limited)
        in_range = _keyed_intervals(
            f_in,
            t,
            g_in,
            limited,
            np.concatenate([t_near[ours], t_far]),
            np.concatenate([k_near[ours], k_far]),
            np.concatenate([limit[k_near[ours]] + near[ours], -far]),
            tol_s,
        )
        free = ~np.isin(windows.key, limited)
        cut = intersect(_take(windows, ~free), in_range)
        both = _join(_take(windows, free), cut)
        windows = _take(both, np.lexsort((both.start, both.key)))
    # Above a mask that varies in azimuth the highest point is not the furthest above it.
    t_peaks, k_peaks = t_max[g_max > 0.0], k_max[g_max > 0.0]
    masked_pair = sites.masked[pairs.site]
    if masked_pair.any():
        masked = keys[masked_pair]
        t_sky, k_sky, _ = keyed_maxima(f_sky, t, sky[masked], masked, ext_tol, select=could_see[masked])
        plain = ~masked_pair[k_peaks]
        t_peaks = np.concatenate([t_peaks[plain], t_sky])
        k_peaks = np.concatenate([k_peaks[plain], k_sky])
    turn_limit = np.array([s.max_azimuth_rate_deg_s for s in station])
    turning = pairs.rates if rates else None
    return _describe(look, turning, turn_limit, windows, t_peaks, k_peaks, t_near, k_near), windows.key


def _lowest_floor_deg(station: Station) -> float:
    """The lowest elevation the station sees anywhere around its horizon (its minimum, and its mask's lowest)."""
    return max(station.min_elevation_deg, min((el for _, el in station.mask), default=station.min_elevation_deg))


def _join(a: Intervals, b: Intervals) -> Intervals:
    return Intervals(
        np.concatenate([a.start, b.start]),
        np.concatenate([a.end, b.end]),
        np.concatenate([a.start_clipped, b.start_clipped]),
        np.concatenate([a.end_clipped, b.end_clipped]),
        np.concatenate([a.key, b.key]).astype(np.int64),
    )


def _station_windows(w: AccessWindows, sel: NDArray[np.bool_]) -> AccessWindows:
    """One station's windows out of every station's (``sel``), as that station's own (no ``station`` index)."""
    return AccessWindows(**{f.name: getattr(w, f.name)[sel] for f in fields(AccessWindows) if f.name != "station"})


def _describe(
    look: Callable[[Vec, Keys], LookAngles],
    rates: Callable[[Vec, Keys], tuple[Vec, Vec]] | None,
    turn_limit: Vec,
    w: Intervals,
    t_peaks: Vec,
    k_peaks: Keys,
    t_near: Vec,
    k_near: Keys,
) -> AccessWindows:
    n = w.start.size
    if n == 0:
        empty = np.empty(0)
        return AccessWindows(
            empty, empty, empty, empty, empty, empty, empty, empty, np.zeros(0, bool), np.zeros(0, bool)
        )
    # Each window's highest point and least range lie at an interior extremum or at an end: one look at those
    # moments, every window's at once, gives both.
    t_ext = np.concatenate([t_peaks, t_near])
    k_ext = np.concatenate([k_peaks, k_near]).astype(np.int64)
    inside = (
        (k_ext[None, :] == w.key[:, None]) & (t_ext[None, :] >= w.start[:, None]) & (t_ext[None, :] <= w.end[:, None])
    )
    win, ext = np.nonzero(inside)
    owner = np.concatenate([np.arange(n), np.arange(n), win])
    cand_t = np.concatenate([w.start, w.end, t_ext[ext]])
    order = np.argsort(owner, kind="stable")
    owner, cand_t = owner[order], cand_t[order]
    a = look(cand_t, w.key[owner])
    bounds = np.flatnonzero(np.concatenate([[True], owner[1:] != owner[:-1]]))
    nearest = np.minimum.reduceat(a.range_km, bounds)
    best = np.array(
        [b + int(np.argmax(a.elevation_deg[b:e])) for b, e in zip(bounds, [*bounds[1:], owner.size], strict=True)]
    )
    culm = cand_t[best]
    t_all = np.concatenate([w.start, culm, w.end])
    angles = look(t_all, np.tile(w.key, 3))
    if rates is None:
        az_rate = el_rate = np.full(n, np.nan)
    else:
        az_rate, el_rate = _peak_rates(rates, w.key, w.start, culm, w.end)
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
        keyhole=az_rate > turn_limit[w.key],
    )


RATE_HALF_SPAN_S = 180.0  # the elevation's rate is sought this far either side of the culmination, every second
RATE_COARSE_S = 10.0  # the first look for the elevation's fastest moment


def pointing_rates(traj: Trajectory, station: Station, frames: EarthFrames, t_s: Vec) -> tuple[Vec, Vec]:
    """Return the azimuth and elevation rates (deg/s) the radar turns at, at ``t_s``: the look angles' time
    derivatives from the satellite's state (``Sites.rates``)."""
    t = np.atleast_1d(np.asarray(t_s, float))
    zero = np.zeros(1, np.int64)
    return _Pairs(one_state(traj), Sites.of([station]), frames, zero, zero).rates(t, np.zeros(t.size, np.int64))


def _peak_rates(
    rates: Callable[[Vec, Keys], tuple[Vec, Vec]], key: Keys, start: Vec, culm: Vec, end: Vec
) -> tuple[Vec, Vec]:
    """Each window's azimuth rate at its culmination and largest elevation rate near it (deg/s, magnitudes).

    The elevation's rate is read every ``RATE_COARSE_S`` within ``RATE_HALF_SPAN_S`` of the culmination, then
    every second within a coarse step of the fastest sample: the seconds a full scan would read there, at a
    sixth of the cost (the rate is smooth, one hump either side of the culmination).
    """
    n = culm.size

    def el_rates(offsets: Vec, centre: Vec) -> tuple[Vec, Vec]:
        grid = np.clip(centre[:, None] + offsets, start[:, None], end[:, None])
        return grid, np.abs(rates(grid.ravel(), np.repeat(key, offsets.size))[1]).reshape(n, -1)

    coarse = np.arange(-RATE_HALF_SPAN_S, RATE_HALF_SPAN_S + 0.5, RATE_COARSE_S)
    grid, rate = el_rates(coarse, culm)
    best = grid[np.arange(n), np.argmax(rate, axis=1)]
    _, fine = el_rates(np.arange(-RATE_COARSE_S, RATE_COARSE_S + 0.5, 1.0), best)
    az = rates(culm, key)[0]
    return np.abs(az), np.maximum(rate.max(axis=1), fine.max(axis=1))
