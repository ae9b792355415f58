"""POST /v1/access-windows with a catalogue (targets): many satellites over many stations, streamed a window a line.

The reference is skyfield's own `find_events` for each satellite over each station (good to about 0.2 s); the
bad element sets, the budget and the body limit are each checked by name.
"""

import csv
import io
import json
import math
import subprocess
import sys
from datetime import UTC, datetime

import numpy as np
import pytest
from sgp4.api import WGS72, Satrec
from sgp4.exporter import export_tle
from skyfield.api import EarthSatellite, wgs84

from planner.propagation import skyfield_times, timescale
from tests.conftest import KEY_A, SQLITE_ONLY

A = {"X-API-Key": KEY_A}
EPOCH = datetime(2024, 3, 1, 6, 0, tzinfo=UTC)
STATIONS = [
    {"name": "Shanghai", "latitude_deg": 31.1, "longitude_deg": 121.3, "altitude_m": 0, "min_elevation_deg": 10},
    {"name": "Tira", "latitude_deg": 50.6166, "longitude_deg": 7.1296, "altitude_m": 307, "min_elevation_deg": 5},
]


def _tle(k: int) -> tuple[str, str, str]:
    """A LEO element set made by sgp4's own sgp4init and exporter (valid checksums), epoch 2024-03-01 06:00."""
    sat = Satrec()
    epoch_days = (EPOCH - datetime(1949, 12, 31, tzinfo=UTC)).total_seconds() / 86400.0
    inc, raan, ma = math.radians(45.0 + 9.0 * k), math.radians(37.0 * k), math.radians(53.0 * k)
    n_rad_min = 2 * math.pi / (95.0 + 1.5 * k)
    sat.sgp4init(WGS72, "i", 44000 + k, epoch_days, 2e-5, 0.0, 0.0, 0.001, math.radians(90.0), inc, ma, n_rad_min, raan)
    line1, line2 = export_tle(sat)
    return f"OBJECT {k}", line1, line2


SETS = [_tle(k) for k in range(5)]


def _text(sets) -> str:
    return "\n".join(f"{name}\n{l1}\n{l2}" for name, l1, l2 in sets) + "\n"


def _body(sets, **more):
    return {"targets": {"tle": _text(sets)}, "ground_stations": STATIONS, "duration_days": 1, **more}


def _lines(r):
    return [json.loads(line) for line in r.text.splitlines() if line]


def _seconds(iso: str) -> float:
    return (datetime.fromisoformat(iso) - EPOCH).total_seconds()


@SQLITE_ONLY
def test_a_catalogue_over_a_network_streams_every_pass_that_skyfield_finds(client):
    r = client.post("/v1/access-windows", json=_body(SETS), headers=A)
    assert r.status_code == 200, r.text
    assert r.headers["content-type"].startswith("application/x-ndjson")
    rows = _lines(r)
    ts = timescale()
    t0, t1 = skyfield_times(EPOCH, 0.0), skyfield_times(EPOCH, 86400.0)
    checked = 0
    for k, (name, l1, l2) in enumerate(SETS):
        sat = EarthSatellite(l1, l2, name, ts=ts)
        for st in STATIONS:
            site = wgs84.latlon(st["latitude_deg"], st["longitude_deg"], st["altitude_m"])
            times, events = sat.find_events(site, t0, t1, altitude_degrees=st["min_elevation_deg"])
            sec = (times - t0) * 86400.0
            ours = [x for x in rows if x["index"] == k and x["station"] == st["name"]]
            rises = [_seconds(x["rise"]) for x in ours if not x["rise_clipped"]]
            sets = [_seconds(x["set"]) for x in ours if not x["set_clipped"]]
            np.testing.assert_allclose(rises, sec[events == 0], atol=0.5)
            np.testing.assert_allclose(sets, sec[events == 2], atol=0.5)
            assert all(x["target"] == name and x["norad_id"] == str(44000 + k) for x in ours)
            assert all(x["rise"].endswith("Z") and x["set"].endswith("Z") for x in ours)  # the API's one time style
            checked += len(rises)
    assert checked >= 10
    # Satellite by satellite, then station by station, then in time.
    order = [(x["index"], [s["name"] for s in STATIONS].index(x["station"]), x["rise"]) for x in rows]
    assert order == sorted(order)


