"""Adapt a model set to a radar: fine-tune on its labelled frames, export, recalibrate trust on held-out scenes.

``gsa adapt --target T --frames DIR --base MODEL_DIR --out OUT_DIR`` (Hou et al. 2023's loop: a GSA
scene's optical observer labels the radar's frames, and the networks learn that radar's look):

1. The base set's networks are read back from its ONNX files (``inference.training.recover``,
   checked against ONNX Runtime), so any served folder, the shipped one included, can be adapted.
2. The labelled frames (``inference.labelled``) are split **by scene**: whole scenes are held out
   for validation, never frames of one scene on both sides. Frames outside the networks' angle
   range (the card's ``max_angle_deg``) are left out and counted.
3. UNet++ (where a radar's look enters) trains, and with ``train_swin`` Swin's last stage (its reading
   of the silhouette; left as it is by default, see ``AdaptOptions``), on the labelled training frames
   mixed with simulated frames of
   the base set's kind (``sim_ratio`` of them per labelled frame), at rates no higher than the base
   networks' own last ones, so what the simulator taught is kept. Augmented only in ways that keep
   the label true: a small translation of frame and label alike (the attitude does not change), and
   added noise (a lower SNR). No flips: a flip is the mirror attitude. Each epoch is scored on the
   held-out scenes and on fresh frames of our own kind; the weights with the lowest sum of both
   losses (the starting ones included) are kept.
4. The result is exported as shipping does (int8 UNet++, float16 Swin, parity checks) into ``OUT_DIR``,
   a folder the service serves with ``GSA_MODEL_DIR``; its card says how it was made. Where int8 moves
   the angles beyond the export's tolerance (the adapted weights are requantised on the frames at hand,
   fewer than shipping's 256), UNet++ stays float16 and the card says why.
5. Trust is recalibrated on the held-out labelled frames (``inference.trust.calibrate``): the bounds'
   scale and floor and every threshold come from the radar the set serves, and ``trust.json``
   names the frames that made it.
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import os
import platform
import shutil
import sys
import tempfile
import time
from dataclasses import asdict
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, cast

import numpy as np
import torch
from numpy.typing import NDArray

from inference.errors import DatasetError, InferenceError, module_main
from inference.files import write_json
from inference.frames import ANGLE_SCALE_DEG
from inference.labelled import FramesArg, LabelledFrames, read_labelled, scene_split
from inference.networks.swin import angle_loss
from inference.networks.unetpp import relative_frobenius_loss
from inference.rotations import geodesic_deg
from inference.training.options import AdaptOptions

SIM_SEED = 31_000  # the simulated frames mixed in: a seed no other set uses
MIN_CALIBRATION_FRAMES = 20
# Held-out scenes under which a recalibration's record carries a caution: the scale of the bounds a scene needs varies
# about 2x from scene to scene, so bounds from 2 scenes covered the next scenes 83-99 % per axis
# (design/measurements.md, "Bounds fitted on few frames").
MIN_CALIBRATION_SCENES = 3


def label_masks(angles_deg: NDArray[np.floating], radar: Any, model: Any) -> NDArray[np.bool_]:
    """The theoretical projection (paper eq. 10) of the target at each attitude, on the models' grid."""
    from inference.rotations import rotation_matrix
    from inference.simulation.radar import Imager
    from inference.simulation.scene import label_mask

    imager = Imager(radar)
    return np.stack([label_mask(imager, model.surface @ rotation_matrix(*a).T) for a in np.asarray(angles_deg)])


