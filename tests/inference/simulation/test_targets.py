"""The built-in targets: no mirror plane, they fit the frame; a symmetric one reports its planes."""

import numpy as np

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
