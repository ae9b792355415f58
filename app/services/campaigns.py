"""Campaigns: a request into ``planner.campaign``, its result stored, and its flight flown again for the exports."""

from __future__ import annotations

from dataclasses import dataclass, replace
from datetime import datetime, timedelta
from typing import Any

import numpy as np
from numpy.typing import NDArray
from sqlalchemy.orm import Session

from app import crud
from app.core.config import Settings
from app.db.models import Campaign as CampaignRow
from app.errors import InputError
from app.schemas import CampaignCreate, CampaignReplan, CampaignResult
from app.schemas.campaigns import CampaignScenePublic, ReplanRecord
from app.schemas.orbits import OrbitIn
from app.services import exports
from app.services.planning import (
    check_epoch_gap,
    observer_optics,
    served_cross_section,
    stored_station_lookup,
    to_orbit,
    to_stations,
    with_radar_of,
    with_stored_station,
)
from planner import ccsds
from planner.alignment import HeightBox
from planner.campaign import (
    CAMPAIGN_MARGIN_S,
    Campaign,
    CampaignOptions,
    FlownTrajectory,
    Progress,
    campaign_pole,
    fly,
    plan_campaign,
)
from planner.closed_loop import replan
from planner.dispersion import SceneDispersion, disperse, trim_margin_km_s
from planner.errors import PlannerError, PlanningStopped
from planner.orbits import earth_frames, trajectory
from planner.plan import PlanOptions, StopCheck
from planner.propagation import Trajectory, as_utc, seconds_between

Vec = NDArray[np.float64]
EXPORT_FILES = {"opm": "opm.txt", "oem": "oem.txt", "czml": "campaign.czml", "access.csv": "access.csv"}
CAMPAIGN_OEM_STEP_S = 120.0  # a campaign's ephemerides span weeks: 2-min samples (LAGRANGE 7 reads them to metres)
# Where a planner error's field belongs in the request.
MARGIN_ROUNDS = 2  # re-plans that shrink a campaign's budget by its trims' margin (the margin moves with the scenes)
_TOP = ("duration_days", "dv_budget_m_s", "scene_span_days", "max_scenes", "return_to_orbit", "start")


def campaign_options(
    req: CampaignCreate, max_grid_points: int | None = None, target_model: str | None = None
) -> CampaignOptions:
    """The planner's options from a request; out of range: a 422 naming the field."""
    s = req.search
    optics = observer_optics(req)
    try:
        box = HeightBox(s.dha_min_km, s.dha_max_km, s.dhp_min_km, s.dhp_max_km, s.step_km)
    except PlannerError as exc:
        raise InputError(["search", exc.field or "search"], str(exc)) from None
    if max_grid_points is not None and box.grid_points > max_grid_points:
        raise InputError(
            ["search", "step_km"],
            f"the dHa/dHp grid has {box.grid_points} points, over the limit of {max_grid_points}: widen step_km",
        )
    try:
        scene = PlanOptions(
            box=box,
            max_miss_km=s.max_miss_km,
            revolutions_before=tuple(sorted(set(s.revolutions_before))),
            optics=optics,
            max_imaging_range_km=s.max_imaging_range_km,
            standoff_km=s.standoff_km,
            min_separation_km=s.min_separation_km,
            cross_section=served_cross_section(target_model),
        )
    except PlannerError as exc:
        raise InputError(["search", exc.field or "search"], str(exc)) from None
    try:
        return CampaignOptions(
            start=as_utc(req.start) if req.start else None,
            duration_s=req.duration_days * 86400.0,
            dv_budget_m_s=req.dv_budget_m_s,
            return_to_orbit=req.return_to_orbit,
            scene_span_s=req.scene_span_days * 86400.0,
            max_scenes=req.max_scenes,
            plan=scene,
        )
    except PlannerError as exc:
        raise InputError([exc.field if exc.field in _TOP else "search"], str(exc)) from None


