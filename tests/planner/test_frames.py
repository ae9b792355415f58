"""A pass's line of sight in the target's LVLH frame, against skyfield's own topocentric positions."""

import math

import numpy as np
from skyfield.api import EarthSatellite, wgs84

from planner.frames import ground_track, lvlh_axes, observation_axes, pass_geometry, swept_deg, visibility_circle
from planner.propagation import EarthFrames, SGP4Trajectory, Station, skyfield_times, timescale
from planner.tle import parse_tle
from tests.utils.orbits import ISS_EPOCH, ISS_L1, ISS_L2

STATION = Station(40.0, -75.0, 100.0, 0.0)


def test_line_of_sight_and_lvlh_against_skyfield():
    t = np.linspace(0.0, 5400.0, 37)
    frames = EarthFrames(ISS_EPOCH, -3600.0, 9000.0)
    geo = pass_geometry(SGP4Trajectory(parse_tle(ISS_L1, ISS_L2), ISS_EPOCH, frames), STATION, frames, t)
    sat = EarthSatellite(ISS_L1, ISS_L2, ts=timescale())
    site = wgs84.latlon(STATION.latitude_deg, STATION.longitude_deg, STATION.altitude_m)
    times = skyfield_times(ISS_EPOCH, t)
    topo = -(sat - site).at(times).position.km  # target to station, GCRS
    state = sat.at(times)
    r, v = state.position.km, state.velocity.km_per_s
    np.testing.assert_allclose(geo.range_km, np.linalg.norm(topo, axis=0), rtol=2e-6)
    # LVLH by hand from skyfield's state: radial, along-track, normal.
    for k in range(len(t)):
        x = r[:, k] / np.linalg.norm(r[:, k])
        z = np.cross(r[:, k], v[:, k])
        z /= np.linalg.norm(z)
        axes = np.stack([x, np.cross(z, x), z], axis=1)
        np.testing.assert_allclose(geo.lvlh[k], axes, atol=2e-6)
        los = axes.T @ topo[:, k] / np.linalg.norm(topo[:, k])
        np.testing.assert_allclose(geo.los_lvlh[:, k], los, atol=2e-6)


def test_lvlh_axes_are_right_handed_rotations():
    rng = np.random.default_rng(0)
    r = rng.normal(size=(3, 20)) * 7000
    v = rng.normal(size=(3, 20)) * 7
    m = lvlh_axes(r, v)
    np.testing.assert_allclose(m @ np.swapaxes(m, 1, 2), np.broadcast_to(np.eye(3), m.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(m), 1.0, atol=1e-12)


def test_observation_axes_of_a_line_of_sight_turning_in_a_plane():
    """A line of sight turning at a steady rate about +z: Y is its direction of travel, Z is +z, the sweep the angle."""
    t = np.linspace(0.0, 10.0, 11)
    a = np.radians(3.0) * t
    los = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)])
    obs = observation_axes(los, t)
    for k in range(len(t)):
        np.testing.assert_allclose(obs[k][:, 1], [-math.sin(a[k]), math.cos(a[k]), 0.0], atol=1e-3)
        np.testing.assert_allclose(obs[k][:, 2], [0.0, 0.0, 1.0], atol=1e-9)
    np.testing.assert_allclose(swept_deg(los), 3.0 * t, atol=1e-9)


def test_ground_track_against_skyfields_wgs84_subpoints():
    frames = EarthFrames(ISS_EPOCH, 0.0, 7200.0)
    traj = SGP4Trajectory(parse_tle(ISS_L1, ISS_L2), ISS_EPOCH, frames)
    t = np.linspace(0.0, 6000.0, 50)
    lat, lon, h = ground_track(traj, frames, t)
    sat = EarthSatellite(ISS_L1, ISS_L2, ts=timescale())
    geo = sat.at(skyfield_times(ISS_EPOCH, t))
    ref_lat, ref_lon = wgs84.latlon_of(geo)
    np.testing.assert_allclose(lat, ref_lat.degrees, atol=2e-4)
    np.testing.assert_allclose((lon - ref_lon.degrees + 180.0) % 360.0 - 180.0, 0.0, atol=2e-4)
    np.testing.assert_allclose(h, wgs84.height_of(geo).km, atol=0.01)


def test_visibility_circle_is_where_skyfield_sees_the_height_at_the_mask():
    """A point at the given height above each circle point is seen from the station at the mask's elevation."""
    station = Station(50.6166, 7.1296, 307.0, min_elevation_deg=3.0, mask=((0.0, 5.0), (90.0, 2.0), (200.0, 12.0)))
    lat, lon = visibility_circle(station, 400.0, n=73)
    site = wgs84.latlon(station.latitude_deg, station.longitude_deg, station.altitude_m)
    t = timescale().utc(2024, 1, 1)
    seen = []
    for la, lo in zip(lat, lon, strict=True):
        alt, az, _ = (wgs84.latlon(la, lo, 400_000.0) - site).at(t).altaz()
        seen.append((alt.degrees, az.degrees))
    alt, az = np.array(seen).T
    pts = np.array(station.mask + ((360.0, 5.0),))
    limit = np.maximum(3.0, np.interp(az, pts[:, 0], pts[:, 1]))
    np.testing.assert_allclose(alt, limit, atol=0.4)  # a sphere of the site's radius against the ellipsoid
