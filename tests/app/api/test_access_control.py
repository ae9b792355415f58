"""Access control generated from the app's route table, API keys at rest, request ids and logs.

Every ``/v1`` route is taken from the app's route table (as its OpenAPI document lists it), so a new route is covered (or the
test names it) without anyone remembering to add it here.
"""

from __future__ import annotations

import copy
import hashlib
import io
import json
import logging
import re
import time
from datetime import datetime

import numpy as np
import pytest
from sqlalchemy import create_engine, func, select, text

from app import crud
from app.core.db import head_revision, make_engine, make_session_factory
from app.core.observability import JsonFormatter, TextFormatter, json_lines_wanted
from app.core.security import LEGACY_SCHEME, AuthThrottle, key_digest, load_key_secret
from app.db.models import ApiKey, Campaign, Estimate, GroundStation, Job, Pass, Plan
from app.schemas import CAMPAIGN_EXAMPLE, PAPER_EXAMPLE
from tests.conftest import KEY_A, KEY_B
from tests.utils.server import npy_bytes

A = {"X-API-Key": KEY_A}
B = {"X-API-Key": KEY_B}
# The stored record each path parameter names; a route with any other parameter fails the test.
ID_PARAMS = {
    "plan_id": "plan",
    "estimate_id": "estimate",
    "pass_id": "pass",
    "name": "station",
    "campaign_id": "campaign",
    "adaptation_id": "adaptation",
    "job_id": "job",
}
# Path parameters that name something every operator shares (a target model), not a stored record: such a
# route answers each operator with their own records of it, so it is checked for keys, not for 404s.
SHARED_PARAMS = {"target": "tiangong-like", "version": "0", "file_name": "manifest.json"}
# Listings of what every operator shares (the service's model sets), not of an operator's records.
SHARED_LISTINGS = {"/v1/model-sets"}
COLLECTIONS = {
    "plan": "plans",
    "estimate": "estimates",
    "pass": "passes",
    "station": "stations",
    "campaign": "campaigns",
    "adaptation": "model-sets/tiangong-like/adaptations",
    "job": "jobs",
}


def _v1_routes(app):
    """Every (method, path) under /v1, from the route table as the app publishes it (its OpenAPI paths)."""
    paths = app.openapi()["paths"]
    return sorted((m.upper(), p) for p, ops in paths.items() if p.startswith("/v1") for m in ops)


def _counts(settings):
    engine = create_engine(settings.database_url)
    with engine.connect() as conn:
        out = {
            t.__tablename__: conn.scalar(select(func.count()).select_from(t))
            for t in (Plan, Estimate, Pass, ApiKey, GroundStation, Campaign)
        }
    engine.dispose()
    return out


@pytest.fixture(scope="module")
def records(client):
    """One plan and one estimate of operator A (the estimate tied to the plan)."""
    plan = client.post("/v1/plans", json=copy.deepcopy(PAPER_EXAMPLE), headers=A)
    assert plan.status_code == 201, plan.text
    frame = np.random.default_rng(0).random((64, 64))
    est = client.post(
        "/v1/estimates", files={"file": ("f.npy", npy_bytes(frame))}, data={"plan_id": plan.json()["id"]}, headers=A
    )
    assert est.status_code == 201, est.text
    w = plan.json()["access_windows"][0]
    rise, end = datetime.fromisoformat(w["rise"]), datetime.fromisoformat(w["set"])
    times = [(rise + (end - rise) * f).isoformat() for f in (0.3, 0.6)]
    buf = io.BytesIO()
    np.savez(buf, frames=np.random.default_rng(1).random((2, 64, 64)))
    ps = client.post(
        "/v1/passes",
        files=[("files", ("p.npz", buf.getvalue()))],
        data={"plan_id": plan.json()["id"], "observed_at": times},
        headers=A,
    )
    assert ps.status_code == 201, ps.text
    site = {**PAPER_EXAMPLE["ground_station"], "name": "site-of-operator-a"}
    st = client.post("/v1/stations", json=site, headers=A)
    assert st.status_code == 201, st.text
    campaign = client.post("/v1/campaigns", json={**CAMPAIGN_EXAMPLE, "duration_days": 8}, headers=A)
    assert campaign.status_code == 201, campaign.text
    with client.app.state.session_factory() as session:  # an adaptation and a data set of A's, ended (none runs)
        owner = session.scalar(select(Estimate.operator_id).where(Estimate.id == est.json()["id"]))
        params = {"adaptation": {"target": "tiangong-like", "options": {}, "frames": 4}, "dataset": {"n": 4}}
        jobs = {
            kind: Job(operator_id=owner, kind=kind, state="failed", stage="", params=params[kind], log="", runner="")
            for kind in ("adaptation", "dataset")
        }
        session.add_all(jobs.values())
        session.commit()
        ids = {kind: job.id for kind, job in jobs.items()}
    return {
        "adaptation": ids["adaptation"],
        "job": ids["dataset"],
        "plan": plan.json()["id"],
        "estimate": est.json()["id"],
        "pass": ps.json()["id"],
        "station": site["name"],
        "campaign": campaign.json()["id"],
    }