def run_campaign(
    req: CampaignCreate,
    max_grid_points: int | None = None,
    max_epoch_gap_days: float | None = None,
    stop: StopCheck | None = None,
    progress: Progress | None = None,
    target_model: str | None = None,
) -> tuple[Campaign, CampaignResult]:
    """Validate a campaign request against the planner, plan it, and return the campaign and its result."""
    target = to_orbit(req.target, "target")
    observer = to_orbit(req.observer, "observer")
    station = to_stations(req)
    opts = campaign_options(req, max_grid_points, target_model)
    if max_epoch_gap_days is not None:
        start = opts.start or target.epoch
        for orbit, orbit_in, where in ((target, req.target, "target"), (observer, req.observer, "observer")):
            check_epoch_gap(orbit, orbit_in, where, start, opts.duration_s, max_epoch_gap_days)
    try:
        campaign = plan_campaign(target, observer, station, opts, stop=stop, progress=progress)
    except PlanningStopped:
        raise
    except PlannerError as exc:
        field = exc.field or "search"
        loc: list[str | int] = [field] if field in ("target", "observer", *_TOP) else ["search", field]
        raise InputError(loc, str(exc)) from None
    spread = dispersed(req, campaign, stop)
    budget = opts.dv_budget_m_s
    for _ in range(MARGIN_ROUNDS):  # the budget keeps the trims' margin: planned again within what it leaves
        if spread is None or campaign.dv_total_km_s * 1000.0 + trim_margin_km_s(spread) * 1000.0 <= budget:
            break
        within = max(0.0, budget - trim_margin_km_s(spread) * 1000.0)
        campaign = plan_campaign(
            target, observer, station, replace(opts, dv_budget_m_s=within), stop=stop, progress=progress
        )
        notes = [
            *campaign.notes,
            f"planned within {within:.0f} m/s to keep the trims' margin inside the {budget:g} m/s",
        ]
        campaign = replace(campaign, options=replace(campaign.options, dv_budget_m_s=budget), notes=notes)
        spread = dispersed(req, campaign, stop)
    return campaign, CampaignResult.from_campaign(campaign, spread)


def plan_and_store_campaign(
    *,
    session: Session,
    operator_id: str,
    campaign_in: CampaignCreate,
    settings: Settings,
    stop: StopCheck | None = None,
    progress: Progress | None = None,
) -> CampaignRow:
    """Plan a campaign within the service's limits (``run_campaign``) and store it with its result."""
    campaign_in = with_stored_station(campaign_in, stored_station_lookup(session, operator_id))
    campaign, result = run_campaign(
        campaign_in,
        max_grid_points=settings.max_grid_points,
        max_epoch_gap_days=settings.max_epoch_gap_days,
        stop=stop,
        progress=progress,
        target_model=settings.default_target,
    )
    first = campaign.scenes[0].plan.station if campaign.scenes else None
    campaign_in = with_radar_of(campaign_in, first.name if first is not None else None)
    return crud.create_campaign(session=session, operator_id=operator_id, request=campaign_in, result=result)


def dispersed(req: CampaignCreate, campaign: Campaign, stop: StopCheck | None = None) -> list[SceneDispersion] | None:
    """With the request's ``dispersion``, every scene flown with its errors (``planner.dispersion``); else None."""
    return None if req.dispersion is None else disperse(campaign, req.dispersion.to_options(), stop)


def rebuild(
    request: dict[str, Any], result: dict[str, Any], stop: StopCheck | None = None, target_model: str | None = None
) -> Campaign:
    """A stored campaign as the planner's ``Campaign``: its request planned again (deterministic), then each of its
    re-plans applied in turn."""
    req = CampaignCreate.model_validate(request)
    campaign, _ = run_campaign(req, stop=stop, target_model=target_model)
    stored = CampaignResult.model_validate(CampaignResult.upgraded(result))
    target = to_orbit(req.target, "target")
    observer = to_orbit(req.observer, "observer")
    station = to_stations(req)
    for record in stored.replans:
        state = _observer_state(OrbitIn.model_validate(record.observer), record.from_time, campaign)
        t_from = seconds_between(campaign.epoch, record.from_time)
        campaign = replan(campaign, target, observer, station, state, t_from, stop=stop)
    return campaign


