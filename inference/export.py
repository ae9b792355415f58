"""Export trained UNet++ and Swin to ONNX, prove parity with torch, and write the model card.

Options shrink or speed up the files once float32 parity is proven: ``--half`` stores the
large weights in float16 (computed in float32), and ``--int8`` quantises UNet++ to int8
(static, per-channel weights, calibrated on real frames), which runs it faster on a CPU with
int8 dot-product instructions. Swin stays in floating point: int8 there moved the angles more
for less time saved (design/measurements.md, "int8 UNet++, floating-point Swin").
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import torch

from inference.errors import InferenceError, module_main
from inference.files import sha256_file, write_json
from inference.frames import ANGLE_SCALE_DEG, silhouette_ious
from inference.runtime import SELFCHECK_POOL, check_computes_here, pooled, selfcheck_frames
from inference.training.checkpoints import load_trained

OPSET = 17
PARITY_RTOL = 1e-4  # relative difference, float32, ORT against torch
HALF_RTOL = 1e-2  # relative difference once the weights are stored in float16 (bf16/fp16 rounding is ~1e-3)
HALF_MIN_ELEMENTS = 1024  # smaller tensors (biases, norms) stay float32: they cost nothing
# int8 UNet++: the largest mean change of an Euler angle (deg, on frames it was not calibrated on)
# that the export accepts. The shipped models moved by 0.06 / 0.12 / 0.12 deg; their error is ~1-2 deg.
INT8_ANGLE_TOL_DEG = 0.25
INT8_MIN_FRAMES = 8  # real frames needed: half calibrate, half check
PARITY_FRAMES = 16  # real frames for the float parity checks (each runs through torch and ORT)


def export_onnx(model: torch.nn.Module, path: Path, img_size: int) -> None:
    """Export with a dynamic batch axis and check the graph."""
    import onnx

    dummy = torch.zeros(2, 1, img_size, img_size)
    torch.onnx.export(
        model,
        (dummy,),
        str(path),
        input_names=["frame"],
        output_names=["out"],
        opset_version=OPSET,
        dynamic_axes={"frame": {0: "batch"}, "out": {0: "batch"}},
        dynamo=False,
    )
    onnx.checker.check_model(onnx.load(str(path)), full_check=True)


def store_half(path: Path, min_elements: int = HALF_MIN_ELEMENTS) -> int:
    """Store a float32 ONNX model's large weights as float16, each followed by a Cast back to float32.

    The graph still computes in float32: ONNX Runtime folds the Casts when it loads the model,
    so only the file halves. Returns the number of tensors converted.
    """
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    model = onnx.load(str(path))
    graph = model.graph
    kept, casts = [], []
    for init in graph.initializer:
        if init.data_type == TensorProto.FLOAT and int(np.prod(init.dims)) >= min_elements:
            half = numpy_helper.from_array(numpy_helper.to_array(init).astype(np.float16), f"{init.name}__fp16")
            kept.append(half)
            casts.append(
                helper.make_node("Cast", [half.name], [init.name], name=f"{init.name}__cast", to=TensorProto.FLOAT)
            )
        else:
            kept.append(init)
    del graph.initializer[:]
    graph.initializer.extend(kept)
    nodes = casts + list(graph.node)
    del graph.node[:]
    graph.node.extend(nodes)
    onnx.checker.check_model(model, full_check=True)
    onnx.save(model, str(path))
    return len(casts)


def quantize_int8(src: Path, dst: Path, frames: np.ndarray) -> int:
    """Quantise a float32 ONNX model to int8: static, per-channel 7-bit weights, QDQ format, calibrated on ``frames``.

    ``frames`` is [N, 1, H, W]: real inputs, whose activation ranges (min/max) fix the
    activation scales. Returns the number of QuantizeLinear nodes (activations quantised).
    """
    import onnx
    from onnxruntime.quantization import CalibrationDataReader, QuantFormat, QuantType, quantize_static
    from onnxruntime.quantization.shape_inference import quant_pre_process

    class Frames(CalibrationDataReader):  # type: ignore[misc]  # onnxruntime ships no type hints
        def __init__(self) -> None:
            self.feeds = iter([{"frame": frames[k : k + 1]} for k in range(len(frames))])

        def get_next(self) -> dict[str, np.ndarray] | None:
            return next(self.feeds, None)

    with tempfile.TemporaryDirectory() as tmp:
        pre = Path(tmp) / "pre.onnx"
        quant_pre_process(str(src), str(pre))  # shape inference and graph fusions, as the quantiser asks
        quantize_static(
            str(pre),
            str(dst),
            Frames(),
            quant_format=QuantFormat.QDQ,
            per_channel=True,
            activation_type=QuantType.QUInt8,
            weight_type=QuantType.QInt8,
            # 7-bit weights: on an x86 CPU without VNNI, onnxruntime's uint8 x int8 kernels sum pairs of
            # products in int16 (VPMADDUBSW), which saturates with full 8-bit weights (255 x 127 x 2). The
            # 8-bit UNet++ gave IoU 0.90 instead of 0.99 on such a CPU (AMD EPYC with AVX2 only) and
            # Swin 18 deg instead of 2; with 7 bits no pair can saturate, so every CPU computes the same.
            reduce_range=True,
        )
    model = onnx.load(str(dst))
    onnx.checker.check_model(model, full_check=True)
    return sum(n.op_type == "QuantizeLinear" for n in model.graph.node)


def parity_inputs(size: int, frames: np.ndarray | None) -> list[np.ndarray]:
    """What parity is checked on: two seeded random frames [2, 1, size, size] and up to PARITY_FRAMES real ones."""
    tests = [np.random.default_rng(0).random((2, 1, size, size), dtype=np.float32)]
    if frames is not None:
        tests.append(frames[:PARITY_FRAMES, None].astype(np.float32))
    return tests


def exported_float(model: torch.nn.Module, path: Path, size: int, inputs: list[np.ndarray]) -> dict[str, Any]:
    """Export ``model`` to ``path`` and hold ONNX Runtime to torch on ``inputs`` (PARITY_RTOL); its card entry."""
    export_onnx(model, path, size)
    worst = max(parity(model, path, t) for t in inputs)
    if worst > PARITY_RTOL:
        raise InferenceError(f"{path.name}: ONNX Runtime differs from torch by {worst:.2e} (> {PARITY_RTOL})")
    return {"weights": "float32", "parity_max_rel_diff": worst}


def stored_half(model: torch.nn.Module, path: Path, inputs: list[np.ndarray]) -> dict[str, Any]:
    """Store the exported file's large weights in float16 (``store_half``) and hold it to torch again (HALF_RTOL)."""
    entry: dict[str, Any] = {"float16_tensors": store_half(path)}
    entry["half_max_rel_diff"] = max(parity(model, path, t) for t in inputs)
    entry["weights"] = "float16 (computed in float32)"
    if entry["half_max_rel_diff"] > HALF_RTOL:
        raise InferenceError(
            f"{path.name}: float16 weights change the output by {entry['half_max_rel_diff']:.2e} "
            f"(> {HALF_RTOL}); export without --half"
        )
    return entry


