"""One command for a GPU machine: simulate the data, train, and hand back half-precision weights in pieces.

On the GPU machine (numpy, scipy, torch only)::

    python -m inference.pipeline run --config paper --n 5000 --work runs/gpu --out "$OUT" --max-minutes 8

generates the data set into ``WORK/data`` (once), trains with ``--resume`` until the
time is up (call it again to continue; the work folder survives while the machine
stays warm), and writes ``unetpp``/``swin`` state dicts in float16, split into pieces
under 15 MB, plus ``pieces.json`` and ``training.json``, into ``OUT``. Back home::

    python -m inference.pipeline join --pieces DIR --run runs/gpu
    gsa export --run runs/gpu

rebuilds ``unetpp.pt`` and ``swin.pt`` (float32) and exports them.
"""

from __future__ import annotations

import argparse
import hashlib
import io
import json
import shutil
import sys
from pathlib import Path
from typing import Any

import torch

from inference.dataset import DatasetSpec, generate
from inference.errors import InferenceError, ModelFileError
from inference.train import train

PIECE_BYTES = 15 * 1024 * 1024


def _split(name: str, state: dict[str, Any], config: dict[str, Any], out: Path) -> list[dict[str, Any]]:
    half = {k: (v.half() if v.is_floating_point() else v) for k, v in state.items()}
    buf = io.BytesIO()
    torch.save({"state_dict": half, "config": config}, buf)
    blob = buf.getvalue()
    pieces = []
    for k in range(0, len(blob), PIECE_BYTES):
        part = blob[k : k + PIECE_BYTES]
        path = out / f"{name}.part{k // PIECE_BYTES:02d}"
        path.write_bytes(part)
        pieces.append({"file": path.name, "sha256": hashlib.sha256(part).hexdigest(), "bytes": len(part)})
    return pieces


def run(config: str, n: int, work: Path, out: Path, max_minutes: float, seed: int = 0, compile_models: bool = False,
        epochs: int | None = None, radar: Any = None) -> dict[str, Any]:  # fmt: skip
    """Generate (once), train (resuming), and write the weights in pieces into ``out``."""
    data = work / "data"
    if not (data / "manifest.json").exists():
        shutil.rmtree(data, ignore_errors=True)
        generate(DatasetSpec(n=n, seed=seed, n_train=int(round(0.8 * n))), data, radar)
    record = train(data, work / "run", config, epochs=epochs, seed=seed, resume=True, max_minutes=max_minutes,
                   compile_models=compile_models)  # fmt: skip
    out.mkdir(parents=True, exist_ok=True)
    manifest: dict[str, Any] = {"complete": record["complete"], "epochs": len(record["history"])}
    for name in ("unetpp", "swin"):
        ck = torch.load(work / "run" / f"{name}.pt", map_location="cpu", weights_only=False)
        manifest[name] = _split(name, ck["state_dict"], ck["config"], out)
    (out / "pieces.json").write_text(json.dumps(manifest, indent=2))
    shutil.copy(work / "run" / "training.json", out / "training.json")
    if (work / "run" / "loss.png").exists():
        shutil.copy(work / "run" / "loss.png", out / "loss.png")
    return manifest


def join(pieces: Path, run_dir: Path) -> None:
    """Rebuild float32 ``unetpp.pt`` and ``swin.pt`` in ``run_dir`` from pieces, checking every sha256."""
    manifest = json.loads((pieces / "pieces.json").read_text())
    run_dir.mkdir(parents=True, exist_ok=True)
    for name in ("unetpp", "swin"):
        blob = b""
        for p in manifest[name]:
            part = (pieces / p["file"]).read_bytes()
            if hashlib.sha256(part).hexdigest() != p["sha256"]:
                raise ModelFileError(f"piece {pieces / p['file']} does not match its sha256", field="model")
            blob += part
        ck = torch.load(io.BytesIO(blob), map_location="cpu", weights_only=False)
        ck["state_dict"] = {k: (v.float() if v.is_floating_point() else v) for k, v in ck["state_dict"].items()}
        torch.save(ck, run_dir / f"{name}.pt")
    shutil.copy(pieces / "training.json", run_dir / "training.json")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m inference.pipeline")
    sub = p.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run")
    r.add_argument("--config", default="paper")
    r.add_argument("--n", type=int, default=5000)
    r.add_argument("--work", default="runs/gpu")
    r.add_argument("--out", required=True)
    r.add_argument("--max-minutes", type=float, default=8.0)
    r.add_argument("--epochs", type=int)
    r.add_argument("--seed", type=int, default=0)
    r.add_argument("--compile", action="store_true")
    j = sub.add_parser("join")
    j.add_argument("--pieces", required=True)
    j.add_argument("--run", required=True)
    args = p.parse_args(argv)
    try:
        if args.cmd == "run":
            m = run(
                args.config,
                args.n,
                Path(args.work),
                Path(args.out),
                args.max_minutes,
                args.seed,
                args.compile,
                args.epochs,
            )
            print(json.dumps({k: v for k, v in m.items() if k in ("complete", "epochs")}))
        else:
            join(Path(args.pieces), Path(args.run))
            print(f"weights rebuilt in {args.run}")
    except InferenceError as exc:
        print(f"pipeline: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
