"""GSA scenes: each plan's chosen access with the estimates tied to it."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Query

from app import crud
from app.api.deps import CurrentOperator, SessionDep, SettingsDep, as_utc, check_page_size
from app.schemas import EstimatePublic, ScenesPublic

router = APIRouter(prefix="/scenes", tags=["scenes"])


@router.get("", response_model=ScenesPublic)
def list_scenes(
    session: SessionDep,
    operator: CurrentOperator,
    settings: SettingsDep,
    limit: Annotated[int | None, Query(ge=1, le=10_000, description="page size (default 20)")] = None,
    offset: Annotated[int, Query(ge=0, le=10_000_000)] = 0,
) -> dict[str, Any]:
    """List the caller's plans, newest first, each with its chosen access and its estimates."""
    limit = check_page_size(limit, settings)
    plans, by_plan, total = crud.list_scenes(session=session, operator_id=operator.id, limit=limit, offset=offset)
    data = [
        {
            "plan_id": p.id,
            "target_name": p.target_name,
            "t_access": as_utc(p.t_access),
            "miss_km": p.miss_km,
            "estimates": [EstimatePublic.row_json(e) for e in by_plan[p.id]],
        }
        for p in plans
    ]
    return {"data": data, "count": total}
