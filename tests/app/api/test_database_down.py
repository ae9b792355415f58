"""PostgreSQL stops answering after the service started: every /v1 request is a 503 that says to retry, never a
500 "this is a bug"; once the database is back the service answers again by itself.

The outage is real: the server refuses new connections to the service's database and ends the open ones
(``ALLOW_CONNECTIONS false`` and ``pg_terminate_backend``), as a restart or a failover does.
"""

from __future__ import annotations

from urllib.parse import urlsplit

from fastapi.testclient import TestClient

from app.core.config import Settings
from app.core.db import upgrade_database
from app.main import create_app
from app.schemas import PAPER_EXAMPLE
from tests.conftest import KEY_A
from tests.utils.databases import postgres_server, postgres_url

A = {"X-API-Key": KEY_A}


def test_postgresql_down_after_start_is_a_503_and_the_service_recovers(tmp_path, pg_root, smoke_models):
    url = postgres_url(pg_root)
    name = urlsplit(url).path.lstrip("/")
    settings = Settings(data_dir=tmp_path, api_keys=KEY_A, model_dir=smoke_models, database_url=url)
    upgrade_database(url)
    srv = postgres_server(pg_root)
    with TestClient(create_app(settings)) as client:
        assert client.get("/v1/stations", headers=A).status_code == 200
        srv.psql(
            f"ALTER DATABASE {name} ALLOW_CONNECTIONS false; "
            f"SELECT pg_terminate_backend(pid) FROM pg_stat_activity WHERE datname = '{name}';"
        )
        try:
            for method, path, body in (
                ("GET", "/v1/stations", None),
                ("GET", "/v1/plans", None),
                ("POST", "/v1/plans", PAPER_EXAMPLE),
            ):
                r = client.request(method, path, headers=A, json=body)
                assert r.status_code == 503, (path, r.status_code, r.text)
                assert "database does not answer" in r.json()["detail"] and r.headers.get("Retry-After")
            assert client.get("/readyz").status_code == 503
        finally:
            srv.psql(f"ALTER DATABASE {name} ALLOW_CONNECTIONS true;")
        assert client.get("/v1/stations", headers=A).status_code == 200
        assert client.get("/readyz").status_code == 200
