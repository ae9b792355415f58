"""Fine-tune the last stage(s) of a trained Swin on the CPU, against a fixed enhancer.

The front of Swin (patch embedding and every stage but the last ``train_stages``)
stays frozen and runs once over every frame, through the enhancer the service runs
(``--enhancer``: an exported model directory, whose int8 UNet++ is then what Swin
learns to read) or the run's own UNet++. Its output is cached on disk (resumable, so
a cut-off run goes on where it stopped), and the last stage(s), the norm and the head
train on that cache, an order of magnitude faster a batch than the whole Swin
(design/measurements.md, "Fine-tuning Swin's tail on a feature cache").

Epochs are scored on a fresh validation set, simulated like the training set with a
seed no other set uses, and the weights with the lowest validation error (the starting
weights included) are kept: the test split is scored once, before and after, and
chooses nothing. The result is a run directory that ``gsa export`` takes as it is.
"""

from __future__ import annotations

import argparse
import copy
import hashlib
import json
import platform
import shutil
import sys
import time
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from typing import Any, cast

import numpy as np
import torch
from numpy.typing import NDArray

from inference.errors import DatasetError, InferenceError, module_main
from inference.files import sha256_file, write_json
from inference.frames import ANGLE_SCALE_DEG
from inference.networks.swin import SwinTransformer
from inference.simulation.dataset import DatasetSpec, frame_truth, load_manifest, load_range, render_frames
from inference.simulation.radar import Radar
from inference.training.augment import perturb_silhouettes
from inference.training.checkpoints import averaged_weights, load_trained, save_checkpoint
from inference.training.options import (
    VAL_SEED,
    FinetuneOptions,
    add_option_arguments,
    check_schedule,
    check_share,
    options_from_args,
)
from inference.training.train import split_indices

CHUNK = 64  # frames per cached chunk (and per progress line)


def front_sha256(swin: SwinTransformer, train_stages: int) -> str:
    """Hash of the frozen front's weights: what the cached features depend on, besides the frames."""
    frozen = [swin.patch_embed, swin.embed_norm, *swin.split_stages(train_stages)[0]]
    h = hashlib.sha256()
    for k, module in enumerate(frozen):
        for name, t in module.state_dict().items():
            h.update(f"{k}.{name}".encode())
            h.update(t.detach().float().contiguous().numpy().tobytes())
    return h.hexdigest()


def validation_spec(manifest: dict[str, Any], n: int, seed: int = VAL_SEED) -> DatasetSpec:
    """A fresh set drawn like the data set's frames (same angles, SNRs, target), with its own seed."""
    spec = dict(manifest["spec"])
    spec.update(n=n, seed=seed, n_train=None)
    return DatasetSpec(**spec)


class FeatureCache:
    """Swin's front output for one set of frames, in a float16 .npy on disk, filled in chunks.

    ``features-NAME.json`` says which inputs made it and how many frames are done, so a run
    cut off while caching goes on from there, and a cache of other inputs is never reused.
    """

    def __init__(self, out: Path, name: str, n: int, shape: tuple[int, ...], identity: dict[str, Any]) -> None:
        self.path = out / f"features-{name}.npy"
        self.meta_path = out / f"features-{name}.json"
        self.identity = identity
        meta = json.loads(self.meta_path.read_text()) if self.meta_path.is_file() else {}
        fresh = meta.get("identity") != identity or not self.path.is_file()
        self.done = 0 if fresh else int(meta.get("done", 0))
        mode = "w+" if fresh else "r+"
        self.array = np.lib.format.open_memmap(self.path, mode=mode, dtype=np.float16, shape=(n, *shape))
        if self.array.shape != (n, *shape):
            raise InferenceError(f"{self.path} holds {self.array.shape}, not {(n, *shape)}; delete it", field="out")

    def fill(self, compute: Callable[[int, int], NDArray[np.float16]], label: str) -> NDArray[np.float16]:
        n = len(self.array)
        t0, first = time.perf_counter(), self.done
        while self.done < n:
            stop = min(self.done + CHUNK, n)
            self.array[self.done : stop] = compute(self.done, stop)
            self.array.flush()
            self.done = stop
            write_json(self.meta_path, {"identity": self.identity, "done": self.done})
            rate = (self.done - first) / max(time.perf_counter() - t0, 1e-9)
            print(
                f"finetune: caching {label} {self.done}/{n} frames ({rate:.1f} frames/s, "
                f"{(n - self.done) / max(rate, 1e-9):.0f} s left)",
                file=sys.stderr,
                flush=True,
            )
        return np.asarray(self.array)


