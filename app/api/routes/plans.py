"""Plans: POST runs Algorithm 1 and stores the result; GET reads the caller's history."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from fastapi import APIRouter, Body, HTTPException, Path, Query, Request, Response
from fastapi.concurrency import run_in_threadpool

from app import crud
from app.api import examples
from app.api.deps import (
    CcsdsFormat,
    CurrentOperator,
    PageDep,
    SessionDep,
    SettingsDep,
    check_span,
    client_watch,
    plan_in_worker,
    planning_budget,
)
from app.schemas import PAPER_EXAMPLE, IsoDateTime, PlanCreate, PlanPublic, PlansPublic, PlanSummary, Text
from app.services.planning import access_csv, plan_and_store, scenes_by_pass

router = APIRouter(prefix="/plans", tags=["plans"])

NOT_FOUND: dict[int | str, dict[str, Any]] = {404: {"description": "no plan with this id belongs to the caller"}}


@router.post(
    "",
    status_code=201,
    response_model=PlanPublic,
    responses={
        201: {"content": {"application/json": {"example": examples.load("plan")}}},
        503: {"description": "planning ran over GSA_PLAN_TIMEOUT_S and was stopped; nothing was stored"},
    },
)
async def create_plan(
    request: Request,
    session: SessionDep,
    operator: CurrentOperator,
    settings: SettingsDep,
    plan_in: Annotated[PlanCreate, Body(openapi_examples={"paper_table_1": {"value": PAPER_EXAMPLE}})],
) -> PlanPublic:
    """Plan a GSA scene: access windows, ranked node alignments, the phasing burn and its verification.

    Planning runs in a worker thread under a time budget (``GSA_PLAN_TIMEOUT_S``) and a memory
    budget (``GSA_PLAN_MEMORY_MB``: the worker's resident memory may grow by that much while it
    plans) and stops when the caller disconnects; in each case nothing is stored.
    """
    check_span(plan_in.search.duration_days, settings, ["search", "duration_days"])
    plan = await plan_in_worker(
        request, "plan", plan_and_store, settings, session=session, operator_id=operator.id, plan_in=plan_in
    )
    return PlanPublic.from_row(plan)


@router.get("", response_model=PlansPublic)
def list_plans(
    session: SessionDep,
    operator: CurrentOperator,
    page: PageDep,
    target_name: Annotated[Text | None, Query(max_length=200)] = None,
    created_after: IsoDateTime | None = None,
    created_before: IsoDateTime | None = None,
) -> dict[str, Any]:
    """List the caller's plans, newest first, filtered by target name and creation time."""
    rows, total = crud.list_plans(
        session=session,
        operator_id=operator.id,
        limit=page.limit,
        offset=page.offset,
        target_name=target_name,
        created_after=created_after,
        created_before=created_before,
    )
    data = [PlanSummary.from_row(p) for p in rows]
    return {"data": data, "count": total}


@router.get(
    "/{plan_id}",
    response_model=PlanPublic,
    responses={**NOT_FOUND, 200: {"content": {"application/json": {"example": examples.load("plan")}}}},
)
def read_plan(session: SessionDep, operator: CurrentOperator, plan_id: Annotated[Text, Path()]) -> PlanPublic:
    """Return one of the caller's plans."""
    plan = crud.get_plan(session=session, operator_id=operator.id, plan_id=plan_id)
    if plan is None:
        raise HTTPException(status_code=404, detail="Plan not found")
    estimate_ids, pass_ids = crud.tied_to_plan(session=session, operator_id=operator.id, plan_id=plan.id)
    return PlanPublic.from_row(plan, estimate_ids, pass_ids)


@router.get(
    "/{plan_id}/export/access.csv",
    response_class=Response,
    responses={**NOT_FOUND, 200: {"content": {"text/csv": {}}, "description": "one row a pass"}},
)
def export_access_csv(session: SessionDep, operator: CurrentOperator, plan_id: Annotated[Text, Path()]) -> Response:
    """The plan's access windows as an STK-style access report (CSV; times ISO 8601 UTC with Z, azimuths from north)."""
    plan = crud.get_plan(session=session, operator_id=operator.id, plan_id=plan_id)
    if plan is None:
        raise HTTPException(status_code=404, detail="Plan not found")
    body = access_csv(plan.result.get("access_windows", []), scenes_by_pass(plan.result))
    name = f"access-{plan.id}.csv"
    return Response(body, media_type="text/csv", headers={"Content-Disposition": f'attachment; filename="{name}"'})


