"""The whole of Algorithm 1: access windows, node alignment, phasing, verification and feasibility.

``make_plan`` joins the pure pieces; it is the one function the service and the
command line call.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from datetime import datetime, timedelta
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from planner.access import MAX_SPAN_S, AccessWindows, merge_windows, network_access, validate_station
from planner.alignment import Candidate, HeightBox, ObserverPlaneModel, align_nodes
from planner.constants import MIN_PERIGEE_HEIGHT_KM, MU_EARTH_KM3_S2, R_EARTH_KM
from planner.elements import Elements, height_change_dv_km_s, state_to_elements
from planner.errors import PlannerError, PlanningStopped, SearchRangeError, StationError
from planner.frames import network_radar_view
from planner.illumination import phase_angle_deg, sun_position_km, sunlit
from planner.manoeuvre import Encounter, Phasing, encounter, phase, rtn_matrix
from planner.optics import ObserverOptics, StandoffWindow, standoff_window, sun_angle_deg
from planner.orbits import Orbit, Reading, earth_frames, elements_trajectory, osculating_elements, trajectory
from planner.propagation import (
    EarthFrames,
    Pole,
    Station,
    Trajectory,
    as_utc,
    earth_orientation_note,
    pole_of_date,
    seconds_between,
)
from planner.radar import CrossSection, RadarView, radar_limits
from planner.search import bisect_roots

Vec = NDArray[np.float64]
STANDOFF_RANGE_KM = (0.5, 500.0)  # under 0.5 km the fly-by is a collision risk; over 500 km, no imaging
# J2 corrections of each candidate's screening burn (design/measurements.md, "Screening every candidate's burn")
SCREEN_CORRECTIONS = 1
STANDOFF_ITERATIONS = 4  # a chosen stand-off settles within 0.5 % in two rounds for fast fly-bys, three for slow ones
SHADOW = "target in Earth's shadow"  # the reason an optical observer cannot image an unlit target
Criterion = Literal["smallest_change", "least_dv"]


@dataclass(frozen=True, slots=True)
class PlanOptions:
    """Everything the search takes besides the two orbits and the station.

    ``start`` defaults to the target's epoch; ``duration_s`` to 10 days (at most 30).
    ``reading`` says how Table-1 elements are taken (TLEs always go through SGP4).
    """

    start: datetime | None = None
    duration_s: float = 10 * 86400.0
    reading: Reading = "osculating"
    box: HeightBox = field(default_factory=HeightBox)
    access_step_s: float = 120.0
    sample_s: float = 1.0
    max_miss_km: float = 10.0
    revolutions_before: tuple[int, ...] = (1, 2)
    criterion: Criterion = "least_dv"
    # What the observer images with: its diffraction range, tracking rate, Sun exclusion and largest phase angle.
    optics: ObserverOptics = field(default_factory=ObserverOptics)
    max_imaging_range_km: float | None = None  # a range cap below the optics' own (None: the optics' range)
    standoff_km: float | None = None  # None: chosen within the optics' stand-off window (``standoff_window``)
    min_separation_km: float = 1.0
    max_dv_m_s: float | None = None  # a candidate dearer than this (height change + phasing) is infeasible
    max_tle_age_days: float = 30.0
    # The target's mean radar cross section by aspect (``planner.radar.CrossSection``; the service gives the served
    # target model's): None leaves the radar's SNR uncomputed (NaN) and unchecked.
    cross_section: CrossSection | None = None

    def __post_init__(self) -> None:
        if not (math.isfinite(self.duration_s) and self.duration_s > 0):
            raise SearchRangeError(f"duration {self.duration_s} s must be positive", field="duration_s")
        if self.duration_s > MAX_SPAN_S:
            raise SearchRangeError(
                f"duration {self.duration_s / 86400.0:.2f} days is over the 30-day limit", field="duration_s"
            )
        if self.reading not in ("osculating", "mean"):
            raise PlannerError(f"reading {self.reading!r} must be 'osculating' or 'mean'", field="reading")
        if not all(k in (1, 2) for k in self.revolutions_before) or not self.revolutions_before:
            raise PlannerError("revolutions_before must be a non-empty subset of (1, 2)", field="revolutions_before")
        for name, least in (("access_step_s", 0.001), ("sample_s", 0.001), ("max_miss_km", 0.001)):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= least):
                raise SearchRangeError(f"{name} {value} must be a number of at least {least:g}", field=name)
        if self.max_dv_m_s is not None and not (math.isfinite(self.max_dv_m_s) and self.max_dv_m_s >= 0.0):
            raise SearchRangeError(f"max_dv_m_s {self.max_dv_m_s} must be a non-negative number", field="max_dv_m_s")
        cap = self.max_imaging_range_km
        if cap is not None and not (math.isfinite(cap) and cap >= 0.001):
            raise SearchRangeError(
                f"max_imaging_range_km {cap} must be a number of at least 0.001 km", field="max_imaging_range_km"
            )
        d = self.standoff_km
        if d is not None and not (math.isfinite(d) and STANDOFF_RANGE_KM[0] <= d <= STANDOFF_RANGE_KM[1]):
            raise SearchRangeError(
                f"standoff_km {d} is outside [{STANDOFF_RANGE_KM[0]}, {STANDOFF_RANGE_KM[1]}] km", field="standoff_km"
            )
        if not (math.isfinite(self.min_separation_km) and 0.0 <= self.min_separation_km <= 100.0):
            raise SearchRangeError(
                f"min_separation_km {self.min_separation_km} is outside [0, 100] km", field="min_separation_km"
            )
        if d is not None and self.min_separation_km > d:
            raise SearchRangeError(
                f"min_separation_km {self.min_separation_km} is above standoff_km {d}: "
                "every plan would be refused; lower it or raise standoff_km",
                field="min_separation_km",
            )
        if self.access_step_s > 300.0:
            raise SearchRangeError("access_step_s above 300 s can miss short passes", field="access_step_s")
        if self.sample_s > 60.0:
            raise SearchRangeError("sample_s must be at most 60 s", field="sample_s")


@dataclass(frozen=True, slots=True)
class Feasibility:
    """Whether one candidate can be flown and imaged, at what cost, and why not.

    Every candidate is screened by its own phasing (Lambert to its own stand-off, corrected once for J2:
    ``screen``); the chosen one's figures are then the verified ones (the burn corrected until it meets
    its aim, the encounter flown over the whole arc). NaN where a candidate could not be phased.
    ``dv_total_km_s`` is the height change plus the phasing burn.
    """

    sunlit: bool
    observer_range_km: float
    phase_angle_deg: float
    feasible: bool
    reasons: tuple[str, ...]
    sun_angle_deg: float = math.nan  # the boresight's angle from the Sun, seen from the observer
    dv_total_km_s: float = math.nan
    standoff_km: float = math.nan
    relative_speed_km_s: float = math.nan
    target_angular_rate_deg_s: float = math.nan
    # The unit vector from the target to the observer at T_access in the target's radial / along-track / normal
    # frame: the imaging geometry, the side of the target the observer sees (None where not phased).
    line_of_sight_rtn: tuple[float, float, float] | None = None
    # The perigee height of the orbit the phasing burn puts the observer on, km (under MIN_PERIGEE_HEIGHT_KM it
    # re-enters: infeasible, and ranked after every candidate that does not).
    transfer_perigee_km: float = math.nan
    # The radar at T_access (``planner.radar``): its elevation, slant range, the SNR the radar equation gives over the
    # integration with the target's mean cross section there, and the time its line of sight takes to sweep the
    # image's aperture relative to the target (held in LVLH).
    radar_elevation_deg: float = math.nan
    radar_range_km: float = math.nan
    radar_snr_db: float = math.nan
    isar_integration_s: float = math.nan
    radar_cross_section_m2: float = math.nan

    @property
    def reenters(self) -> bool:
        return bool(self.transfer_perigee_km < MIN_PERIGEE_HEIGHT_KM)


def line_of_sight_rtn(r_target_km: Vec, v_target_km_s: Vec, rho_km: Vec) -> tuple[float, float, float]:
    """The unit vector along ``rho_km`` (target to observer, GCRS) in the target's radial / along-track / normal axes."""
    u = rtn_matrix(r_target_km, v_target_km_s) @ (rho_km / np.linalg.norm(rho_km))
    return float(u[0]), float(u[1]), float(u[2])


