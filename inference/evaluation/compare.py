"""Training runs side by side: each run's Swin test error per epoch, as a table and a plot.

    gsa compare runs/a64-joint runs/a64-twostage runs/a64-raw --out results/ablation

It reads each run's ``training.json`` (written after every epoch, so a run still going can be
compared too) and counts Swin's epochs: a two-stage run's first epochs train UNet++ alone, so
its Swin epoch 1 is the first epoch after the split. The table gives each run's training time
as well, since two-stage and raw-frame epochs cost less than joint ones.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from inference.errors import InferenceError, module_main


def load_run(run_dir: str | Path) -> dict[str, Any]:
    """Read a run's training record, or say what is wrong with the folder."""
    path = Path(run_dir) / "training.json"
    if not path.is_file():
        raise InferenceError(f"{path} does not exist; give a folder written by gsa train", field="runs")
    try:
        record = json.loads(path.read_text())
    except ValueError as exc:
        raise InferenceError(f"{path} is not a gsa train record ({exc})", field="runs") from None
    missing = [k for k in ("history", "mode", "enhance") if not isinstance(record, dict) or k not in record]
    if missing:
        raise InferenceError(f"{path} is not a gsa train record (no {', '.join(missing)})", field="runs")
    if not record["history"]:
        raise InferenceError(f"{path} has no finished epoch yet", field="runs")
    return record


def describe(record: dict[str, Any]) -> str:
    """How the run trained, in a few words."""
    if not record["enhance"]:
        return "no enhancement (Swin on raw frames)"
    if record["mode"] == "two-stage":
        first = (
            f"UNet++ {record['unet_epochs']} epochs, then" if record.get("unet_epochs") else "frozen trained UNet++,"
        )
        return f"two-stage ({first} Swin on its output)"
    return "joint (per batch: UNet++, then Swin on its output)"


def swin_curve(record: dict[str, Any]) -> list[dict[str, Any]]:
    """The epochs in which Swin trained: Swin epoch, test MAE z/y/x (deg), training seconds so far."""
    frozen_swin = (record["unet_epochs"] or 0) if record["enhance"] and record["mode"] == "two-stage" else 0
    out: list[dict[str, Any]] = []
    seconds = 0.0
    for h in record["history"]:
        seconds += float(h["seconds"])
        if h["epoch"] > frozen_swin:
            out.append({"swin_epoch": len(out) + 1, "test_mae_deg": list(h["test_mae_deg"]), "seconds": seconds})
    return out


def table(runs: dict[str, dict[str, Any]], curves: dict[str, list[dict[str, Any]]]) -> str:
    """A summary row per run, then the test MAE of every run at each Swin epoch (``curves``: their ``swin_curve``)."""
    lines = [
        "| run | how it trained | Swin epochs | training time (min) | last test MAE z / y / x (deg) | best mean (Swin epoch) |",
        "|---|---|---|---|---|---|",
    ]
    for name, r in runs.items():
        c = curves[name]
        if not c:
            lines.append(f"| {name} | {describe(r)} | 0 | {sum(h['seconds'] for h in r['history']) / 60:.1f} | - | - |")
            continue
        best = min(c, key=lambda e: float(np.mean(e["test_mae_deg"])))
        last = " / ".join(f"{v:.2f}" for v in c[-1]["test_mae_deg"])
        lines.append(
            f"| {name} | {describe(r)} | {len(c)} | {c[-1]['seconds'] / 60:.1f} | {last} | "
            f"{np.mean(best['test_mae_deg']):.2f} ({best['swin_epoch']}) |"
        )
    longest = max((len(c) for c in curves.values()), default=0)
    lines += ["", "| Swin epoch | " + " | ".join(curves) + " |", "|---" * (len(curves) + 1) + "|"]
    for k in range(longest):
        cells = [" / ".join(f"{v:.2f}" for v in c[k]["test_mae_deg"]) if k < len(c) else "" for c in curves.values()]
        lines.append(f"| {k + 1} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def plot(curves: dict[str, list[dict[str, Any]]], path: Path) -> None:
    """Test MAE per axis against Swin epochs, one line per run (``curves``: their ``swin_curve``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8), sharey=True)
    for name, c in curves.items():
        if not c:
            continue
        mae = np.array([e["test_mae_deg"] for e in c])
        for k in range(3):
            axes[k].plot([e["swin_epoch"] for e in c], mae[:, k], "o-", ms=3, label=name)
    for k, axis in enumerate("zyx"):
        axes[k].set(xlabel="Swin epoch", title=f"{axis}")
    axes[0].set_ylabel("test MAE (deg)")
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def compare(run_dirs: list[str | Path], out_dir: str | Path) -> str:
    """Write ``compare.md`` and ``compare.png`` for the runs into ``out_dir``; return the table."""
    if not run_dirs:
        raise InferenceError("give at least one run folder", field="runs")
    runs: dict[str, dict[str, Any]] = {}
    for d in run_dirs:
        name = Path(d).name
        if name in runs:
            raise InferenceError(f"two runs are named {name!r}; give folders with different names", field="runs")
        runs[name] = load_run(d)
    curves = {name: swin_curve(r) for name, r in runs.items()}
    text = table(runs, curves)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "compare.md").write_text(text)
    plot(curves, out / "compare.png")
    return text


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("runs", nargs="+", help="run folders written by gsa train (their training.json)")
    p.add_argument("--out", default="results/compare", help="where compare.md and compare.png go")


def run(args: argparse.Namespace) -> int:
    print(compare(args.runs, args.out), end="")
    print(f"written to {args.out}/compare.md and compare.png")
    return 0


def main(argv: list[str] | None = None) -> int:
    return module_main("evaluation.compare", "compare", add_arguments, run, argv)


if __name__ == "__main__":
    sys.exit(main())
