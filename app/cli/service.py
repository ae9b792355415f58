"""gsa serve, gsa db upgrade and gsa keys: the service and its keys."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import Any

from app.cli.common import CliError, load_settings, open_session


def cmd_db_upgrade(_args: argparse.Namespace) -> int:
    from app.core.db import upgrade_database

    url = load_settings().database_url
    upgrade_database(url)
    print(f"database at {url} is at the latest migration")
    return 0


def _secret(settings: Any) -> bytes:
    from app.core.security import load_key_secret

    return load_key_secret(settings.key_secret, settings.data_dir)


def ensure_dev_key(settings: Any) -> str | None:
    """Create a development key on first start (no stored keys, none in GSA_API_KEYS); return it."""
    from app import crud

    key_file = Path(settings.data_dir) / "dev-api-key.txt"
    with open_session() as session:
        if crud.count_api_keys(session=session) == 0 and not settings.env_api_keys:
            _, key = crud.create_api_key(
                session=session, secret=_secret(settings), operator_name="dev", key_name="development"
            )
            key_file.parent.mkdir(parents=True, exist_ok=True)
            key_file.write_text(key + "\n")
            os.chmod(key_file, 0o600)
            return key
    if key_file.exists():
        return key_file.read_text().strip()
    return None


def cmd_serve(args: argparse.Namespace) -> int:
    import uvicorn

    from app.core.db import upgrade_database
    from app.core.observability import configure_logging, json_lines_wanted, uvicorn_log_config
    from app.services.images import sweep_blobs

    settings = load_settings()
    if settings.ray_address and settings.ray_address.strip() != "local":  # a cluster that does not answer: now
        from inference.engine import EngineError, check_address

        try:
            check_address(settings.ray_address)
        except EngineError as exc:
            raise CliError(str(exc)) from None
    json_lines = json_lines_wanted(settings.log_json)
    configure_logging(settings.log_level, json_lines)
    upgrade_database(settings.database_url)
    _secret(settings)  # made once here, before the workers start
    key = ensure_dev_key(settings)
    with open_session() as session:  # files a crash left without their rows
        removed = sweep_blobs(session=session, data_dir=Path(settings.data_dir), grace_s=settings.orphan_grace_s)
    host = args.host or settings.host
    port = args.port or settings.port
    print(f"GSA-ISAR on http://{host}:{port}  (API docs: http://{host}:{port}/docs)")
    if removed:
        print(f"removed {removed} image files that no estimate refers to")
    if key:
        print(f"development API key (send as X-API-Key): {key}")
        print(f"  it is also in {Path(settings.data_dir) / 'dev-api-key.txt'}")
    sys.stdout.flush()
    log_config = uvicorn_log_config(settings.log_level, json_lines)
    from app.core.server import descriptor_warning, raise_descriptor_limit, uvicorn_limits

    warning = descriptor_warning(raise_descriptor_limit(settings.max_connections), settings.max_connections)
    if warning:
        print(f"gsa: warning: {warning}", file=sys.stderr, flush=True)
    uvicorn.run(
        "app.main:create_app",
        factory=True,
        host=host,
        port=port,
        workers=args.workers,
        log_level=settings.log_level,
        log_config=log_config,
        access_log=not settings.log_json,
        **uvicorn_limits(settings),
    )
    return 0


def cmd_keys(args: argparse.Namespace) -> int:
    from app import crud

    with open_session() as session:
        if args.keys_cmd == "create":
            row, key = crud.create_api_key(
                session=session,
                secret=_secret(load_settings()),
                operator_name=args.operator or args.name,
                key_name=args.name,
                role="admin" if args.admin else "operator",
            )
            print(f"{row.id}  {key}")
            print("store this key now: only its hash is kept", file=sys.stderr)
        elif args.keys_cmd == "list":
            for row, op in crud.list_api_keys(session=session):
                state = "revoked" if row.revoked_at else "active"
                print(f"{row.id}  {row.prefix}...  {row.name}  operator={op.name}  role={row.role}  {state}")
        elif args.keys_cmd == "role":
            if crud.set_key_role(session=session, key_id=args.id, role=args.role) is None:
                raise CliError(f"no key with id {args.id}")
            print(f"{args.id}: role {args.role}")
        else:
            if crud.revoke_api_key(session=session, key_id=args.id) is None:
                raise CliError(f"no key with id {args.id}")
            print(f"revoked {args.id}")
    return 0