@dataclass(frozen=True, slots=True)
class Plan:
    """A complete plan; times are seconds after ``epoch`` (UTC)."""

    epoch: datetime
    duration_s: float
    reading: Reading
    windows: AccessWindows
    candidates: list[Candidate]
    feasibility: list[Feasibility]
    chosen_index: int | None
    chosen: Candidate | None
    alignment_dv_km_s: float | None
    step1_miss_km: float | None
    phasing: Phasing | None
    chosen_feasibility: Feasibility | None
    timings_s: dict[str, float]
    notes: list[str]
    target_trajectory: Trajectory | None = None
    observer_trajectory: Trajectory | None = None
    frames: EarthFrames | None = None
    station: Station | None = None  # the chosen candidate's station (the first of a network without one)
    encounter: Encounter | None = None
    stations: tuple[Station, ...] = ()  # every station searched; ``windows.station`` indexes it


def tle_age_notes(orbits: tuple[Orbit, ...], start: datetime, duration_s: float, max_age_days: float) -> list[str]:
    """Return a note for each TLE older (or younger) than ``max_age_days`` anywhere in the span.

    SGP4's error grows by about 1-3 km a day from the epoch for LEO: far from it the windows
    and the plan describe no real pass.
    """
    notes = []
    end = start + timedelta(seconds=duration_s)
    for orbit in orbits:
        if orbit.tle is None:
            continue
        age_days = max(abs((start - orbit.epoch).total_seconds()), abs((end - orbit.epoch).total_seconds())) / 86400.0
        if age_days > max_age_days:
            notes.append(
                f"{orbit.name}: the TLE's epoch {orbit.epoch:%Y-%m-%d} is {age_days:.0f} days from the span's far end, "
                f"over {max_age_days:g} days; SGP4 drifts 1-3 km a day, so use a fresher TLE"
            )
    return notes