@pytest.fixture(scope="module")
def revoked_key(client):
    app = client.app
    with app.state.session_factory() as session:
        row, key = crud.create_api_key(session=session, secret=app.state.key_secret, operator_name="gone", key_name="k")
        crud.revoke_api_key(session=session, key_id=row.id)
    return key


def _path(path, records):
    params = re.findall(r"{(\w+)}", path)
    missing = [p for p in params if p not in ID_PARAMS and p not in SHARED_PARAMS]
    assert not missing, f"route {path} has path parameters {missing}: add them to ID_PARAMS"
    return path.format(**{p: SHARED_PARAMS[p] if p in SHARED_PARAMS else records[ID_PARAMS[p]] for p in params})


def test_every_v1_route_answers_401_without_a_valid_key(client, records, revoked_key):
    routes = _v1_routes(client.app)
    assert len(routes) >= 11
    throttle = client.app.state.auth_throttle
    client.app.state.auth_throttle = AuthThrottle(10**6)  # hundreds of wrong keys on purpose: no back-off here
    try:
        for method, path in routes:
            url = _path(path, records)
            for headers in (
                {},
                {"X-API-Key": revoked_key},
                {"X-API-Key": "gsa_" + "x" * 43},
                {"X-API-Key": KEY_A[:-1]},
            ):
                r = client.request(method, url, headers=headers)
                assert r.status_code == 401, (method, path, headers, r.text)
                assert r.json()["request_id"] == r.headers["X-Request-ID"]
    finally:
        client.app.state.auth_throttle = throttle


def test_an_address_that_sends_wrong_keys_is_backed_off_whatever_key_it_sends(settings):
    """GSA_AUTH_FAILURES_PER_MINUTE wrong keys from one address: the next request is a 429 with Retry-After, the
    right key included (else the answers would still tell keys apart); a missing key is not a guess; once the
    window has passed the address is heard again."""
    from fastapi.testclient import TestClient

    from app.main import create_app

    s = settings.model_copy(update={"auth_failures_per_minute": 5})
    with TestClient(create_app(s)) as c:
        throttle = c.app.state.auth_throttle
        for _ in range(3):
            assert c.get("/v1/plans").status_code == 401  # no key: not counted
        for k in range(5):
            assert c.get("/v1/plans", headers={"X-API-Key": f"wrong-key-{k:016d}"}).status_code == 401
        for headers in ({"X-API-Key": "wrong-key-again-0123"}, A):
            r = c.get("/v1/plans", headers=headers)
            assert r.status_code == 429, r.text
            assert "GSA_AUTH_FAILURES_PER_MINUTE" in r.json()["detail"] and 1 <= int(r.headers["Retry-After"]) <= 60
        # another address is not held back; the window passing frees this one
        assert throttle.wait_s("10.0.0.9") == 0.0
        assert throttle.wait_s("testclient", now=time.monotonic() + 61.0) == 0.0
        throttle._fails.clear()
        assert c.get("/v1/plans", headers=A).status_code == 200


