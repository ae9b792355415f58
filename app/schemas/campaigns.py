"""A campaign: a series of GSA scenes one observer flies within a Delta-v budget (request and result)."""

from __future__ import annotations

from datetime import datetime
from typing import TYPE_CHECKING, Any, Literal

from pydantic import ConfigDict, Field, model_validator

from app.schemas.common import Described, Finite, IsoDateTime, StoredResult, Strict, finite_or_null, utc_or_none
from app.schemas.orbits import OrbitIn
from app.schemas.plans import (
    PAPER_EXAMPLE,
    CandidatePublic,
    ObserverOpticsIn,
    RelativeMotionPublic,
    SceneSearchIn,
    WindowPublic,
    network_names,
)
from app.schemas.stations import GroundStationIn, StationsIn, checked_network
from planner.propagation import utc

if TYPE_CHECKING:
    from app.db.models import Campaign as CampaignRow
    from planner.campaign import Burn, Campaign, CampaignScene, Stretch
    from planner.dispersion import DispersionOptions, SceneDispersion
    from planner.plan import PlanOptions

# The paper's Table 1 from 2022-12-15 (its first ten days have the target in Earth's shadow) for three weeks.
CAMPAIGN_EXAMPLE: dict[str, Any] = {
    **PAPER_EXAMPLE,
    "start": "2022-12-15T16:00:00Z",
    "duration_days": 21,
    "dv_budget_m_s": 1000,
    "return_to_orbit": False,
}


class DispersionIn(Strict):
    """Fly every scene with errors, as an operator flies it (``planner.dispersion``): the phasing burn re-aimed from
    orbit determination, two trims re-aimed at the scene's aim; each scene's feasible share and trims' 95th percentile,
    and the budget's margin for them. Defaults: 10 m / 1 cm/s navigation, 1 % / 0.1 deg burns, 50 samples a scene."""

    samples: int = Field(default=50, ge=2, le=500)
    """Monte Carlo samples a scene (about 0.05 s each on one core)"""
    position_sigma_m: Finite = Field(default=10.0, ge=0.0, le=100_000.0)
    """orbit determination's position error, 1-sigma per axis, m"""
    velocity_sigma_mm_s: Finite = Field(default=10.0, ge=0.0, le=100_000.0)
    """its velocity error, 1-sigma per axis, mm/s"""
    burn_magnitude_sigma_pct: Finite = Field(default=1.0, ge=0.0, le=50.0)
    """each burn's size error, 1-sigma, % of the burn"""
    burn_pointing_sigma_deg: Finite = Field(default=0.1, ge=0.0, le=30.0)
    """each burn's pointing error, 1-sigma, deg"""
    trim_coast_s: Finite = Field(default=2700.0, ge=60.0, le=864_000.0)
    """the least coast after a burn before orbit determination and the next trim, s"""
    seed: int = Field(default=0, ge=0, le=2**31 - 1)
    """the draws' seed (the same seed, the same answer)"""

    def to_options(self) -> DispersionOptions:
        from planner.dispersion import DispersionOptions

        return DispersionOptions(
            samples=self.samples,
            position_sigma_km=self.position_sigma_m / 1000.0,
            velocity_sigma_km_s=self.velocity_sigma_mm_s / 1e6,
            burn_magnitude_sigma=self.burn_magnitude_sigma_pct / 100.0,
            burn_pointing_sigma_deg=self.burn_pointing_sigma_deg,
            trim_coast_s=self.trim_coast_s,
            seed=self.seed,
        )


