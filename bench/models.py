"""Network latency on this CPU: ONNX Runtime (tuned; float32, and int8 for UNet++) against torch eager."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np
import torch

from bench.common import interleaved_medians
from inference.export import export_onnx, quantize_int8
from inference.networks.build import build_models, get_config
from inference.runtime import session_options


def bench_models(configs: tuple[str, ...] = ("paper", "compact", "cpu")) -> list[str]:
    import onnxruntime as ort

    torch.set_num_threads(os.cpu_count() or 1)
    lines = [
        "## Networks on the CPU",
        "",
        f"One 256 x 256 frame (batch 1) and batch 32, {os.cpu_count()} threads. ONNX Runtime with graph",
        "optimisation ALL, sequential execution and no spin-waiting (the service's options) against torch eager under",
        "no_grad. int8: UNet++ quantised as `gsa export --int8` does (static, per-channel, QDQ; here calibrated on",
        "16 random frames, as latency does not depend on the values); Swin is not quantised (see inference/export.py).",
        "Random weights. Batch 1: median of 9 rounds in which eager, float32 and int8 run in turn, so the machine's",
        "drift falls on all alike; batch 32: median of 3. `both` is UNet++ then Swin, as the service runs them.",
        "",
        "| config | network | params | torch eager, batch 1 | ORT float32, batch 1 | ORT int8, batch 1 | "
        "speed-up over eager (int8 where there is one) | ORT batch 32, frames/s | ONNX size (float32) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    opts = session_options()
    tmp = Path(tempfile.mkdtemp())
    rng = np.random.default_rng(0)
    for name in configs:
        cfg = get_config(name)
        unet, swin = build_models(cfg)
        x1 = rng.random((1, 1, cfg.img_size, cfg.img_size), dtype=np.float32)
        x32 = np.repeat(x1, 32, axis=0)
        best: dict[str, tuple[float, float]] = {}
        for role, model in (("UNet++", unet), ("Swin", swin)):
            model.eval()
            path = tmp / f"{name}-{role}.onnx"
            export_onnx(model, path, cfg.img_size)
            contenders = {"fp32": ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])}
            if role == "UNet++":
                q = tmp / f"{name}-{role}-int8.onnx"
                quantize_int8(path, q, rng.random((16, 1, cfg.img_size, cfg.img_size), dtype=np.float32))
                contenders["int8"] = ort.InferenceSession(str(q), opts, providers=["CPUExecutionProvider"])
            t1 = torch.from_numpy(x1)
            fns = {k: (lambda s=s, x=x1: s.run(None, {"frame": x})) for k, s in contenders.items()}
            with torch.no_grad():
                t = interleaved_medians({"eager": lambda m=model, t=t1: m(t), **fns}, 9)
                shipped = "int8" if "int8" in t else "fp32"  # what `gsa export --int8` gives the service
                t32 = interleaved_medians({"b32": lambda s=contenders[shipped], x=x32: s.run(None, {"frame": x})}, 3)
            best[role] = (t["eager"], t[shipped])
            params = sum(p.numel() for p in model.parameters()) / 1e6
            int8 = f"{t['int8'] * 1000:.0f} ms" if "int8" in t else "-"
            lines.append(
                f"| {name} | {role} | {params:.2f} M | {t['eager'] * 1000:.0f} ms | {t['fp32'] * 1000:.0f} ms | {int8} | "
                f"{t['eager'] / t[shipped]:.1f}x | {32 / t32['b32']:.1f} | {path.stat().st_size / 1e6:.1f} MB |"
            )
        eager, ort_best = (sum(v[k] for v in best.values()) for k in (0, 1))
        lines.append(
            f"| {name} | both | | {eager * 1000:.0f} ms | | {ort_best * 1000:.0f} ms (int8 UNet++, float Swin) | "
            f"{eager / ort_best:.1f}x | | |"
        )
    lines.append("")
    return lines


if __name__ == "__main__":
    print("\n".join(bench_models()))
