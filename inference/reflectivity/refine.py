"""Refine attitudes on the image: the local search that minimises a frame's likelihood under the map.

``Objective`` says how an attitude is scored: the frame's negative log-likelihood per pixel under the map (speckle on
a texture of ``shape``, ``inference.reflectivity.model.nll``), plus ``silhouette_weight`` times one minus the soft IoU
of the target's projection with the enhanced silhouette (``inference.fit``), a prior that helps where the silhouettes
are sharp (our own radar) and hurts where they are not; the map's build chooses both on held-out labelled scenes.

``refine`` runs Nelder-Mead over a small rotation about each start (three angles in the observation frame, so no
Euler singularity), every start of a frame scored in one window fixed about the first. ``refine_pass`` refines a
pass's frames together: one rotation of the body common to all of them (a still pass: one attitude in LVLH, seen
through each frame's own observation frame), so the few flashes of each frame add up over the sweep.
``raw_bounds`` is the curvature of the objective summed over the window's pixels, from which the map's calibration
makes 90 % bounds (``inference.reflectivity.build``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from inference.fit import STENCIL, Renderer, Window, quadratic, soft_iou
from inference.reflectivity.likelihood import FrameData, score
from inference.reflectivity.likelihood import Window as Box
from inference.reflectivity.model import ReflectivityMap
from inference.rotations import euler_from_matrix, rotation_matrix, so3_exp

Vec = NDArray[np.float64]

SIMPLEX_DEG = 1.5  # the search's first steps
XATOL_DEG = 0.05
FATOL = 2e-6  # per pixel
MAX_RENDERS = 160
WINDOW_MARGIN_PX = 8
CURVATURE_STEP_DEG = 0.5
PASS_SIMPLEX_DEG = 3.0  # a pass's search: its first steps (a fused pass is off by degrees) ...
PASS_RESTARTS = 1  # ... and how many times it starts again from where it stopped (``refine_pass``) ...
PASS_RENDERS = 120  # ... each search's objective evaluations at most (an evaluation renders every frame)


@dataclass(frozen=True)
class Objective:
    """How an attitude is scored on a frame: the likelihood's texture ``shape`` (None: plain speckle) and the weight of
    the silhouette prior (0: the image alone)."""

    shape: float | None = 2.0
    silhouette_weight: float = 0.0


@dataclass(frozen=True)
class Refined:
    """One start refined on the image: the attitude (Euler z, y, x deg), its objective per pixel, where it started and
    its objective there, and the renders it took."""

    angles_deg: Vec
    cost: float
    start: str
    start_cost: float
    renders: int


def window_about(rmap: ReflectivityMap, angles_deg: Vec, margin_px: int = WINDOW_MARGIN_PX) -> Box:
    """The frame's window about the target at ``angles_deg`` (every search of one frame is scored in one window)."""
    return rmap.window_for(rmap.geometry(rotation_matrix(*np.asarray(angles_deg, float))), margin_px)


class FrameCost:
    """The objective of one frame in one window, as a function of the attitude's rotation matrix."""

    def __init__(
        self,
        rmap: ReflectivityMap,
        frame: NDArray[np.floating],
        window: Box,
        objective: Objective,
        enhanced: NDArray[np.floating] | None = None,
        renderer: Renderer | None = None,
    ) -> None:
        self.rmap, self.window, self.objective = rmap, window, objective
        self.data = FrameData.of(frame)
        self.pixels = window[2] * window[3]
        self._sil = None
        if objective.silhouette_weight > 0 and enhanced is not None and renderer is not None:
            win = Window(*window)
            target = np.ascontiguousarray(win.crop(np.clip(np.asarray(enhanced, np.float32), 0.0, 1.0)))
            self._sil = (renderer, win, target, float(np.clip(np.asarray(enhanced, np.float64), 0, 1).sum()))

    def __call__(self, rotation: Vec) -> float:
        value = score(self.rmap, self.data, rotation, self.window, self.objective.shape)[0]
        if self._sil is not None:
            renderer, win, target, total = self._sil
            occ = renderer.occupancy_of(np.asarray(rotation, float)[None], win)
            value += self.objective.silhouette_weight * (1.0 - float(soft_iou(occ, target, total)[0]))
        return value


def _nelder_mead(
    cost: FrameCost | PassCost, base: Vec, max_renders: int, body: bool = False, simplex_deg: float = SIMPLEX_DEG
) -> tuple[Vec, float, float, int]:
    """Nelder-Mead over a rotation vector (deg) about ``base`` (before it, in the observation frame; or after it, in
    the body, with ``body``), first steps ``simplex_deg``; returns the best rotation, its cost, the start's cost and
    the renders."""
    from scipy.optimize import minimize

    def turned(delta: Vec) -> Vec:
        turn = so3_exp(np.radians(delta))
        return np.asarray(base @ turn if body else turn @ base)

    def f(delta: Vec) -> float:
        return cost(turned(delta))

    x0 = np.zeros(3)
    start = f(x0)
    res = minimize(
        f,
        x0,
        method="Nelder-Mead",
        options={
            "initial_simplex": np.vstack([x0, simplex_deg * np.eye(3)]),
            "xatol": XATOL_DEG,
            "fatol": FATOL,
            "maxfev": max_renders,
        },
    )
    if start <= float(res.fun):
        return base, start, start, int(res.nfev) + 1
    return turned(res.x), float(res.fun), start, int(res.nfev) + 1