COPLANAR_DEG = 0.01  # 1.2 km out of plane at 7000 km: below it the line of nodes is not defined


def check_not_coplanar(target: Trajectory, observer: Trajectory, t1_s: float) -> None:
    """Refuse a target and observer whose orbit planes stay within ``COPLANAR_DEG`` over the span.

    The scene is where the target crosses the observer's plane, on the planes' line of
    nodes; two orbits in one plane (the same orbit, or co-orbital satellites) have no such
    line, so there is no scene to plan.
    """
    t = np.linspace(0.0, t1_s, 5)
    r_t, v_t = target.state(t)
    r_o, v_o = observer.state(t)
    n_t = np.cross(r_t, v_t, axis=0)
    n_o = np.cross(r_o, v_o, axis=0)
    cos = (n_t * n_o).sum(axis=0) / (np.linalg.norm(n_t, axis=0) * np.linalg.norm(n_o, axis=0))
    angle = np.degrees(np.arccos(np.clip(np.abs(cos), -1.0, 1.0)))
    if angle.max() < COPLANAR_DEG:
        raise PlannerError(
            f"the observer's orbit plane stays within {angle.max():.4f} deg of the target's over the span: "
            "the two planes have no line of nodes, so there is no GSA scene; use an observer in another plane",
            field="observer",
        )


def check_planes_apart(target: Orbit, observer: Orbit, start: datetime, span_s: float) -> None:
    """``check_not_coplanar`` of two orbits themselves, osculating over ``span_s`` from ``start``: what a queued
    campaign is checked with before it is queued (the planner checks each stretch so as it plans it)."""
    frames = earth_frames(start, 0.0, span_s)
    pole = pole_of_date(start, 0.0, span_s)
    tgt = trajectory(target, start, frames, 0.0, span_s, "osculating", pole)
    obs = trajectory(observer, start, frames, 0.0, span_s, "osculating", pole)
    check_not_coplanar(tgt, obs, span_s)


def check_box_reachable(elements: Elements, box: HeightBox) -> None:
    """Refuse, before any planning, a (dHa, dHp) box whose corners take the observer's perigee below the limit.

    The lowest perigee in the box is at its (dha_min, dhp_min) corner (the apsides swap when
    the new apogee falls below the new perigee); the error names the box field to raise.
    """
    ha, hp = elements.ha_km + box.dha_min_km, elements.hp_km + box.dhp_min_km
    if min(ha, hp) >= MIN_PERIGEE_HEIGHT_KM:
        return
    field = "dhp_min_km" if hp <= ha else "dha_min_km"
    lowest = min(ha, hp)
    raise SearchRangeError(
        f"{field} takes the observer's perigee to {lowest:.1f} km, below {MIN_PERIGEE_HEIGHT_KM} km "
        f"(observer Ha {elements.ha_km:.1f} km, Hp {elements.hp_km:.1f} km): raise {field}",
        field=field,
    )


StopCheck = Callable[[], str | None]
# The observer after a height change (dHa, dHp), and the first moment (s) a phasing burn may come after it.
ChangedObserver = Callable[[float, float], tuple[Trajectory, float]]
# The order in which the screened candidates are phased (the first that phases is chosen).
CandidateOrder = Callable[[list[Candidate], list[Feasibility]], list[int]]


