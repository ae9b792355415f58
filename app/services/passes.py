"""A pass: simulate the frames a radar forms over one, and fuse a pass's frames into one attitude in LVLH.

Simulation (``pass_geometry_frames`` then ``render_pass``): the plan's target over one of its
access windows, the line of sight from the station in the target's LVLH frame
(``planner.frames``), and the target held at a fixed LVLH attitude or spinning about a
body axis. The line of sight *in the body* sweeps an angle over the pass; each frame is a
sub-aperture of ``aperture_deg`` of that sweep (the paper's 5.1 deg), so its integration
time follows the real rotation rate and its cross-range cell stays lambda / (2 aperture).
Its observation frame is the simulator's (X toward the radar at mid-aperture, Y the line
of sight's rate in the body), and its attitude there is what the frame is rendered at.

Fusion (``fuse_frames``): each checked frame's answer and alternatives placed in LVLH
through the plan's geometry, then ``inference.fusion.fuse``.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, replace
from datetime import datetime, timedelta
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.errors import InputError
from app.services.estimation import (
    check_frames,
    checked_json,
    frames_at,
    frames_at_times,
    matrix_attitude_json,
    target_track,
)
from inference.frames import euler_from_matrix, rotation_matrix
from inference.fusion import PassFrame, fuse, sweep_rates, sweep_sigmas

Vec = NDArray[np.float64]

MIRROR = np.diag([1.0, 1.0, -1.0])  # M R M: a frame's near-mirror, a reflection through its own image plane
MIN_TRUSTED_FRAMES = 3  # a pass answer rests on at least this many trusted frames that agree
NO_BOUND_DEG = 10.0  # a frame whose fit bounds nothing counts as this uncertain


@dataclass(frozen=True)
class PassOptions:
    """How to simulate a pass (``gsa simulate --pass``); see the module's text."""

    window: int | None = None  # which of the plan's access windows (None: the one that culminates highest)
    aperture_deg: float = 5.1  # each frame's sub-aperture: the angle the line of sight sweeps in the body
    step_deg: float | None = None  # between frame centres (None: the aperture, frames side by side)
    max_frames: int = 60
    attitude_lvlh_deg: tuple[float, float, float] | None = None  # body to LVLH, z y x (None: drawn)
    max_angle_deg: float = 40.0  # a drawn attitude: the middle frame's observation-frame angles within this
    spin_deg_s: float = 0.0
    spin_axis: tuple[float, float, float] = (0.0, 0.0, 1.0)  # body axis of the spin
    snr_db: tuple[float, float] | None = (-3.0, 15.0)  # drawn per frame, or None for noise-free
    snr_reference: tuple[float, float] | None = None  # (dB, km): SNR = dB - 40 log10(range / km), the radar equation
    within_deg: float | None = None  # keep only frames whose observation-frame angles are within this (trained range)
    seed: int = 0

    def __post_init__(self) -> None:
        checks = (
            ("aperture_deg", 0.5 <= self.aperture_deg <= 30.0),
            ("step_deg", self.step_deg is None or 0.5 <= self.step_deg <= 90.0),
            ("max_frames", 2 <= self.max_frames <= 1000),
            ("max_angle_deg", 0.0 <= self.max_angle_deg <= 89.0),
            ("spin_deg_s", abs(self.spin_deg_s) <= 10.0),
            ("spin_axis", len(self.spin_axis) == 3 and float(np.linalg.norm(self.spin_axis)) > 0),
            ("within_deg", self.within_deg is None or 0.0 < self.within_deg <= 180.0),
            ("snr_db", self.snr_db is None or (-30.0 <= self.snr_db[0] <= self.snr_db[1] <= 60.0)),
            ("snr_reference", self.snr_reference is None or self.snr_reference[1] > 0),
        )
        for name, ok in checks:
            if not ok:
                raise InputError([name], f"{name} = {getattr(self, name)!r} is out of range")