class SceneDispersionPublic(Described):
    samples: int
    """how many times the scene was flown with errors"""
    feasible_share: float
    """the share of them that arrived within the aim's tolerance"""
    trim_p95_m_s: float | None
    """the 95th percentile of a sample's trims together, m/s (what the budget keeps for this scene)"""
    trim_max_m_s: float | None
    """the largest, m/s"""
    miss_p95_km: float | None
    """the 95th percentile of the distance from the aim point at t_access, km"""
    failed: int
    """samples whose re-aim found no transfer (counted infeasible)"""

    @classmethod
    def from_dispersion(cls, d: SceneDispersion) -> SceneDispersionPublic:
        return cls(
            samples=d.samples,
            feasible_share=d.feasible_share,
            trim_p95_m_s=finite_or_null(d.trim_p95_km_s * 1000.0),
            trim_max_m_s=finite_or_null(d.trim_max_km_s * 1000.0),
            miss_p95_km=finite_or_null(d.miss_p95_km),
            failed=d.failed,
        )


class CampaignCreate(Strict):
    """What to plan: a series of GSA scenes of one target, by one observer, over one radar."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, json_schema_extra={"examples": [CAMPAIGN_EXAMPLE]})

    target: OrbitIn
    """the satellite to image"""
    observer: OrbitIn
    """the optical observer satellite that manoeuvres, scene after scene"""
    ground_station: GroundStationIn | None = Field(
        default=None,
        description="the radar site, or the name of one stored under /v1/stations (the campaign keeps a copy)",
    )
    ground_stations: StationsIn | None = Field(
        default=None,
        description="instead of ground_station, a network of radars (sites or stored names, each its own name; at "
        "most 20): every station's passes are searched, each candidate names the radar that images it, and the "
        "cheapest feasible scene is chosen across them",
    )
    observer_optics: ObserverOpticsIn = Field(default_factory=lambda: ObserverOpticsIn())
    """what the observer images with (as a plan's)"""
    start: IsoDateTime | None = Field(default=None, description="the campaign's start (default: the target's epoch)")
    duration_days: Finite = Field(default=60.0, ge=0.001, le=90.0)
    """the campaign's span, days (at most 90)"""
    dv_budget_m_s: Finite = Field(default=1000.0, ge=0.0, le=20000.0)
    """the Delta-v the whole campaign may spend, m/s"""
    return_to_orbit: bool = False
    """whether the observer returns to its original orbit after each scene (two more burns a scene; the slot along
    the orbit may move by up to half a period, and the answer says by how much)"""
    scene_span_days: Finite = Field(default=10.0, ge=1.0, le=30.0)
    """how far ahead each scene is searched for from where the last one left the observer, days"""
    max_scenes: int = Field(default=20, ge=1, le=100)
    """the most scenes to plan"""
    search: SceneSearchIn = Field(default_factory=lambda: SceneSearchIn())
    """how each scene is searched for (the plan's box, misses, stand-off and separation; defaults: the paper's)"""
    dispersion: DispersionIn | None = None
    """fly every scene with navigation and burn errors and report each one's feasible share and trims (null: not)"""

    @model_validator(mode="after")
    def _one_radar_or_a_network(self) -> CampaignCreate:
        checked_network(self.ground_station, self.ground_stations)
        return self


class CampaignReplan(Strict):
    """Where orbit determination puts the observer after a leg flown: the campaign's later scenes are re-aimed from
    there (``POST /v1/campaigns/{id}/replan``)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, populate_by_name=True)

    observer: OrbitIn
    """the observer's orbit as orbit determination gives it (any orbit input of a plan: elements, a TLE, an OMM or
    an OPM state)"""
    from_time: IsoDateTime = Field(
        alias="from",
        description="the moment the new campaign starts from (UTC): within the campaign, not inside a scene's "
        "approach (between its phasing burn and its T_access); the observer is read there",
    )


class ReplanRecord(Described):
    """One re-plan a campaign came from: the campaign it re-planned, the moment and the observer given."""

    campaign_id: str
    """the campaign re-planned"""
    from_time: datetime
    """the moment it was re-planned from (UTC)"""
    observer: dict[str, Any]
    """the observer's orbit as given"""


