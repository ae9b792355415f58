"""A plan in the formats operators' tools read: CCSDS OPM and OEM (KVN or XML, written by ccsds-ndm), CZML,
GeoJSON, an access report and a pointing file.

Every time is ISO 8601 UTC to the microsecond (a Z in the CSV files and CZML; CCSDS messages write UTC without a
zone designator and state TIME_SYSTEM = UTC), every frame is named: GCRF for the CCSDS messages
(the planner's GCRS axes), INERTIAL (ICRF axes, Cesium's name) for CZML, and azimuth from north
through east with elevation above the station's horizon (WGS-84) for the pointing file.

A plan's exports are written when the plan is made (``render``, from the plan in hand) and stored with it,
compressed, so an export is a read. A plan stored before that has none: its plan is recomputed from its stored
request (the planner is deterministic), the recomputed burn checked against the stored one, and what it writes is
kept for the next request (``render_again``).
"""

from __future__ import annotations

import json
import math
import zlib
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from app.errors import InputError
from planner import ccsds
from planner.errors import PlanningStopped
from planner.plan import Plan, StopCheck
from planner.propagation import utc

Vec = NDArray[np.float64]
ORIGINATOR = "GSA-ISAR"
ARC_MARGIN_S = 3600.0  # the ephemerides run from an hour before the burn to an hour after T_access
OEM_STEP_S = 60.0
POINTING_STEP_S = 1.0


def z_time(t: datetime) -> str:
    """ISO 8601 UTC with a Z, microseconds: the one time style of the CSV and CZML exports."""
    return ccsds.ccsds_time_text(t) + "Z"


@dataclass(frozen=True)
class Arc:
    """The plan's exported arc: times (s after the plan epoch) and the states (GCRS, km, km/s) on it."""

    plan: Plan
    t_burn_s: float
    t_access_s: float
    t0_s: float
    t1_s: float

    def target(self, t_s: Vec) -> tuple[Vec, Vec]:
        assert self.plan.target_trajectory is not None
        return self.plan.target_trajectory.state(t_s)

    def observer(self, t_s: Vec) -> tuple[Vec, Vec]:
        """The observer on its planned path: before the burn as changed for the alignment, after it the burn's arc."""
        return PlannedObserver(self.plan).state(t_s)


class PlannedObserver:
    """A plan's observer on its planned path (a trajectory): before the phasing burn as changed for the alignment,
    from the burn on the burn's own arc; a plan without a burn, as changed."""

    def __init__(self, plan: Plan) -> None:
        assert plan.observer_trajectory is not None
        self.plan = plan

    def state(self, t_s: Any) -> tuple[Vec, Vec]:
        plan = self.plan
        assert plan.observer_trajectory is not None
        t = np.atleast_1d(np.asarray(t_s, float))
        arc = plan.encounter.arc if plan.encounter is not None else None
        if plan.phasing is None or arc is None:
            return plan.observer_trajectory.state(t)
        before = t < plan.phasing.t_burn_s
        r = np.empty((3, t.size))
        v = np.empty((3, t.size))
        if before.any():
            r[:, before], v[:, before] = plan.observer_trajectory.state(t[before])
        if (~before).any():
            r[:, ~before], v[:, ~before] = arc.state(t[~before])
        return r, v


def plan_arc(plan: Plan, stored: dict[str, Any]) -> Arc:
    """Return the exported arc of a recomputed plan, after checking it is the stored one."""
    if plan.phasing is None or plan.encounter is None or plan.encounter.arc is None:
        raise InputError(
            ["plan"],
            "the plan has no phasing burn (no candidate was planned), so there is no "
            "manoeuvre or planned arc to export; the access report still is",
            where="path",
        )
    ph = plan.phasing
    stored_burn = (stored.get("phasing") or {}).get("t_burn")
    if stored_burn is not None:
        drift = abs((utc(plan.epoch, ph.t_burn_s) - datetime.fromisoformat(stored_burn)).total_seconds())
        if drift > 1e-3:
            raise InputError(
                ["plan"],
                f"recomputing the plan moved its burn by {drift:.3f} s (a newer planner?): plan it again to export it",
                where="path",
            )
    t0 = max(ph.t_burn_s - ARC_MARGIN_S, 0.0)
    t1 = min(ph.t_access_s + ARC_MARGIN_S, plan.duration_s)
    return Arc(plan, ph.t_burn_s, ph.t_access_s, t0, t1)


