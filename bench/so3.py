"""Any attitude (issue 43): the service's answer on frames whose attitudes are uniform over all of SO(3), with the
coarse library spread over SO(3) as the search's starts, and the same on the +-45 deg cube (what must not get worse).

Run with ``python -m bench.so3 [--frames N]``; replaces the "Any attitude" section of BENCHMARKS.md. Frames: the
default target from our simulator (SNR -3..15 dB, a seed nothing was trained on), and the robust scattering preset;
the shipped models, the service's whole answer (networks, fit, library search, checks, alternatives), two fitting
threads. Also the library's spacing against its cost (``--spacings``).

Wrong branch: over 5 deg from the truth and nearer its near-mirror (z, -y, -x). Bound coverage: the share of
frames whose per-axis Euler error (wrapped) lies within the answer's 90 % bound.
"""

from __future__ import annotations

import argparse
import sys
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import branches, machine  # noqa: E402
from bench.sections import replace_section  # noqa: E402

TITLE = "Any attitude"
PLOT = Path("bench/so3.png")
SEED = 77_000


def _log(msg: str) -> None:
    print(f"bench.so3: {msg}", file=sys.stderr, flush=True)


MODELS: Path | None = None  # --models: a model folder instead of the shipped one


def _checker(calibration: str | None) -> tuple[Any, Any]:
    """The models (``MODELS``, default the shipped) and the default target's checker, under ``calibration`` (a
    trust.json; None: the models' own)."""
    from inference.runtime import DEFAULT_MODEL_DIR, Estimator
    from inference.trust import Calibration, load_checkers

    est = Estimator.load(MODELS or DEFAULT_MODEL_DIR)
    checker = load_checkers(MODELS or DEFAULT_MODEL_DIR, est.img_size).get("tiangong-like")
    if calibration:
        checker.calibration = Calibration.load(calibration)
    return est, checker


def flipped_trusted(calibration: str | None, n: int = 24) -> tuple[int, int, int, int]:
    """Cross-range-flipped frames (the bad-frame catalogue's): (trusted, of them read as the attitude they show, of them
    over 10 deg from it, frames).

    Read as shown: the answer turned half about the line of sight (``reversed_reading``) within 5 deg of the truth."""
    from inference.rotations import geodesic_deg, reversed_reading
    from inference.simulation.catalogue import bad_frames, bad_frames_truth

    est, checker = _checker(calibration)
    frames = bad_frames("cross-range-flipped", n)
    res = est.estimate(frames)
    checks = checker.check_many(frames, res.enhanced, res.angles_deg, search_enhancer=est.search_enhancer)
    shown = np.array([reversed_reading(c.angles_deg) for c in checks])
    err = geodesic_deg(shown, bad_frames_truth("cross-range-flipped", n))
    trusted = np.array([c.quality.trusted for c in checks])
    return int(trusted.sum()), int((trusted & (err <= 5.0)).sum()), int((trusted & (err > 10.0)).sum()), n


def truth_leaves(
    checker: Any, est: Any, frame: np.ndarray, enhanced: np.ndarray, check: Any, truth: np.ndarray
) -> float:
    """How far (deg) the truth moves when it is itself refined, as the search's fine fit refines, on the silhouette the
    answer was fitted to: over 5 deg, that silhouette holds no minimum near the truth, and no alternative (a fit's
    minimum) can lie within 5 deg of it."""
    from inference.fit import fit
    from inference.rotations import geodesic_deg
    from inference.trust import LIBRARY_FINE, in_cube

    enh = enhanced
    if check.features.get("searched", 0.0) > 0.5 and est.search_enhancer is not None and not in_cube(check.angles_deg):
        enh = est.search_enhancer(frame)  # the search's answers outside the cube fit its UNet++'s silhouette
    refit = fit(checker.renderer, np.asarray(enh, np.float64), {"truth": truth}, LIBRARY_FINE)[0]
    return float(geodesic_deg(refit.angles_deg, truth)[0])


