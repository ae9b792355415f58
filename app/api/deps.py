"""Request dependencies: the database session, the settings, the calling operator, and the upload helpers."""

from __future__ import annotations

import asyncio
import contextlib
import math
import threading
import time
from collections.abc import AsyncIterator, Callable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Annotated, Any, Literal, TypeVar, cast

from fastapi import Depends, HTTPException, Query, Request, Security, UploadFile
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse
from fastapi.security import APIKeyHeader
from sqlalchemy.orm import Session

from app import crud
from app.core.config import Settings
from app.core.observability import resident_mb
from app.core.security import AuthThrottle, digests_equal, key_fingerprint
from app.db.models import Operator
from app.errors import InputError
from app.schemas import CONTROL_CHARACTERS, utc_or_none
from inference.runtime import Estimator, ModelSets
from planner.plan import StopCheck

if TYPE_CHECKING:  # the fit's module imports the simulator's geometry: kept out of `gsa --help`
    from inference.trust import Checker, Checkers

CcsdsFormat = Annotated[
    Literal["kvn", "xml"], Query(description="kvn (502.0-B-3's KEYWORD = value text) or xml (the NDM/XML schema)")
]
"""A CCSDS export's form: the ``format`` query parameter of the OPM and OEM exports."""

api_key_header = APIKeyHeader(name="X-API-Key", auto_error=False, description="an operator's API key")


def get_db(request: Request) -> Iterator[Session]:
    with request.app.state.session_factory() as session:
        yield session


def get_settings_dep(request: Request) -> Settings:
    settings: Settings = request.app.state.settings
    return settings


def require_schema(request: Request) -> None:
    """Answer 503 on every /v1 route while the database is not at the code's schema (before authentication,
    which reads the database). Once the schema is right it is not checked again in this process."""
    if getattr(request.app.state, "schema_ok", False):
        return
    from app.core.db import database_status

    status = database_status(request.app.state.engine)
    if not status["ok"]:
        error = status.get("error", "the database does not answer")
        raise HTTPException(
            status_code=503,
            detail=error
            + (
                ""
                if "upgrade" in error
                else "; retry shortly, and if it stays so check GSA_DATABASE_URL and the server"
            ),
            headers={"Retry-After": "5"},
        )
    request.app.state.schema_ok = True


SessionDep = Annotated[Session, Depends(get_db)]
SettingsDep = Annotated[Settings, Depends(get_settings_dep)]


def get_current_operator(
    request: Request, session: SessionDep, settings: SettingsDep, key: Annotated[str | None, Security(api_key_header)]
) -> Operator:
    """Return the operator whose key made the request; 401 without a valid, unrevoked key; 429 from an address
    that sent too many wrong keys lately (GSA_AUTH_FAILURES_PER_MINUTE)."""
    if not key:
        raise HTTPException(status_code=401, detail="missing API key: send it in the X-API-Key header")
    throttle: AuthThrottle | None = getattr(request.app.state, "auth_throttle", None)
    client = request.client.host if request.client is not None else "unknown"
    if throttle is not None and (wait := throttle.wait_s(client)) > 0:
        raise HTTPException(
            status_code=429,
            detail=f"too many wrong API keys from this address (GSA_AUTH_FAILURES_PER_MINUTE); retry in {wait:.0f} s",
            headers={"Retry-After": str(max(1, math.ceil(wait)))},
        )
    stored = crud.key_for(session=session, secret=request.app.state.key_secret, key=key)
    op = None if stored is None else session.get(Operator, stored.operator_id)
    role = "operator" if stored is None else stored.role
    matches = [digests_equal(key, k) for k in settings.env_api_keys]  # every one compared: constant time
    if op is None and any(matches):
        # Keys from GSA_API_KEYS and GSA_ADMIN_API_KEYS: each is its own operator, created on first use.
        op = crud.get_or_create_operator(session=session, name=f"env-{key_fingerprint(key)}")
        session.commit()
        admins = [digests_equal(key, k) for k in settings.env_admin_keys]
        role = "admin" if any(admins) else "operator"
    if op is None:
        if throttle is not None:
            throttle.failed(client)
        raise HTTPException(status_code=401, detail="invalid or revoked API key")
    request.state.role = role  # the key's role, for the routes that need an admin (is_admin)
    return op


CurrentOperator = Annotated[Operator, Depends(get_current_operator)]


def is_admin(request: Request) -> bool:
    """Whether the request's key has the admin role (after ``get_current_operator`` has run)."""
    return getattr(request.state, "role", "operator") == "admin"


def get_model_sets(request: Request) -> ModelSets:
    """The model sets loaded at start-up, one per target they were trained on (``inference.runtime.ModelSets``)."""
    return cast(ModelSets, request.app.state.model_sets)


ModelSetsDep = Annotated[ModelSets, Depends(get_model_sets)]


