"""A pass's frames fused into one attitude in the target's orbital frame (LVLH).

Each frame's checked answer and alternatives are placed in LVLH through the scene
(``Scene.placements``), then ``inference.fusion.fuse`` finds the attitude they share (still)
or the turning that explains them; a still answer is then fitted to all the frames'
silhouettes at once (``inference.fit.fit_common``). Where the frames as they are make no
trusted still pass, the untrusted frames are read again mirrored in cross-range (a target
turning against the line of sight faster than it sweeps) and the better-supported fusion is kept.
The answer is a ``PassAttitude``; the service and the command line write it as JSON.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from datetime import datetime, timedelta
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from inference.checked import IMAGE, SILHOUETTE
from inference.fusion import Fused, PassFrame, fuse, sweep_rates, sweep_sigmas
from inference.rotations import MIRROR, euler_from_matrix, reversed_reading, rotation_matrix
from scene.errors import SceneError
from scene.geometry import Placements, Scene
from scene.reading import Progress, read_frames

if TYPE_CHECKING:  # the fit and the checks load numba's compiled renderer: imported where they run
    from inference.checked import Checked
    from inference.fit import CommonFit, Renderer
    from inference.runtime import Estimator
    from inference.trust import Checker, ImageRefinement

Vec = NDArray[np.float64]

MIN_TRUSTED_FRAMES = 3  # a pass answer rests on at least this many trusted frames that agree
NO_BOUND_DEG = 10.0  # a frame whose fit bounds nothing counts as this uncertain
REVERSED_NOTE = (
    "read reversed in cross-range (the target turns against the line of sight faster than it sweeps): "
    "answered from the mirrored frame"
)

Sweeps = list[tuple[float, float]]  # each frame's measured sweep rate (rad/s) and integration time (s)


@dataclass(frozen=True)
class FusedFrame:
    """One frame's part in a pass: its own checked answer, the branch the fusion took, and its sweep.

    ``attitude_lvlh``: that branch, body to LVLH, as the answer places it. Sweep rates in rad/s:
    measured (None without integration times), its 1-sigma error, and the answer's prediction.
    """

    index: int
    name: str
    observed_at: datetime
    checked: Checked
    attitude_lvlh: Vec
    branch: str
    used: bool
    rejected_because: str | None
    residual_deg: float
    sweep_rad_s: float | None
    sweep_sigma_rad_s: float | None
    sweep_model_rad_s: float


@dataclass(frozen=True)
class PassAttitude:
    """A pass's fused attitude: body to LVLH and to J2000 (GCRS) at ``attitude_at``, its bounds and its verdict.

    ``stable``: True still in LVLH, False turning at ``rate_deg_s`` (body axes), None undecided
    (fewer than ``MIN_TRUSTED_FRAMES`` trusted frames agree; ``trusted`` is then False).
    ``alternative_lvlh``: another attitude as many frames agree with (the near-mirror of a pass
    whose image plane barely turns), or None.
    """

    trusted: bool
    frames: list[FusedFrame]
    attitude_lvlh: Vec
    attitude_j2000: Vec
    attitude_at: datetime
    uncertainty_deg: tuple[float, ...]
    alternative_lvlh: Vec | None
    used: int
    rejected: int
    stable: bool | None
    rate_deg_s: Vec
    rate_sigma_deg_s: Vec
    turning_chi2: float | None
    common_fit: CommonFit | None
    stability: str
    # Which fit gave a still pass's attitude: its frames' silhouettes, or their images refined together under the
    # set's map (``image_fit``: the frames, the objective per pixel at the start and after, how far it moved).
    refined_on: str = SILHOUETTE
    image_fit: dict[str, float] | None = None

    def trusted_used(self, checks: Sequence[Checked]) -> int:
        """How many of the frames used are usable by their own checks (``usable``)."""
        return sum(1 for f in self.frames if f.used and usable(checks[f.index]))


@dataclass(frozen=True)
class FusedPass:
    """A pass read and fused: the answer, the checks it rests on, seconds per frame of each stage, both stages' times."""

    attitude: PassAttitude
    checks: list[Checked]
    timings_s: dict[str, float]
    fit_s: float
    fuse_s: float


