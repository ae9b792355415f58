"""A campaign: a series of GSA scenes flown one after another by one observer, within a Delta-v budget.

The paper speaks of "a series of GSA scenes": the labelled radar frames of many scenes are the networks'
training data. ``plan_campaign`` plans them in sequence. The campaign's span is searched a stretch at a time
(``scene_span_s``); in each stretch the planner's own Algorithm 1 (``make_plan``) is run from the observer's
state as the previous scene left it, and its cheapest feasible scene is flown, preferring, among those
nearly as cheap, the one whose line of sight is farthest from the scenes already flown (the widest spread
of imaging geometry). A stretch with no feasible scene within the budget is passed over, the observer
coasting through it.

Every manoeuvre is an impulse (``Burn``):

- the height change of Algorithm 1, Step 1, flown as the two tangential burns its cost is reckoned by
  (``height_change_dv_km_s``): at the first perigee after the stretch starts one moves the apogee, at the
  next apogee one moves the perigee;
- the phasing burn of Step 2 (Lambert corrected for J2);
- with ``return_to_orbit``, two more after the fly-by: a Lambert transfer (corrected for J2) back to where
  the observer would have been had it never manoeuvred, and a burn there matching that orbit's velocity.
  The observer is then back on its original orbit, in its original slot.

The observer is carried from scene to scene by the planner's own propagation (two-body + J2 about the
pole of date, ``NumericalJ2Trajectory``). Once planned, the whole burn sequence is flown again from the
campaign's start as one trajectory (``fly``), and each scene's separation, line-of-sight rate,
illumination and closest approach are measured on it (``SceneCheck``); tests/planner/test_campaign.py
checks that flight against an independent integrator.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from datetime import datetime
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from planner.alignment import Candidate
from planner.constants import MU_EARTH_KM3_S2
from planner.elements import elements_of_state, state_to_elements
from planner.errors import PlannerError, PlanningStopped, SearchRangeError
from planner.illumination import phase_angle_deg, sun_position_km, sunlit
from planner.lambert import lambert
from planner.manoeuvre import RelativeMotion, best_lambert, period_s, relative_motion, retarget, rtn_matrix
from planner.orbits import Orbit, earth_frames, trajectory
from planner.plan import (
    CandidateOrder,
    Feasibility,
    Plan,
    PlanOptions,
    StopCheck,
    make_plan,
    rank_candidates,
    stations_of,
)
from planner.propagation import (
    NumericalJ2Trajectory,
    Pole,
    Station,
    Trajectory,
    as_utc,
    pole_of_date,
    propagate_j2,
    seconds_between,
    utc,
)
from planner.search import grid_maxima

Vec = NDArray[np.float64]
MAX_CAMPAIGN_S = 90 * 86400.0
MAX_SCENE_SPAN_S = 30 * 86400.0  # one stretch is one plan: at most the planner's 30 days
# A scene within NEAR_FACTOR x the cheapest feasible one's Delta-v (+ NEAR_MARGIN_KM_S) counts as nearly as cheap;
# among those, the line of sight farthest from the scenes already flown is preferred.
NEAR_FACTOR = 1.25
NEAR_MARGIN_KM_S = 0.005
CAMPAIGN_MARGIN_S = 2 * 86400.0  # the flight and the target run this far past the span (the last scene's return)
RETURN_REVOLUTIONS = (1, 2, 4, 8, 15)  # the return transfer's revolutions: the cheapest is flown
RETURN_SHIFTS = tuple(np.linspace(-0.5, 0.5, 25))  # where on the original orbit it returns to, in its periods
BurnKind = Literal["apogee", "perigee", "phasing", "return", "arrival"]
Progress = Callable[[float, str], None]


@dataclass(frozen=True, slots=True)
class Burn:
    """One impulsive manoeuvre: its time (s after the campaign's epoch), its impulse in GCRS and in the
    observer's radial / along-track / normal frame at the burn (km/s), its kind and its scene."""

    t_s: float
    dv_km_s: tuple[float, float, float]
    dv_rtn_km_s: tuple[float, float, float]
    kind: BurnKind
    scene: int

    @property
    def dv_total_km_s(self) -> float:
        return float(np.linalg.norm(self.dv_km_s))


@dataclass(frozen=True, slots=True)
class CampaignOptions:
    """What a campaign takes besides the orbits and the station.

    ``plan`` carries the per-scene settings (optics, box, stand-off, misses; its ``start``, ``duration_s``,
    ``max_dv_m_s`` and ``criterion`` are the campaign's to set). ``start`` defaults to the target's epoch.
    """

    start: datetime | None = None
    duration_s: float = 60 * 86400.0
    dv_budget_m_s: float = 1000.0
    return_to_orbit: bool = False
    scene_span_s: float = 10 * 86400.0
    max_scenes: int = 20
    plan: PlanOptions = field(default_factory=PlanOptions)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.duration_s) and self.duration_s > 0):
            raise SearchRangeError(f"duration {self.duration_s} s must be positive", field="duration_days")
        if self.duration_s > MAX_CAMPAIGN_S:
            raise SearchRangeError(
                f"duration {self.duration_s / 86400.0:.2f} days is over the 90-day limit of a campaign",
                field="duration_days",
            )
        if not (math.isfinite(self.dv_budget_m_s) and self.dv_budget_m_s >= 0.0):
            raise SearchRangeError(
                f"dv_budget_m_s {self.dv_budget_m_s} must be a non-negative number of m/s", field="dv_budget_m_s"
            )
        if not (math.isfinite(self.scene_span_s) and 86400.0 <= self.scene_span_s <= MAX_SCENE_SPAN_S):
            raise SearchRangeError(
                f"scene_span {self.scene_span_s / 86400.0:g} days is outside [1, 30] days", field="scene_span_days"
            )
        if not 1 <= self.max_scenes <= 100:
            raise SearchRangeError(f"max_scenes {self.max_scenes} is outside [1, 100]", field="max_scenes")
        if self.plan.reading != "osculating":
            raise PlannerError(
                "a campaign carries the observer's state from scene to scene, which only the osculating "
                "reading (numerical propagation) follows: use reading 'osculating'",
                field="reading",
            )


