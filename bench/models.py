"""Network latency on this CPU: ONNX Runtime (tuned) against torch eager, batch 1 and batch 32."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np
import torch

from bench.common import median_time
from inference.export import export_onnx
from inference.models.build import build_models, get_config
from inference.runtime import session_options


def bench_models(configs: tuple[str, ...] = ("paper", "compact", "cpu")) -> list[str]:
    import onnxruntime as ort

    torch.set_num_threads(os.cpu_count() or 1)
    lines = [
        "## Networks on the CPU",
        "",
        f"One 256 x 256 frame (batch 1) and batch 32, {os.cpu_count()} threads. ONNX Runtime with graph",
        "optimisation ALL, sequential execution and no spin-waiting (the service's options) against torch eager under",
        "no_grad. Random weights: latency does not depend on them. Median of 5 runs (batch 32: of 2).",
        "",
        "| config | network | params | torch eager, batch 1 | ORT, batch 1 | speed-up | ORT batch 32, frames/s | ONNX size |",
        "|---|---|---|---|---|---|---|---|",
    ]
    opts = session_options()
    tmp = Path(tempfile.mkdtemp())
    for name in configs:
        cfg = get_config(name)
        unet, swin = build_models(cfg)
        for role, model in (("UNet++", unet), ("Swin", swin)):
            model.eval()
            path = tmp / f"{name}-{role}.onnx"
            export_onnx(model, path, cfg.img_size)
            sess = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
            x1 = np.random.default_rng(0).random((1, 1, cfg.img_size, cfg.img_size), dtype=np.float32)
            x32 = np.repeat(x1, 32, axis=0)
            t1 = torch.from_numpy(x1)
            with torch.no_grad():
                eager = median_time(lambda m=model, t=t1: m(t), 5)
            onnx1 = median_time(lambda s=sess, x=x1: s.run(None, {"frame": x}), 5)
            onnx32 = median_time(lambda s=sess, x=x32: s.run(None, {"frame": x}), 2)
            params = sum(p.numel() for p in model.parameters()) / 1e6
            lines.append(
                f"| {name} | {role} | {params:.2f} M | {eager * 1000:.0f} ms | {onnx1 * 1000:.0f} ms | "
                f"{eager / onnx1:.1f}x | {32 / onnx32:.1f} | {path.stat().st_size / 1e6:.1f} MB |"
            )
    lines.append("")
    return lines


if __name__ == "__main__":
    print("\n".join(bench_models()))
