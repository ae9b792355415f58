"""Request ids, JSON-lines logs and the outermost safety net of the service.

Every request gets an id (the caller's ``X-Request-ID`` when it is a short token,
else a fresh one). It is returned in the ``X-Request-ID`` header, carried by every
error body and by every log line written while the request runs. One access line
per request is logged as JSON: method, path, status, duration, request id; never
headers, so API keys are never logged.
"""

from __future__ import annotations

import json
import logging
import math
import os
import re
import sys
import threading
import time
import traceback
import uuid
from contextvars import ContextVar
from datetime import UTC, datetime
from typing import Any

from starlette.datastructures import MutableHeaders
from starlette.exceptions import HTTPException
from starlette.types import ASGIApp, Message, Receive, Scope, Send

REQUEST_ID_HEADER = "X-Request-ID"
_REQUEST_ID_RE = re.compile(r"^[A-Za-z0-9._:-]{1,64}$")
request_id_var: ContextVar[str | None] = ContextVar("request_id", default=None)

log = logging.getLogger("gsa.access")
errors_log = logging.getLogger("gsa.errors")


def current_request_id() -> str | None:
    return request_id_var.get()


def request_id_from(header: str | None) -> str:
    """Return the caller's request id when it is a short safe token, else a new one."""
    if header and _REQUEST_ID_RE.match(header):
        return header
    return uuid.uuid4().hex


class JsonFormatter(logging.Formatter):
    """One JSON object per line: time, level, logger, message, request id and any ``extra`` fields."""

    _SKIP = frozenset(vars(logging.makeLogRecord({})).keys()) | {"message", "asctime", "color_message"}

    def format(self, record: logging.LogRecord) -> str:
        return json.dumps(self.fields(record), default=str)

    def fields(self, record: logging.LogRecord) -> dict[str, Any]:
        """The record as the JSON line holds it."""
        out: dict[str, Any] = {
            "ts": datetime.fromtimestamp(record.created, UTC).isoformat(timespec="milliseconds"),
            "level": record.levelname.lower(),
            "logger": record.name,
            "msg": record.getMessage(),
        }
        rid = current_request_id()
        if rid is not None:
            out["request_id"] = rid
        for key, value in vars(record).items():
            if key not in self._SKIP and not key.startswith("_"):
                out[key] = value
        if record.exc_info:
            out["exc"] = "".join(traceback.format_exception(*record.exc_info)).rstrip()
        return out


class TextFormatter(JsonFormatter):
    """One readable line per record for a terminal: UTC time, level, message, then the ``extra`` fields.

    ``2026-12-01T18:00:01.123Z info    POST /v1/plans 201 812.4 ms (request_id=9f2c...)``
    """

    def format(self, record: logging.LogRecord) -> str:
        line = self.fields(record)
        ts = line.pop("ts").replace("+00:00", "Z")
        level, msg, exc = line.pop("level"), line.pop("msg"), line.pop("exc", None)
        line.pop("logger", None)
        if {"method", "path", "status"} <= line.keys():  # an access line reads as the request it was
            msg = f"{line.pop('method')} {line.pop('path')} {line.pop('status')}"
            if "duration_ms" in line:
                msg += f" {float(line.pop('duration_ms')):.1f} ms"
        extra = " ".join(f"{k}={v}" for k, v in line.items())
        out = f"{ts} {level:<7} {msg}" + (f" ({extra})" if extra else "")
        return out + ("\n" + exc if exc else "")


def json_lines_wanted(setting: bool | None) -> bool:
    """GSA_LOG_JSON: true or false as set; unset, JSON lines unless stderr is a terminal (people read text)."""
    return (not sys.stderr.isatty()) if setting is None else setting


class RepeatFilter(logging.Filter):
    """Lets a warning or error through once per ``window_s`` for each (logger, level, message template); the
    first one after the window says how many like it were held back. Info lines (the access log) all pass.

    Under a flood (thousands of connections over the open-file limit, each accept failing) one line repeated
    grew the log 341 MB in 70 s; held back here, it is one line every ``window_s``.
    """

    def __init__(self, window_s: float = 10.0) -> None:
        super().__init__()
        self.window_s = window_s
        self._seen: dict[tuple[str, int, str], tuple[float, int]] = {}
        self._lock = threading.Lock()

    def filter(self, record: logging.LogRecord) -> bool:
        if record.levelno < logging.WARNING:
            return True
        key = (record.name, record.levelno, str(record.msg))
        now = time.monotonic()
        with self._lock:
            first, held = self._seen.get(key, (-math.inf, 0))
            if now - first < self.window_s:
                self._seen[key] = (first, held + 1)
                return False
            self._seen[key] = (now, 0)
            if len(self._seen) > 4096:  # forget templates quiet for a window
                self._seen = {k: v for k, v in self._seen.items() if now - v[0] < self.window_s}
        if held:
            record.msg = f"{record.msg} [{held} more like it in the last {self.window_s:g} s not logged]"
        return True


