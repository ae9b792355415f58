"""A pass at the service's edge: the upload checked, the plan's scene built, the fused answer stored.

The numerics (placing the frames, fusing them, simulating a pass) live in ``scene``; this
module checks what the route cannot (frame counts, the plan is the caller's), converts the
stored plan to a ``scene.Scene`` once (``app.services.scenes``) and stores the typed answer.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from datetime import datetime
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray
from sqlalchemy.orm import Session

from app import crud
from app.core.config import Settings
from app.core.security import private_dir
from app.db.models import Pass
from app.errors import InputError
from app.schemas import AttitudePublic, PassResult
from app.services.estimation import prepare_frames
from app.services.scenes import scene_for, windows_of
from app.services.uploads import Upload
from inference.rotations import rotation_matrix
from scene.fusion import fit_and_fuse, pass_span, sweeps_from
from scene.geometry import check_times
from scene.simulation import PassOptions, SimulatedFrame

if TYPE_CHECKING:  # the checks load numba: the service gets them from its dependencies
    from inference.runtime import Estimator
    from inference.trust import Checker

PASS_RECORD_FORMAT = "gsa-isar pass 1"


def create_pass(
    *,
    session: Session,
    operator_id: str,
    settings: Settings,
    est: Estimator,
    checker: Checker,
    uploads: list[Upload],
    plan_id: str,
    observed_at: list[datetime],
    cells_m: tuple[float, float] | None,
    normalised: bool,
    integration_s: list[float] | None = None,
    aperture_deg: float | None = None,
    cancelled: Callable[[], bool] | None = None,
) -> Pass:
    """Fit every frame of a pass, place each in the plan target's LVLH frame at its time, fuse them, and store it.

    ``cancelled()`` (the client gone) stops the fit between frames; nothing is stored then."""
    model_aperture = checker.radar.aperture_deg if cells_m is None else None
    plan = _check_pass(
        session,
        operator_id,
        settings.max_batch_frames,
        uploads,
        plan_id,
        observed_at,
        integration_s,
        aperture_deg,
        model_aperture,
    )
    sweeps = sweeps_from(integration_s, aperture_deg, len(uploads), model_aperture)
    frames, prep_s = prepare_frames(
        est=est, checker=checker, uploads=uploads, resample=False, normalised=normalised, cells_m=cells_m
    )
    fused = fit_and_fuse(
        est=est,
        checker=checker,
        frames=frames,
        scene=scene_for(plan.request, *pass_span(observed_at, sweeps)),
        observed_at=observed_at,
        names=[u.name for u in uploads],
        sweeps=sweeps,
        preprocess_s=prep_s,
        cancelled=cancelled,
    )
    result = PassResult.from_pass(fused.attitude, target=checker.model.name, timings_s=fused.timings_s)
    return crud.create_pass(session=session, operator_id=operator_id, plan_id=plan_id, result=result)


def _check_pass(
    session: Session,
    operator_id: str,
    limit: int,
    uploads: list[Upload],
    plan_id: str,
    observed_at: list[datetime],
    integration_s: list[float] | None,
    aperture_deg: float | None,
    model_aperture_deg: float | None,
) -> Any:
    """What a pass request must be before any fitting (both routes: here, and in a job before it is queued);
    return the plan's row."""
    if len(uploads) < 2:
        raise InputError(["files"], f"a pass needs at least two frames; this upload holds {len(uploads)}")
    if len(uploads) > limit:
        raise InputError(["files"], f"{len(uploads)} frames is over the limit of {limit}")
    if len(observed_at) != len(uploads):
        raise InputError(
            ["observed_at"], f"{len(observed_at)} times for {len(uploads)} frames: send one time per frame"
        )
    plan = crud.get_plan(session=session, operator_id=operator_id, plan_id=plan_id)
    if plan is None:
        raise InputError(["plan_id"], f"no plan {plan_id} belongs to you")
    check_times(windows_of(plan.result, plan.station_name), observed_at)
    sweeps_from(integration_s, aperture_deg, len(uploads), model_aperture_deg)
    return plan