def make_plan(
    target: Orbit,
    observer: Orbit,
    station: Station | Sequence[Station],
    options: PlanOptions | None = None,
    stop: StopCheck | None = None,
    *,
    changed: ChangedObserver | None = None,
    order: CandidateOrder | None = None,
    pole: Pole | None = None,
    target_trajectory: Trajectory | None = None,
) -> Plan:
    """Plan a GSA scene: access windows, ranked alignments, the phasing burn and its verification.

    The height change is made at the observer's element epoch (for a TLE observer:
    at the plan start, from its SGP4 state). Candidates are ranked by miss, then
    by the size of the change. Within a pass the smallest change is taken. The
    chosen candidate is, by ``criterion``, the best-ranked sunlit one
    (``smallest_change``) or the sunlit one with the least total Delta-v
    (``least_dv``; two-body estimate over all candidates); unlit ones only when none
    is sunlit. It is refined against the changed observer's own propagation, phased
    and verified numerically.

    ``stop`` is asked between steps (and between candidates): when it returns a reason,
    planning stops at once with PlanningStopped. No step runs long: the span is at most
    30 days and the service bounds the epoch's distance from it, so the bound is about a second.

    A campaign plans its scenes through three hooks: ``changed`` gives the observer after a height change
    (default: the elements changed at their epoch, a phasing burn any time after it), ``order`` the order in
    which the screened candidates are phased (default ``rank_candidates``), ``pole`` the pole J2 acts about (default:
    the pole of date fitted over this plan's span), ``target_trajectory`` the target's motion in this plan's
    seconds (default: from ``target`` by ``reading``). With ``changed``, the unchanged observer is ``changed(0, 0)``.
    """
    opts = options or PlanOptions()

    def check(stage: str) -> None:
        reason = stop() if stop is not None else None
        if reason:
            raise PlanningStopped(f"planning stopped during {stage}: {reason}", field="search")

    stations = stations_of(station)
    timings: dict[str, float] = {}
    notes: list[str] = []
    clock = time.perf_counter()
    epoch = as_utc(opts.start) if opts.start is not None else target.epoch
    t1 = opts.duration_s
    # Frames and trajectories reach past the span: the encounter is followed for one
    # observer orbit after T_access (at most a day for any Earth orbit planned here).
    frames = earth_frames(epoch, 0.0, t1 + 2 * 86400.0)
    eop_note = earth_orientation_note(epoch, 0.0, t1)
    if eop_note:
        notes.append(eop_note)
    notes += tle_age_notes((target, observer), epoch, t1, opts.max_tle_age_days)
    notes += [*target.notes, *observer.notes]
    obs_el = osculating_elements(observer, epoch, frames)
    check_box_reachable(obs_el, opts.box)
    # One pole of date for the plan: J2 acts about it in every propagation and verification.
    t_first = min(0.0, seconds_between(epoch, obs_el.epoch), seconds_between(epoch, target.epoch))
    obs_period_s = 2 * math.pi * math.sqrt(obs_el.a_km**3 / MU_EARTH_KM3_S2)
    t_end = t1 + min(obs_period_s, 86400.0) + 600.0
    if pole is None:
        pole = pole_of_date(epoch, t_first, t_end)
    tgt = target_trajectory or trajectory(target, epoch, frames, 0.0, t_end, opts.reading, pole)
    tle_obs = observer.tle is not None
    # A TLE observer's elements are an osculating state: only the numerical propagation reads them right.
    obs_reading: Reading = "osculating" if tle_obs else opts.reading
    if changed is not None:
        obs_base = changed(0.0, 0.0)[0]
    else:
        obs_base = elements_trajectory(obs_el, epoch, 0.0, t_end, obs_reading, pole)
    t_ref = 0.0 if tle_obs else seconds_between(epoch, obs_el.epoch)
    check_not_coplanar(tgt, obs_base, t1)
    timings["propagation"] = time.perf_counter() - clock
    check("propagation")

    clock = time.perf_counter()
    windows = merge_windows(network_access(tgt, stations, frames, 0.0, t1, step_s=opts.access_step_s))
    timings["access"] = time.perf_counter() - clock
    check("the access search")

    clock = time.perf_counter()
    a, e, i = obs_el.a_km, obs_el.e, math.radians(obs_el.inclination_deg)
    model = ObserverPlaneModel(obs_base, a, e, i, t_ref, pole.at(max(0.0, t_ref)))
    candidates = align_nodes(tgt, model, windows, opts.box, opts.sample_s, opts.max_miss_km)
    timings["alignment"] = time.perf_counter() - clock
    check("the node alignment")

    # Every candidate is refined against the changed observer's own propagation: the
    # alignment model's nodal-rate sensitivity leaves misses of 0.1-5 km otherwise.
    clock = time.perf_counter()
    cache: dict[tuple[float, float], tuple[Trajectory, float]] = {}
    # A changed observer is needed only up to its last candidate's T_access, plus an orbit for the encounter
    # and the hour or two of track the exports and the plot draw (refinement moves T_access by under a minute).
    horizon: dict[tuple[float, float], float] = {}
    for cand in candidates:
        key = (cand.delta_ha_km, cand.delta_hp_km)
        horizon[key] = max(horizon.get(key, 0.0), cand.t_access_s)

    def by_elements(delta_ha_km: float, delta_hp_km: float) -> tuple[Trajectory, float]:
        if delta_ha_km == 0.0 and delta_hp_km == 0.0:  # no change: the observer as it is, already propagated
            return obs_base, max(0.0, t_ref)
        changed_el = obs_el.with_heights(delta_ha_km, delta_hp_km)
        last = horizon.get((delta_ha_km, delta_hp_km), t_end)
        t_stop = min(t_end, last + max(obs_period_s, 6000.0) + 1200.0)
        return elements_trajectory(changed_el, epoch, 0.0, t_stop, obs_reading, pole), max(0.0, t_ref)

    def changed_and_ready(cand: Candidate) -> tuple[Trajectory, float]:
        key = (cand.delta_ha_km, cand.delta_hp_km)
        if key not in cache:
            cache[key] = (changed or by_elements)(*key)
        return cache[key]

    def changed_observer(cand: Candidate) -> Trajectory:
        return changed_and_ready(cand)[0]

    candidates = _refine_all(candidates, tgt, changed_observer, windows, opts.max_miss_km, check, notes)
    timings["refinement"] = time.perf_counter() - clock

    clock = time.perf_counter()
    lit, feas = _illumination(candidates, tgt, epoch)
    view = network_radar_view(
        tgt,
        stations,
        frames,
        np.array([c.t_access_s for c in candidates]),
        np.array([windows.station_of(c.pass_index) for c in candidates], np.int64),
        opts.cross_section,
    )
    chosen_index = None
    chosen = None
    phasing = None
    step1_miss = None
    alignment_dv = None
    chosen_feas = None
    obs_chosen: Trajectory | None = None
    meet_chosen: Encounter | None = None
    for k, cand in enumerate(candidates):  # every candidate's own cost, stand-off and imaging geometry
        check("the screening of the candidates")
        obs_k, ready = changed_and_ready(cand)
        screened = _with_radar(screen(cand, obs_k, tgt, feas[k], epoch, opts, model, pole, ready), view, k)
        radar = _radar_reasons(cand, windows, stations, view, k)
        feas[k] = replace(screened, feasible=screened.feasible and not radar, reasons=(*screened.reasons, *radar))
    ranked = order(candidates, feas) if order is not None else rank_candidates(feas, opts.criterion)
    if candidates and not lit.any():
        notes.append("no candidate has the target sunlit at T_access; the best unlit one is planned")
    elif candidates and not any(f.feasible for f in feas):
        notes.append("no candidate passes every check in the span; the best one is planned, with its reasons")
    for k in ranked:
        check("the phasing")
        cand = candidates[k]
        obs_new, ready = changed_and_ready(cand)
        t_access = cand.t_access_s
        sun_k = sun_position_km(epoch, t_access)
        try:
            ph, window = _phase_at_standoff(obs_new, tgt, t_access, ready, pole, sun_k[:, 0], opts)
        except PlannerError as exc:
            notes.append(f"candidate {k} skipped: {exc}")
            continue
        chosen_index, phasing, step1_miss, obs_chosen = k, ph, cand.miss_km, obs_new
        chosen = cand
        alignment_dv = float(height_change_dv_km_s(a, e, cand.delta_ha_km, cand.delta_hp_km))
        meet = meet_chosen = encounter(ph, obs_new, tgt, min(t_access + obs_period_s, t_end), pole)
        r_t, v_t = tgt.state(t_access)
        # The line of sight from the target to the observer at T_access: the stand-off vector.
        los = ph.r_observer_km - r_t[:, 0]
        phase_deg = float(phase_angle_deg(r_t[:, 0], sun_k[:, 0], los))
        sun_deg = sun_angle_deg(ph.r_observer_km, r_t[:, 0], sun_k[:, 0])
        dv_total = ph.dv_total_km_s + alignment_dv
        perigee = transfer_perigee_height_km(obs_new, ph)
        reasons = [
            *(() if feas[k].sunlit else (SHADOW,)),
            *_encounter_reasons(meet, phase_deg, sun_deg, opts, window),
            *_dv_reasons(dv_total, opts),
            *_perigee_reasons(perigee),
            *_radar_reasons(cand, windows, stations, view, k),
        ]
        chosen_feas = Feasibility(
            feas[k].sunlit,
            meet.separation_km,
            phase_deg,
            not reasons,
            tuple(reasons),
            sun_deg,
            dv_total,
            float(np.linalg.norm(ph.standoff_km_vec)),
            meet.relative_speed_km_s,
            meet.target_angular_rate_deg_s,
            line_of_sight_rtn(r_t[:, 0], v_t[:, 0], los),
            perigee,
        )
        chosen_feas = feas[k] = _with_radar(chosen_feas, view, k)
        break
    timings["phasing"] = time.perf_counter() - clock
    if not candidates:
        notes.append(
            f"no pass has an alignment within {opts.max_miss_km} km inside the dHa/dHp box; "
            "widen the box, lengthen the span or raise max_miss_km"
        )
    return Plan(
        epoch=epoch,
        duration_s=t1,
        reading=opts.reading,
        windows=windows,
        candidates=candidates,
        feasibility=feas,
        chosen_index=chosen_index,
        chosen=chosen,
        alignment_dv_km_s=alignment_dv,
        step1_miss_km=step1_miss,
        phasing=phasing,
        chosen_feasibility=chosen_feas,
        timings_s=timings,
        notes=notes,
        target_trajectory=tgt,
        observer_trajectory=obs_chosen,
        frames=frames,
        station=stations[windows.station_of(chosen.pass_index)] if chosen is not None else stations[0],
        encounter=meet_chosen,
        stations=stations,
    )