def refine(
    rmap: ReflectivityMap,
    frame: NDArray[np.floating],
    starts: dict[str, Vec],
    objective: Objective | None = None,
    enhanced: NDArray[np.floating] | None = None,
    renderer: Renderer | None = None,
    max_renders: int = MAX_RENDERS,
) -> list[Refined]:
    """Refine each start (name -> Euler z, y, x deg) on the frame under the map, in a window about the first; best
    first."""
    if not starts:
        return []
    window = window_about(rmap, np.asarray(next(iter(starts.values())), float))
    return refine_on(FrameCost(rmap, frame, window, objective or Objective(), enhanced, renderer), starts, max_renders)


def refine_on(cost: FrameCost, starts: dict[str, Vec], max_renders: int = MAX_RENDERS) -> list[Refined]:
    """``refine`` with the frame's objective already made (its window, data and silhouette); best first."""
    out = []
    for name, angles in starts.items():
        rot, best, start, renders = _nelder_mead(cost, rotation_matrix(*np.asarray(angles, float)), max_renders)
        out.append(Refined(np.asarray(euler_from_matrix(rot), float), best, name, start, renders))
    return sorted(out, key=lambda r: r.cost)


def raw_bounds(cost: FrameCost, angles_deg: Vec, step_deg: float = CURVATURE_STEP_DEG) -> Vec:
    """sqrt(diag(inv(H))) per Euler axis (deg), H the Hessian of the objective summed over the window's pixels (a
    Laplace approximation's 1-sigma); infinite where H is not positive definite."""
    pts = np.asarray(angles_deg, float) + step_deg * STENCIL
    values = np.array([cost(rotation_matrix(*p)) for p in pts]) * cost.pixels
    _, hess = quadratic(values)
    hess = hess / step_deg**2
    try:
        if np.all(np.linalg.eigvalsh(hess) > 0):
            return np.sqrt(np.maximum(np.diag(np.linalg.inv(hess)), 0.0))
    except np.linalg.LinAlgError:
        pass
    return np.full(3, np.inf)


class PassCost:
    """A pass's frames scored together: the mean of their objectives, each at its own attitude."""

    def __init__(self, costs: Sequence[FrameCost], bases: Sequence[Vec]) -> None:
        self.costs, self.bases = list(costs), [np.asarray(b, float) for b in bases]

    def __call__(self, turn: Vec) -> float:
        """The mean cost with every frame's attitude turned by ``turn`` in the body (``turn`` = I: the bases)."""
        return float(np.mean([c(b @ turn) for c, b in zip(self.costs, self.bases, strict=True)]))


def refine_pass(
    rmap: ReflectivityMap,
    frames: NDArray[np.floating],
    angles_deg: Vec,
    objective: Objective | None = None,
    max_renders: int = PASS_RENDERS,
) -> tuple[Vec, float, float]:
    """One body rotation common to a pass's frames (Euler starts ``angles_deg`` [N, 3], each frame's observation frame)
    that best explains them all under the map; returns that turn (3 x 3: each frame's refined attitude is its start's
    matrix times it), the mean cost per pixel and the start's.

    A pass's landscape is rough at a degree's scale (each frame's flashes come and go), so the search takes
    ``PASS_SIMPLEX_DEG`` first steps and starts again from where it stopped, up to ``PASS_RESTARTS`` times, while
    that still gains (``max_renders`` evaluations each; an evaluation renders every frame). On a lattice-scattering
    pass 3 deg off, one search from 1.5 deg steps stopped at 2.1 deg, above the truth's cost; 3 deg steps and a
    restart reached 0.49 deg. On harsh-scattering passes 10 frames, one restart and 120 evaluations a search gave a
    median of 0.50 deg in 18 s; 20 frames, two restarts and 160, 0.45 deg in 57 s (design/measurements.md)."""
    obj = objective or Objective()
    bases = [rotation_matrix(*a) for a in np.asarray(angles_deg, float)]
    costs = [FrameCost(rmap, f, window_about(rmap, a), obj) for f, a in zip(frames, angles_deg, strict=True)]
    whole = PassCost(costs, bases)
    turn, best, start, _ = _nelder_mead(whole, np.eye(3), max_renders, True, PASS_SIMPLEX_DEG)
    for _ in range(PASS_RESTARTS):
        again, value, _, _ = _nelder_mead(whole, turn, max_renders, True, PASS_SIMPLEX_DEG)
        gained = best - value
        if gained > 0:
            turn, best = again, value
        if gained < FATOL:
            break
    return turn, best, start


def turned_by(angles_deg: Vec, turn: Vec) -> Vec:
    """Attitudes (Euler z, y, x deg, [N, 3]) each turned by ``turn`` in the body."""
    return np.array([euler_from_matrix(rotation_matrix(*a) @ turn) for a in np.asarray(angles_deg, float)])
