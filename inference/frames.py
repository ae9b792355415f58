"""The contract shared by the simulator, training and serving: frame normalisation and the networks' angle scale.

numpy only, so the service can import it without torch or the simulator. Attitudes are
Euler angles (z, y, x) in degrees of R = Rz(z) Ry(y) Rx(x), body to observation frame
(``inference.rotations``, the one rotation kit); the networks read and write them scaled by
``ANGLE_SCALE_DEG`` (the +-45 deg label range).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

Vec = NDArray[np.float64]

ANGLE_SCALE_DEG = 45.0  # network outputs are angles / ANGLE_SCALE_DEG


def normalise_frame(magnitude: NDArray[np.floating], dynamic_range_db: float = 40.0) -> NDArray[np.float32]:
    """Map an ISAR magnitude image to [0, 1] the way the networks consume it (training and service alike).

    Decibels relative to the 99.5th percentile (robust to one very bright cell:
    a cylinder seen broadside can sit 40 dB above the rest), clipped to
    ``dynamic_range_db`` below it.
    """
    mag = np.abs(np.asarray(magnitude, np.float64))
    ref = float(np.percentile(mag, 99.5))
    if not math.isfinite(ref) or ref <= 0.0:
        return np.zeros(mag.shape, np.float32)
    db = 20.0 * np.log10(np.maximum(mag, ref * 1e-12) / ref)
    return np.clip((db + dynamic_range_db) / dynamic_range_db, 0.0, 1.0).astype(np.float32)
