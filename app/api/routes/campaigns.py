"""Campaigns: POST plans a series of GSA scenes and stores it; GET reads the caller's; exports fly it again."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from fastapi import APIRouter, Body, HTTPException, Path, Query, Request, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse

from app import crud
from app.api import examples
from app.api.deps import (
    CcsdsFormat,
    CurrentOperator,
    PageDep,
    SessionDep,
    SettingsDep,
    plan_in_worker,
    queued,
    wants_job,
)
from app.schemas import (
    CAMPAIGN_EXAMPLE,
    CampaignCreate,
    CampaignPublic,
    CampaignReplan,
    CampaignsPublic,
    CampaignSummary,
    JobPublic,
    Text,
)
from app.services.campaigns import plan_and_store_campaign, replan_and_store, submit_campaign

router = APIRouter(prefix="/campaigns", tags=["campaigns"])

NOT_FOUND: dict[int | str, dict[str, Any]] = {404: {"description": "no campaign with this id belongs to the caller"}}


@router.post(
    "",
    status_code=201,
    response_model=CampaignPublic,
    responses={
        201: {"content": {"application/json": {"example": examples.load("campaign")}}},
        202: {
            "model": JobPublic,
            "description": "with Prefer: respond-async, queued as a job (GET /v1/jobs/{id}); its result_url is the "
            "campaign once planned",
        },
        503: {"description": "planning ran over GSA_CAMPAIGN_TIMEOUT_S and was stopped; nothing was stored"},
    },
)
async def create_campaign(
    request: Request,
    session: SessionDep,
    operator: CurrentOperator,
    settings: SettingsDep,
    campaign_in: Annotated[CampaignCreate, Body(openapi_examples={"paper_three_weeks": {"value": CAMPAIGN_EXAMPLE}})],
) -> CampaignPublic | JSONResponse:
    """Plan a campaign: GSA scenes one after another, the observer carried from each to the next, within a budget.

    Each stretch of ``scene_span_days`` is planned as a plan is (Algorithm 1 from where the last scene left the
    observer) and its cheapest feasible scene flown, preferring among those nearly as cheap a new line of sight;
    the whole burn sequence is then flown again and each scene measured on it. Runs in a worker thread under
    ``GSA_CAMPAIGN_TIMEOUT_S`` and ``GSA_PLAN_MEMORY_MB``, and stops when the caller disconnects; then nothing
    is stored.

    With the header ``Prefer: respond-async`` (RFC 7240) the campaign is checked, queued as a job and answered 202
    at once: a worker process plans it without the request's time limit, and a client that goes away loses
    nothing (``GET /v1/jobs/{id}`` follows it).
    """
    if wants_job(request):
        job = await run_in_threadpool(
            submit_campaign, session=session, settings=settings, operator_id=operator.id, campaign_in=campaign_in
        )
        return queued(request, job, prefer_applied=True)
    row = await plan_in_worker(
        request,
        "campaign",
        plan_and_store_campaign,
        settings,
        settings.campaign_timeout_s,
        "CAMPAIGN",
        session=session,
        operator_id=operator.id,
        campaign_in=campaign_in,
    )
    return CampaignPublic.from_row(row)


@router.get("", response_model=CampaignsPublic)
def list_campaigns(
    session: SessionDep,
    operator: CurrentOperator,
    page: PageDep,
    target_name: Annotated[Text | None, Query(max_length=200)] = None,
) -> CampaignsPublic:
    """List the caller's campaigns, newest first, filtered by target name."""
    rows, total = crud.list_campaigns(
        session=session, operator_id=operator.id, limit=page.limit, offset=page.offset, target_name=target_name
    )
    return CampaignsPublic(data=[CampaignSummary.from_row(r) for r in rows], count=total)


@router.get(
    "/{campaign_id}",
    response_model=CampaignPublic,
    responses={**NOT_FOUND, 200: {"content": {"application/json": {"example": examples.load("campaign")}}}},
)
def read_campaign(
    session: SessionDep, operator: CurrentOperator, campaign_id: Annotated[Text, Path()]
) -> CampaignPublic:
    """Return one of the caller's campaigns."""
    row = crud.get_campaign(session=session, operator_id=operator.id, campaign_id=campaign_id)
    if row is None:
        raise HTTPException(status_code=404, detail="Campaign not found")
    return CampaignPublic.from_row(row)


