"""What every gsa command shares: settings, a database session, the one-line errors, the client options."""

from __future__ import annotations

import argparse
import json
import os
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


def validation_line(exc: ValidationError) -> str:
    """The first error as the field the user wrote and what is wrong with it: pydantic's own validator and union
    tags (``function-after[...]``, ``none``) are left out of the path, and a union's "should be None" branch is
    passed over for the error that says what to fix."""
    errors = exc.errors()
    err = next((e for e in errors if e["type"] != "none_required"), errors[0])
    parts = [
        str(x)
        for x in err["loc"]
        if not (isinstance(x, str) and ("[" in x or x.startswith("function-") or x in ("none", "null")))
    ]
    msg = "not a field this request takes: check its spelling" if err["type"] == "extra_forbidden" else err["msg"]
    return f"{'.'.join(parts) or 'request'}: {msg}"


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
    """The service's own words for a refusal: the field and message of a 422, the detail of others."""
    try:
        detail = r.json().get("detail")
    except ValueError:
        return r.text[:300]
    if isinstance(detail, list) and detail and isinstance(detail[0], dict):
        loc = ".".join(str(x) for x in detail[0].get("loc", ()) if x not in ("body", "query", "path"))
        return f"{loc}: {detail[0].get('msg')}" if loc else str(detail[0].get("msg"))
    return str(detail)[:300]


def call_server(args: argparse.Namespace, method: str, path: str, timeout: float = 60, **kw: Any) -> Any:
    """One request to ``args.server`` with ``args.api_key``; an unreachable server or a refusal is one CliError line."""
    import httpx

    if not args.server:
        raise CliError(
            "give --server URL or set GSA_SERVER (e.g. http://127.0.0.1:8000): this command asks the service"
        )
    try:
        r = httpx.request(
            method, args.server.rstrip("/") + path, headers={"X-API-Key": args.api_key or ""}, timeout=timeout, **kw
        )
    except httpx.HTTPError as exc:
        raise CliError(f"cannot reach {args.server}: {exc}") from None
    if r.status_code >= 400:
        raise CliError(f"server answered {r.status_code}: {_server_detail(r)}")
    return r


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