def choose_window(windows: list[dict[str, Any]], index: int | None) -> tuple[int, dict[str, Any]]:
    """Return the access window asked for, or the one that culminates highest."""
    if not windows:
        raise InputError(["window"], "the plan has no access windows: the station never sees the target in its span")
    if index is None:
        index = int(np.argmax([w["max_elevation_deg"] for w in windows]))
    if not 0 <= index < len(windows):
        raise InputError(
            ["window"], f"window {index} does not exist: the plan has {len(windows)} (0..{len(windows) - 1})"
        )
    return index, windows[index]


def spin_rotation(axis: Vec, rate_deg_s: float, t: Vec) -> Vec:
    """Return rotations (N, 3, 3) by rate * t about a unit axis (Rodrigues)."""
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    a = np.radians(rate_deg_s * np.asarray(t, float))[:, None, None]
    return np.eye(3) + np.sin(a) * k + (1.0 - np.cos(a)) * (k @ k)


def pass_geometry_frames(
    plan_request: dict[str, Any], window: dict[str, Any], opts: PassOptions, rng: np.random.Generator
) -> list[dict[str, Any]]:
    """Return each frame of a simulated pass over ``window``: its time, geometry and true attitudes (no image yet)."""
    from planner.frames import observation_axes, pass_geometry, swept_deg

    rise, end = datetime.fromisoformat(window["rise"]), datetime.fromisoformat(window["set"])
    duration = (end - rise).total_seconds()
    traj, station, frames = target_track(plan_request, rise, 0.0, duration)
    t = np.arange(0.0, duration, 0.5)
    t = np.append(t, duration) if t[-1] < duration else t
    geo = pass_geometry(traj, station, frames, t)
    axis = np.asarray(opts.spin_axis, float) / np.linalg.norm(opts.spin_axis)

    def body_attitude(a0: Vec, times: Vec) -> Vec:  # body to LVLH at ``times`` (spin about the body axis)
        return np.asarray(a0 @ spin_rotation(axis, opts.spin_deg_s, times - t_mid))

    def los_body(a0: Vec, g: Any) -> Vec:  # the line of sight in body axes, from a pass_geometry's samples
        return np.einsum("nji,jn->in", body_attitude(a0, g.t_s), g.los_lvlh)

    sweep = swept_deg(geo.los_lvlh)
    t_mid = float(np.interp(0.5 * sweep[-1], sweep, t))  # the middle of the sweep (a still target's middle frame)
    step3 = np.array([-0.5, 0.0, 0.5])
    g_mid = pass_geometry(traj, station, frames, t_mid + step3)
    if opts.attitude_lvlh_deg is not None:
        a0 = rotation_matrix(*opts.attitude_lvlh_deg)
    else:  # the middle of the pass seen at angles the networks know
        wanted = rotation_matrix(*(float(v) for v in rng.uniform(-opts.max_angle_deg, opts.max_angle_deg, 3)))
        a0 = observation_axes(g_mid.los_lvlh, g_mid.t_s)[1] @ wanted
        for _ in range(8):  # a spin turns the image plane too: settle a0 so the middle frame sees ``wanted``
            a0 = a0 @ observation_axes(los_body(a0, g_mid), g_mid.t_s)[1] @ wanted
    theta = swept_deg(los_body(a0, geo))
    half = opts.aperture_deg / 2.0
    if theta[-1] < opts.aperture_deg:
        raise InputError(
            ["window"],
            f"the line of sight sweeps only {theta[-1]:.1f} deg of the target over this "
            f"pass, less than one {opts.aperture_deg} deg sub-aperture",
        )
    step = opts.step_deg or opts.aperture_deg
    centres = np.arange(half, theta[-1] - half + 1e-9, step)
    centres += (theta[-1] - half - centres[-1]) / 2.0  # centre the frames on the pass
    out = []
    for c in centres:
        t_c = float(np.interp(c, theta, t))
        t0, t1 = float(np.interp(c - half, theta, t)), float(np.interp(c + half, theta, t))
        g = pass_geometry(traj, station, frames, t_c + step3)
        obs_body = observation_axes(los_body(a0, g), g.t_s)[1]
        angles = euler_from_matrix(obs_body.T)  # body to observation frame
        if opts.within_deg is not None and max(abs(a) for a in angles) > opts.within_deg:
            continue
        a = body_attitude(a0, np.array([t_c]))[0]
        lvlh = g.lvlh[1]
        out.append(
            {
                "observed_at": rise + timedelta(seconds=t_c),
                "t_s": t_c,
                "integration_s": t1 - t0,
                "range_km": float(g.range_km[1]),
                "attitude_deg": [float(v) for v in angles],
                "body_to_lvlh": a,
                "observation_in_lvlh": a @ obs_body,
                "lvlh_in_gcrs": lvlh,
            }
        )
    if len(out) > opts.max_frames:  # evenly thinned
        keep = np.unique(np.linspace(0, len(out) - 1, opts.max_frames).round().astype(int))
        out = [out[k] for k in keep]
    if len(out) < 2:
        raise InputError(
            ["within_deg"],
            f"only {len(out)} frame(s) of this pass fall within the angles asked for; "
            "widen within_deg, choose another window, or give the attitude",
        )
    return out


