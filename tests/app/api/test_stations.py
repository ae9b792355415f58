"""/v1/stations: named stations per operator, referenced by name in plans and access requests."""

import pytest

from app.schemas import PAPER_EXAMPLE
from tests.conftest import KEY_A, KEY_B

A = {"X-API-Key": KEY_A}
B = {"X-API-Key": KEY_B}
MASK = [[0, 4], [90, 1], [180, 9], [270, 14]]
SITE = {**PAPER_EXAMPLE["ground_station"], "name": "Shanghai radar", "mask": MASK, "min_elevation_deg": 2.0}


@pytest.fixture(scope="module")
def stored(client):
    r = client.post("/v1/stations", json=SITE, headers=A)
    assert r.status_code == 201, r.text
    return r.json()


def test_a_stored_station_reads_back_and_lists(client, stored):
    assert stored["mask"] == MASK and stored["refraction"] is False and stored["created_at"].endswith("Z")
    one = client.get("/v1/stations/Shanghai radar", headers=A)
    assert one.status_code == 200 and one.json() == stored
    listed = client.get("/v1/stations", headers=A).json()
    assert any(s["name"] == "Shanghai radar" for s in listed["data"]) and listed["count"] >= 1


def test_stations_belong_to_their_operator(client, stored):
    assert client.get("/v1/stations/Shanghai radar", headers=B).status_code == 404
    assert all(s["name"] != "Shanghai radar" for s in client.get("/v1/stations", headers=B).json()["data"])
    again = client.post("/v1/stations", json=SITE, headers=A)
    assert again.status_code == 409 and "already stored" in again.json()["detail"]


def test_access_by_name_equals_access_with_the_coordinates(client, stored):
    body = {"target": PAPER_EXAMPLE["target"], "duration_days": 2}
    by_name = client.post("/v1/access-windows", json={**body, "ground_station": "Shanghai radar"}, headers=A)
    inline = client.post("/v1/access-windows", json={**body, "ground_station": SITE}, headers=A)
    plain = client.post(
        "/v1/access-windows", json={**body, "ground_station": PAPER_EXAMPLE["ground_station"]}, headers=A
    )
    assert by_name.status_code == 200, by_name.text
    assert by_name.json() == inline.json()
    # The mask (and the 2-deg floor) shortens every pass: each masked window lies inside a plain one.
    masked, full = by_name.json()["access_windows"], plain.json()["access_windows"]
    assert 0 < len(masked) <= len(full)
    assert sum(w["duration_s"] for w in masked) < sum(w["duration_s"] for w in full)


def test_a_plan_names_its_station_and_keeps_a_copy(client, stored):
    r = client.post("/v1/plans", json={**PAPER_EXAMPLE, "ground_station": "Shanghai radar"}, headers=A)
    assert r.status_code == 201, r.text
    plan = r.json()
    assert plan["station_name"] == "Shanghai radar"
    # The station can go; the plan keeps the copy it was planned for, and its exports still recompute.
    client.post("/v1/stations", json={**SITE, "name": "temporary"}, headers=A)
    assert client.delete("/v1/stations/temporary", headers=A).status_code == 204
    assert client.get("/v1/stations/temporary", headers=A).status_code == 404
    assert client.delete("/v1/stations/temporary", headers=A).status_code == 404
    assert client.get(f"/v1/plans/{plan['id']}/export/opm", headers=A).status_code == 200


def test_an_unknown_station_name_is_a_422_and_stores_nothing(client):
    before = client.get("/v1/plans", headers=B).json()["count"]
    r = client.post("/v1/plans", json={**PAPER_EXAMPLE, "ground_station": "Nowhere"}, headers=B)
    assert r.status_code == 422
    detail = r.json()["detail"][0]
    assert detail["loc"] == ["body", "ground_station"] and "POST it to /v1/stations" in detail["msg"]
    assert client.get("/v1/plans", headers=B).json()["count"] == before


@pytest.mark.parametrize(
    "mask,words",
    [
        ([[90, 1], [0, 4]], "does not increase"),
        ([[0, 4], [360, 1]], "outside [0, 360)"),
        ([[0, 95]], "outside [-5, 89]"),
        ([[0, 1, 2]], "at most 2 items"),
    ],
)
def test_a_bad_mask_is_a_422_naming_the_mask(client, mask, words):
    for url, body in (
        ("/v1/stations", {**SITE, "name": "bad", "mask": mask}),
        ("/v1/access-windows", {"target": PAPER_EXAMPLE["target"], "ground_station": {**SITE, "mask": mask}}),
    ):
        r = client.post(url, json=body, headers=A)
        assert r.status_code == 422, r.text
        detail = r.json()["detail"][0]
        assert "mask" in detail["loc"] and words in detail["msg"], detail
    assert client.get("/v1/stations/bad", headers=A).status_code == 404


