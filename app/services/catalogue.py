"""A catalogue of satellites over a network of radars: every element set read on its own (a bad one named by its index
and name), the work bounded by a budget, the windows computed in shards and written a line each.

The lines are a pure function of the request: the same bytes whichever way the shards are run.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, replace
from datetime import datetime
from typing import Any

import numpy as np

from app.core.config import Settings
from app.errors import InputError, TooLarge
from app.schemas import AccessCreate, AccessPublic, CatalogueIn
from app.services.exports import z_time
from app.services.planning import access_for, stored_station_lookup, to_station, with_stored_station
from planner.access import AccessWindows, pair_access, validate_station
from planner.errors import PlannerError
from planner.orbits import earth_frames
from planner.propagation import SGP4Catalogue, Station, as_utc, utc_many
from planner.tle import TLE, parse_tle, split_tles, tle_from_omm

SHARD = 64  # satellites searched together: the search's fixed costs shared, its arrays a few MB
COLUMNS = (
    "index",
    "target",
    "norad_id",
    "station",
    "rise",
    "culmination",
    "set",
    "duration_s",
    "max_elevation_deg",
    "rise_azimuth_deg",
    "culmination_azimuth_deg",
    "set_azimuth_deg",
    "min_range_km",
    "rise_clipped",
    "set_clipped",
    "error",
)


def _csv_cell(value: object) -> str:
    """One CSV cell as Python's csv writer writes it (quoted where it holds a comma, quote or line break)."""
    if value is None:
        return ""
    if not isinstance(value, str):
        return str(value)
    if "," in value or '"' in value or "\n" in value or "\r" in value:
        return '"' + value.replace('"', '""') + '"'
    return value


@dataclass(frozen=True, slots=True)
class Entry:
    """One element set of a catalogue: its place, its name, and its TLE or why it has none."""

    index: int
    name: str
    norad_id: str
    tle: TLE | None
    error: str | None = None


def read_catalogue(cat: CatalogueIn) -> list[Entry]:
    """Every element set of the catalogue, each read on its own. A TLE text whose lines cannot be split into sets is
    refused whole (422 naming the line): where one set ends and the next begins is then unknown."""
    out: list[Entry] = []
    if cat.tle is not None:
        try:
            sets = split_tles(cat.tle, field="tle")
        except PlannerError as exc:
            raise InputError(["targets", "tle"], str(exc)) from None
        for k, (line1, line2, name) in enumerate(sets):
            norad = line1[2:7].strip()
            label = name or norad
            try:
                out.append(Entry(k, label, norad, parse_tle(line1, line2, field="tle")))
            except PlannerError as exc:
                out.append(Entry(k, label, norad, None, f"element set {k} ({label}): {exc}"))
        return out
    assert cat.omm is not None
    for k, omm in enumerate(cat.omm):
        label = omm.OBJECT_NAME or str(omm.NORAD_CAT_ID or k)
        norad = "" if omm.NORAD_CAT_ID is None else str(omm.NORAD_CAT_ID)
        try:
            out.append(Entry(k, label, norad, tle_from_omm(omm.model_dump(exclude_none=True))))
        except PlannerError as exc:
            out.append(Entry(k, label, norad, None, f"OMM {k} ({label}): {exc}"))
    return out