def render_pass(
    frames_meta: list[dict[str, Any]],
    opts: PassOptions,
    rng: np.random.Generator,
    radar: Any = None,
    model: Any = None,
    scattering: Any = None,
) -> tuple[Vec, Vec]:
    """Render each frame at its attitude; return the normalised frames [N, H, W] and their SNRs (dB, NaN: none)."""
    from inference.simulation.catalogue import at_attitudes
    from inference.simulation.scene import DEFAULT_SCATTERING

    n = len(frames_meta)
    if opts.snr_reference is not None:
        ref_db, ref_km = opts.snr_reference
        snrs = np.array([ref_db - 40.0 * math.log10(f["range_km"] / ref_km) for f in frames_meta])
    elif opts.snr_db is not None:
        snrs = rng.uniform(opts.snr_db[0], opts.snr_db[1], n)
    else:
        snrs = np.full(n, np.nan)
    seeds = [int(s) for s in rng.integers(0, 2**62, n)]
    angles = np.array([f["attitude_deg"] for f in frames_meta])
    images, _ = at_attitudes(angles, snrs, seeds, radar, model, scattering or DEFAULT_SCATTERING)
    return images.astype(np.float64), np.asarray(snrs, np.float64)


def pass_record(
    frames_meta: list[dict[str, Any]],
    snrs: Vec,
    opts: PassOptions,
    window_index: int,
    window: dict[str, Any],
    plan_request: dict[str, Any],
    cells_m: tuple[float, float],
) -> dict[str, Any]:
    """Return the JSON record (``pass.json``) of a simulated pass: each frame's time, geometry and truth."""

    def att(r: Vec) -> dict[str, Any]:
        return matrix_attitude_json(np.asarray(r))

    return {
        "format": "gsa-isar pass 1",
        "frames_file": "frames.npz (member 'image': [N, H, W] normalised frames, upload with normalised=true)",
        "plan_request": plan_request,
        "window_index": window_index,
        "window": window,
        "options": asdict(opts),
        "range_cell_m": cells_m[0],
        "frames": [
            {
                "index": k,
                "observed_at": _iso_z(f["observed_at"]),
                "integration_s": round(f["integration_s"], 3),
                "range_km": round(f["range_km"], 3),
                "snr_db": None if not math.isfinite(snrs[k]) else round(float(snrs[k]), 3),
                "cross_range_cell_m": cells_m[1],
                "attitude_observation": att(rotation_matrix(*f["attitude_deg"])),
                "attitude_lvlh": att(f["body_to_lvlh"]),
                "attitude_j2000": att(f["lvlh_in_gcrs"] @ f["body_to_lvlh"]),
                "observation_axes_in_lvlh": np.asarray(f["observation_in_lvlh"]).round(12).tolist(),
                "observation_axes_in_j2000": (f["lvlh_in_gcrs"] @ f["observation_in_lvlh"]).round(12).tolist(),
            }
            for k, f in enumerate(frames_meta)
        ],
    }


