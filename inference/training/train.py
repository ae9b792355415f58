"""Train UNet++ and Swin on a simulated data set (Hou et al. 2023 section 4.3.3).

The paper's protocol (recipe ``paper``): Adam, lr 2e-4 decayed x0.98 each epoch, batch 32, 100
epochs; per batch the UNet++ forward and its loss, Swin on the enhanced frames and
its loss, update Swin, update UNet++ (``mode="joint"``). ``mode="two-stage"`` trains
UNet++ first and then Swin on its frozen output; ``enhance=False`` trains Swin on
raw frames (the paper's "without enhancement" row). Angles are regressed scaled by
``ANGLE_SCALE_DEG`` to [-1, 1].

``ema`` also keeps an exponential moving average of both networks' weights (and batch-norm
statistics), updated after every optimiser step; each epoch scores both, and the averaged
weights are the ones written to ``unetpp.pt`` and ``swin.pt``. The raw weights' test error
jitters from epoch to epoch late in training, so which epoch a run stops at would decide too
much; the average smooths that, chosen beforehand rather than by peeking at the test set
(design/measurements.md, "Averaged weights").

Needs numpy, scipy and torch only. Resumable (``checkpoint.pt`` each epoch), seeded,
bf16 autocast on a GPU and on a CPU that computes bf16 natively (``precision``; a 2-core Xeon with
AMX trains UNet++ 4.5x faster than in float32, design/measurements.md "bf16 training on the CPU"),
and it stops cleanly after the epoch in which
``max_minutes`` runs out, so long runs fit in short commands.

Several processes (GPUs, or machines) train one run under ``torchrun`` with PyTorch's DistributedDataParallel:
``torchrun --nproc-per-node N -m inference.training.train ...`` (NCCL on GPUs, gloo on CPUs). Each optimiser step's
batch of ``batch_size`` frames is split between the N processes and their gradients averaged, so N processes take
the steps one process would (the losses are per-frame means; UNet++'s batch norm becomes synchronised batch norm
on GPUs, and keeps per-process statistics on CPUs, where PyTorch has no synchronised one); process 0 scores,
checkpoints and writes the result.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from inference.errors import DatasetError, InferenceError, module_main
from inference.files import write_json
from inference.frames import ANGLE_SCALE_DEG, silhouette_ious
from inference.networks.build import ModelConfig, build_models, get_config
from inference.networks.swin import cube_angle_loss
from inference.networks.unetpp import relative_frobenius_loss
from inference.simulation.dataset import load_arrays, load_manifest, split_ranges
from inference.training.augment import perturb_silhouettes
from inference.training.checkpoints import save_checkpoint
from inference.training.options import (
    RECIPES,
    TrainOptions,
    add_option_arguments,
    options_from_args,
    recipe,
)


def split_indices(manifest: dict[str, Any], n: int) -> tuple[np.ndarray, np.ndarray]:
    """Return train and test indices (``inference.simulation.dataset.split_ranges``, the one split rule)."""
    (a, b), (c, d) = split_ranges({**manifest, "frames": n})
    return np.arange(a, b), np.arange(c, d)


def cpu_has_native_bf16() -> bool:
    """Whether this CPU computes bf16 in hardware (AVX-512 BF16 or AMX), where oneDNN's bf16 kernels pay.

    Elsewhere bf16 is emulated and slower than float32, so ``precision="auto"`` keeps float32 there.
    """
    probes = ("_is_avx512_bf16_supported", "_is_amx_tile_supported")
    return any(bool(getattr(torch.cpu, name, lambda: False)()) for name in probes)


def uses_bf16(dev: torch.device, precision: str) -> bool:
    """Whether a training step runs under bf16 autocast: asked for, or ``auto`` on a GPU or a bf16-native CPU."""
    if precision == "auto":
        return dev.type == "cuda" or (dev.type == "cpu" and cpu_has_native_bf16())
    return precision == "bf16"


def _device(name: str | None) -> torch.device:
    if name:
        return torch.device(name)
    if torch.cuda.is_available():  # torchrun: one GPU a process; Ray Train shows each worker its own GPU alone
        local = int(os.environ.get("LOCAL_RANK", "0"))
        return torch.device("cuda", local if local < torch.cuda.device_count() else 0)
    return torch.device("cpu")


def distributed_world() -> tuple[int, int]:
    """(rank, world size) of this process under torchrun (its RANK and WORLD_SIZE), else (0, 1)."""
    try:
        world = int(os.environ.get("WORLD_SIZE", "1"))
        rank = int(os.environ.get("RANK", "0"))
    except ValueError:
        raise InferenceError("WORLD_SIZE and RANK must be whole numbers (torchrun sets them)", field="world") from None
    return (rank, world) if world > 1 else (0, 1)


def start_distributed(dev: torch.device) -> None:
    """Join the process group torchrun or Ray Train set up for this process (NCCL on a GPU, gloo on a CPU)."""
    import torch.distributed as dist

    if not dist.is_initialized():
        dist.init_process_group("nccl" if dev.type == "cuda" else "gloo")


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
            print(
                f"train: enhancing frames with the frozen UNet++ {done}/{len(todo)} ({time.perf_counter() - t0:.0f} s)",
                file=sys.stderr,
                flush=True,
            )
    return out


@dataclass
class _Run:
    """One training run's state, which each step reads and advances."""

    opts: TrainOptions
    cfg: ModelConfig
    out: Path
    data_dir: Path
    manifest: dict[str, Any]
    data: dict[str, np.ndarray]
    dev_data: dict[str, np.ndarray | torch.Tensor]
    train_idx: np.ndarray
    test_idx: np.ndarray
    dev: torch.device
    unet: torch.nn.Module
    swin: torch.nn.Module
    opt_u: torch.optim.Optimizer
    opt_s: torch.optim.Optimizer
    sch_u: torch.optim.lr_scheduler.LRScheduler
    sch_s: torch.optim.lr_scheduler.LRScheduler
    averaged: dict[str, torch.optim.swa_utils.AveragedModel]
    bf16: bool  # the training steps' forward passes run under bf16 autocast (uses_bf16)
    stage_split: int
    history: list[dict[str, Any]] = field(default_factory=list)
    start_epoch: int = 0
    cache: np.ndarray | None = None  # UNet++ output for every frame once UNet++ is frozen
    gen: torch.Generator | None = None  # draws the perturbed silhouettes (silhouette_noise), on the run's device
    rank: int = 0  # under torchrun: this process's rank and the number of processes (DDP); else 0 and 1
    world: int = 1
    ddp_u: torch.nn.Module | None = None  # the DistributedDataParallel wrappers the steps run through
    ddp_s: torch.nn.Module | None = None
    frames_seen: int = 0  # training frames this process stepped on