def pass_span(observed_at: Sequence[datetime], sweeps: Sweeps | None) -> tuple[datetime, datetime]:
    """Return the span a pass's scene must cover: its frames' times, and half an integration beyond each."""
    if sweeps is None:
        return min(observed_at), max(observed_at)
    half = [timedelta(seconds=0.5 * t) for _, t in sweeps]
    return min(t - h for t, h in zip(observed_at, half, strict=True)), max(
        t + h for t, h in zip(observed_at, half, strict=True)
    )


# The fastest line-of-sight sweep through a target a pass can hold: a LEO pass turns it at most ~2 deg/s, a fast
# tumbler some tens; beyond this a frame's integration time is a mistake, not a measurement.
MAX_SWEEP_DEG_S = 90.0


def sweeps_from(
    integration_s: Sequence[float] | None, aperture_deg: float | None, n_frames: int, default_aperture_deg: float | None
) -> Sweeps | None:
    """Each frame's measured sweep rate (rad/s; the angle its sub-aperture integrates over its integration time),
    with that integration time (s).

    A radar that forms every frame of ``aperture_deg`` (the angle the line of sight sweeps in the
    target over the frame; its cross-range cell is lambda / (2 aperture)) over ``integration_s``
    measured how fast the line of sight turns relative to the body. That is the line of sight's
    own rate for a target still in LVLH, and differs from it by the spin for a turning one
    (``inference.fusion.sweep_rates``). ``default_aperture_deg`` stands in for a missing
    ``aperture_deg`` (None: there is none, and one must be sent). None without ``integration_s``.
    """
    if integration_s is None or len(integration_s) == 0:
        if aperture_deg is not None:
            raise SceneError(["integration_s"], "aperture_deg needs integration_s: send each frame's integration time")
        return None
    if len(integration_s) != n_frames:
        raise SceneError(
            ["integration_s"], f"{len(integration_s)} integration times for {n_frames} frames: send one per frame"
        )
    for k, t in enumerate(integration_s):
        if not (isinstance(t, int | float) and math.isfinite(t) and 0.0 < t <= 3600.0):
            raise SceneError(["integration_s", k], f"frame {k}'s integration time must be in (0, 3600] s, not {t!r}")
    aperture = default_aperture_deg if aperture_deg is None else aperture_deg
    if aperture is None:
        raise SceneError(
            ["aperture_deg"],
            "the frames' cells are not the models': send aperture_deg, the angle each frame integrates "
            "(lambda / (2 x cross-range cell), in deg)",
        )
    if not (math.isfinite(aperture) and 0.0 < aperture <= 30.0):
        raise SceneError(["aperture_deg"], f"aperture_deg must be in (0, 30] deg, not {aperture!r}")
    for k, t in enumerate(integration_s):
        rate = aperture / float(t)
        if rate > MAX_SWEEP_DEG_S:  # 1e-300 s was stored as 5.1e300 deg/s
            raise SceneError(
                ["integration_s", k],
                f"frame {k}'s {aperture:g} deg over {t!r} s is a sweep of {rate:.3g} deg/s; the line of sight turns "
                f"through a target at most {MAX_SWEEP_DEG_S:g} deg/s (a fast tumble): check the integration time",
            )
    return [(math.radians(aperture) / float(t), float(t)) for t in integration_s]


def usable(checked: Checked) -> bool:
    """Whether a pass may use a frame: trusted, or doubted only because another attitude fits as well.

    A lookalike is what a pass resolves (the other frames pick the branch), so such a frame goes
    into the fusion with its alternatives; a frame that fails any other check does not.
    """
    from inference.trust import AMBIGUOUS

    q = checked.quality
    return bool(q.trusted or (checked.alternatives and q.reasons and all(r.endswith(AMBIGUOUS) for r in q.reasons)))