def _grid(t0: float, t1: float, step: float, must: tuple[float, ...] = ()) -> Vec:
    t = np.arange(t0, t1, step)
    return np.unique(np.concatenate([t, [t1], [m for m in must if t0 <= m <= t1]]))


@dataclass(frozen=True)
class Manoeuvre:
    """One impulsive burn as the OPM writes it: its time (s after the epoch), impulse (GCRS, km/s) and RTN (m/s)."""

    t_s: float
    dv_km_s: tuple[float, float, float]
    dv_rtn_m_s: tuple[float, float, float]
    what: str


def opm(arc: Arc, plan_id: str, observer_name: str, now: datetime | None = None, fmt: ccsds.Format = "kvn") -> str:
    """CCSDS OPM 3.0 (502.0-B-3; KVN or XML) of the observer just before the burn, the burn as an impulsive
    manoeuvre."""
    ph = arc.plan.phasing
    assert ph is not None
    r, v = arc.plan.observer_trajectory.state(arc.t_burn_s)  # type: ignore[union-attr]
    burn = Manoeuvre(
        arc.t_burn_s,
        (float(ph.dv_km_s[0]), float(ph.dv_km_s[1]), float(ph.dv_km_s[2])),
        tuple(float(x) * 1000.0 for x in ph.dv_rtn_km_s),  # type: ignore[arg-type]
        "Impulsive phasing burn (two-body Lambert corrected for J2)",
    )
    comment = (
        f"The observer just before its phasing burn, plan {plan_id}; the target is met at "
        f"{ccsds.ccsds_time_text(utc(arc.plan.epoch, arc.t_access_s))} UTC"
    )
    return opm_text(
        arc.plan.epoch, arc.t_burn_s, r[:, 0], v[:, 0], [burn], f"GSA-{plan_id}", observer_name, comment, now, fmt
    )


def opm_text(
    epoch: datetime,
    t_state_s: float,
    r: Vec,
    v: Vec,
    burns: list[Manoeuvre],
    object_id: str,
    observer_name: str,
    comment: str,
    now: datetime | None = None,
    fmt: ccsds.Format = "kvn",
) -> str:
    """CCSDS OPM 3.0 (KVN or XML, written by ccsds-ndm): a state at ``t_state_s`` and each burn as one impulsive
    manoeuvre (GCRF, UTC)."""
    return ccsds.opm_message(
        created=now or datetime.now(UTC),
        originator=ORIGINATOR,
        object_name=observer_name,
        object_id=object_id,
        epoch=utc(epoch, t_state_s),
        r_km=[float(x) for x in r],
        v_km_s=[float(x) for x in v],
        comment=comment,
        burns=[
            ccsds.Burn(
                utc(epoch, b.t_s),
                b.dv_km_s,
                f"{b.what}. The same in RTN (radial, along-track, normal) at the burn: "
                f"{b.dv_rtn_m_s[0]:.4f} / {b.dv_rtn_m_s[1]:.4f} / {b.dv_rtn_m_s[2]:.4f} m/s. "
                "The observer's mass is not planned: MAN_DELTA_MASS is 0",
            )
            for b in burns
        ],
        fmt=fmt,
    )


def oem(
    arc: Arc, plan_id: str, target_name: str, observer_name: str, now: datetime | None = None, fmt: ccsds.Format = "kvn"
) -> str:
    """CCSDS OEM 3.0 (KVN or XML): the target over the arc, the observer in two segments (before and after the
    burn)."""
    assert arc.plan.observer_trajectory is not None and arc.plan.encounter is not None
    assert arc.plan.encounter.arc is not None
    segments = [  # the burn's own instant ends the first observer segment (before it) and starts the second
        OemSegment(target_name, f"GSA-{plan_id}-TARGET", arc.t0_s, arc.t1_s, arc.target, "the target"),
        OemSegment(
            observer_name,
            f"GSA-{plan_id}-OBSERVER",
            arc.t0_s,
            arc.t_burn_s,
            arc.plan.observer_trajectory.state,
            "the observer before the burn",
        ),
        OemSegment(
            observer_name,
            f"GSA-{plan_id}-OBSERVER",
            arc.t_burn_s,
            arc.t1_s,
            arc.plan.encounter.arc.state,
            "the observer after the burn",
        ),
    ]
    return oem_text(arc.plan.epoch, segments, (arc.t_access_s,), f"plan {plan_id}", OEM_STEP_S, now, fmt)


