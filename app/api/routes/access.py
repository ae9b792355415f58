"""Access windows alone (not stored)."""

from __future__ import annotations

from fastapi import APIRouter

from app.api import examples
from app.api.deps import CurrentOperator, SessionDep, SettingsDep, check_span
from app.schemas import AccessCreate, AccessPublic
from app.services.planning import access_for

router = APIRouter(prefix="/access-windows", tags=["access"])


@router.post(
    "",
    response_model=AccessPublic,
    responses={200: {"content": {"application/json": {"example": examples.load("access")}}}},
)
def compute_access(
    session: SessionDep, operator: CurrentOperator, settings: SettingsDep, access_in: AccessCreate
) -> AccessPublic:
    """Return rise, culmination and set of every pass of the target over the station (given, or stored by name)."""
    check_span(access_in.duration_days, settings, ["duration_days"])
    return access_for(session=session, operator_id=operator.id, access_in=access_in, settings=settings)