def recheck_reversed(*, est: Estimator, checker: Checker, frames: Vec, checks: list[Checked]) -> list[Checked]:
    """Give each untrusted frame a second reading, mirrored in cross-range; keep it where its checks trust it.

    A radar forms the image from the line of sight's motion relative to the body. A target
    turning against that motion faster than the line of sight sweeps reverses the cross-range
    axis: the frame shows the body turned by 180 deg about the line of sight, outside the
    networks' range. Mirrored back, it reads as an ordinary frame R', and the body is Rx(180) R'.
    ``fuse_pass`` asks for it only when the frames as they are do not make a trusted, still
    pass; single frames are never given this reading (a flipped single frame must be flagged),
    but a pass can afford it, since the fusion's turning model predicts which way each frame reads.
    """
    from inference.checked import Alternative, Checked, Quality

    todo = [k for k, c in enumerate(checks) if not c.quality.trusted]
    if not todo:
        return checks
    # y -> -y about the centre column n/2: column j -> (n - j) mod n
    mirrored = np.ascontiguousarray(np.roll(frames[todo][:, :, ::-1], 1, axis=2))
    res = est.estimate(mirrored)
    out = list(checks)

    again = checker.check_many(  # no library search, as for the pass's other frames
        mirrored, res.enhanced, res.angles_deg if checker.networks else None, search=False
    )
    for k, c in zip(todo, again, strict=True):
        if not c.quality.trusted:
            continue
        q = c.quality
        out[k] = Checked(
            angles_deg=np.array(reversed_reading(c.angles_deg)),
            network_deg=None if c.network_deg is None else np.array(reversed_reading(c.network_deg)),
            refined=c.refined,
            quality=Quality(q.silhouette_iou, q.uncertainty_deg, True, [REVERSED_NOTE]),
            alternatives=[
                Alternative(reversed_reading(a.angles_deg), a.silhouette_iou, a.fit_gap, a.distance_deg, a.start)
                for a in c.alternatives
            ],
            features={**c.features, "reversed": 1.0},
            refined_on=c.refined_on,
            image_fit=c.image_fit,
        )
    return out


def fit_and_fuse(
    *,
    est: Estimator,
    checker: Checker,
    frames: NDArray[np.float32],
    scene: Scene,
    observed_at: list[datetime],
    names: list[str],
    sweeps: Sweeps | None = None,
    preprocess_s: float = 0.0,
    progress: Progress | None = None,
    cancelled: Callable[[], bool] | None = None,
) -> FusedPass:
    """Read every frame of a pass (the networks, then the fit), place each and fuse them.

    Where the calibration covers the library search's answers (``Calibration.covers_library``: frames over all of
    SO(3)), a frame whose network answer does not fit is searched as a single frame is, so the pass's frames
    outside the networks' cube are read and fused too; otherwise the search is skipped (its answers would all be
    flagged, and the other frames stand in: design/measurements.md, "A pass skips the library search").

    ``frames``: the pass's frames as the models take them [N, H, W]; ``scene``: over the pass's span
    (``pass_span``); ``sweeps``: each frame's measured sweep rate and integration time (``sweeps_from``), or None.
    ``progress(stage, done, total)``: "estimated", "fitted" per frame, then "fused" when the answer is made.
    ``cancelled()``: asked before each frame's fit; yes stops the work (``inference.errors.Cancelled``).
    """
    t0 = time.perf_counter()
    read = read_frames(
        est,
        checker,
        frames,
        search=checker.calibration.covers_library,
        preprocess_s=preprocess_s,
        progress=progress,
        cancelled=cancelled,
    )
    t1 = time.perf_counter()
    attitude, checks = fuse_pass(
        est=est,
        checker=checker,
        frames=read.frames,
        checks=read.checks,
        scene=scene,
        observed_at=observed_at,
        names=names,
        sweeps=sweeps,
        enhanced=read.network.enhanced,
    )
    if progress is not None:
        progress("fused", len(frames), len(frames))
    return FusedPass(attitude, checks, read.timings_s, t1 - t0 + preprocess_s, time.perf_counter() - t1)


