"""Model sets belong to operators (issue 74): each operator is answered by the version it promoted, else by the
shared default, which only an admin key changes; promotion passes a quality gate; nothing shows another operator's
versions or a server path; adaptations lock per operator and target.

Versions are made here as ``gsa adapt`` leaves them (a model folder under GSA_DATA_DIR/model-sets and its row), so
the tenancy is tested without training; tests/app/api/test_adaptations.py runs a real adaptation."""

from __future__ import annotations

import io
import json
import shutil
import threading
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import func, select

from app.core.config import Settings
from app.core.db import upgrade_database
from app.core.security import key_fingerprint
from app.db.models import ModelPromotion, ModelVersion, Operator
from app.main import create_app
from inference.labelled import write_frame
from tests.conftest import KEY_A, KEY_B

ADMIN_KEY = "test-key-admin-000000"
A, B, ADMIN = {"X-API-Key": KEY_A}, {"X-API-Key": KEY_B}, {"X-API-Key": ADMIN_KEY}
T = "tiangong-like"


@pytest.fixture(scope="module")
def settings(tmp_path_factory, smoke_models, backend, pg_root) -> Settings:
    from tests.utils.databases import database_url

    data = tmp_path_factory.mktemp("tenancy")
    s = Settings(
        data_dir=data,
        api_keys=f"{KEY_A},{KEY_B}",
        admin_api_keys=ADMIN_KEY,
        model_dir=smoke_models,
        database_url=database_url(backend, data, pg_root),
        job_workers=0,  # adaptations stay queued: what is tested is who may queue them
    )
    upgrade_database(s.database_url)
    return s


@pytest.fixture(scope="module")
def client(settings):
    with TestClient(create_app(settings)) as c:
        for h in (A, B, ADMIN):  # each environment key's operator is made on its first request
            assert c.get("/v1/model-sets", headers=h).status_code == 200
        yield c


def _operator_id(client, key: str) -> str:
    with client.app.state.session_factory() as s:
        return str(s.scalar(select(Operator.id).where(Operator.name == f"env-{key_fingerprint(key)}")))


def _make_version(client, settings, smoke_models: Path, key: str, number: int, damage: bool = False) -> Path:
    """Version ``number`` of T, made by ``key``'s operator, as an adaptation leaves it."""
    rel = Path("model-sets") / T / f"v{number}"
    folder = settings.data_dir / rel
    shutil.copytree(smoke_models, folder)
    card = json.loads((folder / "model_card.json").read_text())
    card["version"] = {"target": T, "number": number, "base": 0}
    (folder / "model_card.json").write_text(json.dumps(card))
    if damage:
        unet = folder / card["files"]["unetpp"]["file"]
        unet.write_bytes(unet.read_bytes()[:-64] + bytes(64))
    with client.app.state.session_factory() as s:
        s.add(
            ModelVersion(
                target=T,
                version=number,
                operator_id=_operator_id(client, key),
                base_version=0,
                dir=str(rel),
                summary={"labelled_frames": 24, "train_scenes": [f"secret-scene-{number}"], "list_sha256": "ab" * 32},
            )
        )
        s.commit()
    return folder


def _answering(client, headers) -> int:
    buf = io.BytesIO()
    np.save(buf, np.random.default_rng(5).random((64, 64)))
    r = client.post("/v1/estimates", files={"file": ("f.npy", buf.getvalue())}, headers=headers)
    assert r.status_code == 201, r.text
    return int(r.json()["model"]["version"])


def _listed(client, headers) -> dict:
    (entry,) = client.get("/v1/model-sets", headers=headers).json()["data"]
    return entry


@pytest.fixture(scope="module")
def versions(client, settings, smoke_models):
    """A made versions 1 and 3 (3 damaged: a file's bytes changed after its card recorded their sha256); B made 2."""
    _make_version(client, settings, smoke_models, KEY_A, 1)
    _make_version(client, settings, smoke_models, KEY_B, 2)
    _make_version(client, settings, smoke_models, KEY_A, 3, damage=True)