def _augment(
    x: torch.Tensor, y: torch.Tensor, opts: AdaptOptions, gen: torch.Generator
) -> tuple[torch.Tensor, torch.Tensor]:
    """Translate frame and label alike by up to ``shift_px`` (rolling; the frame's edges are noise), and add
    noise to a share of frames: the normalised dB back to power, complex-Gaussian power added at 0.3 to 3x
    the frame's mean, then normalised again as ``normalise_frame`` does."""
    b = x.shape[0]
    if opts.shift_px:
        s = torch.randint(-opts.shift_px, opts.shift_px + 1, (b, 2), generator=gen)
        x = torch.stack([torch.roll(x[k], (int(s[k, 0]), int(s[k, 1])), (-2, -1)) for k in range(b)])
        y = torch.stack([torch.roll(y[k], (int(s[k, 0]), int(s[k, 1])), (-2, -1)) for k in range(b)])
    if opts.noise_share:
        pick = torch.rand(b, generator=gen) < opts.noise_share
        if bool(pick.any()):
            amp = torch.pow(10.0, (x[pick] * 40.0 - 40.0) / 20.0)
            level = amp.pow(2).mean(dim=(-2, -1), keepdim=True) * (
                0.3 + 2.7 * torch.rand(amp.shape[0], 1, 1, 1, generator=gen)
            )
            re = torch.randn(amp.shape, generator=gen)
            im = torch.randn(amp.shape, generator=gen)
            noisy = torch.sqrt((amp + torch.sqrt(level / 2) * re) ** 2 + (torch.sqrt(level / 2) * im) ** 2)
            ref = torch.quantile(noisy.flatten(1), 0.995, dim=1).view(-1, 1, 1, 1).clamp_min(1e-12)
            db = 20.0 * torch.log10(noisy.clamp_min(1e-12) / ref)
            x = x.clone()
            x[pick] = ((db + 40.0) / 40.0).clamp(0.0, 1.0)
    return x, y


