"""The frame contract: the normalisation ignores one bright cell."""

import numpy as np

from inference.frames import normalise_frame


def test_normalise_frame_is_robust_to_one_bright_cell():
    rng = np.random.default_rng(0)
    mag = np.abs(rng.normal(size=(256, 256)))
    mag[10, 10] = 1e4  # 80 dB above the rest
    out = normalise_frame(mag)
    assert out.dtype == np.float32 and out.min() >= 0 and out.max() <= 1
    assert np.median(out) > 0.5  # the rest is not crushed to black
    assert np.all(normalise_frame(np.zeros((4, 4))) == 0)
