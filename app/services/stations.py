"""Stations: store one under its name, refusing a name the operator already holds (compared by ``name_key``)."""

from __future__ import annotations

from typing import Any
from urllib.parse import quote

from sqlalchemy.orm import Session

from app import crud
from app.db.models import GroundStation
from app.errors import Conflict


def store_station(*, session: Session, operator_id: str, station: dict[str, Any]) -> GroundStation:
    """Store the station; a 409 (``Conflict``) naming the stored one where its name is already held."""
    row = crud.create_station(session=session, operator_id=operator_id, station=station)
    if row is not None:
        return row
    same = crud.get_station(session=session, operator_id=operator_id, name=station["name"])
    stored = same.name if same is not None else station["name"]
    raise Conflict(
        f"a station named {stored!r} is already stored (names are compared ignoring case, width and surrounding "
        f"spaces): DELETE /v1/stations/{quote(stored, safe='')} first, or choose another name"
    )