def _iso_z(t: datetime) -> str:
    """ISO 8601 UTC with a Z (microseconds kept)."""
    from datetime import UTC

    return t.astimezone(UTC).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


REVERSED = np.diag([1.0, -1.0, -1.0])  # Rx(180): a frame read reversed in cross-range is the body turned half about X
REVERSED_NOTE = (
    "read reversed in cross-range (the target turns against the line of sight faster than it sweeps): "
    "answered from the mirrored frame"
)


def reversed_reading(angles: Any) -> tuple[float, float, float]:
    """The attitude (Euler z, y, x deg) of a frame read reversed in cross-range, from its mirrored reading's.

    The same map takes a frame's true attitude to the one its mirrored frame shows: Rx(180) R (``REVERSED``)."""
    return euler_from_matrix(REVERSED @ rotation_matrix(*(float(a) for a in angles)))


def recheck_reversed(*, est: Any, checker: Any, frames: Vec, checks: list[Any]) -> list[Any]:
    """Give each untrusted frame a second reading, mirrored in cross-range; keep it where its checks trust it.

    A radar forms the image from the line of sight's motion relative to the body. A target
    turning against that motion faster than the line of sight sweeps reverses the cross-range
    axis: the frame shows the body turned by 180 deg about the line of sight, outside the
    networks' range. Mirrored back, it reads as an ordinary frame R', and the body is Rx(180) R'.
    ``fuse_pass`` asks for it only when the frames as they are do not make a trusted, still
    pass; single frames are never given this reading (a flipped single frame must be flagged),
    but a pass can afford it, since the fusion's turning model predicts which way each frame reads.
    """
    from inference.trust import Alternative, Checked, Quality

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
        )
    return out


@dataclass(frozen=True)
class FusedPass:
    """A pass fitted and fused: the answer, the checks it rests on, the per-frame timings and the two stages' times."""

    result: dict[str, Any]
    checks: list[Any]
    timings_s: dict[str, float]
    fit_s: float
    fuse_s: float


def fit_and_fuse(
    *,
    est: Any,
    checker: Any,
    uploads: list[Any],
    plan_request: dict[str, Any],
    observed_at: list[datetime],
    normalised: bool,
    cells_m: tuple[float, float] | None = None,
    names: list[str] | None = None,
    sweeps: list[tuple[float, float]] | None = None,
) -> FusedPass:
    """Fit every frame of a pass and fuse them: the one path of POST /v1/passes, ``gsa pass`` and the benchmark.

    The single-frame library search stays off (``search=False``): a pass's other frames stand in for
    one that Swin misreads. ``names`` defaults to the uploads' names. ``sweeps``: each frame's
    measured sweep rate and integration time (``sweeps_from``), or None.
    """
    t0 = time.perf_counter()
    frames, res, checks, per_frame = check_frames(
        est=est, checker=checker, uploads=uploads, resample=False, normalised=normalised, cells_m=cells_m, search=False
    )
    t1 = time.perf_counter()
    result, checks = fuse_pass(
        est=est,
        checker=checker,
        frames=frames,
        checks=checks,
        plan_request=plan_request,
        observed_at=observed_at,
        names=names if names is not None else [u.name for u in uploads],
        sweeps=sweeps,
        enhanced=res.enhanced,
    )
    return FusedPass(result, checks, per_frame, t1 - t0, time.perf_counter() - t1)


