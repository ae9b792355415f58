"""A scene's geometry: the target's trajectory over a span seen from the radar, and frames placed in it.

A ``Scene`` is built once from the target's orbit, the station, the reading of the elements
and a span (``Scene.over``): one propagation of the target and one table of Earth rotations.
Everything a pass or an estimate asks of the geometry is then read off it: the line of sight
in the target's LVLH frame over the pass (``Scene.geometry``), and each observation time's
axes (``Scene.placements``). Frames follow ``planner.frames``: a frame is a matrix whose
columns are its axes in GCRS (J2000), and a frame's observation axes are X toward the radar,
Y the line of sight's rate in the target's LVLH frame.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime

import numpy as np
from numpy.typing import NDArray

from planner.access import access_windows as _access_windows
from planner.frames import PassGeometry, observation_axes, pass_geometry
from planner.orbits import Orbit, Reading, earth_frames, trajectory
from planner.propagation import EarthFrames, Station, Trajectory, as_utc, seconds_between, utc
from scene.errors import SceneError

Vec = NDArray[np.float64]

MAX_EPOCH_GAP_S = 60 * 86400.0  # an osculating propagation integrates the whole gap from the elements' epoch
NEAR_S = np.array([-0.5, 0.0, 0.5])  # a placement's line of sight is sampled here about its moment (s)


@dataclass(frozen=True)
class Window:
    """One access window of the target to the station: rise, set (UTC) and the highest elevation (deg)."""

    rise: datetime
    set: datetime
    max_elevation_deg: float


def access_windows(
    target: Orbit, station: Station, reading: Reading, start: datetime, duration_s: float
) -> list[Window]:
    """Return the target's access windows to the station over ``duration_s`` from ``start`` (``planner.access``)."""
    epoch = as_utc(start)
    frames = earth_frames(epoch, 0.0, duration_s)
    w = _access_windows(trajectory(target, epoch, frames, 0.0, duration_s, reading), station, frames, 0.0, duration_s)
    return [
        Window(utc(epoch, w.rise_s[k]), utc(epoch, w.set_s[k]), float(w.max_elevation_deg[k])) for k in range(len(w))
    ]


def choose_window(windows: Sequence[Window], index: int | None) -> tuple[int, Window]:
    """Return the access window asked for (its index and itself), or the one that culminates highest."""
    if not windows:
        raise SceneError(["window"], "the plan has no access windows: the station never sees the target in its span")
    if index is None:
        index = int(np.argmax([w.max_elevation_deg for w in windows]))
    if not 0 <= index < len(windows):
        raise SceneError(
            ["window"], f"window {index} does not exist: the plan has {len(windows)} (0..{len(windows) - 1})"
        )
    return index, windows[index]


def check_times(windows: Sequence[Window], observed_at: Sequence[datetime]) -> None:
    """Refuse any frame time outside every access window (``observed_at``: the station cannot see the target),
    naming the nearest window and how far outside it the time is."""
    for k, t in enumerate(observed_at):
        if any(w.rise <= t <= w.set for w in windows):
            continue
        where = "the plan has no access windows"
        if windows:
            gaps = [max((w.rise - t).total_seconds(), (t - w.set).total_seconds()) for w in windows]
            j = int(np.argmin(gaps))
            w = windows[j]
            side = "before it rises" if t < w.rise else "after it sets"
            where = f"the nearest is window {j}, {w.rise.isoformat()} to {w.set.isoformat()}, {gaps[j]:.0f} s {side}"
        raise SceneError(
            ["observed_at", k],
            f"frame {k}'s time {t.isoformat()} is in none of the plan's access windows: the station cannot see "
            f"the target then ({where})",
        )


