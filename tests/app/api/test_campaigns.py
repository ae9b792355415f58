"""POST/GET /v1/campaigns and their exports: read back by ccsds-ndm, flown by an independent J2 integrator."""

import csv
import io
import json
from datetime import UTC, datetime

import pytest
from ccsds_ndm.ndm_io import NdmIo

from app.schemas import CAMPAIGN_EXAMPLE
from tests.conftest import KEY_A, KEY_B, SQLITE_ONLY

A = {"X-API-Key": KEY_A}
B = {"X-API-Key": KEY_B}


@pytest.fixture(scope="module")
def campaign(client):
    r = client.post("/v1/campaigns", json=CAMPAIGN_EXAMPLE, headers=A)
    assert r.status_code == 201, r.text
    return r.json()


def _t(kvn_time):
    return datetime.fromisoformat(str(kvn_time).rstrip("Z")).replace(tzinfo=UTC)


def _read(tmp_path, text, name):
    path = tmp_path / f"{name}.kvn"
    path.write_text(text)
    return NdmIo().from_path(str(path))


def test_a_campaign_flies_feasible_scenes_within_its_budget(client, campaign):
    scenes = campaign["scenes"]
    assert len(scenes) >= 3
    assert campaign["dv_total_m_s"] <= campaign["dv_budget_m_s"]
    assert campaign["dv_total_m_s"] == pytest.approx(sum(s["dv_total_m_s"] for s in scenes))
    optics_range = 111.8
    for s in scenes:
        assert s["feasible"] and s["candidate"]["feasibility"]["feasible"]
        assert s["burns"] and s["dv_total_m_s"] == pytest.approx(sum(b["dv_total_m_s"] for b in s["burns"]))
        check = s["check"]
        assert check["sunlit"] and check["target_angular_rate_deg_s"] < 10.0 and check["separation_km"] < optics_range
        assert len(s["candidate"]["feasibility"]["line_of_sight_rtn"]) == 3
        rise, set_ = (datetime.fromisoformat(s["access_window"][k]) for k in ("rise", "set"))
        assert rise <= datetime.fromisoformat(s["t_access"]) <= set_
    times = [datetime.fromisoformat(s["t_access"]) for s in scenes]
    assert times == sorted(times)
    assert campaign["stretches"] and all(st["note"] for st in campaign["stretches"])
    # Stored and read back the same; listed; the operator's own.
    got = client.get(f"/v1/campaigns/{campaign['id']}", headers=A)
    assert got.status_code == 200 and got.json()["scenes"] == scenes
    listing = client.get("/v1/campaigns", headers=A).json()
    assert campaign["id"] in [c["id"] for c in listing["data"]]
    row = next(c for c in listing["data"] if c["id"] == campaign["id"])
    assert row["scenes"] == len(scenes) and row["first_access"] == scenes[0]["t_access"]
    assert client.get(f"/v1/campaigns/{campaign['id']}", headers=B).status_code == 404
    for kind in ("opm", "oem", "czml", "access.csv"):
        assert client.get(f"/v1/campaigns/{campaign['id']}/export/{kind}", headers=B).status_code == 404


@pytest.mark.parametrize(
    ("change", "loc"),
    [
        ({"duration_days": 91}, ["body", "duration_days"]),
        ({"dv_budget_m_s": -1}, ["body", "dv_budget_m_s"]),
        ({"observer_optics": {"aperture_m": 0.0}}, ["observer_optics", "aperture_m"]),
        ({"observer_optics": {"wavelength_nm": 1e9}}, ["observer_optics", "wavelength_nm"]),
        (
            {"ground_station": {**CAMPAIGN_EXAMPLE["ground_station"], "max_azimuth_rate_deg_s": 0}},
            ["body", "ground_station", "max_azimuth_rate_deg_s"],
        ),
        ({"scene_span_days": 0.5}, ["body", "scene_span_days"]),
    ],
)
def test_bad_campaign_input_is_a_422_naming_the_field_and_stores_nothing(client, change, loc):
    before = client.get("/v1/campaigns", headers=B).json()["count"]
    r = client.post("/v1/campaigns", json={**CAMPAIGN_EXAMPLE, **change}, headers=B)
    assert r.status_code == 422, r.text
    detail = r.json()["detail"]
    assert any(list(d["loc"])[-len(loc) :] == loc for d in detail), detail
    assert client.get("/v1/campaigns", headers=B).json()["count"] == before


def test_the_czml_marks_every_scene_and_the_csv_every_pass(client, campaign):
    r = client.get(f"/v1/campaigns/{campaign['id']}/export/czml", headers=A)
    assert r.status_code == 200
    packets = {p["id"]: p for p in json.loads(r.text)}
    n = len(campaign["scenes"])
    assert {f"imaging-{k}" for k in range(n)} <= set(packets)
    assert {"document", "target", "observer", "station", "access"} <= set(packets)
    r = client.get(f"/v1/campaigns/{campaign['id']}/export/access.csv", headers=A)
    assert r.status_code == 200
    rows = list(csv.DictReader(io.StringIO(r.text)))
    assert len(rows) == len(campaign["access_windows"]) > n


def test_a_campaign_over_its_time_budget_is_503_and_stores_nothing(settings):
    from fastapi.testclient import TestClient

    from app.main import create_app

    tight = settings.model_copy(update={"campaign_timeout_s": 0.001})
    with TestClient(create_app(tight)) as c:
        before = c.get("/v1/campaigns", headers=A).json()["count"]
        r = c.post("/v1/campaigns", json=CAMPAIGN_EXAMPLE, headers=A)
        assert r.status_code == 503, r.text
        assert "GSA_CAMPAIGN_TIMEOUT_S" in r.text
        assert c.get("/v1/campaigns", headers=A).json()["count"] == before


@SQLITE_ONLY
def test_a_campaign_asked_for_asynchronously_is_a_job_whose_result_is_the_same_campaign(client):
    """``Prefer: respond-async``: 202 and a job at once; the worker process plans the same campaign as the
    synchronous request did (every scene and burn), stored and linked from the job."""
    import time

    short = {**CAMPAIGN_EXAMPLE, "duration_days": 8}
    campaign = client.post("/v1/campaigns", json=short, headers=A).json()  # the same request, answered at once
    r = client.post("/v1/campaigns", json=short, headers={**A, "Prefer": "respond-async"})
    assert r.status_code == 202, r.text
    assert r.headers["preference-applied"] == "respond-async" and r.json()["kind"] == "campaign"
    job_id = r.json()["id"]
    deadline = time.monotonic() + 240
    while True:
        job = client.get(f"/v1/jobs/{job_id}", headers=A).json()
        if job["state"] not in ("queued", "running") or time.monotonic() > deadline:
            break
        time.sleep(0.3)
    assert job["state"] == "done", job
    assert job["result_url"] == f"/v1/campaigns/{job['result']['campaign_id']}"
    assert job["progress"] == 1.0 and "jobs: done" in job["log_tail"]
    planned = client.get(job["result_url"], headers=A).json()
    assert planned["scenes"] == campaign["scenes"] and planned["dv_total_m_s"] == campaign["dv_total_m_s"]
    assert client.get(f"/v1/jobs/{job_id}", headers=B).status_code == 404
    bad = client.post(
        "/v1/campaigns", json={**CAMPAIGN_EXAMPLE, "dv_budget_m_s": -1}, headers={**A, "Prefer": "respond-async"}
    )
    assert bad.status_code == 422  # checked before it is queued: no job