def test_each_operator_is_answered_by_its_own_promotion(client, settings, versions):
    assert client.post(f"/v1/model-sets/{T}/versions/1/promote", headers=A).status_code == 200
    assert (_answering(client, A), _answering(client, B)) == (1, 0)  # B is not switched by A's promotion
    # B can neither promote nor roll back what is A's: another's version is not found, and B's 0 is B's alone.
    assert client.post(f"/v1/model-sets/{T}/versions/1/promote", headers=B).status_code == 404
    assert client.post(f"/v1/model-sets/{T}/versions/0/promote", headers=B).status_code == 200
    assert _answering(client, A) == 1
    assert client.post(f"/v1/model-sets/{T}/versions/2/promote", headers=B).status_code == 200
    assert (_answering(client, A), _answering(client, B)) == (1, 2)
    mine, theirs = _listed(client, A), _listed(client, B)
    assert [v["version"] for v in mine["versions"]] == [0, 1, 3] and mine["answering_version"] == 1
    assert [v["version"] for v in theirs["versions"]] == [0, 2] and theirs["answering_version"] == 2
    body = client.get("/v1/model-sets", headers=B).text
    assert "secret-scene-1" not in body and "secret-scene-2" in body  # B sees its own details only
    for text in (body, client.get("/readyz").text, client.get("/v1/model-sets", headers=A).text):
        assert str(settings.data_dir) not in text and str(settings.model_dir) not in text  # no server path
    # A's re-estimation may name its own versions, never B's.
    other = client.post(f"/v1/model-sets/{T}/re-estimations", json={"version": 2}, headers=A)
    assert other.status_code == 422 and "no version 2 of yours" in other.json()["detail"][0]["msg"]
    assert client.post(f"/v1/model-sets/{T}/versions/0/promote", headers=B).status_code == 200


def test_only_an_admin_key_changes_the_shared_default(client, versions):
    refused = client.post(f"/v1/model-sets/{T}/versions/1/promote", params={"shared": "true"}, headers=A)
    assert refused.status_code == 403 and "admin key" in refused.json()["detail"]
    assert _listed(client, ADMIN)["shared_version"] == 0
    assert [v["version"] for v in _listed(client, ADMIN)["versions"]] == [0, 1, 2, 3]  # an admin chooses among all
    shared = client.post(f"/v1/model-sets/{T}/versions/2/promote", params={"shared": "true"}, headers=ADMIN)
    assert shared.status_code == 200 and shared.json()["shared_version"] == 2
    # B has no promotion of its own: the shared default answers it; A keeps its own promotion.
    assert (_answering(client, A), _answering(client, B), _answering(client, ADMIN)) == (1, 2, 2)
    entry = _listed(client, A)
    v2 = next(v for v in entry["versions"] if v["version"] == 2)  # shown to A as the shared default, no details
    assert v2["shared_default"] and not v2["mine"] and v2["summary"] == {} and entry["shared_version"] == 2
    assert client.post(f"/v1/model-sets/{T}/versions/0/promote", headers=A).status_code == 200
    assert _answering(client, A) == 2  # A withdrew its promotion: the shared default answers it
    back = client.post(f"/v1/model-sets/{T}/versions/0/promote", params={"shared": "true"}, headers=ADMIN)
    assert back.status_code == 200
    assert (_answering(client, A), _answering(client, B)) == (0, 0)


def test_a_damaged_version_fails_the_gate_and_one_damaged_later_answers_503(client, settings, smoke_models, versions):
    r = client.post(f"/v1/model-sets/{T}/versions/3/promote", headers=A)
    assert r.status_code == 409, r.text
    detail = r.json()["detail"]
    assert "not promoted" in detail and "sha256" in detail and str(settings.data_dir) not in detail
    assert _listed(client, A)["answering_version"] == 0 and _answering(client, A) == 0
    # A version that passed the gate and was damaged before this worker loaded it: a 503 saying how to mend it
    # (the server's fault, not the request's), for its operator only.
    folder = _make_version(client, settings, smoke_models, KEY_A, 4)
    assert client.post(f"/v1/model-sets/{T}/versions/4/promote", headers=A).status_code == 200
    (folder / "model_card.json").write_text("{ not json")
    broken = client.post("/v1/estimates", files={"file": ("f.npy", _npy())}, headers=A)
    assert broken.status_code == 503 and "promote another version" in broken.json()["detail"]
    assert str(settings.data_dir) not in broken.text
    assert _answering(client, B) == 0
    assert client.post(f"/v1/model-sets/{T}/versions/0/promote", headers=A).status_code == 200
    assert _answering(client, A) == 0


