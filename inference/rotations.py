"""The rotation kit: Euler angles, quaternions, matrices, the exponential and logarithm of SO(3), one name each.

numpy only. Attitudes are Euler angles (z, y, x) in degrees of R = Rz(z) Ry(y) Rx(x), body to
frame (the paper's table columns); a rotation matrix's columns are the body's axes in the frame
(v_frame = R v_body). A rotation vector is in radians, its direction the axis. Shapes: one
rotation is ``(3, 3)``, a stack ``(N, 3, 3)`` (or ``(..., 3, 3)`` where a function says so), a
rotation vector ``(3,)`` or ``(..., 3)``.

Two fixed matrices carry the frames' symmetries:

- ``MIRROR`` = diag(1, 1, -1), a reflection through the image plane (the observation frame's
  XY plane): a 2-D ISAR frame loses the coordinate along the image normal, so the attitude R and
  its near-mirror ``MIRROR @ R @ MIRROR`` (Euler (z, -y, -x)) draw the same frame for a target
  symmetric about its body xy plane.
- ``RX_180`` = diag(1, -1, -1), the half turn about X: a frame read reversed in cross-range shows
  the body turned by it (``RX_180 @ R``, ``reversed_reading``); acting on Euler (z, y, x) errors, it is
  the near-mirror's sign flip of y and x. The identity is exact, whatever the scattering: the half
  turn about the line of sight (X, range) leaves the line of sight's direction in the body, so every
  return, and negates only cross-range (Y) and the image normal (Z), which the projection drops.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

Vec = NDArray[np.float64]

MIRROR: Vec = np.diag([1.0, 1.0, -1.0])  # reflection through the image plane: M R M is a frame's near-mirror
RX_180: Vec = np.diag([1.0, -1.0, -1.0])  # Rx(180): the body turned half about X (a frame read reversed)


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


def rotation_matrices(angles_deg: Vec) -> Vec:
    """Return R = Rz(z) Ry(y) Rx(x) for angles [H, 3] (deg) as [H, 3, 3] (``rotation_matrix`` over a stack)."""
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


def euler_from_matrix(r: Vec) -> tuple[float, float, float]:
    """Return (z, y, x) in degrees of R = Rz(z) Ry(y) Rx(x) (the inverse of rotation_matrix, |y| < 90).

    z and x lie in (-180, 180], y in [-90, 90].

    >>> [round(a, 9) for a in euler_from_matrix(rotation_matrix(30.0, -20.0, 10.0))]
    [30.0, -20.0, 10.0]
    """
    y = math.asin(max(-1.0, min(1.0, -r[2, 0])))
    z = math.atan2(r[1, 0], r[0, 0])
    x = math.atan2(r[2, 1], r[2, 2])
    return math.degrees(z), math.degrees(y), math.degrees(x)


def reversed_reading(angles_deg: Sequence[float] | Vec) -> tuple[float, float, float]:
    """The attitude (Euler z, y, x deg) a frame shows when its cross-range axis is reversed: ``RX_180 @ R``.

    Its own inverse. A frame whose columns are reversed is, exactly, the ordinary frame of this attitude.

    >>> [round(a, 9) for a in reversed_reading((10.0, 20.0, 30.0))]
    [-10.0, -20.0, -150.0]
    """
    return euler_from_matrix(RX_180 @ rotation_matrix(*(float(a) for a in angles_deg)))


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


def quaternion_matrix(q: Vec) -> Vec:
    """Return the rotation matrix of the unit quaternion ``q`` = (w, x, y, z), scalar first (the inverse of
    ``euler_to_quaternion`` composed with ``rotation_matrix``). Raises ValueError unless ``q`` has unit norm
    (within 1e-3): a quaternion that is not a rotation is a caller's mistake, not something to normalise away.

    >>> [round(a, 9) for a in euler_from_matrix(quaternion_matrix(np.array(euler_to_quaternion(30.0, -20.0, 10.0))))]
    [30.0, -20.0, 10.0]
    """
    q = np.asarray(q, np.float64)
    if q.shape != (4,) or not np.all(np.isfinite(q)):
        raise ValueError(f"a quaternion is 4 finite numbers (w, x, y, z); got {q.tolist()}")
    norm = float(np.linalg.norm(q))
    if abs(norm - 1.0) > 1e-3:
        raise ValueError(f"a rotation's quaternion has unit norm; this one's norm is {norm:.6g}")
    w, x, y, z = q / norm
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def geodesic_deg(a_deg: Vec, b_deg: Vec) -> Vec:
    """Return the rotation angle (deg) between attitudes a and b, Euler z, y, x in degrees, each [N, 3] or [3].

    >>> geodesic_deg(np.array([10.0, 0.0, 0.0]), np.array([0.0, 0.0, 0.0])).round(9).tolist()
    [10.0]
    """
    ra, rb = rotation_matrices(a_deg), rotation_matrices(b_deg)
    trace = np.einsum("hij,hij->h", ra, rb)
    return np.degrees(np.arccos(np.clip((trace - 1.0) / 2.0, -1.0, 1.0)))


def euler_difference(a_deg: Vec, b_deg: Vec) -> Vec:
    """Return a - b per Euler axis, wrapped into [-180, 180) deg (z and x wrap at +-180; y never reaches it).

    >>> euler_difference(np.array([179.0, 10.0, -170.0]), np.array([-179.0, 5.0, 170.0])).tolist()
    [-2.0, 5.0, 20.0]
    """
    return np.asarray((np.asarray(a_deg, float) - np.asarray(b_deg, float) + 180.0) % 360.0 - 180.0)


def angle_deg(a: Vec, b: Vec) -> float:
    """Return the rotation angle (deg) between two rotation matrices.

    >>> round(angle_deg(rotation_matrix(0.0, 0.0, 25.0), np.eye(3)), 9)
    25.0
    """
    cos = min(1.0, max(-1.0, (float(np.sum(a * b)) - 1.0) / 2.0))
    return math.degrees(math.acos(cos))


def skew(w: Vec) -> Vec:
    """Return the cross-product matrices [..., 3, 3] of vectors [..., 3]."""
    z = np.zeros(w.shape[:-1])
    return np.stack(
        [
            np.stack([z, -w[..., 2], w[..., 1]], -1),
            np.stack([w[..., 2], z, -w[..., 0]], -1),
            np.stack([-w[..., 1], w[..., 0], z], -1),
        ],
        -2,
    )


def so3_exp(w: Vec) -> Vec:
    """Return the rotations [..., 3, 3] of rotation vectors [..., 3] (rad), by Rodrigues' formula.

    Written out element by element, I + a K + b (w w^T - theta^2 I): the turning fit calls it
    tens of thousands of times a pass, mostly on a few dozen vectors.

    >>> np.round(so3_exp(np.array([0.0, 0.0, math.pi / 2])) @ [1.0, 0.0, 0.0], 12).tolist()
    [0.0, 1.0, 0.0]
    """
    w = np.asarray(w, float)
    x, y, z = w[..., 0], w[..., 1], w[..., 2]
    t2 = x * x + y * y + z * z
    theta = np.sqrt(t2)
    small = theta < 1e-9
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1.0, np.sin(safe) / safe)
    b = np.where(small, 0.5, (1.0 - np.cos(safe)) / safe**2)
    out = np.empty(w.shape[:-1] + (3, 3))
    bxy, bxz, byz = b * x * y, b * x * z, b * y * z
    out[..., 0, 0] = 1.0 + b * (x * x - t2)
    out[..., 1, 1] = 1.0 + b * (y * y - t2)
    out[..., 2, 2] = 1.0 + b * (z * z - t2)
    out[..., 0, 1] = bxy - a * z
    out[..., 1, 0] = bxy + a * z
    out[..., 0, 2] = bxz + a * y
    out[..., 2, 0] = bxz - a * y
    out[..., 1, 2] = byz - a * x
    out[..., 2, 1] = byz + a * x
    return out


def so3_log(r: Vec) -> Vec:
    """Return the rotation vector (rad) of a rotation matrix (the inverse of ``so3_exp``, angle in [0, pi])."""
    cos = min(1.0, max(-1.0, (float(np.trace(r)) - 1.0) / 2.0))
    angle = math.acos(cos)
    w = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    if angle < 1e-9:
        return w / 2.0
    if math.pi - angle < 1e-6:  # near pi: the axis from the symmetric part
        vals, vecs = np.linalg.eigh((r + r.T) / 2.0)
        return np.asarray(vecs[:, -1] * angle)
    return np.asarray(w * angle / (2.0 * math.sin(angle)))


def so3_logs(r: Vec) -> Vec:
    """Return the rotation vectors (rad) [N, 3] of rotation matrices [N, 3, 3]: ``so3_log`` over a stack."""
    r = np.asarray(r, float)
    cos = np.clip((np.trace(r, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    angle = np.arccos(cos)
    w = np.stack([r[:, 2, 1] - r[:, 1, 2], r[:, 0, 2] - r[:, 2, 0], r[:, 1, 0] - r[:, 0, 1]], axis=1)
    small = angle < 1e-9
    factor = np.where(small, 0.5, angle / (2.0 * np.sin(np.where(small, 1.0, angle))))
    out = w * factor[:, None]
    for k in np.flatnonzero(math.pi - angle < 1e-6):  # near pi: the axis from the symmetric part, one by one
        out[k] = so3_log(r[k])
    return np.asarray(out)


def spin_rotations(axis: Vec, rate_deg_s: float, t_s: Vec) -> Vec:
    """Return the rotations [N, 3, 3] of a spin at ``rate_deg_s`` about a unit ``axis`` after times ``t_s`` [N] (s).

    >>> np.round(spin_rotations(np.array([0.0, 0.0, 1.0]), 90.0, np.array([1.0]))[0] @ [1.0, 0.0, 0.0], 12).tolist()
    [0.0, 1.0, 0.0]
    """
    angles = np.radians(rate_deg_s * np.asarray(t_s, float))
    return so3_exp(np.asarray(axis, float)[None, :] * angles[:, None])


def chordal_mean(rotations: Vec, weights: Vec) -> Vec:
    """Return the weighted chordal L2 mean of rotation matrices [N, 3, 3] (SVD projection of their weighted sum)."""
    m = np.einsum("n,nij->ij", weights, rotations)
    u, _, vt = np.linalg.svd(m)
    d = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    return np.asarray(u @ d @ vt)


def euler_jacobian(r: Vec) -> Vec:
    """Return J with d(rotation) = [J d(z, y, x)] r: the columns e_z, Rz e_y, Rz Ry e_x (rad, left perturbation)."""
    z, y, _ = (math.radians(a) for a in euler_from_matrix(r))
    cz, sz, cy, sy = math.cos(z), math.sin(z), math.cos(y), math.sin(y)
    return np.array([[0.0, -sz, cz * cy], [0.0, cz, sz * cy], [1.0, 0.0, -sy]])


# The super-Fibonacci spiral's two irrational steps (Alexa, "Super-Fibonacci Spirals", CVPR 2022).
_PHI = math.sqrt(2.0)
_PSI = 1.533751168755204288118041


def so3_grid(n: int) -> Vec:
    """Return ``n`` rotations [n, 3, 3] spread evenly over SO(3): the super-Fibonacci spiral on the unit
    quaternions (Alexa 2022), each point a rotation; low discrepancy, any ``n``, no clusters at poles as an Euler
    grid has (where cos y shrinks every cell). ``so3_grid_size`` gives the ``n`` for a spacing.

    >>> r = so3_grid(1000)
    >>> bool(np.allclose(np.einsum("nij,nkj->nik", r, r), np.eye(3), atol=1e-12))
    True
    """
    s = np.arange(n, dtype=float) + 0.5
    t = s / n
    d, big = np.sqrt(t), np.sqrt(1.0 - t)
    alpha, beta = 2.0 * math.pi * s / _PHI, 2.0 * math.pi * s / _PSI
    q = np.stack([d * np.sin(alpha), d * np.cos(alpha), big * np.sin(beta), big * np.cos(beta)], axis=1)
    w, x, y, z = q.T
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], axis=1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], axis=1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=1),
        ],
        axis=1,
    )


def so3_grid_size(spacing_deg: float) -> int:
    """The number of ``so3_grid`` rotations whose cells measure ``spacing_deg`` a side: SO(3)'s volume (8 pi^2 in
    the measure that is dz dy dx near the identity, rotation-vector volume) over a cell's (spacing in rad, cubed).
    At 7.5 deg, 35,000 (the +-45 deg Euler cube at 7.5 deg holds 2,197, 4.4 % of all rotations)."""
    return max(1, round(8.0 * math.pi**2 / math.radians(spacing_deg) ** 3))


def euler_from_matrices(r: Vec) -> Vec:
    """``euler_from_matrix`` over a stack [N, 3, 3]: (z, y, x) deg [N, 3], z and x in (-180, 180], y in [-90, 90]."""
    r = np.asarray(r, float).reshape(-1, 3, 3)
    y = np.degrees(np.arcsin(np.clip(-r[:, 2, 0], -1.0, 1.0)))
    z = np.degrees(np.arctan2(r[:, 1, 0], r[:, 0, 0]))
    x = np.degrees(np.arctan2(r[:, 2, 1], r[:, 2, 2]))
    return np.stack([z, y, x], axis=1)
