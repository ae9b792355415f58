"""A ground radar site: its position, horizon mask and refraction; stored stations by name."""

from __future__ import annotations

from datetime import datetime
from typing import TYPE_CHECKING, Annotated, Any

from pydantic import AfterValidator, ConfigDict, Discriminator, Field, Tag, model_validator

from app.schemas.common import Described, Finite, Name, Strict, normalise_name, utc_or_none
from planner.access import validate_mask
from planner.errors import PlannerError
from planner.radar import RADAR_LIMITS, Radar, validate_radar

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


_RADAR = Radar()


def _radar_field(name: str, description: str) -> Any:
    lo, hi = RADAR_LIMITS[name]
    return Field(default=getattr(_RADAR, name), ge=lo, le=hi, description=f"{description} ({lo:g} to {hi:g})")


class RadarIn(Strict):
    """The site's imaging radar: what decides whether a scene's frames can be formed (``planner.radar``).

    Defaults: the paper's Table 3 band and frame, the transmitter of a tracking-and-imaging radar in that band
    (FHR's TIRA, Ku band), a 34 m dish; each default's source is in docs/planner.md ("The radar in the scene")."""

    min_elevation_deg: Finite = _radar_field(
        "min_elevation_deg",
        "the elevation below which the radar does not image, deg (the station's min_elevation_deg and mask still "
        "decide the access windows)",
    )
    frequency_ghz: Finite = _radar_field("frequency_ghz", "carrier frequency, GHz")
    bandwidth_ghz: Finite = _radar_field("bandwidth_ghz", "bandwidth, GHz (range cell c / 2B)")
    peak_power_kw: Finite = _radar_field("peak_power_kw", "peak transmit power, kW")
    pulse_width_us: Finite = _radar_field("pulse_width_us", "pulse length, microseconds")
    prf_hz: Finite = _radar_field("prf_hz", "pulse repetition frequency, Hz")
    gain_dbi: Finite = _radar_field("gain_dbi", "antenna gain, dBi")
    noise_temperature_k: Finite = _radar_field("noise_temperature_k", "system noise temperature, K")
    losses_db: Finite = _radar_field("losses_db", "system losses, dB")
    aperture_deg: Finite = _radar_field(
        "aperture_deg", "the angle the line of sight sweeps for one frame, deg (cross-range cell lambda / 2 dtheta)"
    )
    pulses: int = _radar_field("pulses", "azimuth samples a frame holds (its pulses at least)")
    max_integration_s: Finite = _radar_field("max_integration_s", "the longest coherent integration it holds, s")
    min_snr_db: Finite = _radar_field(
        "min_snr_db", "the least SNR over the integration a frame is worth reading at, dB"
    )

    @model_validator(mode="after")
    def _consistent(self) -> RadarIn:
        try:
            validate_radar(self.to_radar())
        except PlannerError as exc:
            raise ValueError(str(exc)) from None
        return self

    def to_radar(self) -> Radar:
        """The planner's radar."""
        return Radar(**self.model_dump())


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
    radar: RadarIn = Field(
        default_factory=RadarIn,
        description="the site's imaging radar: its elevation limit, radar equation and coherent time (defaults: a "
        "Ku-band tracking-and-imaging radar in the paper's Table 3 band)",
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


MAX_NETWORK = 20  # stations a plan or campaign may search at once (each one's passes are searched)


def station_name_of(st: StationIn | str) -> str:
    """A station's name, given as a site or as a stored station's name."""
    return st if isinstance(st, str) else st.name


def _unique_names(stations: list[StationIn | str]) -> list[StationIn | str]:
    """Each station of a network its own name (candidates and scenes name their radar by it)."""
    names = [station_name_of(st) for st in stations]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise ValueError(f"names {', '.join(twice)} more than once: give each station its own name")
    return stations


StationsIn = Annotated[
    list[GroundStationIn], Field(min_length=1, max_length=MAX_NETWORK), AfterValidator(_unique_names)
]


def checked_network(ground_station: StationIn | str | None, ground_stations: list[StationIn | str] | None) -> None:
    """One radar (``ground_station``) or a network (``ground_stations``, names unique), not neither; both only in a
    stored request, whose ``ground_station`` is then the radar of the chosen scene, one of the network."""
    if ground_stations is None:
        if ground_station is None:
            raise ValueError("give ground_station (one radar) or ground_stations (a network of radars)")
        return
    names = [station_name_of(st) for st in ground_stations]
    if ground_station is not None and station_name_of(ground_station) not in names:
        raise ValueError("give ground_station or ground_stations, not both")


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
