"""Train UNet++ and Swin on a simulated data set (Hou et al. 2023 section 4.3.3).

The paper's protocol: Adam, lr 2e-4 decayed x0.98 each epoch, batch 32, 100
epochs; per batch the UNet++ forward and its loss, Swin on the enhanced frames and
its loss, update Swin, update UNet++ (``mode="joint"``). ``mode="two-stage"`` trains
UNet++ first and then Swin on its frozen output; ``enhance=False`` trains Swin on
raw frames (the paper's "without enhancement" row). Angles are regressed scaled by
``ANGLE_SCALE_DEG`` to [-1, 1].

``ema`` also keeps an exponential moving average of both networks' weights (and batch-norm
statistics), updated after every optimiser step; each epoch scores both, and the averaged
weights are the ones written to ``unetpp.pt`` and ``swin.pt``. Per-epoch test errors of the
raw weights jitter by 0.1-0.5 deg late in training (the H100 run of 2026-11-23), so which
epoch a run stops at decides too much; the average smooths that, chosen beforehand rather
than by peeking at the test set.

Needs numpy, scipy and torch only. Resumable (``checkpoint.pt`` each epoch), seeded,
bf16 autocast on a GPU, and it stops cleanly after the epoch in which
``max_minutes`` runs out, so long runs fit in short commands.
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from inference.errors import DatasetError, InferenceError, module_main
from inference.frames import ANGLE_SCALE_DEG
from inference.networks.build import ModelConfig, build_models, get_config
from inference.networks.swin import angle_loss
from inference.networks.unetpp import relative_frobenius_loss
from inference.simulation.dataset import load_arrays, load_manifest, split_ranges


def split_indices(manifest: dict[str, Any], n: int) -> tuple[np.ndarray, np.ndarray]:
    """Return train and test indices (``inference.simulation.dataset.split_ranges``, the one split rule)."""
    (a, b), (c, d) = split_ranges({**manifest, "frames": n})
    return np.arange(a, b), np.arange(c, d)


def _device(name: str | None) -> torch.device:
    if name:
        return torch.device(name)
    return torch.device("cuda" if torch.cuda.is_available() else "cpu")


def _batches(idx: np.ndarray, batch: int, rng: np.random.Generator | None) -> list[np.ndarray]:
    order = rng.permutation(idx) if rng is not None else idx
    return [order[k : k + batch] for k in range(0, len(order), batch)]


def _rows(arr: np.ndarray | torch.Tensor, sel: np.ndarray, device: torch.device) -> torch.Tensor:
    """Return rows ``sel`` of a numpy array or of a tensor already on the device, as float32 on ``device``."""
    if isinstance(arr, torch.Tensor):
        return arr[torch.from_numpy(sel).to(arr.device)].to(device=device, dtype=torch.float32)
    return torch.from_numpy(arr[sel].astype(np.float32)).to(device)


def _tensors(
    images: np.ndarray | torch.Tensor,
    data: dict[str, np.ndarray | torch.Tensor],
    sel: np.ndarray,
    device: torch.device,
) -> tuple[torch.Tensor, ...]:
    """Return the frames (``images``: the data set's, or the cached enhanced ones), labels and scaled angles."""
    x = _rows(images, sel, device).unsqueeze(1)
    y = _rows(data["label"], sel, device).unsqueeze(1)
    a = _rows(data["angles_deg"], sel, device) / ANGLE_SCALE_DEG
    return x, y, a


def on_device(data: dict[str, np.ndarray], device: torch.device) -> dict[str, np.ndarray | torch.Tensor]:
    """Move the arrays training reads (frames, labels, angles) onto a GPU once; on a CPU keep numpy."""
    if device.type != "cuda":
        return dict(data)
    return {
        k: (torch.from_numpy(v).to(device) if k in ("image", "label", "angles_deg") else v) for k, v in data.items()
    }


def averaged_weights(state: dict[str, Any]) -> dict[str, Any]:
    """Return the network weights inside an ``AveragedModel`` state dict (without its ``module.`` prefix)."""
    return {k[len("module.") :]: v for k, v in state.items() if k.startswith("module.")}


def check_schedule(lr_decay: float, ema: float | None) -> None:
    """Refuse a learning-rate decay outside (0, 1] or a weight-averaging decay outside (0, 1)."""
    if not 0.0 < lr_decay <= 1.0:
        raise InferenceError(f"lr_decay {lr_decay} must be in (0, 1]", field="lr_decay")
    if ema is not None and not 0.0 < ema < 1.0:
        raise InferenceError(f"ema {ema} must be in (0, 1), e.g. 0.999", field="ema")


def _save(obj: Any, path: Path) -> None:
    """Save atomically, so a reader (or a cut-off run) never sees half a file."""
    tmp = path.with_name(path.name + ".tmp")
    torch.save(obj, tmp)
    tmp.replace(path)


@torch.no_grad()
def predict(
    unet: torch.nn.Module | None, swin: torch.nn.Module, images: np.ndarray, device: torch.device, batch: int = 32
) -> tuple[np.ndarray, np.ndarray | None]:
    """Return angles in degrees [N, 3] (and enhanced frames [N, H, W] when ``unet`` is given)."""
    unet_was, swin_was = (unet.training if unet else False), swin.training
    if unet:
        unet.eval()
    swin.eval()
    angles, enhanced = [], []
    for k in range(0, len(images), batch):
        x = torch.from_numpy(images[k : k + batch].astype(np.float32)).unsqueeze(1).to(device)
        if unet is not None:
            x = unet(x)
            enhanced.append(x[:, 0].float().cpu().numpy())
        angles.append(swin(x).float().cpu().numpy() * ANGLE_SCALE_DEG)
    if unet:
        unet.train(unet_was)
    swin.train(swin_was)
    return np.concatenate(angles), (np.concatenate(enhanced) if enhanced else None)


@torch.no_grad()
def enhance_all(
    unet: torch.nn.Module, images: np.ndarray, device: torch.device, batch: int = 16, rows: np.ndarray | None = None
) -> np.ndarray:
    """Run a frozen UNet++ over the frames once; return the enhanced frames as float16 [N, H, W].

    With ``rows``, only those frames are enhanced (the others stay zero): training on
    ``max_train_frames`` of a large set then costs what those frames and the test split cost.
    """
    unet.eval()
    out = np.zeros(images.shape, np.float16)
    todo = np.arange(len(images)) if rows is None else np.unique(rows)
    t0 = time.perf_counter()
    for k in range(0, len(todo), batch):
        sel = todo[k : k + batch]
        x = torch.from_numpy(images[sel].astype(np.float32)).unsqueeze(1).to(device)
        out[sel] = unet(x)[:, 0].float().cpu().numpy()
        done = min(k + batch, len(todo))
        if done % (batch * 20) == 0 or done == len(todo):
            print(f"train: enhancing frames with the frozen UNet++ {done}/{len(todo)} "
                  f"({time.perf_counter() - t0:.0f} s)", file=sys.stderr, flush=True)  # fmt: skip
    return out


def train(
    data_dir: str | Path,
    out_dir: str | Path,
    config: str | ModelConfig = "smoke",
    epochs: int | None = None,
    batch_size: int | None = None,
    lr: float | None = None,
    mode: str = "joint",
    enhance: bool = True,
    seed: int = 0,
    device: str | None = None,
    resume: bool = False,
    max_minutes: float | None = None,
    max_train_frames: int | None = None,
    log_every: int = 20,
    compile_models: bool = False,
    unet_epochs: int | None = None,
    unet_from: str | Path | None = None,
    threads: int | None = None,
    swin_from: str | Path | None = None,
    lr_decay: float | None = None,
    ema: float | None = None,
    shape: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Train both networks (or Swin alone with ``enhance=False``) and return the training record.

    ``mode="two-stage"`` trains UNet++ for ``unet_epochs`` (default half the epochs),
    then freezes it, runs it once over every frame and trains Swin on those cached
    enhanced frames, which is what makes Swin epochs cheap on a CPU. ``unet_from`` and
    ``swin_from`` start a network from the weights of an earlier run's ``unetpp.pt`` or
    ``swin.pt``: with a fresh learning-rate schedule this continues training that the
    earlier run's decayed schedule had slowed down. ``shape`` overrides the named config's
    network shape (``unet_filters``, ``swin_embed_dim``, ``swin_depths``, ``swin_heads``),
    e.g. to train a small Swin behind a larger, already trained UNet++.
    """
    cfg = (
        config
        if isinstance(config, ModelConfig)
        else get_config(config, epochs=epochs, batch_size=batch_size, lr=lr, lr_decay=lr_decay, **(shape or {}))
    )
    check_schedule(cfg.lr_decay, ema)
    if mode not in ("joint", "two-stage"):
        raise InferenceError(f"mode {mode!r} must be 'joint' or 'two-stage'", field="mode")
    if ema is not None and mode == "two-stage":
        raise InferenceError("ema averages jointly trained networks; use it with mode 'joint'", field="ema")
    if unet_epochs is not None and not 0 <= unet_epochs <= cfg.epochs:
        raise InferenceError(
            f"unet_epochs {unet_epochs} must be between 0 and epochs ({cfg.epochs})", field="unet_epochs"
        )
    for field, given, name in (("unet_from", unet_from, "unetpp.pt"), ("swin_from", swin_from, "swin.pt")):
        if given is not None and not Path(given).is_file():
            raise InferenceError(f"{given} does not exist; give an earlier run's {name}", field=field)
    if threads:
        torch.set_num_threads(threads)
    manifest = load_manifest(data_dir, verify=True)  # fails before any work on a bad data set
    data = load_arrays(data_dir, verify=False)
    n, h, w = data["image"].shape
    if (h, w) != (cfg.img_size, cfg.img_size):
        raise DatasetError(
            f"frames are {h}x{w} but config {cfg.name!r} takes {cfg.img_size}x{cfg.img_size}", field="data"
        )
    train_idx, test_idx = split_indices(manifest, n)
    if max_train_frames:
        train_idx = train_idx[:max_train_frames]
    if len(train_idx) == 0:
        raise DatasetError(f"{data_dir} has no training frames", field="data")

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(seed)
    dev = _device(device)
    unet, swin = build_models(cfg)
    for field, given, net in (("unet_from", unet_from, unet), ("swin_from", swin_from, swin)):
        if given is not None:
            ck0 = torch.load(given, map_location="cpu", weights_only=False)
            try:
                net.load_state_dict({k: v.float() for k, v in ck0["state_dict"].items()})
            except (RuntimeError, KeyError, TypeError) as exc:
                raise InferenceError(f"{given} does not fit config {cfg.name!r}: {exc}", field=field) from None
    unet.to(dev)
    swin.to(dev)
    if dev.type == "cuda":  # NHWC convolutions are what the tensor cores run natively
        torch.backends.cudnn.benchmark = True
        torch.backends.cuda.matmul.allow_tf32 = True
        torch.backends.cudnn.allow_tf32 = True
        unet.to(memory_format=torch.channels_last)  # type: ignore[call-overload]
    dev_data = on_device(data, dev)
    opt_u = torch.optim.Adam(unet.parameters(), lr=cfg.lr)
    opt_s = torch.optim.Adam(swin.parameters(), lr=cfg.lr)
    sch_u = torch.optim.lr_scheduler.ExponentialLR(opt_u, cfg.lr_decay)
    sch_s = torch.optim.lr_scheduler.ExponentialLR(opt_s, cfg.lr_decay)
    averaged: dict[str, torch.optim.swa_utils.AveragedModel] = {}
    if ema is not None:
        from torch.optim.swa_utils import AveragedModel, get_ema_multi_avg_fn

        averaged = {k: AveragedModel(net, multi_avg_fn=get_ema_multi_avg_fn(ema), use_buffers=True)  # type: ignore[no-untyped-call]
                    for k, net in (("unet", unet), ("swin", swin))}  # fmt: skip
    history: list[dict[str, Any]] = []
    start_epoch = 0
    ckpt_path = out / "checkpoint.pt"
    if resume and ckpt_path.exists():
        ck = torch.load(ckpt_path, map_location=dev, weights_only=False)
        try:
            unet.load_state_dict(ck["unet"])
            swin.load_state_dict(ck["swin"])
        except (RuntimeError, KeyError) as exc:
            raise InferenceError(
                f"{ckpt_path} was trained with another network shape than config {cfg.name!r} with these "
                f"overrides; resume with the run's own settings (its training.json) ({str(exc).splitlines()[0]})",
                field="resume",
            ) from None
        opt_u.load_state_dict(ck["opt_u"])
        opt_s.load_state_dict(ck["opt_s"])
        sch_u.load_state_dict(ck["sch_u"])
        sch_s.load_state_dict(ck["sch_s"])
        history, start_epoch = ck["history"], ck["epoch"]
        for k, avg in averaged.items():
            if k in ck.get("ema", {}):
                avg.load_state_dict(ck["ema"][k])
        print(f"train: resumed at epoch {start_epoch}", file=sys.stderr, flush=True)
    run_u: Callable[[torch.Tensor], torch.Tensor] = unet
    run_s: Callable[[torch.Tensor], torch.Tensor] = swin
    if compile_models and dev.type == "cuda":
        run_u, run_s = torch.compile(unet), torch.compile(swin)
    amp = (
        torch.autocast(device_type="cuda", dtype=torch.bfloat16)
        if dev.type == "cuda"
        else torch.autocast("cpu", enabled=False)
    )
    rng = np.random.default_rng(seed + start_epoch)
    t_start = time.perf_counter()
    stage_split = (cfg.epochs // 2 if unet_epochs is None else unet_epochs) if mode == "two-stage" else 0
    cache: np.ndarray | None = None  # UNet++ output for every frame once UNet++ is frozen

    def training_record() -> dict[str, Any]:
        """The training record (``training.json``), written after every epoch and at the end."""
        done = bool(history) and history[-1]["epoch"] >= cfg.epochs
        return {
            "config": cfg.as_dict(),
            "mode": mode,
            "unet_epochs": stage_split if mode == "two-stage" else None,
            "unet_from": str(unet_from) if unet_from is not None else None,
            "swin_from": str(swin_from) if swin_from is not None else None,
            "enhance": enhance,
            "ema": ema,
            "seed": seed,
            "complete": done,
            "data": {"dir": str(data_dir), "content_sha256": manifest["content_sha256"], "frames": int(n),
                     "train": int(len(train_idx)), "test": int(len(test_idx)), "radar": manifest.get("radar"),
                     "target": (manifest.get("model") or {}).get("name")},
            "hardware": {"device": str(dev), "name": torch.cuda.get_device_name(0) if dev.type == "cuda" else platform.processor()
                         or platform.machine(), "torch": torch.__version__, "threads": torch.get_num_threads()},
            "train_seconds": sum(h["seconds"] for h in history),
            "history": history,
        }  # fmt: skip

    for epoch in range(start_epoch, cfg.epochs):
        unet.train()
        swin.train()
        train_unet = enhance and (mode == "joint" or epoch < stage_split)
        train_swin = mode == "joint" or epoch >= stage_split or not enhance
        if enhance and mode == "two-stage" and not train_unet and cache is None:
            cache = enhance_all(unet, data["image"], dev, rows=np.concatenate([train_idx, test_idx]))
        sums = {"unet_loss": torch.zeros((), device=dev), "swin_loss": torch.zeros((), device=dev)}
        batches = _batches(train_idx, cfg.batch_size, rng)
        t_epoch = time.perf_counter()
        for step, sel in enumerate(batches):
            x, y, a = _tensors(dev_data["image"] if cache is None else cache, dev_data, np.sort(sel), dev)
            if dev.type == "cuda":
                x = x.contiguous(memory_format=torch.channels_last)
            with amp:
                if enhance and cache is None:
                    enhanced = run_u(x) if train_unet else run_u(x).detach()
                    loss_u = relative_frobenius_loss(enhanced.float(), y)
                    swin_in = enhanced.detach()
                else:  # raw frames (no enhancement), or frames the frozen UNet++ already enhanced
                    loss_u = torch.zeros((), device=dev)
                    swin_in = x
                loss_s = angle_loss(run_s(swin_in).float(), a)
            if train_swin:
                opt_s.zero_grad(set_to_none=True)
                loss_s.backward()  # type: ignore[no-untyped-call]
                opt_s.step()
                if averaged:
                    averaged["swin"].update_parameters(swin)
            if train_unet:
                opt_u.zero_grad(set_to_none=True)
                loss_u.backward()  # type: ignore[no-untyped-call]
                opt_u.step()
                if averaged:
                    averaged["unet"].update_parameters(unet)
            sums["unet_loss"] += loss_u.detach().float()  # summed on the device: no sync per step
            sums["swin_loss"] += loss_s.detach().float()
            if log_every and (step + 1) % log_every == 0:
                print(
                    f"train: epoch {epoch + 1}/{cfg.epochs} step {step + 1}/{len(batches)} "
                    f"unet {float(sums['unet_loss']) / (step + 1):.4f} swin {float(sums['swin_loss']) / (step + 1):.4f} "
                    f"({(time.perf_counter() - t_epoch) / (step + 1):.2f} s/step)",
                    file=sys.stderr,
                    flush=True,
                )
        if train_unet:  # a frozen network's schedule stands still, so Swin starts stage two at its full rate
            sch_u.step()
        if train_swin:
            sch_s.step()
        # Swin reads the frames UNet++ already enhanced (two-stage), or raw frames through UNet++ (or not).
        src, through_unet = (cache, False) if cache is not None else (data["image"], enhance)

        def test_mae(
            u: torch.nn.Module, s: torch.nn.Module, src: np.ndarray = src, through: bool = through_unet
        ) -> list[float]:
            if not len(test_idx):
                return [math.nan] * 3
            pred, _ = predict(u if through else None, s, src[test_idx], dev)
            return [float(v) for v in np.abs(pred - data["angles_deg"][test_idx]).mean(axis=0)]

        mae = test_mae(unet, swin)
        record = {
            "epoch": epoch + 1,
            "unet_loss": float(sums["unet_loss"]) / len(batches),
            "swin_loss": float(sums["swin_loss"]) / len(batches),
            "test_mae_deg": mae,
            "seconds": time.perf_counter() - t_epoch,
        }
        ema_mae = test_mae(averaged["unet"].module, averaged["swin"].module) if averaged else []
        if averaged:
            record["ema_test_mae_deg"] = ema_mae
        history.append(record)
        print(
            f"train: epoch {epoch + 1}/{cfg.epochs} done: unet {record['unet_loss']:.4f} swin {record['swin_loss']:.4f} "
            f"test MAE z/y/x {mae[0]:.2f}/{mae[1]:.2f}/{mae[2]:.2f} deg"
            + (" (averaged weights {:.2f}/{:.2f}/{:.2f})".format(*ema_mae) if averaged else "")
            + f" ({record['seconds']:.0f} s)",
            file=sys.stderr,
            flush=True,
        )
        _save(
            {"unet": unet.state_dict(), "swin": swin.state_dict(), "opt_u": opt_u.state_dict(),
             "opt_s": opt_s.state_dict(), "sch_u": sch_u.state_dict(), "sch_s": sch_s.state_dict(),
             "history": history, "epoch": epoch + 1, "config": cfg.as_dict(), "enhance": enhance,
             "ema": {k: avg.state_dict() for k, avg in averaged.items()}},
            ckpt_path,
        )  # fmt: skip
        (out / "training.json").write_text(json.dumps(training_record(), indent=2))
        if max_minutes is not None and (time.perf_counter() - t_start) / 60.0 > max_minutes:
            print(
                f"train: stopping after epoch {epoch + 1}: {max_minutes} min used; --resume continues", file=sys.stderr
            )
            break
    final_u, final_s = (averaged["unet"].module, averaged["swin"].module) if averaged else (unet, swin)
    _save({"state_dict": final_u.state_dict(), "config": cfg.as_dict(), "ema": ema}, out / "unetpp.pt")
    _save(
        {"state_dict": final_s.state_dict(), "config": cfg.as_dict(), "enhance": enhance, "ema": ema}, out / "swin.pt"
    )
    record_all = training_record()
    (out / "training.json").write_text(json.dumps(record_all, indent=2))
    plot_history(history, out / "loss.png")
    return record_all


def plot_history(history: list[dict[str, Any]], path: Path) -> None:
    """Draw the loss curves and test MAE per epoch (skipped when matplotlib is absent)."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return
    if not history:
        return
    ep = [h["epoch"] for h in history]
    fig, ax = plt.subplots(1, 2, figsize=(10, 3.8))
    ax[0].plot(ep, [h["unet_loss"] for h in history], label="UNet++ (relative Frobenius)")
    ax[0].plot(ep, [h["swin_loss"] for h in history], label="Swin (MSE, scaled angles)")
    ax[0].set(xlabel="epoch", ylabel="training loss", yscale="log")
    ax[0].legend()
    mae = np.array([h["test_mae_deg"] for h in history])
    for k, name in enumerate("zyx"):
        line = ax[1].plot(ep, mae[:, k], label=name)[0]
        if all("ema_test_mae_deg" in h for h in history):
            ema = np.array([h["ema_test_mae_deg"] for h in history])
            ax[1].plot(ep, ema[:, k], "--", color=line.get_color(), label=f"{name}, averaged weights")
    ax[1].set(xlabel="epoch", ylabel="test MAE (deg)")
    ax[1].legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _ints(text: str) -> tuple[int, ...]:
    """argparse type for a comma-separated list of integers ("2,2,6,2")."""
    try:
        return tuple(int(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a comma-separated list of integers") from None


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--data", required=True, help="data set directory (from `gsa simulate`)")
    p.add_argument("--config", default="compact", help="paper, compact, cpu or smoke")
    p.add_argument("--out", default="runs/train", help="output directory (checkpoints, weights, loss plot)")
    p.add_argument("--epochs", type=int)
    p.add_argument("--batch-size", type=int)
    p.add_argument("--lr", type=float)
    p.add_argument("--lr-decay", type=float, help="learning-rate factor per epoch (default: the config's)")
    p.add_argument("--mode", default="joint", choices=["joint", "two-stage"])
    p.add_argument("--unet-epochs", type=int, help="two-stage: epochs of UNet++ before Swin (default half)")
    p.add_argument("--unet-from", help="start UNet++ from an earlier run's unetpp.pt")
    p.add_argument("--swin-from", help="start Swin from an earlier run's swin.pt (fine-tuning with a fresh schedule)")
    p.add_argument("--threads", type=int, help="torch CPU threads (default: all cores)")
    p.add_argument("--no-enhance", action="store_true", help="train Swin on raw frames (no UNet++)")
    p.add_argument(
        "--ema", type=float, help="also average the weights (decay per step, e.g. 0.999); saved as the result"
    )
    p.add_argument("--unet-filters", type=_ints, help="override the config's UNet++ filters, e.g. 16,32,64,128,256")
    p.add_argument("--swin-dim", type=int, help="override the config's Swin embedding dimension C")
    p.add_argument("--swin-depths", type=_ints, help="override the config's Swin depths, e.g. 2,2,2,2")
    p.add_argument("--swin-heads", type=_ints, help="override the config's Swin heads per stage, e.g. 1,2,4,8")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--device")
    p.add_argument("--resume", action="store_true")
    p.add_argument("--max-minutes", type=float, help="stop after the epoch in which this much time has passed")
    p.add_argument("--max-train-frames", type=int)
    p.add_argument("--compile", action="store_true", help="torch.compile on a GPU")


def run(args: argparse.Namespace) -> int:
    rec = train(
        args.data, args.out, args.config, args.epochs, args.batch_size, args.lr, args.mode, not args.no_enhance,
        args.seed, args.device, args.resume, args.max_minutes, args.max_train_frames, compile_models=args.compile,
        unet_epochs=args.unet_epochs, unet_from=args.unet_from, threads=args.threads, swin_from=args.swin_from,
        lr_decay=args.lr_decay, ema=args.ema,
        shape={"unet_filters": args.unet_filters, "swin_embed_dim": args.swin_dim, "swin_depths": args.swin_depths,
               "swin_heads": args.swin_heads},
    )  # fmt: skip
    last = rec["history"][-1] if rec["history"] else None
    if last:
        z, y, x = last["test_mae_deg"]
        print(f"trained {last['epoch']} epochs into {args.out}: test MAE z/y/x {z:.2f}/{y:.2f}/{x:.2f} deg")
    return 0


def main(argv: list[str] | None = None) -> int:
    return module_main("training.train", "train", add_arguments, run, argv)


if __name__ == "__main__":
    sys.exit(main())
