"""Export trained UNet++ and Swin to ONNX, prove parity with torch, and write the model card."""

from __future__ import annotations

import argparse
import json
import sys
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import torch

from inference.errors import InferenceError, ModelFileError
from inference.models.build import build_models, get_config
from inference.runtime import sha256_file
from inference.train import ANGLE_SCALE_DEG

OPSET = 17
PARITY_RTOL = 1e-4  # relative difference, float32, ORT against torch
HALF_RTOL = 1e-2  # relative difference once the weights are stored in float16 (bf16/fp16 rounding is ~1e-3)
HALF_MIN_ELEMENTS = 1024  # smaller tensors (biases, norms) stay float32: they cost nothing


def load_trained(run_dir: str | Path) -> tuple[torch.nn.Module, torch.nn.Module, dict[str, Any]]:
    """Load ``unetpp.pt`` and ``swin.pt`` from a training run; raise ModelFileError naming a bad file."""
    d = Path(run_dir)
    models = []
    cfg_dict: dict[str, Any] = {}
    for name in ("unetpp.pt", "swin.pt"):
        path = d / name
        if not path.is_file():
            raise ModelFileError(f"checkpoint {path} is missing", field="model")
        try:
            ck = torch.load(path, map_location="cpu", weights_only=False)
        except Exception as exc:
            raise ModelFileError(f"checkpoint {path} cannot be read: {exc}", field="model") from None
        cfg_dict = ck["config"]
        models.append(ck["state_dict"])
    cfg = get_config(cfg_dict["name"], **{k: v for k, v in cfg_dict.items() if k != "name"})
    unet, swin = build_models(cfg)
    unet.load_state_dict(models[0])
    swin.load_state_dict(models[1])
    unet.eval()
    swin.eval()
    return unet, swin, cfg.as_dict()


def export_onnx(model: torch.nn.Module, path: Path, img_size: int) -> None:
    """Export with a dynamic batch axis and check the graph."""
    import onnx

    dummy = torch.zeros(2, 1, img_size, img_size)
    torch.onnx.export(
        model, (dummy,), str(path), input_names=["frame"], output_names=["out"], opset_version=OPSET,
        dynamic_axes={"frame": {0: "batch"}, "out": {0: "batch"}}, dynamo=False,
    )  # fmt: skip
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


def parity(model: torch.nn.Module, path: Path, frames: np.ndarray) -> float:
    """Return the largest relative difference between ONNX Runtime and torch on ``frames`` [N, 1, H, W]."""
    import onnxruntime as ort

    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    with torch.no_grad():
        ref = model(torch.from_numpy(frames)).numpy()
    got = sess.run(None, {"frame": frames})[0]
    return float(np.abs(got - ref).max() / max(np.abs(ref).max(), 1e-12))


def export(
    run_dir: str | Path, out_dir: str | Path, frames: np.ndarray | None = None, extra: dict[str, Any] | None = None,
    half: bool = False,
) -> dict[str, Any]:  # fmt: skip
    """Export a training run's networks to ``out_dir`` with a model card; return the card.

    Parity is checked on random frames and on ``frames`` (real ones, [N, H, W], if given):
    ORT must match torch within PARITY_RTOL. With ``half`` the large weights are then stored
    in float16 (``store_half``), which halves the files; ORT must still match torch within
    HALF_RTOL, and the card records both differences.
    """
    unet, swin, cfg = load_trained(run_dir)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    size = cfg["img_size"]
    rng = np.random.default_rng(0)
    tests = [rng.random((2, 1, size, size), dtype=np.float32)]
    if frames is not None:
        tests.append(frames[:, None].astype(np.float32))
    with torch.no_grad():
        enhanced = [unet(torch.from_numpy(t)).numpy() for t in tests]
    report: dict[str, Any] = {}
    for role, model, inputs in (("unetpp", unet, tests), ("swin", swin, tests + enhanced)):
        path = out / f"{role}.onnx"
        export_onnx(model, path, size)
        worst = max(parity(model, path, t) for t in inputs)
        if worst > PARITY_RTOL:
            raise InferenceError(f"{path}: ONNX Runtime differs from torch by {worst:.2e} (> {PARITY_RTOL})")
        entry: dict[str, Any] = {"weights": "float32", "parity_max_rel_diff": worst}
        if half:
            entry["float16_tensors"] = store_half(path)
            entry["half_max_rel_diff"] = max(parity(model, path, t) for t in inputs)
            entry["weights"] = "float16 (computed in float32)"
            if entry["half_max_rel_diff"] > HALF_RTOL:
                raise InferenceError(f"{path}: float16 weights change the output by {entry['half_max_rel_diff']:.2e} "
                                     f"(> {HALF_RTOL}); export without --half")  # fmt: skip
        report[role] = {"file": path.name, "sha256": sha256_file(path), "bytes": path.stat().st_size, **entry}
    training_path = Path(run_dir) / "training.json"
    training = json.loads(training_path.read_text()) if training_path.is_file() else {}
    card = {
        "name": f"gsa-isar-{cfg['name']}",
        "exported": datetime.now(UTC).isoformat(timespec="seconds"),
        "opset": OPSET,
        "input": "frame [batch, 1, H, W] float32: inference.isar.normalise_frame output",
        "outputs": {"unetpp": "enhanced frame [batch, 1, H, W]", "swin": f"Euler z, y, x / {ANGLE_SCALE_DEG} deg"},
        "angle_scale_deg": ANGLE_SCALE_DEG,
        "config": cfg,
        "files": {k: report[k] for k in ("unetpp", "swin")},
        "training": {k: training.get(k) for k in ("mode", "unet_epochs", "unet_from", "swin_from", "enhance", "seed", "complete", "data",
                                                  "hardware", "train_seconds")},
        "final_epoch": (training.get("history") or [{}])[-1],
        **(extra or {}),
    }  # fmt: skip
    (out / "model_card.json").write_text(json.dumps(card, indent=2))
    return card


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m inference.export")
    p.add_argument("--run", required=True, help="training run directory (unetpp.pt, swin.pt)")
    p.add_argument("--out", required=True)
    p.add_argument("--half", action="store_true", help="store the large weights in float16 (half the size)")
    args = p.parse_args(argv)
    try:
        card = export(args.run, args.out, half=args.half)
    except InferenceError as exc:
        print(f"export: error: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(card["files"], indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
