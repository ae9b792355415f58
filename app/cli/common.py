"""What every gsa command shares: settings, a database session, the one-line errors, the client options."""

from __future__ import annotations

import argparse
import json
import os
import re
from collections.abc import Callable
from datetime import datetime
from pathlib import Path
from typing import Any

from pydantic import ValidationError


class CliError(Exception):
    pass


def load_settings() -> Any:
    from app.core.config import get_settings

    return get_settings()


def open_session() -> Any:
    from app.core.db import make_engine, make_session_factory

    return make_session_factory(make_engine(load_settings().database_url))()


def read_json(path: str) -> Any:
    try:
        text = Path(path).read_text()
    except OSError as exc:
        raise CliError(f"cannot read {path}: {exc.strerror}") from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise CliError(f"{path} is not JSON: {exc.msg} at line {exc.lineno}") from None


def input_line(exc: ValueError) -> str:
    """One line for any domain error (``app.errors.DOMAIN_ERRORS``): the field's path, then what is wrong."""
    from app.errors import input_error

    loc, message = input_error(exc)
    return ".".join(str(x) for x in loc) + ": " + message if loc else message


def validation_line(exc: ValidationError, model: Any = None) -> str:
    """Every error as the field the user wrote and what is wrong with it, on one line: pydantic's own validator and
    union tags (``function-after[...]``, ``none``, a member model's class name) are left out of the paths, a union's
    "should be None" branch is passed over, and a misspelt field is named with the field of ``model`` (the request's
    pydantic class) it most likely meant."""
    return error_line(
        [
            {"loc": [str(x) for x in e["loc"] if not _internal(x)], "msg": e["msg"], "type": e["type"]}
            for e in exc.errors()
        ],
        field_names(model) if model is not None else (),
    )


_CLASS_NAME = re.compile(r"^[A-Z][a-z0-9]+(?:[A-Z][a-z0-9]*)+$")  # StationIn, OmmIn: a union member's tag


def _internal(part: Any) -> bool:
    return isinstance(part, str) and (
        "[" in part or part.startswith("function-") or part in ("none", "null", "str") or bool(_CLASS_NAME.match(part))
    )


def field_names(model: Any) -> set[str]:
    """Every field name of a pydantic model and of the models its fields hold (through unions and lists)."""
    import typing

    from pydantic import BaseModel

    seen: set[Any] = set()
    names: set[str] = set()

    def walk(t: Any) -> None:
        if isinstance(t, type) and issubclass(t, BaseModel):
            if t in seen:
                return
            seen.add(t)
            for name, f in t.model_fields.items():
                names.add(f.alias or name)
                walk(f.annotation)
        for arg in typing.get_args(t):
            walk(arg)

    walk(model)
    return names


def error_line(errors: list[dict[str, Any]], known: Any = ()) -> str:
    """Validation errors (each ``loc``, ``msg``, ``type``, as pydantic and the service's 422 give them) as one line:
    ``path: what is wrong`` joined by "; ", a typo beside the missing field it meant said once, as a typo; ``known``:
    field names a typo may have meant where no missing field is beside it."""
    import difflib

    def path(e: dict[str, Any]) -> tuple[str, ...]:
        return tuple(str(x) for x in e.get("loc", ()) if x not in ("body", "query", "path"))

    real = [e for e in errors if e.get("type") != "none_required"] or errors
    missing = {path(e) for e in real if e.get("type") == "missing"}
    meant: set[tuple[str, ...]] = set()
    out: list[str] = []
    for e in real:
        where = path(e)
        if e.get("type") == "extra_forbidden" and where:
            near = [m[-1] for m in missing if m[:-1] == where[:-1]]
            guess = difflib.get_close_matches(where[-1], near, 1, 0.6) or difflib.get_close_matches(
                where[-1], sorted(known), 1, 0.75
            )
            if guess:
                meant.add((*where[:-1], guess[0]))
                out.append(f"{'.'.join(where)}: not a field this request takes: did you mean {guess[0]}?")
            else:
                out.append(f"{'.'.join(where)}: not a field this request takes: check its spelling")
            continue
        msg = str(e.get("msg", "")).removeprefix("Value error, ").removeprefix("Assertion failed, ")
        out.append(f"{'.'.join(where)}: {msg}" if where else msg)
    lines = [line for e, line in zip(real, out, strict=True) if not (e.get("type") == "missing" and path(e) in meant)]
    return "; ".join(dict.fromkeys(lines)) or "request: not valid"


EXAMPLES_DIR = Path(__file__).resolve().parents[2] / "examples"


EXAMPLE_PLANS = {"paper": "paper-plan-30-days.json", "iss": "iss-plan.json"}


