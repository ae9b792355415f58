"""The result models' constructors against scipy's rotations, and their stored form read back unchanged."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from app.schemas import AttitudePublic, EstimateResult
from inference.checked import Alternative, Checked, Quality


def test_an_attitude_from_a_matrix_is_scipys_rotation():
    r = Rotation.from_euler("ZYX", [123.0, -61.0, 17.0], degrees=True)
    a = AttitudePublic.from_matrix(r.as_matrix())
    x, y, z, w = r.as_quat()
    assert abs(abs(float(np.dot(a.quaternion_wxyz, [w, x, y, z]))) - 1.0) < 1e-12
    assert a.euler_zyx_deg == pytest.approx([123.0, -61.0, 17.0], abs=1e-9)
    np.testing.assert_allclose(a.rotation_matrix, r.as_matrix(), atol=1e-12)
    b = AttitudePublic.from_euler([123.0, -61.0, 17.0])
    np.testing.assert_allclose(b.rotation_matrix, a.rotation_matrix, atol=1e-12)


def test_an_estimate_result_round_trips_through_its_stored_form():
    q = Quality(0.97, (0.4, float("inf"), 0.6), False, ["fits nearly as well: the frame cannot tell them apart"])
    alt = Alternative((10.0, -5.0, -20.0), 0.96123456, 0.001234567, 31.4159, "mirror")
    checked = Checked(np.array([10.0, 5.0, 20.0]), np.array([11.0, 4.0, 19.0]), True, q, [alt], {})
    result = EstimateResult.from_checked(
        checked,
        target="tiangong-like",
        model={"name": "compact"},
        timings_s={"fit": 0.1},
        input_normalised=True,
        cells_m=(0.09, 0.11),
        in_frames=(np.eye(3), np.eye(3)),
    )
    assert result.quality is not None and result.quality.uncertainty_deg == [0.4, None, 0.6]  # no bound: null
    assert result.alternatives[0].silhouette_iou == 0.9612 and result.alternatives[0].distance_deg == 31.42
    stored = result.stored()
    assert stored["format"] == 2 and math.isclose(stored["attitude"]["euler_zyx_deg"][2], 20.0)
    assert EstimateResult.model_validate(EstimateResult.upgraded(stored)) == result