def check_int8_frames(frames: np.ndarray | None) -> None:
    """Refuse int8 without enough real frames to calibrate on and check."""
    if frames is None or len(frames) < INT8_MIN_FRAMES:
        raise InferenceError(
            f"int8 quantisation needs at least {INT8_MIN_FRAMES} real frames to calibrate and check on; "
            "give --frames DATA (a data set from gsa simulate)"
        )


def quantised_unet(path: Path, unet: torch.nn.Module, frames: np.ndarray) -> tuple[dict[str, Any], Any, Any]:
    """Quantise the exported float32 UNet++ at ``path`` in place on the first half of ``frames`` [N, H, W]; return
    the card's int8 entries and, on the second half, the int8 file's output and the float network's [M, 1, H, W]."""
    x = frames[:, None].astype(np.float32)
    calib, check = x[: len(x) // 2], x[len(x) // 2 :]
    nodes = quantize_int8(path, path, calib)
    sess = _session(path)
    got = np.concatenate([sess.run(None, {"frame": check[k : k + 8]})[0] for k in range(0, len(check), 8)])
    with torch.no_grad():
        ref = torch.cat([unet(torch.from_numpy(check[k : k + 8])) for k in range(0, len(check), 8)]).numpy()
    entry = {
        "weights": "int8 (static, per-channel 7-bit weights, QDQ)",
        "int8_quantized_activations": nodes,
        "int8_calibration_frames": len(calib),
        "int8_check_frames": len(check),
        "int8_enhanced_mean_abs_diff": float(np.abs(got - ref).mean()),
    }
    return entry, got, ref


def parity(model: torch.nn.Module, path: Path, frames: np.ndarray) -> float:
    """Return the largest relative difference between ONNX Runtime and torch on ``frames`` [N, 1, H, W]."""
    sess = _session(path)
    with torch.no_grad():
        ref = model(torch.from_numpy(frames)).numpy()
    got = sess.run(None, {"frame": frames})[0]
    return float(np.abs(got - ref).max() / max(np.abs(ref).max(), 1e-12))


def export(
    run_dir: str | Path,
    out_dir: str | Path,
    frames: np.ndarray | None = None,
    extra: dict[str, Any] | None = None,
    half: bool = False,
    int8: bool = False,
) -> dict[str, Any]:
    """Export a training run's networks to ``out_dir`` with a model card; return the card.

    Parity is checked on random frames and on up to PARITY_FRAMES of ``frames`` (real ones,
    [N, H, W], if given): ORT must match torch within PARITY_RTOL. With ``half`` the large
    weights are then stored in float16 (``store_half``), which halves the files; ORT must
    still match torch within HALF_RTOL, and the card records both differences. With
    ``int8`` UNet++ is quantised (``quantize_int8``) on the first half of ``frames``, and
    the second half checks it: Swin's angles from the int8 UNet++ may differ from those
    from the float one by at most INT8_ANGLE_TOL_DEG on average, per axis.
    """
    if int8:
        check_int8_frames(frames)
    unet, swin, cfg, enhance = load_trained(run_dir)
    if int8 and not enhance:
        raise InferenceError("--int8 quantises UNet++, which this run's Swin (trained on raw frames) does not use")
    out = Path(out_dir)
    out.parent.mkdir(parents=True, exist_ok=True)
    # Everything is written and checked in a folder beside ``out`` and moved in only once it all
    # passed, so a failed export leaves the models already in ``out`` (the shipped ones, by default)
    # as they were.
    stage = Path(tempfile.mkdtemp(prefix=f".{out.name}-export-", dir=out.parent))
    try:
        card = _export_into(stage, unet, swin, cfg, enhance, Path(run_dir), frames, extra, half, int8)
        out.mkdir(exist_ok=True)
        for name in ("unetpp.onnx", "swin.onnx", "model_card.json"):  # the card last, naming the new files
            os.replace(stage / name, out / name)
    finally:
        shutil.rmtree(stage, ignore_errors=True)
    return card


def _export_into(
    out: Path,
    unet: torch.nn.Module,
    swin: torch.nn.Module,
    cfg: dict[str, Any],
    enhance: bool,
    run_dir: Path,
    frames: np.ndarray | None,
    extra: dict[str, Any] | None,
    half: bool,
    int8: bool,
) -> dict[str, Any]:
    """Write both ONNX files and the model card into ``out``, checking each step; return the card."""
    size = cfg["img_size"]
    tests = parity_inputs(size, frames)
    with torch.no_grad():
        enhanced = [unet(torch.from_numpy(t)).numpy() for t in tests]
    report: dict[str, Any] = {}
    for role, model, inputs in (("unetpp", unet, tests), ("swin", swin, tests + enhanced)):
        path = out / f"{role}.onnx"
        entry = exported_float(model, path, size, inputs)
        if int8 and role == "unetpp" and frames is not None:
            entry.update(int8_unet(path, swin, unet, frames))
        elif half:
            entry.update(stored_half(model, path, inputs))
        report[role] = {"file": path.name, "sha256": sha256_file(path), "bytes": path.stat().st_size, **entry}
    training_path = Path(run_dir) / "training.json"
    training = json.loads(training_path.read_text()) if training_path.is_file() else {}
    card = {
        "name": f"gsa-isar-{cfg['name']}",
        "exported": datetime.now(UTC).isoformat(timespec="seconds"),
        "opset": OPSET,
        "input": "frame [batch, 1, H, W] float32: inference.frames.normalise_frame output",
        "outputs": {"unetpp": "enhanced frame [batch, 1, H, W]", "swin": f"Euler z, y, x / {ANGLE_SCALE_DEG} deg"},
        "angle_scale_deg": ANGLE_SCALE_DEG,
        "enhance": bool(enhance),
        "config": cfg,
        "files": {k: report[k] for k in ("unetpp", "swin")},
        "training": {
            k: training.get(k)
            for k in (
                "mode",
                "schedule",
                "silhouette_noise",
                "unet_epochs",
                "unet_from",
                "swin_from",
                "enhance",
                "seed",
                "complete",
                "data",
                "hardware",
                "train_seconds",
            )
        },
        **({"finetune": training["finetune"]} if "finetune" in training else {}),
        "final_epoch": (training.get("history") or [{}])[-1],
        # The radar and target the training frames were simulated with: what the fit renders.
        "radar": (training.get("data") or {}).get("radar"),
        "target": (training.get("data") or {}).get("target"),
        "target_model": (training.get("data") or {}).get("target_model"),
        "max_angle_deg": (training.get("data") or {}).get("max_angle_deg"),
        **(extra or {}),
    }
    if size % SELFCHECK_POOL == 0:
        card["selfcheck"] = selfcheck_reference(unet, size)
        check_computes_here(card["selfcheck"], _session(out / "unetpp.onnx"), out)
    write_json(out / "model_card.json", card)
    return card


SELFCHECK_TOL = 0.1  # a correct int8 UNet++ was 0.027 off the float one here, a saturated one 0.28


def selfcheck_reference(unet: torch.nn.Module, size: int) -> dict[str, Any]:
    """What the service checks a UNet++ file against when it loads it (``inference.runtime.check_computes_here``):
    the float network's output on the seeded check frame, pooled."""
    with torch.no_grad():
        ref = unet(torch.from_numpy(selfcheck_frames(size))).numpy()
    return {
        "inputs": "numpy.random.default_rng(0).random((1, 1, H, W), float32)",
        "img_size": size,
        "pool": SELFCHECK_POOL,
        "unetpp_pooled": pooled(ref).round(5).tolist(),
        "tolerance": SELFCHECK_TOL,
    }


def _session(path: Path) -> Any:
    import onnxruntime as ort

    return ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])


