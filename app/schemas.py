"""Request and response schemas of the API (pydantic). The planner never sees these."""

from __future__ import annotations

import math
import re
from datetime import datetime
from typing import TYPE_CHECKING, Annotated, Any, Literal, overload

import numpy as np
from pydantic import AfterValidator, BaseModel, BeforeValidator, ConfigDict, Discriminator, Field, Tag, model_validator
from pydantic.json_schema import SkipJsonSchema

from planner.access import validate_mask
from planner.errors import PlannerError
from planner.propagation import as_utc, utc

if TYPE_CHECKING:
    from planner.access import AccessWindows
    from planner.alignment import Candidate
    from planner.plan import Feasibility, Plan

_ISO_DATE = re.compile(r"^\d{4}-\d{2}-\d{2}")


def _iso_only(value: Any) -> Any:
    """Take date-times as ISO 8601 text only: a bare number (``0``, ``1.7e9``) is refused, not read as Unix time."""
    if isinstance(value, str) and not _ISO_DATE.match(value.strip()):
        raise ValueError("give an ISO 8601 date-time such as 2022-11-28T11:28:29Z")
    if isinstance(value, int | float):
        raise ValueError("give an ISO 8601 date-time such as 2022-11-28T11:28:29Z, not a number")
    return value


@overload
def utc_or_none(moment: datetime) -> datetime: ...
@overload
def utc_or_none(moment: None) -> None: ...
def utc_or_none(moment: datetime | None) -> datetime | None:
    """The same instant as aware UTC (planner.propagation.as_utc; naive is taken as UTC), or None.

    SQLite hands back naive datetimes for UTC columns, and a filter given with another offset
    (``+14:00``) must be the same instant in UTC before it is compared (SQLite compares the text).
    """
    return None if moment is None else as_utc(moment)


def _as_utc_in_range(moment: datetime) -> datetime:
    """The same instant in UTC; one that UTC cannot hold (0001-01-01T00:00+14:00) is a 422, not a crash."""
    try:
        return as_utc(moment)
    except OverflowError:
        raise ValueError("this date-time falls outside years 1-9999 once in UTC; give a real epoch") from None


IsoDateTime = Annotated[datetime, BeforeValidator(_iso_only), AfterValidator(_as_utc_in_range)]

CONTROL_CHARACTERS = re.compile(r"[\x00-\x1f\x7f]")


def _no_control(value: str | None) -> str | None:
    if value is not None and CONTROL_CHARACTERS.search(value):
        raise ValueError("must not contain control characters (NUL, tab, newline, ...); remove them")
    return value


# An id, filter or name from a path, a query or a form: NUL and other control characters are
# refused at the edge (PostgreSQL cannot store NUL in text, and no id or name holds one).
Text = Annotated[str, AfterValidator(_no_control)]
Name = Annotated[str, Field(min_length=1, max_length=200, pattern=r"^[^/\\\x00-\x1f]+$")]
Finite = Annotated[float, Field(allow_inf_nan=False)]