def _npy() -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.random.default_rng(5).random((64, 64)))
    return buf.getvalue()


def test_concurrent_promotions_leave_one_answering_and_no_5xx(client, versions):
    codes: list[int] = []

    def promote(k: int) -> None:
        codes.append(client.post(f"/v1/model-sets/{T}/versions/{k % 2}/promote", headers=A).status_code)

    threads = [threading.Thread(target=promote, args=(k,)) for k in range(12)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(set(codes)) == [200], codes
    with client.app.state.session_factory() as s:
        rows = s.scalar(select(func.count()).select_from(ModelPromotion).where(ModelPromotion.target == T))
    assert rows <= 1 and _listed(client, A)["answering_version"] in (0, 1)
    assert client.post(f"/v1/model-sets/{T}/versions/0/promote", headers=A).status_code == 200


def _labelled(seed: int) -> list:
    files = []
    for k in range(4):
        buf = io.BytesIO()
        rng = np.random.default_rng(seed + k)
        write_frame(buf, rng.random((64, 64)) + 0.01, angles_deg=[1.0, 2.0, 3.0], scene=f"s{k % 2}")
        files.append(("files", (f"f{k}.npz", buf.getvalue())))
    return files


def test_adaptations_lock_per_operator_and_target(client, versions):
    for h, seed in ((A, 0), (B, 10)):
        assert client.post(f"/v1/targets/{T}/labelled-frames", files=_labelled(seed), headers=h).status_code == 201
    first = client.post(f"/v1/model-sets/{T}/adaptations", json={"epochs": 1}, headers=A)
    assert first.status_code == 202, first.text
    other = client.post(f"/v1/model-sets/{T}/adaptations", json={"epochs": 1}, headers=B)
    assert other.status_code == 202, other.text  # another operator's adaptation of the same target is not a 409
    long = client.post(f"/v1/model-sets/{T}/adaptations", json={"max_minutes": 1000}, headers=B)
    assert long.status_code == 422 and "GSA_MAX_ADAPTATION_MINUTES" in long.json()["detail"][0]["msg"]
    many = client.post(f"/v1/model-sets/{T}/adaptations", json={"epochs": 900}, headers=B)
    assert many.status_code == 422 and many.json()["detail"][0]["loc"][-1] == "epochs"
    again = client.post(f"/v1/model-sets/{T}/adaptations", json={"epochs": 1}, headers=A)
    assert again.status_code == 409 and "of yours" in again.json()["detail"]
    assert "base_dir" not in json.dumps(client.get(f"/v1/jobs/{first.json()['id']}", headers=A).json())
    for job, h in ((first, A), (other, B)):
        assert client.delete(f"/v1/jobs/{job.json()['id']}", headers=h).status_code in (200, 202)


def test_an_operator_deletes_its_own_versions_that_answer_no_one(client, settings, smoke_models, versions):
    folder = _make_version(client, settings, smoke_models, KEY_A, 5)
    assert client.post(f"/v1/model-sets/{T}/versions/5/promote", headers=A).status_code == 200
    promoted = client.delete(f"/v1/model-sets/{T}/versions/5", headers=A)
    assert promoted.status_code == 409 and "promote another" in promoted.json()["detail"]
    assert client.post(f"/v1/model-sets/{T}/versions/0/promote", headers=A).status_code == 200
    assert client.delete(f"/v1/model-sets/{T}/versions/5", headers=B).status_code == 404  # not B's
    assert client.post(f"/v1/model-sets/{T}/versions/5/promote", params={"shared": "true"}, headers=ADMIN).is_success
    shared = client.delete(f"/v1/model-sets/{T}/versions/5", headers=A)
    assert shared.status_code == 409 and "shared default" in shared.json()["detail"]
    assert client.post(f"/v1/model-sets/{T}/versions/0/promote", params={"shared": "true"}, headers=ADMIN).is_success
    assert client.delete(f"/v1/model-sets/{T}/versions/5", headers=A).status_code == 204
    assert not folder.exists() and 5 not in [v["version"] for v in _listed(client, A)["versions"]]
    assert client.delete(f"/v1/model-sets/{T}/versions/0", headers=A).status_code == 409  # the configured set
