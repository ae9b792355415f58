"""The contract shared by the simulator, training and serving: frame normalisation and attitude angles.

numpy only, so the service can import it without torch or the simulator. Attitudes are
Euler angles (z, y, x) in degrees of R = Rz(z) Ry(y) Rx(x), body to observation frame;
the networks read and write them scaled by ``ANGLE_SCALE_DEG`` (the +-45 deg label range).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

Vec = NDArray[np.float64]

ANGLE_SCALE_DEG = 45.0  # network outputs are angles / ANGLE_SCALE_DEG


def normalise_frame(magnitude: NDArray[np.floating], dynamic_range_db: float = 40.0) -> NDArray[np.float32]:
    """Map an ISAR magnitude image to [0, 1] the way the networks consume it (training and service alike).

    Decibels relative to the 99.5th percentile (robust to one very bright cell:
    a cylinder seen broadside can sit 40 dB above the rest), clipped to
    ``dynamic_range_db`` below it.
    """
    mag = np.abs(np.asarray(magnitude, np.float64))
    ref = float(np.percentile(mag, 99.5))
    if not math.isfinite(ref) or ref <= 0.0:
        return np.zeros(mag.shape, np.float32)
    db = 20.0 * np.log10(np.maximum(mag, ref * 1e-12) / ref)
    return np.clip((db + dynamic_range_db) / dynamic_range_db, 0.0, 1.0).astype(np.float32)


def rotation_matrix(z_deg: float, y_deg: float, x_deg: float) -> Vec:
    """Return R = Rz(z) Ry(y) Rx(x), body to observation frame, from angles in degrees.

    >>> np.round(rotation_matrix(90.0, 0.0, 0.0) @ [1.0, 0.0, 0.0], 12).tolist()
    [0.0, 1.0, 0.0]
    """
    z, y, x = (math.radians(a) for a in (z_deg, y_deg, x_deg))
    cz, sz, cy, sy, cx, sx = math.cos(z), math.sin(z), math.cos(y), math.sin(y), math.cos(x), math.sin(x)
    rz = np.array([[cz, -sz, 0.0], [sz, cz, 0.0], [0.0, 0.0, 1.0]])
    ry = np.array([[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cx, -sx], [0.0, sx, cx]])
    return rz @ ry @ rx


def euler_from_matrix(r: Vec) -> tuple[float, float, float]:
    """Return (z, y, x) in degrees of R = Rz(z) Ry(y) Rx(x) (the inverse of rotation_matrix, |y| < 90)."""
    y = math.asin(max(-1.0, min(1.0, -r[2, 0])))
    z = math.atan2(r[1, 0], r[0, 0])
    x = math.atan2(r[2, 1], r[2, 2])
    return math.degrees(z), math.degrees(y), math.degrees(x)


def euler_to_quaternion(z_deg: float, y_deg: float, x_deg: float) -> tuple[float, float, float, float]:
    """Return the unit quaternion (w, x, y, z) of R = Rz(z) Ry(y) Rx(x).

    >>> [round(q, 6) for q in euler_to_quaternion(90.0, 0.0, 0.0)]
    [0.707107, 0.0, 0.0, 0.707107]
    """
    hz, hy, hx = (math.radians(a) / 2.0 for a in (z_deg, y_deg, x_deg))
    cz, sz, cy, sy, cx, sx = math.cos(hz), math.sin(hz), math.cos(hy), math.sin(hy), math.cos(hx), math.sin(hx)
    return (
        cz * cy * cx + sz * sy * sx,
        cz * cy * sx - sz * sy * cx,
        cz * sy * cx + sz * cy * sx,
        sz * cy * cx - cz * sy * sx,
    )


def rotation_matrices(angles_deg: Vec) -> Vec:
    """Return R = Rz(z) Ry(y) Rx(x) for angles [H, 3] (deg) as [H, 3, 3] (``inference.frames.rotation_matrix``)."""
    a = np.radians(np.asarray(angles_deg, float).reshape(-1, 3))
    cz, sz = np.cos(a[:, 0]), np.sin(a[:, 0])
    cy, sy = np.cos(a[:, 1]), np.sin(a[:, 1])
    cx, sx = np.cos(a[:, 2]), np.sin(a[:, 2])
    r = np.empty((len(a), 3, 3))
    r[:, 0, 0] = cz * cy
    r[:, 0, 1] = cz * sy * sx - sz * cx
    r[:, 0, 2] = cz * sy * cx + sz * sx
    r[:, 1, 0] = sz * cy
    r[:, 1, 1] = sz * sy * sx + cz * cx
    r[:, 1, 2] = sz * sy * cx - cz * sx
    r[:, 2, 0] = -sy
    r[:, 2, 1] = cy * sx
    r[:, 2, 2] = cy * cx
    return r


def geodesic_deg(a_deg: Vec, b_deg: Vec) -> Vec:
    """Return the rotation angle (deg) between attitudes a and b, Euler z, y, x in degrees, each [N, 3] or [3].

    >>> geodesic_deg(np.array([10.0, 0.0, 0.0]), np.array([0.0, 0.0, 0.0])).round(9).tolist()
    [10.0]
    """
    ra, rb = rotation_matrices(a_deg), rotation_matrices(b_deg)
    trace = np.einsum("hij,hij->h", ra, rb)
    return np.degrees(np.arccos(np.clip((trace - 1.0) / 2.0, -1.0, 1.0)))
