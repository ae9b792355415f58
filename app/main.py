"""The FastAPI application factory: ``app.main:create_app``."""

from __future__ import annotations

from typing import Any

from fastapi import FastAPI, Request
from fastapi.responses import JSONResponse

from app.api.main import api_router
from app.core.config import Settings, get_settings
from app.core.db import make_engine, make_session_factory
from app.errors import install_error_handlers


def create_app(settings: Settings | None = None) -> FastAPI:
    """Build the service. The database must already be migrated (``gsa db upgrade``; ``gsa serve`` does it)."""
    settings = settings or get_settings()
    app = FastAPI(
        title="GSA-ISAR",
        version="0.1.0",
        description="Ground-and-space-access scene planning (Hou et al. 2023, Algorithm 1) and ISAR attitude estimation.",
    )
    engine = make_engine(settings.database_url)
    # The models load once, here: a missing or corrupt file stops the service, naming the file.
    from inference.runtime import Estimator

    app.state.estimator = Estimator.load(settings.model_dir, threads=settings.ort_threads or None)
    app.state.settings = settings
    app.state.engine = engine
    app.state.session_factory = make_session_factory(engine)
    install_error_handlers(app)

    @app.middleware("http")
    async def _limit_body(request: Request, call_next: Any) -> Any:
        length = request.headers.get("content-length")
        multipart = request.headers.get("content-type", "").startswith("multipart/")
        # Uploads are checked file by file against max_upload_bytes; this bounds a whole batch.
        limit = settings.max_upload_bytes * 8 if multipart else settings.max_request_bytes
        if length is not None and length.isdigit() and int(length) > limit:
            return JSONResponse(
                status_code=413, content={"detail": f"request body of {length} bytes is over the limit of {limit}"}
            )
        return await call_next(request)

    @app.get("/readyz", tags=["health"])
    def readyz() -> dict[str, Any]:
        """Say the database answers and which models are loaded."""
        from sqlalchemy import text

        with engine.connect() as conn:
            conn.execute(text("SELECT 1"))
        return {"status": "ready", "database": "ok", "models": app.state.estimator.identity}

    @app.get("/healthz", tags=["health"])
    def healthz() -> dict[str, str]:
        """Say the process is up."""
        return {"status": "ok"}

    app.include_router(api_router, prefix="/v1")
    return app
