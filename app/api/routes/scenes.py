"""GSA scenes: each plan's chosen access with the estimates tied to it."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Query
from sqlalchemy import func, select

from app.api.deps import CurrentOperator, SessionDep, SettingsDep, as_utc, check_page_size
from app.db.models import Estimate, Plan
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
    where = Plan.operator_id == operator.id
    total = int(session.scalar(select(func.count()).select_from(Plan).where(where)) or 0)
    plans = session.scalars(
        select(Plan).where(where).order_by(Plan.created_at.desc()).limit(limit).offset(offset)
    ).all()
    by_plan: dict[str, list[Estimate]] = {p.id: [] for p in plans}
    if by_plan:  # one query for the whole page's estimates
        for e in session.scalars(
            select(Estimate)
            .where(Estimate.plan_id.in_(list(by_plan)), Estimate.operator_id == operator.id)
            .order_by(Estimate.created_at, Estimate.id)
        ):
            by_plan[str(e.plan_id)].append(e)
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