def _observer_state(orbit_in: OrbitIn, when: datetime, campaign: Campaign) -> tuple[Vec, Vec]:
    """The observer's GCRS state at ``when`` from an orbit input (as a campaign reads its start)."""
    orbit = to_orbit(orbit_in, "observer")
    frames = earth_frames(when, 0.0, 1.0)
    r, v = trajectory(orbit, when, frames, 0.0, 1.0, "osculating", campaign.pole).state(0.0)
    return r[:, 0], v[:, 0]


def replan_and_store(
    *,
    session: Session,
    operator_id: str,
    campaign_id: str,
    replan_in: CampaignReplan | None,
    settings: Settings,
    stop: StopCheck | None = None,
) -> CampaignRow | None:
    """Re-plan one of the caller's campaigns from a measured observer state and store the new campaign (the
    original stays as it was). None when no such campaign is the caller's; a 422 names ``from`` or ``observer``."""
    row = crud.get_campaign(session=session, operator_id=operator_id, campaign_id=campaign_id)
    if row is None:
        return None
    if replan_in is None:  # checked once the campaign is the caller's: another's is a 404 whatever the body
        raise InputError([], 'give the body {"observer": <an orbit input>, "from": <UTC time>}')
    req = CampaignCreate.model_validate(row.request)
    stored = CampaignResult.model_validate(CampaignResult.upgraded(row.result))
    when = as_utc(replan_in.from_time)
    end = stored.epoch + timedelta(days=stored.duration_days)
    if not stored.epoch <= when < end:
        what = "a re-plan's start: the scenes before it are flown" if stored.replanned_from else "its start"
        raise InputError(
            ["from"],
            f"from {when:%Y-%m-%dT%H:%M:%SZ} is outside the campaign, {stored.epoch:%Y-%m-%dT%H:%M:%SZ} ({what}) to "
            f"{end:%Y-%m-%dT%H:%M:%SZ}: give a moment within it",
        )
    orbit = to_orbit(replan_in.observer, "observer")
    if settings.max_epoch_gap_days is not None:
        check_epoch_gap(orbit, replan_in.observer, "observer", when, 0.0, settings.max_epoch_gap_days)
    campaign = rebuild(row.request, row.result, stop=stop, target_model=settings.default_target)
    try:
        state = _observer_state(replan_in.observer, when, campaign)
        new = replan(
            campaign,
            to_orbit(req.target, "target"),
            to_orbit(req.observer, "observer"),
            to_stations(req),
            state,
            seconds_between(campaign.epoch, when),
            stop=stop,
        )
    except PlanningStopped:
        raise
    except PlannerError as exc:
        raise InputError([exc.field if exc.field in ("from", "observer") else "from"], str(exc)) from None
    result = CampaignResult.from_campaign(new, dispersed(req, new, stop))
    record = ReplanRecord(
        campaign_id=row.id, from_time=when, observer=replan_in.observer.model_dump(mode="json", exclude_none=True)
    )
    result = result.model_copy(update={"replanned_from": row.id, "replans": [*stored.replans, record]})
    return crud.create_campaign(session=session, operator_id=operator_id, request=req, result=result)


