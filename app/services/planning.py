"""Turn API requests into planner calls and planner results into JSON-ready dicts."""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import replace
from datetime import datetime, timedelta
from typing import Any, TypeVar

from sqlalchemy.orm import Session

from app import crud
from app.core.config import Settings
from app.db.models import Plan as PlanRow
from app.db.models import new_id
from app.errors import InputError
from app.schemas import (
    ORBIT_SOURCES,
    AccessCreate,
    AccessPublic,
    CampaignCreate,
    OrbitIn,
    PlanCreate,
    PlanResult,
    StationIn,
    WindowPublic,
)
from app.services import exports
from inference.runtime import UNNAMED_CARD_TARGET
from planner.access import access_windows
from planner.alignment import HeightBox
from planner.ccsds import elements_from_opm, ephemeris_from_oem, omm_fields, opm_manoeuvre_note
from planner.elements import Elements
from planner.errors import PlannerError, PlanningStopped
from planner.optics import ObserverOptics
from planner.orbits import Orbit, earth_frames, ephemeris_note, trajectory
from planner.plan import Plan, PlanOptions, StopCheck, make_plan
from planner.propagation import Station, as_utc
from planner.radar import CrossSection
from planner.tle import omm_fields_from_text, parse_tle, split_tles, tle_from_omm, tle_lines
from scene.cross_section import for_target

log = logging.getLogger(__name__)


def to_orbit(orbit: OrbitIn, where: str) -> Orbit:
    """Build a planner Orbit, re-raising domain errors with the JSON path of the bad field."""
    try:
        if orbit.tle is not None:
            lines = orbit.tle.splitlines() if isinstance(orbit.tle, str) else orbit.tle
            if len([ln for ln in lines if ln.strip()]) <= 3:
                line1, line2, _ = tle_lines(orbit.tle)
            else:  # a file of several: the one named
                sets = split_tles(orbit.tle)
                line1, line2, _ = _named(orbit.name, [(s[2], s[0][2:7].strip(), s) for s in sets], where, "tle")
            return Orbit(orbit.name, tle=parse_tle(line1, line2))
        if orbit.omm is not None:
            omm = orbit.omm
            if isinstance(omm, list):
                omm = _named(
                    orbit.name,
                    [(o.OBJECT_NAME, None if o.NORAD_CAT_ID is None else str(o.NORAD_CAT_ID), o) for o in omm],
                    where,
                    "omm",
                )
            return Orbit(orbit.name, tle=tle_from_omm(omm.model_dump(exclude_none=True)))
        if orbit.omm_kvn is not None:
            return Orbit(orbit.name, tle=tle_from_omm(omm_fields(orbit.omm_kvn, "omm_kvn"), field="omm_kvn"))
        if orbit.opm is not None:
            note = opm_manoeuvre_note(orbit.opm, f"{where} {orbit.name}")
            return Orbit(orbit.name, elements=elements_from_opm(orbit.opm), notes=(note,) if note else ())
        if orbit.oem is not None:
            eph = ephemeris_from_oem(orbit.oem)
            return Orbit(orbit.name, elements=eph.elements, notes=(ephemeris_note(eph, f"{where} {orbit.name}"),))
        if orbit.omm_xml is not None:
            return Orbit(orbit.name, tle=tle_from_omm(omm_fields(orbit.omm_xml, "omm_xml"), field="omm_xml"))
        if orbit.omm_csv is not None:
            return Orbit(orbit.name, tle=tle_from_omm(omm_fields_from_text(orbit.omm_csv, "csv"), field="omm_csv"))
        assert orbit.elements is not None
        e = orbit.elements
        assert e.ha_km is not None and e.hp_km is not None  # ElementsIn fills them from a and e too
        el = Elements(
            epoch=as_utc(e.epoch),
            ha_km=e.ha_km,
            hp_km=e.hp_km,
            inclination_deg=e.inclination_deg,
            raan_deg=e.raan_deg % 360.0,
            arg_perigee_deg=e.arg_perigee_deg % 360.0,
            mean_anomaly_deg=e.mean_anomaly_deg % 360.0,
        )
        return Orbit(orbit.name, elements=el)
    except PlannerError as exc:
        sub = source_of(orbit)
        loc: list[str | int] = [where, sub]
        if exc.field and exc.field != sub:
            loc.append(exc.field)
        raise InputError(loc, str(exc)) from None