def score(
    frames: np.ndarray,
    truth: np.ndarray,
    spacing_deg: float,
    calibration: str | None = None,
    labels: np.ndarray | None = None,
) -> dict[str, Any]:
    from inference.fit import Library
    from inference.rotations import euler_difference

    est, checker = _checker(calibration)
    t0 = time.perf_counter()
    checker._library = Library.build(checker.renderer, spacing_deg)  # the service builds it on first need
    build_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    res = est.estimate(frames)
    checks = checker.check_many(frames, res.enhanced, res.angles_deg, search_enhancer=est.search_enhancer)
    seconds = time.perf_counter() - t0
    from inference.frames import silhouette_ious

    unet_iou = float(np.mean(silhouette_ious(res.enhanced, labels))) if labels is not None else float("nan")
    search_iou = float("nan")  # the search UNet++'s silhouettes (the set's, where it has one: what a search fits)
    if labels is not None and est.search_enhancer is not None:
        search_iou = float(np.mean(silhouette_ious(np.stack([est.search_enhancer(f) for f in frames]), labels)))
    answers = np.array([c.angles_deg for c in checks])
    b = branches(answers, truth, checks)
    err, to_mirror, wrong, on_mirror, listed = b["err"], b["to_mirror"], b["wrong"], b["on_mirror"], b["listed"]
    trusted = np.array([c.quality.trusted for c in checks])
    basinless = np.zeros(len(checks), bool)
    for k in np.flatnonzero(wrong):
        basinless[k] = truth_leaves(checker, est, frames[k], res.enhanced[k], checks[k], truth[k]) > 5.0
        _log(
            f"wrong branch: frame {k}, {err[k]:.1f} deg off, {to_mirror[k]:.1f} deg from the truth's near-mirror, "
            f"listing the truth: {bool(listed[k])}, trusted: {bool(trusted[k])}, no minimum near the truth: "
            f"{bool(basinless[k])}"
        )
    axis_err = np.abs(euler_difference(answers, truth))
    bounds = np.array([c.quality.uncertainty_deg for c in checks], float)
    covered = np.mean(axis_err <= bounds, axis=0)
    outside = axis_err > bounds
    good = err <= 2.0
    return {
        "frames": len(frames),
        "unet_iou": unet_iou,
        "search_iou": search_iou,
        "median": float(np.median(err)),
        "p95": float(np.percentile(err, 95)),
        "beyond_10": float(np.mean(err > 10.0)),
        "beyond_10_trusted": int(np.sum((err > 10.0) & trusted)),
        "wrong": int(wrong.sum()),
        "wrong_trusted": int((wrong & trusted).sum()),
        "wrong_listing": int((wrong & listed).sum()),
        "wrong_basinless": int(basinless.sum()),
        "wrong_on_mirror": int(on_mirror.sum()),
        "on_mirror_listing": int((on_mirror & listed).sum()),
        "wrong_basin_listing": int((wrong & listed & ~basinless).sum()),
        "trusted": float(trusted.mean()),
        "good_flagged": float(np.mean(~trusted[good])) if good.any() else float("nan"),
        "covered": covered,
        # per axis, the worst: a 90 % bound leaves about 10 % of errors outside on each axis by design
        "trusted_outside_bound": float(np.max(np.mean(outside[trusted], axis=0))) if trusted.any() else float("nan"),
        "searched": float(np.mean([c.features.get("searched", 0.0) > 0.5 for c in checks])),
        "points": {
            "err": err,
            "iou": np.array([c.quality.silhouette_iou for c in checks]),
            "trusted": trusted,
            "searched": np.array([c.features.get("searched", 0.0) > 0.5 for c in checks]),
        },
        "ms": 1000.0 * seconds / len(frames),
        "build_s": build_s,
        "library": len(checker.library.angles_deg),
        "library_mb": checker.library.silhouettes.nbytes / 1e6,
    }


def _calibration_command(calibration: str | None) -> str:
    from inference.runtime import DEFAULT_MODEL_DIR
    from inference.trust import TRUST_FILE, Calibration

    made = Calibration.load(calibration or (MODELS or DEFAULT_MODEL_DIR) / TRUST_FILE).made
    return f"`{made.get('command', 'gsa calibrate')}`"