@SQLITE_ONLY
def test_csv_holds_the_same_windows_and_the_command_line_writes_the_services_bytes(client, tmp_path):
    body = _body(SETS, format="csv")
    r = client.post("/v1/access-windows", json=body, headers=A)
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/csv")
    table = list(csv.DictReader(io.StringIO(r.text)))
    jsonl = _lines(client.post("/v1/access-windows", json=_body(SETS), headers=A))
    assert len(table) == len(jsonl) > 0
    assert [row["rise"] for row in table] == [x["rise"] for x in jsonl]
    request = tmp_path / "catalogue.json"
    request.write_text(json.dumps(body))
    out = subprocess.run(
        [sys.executable, "-m", "app.cli", "access", str(request), "--workers", "2"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.replace("\r\n", "\n") == r.text.replace("\r\n", "\n")


@SQLITE_ONLY
def test_an_omm_array_gives_the_windows_of_its_tles(client):
    """CelesTrak's JSON OMMs for the same element sets (mean elements written out here from each TLE's lines)."""
    omms = []
    for name, l1, l2 in SETS[:2]:
        sat = Satrec.twoline2rv(l1, l2)
        omms.append(
            {
                "OBJECT_NAME": name,
                "NORAD_CAT_ID": sat.satnum,
                "EPOCH": "2024-03-01T06:00:00.000000",
                "MEAN_MOTION": float(l2[52:63]),
                "ECCENTRICITY": float("0." + l2[26:33]),
                "INCLINATION": float(l2[8:16]),
                "RA_OF_ASC_NODE": float(l2[17:25]),
                "ARG_OF_PERICENTER": float(l2[34:42]),
                "MEAN_ANOMALY": float(l2[43:51]),
                "BSTAR": 2e-5,
            }
        )
    by_omm = _lines(client.post("/v1/access-windows", json={**_body(SETS[:2]), "targets": {"omm": omms}}, headers=A))
    by_tle = _lines(client.post("/v1/access-windows", json=_body(SETS[:2]), headers=A))
    assert len(by_omm) == len(by_tle) > 0
    for a, b in zip(by_omm, by_tle, strict=True):
        assert abs(_seconds(a["rise"]) - _seconds(b["rise"])) < 0.01 and a["station"] == b["station"]


@SQLITE_ONLY
def test_a_bad_element_set_is_named_and_refused_unless_skipped(client):
    name, l1, l2 = SETS[2]
    broken = (name, l1[:-1] + str((int(l1[-1]) + 1) % 10), l2)  # a wrong checksum
    sets = [SETS[0], SETS[1], broken, SETS[3]]
    r = client.post("/v1/access-windows", json=_body(sets), headers=A)
    assert r.status_code == 422
    detail = r.json()["detail"][0]
    assert detail["loc"][-2:] == ["targets", "tle"] and "element set 2 (OBJECT 2)" in detail["msg"]
    assert "on_error" in detail["msg"]
    skipped = _lines(client.post("/v1/access-windows", json=_body(sets, on_error="skip"), headers=A))
    errors = [x for x in skipped if "error" in x]
    assert len(errors) == 1 and errors[0]["index"] == 2 and "checksum" in errors[0]["error"]
    assert {x["index"] for x in skipped if "error" not in x} <= {0, 1, 3} and len(skipped) > 1
    # A stray line breaks the file's sets apart: refused whole, naming the line, whatever on_error says.
    stray = _text(SETS[:2]) + "not a line of any element set\n" + _text(SETS[3:])
    body = {**_body([]), "targets": {"tle": stray}, "on_error": "skip"}
    r = client.post("/v1/access-windows", json=body, headers=A)
    assert r.status_code == 422 and "line 7" in r.text, r.text


@SQLITE_ONLY
def test_work_over_the_budget_is_a_413_saying_how_much_fits(client, settings):
    budget = settings.access_budget
    try:
        settings.access_budget = 6.0  # target-station-days
        r = client.post("/v1/access-windows", json=_body(SETS, duration_days=1), headers=A)
        assert r.status_code == 413
        assert "5 targets x 2 stations x 1 days" in r.text and "at most 3 targets" in r.text, r.text
    finally:
        settings.access_budget = budget


@SQLITE_ONLY
def test_a_catalogue_may_be_larger_than_other_requests_bodies(client):
    """CelesTrak's active file is several MB as OMMs: this route takes GSA_MAX_CATALOGUE_BYTES (16 MiB), others
    keep GSA_MAX_REQUEST_BYTES (1 MB)."""
    padded = json.dumps(_body(SETS[:1], duration_days=0.01)) + " " * 2_000_000
    r = client.post("/v1/access-windows", content=padded, headers={**A, "Content-Type": "application/json"})
    assert r.status_code == 200, r.text[:300]
    r = client.post("/v1/plans", content=padded, headers={**A, "Content-Type": "application/json"})
    assert r.status_code == 413


@SQLITE_ONLY
@pytest.mark.parametrize(
    "change,words",
    [
        ({"target": {"name": "x", "tle": [SETS[0][1], SETS[0][2]]}}, "one of them"),
        ({"targets": {}}, "one of them"),
        ({"ground_stations": []}, "at least 1"),
        ({"format": "xml"}, "format"),
        ({"on_error": "ignore"}, "on_error"),
    ],
)
def test_malformed_catalogue_requests_are_422s(client, change, words):
    r = client.post("/v1/access-windows", json={**_body(SETS[:1]), **change}, headers=A)
    assert r.status_code == 422 and words in r.text, r.text
