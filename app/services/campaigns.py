"""Campaigns: a request into ``planner.campaign``, its result stored, and its flight flown again for the exports."""

from __future__ import annotations

from dataclasses import replace
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
from app.schemas.campaigns import ReplanRecord
from app.schemas.orbits import OrbitIn
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
from planner.alignment import HeightBox
from planner.campaign import (
    Campaign,
    CampaignOptions,
    Progress,
    plan_campaign,
)
from planner.closed_loop import replan
from planner.dispersion import SceneDispersion, disperse, trim_margin_km_s
from planner.errors import PlannerError, PlanningStopped
from planner.orbits import earth_frames, trajectory
from planner.plan import PlanOptions, StopCheck, check_planes_apart
from planner.propagation import as_utc, seconds_between

Vec = NDArray[np.float64]
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
    to_stations(checked)
    opts = campaign_options(checked, settings.max_grid_points)
    try:  # what the planner's plane check refuses at once on the synchronous route; here before the job is queued
        check_planes_apart(target, observer, opts.start or target.epoch, min(opts.scene_span_s, opts.duration_s))
    except PlannerError as exc:
        raise InputError(["observer"], str(exc)) from None
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
