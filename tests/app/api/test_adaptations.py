"""Adaptations and model-set versions: a job adapts the set to the caller's labelled frames (gsa adapt in a child
process), the version is listed, promoted, answers estimates naming it, and is rolled back."""

import io
import time

import numpy as np
import pytest

from inference.labelled import write_frame
from inference.simulation.dataset import DatasetSpec, render_frames
from tests.conftest import KEY_A, KEY_B
from tests.utils.models import SMOKE_RADAR

A = {"X-API-Key": KEY_A}
B = {"X-API-Key": KEY_B}
T = "tiangong-like"


@pytest.fixture(scope="module")
def labelled(client):
    """24 frames of another look (the robust preset), 3 scenes of 8, stored as A's labelled frames."""
    arr = render_frames(DatasetSpec(n=24, seed=77, variety="robust"), SMOKE_RADAR, 0, 24)
    files = []
    for k in range(24):
        buf = io.BytesIO()
        write_frame(
            buf,
            arr["image"][k].astype(np.float32),
            angles_deg=arr["angles_deg"][k],
            scene=f"s{k // 8}",
            normalised=True,
        )
        files.append(("files", (f"f{k:02d}.npz", buf.getvalue())))
    r = client.post(f"/v1/targets/{T}/labelled-frames", files=files, headers=A)
    assert r.status_code == 201, r.text
    return arr


def _estimate_version(client):
    frame = np.random.default_rng(3).random((64, 64))
    buf = io.BytesIO()
    np.save(buf, frame)
    r = client.post("/v1/estimates", files={"file": ("f.npy", buf.getvalue())}, headers=A)
    assert r.status_code == 201, r.text
    return r.json()["model"]["version"]


def test_adapt_list_promote_answer_and_roll_back(client, labelled):
    sets = client.get("/v1/model-sets", headers=A).json()["data"]
    assert [s["target"] for s in sets] == [T] and sets[0]["answering_version"] == 0
    r = client.post(
        f"/v1/model-sets/{T}/adaptations",
        json={"epochs": 1, "sim_ratio": 0.5, "crop_px": 32, "lr_unet": 1e-4},
        headers=A,
    )
    assert r.status_code == 202, r.text
    job = r.json()
    assert job["state"] in ("queued", "running") and job["frames"] == 24
    busy = client.post(f"/v1/model-sets/{T}/adaptations", json={"epochs": 1}, headers=A)
    assert busy.status_code == 409 and "already" in busy.json()["detail"]
    deadline = time.monotonic() + 240
    while job["state"] in ("queued", "running") and time.monotonic() < deadline:
        time.sleep(1.0)
        job = client.get(f"/v1/model-sets/{T}/adaptations/{job['id']}", headers=A).json()
    assert job["state"] == "done", job
    assert job["version"] == 1 and job["progress"] == 1.0 and "adapt: epoch 1/1" in job["log"]
    assert client.get(f"/v1/model-sets/{T}/adaptations/{job['id']}", headers=B).status_code == 404
    listed = client.get("/v1/model-sets", headers=A).json()["data"][0]
    v1 = listed["versions"][1]
    assert [v["version"] for v in listed["versions"]] == [0, 1] and listed["answering_version"] == 0
    assert v1["summary"]["labelled_frames"] == 24 and not v1["promoted"]
    assert not set(v1["summary"]["train_scenes"]) & set(v1["summary"]["validation_scenes"])
    assert _estimate_version(client) == 0
    promoted = client.post(f"/v1/model-sets/{T}/versions/1/promote", headers=A)
    assert promoted.status_code == 200 and promoted.json()["answering_version"] == 1
    assert _estimate_version(client) == 1  # every estimate names the version that answered it
    back = client.post(f"/v1/model-sets/{T}/versions/0/promote", headers=A)
    assert back.status_code == 200 and back.json()["answering_version"] == 0
    assert _estimate_version(client) == 0
    assert client.post(f"/v1/model-sets/{T}/versions/7/promote", headers=A).status_code == 404


