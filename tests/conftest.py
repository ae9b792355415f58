"""Shared fixtures: a migrated SQLite database in a temporary data directory and two operators' keys."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from app.core.config import Settings
from app.core.db import upgrade_database
from app.main import create_app

KEY_A = "test-key-operator-a"
KEY_B = "test-key-operator-b"


@pytest.fixture(scope="session")
def smoke_models(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from tests.utils.models import make_smoke_models

    return make_smoke_models(tmp_path_factory.mktemp("smoke"))


@pytest.fixture(scope="session")
def pg_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Where the session's PostgreSQL server keeps its data (started on first use)."""
    return tmp_path_factory.mktemp("pg")


@pytest.fixture(scope="module", params=["sqlite", "postgresql"])
def backend(request: pytest.FixtureRequest) -> str:
    """Every database-backed test module runs once on SQLite and once on a real PostgreSQL server; a test whose
    subject is not the database is marked ``@SQLITE_ONLY`` and runs once, on the module's SQLite client."""
    return str(request.param)


# A database-backed test whose subject is not the database (numerics, memory, start-up): once, on SQLite.
SQLITE_ONLY = pytest.mark.parametrize("backend", ["sqlite"], indirect=True, scope="module")


@pytest.fixture(scope="module")
def settings(tmp_path_factory: pytest.TempPathFactory, smoke_models: Path, backend: str, pg_root: Path) -> Settings:
    from tests.utils.databases import database_url

    data: Path = tmp_path_factory.mktemp("data")
    s = Settings(
        data_dir=data,
        api_keys=f"{KEY_A},{KEY_B}",
        model_dir=smoke_models,
        database_url=database_url(backend, data, pg_root),
    )
    upgrade_database(s.database_url)
    return s


@pytest.fixture(scope="module")
def client(settings: Settings) -> Iterator[TestClient]:
    with TestClient(create_app(settings)) as c:
        yield c
