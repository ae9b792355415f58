"""A stored campaign's exports, flown again from its stored start and burns (no planning is repeated): the observer's
OPM with its burns, both satellites' OEM, CZML, the access report, GeoJSON of the whole campaign, and the radar's
pointing over one scene's pass."""

from __future__ import annotations

import json
from dataclasses import dataclass
from datetime import datetime
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.errors import InputError
from app.schemas import CampaignCreate, CampaignResult
from app.schemas.campaigns import CampaignScenePublic
from app.services import exports
from app.services.planning import access_csv, scenes_by_pass, to_orbit, to_stations
from planner import ccsds
from planner.campaign import CAMPAIGN_MARGIN_S, FlownTrajectory, campaign_pole, fly
from planner.orbits import earth_frames, trajectory
from planner.propagation import EarthFrames, Station, Trajectory, utc

Vec = NDArray[np.float64]

EXPORT_FILES = {
    "opm": "opm.txt",
    "oem": "oem.txt",
    "czml": "campaign.czml",
    "access.csv": "access.csv",
    "geojson": "campaign.geojson",
    "pointing.csv": "pointing.csv",
}
CAMPAIGN_OEM_STEP_S = 120.0  # a campaign's ephemerides span weeks: 2-min samples (LAGRANGE 7 reads them to metres)
SCENE_TRACK_STEP_S = 10.0  # the target's track over a scene's pass in the GeoJSON


@dataclass(frozen=True)
class Flight:
    """A stored campaign flown again: the observer from its stored start through its stored burns, the target
    from the stored request (both deterministic: no planning is repeated). Times are s after ``epoch``."""

    epoch: datetime
    t1_s: float
    observer_flight: FlownTrajectory
    target_trajectory: Trajectory
    burns: list[dict[str, Any]]
    accesses_s: tuple[float, ...]
    frames: EarthFrames
    scenes: list[CampaignScenePublic]
    stations: list[Station]  # the campaign's radars, as its request gives them
    network: bool  # several radars: each window names the one that sees it

    def target(self, t_s: Vec) -> tuple[Vec, Vec]:
        return self.target_trajectory.state(t_s)

    def observer(self, t_s: Vec) -> tuple[Vec, Vec]:
        return self.observer_flight.state(t_s)


def flight(request: dict[str, Any], result: dict[str, Any]) -> Flight:
    """Fly a stored campaign again from its stored start state and burns."""
    req = CampaignCreate.model_validate(request)
    stored = CampaignResult.model_validate(CampaignResult.upgraded(result))
    epoch = stored.epoch
    observer = to_orbit(req.observer, "observer")
    target = to_orbit(req.target, "target")
    end = stored.duration_days * 86400.0
    pole = campaign_pole(epoch, observer, end)
    burns = [b for s in stored.scenes for b in s.burns]
    aims = [_aim_words(s) if b.kind == "phasing" else "" for s in stored.scenes for b in s.burns]
    times = [(b.time - epoch).total_seconds() for b in burns]
    r0, v0 = np.asarray(stored.observer_state.r_km), np.asarray(stored.observer_state.v_km_s)
    flown = fly(
        r0,
        v0,
        0.0,
        end + CAMPAIGN_MARGIN_S,
        [(t, np.asarray(b.dv_m_s) / 1000.0) for t, b in zip(times, burns, strict=True)],
        pole,
    )
    frames = earth_frames(epoch, 0.0, end + CAMPAIGN_MARGIN_S)
    tgt = trajectory(target, epoch, frames, 0.0, end + CAMPAIGN_MARGIN_S, "osculating", pole)
    return Flight(
        epoch,
        end,
        flown,
        tgt,
        [
            {
                "t_s": t,
                "kind": b.kind,
                "dv_km_s": tuple(x / 1000.0 for x in b.dv_m_s),
                "dv_rtn_m_s": tuple(b.dv_rtn_m_s),
                "aim": aim,
            }
            for t, b, aim in zip(times, burns, aims, strict=True)
        ],
        tuple((s.t_access - epoch).total_seconds() for s in stored.scenes),
        frames,
        list(stored.scenes),
        to_stations(req),
        req.ground_stations is not None,
    )


