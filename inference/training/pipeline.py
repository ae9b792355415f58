"""Commands for a GPU machine: simulate the data, train, evaluate, and hand back float16 weights in pieces.

On the GPU machine (numpy, scipy, torch and onnxruntime only)::

    python -m inference.training.pipeline prepare --work W --n 13000 --n-train 12000 --n-snr 300
    python -m inference.training.pipeline run --work W --name compact --recipe shipped --max-minutes 20 --out OUT

``prepare`` simulates the data set into ``W/data`` and Table 7's fresh SNR sets into
``W/snr-0``, ``W/snr-5``, ``W/snr-10`` (each once, on every core). ``run`` trains
``W/NAME`` with ``--resume`` until its epochs are done or the time is up (call it
again to continue while the machine keeps ``W``), evaluates the torch weights on the
test split and the SNR sets (``evaluation.json``), and writes the ``unetpp``/``swin``
state dicts in float16, split into pieces under 15 MB, plus ``pieces.json``, the
training record and the plots into ``OUT``. ``pack --run W/NAME --out OUT`` does the
last step alone, from the newest epoch's checkpoint, while a run is still going.
Back home::

    python -m inference.training.pipeline join --pieces DIR --run runs/gpu
    gsa export --run runs/gpu

rebuilds ``unetpp.pt`` and ``swin.pt`` (float32) and exports them.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import torch

from inference.errors import InferenceError, ModelFileError
from inference.evaluation.evaluate import PAPER, SNR_DB, held_out, plot_errors, row_name, score, snr_spec, table
from inference.files import write_json
from inference.simulation.dataset import DatasetSpec, default_train_frames, generate, load_arrays, load_manifest
from inference.training.checkpoints import averaged_weights, load_trained, read_pieces, same_half, write_pieces
from inference.training.options import RECIPES, TrainOptions, add_option_arguments, options_from_args, recipe
from inference.training.train import predict, train

# A run's records, carried beside its pieces.
RECORDS = ("training.json", "loss.png", "evaluation.json", "evaluation.md", "errors.png")


def prepare(
    work: Path,
    n: int,
    n_train: int | None = None,
    n_snr: int = 0,
    seed: int = 0,
    radar: Any = None,
    workers: int | None = None,
    variety: str | None = None,
    variety_share: float = 1.0,
    attitudes: str = "cube",
    so3_share: float = 1.0,
) -> None:
    """Simulate the data set into ``WORK/data`` and Table 7's fresh SNR sets into ``WORK/snr-DB`` (each once).

    ``attitudes`` "so3" draws ``so3_share`` of the data set's frames over every rotation (the rest in the cube);
    the SNR test sets stay in the cube, where Swin answers.

    ``variety`` (a ``VARIETY_PRESETS`` name) varies the training set's scattering frame by frame;
    the SNR test sets stay default frames, so runs with and without it are scored alike.
    ``variety_share`` varies only that share of the frames (``DatasetSpec.variety_share``).
    """
    data = work / "data"
    if not (data / "manifest.json").exists():
        shutil.rmtree(data, ignore_errors=True)
        n_train = default_train_frames(n) if n_train is None else n_train
        spec = DatasetSpec(
            n=n,
            seed=seed,
            n_train=n_train,
            variety=variety,
            variety_share=variety_share,
            attitudes=attitudes,
            so3_share=so3_share,
        )
        generate(spec, data, radar, workers=workers)
    for snr in SNR_DB if n_snr else ():
        d = work / f"snr-{snr:g}"
        if not (d / "manifest.json").exists():
            shutil.rmtree(d, ignore_errors=True)
            generate(snr_spec(snr, n_snr), d, radar, workers=workers, progress=False)


def evaluate_run(work: Path, name: str, device: str | None = None) -> dict[str, Any]:
    """Evaluate a run's torch weights on the test split and the SNR sets in ``work``; write ``evaluation.json``.

    The same rows as ``gsa evaluate`` (which runs the exported ONNX models), for runs whose
    weights are too large to bring back, such as the paper's Swin-T.
    """
    run_dir = work / name
    # A Swin trained on raw frames (--no-enhance) is scored without UNet++: Table 4's other row.
    unet, swin, _, enhance = load_trained(run_dir)
    dev = torch.device(device or ("cuda" if torch.cuda.is_available() else "cpu"))
    unet.to(dev)
    swin.to(dev)

    def sets() -> Any:
        yield (row_name(None, enhance), *held_out(work / "data", load_manifest(work / "data")))
        for snr in SNR_DB:
            d = work / f"snr-{snr:g}"
            if (d / "manifest.json").exists():
                arrays = load_arrays(d, verify=False)
                yield row_name(snr, enhance), arrays["image"], arrays["angles_deg"]

    rows, errors = score(lambda f: predict(unet if enhance else None, swin, f, dev)[0], sets())
    results = {"run": name, "paper_mae_deg": PAPER, "rows": rows}
    write_json(run_dir / "evaluation.json", results)
    (run_dir / "evaluation.md").write_text(table(results))
    plot_errors(errors, run_dir / "errors.png")
    return results


def pack(run_dir: Path, out: Path, reuse: Path | None = None) -> dict[str, Any]:
    """Write a run's latest weights in float16 pieces, with its records, into ``out``.

    A training run's latest weights are its last epoch's checkpoint; a run without one (a
    ``gsa finetune`` output) gives its ``unetpp.pt``/``swin.pt``. With ``reuse`` (another
    pieces folder), a network whose float16 weights equal that folder's is not written again:
    ``pieces.json`` names that folder's pieces by relative path.
    """
    ckpt = run_dir / "checkpoint.pt"
    if ckpt.is_file():
        ck = torch.load(ckpt, map_location="cpu", weights_only=False)
        ema = ck.get("ema") or {}  # a run with --ema hands back its averaged weights, as its unetpp.pt/swin.pt hold
        states = {
            "unetpp": averaged_weights(ema["unet"]) if "unet" in ema else ck["unet"],
            "swin": averaged_weights(ema["swin"]) if "swin" in ema else ck["swin"],
        }
        manifest: dict[str, Any] = {
            "epochs": ck["epoch"],
            "complete": ck["epoch"] >= ck.get("epochs", ck["config"].get("epochs", 0)),
            "averaged_weights": bool(ema),
        }
        config, enhance = ck["config"], ck.get("enhance", True)
    elif (run_dir / "swin.pt").is_file() and (run_dir / "unetpp.pt").is_file():
        cks = {n: torch.load(run_dir / f"{n}.pt", map_location="cpu", weights_only=False) for n in ("unetpp", "swin")}
        states = {n: ck["state_dict"] for n, ck in cks.items()}
        training = json.loads((run_dir / "training.json").read_text()) if (run_dir / "training.json").is_file() else {}
        manifest = {
            "epochs": len(training.get("history", [])),
            "complete": bool(training.get("complete")),
            "finetuned": "finetune" in training,
        }
        config, enhance = cks["swin"]["config"], cks["swin"].get("enhance", True)
    else:
        raise ModelFileError(f"{ckpt} is missing: the run has not finished an epoch", field="run")
    out.mkdir(parents=True, exist_ok=True)
    prior = json.loads((reuse / "pieces.json").read_text()) if reuse is not None else {}
    for name, state in states.items():
        if reuse is not None and same_half(state, read_pieces(reuse, name, prior)["state_dict"]):
            manifest[name] = [{**p, "file": os.path.relpath(reuse / p["file"], out)} for p in prior[name]]
        else:
            manifest[name] = write_pieces(name, state, config, out, **({"enhance": enhance} if name == "swin" else {}))
    write_json(out / "pieces.json", manifest)
    for extra in RECORDS:
        if (run_dir / extra).exists():
            shutil.copy(run_dir / extra, out / extra)
    return manifest


def run(
    work: Path,
    options: TrainOptions,
    *,
    n: int,
    name: str = "run",
    n_train: int | None = None,
    n_snr: int = 0,
    variety: str | None = None,
    variety_share: float = 1.0,
    radar: Any = None,
    out: Path | None = None,
    evaluate: bool = True,
    attitudes: str = "cube",
    so3_share: float = 1.0,
) -> dict[str, Any]:
    """Simulate (once), train ``WORK/NAME`` (resuming), evaluate when done, and pack the weights into ``out``.

    ``options`` says what to train (a recipe from ``inference.training.options``); this adds the
    data set (``n`` frames, ``n_train`` of them for training, ``n_snr`` per SNR test set) and
    always resumes, so calling it again continues a run the time limit cut off.
    """
    prepare(
        work,
        n,
        n_train,
        n_snr,
        options.seed,
        radar,
        variety=variety,
        variety_share=variety_share,
        attitudes=attitudes,
        so3_share=so3_share,
    )
    record = train(work / "data", work / name, replace(options, resume=True))
    if evaluate:
        evaluate_run(work, name)
    manifest = pack(work / name, out) if out is not None else {}
    return {"complete": record["complete"], "epochs": len(record["history"]), **manifest}


def join(pieces: Path, run_dir: Path) -> None:
    """Rebuild float32 ``unetpp.pt`` and ``swin.pt`` in ``run_dir`` from pieces, checking every sha256."""
    manifest = json.loads((pieces / "pieces.json").read_text())
    run_dir.mkdir(parents=True, exist_ok=True)
    for name in ("unetpp", "swin"):
        ck = read_pieces(pieces, name, manifest)
        ck["state_dict"] = {k: (v.float() if v.is_floating_point() else v) for k, v in ck["state_dict"].items()}
        torch.save(ck, run_dir / f"{name}.pt")
    for extra in RECORDS:
        if (pieces / extra).exists():
            shutil.copy(pieces / extra, run_dir / extra)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m inference.training.pipeline")
    sub = p.add_subparsers(dest="cmd", required=True)
    g = sub.add_parser("prepare", help="simulate the data set and the SNR test sets into WORK")
    r = sub.add_parser("run", help="prepare, train WORK/NAME (resuming), evaluate, pack into OUT")
    for q in (g, r):
        q.add_argument("--work", default="runs/gpu")
        q.add_argument("--n", type=int, default=5000)
        q.add_argument("--n-train", type=int, help="training frames of the set (default 80 %%)")
        q.add_argument("--n-snr", type=int, default=0, help="frames per SNR in Table 7's fresh test sets")
        q.add_argument("--seed", type=int, default=0)
        q.add_argument("--variety", help="vary the training set's scattering frame by frame (a preset: robust)")
        q.add_argument(
            "--variety-share", type=float, default=1.0, help="vary only this share of the frames (default 1)"
        )
        q.add_argument("--attitudes", default="cube", help="cube (default) or so3: the data set's attitudes")
        q.add_argument(
            "--so3-share", type=float, default=1.0, help="with --attitudes so3, this share over every rotation"
        )
    r.add_argument("--name", default="run", help="run folder inside WORK")
    r.add_argument("--out", help="where the float16 pieces go (default: none)")
    r.add_argument(
        "--recipe", default="paper", choices=sorted(RECIPES), help="named training options; the flags below override it"
    )
    r.add_argument("--from", dest="start_from", help="start both networks from a run folder's unetpp.pt and swin.pt")
    add_option_arguments(r, TrainOptions, skip=("seed", "resume", "unet_from", "swin_from", "log_every"))
    k = sub.add_parser("pack", help="write a run's latest weights in float16 pieces into OUT")
    k.add_argument("--run", required=True)
    k.add_argument("--out", required=True)
    k.add_argument("--reuse", help="a pieces folder whose pieces serve again where a network's weights equal them")
    j = sub.add_parser("join")
    j.add_argument("--pieces", required=True)
    j.add_argument("--run", required=True)
    args = p.parse_args(argv)
    try:
        if args.cmd == "prepare":
            prepare(
                Path(args.work),
                args.n,
                args.n_train,
                args.n_snr,
                args.seed,
                variety=args.variety,
                variety_share=args.variety_share,
                attitudes=args.attitudes,
                so3_share=args.so3_share,
            )
            print(f"data sets ready in {args.work}")
        elif args.cmd == "run":
            opts = options_from_args(TrainOptions, args, base=recipe(args.recipe, max_minutes=8.0))
            if args.start_from:
                start = Path(args.start_from)
                opts = replace(opts, unet_from=str(start / "unetpp.pt"), swin_from=str(start / "swin.pt"))
            m = run(
                Path(args.work),
                replace(opts, seed=args.seed),
                n=args.n,
                name=args.name,
                n_train=args.n_train,
                n_snr=args.n_snr,
                variety=args.variety,
                variety_share=args.variety_share,
                out=Path(args.out) if args.out else None,
                attitudes=args.attitudes,
                so3_share=args.so3_share,
            )
            print(json.dumps({k: v for k, v in m.items() if k in ("complete", "epochs")}))
        elif args.cmd == "pack":
            m = pack(Path(args.run), Path(args.out), Path(args.reuse) if args.reuse else None)
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
