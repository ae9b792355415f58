"""Evaluate the exported models on the paper's protocol: Table 4 and Table 7, plus geodesic errors.

Runs the ONNX models (what the service runs) on a data set's test split and on fresh
test sets simulated at 0, 5 and 10 dB, prints the tables beside the paper's figures,
writes ``results.json`` and ``results.md``, and draws error histograms.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from inference.errors import InferenceError, module_main
from inference.files import write_json
from inference.rotations import geodesic_deg
from inference.runtime import Estimator
from inference.simulation.dataset import DatasetSpec, load_manifest, load_range, render_frames, split_ranges
from inference.simulation.radar import Radar

PAPER = {
    "without enhancement": (1.387, 1.223, 1.797),
    "with enhancement": (0.730, 0.705, 0.958),
    "0 dB": (0.618, 0.833, 0.876),
    "5 dB": (0.619, 0.805, 0.815),
    "10 dB": (0.616, 0.805, 0.805),
}


SNR_DB = (0.0, 5.0, 10.0)  # Table 7
SNR_SEED = 10_000  # the fresh SNR test sets: seed SNR_SEED + dB, never a training set's seed


def snr_spec(snr_db: float, n: int, seed: int = SNR_SEED) -> DatasetSpec:
    """The fresh test set of Table 7 at one SNR (the same frames whoever simulates them)."""
    return DatasetSpec(n=n, seed=seed + int(snr_db), snr_min_db=snr_db, snr_max_db=snr_db)


def row_name(snr_db: float | None, enhance: bool = True) -> str:
    """The table row of a test split (``snr_db`` None) or of a fresh SNR set, for models with or without UNet++.

    The paper's Table 7 holds enhanced frames only, so a raw-frame model's SNR rows are named apart.
    """
    if snr_db is None:
        return "with enhancement" if enhance else "without enhancement"
    return f"{snr_db:g} dB" + ("" if enhance else ", without enhancement")


def score(
    predict: Callable[[NDArray[Any]], NDArray[Any]],
    sets: Iterable[tuple[str, NDArray[Any], NDArray[Any]]],
    progress: bool = True,
) -> tuple[dict[str, Any], dict[str, NDArray[np.float64]]]:
    """Run ``predict`` (frames [N, H, W] -> angles [N, 3] deg) over named sets; return the rows and the errors."""
    rows: dict[str, Any] = {}
    errors: dict[str, NDArray[np.float64]] = {}
    for name, images, angles in sets:
        parts = []
        for k in range(0, len(images), 16):
            parts.append(predict(images[k : k + 16].astype(np.float32)))
            if progress and (k // 16) % 16 == 15:
                print(f"evaluate: {name}: {k + 16}/{len(images)} frames", file=sys.stderr, flush=True)
        pred = np.concatenate(parts)
        rows[name] = summarise(pred, angles)
        errors[name] = pred - angles
        if progress:
            r = rows[name]
            print(
                f"evaluate: {name}: MAE z/y/x {r['mae_deg']} deg, geodesic p95 {r['geodesic_p95_deg']} deg",
                file=sys.stderr,
                flush=True,
            )
    return rows, errors


def summarise(pred: NDArray[np.floating], true: NDArray[np.floating]) -> dict[str, Any]:
    err = pred - true
    geo = geodesic_deg(np.asarray(pred, np.float64), np.asarray(true, np.float64))
    return {
        "n": int(len(true)),
        "mae_deg": np.abs(err).mean(axis=0).round(4).tolist(),
        "geodesic_mean_deg": round(float(geo.mean()), 4),
        "geodesic_p95_deg": round(float(np.percentile(geo, 95)), 4),
    }


def evaluate(
    model_dir: str | Path,
    data_dir: str | Path | None = None,
    n_snr: int = 1000,
    seed: int = SNR_SEED,
    out_dir: str | Path = "results",
    radar: Radar | None = None,
    progress: bool = True,
    record: bool = False,
    without: str | Path | None = None,
) -> dict[str, Any]:
    """Evaluate the ONNX models in ``model_dir``; return and write the results (and, with ``record``, into the card).

    ``without`` names a second model folder, trained on raw frames (``gsa train --no-enhance``):
    it is scored on the same frames, which gives Table 4's "without enhancement" row beside the
    "with enhancement" one.
    """
    est = Estimator.load(model_dir)
    models = [est]
    if without is not None:
        raw = Estimator.load(without)
        if raw.enhances:
            raise InferenceError(
                f"{without} runs UNet++ first; --without takes models trained on raw frames (gsa train --no-enhance)",
                field="without",
            )
        if not est.enhances:
            raise InferenceError(
                f"{model_dir} reads raw frames too; beside --without give enhancing models", field="models"
            )
        models.append(raw)
    manifest = load_manifest(data_dir) if data_dir is not None else None
    # The SNR test sets use the data set's radar (or Table 3's).
    radar = radar or (Radar(**manifest["radar"]) if manifest else Radar())
    results: dict[str, Any] = {"model": est.identity, "paper_mae_deg": PAPER}
    if without is not None:
        results["without_model"] = models[1].identity
    frames: list[tuple[float | None, NDArray[Any], NDArray[Any]]] = []  # simulated once, scored by every model
    if data_dir is not None and manifest is not None:
        frames.append((None, *held_out(data_dir, manifest)))
    for snr in SNR_DB:
        arrays = render_frames(snr_spec(snr, n_snr, seed), radar, 0, n_snr)
        frames.append((snr, arrays["image"], arrays["angles_deg"]))
    results["rows"], errors = {}, {}
    rows_of: list[dict[str, Any]] = []  # each model's own rows, --models first
    for m in models:

        def predict(f: NDArray[Any], m: Estimator = m) -> NDArray[Any]:
            return m.estimate(f).angles_deg

        rows, errs = score(
            predict, ((row_name(snr, m.enhances), images, angles) for snr, images, angles in frames), progress
        )
        rows_of.append(rows)
        results["rows"].update(rows)
        errors.update(errs)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "results.json", results)
    (out / "results.md").write_text(table(results))
    plot_errors(errors, out / "errors.png")
    if record:  # the card records its own models' rows only
        card_path = Path(model_dir) / "model_card.json"
        card = json.loads(card_path.read_text())
        card["evaluation"] = {"rows": rows_of[0], "n_per_snr": n_snr, "data": str(data_dir) if data_dir else None}
        write_json(card_path, card)
    return results


def held_out(data_dir: str | Path, manifest: dict[str, Any]) -> tuple[NDArray[Any], NDArray[Any]]:
    """Return a data set's test frames and angles (its manifest's split, or the last 20 %) inside the networks' cube.

    Swin answers the +-45 deg cube (``ANGLE_SCALE_DEG``); a set over SO(3) keeps its test frames outside it for
    UNet++ (``inference.training.train``'s ``test_silhouette_iou``), not for these rows.
    """
    from inference.frames import ANGLE_SCALE_DEG

    _, (lo, hi) = split_ranges(manifest)
    data = load_range(data_dir, lo, hi, verify=False)
    inside = np.all(np.abs(data["angles_deg"]) <= ANGLE_SCALE_DEG, axis=1)
    return data["image"][inside], data["angles_deg"][inside]


def table(results: dict[str, Any]) -> str:
    lines = [
        "| setting | ours z / y / x (deg) | paper z / y / x (deg) | geodesic mean / p95 (deg) |",
        "|---|---|---|---|",
    ]
    for name, row in results["rows"].items():
        paper = PAPER.get(name)
        ours = " / ".join(f"{v:.3f}" for v in row["mae_deg"])
        theirs = " / ".join(f"{v:.3f}" for v in paper) if paper else "-"
        lines.append(
            f"| {name} (n={row['n']}) | {ours} | {theirs} | {row['geodesic_mean_deg']:.3f} / {row['geodesic_p95_deg']:.3f} |"
        )
    return "\n".join(lines) + "\n"


def plot_errors(errors: dict[str, NDArray[np.float64]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    for k, axis in enumerate("zyx"):
        for name, err in errors.items():
            axes[k].hist(err[:, k], bins=60, histtype="step", label=name)
        axes[k].set(xlabel=f"{axis} error (deg)", ylabel="frames")
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--models", help="directory with model_card.json (default: the shipped models)")
    p.add_argument("--data", help="data set whose test split gives the 'with enhancement' row")
    p.add_argument("--n-snr", type=int, default=1000, help="frames per SNR for Table 7 (default 1000)")
    p.add_argument("--out", default="results")
    p.add_argument("--record", action="store_true", help="also write the results into the model card")
    p.add_argument(
        "--without",
        help="models trained on raw frames (--no-enhance), scored on the same frames: "
        "Table 4's 'without enhancement' row",
    )


def run(args: argparse.Namespace) -> int:
    from inference.runtime import DEFAULT_MODEL_DIR

    res = evaluate(
        args.models or DEFAULT_MODEL_DIR,
        args.data,
        args.n_snr,
        out_dir=args.out,
        record=args.record,
        without=args.without,
    )
    print(table(res))
    print(f"written to {args.out}/results.json, results.md and errors.png")
    return 0


def main(argv: list[str] | None = None) -> int:
    return module_main("evaluation.evaluate", "evaluate", add_arguments, run, argv)


if __name__ == "__main__":
    sys.exit(main())
