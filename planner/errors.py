"""Domain errors of the planner: bad input raises one of these, each a ValueError.

Each carries the name of the offending field (``field``) so the service can tell the
caller exactly what to fix.
"""


class PlannerError(ValueError):
    """Base class: an input the planner cannot work with."""

    def __init__(self, message: str, field: str | None = None) -> None:
        super().__init__(message)
        self.field = field


class ElementsError(PlannerError):
    """Orbital elements that describe no usable orbit."""


class TLEError(PlannerError):
    """A two-line element set that is malformed or fails its checksum."""


class StationError(PlannerError):
    """A ground station outside the valid range of coordinates or masks."""


class SearchRangeError(PlannerError):
    """A time span or a dHa/dHp search box that is empty, inverted or too large."""


class LambertError(PlannerError):
    """A Lambert problem with no solution for the requested revolutions."""


class PlanningStopped(PlannerError):
    """Planning was stopped part-way: over its time budget, or its caller went away."""