def fuse_pass(
    *,
    est: Any,
    checker: Any,
    frames: Vec,
    checks: list[Any],
    plan_request: dict[str, Any],
    observed_at: list[datetime],
    names: list[str],
    sweeps: list[tuple[float, float]] | None = None,
    enhanced: Vec | None = None,
) -> tuple[dict[str, Any], list[Any]]:
    """Fuse a checked pass; where it is not a trusted still one, re-read its untrusted frames mirrored and fuse again.

    Returns the answer with the more trusted frames used, and the checks it rests on. ``enhanced``: the
    frames' silhouettes (UNet++'s), which a still answer is fitted to all at once (``fit_common``); a frame
    re-read mirrored takes no part in that.
    """
    placed = frames_at_times(plan_request, observed_at)
    # Both fusions share the frames' placements and the sweeps' errors (the geometry, not the readings).
    sigma = None if sweeps is None else sweep_errors(plan_request, observed_at, placed, sweeps)

    def fused(cs: list[Any]) -> dict[str, Any]:
        return fuse_frames(
            plan_request=plan_request,
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
        )

    first = fused(checks)
    if first["trusted"] and first["stable"]:
        return first, checks
    again = recheck_reversed(est=est, checker=checker, frames=frames, checks=checks)
    if again is checks:
        return first, checks
    second = fused(again)

    def trusted_used(result: dict[str, Any], cs: list[Any]) -> int:
        return sum(1 for f in result["frames"] if f["used"] and usable(cs[f["index"]]))

    if trusted_used(second, again) > trusted_used(first, checks):
        return second, again
    return first, checks


def sweeps_from(
    integration_s: list[float] | None, aperture_deg: float | None, n_frames: int, default_aperture_deg: float | None
) -> list[tuple[float, float]] | None:
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
            raise InputError(["integration_s"], "aperture_deg needs integration_s: send each frame's integration time")
        return None
    if len(integration_s) != n_frames:
        raise InputError(
            ["integration_s"], f"{len(integration_s)} integration times for {n_frames} frames: send one per frame"
        )
    for k, t in enumerate(integration_s):
        if not (isinstance(t, int | float) and math.isfinite(t) and 0.0 < t <= 3600.0):
            raise InputError(["integration_s", k], f"frame {k}'s integration time must be in (0, 3600] s, not {t!r}")
    aperture = default_aperture_deg if aperture_deg is None else aperture_deg
    if aperture is None:
        raise InputError(
            ["aperture_deg"],
            "the frames' cells are not the models': send aperture_deg, the angle each frame integrates "
            "(lambda / (2 x cross-range cell), in deg)",
        )
    if not (math.isfinite(aperture) and 0.0 < aperture <= 30.0):
        raise InputError(["aperture_deg"], f"aperture_deg must be in (0, 30] deg, not {aperture!r}")
    return [(math.radians(aperture) / float(t), float(t)) for t in integration_s]


def _around(
    plan_request: dict[str, Any], observed_at: list[datetime], sweeps: list[tuple[float, float]]
) -> tuple[list[dict[str, Vec]], list[dict[str, Vec]]]:
    """Each frame's placement half an integration before and after its time (``frames_at_times``)."""
    half = [timedelta(seconds=0.5 * t) for _, t in sweeps]
    around = frames_at_times(plan_request, [t - h for t, h in zip(observed_at, half, strict=True)])
    around += frames_at_times(plan_request, [t + h for t, h in zip(observed_at, half, strict=True)])
    return around[: len(sweeps)], around[len(sweeps) :]


def sweep_errors(
    plan_request: dict[str, Any],
    observed_at: list[datetime],
    placed: list[dict[str, Vec]],
    sweeps: list[tuple[float, float]],
) -> Vec:
    """Each measured sweep's 1-sigma error (rad/s, ``inference.fusion.sweep_sigmas``): a still target's sweeps
    half an integration before, at and after each frame's time (``placed``: the frames' placements then)."""
    before, after = _around(plan_request, observed_at, sweeps)
    r0, r1, r2 = _model_sweeps(np.eye(3), np.zeros(3), np.zeros(len(sweeps)), [before, placed, after])
    return sweep_sigmas(np.array([r for r, _ in sweeps]), r0, r1, r2)


