"""Frames read: the networks, then the fit and the checks of each frame (the single, batch and pass routes alike)."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:  # the checks load numba's compiled renderer: the caller has them loaded already
    from inference.checked import Checked
    from inference.runtime import Estimator, NetworkOutput
    from inference.trust import Checker


Progress = Callable[[str, int, int], None]  # (stage, done, total): long reads say how far they are


@dataclass(frozen=True)
class Readings:
    """A batch of frames read: the frames as the models saw them [N, H, W], the networks' output, each frame's
    checked answer, and the seconds per frame of each stage (``preprocess``, the networks', ``fit``)."""

    frames: NDArray[np.float32]
    network: NetworkOutput
    checks: list[Checked]
    timings_s: dict[str, float]


def read_frames(
    est: Estimator,
    checker: Checker,
    frames: NDArray[np.float32],
    refine: bool = True,
    search: bool = True,
    preprocess_s: float = 0.0,
    progress: Progress | None = None,
    cancelled: Callable[[], bool] | None = None,
) -> Readings:
    """Run the networks on the frames [N, H, W] as one batch, then fit and check each (``Checker.check_many``).

    ``preprocess_s``: what preparing the frames took (s, the whole batch), kept in the timings.
    ``progress(stage, done, total)``: "estimated" once the networks have read the batch, then "fitted" per frame.
    ``cancelled()``: asked before each frame's fit; yes stops the work (``inference.errors.Cancelled``).
    """
    res = est.estimate(frames)
    n = len(frames)
    if progress is not None:
        progress("estimated", n, n)
    t1 = time.perf_counter()
    checks = checker.check_many(
        frames,
        res.enhanced,
        res.angles_deg if checker.networks else None,
        refine,
        search,
        None if progress is None else (lambda done, total: progress("fitted", done, total)),
        cancelled,
        est.search_enhancer,
    )
    t_fit = time.perf_counter() - t1
    per_frame = {"preprocess": preprocess_s / n, **{k: v / n for k, v in res.timings_s.items()}, "fit": t_fit / n}
    return Readings(frames, res, checks, per_frame)