def int8_unet(path: Path, swin: torch.nn.Module, unet: torch.nn.Module, frames: np.ndarray) -> dict[str, Any]:
    """Quantise the exported float32 UNet++ at ``path`` in place and check it; return the card's entries.

    Calibrates on the first half of ``frames`` [N, H, W] and checks on the second: Swin's
    angles from the int8 UNet++'s output against those from the float UNet++ (torch).
    """
    entry, enh8, enh = quantised_unet(path, unet, frames)
    with torch.no_grad():
        ref = swin(torch.from_numpy(enh)).numpy() * ANGLE_SCALE_DEG
        got = swin(torch.from_numpy(enh8)).numpy() * ANGLE_SCALE_DEG
    change = np.abs(got - ref)
    mean = change.mean(axis=0)
    if mean.max() > INT8_ANGLE_TOL_DEG:
        raise InferenceError(
            f"{path.name}: int8 UNet++ moves the angles by {mean.max():.2f} deg on average (> {INT8_ANGLE_TOL_DEG}); "
            "export without --int8, or calibrate on more frames"
        )
    return {
        **entry,
        "int8_angle_change_deg": {
            "mean": mean.round(4).tolist(),
            "p95": np.percentile(change, 95, axis=0).round(4).tolist(),
            "max": change.max(axis=0).round(4).tolist(),
        },
    }