T = TypeVar("T")


def _named(name: str, sets: list[tuple[str | None, str | None, T]], where: str, source: str) -> T:
    """The one of several element sets whose name (case and spaces aside) or NORAD number is ``name``; the only
    one when there is one; else a 422 saying how to choose."""
    if len(sets) == 1:
        return sets[0][2]
    key = " ".join(name.split()).casefold()
    hits = [s for s in sets if (s[0] and " ".join(s[0].split()).casefold() == key) or (s[1] and s[1] == name.strip())]
    if len(hits) == 1:
        return hits[0][2]
    shown = ", ".join(f"{s[0] or '?'} ({s[1] or '?'})" for s in sets[:8]) + (", ..." if len(sets) > 8 else "")
    what = "several match" if hits else "none matches"
    raise InputError(
        [where, source],
        f"{len(sets)} satellites are given and {what} the name {name!r}: set the orbit's name to one of their names "
        f"or NORAD numbers: {shown}",
    )


def _osculating_states(orbits: tuple[tuple[OrbitIn, str], ...], reading: str, loc: list[str | int]) -> None:
    """An OPM's or OEM's state vector is an osculating orbit: refuse to read it as mean elements."""
    for orbit, where in orbits:
        for source in ("opm", "oem"):
            if getattr(orbit, source) is not None and reading == "mean":
                raise InputError(
                    loc,
                    f"the {where} is an {source.upper()} state vector, an osculating orbit: plan with reading "
                    "osculating",
                )


def source_of(orbit: OrbitIn) -> str:
    """Which of an orbit's sources the request gave (``elements``, ``tle``, ``omm``, ``omm_xml``, ``omm_csv``)."""
    return next(k for k in ORBIT_SOURCES if getattr(orbit, k) is not None)


def to_station(st: StationIn | str) -> Station:
    """The planner's station from a request's; a name must have been resolved (``with_stored_station``) first."""
    if isinstance(st, str):
        raise InputError(
            ["ground_station"],
            f"station {st!r} is a name, which only the service looks up (POST the plan to it), or give its coordinates",
        )
    return Station(
        latitude_deg=st.latitude_deg,
        longitude_deg=st.longitude_deg,
        altitude_m=st.altitude_m,
        min_elevation_deg=st.min_elevation_deg,
        max_range_km=st.max_range_km,
        mask=tuple((float(a), float(e)) for a, e in st.mask or ()),
        refraction=st.refraction,
        max_azimuth_rate_deg_s=st.max_azimuth_rate_deg_s,
        radar=st.radar.to_radar(),
        name=st.name,
    )


R = TypeVar("R", PlanCreate, AccessCreate, CampaignCreate)


def stored_station_lookup(session: Any, operator_id: str) -> Callable[[str], dict[str, Any] | None]:
    """The lookup a request's station name is resolved with: the operator's stored station, or None."""
    from app import crud

    def lookup(name: str) -> dict[str, Any] | None:
        row = crud.get_station(session=session, operator_id=operator_id, name=name)
        return None if row is None else dict(row.station)

    return lookup


def with_stored_station(req: R, lookup: Callable[[str], dict[str, Any] | None]) -> R:
    """The request with every station given by name (``ground_station``, or each of ``ground_stations``) replaced by
    the stored one (``lookup(name)``, None if absent)."""

    def resolved(st: StationIn | str, loc: list[str | int]) -> StationIn:
        if not isinstance(st, str):
            return st
        stored = lookup(st)
        if stored is None:
            raise InputError(
                loc,
                f"no station named {st!r} is stored: POST it to /v1/stations first "
                "(GET /v1/stations lists yours), or give its coordinates here",
            )
        return StationIn.model_validate(stored)

    update: dict[str, Any] = {}
    if req.ground_station is not None:
        update["ground_station"] = resolved(req.ground_station, ["ground_station"])
    network = getattr(req, "ground_stations", None)
    if network is not None:
        update["ground_stations"] = [resolved(st, ["ground_stations", k]) for k, st in enumerate(network)]
    return req.model_copy(update=update)


