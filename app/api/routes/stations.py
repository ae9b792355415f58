"""Stations: radar sites an operator stores once and names in plans and access requests."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, HTTPException, Path, Response

from app import crud
from app.api import examples
from app.api.deps import CurrentOperator, PageDep, SessionDep
from app.schemas import StationCreate, StationPublic, StationsPublic, Text
from app.services.stations import store_station

router = APIRouter(prefix="/stations", tags=["stations"])

NOT_FOUND: dict[int | str, dict[str, Any]] = {404: {"description": "the caller has no station of this name"}}
StationPath = Annotated[Text, Path(min_length=1, max_length=200, description="the station's name, as stored")]


@router.post(
    "",
    status_code=201,
    response_model=StationPublic,
    responses={
        201: {"content": {"application/json": {"example": examples.load("station")}}},
        409: {"description": "the caller already has a station of this name; nothing changed"},
    },
)
def create_station(session: SessionDep, operator: CurrentOperator, station_in: StationCreate) -> StationPublic:
    """Store a station under its name; plans then give ``"ground_station": "NAME"`` instead of its coordinates.

    A plan keeps a copy of the station it was planned for, so deleting or replacing a station
    later changes no stored plan.
    """
    row = store_station(session=session, operator_id=operator.id, station=station_in.model_dump(mode="json"))
    return StationPublic.from_row(row)


@router.get("", response_model=StationsPublic)
def list_stations(
    session: SessionDep,
    operator: CurrentOperator,
    page: PageDep,
) -> StationsPublic:
    """List the caller's stations by name."""
    rows, total = crud.list_stations(session=session, operator_id=operator.id, limit=page.limit, offset=page.offset)
    return StationsPublic(data=[StationPublic.from_row(r) for r in rows], count=total)


@router.get("/{name}", response_model=StationPublic, responses=NOT_FOUND)
def get_station(session: SessionDep, operator: CurrentOperator, name: StationPath) -> StationPublic:
    """One of the caller's stations."""
    row = crud.get_station(session=session, operator_id=operator.id, name=name)
    if row is None:
        raise HTTPException(status_code=404, detail="Station not found")
    return StationPublic.from_row(row)


@router.delete("/{name}", status_code=204, responses=NOT_FOUND)
def delete_station(session: SessionDep, operator: CurrentOperator, name: StationPath) -> Response:
    """Delete one of the caller's stations (plans made with it keep their copy)."""
    row = crud.get_station(session=session, operator_id=operator.id, name=name)
    if row is None or not crud.delete_station(session=session, station=row):
        raise HTTPException(status_code=404, detail="Station not found")
    return Response(status_code=204)
