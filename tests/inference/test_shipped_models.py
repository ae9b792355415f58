"""The shipped models on this machine's CPU, against the simulator's truth: the silhouette label and the attitude.

Int8 kernels are not the same on every CPU: on an x86 CPU without VNNI, onnxruntime sums pairs
of uint8 x int8 products in int16, which saturates with 8-bit weights. The UNet++ first
shipped gave IoU 0.90 instead of 0.99 on such a machine (AMD EPYC, AVX2 only), and Swin 18
deg instead of 2, while every other test passed: nothing had checked the shipped files' answers
where they run. Here 16 fresh frames (seeded, drawn as a data set is: the default target within
45 deg, SNR -3..15 dB) are enhanced and read, and each is held to the truth it was simulated at.
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from inference.errors import ModelFileError
from inference.rotations import angle_deg, rotation_matrix
from inference.runtime import DEFAULT_MODEL_DIR, Estimator
from inference.simulation.catalogue import at_attitudes

N = 16
SEED = 5_550_000  # no data set, benchmark or calibration uses it


@pytest.fixture(scope="module")
def read():
    rng = np.random.default_rng(SEED)
    angles = rng.uniform(-40.0, 40.0, (N, 3))
    snrs = rng.uniform(-3.0, 15.0, N)
    frames, labels = at_attitudes(angles, snrs, [SEED + k for k in range(N)])
    est = Estimator.load()
    return est.estimate(frames), labels, angles


def _iou(enhanced, labels):
    """Each frame's silhouette (> 0.5) IoU with its label."""
    mask = enhanced > 0.5
    return (mask & labels).sum(axis=(1, 2)) / np.maximum((mask | labels).sum(axis=(1, 2)), 1)


def _refused_once_moved(tmp_path, card, selfcheck):
    """A copy of the shipped set whose card has ``selfcheck`` (a record in ``card``) moved by 0.2 must not load."""
    d = tmp_path / "models"
    shutil.copytree(DEFAULT_MODEL_DIR, d)
    selfcheck["unetpp_pooled"] = (np.array(selfcheck["unetpp_pooled"]) + 0.2).tolist()
    (d / "model_card.json").write_text(json.dumps(card))
    with pytest.raises(ModelFileError, match="computes differently on this CPU"):
        Estimator.load(d)


def test_unetpp_recovers_the_silhouette(read):
    res, labels, _ = read
    iou = _iou(res.enhanced, labels)
    # Measured: median 0.99 on a VNNI CPU and (7-bit weights) on AVX2 alone; 0.90 with saturating weights.
    assert np.median(iou) >= 0.97, np.round(iou, 3)
    assert iou.min() >= 0.93, np.round(iou, 3)


def test_swin_reads_the_attitude(read):
    res, _, angles = read
    err = np.array(
        [angle_deg(rotation_matrix(*a), rotation_matrix(*b)) for a, b in zip(res.angles_deg, angles, strict=True)]
    )
    # Measured: geodesic mean 1.5 deg over 1000 test frames (the model card); 18 deg with a saturated UNet++.
    assert np.median(err) <= 3.0, np.round(err, 2)
    assert np.mean(err) <= 4.0, np.round(err, 2)


def test_a_unetpp_that_computes_otherwise_here_is_refused(tmp_path):
    """The service checks UNet++ against the float network's output recorded at export before it answers.

    The shipped card carries that record; moved by more than its tolerance (as a saturating CPU
    moves the 8-bit file's output: 0.28 against a tolerance of 0.1), the set does not load.
    """
    card = json.loads((DEFAULT_MODEL_DIR / "model_card.json").read_text())
    assert card["selfcheck"]["img_size"] == card["config"]["img_size"]
    _refused_once_moved(tmp_path, card, card["selfcheck"])


def test_the_search_unetpp_draws_silhouettes_outside_the_cube(tmp_path):
    """The shipped search UNet++ (trained over every rotation; the library search fits its silhouettes) against the
    simulator's labels at attitudes uniform over SO(3) (scipy's draw), beside the networks' UNet++, trained on the
    cube. Measured on 600 frames (bench.so3): IoU 0.93 against 0.85. Its self-check record is held as the networks'."""
    from scipy.spatial.transform import Rotation

    from inference.rotations import euler_from_matrices

    rng = np.random.default_rng(SEED + 1)
    angles = euler_from_matrices(Rotation.random(N, random_state=SEED + 1).as_matrix())
    frames, labels = at_attitudes(angles, rng.uniform(-3.0, 15.0, N), [SEED + 100 + k for k in range(N)])
    est = Estimator.load()
    assert est.search_enhancer is not None

    search = _iou(np.stack([est.search_enhancer(f) for f in frames]), labels)
    networks = _iou(est.estimate(frames).enhanced, labels)
    # Measured here: medians 0.966 and 0.836.
    assert np.median(search) >= 0.93 and np.median(search) >= np.median(networks) + 0.05, (search, networks)
    card = json.loads((DEFAULT_MODEL_DIR / "model_card.json").read_text())
    entry = card["files"]["search_unetpp"]
    assert entry["weights"].startswith("int8") and entry["selfcheck"]["img_size"] == card["config"]["img_size"]
    _refused_once_moved(tmp_path, card, entry["selfcheck"])