def train(data_dir: str | Path, out_dir: str | Path, options: TrainOptions | None = None) -> dict[str, Any]:
    """Train both networks (or Swin alone with ``enhance=False``) and return the training record.

    ``options`` (default ``recipe("compact")``) is built by keyword or from a named recipe
    (``inference.training.options.recipe``). ``mode="two-stage"`` trains UNet++ for
    ``unet_epochs`` (default half the epochs), then freezes it, runs it once over every frame
    and trains Swin on those cached enhanced frames, which is what makes Swin epochs cheap on a
    CPU. ``unet_from`` and ``swin_from`` start a network from the weights of an earlier run's
    ``unetpp.pt`` or ``swin.pt``: with a fresh learning-rate schedule this continues training
    that the earlier run's decayed schedule had slowed down. The shape fields override the
    config's network shape, e.g. to train a small Swin behind a larger, already trained UNet++.
    """
    opts = options if options is not None else recipe("compact")
    run = _set_up(Path(data_dir), Path(out_dir), opts)
    ckpt_path = run.out / "checkpoint.pt"
    if opts.resume and ckpt_path.exists():
        _resume(run, ckpt_path)
    run_u: Callable[[torch.Tensor], torch.Tensor] = run.ddp_u or run.unet
    run_s: Callable[[torch.Tensor], torch.Tensor] = run.ddp_s or run.swin
    if opts.compile_models and run.dev.type == "cuda":
        run_u, run_s = torch.compile(run_u), torch.compile(run_s)
    rng = np.random.default_rng(opts.seed + run.start_epoch)
    run.gen = torch.Generator(device=run.dev).manual_seed(opts.seed + run.start_epoch)
    t_start = time.perf_counter()
    for epoch in range(run.start_epoch, opts.epochs):
        t_epoch = time.perf_counter()
        losses = _epoch(run, epoch, rng, run_u, run_s)
        if run.rank != 0:  # process 0 scores, reports and checkpoints; the others step on with it
            if agreed_stop(False, run.world, run.dev):
                break
            continue
        record: dict[str, Any] = {"epoch": epoch + 1, **losses, **_score(run), "seconds": time.perf_counter() - t_epoch}
        run.history.append(record)
        mae, ema_mae = record["test_mae_deg"], record.get("ema_test_mae_deg")
        print(
            f"train: epoch {epoch + 1}/{opts.epochs} done: unet {record['unet_loss']:.4f} swin {record['swin_loss']:.4f} "
            f"test MAE z/y/x {mae[0]:.2f}/{mae[1]:.2f}/{mae[2]:.2f} deg"
            + (" (averaged weights {:.2f}/{:.2f}/{:.2f})".format(*ema_mae) if ema_mae else "")
            + (
                " silhouette IoU cube {cube:.3f} outside {outside:.3f}".format(**record["test_silhouette_iou"])
                if "test_silhouette_iou" in record
                else ""
            )
            + f" ({record['seconds']:.0f} s)",
            file=sys.stderr,
            flush=True,
        )
        _checkpoint(run, epoch + 1, ckpt_path)
        out_of_time = opts.max_minutes is not None and (time.perf_counter() - t_start) / 60.0 > opts.max_minutes
        if agreed_stop(out_of_time, run.world, run.dev):
            print(
                f"train: stopping after epoch {epoch + 1}: {opts.max_minutes} min used; --resume continues",
                file=sys.stderr,
            )
            break
    if run.world == 1:
        return _finish(run)
    import gc

    import torch.distributed as dist

    record = _finish(run) if run.rank == 0 else {}
    # The DDP wrappers hold the process group: freed now, not at interpreter exit, where tearing down gloo's worker
    # threads aborts the process ("terminate called without an active exception", SIGABRT) after its work is done.
    run.ddp_u = run.ddp_s = None
    gc.collect()
    dist.barrier()
    dist.destroy_process_group()
    return record


