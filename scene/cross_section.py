"""The target's mean radar cross section by aspect: what the planner's radar equation needs of the target model.

A table over the sphere of lines of sight (target to radar) in the target's LVLH frame, for a target
flown at its nominal attitude (body axes along LVLH: radial, along-track, orbit normal). Each entry is
the physical-optics echo of the target's mesh (``inference.simulation.po``, single bounce, smooth facets)
averaged over the band and the aperture of the paper's Table 3 radar (15 GHz, 1.6 GHz, 5.1 deg), i.e. the
mean of |s(K)|^2 over the frame's k-patch, which is the cross section the image's energy carries
(Parseval). The table is made once per built-in target and shipped (``scene/data/<target>-rcs.npz``,
``python -m scene.cross_section_build``: about a minute a target; it records the mesh's sha256, which
``tests/scene/test_cross_section.py`` checks against the mesh of today); a lookup interpolates log sigma
bilinearly in azimuth and elevation. This module needs numpy only: the service loads it without the simulator.
"""

from __future__ import annotations

import math
from functools import lru_cache
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from planner.radar import CrossSection
from scene.errors import SceneError

Vec = NDArray[np.float64]

DATA = Path(__file__).parent / "data"
STEP_DEG = 10.0  # the table's grid in azimuth and elevation (the aperture averages over 5.1 deg)


def grid() -> tuple[Vec, Vec]:
    """The table's azimuths (deg, [0, 360) from radial toward along-track) and elevations (deg, -90..90 toward
    the orbit normal)."""
    return np.arange(0.0, 360.0, STEP_DEG), np.arange(-90.0, 90.0 + 0.5 * STEP_DEG, STEP_DEG)


def direction(azimuth_deg: float, elevation_deg: float) -> Vec:
    """The unit line of sight (LVLH) at an azimuth and elevation of the table."""
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    return np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])


class CrossSectionTable:
    """A shipped table as the planner's ``CrossSection``: unit lines of sight (3, N) in LVLH to m^2 (N,)."""

    def __init__(self, rcs_m2: Vec, azimuth_deg: Vec, elevation_deg: Vec) -> None:
        self.log_rcs = np.log10(np.maximum(rcs_m2, 1e-12))
        self.azimuth_deg = azimuth_deg
        self.elevation_deg = elevation_deg

    def __call__(self, los_lvlh: Vec) -> Vec:
        u = np.asarray(los_lvlh, float).reshape(3, -1)
        u = u / np.linalg.norm(u, axis=0)
        el = np.degrees(np.arcsin(np.clip(u[2], -1.0, 1.0)))
        az = np.mod(np.degrees(np.arctan2(u[1], u[0])), 360.0)
        step_a = self.azimuth_deg[1] - self.azimuth_deg[0]
        step_e = self.elevation_deg[1] - self.elevation_deg[0]
        fa = (az - self.azimuth_deg[0]) / step_a
        fe = np.clip((el - self.elevation_deg[0]) / step_e, 0.0, self.elevation_deg.size - 1.000001)
        ja, ie = np.floor(fa).astype(int), np.floor(fe).astype(int)
        wa, we = fa - ja, fe - ie
        n = self.azimuth_deg.size
        ja0, ja1 = ja % n, (ja + 1) % n
        t = self.log_rcs
        value = (1 - we) * ((1 - wa) * t[ie, ja0] + wa * t[ie, ja1]) + we * (
            (1 - wa) * t[ie + 1, ja0] + wa * t[ie + 1, ja1]
        )
        return np.asarray(10.0**value)


@lru_cache(maxsize=4)
def for_target(target_name: str) -> CrossSection:
    """The shipped table of a built-in target as a ``CrossSection``; SceneError where there is none."""
    path = DATA / f"{target_name}-rcs.npz"
    if not path.is_file():
        raise SceneError(
            ["target"], f"no cross-section table for target {target_name!r}: python -m scene.cross_section_build"
        )
    with np.load(path, allow_pickle=False) as f:
        return CrossSectionTable(f["rcs_m2"], f["azimuth_deg"], f["elevation_deg"])
