"""Campaigns flown closed-loop: each scene's aim, and a re-plan from the state orbit determination gives.

Chained fly-bys are chaotic: 1 m along-track at a campaign's start moves the paper's fifth scene by 283 km
(design/measurements.md, "Chaining a campaign's burns"). An operator therefore flies each leg, measures where
the observer is, and re-aims the next one. Two pieces make that possible:

- ``scene_aim``: what a scene aims at. T_access, the observer's position relative to the target there
  (GCRS and the target's radial / along-track / normal axes) and the **tolerance**: how far from that point
  the observer may arrive and the scene stay feasible. At a stand-off d with relative speed v, the optics'
  range R, the tracker's rate w and the least separation s: min(R - d, d - v / w, d - s).
- ``replan``: from a measured state at ``t_from``, every later scene is re-aimed, keeping its T_access and its
  aim point: the height-change burns are flown as planned and the phasing burn is solved again (Lambert on
  the same branch, corrected for J2) from the state actually reached, so each leg starts from the truth and
  no error is carried forward. A scene that can no longer be reached within the budget, or not at all, is
  replaced: the rest of the span is planned afresh from there (``plan_campaign``).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from planner.campaign import (
    CAMPAIGN_MARGIN_S,
    Burn,
    Campaign,
    CampaignScene,
    Progress,
    Shifted,
    Stretch,
    _burn,
    _coast,
    _return,
    campaign_pole,
    check_scene,
    fly,
    plan_campaign,
)
from planner.elements import elements_of_state
from planner.errors import PlannerError
from planner.manoeuvre import period_s, retarget, rtn_matrix
from planner.orbits import Orbit, earth_frames, trajectory
from planner.plan import PlanOptions, StopCheck, imaging_range_km
from planner.propagation import NumericalJ2Trajectory, Pole, Station, Trajectory, propagate_j2, seconds_between, utc

Vec = NDArray[np.float64]
# A measured state farther than this from where the campaign has its observer is another object, not an orbit
# determination of this one (a LEO observer's state is known to metres; a wrong object is thousands of km off).
MAX_STATE_OFFSET_KM = 500.0


@dataclass(frozen=True, slots=True)
class Aim:
    """What one scene aims at: T_access (s after the campaign's epoch), the observer's position relative to the
    target there (GCRS km, and the same in the target's radial / along-track / normal axes) and how far from it
    the observer may arrive with the scene still feasible (km)."""

    t_access_s: float
    relative_km: tuple[float, float, float]
    relative_rtn_km: tuple[float, float, float]
    tolerance_km: float


def aim_tolerance_km(standoff_km: float, relative_speed_km_s: float, opts: PlanOptions) -> float:
    """How far the observer may arrive from a stand-off point and stay within the optics' range, the tracker's
    rate (a straight fly-by at v passing at d' turns the line of sight at up to v / d') and the least separation."""
    rate = math.radians(opts.optics.max_rate_deg_s)
    limits = (
        imaging_range_km(opts) - standoff_km,
        standoff_km - relative_speed_km_s / rate,
        standoff_km - opts.min_separation_km,
    )
    return max(0.0, min(limits))


def scene_aim(scene: CampaignScene, opts: PlanOptions) -> Aim:
    """The scene's aim (``Aim``) from its plan's phasing burn."""
    ph = scene.plan.phasing
    assert ph is not None and scene.plan.target_trajectory is not None
    rel = np.asarray(ph.standoff_km_vec, float)
    r_t, v_t = scene.plan.target_trajectory.state(ph.t_access_s)
    rtn = rtn_matrix(r_t[:, 0], v_t[:, 0]) @ rel
    d = float(np.linalg.norm(rel))
    speed = float(np.linalg.norm(ph.v_relative_km_s))
    return Aim(
        scene.t_access_s,
        (float(rel[0]), float(rel[1]), float(rel[2])),
        (float(rtn[0]), float(rtn[1]), float(rtn[2])),
        aim_tolerance_km(d, speed, opts),
    )


def check_from(campaign: Campaign, t_from_s: float) -> None:
    """Refuse a re-plan moment outside the campaign, or inside a scene's approach (between its phasing burn and its
    T_access, where no burn is planned to re-aim it), naming ``from``."""
    if not 0.0 <= t_from_s < campaign.duration_s:
        raise PlannerError(
            f"from is {t_from_s / 86400.0:.3f} days after the campaign's start, outside its "
            f"{campaign.duration_s / 86400.0:g} days",
            field="from",
        )
    for s in campaign.scenes:
        phasing = next(b.t_s for b in s.burns if b.kind == "phasing")
        if phasing < t_from_s < s.t_access_s:
            raise PlannerError(
                f"from falls inside scene {s.index}'s approach (its phasing burn at {utc(campaign.epoch, phasing):%H:%M:%S}, "
                f"T_access at {utc(campaign.epoch, s.t_access_s):%H:%M:%S} UTC): re-plan before the burn or after T_access",
                field="from",
            )


def replan(
    campaign: Campaign,
    target: Orbit,
    observer: Orbit,
    station: Station | Sequence[Station],
    state: tuple[Vec, Vec],
    t_from_s: float,
    stop: StopCheck | None = None,
    progress: Progress | None = None,
) -> Campaign:
    """Re-plan ``campaign`` from the observer's measured GCRS ``state`` at ``t_from_s`` (s after its epoch).

    The new campaign starts at ``t_from_s`` (its epoch), its budget what the original had left there. Every scene
    after it is re-aimed (``CampaignScene.reaimed``) while that works; from the first that cannot be, the rest of
    the span is planned afresh. ``observer`` is the campaign's own orbit input (its pole of date is fitted from
    it, as the stored campaign's is).
    """
    clock0 = time.perf_counter()
    check_from(campaign, t_from_s)
    r0, v0 = (np.asarray(x, float).reshape(3) for x in state)
    planned = campaign.flown.state(t_from_s)[0][:, 0] if campaign.flown is not None else r0
    if float(np.linalg.norm(planned - r0)) > MAX_STATE_OFFSET_KM:
        raise PlannerError(
            f"the observer given is {np.linalg.norm(planned - r0):,.0f} km from where the campaign has its observer "
            f"at from: another object, or another time? Give this observer's state (within {MAX_STATE_OFFSET_KM:g} km)",
            field="observer",
        )
    opts = campaign.options
    epoch = utc(campaign.epoch, t_from_s)
    shift = seconds_between(campaign.epoch, epoch)
    end = campaign.duration_s - shift
    pole = campaign_pole(epoch, observer, end)
    margin = CAMPAIGN_MARGIN_S
    frames = earth_frames(epoch, 0.0, 1.0)
    target_traj = trajectory(target, epoch, frames, 0.0, end + margin, "osculating", pole)
    spent_before = sum(b.dv_total_km_s for b in campaign.burns if b.t_s < t_from_s)
    budget = opts.dv_budget_m_s / 1000.0 - spent_before
    ghost: Trajectory | None = None
    if opts.return_to_orbit:
        r_i, v_i = campaign.initial_state
        ghost = Shifted(NumericalJ2Trajectory(r_i, v_i, 0.0, campaign.duration_s + margin, pole=pole), shift)
    scenes: list[CampaignScene] = []
    burns: list[Burn] = []
    stretches: list[Stretch] = []
    notes = [f"re-planned from the observer's state at {epoch:%Y-%m-%d %H:%M:%S} UTC"]
    spent = 0.0
    t_cur, r, v = 0.0, r0, v0
    later = [s for s in campaign.scenes if s.t_access_s > t_from_s]
    lost: CampaignScene | None = None
    for s in later:
        if stop is not None and (reason := stop()):
            raise PlannerError(f"re-planning stopped: {reason}", field="replan")
        index = len(scenes)
        try:
            out = _reaim(s, shift, (t_cur, r, v), target_traj, pole, index, ghost)
        except PlannerError as exc:
            notes.append(
                f"scene {s.index} (T_access {utc(campaign.epoch, s.t_access_s):%Y-%m-%d %H:%M}) cannot be re-aimed: {exc}"
            )
            lost = s
            break
        scene_burns, (t_next, r_next, v_next) = out
        dv = sum(b.dv_total_km_s for b in scene_burns)
        if spent + dv > budget:
            notes.append(
                f"scene {s.index} re-aimed needs {dv * 1000.0:.1f} m/s, over the {(budget - spent) * 1000.0:.1f} m/s left"
            )
            lost = s
            break
        spent += dv
        burns += scene_burns
        scenes.append(
            replace(
                s,
                index=index,
                offset_s=s.offset_s - shift,
                t_access_s=s.t_access_s - shift,
                burns=tuple(scene_burns),
                dv_total_km_s=dv,
                reaimed=True,
                check=None,
            )
        )
        n_feasible = sum(f.feasible for f in s.plan.feasibility)
        stretches.append(
            Stretch(s.offset_s - shift, t_next, len(s.plan.candidates), n_feasible, index, "scene re-aimed", s.plan)
        )
        t_cur, r, v = t_next, r_next, v_next
        if progress:
            progress(min(1.0, t_cur / max(end, 1.0)), f"{len(scenes)} scene(s) re-aimed")
    if lost is not None and end - t_cur > 86400.0:  # the rest planned afresh from the state reached
        fresh_start = utc(epoch, math.ceil(t_cur))
        r_s, v_s = _coast((r, v), t_cur, seconds_between(epoch, fresh_start), pole)
        carried = Orbit(observer.name, elements=elements_of_state(r_s, v_s, fresh_start))
        fresh_opts = replace(
            opts,
            start=fresh_start,
            duration_s=end - seconds_between(epoch, fresh_start),
            dv_budget_m_s=max(0.0, (budget - spent) * 1000.0),
            max_scenes=max(1, opts.max_scenes - len(scenes)),
        )
        fresh = plan_campaign(target, carried, station, fresh_opts, stop=stop)
        off = seconds_between(epoch, fresh.epoch)
        for fs in fresh.scenes:
            moved = tuple(replace(b, t_s=b.t_s + off, scene=len(scenes)) for b in fs.burns)
            scenes.append(
                replace(fs, index=len(scenes), offset_s=fs.offset_s + off, t_access_s=fs.t_access_s + off, burns=moved)
            )
            burns += moved
        stretches += [replace(st, t0_s=st.t0_s + off, t1_s=st.t1_s + off) for st in fresh.stretches]
        spent += fresh.dv_total_km_s
        notes += [f"planned afresh from {fresh_start:%Y-%m-%d %H:%M} UTC: {n}" for n in fresh.notes]
    flown = fly(r0, v0, 0.0, end + margin, [(b.t_s, np.asarray(b.dv_km_s)) for b in burns], pole)
    scenes = [replace(s, check=check_scene(s, flown, epoch)) for s in scenes]
    return Campaign(
        epoch=epoch,
        duration_s=end,
        options=replace(opts, start=epoch, duration_s=end, dv_budget_m_s=max(0.0, budget * 1000.0)),
        scenes=scenes,
        stretches=stretches,
        burns=burns,
        dv_total_km_s=spent,
        notes=notes,
        timings_s={"total": time.perf_counter() - clock0},
        initial_state=(r0, v0),
        pole=pole,
        flown=flown,
    )


def _reaim(
    scene: CampaignScene,
    shift_s: float,
    start: tuple[float, Vec, Vec],
    target: Trajectory,
    pole: Pole,
    index: int,
    ghost: Trajectory | None,
) -> tuple[list[Burn], tuple[float, Vec, Vec]]:
    """Fly ``scene`` again from ``start`` (s in the new campaign's time, state): its height-change burns as planned,
    its phasing burn solved again from the state reached to its aim point at its T_access, and with a return, the
    return again. Returns the burns and the state where the next scene may start."""
    t, r, v = start
    ph = scene.plan.phasing
    assert ph is not None
    out: list[Burn] = []
    t_access = scene.t_access_s - shift_s
    for b in scene.burns:
        tb = b.t_s - shift_s
        if b.kind in ("perigee", "apogee"):
            if tb < t:
                continue  # flown before the measured state
            r, v = _coast((r, v), t, tb, pole)
            dv = np.asarray(b.dv_km_s, float)
            out.append(_burn(tb, dv, r, v, b.kind, index))
            t, v = tb, v + dv
        elif b.kind == "phasing":
            if tb < t:
                raise PlannerError("its phasing burn is before the measured state", field="from")
            r, v = _coast((r, v), t, tb, pole)
            r_t = target.state(t_access)[0][:, 0]
            goal = r_t + np.asarray(ph.standoff_km_vec, float)
            dv, r_end, v_end = retarget(r, v, tb, goal, t_access, ph.lambert_revolutions, ph.low_path, pole)
            out.append(_burn(tb, dv, r, v, "phasing", index))
            t, r, v = t_access, r_end, v_end
    t_dep = t_access + 0.9 * period_s(r, v)
    r, v = propagate_j2(r, v, t, t_dep, pole)
    if ghost is not None:
        back, t_back, state_back, _ = _return((r, v), t_dep, ghost, pole, index)
        out += back
        return out, (t_back, np.asarray(state_back[0]), np.asarray(state_back[1]))
    return out, (t_dep, r, v)
