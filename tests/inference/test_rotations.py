"""The rotation kit against scipy's Rotation, an independent implementation of the same group."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from inference.rotations import (
    MIRROR,
    RX_180,
    angle_deg,
    chordal_mean,
    euler_from_matrices,
    euler_from_matrix,
    euler_to_quaternion,
    geodesic_deg,
    rotation_matrices,
    rotation_matrix,
    so3_exp,
    so3_grid,
    so3_grid_size,
    so3_log,
    so3_logs,
    spin_rotations,
)

ANGLES = [(10.0, -20.0, 30.0), (-44.0, 44.0, 0.5), (170.0, -80.0, -179.0), (0.0, 0.0, 0.0)]
one_microradian = 1e-6


@pytest.mark.parametrize("zyx", ANGLES)
def test_euler_matrix_and_quaternion_against_scipy(zyx):
    """R = Rz(z) Ry(y) Rx(x) is scipy's intrinsic 'ZYX' sequence; the quaternion is scalar first."""
    ref = Rotation.from_euler("ZYX", zyx, degrees=True)
    np.testing.assert_allclose(rotation_matrix(*zyx), ref.as_matrix(), atol=1e-12)
    np.testing.assert_allclose(rotation_matrices(np.array([zyx]))[0], ref.as_matrix(), atol=1e-12)
    q = np.array(euler_to_quaternion(*zyx))
    x, y, z, w = ref.as_quat()
    assert abs(abs(float(q @ [w, x, y, z])) - 1.0) < 1e-12  # the same rotation, up to the quaternion's sign
    assert euler_from_matrix(rotation_matrix(*zyx)) == pytest.approx(zyx, abs=1e-9)


