"""The built-in targets: no mirror plane, they fit the frame; a symmetric one reports its planes."""

import numpy as np
import pytest

from inference.simulation.radar import Radar
from inference.simulation.scene import check_fits
from inference.simulation.targets import TargetModel, cylinder, tiangong_like

RADAR = Radar()


def test_default_target_has_no_mirror_plane_and_fits():
    model = tiangong_like()
    assert model.mirror_planes == []
    check_fits(model, RADAR)
    assert 3000 < len(model.scatterers) < 6000


def test_symmetric_target_reports_its_mirror_planes():
    p, n, _, _ = cylinder(np.array([-3.0, 0, 0]), np.array([1.0, 0, 0]), 1.0, 6.0, 0.1)
    model = TargetModel("can", p, p, n, np.zeros(len(p), np.int8))
    assert set(model.mirror_planes) == {"yz", "xz", "xy"}


def test_near_symmetries_have_a_strength_and_an_exact_mirror_is_complete():
    """An exact mirror (a can along x, about its own mid-plane) is complete about all three planes; the default
    target is nearly symmetric about a plane parallel to its body xy plane (its hull; the wings break it), and
    about no other plane."""
    p, n, _, _ = cylinder(np.array([-3.0, 0, 0]), np.array([1.0, 0, 0]), 1.0, 6.0, 0.1)
    can = {s["plane"]: s for s in TargetModel("can", p, p, n, np.zeros(len(p), np.int8)).symmetries()}
    assert all(s["share_within"] == 1.0 and s["p95_m"] < 0.05 for s in can.values())
    shifted = TargetModel("can", p + [0.0, 0.0, 0.4], p, n, np.zeros(len(p), np.int8)).symmetries()
    xy = next(s for s in shifted if s["plane"] == "xy")
    assert (
        xy["share_within"] < 0.9
        and xy["offset_m"] == pytest.approx(0.4, abs=0.021)
        and xy["offset_share_within"] == 1.0
    )
    default = {s["plane"]: s for s in tiangong_like().symmetries()}
    assert default["xy"]["offset_share_within"] > 0.85
    assert default["yz"]["offset_share_within"] < 0.5 and default["xz"]["offset_share_within"] < 0.5


def test_mirror_pair_labels_are_identical_for_a_symmetric_target_and_close_for_the_default():
    """R(z, -y, -x) = N R(z, y, x) N with N = diag(1, 1, -1): a target symmetric about its body xy plane casts the
    same label at both attitudes; the default one, nearly symmetric, casts labels that overlap but differ."""
    from inference.simulation.radar import Imager
    from inference.simulation.scene import mirror_pair_iou

    p, n, _, _ = cylinder(np.array([-3.0, 0, 0]), np.array([1.0, 0, 0]), 1.0, 6.0, 0.1)
    can = TargetModel("can", p, p, n, np.zeros(len(p), np.int8))
    assert mirror_pair_iou(can, Imager(RADAR), n=16)["min"] > 0.97
    default = mirror_pair_iou(tiangong_like(), Imager(RADAR), n=32)
    assert 0.75 < default["mean"] < 0.97
