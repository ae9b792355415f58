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
   candidate within ``agree_deg`` of it, and half as much again (``ANSWER_VOTE``) for each
   frame whose own answer is within it; the best-supported one seeds the mean. Where the
   image plane turns, a wrong branch agrees with few frames and the first count decides;
   where it barely turns, the near-mirror (a reflection through that plane) agrees with
   every frame as well as the truth does, and the frames' own choices decide.
2. **Robust mean.** Each frame takes its candidate nearest the mean; the mean is the
   weighted chordal mean (the weighted sum of rotation matrices projected back onto SO(3)
   by SVD), each frame weighted by 1 / sigma^2 with sigma its 90 % bound over 1.645. Where
   the frames carry their geometry and per-axis bounds, the mean is then refined with each
   frame's full information matrix (its bounds' covariance, through its own Euler axes and
   observation frame, into LVLH): a frame counts most about the axes it sees best. The
   covariance keeps how a frame's Euler axes trade against each other (a tilt the silhouette
   barely shows lies along some mix of y and x); a frame without one counts its axes as independent. A frame
   further than ``max(reject_sigma * sigma_k, reject_floor_deg)`` from the mean is rejected
   (said why); repeat until nothing changes. Frames marked not ``trusted`` (the caller decides;
   the service lets in frames doubted only for a lookalike) are rejected first, unless fewer than two are left.
3. **Bound.** Per LVLH Euler axis, the 90 % interval of the mean: from the frames'
   information (or Student's t on their spread without it), scaled up by their scatter
   beyond it, plus the part of a frame's error the pass's frames share
   (``SHARED_FRACTION`` of its variance), which no number of frames averages away.
4. **Stability.** Two tests; either calls the target turning.

   - *Drift*: the residual rotations log(A^T A_k) (body frame, rad) against the frames'
     times: a least-squares body rate, with its standard error from the residual scatter,
     over ``spin_sigma`` standard errors and over ``min_rate_deg_s``.
   - *A turning model* (``fit_turning``, when the frames carry their line of sight): a
     target spinning at a constant body rate w does not only change its attitude, it turns
     each frame's image plane too, since the image forms from the line of sight's motion
     *relative to the body* (its rate in LVLH less w x the line of sight). So a spinning
     target's frames, placed in LVLH as if it were still, need not agree at all. The model
     predicts every frame's body-to-observation rotation from (A at mid-pass, w) and the
     pass geometry and is fitted to the frames' own answers (a grid over w seeded by the
     lines of sight alone, then least squares on the whole rotations). The target is turning
     when that model beats the still one by a chi-square of over ``turning_chi2`` (3 degrees
     of freedom; each frame's term capped at ``reject_sigma`` squared, so outliers do not
     decide) and its rate is over ``min_rate_deg_s`` and either over ``spin_sigma`` standard
     errors or the gain is spread over the frames: over ``turning_chi2`` still once the
     ``SPREAD_DROP`` frames that gain most are left out. The second arm is for a short
     arc: over a minute, the frames see the line of sight's track in the body, its
     position and its rate, which a body rate and an attitude can trade between (the rate
     about some axis is then barely determined), yet no still attitude explains them,
     least of all frames read reversed in cross-range. The
     answer is then the model's attitude at the middle of the frames' times and its rate,
     with uncertainties from the speed's profile (``widen_by_profile``) where the curvature
     at the minimum understates them: on a short arc the chi-square barely rises along a
     valley where the attitude at mid-pass moves by tens of degrees with the speed.

     *Measured sweeps* (``PassFrame.sweep_rad_s``, where the caller sends each frame's
     integration time): a radar forming a frame of a known sub-aperture angle over a known
     time has measured how fast the line of sight turns relative to the body. For a still
     target that is the line of sight's own rate; for a turning one it is |its LVLH rate less
     (A w) x the line of sight| across the line of sight (``sweep_rates``), one more equation a
     frame for the rate, from every frame of the pass, read or not. Both models are scored
     on them too (each sweep's chi-square term capped as a frame's is), and they close the
     short arc's valley: the rate the attitudes alone trade against the attitude is the one
     the sweeps measure. Their errors: ``SWEEP_SIGMA`` of the rate (the aperture is known as
     well as the cross-range cell), and at a pass's slow ends the gap between the rate over
     a long integration and the rate at its middle (``sweep_sigmas``); measured in
     design/measurements.md, "Measured sweeps in the turning fit".
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from inference.rotations import (
    MIRROR,
    RX_180,
    angle_deg,
    chordal_mean,
    euler_from_matrix,
    euler_jacobian,
    so3_exp,
    so3_log,
    so3_logs,
)

Vec = NDArray[np.float64]
Z90 = 1.6448536269514722  # the two-sided 90 % normal quantile
# The share of a frame's error variance that the other frames of its pass share: a pass turns
# the line of sight through the body in about one plane, so the out-of-plane view, and the fit's
# error there, hardly change from frame to frame. Measured on 20 simulated passes (seeds
# 40000-40019, not the benchmark's; bench/passes.py and BENCHMARKS.md "Pass fusion").
SHARED_FRACTION = 0.1
# A frame's vote for the branch its own answer is on, beside its vote for any branch one of its candidates is on:
# where the image plane barely turns, a reflection through it is the same for every frame and both branches
# agree with every frame; the frames' own choices (brightness, Swin) then decide.
ANSWER_VOTE = 0.5
# The turning test without a significant rate: the gain must stand without the frames that give most of it.
SPREAD_DROP = 2
# A measured sweep rate's 1-sigma error, as a fraction of it: the aperture is known as well as the cross-range
# cell is (a radar's cross-range scaling), the integration time exactly.
SWEEP_SIGMA = 0.02


