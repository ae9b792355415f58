"""Frames to checked attitudes, and attitudes in the frames operators fly in (LVLH, J2000, the observation frame).

Uploads are decoded in ``uploads``; images are written and stored in ``images``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import datetime
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app import crud
from app.db.models import Estimate, utcnow
from app.errors import InputError
from app.schemas import CONTROL_CHARACTERS
from app.services import images
from app.services.uploads import Upload, prepare
from inference.frames import euler_from_matrix, euler_to_quaternion, rotation_matrix


def matrix_attitude_json(r: NDArray[np.float64]) -> dict[str, Any]:
    """``attitude_json`` of a rotation matrix, which it keeps as given (not rebuilt from its Euler angles)."""
    out = attitude_json(np.array(euler_from_matrix(r)))
    out["rotation_matrix"] = np.asarray(r).round(12).tolist()
    return out


def attitude_json(angles_deg: NDArray[np.floating]) -> dict[str, Any]:
    z, y, x = (float(a) for a in angles_deg)
    r = rotation_matrix(z, y, x)
    return {
        "euler_zyx_deg": [z, y, x],
        "quaternion_wxyz": list(euler_to_quaternion(z, y, x)),
        "rotation_matrix": r.round(12).tolist(),
    }


def check_frames(
    *,
    est: Any,
    checker: Any,
    uploads: list[Upload],
    resample: bool,
    normalised: bool,
    cells_m: tuple[float, float] | None,
    refine: bool = True,
    search: bool = True,
) -> tuple[Any, Any, list[Any], dict[str, float]]:
    """Prepare uploads, run the models on them as one batch and fit and check each; return frames, models' output,
    checks and the seconds per frame of each stage."""
    import time

    t0 = time.perf_counter()
    model_cells = (checker.radar.range_cell_m, checker.radar.cross_range_cell_m)
    frames = np.stack([prepare(u, est.img_size, resample, normalised, cells_m, model_cells) for u in uploads])
    t_prep = time.perf_counter() - t0
    res = est.estimate(frames)
    t1 = time.perf_counter()
    checks = checker.check_many(frames, res.enhanced, res.angles_deg if checker.networks else None, refine, search)
    t_fit = time.perf_counter() - t1
    n = len(uploads)
    per_frame = {"preprocess": t_prep / n, **{k: v / n for k, v in res.timings_s.items()}, "fit": t_fit / n}
    return frames, res, checks, per_frame


def checked_json(checked: Any) -> dict[str, Any]:
    """Return an ``inference.trust.Checked`` as the stored result's attitude, quality and alternatives."""
    q = checked.quality
    return {
        "attitude": attitude_json(checked.angles_deg),
        "attitude_network": None if checked.network_deg is None else attitude_json(checked.network_deg),
        "refined": checked.refined,
        "quality": {
            "silhouette_iou": q.silhouette_iou,
            "uncertainty_deg": [b if math.isfinite(b) else None for b in q.uncertainty_deg],
            "trusted": q.trusted,
            "reasons": list(q.reasons),
        },
        "alternatives": [
            {
                **attitude_json(np.array(a.angles_deg)),
                "silhouette_iou": round(a.silhouette_iou, 4),
                "fit_gap": round(a.fit_gap, 5),
                "distance_deg": round(a.distance_deg, 2),
            }
            for a in checked.alternatives
        ],
    }


def target_track(plan_request: dict[str, Any], epoch: datetime, t0_s: float, t1_s: float) -> tuple[Any, Any, Any]:
    """Return a stored plan's target trajectory over ``[t0_s, t1_s]`` after ``epoch``, its station and Earth frames."""
    from app.schemas import PlanCreate
    from app.services.planning import plan_options, to_orbit, to_station
    from planner.orbits import earth_frames, trajectory
    from planner.propagation import as_utc, seconds_between

    req = PlanCreate.model_validate(plan_request)
    target = to_orbit(req.target, "target")
    station = to_station(req.ground_station)
    reading = plan_options(req).reading
    epoch = as_utc(epoch)
    frames = earth_frames(epoch, t0_s, t1_s)
    if target.tle is None and reading != "mean":
        assert target.elements is not None
        if abs(seconds_between(epoch, target.elements.epoch)) > 60 * 86400:
            raise InputError(["observed_at"], "observed_at is more than 60 days from the target's epoch")
    return trajectory(target, epoch, frames, t0_s - 1.0, t1_s + 1.0, reading), station, frames


