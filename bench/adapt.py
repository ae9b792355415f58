"""Adapting to another radar: learning curves of ``gsa adapt`` on stand-in radars the networks never saw.

Writes the "Adapting to another radar" section of BENCHMARKS.md and bench/adapt.png; every point's
figures are kept in bench/results/adapt-STANDIN.json (a point already there is not run again: the
command resumes). Run with ``python -m bench.adapt --standin po`` (and ``--standin harsh``); each
point with frames is an adaptation of the shipped set on this CPU (up to ``--minutes``), then the
service's whole answer (networks, fit, checks, bounds) on held-out scenes.

Stand-in radars, since no real frames exist here:

* ``po``: physical optics on the target's facets (inference/simulation/po.py), smooth (no roughness): bright
  specular returns and little else, the hardest case;
* ``po-rough``: the same with roughness 0.3 (a diffuse term per facet: what blankets and edges give a real
  target);
* ``harsh``: scattering centres outside every range of the robust preset the networks' data varied
  (specular lobes x3, edge returns x2, 8 dominant point returns, 1.5 px blur).

Scenes. A GSA scene labels the frames of one pass, whose attitudes lie along one sweep: here each
scene has a centre drawn in +-30 deg and its frames spaced along a random direction over +-12 deg
about it (1 deg jitter, within +-45), SNR -3..15 dB, and the optical label off the truth by
0.2 deg (1-sigma, per axis). The adaptation's scenes (seed 7000) and the held-out test scenes
(seed 9000, 10 scenes x 10 frames) never share a scene; the test set is never seen by the
adaptation, its validation included. Our own frames: 100 fresh default frames (seed 9100).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from bench.common import machine, stored_results
from bench.sections import replace_section
from inference.frames import normalise_frame
from inference.labelled import LabelledFrames
from inference.rotations import geodesic_deg
from inference.simulation.radar import Imager, Radar
from inference.simulation.scene import DEFAULT_SCATTERING, Scattering, simulate
from inference.simulation.targets import tiangong_like

TITLE = "Adapting to another radar"
STANDINS = {
    "po": Scattering(physics="po"),
    "po-rough": Scattering(physics="po", roughness=0.3),
    "harsh": Scattering(lobe_scale=3.0, edge_gain=2.0, dominant=8, blur_px=1.5),
}
DESCRIBE = {
    "po": "physical optics, smooth (facets, ray-traced shadows)",
    "po-rough": "physical optics, roughness 0.3 (Lambert's diffuse term per facet)",
    "harsh": "scattering centres outside the robust preset (lobes x3, edges x2, 8 dominant returns, 1.5 px blur)",
    "own": "our own simulator's default frames",
}
POINTS = ((0, 0), (30, 3), (100, 5), (300, 10))
POOL_SCENES, POOL_PER_SCENE, POOL_SEED = 10, 30, 7000
TEST_SCENES, TEST_PER_SCENE, TEST_SEED = 10, 10, 9000
OWN_SEED, OWN_N = 9100, 100
LABEL_SIGMA_DEG = 0.2
GOOD_DEG = 2.0  # an answer this close to the truth is a good one (the share of them flagged is reported)
RESULTS = Path("bench/results")
PLOT = Path("bench/adapt.png")


def _log(msg: str) -> None:
    print(f"bench.adapt: {msg}", file=sys.stderr, flush=True)


def scene_frames(
    scattering: Scattering, n_scenes: int, per_scene: int, seed: int, radar: Radar | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str]]:
    """Frames of ``n_scenes`` scenes (see the module's text): normalised frames, truths, optical labels, scenes."""
    radar = radar or Radar()
    imager = Imager(radar)
    model = tiangong_like()
    rng = np.random.default_rng(seed)
    frames, truth, scenes = [], [], []
    for s in range(n_scenes):
        centre = rng.uniform(-30.0, 30.0, 3)
        way = rng.normal(size=3)
        way /= np.linalg.norm(way)
        for t in np.linspace(-12.0, 12.0, per_scene):
            a = np.clip(centre + t * way + rng.normal(0.0, 1.0, 3), -45.0, 45.0)
            snr = float(rng.uniform(-3.0, 15.0))
            f = simulate(
                model, imager, (float(a[0]), float(a[1]), float(a[2])), snr, int(rng.integers(2**62)), scattering
            )
            frames.append(normalise_frame(np.abs(f.image)))
            truth.append(a)
            scenes.append(f"scene-{seed}-{s}")
    truth_arr = np.array(truth)
    labels = truth_arr + rng.normal(0.0, LABEL_SIGMA_DEG, truth_arr.shape)
    return np.stack(frames), truth_arr, labels, scenes


def subset(pool: tuple[Any, ...], frames: int, scenes: int) -> LabelledFrames:
    """``frames`` labelled frames from the first ``scenes`` scenes of the pool, evenly along each sweep."""
    images, _, labels, names = pool
    per = frames // scenes
    idx = []
    for s in range(scenes):
        rows = np.arange(s * POOL_PER_SCENE, (s + 1) * POOL_PER_SCENE)
        idx.extend(rows[np.unique(np.linspace(0, POOL_PER_SCENE - 1, per).round().astype(int))])
    k = np.array(idx)
    return LabelledFrames(
        images[k].astype(np.float32),
        labels[k],
        tuple(names[i] for i in k),
        tuple(f"{names[i]}-{i:04d}.npz" for i in k),
        np.full(len(k), np.nan),
        np.full(len(k), LABEL_SIGMA_DEG),
        tuple(None for _ in k),
    )


def evaluate(model_dir: Path, frames: np.ndarray, truth: np.ndarray) -> dict[str, Any]:
    """The service's answer on these frames: accuracy, trust and bounds against the truth."""
    from inference.runtime import Estimator
    from inference.trust import load_checkers

    est = Estimator.load(model_dir)
    checker = load_checkers(model_dir, est.img_size).get("tiangong-like")
    res = est.estimate(frames)
    checks = checker.check_many(frames, res.enhanced, res.angles_deg, search_enhancer=est.search_enhancer)
    fitted = np.array([c.angles_deg for c in checks])
    geo = geodesic_deg(fitted, truth)
    trusted = np.array([c.quality.trusted for c in checks])
    bound = np.array([c.quality.uncertainty_deg for c in checks], float)
    inside = np.abs(fitted - truth) <= bound
    good = geo <= GOOD_DEG
    return {
        "frames": len(frames),
        "geodesic_median_deg": round(float(np.median(geo)), 3),
        "geodesic_p95_deg": round(float(np.percentile(geo, 95)), 3),
        "beyond_10_deg": round(float(np.mean(geo > 10.0)), 4),
        "trusted": round(float(np.mean(trusted)), 4),
        # per axis, as the bounds are stated (each a 90 % bound on one angle), averaged over z, y, x; and on any axis
        "trusted_outside_bound": round(float(np.mean(~inside[trusted])), 4) if trusted.any() else None,
        "trusted_outside_any_bound": round(float(np.mean(~inside[trusted].all(axis=1))), 4) if trusted.any() else None,
        "bound_coverage": [round(float(v), 4) for v in inside.mean(axis=0)],
        "good_flagged": round(float(np.mean(~trusted[good])), 4) if good.any() else None,
        "trusted_over_5_deg": int(np.sum(trusted & (geo > 5.0))),
        "trusted_over_10_deg": int(np.sum(trusted & (geo > 10.0))),
        "swin_median_deg": round(float(np.median(geodesic_deg(res.angles_deg, truth))), 3),
    }


def variant_key(stored: dict[str, Any], point: str, note: str) -> str:
    """The key FRAMES/SCENES/N of a variant of ``point`` with this note: the stored one that has it (the run
    resumes), else the first N free."""
    n = 1
    while f"{point}/{n}" in stored and stored[f"{point}/{n}"].get("note") != note:
        n += 1
    return f"{point}/{n}"


def run_point(
    standin: str,
    frames: int,
    scenes: int,
    minutes: float,
    work: Path,
    data: dict[str, Any],
    name: str,
    options: dict[str, Any] | None = None,
) -> dict[str, Any]:
    from inference.runtime import DEFAULT_MODEL_DIR
    from inference.training.adapt import AdaptOptions, adapt

    model_dir = DEFAULT_MODEL_DIR
    row: dict[str, Any] = {"frames": frames, "scenes": scenes}
    if frames:
        out = work / f"{standin}-{name}"
        t0 = time.perf_counter()
        rec = adapt(
            DEFAULT_MODEL_DIR,
            subset(data["pool"], frames, scenes),
            out,
            AdaptOptions(max_minutes=minutes, **(options or {})),
        )
        row.update(
            cpu_minutes=rec["cpu_minutes"],
            minutes=round((time.perf_counter() - t0) / 60.0, 2),
            chosen_epoch=rec["chosen_epoch"],
            epochs=len(rec["history"]) - 1,
            recalibrated=rec["calibration"].get("recalibrated", False),
            export=rec.get("export"),
        )
        model_dir = out
    _log(f"{standin} {frames}/{scenes}: evaluating on the held-out scenes and on our own frames")
    row["held_out"] = evaluate(model_dir, *data["test"])
    row["own"] = evaluate(model_dir, *data["own"])
    return row


def rescore_point(standin: str, row: dict[str, Any], work: Path, data: dict[str, Any], name: str) -> dict[str, Any]:
    """A kept point scored again with the code as it is now: its adapted weights as they were, trust recalibrated on
    the same held-out scenes of the adaptation (``recalibrate``, as ``gsa adapt`` does), then ``evaluate``."""
    from inference.runtime import DEFAULT_MODEL_DIR, Estimator
    from inference.simulation.targets import builtin_target
    from inference.training.adapt import recalibrate
    from inference.trust import card_radar_and_target

    model_dir = DEFAULT_MODEL_DIR
    row = dict(row)
    if row["frames"]:
        model_dir = work / f"{standin}-{name}"
        if not (model_dir / "model_card.json").is_file():
            raise SystemExit(f"bench.adapt: {model_dir} is not kept: run the point without --rescore")
        held = set(
            json.loads((model_dir / "model_card.json").read_text())["adaptation"]["labelled"]["validation_scenes"]
        )
        lab = subset(data["pool"], row["frames"], row["scenes"])
        val = lab.subset(np.flatnonzero([s in held for s in lab.scenes]))
        radar, target = card_radar_and_target(model_dir, Estimator.load(model_dir).img_size)
        row["calibration"] = recalibrate(model_dir, val, radar, builtin_target(target), DEFAULT_MODEL_DIR)
    _log(f"{standin} {row['frames']}/{row['scenes']}: scoring again on the held-out scenes and on our own frames")
    row["held_out"] = evaluate(model_dir, *data["test"])
    row["own"] = evaluate(model_dir, *data["own"])
    row["rescored"] = datetime.now(UTC).date().isoformat()
    return row


def section(results: dict[str, dict[str, Any]]) -> list[str]:
    lines = [
        f"## {TITLE}",
        "",
        f"Machine: {machine()}. Date: {datetime.now(UTC).date().isoformat()}. Command: `python -m bench.adapt --standin "
        "STANDIN` (bench/adapt.py says how the frames and scenes are made; results in bench/results/adapt-STANDIN.json).",
        "Each row with frames adapts the shipped set (`gsa adapt`, its defaults unless the row says otherwise: "
        "UNet++ fine-tuned on the labelled frames mixed 1:1 with simulated ones, Swin kept, split by scene, the "
        "weights with the lowest held-out plus own-frame loss, trust recalibrated on the held-out scenes of the "
        "adaptation where they hold 20 frames or more, else the base calibration kept; up to 20 minutes of epochs, "
        "`--minutes`) on this CPU; then the service's whole answer (networks, fit, checks, bounds) on "
        f"{TEST_SCENES} test scenes x {TEST_PER_SCENE} frames no adaptation saw, and on {OWN_N} of our own frames. "
        f"Labels are the truth plus {LABEL_SIGMA_DEG} deg of optical error. Good answer: within {GOOD_DEG:g} deg.",
        "",
        "| stand-in radar | labelled frames / scenes | CPU min | geodesic median / p95 (deg) | beyond 10 deg | trusted | "
        "trusted outside their 90 % bound (per axis) | trusted over 5 / 10 deg off | bound coverage z / y / x | "
        "good answers flagged | own frames: median / trusted |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for standin, rows in results.items():
        for key in sorted(rows, key=lambda k: tuple(int(v) for v in k.split("/"))):
            r = rows[key]
            h, o = r["held_out"], r["own"]
            tob = "-" if h["trusted_outside_bound"] is None else f"{100 * h['trusted_outside_bound']:.0f} %"
            gf = "-" if h["good_flagged"] is None else f"{100 * h['good_flagged']:.0f} %"
            cov = " / ".join(f"{100 * v:.0f}" for v in h["bound_coverage"])
            wrong = f"{h['trusted_over_5_deg']} / {h['trusted_over_10_deg']}" if "trusted_over_5_deg" in h else "-"
            label = f"{r['frames']} / {r['scenes']}" + (f" ({r['note']})" if r.get("note") else "")
            lines.append(
                f"| {DESCRIBE[standin]} | {label} | {r.get('cpu_minutes', 0):.1f} | "
                f"{h['geodesic_median_deg']:.2f} / {h['geodesic_p95_deg']:.1f} | {100 * h['beyond_10_deg']:.0f} % | "
                f"{100 * h['trusted']:.0f} % | {tob} | {wrong} | {cov} % | {gf} | {o['geodesic_median_deg']:.2f} / "
                f"{100 * o['trusted']:.0f} % |"
            )
    lines += [
        "",
        "Goal (issue 42): with at most 100 labelled frames from at most 5 scenes and 30 CPU minutes, held-out median "
        "within 1.5x of our own frames', at most 2 % beyond 10 deg, at least 95 % of trusted answers inside their "
        "bounds, at most 20 % of good answers flagged, our own frames no worse.",
        "",
        "What it shows: recalibrating trust on the radar's own held-out scenes is what moves the trust figures; with "
        "10 or 30 labelled frames the held-out scenes hold under 20 frames, so the base calibration is kept and almost "
        "nothing is trusted. Two calibration choices matter as much as the networks. The library search's trigger "
        "stays the base set's (`Calibration.search_iou_min`): the rows marked 'search trigger recalibrated with the "
        "trust threshold' lowered it with the trust threshold (to 0.71 on rough physical optics, 0.28 on smooth), the "
        "search stopped finding the answers Swin got wrong, and on the same adapted weights the trigger alone moves 26 "
        "% beyond 10 deg to 2 %. And each threshold is calibrated on the answers it judges (design/measurements.md, "
        "'Thresholds from the answers they judge'): at the base trigger most of this radar's frames are searched, and "
        "the doubt threshold and bounds fitted without them flagged half the good answers; the rows scored again on "
        "2026-12-06 (`--rescore`: the same weights, recalibrated) show it, e.g. harsh 100/5 good answers flagged 55 -> "
        "32 %, trusted 29 -> 54 %, rough physical optics 100/5 42 -> 15 %, 46 -> 72 %, with no answer over 10 deg off "
        "trusted in either. Every row but rough physical optics 10/2 and 30/3 (their adapted sets were not kept; they "
        "kept the base calibration) is scored with the code of that date. On harsh the curve falls at every size (0 / "
        "10 / 30 / 100 / 300 frames: 6.66 / 2.67 / 2.64 / 1.53 / 1.18 deg); on rough physical optics 100 and 300 frames "
        "give 1.24 and 1.28 deg (3 and 2 % beyond 10 deg). These rows ran 20 minutes of epochs, 41-50 CPU minutes, "
        "over the goal's 30. Within the 30 (harsh 100/5 with 11 minutes of epochs, `--minutes 11 --note ...`: 24.0 CPU "
        "minutes, the fit's renderer a third faster by then) the held-out loss was lowest at epoch 5 of 11 (Swin 7.7 "
        "deg on the held-out scenes): 2.61 deg, 3 % beyond 10 deg, 5 % trusted, 90 % of good answers flagged; the "
        "20-minute run chose epoch 21 of 22. Run again on 2026-12-06 with bounds fitted at the conformal rank "
        "(design/measurements.md, 'Bounds fitted on few frames'; 25.4 CPU minutes, 13 epochs, the last chosen: Swin 5.3 "
        "deg on the held-out scenes): 2.09 deg, 5 % beyond 10 deg, 37 % trusted, 47 % of good answers flagged; the same "
        "weights recalibrated with the empirical quantile (`--rescore`): 41 % trusted, 43 % flagged, trusted outside "
        "their bound 7 % (6 % at the rank), coverage 84 / 84 / 91 % (85 / 84 / 94 %). Again once the base set's search "
        "trigger was set apart from its trust threshold (0.972 against 0.943; design/measurements.md, 'The search "
        "re-examines the worst-fitting network answers'), which the adapted set keeps (26.5 CPU minutes, 13 epochs, "
        "the last chosen, Swin 5.2 deg): 1.95 deg, p95 6.8, 3 % beyond 10 deg, 34 % trusted, trusted outside their "
        "bound 4 % per axis (9 % on any axis), 54 % of good answers flagged, 96 of the 100 held-out frames searched. "
        "Of the 28 good answers flagged, 21 have a 90 % bound over 5 deg (the good answers' widest bound is 4.8 deg at "
        "the median: this radar's honest bound sits at the limit) and 13 another attitude within the 0.002 margin. The "
        "single runs differ by more than the changes between them (2.61, 2.09 and 1.95 deg): the epochs are capped by "
        "wall time, so a faster or busier machine trains another number of them. Since 2026-12-06 late a set "
        "recalibrated on another radar chooses its network path's bound limit (5-10 deg) and ambiguity margin "
        "(0.002-0) on its held-out frames (`inference/trust.py:network_limits`: the pair that trusts the most correct "
        "answers and no answer over 5 deg off that the base pair does not; design/measurements.md, 'The network "
        "path's limits chosen on the radar's own frames'). Harsh 100/5 again (26.4 CPU minutes; the 14th epoch did "
        "not improve, so the weights are epoch 13's, as before): the held-out frames chose 10 deg and 0.002, and on "
        "the test scenes 60 % are trusted (34), 29 % of good answers flagged (54), 5.6 % of trusted answers outside "
        "their bound per axis (3.9), 3 trusted over 5 deg off (5.8-6.8 deg, each within its x bound of 5.7-7.8 deg), "
        "none over 10. Rough physical optics 100/5 within the budget (26.3 CPU minutes, 13 epochs, the last chosen): "
        "its held-out frames kept 5 deg and 0.002 (the base pair trusted all 34 correct answers there); 1.22 deg, p95 "
        "7.4, 3 % beyond 10 deg, 77 % trusted, 4.8 % of them outside their bound per axis, 13 % of good answers "
        "flagged, none over 5 deg off trusted, our own frames 0.37 deg and 90 % trusted. That point meets the "
        "issue's two trust goals within the budget; beyond 10 deg (3 %) and the median (1.22 deg against 1.5 x 0.32) "
        "do not. On smooth physical optics 100 frames from 5 scenes take the median from 28.6 to 18.4 deg "
        "only (71 % beyond 10 deg; int8 refused, UNet++ in float16) and nothing is trusted. The accuracy goal is not "
        "met on any stand-in at this budget. Of the trust goals, within the budget: good answers flagged 13 % (rough "
        "physical optics) and 29 % (harsh; goal 20 %), where what is left on harsh is mostly another attitude fitting "
        "within 0.002 (12 of 15); trusted answers outside a bound 4.8 % and 5.6 % per axis (goal 5 %): bounds fitted "
        "on the 40 frames of 2 held-out scenes under-cover the next scenes' worst axis. Two ways to train more within "
        "the budget, harsh 100/5 (2026-12-07, design/measurements.md, 'Adapting on windows of the frame'): UNet++ on "
        "128 px windows about the target (`--crop-px 128`, 600 steps against about 200) gave 1.52 deg, 66 % trusted, "
        "19 % of good answers flagged, but our own frames 0.52 deg and one answer over 10 deg off trusted; UNet++ at "
        "1e-4 (`--lr-unet 1e-4`) 1.67 deg, 42 % trusted, 47 % flagged, our own frames 0.40 deg. Both buy this radar's "
        "accuracy with ours, so the defaults stay (neither passed the int8 export; no harsh set here has: UNet++ "
        "served in float16); at equal seconds whole-frame steps drew the better silhouette on both radars, so the "
        "windows' median may be the run's as much as theirs. A third way changes nothing that is learnt: UNet++ "
        "trains channels-last since 2026-12-07 (design/measurements.md, 'bf16 training on the CPU'), 35 s an "
        "epoch against 50, so 19 epochs fit the 11 minutes instead of 13. The validation score was lowest at epoch "
        "13 again, and that set gave 1.88 deg, p95 8.2, 4 % beyond 10 deg, 61 % trusted, 8 % of trusted answers "
        "outside a bound per axis, 35 % of good answers flagged, our own frames 0.31 deg and 89 % trusted: within "
        "the spread of single runs at this point (1.88-2.61 deg), its trust figures worse on the same 40 "
        "calibration frames. On harsh, past about epoch 13 more steps of the same kind do not lower the held-out "
        "loss. On rough physical optics, where the score was still falling when the 11 minutes ended (epoch 13 of "
        "13 chosen), they do: 19 epochs, the last chosen, 24.7 CPU minutes: 1.12 deg (from 1.22), p95 5.6 (7.4), "
        "2 % beyond 10 deg (3 %; the goal's 2 % met), 79 % trusted, 13 % of good answers flagged, our own frames "
        "0.37 deg and 89 % trusted; but 9.7 % of trusted answers outside a bound per axis (4.8 %), coverage 98 / 86 "
        "/ 85 %, and 2 trusted over 5 deg off (none over 10): bounds fitted on 40 frames of 2 scenes under-cover "
        "the next scenes again. The median stays over twice the goal's 0.48 deg on both radars, and what would "
        "move it is a better silhouette, not its loss or a learnt look of the radar (design/measurements.md, 'An "
        "adapted set's error is its silhouette's'). Nor can a rule on 2 held-out scenes make the bounds steady: the "
        "scale a scene needs varies about 2x from scene to scene (design/measurements.md, 'Bounds fitted on few "
        "frames'). Holding 3 of the 5 scenes out (`--validation-share 0.5`, 2026-12-07), so 60 frames calibrate "
        "and 40 train: coverage 85 / 95 / 93 % (rough physical optics) and 98 / 97 / 96 % (harsh), trusted answers "
        "outside a bound 7.0 and 5.6 % per axis (9.7 and 8.2 % with 2 held out), but the answers poorer, rough "
        "physical optics 1.48 deg (1.12) with 4 trusted over 5 deg off, and on harsh 24 % trusted, 63 % of good "
        "answers flagged (2.08 deg). Five scenes do not give both the training and a steady calibration; more "
        "labelled scenes would.",
        "",
        "Physical optics made right off specular (issue 71; 2026-12-08, Intel Xeon 2-core VM, the rows marked so): "
        "the fast path's false facet texture is gone, so smooth physical optics now shows only flashes and edges. As "
        "that issue expected, the smooth stand-in became harder: the shipped set 62.2 deg (28.6 on the old frames), "
        "100 % beyond 10 deg, and 100 labelled frames from 5 scenes within the budget (25.9 CPU minutes) reach 25.1 "
        "deg (18.4 on the old frames with 20 minutes), 91 % beyond 10 deg, nothing trusted: a silhouette network "
        "cannot learn an outline the frame does not hold. The rough stand-in, whose diffuse term now lights the "
        "whole skin evenly, is a little harder at 100 / 5 (1.51 deg, p95 5.8, 2 % beyond 10 deg; 1.12-1.48 on the "
        "old frames within the budget) and easier for the shipped set's trust: 55 % trusted at 0 / 0 (10 %), "
        "p95 12.2 deg (25.0). Within the budget the rough point meets the 2 % beyond 10 deg; its median, trusted "
        "answers outside their bound (9 % per axis) and good answers flagged (24 %) do not meet the goal.",
        "",
        f"![learning curves]({PLOT.name})",
        "",
    ]
    return lines


def plot(results: dict[str, dict[str, Any]]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    for i, (standin, rows) in enumerate(results.items()):
        keys = sorted((k for k in rows if not rows[k].get("note")), key=lambda k: tuple(int(v) for v in k.split("/")))
        n = [max(rows[k]["frames"], 3) for k in keys]
        h = [rows[k]["held_out"] for k in keys]
        c = f"C{i}"  # one colour a stand-in in every panel
        axes[0].plot(n, [r["geodesic_median_deg"] for r in h], "o-", color=c, label=f"{standin}: median")
        axes[0].plot(n, [r["geodesic_p95_deg"] for r in h], "s--", color=c, label=f"{standin}: p95")
        axes[1].plot(n, [100 * r["beyond_10_deg"] for r in h], "o-", color=c, label=standin)
        axes[2].plot(n, [100 * r["trusted"] for r in h], "o-", color=c, label=f"{standin}: trusted")
        axes[2].plot(
            n,
            [np.nan if r["good_flagged"] is None else 100 * r["good_flagged"] for r in h],
            "s--",
            color=c,
            label=f"{standin}: good flagged",
        )
        # The latest run of gsa adapt's defaults within the goal's 30 CPU minutes (a variant row), a star at its size.
        within = [
            k
            for k in rows
            if rows[k].get("note") and not rows[k].get("options") and 0 < rows[k].get("cpu_minutes", 99) <= 30.0
        ]
        if within:
            w = rows[max(within, key=lambda k: (rows[k].get("rescored", ""), int(k.split("/")[-1])))]
            hw, nw = w["held_out"], w["frames"]
            axes[0].plot([nw], [hw["geodesic_median_deg"]], "*", ms=12, color=c, label=f"{standin}: within 30 CPU min")
            axes[1].plot([nw], [100 * hw["beyond_10_deg"]], "*", ms=12, color=c)
            axes[2].plot([nw], [100 * hw["trusted"]], "*", ms=12, color=c)
            if hw["good_flagged"] is not None:
                axes[2].plot([nw], [100 * hw["good_flagged"]], "*", ms=12, mfc="none", color=c)
    own = next(iter(results.values()))
    base = own[min(own, key=lambda k: int(k.split("/")[0]))]["own"]["geodesic_median_deg"]
    axes[0].axhline(base, color="grey", lw=0.8, ls=":", label="own frames, shipped set")
    axes[0].set_yscale("log")
    axes[0].set_ylabel("held-out geodesic error (deg)")
    axes[1].set_ylabel("held-out answers beyond 10 deg (%)")
    axes[2].set_ylabel("%")
    for ax in axes:
        ax.set_xscale("log")
        ax.set_xlabel("labelled frames (0 plotted at 3)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    axes[0].legend(fontsize=6, ncol=2, loc="upper right")
    axes[0].set_ylim(top=axes[0].get_ylim()[1] * 8)  # room for the legend above the curves
    fig.suptitle("gsa adapt: the shipped set adapted to a stand-in radar, scored on held-out scenes")
    fig.tight_layout()
    fig.savefig(PLOT, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.adapt", description=__doc__.split("\n")[0])
    p.add_argument("--standin", choices=sorted(STANDINS), required=True)
    p.add_argument("--points", default=",".join(f"{f}/{s}" for f, s in POINTS), help="FRAMES/SCENES,... to run")
    p.add_argument("--minutes", type=float, default=20.0, help="each adaptation's max_minutes (default 20)")
    p.add_argument("--work", default="/tmp/gsa-bench-adapt", help="where the adapted sets go")
    p.add_argument("--lr-unet", type=float, help="UNet++'s rate (default: gsa adapt's)")
    p.add_argument("--crop-px", type=int, help="train on windows of this many pixels (default: gsa adapt's)")
    p.add_argument(
        "--validation-share", type=float, help="share of the labelled frames held out, by scenes (default: gsa adapt's)"
    )
    p.add_argument(
        "--note",
        help="run the points as a variant of the stored rows (e.g. another --minutes), kept beside them as "
        "FRAMES/SCENES/N with this note in the table",
    )
    p.add_argument("--report-only", action="store_true", help="write the section and plot from the stored results")
    p.add_argument(
        "--rescore",
        action="store_true",
        help="score the stored points again with the code as it is now: their adapted sets (kept under --work) "
        "recalibrated on the same held-out scenes, weights unchanged",
    )
    args = p.parse_args(argv)
    RESULTS.mkdir(parents=True, exist_ok=True)
    path = RESULTS / f"adapt-{args.standin}.json"
    stored: dict[str, Any] = json.loads(path.read_text()) if path.is_file() else {}
    if not args.report_only:
        sc = STANDINS[args.standin]
        _log(
            f"simulating the {args.standin} frames: pool {POOL_SCENES}x{POOL_PER_SCENE}, test {TEST_SCENES}x{TEST_PER_SCENE}"
        )
        pool = scene_frames(sc, POOL_SCENES, POOL_PER_SCENE, POOL_SEED)
        test = scene_frames(sc, TEST_SCENES, TEST_PER_SCENE, TEST_SEED)
        own = scene_frames(DEFAULT_SCATTERING, OWN_N // 10, 10, OWN_SEED)
        data = {"pool": pool, "test": (test[0], test[1]), "own": (own[0], own[1])}
        for point in args.points.split(","):
            if args.note and not args.rescore:
                point = variant_key(stored, point, args.note)
            name = point.replace("/", "-")  # the adapted set's folder under --work
            if args.rescore:
                if point not in stored:
                    raise SystemExit(f"bench.adapt: no stored point {point} to score again")
                stored[point] = rescore_point(args.standin, stored[point], Path(args.work), data, name)
            elif point in stored:
                continue
            else:
                frames, scenes = (int(v) for v in point.split("/")[:2])
                _log(f"point {point}")
                flags = (
                    ("lr_unet", args.lr_unet),
                    ("crop_px", args.crop_px),
                    ("validation_share", args.validation_share),
                )
                options = {k: v for k, v in flags if v is not None}
                stored[point] = run_point(
                    args.standin, frames, scenes, args.minutes, Path(args.work), data, name, options
                )
                stored[point]["options"] = options
                if args.note:
                    stored[point]["note"] = args.note
            path.write_text(json.dumps(stored, indent=1))
    results = stored_results(RESULTS, "adapt", STANDINS)
    replace_section(TITLE, section(results))
    plot(results)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