@dataclass(frozen=True, slots=True)
class SceneCheck:
    """A scene measured on the whole flown burn sequence: at T_access the observer's distance from the target,
    the line of sight's rate as the observer sees it, the target's illumination and Sun phase angle; the
    closest approach from the phasing burn to one orbit after T_access."""

    separation_km: float
    target_angular_rate_deg_s: float
    sunlit: bool
    phase_angle_deg: float
    closest_approach_km: float
    closest_approach_s: float
    relative: RelativeMotion | None = None  # the fly-by about T_access in the target's RTN frame, as flown


@dataclass(frozen=True, slots=True)
class CampaignScene:
    """One flown scene. ``plan`` is its stretch's plan (times in it are seconds after ``plan.epoch``, which is
    ``offset_s`` after the campaign's epoch); every other time is seconds after the campaign's epoch.

    ``feasibility`` is the plan's own (verified from its phasing burn); ``check`` the same scene measured on the
    whole flown sequence. ``dv_total_km_s`` is the sum of the scene's burns (height change, phasing, return).
    """

    index: int
    plan: Plan
    offset_s: float
    t_access_s: float
    burns: tuple[Burn, ...]
    dv_total_km_s: float
    feasibility: Feasibility
    slot_shift_s: float | None = None  # with return_to_orbit: how far along its original orbit it returned to
    check: SceneCheck | None = None
    reaimed: bool = False  # re-aimed by a re-plan (``planner.closed_loop``) from a measured state


@dataclass(frozen=True, slots=True)
class Stretch:
    """One stretch of the span searched for a scene: its bounds (s after the campaign's epoch), how many
    candidates it held and how many were feasible, the scene flown from it (None: none), and why not."""

    t0_s: float
    t1_s: float
    candidates: int
    feasible: int
    scene: int | None
    note: str
    plan: Plan | None = None  # the stretch's plan (its access windows, its candidates)


@dataclass(frozen=True, slots=True)
class Campaign:
    """A planned campaign; times are seconds after ``epoch`` (UTC)."""

    epoch: datetime
    duration_s: float
    options: CampaignOptions
    scenes: list[CampaignScene]
    stretches: list[Stretch]
    burns: list[Burn]
    dv_total_km_s: float
    notes: list[str]
    timings_s: dict[str, float]
    initial_state: tuple[Vec, Vec]
    pole: Pole
    flown: FlownTrajectory | None = None


