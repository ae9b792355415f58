import numpy as np
import pytest
from scipy.optimize import brentq
from skyfield.api import EarthSatellite, wgs84

from planner.access import access_windows, look_angles
from planner.errors import SearchRangeError, StationError
from planner.propagation import EarthFrames, NumericalJ2Trajectory, SGP4Trajectory, Station, skyfield_times, timescale
from planner.tle import parse_tle
from tests.utils.orbits import ISS_EPOCH, ISS_L1, ISS_L2, PAPER_EPOCH, PAPER_STATION, PAPER_TARGET

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