def _refine_all(
    candidates: list[Candidate],
    tgt: Trajectory,
    changed_observer: Callable[[Candidate], Trajectory],
    windows: AccessWindows,
    max_miss_km: float,
    check: Callable[[str], None],
    notes: list[str],
) -> list[Candidate]:
    """Refine every candidate against its changed observer's own propagation; rank them by miss, then by the size
    of the change; leave out (with a note) those that then miss by more than ``max_miss_km``."""
    refined = []
    for cand in candidates:
        check("the refinement of the candidates")
        refined.append(_refined(cand, tgt, changed_observer(cand), windows))
    refined.sort(key=lambda c: (round(c.miss_km, 3), c.change_km, c.t_access_s))
    far = [c for c in refined if c.miss_km > max_miss_km]
    if far:
        notes.append(
            f"{len(far)} candidate(s) left out: refined against the changed observer's propagation, "
            f"they miss by more than max_miss_km {max_miss_km} km"
        )
    return [c for c in refined if c.miss_km <= max_miss_km]


def _illumination(
    candidates: list[Candidate], tgt: Trajectory, epoch: datetime
) -> tuple[NDArray[np.bool_], list[Feasibility]]:
    """Whether the target is sunlit at each candidate's T_access, and each candidate's feasibility so far."""
    lit = np.zeros(0, bool)
    if candidates:
        t_acc = np.array([c.t_access_s for c in candidates])
        r_acc, _ = tgt.state(t_acc)
        lit = sunlit(r_acc, sun_position_km(epoch, t_acc))
    feas = [
        Feasibility(bool(lit[k]), math.nan, math.nan, bool(lit[k]), () if lit[k] else (SHADOW,))
        for k in range(len(candidates))
    ]
    return lit, feas