def agreed_stop(stop: bool, world: int, dev: torch.device) -> bool:
    """Process 0's word on stopping, heard by every process (alone: its own)."""
    if world == 1:
        return stop
    import torch.distributed as dist

    flag = torch.tensor([1 if stop else 0], device=dev)
    dist.broadcast(flag, 0)
    return bool(flag.item())


def _set_up(data_dir: Path, out: Path, opts: TrainOptions) -> _Run:
    """Check the options and the data set, build the networks (from earlier weights where asked) and optimisers."""
    opts.check()
    cfg = get_config(opts.config, **opts.shape())
    if opts.threads:
        torch.set_num_threads(opts.threads)
    manifest = load_manifest(data_dir, verify=True)  # fails before any work on a bad data set
    data = load_arrays(data_dir, verify=False)
    n, h, w = data["image"].shape
    if (h, w) != (cfg.img_size, cfg.img_size):
        raise DatasetError(
            f"frames are {h}x{w} but config {cfg.name!r} takes {cfg.img_size}x{cfg.img_size}", field="data"
        )
    train_idx, test_idx = split_indices(manifest, n)
    if opts.max_train_frames:
        train_idx = train_idx[: opts.max_train_frames]
    if len(train_idx) == 0:
        raise DatasetError(f"{data_dir} has no training frames", field="data")
    out.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(opts.seed)
    dev = _device(opts.device)
    rank, world = distributed_world()
    if world > 1:
        if opts.batch_size < world:
            raise InferenceError(
                f"batch size {opts.batch_size} is smaller than the {world} processes that share each step",
                field="batch_size",
            )
        start_distributed(dev)
    unet, swin = build_models(cfg)
    for name, given, net in (("unet_from", opts.unet_from, unet), ("swin_from", opts.swin_from, swin)):
        if given is not None:
            ck0 = torch.load(given, map_location="cpu", weights_only=False)
            try:
                net.load_state_dict({k: v.float() for k, v in ck0["state_dict"].items()})
            except (RuntimeError, KeyError, TypeError) as exc:
                raise InferenceError(f"{given} does not fit config {cfg.name!r}: {exc}", field=name) from None
    unet.to(dev)
    swin.to(dev)
    bf16 = uses_bf16(dev, opts.precision)
    if dev.type == "cuda":
        torch.backends.cudnn.benchmark = True
        torch.backends.cuda.matmul.allow_tf32 = True
        torch.backends.cudnn.allow_tf32 = True
    # NHWC convolutions are what tensor cores and oneDNN's kernels run natively, bf16 or float32 (design/measurements.md,
    # "bf16 training on the CPU")
    unet.to(memory_format=torch.channels_last)  # type: ignore[call-overload]
    opt_u = torch.optim.Adam(unet.parameters(), lr=opts.lr)
    opt_s = torch.optim.Adam(swin.parameters(), lr=opts.lr)
    averaged: dict[str, torch.optim.swa_utils.AveragedModel] = {}
    if opts.ema is not None:
        from torch.optim.swa_utils import AveragedModel, get_ema_multi_avg_fn

        averaged = {
            k: AveragedModel(net, multi_avg_fn=get_ema_multi_avg_fn(opts.ema), use_buffers=True)  # type: ignore[no-untyped-call]
            for k, net in (("unet", unet), ("swin", swin))
        }
    ddp_u = ddp_s = None
    if world > 1:
        from torch.nn.parallel import DistributedDataParallel as DDP

        ids = [dev.index] if dev.type == "cuda" else None
        if dev.type == "cuda":  # one batch's statistics across the processes (PyTorch has it on GPUs only)
            unet = torch.nn.SyncBatchNorm.convert_sync_batchnorm(unet)  # type: ignore[no-untyped-call]
        ddp_u, ddp_s = DDP(unet, device_ids=ids), DDP(swin, device_ids=ids)  # both start from process 0's weights
    two_stage = opts.mode == "two-stage"
    return _Run(
        opts=opts,
        cfg=cfg,
        out=out,
        data_dir=data_dir,
        manifest=manifest,
        data=data,
        dev_data=on_device(data, dev),
        train_idx=train_idx,
        test_idx=test_idx,
        dev=dev,
        unet=unet,
        swin=swin,
        opt_u=opt_u,
        opt_s=opt_s,
        sch_u=torch.optim.lr_scheduler.ExponentialLR(opt_u, opts.lr_decay),
        sch_s=torch.optim.lr_scheduler.ExponentialLR(opt_s, opts.lr_decay),
        averaged=averaged,
        bf16=bf16,
        stage_split=(opts.epochs // 2 if opts.unet_epochs is None else opts.unet_epochs) if two_stage else 0,
        rank=rank,
        world=world,
        ddp_u=ddp_u,
        ddp_s=ddp_s,
    )


def _resume(run: _Run, ckpt_path: Path) -> None:
    """Load the networks, optimisers, schedules, averages and history of the run's last epoch."""
    ck = torch.load(ckpt_path, map_location=run.dev, weights_only=False)
    try:
        run.unet.load_state_dict(ck["unet"])
        run.swin.load_state_dict(ck["swin"])
    except (RuntimeError, KeyError) as exc:
        raise InferenceError(
            f"{ckpt_path} was trained with another network shape than config {run.cfg.name!r} with these "
            f"overrides; resume with the run's own settings (its training.json) ({str(exc).splitlines()[0]})",
            field="resume",
        ) from None
    run.opt_u.load_state_dict(ck["opt_u"])
    run.opt_s.load_state_dict(ck["opt_s"])
    run.sch_u.load_state_dict(ck["sch_u"])
    run.sch_s.load_state_dict(ck["sch_s"])
    run.history, run.start_epoch = ck["history"], ck["epoch"]
    for k, avg in run.averaged.items():
        if k in ck.get("ema", {}):
            avg.load_state_dict(ck["ema"][k])
    print(f"train: resumed at epoch {run.start_epoch}", file=sys.stderr, flush=True)


def _epoch(
    run: _Run,
    epoch: int,
    rng: np.random.Generator,
    run_u: Callable[[torch.Tensor], torch.Tensor],
    run_s: Callable[[torch.Tensor], torch.Tensor],
) -> dict[str, float]:
    """Train one epoch (per batch: UNet++ and its loss, Swin on its output and its loss, update both); return the mean losses."""
    opts, dev = run.opts, run.dev
    run.unet.train()
    run.swin.train()
    train_unet = opts.enhance and (opts.mode == "joint" or epoch < run.stage_split)
    train_swin = opts.mode == "joint" or epoch >= run.stage_split or not opts.enhance
    amp = torch.autocast(device_type=dev.type, dtype=torch.bfloat16, enabled=run.bf16)
    if opts.enhance and opts.mode == "two-stage" and not train_unet and run.cache is None:
        rows = np.concatenate([run.train_idx, run.test_idx])
        with amp:
            run.cache = enhance_all(run.unet, run.data["image"], dev, rows=rows)
    sums = {"unet_loss": torch.zeros((), device=dev), "swin_loss": torch.zeros((), device=dev)}
    batches = _batches(run.train_idx, opts.batch_size, rng)
    if run.world > 1:  # the same batches in every process (one seed); each takes its share of every one
        batches = [b[run.rank :: run.world] for b in batches if len(b) >= run.world]
    t_epoch = time.perf_counter()
    for step, sel in enumerate(batches):
        run.frames_seen += len(sel)
        images = run.dev_data["image"] if run.cache is None else run.cache
        x, y, a = _tensors(images, run.dev_data, np.sort(sel), dev)
        x = x.contiguous(memory_format=torch.channels_last)
        with amp:
            if opts.enhance and run.cache is None:
                enhanced = run_u(x) if train_unet else run_u(x).detach()
                loss_u = relative_frobenius_loss(enhanced.float(), y)
                swin_in = enhanced.detach()
            else:  # raw frames (no enhancement), or frames the frozen UNet++ already enhanced
                loss_u = torch.zeros((), device=dev)
                swin_in = x
            if train_swin and opts.silhouette_noise and run.gen is not None:
                swin_in = perturb_silhouettes(swin_in, opts.silhouette_noise, run.gen)
            # A frozen Swin's loss is not worth its forward pass (two-stage's UNet++ epochs).
            # Frames outside the cube (a set over SO(3)) teach UNet++ only: ``cube_angle_loss``.
            loss_s = cube_angle_loss(run_s(swin_in).float(), a) if train_swin else torch.zeros((), device=dev)
        if train_swin:
            run.opt_s.zero_grad(set_to_none=True)
            loss_s.backward()  # type: ignore[no-untyped-call]
            run.opt_s.step()
            if run.averaged:
                run.averaged["swin"].update_parameters(run.swin)
        if train_unet:
            run.opt_u.zero_grad(set_to_none=True)
            loss_u.backward()  # type: ignore[no-untyped-call]
            run.opt_u.step()
            if run.averaged:
                run.averaged["unet"].update_parameters(run.unet)
        sums["unet_loss"] += loss_u.detach().float()  # summed on the device: no sync per step
        sums["swin_loss"] += loss_s.detach().float()
        if opts.log_every and (step + 1) % opts.log_every == 0 and run.rank == 0:
            print(
                f"train: epoch {epoch + 1}/{opts.epochs} step {step + 1}/{len(batches)} "
                f"unet {float(sums['unet_loss']) / (step + 1):.4f} swin {float(sums['swin_loss']) / (step + 1):.4f} "
                f"({(time.perf_counter() - t_epoch) / (step + 1):.2f} s/step)",
                file=sys.stderr,
                flush=True,
            )
    if train_unet:  # a frozen network's schedule stands still, so Swin starts stage two at its full rate
        run.sch_u.step()
    if train_swin:
        run.sch_s.step()
    return {k: float(v) / len(batches) for k, v in sums.items()}


def _score(run: _Run) -> dict[str, Any]:
    """Score the test split: the raw weights' per-axis MAE (and the averaged weights', with ``ema``).

    Over the test frames inside the cube (Swin's range). Where the split also has frames outside it (a set over
    SO(3)), ``test_silhouette_iou`` gives UNet++'s mean IoU with the label inside and outside the cube.
    """
    # Swin reads the frames UNet++ already enhanced (two-stage), or raw frames through UNet++ (or not).
    src, through = (run.cache, False) if run.cache is not None else (run.data["image"], run.opts.enhance)
    angles = run.data["angles_deg"][run.test_idx]
    inside = np.all(np.abs(angles) <= ANGLE_SCALE_DEG, axis=1)

    def test(u: torch.nn.Module, s: torch.nn.Module) -> tuple[list[float], np.ndarray | None]:
        """The MAE over the cube's test frames, and UNet++'s output for every test frame (one pass)."""
        if not len(run.test_idx):
            return [math.nan] * 3, None
        pred, enhanced = predict(u if through else None, s, src[run.test_idx], run.dev)
        if not inside.any():
            return [math.nan] * 3, enhanced
        return [float(v) for v in np.abs(pred[inside] - angles[inside]).mean(axis=0)], enhanced

    mae, enhanced = test(run.unet, run.swin)
    scores: dict[str, Any] = {"test_mae_deg": mae}
    if run.averaged:
        scores["ema_test_mae_deg"] = test(run.averaged["unet"].module, run.averaged["swin"].module)[0]
    if enhanced is not None and not inside.all():
        iou = silhouette_ious(enhanced, run.data["label"][run.test_idx])
        scores["test_silhouette_iou"] = {
            "cube": float(iou[inside].mean()) if inside.any() else math.nan,
            "outside": float(iou[~inside].mean()),
        }
    return scores


def _checkpoint(run: _Run, epochs_done: int, path: Path) -> None:
    """Write everything a resumed run needs (atomically), and the training record so far."""
    save_checkpoint(
        {
            "unet": run.unet.state_dict(),
            "swin": run.swin.state_dict(),
            "opt_u": run.opt_u.state_dict(),
            "opt_s": run.opt_s.state_dict(),
            "sch_u": run.sch_u.state_dict(),
            "sch_s": run.sch_s.state_dict(),
            "history": run.history,
            "epoch": epochs_done,
            "epochs": run.opts.epochs,
            "config": run.cfg.as_dict(),
            "enhance": run.opts.enhance,
            "ema": {k: avg.state_dict() for k, avg in run.averaged.items()},
        },
        path,
    )
    write_json(run.out / "training.json", _record(run))


def _finish(run: _Run) -> dict[str, Any]:
    """Write the result's weights (the averaged ones, with ``ema``), the record and the loss plot."""
    opts = run.opts
    final_u, final_s = (
        (run.averaged["unet"].module, run.averaged["swin"].module) if run.averaged else (run.unet, run.swin)
    )
    save_checkpoint(
        {"state_dict": final_u.state_dict(), "config": run.cfg.as_dict(), "ema": opts.ema}, run.out / "unetpp.pt"
    )
    save_checkpoint(
        {"state_dict": final_s.state_dict(), "config": run.cfg.as_dict(), "enhance": opts.enhance, "ema": opts.ema},
        run.out / "swin.pt",
    )
    record = _record(run)
    write_json(run.out / "training.json", record)
    plot_history(run.history, run.out / "loss.png")
    return record


def _record(run: _Run) -> dict[str, Any]:
    """The training record (``training.json``), written after every epoch and at the end."""
    opts, dev = run.opts, run.dev
    spec = run.manifest.get("spec") or {}
    return {
        "config": run.cfg.as_dict(),
        "schedule": opts.schedule(),
        "mode": opts.mode,
        "silhouette_noise": opts.silhouette_noise,
        "unet_epochs": run.stage_split if opts.mode == "two-stage" else None,
        "unet_from": str(opts.unet_from) if opts.unet_from is not None else None,
        "swin_from": str(opts.swin_from) if opts.swin_from is not None else None,
        "enhance": opts.enhance,
        "ema": opts.ema,
        "seed": opts.seed,
        "complete": bool(run.history) and run.history[-1]["epoch"] >= opts.epochs,
        "data": {
            "dir": str(run.data_dir),
            "content_sha256": run.manifest["content_sha256"],
            "frames": int(len(run.data["image"])),
            "train": int(len(run.train_idx)),
            "test": int(len(run.test_idx)),
            "radar": run.manifest.get("radar"),
            "target": (run.manifest.get("model") or {}).get("name"),
            # The target as the data set describes it (size, mesh sha256, symmetries) and the angle range.
            "target_model": run.manifest.get("model"),
            "max_angle_deg": spec.get("max_angle_deg"),
            "variety": spec.get("variety"),
            "variety_share": spec.get("variety_share", 1.0),
        },
        "hardware": {
            "device": str(dev),
            "name": torch.cuda.get_device_name(0) if dev.type == "cuda" else platform.processor() or platform.machine(),
            "torch": torch.__version__,
            "threads": torch.get_num_threads(),
            "bf16_autocast": run.bf16,
        },
        "distributed": {
            "processes": run.world,
            "backend": ("nccl" if dev.type == "cuda" else "gloo") if run.world > 1 else None,
            "frames_per_process": run.frames_seen,
        },
        "train_seconds": sum(h["seconds"] for h in run.history),
        "history": run.history,
    }


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
    swin = [h["swin_loss"] or math.nan for h in history]  # 0: Swin frozen that epoch (two-stage)
    ax[0].plot(ep, swin, label="Swin (MSE, scaled angles)")
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


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--data", help="data set directory (from `gsa simulate`); or --model to simulate one first")
    p.add_argument("--out", default="runs/train", help="output directory (checkpoints, weights, loss plot)")
    p.add_argument(
        "--recipe",
        default="compact",
        choices=sorted(RECIPES),
        help="named options to start from (shipped: how the shipped models were trained); the flags below override it",
    )
    t = p.add_argument_group("another target: simulate its data set into OUT/data first (once), then train")
    t.add_argument("--model", metavar="FILE", help="the target's mesh (.obj, .ply) in metres")
    t.add_argument("--model-scale", type=float, default=1.0, help="scale the mesh by this")
    t.add_argument("--n", type=int, default=5000, help="frames to simulate (default 5000)")
    t.add_argument("--n-train", type=int, help="of which training frames (default 80 %%)")
    t.add_argument("--variety", help="vary each frame's scattering (a preset: robust)")
    add_option_arguments(p, TrainOptions)
    p.add_argument(
        "--ray-workers",
        type=int,
        help="with GSA_RAY_ADDRESS set: Ray Train workers (default: the cluster's GPUs, else 2); DDP across them",
    )


def target_data(
    out: Path, model: str, scale: float, n: int, n_train: int | None, variety: str | None, img_size: int = 256
) -> Path:
    """Simulate ``model``'s data set into ``OUT/data`` unless it is there already; return its directory.

    Frames of another size than the radar's 256 keep its 24 x 29 m scene (coarser cells). The model
    is read and checked against the frame, and the variety preset too, before any work.
    """
    from inference.simulation.dataset import DatasetSpec, default_train_frames, generate
    from inference.simulation.radar import Radar

    base = Radar()
    k = img_size / base.n_range
    radar = Radar(
        n_range=img_size, n_azimuth=img_size, bandwidth_hz=base.bandwidth_hz * k, aperture_deg=base.aperture_deg * k
    )

    data = out / "data"
    if (data / "manifest.json").is_file():
        have = load_manifest(data)["spec"]
        if have.get("model_path") != str(model) or have.get("n") != n:
            raise DatasetError(f"{data} holds another data set; give a new --out", field="out")
        return data
    if n < 2:
        raise DatasetError(f"n {n} must be at least 2 (training and test frames)", field="n")
    n_train = default_train_frames(n) if n_train is None else n_train
    spec = DatasetSpec(n=n, n_train=n_train, model_path=str(model), model_scale=scale, variety=variety)
    generate(spec, data, radar)
    return data


def run(args: argparse.Namespace) -> int:
    if (args.data is None) == (args.model is None):
        raise InferenceError(
            "give --data (a simulated set) or --model FILE (a target to simulate), one of them", field="data"
        )
    opts = options_from_args(TrainOptions, args, base=recipe(args.recipe))
    data = args.data
    if args.model is not None:
        size = get_config(opts.config).img_size
        data = target_data(Path(args.out), args.model, args.model_scale, args.n, args.n_train, args.variety, size)
    address = os.environ.get("GSA_RAY_ADDRESS", "").strip()
    if address:  # Ray Train's TorchTrainer: DistributedDataParallel over the cluster's workers
        from inference.training.ray_train import train_on_ray

        rec = train_on_ray(data, args.out, opts, address, args.ray_workers)
    elif args.ray_workers is not None:
        raise InferenceError("--ray-workers needs a cluster: set GSA_RAY_ADDRESS", field="ray_workers")
    else:
        rec = train(data, args.out, opts)
    last = rec["history"][-1] if rec.get("history") else None  # under torchrun, process 0 alone has the record
    if last:
        z, y, x = last["test_mae_deg"]
        print(f"trained {last['epoch']} epochs into {args.out}: test MAE z/y/x {z:.2f}/{y:.2f}/{x:.2f} deg")
    return 0


def main(argv: list[str] | None = None) -> int:
    return module_main("training.train", "train", add_arguments, run, argv)


if __name__ == "__main__":
    sys.exit(main())
