"""Alembic migrations upgrade and downgrade cleanly on SQLite and on a real PostgreSQL server."""

from __future__ import annotations

import hashlib
import json

import pytest
from alembic import command
from alembic.config import Config
from sqlalchemy import create_engine, inspect, text

from app.core.db import head_revision, migrations_dir
from tests.utils.databases import database_url


@pytest.fixture
def url(backend, tmp_path, pg_root):
    return database_url(backend, tmp_path, pg_root)


def _cfg(url: str) -> Config:
    cfg = Config()
    cfg.set_main_option("script_location", str(migrations_dir()))
    cfg.set_main_option("sqlalchemy.url", url.replace("%", "%%"))
    return cfg


def _tables(url: str) -> set[str]:
    engine = create_engine(url)
    names = set(inspect(engine).get_table_names())
    engine.dispose()
    return names - {"alembic_version"}


def test_upgrade_downgrade_upgrade(url):
    cfg = _cfg(url)
    command.upgrade(cfg, "head")
    assert _tables(url) == {
        "operators",
        "api_keys",
        "plans",
        "estimates",
        "passes",
        "stations",
        "campaigns",
        "labelled_frames",
        "model_versions",
        "jobs",
        "plan_exports",
        "model_promotions",
    }
    command.downgrade(cfg, "base")
    assert _tables(url) == set()
    command.upgrade(cfg, "head")
    assert _tables(url) == {
        "operators",
        "api_keys",
        "plans",
        "estimates",
        "passes",
        "stations",
        "campaigns",
        "labelled_frames",
        "model_versions",
        "jobs",
        "plan_exports",
        "model_promotions",
    }
    engine = create_engine(url)
    with engine.connect() as conn:
        assert conn.execute(text("SELECT version_num FROM alembic_version")).scalar() == head_revision()
        cols = {c["name"] for c in inspect(conn).get_columns("api_keys")}
    engine.dispose()
    assert "hash_scheme" in cols


def test_keys_from_before_0003_keep_working_and_hmac_keys_are_revoked_on_downgrade(url):
    cfg = _cfg(url)
    command.upgrade(cfg, "0002")
    engine = create_engine(url)
    legacy = hashlib.sha256(b"gsa_old-key").hexdigest()
    with engine.begin() as conn:
        conn.execute(text("INSERT INTO operators (id, name, created_at) VALUES ('op1', 'old', CURRENT_TIMESTAMP)"))
        conn.execute(
            text(
                "INSERT INTO api_keys (id, operator_id, name, prefix, key_hash, created_at) "
                "VALUES ('k1', 'op1', 'old', 'gsa_old-', :h, CURRENT_TIMESTAMP)"
            ),
            {"h": legacy},
        )
    command.upgrade(cfg, "head")
    with engine.begin() as conn:
        assert conn.execute(text("SELECT hash_scheme, key_hash FROM api_keys WHERE id = 'k1'")).one() == (
            "sha256",
            legacy,
        )
        conn.execute(
            text(
                "INSERT INTO api_keys (id, operator_id, name, prefix, key_hash, hash_scheme, created_at) "
                "VALUES ('k2', 'op1', 'new', 'gsa_new-', 'ab', 'hmac-sha256', CURRENT_TIMESTAMP)"
            )
        )
    command.downgrade(cfg, "0002")
    with engine.connect() as conn:
        rows = dict(conn.execute(text("SELECT id, revoked_at IS NOT NULL FROM api_keys")).all())
    engine.dispose()
    assert rows == {"k1": False, "k2": True}


def test_lookalike_stations_from_before_0009_are_kept_and_the_first_keeps_the_name(url):
    """Before 0009 "GS" and "gs " could both be stored; after it the older owns the name key (found by any
    spelling), the younger stays stored under a key of its own, and new lookalikes are refused by the database."""
    cfg = _cfg(url)
    command.upgrade(cfg, "0008")
    engine = create_engine(url)
    with engine.begin() as conn:
        conn.execute(text("INSERT INTO operators (id, name, created_at) VALUES ('op1', 'old', CURRENT_TIMESTAMP)"))
        for sid, name, t in (("s1", "GS", "2026-01-01"), ("s2", "gs ", "2026-01-02"), ("s3", "Other", "2026-01-03")):
            conn.execute(
                text(
                    "INSERT INTO stations (id, operator_id, name, created_at, station) VALUES (:i, 'op1', :n, :t, '{}')"
                ),
                {"i": sid, "n": name, "t": t},
            )
    command.upgrade(cfg, "head")
    with engine.begin() as conn:
        keys = dict(conn.execute(text("SELECT id, name_key FROM stations")).all())
    assert keys == {"s1": "gs", "s2": "gs#s2", "s3": "other"}
    with pytest.raises(Exception, match="(?i)unique|duplicate"), engine.begin() as conn:
        conn.execute(
            text(
                "INSERT INTO stations (id, operator_id, name, name_key, created_at, station) "
                "VALUES ('s4', 'op1', 'GS2', 'gs', CURRENT_TIMESTAMP, '{}')"
            )
        )
    command.downgrade(cfg, "0008")
    command.upgrade(cfg, "head")
    engine.dispose()


