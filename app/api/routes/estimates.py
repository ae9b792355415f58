"""Attitude estimates: upload ISAR frames, run the ONNX models, keep the history."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated, Any

import numpy as np
from fastapi import APIRouter, Depends, File, Form, HTTPException, Query, Request, UploadFile
from fastapi import Path as PathParam
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import FileResponse, Response

from app import crud
from app.api import examples
from app.api.deps import (
    CcsdsFormat,
    CheckersDep,
    CurrentOperator,
    ModelSetsDep,
    PageDep,
    SessionDep,
    SettingsDep,
    answering,
    as_utc,
    cells_from_form,
    client_watch,
    observe_work,
    read_upload,
    read_uploads,
)
from app.db.models import Estimate
from app.schemas import EstimatePublic, EstimatesPublic, IsoDateTime, Text
from app.services import attitude_exports, images
from app.services import estimation as svc

router = APIRouter(prefix="/estimates", tags=["estimates"])

NOT_FOUND: dict[int | str, dict[str, Any]] = {404: {"description": "no estimate with this id belongs to the caller"}}


RESAMPLE = "resample a frame of another size to the models' (bilinear, in pixels); without it such a frame is a 422"
PLAN_ID = "one of your plans: with observed_at, the attitude is also given in that plan's target LVLH and J2000 frames"
OBSERVED_AT = "when the frame was observed (ISO 8601 UTC, e.g. 2022-12-05T11:54:33Z); needs plan_id"
SNR_DB = "the frame's signal-to-noise ratio in dB, if known: stored with the estimate, not used by the models"
NORMALISED = (
    "the frame already is the models' input (inference.frames.normalise_frame output in [0, 1], as gsa simulate "
    "data sets store it): take it as sent instead of normalising it again"
)
REFINE = (
    "fit the target's projection to the enhanced frame, starting from Swin's answer (default true); false "
    "returns Swin's answer with the calibration's fixed bounds"
)
TARGET = "which target the frame shows (GET /readyz lists them); default GSA_DEFAULT_TARGET, the shipped tiangong-like"
RANGE_CELL = (
    "the frame's range cell in metres (rows; with cross_range_cell_m): the frame is resampled in metres to the "
    "models' 0.0937 m cells, about its centre pixel"
)
CROSS_RANGE_CELL = "the frame's cross-range cell in metres (columns; with range_cell_m); the models' is 0.1123 m"
FILE = (
    ".npy/.npz (2-D, real or complex) or 8/16-bit grayscale PNG/TIFF. Convention: rows are range, growing toward "
    "the radar; columns are cross-range, along the line of sight's rate of change; the target's centre at pixel "
    "(N/2, N/2) counted from 0; the shipped models' cells are 0.0937 m (range) x 0.1123 m (cross-range), 256 x 256"
)


def estimate_form(
    resample: Annotated[bool, Form(description=RESAMPLE)] = False,
    plan_id: Annotated[Text | None, Form(max_length=36, description=PLAN_ID)] = None,
    observed_at: Annotated[IsoDateTime | None, Form(description=OBSERVED_AT)] = None,
    normalised: Annotated[bool, Form(description=NORMALISED)] = False,
    refine: Annotated[bool, Form(description=REFINE)] = True,
    target: Annotated[Text | None, Form(max_length=200, description=TARGET)] = None,
    range_cell_m: Annotated[float | None, Form(ge=0.001, le=100, description=RANGE_CELL)] = None,
    cross_range_cell_m: Annotated[float | None, Form(ge=0.001, le=100, description=CROSS_RANGE_CELL)] = None,
) -> svc.EstimateRequest:
    """The form fields both estimate routes take, read once."""
    return svc.EstimateRequest(
        resample=resample,
        plan_id=plan_id,
        observed_at=as_utc(observed_at),
        normalised=normalised,
        refine=refine,
        target=target,
        cells_m=cells_from_form(range_cell_m, cross_range_cell_m),
    )


EstimateFormDep = Annotated[svc.EstimateRequest, Depends(estimate_form)]


@router.post(
    "",
    status_code=201,
    response_model=EstimatePublic,
    responses={
        201: {"content": {"application/json": {"example": examples.load("estimate")}}},
        413: {"description": "file too large"},
    },
)
async def create_estimate(
    request: Request,
    session: SessionDep,
    operator: CurrentOperator,
    settings: SettingsDep,
    model_sets: ModelSetsDep,
    checkers: CheckersDep,
    asked: EstimateFormDep,
    file: Annotated[UploadFile, File(description=FILE)],
    snr_db: Annotated[float | None, Form(ge=-100, le=200, description=SNR_DB)] = None,
) -> EstimatePublic:
    """Estimate the attitude of one ISAR frame: Swin's answer, fitted to the target's projection and checked; stored."""
    est, checker = answering(request, session, model_sets, checkers, asked.target, operator)
    started = time.perf_counter()
    data = await read_upload(file, settings.max_upload_bytes)
    # Decoding, the models and the database run in a worker thread, so the event loop keeps serving meanwhile.
    async with client_watch(request) as gone:
        row = await run_in_threadpool(
            svc.estimate_file,
            session=session,
            operator_id=operator.id,
            settings=settings,
            est=est,
            checker=checker,
            data=data,
            filename=file.filename or "upload",
            asked=asked,
            snr_db=snr_db,
            cancelled=gone.is_set,
        )
    observe_work(request, "estimate", started, frames=1)
    return EstimatePublic.from_row(row)


@router.post(
    "/batch", status_code=201, response_model=EstimatesPublic, responses={413: {"description": "file too large"}}
)
async def create_estimates_batch(
    request: Request,
    session: SessionDep,
    operator: CurrentOperator,
    settings: SettingsDep,
    model_sets: ModelSetsDep,
    checkers: CheckersDep,
    asked: EstimateFormDep,
    files: Annotated[list[UploadFile], File(description="several frames, or one .npz stack [N, H, W]; " + FILE)],
) -> EstimatesPublic:
    """Estimate several frames as one batch through the models, each fitted and checked; one stored row each."""
    est, checker = answering(request, session, model_sets, checkers, asked.target, operator)
    started = time.perf_counter()
    uploads = await read_uploads(files, settings)
    async with client_watch(request) as gone:  # the client gone: the fit stops between frames, nothing stored
        rows = await run_in_threadpool(
            svc.estimate_and_store,
            session=session,
            operator_id=operator.id,
            settings=settings,
            est=est,
            checker=checker,
            uploads=uploads,
            asked=asked,
            cancelled=gone.is_set,
        )
    observe_work(request, "estimate_batch", started, frames=len(rows))
    return EstimatesPublic(data=[EstimatePublic.from_row(r) for r in rows], count=len(rows))


@router.get("", response_model=EstimatesPublic)
def list_estimates(
    session: SessionDep,
    operator: CurrentOperator,
    page: PageDep,
    plan_id: Annotated[Text | None, Query(max_length=36)] = None,
    created_after: IsoDateTime | None = None,
    created_before: IsoDateTime | None = None,
) -> EstimatesPublic:
    """List the caller's estimates, newest first, filtered by plan and creation time."""
    rows, total = crud.list_estimates(
        session=session,
        operator_id=operator.id,
        limit=page.limit,
        offset=page.offset,
        plan_id=plan_id,
        created_after=created_after,
        created_before=created_before,
    )
    return EstimatesPublic(data=[EstimatePublic.from_row(r) for r in rows], count=total)