def fuse_pass(
    *,
    est: Estimator,
    checker: Checker,
    frames: Vec | NDArray[np.float32],
    checks: list[Checked],
    scene: Scene,
    observed_at: list[datetime],
    names: list[str],
    sweeps: Sweeps | None = None,
    enhanced: Vec | NDArray[np.float32] | None = None,
) -> tuple[PassAttitude, list[Checked]]:
    """Fuse a checked pass; where it is not a trusted still one, re-read its untrusted frames mirrored and fuse again.

    Returns the answer with the more trusted frames used, and the checks it rests on. ``enhanced``: the
    frames' silhouettes (UNet++'s), which a still answer is fitted to all at once (``fit_common``); a frame
    re-read mirrored takes no part in that. Every placement comes from ``scene``, placed once.
    """
    placed = scene.placements(observed_at)
    # Both fusions share the frames' placements and the sweeps' errors (the geometry, not the readings).
    sigma = None if sweeps is None else sweep_errors(scene, observed_at, placed, sweeps)

    def fused(cs: list[Checked]) -> PassAttitude:
        return fuse_frames(
            scene=scene,
            checks=cs,
            observed_at=observed_at,
            names=names,
            placed=placed,
            sweeps=sweeps,
            sweep_sigma=sigma,
            silhouettes=None
            if enhanced is None
            else [e if c is o else None for e, c, o in zip(enhanced, cs, checks, strict=True)],
            renderer=None if enhanced is None else checker.common_renderer,
            images=frames,
            image=checker.image,
        )

    first = fused(checks)
    if first.trusted and first.stable:
        return first, checks
    again = recheck_reversed(est=est, checker=checker, frames=np.asarray(frames), checks=checks)
    if again is checks:
        return first, checks
    second = fused(again)
    if second.trusted_used(again) > first.trusted_used(checks):
        return second, again
    return first, checks


def sweep_errors(scene: Scene, observed_at: Sequence[datetime], placed: Placements, sweeps: Sweeps) -> Vec:
    """Each measured sweep's 1-sigma error (rad/s, ``inference.fusion.sweep_sigmas``): a still target's sweeps
    half an integration before, at and after each frame's time (``placed``: the frames' placements then)."""
    half = [timedelta(seconds=0.5 * t) for _, t in sweeps]
    before = scene.placements([t - h for t, h in zip(observed_at, half, strict=True)])
    after = scene.placements([t + h for t, h in zip(observed_at, half, strict=True)])
    r0, r1, r2 = _model_sweeps(np.eye(3), np.zeros(3), np.zeros(len(sweeps)), [before, placed, after])
    return sweep_sigmas(np.array([r for r, _ in sweeps]), r0, r1, r2)


def _model_sweeps(rotation: Vec, w_body: Vec, tau: Vec, placements: list[Placements]) -> list[Vec]:
    """A model's sweep rates (rad/s, ``sweep_rates``) at times ``tau``, for each of the frames' placements."""
    return [sweep_rates(rotation, w_body, tau, p.los_lvlh, p.los_rate_lvlh) for p in placements]