@dataclass(frozen=True)
class OemSegment:
    """One OEM segment: an object over ``[t0_s, t1_s]`` (s after the epoch), its states from ``states(t)``."""

    name: str
    object_id: str
    t0_s: float
    t1_s: float
    states: Any
    what: str


def oem_text(
    epoch: datetime,
    segments: list[OemSegment],
    must_s: tuple[float, ...],
    source: str,
    step_s: float,
    now: datetime | None = None,
    fmt: ccsds.Format = "kvn",
) -> str:
    """CCSDS OEM 3.0 (KVN or XML, written by ccsds-ndm): each segment sampled every ``step_s`` and at each of
    ``must_s`` it holds."""
    pieces = []
    for seg in segments:
        if seg.t1_s - seg.t0_s < 1e-6:
            continue
        t = _grid(seg.t0_s, seg.t1_s, step_s, must_s)
        r, v = seg.states(t)
        pieces.append(
            ccsds.Segment(
                seg.name, seg.object_id, f"{seg.what}, {source}: km and km/s", [utc(epoch, x) for x in t], r, v
            )
        )
    return ccsds.oem_message(created=now or datetime.now(UTC), originator=ORIGINATOR, segments=pieces, fmt=fmt)


def czml(arc: Arc, plan_id: str, names: dict[str, str], station: dict[str, Any], windows: list[dict[str, Any]]) -> str:
    """CZML for Cesium: both satellites over the arc, the station, its access intervals, the imaging moment."""
    return czml_text(
        arc.plan.epoch,
        arc.t0_s,
        arc.t1_s,
        (arc.t_burn_s, arc.t_access_s),
        arc.target,
        [(arc.t0_s, arc.t_burn_s, arc.plan.observer_trajectory.state), (arc.t_burn_s, arc.t1_s, arc.observer)],  # type: ignore[union-attr]
        (arc.t_access_s,),
        f"GSA-ISAR plan {plan_id}",
        names,
        station,
        windows,
        network=[
            {
                "name": st.name,
                "latitude_deg": st.latitude_deg,
                "longitude_deg": st.longitude_deg,
                "altitude_m": st.altitude_m,
            }
            for st in arc.plan.stations
        ]
        if len(arc.plan.stations) > 1
        else None,
    )


