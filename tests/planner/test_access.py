import numpy as np
import pytest
from scipy.optimize import brentq, minimize_scalar
from skyfield.api import EarthSatellite, wgs84

from planner.access import access_windows, look_angles
from planner.errors import SearchRangeError, StationError
from planner.propagation import EarthFrames, NumericalJ2Trajectory, SGP4Trajectory, Station, skyfield_times, timescale
from planner.tle import parse_tle
from tests.utils.orbits import (
    ISS_EPOCH,
    ISS_L1,
    ISS_L2,
    MOLNIYA_L1,
    MOLNIYA_L2,
    PAPER_EPOCH,
    PAPER_STATION,
    PAPER_TARGET,
    SSO_L1,
    SSO_L2,
    TLE_2024_EPOCH,
)

ten_ms = 0.010
STATION = Station(31.1, 121.3, 0.0, 10.0)
SPAN_S = 3 * 86400.0


@pytest.fixture(scope="module")
def iss():
    frames = EarthFrames(ISS_EPOCH, 0.0, SPAN_S)
    sat = SGP4Trajectory(parse_tle(ISS_L1, ISS_L2), ISS_EPOCH, frames)
    return sat, frames, access_windows(sat, STATION, frames, 0.0, SPAN_S)


def _skyfield_elevation(t_s):
    sat = EarthSatellite(ISS_L1, ISS_L2, ts=timescale())
    site = wgs84.latlon(STATION.latitude_deg, STATION.longitude_deg, STATION.altitude_m)
    return (sat - site).at(skyfield_times(ISS_EPOCH, t_s)).altaz()[0].degrees - STATION.min_elevation_deg


def test_access_windows_against_brute_force_scan(iss):
    """A 1-s scan of skyfield's own elevation, refined by brentq: an independent path through frames."""
    _, _, w = iss
    assert len(w) > 5
    # One day of the span keeps this under a few seconds; the algorithm is the same every day.
    t = np.arange(0.0, 86400.0, 1.0)
    el = _skyfield_elevation(t)
    idx = np.flatnonzero(np.sign(el[1:]) != np.sign(el[:-1]))
    f = lambda x: float(_skyfield_elevation(np.array([x]))[0])  # noqa: E731
    roots = np.array([brentq(f, t[i], t[i + 1], xtol=1e-7) for i in idx])
    rising = el[idx] < 0
    first_day = w.set_s < 86400.0
    assert first_day.sum() >= 3
    np.testing.assert_allclose(w.rise_s[first_day], roots[rising], atol=ten_ms, rtol=0)
    np.testing.assert_allclose(w.set_s[first_day], roots[~rising], atol=ten_ms, rtol=0)


def test_access_windows_against_skyfield_find_events(iss):
    _, _, w = iss
    sat = EarthSatellite(ISS_L1, ISS_L2, ts=timescale())
    site = wgs84.latlon(STATION.latitude_deg, STATION.longitude_deg, STATION.altitude_m)
    t0, t1 = skyfield_times(ISS_EPOCH, 0.0), skyfield_times(ISS_EPOCH, SPAN_S)
    times, events = sat.find_events(site, t0, t1, altitude_degrees=STATION.min_elevation_deg)
    sec = (times - t0) * 86400.0
    # find_events is itself only good to ~0.2 s.
    np.testing.assert_allclose(w.rise_s, sec[events == 0], atol=0.5)
    np.testing.assert_allclose(w.set_s, sec[events == 2], atol=0.5)
    np.testing.assert_allclose(w.culmination_s, sec[events == 1], atol=0.5)


def test_culmination_is_the_highest_point(iss):
    sat, frames, w = iss
    for k in range(len(w)):
        t = w.culmination_s[k] + np.array([-5.0, 0.0, 5.0])
        r, _ = sat.state(t)
        el = look_angles(r, t, STATION, frames).elevation_deg
        assert el[1] > el[0] and el[1] > el[2]
        assert el[1] == pytest.approx(w.max_elevation_deg[k], abs=1e-9)


def test_max_range_narrows_windows(iss):
    sat, frames, w = iss
    near = Station(STATION.latitude_deg, STATION.longitude_deg, 0.0, STATION.min_elevation_deg, max_range_km=1000.0)
    wn = access_windows(sat, near, frames, 0.0, SPAN_S)
    assert 0 < len(wn) < len(w)
    for k in range(len(wn)):
        t = np.array([wn.rise_s[k], wn.set_s[k]])
        r, _ = sat.state(t)
        rng = look_angles(r, t, near, frames).range_km
        assert np.all(rng <= 1000.0 + 1e-3)