def fuse_frames(
    *,
    scene: Scene,
    checks: list[Checked],
    observed_at: list[datetime],
    names: list[str],
    placed: Placements | None = None,
    sweeps: Sweeps | None = None,
    sweep_sigma: Vec | None = None,
    silhouettes: Sequence[Vec | NDArray[np.float32] | None] | None = None,
    renderer: Renderer | None = None,
    images: Vec | NDArray[np.float32] | None = None,
    image: ImageRefinement | None = None,
) -> PassAttitude:
    """Place each checked frame's answer and alternatives in LVLH (``scene.placements``, unless ``placed`` gives
    them already), fuse them, and describe the pass. ``sweeps``: each frame's measured sweep rate (rad/s)
    and integration time (``sweeps_from``), or None; ``sweep_sigma`` their errors (``sweep_errors``, computed
    here unless given). ``silhouettes`` (each frame's, or None) and ``renderer``: a still answer is then
    fitted to the used frames' silhouettes all at once (``inference.fit.fit_common``). ``images`` (the frames
    themselves) and ``image`` (the set's map): a still answer is then refined on the used frames' images together
    (``still_on_image``)."""
    t0 = min(observed_at)
    placed = placed or scene.placements(observed_at)
    if sweeps is not None and sweep_sigma is None:
        sweep_sigma = sweep_errors(scene, observed_at, placed, sweeps)
    pass_frames = []
    for k, c in enumerate(checks):
        t = observed_at[k]
        obs_in_lvlh = placed.observation_in_lvlh(k)
        answer = rotation_matrix(*(float(a) for a in c.angles_deg))
        cands = [answer, MIRROR @ answer @ MIRROR]
        cands += [rotation_matrix(*a.angles_deg) for a in c.alternatives]
        finite = [b for b in c.quality.uncertainty_deg if math.isfinite(b)]
        bound = max(finite) if len(finite) == 3 else NO_BOUND_DEG
        q = c.quality
        pass_frames.append(
            PassFrame(
                np.array([obs_in_lvlh @ r for r in cands]),
                bound,
                (t - t0).total_seconds(),
                names[k],
                placed.los_lvlh[k],
                placed.los_rate_lvlh[k],
                usable(c),
                "; ".join(q.reasons),
                (q.uncertainty_deg[0], q.uncertainty_deg[1], q.uncertainty_deg[2]) if len(finite) == 3 else None,
                c.bound_cov_deg2,  # None where the bounds are not all finite
                None if sweeps is None else sweeps[k][0],
                None if sweep_sigma is None else float(sweep_sigma[k]),
            )
        )
    fused = fuse(pass_frames)
    common = None
    trusted_used = sum(1 for k in fused.used if usable(checks[k]))  # the common fit keeps the frames used
    enough = trusted_used >= MIN_TRUSTED_FRAMES
    if silhouettes is not None and renderer is not None and fused.reference_s is None and fused.stable and enough:
        together = [k for k in fused.used if silhouettes[k] is not None]
        if len(together) >= 2:
            from inference.fit import fit_common
            from inference.rotations import angle_deg

            common = fit_common(
                renderer,
                [np.asarray(silhouettes[k]) for k in together],
                [placed.observation_in_lvlh(k) for k in together],
                fused.rotation,
            )
            rot = common.rotation
            fused = replace(
                fused,
                rotation=rot,
                euler_zyx_deg=euler_from_matrix(rot),
                residual_deg={k: angle_deg(rot, fused.placed[k]) for k in range(len(pass_frames))},
            )
    image_fit = None
    if images is not None and image is not None and fused.reference_s is None and fused.stable and enough:
        fused, image_fit = still_on_image(fused, image, images, placed)
    if fused.reference_s is None:  # a still attitude holds all pass: given in J2000 at the frame nearest mid-pass
        span = [(t - t0).total_seconds() for t in observed_at]
        mid = int(np.argmin(np.abs(np.array(span) - 0.5 * (min(span) + max(span)))))
        t_mid, lvlh_mid = observed_at[mid], placed.lvlh[mid]
    else:  # a turning one is the attitude at the middle of the frames' times
        t_mid = t0 + timedelta(seconds=fused.reference_s)
        lvlh_mid = scene.placements([t_mid]).lvlh[0]
    # What the fused model says each frame measured: the sweep at the frame's time, which is the middle of its
    # sub-aperture's angle, where the mean rate over the integration equals the rate to second order.
    w_body = np.radians(fused.rate_deg_s) if fused.reference_s is not None else np.zeros(3)
    tau = np.array([(t - t0).total_seconds() for t in observed_at]) - (fused.reference_s or 0.0)
    (model_sweeps,) = _model_sweeps(fused.rotation, w_body, tau, [placed])
    branches = ["answer", "near-mirror"]
    frames_out = [
        FusedFrame(
            index=k,
            name=names[k],
            observed_at=observed_at[k],
            checked=c,
            attitude_lvlh=fused.placed[k],
            branch=[*branches, *[f"alternative {j}" for j in range(len(c.alternatives))]][fused.chosen[k]],
            used=k in fused.used,
            rejected_because=fused.rejected.get(k),
            residual_deg=fused.residual_deg[k],
            sweep_rad_s=None if sweeps is None else sweeps[k][0],
            sweep_sigma_rad_s=None if sweep_sigma is None else float(sweep_sigma[k]),
            sweep_model_rad_s=float(model_sweeps[k]),
        )
        for k, c in enumerate(checks)
    ]
    speed = float(np.linalg.norm(fused.rate_deg_s))
    return PassAttitude(
        trusted=enough,
        frames=frames_out,
        attitude_lvlh=fused.rotation,
        attitude_j2000=lvlh_mid @ fused.rotation,
        attitude_at=t_mid,
        uncertainty_deg=tuple(fused.uncertainty_deg),
        alternative_lvlh=fused.rival,
        used=len(fused.used),
        rejected=len(fused.rejected),
        stable=fused.stable if enough else None,  # undecided: too few trusted frames agree
        rate_deg_s=np.asarray(fused.rate_deg_s, float),
        rate_sigma_deg_s=np.asarray(fused.rate_sigma_deg_s, float),
        turning_chi2=fused.turning_chi2,
        common_fit=common,
        refined_on=SILHOUETTE if image_fit is None else IMAGE,
        image_fit=image_fit,
        stability=(
            f"too few frames to tell: {trusted_used} trusted frames agree, and a pass needs {MIN_TRUSTED_FRAMES} "
            "(frames outside the networks' range, another target, or a target that turns too fast)"
            if not enough
            else "three-axis stable over the pass (no body rate beyond the frames' scatter)"
            if fused.stable
            else f"turning at about {speed:.3f} deg/s about body axis "
            f"({', '.join(f'{v:.2f}' for v in fused.rate_deg_s / max(speed, 1e-12))}): the attitude given is the "
            f"{'turning model' if fused.reference_s is not None else 'mean'}'s at attitude_at"
        ),
    )


