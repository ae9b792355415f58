"""Fusing a pass: synthetic passes whose truth is known, against the per-frame errors of the same pass."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from inference.fusion import PassFrame, fuse, observation_attitude
from inference.rotations import angle_deg, chordal_mean, so3_log, so3_logs

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
    # The stacked log, small angles, ordinary ones and one at pi included.
    many = Rotation.from_rotvec(
        np.vstack([1e-12 * rng.standard_normal((2, 3)), rng.uniform(-1.5, 1.5, (20, 3)), [[math.pi, 0.0, 0.0]]])
    )
    ref = many.as_rotvec()
    got = so3_logs(many.as_matrix())
    np.testing.assert_allclose(got[:-1], ref[:-1], atol=1e-9)
    assert Rotation.from_rotvec(got[-1]).as_matrix() == pytest.approx(many[-1].as_matrix(), abs=1e-9)


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


def _euler_to_rotvec_jacobian(o, e, h=1e-6):
    """d(rotation vector in LVLH, left) / d(Euler z, y, x, rad) of o R(e), by finite differences through scipy."""
    base = o @ Rotation.from_euler("ZYX", e).as_matrix()
    cols = []
    for i in range(3):
        d = np.zeros(3)
        d[i] = h
        r = o @ Rotation.from_euler("ZYX", e + d).as_matrix()
        cols.append(Rotation.from_matrix(r @ base.T).as_rotvec() / h)
    return np.stack(cols, axis=1)


TRIALS = 30


def test_correlated_frame_errors_fuse_to_the_cramer_rao_bound():
    """Frames whose Euler y and x errors trade (correlation -0.95, as a tilt the silhouette barely shows does)
    fuse to the Cramer-Rao bound when they carry their covariance, and do over twice as badly as independent
    axes; one frame that bounds nothing (a doubted fit) does not turn the covariances off for the rest."""
    rng = np.random.default_rng(5)
    sig = np.radians([0.1, 0.5, 0.5])
    rho = -0.95
    cov = np.diag(sig) @ np.array([[1.0, 0.0, 0.0], [0.0, 1.0, rho], [0.0, rho, 1.0]]) @ np.diag(sig)
    chol = np.linalg.cholesky(cov)
    bounds = tuple(1.645 * np.degrees(sig))
    times, obs = _observation_frames(12)
    sq = {"covariance": [], "independent": []}
    crb = []
    for _ in range(TRIALS):
        truth = Rotation.from_euler("ZYX", rng.uniform(-40, 40, 3), degrees=True).as_matrix()
        frames = {mode: [] for mode in sq}
        info = np.zeros((3, 3))
        for k, (t, o) in enumerate(zip(times, obs, strict=True)):
            e0 = Rotation.from_matrix(observation_attitude(truth, o)).as_euler("ZYX")
            j = _euler_to_rotvec_jacobian(o, e0)
            info += np.linalg.inv(j @ cov @ j.T)
            r = Rotation.from_euler("ZYX", e0 + chol @ rng.standard_normal(3)).as_matrix()
            cands = np.array([o @ r, o @ M @ r @ M])
            for mode, fs in frames.items():
                c = 1.645**2 * np.degrees(1.0) ** 2 * cov if mode == "covariance" else None
                fs.append(PassFrame(cands, max(bounds), float(t), f"f{k}", o[:, 0], o[:, 1], True, "", bounds, c))
        off = truth @ Rotation.from_rotvec(np.radians([1.5, -1.0, 0.5])).as_matrix()
        for fs in frames.values():  # a frame whose fit bounds nothing: no per-axis bounds, 10 deg overall
            fs.append(
                PassFrame(np.array([off, off]), 10.0, float(times[-1]) + 5.0, "unbounded", obs[-1][:, 0], obs[-1][:, 1])
            )
        crb.append(np.trace(np.linalg.inv(info)))
        for mode, fs in frames.items():
            sq[mode].append(np.sum(so3_log(fuse(fs).rotation @ truth.T) ** 2))
    full, indep = np.mean(sq["covariance"]), np.mean(sq["independent"])
    assert full <= 1.3 * np.mean(crb), (full, np.mean(crb))
    assert indep >= 1.5 * full, (indep, full)


def test_where_the_image_plane_does_not_turn_the_frames_answers_choose_and_the_mirror_is_reported():
    """A line of sight sweeping about one fixed axis keeps one image plane, so the near-mirror (a reflection
    through it) is the same rotation for every frame: both branches agree with every frame. The frames' own
    answers then choose (here 11 of 16 are right, the first frame wrong), and the other branch is reported."""
    rng = np.random.default_rng(31)
    reflect = np.diag([1.0, 1.0, -1.0])  # the fixed image plane's reflection, in LVLH
    times, obs = _observation_frames(16, tilt_deg=0.0)
    for trial in range(12):
        truth = Rotation.from_euler("ZYX", rng.uniform(-40, 40, 3), degrees=True).as_matrix()
        frames = []
        flipped = {0, *rng.choice(np.arange(1, 16), 4, replace=False)}
        for k, (t, o) in enumerate(zip(times, obs, strict=True)):
            r = (
                observation_attitude(truth, o)
                @ Rotation.from_rotvec(np.radians(0.3) * rng.standard_normal(3)).as_matrix()
            )
            cands = np.array([o @ r, o @ M @ r @ M])
            if k in flipped:  # this frame's own answer is the near-mirror
                cands = cands[::-1]
            frames.append(PassFrame(cands, 0.5, float(t), f"f{k}", o[:, 0], o[:, 1]))
        fused = fuse(frames)
        assert angle_deg(fused.rotation, truth) < 1.0, trial
        assert fused.rival is not None and angle_deg(fused.rival, reflect @ truth @ M) < 1.0, trial
    # A turning image plane tells the branches apart: no rival.
    for _ in range(6):
        truth, frames, _ = _pass(rng, flips=0.3, outliers=0.0)
        fused = fuse(frames)
        assert angle_deg(fused.rotation, truth) < 1.0
        assert fused.rival is None


def test_sweep_rates_are_the_body_frame_line_of_sight_s_turning():
    """sweep_rates against a finite difference: the line of sight carried into the turning body, b(t) = A(t)^T l(t),
    turns at |db/dt|; several models at once give each one's rates (scipy's rotations build the reference)."""
    from inference.fusion import sweep_rates

    rng = np.random.default_rng(7)
    n, h = 9, 1e-3
    los = rng.normal(size=(n, 3))
    los /= np.linalg.norm(los, axis=1, keepdims=True)
    los_rate = rng.normal(size=(n, 3)) * 0.004
    los_rate -= np.sum(los_rate * los, axis=1, keepdims=True) * los  # a unit vector's rate is across it
    tau = rng.uniform(-200.0, 200.0, n)
    models = [(Rotation.random(random_state=s).as_matrix(), rng.normal(size=3) * 0.01) for s in range(4)]

    def body_los(a_ref, w, dt):
        line = los + los_rate * dt
        line /= np.linalg.norm(line, axis=1, keepdims=True)
        a = a_ref @ Rotation.from_rotvec(np.outer(tau + dt, w)).as_matrix()
        return np.einsum("nji,nj->ni", a, line)

    for a_ref, w in models:
        reference = np.linalg.norm(body_los(a_ref, w, h) - body_los(a_ref, w, -h), axis=1) / (2 * h)
        assert sweep_rates(a_ref, w, tau, los, los_rate) == pytest.approx(reference, rel=1e-5)
    batched = sweep_rates(np.array([m[0] for m in models]), np.array([m[1] for m in models]), tau, los, los_rate)
    assert batched.shape == (4, n)
    for row, (a_ref, w) in zip(batched, models, strict=True):
        assert row == pytest.approx(sweep_rates(a_ref, w, tau, los, los_rate), rel=1e-12)
    # A still body: the line of sight's own rate.
    assert sweep_rates(models[0][0], np.zeros(3), tau, los, los_rate) == pytest.approx(np.linalg.norm(los_rate, axis=1))