def _aim_words(scene: CampaignScenePublic) -> str:
    """A scene's aim for its phasing burn's comment: what an operator re-aims to after orbit determination."""
    aim = scene.aim
    if aim is None:
        return ""
    rel = ", ".join(f"{x:.3f}" for x in aim.relative_rtn_km)
    return (
        f". Aim: at {aim.t_access:%Y-%m-%dT%H:%M:%S.%fZ} the observer {sum(x * x for x in aim.relative_km) ** 0.5:.3f} km "
        f"from the target, RTN of the target [{rel}] km, within {aim.tolerance_km:.2f} km; Lambert arc of "
        f"{aim.lambert_revolutions} revolution(s), {'low' if aim.low_path else 'high'} branch"
        + (f"; imaged by radar {scene.candidate.station}" if scene.candidate.station else "")
    )


def export(kind: str, row: Any, fmt: ccsds.Format = "kvn", scene: int | None = None) -> str:
    """One export of a stored campaign (a row, or anything with its fields): ``opm``, ``oem`` (KVN, or XML with
    ``fmt``), ``czml``, ``access.csv``, ``geojson``, ``pointing.csv`` (every scene's pass, or scene ``scene``'s)."""
    if kind == "access.csv":
        return access_csv(row.result.get("access_windows", []), scenes_by_pass(row.result))
    if kind == "pointing.csv":
        return pointing(row, scene)
    fl = flight(row.request, row.result)
    names = {"target": row.target_name, "observer": row.observer_name, "station": row.station_name}
    if kind == "opm":
        r, v = fl.observer(np.array([0.0]))
        burns = [
            exports.Manoeuvre(b["t_s"], b["dv_km_s"], b["dv_rtn_m_s"], f"Impulsive {b['kind']} burn{b['aim']}")
            for b in fl.burns
        ]
        comment = (
            f"The observer at the start of campaign {row.id}, before any burn; {len(fl.accesses_s)} scene(s), "
            f"{len(burns)} burn(s)"
        )
        return exports.opm_text(
            fl.epoch, 0.0, r[:, 0], v[:, 0], burns, f"GSA-{row.id}", row.observer_name, comment, fmt=fmt
        )
    if kind == "oem":
        # One observer segment between burns: each burn's instant ends one (before it) and starts the next.
        edges = [0.0, *(b["t_s"] for b in fl.burns), fl.t1_s]
        segments = [exports.OemSegment(row.target_name, f"GSA-{row.id}-TARGET", 0.0, fl.t1_s, fl.target, "the target")]
        for k, piece in enumerate(fl.observer_flight.pieces):
            what = (
                "the observer before any burn" if k == 0 else f"the observer after its {fl.burns[k - 1]['kind']} burn"
            )
            segments.append(
                exports.OemSegment(
                    row.observer_name, f"GSA-{row.id}-OBSERVER", edges[k], edges[k + 1], piece.state, what
                )
            )
        return exports.oem_text(fl.epoch, segments, fl.accesses_s, f"campaign {row.id}", CAMPAIGN_OEM_STEP_S, fmt=fmt)
    if kind == "czml":
        must = (*fl.accesses_s, *(b["t_s"] for b in fl.burns))
        return exports.czml_text(
            fl.epoch,
            0.0,
            fl.t1_s,
            must,
            fl.target,
            [
                (lo, hi, piece.state)
                for lo, hi, piece in zip(
                    [0.0, *(b["t_s"] for b in fl.burns)],
                    [*(b["t_s"] for b in fl.burns), fl.t1_s],
                    fl.observer_flight.pieces,
                    strict=True,
                )
            ],
            fl.accesses_s,
            f"GSA-ISAR campaign {row.id}",
            names,
            row.request["ground_station"],
            row.result.get("access_windows", []),
            step_s=CAMPAIGN_OEM_STEP_S,
            network=row.request.get("ground_stations"),
        )
    if kind == "geojson":
        return geojson(fl, names)
    raise InputError(
        ["kind"], f"unknown export {kind!r}: opm, oem, czml, access.csv, geojson or pointing.csv", where="path"
    )


