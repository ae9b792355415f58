"""Optical feasibility: is the target sunlit, and at what Sun phase angle does the observer see it."""

from __future__ import annotations

from datetime import datetime

import numpy as np
from numpy.typing import ArrayLike, NDArray

from planner.constants import R_EARTH_KM
from planner.propagation import ephemeris, skyfield_times

Vec = NDArray[np.float64]


def sun_position_km(epoch: datetime, t_s: ArrayLike) -> Vec:
    """Return the geocentric position of the Sun (GCRS, km, shape (3, N)) from de421."""
    eph = ephemeris()
    t = skyfield_times(epoch, np.atleast_1d(np.asarray(t_s, float)))
    return np.asarray((eph["sun"] - eph["earth"]).at(t).position.km).reshape(3, -1)


def sunlit(r_km: Vec, r_sun_km: Vec, earth_radius_km: float = R_EARTH_KM) -> NDArray[np.bool_]:
    """Return whether the Sun's centre is visible from each position (the segment misses the Earth).

    Shapes (3,) or (3, N). Like skyfield's ``is_sunlit``: a spherical Earth, no atmosphere.

    >>> bool(sunlit(np.array([7000.0, 0, 0]), np.array([1.5e8, 0, 0])))
    True
    >>> bool(sunlit(np.array([-7000.0, 0, 0]), np.array([1.5e8, 0, 0])))
    False
    """
    r = np.asarray(r_km, float)
    d = np.asarray(r_sun_km, float) - r
    d_norm = np.linalg.norm(d, axis=0)
    u = d / d_norm
    along = (r * u).sum(axis=0)
    # Closest approach of the ray r + s u (s >= 0) to the Earth's centre.
    s_closest = np.clip(-along, 0.0, d_norm)
    closest = r + u * s_closest
    return np.linalg.norm(closest, axis=0) > earth_radius_km


def phase_angle_deg(r_target_km: Vec, r_sun_km: Vec, line_of_sight_km: Vec) -> Vec:
    """Return the Sun phase angle (deg) at the target: between the target-to-Sun and target-to-observer directions.

    ``line_of_sight_km`` points from the target to the observer. 0 deg is a fully lit face.
    """
    to_sun = np.asarray(r_sun_km, float) - np.asarray(r_target_km, float)
    los = np.asarray(line_of_sight_km, float)
    cos = (to_sun * los).sum(axis=0) / (np.linalg.norm(to_sun, axis=0) * np.linalg.norm(los, axis=0))
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