def _windows(x: torch.Tensor, y: torch.Tensor, size: int, gen: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    """A ``size`` x ``size`` window of each frame and its label alike, centred on a pixel of the label drawn at
    random (so each window shows part of the target's silhouette and the clutter about it), kept inside the frame.
    Frames no larger than ``size`` come back whole."""
    h, w = x.shape[-2:]
    if size <= 0 or (size >= h and size >= w):
        return x, y
    sh, sw = min(size, h), min(size, w)
    weights = y.flatten(1) + 1e-6  # a frame with no silhouette gets a window anywhere
    at = torch.multinomial(weights, 1, generator=gen)[:, 0]
    r0 = (at // w - sh // 2).clamp(0, h - sh)
    c0 = (at % w - sw // 2).clamp(0, w - sw)
    at_rc = [(int(r), int(c)) for r, c in zip(r0.tolist(), c0.tolist(), strict=True)]
    xs = torch.stack([x[k, :, r : r + sh, c : c + sw] for k, (r, c) in enumerate(at_rc)])
    ys = torch.stack([y[k, :, r : r + sh, c : c + sw] for k, (r, c) in enumerate(at_rc)])
    return xs, ys


@torch.no_grad()
def _scores(
    unet: torch.nn.Module, swin: torch.nn.Module, x: NDArray[np.float32], y: NDArray[np.bool_], a: NDArray[np.float64]
) -> dict[str, float]:
    """Validation: both losses (their sum chooses the weights), Swin's geodesic error, UNet++'s silhouette IoU."""
    unet.eval()
    swin.eval()
    lu, ls, ious, pred = [], [], [], []
    for k in range(0, len(x), 16):
        xb = torch.from_numpy(x[k : k + 16, None])
        yb = torch.from_numpy(y[k : k + 16, None].astype(np.float32))
        enh = unet(xb)
        out = swin(enh)
        lu.append(float(relative_frobenius_loss(enh, yb)) * len(xb))
        ls.append(float(angle_loss(out, torch.from_numpy(a[k : k + 16] / ANGLE_SCALE_DEG).float())) * len(xb))
        m = enh[:, 0].numpy() > 0.5
        t = y[k : k + 16]
        ious.extend((m & t).sum(axis=(1, 2)) / np.maximum((m | t).sum(axis=(1, 2)), 1))
        pred.append(out.numpy() * ANGLE_SCALE_DEG)
    geo = geodesic_deg(np.concatenate(pred), a)
    n = len(x)
    return {
        "unet_loss": sum(lu) / n,
        "swin_loss": sum(ls) / n,
        "loss": (sum(lu) + sum(ls)) / n,
        "swin_geodesic_median_deg": float(np.median(geo)),
        "swin_beyond_10_deg": float(np.mean(geo > 10.0)),
        "iou_median": float(np.median(ious)),
    }


def simulated_frames(n: int, max_angle_deg: float, radar: Any, seed: int = SIM_SEED) -> dict[str, NDArray[Any]]:
    """``n`` frames of the simulator's default kind (what the base set learnt from), seeded ``seed``."""
    from inference.simulation.dataset import DatasetSpec, render_frames

    if n == 0:
        size = (0, radar.n_range, radar.n_azimuth)
        return {"image": np.zeros(size, np.float32), "label": np.zeros(size, bool), "angles_deg": np.zeros((0, 3))}
    arr = render_frames(DatasetSpec(n=n, seed=seed, max_angle_deg=max_angle_deg), radar, 0, n)
    return {
        "image": arr["image"].astype(np.float32),
        "label": np.unpackbits(arr["label"], axis=2)[:, :, : radar.n_azimuth].astype(bool),
        "angles_deg": arr["angles_deg"].astype(np.float64),
    }


def _say(text: str) -> None:
    print(f"adapt: {text}", file=sys.stderr, flush=True)


def adapt(
    base_dir: str | Path,
    frames: FramesArg,
    out_dir: str | Path,
    opts: AdaptOptions | None = None,
    target: str | None = None,
    work_dir: str | Path | None = None,
) -> dict[str, Any]:
    """Adapt ``base_dir``'s networks to the labelled frames; write the adapted set to ``out_dir``; return its record.

    ``frames``: a folder in the labelled format (or several), or frames already read. ``target``: the target the
    frames show (default and only choice so far: the base set's). A failure leaves ``out_dir`` as it was.
    """
    from inference.export import export
    from inference.runtime import read_card
    from inference.simulation.targets import builtin_target
    from inference.training.checkpoints import save_checkpoint
    from inference.training.recover import recover
    from inference.training.train import agreed_stop, distributed_world, start_distributed, uses_bf16
    from inference.trust import card_radar_and_target

    opts = opts or AdaptOptions()
    rank, world = distributed_world()  # under torchrun or Ray Train: one of `world` processes (DDP on the CPU)
    if world > 1:
        if opts.batch_size < world:
            raise InferenceError(
                f"batch size {opts.batch_size} is smaller than the {world} processes that share each step",
                field="batch_size",
            )
        start_distributed(torch.device("cpu"))
    lead = rank == 0

    def say(text: str) -> None:
        if lead:
            _say(text)

    t0 = time.perf_counter()
    cpu0 = time.process_time()
    base = Path(base_dir)
    card = read_card(base)
    size = int(card["config"]["img_size"])
    radar, trained_target = card_radar_and_target(base, size)
    if target is not None and target != trained_target:
        raise DatasetError(
            f"target {target!r}: the base set's networks know {trained_target!r}; adapt a set trained on that target",
            field="target",
        )
    model = builtin_target(trained_target)
    max_angle = float(card.get("max_angle_deg") or 45.0)
    frames = read_labelled(frames, size, (radar.range_cell_m, radar.cross_range_cell_m))  # bad ones refused now
    inside = np.all(np.abs(frames.angles_deg) <= max_angle, axis=1)
    left_out = int(np.count_nonzero(~inside))
    frames = frames.subset(np.flatnonzero(inside))
    if len(frames) < 4:
        raise DatasetError(
            f"{len(frames)} labelled frames within the networks' +-{max_angle:g} deg ({left_out} outside): "
            "adapting needs at least 4, from 2 scenes or more",
            field="frames",
        )
    train_idx, val_idx = scene_split(frames.scenes, opts.validation_share, opts.seed)
    say(f"reading the base set {base} back from its ONNX files")
    unet, swin, cfg, parity = recover(base)
    train, val = frames.subset(train_idx), frames.subset(val_idx)
    say(
        f"{len(frames)} labelled frames ({left_out} outside +-{max_angle:g} deg left out): {len(train)} from "
        f"{len(set(train.scenes))} scene(s) to train on, {len(val)} from {len(set(val.scenes))} held out"
    )
    y_train = label_masks(train.angles_deg, radar, model)
    y_val = label_masks(val.angles_deg, radar, model)
    n_sim = int(math.ceil(opts.sim_ratio * len(train)))
    say(f"simulating {n_sim} frames of the base set's kind to mix in")
    sim = simulated_frames(n_sim, max_angle, radar)
    x_all = np.concatenate([train.frames, sim["image"]])
    y_all = np.concatenate([y_train, sim["label"]])
    a_all = np.concatenate([train.angles_deg, sim["angles_deg"]])
    labelled_share = len(train) / len(x_all)

    dev = torch.device("cpu")
    bf16 = uses_bf16(dev, opts.precision)
    torch.manual_seed(opts.seed)
    gen = torch.Generator().manual_seed(opts.seed)
    rng = np.random.default_rng(opts.seed)
    unet.to(memory_format=torch.channels_last)  # type: ignore[call-overload]  # as training does: a third faster a step
    opt_u = torch.optim.Adam(unet.parameters(), lr=opts.lr_unet)
    tail = cast(Any, swin).tail_modules(1).parameters() if opts.train_swin else iter(())
    opt_s = torch.optim.Adam(list(tail) or [torch.zeros(1, requires_grad=True)], lr=opts.lr_swin)
    step_u: torch.nn.Module = unet  # what each step runs: under DDP, wrappers that average the gradients
    step_s: torch.nn.Module = swin
    if world > 1:
        from torch.nn.parallel import DistributedDataParallel as DDP

        step_u = DDP(unet)  # every process starts from process 0's weights
        if opts.train_swin:
            step_s = DDP(swin)
    # What must not be lost: fresh frames of our own kind, scored beside the held-out labelled ones; the weights
    # kept are those with the lowest sum of both losses.
    own = simulated_frames(max(16, len(val)), max_angle, radar, SIM_SEED + 1)

    def validate() -> dict[str, Any]:
        mine = _scores(unet, swin, val.frames, y_val, val.angles_deg)
        ours = _scores(unet, swin, own["image"], own["label"], own["angles_deg"])
        return {
            **mine,
            "own_loss": ours["loss"],
            "own_swin_geodesic_median_deg": ours["swin_geodesic_median_deg"],
            "own_iou_median": ours["iou_median"],
            "score": mine["loss"] + ours["loss"],
        }

    before = validate() if lead else {"score": 0.0}  # process 0 scores, keeps the best weights and writes
    if lead:
        say(
            f"before: held-out Swin median {before['swin_geodesic_median_deg']:.2f} deg, "
            f"UNet++ IoU {before['iou_median']:.3f}, loss {before['loss']:.4f}; our own frames' Swin median "
            f"{before['own_swin_geodesic_median_deg']:.2f} deg"
        )
    best = (before["score"], 0, copy.deepcopy(unet.state_dict()), copy.deepcopy(swin.state_dict())) if lead else None
    history = [{"epoch": 0, **before, "seconds": 0.0}]
    deadline = t0 + 60.0 * opts.max_minutes
    h, w = x_all.shape[-2:]
    repeats = max(1, round(h * w / min(opts.crop_px, h) / min(opts.crop_px, w))) if opts.crop_px else 1
    for epoch in range(1, opts.epochs + 1):
        unet.train()
        swin.train()
        # On windows, an epoch passes over the frames as many times as a frame holds windows: about the pixels (and
        # the seconds) of a whole-frame epoch, so each validation still follows as much training.
        order = np.concatenate([rng.permutation(len(x_all)) for _ in range(repeats)])
        sums = [0.0, 0.0]
        seen = 0  # frames this process stepped on (its share of each batch under DDP)
        for k in range(0, len(order), opts.batch_size):
            sel = np.sort(order[k : k + opts.batch_size])
            if world > 1:  # the same batches everywhere (one seed); each process takes its share of each
                if len(sel) < world:
                    continue
                sel = sel[rank::world]
            x = torch.from_numpy(x_all[sel, None])
            y = torch.from_numpy(y_all[sel, None].astype(np.float32))
            a = torch.from_numpy(a_all[sel] / ANGLE_SCALE_DEG).float()
            x, y = _augment(x, y, opts, gen)
            if opts.crop_px:
                x, y = _windows(x, y, opts.crop_px, gen)
            x = x.contiguous(memory_format=torch.channels_last)
            with torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
                enh = step_u(x)
                loss_u = relative_frobenius_loss(enh.float(), y)
                if opts.train_swin:
                    loss_s = angle_loss(step_s(enh.detach()).float(), a)
                else:
                    loss_s = torch.zeros(())
            if opts.train_swin:
                opt_s.zero_grad(set_to_none=True)
                loss_s.backward()  # type: ignore[no-untyped-call]
                opt_s.step()
            opt_u.zero_grad(set_to_none=True)
            loss_u.backward()  # type: ignore[no-untyped-call]
            opt_u.step()
            sums[0] += float(loss_u.detach()) * len(sel)
            sums[1] += float(loss_s.detach()) * len(sel)
            seen += len(sel)
        if lead:
            score = validate()
            history.append(
                {
                    "epoch": epoch,
                    **score,
                    "train_unet_loss": sums[0] / max(seen, 1),
                    "train_swin_loss": sums[1] / max(seen, 1),
                    "seconds": round(time.perf_counter() - t0, 1),
                }
            )
            mark = ""
            assert best is not None
            if score["score"] < best[0]:
                best = (score["score"], epoch, copy.deepcopy(unet.state_dict()), copy.deepcopy(swin.state_dict()))
                mark = " (best so far)"
            say(
                f"epoch {epoch}/{opts.epochs}: held-out Swin median {score['swin_geodesic_median_deg']:.2f} deg, "
                f"IoU {score['iou_median']:.3f}, loss {score['loss']:.4f}; own frames' Swin median "
                f"{score['own_swin_geodesic_median_deg']:.2f} deg{mark} [{time.perf_counter() - t0:.0f} s]"
            )
        if agreed_stop(time.perf_counter() > deadline, world, torch.device("cpu")):
            say(f"max_minutes {opts.max_minutes:g} reached after epoch {epoch}")
            break
    del step_u, step_s  # the DDP wrappers hold the process group; they go before it does (see _leave_group)
    if not lead:  # process 0 exports and recalibrates; the others are done
        _leave_group(world)
        return {}
    assert best is not None
    unet.load_state_dict(best[2])
    swin.load_state_dict(best[3])
    after = validate()
    train_seconds = time.perf_counter() - t0

    record: dict[str, Any] = {
        "base": {
            "dir": str(base),
            "name": card.get("name"),
            "files": {k: v.get("sha256") for k, v in card["files"].items()},
        },
        "recovered_parity": parity,
        "labelled": {
            "frames": len(frames),
            "left_out_outside_range": left_out,
            "list_sha256": frames.list_sha256(),
            "train_frames": len(train),
            "train_scenes": sorted(set(train.scenes)),
            "validation_frames": len(val),
            "validation_scenes": sorted(set(val.scenes)),
            "coverage_train": _coverage(train.angles_deg, max_angle),
        },
        "simulated_frames": n_sim,
        "labelled_share_of_training": round(labelled_share, 4),
        "options": asdict(opts),
        "augmentations": [f"translation up to {opts.shift_px} px, label alike", f"noise on {opts.noise_share:.0%}"]
        + ([f"windows of {opts.crop_px} px about the target, label alike"] if opts.crop_px else []),
        "chosen_epoch": best[1],
        "history": history,
        "before": before,
        "after": after,
        "bf16": bf16,
        "processes": world,
        "cpu": platform.processor() or platform.machine(),
        "train_seconds": round(train_seconds, 1),
    }
    out = Path(out_dir)
    work = Path(work_dir) if work_dir else Path(tempfile.mkdtemp(prefix="gsa-adapt-"))
    work.mkdir(parents=True, exist_ok=True)
    try:
        for name, net in (("unetpp.pt", unet), ("swin.pt", swin)):
            save_checkpoint({"state_dict": net.state_dict(), "config": cfg, "enhance": True}, work / name)
        data = {k: card.get(k) for k in ("radar", "target", "target_model", "max_angle_deg")}
        data["target"] = data["target"] or trained_target
        write_json(work / "training.json", {"mode": "adapt", "data": data, "complete": True, "seed": opts.seed})
        say(f"exporting to {out} (int8 UNet++, float16 Swin)")
        mixed = np.concatenate([train.frames, sim["image"]])
        int8_frames = mixed[np.random.default_rng(opts.seed).permutation(len(mixed))[:128]]
        try:
            exported = export(work, out, int8_frames, extra={"adaptation": record}, half=True, int8=True)
            record["export"] = "int8 UNet++ (as shipped), float16 Swin"
        except InferenceError as exc:  # int8 moved the angles too far: keep UNet++ in float16, and say why
            say(f"int8 refused ({exc}); exporting UNet++ in float16")
            record["export"] = f"float16 UNet++ and Swin: int8 refused ({exc})"
            exported = export(work, out, int8_frames, extra={"adaptation": record}, half=True, int8=False)
    finally:
        if not work_dir:
            shutil.rmtree(work, ignore_errors=True)
    record["calibration"] = recalibrate(out, val, radar, model, base)
    if not record["calibration"]["recalibrated"] and (base / "trust.json").is_file():
        shutil.copyfile(base / "trust.json", out / "trust.json")
    record["cpu_minutes"] = round((time.process_time() - cpu0) / 60.0, 2)
    record["minutes"] = round((time.perf_counter() - t0) / 60.0, 2)
    exported["adaptation"] = record
    write_json(out / "model_card.json", exported)
    say(f"done in {record['minutes']:.1f} min ({record['cpu_minutes']:.1f} CPU min): {out}")
    _leave_group(world)
    return record


def _leave_group(world: int) -> None:
    """Under DDP: wait for every process, then leave the group.

    The DDP wrappers must be gone first: one still alive at interpreter exit tears down gloo's worker threads there,
    and the process dies with SIGABRT ("terminate called without an active exception") after its work is done."""
    if world > 1:
        import gc

        import torch.distributed as dist

        gc.collect()
        dist.barrier()
        dist.destroy_process_group()


def _coverage(angles: NDArray[np.float64], limit: float) -> float:
    from inference.labelled import coverage

    return round(coverage(angles, limit), 4)


def recalibrate(
    model_dir: Path, val: LabelledFrames, radar: Any, model: Any, base: Path | None = None
) -> dict[str, Any]:
    """Calibrate trust on the held-out labelled frames through the exported set; write its ``trust.json``.

    With fewer than ``MIN_CALIBRATION_FRAMES`` held-out frames the base set's calibration is kept
    (copied) and the record says so: thresholds from a handful of frames would be noise. The library
    search's trigger stays the base set's (``Calibration.search_iou_min``): this radar's poorer
    silhouettes lower the trust threshold, and a trigger that low would stop the search where Swin is wrong.
    The network path's bound limit and ambiguity margin are chosen on the held-out frames (``network_limits``).
    Under ``MIN_CALIBRATION_SCENES`` held-out scenes the record carries a ``caution`` (and the log says it).
    """
    from inference.runtime import Estimator
    from inference.trust import TRUST_FILE, Calibration, Checker, calibrate

    if len(val) < MIN_CALIBRATION_FRAMES:
        return {
            "recalibrated": False,
            "why": f"{len(val)} held-out frames; recalibrating needs {MIN_CALIBRATION_FRAMES}: the base set's "
            "calibration is kept",
        }
    est = Estimator.load(model_dir)
    res = est.estimate(val.frames)
    made = {
        "command": "gsa adapt",
        "date": datetime.now(UTC).date().isoformat(),
        "models": est.identity,
        "labelled_frames": list(val.names),
        "scenes": sorted(set(val.scenes)),
        "list_sha256": val.list_sha256(),
    }
    trigger = None
    if base is not None and (base / TRUST_FILE).is_file():
        trigger = Calibration.load(base / TRUST_FILE).search_below
    _say(f"recalibrating trust on {len(val)} held-out labelled frames (the search's trigger: IoU {trigger})")
    cal, checks = calibrate(
        Checker(model, radar),
        val.frames,
        res.enhanced,
        res.angles_deg,
        val.angles_deg,
        made,
        search_iou_min=trigger,
        search_enhancer=est.search_enhancer,
        own_limits=True,
    )
    cal.write(model_dir / TRUST_FILE)
    fitted = np.array([c.angles_deg for c in checks])
    geo = geodesic_deg(fitted, val.angles_deg)
    scenes = len(set(val.scenes))
    caution = {}
    if scenes < MIN_CALIBRATION_SCENES:
        caution["caution"] = (
            f"trust was calibrated on {scenes} held-out scene(s): the bounds a scene needs vary about 2x from scene to "
            f"scene, and bounds from 2 scenes covered the next ones 83-99 % per axis, not 90 %; label more scenes, "
            f"so that {MIN_CALIBRATION_SCENES} or more are held out and as many are left to learn from"
        )
        _say(caution["caution"])
    return {
        "recalibrated": True,
        "frames": len(val),
        "scenes": scenes,
        **caution,
        "fitted_geodesic_median_deg": round(float(np.median(geo)), 3),
        "flagged_share": round(float(np.mean([not c.quality.trusted for c in checks])), 3),
        "search_iou_min": trigger,
        "max_bound_deg": cal.max_bound_deg,
        "ambiguity_margin": cal.ambiguity_margin,
    }


def add_arguments(p: argparse.ArgumentParser) -> None:
    d = AdaptOptions()
    p.add_argument(
        "--frames",
        required=True,
        nargs="+",
        help="folder(s) of labelled frames (one .npz each; see inference.labelled)",
    )
    p.add_argument("--base", default=None, help="model folder to start from (default: the shipped models)")
    p.add_argument("--out", required=True, help="where to write the adapted model folder (GSA_MODEL_DIR serves it)")
    p.add_argument("--target", default=None, help="the target the frames show (default: the base set's)")
    p.add_argument(
        "--sim-ratio", type=float, default=d.sim_ratio, help=f"simulated frames per labelled one ({d.sim_ratio:g})"
    )
    p.add_argument("--epochs", type=int, default=d.epochs, help=f"at most this many epochs ({d.epochs})")
    p.add_argument(
        "--max-minutes",
        type=float,
        default=d.max_minutes,
        help=f"stop after the epoch that passes this ({d.max_minutes:g})",
    )
    p.add_argument(
        "--validation-share", type=float, default=d.validation_share, help="share of frames held out, by whole scenes"
    )
    p.add_argument("--batch-size", type=int, default=d.batch_size)
    p.add_argument("--lr-unet", type=float, default=d.lr_unet, help=f"UNet++'s Adam rate ({d.lr_unet:g})")
    p.add_argument(
        "--crop-px",
        type=int,
        default=d.crop_px,
        help=f"train on windows of this many pixels about the target, a multiple of 16; 0 whole frames ({d.crop_px})",
    )
    p.add_argument("--train-swin", action="store_true", help="also fine-tune Swin's last stage (default: UNet++ only)")
    p.add_argument("--seed", type=int, default=d.seed)
    p.add_argument(
        "--map",
        action="store_true",
        help="also build the reflectivity map from the frames beside the fine-tuning (inference.reflectivity)",
    )
    p.add_argument(
        "--map-only",
        action="store_true",
        help="only build the map (a few CPU minutes, no training): the base set's networks as they are, plus the map",
    )
    p.add_argument(
        "--ray-workers", type=int, help="with GSA_RAY_ADDRESS set: Ray Train workers (default 2), DDP on their CPUs"
    )


def run(args: argparse.Namespace) -> int:
    from inference.runtime import DEFAULT_MODEL_DIR

    opts = AdaptOptions(
        sim_ratio=args.sim_ratio,
        epochs=args.epochs,
        max_minutes=args.max_minutes,
        validation_share=args.validation_share,
        batch_size=args.batch_size,
        lr_unet=args.lr_unet,
        crop_px=args.crop_px,
        seed=args.seed,
        train_swin=args.train_swin,
    )
    out = Path(args.out)
    base = Path(args.base) if args.base else DEFAULT_MODEL_DIR
    if out.resolve() == base.resolve():
        raise InferenceError("--out is the base folder: write the adapted set to a new folder", field="out")
    # ``gsa adapt --plan`` reads the folder beforehand (the planner places its J2000 labels): ``args.labelled``.
    frames = getattr(args, "labelled", None) or args.frames
    if args.map_only:
        from inference.reflectivity.sets import map_only, summary

        print(json.dumps({"map": summary(map_only(base, frames, out, args.seed, args.target))}, indent=1))
        return 0
    address = os.environ.get("GSA_RAY_ADDRESS", "").strip()
    if address:  # Ray Train's TorchTrainer: DDP over the cluster's workers (CPUs)
        from inference.training.ray_train import adapt_on_ray

        record = adapt_on_ray(base, frames, out, opts, args.target, address, args.ray_workers)
    elif args.ray_workers is not None:
        raise InferenceError("--ray-workers needs a cluster: set GSA_RAY_ADDRESS", field="ray_workers")
    else:
        record = adapt(base, frames, out, opts, args.target)
    shown = {k: record[k] for k in ("before", "after", "chosen_epoch", "calibration", "minutes")}
    if args.map:
        from inference.reflectivity.sets import add_map, summary

        shown["map"] = summary(add_map(out, frames, args.seed, args.target))
    print(json.dumps(shown, indent=1))
    return 0


def main(argv: list[str] | None = None) -> int:
    return module_main("training.adapt", "gsa adapt", add_arguments, run, argv)


if __name__ == "__main__":
    raise SystemExit(main())