def test_another_operators_records_are_404_and_unchanged(client, settings, records):
    before = {name: client.get(f"/v1/{COLLECTIONS[name]}/{rid}", headers=A).json() for name, rid in records.items()}
    counts = _counts(settings)
    checked = 0
    for method, path in _v1_routes(client.app):
        if not set(re.findall(r"{(\w+)}", path)) - set(SHARED_PARAMS):
            continue
        r = client.request(method, _path(path, records), headers=B)
        assert r.status_code == 404, (method, path, r.text)
        checked += 1
    assert checked >= 5  # plan, estimate, its two images, delete
    assert _counts(settings) == counts
    after = {name: client.get(f"/v1/{COLLECTIONS[name]}/{rid}", headers=A).json() for name, rid in records.items()}
    assert after == before


def test_listings_never_show_another_operators_records(client, records):
    for method, path in _v1_routes(client.app):
        if method != "GET" or "{" in path:
            continue
        r = client.get(path, headers=B)
        assert r.status_code == 200, (path, r.text)
        assert all(records[k] not in r.text for k in ("plan", "estimate", "station", "campaign", "job")), path
        if path in SHARED_LISTINGS:
            continue
        mine = client.get(path, headers=A).text
        own = {"/v1/stations": "station", "/v1/campaigns": "campaign", "/v1/jobs": "job"}.get(path, "plan")
        assert records[own] in mine or path == "/v1/estimates", path
    listed = client.get("/v1/estimates", headers=A).json()["data"]
    assert records["estimate"] in [e["id"] for e in listed]


def test_keys_are_stored_as_hmac_under_the_server_secret(client, settings):
    app = client.app
    with app.state.session_factory() as session:
        row, key = crud.create_api_key(session=session, secret=app.state.key_secret, operator_name="hmac", key_name="k")
        assert row.hash_scheme == "hmac-sha256"
        assert row.key_hash != hashlib.sha256(key.encode()).hexdigest()
        assert row.key_hash == key_digest(key, app.state.key_secret)
        assert key not in json.dumps([row.key_hash, row.prefix, row.name])
        assert crud.operator_for_key(session=session, secret=b"another secret" * 3, key=key) is None
    assert client.get("/v1/plans", headers={"X-API-Key": key}).status_code == 200


def test_legacy_sha256_keys_still_work_and_are_rewritten_as_hmac(client):
    app = client.app
    key = "gsa_legacy-key-from-before-migration-0003-xxxxxxx"
    with app.state.session_factory() as session:
        op = crud.get_or_create_operator(session=session, name="legacy")
        session.add(
            ApiKey(
                operator_id=op.id,
                name="old",
                prefix=key[:8],
                key_hash=key_digest(key, b"", LEGACY_SCHEME),
                hash_scheme=LEGACY_SCHEME,
            )
        )
        session.commit()
    assert client.get("/v1/plans", headers={"X-API-Key": key}).status_code == 200
    with app.state.session_factory() as session:
        row = session.scalar(select(ApiKey).where(ApiKey.name == "old"))
        assert row.hash_scheme == "hmac-sha256" and row.key_hash == key_digest(key, app.state.key_secret)
    assert client.get("/v1/plans", headers={"X-API-Key": key}).status_code == 200


def test_key_secret_is_made_once_private_and_refused_when_short(tmp_path):
    s1 = load_key_secret("", tmp_path)
    assert load_key_secret("", tmp_path) == s1 and len(s1) == 64
    assert (tmp_path / "key-secret").stat().st_mode & 0o077 == 0
    assert load_key_secret("configured-secret", tmp_path) == b"configured-secret"
    (tmp_path / "key-secret").write_text("short")
    with pytest.raises(ValueError, match="key-secret"):
        load_key_secret("", tmp_path)


