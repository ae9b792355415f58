"""GSA scene planning: access windows, node alignment, phasing and its verification (Algorithm 1).

The public surface is below; each name is imported from its module when first used, so
``import planner`` costs nothing and ``planner.errors`` stays light for the service's edge.

    from planner import Orbit, PlanOptions, Station, make_plan
    plan = make_plan(Orbit("T", elements=...), Orbit("O", tle=parse_tle(l1, l2)), Station(...), PlanOptions())
"""

from __future__ import annotations

import importlib
from typing import Any

_WHERE = {
    "make_plan": "plan",
    "Plan": "plan",
    "PlanOptions": "plan",
    "Feasibility": "plan",
    "Orbit": "orbits",
    "Reading": "orbits",
    "trajectory": "orbits",
    "elements_trajectory": "orbits",
    "earth_frames": "orbits",
    "Elements": "elements",
    "TLE": "tle",
    "parse_tle": "tle",
    "tle_from_omm": "tle",
    "Station": "propagation",
    "EarthFrames": "propagation",
    "Trajectory": "propagation",
    "as_utc": "propagation",
    "seconds_between": "propagation",
    "utc": "propagation",
    "AccessWindows": "access",
    "access_windows": "access",
    "Candidate": "alignment",
    "HeightBox": "alignment",
    "PlannerError": "errors",
    "PlanningStopped": "errors",
}
__all__ = sorted(_WHERE)


def __getattr__(name: str) -> Any:
    if name not in _WHERE:
        raise AttributeError(f"module 'planner' has no attribute {name!r}")
    value = getattr(importlib.import_module(f"planner.{_WHERE[name]}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return __all__