def submit_pass(
    *,
    session: Session,
    operator_id: str,
    settings: Settings,
    checker: Checker,
    uploads: list[Upload],
    plan_id: str,
    observed_at: list[datetime],
    cells_m: tuple[float, float] | None,
    normalised: bool,
    integration_s: list[float] | None = None,
    aperture_deg: float | None = None,
) -> Any:
    """Queue a pass as a job (``Prefer: respond-async``; up to GSA_MAX_PASS_JOB_FRAMES frames): checked now as the
    synchronous route checks it, its frames kept under ``GSA_DATA_DIR/jobs/ID`` until the worker has fused it."""
    from app.db.models import new_id
    from app.services import jobs, storage

    model_aperture = checker.radar.aperture_deg if cells_m is None else None
    _check_pass(
        session,
        operator_id,
        settings.max_pass_job_frames,
        uploads,
        plan_id,
        observed_at,
        integration_s,
        aperture_deg,
        model_aperture,
    )
    waiting = sum(4 * int(np.prod(u.magnitude.shape)) for u in uploads)  # float32 on disk until it runs
    storage.check_room(session, settings, operator_id, waiting, f"this pass's {len(uploads)} frames")
    job_id = new_id()
    folder = jobs.job_dir(settings, job_id)
    private_dir(folder)
    fd = os.open(folder / "frames.npz", os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "wb") as fh:
        # float32, as the networks read them: float64 doubled what waits on disk (issue 74)
        frames = {f"f{k:05d}": np.asarray(u.magnitude, np.float32) for k, u in enumerate(uploads)}
        np.savez(fh, **frames)  # type: ignore[arg-type]  # numpy's stub reserves allow_pickle
    params = {
        "plan_id": plan_id,
        "observed_at": [t.isoformat() for t in observed_at],
        "target": checker.model.name,
        "names": [u.name for u in uploads],
        "normalised": normalised,
        "frame_normalised": [u.normalised for u in uploads],
        "cells_m": list(cells_m) if cells_m else None,
        "integration_s": integration_s,
        "aperture_deg": aperture_deg,
        "frames": len(uploads),
    }
    return jobs.submit(
        session,
        operator_id=operator_id,
        kind="pass",
        params=params,
        total=len(uploads),
        stage=f"queued: a pass of {len(uploads)} frames",
        job_id=job_id,
        cap=settings.quota_queued_jobs,
    )


def run_pass_job(ctx: Any) -> dict[str, Any]:
    """The job: the kept frames fitted and fused by the target's answering version, the pass stored."""
    import shutil

    from app.services import jobs
    from app.services.model_versions import load_answering

    p = ctx.params
    folder = jobs.job_dir(ctx.settings, ctx.id)
    try:
        with np.load(folder / "frames.npz") as z:
            arrays = [z[f"f{k:05d}"].astype(np.float64) for k in range(int(p["frames"]))]
        uploads = [
            Upload(name=n, sha256="", shape=a.shape, dtype="float32", magnitude=a, normalised=bool(fn))
            for n, a, fn in zip(p["names"], arrays, p["frame_normalised"], strict=True)
        ]
        ctx.report(stage=f"loading the models of {p['target']}")
        with ctx.session_factory() as session:
            est, checker = load_answering(ctx.settings, session, p["target"], ctx.operator_id)
            ctx.report(stage=f"fitting and fusing {len(uploads)} frames", done=0, total=len(uploads))
            row = create_pass(
                session=session,
                operator_id=ctx.operator_id,
                settings=ctx.settings.model_copy(update={"max_batch_frames": ctx.settings.max_pass_job_frames}),
                est=est,
                checker=checker,
                uploads=uploads,
                plan_id=p["plan_id"],
                observed_at=[datetime.fromisoformat(t) for t in p["observed_at"]],
                cells_m=tuple(p["cells_m"]) if p.get("cells_m") else None,
                normalised=bool(p["normalised"]),
                integration_s=p.get("integration_s"),
                aperture_deg=p.get("aperture_deg"),
                cancelled=lambda: ctx.stopping,
            )
        return {"pass_id": row.id, "frames": len(uploads)}
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def pass_record(
    frames: list[SimulatedFrame],
    snrs: NDArray[np.float64],
    opts: PassOptions,
    window_index: int,
    window: dict[str, Any],
    plan_request: dict[str, Any],
    cells_m: tuple[float, float],
) -> dict[str, Any]:
    """Return the JSON record (``pass.json``) of a simulated pass: each frame's time, geometry and truth."""
    from dataclasses import asdict

    def att(r: NDArray[np.float64]) -> dict[str, Any]:
        return AttitudePublic.from_matrix(np.asarray(r)).model_dump()

    return {
        "format": PASS_RECORD_FORMAT,
        "frames_file": "frames.npz (member 'image': [N, H, W] normalised frames, upload with normalised=true)",
        "plan_request": plan_request,
        "window_index": window_index,
        "window": window,
        "options": asdict(opts),
        "range_cell_m": cells_m[0],
        "frames": [
            {
                "index": k,
                "observed_at": f.observed_at.strftime("%Y-%m-%dT%H:%M:%S.%fZ"),
                "integration_s": round(f.integration_s, 3),
                "range_km": round(f.range_km, 3),
                "snr_db": None if not math.isfinite(snrs[k]) else round(float(snrs[k]), 3),
                "cross_range_cell_m": cells_m[1],
                "attitude_observation": att(rotation_matrix(*f.attitude_deg)),
                "attitude_lvlh": att(f.body_to_lvlh),
                "attitude_j2000": att(f.lvlh_in_gcrs @ f.body_to_lvlh),
                "observation_axes_in_lvlh": np.asarray(f.observation_in_lvlh).round(12).tolist(),
                "observation_axes_in_j2000": (f.lvlh_in_gcrs @ f.observation_in_lvlh).round(12).tolist(),
            }
            for k, f in enumerate(frames)
        ],
    }
