"""Data sets: labelled ISAR frames simulated as a job (locally or on a Ray cluster), then read shard by shard."""

from __future__ import annotations

import re
from typing import Annotated, Any

from fastapi import APIRouter, Body, HTTPException, Request
from fastapi import Path as PathParam
from fastapi.responses import FileResponse, JSONResponse, Response

from app.api.deps import CurrentOperator, SessionDep, SettingsDep, queued
from app.schemas import DatasetCreate, JobPublic, Text
from app.services import datasets as datasets_svc

router = APIRouter(prefix="/datasets", tags=["jobs"])

EXAMPLE: dict[str, Any] = {"n": 500, "seed": 1, "shard_size": 250, "n_train": 400}
FILE_NAME = re.compile(r"^(manifest\.json|shard-\d{5}\.npz)$")


@router.post(
    "",
    status_code=202,
    response_model=JobPublic,
    responses={202: {"description": "queued: follow it at /v1/jobs/{id}; the files are listed in its manifest"}},
)
def create_dataset(
    request: Request,
    session: SessionDep,
    operator: CurrentOperator,
    settings: SettingsDep,
    dataset_in: Annotated[DatasetCreate, Body(openapi_examples={"small": {"value": EXAMPLE}})],
) -> JSONResponse:
    """Simulate a labelled data set as a job (``gsa simulate``'s options): shards of ``shard_size`` frames, each
    one task of the engine (this host's worker processes, or the Ray cluster at ``GSA_RAY_ADDRESS``: the same
    bytes either way). When done, ``GET /v1/datasets/{id}/files/manifest.json`` lists the shards."""
    job = datasets_svc.submit_dataset(
        session=session, settings=settings, operator_id=operator.id, dataset_in=dataset_in
    )
    return queued(request, job)


@router.get(
    "/{job_id}/files/{file_name}",
    response_class=FileResponse,
    responses={404: {"description": "no finished data set of yours has this id, or it has no such file"}},
)
def dataset_file(
    session: SessionDep,
    operator: CurrentOperator,
    settings: SettingsDep,
    job_id: Annotated[Text, PathParam(max_length=36)],
    file_name: Annotated[Text, PathParam(max_length=40, description="manifest.json or shard-NNNNN.npz")],
) -> FileResponse:
    """A file of one of the caller's finished data sets: its manifest, or a shard (``.npz``, as gsa simulate's)."""
    from app.services import jobs as jobs_svc

    job = jobs_svc.own(session, operator.id, job_id)
    if job is None or job.kind != "dataset" or job.state != "done" or not FILE_NAME.match(file_name):
        raise HTTPException(status_code=404, detail="Data set file not found")
    path = datasets_svc.dataset_dir(settings, job.id) / file_name
    if not path.is_file():
        raise HTTPException(status_code=404, detail="Data set file not found")
    media = "application/json" if file_name.endswith(".json") else "application/octet-stream"
    return FileResponse(path, media_type=media, filename=file_name)


@router.delete(
    "/{job_id}",
    status_code=204,
    responses={
        404: {"description": "no data set of yours has this id"},
        409: {"description": "the data set is still being made: cancel it first (DELETE /v1/jobs/{id})"},
    },
)
def delete_dataset(
    session: SessionDep,
    operator: CurrentOperator,
    settings: SettingsDep,
    job_id: Annotated[Text, PathParam(max_length=36)],
) -> Response:
    """Remove one of the caller's data sets, its files and its job; what it took from the storage quota is free."""
    from app.services import jobs as jobs_svc

    job = jobs_svc.own(session, operator.id, job_id)
    if job is None or job.kind != "dataset":
        raise HTTPException(status_code=404, detail="Data set not found")
    jobs_svc.remove(session, job, settings)
    return Response(status_code=204)
