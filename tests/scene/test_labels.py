"""A scene's labels: the optical observer's J2000 attitude turned into each frame's angles, both ways round."""

import numpy as np
import pytest

from app.services.scenes import scene_for
from inference.rotations import geodesic_deg
from scene import SceneError, choose_window
from scene.labels import optical_attitudes, plan_resolver
from scene.simulation import PassOptions, simulate_pass
from tests.scene.test_pass_simulation import ISS_REQUEST, _windows


@pytest.fixture(scope="module")
def still_pass():
    _, w = choose_window(_windows(ISS_REQUEST), None)
    scene = scene_for(ISS_REQUEST, w.rise, w.set)
    frames = simulate_pass(scene, PassOptions(max_frames=12, seed=3), np.random.default_rng(3))
    return scene, frames


def test_an_exact_observer_labels_each_frame_with_its_true_attitude(still_pass):
    _, frames = still_pass
    quats, labels = optical_attitudes(frames, 0.0, np.random.default_rng(0))
    truth = np.array([f.attitude_deg for f in frames])
    assert np.allclose(labels, truth, atol=1e-9)
    assert np.allclose(np.linalg.norm(quats, axis=1), 1.0)


def test_the_observers_error_has_the_size_asked_for(still_pass):
    _, frames = still_pass
    truth = np.array([f.attitude_deg for f in frames * 40])
    _, labels = optical_attitudes(frames * 40, 0.2, np.random.default_rng(1))
    err = geodesic_deg(labels, truth)
    # three axes of 0.2 deg each: the rotation angle's rms is 0.2 sqrt(3) (a Maxwell distribution)
    assert np.sqrt(np.mean(err**2)) == pytest.approx(0.2 * np.sqrt(3), rel=0.1)


def test_a_plans_geometry_turns_the_j2000_attitude_back_into_the_frames_angles(still_pass):
    # The simulator's observation axes come from the line of sight in the body; the resolver's from the
    # scene's placements of the moment (the estimate path's): two computations that must agree for a still target.
    scene, frames = still_pass
    quats, labels = optical_attitudes(frames, 0.2, np.random.default_rng(2))
    resolve = plan_resolver(scene)
    got = np.array([resolve(q, f.observed_at, "f") for q, f in zip(quats, frames, strict=True)])
    assert geodesic_deg(got, labels).max() < 0.02
    with pytest.raises(SceneError, match="outside the scene's span"):
        resolve(quats[0], scene.epoch.replace(year=scene.epoch.year - 1), "f")
