"""Map errors to HTTP in one place: bad input is a 4xx that names the field, and every error body carries the request id."""

from __future__ import annotations

import re
from typing import Any

import sqlalchemy.exc
from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException

from app.core.observability import current_request_id, errors_log
from inference.errors import Cancelled, InferenceError
from planner.errors import PlannerError, PlanningStopped
from scene.errors import SceneError


class SafeJSONResponse(JSONResponse):
    """JSON as starlette writes it, or, where a text holds a lone surrogate that UTF-8 cannot encode, with every
    non-ASCII character escaped (valid JSON either way): an answer that echoes odd input is never a 500."""

    def render(self, content: Any) -> bytes:
        try:
            return super().render(content)
        except UnicodeEncodeError:
            import json

            return json.dumps(content, ensure_ascii=True, allow_nan=False, separators=(",", ":")).encode("ascii")


class InputError(ValueError):
    """A request that passed the schema but that the planner cannot use; ``loc`` is the JSON path."""

    def __init__(self, loc: list[str | int], message: str, where: str = "body") -> None:
        super().__init__(message)
        self.loc = loc
        self.message = message
        self.where = where


# Every domain's bad-input error: each names its field, and each is a 422 (or one line on the command line).
DOMAIN_ERRORS: tuple[type[ValueError], ...] = (InputError, SceneError, PlannerError, InferenceError)


def input_error(exc: ValueError) -> tuple[list[str | int], str]:
    """Return the field's path and the message of any domain error (``DOMAIN_ERRORS``): the one mapping.

    A request's own ``InputError`` and the scene's ``SceneError`` carry their path; the planner's
    and the estimator's errors name one field (the planner's default: ``request``).
    """
    if isinstance(exc, InputError | SceneError):
        return list(exc.loc), exc.message
    if isinstance(exc, PlannerError):
        return [exc.field or "request"], str(exc)
    if isinstance(exc, InferenceError):
        return ([exc.field] if exc.field else []), str(exc)
    return [], str(exc)


def _body(loc: list[Any], msg: str) -> dict[str, Any]:
    return {"detail": [{"loc": loc, "msg": msg, "type": "value_error"}], "request_id": current_request_id()}


def _safe(value: Any, depth: int = 0) -> Any:
    """Make a validation error's parts JSON-safe: bytes that are not UTF-8, odd objects, deep nests."""
    if isinstance(value, bytes):
        return value[:200].decode("utf-8", errors="replace")
    if isinstance(value, str):
        value = value.encode("utf-8", "backslashreplace").decode("utf-8")  # a lone surrogate as its escape
        return value if len(value) <= 200 else value[:200] + "..."
    if value is None or isinstance(value, bool | int):
        return value
    if isinstance(value, float):
        return value if value == value and abs(value) != float("inf") else str(value)
    if depth > 4:
        return str(value)[:200]
    if isinstance(value, dict):
        return {str(k): _safe(v, depth + 1) for k, v in list(value.items())[:50]}
    if isinstance(value, list | tuple):
        return [_safe(v, depth + 1) for v in list(value)[:50]]
    return str(value)[:200]


_UNION_TAG = re.compile(r"^[A-Z]\w*In$|^(str|int|float|bool)$|\[")


def _without_union_tags(loc: Any) -> list[Any]:
    """Drop pydantic's union-branch tags (``OmmIn``, ``list[...]``, ``str``) from an error's path: the JSON path stays."""
    return [p for p in loc if not (isinstance(p, str) and _UNION_TAG.search(p))]


def _without_null_branches(errors: list[Any]) -> list[Any]:
    """Drop "Input should be None" beside another error of the same field: an optional field's null branch.

    An optional field (``elements: ElementsIn | None``) that fails its own rules also fails the
    union's None branch; that second error ("Input should be None", at ``[..., "none"]``) only
    confuses, since the schema never offers null there.
    """

    def field(e: Any) -> tuple[Any, ...]:
        loc = tuple(e.get("loc", ()))
        return loc[:-1] if loc and loc[-1] == "none" else loc

    others = {field(e)[: len(field(e))] for e in errors if e.get("type") != "none_required"}
    kept = []
    for e in errors:
        if e.get("type") == "none_required" and any(o[: len(field(e))] == field(e) for o in others):
            continue
        kept.append(e)
    return kept or errors


def _allowed_methods(app: FastAPI, request: Request) -> list[str]:
    """Every method the OpenAPI document serves at this request's path (HEAD with GET, as Starlette does)."""
    import re

    methods: set[str] = set()
    for template, item in app.openapi().get("paths", {}).items():
        pattern = "^" + re.sub(r"\\{[^}]+\\}", "[^/]+", re.escape(template)) + "$"
        if re.match(pattern, request.url.path):
            methods |= {m.upper() for m in item}
    if "GET" in methods:
        methods.add("HEAD")
    return sorted(methods)


class Conflict(Exception):
    """A request the service's present state refuses (HTTP 409): ask again once that state has passed."""