def configure_logging(level: str = "info", json_lines: bool = True) -> None:
    """Send every logger (ours and uvicorn's) to stderr, as JSON lines, or readable text where ``json_lines`` is false."""
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(JsonFormatter() if json_lines else TextFormatter())
    handler.addFilter(RepeatFilter())
    root = logging.getLogger()
    root.handlers[:] = [handler]
    root.setLevel(level.upper())
    for name in ("uvicorn", "uvicorn.error"):
        lg = logging.getLogger(name)
        lg.handlers[:] = []
        lg.propagate = True
    # Our access line replaces uvicorn's (which would not carry the request id).
    logging.getLogger("uvicorn.access").disabled = True


def uvicorn_log_config(level: str = "info", json_lines: bool = True) -> dict[str, Any]:
    """A ``logging.config`` dictionary for uvicorn workers: JSON lines (or text) on stderr, no uvicorn access log."""
    formatter = "app.core.observability." + ("JsonFormatter" if json_lines else "TextFormatter")
    return {
        "version": 1,
        "disable_existing_loggers": False,
        "formatters": {"line": {"()": formatter}},
        "filters": {"repeats": {"()": "app.core.observability.RepeatFilter"}},
        "handlers": {
            "stderr": {
                "class": "logging.StreamHandler",
                "formatter": "line",
                "filters": ["repeats"],
                "stream": "ext://sys.stderr",
            }
        },
        "root": {"handlers": ["stderr"], "level": level.upper()},
        "loggers": {
            "uvicorn": {"handlers": [], "propagate": True},
            "uvicorn.error": {"handlers": [], "propagate": True},
            "uvicorn.access": {"handlers": [], "propagate": False, "level": "CRITICAL"},
        },
    }


class BodyTooLarge(HTTPException):
    """Raised while the body arrives; an HTTPException so that FastAPI's body parsing passes it on as a 413."""

    def __init__(self, limit: int) -> None:
        super().__init__(413, f"request body is over the limit of {limit} bytes")
        self.limit = limit


def _json_response(status: int, body: dict[str, Any], rid: str) -> list[Message]:
    payload = json.dumps(body).encode()
    headers = [
        (b"content-type", b"application/json"),
        (b"content-length", str(len(payload)).encode()),
        (REQUEST_ID_HEADER.lower().encode(), rid.encode()),
    ]
    return [
        {"type": "http.response.start", "status": status, "headers": headers},
        {"type": "http.response.body", "body": payload},
    ]


def route_template(scope: Scope) -> str:
    """The path a request matched with each path parameter's segment put back as ``{name}`` ("/v1/plans/{plan_id}",
    never an id: one metrics series a route); "unmatched" where no route matched."""
    if scope.get("route") is None:
        return "unmatched"
    params = {str(v): k for k, v in (scope.get("path_params") or {}).items()}
    segments = str(scope.get("path", "")).split("/")
    return "/".join(f"{{{params[seg]}}}" if seg in params else seg for seg in segments)


class RequestContextMiddleware:
    """Outermost middleware: request id, body-size limits, the access log line, and a JSON 500 for any bug.

    ``body_limit(headers, path)`` gives the byte limit of a request's body; it is checked against
    ``Content-Length`` up front and against the bytes actually received (chunked uploads).
    """

    def __init__(self, app: ASGIApp, body_limit: Any, metrics: Any = None) -> None:
        self.app = app
        self.body_limit = body_limit
        self.metrics = metrics  # app.core.metrics.Metrics: each request counted by its route's template

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope.get("headers", [])}
        rid = request_id_from(headers.get("x-request-id"))
        token = request_id_var.set(rid)
        t0 = time.perf_counter()
        state = {"status": 500, "started": False}
        limit = int(self.body_limit(headers, str(scope.get("path", ""))))

        async def send_with_id(message: Message) -> None:
            if message["type"] == "http.response.start":
                state["status"], state["started"] = message["status"], True
                MutableHeaders(scope=message)[REQUEST_ID_HEADER] = rid
            await send(message)

        received = 0

        async def receive_limited() -> Message:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > limit:
                    raise BodyTooLarge(limit)
            return message

        try:
            length = headers.get("content-length")
            if length is not None and (not length.isdigit() or int(length) > limit):
                raise BodyTooLarge(limit)
            await self.app(scope, receive_limited, send_with_id)
        except BodyTooLarge as exc:
            if state["started"]:
                raise
            state["status"] = 413
            for m in _json_response(413, {"detail": exc.detail, "request_id": rid}, rid):
                await send(m)
        except Exception:
            errors_log.exception("unhandled error in %s %s", scope.get("method"), scope.get("path"))
            if state["started"]:
                raise
            state["status"] = 500
            body = {
                "detail": "internal server error; this is a bug, please report it with the request id",
                "request_id": rid,
            }
            for m in _json_response(500, body, rid):
                await send(m)
        finally:
            if self.metrics is not None:
                route = route_template(scope)
                self.metrics.request(
                    str(scope.get("method")), str(route), int(state["status"]), time.perf_counter() - t0
                )
            log.info(
                "request",
                extra={
                    "request_id": rid,
                    "method": scope.get("method"),
                    "path": scope.get("path"),
                    "status": state["status"],
                    "duration_ms": round((time.perf_counter() - t0) * 1000.0, 2),
                },
            )
            request_id_var.reset(token)


def resident_mb() -> float:
    """Return this process's resident memory (MiB): /proc/self/statm, or the peak where there is no /proc."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    except (OSError, ValueError, IndexError):
        import resource

        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