def czml_text(
    epoch: datetime,
    t0_s: float,
    t1_s: float,
    must_s: tuple[float, ...],
    target: Any,
    observer: Any,
    accesses_s: tuple[float, ...],
    title: str,
    names: dict[str, str],
    station: dict[str, Any],
    windows: list[dict[str, Any]],
    step_s: float = OEM_STEP_S,
    network: list[dict[str, Any]] | None = None,
) -> str:
    """CZML for Cesium: both satellites over ``[t0_s, t1_s]`` (sampled every ``step_s`` and at ``must_s``: the burns,
    the imaging moments), the station, its access intervals, each imaging moment; with ``network`` (every radar of a
    plan or campaign over several), each other radar and its own access intervals too. ``observer`` is a state function,
    or a list of ``(t0_s, t1_s, states)`` pieces between burns, each its own position interval (Cesium would
    otherwise interpolate across a burn: 0.8 km off near it)."""
    t0, t1 = utc(epoch, t0_s), utc(epoch, t1_s)
    t = _grid(t0_s, t1_s, step_s, must_s)

    def samples(states: Any, lo: float, hi: float) -> list[float]:
        tt = np.unique(np.concatenate([t[(t >= lo) & (t <= hi)], [lo, hi]]))
        r, _ = states(tt)
        out: list[float] = []
        for k in range(tt.size):
            out += [round(float(tt[k] - lo), 3), *(round(float(x) * 1000.0, 2) for x in r[:, k])]
        return out

    interval = f"{z_time(t0)}/{z_time(t1)}"

    def position(pieces: Any) -> Any:
        """One interpolated track, or one a piece (a track split at each burn: no interpolation across one)."""
        if not isinstance(pieces, list):
            pieces = [(t0_s, t1_s, pieces)]
        out = [
            {
                "interval": f"{z_time(utc(epoch, lo))}/{z_time(utc(epoch, hi))}",
                "epoch": z_time(utc(epoch, lo)),
                "referenceFrame": "INERTIAL",
                "interpolationAlgorithm": "LAGRANGE",
                "interpolationDegree": 5,
                "cartesian": samples(states, lo, hi),
            }
            for lo, hi, states in pieces
            if hi > lo
        ]
        if len(out) == 1:
            del out[0]["interval"]
            return out[0]
        return out

    def satellite(key: str, states: Any, colour: list[int]) -> dict[str, Any]:
        return {
            "id": key,
            "name": names[key],
            "availability": interval,
            "position": position(states),
            "point": {"pixelSize": 8, "color": {"rgba": colour}},
            "label": {"text": names[key], "font": "12px sans-serif", "pixelOffset": {"cartesian2": [10, -10]}},
            "path": {
                "width": 1.5,
                "leadTime": 0,
                "trailTime": t1_s - t0_s,
                "material": {"solidColor": {"color": {"rgba": colour}}},
            },
        }

    def access(name: str | None) -> list[str]:
        """The intervals a radar sees the target (of a network's windows, only its own)."""
        return [
            f"{z_time(datetime.fromisoformat(w['rise']))}/{z_time(datetime.fromisoformat(w['set']))}"
            for w in windows
            if datetime.fromisoformat(w["set"]) >= t0
            and datetime.fromisoformat(w["rise"]) <= t1
            and (name is None or w.get("station") in (None, name))
        ]

    def radar(key: str, name: str, site: dict[str, Any], when: list[str]) -> list[dict[str, Any]]:
        where = [site["longitude_deg"], site["latitude_deg"], site.get("altitude_m", 0.0)]
        return [
            {
                "id": key,
                "name": name,
                "position": {"cartographicDegrees": where},
                "point": {"pixelSize": 9, "color": {"rgba": [44, 160, 44, 255]}},
                "label": {"text": name},
            },
            {
                "id": "access" if key == "station" else f"access-{key}",
                "name": f"{name} sees the target" if key != "station" else "the station sees the target",
                "availability": when or interval,
                "polyline": {
                    "positions": {"references": [f"{key}#position", "target#position"]},
                    "width": 1,
                    "material": {"solidColor": {"color": {"rgba": [44, 160, 44, 200]}}},
                },
            },
        ]

    own = names["station"] if network else None
    others = [site for site in network or [] if site.get("name") != names["station"]]
    r_access, _ = target(np.asarray(accesses_s, float))
    packets: list[dict[str, Any]] = [
        {
            "id": "document",
            "name": title,
            "version": "1.0",
            "clock": {
                "interval": interval,
                "currentTime": z_time(utc(epoch, accesses_s[0] if accesses_s else t0_s)),
                "multiplier": 10,
                "range": "CLAMPED",
            },
        },
        satellite("target", target, [255, 127, 14, 255]),
        satellite("observer", observer, [31, 119, 180, 255]),
        *radar("station", names["station"], station, access(own)),
    ]
    for j, site in enumerate(others, start=1):
        packets += radar(f"station-{j}", str(site.get("name", f"station {j}")), site, access(str(site.get("name"))))
    for k, t_s in enumerate(accesses_s):
        t_access = utc(epoch, t_s)
        packets.append(
            {
                "id": "imaging" if len(accesses_s) == 1 else f"imaging-{k}",
                "name": "T_access: the imaging moment" if len(accesses_s) == 1 else f"scene {k}: T_access",
                "availability": f"{z_time(t_access - timedelta(seconds=60))}/"
                f"{z_time(t_access + timedelta(seconds=60))}",
                "position": {
                    "referenceFrame": "INERTIAL",
                    "cartesian": [round(float(x) * 1000.0, 2) for x in r_access[:, k]],
                },
                "point": {"pixelSize": 14, "color": {"rgba": [214, 39, 40, 255]}},
                "label": {"text": f"T_access {z_time(t_access)}"},
            }
        )
    return json.dumps(packets, indent=1)


