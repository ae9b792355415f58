"""A frame under the map: its intensity, floor and window, and the speckle likelihood of an attitude.

``FrameData.of(frame)`` reads a normalised frame back to intensity once; ``score`` renders the map at an attitude
into a fixed window, profiles the frame's gain out (maximum likelihood, a few EM steps) and returns the negative
log-likelihood per pixel. numpy only beside the map's kernels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from inference.reflectivity.model import ReflectivityMap, floor_of, frame_intensity, imputed, nll

Vec = NDArray[np.float64]
Window = tuple[int, int, int, int]
GAIN_STEPS = 10  # Newton converges to 1e-6 per pixel of the objective in 10 (design/measurements.md)


@dataclass(frozen=True)
class FrameData:
    """A normalised frame read back: intensity ``y``, censored pixels ``low`` and ``high``, noise ``floor``."""

    y: Vec
    low: NDArray[np.bool_]
    high: NDArray[np.bool_]
    floor: float

    @staticmethod
    def of(frame: NDArray[np.floating]) -> FrameData:
        y, low, high = frame_intensity(frame)
        return FrameData(y, low, high, floor_of(y))

    def crop(self, window: Window) -> tuple[Vec, NDArray[np.bool_], NDArray[np.bool_]]:
        r0, c0, h, w = window
        sl = (slice(r0, r0 + h), slice(c0, c0 + w))
        return self.y[sl], self.low[sl], self.high[sl]


def profiled_gain(m: Vec, y: Vec, low: NDArray[np.bool_], high: NDArray[np.bool_], floor: float) -> float:
    """The gain g that maximises the likelihood of mu = g m + floor: Newton's steps on the score
    sum m (y - mu) / mu^2 = 0, censored pixels at their expectation under the current mean (EM), a multiplicative
    step wherever Newton's would leave g <= 0."""
    total = float(m.sum())
    if total <= 0:
        return 0.0
    g = max(float(np.sum(np.maximum(y - floor, 0.0))) / total, 1e-12)
    for _ in range(GAIN_STEPS):
        mu = g * m + floor
        yi = imputed(mu, y, low, high)
        score_ = float(np.sum(m * (yi - mu) / mu**2))
        slope = -float(np.sum(m * m * (2.0 * yi - mu) / mu**3))
        step = g - score_ / slope if slope < 0 else -1.0
        g = step if step > 0 else g * float(np.sum(m * yi / mu**2)) / max(float(np.sum(m / mu)), 1e-300)
    return g


def profiled_mean(rmap: ReflectivityMap, data: FrameData, rotation: Vec, window: Window) -> tuple[Vec, float]:
    """The map's mean intensity of ``data``'s ``window`` at ``rotation``, its gain profiled out (``profiled_gain``)
    and the frame's floor added; and the gain."""
    g = rmap.geometry(rotation)
    m = rmap.splat(g, rmap.intensity(g), window)
    y, low, high = data.crop(window)
    gain = profiled_gain(m, y, low, high, data.floor)
    return gain * m + data.floor, gain


def score(
    rmap: ReflectivityMap, data: FrameData, rotation: Vec, window: Window, shape: float | None = None
) -> tuple[float, float]:
    """The negative log-likelihood per pixel of ``data`` in ``window`` under the map at ``rotation`` (``nll``'s
    ``shape``), and the gain (profiled under speckle)."""
    mu, gain = profiled_mean(rmap, data, rotation, window)
    y, low, high = data.crop(window)
    return nll(mu, y, low, high, shape) / y.size, gain


def deviance(rmap: ReflectivityMap, data: FrameData, rotation: Vec, window: Window) -> float:
    """How far the frame is from what the map predicts at ``rotation``: the mean speckle deviance per seen pixel,
    y/mu - log(y/mu) - 1, whose expectation is Euler's gamma (0.577) where the map explains the frame."""
    mu, _ = profiled_mean(rmap, data, rotation, window)
    y, low, high = data.crop(window)
    seen = ~(low | high)
    r = y[seen] / mu[seen]
    return float(np.mean(r - np.log(r) - 1.0)) if r.size else float("nan")
