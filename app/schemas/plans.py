"""A plan: its request (orbits, station, search) and its result (access windows, candidates, the burn)."""

from __future__ import annotations

from datetime import datetime
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from pydantic import ConfigDict, Field, model_validator

from app.schemas.common import Described, Finite, IsoDateTime, StoredResult, Strict, finite_or_null, utc_or_none
from app.schemas.orbits import OrbitIn
from app.schemas.stations import GroundStationIn, StationsIn, checked_network
from planner.optics import EXCLUSIVE_MOST, OPTICS_LIMITS, ObserverOptics
from planner.propagation import utc

if TYPE_CHECKING:
    from app.db.models import Plan as PlanRow
    from planner.access import AccessWindows
    from planner.alignment import Candidate
    from planner.plan import Feasibility, Plan


class SceneSearchIn(Strict):
    """How one scene is searched for: the (dHa, dHp) box, the misses, the burn and the encounter's limits."""

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
    max_miss_km: Finite = Field(default=10.0, ge=0.001, le=1.0e5)
    """a candidate's node-line miss may be at most this, km (0.001-100000)"""
    revolutions_before: list[Literal[1, 2]] = Field(default=[1, 2], min_length=1, max_length=2)
    """how many target revolutions before t_access the phasing burn may be"""
    max_imaging_range_km: Finite | None = Field(default=None, ge=0.001, le=1.0e6)
    """a range cap below the optics' own, km, 0.001-1000000 (default: observer_optics' diffraction range, gsd x aperture /
    (1.22 wavelength))"""
    standoff_km: Finite | None = Field(
        default=None,
        ge=0.5,
        le=500.0,
        description="the observer is aimed this far from the target at T_access (never at the target itself), "
        "perpendicular to the relative velocity and toward the Sun where it can be; default: chosen, the least "
        "range at which the optics track the fly-by (5 % beyond relative speed / max_rate_deg_s), within the range "
        "they resolve observer_optics.gsd_m at",
    )
    min_separation_km: Finite = Field(
        default=1.0,
        ge=0.0,
        le=100.0,
        description="a plan whose closest approach over the arc is under this is marked infeasible (collision risk)",
    )

    @model_validator(mode="after")
    def _ordered(self) -> SceneSearchIn:
        if self.dha_min_km > self.dha_max_km:
            raise ValueError(f"dha_min_km ({self.dha_min_km}) is above dha_max_km ({self.dha_max_km})")
        if self.dhp_min_km > self.dhp_max_km:
            raise ValueError(f"dhp_min_km ({self.dhp_min_km}) is above dhp_max_km ({self.dhp_max_km})")
        return self


class SearchIn(SceneSearchIn):
    """The search: span, element reading, the (dHa, dHp) box and the choice criterion."""

    start: IsoDateTime | None = Field(default=None, description="default: the target's epoch")
    duration_days: Finite = Field(default=10.0, ge=0.001, le=30.0)
    """the span to search from start, days (0.001-30)"""
    reading: Literal["osculating", "mean"] = "osculating"
    """osculating (the instantaneous orbit, numerical J2) or mean (J2 secular rates)"""
    criterion: Literal["smallest_change", "least_dv"] = "least_dv"
    """how the chosen candidate is picked among those that pass every check (then the sunlit ones, then the rest):
    least_dv, the cheapest, or smallest_change, the best-ranked"""
    max_dv_m_s: Finite | None = Field(default=None, ge=0.0, le=20000.0)
    """a candidate dearer than this (height change plus phasing), m/s, is infeasible (default: no cap)"""
    max_phase_angle_deg: Finite | None = Field(default=None, ge=0.001, le=180.0)
    """replaced by observer_optics.max_phase_angle_deg, and still read when given here: the largest Sun phase angle
    (0.001-180 deg)"""
    max_tracking_rate_deg_s: Finite | None = Field(
        default=None,
        ge=0.001,
        le=180.0,
        description="replaced by observer_optics.max_rate_deg_s, and still read when given here: the fastest "
        "line-of-sight rate the observer's pointing follows (0.001-180 deg/s)",
    )


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


_OPTICS = ObserverOptics()  # the defaults are the planner's, written once there with their sources


