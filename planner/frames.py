"""Frames a radar pass is described in: the target's orbital frame (LVLH) and each moment's observation frame.

Vectors follow the planner's convention, (3, N); a frame is a matrix whose columns are its
axes, stacked (N, 3, 3).

- **LVLH** of the target: x radial (out), y along-track (z cross x), z along the orbit
  normal (r cross v).
- **Observation frame** of an ISAR frame: X from the target toward the radar, Y along
  the rate of change of that line of sight *as the target sees it* (in its own LVLH frame:
  a target held fixed in LVLH turns with that frame, and only the line of sight's motion
  relative to the body forms the image), Z = X cross Y. This is the frame the simulator
  images in (``inference.simulation.radar``: the line of sight sweeps from -Y to +Y through X).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from planner.access import look_angles, mask_deg
from planner.constants import F_EARTH, R_EARTH_KM
from planner.propagation import EarthFrames, Station, Trajectory
from planner.radar import CrossSection, RadarView, radar_view

Vec = NDArray[np.float64]


def lvlh_axes(r_km: Vec, v_km_s: Vec) -> Vec:
    """Return the LVLH axes (N, 3, 3), columns radial, along-track, normal, of states (3, N) in their frame."""
    radial = r_km / np.linalg.norm(r_km, axis=0)
    h = np.cross(r_km, v_km_s, axis=0)
    normal = h / np.linalg.norm(h, axis=0)
    along = np.cross(normal, radial, axis=0)
    return np.stack([radial, along, normal], axis=1).transpose(2, 0, 1)


def site_gcrs(station: Station, frames: EarthFrames, t_s: Vec) -> Vec:
    """Return the station's GCRS position (3, N) at ``t_s``."""
    m = frames.gcrs_to_itrs(t_s)  # (3, 3, N), GCRS to ITRS
    return np.asarray(np.einsum("jin,j->in", m, station.itrs_km()))


@dataclass(frozen=True)
class PassGeometry:
    """The line of sight over a pass, sampled at ``t_s``: in the target's LVLH frame, with range and the LVLH axes."""

    t_s: Vec
    los_lvlh: Vec  # (3, N) unit vectors, target to radar, in LVLH
    range_km: Vec  # (N,)
    lvlh: Vec  # (N, 3, 3) LVLH axes in GCRS (columns)


def pass_geometry(traj: Trajectory, station: Station, frames: EarthFrames, t_s: Vec) -> PassGeometry:
    """Return the target-to-station line of sight at ``t_s`` (s after the frames' epoch) in the target's LVLH."""
    t = np.atleast_1d(np.asarray(t_s, float))
    r, v = traj.state(t)
    lvlh = lvlh_axes(r, v)
    los = site_gcrs(station, frames, t) - r
    rng = np.linalg.norm(los, axis=0)
    los_lvlh = np.einsum("nji,jn->in", lvlh, los / rng)
    return PassGeometry(t, los_lvlh, rng, lvlh)


def station_radar_view(
    traj: Trajectory, station: Station, frames: EarthFrames, t_s: Vec, cross_section: CrossSection | None
) -> RadarView:
    """What the station's radar sees of the target at ``t_s`` (``planner.radar.radar_view``): elevation as the
    station sees it (refracted when it asks), range, the aspect's turn in LVLH, integration and SNR."""

    def geometry_at(t: Vec) -> tuple[Vec, Vec]:
        g = pass_geometry(traj, station, frames, t)
        return g.los_lvlh, g.range_km

    def elevation_at(t: Vec) -> Vec:
        r, _ = traj.state(t)
        return look_angles(r, t, station, frames).elevation_deg

    return radar_view(station.radar, np.asarray(t_s, float), geometry_at, elevation_at, cross_section)


def network_radar_view(
    traj: Trajectory,
    stations: tuple[Station, ...],
    frames: EarthFrames,
    t_s: Vec,
    station_index: NDArray[np.int64],
    cross_section: CrossSection | None,
) -> RadarView:
    """``station_radar_view`` for moments each seen by its own station of a network (``station_index``)."""
    t = np.asarray(t_s, float)
    n = t.size
    el, rng, rate, t_int, rcs, snr = (np.full(n, np.nan) for _ in range(6))
    cols = (el, rng, rate, t_int, rcs, snr)
    los = np.full((3, n), np.nan)
    for j in np.unique(station_index):
        sel = station_index == j
        view = station_radar_view(traj, stations[int(j)], frames, t[sel], cross_section)
        parts = (view.elevation_deg, view.range_km, view.rate_deg_s, view.integration_s, view.rcs_m2, view.snr_db)
        for col, part in zip(cols, parts, strict=True):
            col[sel] = part
        los[:, sel] = view.los_lvlh
    return RadarView(el, rng, rate, t_int, rcs, snr, los)