def _mae(pred: NDArray[Any], true: NDArray[Any]) -> list[float]:
    return [round(float(v), 4) for v in np.abs(pred - true).mean(axis=0)]


@torch.no_grad()
def predict_tail(
    modules: torch.nn.Module, swin: SwinTransformer, feats: NDArray[Any], train_stages: int, batch: int = 64
) -> NDArray[np.float32]:
    """Angles in degrees [N, 3] from cached features, with ``swin``'s tail (``modules``, already loaded into it)."""
    modules.eval()
    out = [
        swin.tail(torch.from_numpy(feats[k : k + batch].astype(np.float32)), train_stages).numpy()
        for k in range(0, len(feats), batch)
    ]
    return np.asarray(np.concatenate(out) * ANGLE_SCALE_DEG, np.float32)


def finetune(
    run_dir: str | Path, data_dir: str | Path, out_dir: str | Path, options: FinetuneOptions | None = None
) -> dict[str, Any]:
    """Fine-tune ``run_dir``'s Swin tail into ``out_dir`` (a run directory); return the fine-tuning record.

    The feature cache lives in ``cache_dir`` (default ``out_dir``); point a second round of
    fine-tuning (``run_dir`` an earlier round's output) at the first round's cache to skip caching.
    """
    opts = options if options is not None else FinetuneOptions()
    enhancer, epochs, lr, lr_decay = opts.enhancer, opts.epochs, opts.lr, opts.lr_decay
    batch_size, ema, train_stages, n_val = opts.batch_size, opts.ema, opts.train_stages, opts.n_val
    val_seed, max_train_frames, seed, threads = opts.val_seed, opts.max_train_frames, opts.seed, opts.threads
    cache_dir = opts.cache_dir
    if epochs < 1:
        raise InferenceError(f"epochs {epochs} must be at least 1", field="epochs")
    check_schedule(lr_decay, ema)
    check_share(opts.silhouette_noise)
    if n_val < 16:
        raise InferenceError(f"n_val {n_val} is too few to choose weights by; give at least 16", field="n_val")
    if Path(out_dir).resolve() == Path(run_dir).resolve():
        raise InferenceError("out must be a new directory, not the run itself", field="out")
    if threads:
        torch.set_num_threads(threads)
    unet, swin_module, cfg, enhance = load_trained(run_dir)  # names a missing or bad weights file
    swin = cast(SwinTransformer, swin_module)
    n_stages = len(swin.stages)
    if not 1 <= train_stages <= n_stages:
        raise InferenceError(f"train_stages {train_stages} must be between 1 and {n_stages}", field="train_stages")
    manifest = load_manifest(data_dir, verify=True)  # fails before any work on a bad data set
    n_frames = int(manifest["frames"])
    if manifest["radar"]["n_range"] != cfg["img_size"] or manifest["radar"]["n_azimuth"] != cfg["img_size"]:
        raise DatasetError(f"frames of {data_dir} are not {cfg['img_size']}x{cfg['img_size']}", field="data")
    train_idx, test_idx = split_indices(manifest, n_frames)
    if max_train_frames:
        train_idx = train_idx[:max_train_frames]
    if len(train_idx) == 0 or len(test_idx) == 0:
        raise DatasetError(f"{data_dir} needs both training and test frames", field="data")

    est = None
    if enhance and enhancer is not None:
        from inference.runtime import Estimator  # onnxruntime only when an exported enhancer is asked for

        est = Estimator.load(enhancer)
        if int(est.card["config"]["img_size"]) != int(cfg["img_size"]):
            raise InferenceError(f"enhancer {enhancer} takes other frame sizes than the run", field="enhancer")
    unet.eval()
    swin.eval()

    @torch.no_grad()
    def features(frames: NDArray[Any], perturb_seed: int | None = None) -> NDArray[np.float16]:
        """Swin's front output for frames; with ``perturb_seed``, of silhouettes perturbed (silhouette_noise)."""
        x = np.asarray(frames, np.float32)
        if enhance:
            x = est.enhance(x) if est is not None else unet(torch.from_numpy(x)[:, None])[:, 0].numpy()
        t = torch.from_numpy(np.ascontiguousarray(x))[:, None]
        if perturb_seed is not None and opts.silhouette_noise:
            t = perturb_silhouettes(t, opts.silhouette_noise, torch.Generator().manual_seed(perturb_seed))
        return swin.front(t, train_stages).numpy().astype(np.float16)

    for rows in (train_idx, test_idx):
        if np.any(np.diff(rows) != 1):
            raise DatasetError(f"{data_dir}'s split is not contiguous", field="data")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    cache = out if cache_dir is None else Path(cache_dir)
    cache.mkdir(parents=True, exist_ok=True)
    probe = features(np.zeros((1, cfg["img_size"], cfg["img_size"]), np.float32))
    # What the features depend on: a run fine-tuned before has the same front, so its cache serves again.
    identity = {
        "front_sha256": front_sha256(swin, train_stages),
        "enhancer": est.identity["unetpp_sha256"] if est is not None else None,
        "unetpp_sha256": sha256_file(Path(run_dir) / "unetpp.pt") if enhance and est is None else None,
        "enhance": enhance,
        "train_stages": train_stages,
    }
    t_start = time.perf_counter()

    def data_rows(rows: NDArray[np.int64], perturb: bool = False) -> Callable[[int, int], NDArray[np.float16]]:
        """Features of the split's rows ``a..b``; perturbed ones drawn from a seed of the run's and the chunk's,
        so a cache cut off and resumed holds what one uninterrupted pass would."""
        lo = int(rows[0])  # the split's rows are contiguous: read them shard by shard
        return lambda a, b: features(
            load_range(data_dir, lo + a, lo + b, keys=("image",), verify=False)["image"],
            perturb_seed=(seed * 1_000_003 + lo + a) if perturb else None,
        )

    val_spec = validation_spec(manifest, n_val, val_seed)
    radar = Radar(**manifest["radar"])
    shape = probe.shape[1:]
    data_id = {**identity, "data": manifest["content_sha256"]}
    train_id = {**data_id, "rows": list(_span(train_idx))}
    if opts.silhouette_noise:  # (absent when off, so the caches made before the option still serve)
        train_id.update(silhouette_noise=opts.silhouette_noise, perturb_seed=seed)
    feats = {
        "train": FeatureCache(cache, "train", len(train_idx), shape, train_id).fill(
            data_rows(train_idx, perturb=True), "training frames"
        ),
        "val": FeatureCache(cache, "val", n_val, shape, {**identity, "val": asdict(val_spec)}).fill(
            lambda a, b: features(render_frames(val_spec, radar, a, b)["image"]),
            f"fresh validation frames (seed {val_seed})",
        ),
        "test": FeatureCache(cache, "test", len(test_idx), shape, {**data_id, "rows": list(_span(test_idx))}).fill(
            data_rows(test_idx), "test frames"
        ),
    }
    angles = {
        "train": load_range(data_dir, *_span(train_idx), keys=("angles_deg",), verify=False)["angles_deg"],
        "val": np.array([frame_truth(val_spec, k)[0] for k in range(n_val)], np.float32),
        "test": load_range(data_dir, *_span(test_idx), keys=("angles_deg",), verify=False)["angles_deg"],
    }
    cache_seconds = time.perf_counter() - t_start

    modules, best, history, start_state, start_mae = _train_tail(swin, feats, angles, opts)

    # Keep the weights with the lowest validation error; score the test split once, before and after.
    test_before = score_on(modules, swin, start_state, feats["test"], angles["test"], train_stages)
    test_after = score_on(modules, swin, best["state"], feats["test"], angles["test"], train_stages)
    modules.load_state_dict(best["state"])
    record = {
        "from_run": str(run_dir),
        "data": {
            "dir": str(data_dir),
            "content_sha256": manifest["content_sha256"],
            "variety": manifest["spec"].get("variety"),
        },
        "enhancer": None if est is None else {"dir": str(enhancer), "unetpp_sha256": identity["enhancer"]},
        "train_stages": train_stages,
        "trained_parameters": sum(p.numel() for p in modules.parameters()),
        "epochs": epochs,
        "lr": lr,
        "lr_decay": lr_decay,
        "batch_size": batch_size,
        "silhouette_noise": opts.silhouette_noise,
        "ema": ema,
        "seed": seed,
        "train_frames": int(len(train_idx)),
        "validation": {"spec": asdict(val_spec), "n": n_val},
        "chosen": {k: best[k] for k in ("epoch", "weights", "val_mae_deg")},
        "start_val_mae_deg": start_mae,
        "test_mae_deg_before": test_before,
        "test_mae_deg_after": test_after,
        "history": history,
        "hardware": {
            "device": "cpu",
            "name": platform.processor() or platform.machine(),
            "torch": torch.__version__,
            "threads": torch.get_num_threads(),
        },
        "cache_seconds": round(cache_seconds, 1),
        "train_seconds": round(sum(h["seconds"] for h in history), 1),
    }
    save_checkpoint(
        {"state_dict": swin.state_dict(), "config": cfg, "enhance": enhance, "finetune": True}, out / "swin.pt"
    )
    shutil.copy(Path(run_dir) / "unetpp.pt", out / "unetpp.pt")
    base_path = Path(run_dir) / "training.json"
    training = json.loads(base_path.read_text()) if base_path.is_file() else {"config": cfg}
    if "finetune" in training:  # a second round keeps the first round's record inside its own
        record["previous_round"] = training["finetune"]
    training["finetune"] = record
    write_json(out / "training.json", training)
    plot_finetune(record, out / "finetune.png")
    return record


