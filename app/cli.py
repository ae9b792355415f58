"""The ``gsa`` command line: serve, db, keys, plan, access.

Bad input prints one line on stderr and exits with status 2.
"""

from __future__ import annotations

import argparse
import importlib
import json
import math
import os
import sys
import time
from collections.abc import Callable
from datetime import datetime
from pathlib import Path
from typing import Any

from pydantic import ValidationError


class CliError(Exception):
    pass


def _settings() -> Any:
    from app.core.config import get_settings

    return get_settings()


def _session() -> Any:
    from app.core.db import make_engine, make_session_factory

    return make_session_factory(make_engine(_settings().database_url))()


def cmd_db_upgrade(_args: argparse.Namespace) -> int:
    from app.core.db import upgrade_database

    url = _settings().database_url
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
    with _session() as session:
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

    settings = _settings()
    json_lines = json_lines_wanted(settings.log_json)
    configure_logging(settings.log_level, json_lines)
    upgrade_database(settings.database_url)
    _secret(settings)  # made once here, before the workers start
    key = ensure_dev_key(settings)
    with _session() as session:  # files a crash left without their rows
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
    from app.core.server import raise_descriptor_limit, uvicorn_limits

    raise_descriptor_limit(settings.max_connections)
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

    with _session() as session:
        if args.keys_cmd == "create":
            row, key = crud.create_api_key(
                session=session,
                secret=_secret(_settings()),
                operator_name=args.operator or args.name,
                key_name=args.name,
            )
            print(f"{row.id}  {key}")
            print("store this key now: only its hash is kept", file=sys.stderr)
        elif args.keys_cmd == "list":
            for row, op in crud.list_api_keys(session=session):
                state = "revoked" if row.revoked_at else "active"
                print(f"{row.id}  {row.prefix}...  {row.name}  operator={op.name}  {state}")
        else:
            if crud.revoke_api_key(session=session, key_id=args.id) is None:
                raise CliError(f"no key with id {args.id}")
            print(f"revoked {args.id}")
    return 0


def _read_json(path: str) -> Any:
    try:
        text = Path(path).read_text()
    except OSError as exc:
        raise CliError(f"cannot read {path}: {exc.strerror}") from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise CliError(f"{path} is not JSON: {exc.msg} at line {exc.lineno}") from None


def _input_line(exc: Any) -> str:
    """One line for an ``app.errors.InputError``: the field's path, then what is wrong."""
    return ".".join(str(x) for x in exc.loc) + ": " + exc.message


def _validation_line(exc: ValidationError) -> str:
    err = exc.errors()[0]
    loc = ".".join(str(x) for x in err["loc"])
    return f"{loc}: {err['msg']}"


EXAMPLES_DIR = Path(__file__).resolve().parents[1] / "examples"
EXAMPLE_PLANS = {"paper": "paper-plan.json", "iss": "iss-plan.json"}


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