class FlownTrajectory:
    """The observer through a sequence of impulsive burns: one two-body + J2 integration between burns.

    ``state(t)`` at a burn's own instant gives the state just after it. ``exact(t)`` integrates from the
    start of the piece holding ``t`` to ``t`` itself, where ``state`` interpolates between the integrator's
    steps (to a few cm and 0.5 mm/s: too coarse to chain burns on). Built by ``fly`` and ``height_change``.
    """

    def __init__(
        self, starts: Sequence[tuple[float, Vec, Vec]], pieces: Sequence[Trajectory], t1_s: float, pole: Pole | None
    ) -> None:
        self.initial = list(starts)
        self.starts = np.array([s[0] for s in starts], float)
        self.pieces = list(pieces)
        self.t0_s, self.t1_s = float(self.starts[0]), float(t1_s)
        self.pole = pole

    def state(self, t_s: ArrayLike) -> tuple[Vec, Vec]:
        t = np.atleast_1d(np.asarray(t_s, float))
        k = np.clip(np.searchsorted(self.starts, t, side="right") - 1, 0, len(self.pieces) - 1)
        r = np.empty((3, t.size))
        v = np.empty((3, t.size))
        for j in np.unique(k):
            sel = k == j
            r[:, sel], v[:, sel] = self.pieces[int(j)].state(t[sel])
        return r, v

    def exact(self, t_s: float) -> tuple[Vec, Vec]:
        """The state at ``t_s`` (just before a burn there) integrated from its piece's start, shape (3,)."""
        k = max(0, int(np.searchsorted(self.starts, t_s, side="left")) - 1)
        t0, r0, v0 = self.initial[k]
        return propagate_j2(r0, v0, t0, t_s, self.pole) if t_s > t0 else (r0, v0)


def fly(
    r0_km: Vec, v0_km_s: Vec, t0_s: float, t1_s: float, burns: Sequence[tuple[float, Vec]], pole: Pole | None
) -> FlownTrajectory:
    """Integrate two-body + J2 about ``pole`` from ``(r0, v0)`` at ``t0_s`` to ``t1_s``, adding each burn's impulse
    (``(t_s, dv_km_s)``, within the span) at its moment."""
    starts, pieces = [(t0_s, np.asarray(r0_km, float), np.asarray(v0_km_s, float))], []
    r, v, t = starts[0][1], starts[0][2], t0_s
    for t_burn, dv in sorted(burns, key=lambda b: b[0]):
        if not t0_s <= t_burn <= t1_s:
            raise PlannerError(f"a burn at {t_burn:.1f} s is outside the flown span {t0_s:.1f}..{t1_s:.1f} s")
        piece = NumericalJ2Trajectory(r, v, t, t_burn, pole=pole)
        pieces.append(piece)
        rs, vs = piece.state(t_burn)  # the integration's own last step: exact, not interpolated
        r, v, t = rs[:, 0], vs[:, 0] + np.asarray(dv, float), t_burn
        starts.append((t, r, v))
    pieces.append(NumericalJ2Trajectory(r, v, t, t1_s, pole=pole))
    return FlownTrajectory(starts, pieces, t1_s, pole)


def _apsis(traj: Trajectory, t0_s: float, t1_s: float, highest: bool) -> float:
    """The moment of least (or greatest) radius within ``[t0_s, t1_s]``, refined to a millisecond."""

    def f(t_s: Vec) -> Vec:
        r, _ = traj.state(t_s)
        d = np.linalg.norm(r, axis=0)
        return d if highest else -d

    t = np.linspace(t0_s, t1_s, int(math.ceil((t1_s - t0_s) / 20.0)) + 1)
    values = f(t)
    t_ext, v_ext = grid_maxima(f, t, values, 1e-3)
    if t_ext.size and v_ext.max() >= values.max():
        return float(t_ext[int(np.argmax(v_ext))])
    return float(t[int(np.argmax(values))])