def test_pass_in_progress_at_start_is_clipped():
    frames = EarthFrames(PAPER_EPOCH, 0.0, 86400.0)
    traj = NumericalJ2Trajectory.from_elements(PAPER_TARGET, PAPER_EPOCH, 0.0, 86400.0)
    full = access_windows(traj, PAPER_STATION, frames, 0.0, 86400.0)
    mid = float(full.culmination_s[0])
    late = access_windows(traj, PAPER_STATION, frames, mid, 86400.0)
    assert late.rise_clipped[0] and late.rise_s[0] == mid
    assert late.set_s[0] == pytest.approx(full.set_s[0], abs=1e-3)


def test_bad_station_and_span():
    frames = EarthFrames(PAPER_EPOCH, 0.0, 86400.0)
    traj = NumericalJ2Trajectory.from_elements(PAPER_TARGET, PAPER_EPOCH, 0.0, 86400.0)
    with pytest.raises(StationError, match="latitude_deg"):
        access_windows(traj, Station(91.0, 0.0), frames, 0.0, 86400.0)
    with pytest.raises(SearchRangeError, match="30-day"):
        access_windows(traj, PAPER_STATION, frames, 0.0, 31 * 86400.0)
    with pytest.raises(SearchRangeError, match="inverted"):
        access_windows(traj, PAPER_STATION, frames, 100.0, 0.0)


# --- Against an independent scan: many stations, masks and orbits, grazing passes ---------------
#
# The reference is skyfield's own topocentric elevation (its frames, its SGP4 wrapper), sampled
# every 10 s; each sampled maximum is refined by scipy's bounded minimize_scalar (so a pass shorter
# than the step is still seen) and every crossing by brentq. Nothing of planner.access is used.

STATIONS = {
    "shanghai": (31.1, 121.3, 0.0),
    "tira": (50.6166, 7.1296, 307.0),
    "svalbard": (78.23, 15.39, 500.0),  # above 75 deg latitude
    "cape_town": (-33.93, 18.42, 10.0),
}
ORBITS = {
    "iss": (ISS_L1, ISS_L2, ISS_EPOCH, 86400.0),
    "sso": (SSO_L1, SSO_L2, TLE_2024_EPOCH, 86400.0),
    "molniya": (MOLNIYA_L1, MOLNIYA_L2, TLE_2024_EPOCH, 2 * 86400.0),
}
CASES = [
    ("iss", "shanghai"),
    ("iss", "tira"),
    ("sso", "svalbard"),
    ("sso", "cape_town"),
    ("molniya", "svalbard"),
    ("molniya", "cape_town"),
]
MASKS_DEG = (0.0, 5.0, 10.0, 20.0, 30.0)


class SkyfieldScan:
    """Skyfield's elevation and range of one TLE from one site, on a 10-s grid and at single times."""

    def __init__(self, orbit: str, station: str) -> None:
        l1, l2, epoch, span = ORBITS[orbit]
        lat, lon, alt = STATIONS[station]
        self.ts = timescale()
        self.sat = EarthSatellite(l1, l2, ts=self.ts)
        self.site = wgs84.latlon(lat, lon, alt)
        self.t0 = self.ts.from_datetime(epoch)
        self.span = span
        self.t = np.arange(0.0, span + 1e-9, 10.0)
        self.el, self.rng = self.look(self.t)

    def look(self, t_s):
        t = self.ts.tt_jd(self.t0.whole, self.t0.tt_fraction + np.asarray(t_s, float) / 86400.0)
        alt, _, dist = (self.sat - self.site).at(t).altaz()
        return alt.degrees, dist.km

    def _scalar(self, x, which, offset):
        el, rng = self.look(np.array([x]))
        return float(el[0] - offset if which == "el" else offset - rng[0])

    def crossings(self, which: str, level: float):
        """Return sorted (rises, sets) of the elevation above ``level`` (or of -range above -level)."""
        g = (self.el - level) if which == "el" else (-self.rng + level)
        tt, gg = list(self.t), list(g)
        for i in np.flatnonzero((g[1:-1] >= g[:-2]) & (g[1:-1] > g[2:])) + 1:
            res = minimize_scalar(
                lambda x: -self._scalar(x, which, level),
                bounds=(self.t[i - 1], self.t[i + 1]),
                method="bounded",
                options={"xatol": 1e-4},
            )
            tt.append(res.x)
            gg.append(-res.fun)
        order = np.argsort(tt)
        tt, gg = np.array(tt)[order], np.array(gg)[order]
        pos = gg > 0
        rises, sets = [], []
        for i in np.flatnonzero(pos[1:] != pos[:-1]):
            root = brentq(lambda x: self._scalar(x, which, level), tt[i], tt[i + 1], xtol=1e-7)
            (rises if not pos[i] else sets).append(root)
        return np.array(rises), np.array(sets), bool(pos[0]), bool(pos[-1])


