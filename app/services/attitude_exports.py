"""Attitude as CCSDS messages, KVN or XML, for Orekit, STK and any flight-dynamics tool that reads ADM 2.0
(504.0-B-2): an estimate's attitude in GCRF as an APM, a fused pass's as an AEM over the pass
(``planner.ccsds.apm_message`` and ``aem_message`` write them)."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import numpy as np
from sqlalchemy.orm import Session

from app import crud
from app.db.models import Estimate, Pass
from app.errors import Conflict
from app.schemas import EstimatePublic, PassPublic
from app.services.scenes import scene_for
from inference.rotations import euler_from_matrix, euler_to_quaternion, so3_exp
from planner.ccsds import Format, aem_message, apm_message

AEM_STEP_S = 1.0  # the AEM's attitude every second over the pass

ORIGINATOR = "GSA-ISAR"


def estimate_apm(row: Estimate, fmt: Format) -> str:
    """The estimate's attitude (body to GCRF) at its observation time as an APM; a ``Conflict`` (409) when it has
    none in an inertial frame (made without ``plan_id`` and ``observed_at``)."""
    e = EstimatePublic.from_row(row)
    if e.attitude_j2000 is None or e.observed_at is None:
        raise Conflict(
            f"estimate {row.id} has no attitude in an inertial frame: estimate the frame with plan_id and "
            "observed_at (the scene's geometry places the observation frame in GCRF), then export its APM"
        )
    q = e.quality
    comments = [
        f"GSA-ISAR estimate {row.id} of {row.input_name}",
        "body to GCRF at EPOCH: Q rotates GCRF's axes onto the body's (the body axes in GCRF are R(Q)'s columns)",
        f"target model {e.target or '-'}; models {e.model.get('name', '-')} version {e.model.get('version', 0)}",
    ]
    if q is not None:
        bound = ", ".join("-" if b is None else f"{b:.2f}" for b in q.uncertainty_deg)
        comments.append(f"trusted {'yes' if q.trusted else 'no'}; 90 % bound on Euler z, y, x (deg): {bound}")
    observed = e.observed_at if e.observed_at.tzinfo else e.observed_at.replace(tzinfo=UTC)
    return apm_message(
        created=datetime.now(UTC),
        originator=ORIGINATOR,
        object_name=(e.target or "UNKNOWN").upper(),
        object_id="UNKNOWN",
        epoch=observed,
        quaternion_wxyz=e.attitude_j2000.quaternion_wxyz,
        comments=comments,
        fmt=fmt,
    )


def pass_aem(session: Session, operator_id: str, row: Pass, fmt: Format) -> str:
    """The fused pass's attitude (body to GCRF) every second from its first frame to its last, as an AEM: a target
    still in LVLH keeps ``attitude_lvlh`` while LVLH turns with the orbit; a turning one follows the fitted body
    rate from ``attitude_at``. A ``Conflict`` (409) for a pass with no plan (nothing places LVLH in GCRF)."""
    p = PassPublic.from_row(row)
    plan = crud.get_plan(session=session, operator_id=operator_id, plan_id=p.plan_id) if p.plan_id else None
    if plan is None:
        raise Conflict(
            f"pass {row.id} has no plan: its attitude is in LVLH only; fuse the pass with plan_id (the scene's "
            "geometry places LVLH in GCRF), then export its AEM"
        )
    times = sorted(f.observed_at if f.observed_at.tzinfo else f.observed_at.replace(tzinfo=UTC) for f in p.frames)
    first, last = times[0], times[-1]
    n = max(int((last - first).total_seconds() // AEM_STEP_S), 1)
    steps = [first + timedelta(seconds=k * AEM_STEP_S) for k in range(n)] + [last]
    if steps[-1] == steps[0]:  # one moment: the message still needs two lines
        steps = [first, first + timedelta(seconds=AEM_STEP_S)]
    scene = scene_for(plan.request, steps[0] - timedelta(seconds=2), steps[-1] + timedelta(seconds=2))
    lvlh = scene.geometry(scene.seconds(steps)).lvlh
    a_ref = np.asarray(p.attitude_lvlh.rotation_matrix, float)
    turning = p.stable is False and p.attitude_at is not None
    w_body = np.radians(np.asarray(p.rate_deg_s, float))
    at = p.attitude_at if p.attitude_at is None or p.attitude_at.tzinfo else p.attitude_at.replace(tzinfo=UTC)
    quaternions = []
    for k, t in enumerate(steps):
        body_to_lvlh = a_ref @ so3_exp((t - at).total_seconds() * w_body) if turning and at else a_ref
        quaternions.append(list(euler_to_quaternion(*euler_from_matrix(np.asarray(lvlh[k]) @ body_to_lvlh))))
    model = (
        f"turning at {', '.join(f'{v:.3f}' for v in p.rate_deg_s)} deg/s (body axes) from {at.isoformat() if at else '-'}"
        if turning
        else "still in LVLH over the pass (LVLH turns with the orbit)"
    )
    comments = [
        f"GSA-ISAR pass {row.id}: {len(p.frames)} frames, {p.used} used; trusted {'yes' if p.trusted else 'no'}",
        f"body to GCRF each second: the fused body-to-LVLH attitude, {model}",
        "Q rotates GCRF's axes onto the body's (the body axes in GCRF are R(Q)'s columns)",
        f"90 % bound on the fused LVLH Euler z, y, x (deg): {', '.join(f'{b:.2f}' for b in p.uncertainty_deg)}",
    ]
    return aem_message(
        created=datetime.now(UTC),
        originator=ORIGINATOR,
        object_name=(p.target or "UNKNOWN").upper(),
        object_id="UNKNOWN",
        times=steps,
        quaternions_wxyz=quaternions,
        comments=comments,
        fmt=fmt,
    )
