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
