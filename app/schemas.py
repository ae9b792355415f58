"""Request and response schemas of the API (pydantic). The planner never sees these."""

from __future__ import annotations

import re
from datetime import datetime
from typing import Annotated, Any, Literal, overload

from pydantic import AfterValidator, BaseModel, BeforeValidator, ConfigDict, Discriminator, Field, Tag, model_validator
from pydantic.json_schema import SkipJsonSchema

from planner.access import validate_mask
from planner.errors import PlannerError
from planner.propagation import as_utc

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


IsoDateTime = Annotated[datetime, BeforeValidator(_iso_only), AfterValidator(as_utc)]

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


class Strict(BaseModel):
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
    raan_deg: Finite = Field(ge=-360.0, le=360.0)
    arg_perigee_deg: Finite = Field(ge=-360.0, le=360.0)
    mean_anomaly_deg: Finite = Field(ge=-360.0, le=360.0)

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


class OmmIn(BaseModel):
    """One CCSDS OMM (mean elements for SGP4) as CelesTrak serves it in JSON (``FORMAT=json``)."""

    model_config = ConfigDict(extra="allow", allow_inf_nan=False)

    OBJECT_NAME: Annotated[str, Field(max_length=80)] | None = None
    OBJECT_ID: Annotated[str, Field(max_length=40)] | None = None
    EPOCH: Annotated[str, Field(max_length=40, description="UTC, e.g. 2024-03-01T06:00:00.000000")]
    MEAN_MOTION: Finite = Field(description="revolutions a day")
    ECCENTRICITY: Finite
    INCLINATION: Finite = Field(description="deg")
    RA_OF_ASC_NODE: Finite = Field(description="deg")
    ARG_OF_PERICENTER: Finite = Field(description="deg")
    MEAN_ANOMALY: Finite = Field(description="deg")
    EPHEMERIS_TYPE: int | None = None
    CLASSIFICATION_TYPE: Annotated[str, Field(max_length=1)] | None = None
    NORAD_CAT_ID: int | None = None
    ELEMENT_SET_NO: int | None = None
    REV_AT_EPOCH: int | None = None
    BSTAR: Finite | None = None
    MEAN_MOTION_DOT: Finite | None = None
    MEAN_MOTION_DDOT: Finite | None = None


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
    # Optional, but never null in the schema: oneOf above says which one is given.
    elements: ElementsIn | SkipJsonSchema[None] = None
    tle: (
        Annotated[list[Annotated[str, Field(max_length=80)]], Field(min_length=2, max_length=3)]
        | Annotated[str, Field(max_length=300)]
        | SkipJsonSchema[None]
    ) = Field(default=None, description="two element lines, a 3LE (a name line first), or the same as one text block")
    omm: OmmIn | SkipJsonSchema[None] = None
    omm_xml: Annotated[str, Field(max_length=20_000)] | SkipJsonSchema[None] = None
    omm_csv: Annotated[str, Field(max_length=5_000)] | SkipJsonSchema[None] = None
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
    latitude_deg: Finite = Field(ge=-90.0, le=90.0)
    longitude_deg: Finite = Field(ge=-180.0, le=360.0)
    altitude_m: Finite = Field(default=0.0, ge=-500.0, le=9000.0)
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


class StationPublic(StationIn):
    created_at: datetime


class StationsPublic(BaseModel):
    data: list[StationPublic]
    count: int