LOOKALIKES = ["gs-lookalike", "GS-LOOKALIKE", "Gs-Lookalike ", " gs-lookalike", "\uff47\uff53-lookalike"]


def test_lookalike_names_are_one_station_found_by_any_of_them(client):
    """Case, width (full-width letters) and surrounding spaces aside, a name is one station: the second is a 409
    naming the one stored, and any spelling reads it (independent reference: unicodedata's NFKC and casefold)."""
    import unicodedata

    first = client.post("/v1/stations", json={**SITE, "name": LOOKALIKES[0]}, headers=A)
    assert first.status_code == 201, first.text
    for name in LOOKALIKES[1:]:
        assert unicodedata.normalize("NFKC", name.strip()).casefold() == LOOKALIKES[0]
        r = client.post("/v1/stations", json={**SITE, "name": name}, headers=A)
        assert r.status_code == 409, (name, r.text)
        assert "'gs-lookalike'" in r.json()["detail"]
        got = client.get(f"/v1/stations/{name}", headers=A)
        assert got.status_code == 200 and got.json()["name"] == LOOKALIKES[0]
    # NFD and NFC spellings of one name are one station too, stored in NFC
    nfd = "Cafe\u0301 radar"
    r = client.post("/v1/stations", json={**SITE, "name": nfd}, headers=A)
    assert r.status_code == 201 and r.json()["name"] == unicodedata.normalize("NFC", nfd)
    assert client.post("/v1/stations", json={**SITE, "name": "CAF\u00c9 RADAR"}, headers=A).status_code == 409
    plan = client.post("/v1/plans", json={**PAPER_EXAMPLE, "ground_station": " GS-lookalike"}, headers=A)
    assert plan.status_code == 201, plan.text


@pytest.mark.parametrize(
    "name",
    ["a\x7fb", "G\u200bS", "G\u200fS", "G\u2028S", ".", "..", "   "],
    ids=["DEL", "zero-width", "bidi", "line-separator", "dot", "dot-dot", "blank"],
)
def test_names_that_could_not_be_read_back_are_refused(client, name):
    before = client.get("/v1/stations", headers=A).json()["count"]
    r = client.post("/v1/stations", json={**SITE, "name": name}, headers=A)
    assert r.status_code == 422, r.text
    assert r.json()["detail"][0]["loc"] == ["body", "name"]
    assert client.get("/v1/stations", headers=A).json()["count"] == before


def test_concurrent_deletes_of_one_station_answer_one_204(client):
    from concurrent.futures import ThreadPoolExecutor

    def delete(name: str) -> int:
        return client.delete(f"/v1/stations/{name}", headers=A).status_code

    for round_ in range(3):
        name = f"deleted-{round_}"
        assert client.post("/v1/stations", json={**SITE, "name": name}, headers=A).status_code == 201
        with ThreadPoolExecutor(8) as pool:
            codes = sorted(pool.map(delete, [name] * 8))
        assert codes == [204] + [404] * 7, codes


def test_a_stored_radar_block_is_what_plans_are_judged_by(client):
    """A station's radar is stored with it; a plan by the station's name is judged by its limits: raising the radar's
    elevation limit to 60 deg makes every candidate below 60 deg infeasible, with the reason and the figures."""
    strict = {**SITE, "name": "strict radar", "radar": {"min_elevation_deg": 60.0, "max_integration_s": 90.0}}
    r = client.post("/v1/stations", json=strict, headers=A)
    assert r.status_code == 201, r.text
    assert r.json()["radar"]["min_elevation_deg"] == 60.0 and r.json()["radar"]["prf_hz"] == 55.0  # defaults kept
    plan = client.post("/v1/plans", json={**PAPER_EXAMPLE, "ground_station": "strict radar"}, headers=A)
    assert plan.status_code == 201, plan.text
    for c in plan.json()["candidates"]:
        f = c["feasibility"]
        assert f["radar_range_km"] > 0 and f["isar_integration_s"] > 0 and f["radar_cross_section_m2"] > 0
        assert f["radar_snr_db"] is not None
        low = f["radar_elevation_deg"] < 60.0
        assert low == any("min_elevation_deg 60" in reason for reason in f["reasons"])
        assert not (low and f["feasible"])