def height_change(
    r0_km: Vec,
    v0_km_s: Vec,
    base: Trajectory,
    t0_s: float,
    t1_s: float,
    delta_ha_km: float,
    delta_hp_km: float,
    pole: Pole | None,
) -> tuple[FlownTrajectory, float, list[tuple[float, Vec, BurnKind]]]:
    """Fly Algorithm 1's height change from ``(r0, v0)`` at ``t0_s`` (``base``: the same, unburnt): two tangential
    burns.

    At the first perigee after ``t0_s`` one burn moves the apogee by ``delta_ha_km``; at the next apogee
    another moves the perigee by ``delta_hp_km`` (each apsis as the osculating orbit just before the burn has
    it; vis-viva for each burn's speed, as ``height_change_dv_km_s`` reckons the cost). Returns the changed
    observer over ``[t0_s, t1_s]``, the moment the change is done, and the burns (a zero one left out).
    """
    start = (t0_s, np.asarray(r0_km, float), np.asarray(v0_km_s, float))
    if delta_ha_km == 0.0 and delta_hp_km == 0.0:
        return FlownTrajectory([start], [base], t1_s, pole), t0_s, []
    period = period_s(start[1], start[2])
    t_p = _apsis(base, t0_s + 1.0, t0_s + period, highest=False)
    r, v = propagate_j2(start[1], start[2], t0_s, t_p, pole)
    dv1 = _tangential(r, v, _apsides_km(r, v)[1], delta_ha_km)
    after = NumericalJ2Trajectory(r, v + dv1, t_p, t1_s, pole=pole)
    t_a = _apsis(after, t_p + 0.3 * period, t_p + 0.8 * period, highest=True)
    r2, v2 = propagate_j2(r, v + dv1, t_p, t_a, pole)
    dv2 = _tangential(r2, v2, _apsides_km(r2, v2)[0], delta_hp_km)
    last = NumericalJ2Trajectory(r2, v2 + dv2, t_a, t1_s, pole=pole)
    burns: list[tuple[float, Vec, BurnKind]] = [(t_p, dv1, "perigee"), (t_a, dv2, "apogee")]
    kept = [b for b in burns if float(np.linalg.norm(b[1])) > 0.0]
    changed = FlownTrajectory([start, (t_p, r, v + dv1), (t_a, r2, v2 + dv2)], [base, after, last], t1_s, pole)
    return changed, t_a, kept


def _apsides_km(r_km: Vec, v_km_s: Vec) -> tuple[float, float]:
    """The perigee and apogee radii of the osculating two-body orbit of a state."""
    a, e, *_ = (float(x) for x in state_to_elements(r_km, v_km_s))
    return a * (1.0 - e), a * (1.0 + e)


def _tangential(r_km: Vec, v_km_s: Vec, other_apsis_km: float, change_km: float) -> Vec:
    """The tangential impulse at ``r_km`` (an apsis) that moves the other apsis, now at ``other_apsis_km``, by
    ``change_km``: the difference of the vis-viva speeds there for the two orbits (zero for no change, even
    where J2 keeps the burn's point off the osculating apsis by a few km)."""
    rn = float(np.linalg.norm(r_km))

    def speed(other_km: float) -> float:
        return math.sqrt(MU_EARTH_KM3_S2 * (2.0 / rn - 2.0 / (rn + other_km)))

    vhat = v_km_s / float(np.linalg.norm(v_km_s))
    return np.asarray((speed(other_apsis_km + change_km) - speed(other_apsis_km)) * vhat, float)


def spread_order(previous: Sequence[tuple[float, float, float]]) -> CandidateOrder:
    """The campaign's order of a stretch's candidates: feasible first, cheapest first, except that among the
    feasible ones nearly as cheap as the cheapest (``NEAR_FACTOR``, ``NEAR_MARGIN_KM_S``) the one whose line of
    sight (in the target's radial / along-track / normal frame) is farthest from every scene flown so far
    comes first."""
    before = np.array(previous, float).reshape(-1, 3)

    def order(candidates: list[Candidate], feas: list[Feasibility]) -> list[int]:
        ranked = rank_candidates(feas, "least_dv")
        feasible = [k for k in ranked if feas[k].feasible and math.isfinite(feas[k].dv_total_km_s)]
        if not feasible or not before.size:
            return ranked
        cheapest = feas[feasible[0]].dv_total_km_s
        near = [k for k in feasible if feas[k].dv_total_km_s <= NEAR_FACTOR * cheapest + NEAR_MARGIN_KM_S]

        def least_angle(k: int) -> float:
            los = feas[k].line_of_sight_rtn
            if los is None:
                return 0.0
            return float(np.degrees(np.arccos(np.clip(before @ np.asarray(los), -1.0, 1.0))).min())

        near.sort(key=lambda k: -least_angle(k))
        return near + [k for k in ranked if k not in near]

    return order


