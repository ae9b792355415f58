"""The one converter from a stored plan to a ``scene.Scene``: the request validated once, its orbit and station built."""

from __future__ import annotations

from datetime import datetime
from typing import Any

from app.schemas import AccessPublic, PlanCreate, PlanResult
from app.services.planning import plan_options, to_orbit, to_station
from scene import Scene, Window


def plan_request(request: PlanCreate | dict[str, Any]) -> PlanCreate:
    """A stored plan's request as the typed request (validated here, once per scene)."""
    return request if isinstance(request, PlanCreate) else PlanCreate.model_validate(request)


def scene_for(
    request: PlanCreate | dict[str, Any], start: datetime, end: datetime, field: str = "observed_at"
) -> Scene:
    """Return the scene of a plan's target and station over ``[start, end]`` (one propagation).

    ``field`` names what set the span, for the error where it lies too far from the target's epoch.
    """
    req = plan_request(request)
    assert req.ground_station is not None  # a stored request names its (chosen) radar
    return Scene.over(
        to_orbit(req.target, "target"), to_station(req.ground_station), plan_options(req).reading, start, end, field
    )


def windows_of(result: dict[str, Any] | AccessPublic | PlanResult, station: str | None = None) -> list[Window]:
    """A plan's (or an access search's) access windows, stored or typed, as the scene takes them; of a network's,
    only ``station``'s (the stored request's one radar)."""
    if isinstance(result, AccessPublic | PlanResult):
        rows = [w.model_dump(mode="json") for w in result.access_windows]
    else:
        rows = list(result.get("access_windows", []))
    return [
        Window(datetime.fromisoformat(w["rise"]), datetime.fromisoformat(w["set"]), float(w["max_elevation_deg"]))
        for w in rows
        if w.get("station") is None or station is None or w["station"] == station
    ]