@pytest.fixture(scope="module")
def scans():
    return {}


def _ours(orbit, station, mask, max_range_km=None):
    l1, l2, epoch, span = ORBITS[orbit]
    frames = EarthFrames(epoch, -3600.0, span + 3600.0)
    sat = SGP4Trajectory(parse_tle(l1, l2), epoch, frames)
    lat, lon, alt = STATIONS[station]
    st = Station(lat, lon, alt, mask, max_range_km=max_range_km)
    return access_windows(sat, st, frames, 0.0, span)


def _scan(scans, orbit, station):
    if (orbit, station) not in scans:
        scans[orbit, station] = SkyfieldScan(orbit, station)
    return scans[orbit, station]


def _assert_same_windows(w, rises, sets, open_start, open_end):
    ours_rise = w.rise_s[~w.rise_clipped]
    ours_set = w.set_s[~w.set_clipped]
    assert ours_rise.size == rises.size and ours_set.size == sets.size, (ours_rise, rises, ours_set, sets)
    np.testing.assert_allclose(ours_rise, rises, atol=ten_ms, rtol=0)
    np.testing.assert_allclose(ours_set, sets, atol=ten_ms, rtol=0)
    assert bool(w.rise_clipped.any()) == open_start and bool(w.set_clipped.any()) == open_end


@pytest.mark.parametrize("orbit,station", CASES)
def test_every_rise_and_set_against_a_skyfield_scan(scans, orbit, station):
    """Masks 0-30 deg: every rise and set within 10 ms of the scan, none missing, none extra."""
    ref = _scan(scans, orbit, station)
    for mask in MASKS_DEG:
        rises, sets, open_start, open_end = ref.crossings("el", mask)
        w = _ours(orbit, station, mask)
        _assert_same_windows(w, rises, sets, open_start, open_end)
        # The culmination is the highest point of each window, and no window holds a lower range.
        for k in range(len(w)):
            inside = (ref.t > w.rise_s[k]) & (ref.t < w.set_s[k])
            if inside.any():
                assert w.max_elevation_deg[k] >= ref.el[inside].max() - 1e-6
                assert w.min_range_km[k] <= ref.rng[inside].min() + 1e-6


@pytest.mark.parametrize("orbit,station", [("iss", "shanghai"), ("iss", "tira"), ("sso", "svalbard")])
def test_grazing_passes_a_hair_above_the_mask(scans, orbit, station):
    """Set the mask 0.01 deg under each pass's peak: passes of a few seconds, still found and timed."""
    ref = _scan(scans, orbit, station)
    full = _ours(orbit, station, 0.0)
    assert len(full) >= 3
    for peak in full.max_elevation_deg:
        mask = float(peak) - 0.01
        rises, sets, open_start, open_end = ref.crossings("el", mask)
        w = _ours(orbit, station, mask)
        _assert_same_windows(w, rises, sets, open_start, open_end)
        grazing = np.abs(w.max_elevation_deg - peak) < 1e-6
        assert grazing.sum() == 1 and (w.set_s - w.rise_s)[grazing][0] < 60.0


def _in_view_and_range(ref, mask, limit_km):
    """The scan's windows above ``mask`` and within ``limit_km``: where both of its interval sets hold."""

    def intervals(r, s, o0, o1):
        r = np.concatenate([[0.0], r]) if o0 else r
        s = np.concatenate([s, [ref.span]]) if o1 else s
        return list(zip(r, s, strict=True))

    return [
        (max(a0, b0), min(a1, b1))
        for a0, a1 in intervals(*ref.crossings("el", mask))
        for b0, b1 in intervals(*ref.crossings("range", limit_km))
        if max(a0, b0) < min(a1, b1)
    ]


@pytest.mark.parametrize("station,limit_km", [("cape_town", 2600.0), ("svalbard", 30000.0), ("cape_town", 30000.0)])
def test_range_limit_cuts_windows_inside_a_pass(scans, station, limit_km):
    """A Molniya pass enters and leaves range inside one elevation pass: a window is where both hold."""
    ref = _scan(scans, "molniya", station)
    both = _in_view_and_range(ref, 0.0, limit_km)
    w = _ours("molniya", station, 0.0, max_range_km=limit_km)
    assert len(both) >= 1 and len(w) == len(both)
    np.testing.assert_allclose(w.rise_s, [b[0] for b in both], atol=ten_ms, rtol=0)
    np.testing.assert_allclose(w.set_s, [b[1] for b in both], atol=ten_ms, rtol=0)
    for k in range(len(w)):
        inside = (ref.t >= w.rise_s[k]) & (ref.t <= w.set_s[k])
        # The least range over the window, not the range at culmination.
        assert w.min_range_km[k] <= ref.rng[inside].min() + 1e-6
        assert w.min_range_km[k] >= ref.rng[inside].min() - 50.0


