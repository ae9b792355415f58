"""One attitude from a pass: fuse per-frame estimates expressed in the target's orbital (LVLH) frame.

numpy (and scipy for one t quantile). A three-axis-stabilised target keeps one body-to-LVLH rotation over a pass
while the radar's observation frame sweeps across it, so every frame estimates the same
rotation from another side (issue 21). Each frame k gives ``A_k = O_k R_k``: ``R_k`` its
fitted attitude (body to observation frame, ``inference.trust``), ``O_k`` its observation
axes in LVLH (columns), and the same for each of its alternatives (the near-mirror above
all, whose reflection is through that frame's own image plane, so it differs from frame
to frame while the truth does not).

``fuse``:

1. **Branches.** Every candidate of every frame is scored by how many frames have some
   candidate within ``agree_deg`` of it; the best-supported one seeds the mean.
2. **Robust mean.** Each frame takes its candidate nearest the mean; the mean is the
   weighted chordal mean (the weighted sum of rotation matrices projected back onto SO(3)
   by SVD), each frame weighted by 1 / sigma^2 with sigma its 90 % bound over 1.645.
   A frame further than ``max(reject_sigma * sigma_k, reject_floor_deg)`` from the mean is
   rejected (said why); repeat until nothing changes.
3. **Bound.** Per LVLH Euler axis, the 90 % interval of the weighted mean of the frames
   used: Student's t (n - 1 degrees of freedom) on their spread, never below the bound
   their own per-frame bounds imply (1.645 / sqrt(sum of weights)).
4. **Stability.** The residual rotations log(A^T A_k) (body frame, rad) against the
   frames' times: a least-squares body rate, with its standard error from the residual
   scatter. The target is called turning when the rate is over ``spin_sigma`` standard
   errors and over ``min_rate_deg_s``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from inference.frames import euler_from_matrix

Vec = NDArray[np.float64]
Z90 = 1.6448536269514722  # the two-sided 90 % normal quantile


@dataclass(frozen=True)
class PassFrame:
    """One frame of a pass: its candidates (body to LVLH, [M, 3, 3], the answer first), 90 % bounds (deg), time (s)."""

    candidates: Vec
    bound_deg: float
    time_s: float
    name: str = ""


@dataclass(frozen=True)
class Fused:
    """The pass's attitude (body to LVLH) and how it was reached."""

    rotation: Vec
    euler_zyx_deg: tuple[float, float, float]
    uncertainty_deg: tuple[float, float, float]
    used: list[int]
    rejected: dict[int, str]
    branch_changed: list[int]  # frames whose answer was replaced by one of their alternatives
    rate_deg_s: Vec
    rate_sigma_deg_s: Vec
    stable: bool
    residual_deg: dict[int, float] = field(default_factory=dict)


def so3_log(r: Vec) -> Vec:
    """Return the rotation vector (rad) of a rotation matrix."""
    cos = min(1.0, max(-1.0, (float(np.trace(r)) - 1.0) / 2.0))
    angle = math.acos(cos)
    w = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    if angle < 1e-9:
        return w / 2.0
    if math.pi - angle < 1e-6:  # near pi: the axis from the symmetric part
        vals, vecs = np.linalg.eigh((r + r.T) / 2.0)
        return np.asarray(vecs[:, -1] * angle)
    return np.asarray(w * angle / (2.0 * math.sin(angle)))


def angle_deg(a: Vec, b: Vec) -> float:
    """Return the rotation angle (deg) between two rotation matrices."""
    cos = min(1.0, max(-1.0, (float(np.sum(a * b)) - 1.0) / 2.0))
    return math.degrees(math.acos(cos))


def chordal_mean(rotations: Vec, weights: Vec) -> Vec:
    """Return the weighted chordal L2 mean of rotation matrices [N, 3, 3] (SVD projection of their weighted sum)."""
    m = np.einsum("n,nij->ij", weights, rotations)
    u, _, vt = np.linalg.svd(m)
    d = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    return np.asarray(u @ d @ vt)