def rank_candidates(feas: list[Feasibility], criterion: Criterion) -> list[int]:
    """The order in which candidates are phased: those that pass every check first, then the sunlit ones, then
    the rest, in each of the last two those whose transfer stays up before those that re-enter; within each, by
    their screened Delta-v (``least_dv``) or by rank (``smallest_change``)."""

    def key(k: int) -> tuple[int, bool, float]:
        f = feas[k]
        tier = 0 if f.feasible else 1 if f.sunlit else 2
        dv = f.dv_total_km_s if math.isfinite(f.dv_total_km_s) else math.inf
        return tier, f.reenters, dv if criterion == "least_dv" else float(k)

    return sorted(range(len(feas)), key=key)


def screen(
    cand: Candidate,
    observer: Trajectory,
    tgt: Trajectory,
    lit: Feasibility,
    epoch: datetime,
    opts: PlanOptions,
    model: ObserverPlaneModel,
    pole: Pole,
    t_ready_s: float | None = None,
) -> Feasibility:
    """Screen one candidate: its phasing to its own stand-off (chosen as ``_phase_at_standoff`` does, from the
    optics' window), its cost, and the imaging geometry at T_access of a straight fly-by past the aim point
    (range the stand-off, rate v_perp / d, phase and Sun angles from the aim point). ``lit``: its illumination
    (``_illumination``). The chosen candidate is verified afterwards in full.

    The relative speed comes from a plain Lambert burn, not integrated (``phase(propagate=False)``); the cost
    from a burn corrected once for J2 (``SCREEN_CORRECTIONS``), its side set once: the plain burn's cost is far
    off, one correction's close (design/measurements.md, "Screening every candidate's burn"). ``t_ready_s``:
    the first moment the burn may come (default: the height change's epoch).
    """
    t = cand.t_access_s
    sun = sun_position_km(epoch, t)[:, 0]
    shadow = () if lit.sunlit else (SHADOW,)

    def burn(standoff_km: float, propagate: bool = True) -> Phasing:
        return phase(
            observer,
            tgt,
            t,
            opts.revolutions_before,
            max(0.0, model.t_ref_s) if t_ready_s is None else t_ready_s,
            max_corrections=SCREEN_CORRECTIONS,
            pole=pole,
            standoff_km=standoff_km,
            sun_km=sun,
            standoff_rounds=1,
            propagate=propagate,
        )

    try:
        window = None
        if opts.standoff_km is not None:
            ph = burn(opts.standoff_km)
        else:  # the relative speed from a plain Lambert burn (within a percent), the cost from a corrected one
            first = burn(_first_standoff_km(opts), propagate=False)
            window = standoff_window(float(np.linalg.norm(first.v_relative_km_s)), opts.optics, opts.min_separation_km)
            ph = burn(_aim_km(window))
            if window.feasible and _rate_deg_s(ph) > opts.optics.max_rate_deg_s:  # the quick speed was a little low
                window = standoff_window(float(np.linalg.norm(ph.v_relative_km_s)), opts.optics, opts.min_separation_km)
                ph = burn(_aim_km(window))
    except PlannerError as exc:
        return replace(lit, feasible=False, reasons=(*shadow, f"no phasing burn: {exc}"))
    r_ts, v_ts = tgt.state(t)
    r_t = r_ts[:, 0]
    rho = np.asarray(ph.standoff_km_vec, float)
    v_rel = np.asarray(ph.v_relative_km_s, float)
    d = float(np.linalg.norm(rho))
    rate = _rate_deg_s(ph)
    phase_deg = float(phase_angle_deg(r_t, sun, rho))
    sun_deg = sun_angle_deg(r_t + rho, r_t, sun)
    dv = ph.dv_total_km_s + float(height_change_dv_km_s(model.a_km, model.e, cand.delta_ha_km, cand.delta_hp_km))
    speed = float(np.linalg.norm(v_rel))
    closest = float(np.linalg.norm(np.cross(rho, v_rel))) / speed  # a straight line's least distance
    straight = Encounter(d, speed, rate, closest, t, None)
    perigee = transfer_perigee_height_km(observer, ph)
    reasons = (
        *shadow,
        *_encounter_reasons(straight, phase_deg, sun_deg, opts, window),
        *_dv_reasons(dv, opts),
        *_perigee_reasons(perigee),
    )
    los = line_of_sight_rtn(r_t, v_ts[:, 0], rho)
    return Feasibility(lit.sunlit, d, phase_deg, not reasons, reasons, sun_deg, dv, d, speed, rate, los, perigee)


