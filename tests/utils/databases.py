"""Fresh databases for tests: a SQLite file, or a new database on a real PostgreSQL server.

PostgreSQL comes from the ``pgserver`` wheel (PostgreSQL 16 binaries), started once
per test session in a temporary folder and stopped when the session ends: a real
server, never a mock.
"""

from __future__ import annotations

import uuid
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

_server: Any = None


def postgres_server(root: Path) -> Any:
    """Start (once) and return the session's PostgreSQL server."""
    global _server
    if _server is None:
        import pgserver

        _server = pgserver.get_server(root, cleanup_mode="stop")
    return _server


def postgres_url(root: Path) -> str:
    """Create an empty database on the session's server; return its SQLAlchemy URL (psycopg 3 driver)."""
    srv = postgres_server(root)
    name = "gsa_" + uuid.uuid4().hex[:12]
    srv.psql(f"CREATE DATABASE {name};")
    uri = urlsplit(srv.get_uri())
    return f"postgresql+psycopg://postgres:@/{name}?{uri.query}"


def database_url(kind: str, data_dir: Path, pg_root: Path) -> str:
    if kind == "sqlite":
        return f"sqlite:///{(data_dir / 'gsa.db').as_posix()}"
    if kind == "postgresql":
        return postgres_url(pg_root)
    raise ValueError(kind)


def store_campaign_row(
    url: str, *, campaign_id: str, operator_id: str, windows: list[dict[str, Any]], scenes: list[dict[str, Any]]
) -> None:
    """A campaign row of the paper's target, observer and station with these access windows and scenes, written
    straight to the database: it stands in for one the campaign planner flew where only its geometry matters."""
    from datetime import UTC, datetime

    from sqlalchemy import create_engine

    from app.db.models import Campaign
    from app.schemas import PAPER_EXAMPLE

    engine = create_engine(url)
    with engine.begin() as conn:
        conn.execute(
            Campaign.__table__.insert().values(
                id=campaign_id,
                operator_id=operator_id,
                created_at=datetime.now(UTC),
                target_name=PAPER_EXAMPLE["target"]["name"],
                observer_name=PAPER_EXAMPLE["observer"]["name"],
                station_name=PAPER_EXAMPLE["ground_station"]["name"],
                scenes=len(scenes),
                dv_total_m_s=0.0,
                first_access=None,
                request={k: PAPER_EXAMPLE[k] for k in ("target", "observer", "ground_station")},
                result={"access_windows": windows, "scenes": scenes},
            )
        )
    engine.dispose()