class BurnPublic(Described):
    time: datetime
    """the impulse's moment (UTC)"""
    kind: Literal["perigee", "apogee", "phasing", "return", "arrival"]
    """perigee and apogee: the height change's two tangential burns; phasing: the Lambert burn to the scene; return
    and arrival: the way back to the original orbit"""
    dv_m_s: list[float]
    """the impulse in GCRS, m/s"""
    dv_rtn_m_s: list[float]
    """the same in the observer's radial / along-track / orbit-normal frame just before it, m/s"""
    dv_total_m_s: float
    """its size, m/s"""

    @classmethod
    def from_burn(cls, epoch: datetime, b: Burn) -> BurnPublic:
        return cls(
            time=utc(epoch, b.t_s),
            kind=b.kind,
            dv_m_s=[x * 1000.0 for x in b.dv_km_s],
            dv_rtn_m_s=[x * 1000.0 for x in b.dv_rtn_km_s],
            dv_total_m_s=b.dv_total_km_s * 1000.0,
        )


class SceneCheckPublic(Described):
    """One scene measured on the whole burn sequence flown again from the campaign's start (two-body + J2)."""

    separation_km: float
    """the observer's distance from the target at t_access, km"""
    target_angular_rate_deg_s: float
    """how fast the target crosses the observer's sky at t_access, deg/s"""
    sunlit: bool
    """whether the target is in sunlight at t_access"""
    phase_angle_deg: float
    """the Sun-target-observer angle at t_access, deg"""
    closest_approach_km: float
    """the least distance from the phasing burn to 0.9 of an orbit after t_access, km"""
    closest_approach_time: datetime
    """when it is (UTC)"""
    relative_motion: RelativeMotionPublic | None = None
    """the fly-by a minute either side of t_access in the target's orbital frame, as flown (the console draws it)"""


class AimPublic(Described):
    """What a scene's phasing burn aims at, for an operator who re-aims each leg from orbit determination."""

    t_access: datetime
    """the imaging moment the aim holds for (UTC)"""
    relative_km: list[float]
    """where the observer is aimed, relative to the target at t_access: GCRS, km"""
    relative_rtn_km: list[float]
    """the same in the target's radial / along-track / orbit-normal axes, km"""
    tolerance_km: float
    """how far from that point the observer may arrive and the scene stay feasible (the optics' range, the tracker's
    rate and the least separation, whichever is nearest), km"""
    lambert_revolutions: int
    """the phasing arc's complete revolutions (a re-aim keeps the branch)"""
    low_path: bool
    """the phasing arc's Lambert branch"""


class CampaignScenePublic(Described):
    index: int
    """the scene's place in the campaign (0-based)"""
    t_access: datetime
    """the imaging moment (UTC)"""
    feasible: bool
    """whether every check passes (a flown scene always does; the check below measures it again)"""
    dv_total_m_s: float
    """what the scene costs: its height change, phasing and (with return_to_orbit) return burns, m/s"""
    burns: list[BurnPublic]
    """the scene's burns, in time order"""
    candidate: CandidatePublic
    """the scene as its stretch's plan chose it: the node alignment, the stand-off and the imaging geometry
    (range, rate, phase angle, sunlit, line of sight)"""
    access_window: WindowPublic
    """the radar's pass the scene lies in"""
    check: SceneCheckPublic
    """the scene measured on the whole flown burn sequence"""
    slot_shift_s: float | None
    """with return_to_orbit: how far along its original orbit the observer returned to (s; positive: ahead)"""
    aim: AimPublic | None = None
    """what the scene's phasing burn aims at, and the tolerance that keeps it feasible"""
    reaimed: bool = False
    """true when a re-plan re-aimed this scene from a measured state (its T_access and aim kept, its burns new)"""
    dispersion: SceneDispersionPublic | None = None
    """the scene flown with the request's errors (``dispersion``), or null"""

    @classmethod
    def from_scene(
        cls, epoch: datetime, s: CampaignScene, opts: PlanOptions, dispersion: SceneDispersion | None = None
    ) -> CampaignScenePublic:
        plan = s.plan
        assert plan.chosen is not None and s.check is not None
        check = s.check
        names = network_names(plan)
        window = WindowPublic.from_windows(plan.epoch, plan.windows, names)[plan.chosen.pass_index]
        return cls(
            index=s.index,
            t_access=utc(epoch, s.t_access_s),
            feasible=s.feasibility.feasible,
            dv_total_m_s=s.dv_total_km_s * 1000.0,
            burns=[BurnPublic.from_burn(epoch, b) for b in s.burns],
            candidate=CandidatePublic.from_candidate(plan.epoch, plan.chosen, s.feasibility, window.station),
            access_window=window,
            check=SceneCheckPublic(
                separation_km=check.separation_km,
                target_angular_rate_deg_s=check.target_angular_rate_deg_s,
                sunlit=check.sunlit,
                phase_angle_deg=check.phase_angle_deg,
                closest_approach_km=check.closest_approach_km,
                closest_approach_time=utc(epoch, check.closest_approach_s),
                relative_motion=None if check.relative is None else RelativeMotionPublic.from_motion(check.relative),
            ),
            slot_shift_s=s.slot_shift_s,
            aim=_aim_public(epoch, s, opts),
            reaimed=s.reaimed,
            dispersion=None if dispersion is None else SceneDispersionPublic.from_dispersion(dispersion),
        )