def fuse(frames: list[PassFrame], agree_deg: float = 3.0, reject_sigma: float = 4.0, reject_floor_deg: float = 2.0,
         spin_sigma: float = 4.0, min_rate_deg_s: float = 0.02) -> Fused:  # fmt: skip
    """Fuse a pass's frames into one body-to-LVLH attitude (see the module's text)."""
    if len(frames) < 2:
        raise ValueError("a pass needs at least two frames to fuse")
    sigma = np.array([max(f.bound_deg, 1e-3) / Z90 for f in frames])
    # 1. The best-supported candidate seeds the mean.
    best_support, seed = -1.0, frames[0].candidates[0]
    for f in frames:
        for c in f.candidates:
            support = sum(1.0 for g in frames if min(angle_deg(c, d) for d in g.candidates) <= max(agree_deg, 0.0))
            if support > best_support:
                best_support, seed = support, c
    mean = seed
    rejected: dict[int, str] = {}
    chosen = [0] * len(frames)
    for _ in range(20):
        chosen = [int(np.argmin([angle_deg(mean, c) for c in f.candidates])) for f in frames]
        dist = np.array([angle_deg(mean, f.candidates[j]) for f, j in zip(frames, chosen, strict=True)])
        limit = np.maximum(reject_sigma * sigma, reject_floor_deg)
        new_rejected = {
            k: f"{dist[k]:.1f} deg from the pass's mean, over its limit of {limit[k]:.1f} deg"
            for k in range(len(frames))
            if dist[k] > limit[k]
        }
        used = [k for k in range(len(frames)) if k not in new_rejected]
        if len(used) < 2:
            used = list(np.argsort(dist)[:2])
            new_rejected = {k: v for k, v in new_rejected.items() if k not in used}
        rots = np.array([frames[k].candidates[chosen[k]] for k in used])
        new_mean = chordal_mean(rots, 1.0 / sigma[used] ** 2)
        done = new_rejected == rejected and angle_deg(new_mean, mean) < 1e-6
        mean, rejected = new_mean, new_rejected
        if done:
            break
    used = [k for k in range(len(frames)) if k not in rejected]
    rots = np.array([frames[k].candidates[chosen[k]] for k in used])
    w = 1.0 / sigma[used] ** 2
    # 3. Per-axis bound on the fused Euler angles.
    euler = np.array(euler_from_matrix(mean))
    each = np.array([euler_from_matrix(r) for r in rots])
    dev = (each - euler + 180.0) % 360.0 - 180.0
    n = len(used)
    spread = np.sqrt(np.sum(w[:, None] * dev**2, axis=0) / np.sum(w)) if n > 1 else np.zeros(3)
    n_eff = float(np.sum(w) ** 2 / np.sum(w**2))
    t = _t90(max(n - 1, 1))
    statistical = t * spread / math.sqrt(max(n_eff, 1.0))
    floor = Z90 / math.sqrt(float(np.sum(w)))
    bound = np.maximum(statistical, floor)
    # 4. Stability: a body rate from the residual rotations over time.
    times = np.array([frames[k].time_s for k in used])
    resid = np.array([so3_log(mean.T @ r) for r in rots])  # body frame, rad
    rate, rate_sigma = _rate(times, resid, w)
    speed = math.degrees(float(np.linalg.norm(rate)))
    z = float(np.linalg.norm(rate / np.maximum(rate_sigma, 1e-12))) / math.sqrt(3.0)
    stable = not (z > spin_sigma and speed > min_rate_deg_s)
    return Fused(
        rotation=mean,
        euler_zyx_deg=tuple(float(a) for a in euler),  # type: ignore[arg-type]
        uncertainty_deg=tuple(float(b) for b in bound),  # type: ignore[arg-type]
        used=used,
        rejected=rejected,
        branch_changed=[k for k in used if chosen[k] != 0],
        rate_deg_s=np.degrees(rate),
        rate_sigma_deg_s=np.degrees(rate_sigma),
        stable=stable,
        residual_deg={k: angle_deg(mean, frames[k].candidates[chosen[k]]) for k in range(len(frames))},
    )


def _rate(times: Vec, resid: Vec, weights: Vec) -> tuple[Vec, Vec]:
    """Weighted least squares resid = c + rate t per axis; return the rate and its standard error (rad/s)."""
    if len(times) < 3 or np.ptp(times) <= 0:
        return np.zeros(3), np.full(3, np.inf)
    x = np.stack([np.ones_like(times), times - times.mean()], axis=1)
    sw = np.sqrt(weights)[:, None]
    coef, *_ = np.linalg.lstsq(x * sw, resid * sw, rcond=None)
    fitted = x @ coef
    dof = max(len(times) - 2, 1)
    s2 = np.sum(weights[:, None] * (resid - fitted) ** 2, axis=0) / dof / (np.sum(weights) / len(weights))
    sxx = float(np.sum(weights * (times - times.mean()) ** 2) / (np.sum(weights) / len(weights)))
    return np.asarray(coef[1]), np.sqrt(s2 / sxx)


def _t90(dof: int) -> float:
    """Return Student's t two-sided 90 % quantile."""
    from scipy.stats import t

    return float(t.ppf(0.95, dof))


def observation_attitude(body_to_lvlh: Vec, observation_in_lvlh: Vec) -> Vec:
    """Return the body-to-observation rotation a frame sees: O^T A (the inverse of A_k = O_k R_k)."""
    return np.asarray(observation_in_lvlh.T @ body_to_lvlh)