def _finite_or_null(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


class Described(BaseModel):
    """Every field's description is the docstring under it (or its Field's): one place for each field's words."""

    model_config = ConfigDict(use_attribute_docstrings=True)


class Strict(Described):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


# Orbits: Table-1 elements or a TLE
class ElementsIn(Strict):
    """Orbital elements at an epoch, as in the paper's Table 1 (heights above 6378.137 km)."""

    model_config = ConfigDict(
        extra="forbid",
        allow_inf_nan=False,
        json_schema_extra={
            "oneOf": [{"required": ["ha_km", "hp_km"]}, {"required": ["semi_major_axis_km", "eccentricity"]}]
        },
    )

    epoch: IsoDateTime
    """the elements' epoch (ISO 8601, UTC)"""
    # The size and shape: apogee and perigee heights (Table 1), or the semi-major axis and eccentricity.
    ha_km: Annotated[Finite, Field(ge=100.0, le=1.0e6)] | SkipJsonSchema[None] = Field(
        default=None, description="apogee height above 6378.137 km, km"
    )
    hp_km: Annotated[Finite, Field(ge=100.0, le=1.0e6)] | SkipJsonSchema[None] = Field(
        default=None, description="perigee height, km (at least 100)"
    )
    semi_major_axis_km: Annotated[Finite, Field(ge=6478.137, le=1.0e6)] | SkipJsonSchema[None] = Field(
        default=None, description="instead of ha_km and hp_km: the semi-major axis, km"
    )
    eccentricity: Annotated[Finite, Field(ge=0.0, lt=1.0)] | SkipJsonSchema[None] = Field(
        default=None, description="with semi_major_axis_km"
    )
    inclination_deg: Finite = Field(ge=0.0, le=180.0)
    """inclination to the GCRS/J2000 equator, deg"""
    raan_deg: Finite = Field(ge=-360.0, le=360.0)
    """right ascension of the ascending node, deg"""
    arg_perigee_deg: Finite = Field(ge=-360.0, le=360.0)
    """argument of perigee, deg"""
    mean_anomaly_deg: Finite = Field(ge=-360.0, le=360.0)
    """mean anomaly at the epoch, deg"""

    @model_validator(mode="after")
    def _one_size_and_shape(self) -> ElementsIn:
        heights = self.ha_km is not None, self.hp_km is not None
        kepler = self.semi_major_axis_km is not None, self.eccentricity is not None
        if not ((all(heights) and not any(kepler)) or (all(kepler) and not any(heights))):
            raise ValueError("give ha_km and hp_km, or semi_major_axis_km and eccentricity (one pair, both of it)")
        if self.semi_major_axis_km is not None and self.eccentricity is not None:
            hp = self.semi_major_axis_km * (1.0 - self.eccentricity) - 6378.137
            if hp < 100.0:
                raise ValueError(f"the perigee is {hp:.1f} km high: below 100 km the orbit decays")
            self.ha_km = self.semi_major_axis_km * (1.0 + self.eccentricity) - 6378.137
            self.hp_km = hp
        assert self.ha_km is not None and self.hp_km is not None
        if self.ha_km < self.hp_km:
            raise ValueError(f"ha_km ({self.ha_km}) is below hp_km ({self.hp_km}): give the apogee height first")
        return self


class OmmIn(Described):
    """One CCSDS OMM (mean elements for SGP4) as CelesTrak serves it in JSON (``FORMAT=json``)."""

    model_config = ConfigDict(extra="allow", allow_inf_nan=False)

    OBJECT_NAME: Annotated[str, Field(max_length=80)] | None = None
    """the object's name"""
    OBJECT_ID: Annotated[str, Field(max_length=40)] | None = None
    """international designator (COSPAR), e.g. 1998-067A"""
    EPOCH: Annotated[str, Field(max_length=40, description="UTC, e.g. 2024-03-01T06:00:00.000000")]
    MEAN_MOTION: Finite = Field(description="revolutions a day")
    ECCENTRICITY: Finite
    """mean eccentricity (SGP4)"""
    INCLINATION: Finite = Field(description="deg")
    RA_OF_ASC_NODE: Finite = Field(description="deg")
    ARG_OF_PERICENTER: Finite = Field(description="deg")
    MEAN_ANOMALY: Finite = Field(description="deg")
    EPHEMERIS_TYPE: int | None = None
    """0: SGP4"""
    CLASSIFICATION_TYPE: Annotated[str, Field(max_length=1)] | None = None
    """U: unclassified"""
    NORAD_CAT_ID: int | None = None
    """NORAD catalogue number"""
    ELEMENT_SET_NO: int | None = None
    """element set number"""
    REV_AT_EPOCH: int | None = None
    """revolution number at the epoch"""
    BSTAR: Finite | None = None
    """SGP4 drag term, 1/earth radii"""
    MEAN_MOTION_DOT: Finite | None = None
    """first derivative of the mean motion / 2, rev/day^2"""
    MEAN_MOTION_DDOT: Finite | None = None
    """second derivative of the mean motion / 6, rev/day^3"""


ORBIT_SOURCES = ("elements", "tle", "omm", "omm_xml", "omm_csv", "omm_kvn", "opm")


class OrbitIn(Strict):
    """A satellite: a name and exactly one of ``elements``, ``tle`` (2 lines, a 3LE, or a text block), ``omm`` (a
    CelesTrak OMM JSON object), ``omm_xml``, ``omm_csv`` or ``omm_kvn`` (CelesTrak's OMM XML, CSV or KVN text, one
    element set), or ``opm`` (a CCSDS OPM in KVN: its state vector, taken as osculating elements)."""

    model_config = ConfigDict(
        extra="forbid",
        allow_inf_nan=False,
        json_schema_extra={"oneOf": [{"required": [k]} for k in ORBIT_SOURCES]},
    )

    name: Name
    """the satellite's name"""
    # Optional, but never null in the schema: oneOf above says which one is given.
    elements: ElementsIn | SkipJsonSchema[None] = None
    """orbital elements (Table 1 form: heights, or a and e)"""
    tle: (
        Annotated[list[Annotated[str, Field(max_length=80)]], Field(min_length=2, max_length=3)]
        | Annotated[str, Field(max_length=300)]
        | SkipJsonSchema[None]
    ) = Field(default=None, description="two element lines, a 3LE (a name line first), or the same as one text block")
    omm: OmmIn | SkipJsonSchema[None] = None
    """one CCSDS OMM as a CelesTrak JSON object"""
    omm_xml: Annotated[str, Field(max_length=20_000)] | SkipJsonSchema[None] = None
    """one CCSDS OMM as CelesTrak's XML"""
    omm_csv: Annotated[str, Field(max_length=5_000)] | SkipJsonSchema[None] = None
    """one CCSDS OMM as CelesTrak's CSV (a header line and one row)"""
    omm_kvn: Annotated[str, Field(max_length=20_000)] | SkipJsonSchema[None] = Field(
        default=None, description="a CCSDS OMM in KVN (KEYWORD = value lines), as CelesTrak serves FORMAT=kvn"
    )
    opm: Annotated[str, Field(max_length=20_000)] | SkipJsonSchema[None] = Field(
        default=None,
        description="a CCSDS OPM 2.0/3.0 in KVN: EPOCH (UTC) and X..Z_DOT (km, km/s) in EME2000, GCRF or ICRF about "
        "the Earth, read as osculating elements (plan with reading osculating)",
    )

    @model_validator(mode="after")
    def _one_source(self) -> OrbitIn:
        given = [k for k in ORBIT_SOURCES if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError(f"give exactly one of {', '.join(repr(k) for k in ORBIT_SOURCES)}; got {len(given)}")
        return self


def _mask_in_order(mask: list[list[float]] | None) -> list[list[float]] | None:
    """Azimuths increasing within [0, 360), elevations within [-5, 89]: the planner's own check, with its words."""
    if mask is not None:
        try:
            validate_mask(tuple((float(a), float(e)) for a, e in mask))
        except PlannerError as exc:
            raise ValueError(str(exc)) from None
    return mask


# [azimuth_deg, elevation_deg]: a two-number array, not a tuple (whose prefixItems OpenAPI 3.0 tools misread).
MaskPoint = Annotated[list[Finite], Field(min_length=2, max_length=2)]


class StationIn(Strict):
    """A ground radar site on the WGS-84 ellipsoid, its horizon and whether elevations are refracted."""

    name: Name = "GS"
    """the station's name"""
    latitude_deg: Finite = Field(ge=-90.0, le=90.0)
    """geodetic latitude (WGS-84), deg"""
    longitude_deg: Finite = Field(ge=-180.0, le=360.0)
    """longitude, deg east"""
    altitude_m: Finite = Field(default=0.0, ge=-500.0, le=9000.0)
    """height above the WGS-84 ellipsoid, m"""
    min_elevation_deg: Finite = Field(
        default=0.0, ge=-5.0, le=89.0, description="the lowest elevation the radar tracks at, in every direction (deg)"
    )
    max_range_km: Finite | None = Field(default=None, gt=0.0, le=1.0e5, description="the radar's longest slant range")
    mask: Annotated[list[MaskPoint] | None, AfterValidator(_mask_in_order)] = Field(
        default=None,
        max_length=720,
        description="the horizon the site sees (hills, buildings): [azimuth_deg, elevation_deg] pairs with the "
        "azimuths increasing in [0, 360) from north through east, linear between points and around north; "
        "a target is in view above both this and min_elevation_deg",
        examples=[[[0, 5], [90, 2], [180, 8], [270, 15]]],
    )
    refraction: bool = Field(
        default=False,
        description="add atmospheric refraction to every elevation (optical, Saemundsson's formula at 10 C and "
        "1010 hPa: 0.48 deg at the horizon); off (the default), elevations are geometric",
    )


StationName = Annotated[
    str,
    Field(
        min_length=1,
        max_length=200,
        pattern=r"^[^/\\\x00-\x1f]+$",
        description="the name of a station stored under /v1/stations",
    ),
]


def _station_kind(value: Any) -> str:
    return "str" if isinstance(value, str) else "StationIn"


# A site, or a stored site's name: told apart by the JSON type, so a bad site's errors are its own
# (not also "Input should be a valid string" from the name branch).
GroundStationIn = Annotated[
    Annotated[StationIn, Tag("StationIn")] | Annotated[StationName, Tag("str")], Discriminator(_station_kind)
]


STATION_EXAMPLE: dict[str, Any] = {
    "name": "Shanghai",
    "latitude_deg": 31.1,
    "longitude_deg": 121.3,
    "altitude_m": 4.0,
    "min_elevation_deg": 3.0,
    "mask": [[0, 5], [90, 2], [180, 8], [270, 15]],
}


class StationCreate(StationIn):
    """A station to store under /v1/stations and name in plans (``"ground_station": "NAME"``)."""

    model_config = ConfigDict(
        extra="forbid",
        allow_inf_nan=False,
        json_schema_extra={"examples": [STATION_EXAMPLE]},
    )

    name: Name
    """the station's name, unique among yours"""


class StationPublic(StationIn):
    created_at: datetime
    """when it was stored (UTC)"""

    @staticmethod
    def row_json(row: Any) -> dict[str, Any]:
        """Return a stored station row (app.db.models.GroundStation) as this schema's JSON-ready dict."""
        return {**row.station, "created_at": utc_or_none(row.created_at)}


class StationsPublic(Described):
    data: list[StationPublic]
    """the stations of this page, by name"""
    count: int
    """how many stations you have"""


class SearchIn(Strict):
    """The search: span, element reading, the (dHa, dHp) box and the choice criterion."""

    start: IsoDateTime | None = Field(default=None, description="default: the target's epoch")
    duration_days: Finite = Field(default=10.0, gt=0.0, le=30.0)
    """the span to search from start, days (at most 30)"""
    reading: Literal["osculating", "mean"] = "osculating"
    """osculating (the instantaneous orbit, numerical J2) or mean (J2 secular rates)"""
    dha_min_km: Finite = Field(default=-50.0, ge=-500.0, le=500.0)
    """the lowest apogee height change to try, km"""
    dha_max_km: Finite = Field(default=50.0, ge=-500.0, le=500.0)
    """the highest apogee height change, km"""
    dhp_min_km: Finite = Field(default=-50.0, ge=-500.0, le=500.0)
    """the lowest perigee height change, km"""
    dhp_max_km: Finite = Field(default=50.0, ge=-500.0, le=500.0)
    """the highest perigee height change, km"""
    step_km: Finite = Field(default=0.1, ge=0.001, le=100.0)
    """the (dHa, dHp) grid step, km"""
    max_miss_km: Finite = Field(default=10.0, gt=0.0, le=1.0e5)
    """a candidate's node-line miss may be at most this, km"""
    revolutions_before: list[Literal[1, 2]] = Field(default=[1, 2], min_length=1, max_length=2)
    """how many target revolutions before t_access the phasing burn may be"""
    criterion: Literal["smallest_change", "least_dv"] = "least_dv"
    """how the chosen candidate is picked: least_dv or smallest_change"""
    max_imaging_range_km: Finite = Field(default=50.0, gt=0.0)
    """the observer may be at most this far from the target at t_access, km"""
    max_phase_angle_deg: Finite = Field(default=90.0, gt=0.0, le=180.0)
    """the Sun-target-observer angle may be at most this, deg"""
    standoff_km: Finite = Field(
        default=5.0,
        ge=0.5,
        le=500.0,
        description="the observer is aimed this far from the target at T_access (never at the target itself), "
        "perpendicular to the relative velocity and toward the Sun where it can be",
    )
    min_separation_km: Finite = Field(
        default=1.0,
        ge=0.0,
        le=100.0,
        description="a plan whose closest approach over the arc is under this is marked infeasible (collision risk)",
    )
    max_tracking_rate_deg_s: Finite = Field(
        default=10.0,
        gt=0.0,
        le=180.0,
        description="the fastest line-of-sight rate the observer's optics can follow; faster fly-bys are infeasible",
    )

    @model_validator(mode="after")
    def _ordered(self) -> SearchIn:
        if self.dha_min_km > self.dha_max_km:
            raise ValueError(f"dha_min_km ({self.dha_min_km}) is above dha_max_km ({self.dha_max_km})")
        if self.dhp_min_km > self.dhp_max_km:
            raise ValueError(f"dhp_min_km ({self.dhp_min_km}) is above dhp_max_km ({self.dhp_max_km})")
        return self


PAPER_EXAMPLE: dict[str, Any] = {
    "target": {
        "name": "Sat_Target",
        "elements": {
            "epoch": "2022-11-27T16:00:00Z",
            "ha_km": 700,
            "hp_km": 600,
            "inclination_deg": 43,
            "raan_deg": 290,
            "arg_perigee_deg": 100,
            "mean_anomaly_deg": 200,
        },
    },
    "observer": {
        "name": "Sat_Obs",
        "elements": {
            "epoch": "2022-11-27T16:00:00Z",
            "ha_km": 700,
            "hp_km": 350,
            "inclination_deg": 99,
            "raan_deg": 10,
            "arg_perigee_deg": 0,
            "mean_anomaly_deg": 316.5,
        },
    },
    "ground_station": {"name": "GS", "latitude_deg": 31.1, "longitude_deg": 121.3, "altitude_m": 0},
}


class PlanCreate(Strict):
    """What to plan: the paper's Table 1 is the example."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, json_schema_extra={"examples": [PAPER_EXAMPLE]})

    target: OrbitIn
    """the satellite to image"""
    observer: OrbitIn
    """the optical observer satellite that manoeuvres"""
    ground_station: GroundStationIn = Field(
        description="the radar site, or the name of one stored under /v1/stations (the plan keeps a copy)"
    )
    search: SearchIn = Field(default_factory=SearchIn)
    """the search: span, box, ranking and encounter limits (defaults: the paper's)"""


class AccessCreate(Strict):
    """Access windows of one satellite to one station."""

    model_config = ConfigDict(
        extra="forbid",
        allow_inf_nan=False,
        json_schema_extra={
            "examples": [{"target": PAPER_EXAMPLE["target"], "ground_station": PAPER_EXAMPLE["ground_station"]}]
        },
    )

    target: OrbitIn
    """the satellite"""
    ground_station: GroundStationIn = Field(description="the radar site, or the name of one stored under /v1/stations")
    start: IsoDateTime | None = None
    """the start of the span (ISO 8601, UTC; default: the target's epoch)"""
    duration_days: Finite = Field(default=7.0, gt=0.0, le=30.0)
    """the span, days (at most 30)"""
    reading: Literal["osculating", "mean"] = "osculating"
    """osculating (numerical J2) or mean (J2 secular rates)"""


# Responses
class WindowPublic(Described):
    rise: datetime
    """when the target rises above the mask (UTC)"""
    culmination: datetime
    """its highest elevation (UTC)"""
    set: datetime
    """when it sets below the mask (UTC)"""
    duration_s: float
    """set - rise, s"""
    max_elevation_deg: float
    """the highest elevation, deg (refracted when the station asks for it)"""
    rise_azimuth_deg: float
    """azimuth at rise, deg from north through east"""
    culmination_azimuth_deg: float
    """azimuth at culmination, deg"""
    set_azimuth_deg: float
    """azimuth at set, deg"""
    min_range_km: float
    """the least slant range inside the window, km"""
    rise_clipped: bool
    """true when the pass was already in progress at the span's start (rise is the start)"""
    set_clipped: bool
    """true when it was still in progress at the span's end"""

    @classmethod
    def from_windows(cls, epoch: datetime, w: AccessWindows) -> list[WindowPublic]:
        """Return the planner's windows (seconds after ``epoch``) as UTC records."""
        return [
            cls(
                rise=utc(epoch, w.rise_s[k]),
                culmination=utc(epoch, w.culmination_s[k]),
                set=utc(epoch, w.set_s[k]),
                duration_s=float(w.set_s[k] - w.rise_s[k]),
                max_elevation_deg=float(w.max_elevation_deg[k]),
                rise_azimuth_deg=float(w.rise_azimuth_deg[k]),
                culmination_azimuth_deg=float(w.culmination_azimuth_deg[k]),
                set_azimuth_deg=float(w.set_azimuth_deg[k]),
                min_range_km=float(w.min_range_km[k]),
                rise_clipped=bool(w.rise_clipped[k]),
                set_clipped=bool(w.set_clipped[k]),
            )
            for k in range(len(w))
        ]


class FeasibilityPublic(Described):
    sunlit: bool
    """whether the target is in sunlight at t_access (an optical observer needs it)"""
    feasible: bool
    """whether every check passes"""
    reasons: list[str]
    """each failed check in words; empty when feasible"""
    observer_range_km: float | None
    """observer-target distance at t_access, km (the chosen candidate's, once planned)"""
    phase_angle_deg: float | None
    """Sun-target-observer angle at t_access, deg (the chosen candidate's)"""

    @classmethod
    def from_feasibility(cls, f: Feasibility) -> FeasibilityPublic:
        return cls(
            sunlit=f.sunlit,
            feasible=f.feasible,
            reasons=list(f.reasons),
            observer_range_km=_finite_or_null(f.observer_range_km),
            phase_angle_deg=_finite_or_null(f.phase_angle_deg),
        )


class CandidatePublic(Described):
    pass_index: int
    """which access window (0-based) this candidate belongs to"""
    node: str
    """the node line the alignment uses: +OC on the target's ascending side, -OC on its descending side"""
    t_access: datetime
    """the moment the target crosses the observer's orbital plane inside the pass (UTC)"""
    delta_ha_km: float
    """the observer's apogee height change this alignment needs, km"""
    delta_hp_km: float
    """the observer's perigee height change, km"""
    miss_km: float
    """distance of the target from the changed observer's orbital plane at t_access, km"""
    change_km: float
    """|dHa| + |dHp|, km: what smallest_change ranks by"""
    t_access_range: list[datetime] | None
    """the earliest and latest t_access the (dHa, dHp) box reaches in this pass, or null"""
    family: list[list[float]] = Field(description="(dHa, dHp) km pairs aligning the node line at the same moment")
    feasibility: FeasibilityPublic
    """whether this candidate can be imaged: light, range, phase angle"""

    @classmethod
    def from_candidate(cls, epoch: datetime, c: Candidate, f: Feasibility) -> CandidatePublic:
        return cls(
            pass_index=c.pass_index,
            node=c.node,
            t_access=utc(epoch, c.t_access_s),
            delta_ha_km=c.delta_ha_km,
            delta_hp_km=c.delta_hp_km,
            miss_km=c.miss_km,
            change_km=c.change_km,
            t_access_range=[utc(epoch, t) for t in c.t_access_range_s] if c.t_access_range_s else None,
            family=[
                [round(float(a), 4), round(float(p), 4)] for a, p in zip(c.family_dha_km, c.family_dhp_km, strict=True)
            ],
            feasibility=FeasibilityPublic.from_feasibility(f),
        )


class VerificationPublic(Described):
    miss_km: float = Field(
        description="numerically propagated (J2) distance of the observer from its aim point at T_access"
    )
    two_body_miss_km: float = Field(
        description="distance from the target if the plain two-body Lambert burn were flown"
    )
    corrections: int
    """differential corrections the shooting took to meet the aim point"""
    relative_speed_km_s: float = Field(description="observer-target relative speed at T_access")
    standoff_km: float = Field(description="distance of the aim point from the target")
    separation_km: float = Field(description="propagated observer-target distance at T_access")
    closest_approach_km: float = Field(
        description="least observer-target distance from the burn to one orbit after T_access"
    )
    closest_approach_time: datetime
    """when the closest approach is (UTC)"""
    target_angular_rate_deg_s: float = Field(
        description="the target's angular rate seen from the observer at T_access (what an optical tracker must follow)"
    )

    @classmethod
    def from_plan(cls, plan: Plan) -> VerificationPublic:
        ph, meet = plan.phasing, plan.encounter
        assert ph is not None and meet is not None
        return cls(
            miss_km=ph.miss_km,
            two_body_miss_km=ph.two_body_miss_km,
            corrections=ph.corrections,
            relative_speed_km_s=meet.relative_speed_km_s,
            standoff_km=float(np.linalg.norm(ph.standoff_km_vec)),
            separation_km=meet.separation_km,
            closest_approach_km=meet.closest_approach_km,
            closest_approach_time=utc(plan.epoch, meet.closest_approach_s),
            target_angular_rate_deg_s=meet.target_angular_rate_deg_s,
        )


class PhasingPublic(Described):
    t_burn: datetime
    """the phasing burn's moment (UTC)"""
    t_access: datetime
    """the imaging moment the burn aims at (UTC)"""
    revolutions_before: int
    """how many target revolutions before t_access the burn is"""
    lambert_revolutions: int
    """complete revolutions of the Lambert arc"""
    dv_m_s: list[float] = Field(description="impulse in GCRS, m/s")
    dv_rtn_m_s: list[float] = Field(description="impulse in radial / along-track / cross-track, m/s")
    dv_total_m_s: float
    """the burn's size, m/s"""
    verification: VerificationPublic
    """the burn flown by the numerical J2 propagator, and the encounter it gives"""

    @classmethod
    def from_plan(cls, plan: Plan) -> PhasingPublic | None:
        ph = plan.phasing
        if ph is None:
            return None
        return cls(
            t_burn=utc(plan.epoch, ph.t_burn_s),
            t_access=utc(plan.epoch, ph.t_access_s),
            revolutions_before=ph.revolutions_before,
            lambert_revolutions=ph.lambert_revolutions,
            dv_m_s=[float(x) * 1000.0 for x in ph.dv_km_s],
            dv_rtn_m_s=[float(x) * 1000.0 for x in ph.dv_rtn_km_s],
            dv_total_m_s=ph.dv_total_km_s * 1000.0,
            verification=VerificationPublic.from_plan(plan),
        )


class PlanResult(Described):
    epoch: datetime
    """the start of the search span (UTC)"""
    duration_days: float
    """the span searched, days"""
    reading: str
    """how the elements were read: osculating or mean"""
    access_windows: list[WindowPublic]
    """every pass of the target over the station"""
    candidates: list[CandidatePublic]
    """the best alignment of each pass, ranked by miss"""
    chosen: CandidatePublic | None
    """the candidate planned (the best sunlit one by the criterion), or null"""
    alignment_dv_m_s: float | None
    """the height change's cost, m/s"""
    phasing: PhasingPublic | None
    """the burn that brings the observer to the target at t_access, or null"""
    timings_s: dict[str, float]
    """where the planning time went, seconds"""
    notes: list[str]
    """what the planner wants the operator to know, in words"""

    @classmethod
    def from_plan(cls, plan: Plan) -> PlanResult:
        """Return the planner's ``Plan`` as the stored and returned result (times in UTC, speeds in m/s)."""
        ep = plan.epoch
        chosen = None
        if plan.chosen is not None and plan.chosen_feasibility is not None:
            chosen = CandidatePublic.from_candidate(ep, plan.chosen, plan.chosen_feasibility)
        return cls(
            epoch=ep,
            duration_days=plan.duration_s / 86400.0,
            reading=plan.reading,
            access_windows=WindowPublic.from_windows(ep, plan.windows),
            candidates=[
                CandidatePublic.from_candidate(ep, c, f) for c, f in zip(plan.candidates, plan.feasibility, strict=True)
            ],
            chosen=chosen,
            alignment_dv_m_s=None if plan.alignment_dv_km_s is None else plan.alignment_dv_km_s * 1000.0,
            phasing=PhasingPublic.from_plan(plan),
            timings_s={k: round(v, 4) for k, v in plan.timings_s.items()},
            notes=plan.notes,
        )


class PlanPublic(PlanResult):
    id: str
    """the plan's id"""
    created_at: datetime
    """when it was stored (UTC)"""
    target_name: str
    """the target's name"""
    observer_name: str
    """the observer's name"""
    station_name: str
    """the station's name"""

    @staticmethod
    def row_json(plan: Any) -> dict[str, Any]:
        """Return a stored plan row (app.db.models.Plan) as this schema's JSON-ready dict."""
        return {
            **plan.result,
            "id": plan.id,
            "created_at": utc_or_none(plan.created_at),
            "target_name": plan.target_name,
            "observer_name": plan.observer_name,
            "station_name": plan.station_name,
        }


class PlanSummary(Described):
    id: str
    """the plan's id"""
    created_at: datetime
    """when it was stored (UTC)"""
    target_name: str
    """the target's name"""
    observer_name: str
    """the observer's name"""
    station_name: str
    """the station's name"""
    t_access: datetime | None
    """the chosen candidate's t_access (UTC), or null"""
    miss_km: float | None
    """the chosen candidate's miss, km, or null"""


class PlansPublic(Described):
    data: list[PlanSummary]
    """the plans of this page, newest first"""
    count: int
    """how many plans match in all"""


class AccessPublic(Described):
    epoch: datetime
    """the start of the span (UTC)"""
    duration_days: float
    """the span searched, days"""
    access_windows: list[WindowPublic]
    """every pass of the target over the station in the span, in time order"""


class AttitudePublic(Described):
    euler_zyx_deg: list[float] = Field(description="Euler angles z, y, x (deg): R = Rz Ry Rx, body to frame")
    quaternion_wxyz: list[float]
    """the same rotation as a unit quaternion, scalar first (body to frame)"""
    rotation_matrix: list[list[float]]
    """the same rotation as a 3 x 3 matrix, rows the frame's axes in body coordinates (body to frame: v_frame = R v_body)"""


class QualityPublic(Described):
    silhouette_iou: float = Field(
        description="IoU of the fitted projection (the label the simulator would draw) with UNet++'s silhouette; "
        "fresh frames of the default target: 0.98-0.99"
    )
    uncertainty_deg: list[float | None] = Field(
        description="90 % bound on the error of z, y, x (deg), calibrated on fresh frames (inference/models/shipped/"
        "trust.json); null where the fit's curvature bounds nothing"
    )
    trusted: bool = Field(description="false when any check failed; reasons says which")
    reasons: list[str] = Field(description="each failed check in words; empty when trusted")


class AlternativePublic(AttitudePublic):
    silhouette_iou: float
    """IoU of this attitude's projection with UNet++'s silhouette"""
    fit_gap: float = Field(
        description="how much lower its soft IoU is than the answer's; negative when it fits better but the answer "
        "stays nearer Swin's estimate (Swin saw the brightness the silhouette lacks)"
    )
    distance_deg: float = Field(description="rotation angle between it and the answer")


class EstimatePublic(Described):
    id: str
    """the estimate's id"""
    created_at: datetime
    """when it was stored (UTC)"""
    plan_id: str | None
    """the plan the frame belongs to, if one was given"""
    observed_at: datetime | None
    """when the frame was observed (UTC), if given"""
    input_name: str
    """the uploaded file's name (with the member and index for stacks)"""
    input_sha256: str
    """sha256 of the uploaded file"""
    shape: list[int]
    """the uploaded frame's shape [rows, columns]"""
    dtype: str
    """the uploaded array's type"""
    snr_db: float | None
    """the SNR the caller stated, dB, if any"""
    attitude: AttitudePublic = Field(
        description="in the ISAR observation frame: the fitted attitude (Swin's own when refine=false)"
    )
    attitude_network: AttitudePublic | None = Field(
        None, description="Swin's own estimate, the fit's start (null for a target without trained networks)"
    )
    refined: bool = Field(True, description="whether the attitude was fitted to the target's projection")
    target: str | None = Field(None, description="the target model the frame was fitted to")
    quality: QualityPublic | None = Field(None, description="how sure the answer is (null on estimates made before it)")
    alternatives: list[AlternativePublic] = Field(
        default_factory=list, description="other attitudes that fit nearly as well, e.g. the near-mirror (z, -y, -x)"
    )
    attitude_lvlh: AttitudePublic | None = None
    """the attitude in the target's LVLH frame (with plan_id and observed_at)"""
    attitude_j2000: AttitudePublic | None = None
    """the attitude in J2000/GCRS (with plan_id and observed_at)"""
    model: dict[str, Any]
    """the models that answered: their card's name and file hashes"""
    timings_s: dict[str, float]
    """where the time went, seconds (decoding, the networks, the fit)"""
    input_normalised: bool = Field(
        False, description="true when the frame was sent already normalised (normalised=true) and taken as sent"
    )
    links: dict[str, str]
    """the estimate's own URL and its images' URLs"""

    @staticmethod
    def row_json(e: Any) -> dict[str, Any]:
        """Return a stored estimate row (app.db.models.Estimate) as this schema's JSON-ready dict."""
        r = e.result
        return {
            "id": e.id,
            "created_at": utc_or_none(e.created_at),
            "plan_id": e.plan_id,
            "observed_at": utc_or_none(e.observed_at),
            "input_name": e.input_name,
            "input_sha256": e.input_sha256,
            "shape": e.shape,
            "dtype": e.dtype,
            "snr_db": e.snr_db,
            "attitude": r["attitude"],
            "attitude_network": r.get("attitude_network"),
            "refined": r.get("refined", False),
            "target": r.get("target"),
            "quality": r.get("quality"),
            "alternatives": r.get("alternatives", []),
            "attitude_lvlh": r.get("attitude_lvlh"),
            "attitude_j2000": r.get("attitude_j2000"),
            "model": r["model"],
            "timings_s": r["timings_s"],
            "input_normalised": r.get("input_normalised", False),
            "links": {
                "self": f"/v1/estimates/{e.id}",
                "enhanced_png": f"/v1/estimates/{e.id}/enhanced.png",
                "original_png": f"/v1/estimates/{e.id}/original.png",
            },
        }


class EstimatesPublic(Described):
    data: list[EstimatePublic]
    """the estimates of this page"""
    count: int
    """how many estimates match in all"""


class ScenePublic(Described):
    plan_id: str
    """the plan"""
    target_name: str
    """its target's name"""
    t_access: datetime | None
    """its chosen t_access (UTC), or null"""
    miss_km: float | None
    """its chosen miss, km, or null"""
    estimates: list[EstimatePublic]
    """the estimates tied to the plan"""


class ScenesPublic(Described):
    data: list[ScenePublic]
    """the scenes of this page, newest first"""
    count: int
    """how many plans the caller has"""


class ErrorMessage(Described):
    """An error that is not about one field: its reason and the request id to quote."""

    detail: str
    """what was wrong and what to do"""
    request_id: str | None = None
    """the X-Request-ID of the request, to find it in the server's log"""


ERROR_RESPONSES: dict[int | str, dict[str, Any]] = {
    400: {"model": ErrorMessage, "description": "the body could not be parsed"},
    401: {"model": ErrorMessage, "description": "no API key, or an invalid or revoked one"},
    413: {"model": ErrorMessage, "description": "the request or an uploaded file is over its size limit"},
}


class PassFramePublic(Described):
    index: int
    """the frame's place in the upload (0-based)"""
    name: str
    """the frame's file name or stack member"""
    observed_at: datetime
    """when the frame was observed (UTC)"""
    attitude: AttitudePublic = Field(description="the frame's fitted attitude, in its own observation frame")
    attitude_network: AttitudePublic | None = None
    """Swin's own estimate for this frame"""
    refined: bool
    """whether the frame was fitted"""
    quality: QualityPublic
    """the frame's checks and bounds"""
    alternatives: list[AlternativePublic]
    """other attitudes that fit the frame nearly as well"""
    attitude_lvlh: AttitudePublic = Field(
        description="the branch the fusion took for this frame, body to LVLH at the frame's time, placed as the "
        "pass's answer sees it: for a turning target through the observation frame its rate turns"
    )
    branch: str = Field(description="answer, near-mirror, or alternative N: which of the frame's candidates agreed")
    used: bool
    """whether the fusion used this frame"""
    rejected_because: str | None = None
    """why it was not used, in words; null when used"""
    residual_deg: float = Field(
        description="rotation angle between this frame's branch and the fused attitude (for a turning target, the "
        "turning model's prediction for the frame)"
    )
    sweep_deg_s: float | None = Field(
        default=None,
        description="the line of sight's rate relative to the body as the radar measured it (aperture_deg / "
        "integration_s, deg/s); null when integration_s was not sent",
    )
    sweep_sigma_deg_s: float | None = Field(
        default=None,
        description="the 1-sigma error the fit gives sweep_deg_s (deg/s): 2 % of it, and more at a pass's ends, "
        "where one frame integrates for minutes and the rate changes over it; null without integration_s",
    )
    sweep_model_deg_s: float | None = Field(
        default=None,
        description="that rate as the pass's answer predicts it: the line of sight's own rate in LVLH for a still "
        "target, less the spin's part for a turning one",
    )


class PassAttitudeJ2000(AttitudePublic):
    at: datetime = Field(description="LVLH turns with the orbit: the J2000 attitude holds at this moment (mid-pass)")


class PassCommonFit(Described):
    frames: int
    """the frames fitted together"""
    moved_deg: float
    """how far (deg) the common fit moved the frames' robust mean"""
    silhouette_iou: float
    """the frames' mean soft IoU with the fitted attitude's silhouette"""


class PassPublic(Described):
    id: str
    """the pass's id"""
    created_at: datetime
    """when it was stored (UTC)"""
    plan_id: str | None
    """the plan the pass belongs to"""
    target: str
    """the target model the frames were fitted to"""
    attitude_lvlh: AttitudePublic = Field(
        description="the fused attitude, body to LVLH (x radial, y along-track, z normal)"
    )
    attitude_j2000: PassAttitudeJ2000
    """the fused attitude in J2000/GCRS at the pass's middle"""
    uncertainty_deg: list[float] = Field(description="90 % bound on the fused LVLH Euler z, y, x (deg)")
    alternative_lvlh: AttitudePublic | None = Field(
        default=None,
        description="another attitude (body to LVLH) that as many of the pass's frames agree with as with "
        "attitude_lvlh: the near-mirror, where the image plane barely turns over the pass (a reflection through it "
        "is then the same for every frame, so the pass's geometry cannot tell the two apart and the frames' own "
        "answers chose; uncertainty_deg does not cover it). Null when the frames tell them apart, and for a "
        "turning target",
    )
    trusted: bool = Field(
        default=True,
        description="false when fewer than 3 trusted frames agree: the fused attitude rests on too little",
    )
    used: int
    """how many frames the fusion used"""
    rejected: int
    """how many it did not use"""
    stable: bool | None = Field(
        description="true: three-axis stable over the pass; false: the frames show a body rate beyond their scatter; "
        "null: undecided, fewer than 3 trusted frames agree (see stability)"
    )
    rate_deg_s: list[float] = Field(description="the fitted body rate (deg/s, body axes)")
    rate_sigma_deg_s: list[float | None]
    """the fitted turning rate's standard error, deg/s (the turning model)"""
    turning_chi2: float | None = Field(
        default=None,
        description="how much better (chi-square, 3 degrees of freedom) a constant-rate model fits the frames than a "
        "still attitude; the target is called turning over 30",
    )
    common_fit: PassCommonFit | None = Field(
        default=None,
        description="a still pass's attitude_lvlh is the robust mean of its frames' answers, then fitted to the used "
        "frames' silhouettes all at once (their mean soft IoU, on a denser skin than a single frame's fit): how "
        "many frames, and how far the fit moved the mean. Null for a turning or undecided pass, or with fewer "
        "than 2 frames' silhouettes",
    )
    stability: str
    """the stability verdict in words: still in LVLH, or turning at a rate"""
    frames: list[PassFramePublic]
    """every frame's own answer and its part in the fusion"""

    @staticmethod
    def row_json(p: Any) -> dict[str, Any]:
        return {"id": p.id, "created_at": utc_or_none(p.created_at), "plan_id": p.plan_id, **p.result}