class SearchIn(Strict):
    """The search: span, element reading, the (dHa, dHp) box and the choice criterion."""

    start: IsoDateTime | None = Field(default=None, description="default: the target's epoch")
    duration_days: Finite = Field(default=10.0, gt=0.0, le=30.0)
    reading: Literal["osculating", "mean"] = "osculating"
    dha_min_km: Finite = Field(default=-50.0, ge=-500.0, le=500.0)
    dha_max_km: Finite = Field(default=50.0, ge=-500.0, le=500.0)
    dhp_min_km: Finite = Field(default=-50.0, ge=-500.0, le=500.0)
    dhp_max_km: Finite = Field(default=50.0, ge=-500.0, le=500.0)
    step_km: Finite = Field(default=0.1, ge=0.001, le=100.0)
    max_miss_km: Finite = Field(default=10.0, gt=0.0, le=1.0e5)
    revolutions_before: list[Literal[1, 2]] = Field(default=[1, 2], min_length=1, max_length=2)
    criterion: Literal["smallest_change", "least_dv"] = "least_dv"
    max_imaging_range_km: Finite = Field(default=50.0, gt=0.0)
    max_phase_angle_deg: Finite = Field(default=90.0, gt=0.0, le=180.0)
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
    observer: OrbitIn
    ground_station: GroundStationIn = Field(
        description="the radar site, or the name of one stored under /v1/stations (the plan keeps a copy)"
    )
    search: SearchIn = Field(default_factory=SearchIn)


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
    ground_station: GroundStationIn = Field(description="the radar site, or the name of one stored under /v1/stations")
    start: IsoDateTime | None = None
    duration_days: Finite = Field(default=7.0, gt=0.0, le=30.0)
    reading: Literal["osculating", "mean"] = "osculating"


# Responses
class WindowPublic(BaseModel):
    rise: datetime
    culmination: datetime
    set: datetime
    duration_s: float
    max_elevation_deg: float
    rise_azimuth_deg: float
    culmination_azimuth_deg: float
    set_azimuth_deg: float
    min_range_km: float
    rise_clipped: bool
    set_clipped: bool


class FeasibilityPublic(BaseModel):
    sunlit: bool
    feasible: bool
    reasons: list[str]
    observer_range_km: float | None
    phase_angle_deg: float | None


class CandidatePublic(BaseModel):
    pass_index: int
    node: str
    t_access: datetime
    delta_ha_km: float
    delta_hp_km: float
    miss_km: float
    change_km: float
    t_access_range: list[datetime] | None
    family: list[list[float]] = Field(description="(dHa, dHp) km pairs aligning the node line at the same moment")
    feasibility: FeasibilityPublic


class VerificationPublic(BaseModel):
    miss_km: float = Field(
        description="numerically propagated (J2) distance of the observer from its aim point at T_access"
    )
    two_body_miss_km: float = Field(
        description="distance from the target if the plain two-body Lambert burn were flown"
    )
    corrections: int
    relative_speed_km_s: float = Field(description="observer-target relative speed at T_access")
    standoff_km: float = Field(description="distance of the aim point from the target")
    separation_km: float = Field(description="propagated observer-target distance at T_access")
    closest_approach_km: float = Field(
        description="least observer-target distance from the burn to one orbit after T_access"
    )
    closest_approach_time: datetime
    target_angular_rate_deg_s: float = Field(
        description="the target's angular rate seen from the observer at T_access (what an optical tracker must follow)"
    )


class PhasingPublic(BaseModel):
    t_burn: datetime
    t_access: datetime
    revolutions_before: int
    lambert_revolutions: int
    dv_m_s: list[float] = Field(description="impulse in GCRS, m/s")
    dv_rtn_m_s: list[float] = Field(description="impulse in radial / along-track / cross-track, m/s")
    dv_total_m_s: float
    verification: VerificationPublic


class PlanResult(BaseModel):
    epoch: datetime
    duration_days: float
    reading: str
    access_windows: list[WindowPublic]
    candidates: list[CandidatePublic]
    chosen: CandidatePublic | None
    alignment_dv_m_s: float | None
    phasing: PhasingPublic | None
    timings_s: dict[str, float]
    notes: list[str]


class PlanPublic(PlanResult):
    id: str
    created_at: datetime
    target_name: str
    observer_name: str
    station_name: str


class PlanSummary(BaseModel):
    id: str
    created_at: datetime
    target_name: str
    observer_name: str
    station_name: str
    t_access: datetime | None
    miss_km: float | None


class PlansPublic(BaseModel):
    data: list[PlanSummary]
    count: int


class AccessPublic(BaseModel):
    epoch: datetime
    duration_days: float
    access_windows: list[WindowPublic]