def _aim_public(epoch: datetime, s: CampaignScene, opts: PlanOptions) -> AimPublic:
    from planner.closed_loop import scene_aim

    aim = scene_aim(s, opts)
    ph = s.plan.phasing
    assert ph is not None
    return AimPublic(
        t_access=utc(epoch, aim.t_access_s),
        relative_km=list(aim.relative_km),
        relative_rtn_km=list(aim.relative_rtn_km),
        tolerance_km=aim.tolerance_km,
        lambert_revolutions=ph.lambert_revolutions,
        low_path=ph.low_path,
    )


class StretchPublic(Described):
    start: datetime
    """the stretch's start (UTC)"""
    end: datetime
    """its end: the next stretch's start (UTC)"""
    candidates: int
    """how many candidates its plan held"""
    feasible: int
    """how many of them passed every check (within the budget left)"""
    scene: int | None
    """the scene flown from it, or null"""
    note: str
    """what became of it: "scene flown", or why no scene, with the commonest reasons"""

    @classmethod
    def from_stretch(cls, epoch: datetime, s: Stretch) -> StretchPublic:
        return cls(
            start=utc(epoch, s.t0_s),
            end=utc(epoch, s.t1_s),
            candidates=s.candidates,
            feasible=s.feasible,
            scene=s.scene,
            note=s.note,
        )


class ObserverStatePublic(Described):
    epoch: datetime
    """the campaign's start (UTC)"""
    r_km: list[float]
    """the observer's GCRS position there, km (before any burn)"""
    v_km_s: list[float]
    """its GCRS velocity, km/s"""