def frames_at(plan_request: dict[str, Any], observed_at: datetime) -> dict[str, NDArray[np.float64]]:
    """Return the observation, LVLH and J2000 (GCRS) axes at ``observed_at`` for a stored plan's target and station.

    Each is a matrix whose columns are the frame's axes in GCRS (``planner.frames``: the
    observation frame's Y follows the line of sight's rate in the target's LVLH frame).
    """
    return frames_at_times(plan_request, [observed_at])[0]


def frames_at_times(plan_request: dict[str, Any], times: list[datetime]) -> list[dict[str, NDArray[np.float64]]]:
    """``frames_at`` for several moments, from one propagation of the target over their span."""
    from planner.frames import observation_axes, pass_geometry

    t0 = min(times)
    offsets = np.array([(t - t0).total_seconds() for t in times])
    traj, station, frames = target_track(plan_request, t0, 0.0, float(offsets.max()))
    near = np.array([-0.5, 0.0, 0.5])
    geo = pass_geometry(traj, station, frames, (offsets[:, None] + near).ravel())
    out = []
    for k in range(len(times)):
        los = geo.los_lvlh[:, 3 * k : 3 * k + 3]
        lvlh = geo.lvlh[3 * k + 1]
        out.append(
            {
                "observation": lvlh @ observation_axes(los, near)[1],
                "lvlh": lvlh,
                "j2000": np.eye(3),
                "los_lvlh": los[:, 1],
                "los_rate_lvlh": (los[:, 2] - los[:, 0]) / (near[2] - near[0]),
            }
        )
    return out


def attitudes_in_frames(
    plan_request: dict[str, Any], observed_at: datetime, angles_deg: NDArray[np.floating]
) -> dict[str, Any]:
    """Return the estimated attitude (body to frame) in the LVLH and J2000 frames too."""
    axes = frames_at(plan_request, observed_at)
    body_to_obs = rotation_matrix(*(float(a) for a in angles_deg))
    body_to_gcrs = axes["observation"] @ body_to_obs
    out: dict[str, Any] = {name: matrix_attitude_json(axes[name].T @ body_to_gcrs) for name in ("lvlh", "j2000")}
    out["observation_axes_in_j2000"] = axes["observation"].round(12).tolist()
    return out


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
    session: Any,
    operator_id: str,
    settings: Any,
    est: Any,
    checker: Any,
    uploads: list[Upload],
    asked: EstimateRequest,
    snr_db: float | None = None,
) -> list[Estimate]:
    """Validate everything, run the models on one batch, store the images, then the rows in one transaction.

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
    frames, res, checks, per_frame = check_frames(
        est=est,
        checker=checker,
        uploads=uploads,
        resample=resample,
        normalised=normalised,
        cells_m=cells_m,
        refine=refine,
    )
    enhanced = res.enhanced
    angles = [c.angles_deg for c in checks]
    in_frames: list[dict[str, Any] | None] = [None] * len(uploads)
    if plan is not None and observed_at is not None:
        in_frames = [attitudes_in_frames(plan.request, observed_at, a) for a in angles]
    rows = []
    blobs: list[bytes] = []
    for k, u in enumerate(uploads):
        blobs += [images.png_bytes(frames[k]), images.png_bytes(enhanced[k])]
        original = images.store_blob(settings.data_dir, blobs[-2])
        enh = images.store_blob(settings.data_dir, blobs[-1])
        result: dict[str, Any] = {
            **checked_json(checks[k]),
            "target": checker.model.name,
            "model": est.identity,
            "timings_s": {**per_frame, "batch_size": len(uploads)},
            "input_normalised": normalised or u.normalised,
            "cells_m": list(cells_m) if cells_m else None,
        }
        placed = in_frames[k]
        if placed is not None:
            result["attitude_lvlh"] = placed["lvlh"]
            result["attitude_j2000"] = placed["j2000"]
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
                result=result,
                original_sha256=original,
                enhanced_sha256=enh,
            )
        )
    stored = crud.create_estimates(session=session, rows=rows)
    for blob in blobs:  # a concurrent delete of an estimate with the same image may have removed it meanwhile
        images.store_blob(settings.data_dir, blob)
    return stored
