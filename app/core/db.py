"""Engine and sessions. Tables are created by Alembic migrations only (``gsa db upgrade``)."""

from __future__ import annotations

import os
from functools import lru_cache
from pathlib import Path
from typing import Any

from sqlalchemy import Engine, create_engine, event
from sqlalchemy.orm import Session, sessionmaker


def _prepare_sqlite_file(url: str) -> None:
    """Create a SQLite database's folder (0700) and file (0600) before SQLite does (it would use the umask:
    a world-readable 0644); its -wal and -shm files take the file's mode.

    An existing file is left unopened: closing any descriptor of a file drops every POSIX lock this process holds
    on it, so opening and closing the database beside a live connection (a second engine in one process: a
    restart in the tests, ``gsa serve``'s own start-up session) took that connection's locks away, and another
    process's commits were lost under its stale pages."""
    from app.core.security import private_dir

    path = url.split("///", 1)[-1]
    if path and path != ":memory:" and not os.path.exists(path):
        private_dir(Path(path).parent)
        try:
            os.close(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))
        except FileExistsError:
            pass  # made meanwhile by another process


def make_engine(url: str) -> Engine:
    """Create an engine; SQLite gets WAL, foreign keys and a busy timeout on every connection."""
    if url.startswith("sqlite"):
        _prepare_sqlite_file(url)
        engine = create_engine(url, connect_args={"check_same_thread": False, "timeout": 30})

        @event.listens_for(engine, "connect")
        def _sqlite_pragmas(dbapi_conn: Any, _record: Any) -> None:
            cur = dbapi_conn.cursor()
            cur.execute("PRAGMA journal_mode=WAL")
            cur.execute("PRAGMA foreign_keys=ON")
            cur.execute("PRAGMA busy_timeout=30000")
            cur.execute("PRAGMA synchronous=NORMAL")
            cur.close()

        return engine
    return create_engine(url, pool_pre_ping=True)


def make_session_factory(engine: Engine) -> sessionmaker[Session]:
    return sessionmaker(bind=engine, expire_on_commit=False)


def migrations_dir() -> Path:
    """Return the folder of the Alembic migrations (beside the packages, or under the working directory)."""
    here = Path(__file__).resolve().parents[2] / "migrations"
    if (here / "env.py").exists():
        return here
    return Path.cwd() / "migrations"


def upgrade_database(url: str) -> None:
    """Apply every Alembic migration to the database at ``url``."""
    from alembic import command
    from alembic.config import Config

    if url.startswith("sqlite"):
        _prepare_sqlite_file(url)
    cfg = Config()
    cfg.set_main_option("script_location", str(migrations_dir()))
    cfg.set_main_option("sqlalchemy.url", url.replace("%", "%%"))
    command.upgrade(cfg, "head")


@lru_cache(maxsize=1)
def head_revision() -> str | None:
    """Return the newest Alembic revision shipped with the code."""
    from alembic.config import Config
    from alembic.script import ScriptDirectory

    cfg = Config()
    cfg.set_main_option("script_location", str(migrations_dir()))
    return ScriptDirectory.from_config(cfg).get_current_head()


def database_status(engine: Engine) -> dict[str, Any]:
    """Say whether the database answers and is migrated to the code's schema (never raises)."""
    from alembic.runtime.migration import MigrationContext
    from sqlalchemy import text
    from sqlalchemy.exc import SQLAlchemyError

    head = head_revision()
    try:
        with engine.connect() as conn:
            conn.execute(text("SELECT 1"))
            revision = MigrationContext.configure(conn).get_current_revision()
    except SQLAlchemyError as exc:
        return {
            "ok": False,
            "dialect": engine.dialect.name,
            "error": f"the database does not answer ({type(exc).__name__})",
            "head": head,
        }
    ok = revision == head
    out: dict[str, Any] = {"ok": ok, "dialect": engine.dialect.name, "revision": revision, "head": head}
    if not ok:
        out["error"] = "the database is not at the code's schema: run `gsa db upgrade`"
    return out