def to_stations(req: PlanCreate | CampaignCreate) -> list[Station]:
    """The planner's stations of a request: its one radar, or its network (names resolved first)."""
    if req.ground_stations is not None:
        return [to_station(st) for st in req.ground_stations]
    assert req.ground_station is not None  # the request's own check: one or the other
    return [to_station(req.ground_station)]


def with_radar_of(req: R, station_name: str | None) -> R:
    """A network request as it is stored: ``ground_station`` the radar named (the chosen scene's, else the first), so
    what reads a stored request's one station (exports, passes, labelled frames) reads that one."""
    network = getattr(req, "ground_stations", None)
    if network is None:
        return req
    sites = [st for st in network if isinstance(st, StationIn)]
    chosen = next((st for st in sites if st.name == station_name), sites[0])
    return req.model_copy(update={"ground_station": chosen})


def observer_optics(req: PlanCreate | CampaignCreate) -> ObserverOptics:
    """The request's optics, with the search's older fields (max_tracking_rate_deg_s, max_phase_angle_deg) read
    where given; out of physical range: a 422 naming the field where it was given."""
    s, o = req.search, req.observer_optics
    values = o.model_dump()
    where: dict[str, list[str | int]] = {name: ["observer_optics", name] for name in values}
    for old, new in (("max_tracking_rate_deg_s", "max_rate_deg_s"), ("max_phase_angle_deg", "max_phase_angle_deg")):
        if getattr(s, old, None) is not None:
            values[new] = getattr(s, old)
            where[new] = ["search", old]
    try:
        return ObserverOptics(**values)
    except PlannerError as exc:
        raise InputError(where.get(exc.field or "", ["observer_optics"]), str(exc)) from None


def served_cross_section(target_model: str | None = None) -> CrossSection:
    """The served target model's mean radar cross section by aspect (``scene.cross_section``; GSA_DEFAULT_TARGET, the
    shipped tiangong-like by default): the radar equation's sigma in every plan and campaign."""
    return for_target(target_model or UNNAMED_CARD_TARGET)


def plan_options(req: PlanCreate, target_model: str | None = None) -> PlanOptions:
    s = req.search
    optics = observer_optics(req)
    try:
        box = HeightBox(s.dha_min_km, s.dha_max_km, s.dhp_min_km, s.dhp_max_km, s.step_km)
        return PlanOptions(
            start=as_utc(s.start) if s.start else None,
            duration_s=s.duration_days * 86400.0,
            reading=s.reading,
            box=box,
            max_miss_km=s.max_miss_km,
            revolutions_before=tuple(sorted(set(s.revolutions_before))),
            criterion=s.criterion,
            optics=optics,
            max_imaging_range_km=s.max_imaging_range_km,
            standoff_km=s.standoff_km,
            min_separation_km=s.min_separation_km,
            max_dv_m_s=s.max_dv_m_s,
            cross_section=served_cross_section(target_model),
        )
    except PlannerError as exc:
        raise InputError(planner_loc(exc.field), str(exc)) from None


def check_epoch_gap(
    orbit: Orbit, orbit_in: OrbitIn, where: str, start: datetime, duration_s: float, limit_days: float
) -> None:
    """Refuse an orbit whose epoch lies more than ``limit_days`` from the search span (``GSA_MAX_EPOCH_GAP_DAYS``).

    The osculating propagation integrates the whole gap (about 4.5 CPU-seconds a year), and
    a TLE far from its epoch describes no real orbit: both are bounded here, before any work.
    """
    epoch = orbit.epoch
    end = start + timedelta(seconds=duration_s)
    gap_s = max((start - epoch).total_seconds(), (epoch - end).total_seconds(), 0.0)
    if gap_s <= limit_days * 86400.0:
        return
    loc: list[str | int] = [where, source_of(orbit_in)] if orbit_in.elements is None else [where, "elements", "epoch"]
    raise InputError(
        loc,
        f"the epoch {epoch:%Y-%m-%dT%H:%M:%SZ} is {gap_s / 86400.0:.1f} days from the search span, over the limit "
        f"of {limit_days:g} days (GSA_MAX_EPOCH_GAP_DAYS): give elements or a TLE near the span, or move search.start",
    )