def _owned(session: SessionDep, operator_id: str, estimate_id: Annotated[Text, PathParam()]) -> Estimate:
    e = crud.get_estimate(session=session, operator_id=operator_id, estimate_id=estimate_id)
    if e is None:
        raise HTTPException(status_code=404, detail="Estimate not found")
    return e


@router.get(
    "/{estimate_id}",
    response_model=EstimatePublic,
    responses={**NOT_FOUND, 200: {"content": {"application/json": {"example": examples.load("estimate")}}}},
)
def read_estimate(
    session: SessionDep, operator: CurrentOperator, estimate_id: Annotated[Text, PathParam()]
) -> EstimatePublic:
    """Return one of the caller's estimates, with the fused passes of its plan it was observed in (``pass_ids``)."""
    row = _owned(session, operator.id, estimate_id)
    passes = crud.passes_over(session=session, operator_id=operator.id, plan_id=row.plan_id, moment=row.observed_at)
    return EstimatePublic.from_row(row, passes)


@router.get(
    "/{estimate_id}/export/apm",
    response_class=Response,
    responses={
        **NOT_FOUND,
        200: {"content": {"text/plain": {}, "application/xml": {}}},
        409: {
            "description": "the estimate has no attitude in an inertial frame (made without plan_id and observed_at)"
        },
    },
)
def export_apm(
    session: SessionDep,
    operator: CurrentOperator,
    estimate_id: Annotated[Text, PathParam()],
    format: CcsdsFormat = "kvn",  # noqa: A002 (the query parameter's name)
) -> Response:
    """The estimate's attitude as a CCSDS APM 2.0 (ADM 504.0-B-2; KVN, or XML with ``format=xml``): the quaternion
    from GCRF to the body at its observation time, with the estimate, its models and its trust in comments."""
    row = _owned(session, operator.id, estimate_id)
    text = attitude_exports.estimate_apm(row, format)
    media = "application/xml" if format == "xml" else "text/plain"
    name = f"estimate-{row.id}.apm" + (".xml" if format == "xml" else "")
    return Response(text, media_type=media, headers={"Content-Disposition": f'attachment; filename="{name}"'})


def _png(settings: SettingsDep, digest: str) -> Response:
    path = images.blob_path(Path(settings.data_dir), digest)
    if not path.is_file():
        raise HTTPException(status_code=404, detail="Image not found")
    return FileResponse(path, media_type="image/png")


