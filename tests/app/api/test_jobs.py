"""Jobs: a data set simulated by a worker process beside the server, followed, listed, cancelled, resumed after a
restart; the files the same bytes as ``generate`` writes in this process; other operators' jobs out of reach."""

import hashlib
import io
import time

import numpy as np
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import update

from app.core.db import make_engine, make_session_factory
from app.db.models import Job
from app.main import create_app
from app.services.jobs import host
from inference.simulation.dataset import DatasetSpec, generate
from inference.simulation.radar import Radar
from tests.conftest import KEY_A, KEY_B

A = {"X-API-Key": KEY_A}
B = {"X-API-Key": KEY_B}
RADAR = {"n_range": 64, "n_azimuth": 64, "bandwidth_hz": 0.4e9, "aperture_deg": 1.275}
SMALL = Radar(n_range=64, n_azimuth=64, bandwidth_hz=0.4e9, aperture_deg=1.275)


def wait(client, job_id, states=("done", "failed", "cancelled"), timeout=120.0):
    deadline = time.monotonic() + timeout
    while True:
        job = client.get(f"/v1/jobs/{job_id}", headers=A).json()
        if job["state"] in states or time.monotonic() > deadline:
            return job
        time.sleep(0.2)


def test_a_data_set_job_writes_the_bytes_this_process_would(client, settings, tmp_path):
    body = {"n": 6, "seed": 5, "shard_size": 2, "n_train": 4, "radar": RADAR}
    r = client.post("/v1/datasets", json=body, headers=A)
    assert r.status_code == 202, r.text
    job = r.json()
    assert job["kind"] == "dataset" and job["state"] in ("queued", "running") and job["total"] == 6
    assert r.headers["location"] == f"/v1/jobs/{job['id']}"
    done = wait(client, job["id"])
    assert done["state"] == "done", done
    assert done["done"] == 6 and done["progress"] == 1.0 and done["result_url"] == f"/v1/jobs/{job['id']}"
    assert "dataset: 6 frames" in done["log_tail"] and done["finished_at"] >= done["started_at"]
    # The same set made here, in this process, one worker: the same shards, byte for byte.
    here = generate(
        DatasetSpec(n=6, seed=5, shard_size=2, n_train=4), tmp_path / "here", SMALL, workers=1, progress=False
    )
    assert done["result"]["content_sha256"] == here["content_sha256"] and done["result"]["shards"] == 3
    manifest = client.get(f"/v1/datasets/{job['id']}/files/manifest.json", headers=A)
    assert manifest.status_code == 200 and manifest.json()["split"] == {"train": [0, 4], "test": [4, 6]}
    shard = client.get(f"/v1/datasets/{job['id']}/files/shard-00002.npz", headers=A)
    assert shard.status_code == 200
    assert shard.content == (tmp_path / "here" / "shard-00002.npz").read_bytes()
    assert hashlib.sha256(shard.content).hexdigest() == here["shards"][2]["sha256"]
    # What the job wrote is this user's alone, whatever the umask: folders 0700, files 0600.
    for path in (settings.data_dir / "jobs", settings.data_dir / "datasets" / job["id"]):
        assert path.stat().st_mode & 0o777 == 0o700, path
    for path in (
        settings.data_dir / "jobs" / f"{job['id']}.log",
        settings.data_dir / "datasets" / job["id"] / "shard-00002.npz",
    ):
        assert path.stat().st_mode & 0o777 == 0o600, path
    with np.load(io.BytesIO(shard.content)) as z:
        assert z["image"].shape == (2, 64, 64) and list(z["index"]) == [4, 5]
    # Another operator sees none of it.
    assert client.get(f"/v1/jobs/{job['id']}", headers=B).status_code == 404
    assert client.delete(f"/v1/jobs/{job['id']}", headers=B).status_code == 404
    assert client.get(f"/v1/datasets/{job['id']}/files/manifest.json", headers=B).status_code == 404
    assert job["id"] not in [j["id"] for j in client.get("/v1/jobs", headers=B).json()["data"]]
    # Listed with filters; a finished job is removed by DELETE, its data set with it.
    listing = client.get("/v1/jobs", params={"kind": "dataset", "state": "done"}, headers=A).json()
    assert job["id"] in [j["id"] for j in listing["data"]] and listing["count"] >= 1
    assert client.get("/v1/jobs", params={"state": "done", "kind": "campaign"}, headers=A).json()["data"] == []
    assert client.get(f"/v1/datasets/{job['id']}/files/..%2Fgsa.db", headers=A).status_code == 404
    assert client.delete(f"/v1/datasets/{job['id']}", headers=B).status_code == 404  # not B's to delete
    assert client.delete(f"/v1/jobs/{job['id']}", headers=A).status_code == 204
    assert not (settings.data_dir / "datasets" / job["id"]).exists()
    assert not (settings.data_dir / "jobs" / f"{job['id']}.log").exists()
    assert client.get(f"/v1/jobs/{job['id']}", headers=A).status_code == 404
    assert client.delete(f"/v1/jobs/{job['id']}", headers=A).status_code == 404