class AttitudePublic(BaseModel):
    euler_zyx_deg: list[float] = Field(description="Euler angles z, y, x (deg): R = Rz Ry Rx, body to frame")
    quaternion_wxyz: list[float]
    rotation_matrix: list[list[float]]


class QualityPublic(BaseModel):
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
    fit_gap: float = Field(
        description="how much lower its soft IoU is than the answer's; negative when it fits better but the answer "
        "stays nearer Swin's estimate (Swin saw the brightness the silhouette lacks)"
    )
    distance_deg: float = Field(description="rotation angle between it and the answer")


class EstimatePublic(BaseModel):
    id: str
    created_at: datetime
    plan_id: str | None
    observed_at: datetime | None
    input_name: str
    input_sha256: str
    shape: list[int]
    dtype: str
    snr_db: float | None
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
    attitude_j2000: AttitudePublic | None = None
    model: dict[str, Any]
    timings_s: dict[str, float]
    input_normalised: bool = Field(
        False, description="true when the frame was sent already normalised (normalised=true) and taken as sent"
    )
    links: dict[str, str]

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


class EstimatesPublic(BaseModel):
    data: list[EstimatePublic]
    count: int


class ScenePublic(BaseModel):
    plan_id: str
    target_name: str
    t_access: datetime | None
    miss_km: float | None
    estimates: list[EstimatePublic]


class ScenesPublic(BaseModel):
    data: list[ScenePublic]
    count: int


class ErrorMessage(BaseModel):
    """An error that is not about one field: its reason and the request id to quote."""

    detail: str
    request_id: str | None = None


ERROR_RESPONSES: dict[int | str, dict[str, Any]] = {
    400: {"model": ErrorMessage, "description": "the body could not be parsed"},
    401: {"model": ErrorMessage, "description": "no API key, or an invalid or revoked one"},
    413: {"model": ErrorMessage, "description": "the request or an uploaded file is over its size limit"},
}


class PassFramePublic(BaseModel):
    index: int
    name: str
    observed_at: datetime
    attitude: AttitudePublic = Field(description="the frame's fitted attitude, in its own observation frame")
    attitude_network: AttitudePublic | None = None
    refined: bool
    quality: QualityPublic
    alternatives: list[AlternativePublic]
    attitude_lvlh: AttitudePublic = Field(description="the branch the fusion took for this frame, in LVLH")
    branch: str = Field(description="answer, near-mirror, or alternative N: which of the frame's candidates agreed")
    used: bool
    rejected_because: str | None = None
    residual_deg: float = Field(description="rotation angle between this frame's branch and the fused attitude")


class PassAttitudeJ2000(AttitudePublic):
    at: datetime = Field(description="LVLH turns with the orbit: the J2000 attitude holds at this moment (mid-pass)")


class PassPublic(BaseModel):
    id: str
    created_at: datetime
    plan_id: str | None
    target: str
    attitude_lvlh: AttitudePublic = Field(
        description="the fused attitude, body to LVLH (x radial, y along-track, z normal)"
    )
    attitude_j2000: PassAttitudeJ2000
    uncertainty_deg: list[float] = Field(description="90 % bound on the fused LVLH Euler z, y, x (deg)")
    trusted: bool = Field(
        default=True,
        description="false when fewer than 3 trusted frames agree: the fused attitude rests on too little",
    )
    used: int
    rejected: int
    stable: bool = Field(description="false when the frames show a body rate beyond their scatter")
    rate_deg_s: list[float] = Field(description="the fitted body rate (deg/s, body axes)")
    rate_sigma_deg_s: list[float | None]
    turning_chi2: float | None = Field(
        default=None,
        description="how much better (chi-square, 3 degrees of freedom) a constant-rate model fits the frames than a "
        "still attitude; the target is called turning over 30",
    )
    stability: str
    frames: list[PassFramePublic]

    @staticmethod
    def row_json(p: Any) -> dict[str, Any]:
        return {"id": p.id, "created_at": utc_or_none(p.created_at), "plan_id": p.plan_id, **p.result}