def submit_campaign(*, session: Session, settings: Settings, operator_id: str, campaign_in: CampaignCreate) -> Any:
    """Queue the campaign as a job (``Prefer: respond-async``): checked now as the planner will see it (a bad
    request is a 422 here, not a failed job), planned by a worker process without the request's time limit."""
    from app.services import jobs

    checked = with_stored_station(campaign_in, stored_station_lookup(session, operator_id))
    target, observer = to_orbit(checked.target, "target"), to_orbit(checked.observer, "observer")
    if (target.elements, target.tle) == (observer.elements, observer.tle):
        # what the planner's plane check refuses at once on the synchronous route; here before the job is queued
        raise InputError(
            ["observer"],
            "the observer's orbit is the target's: the two planes have no line of nodes, so there is no GSA scene; "
            "use an observer in another plane",
        )
    to_stations(checked)
    campaign_options(checked, settings.max_grid_points)
    return jobs.submit(
        session,
        operator_id=operator_id,
        kind="campaign",
        params=campaign_in.model_dump(mode="json"),
        stage=f"queued: a campaign over {campaign_in.duration_days:g} days",
        engine="local",
        cap=settings.quota_queued_jobs,
    )


def run_campaign_job(ctx: Any) -> dict[str, Any]:
    """The job: plan and store the campaign, the planner's progress as the job's."""

    def progress(share: float, text: str) -> None:
        ctx.report(stage=text, progress=share)

    def stop() -> str | None:
        ctx.check()
        return None

    with ctx.session_factory() as session:
        row = plan_and_store_campaign(
            session=session,
            operator_id=ctx.operator_id,
            campaign_in=CampaignCreate.model_validate(ctx.params),
            settings=ctx.settings,
            stop=stop,
            progress=progress,
        )
        return {"campaign_id": row.id, "scenes": row.scenes, "dv_total_m_s": row.dv_total_m_s}


@dataclass(frozen=True)
class Flight:
    """A stored campaign flown again: the observer from its stored start through its stored burns, the target
    from the stored request (both deterministic: no planning is repeated). Times are s after ``epoch``."""

    epoch: datetime
    t1_s: float
    observer_flight: FlownTrajectory
    target_trajectory: Trajectory
    burns: list[dict[str, Any]]
    accesses_s: tuple[float, ...]

    def target(self, t_s: Vec) -> tuple[Vec, Vec]:
        return self.target_trajectory.state(t_s)

    def observer(self, t_s: Vec) -> tuple[Vec, Vec]:
        return self.observer_flight.state(t_s)


def flight(request: dict[str, Any], result: dict[str, Any]) -> Flight:
    """Fly a stored campaign again from its stored start state and burns."""
    req = CampaignCreate.model_validate(request)
    stored = CampaignResult.model_validate(CampaignResult.upgraded(result))
    epoch = stored.epoch
    observer = to_orbit(req.observer, "observer")
    target = to_orbit(req.target, "target")
    end = stored.duration_days * 86400.0
    pole = campaign_pole(epoch, observer, end)
    burns = [b for s in stored.scenes for b in s.burns]
    aims = [_aim_words(s) if b.kind == "phasing" else "" for s in stored.scenes for b in s.burns]
    times = [(b.time - epoch).total_seconds() for b in burns]
    r0, v0 = np.asarray(stored.observer_state.r_km), np.asarray(stored.observer_state.v_km_s)
    flown = fly(
        r0,
        v0,
        0.0,
        end + CAMPAIGN_MARGIN_S,
        [(t, np.asarray(b.dv_m_s) / 1000.0) for t, b in zip(times, burns, strict=True)],
        pole,
    )
    frames = earth_frames(epoch, 0.0, end + CAMPAIGN_MARGIN_S)
    tgt = trajectory(target, epoch, frames, 0.0, end + CAMPAIGN_MARGIN_S, "osculating", pole)
    return Flight(
        epoch,
        end,
        flown,
        tgt,
        [
            {
                "t_s": t,
                "kind": b.kind,
                "dv_km_s": tuple(x / 1000.0 for x in b.dv_m_s),
                "dv_rtn_m_s": tuple(b.dv_rtn_m_s),
                "aim": aim,
            }
            for t, b, aim in zip(times, burns, aims, strict=True)
        ],
        tuple((s.t_access - epoch).total_seconds() for s in stored.scenes),
    )