@pytest.mark.parametrize(
    ("body", "field"),
    [
        ({"n": 0}, "n"),
        ({"n": 4, "snr_min_db": 10, "snr_max_db": 1}, "snr_min_db"),
        ({"n": 4, "snr_min_db": 1, "snr_max_db": None}, "snr_min_db"),
        ({"n": 4, "variety_share": 0.5}, "variety_share"),
        ({"n": 4, "physics": "fdtd"}, "physics"),
        ({"n": 4, "radar": {"n_azimuth": 60}}, "radar"),
        ({"n": 4, "frames": 3}, "frames"),
        ({"n": 1_000_000, "radar": {"n_range": 1024, "n_azimuth": 1024}}, "n"),  # 2.2 TB: over GSA_MAX_DATASET_GB
    ],
)
def test_a_bad_data_set_request_is_a_422_naming_the_field_and_no_job(client, body, field):
    before = client.get("/v1/jobs", headers=A).json()["count"]
    r = client.post("/v1/datasets", json=body, headers=A)
    assert r.status_code == 422, r.text
    assert field in str(r.json()["detail"][0]["loc"]), r.json()
    assert client.get("/v1/jobs", headers=A).json()["count"] == before


def test_cancel_a_running_and_a_queued_job(client, settings):
    # One worker (GSA_JOB_WORKERS=1): the first runs, the second waits its turn.
    long = client.post("/v1/datasets", json={"n": 4000, "shard_size": 20, "radar": RADAR}, headers=A).json()
    queued = client.post("/v1/datasets", json={"n": 4, "radar": RADAR}, headers=A).json()
    running = wait(client, long["id"], states=("running",), timeout=60)
    assert running["state"] == "running"
    deadline = time.monotonic() + 60
    while running["done"] == 0 and time.monotonic() < deadline:  # it has written a shard: there is work to undo
        time.sleep(0.2)
        running = client.get(f"/v1/jobs/{long['id']}", headers=A).json()
    assert 0 < running["done"] < 4000 and running["total"] == 4000
    assert running["eta_s"] is None or running["eta_s"] > 0
    assert client.get(f"/v1/jobs/{queued['id']}", headers=A).json()["state"] == "queued"
    r = client.delete(f"/v1/jobs/{queued['id']}", headers=A)
    assert r.status_code == 200 and r.json()["state"] == "cancelled"
    r = client.delete(f"/v1/jobs/{long['id']}", headers=A)
    assert r.status_code == 202 and r.json()["cancel_requested"] is True
    stopped = wait(client, long["id"], timeout=30)
    assert stopped["state"] == "cancelled" and stopped["done"] < 4000, stopped
    assert not (settings.data_dir / "datasets" / long["id"]).exists()
    assert not (settings.data_dir / "datasets" / f"{long['id']}.partial").exists()
    assert client.get(f"/v1/jobs/{queued['id']}", headers=A).json()["attempts"] == 0  # never started