def _model_sweeps(rotation: Vec, w_body: Vec, tau: Vec, placements: list[list[dict[str, Vec]]]) -> list[Vec]:
    """A model's sweep rates (rad/s, ``sweep_rates``) at times ``tau``, for each list of the frames' placements."""
    return [
        sweep_rates(
            rotation,
            w_body,
            tau,
            np.array([p["los_lvlh"] for p in ps]),
            np.array([p["los_rate_lvlh"] for p in ps]),
        )
        for ps in placements
    ]


def check_times(plan_result: dict[str, Any], observed_at: list[datetime]) -> None:
    """Every frame's time must fall inside one of the plan's access windows (422 naming observed_at)."""
    windows = [
        (datetime.fromisoformat(w["rise"]), datetime.fromisoformat(w["set"]))
        for w in plan_result.get("access_windows", [])
    ]
    for k, t in enumerate(observed_at):
        if not any(rise <= t <= end for rise, end in windows):
            raise InputError(
                ["observed_at", k],
                f"frame {k}'s time {t.isoformat()} is in none of the plan's access windows: the station cannot see "
                "the target then",
            )


def usable(checked: Any) -> bool:
    """Whether a pass may use a frame: trusted, or doubted only because another attitude fits as well.

    A lookalike is what a pass resolves (the other frames pick the branch), so such a frame goes
    into the fusion with its alternatives; a frame that fails any other check does not.
    """
    from inference.trust import AMBIGUOUS

    q = checked.quality
    return bool(q.trusted or (checked.alternatives and q.reasons and all(r.endswith(AMBIGUOUS) for r in q.reasons)))


