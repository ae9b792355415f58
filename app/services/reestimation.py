"""Re-estimation: the operator's stored frames of a target read again by another model version, as a job.

``POST /v1/model-sets/{target}/re-estimations`` queues it; the worker loads the version's networks and checks, reads
each stored estimate's frame (the frame the models saw, as stored: 8 bits a pixel) and stores a new estimate with
the same plan, time and name ("re-estimate of ..."), then says how far each answer moved and how many are trusted
before and after. The old estimates stay as they were.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from sqlalchemy import select
from sqlalchemy.orm import Session

from app.core.config import Settings
from app.db.models import Estimate, Job, ModelVersion
from app.errors import InputError
from app.services import jobs
from app.services.model_versions import load_answering, usable_row

MAX_LISTED = 1000  # pairs kept in the job's result; the counts and the median cover them all


def _version_row(session: Session, operator_id: str, target: str, version: int) -> ModelVersion | None:
    """The version's row (None: 0), when it is one the operator may use: its own, or the shared default."""
    try:
        return usable_row(session, operator_id, target, version)
    except LookupError:
        raise InputError(
            ["version"],
            f"{target} has no version {version} of yours (GET /v1/model-sets lists them; 0: the configured set)",
        ) from None


def _estimates(session: Session, operator_id: str, target: str, plan_id: str | None, limit: int) -> list[Estimate]:
    """The operator's estimates of ``target`` (of ``plan_id``), oldest first, at most ``limit``."""
    q = select(Estimate).where(Estimate.operator_id == operator_id).order_by(Estimate.created_at, Estimate.id)
    if plan_id is not None:
        q = q.where(Estimate.plan_id == plan_id)
    out = []
    for row in session.scalars(q):
        if (row.result or {}).get("target") == target and not row.input_name.startswith("re-estimate of "):
            out.append(row)
            if len(out) >= limit:
                break
    return out


def submit_reestimation(
    *,
    session: Session,
    settings: Settings,
    operator_id: str,
    target: str,
    version: int,
    plan_id: str | None,
    limit: int,
) -> Job:
    """Check the request (the version exists; there are estimates to read again) and queue it."""
    _version_row(session, operator_id, target, version)
    rows = _estimates(session, operator_id, target, plan_id, limit)
    if not rows:
        where = f" of plan {plan_id}" if plan_id else ""
        raise InputError(["target"], f"you have no stored estimates of {target}{where} to estimate again")
    return jobs.submit(
        session,
        operator_id=operator_id,
        kind="reestimate",
        params={"target": target, "version": version, "plan_id": plan_id, "limit": limit},
        total=len(rows),
        stage=f"queued: {len(rows)} estimates of {target} with version {version}",
        engine="local",
        cap=settings.quota_queued_jobs,
    )


def _angle_deg(q1: list[float], q2: list[float]) -> float:
    """The rotation angle between two attitudes (unit quaternions, either sign)."""
    dot = abs(float(np.dot(np.asarray(q1, float), np.asarray(q2, float))))
    return float(np.degrees(2.0 * np.arccos(min(1.0, dot))))


def run_reestimation(ctx: Any) -> dict[str, Any]:
    """The job: load the version, read each stored frame again, store the new estimates, compare."""
    from PIL import Image

    from app.services import images
    from app.services.estimation import EstimateRequest, estimate_and_store
    from app.services.uploads import Upload

    settings: Settings = ctx.settings
    target, version = ctx.params["target"], int(ctx.params["version"])
    ctx.report(stage=f"loading version {version} of {target}")
    with ctx.session_factory() as session:
        _version_row(session, ctx.operator_id, target, version)
        est, checker = load_answering(settings, session, target, ctx.operator_id, version)
        olds = _estimates(session, ctx.operator_id, target, ctx.params.get("plan_id"), int(ctx.params["limit"]))
        pairs: list[dict[str, Any]] = []
        before = after = 0
        for k, old in enumerate(olds):
            ctx.report(stage=f"estimating {k + 1}/{len(olds)} with version {version}", done=k, total=len(olds))
            with Image.open(images.blob_path(settings.data_dir, old.original_sha256)) as im:
                frame = np.asarray(im, dtype=np.float64) / 255.0
            upload = Upload(
                name=f"re-estimate of {old.input_name}"[:255],
                sha256=old.input_sha256,
                shape=tuple(old.shape),
                dtype=old.dtype,
                magnitude=frame,
                normalised=True,
            )
            asked = EstimateRequest(plan_id=old.plan_id, observed_at=old.observed_at, normalised=True, target=target)
            (new,) = estimate_and_store(
                session=session,
                operator_id=ctx.operator_id,
                settings=settings,
                est=est,
                checker=checker,
                uploads=[upload],
                asked=asked,
                snr_db=old.snr_db,
                cancelled=lambda: ctx.stopping,
            )
            was, now = old.result.get("quality") or {}, new.result.get("quality") or {}
            before += bool(was.get("trusted"))
            after += bool(now.get("trusted"))
            pairs.append(
                {
                    "from": old.id,
                    "to": new.id,
                    "change_deg": round(
                        _angle_deg(
                            old.result["attitude"]["quaternion_wxyz"], new.result["attitude"]["quaternion_wxyz"]
                        ),
                        3,
                    ),
                    "trusted": [bool(was.get("trusted")), bool(now.get("trusted"))],
                }
            )
        ctx.report(stage="done", done=len(olds), total=len(olds))
    changes = [p["change_deg"] for p in pairs]
    return {
        "target": target,
        "version": version,
        "estimates": len(pairs),
        "trusted_before": before,
        "trusted_after": after,
        "median_change_deg": round(float(np.median(changes)), 3) if changes else None,
        "input": "each estimate's stored frame (the models' input, 8 bits a pixel)",
        "pairs": pairs[:MAX_LISTED],
    }
