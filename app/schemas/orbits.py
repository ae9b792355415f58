"""An orbit as a request gives it: Table-1 elements, a TLE, an OMM (JSON, XML, CSV, KVN) or an OPM."""

from __future__ import annotations

from typing import TYPE_CHECKING, Annotated

from pydantic import ConfigDict, Field, model_validator
from pydantic.json_schema import SkipJsonSchema

from app.schemas.common import Described, Finite, IsoDateTime, Name, Strict

if TYPE_CHECKING:
    pass


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


ORBIT_SOURCES = ("elements", "tle", "omm", "omm_xml", "omm_csv", "omm_kvn", "opm", "oem")


class OrbitIn(Strict):
    """A satellite: a name and exactly one of ``elements``, ``tle`` (2 lines, a 3LE, or a text block), ``omm`` (a
    CelesTrak OMM JSON object), ``omm_xml``, ``omm_csv`` or ``omm_kvn`` (CelesTrak's OMM XML, CSV or KVN text, one
    element set), ``opm`` (a CCSDS OPM in KVN or XML: its state vector, taken as osculating elements), or ``oem`` (a
    CCSDS OEM in KVN or XML: its first state, taken as osculating elements)."""

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
        Annotated[list[Annotated[str, Field(max_length=80)]], Field(min_length=2, max_length=30_000)]
        | Annotated[str, Field(max_length=1_000_000)]
        | SkipJsonSchema[None]
    ) = Field(
        default=None,
        description="two element lines, a 3LE (a name line first), or the same as one text block; a text block of "
        "several satellites (CelesTrak's 3LE files) gives the one whose name line or NORAD number is this orbit's name",
    )
    omm: OmmIn | Annotated[list[OmmIn], Field(min_length=1, max_length=2000)] | SkipJsonSchema[None] = None
    """a CCSDS OMM as a CelesTrak JSON object, or CelesTrak's JSON array as served (one object or several: the one
    whose OBJECT_NAME or NORAD_CAT_ID is this orbit's name is taken)"""
    omm_xml: Annotated[str, Field(max_length=20_000)] | SkipJsonSchema[None] = None
    """one CCSDS OMM as CelesTrak's XML"""
    omm_csv: Annotated[str, Field(max_length=5_000)] | SkipJsonSchema[None] = None
    """one CCSDS OMM as CelesTrak's CSV (a header line and one row)"""
    omm_kvn: Annotated[str, Field(max_length=20_000)] | SkipJsonSchema[None] = Field(
        default=None, description="a CCSDS OMM in KVN (KEYWORD = value lines), as CelesTrak serves FORMAT=kvn"
    )
    opm: Annotated[str, Field(max_length=20_000)] | SkipJsonSchema[None] = Field(
        default=None,
        description="a CCSDS OPM 2.0/3.0 in KVN or XML (NDM/XML, no DTD): EPOCH (UTC) and X..Z_DOT (km, km/s) in "
        "EME2000, GCRF or ICRF about the Earth, read as osculating elements (plan with reading osculating)",
    )

    oem: Annotated[str, Field(max_length=2_000_000)] | SkipJsonSchema[None] = Field(
        default=None,
        description="a CCSDS OEM 2.0/3.0 in KVN or XML (NDM/XML, no DTD), Earth-centred, EME2000, GCRF or ICRF, UTC: "
        "its first segment's first state read as osculating elements (plan with reading osculating). The plan's "
        "notes say how far two-body + J2 from that state departs from the OEM's own states over its first segment, "
        "and how many later segments (after manoeuvres) are not flown",
    )

    @model_validator(mode="after")
    def _one_source(self) -> OrbitIn:
        given = [k for k in ORBIT_SOURCES if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError(f"give exactly one of {', '.join(repr(k) for k in ORBIT_SOURCES)}; got {len(given)}")
        return self