def plot(ours: dict[str, np.ndarray], robust: dict[str, np.ndarray], calibration: str | None) -> None:
    """Each SO(3) frame's geodesic error against its fit's silhouette IoU, trusted or flagged, and the threshold."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from inference.runtime import DEFAULT_MODEL_DIR
    from inference.trust import TRUST_FILE, Calibration

    cal = Calibration.load(calibration or (MODELS or DEFAULT_MODEL_DIR) / TRUST_FILE)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), sharey=True)
    for ax, (name, pts) in zip(axes, (("our frames", ours), ("robust preset", robust)), strict=True):
        err = np.maximum(pts["err"], 0.01)
        for mask, colour, label in (
            (pts["trusted"], "tab:green", "trusted"),
            (~pts["trusted"], "tab:red", "flagged"),
        ):
            ax.scatter(pts["iou"][mask], err[mask], s=10, c=colour, alpha=0.7, label=f"{label} ({mask.sum()})")
        if cal.library_iou_min is not None:
            ax.axvline(cal.library_iou_min, color="k", ls="--", lw=1, label="library search's IoU threshold")
        ax.axhline(10.0, color="grey", ls=":", lw=1)
        ax.set_yscale("log")
        ax.set_xlabel("fitted projection's IoU with the silhouette it was fitted to")
        ax.set_title(f"uniform SO(3), {name}")
        ax.legend(loc="upper left", fontsize=8)
    axes[0].set_ylabel("geodesic error (deg)")
    fig.tight_layout()
    fig.savefig(PLOT, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.so3", description=__doc__.split("\n")[0])
    p.add_argument("--frames", type=int, default=200)
    p.add_argument("--spacings", default="10,15,20", help="library spacings (deg) to compare on the SO(3) frames")
    p.add_argument("--calibration", help="the trust calibration (a trust.json) to check with (default: the models')")
    p.add_argument("--models", help="a model folder to measure instead of the shipped one")
    p.add_argument("--out", default="BENCHMARKS.md", help="the markdown file whose section is replaced")
    args = p.parse_args(argv)
    global MODELS
    MODELS = Path(args.models) if args.models else None
    from inference.fit import LIBRARY_SPACING_DEG
    from inference.simulation.catalogue import simulated
    from inference.simulation.dataset import DatasetSpec

    n = args.frames
    sets = {
        "uniform SO(3), our frames": DatasetSpec(n=n, seed=SEED, attitudes="so3"),
        "uniform SO(3), robust preset": DatasetSpec(n=n, seed=SEED + 1, attitudes="so3", variety="robust"),
        "+-45 deg cube, our frames": DatasetSpec(n=n, seed=SEED + 2),
    }
    rows: dict[str, dict[str, Any]] = {}
    for name, spec in sets.items():
        frames, truth, _, labels = simulated(spec)
        rows[name] = score(frames, truth, LIBRARY_SPACING_DEG, args.calibration, labels)
        _log(f"{name}: { {k: v for k, v in rows[name].items() if k != 'points'} }")
    spacing_rows = {}
    frames, truth, _, _ = simulated(sets["uniform SO(3), our frames"])
    for s in (float(x) for x in args.spacings.split(",")):
        spacing_rows[s] = (
            rows["uniform SO(3), our frames"] if s == LIBRARY_SPACING_DEG else score(frames, truth, s, args.calibration)
        )
        _log(f"spacing {s}: { {k: v for k, v in spacing_rows[s].items() if k != 'points'} }")
    lines = [
        f"## {TITLE}",
        "",
        f"Machine: {machine()}. Date: {datetime.now(UTC).date().isoformat()}. Command: `python -m bench.so3 --frames "
        f"{n}{' --calibration ' + args.calibration if args.calibration else ''}"
        f"{' --models ' + args.models if args.models else ''}` (bench/so3.py). {n} fresh frames a row (SNR -3..15 dB, "
        f"seeds nothing was trained on), {'the models of ' + args.models if args.models else 'the shipped models'}, "
        f"the service's whole answer with the coarse library spread over SO(3) at {LIBRARY_SPACING_DEG:g} deg "
        "(the search's starts where Swin's answer does not fit), two fitting threads. Wrong branch: over 5 deg off and "
        "nearer the truth's near-mirror. No minimum near the truth: the truth itself, refined as the search's fine fit "
        "refines on the silhouette the answer was fitted to, moves over 5 deg (`truth_leaves`), so no alternative (a "
        "fit's minimum) can lie within 5 deg of it; but where the answer lies within 5 deg of the truth's near-mirror, its "
        "own near-mirror, listed (`fitted: false`) where the fit on that branch settled over 2 deg from it, lies "
        "within 5 deg of the truth (the mirror is an isometry). Bound coverage: share of frames within the 90 % bound, per axis z / y / x. "
        "Goal (issue 43): uniform SO(3) median <= 1 deg, at most 3 % beyond 10 deg and none of them trusted, the "
        "cube no worse, <= 300 ms a frame. Trust: the checks and bounds of "
        f"`{args.calibration or (args.models or 'inference/models/shipped') + '/trust.json'}` "
        f"({_calibration_command(args.calibration)}); an answer of the library search is held to the thresholds and bounds "
        "calibrated on the search's own answers over SO(3) (`Calibration.library_*`), and fits the silhouette of the "
        "set's search UNet++ (trained over every rotation) where it has one. Trusted outside their bound: "
        "the share of trusted answers whose error exceeds their 90 % bound, on the worst axis.",
        "",
        f"![Error against the fit's silhouette IoU over SO(3)]({PLOT})",
        "",
        "| frames | median (deg) | p95 (deg) | beyond 10 deg | of them trusted | wrong branch | of them trusted | "
        "of them listing the truth | of them with no minimum near the truth (the others listing it) | "
        "of them within 5 deg of the truth's near-mirror (listing the truth) | trusted | good (<= 2 deg) flagged | "
        "trusted outside their bound | bound coverage z / y / x | ms a frame | UNet++ IoU with the label | "
        "search UNet++ IoU |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, r in rows.items():
        cov = " / ".join(f"{100 * c:.0f} %" for c in r["covered"])
        lines.append(
            f"| {name} | {r['median']:.2f} | {r['p95']:.1f} | {100 * r['beyond_10']:.1f} % | {r['beyond_10_trusted']} | "
            f"{r['wrong']} | {r['wrong_trusted']} | {r['wrong_listing']} | "
            f"{r['wrong_basinless']} ({r['wrong_basin_listing']} of the other {r['wrong'] - r['wrong_basinless']}) | "
            f"{r['wrong_on_mirror']} ({r['on_mirror_listing']}) | {100 * r['trusted']:.0f} % | "
            f"{100 * r['good_flagged']:.0f} % | {100 * r['trusted_outside_bound']:.0f} % | {cov} | {r['ms']:.0f} | {r['unet_iou']:.3f} | "
            f"{'-' if np.isnan(r['search_iou']) else format(r['search_iou'], '.3f')} |"
        )
    lines += [
        "",
        "The library's spacing, on the uniform SO(3) frames of our simulator (the nearest entry to a random attitude "
        "lies about half a spacing away; the coarse fit must reach the truth from there):",
        "",
        "| spacing (deg) | entries | built in (s) | memory (MB) | median (deg) | beyond 10 deg | ms a frame |",
        "|---|---|---|---|---|---|---|",
    ]
    for s, r in spacing_rows.items():
        lines.append(
            f"| {s:g} | {r['library']:,} | {r['build_s']:.1f} | {r['library_mb']:.0f} | {r['median']:.2f} | "
            f"{100 * r['beyond_10']:.1f} % | {r['ms']:.0f} |"
        )
    lines.append("")
    plot(rows["uniform SO(3), our frames"]["points"], rows["uniform SO(3), robust preset"]["points"], args.calibration)
    flipped, shown, far, n_flipped = flipped_trusted(args.calibration)
    lines[-1:-1] = [
        "",
        f"Cross-range-flipped frames (the bad-frame catalogue's, `inference.simulation.catalogue.bad_frames`): "
        f"{flipped} of {n_flipped} trusted, {shown} of them read as the attitude they show (the truth turned half "
        f"about the line of sight, within 5 deg; the answer's `attitude_reversed` is then the truth), {far} over 10 deg "
        "from it (a wrong answer trusted, as the fit can give on a frame of that attitude itself). Such a frame "
        "is exactly the frame of that attitude, whatever the scattering (tests/inference/simulation/test_scene.py), "
        "so over SO(3) no single-frame check can flag it; under the networks' cube it was flagged only because "
        "that attitude lies outside the cube.",
    ]
    replace_section(TITLE, lines, Path(args.out))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