# What SQLAlchemy raises when the database cannot be reached or holds no connection for us: 503, never 500.
DATABASE_DOWN: tuple[type[Exception], ...] = (
    sqlalchemy.exc.OperationalError,
    sqlalchemy.exc.InterfaceError,
    sqlalchemy.exc.TimeoutError,
)


class TooMany(Exception):
    """Over a per-operator count (HTTP 429), such as queued jobs: the message says what is used and allowed."""


class Forbidden(Exception):
    """A request the caller's key has no role for (HTTP 403): the message says which role and how to get it."""


class VersionUnusable(Exception):
    """A promoted model version's files cannot be loaded here (damaged, removed, or computing otherwise): HTTP 503,
    the server's fault, not the request's; promoting another version (or 0) mends it."""


class TooLarge(Exception):
    """A request over one of the service's size limits, found while reading it (HTTP 413): send less."""


def install_error_handlers(app: FastAPI) -> None:
    async def _domain_error(_request: Request, exc: Exception) -> JSONResponse:
        assert isinstance(exc, ValueError)
        loc, message = input_error(exc)
        return SafeJSONResponse(status_code=422, content=_body([getattr(exc, "where", "body"), *loc], message))

    for kind in DOMAIN_ERRORS:
        app.add_exception_handler(kind, _domain_error)

    @app.exception_handler(Conflict)
    async def _conflict(_request: Request, exc: Conflict) -> JSONResponse:
        return SafeJSONResponse(status_code=409, content={"detail": str(exc), "request_id": current_request_id()})

    async def _database_down(request: Request, exc: Exception) -> JSONResponse:
        # The database stopped answering after start (restarted, unreachable, out of connections): not a bug and
        # not the caller's input. The schema is checked again on the next request (deps.require_schema).
        request.app.state.schema_ok = False
        errors_log.warning("the database does not answer: %s: %s", type(exc).__name__, str(exc).splitlines()[0][:300])
        return SafeJSONResponse(
            status_code=503,
            content={
                "detail": "the database does not answer; retry shortly (the service recovers by itself once it is back)",
                "request_id": current_request_id(),
            },
            headers={"Retry-After": "5"},
        )

    for down in DATABASE_DOWN:
        app.add_exception_handler(down, _database_down)

    @app.exception_handler(Cancelled)
    async def _cancelled(_request: Request, exc: Cancelled) -> JSONResponse:
        # The client went away and its work was stopped; nobody reads this answer (499: nginx's "client closed").
        return SafeJSONResponse(
            status_code=499, content={"detail": f"the client went away: {exc}", "request_id": current_request_id()}
        )

    @app.exception_handler(TooLarge)
    async def _too_large(_request: Request, exc: TooLarge) -> JSONResponse:
        return SafeJSONResponse(status_code=413, content={"detail": str(exc), "request_id": current_request_id()})

    @app.exception_handler(TooMany)
    async def _too_many(_request: Request, exc: TooMany) -> JSONResponse:
        return SafeJSONResponse(
            status_code=429,
            content={"detail": str(exc), "request_id": current_request_id()},
            headers={"Retry-After": "30"},
        )

    @app.exception_handler(Forbidden)
    async def _forbidden(_request: Request, exc: Forbidden) -> JSONResponse:
        return SafeJSONResponse(status_code=403, content={"detail": str(exc), "request_id": current_request_id()})

    @app.exception_handler(VersionUnusable)
    async def _version_unusable(_request: Request, exc: VersionUnusable) -> JSONResponse:
        errors_log.error("%s", exc)
        return SafeJSONResponse(status_code=503, content={"detail": str(exc), "request_id": current_request_id()})

    @app.exception_handler(PlanningStopped)
    async def _planning_stopped(_request: Request, exc: PlanningStopped) -> JSONResponse:
        # Not the caller's input: the service's budget (GSA_PLAN_TIMEOUT_S). Retry later or plan less.
        return SafeJSONResponse(status_code=503, content={"detail": str(exc), "request_id": current_request_id()})

    @app.exception_handler(RequestValidationError)
    async def _validation_error(_request: Request, exc: RequestValidationError) -> JSONResponse:
        errors = [
            {
                "loc": _safe(_without_union_tags(e.get("loc", ()))),
                "msg": _safe(e.get("msg", "")),
                "type": _safe(e.get("type", "")),
                **({"input": _safe(e["input"])} if "input" in e else {}),
            }
            for e in _without_null_branches(list(exc.errors()))
        ]
        return SafeJSONResponse(status_code=422, content={"detail": errors, "request_id": current_request_id()})

    @app.exception_handler(StarletteHTTPException)
    async def _http_error(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        headers = getattr(exc, "headers", None)
        if exc.status_code == 405:
            # Starlette names only the first matching route's methods; a path served by two
            # routes (GET and POST /v1/plans) must list both.
            allowed = _allowed_methods(app, request)
            if allowed:
                headers = {**(headers or {}), "Allow": ", ".join(allowed)}
        return JSONResponse(
            status_code=exc.status_code,
            content={"detail": exc.detail, "request_id": current_request_id()},
            headers=headers,
        )
