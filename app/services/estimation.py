"""Uploaded frames to stored, checked attitudes, placed by a plan in the frames operators fly in (LVLH, J2000).

Uploads are decoded in ``uploads``; images are written and stored in ``images``; the frames are
read (the networks, the fit, the checks) by ``scene.reading`` and placed by the plan's ``scene.Scene``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from datetime import datetime
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray
from sqlalchemy.orm import Session

from app import crud
from app.core.config import Settings
from app.db.models import Estimate, utcnow
from app.errors import InputError
from app.schemas import CONTROL_CHARACTERS
from app.schemas.estimates import EstimateResult
from app.services import images
from app.services.scenes import scene_for, windows_of
from app.services.uploads import DecodeBudget, Upload, decode, prepare
from inference.rotations import rotation_matrix
from scene.errors import SceneError
from scene.geometry import check_times
from scene.reading import Readings, read_frames

if TYPE_CHECKING:  # the checks load numba: the service gets them from its dependencies
    from inference.runtime import Estimator
    from inference.trust import Checker


def prepare_frames(
    *,
    est: Estimator,
    checker: Checker,
    uploads: list[Upload],
    resample: bool,
    normalised: bool,
    cells_m: tuple[float, float] | None,
) -> tuple[NDArray[np.float32], float]:
    """Return the uploads as the frames the models take [N, H, W], and the seconds that took."""
    t0 = time.perf_counter()
    model_cells = (checker.radar.range_cell_m, checker.radar.cross_range_cell_m)
    frames = np.stack([prepare(u, est.img_size, resample, normalised, cells_m, model_cells) for u in uploads])
    return frames, time.perf_counter() - t0


def check_frames(
    *,
    est: Estimator,
    checker: Checker,
    uploads: list[Upload],
    resample: bool,
    normalised: bool,
    cells_m: tuple[float, float] | None,
    refine: bool = True,
    search: bool = True,
    cancelled: Callable[[], bool] | None = None,
) -> Readings:
    """Prepare uploads, run the models on them as one batch and fit and check each (``scene.reading``)."""
    frames, prep_s = prepare_frames(
        est=est, checker=checker, uploads=uploads, resample=resample, normalised=normalised, cells_m=cells_m
    )
    return read_frames(est, checker, frames, refine, search, preprocess_s=prep_s, cancelled=cancelled)


@dataclass(frozen=True)
class EstimateRequest:
    """What an estimate's form asks, beside its frames (the single and the batch route take the same)."""

    resample: bool = False
    plan_id: str | None = None
    observed_at: datetime | None = None
    normalised: bool = False
    refine: bool = True
    target: str | None = None
    cells_m: tuple[float, float] | None = None


def estimate_and_store(
    *,
    session: Session,
    operator_id: str,
    settings: Settings,
    est: Estimator,
    checker: Checker,
    uploads: list[Upload],
    asked: EstimateRequest,
    snr_db: float | None = None,
    cancelled: Callable[[], bool] | None = None,
) -> list[Estimate]:
    """Validate everything, run the models on one batch, store the images, then the rows in one transaction.

    ``cancelled()`` (the client gone) stops the fit between frames; nothing is stored then.

    The single and batch upload routes both end here; the images are stored before their rows, and
    again after them, because a concurrent delete of an estimate with the same image may remove it.
    """
    resample, plan_id, observed_at = asked.resample, asked.plan_id, asked.observed_at
    normalised, refine, cells_m = asked.normalised, asked.refine, asked.cells_m
    if not uploads:
        raise InputError(["file"], "no frames in the upload")
    if len(uploads) > settings.max_batch_frames:
        raise InputError(["file"], f"{len(uploads)} frames is over the batch limit of {settings.max_batch_frames}")
    if any(CONTROL_CHARACTERS.search(u.name) for u in uploads):
        raise InputError(["file"], "a frame's name (a stack member) must not contain control characters")
    if (observed_at is None) != (plan_id is None) and observed_at is not None:
        raise InputError(["plan_id"], "observed_at needs a plan_id to place the attitude in LVLH and J2000")
    plan = None
    if plan_id is not None:
        plan = crud.get_plan(session=session, operator_id=operator_id, plan_id=plan_id)
        if plan is None:
            raise InputError(["plan_id"], f"no plan {plan_id} belongs to you")
        if observed_at is not None:  # a frame the station could not have made is refused, not placed
            try:
                check_times(windows_of(plan.result, plan.station_name), [observed_at])
            except SceneError as exc:
                raise InputError(["observed_at"], str(exc).replace("frame 0's time", "observed_at")) from None
    read = check_frames(
        est=est,
        checker=checker,
        uploads=uploads,
        resample=resample,
        normalised=normalised,
        cells_m=cells_m,
        refine=refine,
        cancelled=cancelled,
    )
    frames, enhanced, checks = read.frames, read.network.enhanced, read.checks
    in_frames: list[tuple[NDArray[np.float64], NDArray[np.float64]] | None] = [None] * len(uploads)
    if plan is not None and observed_at is not None:  # the batch's one moment, placed once
        placed = scene_for(plan.request, observed_at, observed_at).placements([observed_at])
        in_frames = [placed.attitudes(0, rotation_matrix(*(float(a) for a in c.angles_deg))) for c in checks]
    rows = []
    blobs: list[bytes] = []
    for k, u in enumerate(uploads):
        blobs += [images.png_bytes(frames[k]), images.png_bytes(enhanced[k])]
        original = images.store_blob(settings.data_dir, blobs[-2])
        enh = images.store_blob(settings.data_dir, blobs[-1])
        result = EstimateResult.from_checked(
            checks[k],
            target=checker.model.name,
            model=est.identity,
            timings_s={**read.timings_s, "batch_size": len(uploads)},
            input_normalised=normalised or u.normalised,
            cells_m=cells_m,
            in_frames=in_frames[k],
            model_cells_m=(checker.radar.range_cell_m, checker.radar.cross_range_cell_m),
        )
        rows.append(
            Estimate(
                operator_id=operator_id,
                created_at=utcnow(),
                plan_id=plan_id,
                observed_at=observed_at,
                input_name=u.name[:255],
                input_sha256=u.sha256,
                shape=list(u.shape),
                dtype=u.dtype,
                snr_db=snr_db,
                result=result.stored(),
                original_sha256=original,
                enhanced_sha256=enh,
            )
        )
    stored = crud.create_estimates(session=session, rows=rows)
    for blob in blobs:  # a concurrent delete of an estimate with the same image may have removed it meanwhile
        images.store_blob(settings.data_dir, blob)
    return stored


def estimate_file(
    *,
    session: Session,
    operator_id: str,
    settings: Settings,
    est: Estimator,
    checker: Checker,
    data: bytes,
    filename: str,
    asked: EstimateRequest,
    snr_db: float | None = None,
    cancelled: Callable[[], bool] | None = None,
) -> Estimate:
    """Decode one uploaded frame (a stack is refused: the batch route takes it), estimate it and store it."""
    budget = DecodeBudget.of(settings, "file")
    uploads = decode(data, filename, allow_stack=False, max_side=settings.max_image_side, budget=budget)
    if len(uploads) != 1:
        raise InputError(["file"], f"the file holds {len(uploads)} frames; send stacks to /v1/estimates/batch")
    return estimate_and_store(
        session=session,
        operator_id=operator_id,
        settings=settings,
        est=est,
        checker=checker,
        uploads=uploads,
        asked=asked,
        snr_db=snr_db,
        cancelled=cancelled,
    )[0]
