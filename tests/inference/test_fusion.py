"""Fusing a pass: synthetic passes whose truth is known, against the per-frame errors of the same pass."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from inference.fusion import PassFrame, angle_deg, chordal_mean, fuse, observation_attitude, so3_log

M = np.diag([1.0, 1.0, -1.0])  # the near-mirror: M R M, a reflection through the frame's image plane


def _observation_frames(n, sweep_deg=80.0, tilt_deg=25.0, duration_s=300.0):
    """Observation axes in LVLH over a pass: the line of sight sweeping about an axis that tilts as it goes.

    Over a real pass the image plane turns as well as the line of sight (its normal, the
    line of sight's rate axis, moves), which is what makes a near-mirror inconsistent from
    frame to frame; a sweep about one fixed axis would reflect every frame through the same
    plane, an ambiguity no fusion can resolve.
    """
    times = np.linspace(0.0, duration_s, n)
    out = []
    for t in times:
        tilt = -tilt_deg + 2 * tilt_deg * t / duration_s
        axis = Rotation.from_euler("x", tilt, degrees=True).apply([0.0, 0.0, 1.0])
        ang = math.radians(-sweep_deg / 2 + sweep_deg * t / duration_s)
        x = Rotation.from_rotvec(axis * ang).apply([1.0, 0.0, 0.0])
        y = np.cross(axis, x)
        y /= np.linalg.norm(y)
        out.append(np.stack([x, y, np.cross(x, y)], axis=1))
    return times, out


def _pass(rng, n=24, noise_deg=0.4, flips=0.2, outliers=0.05, spin_deg_s=0.0):
    truth = Rotation.from_euler("ZYX", rng.uniform(-40, 40, 3), degrees=True).as_matrix()
    times, frames_obs = _observation_frames(n)
    frames, single = [], []
    for k, (t, o) in enumerate(zip(times, frames_obs, strict=True)):
        body = truth @ Rotation.from_rotvec(np.radians(spin_deg_s) * t * np.array([0.0, 0.0, 1.0])).as_matrix()
        r_true = observation_attitude(body, o)
        r = r_true @ Rotation.from_rotvec(np.radians(noise_deg) * rng.standard_normal(3) / math.sqrt(3)).as_matrix()
        u = rng.random()
        if u < flips:
            r = M @ r @ M
        elif u < flips + outliers:
            r = r @ Rotation.from_rotvec(np.radians(25.0) * rng.standard_normal(3) / math.sqrt(3)).as_matrix()
        cands = np.array([o @ r, o @ (M @ r @ M)])
        frames.append(PassFrame(cands, 1.645 * noise_deg, float(t), f"f{k}"))
        single.append(angle_deg(o @ r, body))
    return truth, frames, np.array(single)


def test_chordal_mean_and_log_against_scipy():
    rng = np.random.default_rng(1)
    rots = Rotation.from_rotvec(0.05 * rng.standard_normal((30, 3)))
    ours = chordal_mean(rots.as_matrix(), np.ones(30))
    ref = rots.mean().as_matrix()  # scipy: the chordal L2 mean by quaternions
    assert angle_deg(ours, ref) < 1e-6
    r = Rotation.from_rotvec([0.3, -0.2, 0.1])
    np.testing.assert_allclose(so3_log(r.as_matrix()), r.as_rotvec(), atol=1e-12)


def test_fusion_beats_single_frames_and_resolves_every_mirror():
    rng = np.random.default_rng(2026)
    ratios = []
    for _ in range(20):
        truth, frames, single = _pass(rng)
        fused = fuse(frames)
        err = angle_deg(fused.rotation, truth)
        assert err < 5.0  # never the wrong branch
        ratios.append(err / np.median(single))
        assert fused.stable
        flipped = [k for k, f in enumerate(frames) if angle_deg(f.candidates[0], truth) > 5.0]
        assert set(flipped) <= set(fused.branch_changed) | set(fused.rejected)
    assert np.median(ratios) <= 1 / 3, ratios


def test_the_bound_covers_the_fused_error():
    rng = np.random.default_rng(7)
    covered = []
    for _ in range(40):
        truth, frames, _ = _pass(rng, flips=0.0, outliers=0.0)
        fused = fuse(frames)
        true_euler = Rotation.from_matrix(truth).as_euler("ZYX", degrees=True)
        covered.append(np.abs(np.array(fused.euler_zyx_deg) - true_euler) <= np.array(fused.uncertainty_deg))
    assert np.mean(covered) >= 0.8, np.mean(covered, axis=0)


def test_a_spinning_target_is_not_called_stable_and_its_rate_is_measured():
    rng = np.random.default_rng(11)
    hits, rates = 0, []
    for _ in range(20):
        _, frames, _ = _pass(rng, flips=0.0, outliers=0.0, spin_deg_s=0.5)
        fused = fuse(frames, reject_floor_deg=180.0, reject_sigma=1e9)
        hits += not fused.stable
        rates.append(float(np.linalg.norm(fused.rate_deg_s)))
    assert hits >= 19
    assert np.all(np.abs(np.array(rates) - 0.5) <= 0.1), rates


def test_one_frame_is_not_a_pass():
    rng = np.random.default_rng(0)
    _, frames, _ = _pass(rng, n=3)
    with pytest.raises(ValueError, match="at least two"):
        fuse(frames[:1])