def test_a_restart_resumes_a_job_whose_process_is_gone_and_fails_one_resumed_too_often(client, settings):
    r = client.post("/v1/datasets", json={"n": 4, "shard_size": 2, "seed": 9, "radar": RADAR}, headers=A)
    first = wait(client, r.json()["id"])
    assert first["state"] == "done"
    r2 = client.post("/v1/datasets", json={"n": 2, "radar": RADAR}, headers=A).json()
    assert wait(client, r2["id"])["state"] == "done"
    client.app.state.jobs.stop()  # the server stops (a kill: its dispatcher says nothing more)
    factory = make_session_factory(make_engine(settings.database_url))
    dead = 2**22 + 12345  # no such process
    with factory() as s:  # as a server killed mid-job leaves them: running, their worker gone
        for job_id, attempts in ((first["id"], 1), (r2["id"], 3)):
            s.execute(
                update(Job)
                .where(Job.id == job_id)
                .values(state="running", runner=f"{host()}:{dead}", attempts=attempts, result=None, finished_at=None)
            )
        s.commit()
    with TestClient(create_app(settings)) as restarted:  # the service starting again
        resumed = wait(restarted, first["id"])
        assert resumed["state"] == "done" and resumed["attempts"] == 2, resumed
        assert "restarted" in resumed["log_tail"]
        assert resumed["result"]["content_sha256"] == first["result"]["content_sha256"]
        failed = restarted.get(f"/v1/jobs/{r2['id']}", headers=A).json()
        assert failed["state"] == "failed" and "stopped while it ran, 3 times" in failed["error"]


def _down(*_args, **_kwargs):
    from sqlalchemy.exc import OperationalError

    raise OperationalError("SELECT 1", {}, ConnectionRefusedError("the database is down"))


def _outage_job(ctx):
    """A job whose own work meets the database down (as a campaign storing its row would)."""
    ctx.report(stage="working", progress=0.5)
    _down()


def _flaky_job(ctx):
    """A job that reports while the database comes and goes, then ends."""
    for k in range(6):
        ctx.report(stage=f"step {k}", done=k, total=6)
    return {"steps": 6}


def test_a_database_outage_queues_the_job_again_and_the_work_outlives_a_flaky_database(client, settings, monkeypatch):
    """A job worker (run in this process, its job claimed as the dispatcher claims one) whose work meets the
    database down is queued again with the reason on its row, not failed, until its last start; progress writes that
    meet the database down are kept and written later, and the job ends done."""
    from app.services import job_worker, jobs
    from app.services.jobs import MAX_ATTEMPTS

    factory = make_session_factory(make_engine(settings.database_url))
    operator = client.get("/v1/jobs", headers=A)  # the operator exists
    assert operator.status_code == 200

    def claimed(kind: str, attempts: int) -> str:
        from app.db.models import Operator

        with factory() as s:
            op = s.query(Operator).filter(Operator.name.like("env-%")).first()
            job = jobs.submit(s, operator_id=op.id, kind=kind, params={}, stage="queued", engine="local", cap=None)
            s.execute(
                update(Job)
                .where(Job.id == job.id)
                .values(state="running", runner=f"{host()}:0", attempts=attempts, started_at=Job.created_at)
            )
            s.commit()
            return job.id

    monkeypatch.setattr(job_worker, "settings_from_env", lambda: settings)
    monkeypatch.setitem(job_worker.KINDS, "campaign", "tests.app.api.test_jobs:_outage_job")
    monkeypatch.setattr(job_worker, "WRITE_EVERY_S", 0.0)
    first = claimed("campaign", 1)
    assert job_worker.run(first) == 0
    with factory() as s:
        row = s.get(Job, first)
        assert row.state == "queued" and row.runner == "" and "database did not answer" in row.stage, row.stage
        assert "queued again" in row.log and row.error is None
    last = claimed("campaign", MAX_ATTEMPTS)
    assert job_worker.run(last) == 0
    with factory() as s:
        row = s.get(Job, last)
        assert row.state == "failed" and "database did not answer" in row.error and "3 starts" in row.error

    import app.core.db

    real = app.core.db.make_session_factory
    calls = {"n": 0}

    def flaky_factory(engine):
        made = real(engine)

        def session():
            calls["n"] += 1
            if 3 <= calls["n"] <= 6:  # the database away for four writes, mid-job
                _down()
            return made()

        return session

    monkeypatch.setattr(app.core.db, "make_session_factory", flaky_factory)
    monkeypatch.setitem(job_worker.KINDS, "campaign", "tests.app.api.test_jobs:_flaky_job")
    flaky = claimed("campaign", 1)
    assert job_worker.run(flaky) == 0
    with factory() as s:
        row = s.get(Job, flaky)
        assert row.state == "done" and row.result == {"steps": 6} and row.done == 5, (row.state, row.error)
    assert calls["n"] > 6