@dataclass(frozen=True)
class PassFrame:
    """One frame of a pass: its candidates (body to LVLH, [M, 3, 3], the answer first), 90 % bounds (deg), time (s)."""

    candidates: Vec
    bound_deg: float
    time_s: float
    name: str = ""
    los: Vec | None = None  # line of sight (target to radar) in LVLH, unit
    los_rate: Vec | None = None  # its rate in LVLH (1/s)
    trusted: bool = True
    why_not: str = ""  # why the frame's own checks did not trust it
    axis_bounds_deg: tuple[float, float, float] | None = None  # 90 % bounds on its own Euler z, y, x (obs frame)
    # Their covariance (deg^2, diagonal = the bounds squared; inference.trust.bound_covariance), where the fit has
    # one: how the frame's Euler axes trade against each other. Without it the axes count as independent.
    axis_cov_deg2: Vec | None = None
    # The line of sight's angular rate relative to the body as the radar measured it (rad/s): the sub-aperture's
    # angle over its integration time (a cross-range cell follows it). A still target's is the line of sight's own
    # rate in LVLH; a turning one's differs by the spin (``sweep_rates``). Read for every frame, trusted or not.
    sweep_rad_s: float | None = None
    # Its 1-sigma error (rad/s; ``sweep_sigmas``), where the caller knows it: at least SWEEP_SIGMA of the rate.
    sweep_sigma_rad_s: float | None = None


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
    turning_chi2: float | None = None  # how much better the turning model fits than the still one
    reference_s: float | None = None  # a turning answer's time (s, the frames' clock); a still one holds throughout
    chosen: list[int] = field(default_factory=list)  # each frame's candidate the answer took
    placed: Vec = field(default_factory=lambda: np.zeros((0, 3, 3)))  # that candidate, body to LVLH, as the
    # answer places it ([N, 3, 3]: for a turning answer through the model's observation frames, ``place_turning``)
    # Another attitude (body to LVLH) that as many frames agree with as with the answer, where there is one: the
    # near-mirror of a pass whose image plane barely turns (``_rival_branch``); the frames' own answers chose.
    rival: Vec | None = None


def _informations(frames: list[PassFrame]) -> list[list[Vec]]:
    """Each frame's information matrix (LVLH, left perturbation, 1/rad^2) for each of its candidates.

    A frame without per-axis bounds (a fit that bounds nothing) counts as equally unsure about
    every axis, by its overall bound, as in the chordal mean: it is then rejected or weighs little,
    and the other frames keep their own axes.
    """
    out: list[list[Vec]] = []
    for f in frames:
        assert f.los is not None and f.los_rate is not None
        if f.axis_bounds_deg is None:
            iso = (Z90 / math.radians(max(f.bound_deg, 1e-3))) ** 2
            out.append([iso * np.eye(3) for _ in f.candidates])
            continue
        obs = observation_in_lvlh(f.los[None], f.los_rate[None])[0]
        if f.axis_cov_deg2 is not None:
            cov = np.radians(1.0) ** 2 * np.asarray(f.axis_cov_deg2, float) / Z90**2
        else:
            cov = np.diag((np.radians(np.maximum(np.array(f.axis_bounds_deg, float), 1e-3)) / Z90) ** 2)
        mats = []
        mirrored = obs @ MIRROR @ obs.T @ f.candidates[0] @ MIRROR
        for c in f.candidates:
            # The near-mirror (z, -y, -x) of the answer: its Euler axes trade with the signs of y and x turned.
            c_cov = RX_180 @ cov @ RX_180 if angle_deg(c, mirrored) < 1e-6 else cov
            j = obs @ euler_jacobian(obs.T @ c)
            mats.append(np.linalg.inv(j @ c_cov @ j.T))
        out.append(mats)
    return out


RIVAL_DISTINCT_DEG = 3.0  # a rival branch lies at least this far from the answer (beyond the frames' agreement)


def _rival_branch(
    frames: list[PassFrame],
    pool: list[int],
    used: list[int],
    sigma: Vec,
    agreeing: list[tuple[Vec, int]],
    mean: Vec,
    agree_deg: float,
) -> Vec | None:
    """The attitude of another branch that as many frames agree with as with ``mean``, or None.

    ``agreeing`` holds every candidate of the ``pool`` frames with how many of them agree with it.

    Where a pass's image plane barely turns, the near-mirror (a reflection through that plane)
    is nearly the same rotation for every frame, so every frame has a candidate on it as well as
    on the truth: the pass's geometry cannot tell them apart, only the frames' own choices can.
    The rival is the chordal mean of the used frames' candidates nearest the best-supported
    candidate at least ``max(RIVAL_DISTINCT_DEG, 2 agree_deg)`` from the answer.
    """
    apart = max(RIVAL_DISTINCT_DEG, 2.0 * agree_deg)
    own = sum(1 for j in pool if min(angle_deg(mean, d) for d in frames[j].candidates) <= agree_deg)
    others = [(c, n) for c, n in agreeing if angle_deg(c, mean) >= apart]
    if not others:
        return None
    c, n = max(others, key=lambda cn: cn[1])
    if n < own:
        return None
    near = [(j, min(frames[j].candidates, key=lambda d: angle_deg(c, d))) for j in used]
    near = [(j, d) for j, d in near if angle_deg(c, d) <= agree_deg]
    if len(near) < 2:
        return None
    return chordal_mean(np.array([d for _, d in near]), np.array([1.0 / sigma[j] ** 2 for j, _ in near]))