def _aim_words(scene: CampaignScenePublic) -> str:
    """A scene's aim for its phasing burn's comment: what an operator re-aims to after orbit determination."""
    aim = scene.aim
    if aim is None:
        return ""
    rel = ", ".join(f"{x:.3f}" for x in aim.relative_rtn_km)
    return (
        f". Aim: at {aim.t_access:%Y-%m-%dT%H:%M:%S.%fZ} the observer {sum(x * x for x in aim.relative_km) ** 0.5:.3f} km "
        f"from the target, RTN of the target [{rel}] km, within {aim.tolerance_km:.2f} km; Lambert arc of "
        f"{aim.lambert_revolutions} revolution(s), {'low' if aim.low_path else 'high'} branch"
        + (f"; imaged by radar {scene.candidate.station}" if scene.candidate.station else "")
    )


def export(kind: str, row: Any, fmt: ccsds.Format = "kvn") -> str:
    """One export of a stored campaign (a row, or anything with its fields): ``opm``, ``oem`` (KVN, or XML with
    ``fmt``), ``czml``, ``access.csv``."""
    from app.services.planning import access_csv, scenes_by_pass

    if kind == "access.csv":
        return access_csv(row.result.get("access_windows", []), scenes_by_pass(row.result))
    fl = flight(row.request, row.result)
    names = {"target": row.target_name, "observer": row.observer_name, "station": row.station_name}
    if kind == "opm":
        r, v = fl.observer(np.array([0.0]))
        burns = [
            exports.Manoeuvre(b["t_s"], b["dv_km_s"], b["dv_rtn_m_s"], f"Impulsive {b['kind']} burn{b['aim']}")
            for b in fl.burns
        ]
        comment = (
            f"The observer at the start of campaign {row.id}, before any burn; {len(fl.accesses_s)} scene(s), "
            f"{len(burns)} burn(s)"
        )
        return exports.opm_text(
            fl.epoch, 0.0, r[:, 0], v[:, 0], burns, f"GSA-{row.id}", row.observer_name, comment, fmt=fmt
        )
    if kind == "oem":
        # One observer segment between burns: each burn's instant ends one (before it) and starts the next.
        edges = [0.0, *(b["t_s"] for b in fl.burns), fl.t1_s]
        segments = [exports.OemSegment(row.target_name, f"GSA-{row.id}-TARGET", 0.0, fl.t1_s, fl.target, "the target")]
        for k, piece in enumerate(fl.observer_flight.pieces):
            what = (
                "the observer before any burn" if k == 0 else f"the observer after its {fl.burns[k - 1]['kind']} burn"
            )
            segments.append(
                exports.OemSegment(
                    row.observer_name, f"GSA-{row.id}-OBSERVER", edges[k], edges[k + 1], piece.state, what
                )
            )
        return exports.oem_text(fl.epoch, segments, fl.accesses_s, f"campaign {row.id}", CAMPAIGN_OEM_STEP_S, fmt=fmt)
    if kind == "czml":
        must = (*fl.accesses_s, *(b["t_s"] for b in fl.burns))
        return exports.czml_text(
            fl.epoch,
            0.0,
            fl.t1_s,
            must,
            fl.target,
            [
                (lo, hi, piece.state)
                for lo, hi, piece in zip(
                    [0.0, *(b["t_s"] for b in fl.burns)],
                    [*(b["t_s"] for b in fl.burns), fl.t1_s],
                    fl.observer_flight.pieces,
                    strict=True,
                )
            ],
            fl.accesses_s,
            f"GSA-ISAR campaign {row.id}",
            names,
            row.request["ground_station"],
            row.result.get("access_windows", []),
            step_s=CAMPAIGN_OEM_STEP_S,
            network=row.request.get("ground_stations"),
        )
    raise InputError(["kind"], f"unknown export {kind!r}: opm, oem, czml or access.csv", where="path")
