"""Access windows alone (not stored)."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from app import openapi_examples as examples
from app.api.deps import CurrentOperator, SessionDep, SettingsDep, check_span
from app.schemas import AccessCreate, AccessPublic
from app.services.planning import run_access, stored_station_lookup, with_stored_station

router = APIRouter(prefix="/access-windows", tags=["access"])


@router.post(
    "",
    response_model=AccessPublic,
    responses={200: {"content": {"application/json": {"example": examples.load("access")}}}},
)
def compute_access(
    session: SessionDep, operator: CurrentOperator, settings: SettingsDep, access_in: AccessCreate
) -> dict[str, Any]:
    """Return rise, culmination and set of every pass of the target over the station (given, or stored by name)."""
    check_span(access_in.duration_days, settings, ["duration_days"])
    access_in = with_stored_station(access_in, stored_station_lookup(session, operator.id))
    return run_access(access_in, max_epoch_gap_days=settings.max_epoch_gap_days)
