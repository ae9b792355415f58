"""Attitude as CCSDS messages: an estimate's attitude in GCRF as an APM 2.0 (ADM 504.0-B-2), KVN or XML, for
Orekit, STK and any flight-dynamics tool that reads ADM (``planner.ccsds.apm_message`` writes it)."""

from __future__ import annotations

from datetime import UTC, datetime

from app.db.models import Estimate
from app.errors import Conflict
from app.schemas import EstimatePublic
from planner.ccsds import Format, apm_message

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