def test_adaptations_from_before_0011_become_jobs_and_come_back_on_downgrade(url):
    """0011 moves each adaptation into ``jobs`` (kind adaptation, its target, options and version kept) and makes
    the database refuse a second active job of one key; a downgrade puts them back."""
    cfg = _cfg(url)
    command.upgrade(cfg, "0010")
    engine = create_engine(url)
    with engine.begin() as conn:
        conn.execute(text("INSERT INTO operators (id, name, created_at) VALUES ('op1', 'old', CURRENT_TIMESTAMP)"))
        conn.execute(
            text(
                "INSERT INTO adaptations (id, operator_id, created_at, finished_at, target, state, stage, progress, "
                "log, options, frames, version, error, runner) VALUES ('a1', 'op1', CURRENT_TIMESTAMP, "
                "CURRENT_TIMESTAMP, 'tiangong-like', 'done', 'done', 1.0, 'adapt: done', '{\"epochs\": 3}', 24, 2, "
                "NULL, 'h:1')"
            )
        )
    command.upgrade(cfg, "head")
    with engine.begin() as conn:
        row = conn.execute(text("SELECT kind, key, state, params, result FROM jobs WHERE id = 'a1'")).one()
    params = row.params if isinstance(row.params, dict) else json.loads(row.params)
    result = row.result if isinstance(row.result, dict) else json.loads(row.result)
    assert (row.kind, row.key, row.state) == ("adaptation", "adaptation:tiangong-like", "done")
    assert params == {"target": "tiangong-like", "options": {"epochs": 3}, "frames": 24} and result == {"version": 2}
    insert = text(
        "INSERT INTO jobs (id, operator_id, kind, key, state, stage, progress, done, total, created_at, params, log, "
        "runner, engine, attempts, cancel_requested) VALUES (:i, 'op1', 'adaptation', 'adaptation:x', :s, '', 0, 0, "
        "0, CURRENT_TIMESTAMP, '{}', '', '', 'local', 0, false)"
    )
    with engine.begin() as conn:
        conn.execute(insert, {"i": "j1", "s": "running"})
        conn.execute(insert, {"i": "j2", "s": "done"})  # an ended job of the same key is no obstacle
    with pytest.raises(Exception, match="(?i)unique|duplicate"), engine.begin() as conn:
        conn.execute(insert, {"i": "j3", "s": "queued"})
    command.downgrade(cfg, "0010")
    with engine.begin() as conn:
        back = conn.execute(text("SELECT target, version, frames FROM adaptations WHERE id = 'a1'")).one()
    assert tuple(back) == ("tiangong-like", 2, 24)
    command.upgrade(cfg, "head")
    engine.dispose()


def test_the_version_promoted_before_0013_becomes_the_shared_default_and_comes_back_on_downgrade(url):
    """Before 0013 one promoted version answered every operator: after it, that version is the shared default (so
    every operator is answered as before), keys gain the operator role, and a downgrade puts the flag back."""
    cfg = _cfg(url)
    command.upgrade(cfg, "0012")
    engine = create_engine(url)
    insert = text(
        "INSERT INTO model_versions (id, target, version, created_at, operator_id, base_version, dir, summary, "
        "promoted) VALUES (:i, 'tiangong-like', :v, CURRENT_TIMESTAMP, NULL, 0, :d, '{}', :p)"
    )
    with engine.begin() as conn:
        conn.execute(text("INSERT INTO operators (id, name, created_at) VALUES ('op1', 'old', CURRENT_TIMESTAMP)"))
        conn.execute(
            text(
                "INSERT INTO api_keys (id, operator_id, name, prefix, key_hash, hash_scheme, created_at) VALUES "
                "('k1', 'op1', 'k', 'gsa_abcd', :h, 'hmac-sha256', CURRENT_TIMESTAMP)"
            ),
            {"h": "0" * 64},
        )
        conn.execute(insert, {"i": "m1", "v": 1, "d": "model-sets/tiangong-like/v1", "p": False})
        conn.execute(insert, {"i": "m2", "v": 2, "d": "model-sets/tiangong-like/v2", "p": True})
    command.upgrade(cfg, "head")
    with engine.begin() as conn:
        rows = conn.execute(text("SELECT scope, target, version FROM model_promotions")).all()
        role = conn.execute(text("SELECT role FROM api_keys WHERE id = 'k1'")).scalar()
    assert [tuple(r) for r in rows] == [("shared", "tiangong-like", 2)] and role == "operator"
    command.downgrade(cfg, "0012")
    with engine.begin() as conn:
        flags = conn.execute(text("SELECT version, promoted FROM model_versions ORDER BY version")).all()
    assert [(v, bool(p)) for v, p in flags] == [(1, False), (2, True)]
    command.upgrade(cfg, "head")
    engine.dispose()


def test_an_unmigrated_database_answers_503_naming_the_fix(url, tmp_path, smoke_models):
    """Every /v1 route answers 503 "run gsa db upgrade" (not 500) until the schema is there, key or no key."""
    from fastapi.testclient import TestClient

    from app.core.config import Settings
    from app.core.db import upgrade_database
    from app.main import create_app

    settings = Settings(
        data_dir=tmp_path / "data", api_keys="k-unmigrated-0123456", model_dir=smoke_models, database_url=url
    )
    with TestClient(create_app(settings)) as client:
        for method, path in [
            ("GET", "/v1/plans"),
            ("GET", "/v1/estimates"),
            ("POST", "/v1/plans"),
            ("GET", "/v1/scenes"),
        ]:
            for headers in ({"X-API-Key": "k-unmigrated-0123456"}, {}):
                r = client.request(method, path, headers=headers)
                assert r.status_code == 503, (path, r.text)
                assert "gsa db upgrade" in r.text
        assert client.get("/readyz").status_code == 503
        assert client.get("/healthz").status_code == 200
        upgrade_database(url)
        assert client.get("/v1/plans", headers={"X-API-Key": "k-unmigrated-0123456"}).status_code == 200
