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