def stations_of(station: Station | Sequence[Station]) -> tuple[Station, ...]:
    """One station or a network as a tuple, each checked; StationError (``ground_stations``) for none."""
    stations = (station,) if isinstance(station, Station) else tuple(station)
    if not stations:
        raise StationError("the list of stations is empty: give at least one", field="ground_stations")
    for st in stations:
        validate_station(st)
    return stations


def _radar_reasons(
    cand: Candidate, windows: AccessWindows, stations: tuple[Station, ...], view: RadarView, k: int
) -> list[str]:
    """Why the radar cannot image candidate ``k`` at T_access, in words: a pass it cannot follow (a keyhole: its
    azimuth rate near the zenith), then each of its limits there (``planner.radar.radar_limits``)."""
    p = cand.pass_index
    station = stations[windows.station_of(p)]
    reasons = []
    if windows.keyhole.size and windows.keyhole[p]:
        reasons.append(
            f"the radar must turn {windows.max_azimuth_rate_deg_s[p]:.1f} deg/s in azimuth at this pass's culmination, "
            f"over its {station.max_azimuth_rate_deg_s:g} deg/s (a keyhole)"
        )
    elevation, t_int, snr = view.elevation_deg[k], view.integration_s[k], view.snr_db[k]
    return reasons + radar_limits(station.radar, float(elevation), float(t_int), float(snr))


def _with_radar(f: Feasibility, view: RadarView, k: int) -> Feasibility:
    """``f`` with candidate ``k``'s radar figures at T_access (``view``)."""
    return replace(
        f,
        radar_elevation_deg=float(view.elevation_deg[k]),
        radar_range_km=float(view.range_km[k]),
        radar_snr_db=float(view.snr_db[k]),
        isar_integration_s=float(view.integration_s[k]),
        radar_cross_section_m2=float(view.rcs_m2[k]),
    )


def _rate_deg_s(ph: Phasing) -> float:
    """How fast the target crosses the observer's sky at T_access past the burn's aim point, deg/s (|rho x v| / rho^2)."""
    rho = np.asarray(ph.standoff_km_vec, float)
    d2 = float(rho @ rho)
    return math.degrees(float(np.linalg.norm(np.cross(rho, ph.v_relative_km_s))) / d2) if d2 > 0.0 else math.inf


def transfer_perigee_height_km(observer: Trajectory, ph: Phasing) -> float:
    """The perigee height (above ``R_EARTH_KM``) of the two-body orbit the phasing burn puts the observer on."""
    r, _ = observer.state(ph.t_burn_s)
    a, e, *_ = state_to_elements(r[:, 0], ph.v_departure_km_s)
    return float(a * (1.0 - e)) - R_EARTH_KM


def _perigee_reasons(height: float) -> list[str]:
    """A phasing transfer whose perigee is below ``MIN_PERIGEE_HEIGHT_KM`` (it re-enters), in words."""
    if height >= MIN_PERIGEE_HEIGHT_KM:
        return []
    return [
        f"the phasing transfer's perigee is {height:.0f} km high, below {MIN_PERIGEE_HEIGHT_KM:g} km: "
        "the observer would re-enter"
    ]


def _dv_reasons(dv_total_km_s: float, opts: PlanOptions) -> list[str]:
    """A candidate dearer than ``max_dv_m_s``, in words."""
    if opts.max_dv_m_s is None or dv_total_km_s * 1000.0 <= opts.max_dv_m_s:
        return []
    return [f"needs {dv_total_km_s * 1000.0:.1f} m/s, over max_dv_m_s {opts.max_dv_m_s:g}"]


def _phase_at_standoff(
    observer: Trajectory,
    tgt: Trajectory,
    t_access_s: float,
    t_earliest_burn_s: float,
    pole: Pole,
    sun_km: Vec,
    opts: PlanOptions,
) -> tuple[Phasing, StandoffWindow | None]:
    """Phase the observer to a stand-off beside the target at T_access: the one asked for, or one chosen.

    A chosen stand-off lies within the optics' window for the fly-by's relative speed (``standoff_window``):
    a first phasing to the middle of the optics' range measures the speed, the next aims at the window's
    choice, and so on until the choice moves by under 0.5 % (a fast fly-by's speed is the planes' crossing
    and barely moves; a slow, co-orbital one's bends with the aim). Returns the window too (None for a
    stand-off given).
    """

    def to(standoff_km: float) -> Phasing:
        return phase(
            observer,
            tgt,
            t_access_s,
            opts.revolutions_before,
            t_earliest_burn_s=t_earliest_burn_s,
            pole=pole,
            standoff_km=standoff_km,
            sun_km=sun_km,
        )

    if opts.standoff_km is not None:
        return to(opts.standoff_km), None
    d = _first_standoff_km(opts)
    ph = to(d)
    for _ in range(STANDOFF_ITERATIONS):  # a slow, curved fly-by's speed moves with the aim: a few rounds
        window = standoff_window(float(np.linalg.norm(ph.v_relative_km_s)), opts.optics, opts.min_separation_km)
        d_new = _aim_km(window)
        if abs(d_new - d) <= 0.005 * d:
            break
        d, ph = d_new, to(d_new)
    return ph, window