def run_plan(
    req: PlanCreate,
    max_grid_points: int | None = None,
    max_epoch_gap_days: float | None = None,
    max_tle_age_days: float | None = None,
    stop: StopCheck | None = None,
    target_model: str | None = None,
) -> tuple[Plan, PlanResult]:
    """Validate a plan request against the planner, run it, and return the plan and its result."""
    _osculating_states(((req.target, "target"), (req.observer, "observer")), req.search.reading, ["search", "reading"])
    target = to_orbit(req.target, "target")
    observer = to_orbit(req.observer, "observer")
    station = to_stations(req)
    opts = plan_options(req, target_model)
    if max_tle_age_days is not None:
        opts = replace(opts, max_tle_age_days=max_tle_age_days)
    if max_epoch_gap_days is not None:
        start = opts.start or target.epoch
        for orbit, orbit_in, where in ((target, req.target, "target"), (observer, req.observer, "observer")):
            check_epoch_gap(orbit, orbit_in, where, start, opts.duration_s, max_epoch_gap_days)
    if max_grid_points is not None and opts.box.grid_points > max_grid_points:
        raise InputError(
            ["search", "step_km"],
            f"the dHa/dHp grid has {opts.box.grid_points} points, over the limit of {max_grid_points}: widen step_km",
        )
    try:
        plan = make_plan(target, observer, station, opts, stop=stop)
    except PlanningStopped:
        raise
    except PlannerError as exc:
        raise InputError(planner_loc(exc.field), str(exc)) from None
    return plan, PlanResult.from_plan(plan)


def planner_loc(field: str | None) -> list[str | int]:
    """Where in a plan request a planner's refusal points: the orbit it names, a field of ``search`` that exists,
    else the ``search`` block itself (the planner's own names, ``t_s`` and the like, are no field of the request)."""
    from app.schemas.plans import SearchIn

    if field in ("target", "observer", "ground_station"):
        return [field]
    if field is not None and field in SearchIn.model_fields:
        return ["search", field]
    return ["search"]


def plan_and_store(
    *,
    session: Session,
    operator_id: str,
    plan_in: PlanCreate,
    settings: Settings,
    stop: StopCheck | None = None,
) -> PlanRow:
    """Plan a request within the service's limits (``run_plan``) and store it with its result.

    A station given by name is the caller's stored one; the plan keeps a copy of it.
    """
    plan_in = with_stored_station(plan_in, stored_station_lookup(session, operator_id))
    plan, result = run_plan(
        plan_in,
        max_grid_points=settings.max_grid_points,
        max_epoch_gap_days=settings.max_epoch_gap_days,
        max_tle_age_days=settings.max_tle_age_days,
        stop=stop,
        target_model=settings.default_target,
    )
    plan_id = new_id()
    plan_in = with_radar_of(plan_in, plan.station.name if plan.station is not None else None)
    assert plan_in.ground_station is not None and not isinstance(plan_in.ground_station, str)  # resolved above
    names = {"target": plan_in.target.name, "observer": plan_in.observer.name, "station": plan_in.ground_station.name}
    try:  # the exports, from the plan in hand: stored with it, so each is a read (app.services.exports)
        texts = exports.render(
            plan,
            result.stored(),
            plan_id=plan_id,
            names=names,
            station=plan_in.ground_station.model_dump(mode="json"),
            stop=stop,
        )
    except PlanningStopped as exc:  # the plan stands; its exports are made on their first request instead
        log.warning("plan %s stored without its exports: %s", plan_id, exc)
        texts = {}
    return crud.create_plan(
        session=session,
        operator_id=operator_id,
        request=plan_in,
        result=result,
        plan_id=plan_id,
        exports=exports.pack(texts),
    )


def access_for(*, session: Session, operator_id: str, access_in: AccessCreate, settings: Settings) -> AccessPublic:
    """Access windows over the caller's station (given, or stored by name), within the service's limits."""
    access_in = with_stored_station(access_in, stored_station_lookup(session, operator_id))
    return run_access(access_in, max_epoch_gap_days=settings.max_epoch_gap_days)