POINTING_COLUMNS = (
    "access",
    "time_utc",
    "azimuth_deg",
    "elevation_deg",
    "range_km",
    "range_rate_km_s",
    "azimuth_rate_deg_s",
    "elevation_rate_deg_s",
)


def _utc_strings(epoch: datetime, t_s: Vec) -> list[str]:
    """``z_time(utc(epoch, t))`` for each of ``t_s`` (ascending), at numpy's speed: one ``utc`` at the first time,
    whole seconds added to it unless a leap second lies between the first and the last (then one by one)."""
    if t_s.size == 0:
        return []
    first, last = utc(epoch, float(t_s[0])), utc(epoch, float(t_s[-1]))
    if (last - first).total_seconds() != float(t_s[-1] - t_s[0]):  # a leap second inside: UTC's clock repeats one
        return [z_time(utc(epoch, float(t))) for t in t_s]
    base = np.datetime64(first.replace(tzinfo=None), "us")
    micro = np.round((t_s - t_s[0]) * 1e6).astype("int64").astype("timedelta64[us]")
    return [s + "Z" for s in np.datetime_as_string(base + micro, unit="us").tolist()]


POINTING_CHUNK = 12  # passes computed together: one vectorised call each, and the stop asked between chunks


def pointing_csv(plan: Plan, windows: list[dict[str, Any]], stop: StopCheck | None = None) -> str:
    """The radar's pointing over each pass of a plan (``pointing_lines``)."""
    assert plan.target_trajectory is not None and plan.frames is not None and plan.station is not None
    return pointing_lines(plan.target_trajectory, plan.station, plan.frames, plan.epoch, list(enumerate(windows)), stop)


def pointing_lines(
    traj: Any,
    station: Any,
    frames: Any,
    epoch: datetime,
    windows: list[tuple[int, dict[str, Any]]],
    stop: StopCheck | None = None,
) -> str:
    """The radar's pointing over each pass (its access.csv row number, its window), 1-s steps: azimuth (from north,
    through east), elevation, range and its rate, and the azimuth's and elevation's rates the antenna turns at.
    ``stop()`` is asked before each chunk of ``POINTING_CHUNK`` passes (a reason stops the work:
    ``PlanningStopped``)."""
    from planner.access import look_angles, pointing_rates

    lines = [",".join(POINTING_COLUMNS)]
    for first in range(0, len(windows), POINTING_CHUNK):
        if stop is not None and (why := stop()) is not None:
            raise PlanningStopped(f"writing pass {first} of {len(windows)} of pointing.csv: {why}")
        passes, times = [], []
        for k, window in windows[first : first + POINTING_CHUNK]:
            rise = (datetime.fromisoformat(window["rise"]) - epoch).total_seconds()
            end = (datetime.fromisoformat(window["set"]) - epoch).total_seconds()
            t_k = np.arange(math.ceil(rise), math.floor(end) + 1e-9, POINTING_STEP_S)
            if t_k.size:
                passes.append((k, t_k))
                times.append(t_k)
        if not times:
            continue
        t = np.concatenate(times)
        look = look_angles(traj.state(t)[0], t, station, frames)
        dt = 0.5
        rate = (
            look_angles(traj.state(t + dt)[0], t + dt, station, frames).range_km
            - look_angles(traj.state(t - dt)[0], t - dt, station, frames).range_km
        ) / (2 * dt)
        az_rate, el_rate = pointing_rates(traj, station, frames, t)
        columns = [look.azimuth_deg, look.elevation_deg, look.range_km, rate, az_rate, el_rate]
        at = 0
        for k, t_k in passes:
            part = slice(at, at + t_k.size)
            at += t_k.size
            lines += [
                f"{k},{when},{az:.4f},{el:.4f},{rng:.3f},{rr:.5f},{azr:.4f},{elr:.4f}"
                for when, az, el, rng, rr, azr, elr in zip(
                    _utc_strings(epoch, t_k), *(c[part].tolist() for c in columns), strict=True
                )
            ]
    return "\n".join(lines) + "\n"


TRACK_STEP_S = 20.0
TRACK_HALF_SPAN_S = 3000.0  # about half a low orbit either side of the chosen moment


