"""The reflectivity map on stand-in radars: ``gsa adapt --map-only`` from labelled frames, the service's answers after.

Writes the "Adapting to another radar: the reflectivity map" section of BENCHMARKS.md and bench/reflectivity.png;
every point's figures are kept in bench/results/reflectivity-STANDIN.json (a point already there is not run again).
Run with ``python -m bench.reflectivity --standin harsh`` (and ``--standin po``).

The stand-ins, their labelled scenes (pool seed 7000) and the held-out test scenes (seed 9000, 10 scenes x 10
frames) are ``bench.adapt``'s, so the rows compare with its fine-tuning rows. A point FRAMES/SCENES builds a map from
that many labelled frames of the first SCENES pool scenes onto the shipped networks, unchanged (no training), then
scores the service's whole answer (networks, silhouette fit, checks, then the refinement on the image) on the test
scenes. 0/0 is the shipped set as it is. Seconds per frame are the whole answer's on this machine, one frame at a time
on 2 threads (``Checker.check_many``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

from bench.adapt import (
    POOL_PER_SCENE,
    POOL_SCENES,
    POOL_SEED,
    STANDINS,
    TEST_PER_SCENE,
    TEST_SCENES,
    TEST_SEED,
    evaluate,
    scene_frames,
    subset,
)
from bench.common import machine, stored_results
from bench.sections import replace_section

TITLE = "Adapting to another radar: the reflectivity map"
POINTS = ((0, 0), (30, 3), (100, 5))
RESULTS = Path("bench/results")
PLOT = Path("bench/reflectivity.png")


def _log(msg: str) -> None:
    print(f"bench.reflectivity: {msg}", file=sys.stderr, flush=True)


def run_point(standin: str, frames: int, scenes: int, work: Path, data: dict[str, Any]) -> dict[str, Any]:
    from inference.reflectivity.sets import map_only
    from inference.runtime import DEFAULT_MODEL_DIR

    row: dict[str, Any] = {"frames": frames, "scenes": scenes}
    model_dir = DEFAULT_MODEL_DIR
    if frames:
        out = work / f"{standin}-{frames}-{scenes}"
        if out.exists():
            import shutil

            shutil.rmtree(out)
        record = map_only(DEFAULT_MODEL_DIR, subset(data["pool"], frames, scenes), out)
        row["map"] = {
            k: record[k] for k in ("look", "objective", "calibration", "trials", "seconds", "cpu_seconds", "sites")
        }
        model_dir = out
    _log(f"{standin} {frames}/{scenes}: the service's answers on the held-out scenes")
    t0 = time.perf_counter()
    row["held_out"] = evaluate(model_dir, *data["test"])
    row["seconds_per_frame"] = round((time.perf_counter() - t0) / len(data["test"][0]), 3)
    return row


def section(results: dict[str, dict[str, Any]]) -> list[str]:
    lines = [
        f"## {TITLE}",
        "",
        f"Measured on {machine()}. `python -m bench.reflectivity --standin STANDIN` (bench/reflectivity.py says how; "
        "results in bench/results/reflectivity-STANDIN.json). The shipped networks unchanged: `gsa adapt --map-only` "
        "learns the radar's reflectivity from the labelled frames, and the service refines each answer on the frame's "
        "likelihood under it. Held-out test scenes only (bench.adapt's 10 scenes x 10 frames, never seen by the build).",
        "",
        "| stand-in | labelled frames / scenes | map built (CPU s) | look, objective chosen | median | p95 | beyond 10 deg "
        "| trusted | trusted outside 90 % bound (per axis) | good (<= 2 deg) flagged | s / frame |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for standin, rows in results.items():
        for key in sorted(rows, key=lambda k: (int(k.split("/")[0]), k)):
            r = rows[key]
            h = r["held_out"]
            m = r.get("map")
            chosen = "none (the shipped set)"
            built = "-"
            if m:
                look, obj = m["look"], m["objective"]
                chosen = (
                    f"{look['window']} window, blur {look['blur_px']:g} px; silhouette weight "
                    f"{obj['silhouette_weight']:g}, texture {obj['shape'] if obj['shape'] else 'none'}"
                )
                built = f"{m['cpu_seconds']:.0f}"
                if not m["calibration"].get("informative", True):
                    chosen += (
                        f" (held-out answers {m['calibration']['median_deg']:.2f} deg from 2 deg starts: not "
                        "informative, the set answers on the silhouette)"
                    )
            lines.append(
                f"| {standin} | {r['frames']} / {r['scenes']} | {built} | {chosen} | {h['geodesic_median_deg']:.2f} "
                f"| {h['geodesic_p95_deg']:.1f} | {100 * h['beyond_10_deg']:.0f} % | {100 * h['trusted']:.0f} % | "
                + (f"{100 * h['trusted_outside_bound']:.1f} %" if h["trusted_outside_bound"] is not None else "-")
                + " | "
                + (f"{100 * h['good_flagged']:.0f} %" if h["good_flagged"] is not None else "-")
                + f" | {r['seconds_per_frame']:.2f} |"
            )
    lines += [""]
    return lines


def plot(results: dict[str, dict[str, Any]]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 4))
    for standin, rows in results.items():
        pts = sorted((r["frames"], r["held_out"]["geodesic_median_deg"]) for r in rows.values())
        ax.plot([p[0] for p in pts], [p[1] for p in pts], "o-", label=f"{standin}: median")
        p95 = sorted((r["frames"], r["held_out"]["geodesic_p95_deg"]) for r in rows.values())
        ax.plot([p[0] for p in p95], [p[1] for p in p95], "x--", alpha=0.6, label=f"{standin}: p95")
    ax.axhline(0.5, color="grey", lw=0.8, ls=":", label="goal: 0.5 deg median (scattering radars)")
    ax.set_yscale("log")
    ax.set_xlabel("labelled frames the map was built from (0: the shipped set)")
    ax.set_ylabel("held-out error (deg)")
    ax.set_title("The reflectivity map: the service's answers on held-out scenes")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(PLOT, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.reflectivity", description=__doc__.split("\n")[0])
    p.add_argument("--standin", choices=sorted(STANDINS), required=True)
    p.add_argument("--points", default=",".join(f"{f}/{s}" for f, s in POINTS), help="FRAMES/SCENES,... to run")
    p.add_argument("--work", default="/tmp/gsa-bench-reflectivity", help="where the sets with maps go")
    p.add_argument("--report-only", action="store_true", help="write the section and plot from the stored results")
    args = p.parse_args(argv)
    RESULTS.mkdir(parents=True, exist_ok=True)
    path = RESULTS / f"reflectivity-{args.standin}.json"
    stored: dict[str, Any] = json.loads(path.read_text()) if path.is_file() else {}
    if not args.report_only:
        sc = STANDINS[args.standin]
        todo = [pt for pt in args.points.split(",") if pt not in stored]
        if todo:
            _log(
                f"simulating the {args.standin} frames: pool {POOL_SCENES}x{POOL_PER_SCENE}, test {TEST_SCENES}x{TEST_PER_SCENE}"
            )
            pool = scene_frames(sc, POOL_SCENES, POOL_PER_SCENE, POOL_SEED)
            test = scene_frames(sc, TEST_SCENES, TEST_PER_SCENE, TEST_SEED)
            data = {"pool": pool, "test": (test[0], test[1])}
            for point in todo:
                frames, scenes = (int(v) for v in point.split("/"))
                _log(f"point {point}")
                stored[point] = run_point(args.standin, frames, scenes, Path(args.work), data)
                path.write_text(json.dumps(stored, indent=1))
    results = stored_results(RESULTS, "reflectivity", STANDINS)
    replace_section(TITLE, section(results))
    plot(results)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