class CampaignResult(StoredResult):
    epoch: datetime
    """the campaign's start (UTC)"""
    duration_days: float
    """its span, days"""
    dv_budget_m_s: float
    """the budget it was planned within, m/s"""
    return_to_orbit: bool
    """whether the observer returns to its original orbit after each scene"""
    dv_total_m_s: float
    """what the whole campaign spends, m/s"""
    scenes: list[CampaignScenePublic]
    """the scenes flown, in time order"""
    stretches: list[StretchPublic]
    """each stretch of the span searched, and what came of it"""
    access_windows: list[WindowPublic]
    """every pass of the target over the station in the span searched"""
    observer_state: ObserverStatePublic
    """where the observer starts: with the burns, the whole flight (the exports fly it again from here)"""
    timings_s: dict[str, float]
    """where the planning time went, seconds"""
    notes: list[str]
    """what the planner wants the operator to know, in words"""
    replanned_from: str | None = None
    """the campaign this one was re-planned from (``POST /v1/campaigns/{id}/replan``), or null"""
    replans: list[ReplanRecord] = Field(default_factory=list)
    """every re-plan from the first campaign to this one, oldest first"""
    trim_margin_m_s: float | None = None
    """with ``dispersion``: the Delta-v the budget keeps for the trims, the sum of the scenes' 95th percentiles, m/s"""

    @classmethod
    def from_campaign(cls, c: Campaign, dispersions: list[SceneDispersion] | None = None) -> CampaignResult:
        ep = c.epoch
        windows: list[WindowPublic] = []
        for s in c.stretches:  # each stretch's own passes (a stretch's plan may reach past the next one's start)
            plan = s.plan
            if plan is None:
                continue
            off = (plan.epoch - ep).total_seconds()
            names = network_names(plan)
            for w, rise in zip(
                WindowPublic.from_windows(plan.epoch, plan.windows, names), plan.windows.rise_s, strict=True
            ):
                if s.t0_s <= rise + off < s.t1_s:
                    windows.append(w)
        r0, v0 = c.initial_state
        by_scene = {d.scene: d for d in dispersions or ()}
        margin = None
        notes = list(c.notes)
        if dispersions is not None:
            from planner.dispersion import trim_margin_km_s

            margin = trim_margin_km_s(dispersions) * 1000.0
            total = c.dv_total_km_s * 1000.0 + margin
            if total > c.options.dv_budget_m_s:
                notes.append(
                    f"with the trims' 95th-percentile margin ({margin:.1f} m/s) the campaign needs {total:.1f} m/s, "
                    f"over its budget of {c.options.dv_budget_m_s:g} m/s: plan it within {c.options.dv_budget_m_s - margin:.0f} "
                    "m/s, or fly fewer scenes"
                )
        return cls(
            epoch=ep,
            duration_days=c.duration_s / 86400.0,
            dv_budget_m_s=c.options.dv_budget_m_s,
            return_to_orbit=c.options.return_to_orbit,
            dv_total_m_s=c.dv_total_km_s * 1000.0,
            scenes=[CampaignScenePublic.from_scene(ep, s, c.options.plan, by_scene.get(s.index)) for s in c.scenes],
            stretches=[StretchPublic.from_stretch(ep, s) for s in c.stretches],
            access_windows=windows,
            observer_state=ObserverStatePublic(epoch=ep, r_km=[float(x) for x in r0], v_km_s=[float(x) for x in v0]),
            timings_s={k: round(v, 4) for k, v in c.timings_s.items()},
            notes=notes,
            trim_margin_m_s=margin,
        )


class CampaignPublic(CampaignResult):
    id: str
    """the campaign's id"""
    created_at: datetime
    """when it was stored (UTC)"""
    target_name: str
    """the target's name"""
    observer_name: str
    """the observer's name"""
    station_name: str
    """the station's name"""

    @classmethod
    def from_row(cls, row: CampaignRow) -> CampaignPublic:
        """Return a stored campaign row as the answer."""
        return cls.model_validate(
            {
                **CampaignResult.upgraded(row.result),
                "id": row.id,
                "created_at": utc_or_none(row.created_at),
                "target_name": row.target_name,
                "observer_name": row.observer_name,
                "station_name": row.station_name,
            }
        )


class CampaignSummary(Described):
    id: str
    """the campaign's id"""
    created_at: datetime
    """when it was stored (UTC)"""
    target_name: str
    """the target's name"""
    observer_name: str
    """the observer's name"""
    station_name: str
    """the station's name"""
    scenes: int
    """how many scenes it flies"""
    dv_total_m_s: float
    """what it spends, m/s"""
    first_access: datetime | None
    """its first scene's t_access (UTC), or null"""

    @classmethod
    def from_row(cls, row: CampaignRow) -> CampaignSummary:
        return cls(
            id=row.id,
            created_at=utc_or_none(row.created_at),
            target_name=row.target_name,
            observer_name=row.observer_name,
            station_name=row.station_name,
            scenes=row.scenes,
            dv_total_m_s=row.dv_total_m_s,
            first_access=utc_or_none(row.first_access),
        )


class CampaignsPublic(Described):
    data: list[CampaignSummary]
    """the campaigns of this page, newest first"""
    count: int
    """how many campaigns match in all"""
