"""A campaign's scenes flown with errors, as an operator flies them: how often each still lands within its aim.

Each scene's approach is flown ``samples`` times (Monte Carlo, seeded). Orbit determination before the phasing
burn measures the observer with a navigation error (``position_sigma_km``, ``velocity_sigma_km_s`` per axis); the
burn is re-aimed from that measurement (``planner.manoeuvre.retarget``, the plan's branch) and executed with a
magnitude error (``burn_magnitude_sigma``, a fraction) and a pointing error (``burn_pointing_sigma_deg``) on the
true state. Then, as an operator trims an approach (``trim_times``): as soon as ``trim_coast_s`` after the burn
allows, and again a quarter revolution before T_access, orbit determination measures again and a trim burn is
re-aimed at the same aim point and T_access, executed with the same errors. The true observer is flown to T_access: the scene
is feasible when it arrives within its aim's tolerance (``planner.closed_loop.scene_aim``). Each scene reports its
``feasible_share`` and the 95th percentile of its trim, which a campaign's budget must keep in reserve.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from planner.campaign import Campaign, CampaignScene
from planner.closed_loop import scene_aim
from planner.errors import PlannerError, PlanningStopped, SearchRangeError
from planner.manoeuvre import lambert_options, period_s, retarget
from planner.plan import StopCheck
from planner.propagation import Pole, propagate_j2

Vec = NDArray[np.float64]
MIN_TRIM_LEAD_S = 600.0  # a trim this close to T_access or closer is moved to the middle of the approach


@dataclass(frozen=True, slots=True)
class DispersionOptions:
    """The errors a campaign is flown with (defaults: 10 m and 1 cm/s navigation, 1 % and 0.1 deg burns)."""

    samples: int = 50
    # the least coast after the phasing burn before orbit determination and the trim (``trim_time``)
    position_sigma_km: float = 0.010
    velocity_sigma_km_s: float = 1e-5
    burn_magnitude_sigma: float = 0.01
    burn_pointing_sigma_deg: float = 0.1
    trim_coast_s: float = 2700.0
    seed: int = 0

    def __post_init__(self) -> None:
        checks = (
            ("samples", self.samples, 2, 2000),
            ("position_sigma_km", self.position_sigma_km, 0.0, 100.0),
            ("velocity_sigma_km_s", self.velocity_sigma_km_s, 0.0, 0.1),
            ("burn_magnitude_sigma", self.burn_magnitude_sigma, 0.0, 0.5),
            ("burn_pointing_sigma_deg", self.burn_pointing_sigma_deg, 0.0, 30.0),
            ("trim_coast_s", self.trim_coast_s, 60.0, 10 * 86400.0),
        )
        for name, value, lo, hi in checks:
            if not (math.isfinite(value) and lo <= value <= hi):
                raise SearchRangeError(
                    f"dispersion.{name} {value:g} is outside [{lo:g}, {hi:g}]", field=f"dispersion.{name}"
                )


@dataclass(frozen=True, slots=True)
class SceneDispersion:
    """One scene flown ``samples`` times with errors: the share that landed within ``tolerance_km`` of its aim, the
    trims' (all of a sample's together) 95th percentile and largest (km/s), the misses' 95th percentile (km), and the samples whose re-aim failed."""

    scene: int
    samples: int
    feasible_share: float
    trim_p95_km_s: float
    trim_max_km_s: float
    miss_p95_km: float
    tolerance_km: float
    failed: int


def _executed(dv: Vec, rng: np.random.Generator, opts: DispersionOptions) -> Vec:
    """An impulse as the engine gives it: its size off by a fraction, its direction tilted about a random axis."""
    size = float(np.linalg.norm(dv))
    if size == 0.0:
        return dv
    axis = np.cross(dv, rng.normal(size=3))
    axis /= np.linalg.norm(axis)
    tilt = math.radians(rng.normal(0.0, opts.burn_pointing_sigma_deg))
    u = dv / size
    turned = u * math.cos(tilt) + np.cross(axis, u) * math.sin(tilt)  # axis is perpendicular to u
    return np.asarray(turned * size * (1.0 + rng.normal(0.0, opts.burn_magnitude_sigma)), float)


def _measured(r: Vec, v: Vec, rng: np.random.Generator, opts: DispersionOptions) -> tuple[Vec, Vec]:
    return r + rng.normal(0.0, opts.position_sigma_km, 3), v + rng.normal(0.0, opts.velocity_sigma_km_s, 3)