SEARCH_INT8_MIN_IOU = 0.97  # the int8 search UNet++'s silhouettes' mean IoU with the float one's that is accepted


def export_search_enhancer(
    run_dir: str | Path, model_dir: str | Path, frames: np.ndarray | None = None, int8: bool = False, half: bool = False
) -> dict[str, Any]:
    """Add a run's UNet++ to the model set in ``model_dir`` as its search UNet++ (``search_unetpp-<sha256 prefix>.onnx``); return
    its card entry. The set's networks are left as they are; the card (written last) names the new file.

    The library search fits this UNet++'s silhouette (``inference.trust.Checker.check``), so a UNet++ trained over
    every rotation serves the frames outside the networks' cube while Swin keeps reading the UNet++ it was tuned
    on. Float parity as ``export``; with ``int8`` the check is the silhouette the search fits, not Swin's angles:
    the int8 silhouettes (> 0.5) of the second half of ``frames`` must reach a mean IoU of ``SEARCH_INT8_MIN_IOU``
    with the float network's.
    """
    from inference.files import read_json
    from inference.runtime import SEARCH_ROLE, read_card

    if int8:
        check_int8_frames(frames)
    d = Path(model_dir)
    card = read_card(d)
    unet, _, cfg, _ = load_trained(run_dir)
    size = int(cfg["img_size"])
    if size != int(card["config"]["img_size"]):
        raise InferenceError(f"{run_dir} takes {size} px frames, the model set in {d} {card['config']['img_size']} px")
    stage = Path(tempfile.mkdtemp(prefix=f".{d.name}-search-", dir=d.parent))
    try:
        path = stage / f"{SEARCH_ROLE}.onnx"
        tests = parity_inputs(size, frames)
        entry = exported_float(unet, path, size, tests)
        if int8 and frames is not None:
            int8_entry, got, ref = quantised_unet(path, unet, frames)
            iou = silhouette_ious(got[:, 0], ref[:, 0])
            if float(iou.mean()) < SEARCH_INT8_MIN_IOU:
                raise InferenceError(
                    f"{path.name}: the int8 UNet++'s silhouettes overlap the float one's by IoU {iou.mean():.3f} on "
                    f"average (< {SEARCH_INT8_MIN_IOU}); export without --int8, or calibrate on more frames"
                )
            entry.update(
                int8_entry,
                int8_silhouette_iou={"mean": round(float(iou.mean()), 4), "min": round(float(iou.min()), 4)},
            )
        elif half:
            entry.update(stored_half(unet, path, tests))
        selfcheck = selfcheck_reference(unet, size) if size % SELFCHECK_POOL == 0 else None
        if selfcheck is not None:
            check_computes_here(selfcheck, _session(path), stage)
        training_path = Path(run_dir) / "training.json"
        training = read_json(training_path) if training_path.is_file() else {}
        data = training.get("data") or {}
        sha = sha256_file(path)
        # Under a name of its own content, so the card (written last) and the file it names always agree; the file
        # an earlier export added goes once the card no longer names it.
        name = f"{SEARCH_ROLE}-{sha[:12]}.onnx"
        entry = {
            "file": name,
            "sha256": sha,
            "bytes": path.stat().st_size,
            **entry,
            "exported": datetime.now(UTC).isoformat(timespec="seconds"),
            "training": {
                "data": {k: data.get(k) for k in ("content_sha256", "frames", "train", "target", "variety")},
                **{k: training.get(k) for k in ("mode", "unet_epochs", "train_seconds", "hardware", "complete")},
                "final_epoch": (training.get("history") or [{}])[-1],
            },
            **({"selfcheck": selfcheck} if selfcheck else {}),
        }
        os.replace(path, d / name)
        old = (card["files"].get(SEARCH_ROLE) or {}).get("file")
        card["files"][SEARCH_ROLE] = entry
        write_json(d / "model_card.json", card)
        if old and old != name and (d / old).is_file():
            (d / old).unlink()
    finally:
        shutil.rmtree(stage, ignore_errors=True)
    return entry