def _burn(t_s: float, dv: Vec, r: Vec, v: Vec, kind: BurnKind, scene: int) -> Burn:
    """A burn of ``dv`` at ``t_s`` from the state ``(r, v)`` just before it."""
    rtn = rtn_matrix(r, v) @ dv
    return Burn(
        float(t_s),
        (float(dv[0]), float(dv[1]), float(dv[2])),
        (float(rtn[0]), float(rtn[1]), float(rtn[2])),
        kind,
        scene,
    )


class Shifted:
    """A trajectory with its time counted from ``offset_s`` later (a stretch's seconds from the campaign's)."""

    def __init__(self, traj: Trajectory, offset_s: float) -> None:
        self.traj, self.offset_s = traj, offset_s

    def state(self, t_s: ArrayLike) -> tuple[Vec, Vec]:
        return self.traj.state(np.asarray(t_s, float) + self.offset_s)


def _shifted(pole: Pole, offset_s: float) -> Pole:
    """The same pole, its time counted from ``offset_s`` later."""
    return Pole(pole.t_mid_s - offset_s, pole.c)


def plan_campaign(
    target: Orbit,
    observer: Orbit,
    station: Station | Sequence[Station],
    options: CampaignOptions | None = None,
    stop: StopCheck | None = None,
    progress: Progress | None = None,
) -> Campaign:
    """Plan a campaign of GSA scenes (see the module's docstring).

    ``stop`` is asked between stretches and inside each stretch's plan; ``progress(fraction, what)`` is told
    after each stretch. Bad input in the first stretch raises PlannerError naming the field; a later
    stretch's failure (the observer's perigee taken too low by a scene, no phasing) ends the campaign there,
    with a note.
    """
    opts = options or CampaignOptions()
    stations = stations_of(station)
    clock0 = time.perf_counter()
    timings: dict[str, float] = {"plans": 0.0, "returns": 0.0, "flight": 0.0}
    notes: list[str] = [*target.notes, *observer.notes]
    epoch = as_utc(opts.start) if opts.start is not None else target.epoch
    end_s = opts.duration_s
    margin = CAMPAIGN_MARGIN_S
    pole = campaign_pole(epoch, observer, end_s)
    frames = earth_frames(epoch, 0.0, 1.0)
    start_state = trajectory(observer, epoch, frames, 0.0, 1.0, "osculating", pole).state(0.0)
    r0, v0 = start_state[0][:, 0], start_state[1][:, 0]
    # The target once over the whole campaign (each stretch would otherwise integrate it again from its epoch).
    target_traj = None
    if target.tle is None:
        target_traj = trajectory(target, epoch, frames, 0.0, end_s + margin, "osculating", pole)
    ghost: Trajectory | None = None
    if opts.return_to_orbit:
        ghost = NumericalJ2Trajectory(r0, v0, 0.0, end_s + margin, pole=pole)
    budget = opts.dv_budget_m_s / 1000.0
    spent = 0.0
    scenes: list[CampaignScene] = []
    stretches: list[Stretch] = []
    burns: list[Burn] = []
    t_free, state = 0.0, (r0, v0)
    while t_free < end_s - 3600.0 and len(scenes) < opts.max_scenes:
        reason = stop() if stop is not None else None
        if reason:
            raise PlanningStopped(f"campaign planning stopped: {reason}", field="campaign")
        offset = float(math.ceil(t_free - 1e-6))
        if offset > t_free:
            state = _coast(state, t_free, offset, pole)
        span = min(opts.scene_span_s, end_s - offset)
        scene_epoch = utc(epoch, offset)
        offset = seconds_between(epoch, scene_epoch)
        left = budget - spent
        share = left / 2.0 if opts.return_to_orbit else left
        clock = time.perf_counter()
        try:
            plan, flown_change = _plan_stretch(
                target,
                observer.name,
                stations,
                state,
                scene_epoch,
                span,
                share,
                scenes,
                opts,
                pole,
                offset,
                stop,
                None if target_traj is None else Shifted(target_traj, offset),
            )
        except PlanningStopped:
            raise
        except PlannerError as exc:
            if not scenes and not stretches:
                raise
            notes.append(f"the campaign ends at {scene_epoch:%Y-%m-%d %H:%M}: {exc}")
            break
        finally:
            timings["plans"] += time.perf_counter() - clock
        n_feasible = sum(f.feasible for f in plan.feasibility)
        chosen = plan.chosen_feasibility
        if plan.chosen is None or plan.phasing is None or chosen is None or not chosen.feasible:
            note = _why_none(plan, left)
            stretches.append(Stretch(offset, offset + span, len(plan.candidates), n_feasible, None, note, plan))
            state = _coast(state, offset, offset + span, pole)
            t_free = offset + span
            if progress:
                progress(min(1.0, t_free / end_s), f"{len(scenes)} scene(s) planned")
            continue
        index = len(scenes)
        change_traj, change_burns = flown_change[(plan.chosen.delta_ha_km, plan.chosen.delta_hp_km)]
        scene_burns = [_burn(t + offset, dv, *change_traj.exact(t), kind, index) for t, dv, kind in change_burns]
        # The phasing burn again, from the exactly integrated state (the plan's is read between integrator steps,
        # 0.5 mm/s off, which grows to km over a campaign's scenes), to the plan's own aim point.
        ph = plan.phasing
        assert plan.target_trajectory is not None
        scene_pole = _shifted(pole, offset)
        r_b, v_b = change_traj.exact(ph.t_burn_s)
        goal = plan.target_trajectory.state(ph.t_access_s)[0][:, 0] + np.asarray(ph.standoff_km_vec, float)
        dv_ph, _, _ = retarget(
            r_b, v_b, ph.t_burn_s, goal, ph.t_access_s, ph.lambert_revolutions, ph.low_path, scene_pole
        )
        scene_burns.append(_burn(ph.t_burn_s + offset, dv_ph, r_b, v_b, "phasing", index))
        t_access = plan.chosen.t_access_s + offset
        t_dep = plan.chosen.t_access_s + 0.9 * period_s(r_b, v_b + dv_ph)
        after = propagate_j2(r_b, v_b + dv_ph, ph.t_burn_s, t_dep, scene_pole)
        next_free = t_dep + offset
        slot_shift = None
        clock = time.perf_counter()
        if opts.return_to_orbit:
            assert ghost is not None
            try:
                back, t_back, state_back, slot_shift = _return(after, t_dep + offset, ghost, pole, index)
            except PlannerError as exc:
                timings["returns"] += time.perf_counter() - clock
                notes.append(f"the campaign ends after scene {index}: no return to the original orbit ({exc})")
                break
            scene_burns += back
            after, next_free = state_back, t_back
        timings["returns"] += time.perf_counter() - clock
        dv_scene = sum(b.dv_total_km_s for b in scene_burns)
        if spent + dv_scene > budget:  # its return made it dearer than what is left: coast on past it
            note = (
                f"the stretch's best scene needs {dv_scene * 1000.0:.1f} m/s"
                f"{' with its return' if opts.return_to_orbit else ''}, over the {left * 1000.0:.1f} m/s left"
            )
            stretches.append(Stretch(offset, offset + span, len(plan.candidates), n_feasible, None, note, plan))
            state = _coast(state, offset, offset + span, pole)
            t_free = offset + span
            continue
        spent += dv_scene
        burns += scene_burns
        scenes.append(CampaignScene(index, plan, offset, t_access, tuple(scene_burns), dv_scene, chosen, slot_shift))
        stretches.append(Stretch(offset, next_free, len(plan.candidates), n_feasible, index, "scene flown", plan))
        t_free, state = next_free, (np.asarray(after[0]), np.asarray(after[1]))
        if progress:
            progress(min(1.0, t_free / end_s), f"{len(scenes)} scene(s) planned")
    if len(scenes) == opts.max_scenes:
        notes.append(f"the campaign stops at max_scenes {opts.max_scenes}")
    if not scenes:
        notes.append("no feasible scene within the budget anywhere in the span; each stretch says why")
    clock = time.perf_counter()
    flown = fly(r0, v0, 0.0, end_s + margin, [(b.t_s, np.asarray(b.dv_km_s)) for b in burns], pole)
    scenes = [replace(s, check=check_scene(s, flown, epoch)) for s in scenes]
    timings["flight"] = time.perf_counter() - clock
    timings["total"] = time.perf_counter() - clock0
    return Campaign(
        epoch=epoch,
        duration_s=end_s,
        options=opts,
        scenes=scenes,
        stretches=stretches,
        burns=burns,
        dv_total_km_s=spent,
        notes=notes,
        timings_s=timings,
        initial_state=(r0, v0),
        pole=pole,
        flown=flown,
    )