def models_for(model_sets: ModelSets, checker: Checker) -> Estimator:
    """The networks for the checker's target: its own model set, or the default set's (version 0)."""
    return model_sets.for_target(checker.model.name)


def answering(
    request: Request, session: Session, model_sets: ModelSets, checkers: Any, target: str | None, operator: Operator
) -> Any:
    """(Estimator, Checker) that answer ``target`` for ``operator`` now: the networks and calibration of the version
    promoted for it, or of the shared default (``app.services.model_versions``), else the configured set's."""
    checker = checker_for(checkers, target)
    return request.app.state.served.resolve(session, model_sets, checker, operator.id)


def get_checkers(request: Request) -> Checkers:
    """The targets the fit knows (``inference.trust.Checkers``), loaded at start-up."""
    return cast("Checkers", request.app.state.checkers)


# Any at run time: FastAPI reads this annotation when the app is built, and inference.trust loads numba's compiled
# renderer, which `gsa --help` and `import app.main` must not pay for (tests/test_layout.py).
CheckersDep = Annotated[Any, Depends(get_checkers)]


as_utc = utc_or_none  # the routes' name for it


DEFAULT_PAGE_SIZE = 20


@dataclass(frozen=True)
class Page:
    """One page of a listing: how many (checked against GSA_MAX_PAGE_SIZE) and how many to skip."""

    limit: int
    offset: int


def page_of(
    settings: SettingsDep,
    limit: Annotated[int | None, Query(ge=1, le=10_000, description="page size (default 20)")] = None,
    offset: Annotated[int, Query(ge=0, le=10_000_000, description="how many to skip, newest first")] = 0,
) -> Page:
    """The page every listing route takes (``limit``, ``offset``)."""
    return Page(check_page_size(limit, settings), offset)


PageDep = Annotated[Page, Depends(page_of)]


def check_page_size(limit: int | None, settings: Settings) -> int:
    """Return the page size: 20 (or the limit, if smaller) when not given; refuse one over ``GSA_MAX_PAGE_SIZE``."""
    if limit is None:
        return min(DEFAULT_PAGE_SIZE, settings.max_page_size)
    if limit > settings.max_page_size:
        raise InputError(
            ["limit"],
            f"limit {limit} is over the page size limit {settings.max_page_size} (GSA_MAX_PAGE_SIZE)",
            where="query",
        )
    return limit


def check_span(days: float, settings: Settings, loc: list[str | int]) -> None:
    """Refuse a planning span longer than the operator's ``GSA_MAX_SPAN_DAYS``."""
    if days > settings.max_span_days:
        raise InputError(
            loc, f"{days} days is over the span limit of {settings.max_span_days} days (GSA_MAX_SPAN_DAYS)"
        )


async def read_upload(upload: UploadFile, limit: int) -> bytes:
    if CONTROL_CHARACTERS.search(upload.filename or ""):
        raise InputError(["file"], "the file name must not contain control characters (NUL, tab, newline, ...)")
    data = await upload.read(limit + 1)
    if len(data) > limit:
        raise HTTPException(
            status_code=413, detail=f"file {upload.filename!r} is over the upload limit of {limit} bytes"
        )
    return data


def check_file_count(files: list[UploadFile], settings: Settings) -> None:
    """Refuse a request of more files than it may hold frames, before any file is read (each holds one or more)."""
    if len(files) > settings.max_batch_frames:
        raise InputError(
            ["files"],
            f"{len(files)} files is over the limit of {settings.max_batch_frames} frames a request "
            "(GSA_MAX_BATCH_FRAMES); send the rest in another request",
        )


async def read_uploads(files: list[UploadFile], settings: Settings) -> list[Any]:
    """Read and decode every uploaded file (stacks allowed) into frames, each file checked against the limits.

    The count of files, and each file's frames and decoded size from its header, are checked against the request's
    budget (GSA_MAX_BATCH_FRAMES, GSA_MAX_DECODED_MB) before its pixels are decoded.
    """
    from fastapi.concurrency import run_in_threadpool

    from app.services.uploads import DecodeBudget, charge_headers, decode

    check_file_count(files, settings)
    budget = DecodeBudget.of(settings)
    read = []
    for f in files:  # every file's headers against the request's budget before any file is decoded
        data = await read_upload(f, settings.max_upload_bytes)
        charge_headers(data, f.filename or "upload", budget, settings.max_image_side)
        read.append((f.filename or "upload", data))
    uploads: list[Any] = []
    again = DecodeBudget.of(settings)  # what decoding finds is charged too (a header the pre-pass could not read)
    for name, data in read:
        uploads += await run_in_threadpool(decode, data, name, max_side=settings.max_image_side, budget=again)
    return uploads


