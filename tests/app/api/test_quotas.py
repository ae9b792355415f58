"""Quotas and clean-up (issue 74): a per-operator storage quota (413) and cap on queued jobs (429) that say what is
used and what is allowed; DELETE of labelled frames, data sets, versions not promoted and ended jobs; jobs started
in turn between operators; a cancel that stops the worker's whole process group; leftovers swept at start-up.

No job runs here (GSA_JOB_WORKERS=0): what is tested is what the service accepts, refuses and removes."""

from __future__ import annotations

import io
import os
import signal
import subprocess
import sys
import time
from datetime import UTC, datetime, timedelta
from types import SimpleNamespace

import numpy as np
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import select

from app.core.config import Settings
from app.core.db import upgrade_database
from app.db.models import LabelledFrame
from app.main import create_app
from app.services import images, jobs
from app.services.storage import folder_bytes
from inference.labelled import write_frame
from tests.conftest import KEY_A, KEY_B

A, B = {"X-API-Key": KEY_A}, {"X-API-Key": KEY_B}
T = "tiangong-like"
RADAR = {"n_range": 64, "n_azimuth": 64, "bandwidth_hz": 0.4e9, "aperture_deg": 1.275}
QUOTA_MB = 0.1  # 104,857 bytes: 24 stored 64 x 64 frames (4,217 bytes each as 8-bit PNG) fit, 25 do not


@pytest.fixture(scope="module")
def settings(tmp_path_factory, smoke_models, backend, pg_root) -> Settings:
    from tests.utils.databases import database_url

    data = tmp_path_factory.mktemp("quotas")
    s = Settings(
        data_dir=data,
        api_keys=f"{KEY_A},{KEY_B}",
        model_dir=smoke_models,
        database_url=database_url(backend, data, pg_root),
        job_workers=0,
        quota_storage_mb=QUOTA_MB,
        quota_queued_jobs=2,
    )
    upgrade_database(s.database_url)
    return s


@pytest.fixture(scope="module")
def client(settings):
    with TestClient(create_app(settings)) as c:
        yield c


def _frames(n: int, seed: int, scene: str) -> list:
    files = []
    for k in range(n):
        buf = io.BytesIO()
        rng = np.random.default_rng(seed + k)
        write_frame(buf, rng.random((64, 64)) + 0.01, angles_deg=[1.0, 2.0, float(k)], scene=scene)
        files.append(("files", (f"{scene}-{k}.npz", buf.getvalue())))
    return files


def _stored(client, headers) -> int:
    return int(client.get(f"/v1/targets/{T}/labelled-frames", headers=headers).json()["count"])


def test_the_storage_quota_refuses_what_would_pass_it_and_deleting_makes_room(client, settings):
    for scene, seed in (("s0", 0), ("s1", 100)):
        assert (
            client.post(f"/v1/targets/{T}/labelled-frames", files=_frames(12, seed, scene), headers=A).status_code
            == 201
        )
    assert folder_bytes(settings.data_dir / "images") == 24 * 4228  # as stored: what the quota counts
    over = client.post(f"/v1/targets/{T}/labelled-frames", files=_frames(1, 500, "s2"), headers=A)
    assert over.status_code == 413, over.text
    detail = over.json()["detail"]
    assert "you store 0.1 MB" in detail and "GSA_QUOTA_STORAGE_MB" in detail and "would add 0.0 MB" in detail
    assert "DELETE /v1/targets/{target}/labelled-frames?scene=S" in detail
    assert _stored(client, A) == 24  # nothing of the refused upload was kept
    assert client.post(f"/v1/targets/{T}/labelled-frames", files=_frames(1, 500, "s2"), headers=B).status_code == 201
    # A deletes one scene: its rows and images go, and there is room again.
    bare = client.delete(f"/v1/targets/{T}/labelled-frames", headers=A)
    assert bare.status_code == 422 and bare.json()["detail"][0]["loc"] == ["query", "scene"]
    gone = client.delete(f"/v1/targets/{T}/labelled-frames", params={"scene": "s0"}, headers=A)
    assert gone.status_code == 200 and gone.json()["deleted"] == 12 and gone.json()["per_scene"] == {"s1": 12}
    assert folder_bytes(settings.data_dir / "images") == 13 * 4228  # A's 12 left and B's one
    assert _stored(client, B) == 1  # B's frames are B's
    assert client.post(f"/v1/targets/{T}/labelled-frames", files=_frames(1, 500, "s2"), headers=A).status_code == 201
    every = client.delete(f"/v1/targets/{T}/labelled-frames", params={"all": "true"}, headers=A)
    assert every.json()["deleted"] == 13 and _stored(client, A) == 0
    with client.app.state.session_factory() as s:
        (left,) = s.scalars(select(LabelledFrame.frame_sha256)).all()
    assert images.blob_path(settings.data_dir, left).is_file()