def calibration_frames(data_dir: str | Path, n: int) -> tuple[np.ndarray, str]:
    """Return the first ``n`` training frames of a data set [n, H, W] (its manifest's split, or the first 80 %).

    Also returns the data set's content sha256, for the model card.
    """
    from inference.simulation.dataset import load_manifest, load_range

    if n < INT8_MIN_FRAMES:
        raise InferenceError(f"--n-frames {n} is too few: give at least {INT8_MIN_FRAMES}")
    manifest = load_manifest(data_dir)
    from inference.simulation.dataset import split_ranges

    (_, train_end), _ = split_ranges(manifest)
    if train_end < INT8_MIN_FRAMES:
        raise InferenceError(f"{data_dir} has {train_end} training frames: too few to calibrate on")
    frames = load_range(data_dir, 0, min(n, train_end), ("image",), verify=False)["image"].astype(np.float32)
    return frames, str(manifest["content_sha256"])


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--run", required=True, help="training run directory (unetpp.pt, swin.pt)")
    p.add_argument("--out", help="output directory (default: the package's shipped models)")
    p.add_argument(
        "--half",
        action="store_true",
        help="store the large weights in float16, computed in float32 (half the file size)",
    )
    p.add_argument(
        "--int8",
        action="store_true",
        help="quantise UNet++ to int8, calibrated on --frames (about 2x faster on the CPU)",
    )
    p.add_argument(
        "--frames", metavar="DATA", help="data set whose first training frames check parity (and calibrate --int8)"
    )
    p.add_argument("--n-frames", type=int, default=256, help="how many of its frames (default 256)")
    p.add_argument(
        "--search-unet",
        action="store_true",
        help="add only the run's UNet++ to the model set in --out as the one the library search fits "
        "(search_unetpp.onnx; a UNet++ trained over every rotation), leaving the set's networks as they are",
    )