def campaign_pole(epoch: datetime, observer: Orbit, duration_s: float) -> Pole:
    """The one pole of date a campaign's J2 acts about: fitted from the observer's epoch (or the start) to past
    the span's end."""
    return pole_of_date(epoch, min(0.0, seconds_between(epoch, observer.epoch)), duration_s + CAMPAIGN_MARGIN_S)


def _coast(state: tuple[Vec, Vec], t0_s: float, t1_s: float, pole: Pole) -> tuple[Vec, Vec]:
    """The observer's state at ``t1_s`` after coasting (no burn) from ``state`` at ``t0_s`` (a microsecond or less,
    under 1 cm: none; the integrator cannot step that short)."""
    if t1_s - t0_s <= 1e-6:
        return state
    return propagate_j2(state[0], state[1], t0_s, t1_s, pole)


def _plan_stretch(
    target: Orbit,
    name: str,
    station: tuple[Station, ...],
    state: tuple[Vec, Vec],
    scene_epoch: datetime,
    span_s: float,
    max_dv_km_s: float,
    scenes: list[CampaignScene],
    opts: CampaignOptions,
    pole: Pole,
    offset_s: float,
    stop: StopCheck | None,
    target_traj: Trajectory | None,
) -> tuple[Plan, dict[tuple[float, float], tuple[FlownTrajectory, list[tuple[float, Vec, BurnKind]]]]]:
    """Plan one stretch from the observer's carried state: Algorithm 1 with the height change flown as burns."""
    carried = Orbit(name, elements=elements_of_state(state[0], state[1], scene_epoch))
    scene_pole = _shifted(pole, offset_s)
    t_end = span_s + 86400.0 + 600.0  # past make_plan's own end (the span, an observer orbit, 600 s)
    base = NumericalJ2Trajectory(state[0], state[1], 0.0, t_end, pole=scene_pole)
    flown: dict[tuple[float, float], tuple[FlownTrajectory, list[tuple[float, Vec, BurnKind]]]] = {}

    def changed(delta_ha_km: float, delta_hp_km: float) -> tuple[Trajectory, float]:
        traj, ready, burns = height_change(state[0], state[1], base, 0.0, t_end, delta_ha_km, delta_hp_km, scene_pole)
        flown[(delta_ha_km, delta_hp_km)] = (traj, burns)
        return traj, ready

    plan_opts = replace(
        opts.plan,
        start=scene_epoch,
        duration_s=span_s,
        max_dv_m_s=max_dv_km_s * 1000.0,
        criterion="least_dv",
    )
    previous = [s.feasibility.line_of_sight_rtn for s in scenes if s.feasibility.line_of_sight_rtn is not None]
    plan = make_plan(
        target,
        carried,
        station,
        plan_opts,
        stop,
        changed=changed,
        order=spread_order(previous),
        pole=scene_pole,
        target_trajectory=target_traj,
    )
    return plan, flown


