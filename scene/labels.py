"""A GSA scene's labels: the optical observer's attitude of the target, turned into each radar frame's angles.

While the radar images the target, the observer satellite measures its attitude (body to J2000).
A frame's label is that attitude seen from the frame's observation axes (X toward the radar, Y the
line of sight's rate in LVLH; ``scene.geometry``): ``angles = euler(observation^T @ body_to_j2000)``,
the reverse of what the estimate path does with an answer (``Placements.attitudes``).

- ``optical_attitudes``: what an observer with an error of ``sigma_deg`` (1-sigma, per axis, a small
  rotation applied in the body) reports for a simulated pass, and the frames' labels from it;
- ``plan_resolver``: the ``inference.labelled.Resolver`` of a scene, which labels frames written with
  ``quaternion_j2000`` and ``observed_at``.
"""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime

import numpy as np
from numpy.typing import NDArray

from inference.labelled import Resolver
from inference.rotations import euler_from_matrix, euler_to_quaternion, quaternion_matrix, so3_exp
from scene.geometry import Scene
from scene.simulation import SimulatedFrame

Vec = NDArray[np.float64]


def optical_attitudes(frames: Sequence[SimulatedFrame], sigma_deg: float, rng: np.random.Generator) -> tuple[Vec, Vec]:
    """The observer's measured attitude of each frame, body to J2000 as quaternions (w, x, y, z) [N, 4], and
    the labels it gives in each frame's observation frame (Euler z, y, x deg) [N, 3].

    The true body-to-J2000 rotation is LVLH-in-J2000 times body-to-LVLH; the measurement is it times a
    small rotation drawn with ``sigma_deg`` per axis (the optical estimate's error).
    """
    quats, labels = [], []
    for f in frames:
        body_to_gcrs = f.lvlh_in_gcrs @ f.body_to_lvlh
        error = so3_exp(np.radians(rng.normal(0.0, sigma_deg, 3))) if sigma_deg > 0 else np.eye(3)
        measured = body_to_gcrs @ error
        observation = f.lvlh_in_gcrs @ f.observation_in_lvlh
        quats.append(euler_to_quaternion(*euler_from_matrix(measured)))
        labels.append(euler_from_matrix(observation.T @ measured))
    return np.array(quats), np.array(labels)


def plan_resolver(scene: Scene) -> Resolver:
    """Label frames by the scene's geometry: a quaternion (body to J2000) at a moment -> the frame's Euler angles."""

    def resolve(quaternion: Vec, when: datetime, name: str) -> tuple[float, float, float]:
        from scene.errors import SceneError

        t = (when - scene.epoch).total_seconds()
        if not -1e-6 <= t <= scene.duration_s + 1e-6:
            raise SceneError(["observed_at"], f"{name}: {when.isoformat()} is outside the scene's span")
        observation = scene.placements([when]).observation[0]
        return euler_from_matrix(observation.T @ quaternion_matrix(quaternion))

    return resolve