def test_request_id_is_returned_echoed_and_in_error_bodies(client):
    r = client.get("/v1/plans", headers=A)
    assert re.fullmatch(r"[0-9a-f]{32}", r.headers["X-Request-ID"])
    r = client.get("/v1/plans", headers={**A, "X-Request-ID": "op-trace-42"})
    assert r.headers["X-Request-ID"] == "op-trace-42"
    r = client.get("/v1/plans", headers={**A, "X-Request-ID": "bad id with spaces"})
    assert re.fullmatch(r"[0-9a-f]{32}", r.headers["X-Request-ID"])
    r = client.get("/v1/plans", params={"limit": 0}, headers={**A, "X-Request-ID": "trace-7"})
    assert r.status_code == 422 and r.json()["request_id"] == "trace-7"
    r = client.get("/v1/plans/nope", headers={**A, "X-Request-ID": "trace-8"})
    assert r.status_code == 404 and r.json()["request_id"] == "trace-8"


def test_logs_are_json_lines_with_the_request_id_and_never_the_key(client, caplog):
    caplog.set_level(logging.INFO, logger="gsa.access")
    client.get("/v1/plans", headers={**A, "X-Request-ID": "log-check-1"})
    lines = [JsonFormatter().format(rec) for rec in caplog.records]
    access = [json.loads(line) for line in lines if "log-check-1" in line]
    assert access and access[-1]["path"] == "/v1/plans" and access[-1]["status"] == 200
    assert access[-1]["method"] == "GET" and access[-1]["duration_ms"] >= 0
    assert all(KEY_A not in line for line in lines)


def test_on_a_terminal_the_same_lines_are_readable_text(client, caplog, monkeypatch):
    caplog.set_level(logging.INFO, logger="gsa.access")
    client.get("/v1/plans", headers={**A, "X-Request-ID": "log-check-2"})
    (line,) = [TextFormatter().format(r) for r in caplog.records if "log-check-2" in JsonFormatter().format(r)]
    assert re.match(r"^\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}Z info +\S", line), line
    assert re.search(r" GET /v1/plans 200 [\d.]+ ms \(.*request_id=log-check-2", line), line
    assert KEY_A not in line and "\n" not in line
    # GSA_LOG_JSON unset: JSON unless stderr is a terminal; set, as set.
    monkeypatch.setattr("sys.stderr.isatty", lambda: True)
    assert json_lines_wanted(None) is False and json_lines_wanted(True) is True
    monkeypatch.setattr("sys.stderr.isatty", lambda: False)
    assert json_lines_wanted(None) is True and json_lines_wanted(False) is False


def test_a_bug_is_a_json_500_with_the_request_id(settings, caplog):
    from fastapi.testclient import TestClient

    from app.main import create_app

    app = create_app(settings)

    @app.get("/boom")
    def boom() -> None:
        raise RuntimeError("a bug")

    with TestClient(app, raise_server_exceptions=False) as c:
        r = c.get("/boom", headers={"X-Request-ID": "bug-1"})
    assert r.status_code == 500
    assert r.json()["request_id"] == "bug-1" and r.headers["X-Request-ID"] == "bug-1"
    assert any(rec.name == "gsa.errors" and rec.exc_info for rec in caplog.records)


def test_readyz_reports_database_schema_and_models(client, settings):
    r = client.get("/readyz")
    assert r.status_code == 200
    db = r.json()["database"]
    assert db["ok"] and db["revision"] == head_revision() and db["dialect"] in ("sqlite", "postgresql")
    assert r.json()["models"]["name"]


def test_readyz_is_503_on_an_unmigrated_database(settings, tmp_path):
    from fastapi.testclient import TestClient

    from app.main import create_app

    bare = settings.model_copy(update={"database_url": f"sqlite:///{tmp_path / 'empty.db'}", "data_dir": tmp_path})
    with TestClient(create_app(bare)) as c:
        r = c.get("/readyz")
    assert r.status_code == 503 and not r.json()["database"]["ok"]
    assert "gsa db upgrade" in r.json()["database"]["error"]


def test_database_answers_on_its_backend(settings, backend):
    engine = make_engine(settings.database_url)
    with make_session_factory(engine)() as session:
        assert session.execute(text("SELECT 1")).scalar() == 1
    assert engine.dialect.name == backend
    engine.dispose()
