"""A simulated pass (gsa simulate --pass): its scene's geometry against skyfield, and its fusion (still and spinning).

The frames here carry their true attitude plus noise instead of a network's answer, so the
fusion is tested on the pass geometry alone: the simulator builds each frame's observation
frame numerically from the body-frame line of sight (``planner.frames``); the fusion's turning
model predicts it in closed form (``inference.fusion.turning_prediction``). The two are
written independently.
"""

import math
from datetime import datetime

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from skyfield.api import EarthSatellite, wgs84

from app.schemas import PAPER_EXAMPLE, AccessCreate
from app.services.planning import run_access
from app.services.scenes import scene_for, windows_of
from inference.checked import Checked, Quality
from inference.rotations import angle_deg, euler_from_matrix, rotation_matrix, spin_rotations
from planner.propagation import skyfield_times, timescale
from scene import SceneError, choose_window
from scene.fusion import fuse_frames, fuse_pass, pass_span
from scene.simulation import PassOptions, render_pass, simulate_pass
from tests.utils.orbits import ISS_EPOCH, ISS_L1, ISS_L2

ISS_REQUEST = {
    "target": {"name": "ISS", "tle": [ISS_L1, ISS_L2]},
    "observer": PAPER_EXAMPLE["observer"],
    "ground_station": {"name": "GS", "latitude_deg": 40.0, "longitude_deg": -75.0, "altitude_m": 100.0},
    "search": {"start": ISS_EPOCH.isoformat(), "duration_days": 1.0},
}


def _windows(req):
    acc = {"target": req["target"], "ground_station": req["ground_station"], "duration_days": 1.0}
    if "search" in req:
        acc["start"] = req["search"]["start"]
    return windows_of(run_access(AccessCreate.model_validate(acc)))


def _simulate(req, window, opts, rng):
    """The pass's frames, from the scene of the plan's target and station over the window (built once)."""
    return simulate_pass(scene_for(req, window.rise, window.set), opts, rng)


@pytest.fixture(scope="module")
def iss_windows():
    return _windows(ISS_REQUEST)


@pytest.fixture(scope="module")
def paper_windows():
    return _windows(PAPER_EXAMPLE)


def test_frames_are_one_aperture_apart_by_skyfield(iss_windows):
    """For a still target the line of sight turns in the body as in LVLH: 5.1 deg between frame centres."""
    _, w = choose_window(iss_windows, None)
    meta = _simulate(ISS_REQUEST, w, PassOptions(), np.random.default_rng(0))
    assert len(meta) >= 5
    sat = EarthSatellite(ISS_L1, ISS_L2, ts=timescale())
    site = wgs84.latlon(40.0, -75.0, 100.0)
    t = np.array([(f.observed_at - ISS_EPOCH).total_seconds() for f in meta])
    times = skyfield_times(ISS_EPOCH, t)
    los = -(sat - site).at(times).position.km
    state = sat.at(times)
    r, v = state.position.km, state.velocity.km_per_s
    in_lvlh = []
    for k in range(len(t)):
        x = r[:, k] / np.linalg.norm(r[:, k])
        z = np.cross(r[:, k], v[:, k])
        z /= np.linalg.norm(z)
        axes = np.stack([x, np.cross(z, x), z], axis=1)
        in_lvlh.append(axes.T @ los[:, k] / np.linalg.norm(los[:, k]))
        # and the frame's X axis (toward the radar) is that line of sight
        np.testing.assert_allclose(meta[k].observation_in_lvlh[:, 0], in_lvlh[-1], atol=1e-5)
    steps = [math.degrees(math.acos(np.clip(a @ b, -1, 1))) for a, b in zip(in_lvlh, in_lvlh[1:], strict=False)]
    # Centres are 5.1 deg apart along the sweep; a chord of the curved path is at most that.
    assert all(4.9 < s <= 5.1 + 1e-3 for s in steps), steps
    assert all(f.range_km > 300 for f in meta)