def information_mean(rotations: Vec, infos: Vec, start: Vec) -> Vec:
    """Return the rotation minimising sum log(R_k A^T)^T I_k log(R_k A^T) (Gauss-Newton from ``start``)."""
    a = start
    for _ in range(20):
        eps = np.array([so3_log(r @ a.T) for r in rotations])
        step = np.linalg.solve(np.sum(infos, axis=0), np.einsum("kij,kj->i", infos, eps))
        a = so3_exp(step) @ a
        if float(np.linalg.norm(step)) < 1e-12:
            break
    return np.asarray(a)


def fuse(
    frames: list[PassFrame],
    agree_deg: float = 3.0,
    reject_sigma: float = 4.0,
    reject_floor_deg: float = 2.0,
    spin_sigma: float = 4.0,
    min_rate_deg_s: float = 0.02,
    turning_chi2: float = 30.0,
    shared_fraction: float | None = None,
    sweep_sigma: float = SWEEP_SIGMA,
) -> Fused:
    """Fuse a pass's frames into one body-to-LVLH attitude (see the module's text).

    The steps: the best-supported candidate seeds a robust mean (``_seed``, ``_robust_mean``); its
    per-axis bounds (``_bounds``); a body rate from the residuals tells stable from drifting, and a
    turning model replaces the still answer where it explains the frames far better (``_turning``).
    """
    shared_fraction = SHARED_FRACTION if shared_fraction is None else shared_fraction
    if len(frames) < 2:
        raise ValueError("a pass needs at least two frames to fuse")
    sigma = np.array([max(f.bound_deg, 1e-3) / Z90 for f in frames])
    untrusted = {
        k: f"not trusted by its own checks ({f.why_not or 'see its quality'})"
        for k, f in enumerate(frames)
        if not f.trusted
    }
    pool = [k for k in range(len(frames)) if k not in untrusted]
    fallback = len(pool) < 2
    if fallback:  # too few trusted frames: fuse them all, and say so through their quality
        pool, untrusted = list(range(len(frames))), {}
    infos = _informations(frames) if all(f.los is not None and f.los_rate is not None for f in frames) else None
    seed, agreeing = _seed(frames, pool, agree_deg)
    limit = np.maximum(reject_sigma * sigma, reject_floor_deg)
    mean, rejected, chosen = _robust_mean(frames, pool, untrusted, seed, sigma, limit, infos)
    used = [k for k in range(len(frames)) if k not in rejected]
    rots = np.array([frames[k].candidates[chosen[k]] for k in used])
    w = 1.0 / sigma[used] ** 2
    euler = np.array(euler_from_matrix(mean))
    bound = _bounds(frames, used, chosen, mean, sigma, infos, shared_fraction)
    rival = _rival_branch(frames, pool, used, sigma, agreeing, mean, agree_deg)
    # 4. Stability: a body rate from the residual rotations over time (drift) ...
    times = np.array([frames[k].time_s for k in used])
    resid = np.array([so3_log(mean.T @ r) for r in rots])  # body frame, rad
    rate, rate_sigma = _rate(times, resid, w)
    speed = math.degrees(float(np.linalg.norm(rate)))
    z = float(np.linalg.norm(rate / np.maximum(rate_sigma, 1e-12))) / math.sqrt(3.0)
    stable = not (z > spin_sigma and speed > min_rate_deg_s)
    still = Fused(
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
        chosen=chosen,
        placed=np.array([frames[k].candidates[chosen[k]] for k in range(len(frames))]),
        rival=rival,
    )
    # ... and a turning model, where the frames carry their geometry and enough of them are trusted (a turning
    # fit to frames their own checks doubt says nothing, and costs seconds on a long pass).
    if fallback or len(pool) < 4 or any(frames[k].los is None or frames[k].los_rate is None for k in pool):
        return still
    return _turning(
        frames,
        pool,
        untrusted,
        still,
        sigma,
        limit,
        reject_sigma,
        spin_sigma,
        min_rate_deg_s,
        turning_chi2,
        sweep_sigma,
    )


def _seed(frames: list[PassFrame], pool: list[int], agree_deg: float) -> tuple[Vec, list[tuple[Vec, int]]]:
    """1. The best-supported candidate, which seeds the mean: frames with some candidate near it, and half as much
    again for each whose own answer is near it (the branch its brightness and Swin chose). Returns it and every
    candidate with how many frames agree with it."""
    best_support, seed = -1.0, frames[pool[0]].candidates[0]
    agreeing: list[tuple[Vec, int]] = []
    for k in pool:
        for c in frames[k].candidates:
            support, count = 0.0, 0
            for i in pool:
                near = [angle_deg(c, d) <= max(agree_deg, 0.0) for d in frames[i].candidates]
                hit = any(near)
                count += hit
                support += float(hit) + ANSWER_VOTE * float(near[0])
            agreeing.append((c, count))
            if support > best_support:
                best_support, seed = support, c
    return seed, agreeing