def run_access(req: AccessCreate, max_epoch_gap_days: float | None = None) -> AccessPublic:
    """Compute access windows alone: one satellite over one station (a catalogue is ``app.services.catalogue``)."""
    if req.target is None or req.ground_station is None:
        raise InputError(["target"], "one satellite's windows need target and ground_station")
    _osculating_states(((req.target, "target"),), req.reading, ["reading"])
    target = to_orbit(req.target, "target")
    station = to_station(req.ground_station)
    epoch = as_utc(req.start) if req.start else target.epoch
    t1 = req.duration_days * 86400.0
    if max_epoch_gap_days is not None:
        check_epoch_gap(target, req.target, "target", epoch, t1, max_epoch_gap_days)
    frames = earth_frames(epoch, 0.0, t1)
    try:
        traj = trajectory(target, epoch, frames, 0.0, t1, req.reading)
        w = access_windows(traj, station, frames, 0.0, t1)
    except PlannerError as exc:
        raise InputError([exc.field or "request"], str(exc)) from None
    return AccessPublic(
        epoch=epoch, duration_days=req.duration_days, access_windows=WindowPublic.from_windows(epoch, w)
    )


ACCESS_CSV_COLUMNS = (
    "access",
    "rise_utc",
    "culmination_utc",
    "set_utc",
    "duration_s",
    "rise_azimuth_deg",
    "culmination_azimuth_deg",
    "set_azimuth_deg",
    "max_elevation_deg",
    "min_range_km",
    "rise_clipped",
    "set_clipped",
    "scene",
)


def _z(iso: str) -> str:
    """A stored ISO 8601 time in the exports' one time style (``exports.z_time``)."""
    from app.services.exports import z_time

    return z_time(datetime.fromisoformat(iso))


def scenes_by_pass(result: dict[str, Any]) -> dict[int, str]:
    """Which stored access window (by its index) each scene of a plan or campaign result images in: a plan's chosen
    candidate is "chosen", a campaign's scenes their numbers ("2", or "2;3" where two share a pass)."""
    windows = result.get("access_windows", [])
    moments = []
    if result.get("chosen"):
        moments.append(("chosen", result["chosen"]["t_access"], result["chosen"].get("station")))
    for sc in result.get("scenes", []):
        moments.append((str(sc["index"]), sc["t_access"], (sc.get("candidate") or {}).get("station")))
    marks: dict[int, list[str]] = {}
    for label, when, station in moments:
        t = datetime.fromisoformat(when)
        for k, w in enumerate(windows):
            same = station is None or w.get("station") in (None, station)
            if same and datetime.fromisoformat(w["rise"]) <= t <= datetime.fromisoformat(w["set"]):
                marks.setdefault(k, []).append(label)
                break
    return {k: ";".join(v) for k, v in marks.items()}


def access_csv(windows: list[dict[str, Any]], scenes: dict[int, str] | None = None) -> str:
    """The plan's access windows as an STK-style access report: one row a pass, times in UTC (Z), angles in degrees.

    Azimuths are from north through east, elevations above the station's horizon (WGS84
    normal), ranges in km; a window cut by the span's start or end says so in its clipped flags. ``scene`` marks
    the pass a scene images in (``scenes_by_pass``): "chosen" for a plan's, the scene numbers for a campaign's.
    """
    import csv
    import io

    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow(ACCESS_CSV_COLUMNS)
    for k, win in enumerate(windows):  # numbered from 0, as the plan's pass_index, pointing.csv and the console
        w.writerow(
            [
                k,
                _z(win["rise"]),
                _z(win["culmination"]),
                _z(win["set"]),
                f"{win['duration_s']:.3f}",
                f"{win['rise_azimuth_deg']:.4f}",
                f"{win['culmination_azimuth_deg']:.4f}",
                f"{win['set_azimuth_deg']:.4f}",
                f"{win['max_elevation_deg']:.4f}",
                f"{win['min_range_km']:.3f}",
                str(win["rise_clipped"]).lower(),
                str(win["set_clipped"]).lower(),
                (scenes or {}).get(k, ""),
            ]
        )
    return out.getvalue()
