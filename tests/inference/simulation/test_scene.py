"""The scene: labels that move as the rotation predicts, image and label agreeing, the scattering variety."""

import numpy as np
import pytest

from inference.errors import RadarError
from inference.frames import normalise_frame
from inference.rotations import rotation_matrix
from inference.simulation.radar import Imager, Radar, projection_matrix
from inference.simulation.scene import simulate
from inference.simulation.targets import FLAT, TargetModel, tiangong_like

RADAR = Radar()
IMAGER = Imager(RADAR)


def _cluster_model(p_body):
    pts = np.asarray(p_body, float) + np.random.default_rng(0).normal(0, 0.02, (200, 3))
    return TargetModel("dot", pts, pts, np.zeros_like(pts), np.full(len(pts), FLAT, np.int8))


@pytest.mark.parametrize("angles", [(0.0, 0.0, 0.0), (30.0, -20.0, 10.0), (-45.0, 45.0, -45.0)])
def test_label_moves_as_the_rotation_predicts(angles):
    p = np.array([5.0, 2.0, 1.0])
    model = _cluster_model(p)
    frame = simulate(model, IMAGER, angles, None, 0)
    rows, cols = np.nonzero(frame.label)
    expected = projection_matrix(RADAR) @ rotation_matrix(*angles) @ p
    assert rows.mean() == pytest.approx(expected[0] / RADAR.range_cell_m + 128, abs=1.0)
    assert cols.mean() == pytest.approx(expected[1] / RADAR.cross_range_cell_m + 128, abs=1.0)


def test_image_and_label_overlap():
    """On noise-free frames, the bright part of the image lies on the label.

    Not all of it: an end cap facing the radar flashes, and its 25-dB sidelobes run
    along the row and column off the silhouette (0.80 of the bright pixels on the
    label at zero attitude, over 0.98 at the others).
    """
    from scipy.ndimage import binary_dilation

    model = tiangong_like()
    for k, angles in enumerate([(0.0, 0.0, 0.0), (20.0, -30.0, 40.0), (-40.0, 10.0, -25.0)]):
        frame = simulate(model, IMAGER, angles, None, k)
        bright = normalise_frame(np.abs(frame.image)) > 0.5  # within 20 dB of the brightest
        on_label = binary_dilation(frame.label, iterations=2)
        precision = (bright & on_label).sum() / bright.sum()
        assert precision > (0.75 if k == 0 else 0.95)
        iou = (bright & frame.label).sum() / (bright | frame.label).sum()
        assert iou > 0.1


def test_default_frames_are_unchanged_by_the_scattering_options():
    """The hash of three default frames, recorded on the commit before inference.simulation.scene.Scattering existed."""
    import hashlib

    from inference.simulation.dataset import DatasetSpec, render_frames

    a = render_frames(DatasetSpec(n=3, seed=0), RADAR, 0, 3)
    digest = hashlib.sha256(a["image"].tobytes() + a["label"].tobytes()).hexdigest()
    assert digest == "cfddc122e75fce63eb09552a5c8953761952b81d0dcf676feb7bcf22eaac5a44"


def test_every_variant_images_the_target_where_its_label_is():
    from inference.simulation.scene import VARIANTS

    model = tiangong_like()
    for name, sc in VARIANTS.items():
        f = simulate(model, IMAGER, (15.0, -10.0, 20.0), None, 2, sc)
        mag = np.abs(f.image)
        inside = mag[f.label].mean()
        outside = mag[~f.label].mean()
        assert inside > 5 * outside, name


def test_bad_scattering_options_are_refused():
    from inference.simulation.scene import Scattering

    for kw in ({"window": "kaiser"}, {"edge_gain": -1}, {"scatterers": "mesh"}, {"scale_error": 0.5}):
        with pytest.raises(RadarError, match=next(iter(kw))):
            Scattering(**kw)


@pytest.mark.parametrize("physics", ["centres", "po"])
def test_a_frame_reversed_in_cross_range_is_the_frame_of_the_body_turned_half_about_the_line_of_sight(physics):
    """Why a single frame cannot tell its cross-range sign over SO(3): reversing the columns about the centre
    pixel (column j -> N - j) gives the frame of Rx(180) R, since that half turn keeps the line of sight's direction
    in the body (every return and shadow alike) and negates cross-range; the projection drops the image normal.
    Checked on the scattering centres and on physical optics (facets, ray-traced shadows), noise-free, against
    attitudes inside and far outside the networks' cube. Not so in range: rows reversed are no frame of the half turn
    about cross-range (correlation 0.00-0.18), since that turn shows the radar the body's other side."""
    from inference.rotations import euler_from_matrix, reversed_reading
    from inference.simulation.scene import Scattering

    scattering = Scattering(physics=physics)
    model = tiangong_like()
    for angles in [(10.0, 20.0, 30.0), (-100.0, 50.0, 140.0), (170.0, -80.0, -60.0)]:
        seen = np.abs(simulate(model, IMAGER, angles, None, 5, scattering).image)
        turned = np.abs(simulate(model, IMAGER, reversed_reading(angles), None, 5, scattering).image)
        reversed_ = np.roll(seen[:, ::-1], 1, axis=1)
        assert np.abs(reversed_ - turned).max() <= 0.03 * turned.max(), angles
        assert np.corrcoef(reversed_.ravel(), turned.ravel())[0, 1] >= 0.999, angles
        other = np.abs(
            simulate(
                model, IMAGER, reversed_reading((angles[0] + 20.0, angles[1], angles[2])), None, 5, scattering
            ).image
        )
        assert np.corrcoef(reversed_.ravel(), other.ravel())[0, 1] < 0.9, angles  # the test can fail
        rows = np.roll(seen[::-1], 1, axis=0)
        half_about_y = euler_from_matrix(np.diag([-1.0, 1.0, -1.0]) @ rotation_matrix(*angles))
        ry = np.abs(simulate(model, IMAGER, half_about_y, None, 5, scattering).image)
        assert np.corrcoef(rows.ravel(), ry.ravel())[0, 1] < 0.5, angles