def _robust_mean(
    frames: list[PassFrame],
    pool: list[int],
    untrusted: dict[int, str],
    seed: Vec,
    sigma: Vec,
    limit: Vec,
    infos: list[list[Vec]] | None,
) -> tuple[Vec, dict[int, str], list[int]]:
    """2. From the seed, each frame's nearest candidate, the frames beyond their limit rejected, the weighted mean
    again, until nothing changes. Returns the mean, the rejected frames with why, and each frame's candidate."""
    mean = seed
    rejected: dict[int, str] = dict(untrusted)
    chosen = [0] * len(frames)
    for _ in range(20):
        chosen = [int(np.argmin([angle_deg(mean, c) for c in f.candidates])) for f in frames]
        dist = np.array([angle_deg(mean, f.candidates[j]) for f, j in zip(frames, chosen, strict=True)])
        new_rejected = {
            k: f"{dist[k]:.1f} deg from the pass's mean, over its limit of {limit[k]:.1f} deg"
            for k in pool
            if dist[k] > limit[k]
        }
        used = [k for k in pool if k not in new_rejected]
        if len(used) < 2:
            used = [pool[j] for j in np.argsort(dist[pool])[:2]]
            new_rejected = {k: v for k, v in new_rejected.items() if k not in used}
        new_rejected.update(untrusted)
        rots = np.array([frames[k].candidates[chosen[k]] for k in used])
        new_mean = chordal_mean(rots, 1.0 / sigma[used] ** 2)
        if infos is not None:
            new_mean = information_mean(rots, np.array([infos[k][chosen[k]] for k in used]), new_mean)
        done = new_rejected == rejected and angle_deg(new_mean, mean) < 1e-6
        mean, rejected = new_mean, new_rejected
        if done:
            break
    return mean, rejected, chosen


def _bounds(
    frames: list[PassFrame],
    used: list[int],
    chosen: list[int],
    mean: Vec,
    sigma: Vec,
    infos: list[list[Vec]] | None,
    shared_fraction: float,
) -> Vec:
    """3. The 90 % bound on each fused Euler angle (deg): the frames' information, scaled up by the scatter beyond
    it, where they carry their geometry; else their weighted scatter (Student's t); with the share of a single
    frame's error the frames have in common either way."""
    rots = np.array([frames[k].candidates[chosen[k]] for k in used])
    w = 1.0 / sigma[used] ** 2
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
    if infos is not None:  # the information's own bound, scaled up by the scatter beyond it
        h = np.sum([infos[k][chosen[k]] for k in used], axis=0)
        eps = [so3_log(frames[k].candidates[chosen[k]] @ mean.T) for k in used]
        chi2 = float(sum(e @ infos[k][chosen[k]] @ e for e, k in zip(eps, used, strict=True)))
        scale = math.sqrt(max(1.0, chi2 / max(3 * n - 3, 1)))
        j = np.linalg.inv(euler_jacobian(mean))
        single = np.mean([j @ np.linalg.inv(infos[k][chosen[k]]) @ j.T for k in used], axis=0)
        cov_e = j @ np.linalg.inv(h) @ j.T * scale**2 + shared_fraction * single
        return np.asarray(np.degrees(Z90 * np.sqrt(np.maximum(np.diag(cov_e), 0.0))))
    return np.asarray(np.sqrt(bound**2 + shared_fraction * float(np.median(sigma[used] * Z90)) ** 2))


def _turning(
    frames: list[PassFrame],
    pool: list[int],
    untrusted: dict[int, str],
    still: Fused,
    sigma: Vec,
    limit: Vec,
    reject_sigma: float,
    spin_sigma: float,
    min_rate_deg_s: float,
    turning_chi2: float,
    sweep_sigma: float,
) -> Fused:
    """5. The turning model fitted to the trusted frames (and every frame's sweep), kept where it explains them
    better than the still answer by over ``turning_chi2`` at a rate it resolves; else the still answer, with that
    gain."""
    mean = still.rotation
    turn = fit_turning([frames[k] for k in pool], mean, sweep_frames=frames, sweep_sigma=sweep_sigma)
    cap = reject_sigma**2
    still_terms = np.array([min((still.residual_deg[k] / sigma[k]) ** 2, cap) for k in pool])
    per_frame = still_terms - np.minimum(turn.chi2_terms, cap)  # each frame's part of the gain
    sweeps = Sweeps.of(frames, turn.reference_s, sweep_sigma)
    if sweeps is not None:  # and each sweep rate's: a still body's is the line of sight's own
        still_sweeps = np.minimum(sweeps.residuals(mean, np.zeros(3)) ** 2, cap)
        per_frame = np.concatenate([per_frame, still_sweeps - np.minimum(turn.sweep_terms, cap)])
    gain = float(np.sum(per_frame))
    spread_gain = gain - float(np.sum(np.sort(np.maximum(per_frame, 0.0))[-SPREAD_DROP:]))
    turn_speed = float(np.linalg.norm(turn.rate_deg_s))
    turning = (
        gain > turning_chi2
        and turn_speed > min_rate_deg_s
        and (turn_speed > spin_sigma * turn.speed_sigma_deg_s or spread_gain > turning_chi2)
    )
    if not turning:
        return replace(still, turning_chi2=gain)
    turn = widen_by_profile(turn, [frames[k] for k in pool], frames, sweep_sigma)
    resid_t = dict(zip(pool, (float(r) for r in turn.residual_deg), strict=True))
    rejected_t = dict(untrusted)
    for k in pool:
        if resid_t[k] > limit[k]:
            rejected_t[k] = f"{resid_t[k]:.1f} deg from the turning model, over its limit of {limit[k]:.1f} deg"
    used_t = [k for k in range(len(frames)) if k not in rejected_t]
    placed_t, chosen_t = place_turning(frames, turn.rotation, turn.rate_deg_s, turn.reference_s)
    return Fused(
        rotation=turn.rotation,
        euler_zyx_deg=tuple(float(a) for a in euler_from_matrix(turn.rotation)),  # type: ignore[arg-type]
        uncertainty_deg=turn.uncertainty_deg,
        used=used_t,
        rejected=rejected_t,
        branch_changed=[pool[j] for j, c in enumerate(turn.chosen) if c != 0 and pool[j] in used_t],
        rate_deg_s=turn.rate_deg_s,
        rate_sigma_deg_s=turn.rate_sigma_deg_s,
        stable=False,
        residual_deg={**still.residual_deg, **resid_t},
        turning_chi2=gain,
        reference_s=turn.reference_s,
        chosen=chosen_t,
        placed=placed_t,
        rival=None,
    )


