"""Passes: a pass's frames, each fitted and placed in the target's orbital frame, fused into one attitude."""

from __future__ import annotations

import time
from typing import Annotated

from fastapi import APIRouter, File, Form, HTTPException, Query, Request, UploadFile
from fastapi import Path as PathParam
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse, Response

from app import crud
from app.api.deps import (
    CcsdsFormat,
    CheckersDep,
    CurrentOperator,
    ModelSetsDep,
    PageDep,
    SessionDep,
    SettingsDep,
    answering,
    cells_from_form,
    client_watch,
    job_limits,
    observe_work,
    queued,
    read_uploads,
    wants_job,
)
from app.schemas import IsoDateTime, JobPublic, PassesPublic, PassPublic, PassSummary, Text
from app.services import attitude_exports
from app.services import passes as pass_svc

router = APIRouter(prefix="/passes", tags=["passes"])

OBSERVED_AT = "each frame's time (ISO 8601 UTC), one per frame in upload order (repeat the field); inside the plan's access windows"
INTEGRATION_S = (
    "each frame's integration time (s), one per frame in upload order (repeat the field; gsa simulate --pass writes "
    "it): with aperture_deg, the line of sight's measured rate relative to the body, which tells a turning target's "
    "rate far better than its frames' attitudes alone"
)
APERTURE_DEG = (
    "the angle the line of sight sweeps in the target over each frame (deg; lambda / (2 x cross-range cell)); "
    "default: the models' radar's, for frames at the models' cells"
)


@router.post(
    "",
    status_code=201,
    response_model=PassPublic,
    responses={
        413: {"description": "file too large"},
        202: {"model": JobPublic, "description": "with Prefer: respond-async, queued as a job (GET /v1/jobs/{id})"},
    },
)
async def create_pass(
    request: Request,
    session: SessionDep,
    operator: CurrentOperator,
    settings: SettingsDep,
    model_sets: ModelSetsDep,
    checkers: CheckersDep,
    files: Annotated[
        list[UploadFile], File(description="the pass's frames: several files, or one .npz stack [N, H, W]")
    ],
    plan_id: Annotated[Text, Form(max_length=36, description="the plan whose target and station made the pass")],
    observed_at: Annotated[list[IsoDateTime], Form(description=OBSERVED_AT)],
    target: Annotated[
        Text | None, Form(max_length=200, description="the target model (default GSA_DEFAULT_TARGET)")
    ] = None,
    normalised: Annotated[bool, Form(description="the frames already are the models' input (gsa simulate)")] = False,
    range_cell_m: Annotated[float | None, Form(ge=0.001, le=100, description="the frames' range cell (m)")] = None,
    cross_range_cell_m: Annotated[
        float | None, Form(ge=0.001, le=100, description="the frames' cross-range cell (m)")
    ] = None,
    integration_s: Annotated[list[float] | None, Form(description=INTEGRATION_S)] = None,
    aperture_deg: Annotated[float | None, Form(ge=0.01, le=30, description=APERTURE_DEG)] = None,
) -> PassPublic | JSONResponse:
    """Fit every frame of a pass, place each in the plan target's LVLH frame at its time, and fuse them; stored.

    With ``Prefer: respond-async`` the pass is checked, kept and queued as a job (202; up to
    ``GSA_MAX_PASS_JOB_FRAMES`` frames rather than ``GSA_MAX_BATCH_FRAMES``): a worker process fits and fuses it,
    and the job's ``result_url`` is the pass once stored."""
    cells_m = cells_from_form(range_cell_m, cross_range_cell_m)
    est, checker = answering(request, session, model_sets, checkers, target, operator)
    started = time.perf_counter()
    if wants_job(request):
        limits = job_limits(settings)
        uploads = await read_uploads(files, limits)
        job = await run_in_threadpool(
            pass_svc.submit_pass,
            session=session,
            operator_id=operator.id,
            settings=limits,
            checker=checker,
            uploads=uploads,
            plan_id=plan_id,
            observed_at=observed_at,
            cells_m=cells_m,
            normalised=normalised,
            integration_s=integration_s,
            aperture_deg=aperture_deg,
        )
        return queued(request, job, prefer_applied=True)
    uploads = await read_uploads(files, settings)
    async with client_watch(request) as gone:  # the client gone: the fit stops between frames, nothing stored
        row = await run_in_threadpool(
            pass_svc.create_pass,
            session=session,
            operator_id=operator.id,
            settings=settings,
            est=est,
            checker=checker,
            uploads=uploads,
            plan_id=plan_id,
            observed_at=observed_at,
            cells_m=cells_m,
            normalised=normalised,
            integration_s=integration_s,
            aperture_deg=aperture_deg,
            cancelled=gone.is_set,
        )
    observe_work(request, "pass", started, frames=len(uploads))
    return PassPublic.from_row(row)


@router.get("", response_model=PassesPublic)
def list_passes(
    session: SessionDep,
    operator: CurrentOperator,
    page: PageDep,
    plan_id: Annotated[Text | None, Query(max_length=36, description="only the passes of this plan")] = None,
) -> PassesPublic:
    """List the caller's fused passes, newest first (filter by plan)."""
    rows, total = crud.list_passes(
        session=session, operator_id=operator.id, limit=page.limit, offset=page.offset, plan_id=plan_id
    )
    return PassesPublic(data=[PassSummary.from_row(r) for r in rows], count=total)


@router.get("/{pass_id}", response_model=PassPublic, responses={404: {"description": "no pass with this id is yours"}})
def read_pass(session: SessionDep, operator: CurrentOperator, pass_id: Annotated[Text, PathParam()]) -> PassPublic:
    """Return one of the caller's passes."""
    row = crud.get_pass(session=session, operator_id=operator.id, pass_id=pass_id)
    if row is None:
        raise HTTPException(status_code=404, detail="Pass not found")
    return PassPublic.from_row(row)


@router.get(
    "/{pass_id}/export/aem",
    response_class=Response,
    responses={
        404: {"description": "no pass with this id is yours"},
        200: {"content": {"text/plain": {}, "application/xml": {}}},
        409: {"description": "the pass has no plan: its attitude is in LVLH only"},
    },
)
def export_aem(
    session: SessionDep,
    operator: CurrentOperator,
    pass_id: Annotated[Text, PathParam()],
    format: CcsdsFormat = "kvn",  # noqa: A002 (the query parameter's name)
) -> Response:
    """The pass's fused attitude as a CCSDS AEM 2.0 (ADM 504.0-B-2; KVN, or XML with ``format=xml``): the quaternion
    from GCRF to the body every second from its first frame to its last (the turning model's, for a turning
    target), with the pass's verdict and bounds in comments."""
    row = crud.get_pass(session=session, operator_id=operator.id, pass_id=pass_id)
    if row is None:
        raise HTTPException(status_code=404, detail="Pass not found")
    text = attitude_exports.pass_aem(session, operator.id, row, format)
    media = "application/xml" if format == "xml" else "text/plain"
    name = f"pass-{row.id}.aem" + (".xml" if format == "xml" else "")
    return Response(text, media_type=media, headers={"Content-Disposition": f'attachment; filename="{name}"'})