def _scene_windows(result: dict[str, Any], scene: int | None) -> list[tuple[int, dict[str, Any]]]:
    """The stored access windows (with their access.csv row numbers) the campaign's scenes image in, or scene
    ``scene``'s; InputError naming ``scene`` where the campaign has no such scene or it images in no stored pass."""
    scenes = [str(s["index"]) for s in result.get("scenes", [])]
    if scene is not None and str(scene) not in scenes:
        raise InputError(
            ["scene"],
            f"the campaign has no scene {scene}: its scenes are "
            + (", ".join(scenes) if scenes else "none (it found no feasible scene)"),
            where="query",
        )
    windows = result.get("access_windows", [])
    marks = scenes_by_pass(result)
    chosen = [k for k in sorted(marks) if scene is None or str(scene) in marks[k].split(";")]
    if scene is not None and not chosen:
        raise InputError(["scene"], f"scene {scene}'s pass is not among the campaign's stored passes", where="query")
    return [(k, windows[k]) for k in chosen]


def pointing(row: Any, scene: int | None = None) -> str:
    """The radar's pointing over the passes the campaign's scenes image in (or scene ``scene``'s), 1-s steps, from
    the station that images each: the plan's pointing.csv columns, ``access`` its row in access.csv."""
    chosen = _scene_windows(row.result, scene)  # refused before anything is flown
    fl = flight(row.request, row.result)
    by_name: dict[str | None, Station] = {s.name: s for s in fl.stations} if fl.network else {None: fl.stations[0]}
    lines = [",".join(exports.POINTING_COLUMNS)]
    for k, window in chosen:
        station = by_name.get(window.get("station"), fl.stations[0])
        text = exports.pointing_lines(fl.target_trajectory, station, fl.frames, fl.epoch, [(k, window)])
        lines += text.splitlines()[1:]
    return "\n".join(lines) + "\n"


def geojson(fl: Flight, names: dict[str, str]) -> str:
    """GeoJSON (RFC 7946, WGS-84 longitude/latitude) of the whole campaign: each station, the target's track over
    each scene's pass (its in-view part), the target under each T_access with the observer there, and each burn where
    the observer makes it (the point below it), with what it costs."""
    from planner.frames import ground_track

    features: list[dict[str, Any]] = []
    for st in fl.stations:
        features.append(
            exports.feature(
                "station",
                {"type": "Point", "coordinates": [st.longitude_deg, st.latitude_deg]},
                name=st.name or names["station"],
                altitude_m=st.altitude_m,
                min_elevation_deg=st.min_elevation_deg,
            )
        )

    def point(lat: Vec, lon: Vec) -> dict[str, Any]:
        return {"type": "Point", "coordinates": [round(float(lon[0]), 5), round(float(lat[0]), 5)]}

    for sc in fl.scenes:
        w = sc.access_window
        rise, end = (max(0.0, (t - fl.epoch).total_seconds()) for t in (w.rise, w.set))
        t = np.arange(rise, end + 1e-9, SCENE_TRACK_STEP_S)
        if t.size >= 2:
            lat, lon, _ = ground_track(fl.target_trajectory, fl.frames, t)
            features.append(
                exports.feature(
                    "scene_pass",
                    {"type": "MultiLineString", "coordinates": exports.line_parts(lat, lon)},
                    scene=sc.index,
                    station=w.station,
                    name=names["target"],
                    start=exports.z_time(w.rise),
                    end=exports.z_time(w.set),
                    max_elevation_deg=round(w.max_elevation_deg, 3),
                )
            )
        t_a = np.array([(sc.t_access - fl.epoch).total_seconds()])
        features.append(
            exports.feature(
                "t_access",
                point(*ground_track(fl.target_trajectory, fl.frames, t_a)[:2]),
                scene=sc.index,
                time=exports.z_time(sc.t_access),
                feasible=sc.feasible,
                station=sc.candidate.station,
                name=names["target"],
            )
        )
        features.append(
            exports.feature(
                "observer_at_t_access",
                point(*ground_track(fl.observer_flight, fl.frames, t_a)[:2]),
                scene=sc.index,
                time=exports.z_time(sc.t_access),
                name=names["observer"],
            )
        )
    for b in fl.burns:
        t_b = np.array([b["t_s"]])
        features.append(
            exports.feature(
                "burn",
                point(*ground_track(fl.observer_flight, fl.frames, t_b)[:2]),
                kind_of_burn=b["kind"],
                time=exports.z_time(utc(fl.epoch, float(b["t_s"]))),
                dv_m_s=round(1000.0 * float(np.linalg.norm(b["dv_km_s"])), 4),
                dv_rtn_m_s=[round(float(x), 4) for x in b["dv_rtn_m_s"]],
                name=names["observer"],
            )
        )
    return json.dumps({"type": "FeatureCollection", "features": features}, indent=1)