def observation_axes(los: Vec, t_s: Vec) -> Vec:
    """Return observation axes (N, 3, 3) from unit lines of sight (3, N) at times ``t_s``, in the lines' frame.

    X is the line of sight, Y its rate (by central differences, one-sided at the ends) with the
    part along X removed, Z = X cross Y. Needs at least two times, increasing.
    """
    t = np.asarray(t_s, float)
    rate = np.gradient(los, t, axis=1)
    rate = rate - np.sum(rate * los, axis=0) * los
    y = rate / np.linalg.norm(rate, axis=0)
    return np.stack([los, y, np.cross(los, y, axis=0)], axis=1).transpose(2, 0, 1)


def swept_deg(los: Vec) -> Vec:
    """Return the cumulative angle (deg) the unit lines of sight (3, N) sweep, 0 at the first."""
    cos = np.clip(np.sum(los[:, 1:] * los[:, :-1], axis=0), -1.0, 1.0)
    return np.concatenate([[0.0], np.cumsum(np.degrees(np.arccos(cos)))])


def geodetic(r_itrs_km: Vec) -> tuple[Vec, Vec, Vec]:
    """Return WGS-84 geodetic latitude, longitude (deg) and height (km) of ITRS positions (3, N).

    Bowring's iteration from the geocentric latitude; three steps reach 1e-9 deg for any
    height from the ground to GEO.
    """
    x, y, z = np.asarray(r_itrs_km, float)
    e2 = F_EARTH * (2.0 - F_EARTH)
    p = np.hypot(x, y)
    lat = np.arctan2(z, p * (1.0 - e2))
    for _ in range(4):
        n = R_EARTH_KM / np.sqrt(1.0 - e2 * np.sin(lat) ** 2)
        h = p / np.cos(lat) - n
        lat = np.arctan2(z, p * (1.0 - e2 * n / (n + h)))
    n = R_EARTH_KM / np.sqrt(1.0 - e2 * np.sin(lat) ** 2)
    h = p / np.cos(lat) - n
    return np.degrees(lat), np.degrees(np.arctan2(y, x)), h


def ground_track(traj: Trajectory, frames: EarthFrames, t_s: Vec) -> tuple[Vec, Vec, Vec]:
    """The sub-satellite points of ``traj`` at ``t_s``: geodetic latitude, longitude (deg) and height (km)."""
    t = np.asarray(t_s, float)
    r, _ = traj.state(t)
    return geodetic(frames.to_itrs(t, r))


def visibility_circle(station: Station, height_km: float, n: int = 361) -> tuple[Vec, Vec]:
    """Where a satellite at ``height_km`` is in view of ``station``: the ground points (lat, lon deg), one an azimuth.

    At each azimuth the limit is the station's mask there (``planner.access.mask_deg``, never below
    its minimum elevation); the Earth-central angle to the edge is arccos(R cos e / (R + h)) - e on
    a sphere of the site's geocentric radius. Geometric elevations: refraction would widen it a little.
    """
    az = np.linspace(0.0, 360.0, n)
    e = np.radians(mask_deg(station, az))
    radius = float(np.linalg.norm(station.itrs_km()))
    lam = np.arccos(radius * np.cos(e) / (radius + height_km)) - e
    lat1, lon1, a = np.radians(station.latitude_deg), np.radians(station.longitude_deg), np.radians(az)
    lat2 = np.arcsin(np.sin(lat1) * np.cos(lam) + np.cos(lat1) * np.sin(lam) * np.cos(a))
    lon2 = lon1 + np.arctan2(np.sin(a) * np.sin(lam) * np.cos(lat1), np.cos(lam) - np.sin(lat1) * np.sin(lat2))
    return np.degrees(lat2), (np.degrees(lon2) + 180.0) % 360.0 - 180.0


def terminator(sun_itrs_km: Vec, n: int = 361) -> tuple[Vec, Vec, float, float]:
    """The day-night line for the Sun at ``sun_itrs_km`` (ITRS, km): the great circle 90 deg from the subsolar point,
    as ground points (lat, lon deg) by azimuth from the antisolar point (north through east, as
    ``visibility_circle``), and that point (lat, lon deg).

    Geocentric directions on a sphere, geometric (no refraction, the Sun's centre): where the Sun's elevation,
    seen from the ground, is 0 to within the Earth's flattening (about 0.2 deg).
    """
    s = np.asarray(sun_itrs_km, float).reshape(3)
    s = s / np.linalg.norm(s)
    lat1 = -np.arcsin(s[2])  # the antisolar point
    lon1 = np.arctan2(-s[1], -s[0])
    a = np.radians(np.linspace(0.0, 360.0, n))
    lam = np.pi / 2.0
    lat2 = np.arcsin(np.sin(lat1) * np.cos(lam) + np.cos(lat1) * np.sin(lam) * np.cos(a))
    lon2 = lon1 + np.arctan2(np.sin(a) * np.sin(lam) * np.cos(lat1), np.cos(lam) - np.sin(lat1) * np.sin(lat2))
    wrap = (np.degrees(lon2) + 180.0) % 360.0 - 180.0
    return np.degrees(lat2), wrap, float(np.degrees(lat1)), float((np.degrees(lon1) + 180.0) % 360.0 - 180.0)