def test_queued_jobs_are_capped_per_operator_and_ended_ones_deleted(client, settings):
    made = [client.post("/v1/datasets", json={"n": 2, "radar": RADAR}, headers=A) for _ in range(3)]
    assert [r.status_code for r in made] == [202, 202, 429]
    assert "GSA_QUOTA_QUEUED_JOBS = 2" in made[2].json()["detail"] and "you have 2 jobs" in made[2].json()["detail"]
    assert made[2].headers["retry-after"]
    assert client.post("/v1/datasets", json={"n": 2, "radar": RADAR}, headers=B).status_code == 202  # B's own cap
    first = made[0].json()["id"]
    assert client.delete(f"/v1/datasets/{first}", headers=A).status_code == 409  # queued: cancel it first
    cancelled = client.delete(f"/v1/jobs/{first}", headers=A)
    assert cancelled.status_code == 200 and cancelled.json()["state"] == "cancelled"
    assert client.post("/v1/datasets", json={"n": 2, "radar": RADAR}, headers=A).status_code == 202  # room again
    assert client.delete(f"/v1/datasets/{first}", headers=A).status_code == 204  # ended: removed
    assert client.get(f"/v1/jobs/{first}", headers=A).status_code == 404


def test_a_data_set_over_the_storage_quota_is_413(client):
    big = client.post("/v1/datasets", json={"n": 40, "radar": RADAR}, headers=B)
    assert big.status_code == 413 and "a data set of 40 frames" in big.json()["detail"]


def _job(op: str, minute: int) -> SimpleNamespace:
    return SimpleNamespace(operator_id=op, created_at=datetime(2026, 1, 1, tzinfo=UTC) + timedelta(minutes=minute))


def test_jobs_start_in_turn_between_operators():
    """Operator a queued five jobs, then b one and c one: b's and c's start within the first three, not after a's
    five; an operator with a job running, or served more lately, waits behind one without."""
    queued = [_job("a", k) for k in range(5)] + [_job("b", 10), _job("c", 11)]
    order = [j.operator_id for j in jobs.fair_order(queued, jobs.Counter())]  # type: ignore[arg-type]
    assert order == ["a", "b", "c", "a", "a", "a", "a"]
    busy = [j.operator_id for j in jobs.fair_order(queued, jobs.Counter({"a": 1}))]  # type: ignore[arg-type]
    assert busy[:3] == ["b", "c", "a"]
    # One worker: a's job has just ended, so nobody runs; a, served last, goes after b and c, who never were.
    served = {"a": datetime(2026, 1, 1, 0, 30, tzinfo=UTC), "c": datetime(2026, 1, 1, 0, 10, tzinfo=UTC)}
    turn = [j.operator_id for j in jobs.fair_order(queued, jobs.Counter(), served)]  # type: ignore[arg-type]
    assert turn == ["b", "c", "a", "a", "a", "a", "a"]


def test_a_cancel_stops_the_worker_and_every_process_it_started(tmp_path):
    """The dispatcher starts a worker in a session of its own; stopping its group takes a child it started too
    (a gsa adapt, a simulation pool), which a signal to the worker alone left running for good."""
    script = (
        "import subprocess, sys, time; "
        "c = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(60)']); "
        f"open({str(tmp_path / 'child')!r}, 'w').write(str(c.pid)); time.sleep(60)"
    )
    worker = subprocess.Popen([sys.executable, "-c", script], start_new_session=True)
    deadline = time.monotonic() + 20
    while not (tmp_path / "child").exists() or not (tmp_path / "child").read_text():
        assert time.monotonic() < deadline
        time.sleep(0.05)
    child = int((tmp_path / "child").read_text())
    jobs.stop_group(worker.pid, signal.SIGTERM)
    assert worker.wait(10) == -signal.SIGTERM
    deadline = time.monotonic() + 10
    while jobs.pid_alive(child):
        assert time.monotonic() < deadline, "the worker's child outlived the cancel"
        time.sleep(0.05)


def test_leftovers_of_ended_jobs_are_swept_at_start(client, settings):
    stray = settings.data_dir / "jobs" / "00000000-dead-job"
    stray.mkdir(parents=True)
    (stray / "frames.npz").write_bytes(b"x" * 1000)
    partial = settings.data_dir / "model-sets" / T / "v9.partial"
    partial.mkdir(parents=True)
    with client.app.state.session_factory() as s:
        gone = jobs.sweep_leftovers(s, settings)
    assert "00000000-dead-job" in gone and "v9.partial" in gone
    assert not stray.exists() and not partial.exists()
    assert os.path.isdir(settings.data_dir / "jobs")


def test_a_sweep_leaves_another_services_adaptation_work_alone(client, settings, tmp_path):
    """Two services on one host, each with its own data folder: one's start-up sweep must not remove the other's
    running adaptation's frames (it did, when both worked in the system's temporary folder: a CI run failed so)."""
    from app.services.model_versions import work_root

    other = tmp_path / "other-data"
    theirs = work_root(other) / "gsa-adaptation-running"
    theirs.mkdir()
    (theirs / "frames").mkdir()
    ours = work_root(settings.data_dir) / "gsa-adaptation-left"
    ours.mkdir()
    with client.app.state.session_factory() as s:
        gone = jobs.sweep_leftovers(s, settings)
    assert "gsa-adaptation-left" in gone and not ours.exists()
    assert (theirs / "frames").is_dir()
