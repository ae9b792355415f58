"""The contract shared by the simulator, training and serving: frame normalisation and the networks' angle scale.

numpy only, so the service can import it without torch or the simulator. Attitudes are
Euler angles (z, y, x) in degrees of R = Rz(z) Ry(y) Rx(x), body to observation frame
(``inference.rotations``, the one rotation kit); the networks read and write them scaled by
``ANGLE_SCALE_DEG`` (the +-45 deg label range).
"""

from __future__ import annotations

import ast
import math
import threading
from typing import Any

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


NORMALISED_MIN_TOP_SHARE = 0.004  # normalise_frame clips the top 0.5 % of pixels to 1.0 (a margin for ties)


def normalised_problem(mag: NDArray[np.floating]) -> str | None:
    """Why ``mag`` cannot be ``normalise_frame``'s output (a phrase after "normalised"), or None when it can be.

    A normalised frame lies in [0, 1] and, since ``normalise_frame`` maps its 99.5th percentile and
    everything above it to 1.0, has at least 0.5 % of its pixels at 1.0; a raw frame that merely
    lies in [0, 1] does not.
    """
    lo, hi = float(np.min(mag)), float(np.max(mag))
    if lo < 0.0 or hi > 1.0:
        return (
            f"needs values in [0, 1] (inference.frames.normalise_frame output); this frame spans [{lo:.3g}, {hi:.3g}]"
        )
    at_top = float(np.mean(np.asarray(mag) >= 0.999))
    if at_top < NORMALISED_MIN_TOP_SHARE:
        return (
            f"needs 0.5 % of the pixels at 1.0, where inference.frames.normalise_frame puts its top; this frame "
            f"has {100 * at_top:.2g} %: this is a raw frame"
        )
    return None


def resample_metres(
    mag: NDArray[np.floating], cells_m: tuple[float, float], model_cells_m: tuple[float, float], size: int
) -> NDArray[np.float64]:
    """Resample a frame of cells ``cells_m`` (range, cross-range metres) to the models' cells, centred, ``size`` a side.

    Bilinear; the frame's centre pixel (N/2, counted from 0) stays the centre. Where the frame
    covers less than the models' frame (24 x 29 m for the shipped models), the rest is its median
    (its noise floor). Raises ``InferenceError`` (field ``range_cell_m``) when the frame covers
    under 8 of the models' pixels.
    """
    from scipy.ndimage import affine_transform

    from inference.errors import InferenceError

    mag = np.asarray(mag, np.float64)
    scale = (model_cells_m[0] / cells_m[0], model_cells_m[1] / cells_m[1])  # input pixels per model pixel
    spans = (mag.shape[0] / scale[0], mag.shape[1] / scale[1])
    if min(spans) < 8:
        raise InferenceError(
            f"a {mag.shape[0]}x{mag.shape[1]} frame of {cells_m[0]:g} x {cells_m[1]:g} m cells covers under 8 of the "
            f"models' {model_cells_m[0]:.4f} x {model_cells_m[1]:.4f} m pixels: check the cell sizes",
            field="range_cell_m",
        )
    centre_in = np.array([mag.shape[0] // 2, mag.shape[1] // 2], float)
    offset = centre_in - np.array(scale) * (size // 2)
    out = affine_transform(
        mag, scale, offset=offset, output_shape=(size, size), order=1, mode="constant", cval=float(np.median(mag))
    )
    return np.asarray(out, np.float64)


_AST_LOCK = threading.Lock()
_LITERAL_EVAL = ast.literal_eval


def _serial_literal_eval(node_or_string: Any) -> Any:
    """``ast.literal_eval``, one thread at a time.

    numpy parses every .npy header (``np.load``, ``npy_header``) with ``ast.literal_eval``, and CPython 3.11 (3.11.7
    here) can fail that when two threads parse at once: SystemError "AST constructor recursion depth mismatch"
    (python/cpython#106905). The service reads uploads in a thread pool, and the two-worker load test met it as a
    500 on an .npy upload. numpy imports ``ast`` inside its reader, so the stand-in goes on the ``ast`` module
    itself (the same function, serialised); a header is a few hundred bytes, so the lock costs nothing measurable.
    """
    with _AST_LOCK:
        return _LITERAL_EVAL(node_or_string)


if getattr(ast.literal_eval, "__name__", "") != "_serial_literal_eval":
    ast.literal_eval = _serial_literal_eval


def npy_header(fh: Any) -> tuple[tuple[int, ...], np.dtype[Any]]:
    """A .npy file's shape and dtype read from its header alone (``fh`` at the file's start, left after the header).

    ``np.load`` allocates what the header promises before reading a byte of data; this is what a reader checks
    first (sizes, counts, budgets). Raises ValueError for anything that is not a readable .npy header.
    """
    try:
        version = np.lib.format.read_magic(fh)
        if version == (1, 0):
            shape, _fortran, dtype = np.lib.format.read_array_header_1_0(fh)
        elif version in ((2, 0), (3, 0)):
            shape, _fortran, dtype = np.lib.format.read_array_header_2_0(fh)
        else:
            raise ValueError(f"unsupported .npy version {version}")
    except (OSError, EOFError, SyntaxError, TypeError) as exc:
        raise ValueError(str(exc)) from None
    return tuple(int(d) for d in shape), dtype


def silhouette_ious(enhanced: NDArray[np.floating], labels: NDArray[Any]) -> NDArray[np.float64]:
    """Each frame's IoU of a silhouette (> 0.5, e.g. UNet++'s) with its label [N]; 1 where both are empty.

    >>> silhouette_ious(np.array([[[0.9, 0.2], [0.7, 0.0]]]), np.array([[[1, 1], [0, 0]]])).tolist()
    [0.3333333333333333]
    """
    a = np.asarray(enhanced) > 0.5
    b = np.asarray(labels) > 0.5
    inter = np.logical_and(a, b).sum(axis=(1, 2))
    union = np.logical_or(a, b).sum(axis=(1, 2))
    return np.asarray(np.where(union > 0, inter / np.maximum(union, 1), 1.0), np.float64)
