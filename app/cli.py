"""The ``gsa`` command line: serve, db, keys, plan, access.

Bad input prints one line on stderr and exits with status 2.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import sys
import time
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
    from app.core.observability import configure_logging, uvicorn_log_config
    from app.services.estimation import sweep_blobs

    settings = _settings()
    configure_logging(settings.log_level, settings.log_json)
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
    log_config = uvicorn_log_config(settings.log_level) if settings.log_json else None
    from app.core.server import raise_descriptor_limit, uvicorn_limits

    raise_descriptor_limit(settings.max_connections)
    uvicorn.run("app.main:create_app", factory=True, host=host, port=port, workers=args.workers,
                log_level=settings.log_level, log_config=log_config, access_log=not settings.log_json,
                **uvicorn_limits(settings))  # fmt: skip
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


def _validation_line(exc: ValidationError) -> str:
    err = exc.errors()[0]
    loc = ".".join(str(x) for x in err["loc"])
    return f"{loc}: {err['msg']}"


def cmd_plan(args: argparse.Namespace) -> int:
    from app.errors import InputError
    from app.schemas import PlanCreate
    from app.services.planning import run_plan

    try:
        req = PlanCreate.model_validate(_read_json(args.file))
        plan, result = run_plan(req)
    except ValidationError as exc:
        raise CliError(_validation_line(exc)) from None
    except InputError as exc:
        raise CliError(".".join(str(x) for x in exc.loc) + ": " + exc.message) from None
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print(format_plan(result))
    if args.plot:
        from planner.plot import plot_plan

        plot_plan(plan, args.plot, title=f"{req.target.name} / {req.observer.name} / {req.ground_station.name}")
        print(f"plot written to {args.plot}", file=sys.stderr)
    return 0


def cmd_access(args: argparse.Namespace) -> int:
    from app.errors import InputError
    from app.schemas import AccessCreate
    from app.services.planning import run_access

    try:
        result = run_access(AccessCreate.model_validate(_read_json(args.file)))
    except ValidationError as exc:
        raise CliError(_validation_line(exc)) from None
    except InputError as exc:
        raise CliError(".".join(str(x) for x in exc.loc) + ": " + exc.message) from None
    print(json.dumps(result, indent=2) if args.json else format_windows(result["access_windows"]))
    return 0


def format_windows(windows: list[dict[str, Any]]) -> str:
    lines = [f"{'rise (UTC)':<27} {'culmination':<27} {'set':<27} {'max el':>7} {'min range':>10}"]
    for w in windows:
        lines.append(
            f"{w['rise'][:26]:<27} {w['culmination'][:26]:<27} {w['set'][:26]:<27} "
            f"{w['max_elevation_deg']:7.2f} {w['min_range_km']:9.1f}k"
        )
    return "\n".join(lines)


def format_plan(r: dict[str, Any]) -> str:
    """Return a plan as a readable report."""
    out = [f"epoch {r['epoch']}, {r['duration_days']:g} days, elements read as {r['reading']}"]
    out.append(f"\n{len(r['access_windows'])} access windows")
    out.append(format_windows(r["access_windows"][:10]))
    if len(r["access_windows"]) > 10:
        out.append(f"... and {len(r['access_windows']) - 10} more")
    out.append(f"\n{len(r['candidates'])} candidates (best of each pass, ranked by miss)")
    out.append(f"{'#':>3} {'T_access (UTC)':<27} {'dHa km':>8} {'dHp km':>8} {'miss km':>9} {'node':>5} {'sunlit':>7}")
    for k, c in enumerate(r["candidates"][:15]):
        out.append(
            f"{k:3d} {c['t_access'][:26]:<27} {c['delta_ha_km']:8.1f} {c['delta_hp_km']:8.1f} "
            f"{c['miss_km']:9.3f} {c['node']:>5} {('yes' if c['feasibility']['sunlit'] else 'no'):>7}"
        )
    ch = r.get("chosen")
    if ch:
        out.append(
            f"\nchosen: T_access {ch['t_access']}, dHa {ch['delta_ha_km']:.1f} km, dHp {ch['delta_hp_km']:.1f} km"
        )
        out.append(f"  node-line miss with the changed observer's own propagation: {ch['miss_km']:.3f} km")
        out.append(f"  height change costs {r['alignment_dv_m_s']:.1f} m/s")
    ph = r.get("phasing")
    if ph:
        v = ph["verification"]
        out.append(
            f"phasing: burn {ph['t_burn']} ({ph['revolutions_before']} rev before), "
            f"dv {ph['dv_total_m_s']:.1f} m/s, RTN [{', '.join(f'{x:.1f}' for x in ph['dv_rtn_m_s'])}] m/s"
        )
        out.append(
            f"verification (numerical J2): {v['miss_km'] * 1000:.1f} m from the aim point at T_access "
            f"(two-body Lambert alone: {v['two_body_miss_km']:.1f} km), relative speed {v['relative_speed_km_s']:.2f} km/s"
        )
        out.append(
            f"encounter: stand-off {v['standoff_km']:.2f} km, separation {v['separation_km']:.3f} km at T_access, "
            f"closest approach {v['closest_approach_km']:.3f} km at {v['closest_approach_time']}, "
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


def add_inference_command(sub: Any, name: str, module: str, help: str) -> None:
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


def _print_checked(body: dict[str, Any], prefix: str = "") -> None:
    """Print an estimate's answer (the API's JSON shape): attitude, network answer, quality, alternatives."""
    z, y, x = body["attitude"]["euler_zyx_deg"]
    q = body["attitude"]["quaternion_wxyz"]
    kind = "fitted" if body.get("refined") else "network"
    print(f"{prefix}z {z:.2f} y {y:.2f} x {x:.2f} deg ({kind}, observation frame, target {body.get('target')}); "
          f"quaternion w x y z {', '.join(f'{v:.5f}' for v in q)}")  # fmt: skip
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
        print(f"also fits: z {az:.2f} y {ay:.2f} x {ax:.2f} deg ({alt['distance_deg']:.0f} deg away, "
              f"IoU {alt['silhouette_iou']:.3f}, fit {alt['fit_gap']:+.4f})")  # fmt: skip


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
    if args.server:
        import httpx

        form = {"resample": str(args.resample).lower(), "normalised": str(args.normalised).lower(),
                "refine": str(not args.no_refine).lower()}  # fmt: skip
        if args.target:
            form["target"] = args.target
        if args.plan_id:
            form["plan_id"] = args.plan_id
        if args.observed_at:
            form["observed_at"] = args.observed_at
        if cells:
            form.update({"range_cell_m": str(cells[0]), "cross_range_cell_m": str(cells[1])})
        try:
            r = httpx.post(
                args.server.rstrip("/") + "/v1/estimates", files={"file": (Path(args.file).name, data)},
                data=form, headers={"X-API-Key": args.api_key or ""}, timeout=60,
            )  # fmt: skip
        except httpx.HTTPError as exc:
            raise CliError(f"cannot reach {args.server}: {exc}") from None
        if r.status_code >= 400:
            raise CliError(f"server answered {r.status_code}: {r.text[:300]}")
        body = r.json()
        _print_checked(body, prefix=f"estimate {body['id']}: ")
        return 0
    from app.services import estimation as svc
    from inference.runtime import Estimator
    from inference.trust import load_checkers

    settings = _settings()
    try:
        model_dir = args.models or settings.model_dir
        est = Estimator.load(model_dir)
        checkers = load_checkers(model_dir, est.img_size, settings.target_model, settings.target_scale,
                                 settings.default_target)  # fmt: skip
        checker = checkers.get(args.target or checkers.default)
        (up,) = svc.decode(data, Path(args.file).name, allow_stack=False)
        model_cells = (checker.radar.range_cell_m, checker.radar.cross_range_cell_m)
        frame = svc.prepare(up, est.img_size, args.resample, args.normalised, cells, model_cells)
        res = est.estimate(frame[None])
        t0 = time.perf_counter()
        checked = checker.check(frame, res.enhanced[0], res.angles_deg[0] if checker.networks else None,
                                not args.no_refine)  # fmt: skip
        t_fit = time.perf_counter() - t0
    except InputError as exc:
        raise CliError(exc.message) from None
    except InferenceError as exc:
        raise CliError(str(exc)) from None
    body = {**svc.checked_json(checked), "target": checker.model.name}
    _print_checked(body)
    print(f"UNet++ {res.timings_s['unetpp'] * 1000:.0f} ms, Swin {res.timings_s['swin'] * 1000:.0f} ms, "
          f"fit and checks {t_fit * 1000:.0f} ms")  # fmt: skip
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
        ax[1].set_title(f"enhanced; fitted z {z:.1f} y {y:.1f} x {x:.1f} deg\n"
                        f"IoU {q.silhouette_iou:.3f}, {'trusted' if q.trusted else 'NOT trusted'}", fontsize=10)  # fmt: skip
        for a in ax:
            a.contour(outline, levels=[0.5], colors=["#ff7f0e"], linewidths=0.9)
            a.set_xlabel("cross-range cell (column)")
            a.set_ylabel("range cell (row)")
        fig.tight_layout()
        fig.savefig(args.plot, dpi=100)
        plt.close(fig)
        print(f"plot written to {args.plot}", file=sys.stderr)
    return 0


# The inference commands: name, module of inference (its add_arguments and run), help.
INFERENCE_COMMANDS = (
    ("simulate", "dataset", "simulate a labelled ISAR data set (or --preview a few frames)"),
    ("train", "train", "train UNet++ and Swin on a simulated data set"),
    ("finetune", "finetune", "fine-tune Swin's last stage of a trained run on cached features (CPU)"),
    ("export", "export", "export a training run to ONNX with a model card"),
    ("calibrate", "trust", "fit the attitude checks' thresholds and 90-percent bounds on fresh frames (trust.json)"),
    ("compare", "compare", "set training runs side by side: Swin's test error per epoch"),
    ("evaluate", "evaluate", "the paper's Tables 4 and 7 for the ONNX models"),
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
    pl.add_argument("file")
    pl.add_argument("--json", action="store_true", help="print JSON instead of a table")
    pl.add_argument("--plot", metavar="PNG", help="draw ground track, elevation and alignment error")
    pl.set_defaults(func=cmd_plan)
    ac = sub.add_parser("access", help="access windows from a JSON request (the body of POST /v1/access-windows)")
    ac.add_argument("file")
    ac.add_argument("--json", action="store_true")
    ac.set_defaults(func=cmd_access)
    for name, module, help in INFERENCE_COMMANDS:
        if name == load:
            add_inference_command(sub, name, module, help)
        else:
            # Not asked for: a stand-in that keeps `gsa --help` from importing torch and the simulator.
            sub.add_parser(name, help=help, add_help=False)
    es = sub.add_parser("estimate", help="estimate the attitude in one ISAR frame (.npy, .npz, PNG, TIFF)")
    es.add_argument("file")
    es.add_argument("--models", help="model directory (default: GSA_MODEL_DIR or the shipped models)")
    es.add_argument("--resample", action="store_true", help="resample a frame of another size")
    es.add_argument("--normalised", action="store_true",
                    help="the frame is already normalised (a frame of a gsa simulate data set): take it as sent")  # fmt: skip
    es.add_argument("--server", help="send it to a running service instead, e.g. http://127.0.0.1:8000")
    es.add_argument("--api-key")
    es.add_argument("--plot", metavar="PNG", help="draw the input and the enhanced frame with the fitted outline")
    es.add_argument("--no-refine", action="store_true", help="answer Swin's estimate, without the fit")
    es.add_argument("--target", help="the target the frame shows (default GSA_DEFAULT_TARGET: tiangong-like)")
    es.add_argument("--plan-id", help="with --server: one of your plans, to place the attitude in LVLH and J2000")
    es.add_argument("--observed-at", help="with --server and --plan-id: when the frame was observed (ISO 8601 UTC)")
    es.add_argument("--range-cell-m", type=float, help="the frame's range cell (rows) in metres: resample in metres")
    es.add_argument("--cross-range-cell-m", type=float, help="the frame's cross-range cell (columns) in metres")
    es.set_defaults(func=cmd_estimate)
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
