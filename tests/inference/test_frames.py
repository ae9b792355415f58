"""The frame contract: Euler angles round-trip, the normalisation ignores one bright cell."""

import numpy as np
import pytest

from inference.frames import euler_from_matrix, normalise_frame, rotation_matrix


def test_euler_round_trip():
    for z, y, x in [(10.0, -20.0, 30.0), (-44.0, 44.0, 0.5)]:
        assert euler_from_matrix(rotation_matrix(z, y, x)) == pytest.approx((z, y, x), abs=1e-9)


def test_normalise_frame_is_robust_to_one_bright_cell():
    rng = np.random.default_rng(0)
    mag = np.abs(rng.normal(size=(256, 256)))
    mag[10, 10] = 1e4  # 80 dB above the rest
    out = normalise_frame(mag)
    assert out.dtype == np.float32 and out.min() >= 0 and out.max() <= 1
    assert np.median(out) > 0.5  # the rest is not crushed to black
    assert np.all(normalise_frame(np.zeros((4, 4))) == 0)