def _print_listing(
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


def cmd_plans(args: argparse.Namespace) -> int:
    from urllib.parse import quote

    if args.plans_cmd == "show":
        body = call_server(args, "GET", f"/v1/plans/{quote(args.id, safe='')}").json()
        if args.json:
            print(json.dumps(body, indent=2))
        else:
            print(
                f"plan {body['id']}: {body['target_name']} / {body['observer_name']} / {body['station_name']}, "
                f"created {utc_text(body['created_at'])}"
            )
            print(format_plan(body))
        return 0

    def row(p: dict[str, Any]) -> str:
        miss = "-" if p["miss_km"] is None else f"{p['miss_km']:9.3f}"
        return (
            f"{p['id']:<36}  {utc_text(p['created_at']):<24}  {p['target_name'][:16]:<16} {p['observer_name'][:16]:<16} "
            f"{p['station_name'][:14]:<14} {utc_text(p['t_access']):<24} {miss:>9}"
        )

    header = (
        f"{'id':<36}  {'created (UTC)':<24}  {'target':<16} {'observer':<16} {'station':<14} {'T_access (UTC)':<24} "
        f"{'miss (km)':>9}"
    )
    return _print_listing(
        args, "/v1/plans", {"target_name": args.target_name}, "{count} plans; newest {shown}:", header, row
    )


def cmd_estimates(args: argparse.Namespace) -> int:
    from urllib.parse import quote

    if args.estimates_cmd == "show":
        body = call_server(args, "GET", f"/v1/estimates/{quote(args.id, safe='')}").json()
        if args.json:
            print(json.dumps(body, indent=2))
        else:
            _print_checked(
                body, prefix=f"estimate {body['id']} ({body['input_name']}, {utc_text(body['created_at'])}): "
            )
        return 0

    def row(e: dict[str, Any]) -> str:
        z, y, x = e["attitude"]["euler_zyx_deg"]
        quality = e.get("quality")  # null on estimates made before the checks
        trusted = "-" if quality is None else "yes" if quality["trusted"] else "no"
        return (
            f"{e['id']:<36}  {utc_text(e['created_at']):<24}  {e['input_name'][:20]:<20} "
            f"{f'{z:.2f}, {y:.2f}, {x:.2f}':<22} {trusted:<7}  {e.get('plan_id') or '-'}"
        )

    header = f"{'id':<36}  {'created (UTC)':<24}  {'input':<20} {'z, y, x (deg)':<22} {'trusted':<7}  plan"
    return _print_listing(
        args, "/v1/estimates", {"plan_id": args.plan_id}, "{count} estimates; newest {shown}:", header, row
    )


def cmd_stations(args: argparse.Namespace) -> int:
    from urllib.parse import quote

    if args.stations_cmd == "add":
        body = call_server(args, "POST", "/v1/stations", json=_read_json(args.file)).json()
        print(f"station {body['name']!r} stored")
        return 0
    if args.stations_cmd == "delete":
        call_server(args, "DELETE", f"/v1/stations/{quote(args.name, safe='')}")
        print(f"station {args.name!r} deleted")
        return 0
    if args.stations_cmd == "show":
        print(json.dumps(call_server(args, "GET", f"/v1/stations/{quote(args.name, safe='')}").json(), indent=2))
        return 0

    def row(st: dict[str, Any]) -> str:
        return (
            f"{st['name'][:24]:<24} {st['latitude_deg']:10.4f} {st['longitude_deg']:10.4f} {st['altitude_m']:8.0f} "
            f"{st['min_elevation_deg']:12.1f} {len(st.get('mask') or []):11d}  {'on' if st['refraction'] else 'off'}"
        )

    header = (
        f"{'name':<24} {'lat (deg)':>10} {'lon (deg)':>10} {'alt (m)':>8} {'min el (deg)':>12} {'mask points':>11}  "
        "refraction"
    )
    return _print_listing(args, "/v1/stations", {}, "{count} stations:", header, row)


def cmd_plan(args: argparse.Namespace) -> int:
    from app.errors import InputError
    from app.schemas import PlanCreate
    from app.services.planning import run_plan

    if args.export and Path(args.export).exists() and any(Path(args.export).iterdir()):
        raise CliError(f"{args.export} is not empty: give a new or empty directory for --export")
    if bool(args.file) == bool(args.example):
        raise CliError("give a request file (the body of POST /v1/plans) or --example paper|iss, not both")
    source = args.file or str(EXAMPLES_DIR / EXAMPLE_PLANS[args.example])
    if args.example and not Path(source).is_file():
        raise CliError(f"{source} is missing: the examples live in the repository's examples/ folder")
    if args.server:
        if args.export or args.plot:
            raise CliError("--export and --plot plan locally; with --server, GET /v1/plans/ID/export/... instead")
        body = call_server(args, "POST", "/v1/plans", json=_read_json(source), timeout=600).json()
        print(json.dumps(body, indent=2) if args.json else f"plan {body['id']} stored\n" + format_plan(body))
        return 0
    try:
        req = PlanCreate.model_validate(_read_json(source))
        plan, result = run_plan(req)
    except ValidationError as exc:
        raise CliError(_validation_line(exc)) from None
    except InputError as exc:
        raise CliError(_input_line(exc)) from None
    assert not isinstance(req.ground_station, str)  # run_plan refuses a station name: only the server resolves one
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print(format_plan(result))
    if args.export:
        _export_plan(plan, result, req, Path(args.export))
    if args.plot:
        from planner.plot import plot_plan

        plot_plan(plan, args.plot, title=f"{req.target.name} / {req.observer.name} / {req.ground_station.name}")
        print(f"plot written to {args.plot}", file=sys.stderr)
    return 0


def _export_plan(plan: Any, result: dict[str, Any], req: Any, folder: Path) -> None:
    """Write the plan in every export format into ``folder`` (as GET /v1/plans/{id}/export/... serves them)."""
    from app.errors import InputError
    from app.services import exports
    from app.services.planning import access_csv

    folder.mkdir(parents=True, exist_ok=True)
    name = "local"
    files = {
        "access.csv": access_csv(result["access_windows"]),
        "pointing.csv": exports.pointing_csv(plan, result["access_windows"]),
    }
    names = {"target": req.target.name, "observer": req.observer.name, "station": req.ground_station.name}
    files["plan.geojson"] = exports.geojson(plan, names, result["access_windows"])
    try:
        arc = exports.plan_arc(plan, result)
    except InputError as exc:
        print(f"note: no OPM, OEM or CZML: {exc.message}", file=sys.stderr)
    else:
        files["opm.txt"] = exports.opm(arc, name, req.observer.name)
        files["oem.txt"] = exports.oem(arc, name, req.target.name, req.observer.name)
        files["plan.czml"] = exports.czml(arc, name, names, req.ground_station.model_dump(), result["access_windows"])
    for fname, body in files.items():
        (folder / fname).write_text(body)
    print(f"wrote {', '.join(sorted(files))} to {folder}", file=sys.stderr)


def cmd_access(args: argparse.Namespace) -> int:
    from app.errors import InputError
    from app.schemas import AccessCreate
    from app.services.planning import run_access

    try:
        result = run_access(AccessCreate.model_validate(_read_json(args.file)))
    except ValidationError as exc:
        raise CliError(_validation_line(exc)) from None
    except InputError as exc:
        raise CliError(_input_line(exc)) from None
    print(json.dumps(result, indent=2) if args.json else format_windows(result["access_windows"]))
    return 0


def utc_text(iso: str | None) -> str:
    """An ISO 8601 instant as the CLI writes every time: UTC to the millisecond with a ``Z``."""
    if not iso:
        return "-"
    from datetime import UTC

    t = datetime.fromisoformat(iso.replace("Z", "+00:00"))
    t = t.replace(tzinfo=UTC) if t.tzinfo is None else t.astimezone(UTC)
    return t.strftime("%Y-%m-%dT%H:%M:%S.") + f"{t.microsecond // 1000:03d}Z"


def format_windows(windows: list[dict[str, Any]]) -> str:
    lines = [
        f"{'rise (UTC)':<25} {'culmination (UTC)':<25} {'set (UTC)':<25} {'max el (deg)':>12} "
        f"{'min range (km)':>14} {'duration (s)':>12}"
    ]
    for w in windows:
        lines.append(
            f"{utc_text(w['rise']):<25} {utc_text(w['culmination']):<25} {utc_text(w['set']):<25} "
            f"{w['max_elevation_deg']:12.2f} {w['min_range_km']:14.1f} {w['duration_s']:12.1f}"
        )
    return "\n".join(lines)


def format_plan(r: dict[str, Any]) -> str:
    """Return a plan as a readable report: every time in UTC with Z, every number with its unit."""
    out = [f"epoch {utc_text(r['epoch'])}, {r['duration_days']:g} days, elements read as {r['reading']}"]
    out.append(f"\n{len(r['access_windows'])} access windows")
    out.append(format_windows(r["access_windows"][:10]))
    if len(r["access_windows"]) > 10:
        out.append(f"... and {len(r['access_windows']) - 10} more")
    out.append(f"\n{len(r['candidates'])} candidates (best of each pass, ranked by miss); * marks the chosen one")
    out.append(
        f"{'#':>4} {'T_access (UTC)':<25} {'dHa (km)':>9} {'dHp (km)':>9} {'miss (km)':>10} {'node':>5} {'sunlit':>7}"
    )
    chosen_at = (r.get("chosen") or {}).get("t_access")
    shown = [(k, c) for k, c in enumerate(r["candidates"]) if k < 15 or c["t_access"] == chosen_at]
    for n, (k, c) in enumerate(shown):
        if n and k != shown[n - 1][0] + 1:
            out.append("   ...")
        mark = "*" if c["t_access"] == chosen_at else " "
        out.append(
            f"{mark}{k:3d} {utc_text(c['t_access']):<25} {c['delta_ha_km']:9.1f} {c['delta_hp_km']:9.1f} "
            f"{c['miss_km']:10.3f} {c['node']:>5} {('yes' if c['feasibility']['sunlit'] else 'no'):>7}"
        )
    ch = r.get("chosen")
    if ch:
        out.append(
            f"\nchosen: T_access {utc_text(ch['t_access'])}, dHa {ch['delta_ha_km']:.1f} km, dHp {ch['delta_hp_km']:.1f} km"
        )
        out.append(f"  node-line miss with the changed observer's own propagation: {ch['miss_km']:.3f} km")
        out.append(f"  height change costs {r['alignment_dv_m_s']:.1f} m/s")
    ph = r.get("phasing")
    if ph:
        v = ph["verification"]
        out.append(
            f"phasing: burn {utc_text(ph['t_burn'])} ({ph['revolutions_before']} rev before), "
            f"dv {ph['dv_total_m_s']:.1f} m/s, RTN [{', '.join(f'{x:.1f}' for x in ph['dv_rtn_m_s'])}] m/s"
        )
        out.append(
            f"verification (numerical J2): {v['miss_km'] * 1000:.1f} m from the aim point at T_access "
            f"(two-body Lambert alone: {v['two_body_miss_km']:.1f} km), relative speed {v['relative_speed_km_s']:.2f} km/s"
        )
        out.append(
            f"encounter: stand-off {v['standoff_km']:.2f} km, separation {v['separation_km']:.3f} km at T_access, "
            f"closest approach {v['closest_approach_km']:.3f} km at {utc_text(v['closest_approach_time'])}, "
            f"target angular rate {v['target_angular_rate_deg_s']:.2f} deg/s"
        )
    if ch:
        f = ch["feasibility"]
        out.append(
            f"feasible: {'yes' if f['feasible'] else 'no'}" + (f" ({'; '.join(f['reasons'])})" if f["reasons"] else "")
        )
    for note in r["notes"]:
        out.append(f"note: {note}")
    return "\n".join(out)


def add_inference_command(sub: Any, name: str, module: str, help: str) -> argparse.ArgumentParser:
    """Register ``gsa NAME``, whose arguments and ``run`` live in ``inference.MODULE``.

    Its InferenceError (bad input) becomes the one-line error and exit 2 of every command.
    """
    mod = importlib.import_module(f"inference.{module}")
    p = sub.add_parser(name, help=help)
    mod.add_arguments(p)

    def command(args: argparse.Namespace) -> int:
        from inference.errors import InferenceError

        try:
            return int(mod.run(args))
        except InferenceError as exc:
            raise CliError(str(exc)) from None

    p.set_defaults(func=command)
    return p


def _print_checked(body: dict[str, Any], prefix: str = "") -> None:
    """Print an estimate's answer (the API's JSON shape): attitude, network answer, quality, alternatives."""
    z, y, x = body["attitude"]["euler_zyx_deg"]
    q = body["attitude"]["quaternion_wxyz"]
    kind = "fitted" if body.get("refined") else "network"
    print(
        f"{prefix}z {z:.2f} y {y:.2f} x {x:.2f} deg ({kind}, observation frame, target {body.get('target')}); "
        f"quaternion w x y z {', '.join(f'{v:.5f}' for v in q)}"
    )
    net = body.get("attitude_network")
    if net and body.get("refined"):
        nz, ny, nx = net["euler_zyx_deg"]
        print(f"Swin alone: z {nz:.2f} y {ny:.2f} x {nx:.2f} deg")
    qual = body.get("quality")
    if qual:
        bounds = " / ".join("-" if b is None else f"{b:.2f}" for b in qual["uncertainty_deg"])
        state = "trusted" if qual["trusted"] else "NOT TRUSTED"
        print(f"{state}: silhouette IoU {qual['silhouette_iou']:.3f}, 90 % bound z / y / x {bounds} deg")
        for r in qual["reasons"]:
            print(f"  - {r}")
    for alt in body.get("alternatives", []):
        az, ay, ax = alt["euler_zyx_deg"]
        print(
            f"also fits: z {az:.2f} y {ay:.2f} x {ax:.2f} deg ({alt['distance_deg']:.0f} deg away, "
            f"IoU {alt['silhouette_iou']:.3f}, fit {alt['fit_gap']:+.4f})"
        )


def _local_models(args: argparse.Namespace, settings: Any) -> tuple[Any, Any]:
    """The estimator and the checker of the target asked for (``--models``, ``--target``), loaded here."""
    from inference.runtime import Estimator
    from inference.trust import load_checkers

    model_dir = args.models or settings.model_dir
    est = Estimator.load(model_dir)
    checkers = load_checkers(
        model_dir, est.img_size, settings.target_model, settings.target_scale, settings.default_target
    )
    return est, checkers.get(args.target or checkers.default)


def _one_frame(args: argparse.Namespace, data: bytes) -> tuple[str, bytes, bool]:
    """The one frame ``gsa estimate`` reads: the file itself, or frame ``--frame K`` of a stack (a ``gsa simulate``
    shard, whose frames are normalised and say so), as .npy bytes; with whether the file says it is normalised."""
    import io

    import numpy as np

    from app.errors import InputError
    from app.services import uploads as upload_svc

    name = Path(args.file).name
    if args.frame is None and not data.startswith(b"PK"):
        return name, data, False
    try:
        frames = upload_svc.decode(data, name, allow_stack=True)
    except InputError as exc:
        raise CliError(_input_line(exc)) from None
    if args.frame is None:
        if len(frames) == 1:
            return name, data, frames[0].normalised
        raise CliError(f"{args.file} holds {len(frames)} frames: pick one with --frame K (0..{len(frames) - 1})")
    if not 0 <= args.frame < len(frames):
        raise CliError(f"--frame {args.frame}: {args.file} holds frames 0..{len(frames) - 1}")
    buf = io.BytesIO()
    np.save(buf, frames[args.frame].magnitude.astype(np.float32))
    return f"{name}[{args.frame}]", buf.getvalue(), frames[args.frame].normalised


def cmd_estimate(args: argparse.Namespace) -> int:
    import numpy as np

    from app.errors import InputError
    from inference.errors import InferenceError

    if (args.plan_id or args.observed_at) and not args.server:
        raise CliError("--plan-id and --observed-at need --server: plans are stored by the service")
    if bool(args.plan_id) != bool(args.observed_at):
        raise CliError("give --plan-id and --observed-at together")
    if (args.range_cell_m is None) != (args.cross_range_cell_m is None):
        raise CliError("give --range-cell-m and --cross-range-cell-m together (the frame's cells in metres)")
    for name in ("range_cell_m", "cross_range_cell_m"):
        value = getattr(args, name)
        if value is not None and not 0 < value <= 100:
            raise CliError(f"--{name.replace('_', '-')} {value}: a cell size in metres, over 0 and at most 100")
    cells = None if args.range_cell_m is None else (args.range_cell_m, args.cross_range_cell_m)
    try:
        data = Path(args.file).read_bytes()
    except OSError as exc:
        raise CliError(f"cannot read {args.file}: {exc.strerror}") from None
    name, data, file_normalised = _one_frame(args, data)
    if args.server:
        form = {
            "resample": str(args.resample).lower(),
            "normalised": str(args.normalised or file_normalised).lower(),
            "refine": str(not args.no_refine).lower(),
        }
        if args.target:
            form["target"] = args.target
        if args.plan_id:
            form["plan_id"] = args.plan_id
        if args.observed_at:
            form["observed_at"] = args.observed_at
        if cells:
            form.update({"range_cell_m": str(cells[0]), "cross_range_cell_m": str(cells[1])})
        r = call_server(args, "POST", "/v1/estimates", files={"file": (name, data)}, data=form, timeout=60)
        body = r.json()
        _print_checked(body, prefix=f"estimate {body['id']}: ")
        return 0
    from app.services import estimation as svc
    from app.services import uploads as upload_svc

    settings = _settings()
    try:
        est, checker = _local_models(args, settings)
        (up,) = upload_svc.decode(data, name, allow_stack=False)
        model_cells = (checker.radar.range_cell_m, checker.radar.cross_range_cell_m)
        frame = upload_svc.prepare(
            up, est.img_size, args.resample, args.normalised or file_normalised, cells, model_cells
        )
        res = est.estimate(frame[None])
        t0 = time.perf_counter()
        checked = checker.check(
            frame, res.enhanced[0], res.angles_deg[0] if checker.networks else None, not args.no_refine
        )
        t_fit = time.perf_counter() - t0
    except InputError as exc:
        raise CliError(exc.message) from None
    except InferenceError as exc:
        raise CliError(str(exc)) from None
    body = {**svc.checked_json(checked), "target": checker.model.name}
    _print_checked(body)
    print(
        f"UNet++ {res.timings_s['unetpp'] * 1000:.0f} ms, Swin {res.timings_s['swin'] * 1000:.0f} ms, "
        f"fit and checks {t_fit * 1000:.0f} ms"
    )
    if args.plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        outline = checker.renderer.occupancy(np.asarray(checked.angles_deg, float)[None])[0] > 0.5
        z, y, x = (float(a) for a in checked.angles_deg)
        fig, ax = plt.subplots(1, 2, figsize=(9, 4.6))
        ax[0].imshow(frame, cmap="gray", vmin=0, vmax=1)
        ax[0].set_title("input (normalised) and the fitted projection")
        ax[1].imshow(np.clip(res.enhanced[0], 0, 1), cmap="gray", vmin=0, vmax=1)
        q = checked.quality
        ax[1].set_title(
            f"enhanced; fitted z {z:.1f} y {y:.1f} x {x:.1f} deg\n"
            f"IoU {q.silhouette_iou:.3f}, {'trusted' if q.trusted else 'NOT trusted'}",
            fontsize=10,
        )
        for a in ax:
            a.contour(outline, levels=[0.5], colors=["#ff7f0e"], linewidths=0.9)
            a.set_xlabel("cross-range cell (column)")
            a.set_ylabel("range cell (row)")
        fig.tight_layout()
        fig.savefig(args.plot, dpi=100)
        plt.close(fig)
        print(f"plot written to {args.plot}", file=sys.stderr)
    return 0


def add_pass_arguments(p: argparse.ArgumentParser) -> None:
    """``gsa simulate --pass``: the frames of one radar pass instead of a data set."""
    g = p.add_argument_group("a radar pass (--pass REQUEST.json): the frames the station's radar forms over one pass")
    g.add_argument(
        "--pass",
        dest="pass_request",
        metavar="REQUEST.json",
        help="a plan request (the body of POST /v1/plans): its target over one of its access windows to its "
        "station; with --out DIR writes DIR/frames.npz, DIR/pass.json and DIR/frames.png",
    )
    g.add_argument("--window", type=int, help="which of the plan's access windows (default: the highest)")
    g.add_argument("--frames", type=int, default=60, help="at most this many frames, thinned evenly (default 60)")
    g.add_argument(
        "--step-deg", type=float, help="between frame centres, in line-of-sight sweep (default: the aperture)"
    )
    g.add_argument(
        "--attitude-lvlh",
        metavar="Z,Y,X",
        help="the target's attitude, body to LVLH, deg (default: drawn so mid-pass looks within --max-angle-deg)",
    )
    g.add_argument(
        "--spin-deg-s", type=float, default=0.0, help="spin about --spin-axis (deg/s, default 0: still in LVLH)"
    )
    g.add_argument("--spin-axis", default="0,0,1", metavar="X,Y,Z", help="the spin's body axis (default 0,0,1)")
    g.add_argument(
        "--snr-reference",
        metavar="DB@KM",
        help="SNR from range by the radar equation: DB at KM, falling as range to the fourth power",
    )
    g.add_argument(
        "--within-deg",
        type=float,
        help="keep only frames whose observation-frame angles are within this (the networks' range: 45)",
    )


def _pass_or_data_set(data_set: Any) -> Any:
    """``gsa simulate``: a pass with --pass, else the data set command."""

    def command(args: argparse.Namespace) -> int:
        return cmd_simulate_pass(args) if args.pass_request else int(data_set(args))

    return command


def _floats(text: str, n: int, flag: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != n or not all(math.isfinite(v) for v in values):
        raise CliError(f"{flag} {text!r}: write {n} numbers separated by commas")
    return values


def _plan_for_pass(request: Any) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """A plan request, checked, and its target's access windows to its station over the request's span."""
    from app.errors import InputError
    from app.schemas import AccessCreate, PlanCreate
    from app.services.planning import run_access

    try:
        req = PlanCreate.model_validate(request)
        acc = AccessCreate(
            target=req.target,
            ground_station=req.ground_station,
            start=req.search.start,
            duration_days=req.search.duration_days,
            reading=req.search.reading,
        )
        windows = run_access(acc)["access_windows"]
    except ValidationError as exc:
        raise CliError(_validation_line(exc)) from None
    except InputError as exc:
        raise CliError(_input_line(exc)) from None
    return req.model_dump(mode="json", exclude_none=True), windows


def cmd_simulate_pass(args: argparse.Namespace) -> int:
    import numpy as np

    from app.errors import InputError
    from app.services import passes as pass_svc
    from inference.simulation.dataset import parse_snr
    from inference.simulation.isar import Radar

    if not args.out:
        raise CliError("give --out DIR for the pass's frames")
    out = Path(args.out)
    if out.exists():
        raise CliError(f"{out} exists: give a new directory")
    lo, hi = parse_snr(args.snr_db)
    ref = None
    if args.snr_reference:
        db, sep, km = args.snr_reference.partition("@")
        try:
            ref = (float(db), float(km))
        except ValueError:
            raise CliError(f"--snr-reference {args.snr_reference!r}: write DB@KM, e.g. 12@800") from None
        if not sep or not all(math.isfinite(v) for v in ref) or ref[1] <= 0:
            raise CliError(f"--snr-reference {args.snr_reference!r}: write DB@KM with KM over 0, e.g. 12@800")
    try:
        radar = Radar(args.carrier_hz, args.bandwidth_hz, args.n_range, args.n_azimuth, args.aperture_deg)
        request, windows = _plan_for_pass(_read_json(args.pass_request))
        opts = pass_svc.PassOptions(
            window=args.window,
            aperture_deg=args.aperture_deg,
            step_deg=args.step_deg,
            max_frames=args.frames,
            attitude_lvlh_deg=_floats(args.attitude_lvlh, 3, "--attitude-lvlh") if args.attitude_lvlh else None,  # type: ignore[arg-type]
            max_angle_deg=min(args.max_angle_deg, 89.0),
            spin_deg_s=args.spin_deg_s,
            spin_axis=_floats(args.spin_axis, 3, "--spin-axis"),  # type: ignore[arg-type]
            snr_db=None if lo is None or hi is None else (lo, hi),
            snr_reference=ref,
            within_deg=args.within_deg,
            seed=args.seed,
        )
        index, window = pass_svc.choose_window(windows, opts.window)
        rng = np.random.default_rng(opts.seed)
        meta = pass_svc.pass_geometry_frames(request, window, opts, rng)
        model = None
        if args.model:
            from inference.simulation.dataset import DatasetSpec, build_model

            model = build_model(DatasetSpec(n=1, model_path=args.model, model_scale=args.model_scale), radar)
        print(
            f"window {index}: {window['rise']} to {window['set']}, culminating at "
            f"{window['max_elevation_deg']:.1f} deg; rendering {len(meta)} frames",
            file=sys.stderr,
        )
        images, snrs = pass_svc.render_pass(meta, opts, rng, radar, model)
    except InputError as exc:
        raise CliError(_input_line(exc)) from None
    record = pass_svc.pass_record(
        meta, snrs, opts, index, window, request, (radar.range_cell_m, radar.cross_range_cell_m)
    )
    partial = out.with_name(out.name + ".partial")
    partial.mkdir(parents=True, exist_ok=False)
    np.savez_compressed(partial / "frames.npz", image=images.astype(np.float32))
    (partial / "pass.json").write_text(json.dumps(record, indent=1))
    _contact_sheet(images, record, partial / "frames.png")
    partial.rename(out)
    inside = sum(max(abs(a) for a in f["attitude_observation"]["euler_zyx_deg"]) <= 45.0 for f in record["frames"])
    print(
        f"{len(meta)} frames in {out} ({inside} within the networks' 45 deg range); upload frames.npz with "
        "normalised=true and each frame's observed_at from pass.json"
    )
    return 0


def _contact_sheet(images: Any, record: dict[str, Any], path: Path, most: int = 12) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    pick = np.unique(np.linspace(0, len(images) - 1, min(most, len(images))).round().astype(int))
    cols = min(6, len(pick))
    rows = -(-len(pick) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(2.2 * cols, 2.75 * rows), squeeze=False)
    for ax in axes.ravel():
        ax.axis("off")
    for ax, k in zip(axes.ravel(), pick, strict=False):
        f = record["frames"][k]
        z, y, x = f["attitude_observation"]["euler_zyx_deg"]
        ax.imshow(images[k], cmap="gray", vmin=0, vmax=1)
        snr = "noise-free" if f["snr_db"] is None else f"{f['snr_db']:.0f} dB"
        ax.set_title(f"{f['observed_at'][11:19]}Z, {snr}\n{z:.0f} / {y:.0f} / {x:.0f} deg", fontsize=7)
    w = record["window"]
    fig.suptitle(
        f"pass {w['rise'][:19]} to {w['set'][11:19]} UTC, max elevation {w['max_elevation_deg']:.0f} deg "
        "(frame time, SNR, attitude in its observation frame)",
        fontsize=9,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def cmd_pass(args: argparse.Namespace) -> int:
    """Fuse a simulated (or any) pass: each frame estimated and fitted, placed in LVLH, fused."""

    from app.errors import InputError
    from inference.errors import InferenceError

    folder = Path(args.folder)
    rec = _read_json(str(folder / "pass.json"))
    try:
        data = (folder / "frames.npz").read_bytes()
    except OSError as exc:
        raise CliError(f"cannot read {folder / 'frames.npz'}: {exc.strerror}") from None
    try:
        times = [datetime.fromisoformat(f["observed_at"]) for f in rec["frames"]]
    except (KeyError, TypeError, ValueError):
        raise CliError(
            f"{folder / 'pass.json'} has no frames with an observed_at each (write it with gsa simulate --pass)"
        ) from None
    if args.server:
        return _pass_on_server(args, data, rec)
    from app.services import passes as pass_svc
    from app.services import uploads as upload_svc

    settings = _settings()
    request = rec.get("plan_request")
    if args.plan:
        request, _ = _plan_for_pass(_read_json(args.plan))
    if request is None:
        raise CliError("give --plan PLAN.json: the pass record names no plan")
    try:
        est, checker = _local_models(args, settings)
        uploads = upload_svc.decode(data, "frames.npz")
        if len(uploads) != len(times):
            raise CliError(f"frames.npz holds {len(uploads)} frames and pass.json {len(times)} times")
        fused = pass_svc.fit_and_fuse(
            est=est,
            checker=checker,
            uploads=uploads,
            plan_request=request,
            observed_at=times,
            normalised=True,
            names=[f"frame {k}" for k in range(len(times))],
        )
        result = fused.result
    except InputError as exc:
        raise CliError(_input_line(exc)) from None
    except InferenceError as exc:
        raise CliError(str(exc)) from None
    if args.json:
        print(json.dumps(result, indent=1, default=str))
    else:
        _print_pass(result, rec)
        print(f"{len(times)} frames: estimated and fitted in {fused.fit_s:.1f} s, fused in {fused.fuse_s:.1f} s")
    if args.plot:
        _plot_pass(result, rec, args.plot)
        print(f"plot written to {args.plot}", file=sys.stderr)
    return 0


def _pass_on_server(args: argparse.Namespace, data: bytes, rec: dict[str, Any]) -> int:

    if not args.plan_id:
        raise CliError("--server needs --plan-id: the stored plan the pass belongs to")
    form: dict[str, Any] = {
        "plan_id": args.plan_id,
        "normalised": "true",
        "observed_at": [f["observed_at"] for f in rec["frames"]],
    }
    if args.target:
        form["target"] = args.target
    r = call_server(args, "POST", "/v1/passes", files={"files": ("frames.npz", data)}, data=form, timeout=300)
    body = r.json()
    if args.json:
        print(json.dumps(body, indent=1))
    else:
        print(f"pass {body['id']}:")
        _print_pass(body, rec)
    if args.plot:
        _plot_pass(body, rec, args.plot)
    return 0


def _truth_lvlh(rec: dict[str, Any], k: int) -> Any:
    from inference.frames import rotation_matrix

    f = rec["frames"][k]
    return rotation_matrix(*f["attitude_lvlh"]["euler_zyx_deg"]) if "attitude_lvlh" in f else None


def _print_pass(result: dict[str, Any], rec: dict[str, Any]) -> None:
    import numpy as np

    from inference.frames import rotation_matrix
    from inference.fusion import angle_deg

    z, y, x = result["attitude_lvlh"]["euler_zyx_deg"]
    bz, by, bx = result["uncertainty_deg"]
    print(
        f"fused, body to LVLH: z {z:.2f} y {y:.2f} x {x:.2f} deg (90 % bound {bz:.2f} / {by:.2f} / {bx:.2f}); "
        f"{result['used']} frames used, {result['rejected']} rejected"
        f"{'' if result.get('trusted', True) else '; NOT TRUSTED'}"
    )
    print(result["stability"])
    errors = []
    for f in result["frames"]:
        truth = _truth_lvlh(rec, f["index"]) if f["index"] < len(rec.get("frames", [])) else None
        err = ""
        if truth is not None:
            errors.append(angle_deg(rotation_matrix(*f["attitude_lvlh"]["euler_zyx_deg"]), truth))
            err = f", {errors[-1]:.2f} deg from the truth"
        why = f["rejected_because"] or ""
        state = "used" if f["used"] else f"rejected: {why if len(why) <= 90 else why[:87] + '...'}"
        at = f["observed_at"] if isinstance(f["observed_at"], str) else f["observed_at"].isoformat()
        print(f"  {at[11:19]} {f['branch']:<12} residual {f['residual_deg']:.2f} deg{err}; {state}")
    truth = _truth_lvlh(rec, 0) if rec.get("frames") else None
    if errors and truth is not None and result["stable"]:
        off = angle_deg(rotation_matrix(z, y, x), truth)
        print(
            f"against the simulated truth: fused {off:.3f} deg, single frames' median {float(np.median(errors)):.3f} deg"
        )


def _plot_pass(result: dict[str, Any], rec: dict[str, Any], path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    def when(v: Any) -> datetime:
        return v if isinstance(v, datetime) else datetime.fromisoformat(v)

    times = [when(f["observed_at"]) for f in result["frames"]]
    t0 = min(times)
    t = np.array([(x - t0).total_seconds() for x in times])
    each = np.array([f["attitude_lvlh"]["euler_zyx_deg"] for f in result["frames"]])
    bounds = np.array(
        [[b if b is not None else np.nan for b in f["quality"]["uncertainty_deg"]] for f in result["frames"]]
    )
    used = np.array([f["used"] for f in result["frames"]])
    fused = np.array(result["attitude_lvlh"]["euler_zyx_deg"])
    ub = np.array(result["uncertainty_deg"])
    fig, axes = plt.subplots(3, 1, figsize=(8, 7.5), sharex=True)
    for i, (ax, name) in enumerate(zip(axes, ("z (yaw)", "y (pitch)", "x (roll)"), strict=True)):
        ax.errorbar(t[used], each[used, i], yerr=bounds[used, i], fmt="o", ms=4, capsize=2, label="frame (90 % bound)")
        span = each[used, i] if used.any() else each[:, i]
        pad = max(1.0, 0.5 * float(np.ptp(span)), 3.0 * float(np.nanmax(bounds[used, i])) if used.any() else 1.0)
        lo, hi = float(span.min()) - pad, float(span.max()) + pad
        if (~used).any():  # rejected frames far off are drawn at the edge, so the used ones keep their scale
            ax.plot(t[~used], np.clip(each[~used, i], lo, hi), "x", color="tab:red", ms=7, label="rejected (clipped)")
        ax.set_ylim(lo, hi)
        if result["stable"]:
            ax.axhline(fused[i], color="tab:orange", label="fused")
            ax.axhspan(fused[i] - ub[i], fused[i] + ub[i], color="tab:orange", alpha=0.2)
        truth = [_truth_lvlh(rec, f["index"]) for f in result["frames"] if f["index"] < len(rec.get("frames", []))]
        if truth and truth[0] is not None and len(truth) == len(t):
            from inference.frames import euler_from_matrix

            tv = np.array([euler_from_matrix(r) for r in truth])
            ax.plot(t, tv[:, i], "k--", lw=1, label="truth")
        ax.set_ylabel(f"{name}, deg")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8, ncol=4)
    axes[-1].set_xlabel(f"seconds after {t0:%Y-%m-%d %H:%M:%S} UTC")
    fig.suptitle(
        f"pass attitude, body to LVLH: {result['used']} used, {result['rejected']} rejected; "
        f"{'stable' if result['stable'] else 'TURNING'}",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


# The inference commands: name, module of inference (its add_arguments and run), help.
INFERENCE_COMMANDS = (
    ("simulate", "simulation.dataset", "simulate a labelled ISAR data set (or --preview a few frames)"),
    ("train", "training.train", "train UNet++ and Swin on a simulated data set"),
    ("finetune", "training.finetune", "fine-tune Swin's last stage of a trained run on cached features (CPU)"),
    ("export", "export", "export a training run to ONNX with a model card"),
    ("calibrate", "trust", "fit the attitude checks' thresholds and 90-percent bounds on fresh frames (trust.json)"),
    ("compare", "evaluation.compare", "set training runs side by side: Swin's test error per epoch"),
    ("evaluate", "evaluation.evaluate", "the paper's Tables 4 and 7 for the ONNX models"),
)


def command_name(argv: list[str]) -> str | None:
    """Return the subcommand ``argv`` names (its first word that is not an option), if any."""
    return next((a for a in argv if not a.startswith("-")), None)


def build_parser(load: str | None = None) -> argparse.ArgumentParser:
    """Build gsa's parser; only the inference command ``load`` gets its real arguments (and imports its module)."""
    p = argparse.ArgumentParser(prog="gsa", description="GSA-ISAR: GSA scene planning and ISAR attitude estimation")
    sub = p.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("serve", help="migrate the database and start the API")
    s.add_argument("--host")
    s.add_argument("--port", type=int)
    s.add_argument("--workers", type=int, default=1)
    s.set_defaults(func=cmd_serve)
    db = sub.add_parser("db", help="database maintenance")
    dbs = db.add_subparsers(dest="db_cmd", required=True)
    dbs.add_parser("upgrade", help="apply all migrations").set_defaults(func=cmd_db_upgrade)
    k = sub.add_parser("keys", help="API keys")
    ks = k.add_subparsers(dest="keys_cmd", required=True)
    kc = ks.add_parser("create", help="create a key and print it once")
    kc.add_argument("name")
    kc.add_argument("--operator", help="operator the key belongs to (default: NAME)")
    ks.add_parser("list", help="list keys")
    kr = ks.add_parser("revoke", help="revoke a key")
    kr.add_argument("id")
    k.set_defaults(func=cmd_keys)
    pl = sub.add_parser("plan", help="plan a GSA scene from a JSON request (the body of POST /v1/plans)")
    pl.add_argument("file", nargs="?", help="the request (JSON); or --example")
    pl.add_argument("--example", choices=sorted(EXAMPLE_PLANS), help="plan a shipped example (examples/*.json)")
    add_client_options(pl, "plan on a running service (stored there; a station may be named)")
    pl.add_argument("--json", action="store_true", help="print JSON instead of a table")
    pl.add_argument("--plot", metavar="PNG", help="draw ground track, elevation and alignment error")
    pl.add_argument(
        "--export",
        metavar="DIR",
        help="also write the plan as opm.txt, oem.txt (CCSDS KVN), plan.czml, plan.geojson, access.csv and pointing.csv",
    )
    pl.set_defaults(func=cmd_plan)
    for noun, func in (("plans", cmd_plans), ("estimates", cmd_estimates)):
        c = sub.add_parser(noun, help=f"your {noun} stored on the service (list, show)")
        cs = c.add_subparsers(dest=f"{noun}_cmd", required=True)
        cl = cs.add_parser("list", help=f"your {noun}, newest first")
        cl.add_argument("--limit", type=int, default=20)
        cl.add_argument("--json", action="store_true")
        if noun == "plans":
            cl.add_argument("--target-name", help="only this target's plans")
        else:
            cl.add_argument("--plan-id", help="only the estimates tied to this plan")
        cw = cs.add_parser("show", help=f"one of your {noun}")
        cw.add_argument("id")
        cw.add_argument("--json", action="store_true")
        for q in (cl, cw):
            add_client_options(q, "the service")
        c.set_defaults(func=func)
    st = sub.add_parser("stations", help="your named stations on the service (list, show, add, delete)")
    sts = st.add_subparsers(dest="stations_cmd", required=True)
    stl = sts.add_parser("list", help="your stations by name")
    stl.add_argument("--limit", type=int, default=100)
    stl.add_argument("--json", action="store_true")
    sta = sts.add_parser("add", help="store a station from a JSON file (name, latitude_deg, longitude_deg, mask, ...)")
    sta.add_argument("file")
    for verb in ("show", "delete"):
        sts.add_parser(verb, help=f"{verb} one station").add_argument("name")
    for q in sts.choices.values():
        add_client_options(q, "the service")
    st.set_defaults(func=cmd_stations)
    ac = sub.add_parser("access", help="access windows from a JSON request (the body of POST /v1/access-windows)")
    ac.add_argument("file")
    ac.add_argument("--json", action="store_true")
    ac.set_defaults(func=cmd_access)
    for name, module, help in INFERENCE_COMMANDS:
        if name == load:
            p_inf = add_inference_command(sub, name, module, help)
            if name == "simulate":  # --pass needs the planner's geometry, so it lives here, not in inference
                add_pass_arguments(p_inf)
                p_inf.set_defaults(func=_pass_or_data_set(p_inf.get_default("func")))
        else:
            # Not asked for: a stand-in that keeps `gsa --help` from importing torch and the simulator.
            sub.add_parser(name, help=help, add_help=False)
    es = sub.add_parser("estimate", help="estimate the attitude in one ISAR frame (.npy, .npz, PNG, TIFF)")
    es.add_argument("file")
    es.add_argument("--models", help="model directory (default: GSA_MODEL_DIR or the shipped models)")
    es.add_argument("--resample", action="store_true", help="resample a frame of another size")
    es.add_argument(
        "--frame", type=int, help="frame K of a stack (.npz [N, H, W], e.g. a gsa simulate shard, read as it is)"
    )
    es.add_argument(
        "--normalised",
        action="store_true",
        help="the frame is already normalised (a frame of a gsa simulate data set): take it as sent",
    )
    add_client_options(es)
    es.add_argument("--plot", metavar="PNG", help="draw the input and the enhanced frame with the fitted outline")
    es.add_argument("--no-refine", action="store_true", help="answer Swin's estimate, without the fit")
    es.add_argument("--target", help="the target the frame shows (default GSA_DEFAULT_TARGET: tiangong-like)")
    es.add_argument("--plan-id", help="with --server: one of your plans, to place the attitude in LVLH and J2000")
    es.add_argument("--observed-at", help="with --server and --plan-id: when the frame was observed (ISO 8601 UTC)")
    es.add_argument("--range-cell-m", type=float, help="the frame's range cell (rows) in metres: resample in metres")
    es.add_argument("--cross-range-cell-m", type=float, help="the frame's cross-range cell (columns) in metres")
    es.set_defaults(func=cmd_estimate)
    ps = sub.add_parser("pass", help="fuse a pass's frames into one attitude in the target's orbital frame (LVLH)")
    ps.add_argument("folder", help="a folder with frames.npz and pass.json, as gsa simulate --pass writes")
    ps.add_argument("--plan", metavar="PLAN.json", help="the plan request the pass belongs to (default: pass.json's)")
    ps.add_argument("--models", help="model directory (default: GSA_MODEL_DIR or the shipped models)")
    ps.add_argument("--target", help="the target the frames show (default GSA_DEFAULT_TARGET: tiangong-like)")
    ps.add_argument("--json", action="store_true", help="print the fused pass as JSON")
    ps.add_argument("--plot", metavar="PNG", help="draw each frame's LVLH attitude with its bound beside the fused one")
    add_client_options(ps, "send it to a running service (POST /v1/passes) instead")
    ps.add_argument("--plan-id", help="with --server: the stored plan the pass belongs to")
    ps.set_defaults(func=cmd_pass)
    return p


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    args = build_parser(command_name(argv)).parse_args(argv)
    try:
        return int(args.func(args))
    except CliError as exc:
        print(f"gsa: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
