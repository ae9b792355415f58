"""The reflectivity map on stand-in radars: ``gsa adapt --map-only`` from labelled frames, the service's answers after.

Writes the "Adapting to another radar: the reflectivity map" section of BENCHMARKS.md and bench/reflectivity.png;
every point's figures are kept in bench/results/reflectivity-STANDIN.json (a point already there is not run again).
Run with ``python -m bench.reflectivity --standin harsh`` (and ``--standin po``).

``--passes`` runs the pass rows instead: ``PASS_SCENES`` further scenes of ``PASS_FRAMES`` frames each (seed
``PASS_SEED``), every frame of a scene given the truth turned by one body rotation of ``PASS_START_DEG`` (what a
pass's silhouette fusion leaves: one attitude off, seen through each frame's observation frame), then refined together
as the service refines a still pass (``ImageRefiner.refine_still``'s search, ``refine_pass``) under the 100 / 5
point's map, and, for contrast, each frame refined alone from the same start as a single frame is. The map's own
pass check (``pass_informative``, which gates the service's pass refinement) is reported beside.

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
PASS_POINT = (100, 5)
PASS_SCENES, PASS_FRAMES, PASS_SEED, PASS_START_DEG = 8, 20, 9500, 3.0
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


def run_passes(standin: str, work: Path) -> dict[str, Any]:
    """The pass rows (see the module's text) under the PASS_POINT map in ``work`` (built there if missing)."""
    import numpy as np

    from inference.reflectivity.build import PASS_FRAMES as REFINED
    from inference.reflectivity.build import spread
    from inference.reflectivity.refine import refine, refine_pass, turned_by
    from inference.reflectivity.serve import REFINE_RENDERS, load_refiner
    from inference.reflectivity.sets import map_only
    from inference.rotations import geodesic_deg, so3_exp
    from inference.runtime import DEFAULT_MODEL_DIR
    from inference.trust import card_radar_and_target

    sc = STANDINS[standin]
    frames_n, scenes_n = PASS_POINT
    out = work / f"{standin}-{frames_n}-{scenes_n}"
    built = None
    if not (out / "reflectivity.npz").is_file():
        _log(f"{standin}: building the {frames_n}/{scenes_n} map")
        if out.exists():
            import shutil

            shutil.rmtree(out)
        pool = scene_frames(sc, POOL_SCENES, POOL_PER_SCENE, POOL_SEED)
        built = map_only(DEFAULT_MODEL_DIR, subset(pool, frames_n, scenes_n), out)
    radar, target = card_radar_and_target(out)
    refiner = load_refiner(out, radar, target)
    assert refiner is not None
    cal = refiner.map.record.get("calibration") or {}
    _log(f"{standin}: simulating {PASS_SCENES} passes of {PASS_FRAMES} frames")
    images, truth, _, _ = scene_frames(sc, PASS_SCENES, PASS_FRAMES, PASS_SEED)
    rng = np.random.default_rng(PASS_SEED)
    passes, singles, seconds = [], [], []
    for s in range(PASS_SCENES):
        rows = slice(s * PASS_FRAMES, (s + 1) * PASS_FRAMES)
        w = rng.normal(size=3)
        starts = turned_by(truth[rows], so3_exp(np.radians(PASS_START_DEG) * w / np.linalg.norm(w)))
        t0 = time.perf_counter()
        idx = spread(PASS_FRAMES, REFINED)  # as the service refines a pass: its frames spread to REFINED
        turn, _, _ = refine_pass(refiner.map, images[rows][idx].astype(float), starts[idx], refiner.objective)
        seconds.append(time.perf_counter() - t0)
        passes.append(float(np.median(geodesic_deg(turned_by(starts, turn), truth[rows]))))
        for k in range(PASS_FRAMES):
            one = refine(
                refiner.map, images[rows][k], {"start": starts[k]}, refiner.objective, max_renders=REFINE_RENDERS
            )
            singles.append(float(geodesic_deg(one[0].angles_deg, truth[rows][k])[0]))
        _log(
            f"{standin}: pass {s}: {passes[-1]:.2f} deg in {seconds[-1]:.0f} s; its frames alone {np.median(singles[-PASS_FRAMES:]):.2f}"
        )
    p, f = np.array(passes), np.array(singles)
    return {
        "map": f"{frames_n}/{scenes_n}",
        "map_built_cpu_s": None if built is None else built.get("cpu_seconds"),
        "pass_informative": cal.get("pass_informative"),
        "pass_check_median_deg": cal.get("pass_median_deg"),
        "frame_informative": cal.get("informative", True),
        "passes": PASS_SCENES,
        "frames_per_pass": PASS_FRAMES,
        "frames_refined_together": REFINED,
        "start_deg": PASS_START_DEG,
        "pass_errors_deg": [round(x, 3) for x in passes],
        "pass_median_deg": round(float(np.median(p)), 3),
        "pass_p90_deg": round(float(np.percentile(p, 90)), 3),
        "passes_within_1_deg": round(float(np.mean(p <= 1.0)), 3),
        "single_median_deg": round(float(np.median(f)), 3),
        "single_p90_deg": round(float(np.percentile(f, 90)), 3),
        "seconds_per_pass": round(float(np.mean(seconds)), 1),
    }


def pass_section(results: dict[str, dict[str, Any]]) -> list[str]:
    rows = {k: v["passes"] for k, v in results.items() if "passes" in v}
    if not rows:
        return []
    lines = [
        f"### A still pass refined on its images together ({PASS_FRAMES} frames, one attitude {PASS_START_DEG:g} deg off)",
        "",
        "`python -m bench.reflectivity --standin STANDIN --passes`. Each pass's frames start from the truth turned by "
        "one body rotation (what a silhouette fusion leaves), and are refined together as the service refines a "
        "still pass (one turn searched on 10 of its frames spread over it, applied to all 20); the same starts "
        "refined frame by frame for contrast. The map is the 100 / 5 point's, rebuilt with its pass check (its CPU "
        "seconds in bench/results). Seconds per pass with nothing else running on the machine.",
        "",
        "| stand-in | passes | pass median | pass p90 | passes within 1 deg | frames alone: median | p90 | "
        "the build's own pass check | s / pass |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for standin, r in rows.items():
        check = (
            "not run (map built before it)"
            if r["pass_informative"] is None
            else f"{r['pass_check_median_deg']:.2f} deg: "
            + ("refines passes" if r["pass_informative"] else "passes left to the silhouettes")
        )
        lines.append(
            f"| {standin} | {r['passes']} | {r['pass_median_deg']:.2f} | {r['pass_p90_deg']:.2f} | "
            f"{100 * r['passes_within_1_deg']:.0f} % | {r['single_median_deg']:.2f} | {r['single_p90_deg']:.2f} | "
            f"{check} | {r['seconds_per_pass']:.0f} |"
        )
    return [*lines, ""]


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
        for key in sorted((k for k in rows if k != "passes"), key=lambda k: (int(k.split("/")[0]), k)):
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
    return lines + pass_section(results)


def plot(results: dict[str, dict[str, Any]]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9.5, 4))
    for standin, rows in results.items():
        points = [r for k, r in rows.items() if k != "passes"]
        pts = sorted((r["frames"], r["held_out"]["geodesic_median_deg"]) for r in points)
        (line,) = ax.plot([p[0] for p in pts], [p[1] for p in pts], "o-", label=f"{standin}: median")
        if "passes" in rows:
            pr = rows["passes"]
            ax.plot(
                [PASS_POINT[0]],
                [pr["pass_median_deg"]],
                "*",
                ms=13,
                color=line.get_color(),
                label=f"{standin}: {pr['frames_per_pass']}-frame pass from {pr['start_deg']:g} deg off, median",
            )
        p95 = sorted((r["frames"], r["held_out"]["geodesic_p95_deg"]) for r in points)
        ax.plot([p[0] for p in p95], [p[1] for p in p95], "x--", alpha=0.6, label=f"{standin}: p95")
    ax.axhline(0.5, color="grey", lw=0.8, ls=":", label="goal: 0.5 deg median (scattering radars)")
    ax.set_yscale("log")
    ax.set_xlabel("labelled frames the map was built from (0: the shipped set)")
    ax.set_ylabel("held-out error (deg)")
    ax.set_title("The reflectivity map: the service's answers on held-out scenes")
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    fig.savefig(PLOT, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.reflectivity", description=__doc__.split("\n")[0])
    p.add_argument("--standin", choices=sorted(STANDINS), required=True)
    p.add_argument("--points", default=",".join(f"{f}/{s}" for f, s in POINTS), help="FRAMES/SCENES,... to run")
    p.add_argument("--work", default="/tmp/gsa-bench-reflectivity", help="where the sets with maps go")
    p.add_argument("--report-only", action="store_true", help="write the section and plot from the stored results")
    p.add_argument("--passes", action="store_true", help="run the pass rows (see the module's text)")
    args = p.parse_args(argv)
    RESULTS.mkdir(parents=True, exist_ok=True)
    path = RESULTS / f"reflectivity-{args.standin}.json"
    stored: dict[str, Any] = json.loads(path.read_text()) if path.is_file() else {}
    if args.passes and not args.report_only:
        stored["passes"] = run_passes(args.standin, Path(args.work))
        path.write_text(json.dumps(stored, indent=1))
    elif not args.report_only:
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