@router.get("/{estimate_id}/enhanced.png", response_class=FileResponse, responses=NOT_FOUND)
def enhanced_png(
    session: SessionDep, operator: CurrentOperator, settings: SettingsDep, estimate_id: Annotated[Text, PathParam()]
) -> Response:
    """The UNet++-enhanced frame."""
    return _png(settings, _owned(session, operator.id, estimate_id).enhanced_sha256)


@router.get("/{estimate_id}/original.png", response_class=FileResponse, responses=NOT_FOUND)
def original_png(
    session: SessionDep, operator: CurrentOperator, settings: SettingsDep, estimate_id: Annotated[Text, PathParam()]
) -> Response:
    """The uploaded frame as the models saw it (normalised)."""
    return _png(settings, _owned(session, operator.id, estimate_id).original_sha256)


@router.get(
    "/{estimate_id}/outline.png",
    response_class=Response,
    responses={**NOT_FOUND, 200: {"content": {"image/png": {}}, "description": "the fitted outline, 255 on the edge"}},
)
def outline_png(
    session: SessionDep, operator: CurrentOperator, checkers: CheckersDep, estimate_id: Annotated[Text, PathParam()]
) -> Response:
    """The target's projection at the answered attitude, as its edge on the frame's grid (to lay over original.png).

    Drawn again from the stored attitude with the target the frame was fitted to; 404 where that
    target is no longer served.
    """
    stored = EstimatePublic.from_row(_owned(session, operator.id, estimate_id))
    checker = _served_checker(checkers, stored)
    angles = np.asarray(stored.attitude.euler_zyx_deg, float)[None]
    occupancy = checker.renderer.occupancy(angles)[0] > 0.5
    return Response(images.outline_png(occupancy), media_type="image/png")


def _served_checker(checkers: Any, stored: EstimatePublic) -> Any:
    """The checker of the target the estimate was fitted to; 404 where this service no longer serves it."""
    from inference.errors import ModelFileError

    try:
        return checkers.get(stored.target or checkers.default)
    except ModelFileError:  # a target this service no longer has
        raise HTTPException(status_code=404, detail="the estimate's target is not served here") from None


MAP_VIEW_RESPONSES: dict[int | str, dict[str, Any]] = {
    **NOT_FOUND,
    200: {"content": {"image/png": {}}, "description": "a view of the frame under the model set's reflectivity map"},
}


@router.get("/{estimate_id}/map.png", response_class=Response, responses=MAP_VIEW_RESPONSES)
def map_png(
    session: SessionDep,
    operator: CurrentOperator,
    settings: SettingsDep,
    checkers: CheckersDep,
    estimate_id: Annotated[Text, PathParam()],
) -> Response:
    """What the model set's reflectivity map predicts of the frame at the answered attitude, normalised as frames are
    (40 dB below the frame's reference). 404 where the set serving the estimate's target has no map."""
    return Response(_map_view(session, operator.id, settings, checkers, estimate_id, 0), media_type="image/png")


@router.get("/{estimate_id}/residual.png", response_class=Response, responses=MAP_VIEW_RESPONSES)
def residual_png(
    session: SessionDep,
    operator: CurrentOperator,
    settings: SettingsDep,
    checkers: CheckersDep,
    estimate_id: Annotated[Text, PathParam()],
) -> Response:
    """The frame over the map's prediction at the answered attitude, in dB: -10 black, 0 grey, +10 white. 404 where
    the set serving the estimate's target has no map."""
    return Response(_map_view(session, operator.id, settings, checkers, estimate_id, 1), media_type="image/png")


def _map_view(session: Any, operator_id: str, settings: Any, checkers: Any, estimate_id: str, which: int) -> bytes:
    """A stored estimate's view under the map as a PNG: ``which`` 0 the map's prediction, 1 the residual."""
    row = _owned(session, operator_id, estimate_id)
    stored = EstimatePublic.from_row(row)
    checker = _served_checker(checkers, stored)
    views = getattr(checker.image, "views", None)
    if views is None:
        raise HTTPException(
            status_code=404, detail="the model set serving this target has no reflectivity map (gsa adapt --map-only)"
        )
    frame = images.png_frame(images.blob_path(Path(settings.data_dir), row.original_sha256).read_bytes())
    return images.png_bytes(views(frame, np.asarray(stored.attitude.euler_zyx_deg, float))[which])


@router.delete("/{estimate_id}", status_code=204, responses=NOT_FOUND)
def delete_estimate(
    session: SessionDep, operator: CurrentOperator, settings: SettingsDep, estimate_id: Annotated[Text, PathParam()]
) -> Response:
    """Delete one of the caller's estimates (its images go when no other estimate uses them)."""
    e = _owned(session, operator.id, estimate_id)
    digests = {e.original_sha256, e.enhanced_sha256}
    crud.delete_estimate(session=session, estimate=e)
    for d in digests:
        if not crud.blob_in_use(session=session, digest=d):
            images.blob_path(Path(settings.data_dir), d).unlink(missing_ok=True)
    return Response(status_code=204)
