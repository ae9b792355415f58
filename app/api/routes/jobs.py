"""Jobs: long work (adaptations, data sets, campaigns asked for with ``Prefer: respond-async``) as one resource."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from fastapi import APIRouter, HTTPException, Query
from fastapi import Path as PathParam
from fastapi.responses import JSONResponse, Response

from app.api.deps import CurrentOperator, PageDep, SessionDep, SettingsDep
from app.db.models import JOB_FINAL
from app.schemas import JobPublic, JobsPublic, Text
from app.services import jobs as jobs_svc

router = APIRouter(prefix="/jobs", tags=["jobs"])

NOT_FOUND: dict[int | str, dict[str, Any]] = {404: {"description": "no job with this id is yours"}}


@router.get("", response_model=JobsPublic)
def list_jobs(
    session: SessionDep,
    operator: CurrentOperator,
    page: PageDep,
    kind: Annotated[
        Literal["adaptation", "dataset", "campaign", "reestimate", "pass"] | None,
        Query(description="only jobs of this kind"),
    ] = None,
    state: Annotated[
        Literal["queued", "running", "done", "failed", "cancelled"] | None, Query(description="only jobs in this state")
    ] = None,
) -> JobsPublic:
    """The caller's jobs, newest first (filter by kind and state)."""
    rows, total = jobs_svc.listing(session, operator.id, page.limit, page.offset, kind, state)
    return JobsPublic(data=[JobPublic.from_row(r) for r in rows], count=total)


@router.get("/{job_id}", response_model=JobPublic, responses=NOT_FOUND)
def read_job(
    session: SessionDep, operator: CurrentOperator, job_id: Annotated[Text, PathParam(max_length=36)]
) -> JobPublic:
    """One of the caller's jobs: state, stage, progress with counts and the time left, log tail, result link."""
    job = jobs_svc.own(session, operator.id, job_id)
    if job is None:
        raise HTTPException(status_code=404, detail="Job not found")
    return JobPublic.from_row(job)


@router.delete(
    "/{job_id}",
    response_model=JobPublic,
    responses={
        **NOT_FOUND,
        202: {"model": JobPublic, "description": "the running job is asked to stop; it says cancelled once it has"},
        204: {"description": "the ended job is removed, with what it kept on disk (a data set's files, its log)"},
    },
)
def cancel_job(
    session: SessionDep,
    operator: CurrentOperator,
    settings: SettingsDep,
    job_id: Annotated[Text, PathParam(max_length=36)],
) -> JobPublic | Response:
    """Cancel one of the caller's jobs: a queued one at once (200), a running one at its next step (202; asking
    again is harmless). Its worker and every process the worker started are stopped, and what the job made so far
    is removed (a data set's shards, an adaptation's partial version, a queued pass's frames).

    An ended job (done, failed or cancelled) is removed instead (204), with its files: a data set goes with its
    job. What a job stored elsewhere stays (a campaign, a pass, an adapted version: DELETE those themselves)."""
    job = jobs_svc.own(session, operator.id, job_id)
    if job is None:
        raise HTTPException(status_code=404, detail="Job not found")
    if job.state in JOB_FINAL:
        jobs_svc.remove(session, job, settings)
        return Response(status_code=204)
    job = jobs_svc.cancel(session, job, settings)
    body = JobPublic.from_row(job)
    if job.state == "running":
        return JSONResponse(status_code=202, content=body.model_dump(mode="json"))
    return body