@router.post(
    "/{campaign_id}/replan",
    status_code=201,
    response_model=CampaignPublic,
    responses={
        **NOT_FOUND,
        503: {"description": "re-planning ran over GSA_CAMPAIGN_TIMEOUT_S and was stopped; nothing was stored"},
    },
)
async def replan_campaign(
    request: Request,
    session: SessionDep,
    operator: CurrentOperator,
    settings: SettingsDep,
    campaign_id: Annotated[Text, Path()],
    replan_in: Annotated[CampaignReplan | None, Body()] = None,
) -> CampaignPublic:
    """Re-plan a campaign from where orbit determination puts the observer (``observer`` at ``from``).

    The answer is a new campaign, starting at ``from``, that names ``replanned_from``: every later scene re-aimed
    from that state (its T_access and aim point kept, its phasing burn solved again on the same branch), and the
    rest of the span planned afresh from the first scene that can no longer be reached within the budget left.
    The original campaign stays as it was. ``from`` must lie within the campaign (a re-plan's own start is the
    earliest: the scenes before it are flown), not inside a scene's approach; an observer farther than 500 km from
    where the campaign has it is refused as another object.
    """
    row = await plan_in_worker(
        request,
        "campaign",
        replan_and_store,
        settings,
        settings.campaign_timeout_s,
        "CAMPAIGN",
        session=session,
        operator_id=operator.id,
        campaign_id=campaign_id,
        replan_in=replan_in,
    )
    if row is None:
        raise HTTPException(status_code=404, detail="Campaign not found")
    return CampaignPublic.from_row(row)


EXPORT_TYPES = {
    "opm": (
        "text/plain",
        "CCSDS OPM 3.0 (KVN, or XML with format=xml): the observer at the start, and every burn (GCRF, UTC)",
        "opm.txt",
    ),
    "oem": (
        "text/plain",
        "CCSDS OEM 3.0 (KVN, or XML with format=xml): the target, and the observer in one segment between burns "
        "(GCRF, UTC, 120 s)",
        "oem.txt",
    ),
    "czml": (
        "application/json",
        "CZML for Cesium: both satellites, the station, access intervals, each T_access",
        "czml",
    ),
    "access.csv": (
        "text/csv",
        "every pass of the target over the station in the span searched, one row a pass; scene marks the pass each "
        "scene images in",
        "csv",
    ),
    "geojson": (
        "application/geo+json",
        "GeoJSON of the whole campaign: each station, the target's track over each scene's pass, the target and the "
        "observer under each T_access, and each burn where the observer makes it",
        "geojson",
    ),
    "pointing.csv": (
        "text/csv",
        "the radar's tasking file: its pointing over the pass each scene images in (or scene K's, with scene=K), "
        "1-s steps, from the station that images it; access is the pass's row in access.csv",
        "pointing.csv",
    ),
}


def _export_route(kind: str) -> None:
    from app.services import campaign_exports

    media, what, suffix = EXPORT_TYPES[kind]

    def answer(
        session: Any, operator: Any, campaign_id: str, fmt: Literal["kvn", "xml"], scene: int | None = None
    ) -> Response:
        row = crud.get_campaign(session=session, operator_id=operator.id, campaign_id=campaign_id)
        if row is None:
            raise HTTPException(status_code=404, detail="Campaign not found")
        body = campaign_exports.export(kind, row, fmt, scene)
        media_type, name = media, f"campaign-{row.id}.{suffix}"
        if scene is not None:
            name = f"campaign-{row.id}-scene-{scene}.{suffix}"
        if fmt == "xml":
            media_type, name = "application/xml", name.replace(".txt", ".xml")
        return Response(body, media_type=media_type, headers={"Content-Disposition": f'attachment; filename="{name}"'})

    content: dict[str, Any] = {media: {}}
    if kind in ("opm", "oem"):
        content["application/xml"] = {}

        def export(
            session: SessionDep,
            operator: CurrentOperator,
            campaign_id: Annotated[Text, Path()],
            format: CcsdsFormat = "kvn",  # noqa: A002 (the query parameter's name)
        ) -> Response:
            return answer(session, operator, campaign_id, format)

    elif kind == "pointing.csv":

        def export(  # type: ignore[misc]
            session: SessionDep,
            operator: CurrentOperator,
            campaign_id: Annotated[Text, Path()],
            scene: Annotated[
                int | None,
                Query(ge=0, description="one scene's pass (its index, as the campaign lists its scenes); all without"),
            ] = None,
        ) -> Response:
            return answer(session, operator, campaign_id, "kvn", scene)

    else:

        def export(  # type: ignore[misc]
            session: SessionDep, operator: CurrentOperator, campaign_id: Annotated[Text, Path()]
        ) -> Response:
            return answer(session, operator, campaign_id, "kvn")

    export.__doc__ = f"The campaign as {what}. Flown again from the stored start and burns (no planning is repeated)."
    export.__name__ = f"export_campaign_{kind.replace('.', '_')}"
    router.add_api_route(
        f"/{{campaign_id}}/export/{kind}",
        export,
        methods=["GET"],
        response_class=Response,
        responses={**NOT_FOUND, 200: {"content": content, "description": what}},
    )


for _kind in EXPORT_TYPES:
    _export_route(_kind)