@dataclass(frozen=True)
class Turning:
    """A constant-rate fit of a pass: body to LVLH at the frames' middle time, body rate, and how well it fits."""

    rotation: Vec
    rate_deg_s: Vec
    rate_sigma_deg_s: Vec
    speed_sigma_deg_s: float
    uncertainty_deg: tuple[float, float, float]
    residual_deg: Vec
    chi2_terms: Vec
    chosen: list[int]
    reference_s: float
    scale: float = 1.0  # the fit's scatter beyond the frames' bounds (chi-square per degree of freedom, at least 1)
    sweep_terms: Vec = field(default_factory=lambda: np.zeros(0))  # each measured sweep rate's chi-square term


@dataclass(frozen=True)
class Sweeps:
    """The frames' measured sweep rates (``PassFrame.sweep_rad_s``) as the turning fit reads them."""

    tau: Vec  # s from the fit's reference time
    los: Vec  # [M, 3] LVLH
    los_rate: Vec  # [M, 3] LVLH, 1/s
    rate: Vec  # measured, rad/s
    sigma: Vec  # 1-sigma, rad/s

    @classmethod
    def of(cls, frames: list[PassFrame], reference_s: float, sigma_fraction: float = SWEEP_SIGMA) -> Sweeps | None:
        """The sweeps of those ``frames`` that carry one and their line of sight; None where none does."""
        fs = [f for f in frames if f.sweep_rad_s is not None and f.los is not None and f.los_rate is not None]
        if not fs:
            return None
        rate = np.array([f.sweep_rad_s for f in fs], float)
        given = np.array([f.sweep_sigma_rad_s or 0.0 for f in fs], float)
        return cls(
            tau=np.array([f.time_s for f in fs], float) - reference_s,
            los=np.array([f.los for f in fs], float),
            los_rate=np.array([f.los_rate for f in fs], float),
            rate=rate,
            sigma=np.maximum(np.maximum(sigma_fraction * rate, given), 1e-9),
        )

    def residuals(self, a_ref: Vec, w_body: Vec) -> Vec:
        """(predicted - measured) / sigma for a body that is ``a_ref`` at tau 0 and turns at ``w_body`` (rad/s)."""
        return (sweep_rates(a_ref, w_body, self.tau, self.los, self.los_rate) - self.rate) / self.sigma


def sweep_sigmas(rates: Vec, before: Vec, centre: Vec, after: Vec, fraction: float = SWEEP_SIGMA) -> Vec:
    """1-sigma errors (rad/s) of measured sweep rates ``rates``, modelled by the rate at the frame's time.

    A frame measures the mean rate over its integration, the model gives it at the frame's time;
    they part by about a sixth of the rate's second difference over the integration
    (``before``, ``centre``, ``after``: a still target's sweep rates half an integration
    either side and at the time), which matters at a pass's ends, where the line of sight
    crawls and one frame integrates for minutes. Added in quadrature to ``fraction``.
    """
    kappa = np.abs(before + after - 2.0 * centre) / (6.0 * np.maximum(centre, 1e-12))
    return np.asarray(rates * np.sqrt(fraction**2 + kappa**2))


def sweep_rates(a_ref: Vec, w_body: Vec, tau: Vec, los: Vec, los_rate: Vec) -> Vec:
    """The line of sight's angular rate relative to the body (rad/s) at each tau: |its LVLH rate less spin x los|
    across the line of sight, the body being ``a_ref`` at tau 0 and turning at ``w_body`` (body axes, rad/s).

    ``a_ref`` [..., 3, 3] and ``w_body`` [..., 3] may carry leading axes (several models at once); the
    answer is then [..., M] for the M taus, lines of sight [M, 3] and their rates [M, 3].
    """
    a_ref, w = np.asarray(a_ref, float), np.asarray(w_body, float)
    rot = a_ref[..., None, :, :] @ so3_exp(np.asarray(tau, float)[:, None] * w[..., None, :])
    spin = np.einsum("...mij,...j->...mi", rot, w)
    rel = los_rate - np.cross(spin, los)
    rel = rel - np.sum(rel * los, axis=-1, keepdims=True) * los
    return np.asarray(np.linalg.norm(rel, axis=-1))