def add_client_options(p: argparse.ArgumentParser, what: str = "send it to a running service instead") -> None:
    """``--server`` and ``--api-key``, defaulting to GSA_SERVER and GSA_API_KEY (every client command has them)."""
    p.add_argument(
        "--server",
        default=os.environ.get("GSA_SERVER") or None,
        help=f"{what}, e.g. http://127.0.0.1:8000 (default: GSA_SERVER)",
    )
    p.add_argument(
        "--api-key", default=os.environ.get("GSA_API_KEY") or None, help="your API key (default: GSA_API_KEY)"
    )


def _server_detail(r: Any) -> str:
    """The service's own words for a refusal: every field and message of a 422 (``error_line``), the detail of
    others."""
    try:
        detail = r.json().get("detail")
    except ValueError:
        return r.text[:300]
    if isinstance(detail, list) and detail and isinstance(detail[0], dict):
        return error_line(detail)
    return str(detail)[:300]


def call_server(
    args: argparse.Namespace,
    method: str,
    path: str,
    timeout: float = 60,
    headers: dict[str, str] | None = None,
    **kw: Any,
) -> Any:
    """One request to ``args.server`` with ``args.api_key``; an unreachable server or a refusal is one CliError line."""
    import httpx

    if not args.server:
        raise CliError(
            "give --server URL or set GSA_SERVER (e.g. http://127.0.0.1:8000): this command asks the service"
        )
    try:
        r = httpx.request(
            method,
            args.server.rstrip("/") + path,
            headers={"X-API-Key": args.api_key or "", **(headers or {})},
            timeout=timeout,
            **kw,
        )
    except httpx.HTTPError as exc:
        raise CliError(f"cannot reach {args.server}: {exc}") from None
    if r.status_code >= 400:
        raise CliError(f"server answered {r.status_code}: {_server_detail(r)}")
    return r


ID_LENGTH = 36  # a full id (a UUID); anything shorter is read as the start of one (the lists and the console show 8)


def resolve_id(args: argparse.Namespace, listing: str, given: str, what: str) -> str:
    """The id of one of ``what`` (plural: "plans") that ``given`` starts with, from the caller's own listing route (``/v1/plans``...): a full
    id as it is; a prefix (as lists show them) when exactly one of yours starts so; several: one line saying which;
    none: as given, for the service's own 404."""
    if len(given) >= ID_LENGTH or not given:
        return given
    found: list[str] = []
    offset = 0
    while offset < 10_000:  # the listing's own page size (20, or the operator's smaller one)
        body = call_server(args, "GET", listing, params={"offset": offset}).json()
        rows = body.get("data", [])
        found += [r["id"] for r in rows if str(r.get("id", "")).startswith(given)]
        offset += len(rows)
        if not rows or offset >= int(body.get("count", 0)):
            break
    if len(found) == 1:
        return found[0]
    if not found:
        return given  # the service says what it says of an id it does not know (a 404)
    shown = ", ".join(f[:12] for f in found[:5]) + (", ..." if len(found) > 5 else "")
    raise CliError(f"{len(found)} of your {what} have ids starting with {given!r} ({shown}): give more of it")


def print_listing(
    args: argparse.Namespace,
    path: str,
    filters: dict[str, Any],
    title: str,
    header: str,
    row: Callable[[dict[str, Any]], str],
) -> int:
    """GET a listing route (``--limit`` and the filters given) and print it as JSON or as a table of ``row``s
    under ``title`` (a format of ``count``, all that match, and ``shown``)."""
    params = {"limit": args.limit, **{k: v for k, v in filters.items() if v}}
    body = call_server(args, "GET", path, params=params).json()
    if args.json:
        print(json.dumps(body, indent=2))
        return 0
    print(title.format(count=body["count"], shown=len(body["data"])))
    print(header)
    for item in body["data"]:
        print(row(item))
    return 0


def utc_text(moment: str | datetime | None) -> str:
    """An instant (ISO 8601 text or a datetime) as the CLI writes every time: UTC to the millisecond with a ``Z``."""
    if not moment:
        return "-"
    from datetime import UTC

    t = moment if isinstance(moment, datetime) else datetime.fromisoformat(moment.replace("Z", "+00:00"))
    t = t.replace(tzinfo=UTC) if t.tzinfo is None else t.astimezone(UTC)
    return t.strftime("%Y-%m-%dT%H:%M:%S.") + f"{t.microsecond // 1000:03d}Z"


def local_models(args: argparse.Namespace, settings: Any) -> tuple[Any, Any]:
    """The estimator and the checker of the target asked for (``--models``, ``--target``), loaded here."""
    from inference.runtime import Estimator
    from inference.trust import load_checkers

    model_dir = args.models or settings.model_dir
    est = Estimator.load(model_dir)
    checkers = load_checkers(
        model_dir, est.img_size, settings.target_model, settings.target_scale, settings.default_target
    )
    return est, checkers.get(args.target or checkers.default)
