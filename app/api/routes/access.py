"""Access windows alone (not stored)."""

from __future__ import annotations

from fastapi import APIRouter
from fastapi.responses import StreamingResponse

from app.api import examples
from app.api.deps import CurrentOperator, SessionDep, SettingsDep, check_span
from app.schemas import AccessCreate, AccessPublic
from app.services.catalogue import access_answer

router = APIRouter(prefix="/access-windows", tags=["access"])


@router.post(
    "",
    response_model=AccessPublic,
    responses={
        200: {
            "content": {
                "application/json": {"example": examples.load("access")},
                "application/x-ndjson": {"schema": {"type": "string"}},
                "text/csv": {"schema": {"type": "string"}},
            },
            "description": "one satellite's windows (JSON); a catalogue's (targets) streamed a window a line, as JSON "
            "lines or CSV (format)",
        },
        413: {"description": "a catalogue over GSA_ACCESS_BUDGET target-station-days: the answer says how many fit"},
    },
)
def compute_access(
    session: SessionDep, operator: CurrentOperator, settings: SettingsDep, access_in: AccessCreate
) -> AccessPublic | StreamingResponse:
    """Return rise, culmination and set of every pass of the target over the station (given, or stored by name);
    or, with ``targets``, of every satellite of a catalogue over every station, streamed a window a line."""
    check_span(access_in.duration_days, settings, ["duration_days"])
    answer = access_answer(session=session, operator_id=operator.id, access_in=access_in, settings=settings)
    if isinstance(answer, AccessPublic):
        return answer
    return StreamingResponse(answer.pieces, media_type=answer.media_type)