def _return(
    state: tuple[Vec, ...], t_dep_s: float, ghost: Trajectory, pole: Pole, index: int
) -> tuple[list[Burn], float, tuple[Vec, Vec], float]:
    """The cheapest return to the original orbit from ``state`` at ``t_dep_s``: a Lambert transfer of
    ``RETURN_REVOLUTIONS`` revolutions to where the never-manoeuvred observer (``ghost``) is ``shift`` seconds
    later (``RETURN_SHIFTS`` of its period, either way: the slot may move, the orbit may not, up to the plane's
    J2 drift over the shift), corrected for J2, and a burn there matching that state's velocity.

    Chosen by the two-body cost over every revolution count and shift, then flown from the exact state.
    Returns the two burns, the arrival time, the state just after arriving and the slot's shift (s).
    """
    r, v = np.asarray(state[0], float), np.asarray(state[1], float)
    r_g0, v_g0 = (x[:, 0] for x in ghost.state(t_dep_s))
    p = period_s(r_g0, v_g0)
    best: tuple[float, float, float, int, bool] | None = None
    for k in RETURN_REVOLUTIONS:
        t_arr = t_dep_s + k * p
        shifts = np.asarray(RETURN_SHIFTS) * p
        r_g, v_g = ghost.state(t_arr + shifts)
        for j, shift in enumerate(shifts):
            try:
                v_dep, m, low = best_lambert(r, v, r_g[:, j], t_arr - t_dep_s)
                v_arr = lambert(r, r_g[:, j], t_arr - t_dep_s, m, low, prograde_normal=np.cross(r, v)).v2_km_s
            except PlannerError:
                continue
            cost = float(np.linalg.norm(v_dep - v) + np.linalg.norm(v_g[:, j] - v_arr))
            if best is None or cost < best[0]:
                best = (cost, t_arr, float(shift), m, low)
    if best is None:
        raise PlannerError("no Lambert transfer back to the original orbit", field="return_to_orbit")
    _, t_arr, shift, m, low = best
    r_g, v_g = (x[:, 0] for x in ghost.state(t_arr + shift))
    dv, r_end, v_end = retarget(r, v, t_dep_s, r_g, t_arr, m, low, pole)
    back = [
        _burn(t_dep_s, dv, r, v, "return", index),
        _burn(t_arr, v_g - v_end, r_end, v_end, "arrival", index),
    ]
    return back, t_arr, (r_end, v_g), shift