@dataclass(frozen=True)
class Placements:
    """Observation times placed in the scene: each one's frames as stacked arrays.

    ``observation`` and ``lvlh`` (N, 3, 3): the frame's observation axes and the target's LVLH
    axes in GCRS (columns); ``los_lvlh`` (N, 3): the unit line of sight, target to radar, in
    LVLH; ``los_rate_lvlh`` (N, 3): its rate (1/s), by a central difference over 1 s.
    """

    times: tuple[datetime, ...]
    observation: Vec
    lvlh: Vec
    los_lvlh: Vec
    los_rate_lvlh: Vec

    def __len__(self) -> int:
        return len(self.times)

    def observation_in_lvlh(self, k: int) -> Vec:
        """Return time ``k``'s observation axes in LVLH (columns)."""
        return np.asarray(self.lvlh[k].T @ self.observation[k])

    def attitudes(self, k: int, body_to_observation: Vec) -> tuple[Vec, Vec]:
        """Return an attitude (body to time ``k``'s observation frame) as body to LVLH and body to J2000 (GCRS)."""
        body_to_gcrs = self.observation[k] @ body_to_observation
        return np.asarray(self.lvlh[k].T @ body_to_gcrs), np.asarray(np.eye(3).T @ body_to_gcrs)


@dataclass(frozen=True)
class Scene:
    """The target's trajectory and the Earth's rotation over a span, with the station that sees it.

    Its clock counts seconds from ``epoch``, the span's start; ``duration_s`` is the span's length.
    Build it with ``Scene.over``.
    """

    target: Orbit
    station: Station
    reading: Reading
    epoch: datetime
    duration_s: float
    trajectory: Trajectory
    earth: EarthFrames

    @classmethod
    def over(
        cls,
        target: Orbit,
        station: Station,
        reading: Reading,
        start: datetime,
        end: datetime,
        field: str = "observed_at",
    ) -> Scene:
        """Propagate ``target`` once over ``[start, end]`` (1 s beyond each end) and tabulate the Earth's rotation.

        An osculating orbit is integrated from its elements' epoch, so a span more than 60 days
        from it is refused (``SceneError`` naming ``field``) before any work.
        """
        epoch = as_utc(start)
        duration_s = (as_utc(end) - epoch).total_seconds()
        if duration_s < 0:
            raise SceneError([field], f"the span ends ({end.isoformat()}) before it starts ({start.isoformat()})")
        frames = earth_frames(epoch, 0.0, duration_s)
        if target.tle is None and reading != "mean":
            assert target.elements is not None
            if abs(seconds_between(epoch, target.elements.epoch)) > MAX_EPOCH_GAP_S:
                raise SceneError([field], f"{field} is more than 60 days from the target's epoch")
        traj = trajectory(target, epoch, frames, -1.0, duration_s + 1.0, reading)
        return cls(target, station, reading, epoch, duration_s, traj, frames)

    def seconds(self, times: Sequence[datetime]) -> Vec:
        """Return seconds after the scene's epoch of ``times`` (UTC)."""
        return np.array([(t - self.epoch).total_seconds() for t in times])

    def geometry(self, t_s: Vec) -> PassGeometry:
        """Return the line of sight, range and LVLH axes at ``t_s`` (s on the scene's clock)."""
        return pass_geometry(self.trajectory, self.station, self.earth, t_s)

    def placements(self, times: Sequence[datetime]) -> Placements:
        """Place each of ``times``: its observation axes, the target's LVLH axes and the line of sight with its rate."""
        offsets = self.seconds(times)
        geo = self.geometry((offsets[:, None] + NEAR_S).ravel())
        n = len(times)
        observation, lvlh = np.empty((n, 3, 3)), np.empty((n, 3, 3))
        los, los_rate = np.empty((n, 3)), np.empty((n, 3))
        for k in range(n):
            near = geo.los_lvlh[:, 3 * k : 3 * k + 3]
            lvlh[k] = geo.lvlh[3 * k + 1]
            observation[k] = lvlh[k] @ observation_axes(near, NEAR_S)[1]
            los[k] = near[:, 1]
            los_rate[k] = (near[:, 2] - near[:, 0]) / (NEAR_S[2] - NEAR_S[0])
        return Placements(tuple(times), observation, lvlh, los, los_rate)