def observation_in_lvlh(los: Vec, los_rate: Vec, spin_lvlh: Vec | None = None) -> Vec:
    """Return observation axes in LVLH [N, 3, 3] (columns): X the line of sight, Y its rate relative to the body.

    ``spin_lvlh`` (rad/s, [N, 3]) is the body's rotation in LVLH; the line of sight's rate as
    the body sees it is its LVLH rate less spin x line of sight (``planner.frames``: the
    same axes for a body still in LVLH).
    """
    rate = los_rate if spin_lvlh is None else los_rate - np.cross(spin_lvlh, los)
    rate = rate - np.sum(rate * los, axis=-1, keepdims=True) * los
    y = rate / np.linalg.norm(rate, axis=-1, keepdims=True)
    return np.stack([los, y, np.cross(los, y)], axis=-1)


def turning_prediction(a_ref: Vec, w_body: Vec, tau: Vec, los: Vec, los_rate: Vec) -> Vec:
    """Return each frame's body-to-observation rotation [N, 3, 3] for a body turning at w (rad/s, body axes).

    The body is ``a_ref`` (body to LVLH) at tau = 0 and ``a_ref exp(w tau)`` at tau (s).
    """
    a = a_ref @ so3_exp(np.outer(tau, w_body))
    obs = observation_in_lvlh(los, los_rate, a @ w_body)
    return np.asarray(np.swapaxes(obs, -1, -2) @ a)


def place_turning(frames: list[PassFrame], rotation: Vec, rate_deg_s: Vec, reference_s: float) -> tuple[Vec, list[int]]:
    """Each frame's answer placed in LVLH as a turning answer sees it, and which candidate that is.

    A frame's candidates come placed as if the body were still (``PassFrame.candidates``); a
    turning body's image plane is turned by its rate (``observation_in_lvlh``), so each frame is
    placed again through the model's observation frame at its time, and takes the candidate
    nearest the model's attitude then (``rotation`` at ``reference_s``, turning at
    ``rate_deg_s`` about body axes). Frames without a line of sight keep the still placement.
    """
    w = np.radians(np.asarray(rate_deg_s, float))
    placed, chosen = [], []
    for f in frames:
        a = rotation @ so3_exp((f.time_s - reference_s) * w)
        cands = f.candidates
        if f.los is not None and f.los_rate is not None:
            still = observation_in_lvlh(f.los[None], f.los_rate[None])[0]
            turned = observation_in_lvlh(f.los[None], f.los_rate[None], (a @ w)[None])[0]
            cands = turned @ still.T @ f.candidates
        j = int(np.argmin([angle_deg(a, c) for c in cands]))
        placed.append(cands[j])
        chosen.append(j)
    return np.array(placed), chosen