def check_scene(scene: CampaignScene, flown: Trajectory, epoch: datetime) -> SceneCheck:
    """Measure a scene on the flown burn sequence (``SceneCheck``)."""
    plan = scene.plan
    assert plan.target_trajectory is not None and plan.phasing is not None
    off = scene.offset_s

    def target(t_s: Vec) -> tuple[Vec, Vec]:
        assert plan.target_trajectory is not None
        return plan.target_trajectory.state(np.asarray(t_s) - off)

    t = scene.t_access_s
    r_o, v_o = flown.state(t)
    r_t, v_t = target(np.array([t]))
    rho, rho_dot = (r_t - r_o)[:, 0], (v_t - v_o)[:, 0]
    rate = math.degrees(float(np.linalg.norm(np.cross(rho, rho_dot))) / float(rho @ rho))
    sun = sun_position_km(epoch, t)
    lit = bool(sunlit(r_t, sun)[0])
    phase_deg = float(phase_angle_deg(r_t[:, 0], sun[:, 0], -rho))

    def distance(t_s: Vec) -> Vec:
        ro, _ = flown.state(t_s)
        rt, _ = target(t_s)
        return np.asarray(np.linalg.norm(ro - rt, axis=0), float)

    t0 = plan.phasing.t_burn_s + off
    p = period_s(r_o[:, 0], v_o[:, 0])
    grid = np.linspace(t0, t + 0.9 * p, int(math.ceil(t + 0.9 * p - t0)) + 1)
    t_min, _ = grid_maxima(lambda x: -distance(x), grid, -distance(grid), 1e-4)
    cand = np.concatenate([t_min, grid[[0, -1]]])
    d = distance(cand)
    j = int(np.argmin(d))
    fly_by = relative_motion(flown.state, target, t, t0, t + 0.9 * p)
    return SceneCheck(float(np.linalg.norm(rho)), rate, lit, phase_deg, float(d[j]), float(cand[j]), fly_by)


def _why_none(plan: Plan, left_km_s: float) -> str:
    """Why a stretch gave no scene, in words: the commonest reasons among its candidates."""
    if not plan.candidates:
        return "no candidate: no pass has an alignment within max_miss_km inside the dHa/dHp box"
    counts: dict[str, int] = {}
    for f in plan.feasibility:
        for reason in f.reasons:
            key = _reason_kind(reason)
            counts[key] = counts.get(key, 0) + 1
    top = sorted(counts.items(), key=lambda kv: -kv[1])[:3]
    said = "; ".join(f"{n} of {len(plan.candidates)}: {what}" for what, n in top)
    return f"no feasible scene within the {left_km_s * 1000.0:.1f} m/s left ({said})"


def _reason_kind(reason: str) -> str:
    """A reason with its numbers taken out, so like reasons count together."""
    if reason.startswith("needs "):
        return "over the budget"
    if "shadow" in reason:
        return "target in Earth's shadow"
    if "deg/s" in reason and "tracker" in reason or "needs >=" in reason:
        return "too fast to track within the optics' range"
    if "phase angle" in reason:
        return "Sun phase angle too large"
    if "from the Sun" in reason:
        return "inside the Sun exclusion"
    if "re-enter" in reason:
        return "the phasing transfer re-enters"
    if "keyhole" in reason:
        return "radar keyhole"
    if "min_elevation_deg" in reason:
        return "radar under its elevation limit"
    if "max_integration_s" in reason:
        return "radar's integration too long"
    if "cross-range would alias" in reason:
        return "radar's integration too short for its pulses"
    if "min_snr_db" in reason:
        return "radar SNR too low"
    if "collision" in reason:
        return "closest approach too near"
    return reason.split(":")[0]