def still_on_image(
    fused: Fused, image: ImageRefinement, images: Vec | NDArray[np.float32], placed: Placements
) -> tuple[Fused, dict[str, float] | None]:
    """A still pass's attitude refined on its used frames' images together under the set's map: each frame sees the
    one LVLH attitude through its own observation frame, and one body turn common to them is searched
    (``ImageRefiner.refine_still``). Returns the fusion with the turned attitude and the fit's record, or as it was
    and None where the map does not refine passes or found nothing better."""
    from inference.rotations import angle_deg

    used = sorted(fused.used)
    bases = np.array([euler_from_matrix(placed.observation_in_lvlh(k).T @ fused.rotation) for k in used])
    done = image.refine_still(images[used], bases)
    if done is None or not done.nll_per_pixel < done.start_nll_per_pixel:
        return fused, None
    rot = fused.rotation @ done.turn
    moved = angle_deg(rot, fused.rotation)
    fit = {
        "frames": done.frames,
        "nll_per_pixel": round(done.nll_per_pixel, 6),
        "start_nll_per_pixel": round(done.start_nll_per_pixel, 6),
        "moved_deg": round(moved, 4),
    }
    out = replace(
        fused,
        rotation=rot,
        euler_zyx_deg=euler_from_matrix(rot),
        residual_deg={k: angle_deg(rot, fused.placed[k]) for k in range(len(fused.placed))},
    )
    return out, fit