def fuse_frames(
    *,
    plan_request: dict[str, Any],
    checks: list[Any],
    observed_at: list[datetime],
    names: list[str],
    placed: list[dict[str, Vec]] | None = None,
    sweeps: list[tuple[float, float]] | None = None,
    sweep_sigma: Vec | None = None,
    silhouettes: list[Vec | None] | None = None,
    renderer: Any = None,
) -> dict[str, Any]:
    """Place each checked frame's answer and alternatives in LVLH (``frames_at_times``, unless ``placed`` gives
    those axes already), fuse them, and describe the pass. ``sweeps``: each frame's measured sweep rate (rad/s)
    and integration time (``sweeps_from``), or None; ``sweep_sigma`` their errors (``sweep_errors``, computed
    here unless given). ``silhouettes`` (each frame's, or None) and ``renderer``: a still answer is then
    fitted to the used frames' silhouettes all at once (``inference.fit.fit_common``)."""
    t0 = min(observed_at)
    placed = placed or frames_at_times(plan_request, observed_at)
    if sweeps is not None and sweep_sigma is None:
        sweep_sigma = sweep_errors(plan_request, observed_at, placed, sweeps)
    pass_frames = []
    for k, (c, axes) in enumerate(zip(checks, placed, strict=True)):
        t = observed_at[k]
        obs_in_lvlh = axes["lvlh"].T @ axes["observation"]
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
                axes["los_lvlh"],
                axes["los_rate_lvlh"],
                usable(c),
                "; ".join(q.reasons),
                tuple(q.uncertainty_deg) if len(finite) == 3 else None,
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
            from inference.fusion import angle_deg

            common = fit_common(
                renderer,
                [np.asarray(silhouettes[k]) for k in together],
                [placed[k]["lvlh"].T @ placed[k]["observation"] for k in together],
                fused.rotation,
            )
            rot = common.rotation
            fused = replace(
                fused,
                rotation=rot,
                euler_zyx_deg=euler_from_matrix(rot),
                residual_deg={k: angle_deg(rot, fused.placed[k]) for k in range(len(pass_frames))},
            )
    if fused.reference_s is None:  # a still attitude holds all pass: given in J2000 at the frame nearest mid-pass
        span = [(t - t0).total_seconds() for t in observed_at]
        mid = int(np.argmin(np.abs(np.array(span) - 0.5 * (min(span) + max(span)))))
        t_mid, lvlh_mid = observed_at[mid], placed[mid]["lvlh"]
    else:  # a turning one is the attitude at the middle of the frames' times
        t_mid = t0 + timedelta(seconds=fused.reference_s)
        lvlh_mid = frames_at(plan_request, t_mid)["lvlh"]
    j2000 = lvlh_mid @ fused.rotation
    # What the fused model says each frame measured: the sweep at the frame's time, which is the middle of its
    # sub-aperture's angle, where the mean rate over the integration equals the rate to second order.
    w_body = np.radians(fused.rate_deg_s) if fused.reference_s is not None else np.zeros(3)
    tau = np.array([(t - t0).total_seconds() for t in observed_at]) - (fused.reference_s or 0.0)
    (model_sweeps,) = _model_sweeps(fused.rotation, w_body, tau, [placed])
    frames_out = []
    for k, c in enumerate(checks):
        chosen = fused.chosen[k]
        frames_out.append(
            {
                "index": k,
                "name": names[k],
                "observed_at": observed_at[k],
                **checked_json(c),
                "attitude_lvlh": matrix_attitude_json(fused.placed[k]),
                "branch": ["answer", "near-mirror", *[f"alternative {j}" for j in range(len(c.alternatives))]][chosen],
                "used": k in fused.used,
                "rejected_because": fused.rejected.get(k),
                "residual_deg": round(fused.residual_deg[k], 4),
                "sweep_deg_s": None if sweeps is None else round(math.degrees(sweeps[k][0]), 5),
                "sweep_sigma_deg_s": None if sweep_sigma is None else round(math.degrees(float(sweep_sigma[k])), 5),
                "sweep_model_deg_s": round(math.degrees(float(model_sweeps[k])), 5),
            }
        )
    speed = float(np.linalg.norm(fused.rate_deg_s))
    return {
        "trusted": enough,
        "frames": frames_out,
        "attitude_lvlh": matrix_attitude_json(fused.rotation),
        "attitude_j2000": {**matrix_attitude_json(j2000), "at": t_mid},
        "uncertainty_deg": [round(b, 4) for b in fused.uncertainty_deg],
        "alternative_lvlh": None if fused.rival is None else matrix_attitude_json(fused.rival),
        "used": len(fused.used),
        "rejected": len(fused.rejected),
        "stable": fused.stable if enough else None,  # undecided: too few trusted frames agree
        "rate_deg_s": [round(float(r), 5) for r in fused.rate_deg_s],
        "rate_sigma_deg_s": [round(float(r), 5) if math.isfinite(r) else None for r in fused.rate_sigma_deg_s],
        "turning_chi2": None if fused.turning_chi2 is None else round(fused.turning_chi2, 2),
        "common_fit": None
        if common is None
        else {
            "frames": common.frames,
            "moved_deg": round(common.moved_deg, 4),
            "silhouette_iou": round(common.iou, 4),
        },
        "attitude_at": t_mid,
        "stability": (
            f"too few frames to tell: {trusted_used} trusted frames agree, and a pass needs {MIN_TRUSTED_FRAMES} "
            "(frames outside the networks' range, another target, or a target that turns too fast)"
            if not enough
            else "three-axis stable over the pass (no body rate beyond the frames' scatter)"
            if fused.stable
            else f"turning at about {speed:.3f} deg/s about body axis "
            f"({', '.join(f'{v:.2f}' for v in fused.rate_deg_s / max(speed, 1e-12))}): the attitude given is the "
            f"{'turning model' if fused.reference_s is not None else 'mean'}'s at attitude_at"
        ),
    }
