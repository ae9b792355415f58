"""Targets' labelled frames: a radar's frames with the optical observer's attitude, the data an adaptation learns from."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, File, Form, Query, UploadFile
from fastapi import Path as PathParam
from fastapi.concurrency import run_in_threadpool

from app import crud
from app.api.deps import (
    CheckersDep,
    CurrentOperator,
    ModelSetsDep,
    PageDep,
    SessionDep,
    SettingsDep,
    check_file_count,
    checker_for,
    models_for,
    read_upload,
)
from app.schemas import LabelledDeleted, LabelledFramePublic, LabelledFramesPublic, LabelledUpload, Text
from app.services import labelled as labelled_svc

router = APIRouter(prefix="/targets", tags=["labelled frames"])

FILES = (
    "labelled frames, one .npz each (the format of inference.labelled, as gsa simulate --scene writes it): 'image' "
    "(2-D, raw or complex, [range, cross-range]; 'normalised' optional), the label as 'angles_deg' (z, y, x in the "
    "frame's observation frame) or 'quaternion_j2000' (body to J2000, w x y z) with 'observed_at' and plan_id; "
    "optionally 'scene', 'attitude_sigma_deg', 'snr_db', 'range_cell_m' with 'cross_range_cell_m'. Or an image "
    "file (.png, .tif: 8/16-bit grayscale magnitudes; .npy: a 2-D array) whose label is a form field below, one "
    "per image file in the order of the files"
)
FORM_LABEL = (
    "repeat the field, one per image file (.png, .tif, .npy) in the order of the files; an .npz carries its own"
)


@router.post(
    "/{target}/labelled-frames",
    status_code=201,
    response_model=LabelledUpload,
    responses={
        409: {"description": "a file of the upload was stored by another request meanwhile; send it again"},
        413: {"description": "file too large"},
    },
)
async def add_labelled_frames(
    session: SessionDep,
    operator: CurrentOperator,
    settings: SettingsDep,
    model_sets: ModelSetsDep,
    checkers: CheckersDep,
    target: Annotated[Text, PathParam(max_length=200, description="the target model the frames show")],
    files: Annotated[list[UploadFile], File(description=FILES)],
    plan_id: Annotated[
        Text | None,
        Form(
            max_length=36, description="the plan whose geometry places labels given in J2000 (and the scene's station)"
        ),
    ] = None,
    scene: Annotated[
        Text | None,
        Form(max_length=200, description="the scene of frames whose file names none (default: the file's name)"),
    ] = None,
    attitude_sigma_deg: Annotated[
        float | None, Form(ge=0, le=10, description="the optical estimate's 1-sigma (deg), for frames that give none")
    ] = None,
    campaign_id: Annotated[
        Text | None,
        Form(
            max_length=36,
            description="instead of plan_id: the campaign whose target and station place labels given in J2000 "
            "(its frames' times within its access windows)",
        ),
    ] = None,
    angles_deg: Annotated[
        list[str] | None,
        Form(description=f"an image file's label 'z,y,x' (deg, the frame's observation frame): {FORM_LABEL}"),
    ] = None,
    quaternion_j2000: Annotated[
        list[str] | None,
        Form(description=f"instead of angles_deg: 'w,x,y,z' body to J2000, with observed_at and plan_id: {FORM_LABEL}"),
    ] = None,
    observed_at: Annotated[
        list[str] | None, Form(description=f"an image file's time (ISO 8601, UTC): {FORM_LABEL}")
    ] = None,
) -> LabelledUpload:
    """Store labelled frames of a target: each frame, its label in the frame's observation frame, and where it came from.

    Every file is read and checked before anything is stored; a file already stored (same content, same target)
    is not stored twice.
    """
    checker = checker_for(checkers, target)
    est = models_for(model_sets, checker)
    check_file_count(files, settings)
    data = [
        (f.filename or f"frame-{k}.npz", await read_upload(f, settings.max_upload_bytes)) for k, f in enumerate(files)
    ]
    return await run_in_threadpool(
        labelled_svc.create_labelled,
        session=session,
        operator_id=operator.id,
        settings=settings,
        target=checker.model.name,
        size=est.img_size,
        model_cells_m=(checker.radar.range_cell_m, checker.radar.cross_range_cell_m),
        files=data,
        plan_id=plan_id,
        scene=scene,
        attitude_sigma_deg=attitude_sigma_deg,
        campaign_id=campaign_id,
        angles_deg=angles_deg,
        quaternion_j2000=quaternion_j2000,
        observed_at=observed_at,
    )


@router.get("/{target}/labelled-frames", response_model=LabelledFramesPublic)
def list_labelled_frames(
    session: SessionDep,
    operator: CurrentOperator,
    checkers: CheckersDep,
    page: PageDep,
    target: Annotated[Text, PathParam(max_length=200, description="the target model")],
    scene: Annotated[Text | None, Query(max_length=200, description="only this scene's frames")] = None,
) -> LabelledFramesPublic:
    """List the caller's labelled frames of a target, newest first, with the counts per scene and the attitude coverage."""
    name = checker_for(checkers, target).model.name
    rows, _ = crud.list_labelled(
        session=session, operator_id=operator.id, target=name, limit=page.limit, offset=page.offset, scene=scene
    )
    summary = labelled_svc.summarise(session=session, operator_id=operator.id, target=name)
    return LabelledFramesPublic(**summary.model_dump(), data=[LabelledFramePublic.from_row(r) for r in rows])


@router.delete("/{target}/labelled-frames", response_model=LabelledDeleted)
def delete_labelled_frames(
    session: SessionDep,
    operator: CurrentOperator,
    settings: SettingsDep,
    checkers: CheckersDep,
    target: Annotated[Text, PathParam(max_length=200, description="the target model")],
    scene: Annotated[Text | None, Query(max_length=200, description="delete this scene's frames")] = None,
    every: Annotated[bool, Query(alias="all", description="delete all your labelled frames of the target")] = False,
) -> LabelledDeleted:
    """Delete the caller's labelled frames of a target: one scene's (``scene=S``), or all of them (``all=true``).
    Versions already adapted from them stay; what the frames took from the storage quota is free again."""
    name = checker_for(checkers, target).model.name
    return labelled_svc.delete_labelled(
        session=session, settings=settings, operator_id=operator.id, target=name, scene=scene, every=every
    )