def fit_turning(
    frames: list[PassFrame],
    start: Vec,
    max_rate_deg_s: float = 1.2,
    grid_deg_s: float = 0.12,
    sweep_frames: list[PassFrame] | None = None,
    sweep_sigma: float = SWEEP_SIGMA,
) -> Turning:
    """Fit a constant body rate to a pass's frames (each with ``los`` and ``los_rate``); see the module's text.

    ``sweep_frames`` (any of the pass's frames, read or not) add their measured sweep rates.
    """
    from scipy.optimize import least_squares

    times = np.array([f.time_s for f in frames], float)
    reference = 0.5 * float(times.min() + times.max())
    los, los_rate, tau, sigma, measured = _turning_inputs(frames, reference)
    sweeps = Sweeps.of(sweep_frames or [], reference, sweep_sigma)
    # Seeds: a grid over w, each scored by the lines of sight alone (the body-frame line of
    # sight of frame k, X_k, is exp(-w tau) a^T los_k: Wahba's problem for a, per w).
    x_body = np.array([m[0][0] for m in measured])  # first row of R: the line of sight in body axes
    g = np.radians(np.arange(-max_rate_deg_s, max_rate_deg_s + 1e-9, grid_deg_s))
    grid = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    u = np.einsum("gnij,nj->gni", so3_exp(grid[:, None, :] * tau[None, :, None]), x_body)
    wts = 1.0 / sigma**2
    b = np.einsum("n,ni,gnj->gij", wts, los, u)
    uu, _, vt = np.linalg.svd(b)
    d = np.sign(np.linalg.det(uu @ vt))
    uu[:, :, 2] *= d[:, None]
    a_grid = uu @ vt
    cost = np.einsum("n,gni->g", wts, (los[None] - np.einsum("gij,gnj->gni", a_grid, u)) ** 2)
    if sweeps is not None:  # and by the sweep rates each (a, w) predicts
        predicted = sweep_rates(a_grid, grid, sweeps.tau, sweeps.los, sweeps.los_rate)  # [grid, sweeps]
        cost += np.sum(np.minimum(((predicted - sweeps.rate) / sweeps.sigma) ** 2, TERM_CAP), 1)
    seeds = [(start, np.zeros(3))] + [(a_grid[i], grid[i]) for i in np.argsort(cost)[:6]]

    def residuals(p: Vec, a0: Vec, pick: list[int]) -> Vec:
        pred = turning_prediction(a0 @ so3_exp(p[:3]), p[3:], tau, los, los_rate)
        picked = np.array([measured[k][pick[k]] for k in range(len(frames))])
        r = (so3_logs(picked @ np.swapaxes(pred, -1, -2)) / sigma[:, None]).ravel()
        if sweeps is not None:
            r = np.concatenate([r, sweeps.residuals(a0 @ so3_exp(p[:3]), p[3:])])
        return np.asarray(r)

    n_att = 3 * len(frames)

    def robust_chi2(fun: Vec) -> float:  # capped per frame: a frame's three attitude terms, a sweep's one
        return capped_chi2((fun[:n_att].reshape(-1, 3) ** 2).sum(1)) + capped_chi2(fun[n_att:] ** 2)

    def nearest(a0: Vec, p: Vec) -> list[int]:
        pred = turning_prediction(a0 @ so3_exp(p[:3]), p[3:], tau, los, los_rate)
        return [int(np.argmin([angle_deg(m, pred[k]) for m in measured[k]])) for k in range(len(frames))]

    best = None
    for a0, w0 in seeds:
        p = np.concatenate([np.zeros(3), w0])
        pick = nearest(a0, p)
        for _ in range(3):
            sol = least_squares(
                residuals, p, args=(a0, pick), loss="soft_l1", f_scale=4.0, x_scale=1.0, max_nfev=MAX_NFEV
            )
            p = sol.x
            new_pick = nearest(a0, p)
            if new_pick == pick:
                break
            pick = new_pick
        robust = robust_chi2(sol.fun)
        if best is None or robust < best[0]:
            best = (robust, a0, p, pick, sol)
    assert best is not None
    _, a0, p, pick, sol = best
    a_ref = a0 @ so3_exp(p[:3])
    pred = turning_prediction(a_ref, p[3:], tau, los, los_rate)
    resid = np.array([angle_deg(measured[k][pick[k]], pred[k]) for k in range(len(frames))])
    terms = (resid / np.degrees(sigma)) ** 2
    sweep_terms = np.zeros(0) if sweeps is None else sweeps.residuals(a_ref, p[3:]) ** 2
    try:
        cov = np.linalg.inv(sol.jac.T @ sol.jac)
    except np.linalg.LinAlgError:
        cov = np.full((6, 6), np.inf)
    dof = len(frames) * 3 + len(sweep_terms) - 6
    scale = max(1.0, (capped_chi2(terms) + capped_chi2(sweep_terms)) / max(dof, 1))
    cov = cov * scale
    speed = float(np.linalg.norm(p[3:]))
    w_hat = p[3:] / max(speed, 1e-12)
    speed_sigma = math.degrees(math.sqrt(max(float(w_hat @ cov[3:, 3:] @ w_hat), 0.0)))
    rate_sigma = np.degrees(np.sqrt(np.maximum(np.diag(cov[3:, 3:]), 0.0)))
    # Per Euler axis: the attitude's covariance (rotation vector, body) through the Euler map.
    e0 = np.array(euler_from_matrix(a_ref))
    jac = np.empty((3, 3))
    for i in range(3):
        dv = np.zeros(3)
        dv[i] = 1e-6
        jac[:, i] = ((np.array(euler_from_matrix(a_ref @ so3_exp(dv))) - e0 + 180.0) % 360.0 - 180.0) / 1e-6
    cov_e = jac @ cov[:3, :3] @ jac.T
    bound = np.array([Z90 * math.sqrt(max(c, 0.0)) for c in np.diag(cov_e)])
    return Turning(
        rotation=a_ref,
        rate_deg_s=np.degrees(p[3:]),
        rate_sigma_deg_s=rate_sigma,
        speed_sigma_deg_s=speed_sigma,
        uncertainty_deg=tuple(float(b) for b in bound),  # type: ignore[arg-type]
        residual_deg=resid,
        chi2_terms=terms,
        chosen=pick,
        reference_s=reference,
        scale=scale,
        sweep_terms=sweep_terms,
    )


def widen_by_profile(
    turn: Turning,
    frames: list[PassFrame],
    sweep_frames: list[PassFrame] | None = None,
    sweep_sigma: float = SWEEP_SIGMA,
) -> Turning:
    """Return ``turn`` with its speed's and attitude's uncertainty taken from the speed's profile where that is wider.

    The rate's standard error from the curvature at the minimum holds for a long arc; over a
    short one (``speed_profile``) the chi-square stays low far from it. The speed's sigma
    becomes the 90 % profile interval's half-width over 1.645 (each rate axis widened in
    proportion), and every Euler bound covers the attitudes the profile reaches within it.
    """
    speed = float(np.linalg.norm(np.radians(turn.rate_deg_s)))
    if speed < 1e-9:
        return turn
    los, los_rate, tau, sigma, measured = _turning_inputs(frames, turn.reference_s)
    sweeps = Sweeps.of(sweep_frames or [], turn.reference_s, sweep_sigma)
    sides = speed_profile(
        measured, turn.chosen, turn.rotation, np.radians(turn.rate_deg_s), tau, sigma, los, los_rate, sweeps
    )
    best = capped_chi2(turn.chi2_terms) + capped_chi2(turn.sweep_terms)
    limit = CHI2_90_1DOF * turn.scale  # the 90 % interval (scaled by the fit's own scatter)
    centre = math.degrees(speed)
    reach = [
        _crossing(centre, np.degrees([q for q, _, _ in side]), np.array([c - best for _, c, _ in side]), limit)
        for side in sides
    ]
    profile_sigma = max(abs(r - centre) for r in reach) / Z90
    speed_sigma, rate_sigma = turn.speed_sigma_deg_s, turn.rate_sigma_deg_s
    if profile_sigma > speed_sigma:
        extra = math.sqrt(profile_sigma**2 - speed_sigma**2)
        rate_sigma = np.sqrt(rate_sigma**2 + (np.abs(turn.rate_deg_s) / centre * extra) ** 2)
        speed_sigma = profile_sigma
    e0 = np.array(euler_from_matrix(turn.rotation))
    bound = np.array(turn.uncertainty_deg)
    for _, c, a in (point for side in sides for point in side):
        if c - best <= limit:
            bound = np.maximum(bound, np.abs((np.array(euler_from_matrix(a)) - e0 + 180.0) % 360.0 - 180.0))
    return replace(
        turn,
        speed_sigma_deg_s=speed_sigma,
        rate_sigma_deg_s=rate_sigma,
        uncertainty_deg=tuple(float(b) for b in bound),  # type: ignore[arg-type]
    )