def line_parts(lat: Vec, lon: Vec, keep: NDArray[np.bool_] | None = None) -> list[list[list[float]]]:
    """A track as GeoJSON line parts, cut where it crosses the antimeridian (RFC 7946 section 3.1.9) and,
    with ``keep``, where it leaves the kept points. A part that meets the antimeridian runs on to it: it ends at
    +-180 deg, and the next starts at -+180, at the latitude where the track crosses (linear between the samples),
    so a map shows no gap there."""
    parts: list[list[list[float]]] = [[]]
    for k in range(lat.size):
        if keep is not None and not keep[k]:
            parts.append([])
            continue
        if k and abs(lon[k] - lon[k - 1]) > 180.0 and (keep is None or keep[k - 1]):
            edge = 180.0 if lon[k - 1] > 0 else -180.0  # leaving eastward over +180, or westward over -180
            after = float(lon[k]) + 2.0 * edge  # the next sample's longitude unwrapped past the edge
            share = (edge - float(lon[k - 1])) / (after - float(lon[k - 1]))
            lat_x = round(float(lat[k - 1] + share * (lat[k] - lat[k - 1])), 5)
            parts[-1].append([edge, lat_x])
            parts.append([[-edge, lat_x]])
        parts[-1].append([round(float(lon[k]), 5), round(float(lat[k]), 5)])
    return [p for p in parts if len(p) > 1]


def feature(kind: str, geometry: dict[str, Any], **properties: Any) -> dict[str, Any]:
    return {"type": "Feature", "geometry": geometry, "properties": {"kind": kind, **properties}}


def footprint_polygon(lat: Any, lon: Any) -> dict[str, Any]:
    """The area inside a visibility circle as a GeoJSON Polygon, or a MultiPolygon where it crosses the antimeridian.

    The ``antimeridian`` package (with shapely) cuts the ring at +-180 deg and closes a ring that encloses a
    pole along it (RFC 7946 3.1.9), so GIS tools can fill it: hand-cutting rings gets the pole cases wrong.
    """
    import antimeridian
    from shapely.geometry import Polygon, mapping

    # The circle runs clockwise (azimuth); RFC 7946's right-hand rule wants exteriors counter-clockwise, which is
    # also how antimeridian tells which pole a ring that crosses the antimeridian once encloses.
    ring = [(round(float(x), 5), round(float(y), 5)) for x, y in zip(lon, lat, strict=True)][::-1]
    shape = antimeridian.fix_polygon(Polygon(ring))
    return dict(mapping(shape))