def _optics_field(name: str) -> Any:
    """The field ``name`` of the observer's optics with the planner's default and bounds (``OPTICS_LIMITS``)."""
    least, most, _ = OPTICS_LIMITS[name]
    if name in EXCLUSIVE_MOST:
        return Field(default=getattr(_OPTICS, name), ge=least, lt=most)
    return Field(default=getattr(_OPTICS, name), ge=least, le=most)


class ObserverOpticsIn(Strict):
    """The observer's telescope and pointing: the range it resolves at, the rate it tracks, the Sun it avoids.

    Defaults (``planner.optics.ObserverOptics``, where each is sourced): a 0.3 m aperture at 550 nm,
    0.25 m ground sample distance, 10 deg/s tracking, 30 deg Sun exclusion, 90 deg largest phase angle.
    """

    aperture_m: Finite = _optics_field("aperture_m")
    """the telescope's aperture diameter, m (0.01-10)"""
    wavelength_nm: Finite = _optics_field("wavelength_nm")
    """the imaging wavelength, nm (100-20000)"""
    gsd_m: Finite = _optics_field("gsd_m")
    """the ground sample distance the attitude work needs, m (0.001-100): with the aperture, it sets the largest
    range"""
    max_rate_deg_s: Finite = _optics_field("max_rate_deg_s")
    """the fastest line-of-sight rate the pointing follows, deg/s (0.001-180)"""
    sun_exclusion_deg: Finite = _optics_field("sun_exclusion_deg")
    """the boresight's least angle from the Sun, deg (0 up to 180)"""
    max_phase_angle_deg: Finite = _optics_field("max_phase_angle_deg")
    """the largest Sun-target-observer angle that still shows the target's lit side, deg (0.001-180)"""


