"""A ground radar site: its position, horizon mask and refraction; stored stations by name."""

from __future__ import annotations

from datetime import datetime
from typing import TYPE_CHECKING, Annotated, Any

from pydantic import AfterValidator, ConfigDict, Discriminator, Field, Tag

from app.schemas.common import Described, Finite, Name, Strict, normalise_name, utc_or_none
from planner.access import validate_mask
from planner.errors import PlannerError

if TYPE_CHECKING:
    from app.db.models import GroundStation

    pass


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
    max_range_km: Finite | None = Field(
        default=None, ge=0.001, le=1.0e5, description="the radar's longest slant range, km (0.001-100000)"
    )
    max_azimuth_rate_deg_s: Finite = Field(
        default=10.0,
        ge=0.001,
        le=360.0,
        description="the fastest the antenna turns in azimuth, deg/s, 0.001-360 (10: a conservative rate for a large tracking "
        "antenna; give the site's own): a pass that needs more near the zenith is flagged a keyhole",
    )
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
    AfterValidator(normalise_name),
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

    @classmethod
    def from_row(cls, row: GroundStation) -> StationPublic:
        """Return a stored station row as the answer."""
        return cls.model_validate({**row.station, "created_at": utc_or_none(row.created_at)})


class StationsPublic(Described):
    data: list[StationPublic]
    """the stations of this page, by name"""
    count: int
    """how many stations you have"""