def test_pointing_rates_against_skyfields_altaz(iss):
    """The radar's azimuth and elevation rates against a central difference (0.02 s) of skyfield's own altaz, at a
    spread of moments of the highest pass; the window's azimuth rate is its culmination's, the largest a dense
    scan of skyfield's azimuth finds, and a station limit under it marks the pass a keyhole."""
    from dataclasses import replace

    from planner.access import pointing_rates

    sat_traj, frames, w = iss
    k = int(np.argmax(w.max_elevation_deg))
    sat = EarthSatellite(ISS_L1, ISS_L2, ts=timescale())
    site = wgs84.latlon(STATION.latitude_deg, STATION.longitude_deg, STATION.altitude_m)

    def sky_rates(t_s):
        alt_a, az_a, _ = (sat - site).at(skyfield_times(ISS_EPOCH, t_s + 0.01)).altaz()
        alt_b, az_b, _ = (sat - site).at(skyfield_times(ISS_EPOCH, t_s - 0.01)).altaz()
        d_az = (az_a.degrees - az_b.degrees + 180.0) % 360.0 - 180.0
        return d_az / 0.02, (alt_a.degrees - alt_b.degrees) / 0.02

    t = np.linspace(w.rise_s[k] + 5.0, w.set_s[k] - 5.0, 9)
    az, el = pointing_rates(sat_traj, STATION, frames, t)
    sky_az, sky_el = sky_rates(t)
    np.testing.assert_allclose(az, sky_az, atol=2e-3)  # deg/s
    np.testing.assert_allclose(el, sky_el, atol=2e-3)
    dense = np.arange(w.rise_s[k], w.set_s[k], 0.5)
    peak = float(np.abs(sky_rates(dense)[0]).max())
    assert w.max_azimuth_rate_deg_s[k] == pytest.approx(peak, rel=0.01)
    assert w.max_elevation_rate_deg_s[k] <= float(np.abs(sky_rates(dense)[1]).max()) + 1e-3
    assert not w.keyhole[k]
    slow = replace(STATION, max_azimuth_rate_deg_s=0.5 * float(w.max_azimuth_rate_deg_s[k]))
    assert access_windows(sat_traj, slow, frames, 0.0, SPAN_S).keyhole[k]
    with pytest.raises(StationError, match="max_azimuth_rate_deg_s"):
        access_windows(sat_traj, replace(STATION, max_azimuth_rate_deg_s=0.0), frames, 0.0, SPAN_S)


@pytest.mark.parametrize("orbit", ["iss", "molniya"])
def test_a_network_searched_at_once_finds_each_stations_windows_of_the_scan(scans, orbit):
    """Every station of a network in one search (one propagation shared, every crossing refined together): each
    station's windows are those the independent scan finds for it alone, masks and a range limit differing."""
    from planner.access import network_access

    l1, l2, epoch, span = ORBITS[orbit]
    frames = EarthFrames(epoch, -3600.0, span + 3600.0)
    sat = SGP4Trajectory(parse_tle(l1, l2), epoch, frames)
    names = ["shanghai", "tira"] if orbit == "iss" else ["svalbard", "cape_town"]
    network = [(name, mask, None) for name in names for mask in (0.0, 10.0, 20.0)]
    if orbit == "molniya":
        network.append(("cape_town", 0.0, 2600.0))
    stations = [Station(*STATIONS[name], mask, max_range_km=limit) for name, mask, limit in network]
    found = network_access(sat, stations, frames, 0.0, span)
    assert len(found) == len(network)
    for (name, mask, limit), w in zip(network, found, strict=True):
        ref = _scan(scans, orbit, name)
        if limit is None:
            _assert_same_windows(w, *ref.crossings("el", mask))
        else:
            both = _in_view_and_range(ref, mask, limit)
            assert len(both) >= 1 and len(w) == len(both)
            np.testing.assert_allclose(w.rise_s, [b[0] for b in both], atol=ten_ms, rtol=0)
            np.testing.assert_allclose(w.set_s, [b[1] for b in both], atol=ten_ms, rtol=0)
        assert w.station.size == 0  # each station's own windows