def queued(request: Request, job: Any, prefer_applied: bool = False) -> JSONResponse:
    """The 202 of work queued as a job: the job as ``GET /v1/jobs/{id}`` shows it, its address in ``Location``;
    the dispatcher is told there is work."""
    from app.schemas import JobPublic

    request.app.state.jobs.nudge()
    headers = {"Location": f"/v1/jobs/{job.id}"}
    if prefer_applied:
        headers["Preference-Applied"] = "respond-async"
    return JSONResponse(status_code=202, content=JobPublic.from_row(job).model_dump(mode="json"), headers=headers)


def wants_job(request: Request) -> bool:
    """The client asked for the work to be queued (``Prefer: respond-async``, RFC 7240)."""
    return "respond-async" in request.headers.get("prefer", "").lower()


def job_limits(settings: Settings) -> Settings:
    """The upload limits of a pass queued as a job: GSA_MAX_PASS_JOB_FRAMES frames, and the decoded budget grown
    with them (at most 4 GiB)."""
    scale = max(1, -(-settings.max_pass_job_frames // settings.max_batch_frames))
    return settings.model_copy(
        update={
            "max_batch_frames": settings.max_pass_job_frames,
            "max_decoded_mb": min(settings.max_decoded_mb * scale, 4096),
        }
    )


def cells_from_form(range_cell_m: float | None, cross_range_cell_m: float | None) -> tuple[float, float] | None:
    if (range_cell_m is None) != (cross_range_cell_m is None):
        missing = "cross_range_cell_m" if cross_range_cell_m is None else "range_cell_m"
        raise InputError([missing], "send range_cell_m and cross_range_cell_m together (the frame's cells in metres)")
    return None if range_cell_m is None or cross_range_cell_m is None else (range_cell_m, cross_range_cell_m)


def checker_for(checkers: Any, target: str | None) -> Any:
    from inference.errors import ModelFileError

    try:
        return checkers.get(target or checkers.default)
    except ModelFileError as exc:
        raise InputError(["target"], str(exc)) from None


def planning_budget(
    settings: Settings, gone: threading.Event | None = None, timeout_s: float | None = None, name: str = "PLAN"
) -> StopCheck:
    """A plan's stop check: the caller gone, or over its time (GSA_PLAN_TIMEOUT_S; a campaign's
    GSA_CAMPAIGN_TIMEOUT_S) or memory (GSA_PLAN_MEMORY_MB) budget.

    Creating a plan and recomputing one for an export are the same work, under the same budget.
    """
    limit_s = settings.plan_timeout_s if timeout_s is None else timeout_s
    deadline = time.monotonic() + limit_s
    memory_limit = resident_mb() + settings.plan_memory_mb

    def stop() -> str | None:
        if gone is not None and gone.is_set():
            return "the client disconnected"
        if time.monotonic() > deadline:
            return f"over the {limit_s:g}-s budget (GSA_{name}_TIMEOUT_S); plan a shorter span or a coarser box"
        if resident_mb() > memory_limit:
            return (
                f"over the {settings.plan_memory_mb:g}-MB memory budget (GSA_PLAN_MEMORY_MB); plan a shorter span "
                "or a coarser box"
            )
        return None

    return stop


def observe_work(request: Request, kind: str, started: float, frames: int = 0) -> None:
    """Count a stored piece of work in the app's metrics (``/metrics``): its time since ``started`` (a
    ``time.perf_counter()`` reading) and, for estimates and passes, its frames."""
    metrics = getattr(request.app.state, "metrics", None)
    if metrics is None:
        return
    metrics.work.labels(kind).observe(time.perf_counter() - started)
    if frames:
        metrics.frames.inc(frames)


T = TypeVar("T")


async def plan_in_worker(
    request: Request,
    kind: str,
    work: Callable[..., T],
    settings: Settings,
    timeout_s: float | None = None,
    budget_name: str = "PLAN",
    **kwargs: Any,
) -> T:
    """Run planning ``work(settings=..., stop=..., **kwargs)`` in a worker thread under its budget (``planning_budget``), stopped
    when the caller disconnects, and count it in the metrics as ``kind``: what a plan and a campaign route share."""
    started = time.perf_counter()
    async with client_watch(request) as gone:
        stop = planning_budget(settings, gone, timeout_s, budget_name)
        result = await run_in_threadpool(work, settings=settings, stop=stop, **kwargs)
    observe_work(request, kind, started)
    return result


@contextlib.asynccontextmanager
async def client_watch(request: Request, every_s: float = 0.2) -> AsyncIterator[threading.Event]:
    """An event set once the client has gone (polled every ``every_s``), for work in a worker thread to stop on:
    a plan's budget, a batch's or a pass's fit between frames (``inference.errors.Cancelled``)."""
    gone = threading.Event()

    async def watch() -> None:
        while not gone.is_set():
            if await request.is_disconnected():
                gone.set()
            await asyncio.sleep(every_s)

    watcher = asyncio.create_task(watch())
    try:
        yield gone
    finally:
        watcher.cancel()