CHI2_90_1DOF = 2.705543454095404  # the 90 % quantile of chi-square with one degree of freedom
# The speeds (times the fitted one) the profile visits, each side walked outward from the fitted speed.
PROFILE_SLOWER = (0.8, 0.6, 0.45, 0.3)
PROFILE_FASTER = (1.25, 1.6, 2.2, 3.0)
# Function evaluations a turning solve may take from one seed: from a good seed it converges in 7 to 30; one
# that wanders takes up to 600 and ends elsewhere (measured on bench.passes' spinning passes).
MAX_NFEV = 80
TERM_CAP = 16.0  # a frame's chi-square term in the turning fit is capped here, so outliers do not decide


def capped_chi2(terms: Vec) -> float:
    """The sum of per-frame chi-square terms, each capped at ``TERM_CAP``."""
    return float(np.sum(np.minimum(terms, TERM_CAP)))


def _turning_inputs(frames: list[PassFrame], reference_s: float) -> tuple[Vec, Vec, Vec, Vec, list[Vec]]:
    """What the turning fit reads from the frames: lines of sight and their rates (LVLH), times from
    ``reference_s``, 1-sigma errors (rad), and each frame's candidates as body-to-observation rotations
    (the still placement undone)."""
    los = np.array([f.los for f in frames], float)
    los_rate = np.array([f.los_rate for f in frames], float)
    tau = np.array([f.time_s for f in frames], float) - reference_s
    sigma = np.radians(np.array([max(f.bound_deg, 1e-3) / Z90 for f in frames]))
    still = observation_in_lvlh(los, los_rate)
    measured = [np.swapaxes(still[k], 0, 1)[None] @ f.candidates for k, f in enumerate(frames)]
    return los, los_rate, tau, sigma, measured


def speed_profile(
    measured: list[Vec],
    pick: list[int],
    a_ref: Vec,
    w: Vec,
    tau: Vec,
    sigma: Vec,
    los: Vec,
    los_rate: Vec,
    sweeps: Sweeps | None = None,
) -> list[list[tuple[float, float, Vec]]]:
    """The turning model refitted at other speeds: for the slower side, then the faster, (speed rad/s, capped
    chi-square, attitude) at each of its factors, outward (``_turning_inputs`` gives the arguments).

    At each speed the attitude and the rate's direction are fitted again (from the neighbouring
    speed's answer, outward from the fitted one). Over a short arc the frames fix the line of
    sight's track in the body to first order, and one combination of rate and attitude is left
    free: the chi-square then barely rises along it, however sharp its curvature at the minimum.
    """
    from scipy.optimize import least_squares

    speed = float(np.linalg.norm(w))
    u = w / speed
    e1 = np.cross(u, [1.0, 0.0, 0.0] if abs(u[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(u, e1)

    def rate(q: Vec, s: float) -> Vec:
        d = u + q[3] * e1 + q[4] * e2
        return np.asarray(s * d / np.linalg.norm(d))

    n_att = 3 * len(measured)

    def residuals(q: Vec, s: float) -> Vec:
        pred = turning_prediction(a_ref @ so3_exp(q[:3]), rate(q, s), tau, los, los_rate)
        r = [so3_log(measured[k][pick[k]] @ pred[k].T) / sigma[k] for k in range(len(measured))]
        if sweeps is not None:
            r.append(sweeps.residuals(a_ref @ so3_exp(q[:3]), rate(q, s)))
        return np.concatenate(r)

    sides = []
    for factors in (PROFILE_SLOWER, PROFILE_FASTER):
        q, side = np.zeros(5), []
        for f in factors:
            sol = least_squares(residuals, q, args=(f * speed,), loss="soft_l1", f_scale=4.0)
            q = sol.x
            chi2 = capped_chi2((sol.fun[:n_att].reshape(-1, 3) ** 2).sum(1)) + capped_chi2(sol.fun[n_att:] ** 2)
            side.append((f * speed, chi2, a_ref @ so3_exp(q[:3])))
        sides.append(side)
    return sides


def _crossing(centre: float, speeds: Vec, d_chi2: Vec, limit: float) -> float:
    """How far out from ``centre`` (Delta chi-square 0) the profile stays within ``limit``: its outermost point
    within it, interpolated linearly toward the next one out (the profile need not rise steadily)."""
    s = np.concatenate([[centre], speeds])
    c = np.concatenate([[0.0], np.maximum(d_chi2, 0.0)])
    j = int(np.flatnonzero(c <= limit)[-1])
    if j == len(s) - 1:
        return float(s[j])
    return float(s[j] + (limit - c[j]) / max(c[j + 1] - c[j], 1e-12) * (s[j + 1] - s[j]))


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