def geojson(plan: Plan, names: dict[str, str], windows: list[dict[str, Any]]) -> str:
    """GeoJSON (RFC 7946, WGS-84 longitude/latitude): the station, where it sees the target, both ground tracks
    around the chosen moment (the target's in-view part apart), and the target under T_access."""
    from planner.access import look_angles, mask_deg
    from planner.frames import ground_track, terminator, visibility_circle
    from planner.illumination import sun_position_km

    assert plan.target_trajectory is not None and plan.frames is not None and plan.station is not None
    st, epoch = plan.station, plan.epoch
    chosen = plan.chosen
    if chosen is not None:
        t_c = chosen.t_access_s
    elif windows:
        t_c = (datetime.fromisoformat(windows[0]["culmination"]) - epoch).total_seconds()
    else:
        t_c = 0.0
    t = np.arange(max(0.0, t_c - TRACK_HALF_SPAN_S), min(plan.duration_s, t_c + TRACK_HALF_SPAN_S) + 1e-9, TRACK_STEP_S)
    lat, lon, h = ground_track(plan.target_trajectory, plan.frames, t)
    r, _ = plan.target_trajectory.state(t)
    look = look_angles(r, t, st, plan.frames)
    seen = look.elevation_deg >= mask_deg(st, look.azimuth_deg)
    span = {"start": z_time(utc(epoch, float(t[0]))), "end": z_time(utc(epoch, float(t[-1])))}
    # The radar's sky over the pass nearest the chosen moment: (time, azimuth, elevation) of the in-view samples.
    sky = []
    if seen.any():
        runs = np.split(np.flatnonzero(seen), np.flatnonzero(np.diff(np.flatnonzero(seen)) > 1) + 1)
        run = min(runs, key=lambda r: float(np.min(np.abs(t[r] - t_c))))
        sky = [
            [
                z_time(utc(epoch, float(t[k]))),
                round(float(look.azimuth_deg[k]), 4),
                round(float(look.elevation_deg[k]), 4),
            ]
            for k in run
        ]
    features = [
        feature(
            "station",
            {"type": "Point", "coordinates": [st.longitude_deg, st.latitude_deg]},
            name=names["station"],
            altitude_m=st.altitude_m,
            min_elevation_deg=st.min_elevation_deg,
            mask=[list(p) for p in st.mask],
        ),
        feature(
            "target_track",
            {"type": "MultiLineString", "coordinates": line_parts(lat, lon)},
            name=names["target"],
            **span,
        ),
        feature(
            "target_in_view",
            {"type": "MultiLineString", "coordinates": line_parts(lat, lon, keep=seen)},
            name=names["target"],
            sky_time_az_el_deg=sky,
            sky_note="the pass nearest the chosen moment as the radar sees it: azimuth from north through east, "
            "elevation above the horizon (WGS-84, geometric), 20-s steps",
        ),
    ]
    height = float(np.interp(t_c, t, h))
    c_lat, c_lon = visibility_circle(st, height)
    features.append(
        feature(
            "visibility_circle",
            {"type": "MultiLineString", "coordinates": line_parts(c_lat, c_lon)},
            height_km=round(height, 3),
            elevation_limit="the station's mask by azimuth, never below min_elevation_deg (geometric)",
        )
    )
    features.append(
        feature(
            "visibility_footprint",
            footprint_polygon(c_lat, c_lon),
            height_km=round(height, 3),
            elevation_limit="the station's mask by azimuth, never below min_elevation_deg (geometric)",
        )
    )
    if plan.observer_trajectory is not None:  # where the plan flies it: across its phasing burn
        o_lat, o_lon, _ = ground_track(PlannedObserver(plan), plan.frames, t)
        features.append(
            feature(
                "observer_track",
                {"type": "MultiLineString", "coordinates": line_parts(o_lat, o_lon)},
                name=names["observer"],
                **span,
            )
        )
    # The night side at the chosen moment: the Sun (de421) below the horizon there (geometric).
    sun = plan.frames.to_itrs(np.array([t_c]), sun_position_km(epoch, [t_c]))
    n_lat, n_lon, anti_lat, anti_lon = terminator(sun[:, 0])
    features.append(
        feature(
            "night",
            footprint_polygon(n_lat, n_lon),
            time=z_time(utc(epoch, t_c)),
            antisolar_point=[round(anti_lon, 5), round(anti_lat, 5)],
            edge="the Sun's centre on the horizon (geometric, no refraction)",
        )
    )
    if chosen is not None:
        a_lat, a_lon, _ = ground_track(plan.target_trajectory, plan.frames, np.array([t_c]))
        features.append(
            feature(
                "t_access",
                {"type": "Point", "coordinates": [round(float(a_lon[0]), 5), round(float(a_lat[0]), 5)]},
                time=z_time(utc(epoch, t_c)),
            )
        )
        if plan.observer_trajectory is not None:
            b_lat, b_lon, _ = ground_track(PlannedObserver(plan), plan.frames, np.array([t_c]))
            features.append(
                feature(
                    "observer_at_t_access",
                    {"type": "Point", "coordinates": [round(float(b_lon[0]), 5), round(float(b_lat[0]), 5)]},
                    time=z_time(utc(epoch, t_c)),
                    name=names["observer"],
                )
            )
    return json.dumps({"type": "FeatureCollection", "features": features}, indent=1)


NEEDS_BURN = ("opm", "oem", "czml")  # the exports of the planned arc: a plan without a burn has none
CCSDS_KINDS = ("opm", "oem")  # written in KVN, or XML with format=xml
COMPRESSION = 1  # zlib's level: a 10-day plan's 4.2-MB pointing.csv takes 34 ms to 1.5 MB (level 6: 166 ms, 1.3 MB)


def stored_name(kind: str, fmt: ccsds.Format = "kvn") -> str:
    """The name an export is stored under: ``opm``, ``opm.xml``, ``pointing.csv``..."""
    return f"{kind}.xml" if fmt == "xml" and kind in CCSDS_KINDS else kind


