"""Access windows alone: one satellite over one station, or a catalogue over a network, streamed."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import ConfigDict, Field, model_validator
from pydantic.json_schema import SkipJsonSchema

from app.schemas.common import Finite, IsoDateTime, Strict
from app.schemas.orbits import OmmIn, OrbitIn
from app.schemas.plans import PAPER_EXAMPLE
from app.schemas.stations import GroundStationIn, StationsIn, checked_network

# CelesTrak's "active" group holds about 10,000 objects; the work a request may ask for is bounded by the budget
# (GSA_ACCESS_BUDGET, target-station-days), not by this.
MAX_CATALOGUE = 50_000


class CatalogueIn(Strict):
    """Many satellites at once, as CelesTrak serves them: one of ``tle`` or ``omm``."""

    tle: Annotated[str, Field(min_length=1)] | SkipJsonSchema[None] = None
    """a TLE file's text (2LE or 3LE: an optional name line, then lines '1 ...' and '2 ...', set after set)"""
    omm: Annotated[list[OmmIn], Field(min_length=1, max_length=MAX_CATALOGUE)] | SkipJsonSchema[None] = None
    """an array of OMMs in JSON (CelesTrak's FORMAT=json)"""

    @model_validator(mode="after")
    def _one_form(self) -> CatalogueIn:
        if (self.tle is None) == (self.omm is None):
            raise ValueError("give the catalogue as tle (a TLE file's text) or omm (an array of OMMs), one of them")
        return self


class AccessCreate(Strict):
    """Access windows of one satellite to one station, or of a catalogue of satellites to a network."""

    model_config = ConfigDict(
        extra="forbid",
        allow_inf_nan=False,
        json_schema_extra={
            "examples": [{"target": PAPER_EXAMPLE["target"], "ground_station": PAPER_EXAMPLE["ground_station"]}]
        },
    )

    target: OrbitIn | SkipJsonSchema[None] = None
    """the satellite (or ``targets``: a catalogue)"""
    targets: CatalogueIn | SkipJsonSchema[None] = None
    """instead of ``target``, a catalogue of satellites (a TLE file or an OMM array): the windows are streamed, a
    line each, as JSON lines or CSV (``format``)"""
    ground_station: GroundStationIn | None = Field(
        default=None, description="the radar site, or the name of one stored under /v1/stations"
    )
    ground_stations: StationsIn | None = Field(
        default=None, description="instead of ground_station, several sites or stored names (each its own name)"
    )
    start: IsoDateTime | None = None
    """the start of the span (ISO 8601, UTC; default: the target's epoch, or a catalogue's newest)"""
    duration_days: Finite = Field(default=7.0, ge=0.001, le=30.0)
    """the span, days (0.001-30)"""
    reading: Literal["osculating", "mean"] = "osculating"
    """osculating (numerical J2) or mean (J2 secular rates); a catalogue's TLEs and OMMs are always SGP4's"""
    format: Literal["jsonl", "csv"] = "jsonl"
    """a catalogue's answer: JSON lines (application/x-ndjson) or CSV (text/csv), a window a line"""
    on_error: Literal["fail", "skip"] = "fail"
    """a catalogue's element set that cannot be read or propagated: the whole request refused (422 naming it), or
    skipped with an error line in the answer and the rest answered"""

    @model_validator(mode="after")
    def _one_target_and_radars(self) -> AccessCreate:
        if (self.target is None) == (self.targets is None):
            raise ValueError("give target (one satellite) or targets (a catalogue), one of them")
        checked_network(self.ground_station, self.ground_stations)
        if self.target is not None and self.ground_stations is not None:
            raise ValueError("ground_stations is for a catalogue (targets); give one satellite one ground_station")
        return self