def test_each_frame_is_rendered_where_the_scene_places_it(paper_windows):
    """The attitude a frame is rendered at, placed back in LVLH by a scene of its own times, is the truth."""
    _, w = choose_window(paper_windows, None)
    meta = _simulate(PAPER_EXAMPLE, w, PassOptions(), np.random.default_rng(1))
    some = meta[:: max(1, len(meta) // 6)]
    times = [f.observed_at for f in some]
    placed = scene_for(PAPER_EXAMPLE, min(times), max(times)).placements(times)
    for k, f in enumerate(some):
        body_to_lvlh, _ = placed.attitudes(k, rotation_matrix(*f.attitude_deg))
        assert angle_deg(body_to_lvlh, f.body_to_lvlh) < 0.02
        # Still in LVLH: the same matrix (compared entry by entry: an angle through arccos reads a matrix 1e-13 off
        # orthonormal as 4e-5 deg from itself).
        np.testing.assert_allclose(f.body_to_lvlh, meta[0].body_to_lvlh, rtol=0, atol=1e-12)


def _checked(angles, bound):
    q = Quality(silhouette_iou=0.99, uncertainty_deg=(bound, bound, bound), trusted=True, reasons=[])
    return Checked(np.array(angles), None, True, q, [], {})


def _noisy_pass(windows, rng, spin_deg_s, noise_deg=0.25, flips=0.0):
    k = int(rng.integers(len(windows)))
    opts = PassOptions(spin_deg_s=spin_deg_s, max_frames=40, seed=int(rng.integers(1 << 30)))
    meta = _simulate(PAPER_EXAMPLE, windows[k], opts, rng)
    checks = []
    for f in meta:
        r = rotation_matrix(*f.attitude_deg)
        r = r @ Rotation.from_rotvec(np.radians(noise_deg) * rng.standard_normal(3) / math.sqrt(3)).as_matrix()
        if rng.random() < flips:
            m = np.diag([1.0, 1.0, -1.0])
            r = m @ r @ m
        checks.append(_checked(euler_from_matrix(r), 1.645 * noise_deg))
    return meta, checks


def _fuse(meta, checks, sweeps=None):
    times = [f.observed_at for f in meta]
    return fuse_frames(
        scene=scene_for(PAPER_EXAMPLE, *pass_span(times, sweeps)),
        checks=checks,
        observed_at=times,
        names=[str(k) for k in range(len(meta))],
        sweeps=sweeps,
    )


def _sweeps(meta, rng, noise=0.01, aperture_deg=5.1):
    """Each frame's measured sweep, the simulator's sub-aperture over its integration time (1 % noise), and that time."""
    return [
        (math.radians(aperture_deg) / f.integration_s * (1.0 + noise * rng.standard_normal()), f.integration_s)
        for f in meta
    ]


def test_a_still_pass_is_stable_and_beats_its_frames(paper_windows):
    rng = np.random.default_rng(5)
    windows = [w for w in paper_windows if w.max_elevation_deg > 10]
    for _ in range(4):
        meta, checks = _noisy_pass(windows, rng, 0.0, flips=0.2)
        out = _fuse(meta, checks)
        assert out.stable and out.trusted, out.stability
        assert angle_deg(out.attitude_lvlh, meta[0].body_to_lvlh) < 0.25  # 0.25 deg per frame, independent noise
        assert out.turning_chi2 is not None and out.turning_chi2 < 30


class _TruthRefiner:
    """Stands in for the set's map: it checks that every frame's start is the one LVLH attitude seen through that
    frame's own observation frame (the simulator's, not the scene's), and answers the body turn to the truth."""

    def __init__(self, meta):
        self.meta, self.seen = meta, []

    def refine_still(self, frames, angles_deg):
        from inference.checked import StillRefinement

        truth = {k: rotation_matrix(*f.attitude_deg) for k, f in enumerate(self.meta)}
        used = [int(f[0, 0]) for f in frames]  # each stand-in frame carries its index
        turns = [rotation_matrix(*a).T @ truth[k] for a, k in zip(angles_deg, used, strict=True)]
        self.seen = used
        assert max(angle_deg(t, turns[0]) for t in turns) < 1e-4  # one body turn explains every frame
        return StillRefinement(turns[0], -2.0, -1.0, len(used))


def test_a_still_pass_refined_on_its_images_answers_the_turned_attitude(paper_windows):
    """A still pass whose frames' images are refined together (a map's ``refine_still``): the fused attitude turned in
    the body by what the refinement found, every used frame taking part, and the answer says it came from the image."""
    rng = np.random.default_rng(8)
    windows = [w for w in paper_windows if w.max_elevation_deg > 10]
    meta, checks = _noisy_pass(windows, rng, 0.0, noise_deg=1.0)
    times = [f.observed_at for f in meta]
    images = np.zeros((len(meta), 4, 4))
    images[:, 0, 0] = np.arange(len(meta))
    refiner = _TruthRefiner(meta)
    out = fuse_frames(
        scene=scene_for(PAPER_EXAMPLE, *pass_span(times, None)),
        checks=checks,
        observed_at=times,
        names=[str(k) for k in range(len(meta))],
        images=images,
        image=refiner,
    )
    assert out.stable and out.refined_on == "image" and out.image_fit["frames"] == out.used == len(refiner.seen)
    assert angle_deg(out.attitude_lvlh, meta[0].body_to_lvlh) < 1e-4
    assert max(f.residual_deg for f in out.frames if f.used) > 0.1  # the frames' own answers stay as they were
    plain = _fuse(meta, checks)
    assert plain.refined_on == "silhouette" and plain.image_fit is None
    assert math.isclose(out.image_fit["moved_deg"], angle_deg(plain.attitude_lvlh, out.attitude_lvlh), abs_tol=1e-3)


@pytest.mark.parametrize("sense", [1.0, -1.0])
def test_a_spinning_target_is_found_turning_with_its_rate(paper_windows, sense):
    rng = np.random.default_rng(11 if sense > 0 else 12)
    windows = [w for w in paper_windows if w.max_elevation_deg > 10]
    found = 0
    for _ in range(4):
        try:
            meta, checks = _noisy_pass(windows, rng, sense * 0.5)
        except SceneError:  # too few frames of this pass within the networks' range
            continue
        out = _fuse(meta, checks)
        if out.stable:
            continue
        found += 1
        rate = out.rate_deg_s
        assert abs(np.linalg.norm(rate) - 0.5) <= 0.1, rate  # within 20 %
        assert abs(rate[2]) / np.linalg.norm(rate) > 0.95  # about body z
        at = out.attitude_at
        assert isinstance(at, datetime)
        times = np.array([(f.observed_at - at).total_seconds() for f in meta])
        k = int(np.argmin(np.abs(times)))
        truth = meta[k].body_to_lvlh @ spin_rotations(np.array([0.0, 0.0, 1.0]), sense * 0.5, np.array([-times[k]]))[0]
        assert angle_deg(out.attitude_lvlh, truth) < 1.0
        # Each frame placed in LVLH as the turning answer sees it: its noisy answer, not the image plane's turn.
        placed = [angle_deg(f.attitude_lvlh, meta[f.index].body_to_lvlh) for f in out.frames if f.used]
        assert placed and max(placed) < 2.0, placed
    assert found >= 3


@pytest.mark.parametrize("spin_deg_s", [0.5, -0.5, 0.0])
def test_a_minute_of_a_pass_tells_still_from_turning(paper_windows, spin_deg_s):
    """Five frames (about a minute) of a pass: too short an arc to pin the body rate on every axis, long
    enough that no still attitude explains a spinning target's frames, while a still target's fit the still model."""
    rng = np.random.default_rng(21)
    windows = [w for w in paper_windows if w.max_elevation_deg > 10]
    verdicts, rates = [], []
    while len(verdicts) < 6:
        try:
            meta, checks = _noisy_pass(windows, rng, spin_deg_s, noise_deg=0.2)
        except SceneError:
            continue
        m = len(meta) // 2 - 2
        out = _fuse(meta[m : m + 5], checks[m : m + 5])
        assert out.trusted, out.stability
        verdicts.append(out.stable)
        rates.append(float(np.linalg.norm(out.rate_deg_s)))
    if spin_deg_s:
        assert verdicts == [False] * 6, verdicts
        assert abs(np.median(rates) - 0.5) <= 0.1, rates
    else:
        assert verdicts == [True] * 6, verdicts


def test_a_short_arc_states_how_little_it_knows_of_the_rate(paper_windows):
    """Four frames anywhere in a spinning pass: the stated 90 % interval of the body z rate holds the truth.

    Over so short an arc a rate and an attitude trade off, and the curvature at the best fit
    alone puts the truth outside its 90 % interval on 5 of these 16 arcs."""
    rng = np.random.default_rng(33)
    windows = [w for w in paper_windows if w.max_elevation_deg > 10]
    misses = turning = 0
    while turning < 16:
        spin = 0.5 if turning % 2 else -0.5
        try:
            meta, checks = _noisy_pass(windows, rng, spin, noise_deg=0.3)
        except SceneError:
            continue
        m = int(rng.integers(0, len(meta) - 4))
        out = _fuse(meta[m : m + 4], checks[m : m + 4])
        if out.stable is not False:
            continue
        turning += 1
        misses += abs(out.rate_deg_s[2] - spin) > 1.645 * out.rate_sigma_deg_s[2]
    assert misses <= 3, misses  # 90 % coverage: about 1.6 of 16 expected


def test_a_pass_of_untrusted_frames_says_so(paper_windows):
    rng = np.random.default_rng(8)
    meta, checks = _noisy_pass([w for w in paper_windows if w.max_elevation_deg > 10], rng, 0.0)
    doubtful = []
    for c in checks:
        q = Quality(c.quality.silhouette_iou, c.quality.uncertainty_deg, False, ["the silhouette fits poorly"])
        doubtful.append(Checked(c.angles_deg, None, True, q, [], {}))
    doubtful[0] = checks[0]  # one trusted frame is not a pass
    out = _fuse(meta, doubtful)
    assert not out.trusted and "too few frames" in out.stability
    assert out.stable is None  # undecided: neither stable nor turning


def test_bad_pass_options_name_the_field(paper_windows):
    with pytest.raises(SceneError) as e:
        PassOptions(aperture_deg=0.0)
    assert e.value.loc == ["aperture_deg"]
    with pytest.raises(SceneError) as e:
        choose_window(paper_windows, len(paper_windows))
    assert e.value.loc == ["window"]
    with pytest.raises(SceneError) as e:
        choose_window([], None)
    assert e.value.loc == ["window"]


def test_a_still_pass_measures_the_sweep_its_geometry_predicts(paper_windows):
    """A still target's sweep is the line of sight's own rate in LVLH (the fusion's closed form), which the
    simulator's integration times, from the line of sight swept through the body numerically, must match."""
    rng = np.random.default_rng(44)
    windows = [w for w in paper_windows if w.max_elevation_deg > 10]
    for _ in range(4):
        meta, checks = _noisy_pass(windows, rng, 0.0)
        out = _fuse(meta, checks, _sweeps(meta, rng, noise=0.0))
        assert out.stable and out.turning_chi2 < 30, out.stability
        rel = [abs(f.sweep_model_rad_s / f.sweep_rad_s - 1.0) for f in out.frames]
        # The frame measures the mean rate over its integration, the model the rate at its time: they part only
        # where the rate bends within a frame, at the pass's ends (a minute and more a frame).
        assert np.median(rel) < 0.005 and max(rel) < 0.08, rel
        noisy = _fuse(meta, checks, _sweeps(meta, rng))
        assert noisy.stable, noisy.stability


def test_measured_sweeps_pin_the_rate_of_a_short_arc(paper_windows):
    """Four readable frames of a spinning pass, the rest unreadable but each with its integration time: the
    sweeps tell the rate that four frames' attitudes leave loose (without them, one of these 12 arcs is
    undecided and 4 more miss the rate by 12 to 46 %; with them, the worst is 0.6 % off)."""
    rng = np.random.default_rng(35)
    windows = [w for w in paper_windows if w.max_elevation_deg > 10]
    errors, misses = [], 0
    while len(errors) < 12:
        spin = 0.5 if len(errors) % 2 else -0.5
        try:
            meta, checks = _noisy_pass(windows, rng, spin, noise_deg=0.3)
        except SceneError:
            continue
        m = int(rng.integers(0, len(meta) - 4))
        unread = []
        for k, c in enumerate(checks):
            q = Quality(c.quality.silhouette_iou, c.quality.uncertainty_deg, False, ["outside the networks' range"])
            unread.append(c if m <= k < m + 4 else Checked(c.angles_deg, None, True, q, [], {}))
        out = _fuse(meta, unread, _sweeps(meta, rng))
        assert out.stable is False, out.stability
        rate = out.rate_deg_s
        errors.append(abs(np.linalg.norm(rate) / 0.5 - 1.0))
        assert abs(rate[2]) / np.linalg.norm(rate) > 0.95  # about body z
        misses += abs(rate[2] - spin) > 1.645 * out.rate_sigma_deg_s[2]
    assert max(errors) < 0.05, errors
    assert misses <= 3, misses  # 90 % coverage: about 1.2 of 12 expected


def test_a_still_pass_fitted_to_its_exact_silhouettes_at_once_lands_on_the_truth(paper_windows):
    """A real pass's frames fitted alone to their exact labels from 1 deg off, then all together from their mean."""
    from inference.runtime import DEFAULT_MODEL_DIR
    from inference.simulation.catalogue import at_attitudes
    from inference.trust import load_checkers

    rng = np.random.default_rng(21)
    windows = [w for w in paper_windows if w.max_elevation_deg > 10]
    opts = PassOptions(seed=21, max_frames=12, within_deg=40.0)
    meta = _simulate(PAPER_EXAMPLE, windows[0], opts, rng)
    angles = np.array([f.attitude_deg for f in meta])
    _, labels = at_attitudes(angles, np.full(len(meta), np.nan), [0] * len(meta))
    images = np.stack(render_pass(meta, opts, rng)[0]).astype(float)
    checker = load_checkers(DEFAULT_MODEL_DIR).get("tiangong-like")  # the shipped calibration
    starts = angles + rng.uniform(-1.0, 1.0, angles.shape)
    checks = checker.check_many(images, labels.astype(float), starts, search=False)
    times = [f.observed_at for f in meta]
    the_pass = {
        "est": None,
        "checker": checker,
        "frames": images,
        "checks": checks,
        "scene": scene_for(PAPER_EXAMPLE, min(times), max(times)),
        "observed_at": times,
        "names": [str(k) for k in range(len(meta))],
    }
    out, _ = fuse_pass(**the_pass, enhanced=labels.astype(float))
    assert out.stable and out.trusted, out.stability
    common = out.common_fit
    assert common is not None and common.frames == out.used >= 3
    truth = meta[0].body_to_lvlh
    fused = angle_deg(out.attitude_lvlh, truth)
    single = np.median(
        [angle_deg(rotation_matrix(*c.angles_deg), rotation_matrix(*a)) for c, a in zip(checks, angles, strict=True)]
    )
    assert fused < 0.1 and fused < single, (fused, single)
    # Without the silhouettes the same frames give the robust mean alone, which the common fit moved from.
    plain, _ = fuse_pass(**the_pass)
    assert plain.common_fit is None
    assert angle_deg(plain.attitude_lvlh, out.attitude_lvlh) == pytest.approx(common.moved_deg, abs=2e-3)