def trim_times(t_burn_s: float, t_access_s: float, period: float, coast_s: float) -> list[float]:
    """When the trims come: each a quarter revolution plus whole ones before T_access (a Lambert arc near 180 or 360
    deg is ill-conditioned: the trim would blow up). The first as early as ``coast_s`` after the burn allows (cheap:
    a velocity error's along-track drift grows with time), the last a quarter revolution before T_access (so its own
    execution error has little time to grow), ``coast_s`` apart; the middle of the approach where neither fits."""
    whole = math.floor((t_access_s - t_burn_s - coast_s) / period - 0.25)
    if whole < 0:
        return [0.5 * (t_burn_s + t_access_s)]
    first = t_access_s - (whole + 0.25) * period
    last = t_access_s - 0.25 * period
    if last - first >= coast_s and last <= t_access_s - MIN_TRIM_LEAD_S:
        return [first, last]
    return [first]


def _trim(r: Vec, v: Vec, t_s: float, goal: Vec, t_access_s: float, pole: Pole) -> Vec:
    """The trim from a measured state: of the Lambert arcs to the aim point, the cheapest once corrected for J2."""
    best: Vec | None = None
    failure: PlannerError | None = None
    for _, _, m, low in lambert_options(r, v, goal, t_access_s - t_s)[:3]:
        try:
            dv, _, _ = retarget(r, v, t_s, goal, t_access_s, m, low, pole)
        except PlannerError as exc:
            failure = failure or exc
            continue
        if best is None or np.linalg.norm(dv) < np.linalg.norm(best):
            best = dv
    if best is None:
        raise failure or PlannerError("no trim reaches the aim point", field="dispersion")
    return best


def disperse_scene(campaign: Campaign, scene: CampaignScene, opts: DispersionOptions) -> SceneDispersion:
    """Fly one scene's approach ``opts.samples`` times with errors (see the module's docstring)."""
    assert campaign.flown is not None and scene.plan.phasing is not None and scene.plan.target_trajectory is not None
    ph = scene.plan.phasing
    aim = scene_aim(scene, campaign.options.plan)
    burn = next(b for b in scene.burns if b.kind == "phasing")
    t_b, t_a = burn.t_s, scene.t_access_s
    goal = scene.plan.target_trajectory.state(ph.t_access_s)[0][:, 0] + np.asarray(aim.relative_km)
    r0, v0 = campaign.flown.exact(t_b)
    pole = campaign.pole
    t_trims = trim_times(t_b, t_a, period_s(r0, v0 + np.asarray(burn.dv_km_s)), opts.trim_coast_s)
    rng = np.random.default_rng(opts.seed + 7919 * scene.index)
    trims, misses, failed = [], [], 0
    for _ in range(opts.samples):
        try:
            r_m, v_m = _measured(r0, v0, rng, opts)
            dv, _, _ = retarget(r_m, v_m, t_b, goal, t_a, ph.lambert_revolutions, ph.low_path, pole)
            t, r, v = t_b, r0, v0 + _executed(dv, rng, opts)
            spent = 0.0
            for t_trim in t_trims:
                r, v = propagate_j2(r, v, t, t_trim, pole)
                r_m, v_m = _measured(r, v, rng, opts)
                trim = _trim(r_m, v_m, t_trim, goal, t_a, pole)
                spent += float(np.linalg.norm(trim))
                t, v = t_trim, v + _executed(trim, rng, opts)
            r_end, _ = propagate_j2(r, v, t, t_a, pole)
        except PlannerError:  # no transfer from where the errors left it: the scene is lost in this sample
            failed += 1
            continue
        trims.append(spent)
        misses.append(float(np.linalg.norm(r_end - goal)))
    landed = np.asarray(misses) <= aim.tolerance_km
    return SceneDispersion(
        scene=scene.index,
        samples=opts.samples,
        feasible_share=float(landed.sum()) / opts.samples,
        trim_p95_km_s=float(np.percentile(trims, 95)) if trims else math.nan,
        trim_max_km_s=float(max(trims)) if trims else math.nan,
        miss_p95_km=float(np.percentile(misses, 95)) if misses else math.nan,
        tolerance_km=aim.tolerance_km,
        failed=failed,
    )


def disperse(campaign: Campaign, opts: DispersionOptions, stop: StopCheck | None = None) -> list[SceneDispersion]:
    """Every scene of a campaign flown with errors; ``stop`` is asked before each scene (PlanningStopped)."""
    out = []
    for scene in campaign.scenes:
        if stop is not None and (reason := stop()):
            raise PlanningStopped(f"the dispersion stopped: {reason}", field="dispersion")
        out.append(disperse_scene(campaign, scene, opts))
    return out


def trim_margin_km_s(dispersions: list[SceneDispersion]) -> float:
    """The Delta-v a campaign's budget keeps for its trims: the sum of its scenes' 95th-percentile trims."""
    return float(sum(d.trim_p95_km_s for d in dispersions if math.isfinite(d.trim_p95_km_s)))
