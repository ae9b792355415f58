"""GSA scenes: each plan's chosen access with the estimates tied to it."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Query
from sqlalchemy import func, select

from app.api.deps import CurrentOperator, SessionDep, as_utc
from app.api.routes.estimates import public
from app.db.models import Estimate, Plan
from app.schemas import ScenesPublic

router = APIRouter(prefix="/scenes", tags=["scenes"])


@router.get("", response_model=ScenesPublic)
def list_scenes(
    session: SessionDep,
    operator: CurrentOperator,
    limit: Annotated[int, Query(ge=1, le=100)] = 20,
    offset: Annotated[int, Query(ge=0, le=10_000_000)] = 0,
) -> dict[str, Any]:
    """List the caller's plans, newest first, each with its chosen access and its estimates."""
    where = Plan.operator_id == operator.id
    total = int(session.scalar(select(func.count()).select_from(Plan).where(where)) or 0)
    plans = session.scalars(
        select(Plan).where(where).order_by(Plan.created_at.desc()).limit(limit).offset(offset)
    ).all()
    data = []
    for p in plans:
        ests = session.scalars(
            select(Estimate)
            .where(Estimate.plan_id == p.id, Estimate.operator_id == operator.id)
            .order_by(Estimate.created_at)
        ).all()
        data.append({"plan_id": p.id, "target_name": p.target_name, "t_access": as_utc(p.t_access), "miss_km": p.miss_km,
                     "estimates": [public(e) for e in ests]})  # fmt: skip
    return {"data": data, "count": total}
