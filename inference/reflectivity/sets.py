"""A map in a model set: ``gsa adapt --map`` (beside the fine-tuning) and ``gsa adapt --map-only`` (the base set's
networks kept as they are, the map added).

``add_map(model_dir, frames)`` builds the map from labelled frames with the set's own radar, target and UNet++ (whose
silhouettes decide whether the silhouette prior helps on this radar), writes ``reflectivity.npz`` beside the
networks and lists it in the card (``files.map``, and ``map``: what was chosen and measured). ``map_only`` copies the
base set to a new folder first, so the served set never changes under a build.
"""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path
from typing import Any

from inference.errors import InferenceError
from inference.files import write_json
from inference.labelled import FramesArg, read_labelled
from inference.reflectivity.build import build_map
from inference.reflectivity.serve import MAP_ROLE, save_map


def _say(text: str) -> None:
    print(f"adapt: {text}", file=sys.stderr, flush=True)


def add_map(model_dir: str | Path, frames: FramesArg, seed: int = 0, target: str | None = None) -> dict[str, Any]:
    """Build the map of ``model_dir``'s set from ``frames`` and add it to the set; returns the map's record."""
    from inference.fit import Renderer
    from inference.runtime import Estimator
    from inference.simulation.targets import builtin_target
    from inference.trust import card_radar_and_target

    d = Path(model_dir)
    est = Estimator.load(d)
    radar, trained = card_radar_and_target(d, est.img_size)
    if target is not None and target != trained:
        raise InferenceError(
            f"target {target!r}: the set's networks and map are of {trained!r}; give that target", field="target"
        )
    model = builtin_target(trained)
    labelled = read_labelled(frames, est.img_size, (radar.range_cell_m, radar.cross_range_cell_m))
    _say(f"building the reflectivity map from {len(labelled)} labelled frames ({len(set(labelled.scenes))} scenes)")
    enhanced = est.enhance(labelled.frames) if est.enhances else None
    renderer = Renderer(model, radar) if enhanced is not None else None
    rmap = build_map(model, radar, labelled, enhanced, renderer, seed, _say)
    entry = save_map(rmap, d)
    card_path = d / "model_card.json"
    card = json.loads(card_path.read_text())
    card.setdefault("files", {})[MAP_ROLE] = entry
    card["map"] = rmap.record
    write_json(card_path, card)
    cal = rmap.record["calibration"]
    _say(
        f"map written ({rmap.record['cpu_seconds']:.0f} CPU s): held-out median {cal['median_deg']:.2f} deg from "
        f"{cal['frames']} frames"
        + (
            ""
            if cal["informative"]
            else ": no closer than their starts, so the set answers on the silhouette as without a map (label more "
            "scenes, or adapt the networks)"
        )
    )
    return rmap.record


def map_only(
    base_dir: str | Path, frames: FramesArg, out_dir: str | Path, seed: int = 0, target: str | None = None
) -> dict[str, Any]:
    """A new set in ``out_dir``: the base set's files as they are, and a map built from ``frames``. A failure leaves
    no ``out_dir`` behind."""
    base, out = Path(base_dir), Path(out_dir)
    if out.exists() and any(out.iterdir()):
        raise InferenceError(f"--out {out} is not empty: write the new set to a new folder", field="out")
    partial = out.with_name(out.name + ".partial")
    shutil.rmtree(partial, ignore_errors=True)
    try:
        shutil.copytree(base, partial)
        card_path = partial / "model_card.json"
        card = json.loads(card_path.read_text())
        card.pop("version", None)  # the service numbers the new version
        card.get("files", {}).pop(MAP_ROLE, None)
        card.pop("map", None)
        write_json(card_path, card)
        record = add_map(partial, frames, seed, target)
        if out.exists():
            out.rmdir()
        partial.rename(out)
    finally:
        shutil.rmtree(partial, ignore_errors=True)
    return record


def summary(record: dict[str, Any]) -> dict[str, Any]:
    """What a version's summary says of its map."""
    cal = record.get("calibration") or {}
    return {
        "frames": record.get("frames"),
        "scenes": record.get("scenes"),
        "look": record.get("look"),
        "objective": record.get("objective"),
        "held_out_median_deg": cal.get("median_deg"),
        "held_out_p90_deg": cal.get("p90_deg"),
        "informative": cal.get("informative", True),
        "cpu_seconds": record.get("cpu_seconds"),
        "list_sha256": record.get("list_sha256"),
    }