def check_budget(n_targets: int, n_stations: int, days: float, budget: float) -> None:
    """Refuse work over ``budget`` target-station-days (413), saying how much of it fits."""
    work = n_targets * n_stations * days
    if work > budget:
        fits = int(budget // (n_stations * days))
        raise TooLarge(
            f"{n_targets} targets x {n_stations} stations x {days:g} days is {work:,.0f} target-station-days, over "
            f"GSA_ACCESS_BUDGET {budget:,.0f}: send at most {fits} targets at these stations and days, or fewer "
            "stations or days"
        )


@dataclass(frozen=True, slots=True)
class Catalogue:
    """A checked catalogue request, ready to run in shards: its entries, stations, start and span."""

    entries: list[Entry]
    stations: list[Station]
    names: list[str]
    epoch: datetime
    span_s: float
    fmt: str

    def shards(self) -> list[list[Entry]]:
        good = [e for e in self.entries if e.tle is not None]
        return [good[k : k + SHARD] for k in range(0, len(good), SHARD)]

    def header(self) -> str:
        return ",".join(COLUMNS) + "\r\n" if self.fmt == "csv" else ""

    def errors(self) -> list[str]:
        """The error lines of the entries that could not be read, in their catalogue order."""
        return [self.line(e, None, None, 0, e.error) for e in self.entries if e.error]

    def line(
        self,
        e: Entry,
        station: str | None,
        w: AccessWindows | None,
        k: int,
        error: str | None = None,
        times: tuple[datetime, datetime, datetime] | None = None,
    ) -> str:
        """One line of the answer: a window (``k`` of ``w``, with ``times``, its rise, culmination and set in UTC) or an
        entry's error."""
        row: dict[str, object] = {"index": e.index, "target": e.name, "norad_id": e.norad_id, "station": station}
        if w is not None:
            assert times is not None  # converted a shard at a time (run_shard)
            rise, culmination, end = times
            row |= {
                "rise": z_time(rise),
                "culmination": z_time(culmination),
                "set": z_time(end),
                "duration_s": round(float(w.set_s[k] - w.rise_s[k]), 4),
                "max_elevation_deg": round(float(w.max_elevation_deg[k]), 4),
                "rise_azimuth_deg": round(float(w.rise_azimuth_deg[k]), 4),
                "culmination_azimuth_deg": round(float(w.culmination_azimuth_deg[k]), 4),
                "set_azimuth_deg": round(float(w.set_azimuth_deg[k]), 4),
                "min_range_km": round(float(w.min_range_km[k]), 4),
                "rise_clipped": bool(w.rise_clipped[k]),
                "set_clipped": bool(w.set_clipped[k]),
            }
        if error is not None:
            row["error"] = error
        if self.fmt == "jsonl":
            return json.dumps(row, separators=(",", ":")) + "\n"
        return ",".join(_csv_cell(row.get(c)) for c in COLUMNS) + "\r\n"

    def run_shard(self, shard: list[Entry]) -> str:
        """A shard's lines: each satellite's windows, station by station in the request's order, in time order. A
        satellite SGP4 cannot propagate over the span (decayed) gets an error line instead."""
        frames = earth_frames(self.epoch, 0.0, self.span_s)
        tles = [e.tle for e in shard if e.tle is not None]
        try:
            state = SGP4Catalogue(tles, self.epoch, frames).state
            # The lines carry no turning rates: they are not sought (the search's dearest part).
            found = pair_access(state, len(tles), self.stations, frames, 0.0, self.span_s, rates=False)
        except PlannerError:
            if len(shard) == 1:
                return self.line(
                    shard[0],
                    None,
                    None,
                    0,
                    f"element set {shard[0].index} ({shard[0].name}): SGP4 cannot propagate it over the span",
                )
            return "".join(self.run_shard([e]) for e in shard)  # find which one, satellite by satellite
        # Every window's rise, culmination and set of the shard turned into UTC at once.
        seconds = [np.stack([w.rise_s, w.culmination_s, w.set_s], axis=1).ravel() for ws in found for w in ws]
        moments = iter(utc_many(self.epoch, np.concatenate(seconds) if seconds else np.empty(0)))
        out = []
        for e, per_station in zip(shard, found, strict=True):
            for name, w in zip(self.names, per_station, strict=True):
                for k in range(len(w)):
                    times = (next(moments), next(moments), next(moments))
                    out.append(self.line(e, name, w, k, times=times))
        return "".join(out)


@dataclass(frozen=True, slots=True)
class Streamed:
    """An answer written a piece at a time: its pieces and their media type."""

    pieces: Iterator[str]
    media_type: str


def access_answer(
    *, session: Any, operator_id: str, access_in: AccessCreate, settings: Settings
) -> AccessPublic | Streamed:
    """POST /v1/access-windows: one satellite's windows (``planning.access_for``), or a catalogue's, streamed."""
    if access_in.targets is None:
        return access_for(session=session, operator_id=operator_id, access_in=access_in, settings=settings)
    access_in = with_stored_station(access_in, stored_station_lookup(session, operator_id))
    cat = prepare(access_in, settings.access_budget)
    return Streamed(stream(cat), "text/csv" if cat.fmt == "csv" else "application/x-ndjson")


def prepare(req: AccessCreate, budget: float) -> Catalogue:
    """Check a catalogue request (stations already resolved): element sets read, the budget, the errors."""
    assert req.targets is not None
    entries = read_catalogue(req.targets)
    stations = [req.ground_station] if req.ground_stations is None else list(req.ground_stations)
    resolved = [to_station(st) for st in stations]  # type: ignore[arg-type]
    where = ["ground_station"] if req.ground_stations is None else ["ground_stations"]
    for k, station in enumerate(resolved):
        try:
            validate_station(station)
        except PlannerError as exc:
            loc: list[str | int] = [*where, *([k] if req.ground_stations is not None else []), exc.field or "station"]
            raise InputError(loc, str(exc)) from None
    names = [st.name or f"station {k}" for k, st in enumerate(resolved)]
    check_budget(len(entries), len(resolved), req.duration_days, budget)
    bad = [e for e in entries if e.error]
    if bad and req.on_error == "fail":
        raise InputError(
            ["targets", "tle" if req.targets.tle is not None else "omm"],
            f"{len(bad)} of {len(entries)} element sets cannot be read, the first {bad[0].error}; fix them, or send "
            "on_error: skip to have the rest answered and these listed as error lines",
        )
    good = [e.tle for e in entries if e.tle is not None]
    if not good:
        raise InputError(["targets"], "no element set of the catalogue can be read")
    epoch = as_utc(req.start) if req.start else max(t.epoch for t in good)
    return Catalogue(entries, resolved, names, epoch, req.duration_days * 86400.0, req.format)


def shard_lines(job: tuple[Catalogue, list[Entry]]) -> str:
    """``Catalogue.run_shard`` as a plain function of one argument, for an engine's map (Ray's tasks take
    functions): the catalogue comes without its entries, only the shard's travel."""
    cat, shard = job
    return cat.run_shard(shard)


def shard_jobs(cat: Catalogue) -> list[tuple[Catalogue, list[Entry]]]:
    """Each shard with the catalogue it belongs to (its entries left out: each job carries its own)."""
    bare = replace(cat, entries=[])
    return [(bare, shard) for shard in cat.shards()]


def stream(cat: Catalogue, map_shards: Callable[..., Iterable[str]] = map) -> Iterator[str]:
    """The answer a piece at a time: the header (CSV), the entries that could not be read, then shard by shard, the
    shards run by ``map_shards`` (here, in order; an engine's map on processes or Ray, in order too)."""
    yield cat.header() + "".join(cat.errors())
    yield from map_shards(shard_lines, shard_jobs(cat))