def test_exp_and_log_against_scipy_rotvec():
    rng = np.random.default_rng(1)
    w = rng.normal(size=(50, 3))
    w *= (rng.uniform(0.0, math.pi - 1e-3, 50) / np.linalg.norm(w, axis=1))[:, None]
    np.testing.assert_allclose(so3_exp(w), Rotation.from_rotvec(w).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(so3_logs(so3_exp(w)), w, atol=one_microradian)
    np.testing.assert_allclose(so3_log(so3_exp(w[0])), w[0], atol=one_microradian)
    near_pi = np.array([0.0, math.pi - 1e-8, 0.0])  # the axis from the symmetric part
    assert angle_deg(so3_exp(so3_log(so3_exp(near_pi))), so3_exp(near_pi)) < 1e-4


def test_spin_rotations_turn_about_their_axis():
    axis = np.array([1.0, 2.0, 2.0]) / 3.0
    r = spin_rotations(axis, 3.0, np.array([0.0, 10.0, -20.0]))
    np.testing.assert_allclose(
        r, Rotation.from_rotvec(np.outer([0.0, 30.0, -60.0], axis), degrees=True).as_matrix(), atol=1e-12
    )


def test_geodesic_and_angle_agree_with_scipy_magnitude():
    a, b = Rotation.from_euler("ZYX", ANGLES[0], degrees=True), Rotation.from_euler("ZYX", ANGLES[1], degrees=True)
    truth = math.degrees((a.inv() * b).magnitude())
    assert angle_deg(a.as_matrix(), b.as_matrix()) == pytest.approx(truth, abs=1e-9)
    assert geodesic_deg(np.array(ANGLES[0]), np.array(ANGLES[1]))[0] == pytest.approx(truth, abs=1e-9)


def test_chordal_mean_of_one_rotation_and_of_a_symmetric_pair():
    r = rotation_matrix(*ANGLES[0])
    np.testing.assert_allclose(chordal_mean(np.array([r, r]), np.array([1.0, 2.0])), r, atol=1e-12)
    pair = np.array([r @ rotation_matrix(0.0, 0.0, 5.0), r @ rotation_matrix(0.0, 0.0, -5.0)])
    np.testing.assert_allclose(chordal_mean(pair, np.ones(2)), r, atol=1e-12)


@pytest.mark.parametrize("zyx", ANGLES[:2])
def test_the_two_symmetries(zyx):
    """The near-mirror M R M is Euler (z, -y, -x); a frame read reversed is the body turned half about X."""
    r = rotation_matrix(*zyx)
    z, y, x = zyx
    assert euler_from_matrix(MIRROR @ r @ MIRROR) == pytest.approx((z, -y, -x), abs=1e-9)
    np.testing.assert_allclose(RX_180, Rotation.from_euler("x", 180, degrees=True).as_matrix(), atol=1e-15)
    # the projection on the image plane (the frame's X and Y rows) is the same for R and M R M, up to z's sign
    np.testing.assert_allclose((MIRROR @ r @ MIRROR)[:2, :2], r[:2, :2], atol=1e-12)


def test_quaternion_matches_rotation_matrix():
    from inference.rotations import rotation_matrix

    z, y, x = 30.0, -20.0, 10.0
    w, qx, qy, qz = euler_to_quaternion(z, y, x)
    r = np.array(
        [
            [1 - 2 * (qy**2 + qz**2), 2 * (qx * qy - w * qz), 2 * (qx * qz + w * qy)],
            [2 * (qx * qy + w * qz), 1 - 2 * (qx**2 + qz**2), 2 * (qy * qz - w * qx)],
            [2 * (qx * qz - w * qy), 2 * (qy * qz + w * qx), 1 - 2 * (qx**2 + qy**2)],
        ]
    )
    np.testing.assert_allclose(r, rotation_matrix(z, y, x), atol=1e-12)


def test_the_so3_grid_covers_every_rotation_within_its_spacing():
    """Brute force: the nearest grid rotation to each of 3,000 drawn uniformly by scipy lies within the spacing (a
    cell's half-diagonal is 0.87 of it), about half a spacing at the median."""
    drawn = Rotation.random(3000, random_state=3).as_matrix()
    for spacing in (12.0, 15.0, 20.0):
        grid = so3_grid(so3_grid_size(spacing))
        cos = (np.einsum("aij,bij->ab", drawn, grid).max(axis=1) - 1.0) / 2.0
        nearest = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
        assert nearest.max() < 0.9 * spacing and 0.4 * spacing < np.median(nearest) < 0.6 * spacing, spacing
    assert so3_grid_size(7.5) == pytest.approx(35_000, rel=0.01)


def test_euler_from_matrices_is_euler_from_matrix_over_a_stack():
    r = Rotation.random(50, random_state=4).as_matrix()
    np.testing.assert_allclose(euler_from_matrices(r), [euler_from_matrix(m) for m in r], atol=1e-12)


def test_uniform_rotations_of_the_simulator_follow_the_haar_measure():
    """Closed forms of the Haar measure: the rotation angle has CDF (t - sin t) / pi on [0, pi], and sin y of the
    Euler angle y is uniform on [-1, 1] (its density is cos y / 2). Kolmogorov-Smirnov on 2,000 draws."""
    from scipy import stats

    from inference.simulation.dataset import DatasetSpec, frame_truth

    spec = DatasetSpec(n=2000, seed=5, attitudes="so3")
    angles = np.array([frame_truth(spec, k)[0] for k in range(spec.n)])
    theta = np.radians(geodesic_deg(angles, np.zeros_like(angles)))
    assert stats.kstest(theta, lambda t: (t - np.sin(t)) / np.pi).pvalue > 0.01
    assert stats.kstest(np.sin(np.radians(angles[:, 1])), stats.uniform(-1, 2).cdf).pvalue > 0.01
    assert np.abs(angles[:, [0, 2]]).max() > 170.0  # the whole range, not the cube
    cube = np.array([frame_truth(DatasetSpec(n=3, seed=5), k)[0] for k in range(3)])
    assert np.abs(cube).max() <= 45.0