class PlanCreate(Strict):
    """What to plan: the paper's Table 1 is the example."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, json_schema_extra={"examples": [PAPER_EXAMPLE]})

    target: OrbitIn
    """the satellite to image"""
    observer: OrbitIn
    """the optical observer satellite that manoeuvres"""
    ground_station: GroundStationIn | None = Field(
        default=None,
        description="the radar site, or the name of one stored under /v1/stations (the plan keeps a copy)",
    )
    ground_stations: StationsIn | None = Field(
        default=None,
        description="instead of ground_station, a network of radars (sites or stored names, each its own name; at "
        "most 20): every station's passes are searched, each candidate names the radar that images it, and the "
        "cheapest feasible scene is chosen across them",
    )
    search: SearchIn = Field(default_factory=SearchIn)
    """the search: span, box, ranking and encounter limits (defaults: the paper's)"""
    observer_optics: ObserverOpticsIn = Field(default_factory=lambda: ObserverOpticsIn())
    """what the observer images with (defaults: a 0.3 m telescope at 550 nm resolving 0.25 m, within 111.8 km)"""

    @model_validator(mode="after")
    def _one_radar_or_a_network(self) -> PlanCreate:
        checked_network(self.ground_station, self.ground_stations)
        return self


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
    max_azimuth_rate_deg_s: float | None = None
    """how fast the radar must turn in azimuth to follow the pass, at its culmination (its fastest), deg/s"""
    max_elevation_rate_deg_s: float | None = None
    """the largest elevation rate within 3 minutes of the culmination, deg/s"""
    keyhole: bool = False
    """true when max_azimuth_rate_deg_s is over the station's max_azimuth_rate_deg_s: the radar loses the target
    near the zenith"""
    station: str | None = None
    """the station the pass is over (a plan over a network of stations; null for one station)"""

    @classmethod
    def from_windows(cls, epoch: datetime, w: AccessWindows, names: list[str] | None = None) -> list[WindowPublic]:
        """Return the planner's windows (seconds after ``epoch``) as UTC records; ``names``: a network's stations."""
        return [
            cls(
                station=None if not names else names[w.station_of(k)],
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
                max_azimuth_rate_deg_s=float(w.max_azimuth_rate_deg_s[k]),
                max_elevation_rate_deg_s=float(w.max_elevation_rate_deg_s[k]),
                keyhole=bool(w.keyhole[k]),
            )
            for k in range(len(w))
        ]


class FeasibilityPublic(Described):
    sunlit: bool
    """whether the target is in sunlight at t_access (an optical observer needs it)"""
    feasible: bool
    """whether every check passes (every candidate screened by its own two-body phasing; the chosen one verified
    with the J2-corrected burn and its whole arc)"""
    reasons: list[str]
    """each failed check in words and numbers; empty when feasible"""
    observer_range_km: float | None
    """observer-target distance at t_access, km: the candidate's stand-off"""
    phase_angle_deg: float | None
    """Sun-target-observer angle at t_access, deg"""
    sun_angle_deg: float | None = None
    """the observer's boresight's angle from the Sun at t_access, deg"""
    relative_speed_km_s: float | None = None
    """the fly-by's relative speed at t_access, km/s"""
    target_angular_rate_deg_s: float | None = None
    """how fast the target crosses the observer's sky at t_access, deg/s (what the pointing must follow)"""
    line_of_sight_rtn: list[float] | None = None
    """the imaging geometry: the unit vector from the target to the observer at t_access in the target's radial /
    along-track / orbit-normal frame (which side of the target the observer sees), or null"""
    transfer_perigee_km: float | None = None
    """the perigee height of the orbit the phasing burn puts the observer on, km (under 100 km it re-enters:
    infeasible), or null"""
    radar_elevation_deg: float | None = None
    """the target's elevation seen from the radar at t_access, deg (under the radar's min_elevation_deg:
    infeasible)"""
    radar_range_km: float | None = None
    """the radar's slant range to the target at t_access, km"""
    radar_snr_db: float | None = None
    """the radar equation's SNR over the integration, with the target model's mean cross section at this aspect,
    dB (under the radar's min_snr_db: infeasible)"""
    isar_integration_s: float | None = None
    """the time the radar's line of sight takes to sweep the frame's aperture relative to the target (held in its
    orbital frame) at t_access, s (over the radar's max_integration_s, or too short for its pulses: infeasible)"""
    radar_cross_section_m2: float | None = None
    """the target model's mean radar cross section at this aspect (band and aperture averaged), m^2"""

    @classmethod
    def from_feasibility(cls, f: Feasibility) -> FeasibilityPublic:
        return cls(
            sunlit=f.sunlit,
            feasible=f.feasible,
            reasons=list(f.reasons),
            observer_range_km=finite_or_null(f.observer_range_km),
            phase_angle_deg=finite_or_null(f.phase_angle_deg),
            sun_angle_deg=finite_or_null(f.sun_angle_deg),
            relative_speed_km_s=finite_or_null(f.relative_speed_km_s),
            target_angular_rate_deg_s=finite_or_null(f.target_angular_rate_deg_s),
            line_of_sight_rtn=None if f.line_of_sight_rtn is None else list(f.line_of_sight_rtn),
            transfer_perigee_km=finite_or_null(f.transfer_perigee_km),
            radar_elevation_deg=finite_or_null(f.radar_elevation_deg),
            radar_range_km=finite_or_null(f.radar_range_km),
            radar_snr_db=finite_or_null(f.radar_snr_db),
            isar_integration_s=finite_or_null(f.isar_integration_s),
            radar_cross_section_m2=finite_or_null(f.radar_cross_section_m2),
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
    dv_total_m_s: float | None = None
    """what this candidate costs: the height change plus its own phasing burn (two-body Lambert to its own
    stand-off; the chosen one's J2-corrected), m/s; null where no burn reaches it"""
    standoff_km: float | None = None
    """where the observer is aimed beside the target at t_access, km (chosen from the optics, or as asked)"""
    feasibility: FeasibilityPublic
    """whether this candidate can be imaged: light, range, rate, Sun, phase angle, cost"""
    station: str | None = None
    """the radar that images it (a plan over a network of stations; null for one station)"""

    @classmethod
    def from_candidate(
        cls, epoch: datetime, c: Candidate, f: Feasibility, station: str | None = None
    ) -> CandidatePublic:
        dv = finite_or_null(f.dv_total_km_s)
        return cls(
            station=station,
            dv_total_m_s=None if dv is None else dv * 1000.0,
            standoff_km=finite_or_null(f.standoff_km),
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


class RelativeMotionPublic(Described):
    """The fly-by about T_access: where the observer is relative to the target, in the target's own orbital frame
    at each moment (radial, along-track, orbit normal; the Hill frame), one sample a second."""

    t_s: list[float]
    """seconds from T_access"""
    radial_km: list[float]
    """the observer's offset from the target along the target's radius (up), km"""
    along_track_km: list[float]
    """along the target's direction of motion, km"""
    cross_track_km: list[float]
    """along the target's orbit normal, km"""

    @classmethod
    def from_motion(cls, motion: Any) -> RelativeMotionPublic:
        r, t, n = (np.round(np.asarray(motion.rtn_km[k], float), 3).tolist() for k in range(3))
        return cls(
            t_s=np.round(np.asarray(motion.t_s, float), 3).tolist(), radial_km=r, along_track_km=t, cross_track_km=n
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
    relative_motion: RelativeMotionPublic | None = None
    """the fly-by a minute either side of T_access in the target's orbital frame (the console draws it)"""

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
            relative_motion=RelativeMotionPublic.from_motion(meet.relative) if meet.relative is not None else None,
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


class PlanResult(StoredResult):
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
        names = network_names(plan)

        def station(c: Candidate) -> str | None:
            return None if names is None else names[plan.windows.station_of(c.pass_index)]

        chosen = None
        if plan.chosen is not None and plan.chosen_feasibility is not None:
            chosen = CandidatePublic.from_candidate(ep, plan.chosen, plan.chosen_feasibility, station(plan.chosen))
        return cls(
            epoch=ep,
            duration_days=plan.duration_s / 86400.0,
            reading=plan.reading,
            access_windows=WindowPublic.from_windows(ep, plan.windows, names),
            candidates=[
                CandidatePublic.from_candidate(ep, c, f, station(c))
                for c, f in zip(plan.candidates, plan.feasibility, strict=True)
            ],
            chosen=chosen,
            alignment_dv_m_s=None if plan.alignment_dv_km_s is None else plan.alignment_dv_km_s * 1000.0,
            phasing=PhasingPublic.from_plan(plan),
            timings_s={k: round(v, 4) for k, v in plan.timings_s.items()},
            notes=plan.notes,
        )


def network_names(plan: Plan) -> list[str] | None:
    """The names of a plan's stations when it searched a network (more than one), else None."""
    return [st.name for st in plan.stations] if len(plan.stations) > 1 else None


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
    estimate_ids: list[str] = Field(default_factory=list)
    """the caller's estimates tied to this plan (observed in its passes), oldest first"""
    pass_ids: list[str] = Field(default_factory=list)
    """the caller's fused passes of this plan, oldest first"""

    @classmethod
    def from_row(
        cls, plan: PlanRow, estimate_ids: list[str] | None = None, pass_ids: list[str] | None = None
    ) -> PlanPublic:
        """Return a stored plan row, of any stored format, as the answer (with what is tied to it, where given)."""
        return cls.model_validate(
            {
                **PlanResult.upgraded(plan.result),
                "id": plan.id,
                "created_at": utc_or_none(plan.created_at),
                "target_name": plan.target_name,
                "observer_name": plan.observer_name,
                "station_name": plan.station_name,
                "estimate_ids": estimate_ids or [],
                "pass_ids": pass_ids or [],
            }
        )


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
    feasible: bool | None = None
    """whether the chosen candidate passes every check, or null (no candidate)"""
    dv_total_m_s: float | None = None
    """the chosen candidate's Delta-v (height change plus phasing), m/s, or null"""

    @classmethod
    def from_row(cls, p: PlanRow) -> PlanSummary:
        chosen = (p.result or {}).get("chosen") or {}
        return cls(
            id=p.id,
            created_at=utc_or_none(p.created_at),
            target_name=p.target_name,
            observer_name=p.observer_name,
            station_name=p.station_name,
            t_access=utc_or_none(p.t_access),
            miss_km=p.miss_km,
            feasible=(chosen.get("feasibility") or {}).get("feasible") if chosen else None,
            dv_total_m_s=chosen.get("dv_total_m_s") if chosen else None,
        )


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