def render(
    plan: Plan,
    stored: dict[str, Any],
    *,
    plan_id: str,
    names: dict[str, str],
    station: dict[str, Any],
    now: datetime | None = None,
    stop: StopCheck | None = None,
) -> dict[str, str]:
    """Every export of a plan, by stored name: what the plan's exports serve. ``stored`` is the plan's stored result
    (its windows; its burn, which a recomputed plan is checked against). ``stop`` as for ``pointing_csv``."""
    windows = stored.get("access_windows", [])
    out = {"geojson": geojson(plan, names, windows), "pointing.csv": pointing_csv(plan, windows, stop)}
    if stored.get("phasing"):
        arc = plan_arc(plan, stored)
        now = now or datetime.now(UTC)
        for fmt in ccsds.FORMATS:
            out[stored_name("opm", fmt)] = opm(arc, plan_id, names["observer"], now, fmt)
        # The OEM in XML is written from the stored KVN on its first request (LATER): its serializer's 0.1 s a plan
        # is spent only for who asks for it.
        out["oem"] = oem(arc, plan_id, names["target"], names["observer"], now)
        out["czml"] = czml(arc, plan_id, names, station, windows)
    return out


# An export written from another stored one on its first request: its name -> (source, message kind).
LATER: dict[str, tuple[str, Literal["OEM", "OPM"]]] = {"oem.xml": ("oem", "OEM")}


def with_later(texts: dict[str, str]) -> dict[str, str]:
    """``render``'s exports and those it leaves for later (``LATER``), written now: every export of the plan."""
    return texts | {
        name: ccsds.convert(texts[source], what, "xml") for name, (source, what) in LATER.items() if source in texts
    }


def pack(texts: dict[str, str]) -> dict[str, bytes]:
    return {name: zlib.compress(text.encode(), COMPRESSION) for name, text in texts.items()}


def unpack(body: bytes) -> str:
    return zlib.decompress(body).decode()


def check_exportable(kind: str, row: Any) -> None:
    """A plan without a burn has no arc to export: refused before anything is read or computed."""
    if kind in NEEDS_BURN and not row.result.get("phasing"):
        raise InputError(
            ["plan"],
            "the plan has no phasing burn (no candidate was planned), so there is no manoeuvre or planned arc to "
            "export; the access report still is",
            where="path",
        )


def stored_export(session: Any, row: Any, kind: str, fmt: ccsds.Format = "kvn") -> str | None:
    """A stored plan's export as written when it was made (one of ``LATER`` written from its stored source and kept
    on its first request); None where the plan has none stored (made before)."""
    from app import crud

    check_exportable(kind, row)
    name = stored_name(kind, fmt)
    body = crud.get_plan_export(session=session, plan_id=row.id, name=name)
    if body is None and name in LATER:
        source, what = LATER[name]
        kvn = crud.get_plan_export(session=session, plan_id=row.id, name=source)
        if kvn is not None:
            text = ccsds.convert(unpack(kvn), what, "xml")
            crud.store_plan_exports(session=session, plan_id=row.id, exports=pack({name: text}))
            return text
    return None if body is None else unpack(body)


def keep(session: Any, row: Any, texts: dict[str, str]) -> None:
    """Store the exports ``render_again`` wrote for an older plan, so its next request is a read."""
    from app import crud

    crud.store_plan_exports(session=session, plan_id=row.id, exports=pack(texts))


def render_again(row: Any, settings: Any, stop: StopCheck | None = None) -> dict[str, str]:
    """Every export of a stored plan made before its exports were stored: the plan is recomputed from its stored
    request under ``stop`` (the plan budget: GSA_PLAN_TIMEOUT_S, GSA_PLAN_MEMORY_MB, the client gone), which the
    writing obeys too."""
    from app.schemas import PlanCreate
    from app.services.planning import run_plan

    plan, _ = run_plan(PlanCreate.model_validate(row.request), max_grid_points=settings.max_grid_points, stop=stop)
    names = {"target": row.target_name, "observer": row.observer_name, "station": row.station_name}
    return render(plan, row.result, plan_id=row.id, names=names, station=row.request["ground_station"], stop=stop)