def _train_tail(
    swin: SwinTransformer,
    feats: dict[str, NDArray[np.float16]],
    angles: dict[str, NDArray[np.float32]],
    opts: FinetuneOptions,
) -> tuple[torch.nn.ModuleList, dict[str, Any], list[dict[str, Any]], dict[str, Any], list[float]]:
    """Train Swin's tail on the cached features; score each epoch (and the averaged weights) on the validation set.

    Returns the tail's modules, the best weights seen (``epoch``, ``weights``, ``val_mae_deg``, ``state``), the
    epochs' records, and the starting weights with their validation error.
    """
    seed, train_stages, epochs, batch_size, ema = opts.seed, opts.train_stages, opts.epochs, opts.batch_size, opts.ema
    lr, lr_decay = opts.lr, opts.lr_decay
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    modules = swin.tail_modules(train_stages)
    opt = torch.optim.Adam(modules.parameters(), lr=lr)
    sched = torch.optim.lr_scheduler.ExponentialLR(opt, lr_decay)
    averaged = None
    if ema is not None:
        from torch.optim.swa_utils import AveragedModel, get_ema_multi_avg_fn

        averaged = AveragedModel(modules, multi_avg_fn=get_ema_multi_avg_fn(ema), use_buffers=True)  # type: ignore[no-untyped-call]

    def score(state: dict[str, Any] | None = None) -> list[float]:
        """Validation MAE per axis of the tail's weights (or of ``state``)."""
        if state is None:
            return _mae(predict_tail(modules, swin, feats["val"], train_stages), angles["val"])
        return score_on(modules, swin, state, feats["val"], angles["val"], train_stages)

    start_mae = score()
    start_state = copy.deepcopy(modules.state_dict())
    best: dict[str, Any] = {"epoch": 0, "weights": "start", "val_mae_deg": start_mae, "state": start_state}
    print(f"finetune: starting weights: validation MAE z/y/x {_fmt(start_mae)} deg", file=sys.stderr, flush=True)
    history: list[dict[str, Any]] = []
    x_train, y_train = feats["train"], torch.from_numpy(angles["train"] / ANGLE_SCALE_DEG)
    for epoch in range(1, epochs + 1):
        modules.train()
        t_epoch, total = time.perf_counter(), 0.0
        order = rng.permutation(len(x_train))
        batches = [np.sort(order[k : k + batch_size]) for k in range(0, len(order), batch_size)]
        for step, sel in enumerate(batches):
            f = torch.from_numpy(x_train[sel].astype(np.float32))
            loss = torch.nn.functional.mse_loss(swin.tail(f, train_stages), y_train[sel])
            opt.zero_grad(set_to_none=True)
            loss.backward()  # type: ignore[no-untyped-call]
            opt.step()
            if averaged is not None:
                averaged.update_parameters(modules)
            total += float(loss.detach())
            if (step + 1) % 100 == 0:
                print(
                    f"finetune: epoch {epoch}/{epochs} step {step + 1}/{len(batches)} loss {total / (step + 1):.5f} "
                    f"({(time.perf_counter() - t_epoch) / (step + 1):.2f} s/step)",
                    file=sys.stderr,
                    flush=True,
                )
        sched.step()
        rec: dict[str, Any] = {"epoch": epoch, "swin_loss": total / len(batches), "val_mae_deg": score()}
        candidates = [("trained", rec["val_mae_deg"], modules.state_dict())]
        if averaged is not None:
            avg_state = averaged_weights(averaged.state_dict())
            rec["ema_val_mae_deg"] = score(avg_state)
            candidates.append(("averaged", rec["ema_val_mae_deg"], avg_state))
        rec["seconds"] = time.perf_counter() - t_epoch
        history.append(rec)
        for which, mae, state in candidates:
            if float(np.mean(mae)) < float(np.mean(best["val_mae_deg"])):
                best = {"epoch": epoch, "weights": which, "val_mae_deg": mae, "state": copy.deepcopy(state)}
        print(
            f"finetune: epoch {epoch}/{epochs} done: loss {rec['swin_loss']:.5f}, validation MAE z/y/x "
            f"{_fmt(rec['val_mae_deg'])} deg"
            + (f" (averaged weights {_fmt(rec['ema_val_mae_deg'])})" if averaged else "")
            + f" ({rec['seconds']:.0f} s)",
            file=sys.stderr,
            flush=True,
        )

    return modules, best, history, start_state, start_mae