EXPORT_TYPES = {
    "opm": (
        "text/plain",
        "CCSDS OPM 3.0 (KVN, or XML with format=xml): the observer before its burn, and the burn (GCRF, UTC)",
        "opm.txt",
    ),
    "oem": (
        "text/plain",
        "CCSDS OEM 3.0 (KVN, or XML with format=xml): target and observer over the planned arc (GCRF, UTC, 60 s)",
        "oem.txt",
    ),
    "czml": ("application/json", "CZML for Cesium: both satellites, the station, access intervals, T_access", "czml"),
    "geojson": (
        "application/geo+json",
        "GeoJSON for GIS tools: the station, where it sees the target, both ground tracks, T_access",
        "geojson",
    ),
    "pointing.csv": (
        "text/csv",
        "the radar's azimuth, elevation, range and range rate over each pass, 1 s steps",
        "pointing.csv",
    ),
}


async def _export(
    kind: str,
    fmt: Literal["kvn", "xml"],
    plan_id: str,
    request: Request,
    session: SessionDep,
    operator: CurrentOperator,
    settings: SettingsDep,
) -> Response:
    from app.services import exports

    row = crud.get_plan(session=session, operator_id=operator.id, plan_id=plan_id)
    if row is None:
        raise HTTPException(status_code=404, detail="Plan not found")
    # A read and a decompression (15 ms for a 4-MB pointing.csv), or the OEM in XML converted on its first request
    # (0.2 s): off the event loop, as the recompute below.
    body = await run_in_threadpool(exports.stored_export, session, row, kind, fmt)
    if body is None:  # a plan made before exports were stored: recomputed in a worker thread under the plan budget,
        async with client_watch(request) as gone:  # stopped when the client leaves, and kept for the next request
            texts = await run_in_threadpool(exports.render_again, row, settings, planning_budget(settings, gone))
        exports.keep(session, row, texts)
        body = await run_in_threadpool(exports.stored_export, session, row, kind, fmt)
    media, _, suffix = EXPORT_TYPES[kind]
    if fmt == "xml" and kind in exports.CCSDS_KINDS:
        media, suffix = "application/xml", suffix.replace(".txt", ".xml")
    name = f"plan-{row.id}.{suffix}"
    return Response(body, media_type=media, headers={"Content-Disposition": f'attachment; filename="{name}"'})


def _export_route(kind: str) -> None:
    media, what, _ = EXPORT_TYPES[kind]
    doc = (
        f"The plan as {what}. Written when the plan was made and served as stored; a plan made before that is "
        "recomputed once from its stored request under the plan budget (GSA_PLAN_TIMEOUT_S: 503 over it), stopped "
        "if the client leaves; 422 at once if the plan has no burn and the export needs one."
    )
    content: dict[str, Any] = {media: {}}
    if kind in ("opm", "oem"):
        content["application/xml"] = {}

        async def export(
            request: Request,
            session: SessionDep,
            operator: CurrentOperator,
            settings: SettingsDep,
            plan_id: Annotated[Text, Path()],
            format: CcsdsFormat = "kvn",  # noqa: A002 (the query parameter's name)
        ) -> Response:
            return await _export(kind, format, plan_id, request, session, operator, settings)

    else:

        async def export(  # type: ignore[misc]
            request: Request,
            session: SessionDep,
            operator: CurrentOperator,
            settings: SettingsDep,
            plan_id: Annotated[Text, Path()],
        ) -> Response:
            return await _export(kind, "kvn", plan_id, request, session, operator, settings)

    export.__doc__ = doc
    export.__name__ = f"export_{kind.replace('.', '_')}"
    router.add_api_route(
        f"/{{plan_id}}/export/{kind}",
        export,
        methods=["GET"],
        response_class=Response,
        responses={
            **NOT_FOUND,
            200: {"content": content, "description": what},
            503: {"description": "recomputing an older plan ran over GSA_PLAN_TIMEOUT_S and was stopped"},
        },
    )


for _kind in EXPORT_TYPES:
    _export_route(_kind)
