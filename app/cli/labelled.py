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
    import numpy as np

    from app.errors import DOMAIN_ERRORS
    from app.services.scenes import scene_for
    from inference.labelled import frame_files, parse_time, read_folder
    from scene.labels import plan_resolver

    times = []
    for f in frame_files(folder):
        with np.load(f, allow_pickle=False) as z:
            if "observed_at" in z.files:
                times.append(parse_time(str(z["observed_at"]), f))
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
            args.labelled = read_with_plan(args.frames, args.plan, size, (radar.range_cell_m, radar.cross_range_cell_m))
        return int(command(args))

    return run