def test_stored_estimates_are_read_again_by_another_version_as_a_job(client, labelled):
    """After the test above: A's estimates (3, made by versions 0, 1, 0) read again by version 1, each a new
    estimate naming version 1, its old one kept; B's are not touched; a missing version is a 422."""
    mine = client.get("/v1/estimates", params={"limit": 100}, headers=A).json()["data"]
    theirs = client.get("/v1/estimates", headers=B).json()["count"]
    r = client.post(f"/v1/model-sets/{T}/re-estimations", json={"version": 1}, headers=A)
    assert r.status_code == 202, r.text
    job = r.json()
    assert job["kind"] == "reestimate" and job["total"] == len(mine) == 3
    deadline = time.monotonic() + 240
    while job["state"] in ("queued", "running") and time.monotonic() < deadline:
        time.sleep(0.5)
        job = client.get(f"/v1/jobs/{job['id']}", headers=A).json()
    assert job["state"] == "done", job
    res = job["result"]
    assert res["estimates"] == 3 and res["version"] == 1 and len(res["pairs"]) == 3
    assert {p["from"] for p in res["pairs"]} == {e["id"] for e in mine}
    assert 0 <= res["trusted_after"] <= 3 and all(0 <= p["change_deg"] <= 180 for p in res["pairs"])
    for pair in res["pairs"]:
        old = client.get(f"/v1/estimates/{pair['from']}", headers=A).json()
        new = client.get(f"/v1/estimates/{pair['to']}", headers=A).json()
        assert new["model"]["version"] == 1 and new["input_name"] == "re-estimate of " + old["input_name"]
        assert (new["plan_id"], new["observed_at"], new["input_sha256"]) == (
            old["plan_id"],
            old["observed_at"],
            old["input_sha256"],
        )
    assert client.get("/v1/estimates", headers=A).json()["count"] == 6  # the old ones stay
    assert client.get("/v1/estimates", headers=B).json()["count"] == theirs
    missing = client.post(f"/v1/model-sets/{T}/re-estimations", json={"version": 7}, headers=A)
    assert missing.status_code == 422 and "no version 7" in missing.json()["detail"][0]["msg"]
    none = client.post(f"/v1/model-sets/{T}/re-estimations", json={"version": 0}, headers=B)
    assert none.status_code == 422 and "no stored estimates" in none.json()["detail"][0]["msg"]


def test_adaptation_refusals(client, labelled):
    few = client.post(f"/v1/model-sets/{T}/adaptations", json={"epochs": 1}, headers=B)  # B has no labelled frames
    assert few.status_code == 422 and "at least 4, from 2 scenes" in few.json()["detail"][0]["msg"]
    other = client.post("/v1/model-sets/comsat-like/adaptations", json={}, headers=A)
    assert other.status_code == 422 and "no model set is trained on" in other.json()["detail"][0]["msg"]
    bad = client.post(f"/v1/model-sets/{T}/adaptations", json={"epochs": 0}, headers=A)
    assert bad.status_code == 422 and "epochs" in str(bad.json()["detail"][0]["loc"])
    # A NUL in a re-estimation's plan_id is a 422 naming it, on every database (PostgreSQL stores no NUL: it was a 500).
    nul = client.post(f"/v1/model-sets/{T}/re-estimations", json={"version": 0, "plan_id": "ab\u0000cd"}, headers=A)
    assert nul.status_code == 422 and "plan_id" in str(nul.json()["detail"][0]["loc"])
    extra = client.post(f"/v1/model-sets/{T}/adaptations", json={"epoch": 3}, headers=A)
    assert extra.status_code == 422
    odd = client.post(f"/v1/model-sets/{T}/adaptations", json={"crop_px": 100}, headers=A)
    assert odd.status_code == 422 and "crop_px" in str(odd.json()["detail"][0]["loc"])
    assert "multiple of 16" in odd.json()["detail"][0]["msg"]
    both = client.post(f"/v1/model-sets/{T}/adaptations", json={"crop_px": 128, "train_swin": True}, headers=A)
    assert both.status_code == 422 and "Swin reads whole frames" in both.json()["detail"][0]["msg"]