def run(args: argparse.Namespace) -> int:
    """Run the export command from parsed arguments; raises InferenceError on bad input."""
    from inference.runtime import DEFAULT_MODEL_DIR

    if args.int8 and not args.frames:
        raise InferenceError("--int8 needs --frames DATA: real frames to calibrate on (a data set from gsa simulate)")
    frames = None
    options: dict[str, Any] = {"half": args.half, "int8": args.int8, "frames": None}
    if args.frames:
        frames, sha = calibration_frames(args.frames, args.n_frames)
        options["frames"] = {"data": str(args.frames), "content_sha256": sha, "first_training_frames": len(frames)}
    if args.search_unet:
        entry = export_search_enhancer(args.run, args.out or DEFAULT_MODEL_DIR, frames, args.int8, args.half)
        shown = f", int8 silhouettes IoU {entry['int8_silhouette_iou']['mean']:.3f}" if args.int8 else ""
        print(
            f"search UNet++: {entry['file']} {entry['bytes'] / 1e6:.1f} MB sha256 {entry['sha256'][:16]} "
            f"parity {entry['parity_max_rel_diff']:.1e}{shown}"
        )
        return 0
    card = export(
        args.run,
        args.out or DEFAULT_MODEL_DIR,
        frames=frames,
        half=args.half,
        int8=args.int8,
        extra={"export_options": options},
    )
    for role, f in card["files"].items():
        extra = f" (float16 weights: {f['half_max_rel_diff']:.1e})" if "half_max_rel_diff" in f else ""
        if "int8_angle_change_deg" in f:
            extra = f" (int8: angles change by {'/'.join(f'{v:.2f}' for v in f['int8_angle_change_deg']['mean'])} deg)"
        print(
            f"{role}: {f['file']} {f['bytes'] / 1e6:.1f} MB sha256 {f['sha256'][:16]} "
            f"parity {f['parity_max_rel_diff']:.1e}{extra}"
        )
    return 0


def main(argv: list[str] | None = None) -> int:
    return module_main("export", "export", add_arguments, run, argv)


if __name__ == "__main__":
    sys.exit(main())
