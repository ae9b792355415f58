"""GSA scenes: each plan's chosen access with the estimates tied to it."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from app import crud
from app.api.deps import CurrentOperator, PageDep, SessionDep, as_utc
from app.schemas import EstimatePublic, ScenesPublic

router = APIRouter(prefix="/scenes", tags=["scenes"])


@router.get("", response_model=ScenesPublic)
def list_scenes(
    session: SessionDep,
    operator: CurrentOperator,
    page: PageDep,
) -> dict[str, Any]:
    """List the caller's plans, newest first, each with its chosen access and its estimates."""
    plans, by_plan, total = crud.list_scenes(
        session=session, operator_id=operator.id, limit=page.limit, offset=page.offset
    )
    data = [
        {
            "plan_id": p.id,
            "target_name": p.target_name,
            "t_access": as_utc(p.t_access),
            "miss_km": p.miss_km,
            "estimates": [EstimatePublic.from_row(e) for e in by_plan[p.id]],
        }
        for p in plans
    ]
    return {"data": data, "count": total}