def _first_standoff_km(opts: PlanOptions) -> float:
    """The stand-off a first burn aims at to measure the fly-by's speed: the middle of the range the optics allow."""
    return min(STANDOFF_RANGE_KM[1], 0.5 * imaging_range_km(opts))


def _aim_km(window: StandoffWindow) -> float:
    """The window's choice of stand-off, within the stand-offs a plan may aim at."""
    return min(max(window.choose_km(), STANDOFF_RANGE_KM[0]), STANDOFF_RANGE_KM[1])


def imaging_range_km(opts: PlanOptions) -> float:
    """The farthest the observer may image from: the optics' diffraction range, or a lower cap asked for."""
    cap = opts.max_imaging_range_km
    return opts.optics.max_range_km if cap is None else min(cap, opts.optics.max_range_km)


def _encounter_reasons(
    meet: Encounter, phase_deg: float, sun_deg: float, opts: PlanOptions, window: StandoffWindow | None
) -> list[str]:
    """Why an encounter cannot be imaged, in words and numbers: no stand-off both tracks and resolves the fly-by,
    a collision risk, range, Sun phase, Sun exclusion, tracking rate."""
    optics = opts.optics
    reasons = list(window.reasons) if window is not None else []
    if meet.closest_approach_km < opts.min_separation_km:
        reasons.append(
            f"closest approach {meet.closest_approach_km:.2f} km is under min_separation_km "
            f"{opts.min_separation_km} km: a collision risk"
        )
    limit = imaging_range_km(opts)
    if meet.separation_km > limit and not (window is not None and window.reasons):
        what = (
            f"the optics resolve {optics.gsd_m:g} m only within {limit:.1f} km"
            if opts.max_imaging_range_km is None or opts.max_imaging_range_km >= optics.max_range_km
            else f"over max_imaging_range_km {opts.max_imaging_range_km:g} km"
        )
        reasons.append(f"observer is {meet.separation_km:.1f} km away at T_access; {what}")
    if phase_deg > optics.max_phase_angle_deg:
        reasons.append(f"Sun phase angle {phase_deg:.1f} deg is over {optics.max_phase_angle_deg:g} deg")
    if sun_deg < optics.sun_exclusion_deg:
        reasons.append(
            f"the boresight is {sun_deg:.1f} deg from the Sun, inside the {optics.sun_exclusion_deg:g} deg exclusion"
        )
    if meet.target_angular_rate_deg_s > optics.max_rate_deg_s and not (window is not None and window.reasons):
        reasons.append(
            f"the target crosses the observer's sky at {meet.target_angular_rate_deg_s:.1f} deg/s, over the "
            f"{optics.max_rate_deg_s:g} deg/s a tracker follows (a larger standoff_km lowers it)"
        )
    return reasons


def _refined(cand: Candidate, tgt: Trajectory, obs: Trajectory, windows: AccessWindows) -> Candidate:
    """Return ``cand`` with ``t_access_s`` and ``miss_km`` from the changed observer's own propagation.

    ``t_access_range_s`` is widened to hold the refined moment where it fell just outside
    (the range is read from 1-s samples of the pass).
    """
    t_access, miss = _refine_crossing(tgt, obs, windows, cand)
    t_range = cand.t_access_range_s
    if t_range is not None:
        t_range = (min(t_range[0], t_access), max(t_range[1], t_access))
    return replace(cand, t_access_s=t_access, miss_km=miss, t_access_range_s=t_range)


def _refine_crossing(tgt: Trajectory, obs: Trajectory, windows: AccessWindows, cand: Candidate) -> tuple[float, float]:
    """Return the moment in the candidate's pass where the target truly crosses the changed observer's plane, and the miss there."""
    from planner.alignment import node_miss_km

    rise, set_ = float(windows.rise_s[cand.pass_index]), float(windows.set_s[cand.pass_index])

    def g(t_s: Vec) -> Vec:
        r, _ = tgt.state(t_s)
        ro, vo = obs.state(t_s)
        n = np.cross(ro, vo, axis=0)
        return (n * r).sum(axis=0) / (np.linalg.norm(n, axis=0) * np.linalg.norm(r, axis=0))

    lo, hi = max(rise, cand.t_access_s - 60.0), min(set_, cand.t_access_s + 60.0)
    grid = np.linspace(lo, hi, 121)
    vals = g(grid)
    flips = np.flatnonzero(np.sign(vals[1:]) != np.sign(vals[:-1]))
    if flips.size:
        j = int(flips[np.argmin(np.abs(grid[flips] - cand.t_access_s))])
        t_access = float(bisect_roots(g, grid[j : j + 1], grid[j + 1 : j + 2], 1e-4)[0])
    else:
        t_access = float(grid[np.argmin(np.abs(vals))])
    r, v = tgt.state(t_access)
    ro, vo = obs.state(t_access)
    miss, _ = node_miss_km(r, v, np.cross(ro, vo, axis=0) / np.linalg.norm(np.cross(ro, vo, axis=0)))
    return t_access, float(miss[0])
