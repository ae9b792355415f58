"""Fit a map's laws and reflectivities to labelled frames, all at once, by maximum likelihood.

Under speckle a pixel's intensity is exponential about the map's mean, so the likelihood of every labelled frame
is maximised by minimising the Itakura-Saito divergence between the frames and the map. The mean is linear in each
group of parameters (the parts' law nodes and reflectivities, the frames' gains), all non-negative, so each iteration
takes the multiplicative step of IS-NMF (Fevotte, Bertin & Durrieu 2009, Neural Computation 21:793):

    theta <- theta * (sum Phi^T y / mu^2) / (sum Phi^T 1 / mu)

with censored pixels (at 0 or 1 in the normalised frame) replaced by their expectation under the current mean (EM).
The frames' attitudes are their labels; the frames' floors come from their own background.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from inference.reflectivity.likelihood import FrameData, Window, profiled_gain
from inference.reflectivity.model import LAW_BINS, Geometry, ReflectivityMap, imputed, nll
from inference.rotations import rotation_matrices

Vec = NDArray[np.float64]
ITERATIONS = 40


@dataclass
class _Frame:
    """One labelled frame's fixed part: the live sites' geometry, the window's data, the gain."""

    idx: NDArray[np.intp]
    geo: Geometry
    window: Window
    y: Vec
    low: NDArray[np.bool_]
    high: NDArray[np.bool_]
    floor: float
    gain: float = 1.0


def _subset(g: Geometry, idx: NDArray[np.intp]) -> Geometry:
    return Geometry(g.u[idx], g.v[idx], g.c[idx], g.vis[idx], g.spec[idx])


def prepare(rmap: ReflectivityMap, frames: NDArray[np.floating], angles_deg: Vec) -> list[_Frame]:
    """Each labelled frame's live sites (facing the radar, visible) and its data in the window about the target."""
    out = []
    for frame, rot in zip(frames, rotation_matrices(np.asarray(angles_deg, float)), strict=True):
        g = rmap.geometry(rot)
        idx = np.flatnonzero((g.c > 0) & (g.vis > 0))
        sub = _subset(g, idx)
        win = rmap.window_for(g)
        data = FrameData.of(frame)
        y, low, high = data.crop(win)
        out.append(_Frame(idx, sub, win, y, low, high, data.floor))
    return out


def _mean(rmap: ReflectivityMap, f: _Frame) -> tuple[Vec, Vec]:
    """The frame's live sites' returns and its mean image before gain and floor."""
    assert rmap.rho is not None
    part = rmap.sites.part[f.idx]
    values = (rmap.sites.areas[f.idx] * rmap.law_at(f.geo.c, part) + rmap.rho[part] * f.geo.spec) * f.geo.vis
    return values, rmap.splat(f.geo, values, f.window)


def divergence(rmap: ReflectivityMap, frames: Sequence[_Frame]) -> Vec:
    """Each frame's negative log-likelihood per pixel under the map (speckle; its gain profiled out)."""
    out = []
    for f in frames:
        _, m = _mean(rmap, f)
        gain = profiled_gain(m, f.y, f.low, f.high, f.floor)
        out.append(nll(gain * m + f.floor, f.y, f.low, f.high) / f.y.size)
    return np.array(out)


def fit(
    rmap: ReflectivityMap,
    frames: Sequence[_Frame],
    iterations: int = ITERATIONS,
    specular: bool = True,
    progress: Callable[[int, int, float], None] | None = None,
) -> list[float]:
    """Fit ``rmap``'s laws and (with ``specular``) reflectivities to ``frames`` in place; return the mean divergence
    per pixel before each iteration's step."""
    assert rmap.rho is not None and rmap.law is not None
    n_parts = rmap.sites.n_parts
    n_law = n_parts * LAW_BINS
    if specular and not np.any(rmap.rho > 0):
        rmap.rho = np.full(n_parts, 1e-4)
    for f in frames:  # a start for each gain
        _, m = _mean(rmap, f)
        f.gain = profiled_gain(m, f.y, f.low, f.high, f.floor)
    history: list[float] = []
    for it in range(iterations):
        num_l, den_l = np.zeros(n_law), np.zeros(n_law)
        num_r, den_r = np.zeros(n_parts), np.zeros(n_parts)
        total = 0.0
        for f in frames:
            _, m = _mean(rmap, f)
            mu = f.gain * m + f.floor
            total += nll(mu, f.y, f.low, f.high) / f.y.size
            yi = imputed(mu, f.y, f.low, f.high)
            q1, q2 = yi / mu**2, 1.0 / mu
            f.gain *= float(np.sum(m * q1)) / max(float(np.sum(m * q2)), 1e-300)  # the frame's gain: its own step
            big_n, big_d = rmap.gather(f.geo, q1, q2, f.window)
            scale = f.gain * f.geo.vis
            big_n *= scale
            big_d *= scale
            part = rmap.sites.part[f.idx]
            lo, frac = rmap.law_weights(f.geo.c, part)
            area = rmap.sites.areas[f.idx]
            for nodes, share in ((lo, 1.0 - frac), (lo + 1, frac)):
                num_l += np.bincount(nodes, area * share * big_n, n_law)
                den_l += np.bincount(nodes, area * share * big_d, n_law)
            if specular:
                num_r += np.bincount(part, f.geo.spec * big_n, n_parts)
                den_r += np.bincount(part, f.geo.spec * big_d, n_parts)
        history.append(total / max(len(frames), 1))
        if progress is not None:
            progress(it + 1, iterations, history[-1])
        seen = den_l > 0
        rmap.law[seen] *= num_l[seen] / den_l[seen]
        if specular:
            seen_r = den_r > 0
            rmap.rho[seen_r] *= num_r[seen_r] / den_r[seen_r]
        # One scale is free between the map and the frames' gains: the largest law node stays 1.
        top = float(rmap.law.max())
        if top > 0:
            rmap.law /= top
            rmap.rho /= top
            for f in frames:
                f.gain *= top
    return history