def _span(rows: NDArray[np.int64]) -> tuple[int, int]:
    return int(rows[0]), int(rows[-1]) + 1


def _fmt(mae: list[float]) -> str:
    return "/".join(f"{v:.3f}" for v in mae)


def score_on(
    modules: torch.nn.ModuleList,
    swin: SwinTransformer,
    state: dict[str, Any],
    feats: NDArray[Any],
    angles: NDArray[Any],
    train_stages: int,
) -> list[float]:
    """MAE per axis (deg) of ``swin`` with its tail set to ``state``; the tail's own weights are put back."""
    saved = copy.deepcopy(modules.state_dict())
    modules.load_state_dict(state)
    try:
        return _mae(predict_tail(modules, swin, feats, train_stages), angles)
    finally:
        modules.load_state_dict(saved)


def plot_finetune(record: dict[str, Any], path: Path) -> None:
    """Draw the validation MAE per epoch (trained and averaged weights); skipped when matplotlib is absent."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return
    hist = record["history"]
    ep = [0] + [h["epoch"] for h in hist]
    fig, ax = plt.subplots(figsize=(6, 3.8))
    for k, name in enumerate("zyx"):
        line = ax.plot(ep, [record["start_val_mae_deg"][k]] + [h["val_mae_deg"][k] for h in hist], "o-", label=name)[0]
        if all("ema_val_mae_deg" in h for h in hist):
            ax.plot(
                ep,
                [record["start_val_mae_deg"][k]] + [h["ema_val_mae_deg"][k] for h in hist],
                "--",
                color=line.get_color(),
                label=f"{name}, averaged weights",
            )
    c = record["chosen"]
    ax.set(
        xlabel="epoch (0: the starting weights)",
        ylabel="validation MAE (deg)",
        title=f"kept: epoch {c['epoch']}, {c['weights']} weights",
    )
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--run", required=True, help="training run directory (unetpp.pt, swin.pt)")
    p.add_argument("--data", required=True, help="the data set it was trained on (from `gsa simulate`)")
    p.add_argument("--out", required=True, help="new run directory: swin.pt, unetpp.pt, training.json, finetune.png")
    add_option_arguments(p, FinetuneOptions)


def run(args: argparse.Namespace) -> int:
    rec = finetune(args.run, args.data, args.out, options_from_args(FinetuneOptions, args))
    c = rec["chosen"]
    print(
        f"fine-tuned into {args.out}: kept epoch {c['epoch']} ({c['weights']} weights), validation MAE z/y/x "
        f"{_fmt(c['val_mae_deg'])} deg; test MAE {_fmt(rec['test_mae_deg_before'])} -> {_fmt(rec['test_mae_deg_after'])} deg"
    )
    return 0


def main(argv: list[str] | None = None) -> int:
    return module_main("training.finetune", "finetune", add_arguments, run, argv)


if __name__ == "__main__":
    sys.exit(main())