@pytest.mark.parametrize(
    "radar, field",
    [
        ({"prf_hz": -1}, "prf_hz"),
        ({"gain_dbi": 250}, "gain_dbi"),
        ({"min_elevation_deg": 95}, "min_elevation_deg"),
        ({"max_integration_s": 0}, "max_integration_s"),
        ({"unknown_figure": 1}, "unknown_figure"),
    ],
)
def test_radar_out_of_physical_range_is_a_422_naming_the_field(client, radar, field):
    r = client.post("/v1/plans", json={**PAPER_EXAMPLE, "ground_station": {**SITE, "radar": radar}}, headers=A)
    assert r.status_code == 422, r.text
    locs = [e["loc"] for e in r.json()["detail"]]
    assert any(loc[-3:] == ["ground_station", "radar", field] for loc in locs), locs


def test_a_radar_whose_figures_do_not_fit_together_is_a_422_saying_what_to_fix(client):
    """256 us pulses at 5 kHz are on 128 % of the time."""
    r = client.post("/v1/stations", json={**SITE, "name": "hot radar", "radar": {"prf_hz": 5000.0}}, headers=A)
    assert r.status_code == 422, r.text
    text = str(r.json()["detail"])
    assert "radar" in text and "duty cycle" in text and "pulse_width_us" in text


TIRA_SITE = {
    "name": "Tira",
    "latitude_deg": 50.6166,
    "longitude_deg": 7.1296,
    "altitude_m": 307,
    "min_elevation_deg": 5,
}


def test_a_plan_over_a_network_names_each_candidates_radar(client, stored):
    """A stored station by name and a site given inline: every pass and candidate names its radar, the chosen one's
    radar is the plan's station, and the plan's exports are over it."""
    body = {**PAPER_EXAMPLE, "ground_station": None, "ground_stations": ["Shanghai radar", TIRA_SITE]}
    del body["ground_station"]
    r = client.post("/v1/plans", json=body, headers=A)
    assert r.status_code == 201, r.text
    plan = r.json()
    assert {w["station"] for w in plan["access_windows"]} == {"Shanghai radar", "Tira"}
    assert {c["station"] for c in plan["candidates"]} <= {"Shanghai radar", "Tira"}
    assert plan["chosen"]["station"] == plan["station_name"]
    for c in plan["candidates"]:
        window = next(
            w for w in plan["access_windows"] if w["rise"] <= c["t_access"] <= w["set"] and w["station"] == c["station"]
        )
        assert window is not None
    csv_text = client.get(f"/v1/plans/{plan['id']}/export/pointing.csv", headers=A)
    assert csv_text.status_code == 200, csv_text.text
    # The CZML draws both radars, each with its own passes.
    czml = {p["id"]: p for p in client.get(f"/v1/plans/{plan['id']}/export/czml", headers=A).json()}
    other = "Tira" if plan["station_name"] == "Shanghai radar" else "Shanghai radar"
    assert czml["station"]["name"] == plan["station_name"] and czml["station-1"]["name"] == other
    lo, hi = czml["document"]["clock"]["interval"].split("/")
    for key, name in (("access", plan["station_name"]), ("access-station-1", other)):
        own = [w for w in plan["access_windows"] if w["station"] == name and w["set"] >= lo and w["rise"] <= hi]
        shown = czml[key]["availability"]
        assert len(shown) == len(own) if own else isinstance(shown, str), (key, shown, own)


@pytest.mark.parametrize(
    "network, loc_end, words",
    [
        ([], "ground_stations", "at least 1"),
        (["Shanghai radar", "Shanghai radar"], "ground_stations", "more than once"),
        (["no such radar", TIRA_SITE], 0, "no station named 'no such radar'"),
    ],
)
def test_bad_networks_are_422s_naming_the_field(client, stored, network, loc_end, words):
    body = {k: v for k, v in PAPER_EXAMPLE.items() if k != "ground_station"}
    r = client.post("/v1/plans", json={**body, "ground_stations": network}, headers=A)
    assert r.status_code == 422, r.text
    detail = r.json()["detail"]
    assert any("ground_stations" in e["loc"] for e in detail) and words in r.text, detail


def test_a_station_and_a_network_together_or_neither_are_refused(client):
    both = client.post("/v1/plans", json={**PAPER_EXAMPLE, "ground_stations": [TIRA_SITE]}, headers=A)
    assert both.status_code == 422 and "not both" in both.text
    body = {k: v for k, v in PAPER_EXAMPLE.items() if k != "ground_station"}
    neither = client.post("/v1/plans", json=body, headers=A)
    assert neither.status_code == 422 and "ground_station (one radar) or ground_stations" in neither.text
