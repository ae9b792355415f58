"""Labelled frames on the command line where a plan places them: ``gsa adapt --plan`` (frames labelled in J2000)."""

from __future__ import annotations

import argparse
from datetime import timedelta
from pathlib import Path
from typing import Any

from app.cli.common import CliError, input_line, read_json


def add_plan_argument(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--plan",
        metavar="PLAN_ID|REQUEST.json",
        help="the plan whose geometry places frames labelled with quaternion_j2000 and observed_at (a stored plan's "
        "id, from this machine's database, or a plan request file); frames labelled with angles_deg need none",
    )


def plan_request_of(source: str) -> dict[str, Any]:
    """A plan request from a file, or from a plan stored in this machine's database."""
    from app.cli.passes import _stored_plan_request

    path = Path(source)
    return read_json(str(path)) if path.is_file() else _stored_plan_request(source)[0]


def read_with_plan(folder: str, plan: str, size: int, model_cells_m: tuple[float, float]) -> Any:
    """Read a labelled folder, its J2000 labels placed by the plan's geometry over the frames' span."""

    from app.errors import DOMAIN_ERRORS
    from app.services.scenes import scene_for
    from inference.labelled import frame_files, observed_times, read_folder
    from scene.labels import plan_resolver

    try:
        times = observed_times([(f.name, f) for f in frame_files(folder)])
    except DOMAIN_ERRORS as exc:
        raise CliError(input_line(exc)) from None
    if not times:
        raise CliError(f"--plan: no frame of {folder} has an observed_at to place")
    try:
        scene = scene_for(plan_request_of(plan), min(times) - timedelta(seconds=1), max(times) + timedelta(seconds=1))
        return read_folder(folder, size, model_cells_m, resolve=plan_resolver(scene))
    except DOMAIN_ERRORS as exc:
        raise CliError(input_line(exc)) from None


def adapt_with_plan(command: Any) -> Any:
    """``gsa adapt``: with --plan, the folder is read here (the planner places it) and handed to the adaptation."""

    def run(args: argparse.Namespace) -> int:
        if args.plan:
            from inference.runtime import DEFAULT_MODEL_DIR, read_card
            from inference.trust import card_radar_and_target

            base = Path(args.base) if args.base else DEFAULT_MODEL_DIR
            size = int(read_card(base)["config"]["img_size"])
            radar, _ = card_radar_and_target(base, size)
            from inference.labelled import concatenated

            cells = (radar.range_cell_m, radar.cross_range_cell_m)
            args.labelled = concatenated([read_with_plan(f, args.plan, size, cells) for f in args.frames])
        return int(command(args))

    return run


def cmd_labelled(args: argparse.Namespace) -> int:
    """``gsa labelled add FOLDER --target T``, ``list --target T`` and ``delete --target T --scene S`` (or
    ``--all``) on the service."""
    import json

    from app.cli.common import call_server
    from inference.labelled import frame_files

    path = f"/v1/targets/{args.target}/labelled-frames"
    if args.labelled_cmd == "list":
        params: dict[str, Any] = {"limit": args.limit}
        if args.scene:
            params["scene"] = args.scene
        body = call_server(args, "GET", path, params=params).json()
        if args.json:
            print(json.dumps(body, indent=1))
            return 0
        _summary(body)
        for f in body["data"]:
            z, y, x = f["angles_deg"]
            print(f"  {f['id'][:8]}  {f['scene'][:24]:<24} {z:8.2f} {y:8.2f} {x:8.2f}  {f['name']}")
        total = body["per_scene"].get(args.scene, 0) if args.scene else body["count"]
        if total > len(body["data"]):
            print(f"  ... the newest {len(body['data'])} of {total} shown; --limit N shows more")
        return 0
    if args.labelled_cmd == "delete":
        if bool(args.scene) == bool(args.all):
            raise CliError("give --scene S (one scene's frames) or --all (every labelled frame of the target)")
        params = {"scene": args.scene} if args.scene else {"all": "true"}
        body = call_server(args, "DELETE", path, params=params).json()
        if args.json:
            print(json.dumps(body, indent=1))
            return 0
        print(f"deleted {body['deleted']} labelled frames of {body['target']}")
        _summary(body)
        return 0
    if not 1 <= args.batch <= 64:
        raise CliError(f"--batch {args.batch}: between 1 and 64 files a request")
    try:
        files = frame_files(args.folder)
    except ValueError as exc:
        raise CliError(str(exc)) from None
    form: dict[str, Any] = {}
    if args.plan_id:
        form["plan_id"] = args.plan_id
    if args.scene:
        form["scene"] = args.scene
    stored, already, body = 0, 0, {}
    for k in range(0, len(files), args.batch):
        part = files[k : k + args.batch]
        upload = [("files", (f.name, f.read_bytes())) for f in part]
        body = call_server(args, "POST", path, files=upload, data=form, timeout=300).json()
        stored += len(body["stored"])
        already += len(body["already_stored"])
        print(f"{k + len(part)}/{len(files)} files sent", file=__import__("sys").stderr)
    if args.json:
        print(json.dumps({**body, "stored": stored, "already_stored": already}, indent=1))
        return 0
    print(f"{stored} labelled frames stored, {already} already there")
    _summary(body)
    return 0


def _summary(body: dict[str, Any]) -> None:
    scenes = ", ".join(f"{k} ({v})" for k, v in sorted(body["per_scene"].items()))
    print(
        f"{body['count']} labelled frames of {body['target']} in {len(body['per_scene'])} scene(s): {scenes or '-'}; "
        f"attitude coverage {100 * body['coverage']:.1f} % of the networks' +-45 deg cube (15 deg cells)"
    )
