"""End-to-end estimate latency of a real uvicorn server against the raw two-model time, and the batch gain."""

from __future__ import annotations

import io
import statistics
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def bench_service(model_dir: Path, clients: int = 8, per_client: int = 12) -> list[str]:
    import httpx

    from bench.common import median_time
    from inference.frames import normalise_frame
    from inference.runtime import Estimator
    from inference.simulation.radar import Imager, Radar
    from inference.simulation.scene import simulate
    from inference.simulation.targets import tiangong_like
    from tests.utils.server import Server

    est = Estimator.load(model_dir)
    size = est.img_size
    frame = simulate(tiangong_like(), Imager(Radar(n_range=size, n_azimuth=size)), (10.0, 5.0, -5.0), 10.0, 0).image
    buf = io.BytesIO()
    np.save(buf, np.abs(frame).astype(np.float32))
    npy = buf.getvalue()
    norm = normalise_frame(np.abs(frame))[None]
    raw_ms = median_time(lambda: est.estimate(norm), 20) * 1000
    # The models alone on a 32-frame stack, run in pieces of 1 ... 32 frames: the ceiling of any batch gain.
    stack32 = np.repeat(norm, 32, axis=0)
    per_frame_ms = {}
    default_run_batch = est.run_batch
    for run_batch in (1, 2, 4, 8, 32):
        est.run_batch = run_batch
        per_frame_ms[run_batch] = median_time(lambda: est.estimate(stack32), 3) * 1000 / 32
    est.run_batch = default_run_batch

    tmp = Path(tempfile.mkdtemp())
    env = {
        "GSA_DATA_DIR": str(tmp),
        "GSA_API_KEYS": "bench-service-key-0",
        "GSA_MODEL_DIR": str(model_dir),
        "GSA_MAX_UPLOAD_BYTES": str(32 * 1024 * 1024),
        "GSA_LOG_LEVEL": "warning",
    }  # a 32-frame float32 stack is 8.4 MB
    server = Server(env, workers=1).start()
    url = server.url
    try:
        headers = {"X-API-Key": "bench-service-key-0"}

        model_s: list[float] = []  # the model time each answer reports, for the overhead of that same request

        def one(_: int) -> list[float]:
            out = []
            with httpx.Client(timeout=60) as c:
                for _ in range(per_client):
                    t0 = time.perf_counter()
                    r = c.post(url + "/v1/estimates", files={"file": ("f.npy", npy)}, headers=headers)
                    out.append(time.perf_counter() - t0)
                    assert r.status_code == 201, r.text
                    t = r.json()["timings_s"]
                    model_s.append(t["unetpp"] + t["swin"])
            return out

        one(0)
        t0 = time.perf_counter()
        with ThreadPoolExecutor(clients) as pool:
            lat = sorted(x for xs in pool.map(one, range(clients)) for x in xs)
        wall = time.perf_counter() - t0
        single_fps = len(lat) / wall
        p50, p99 = np.percentile(lat, 50) * 1000, np.percentile(lat, 99) * 1000
        # One client, one request at a time: what a request costs beyond the models.
        model_s.clear()
        seq = one(0) + one(0)
        seq_ms = statistics.median(seq) * 1000
        # This VM's speed drifts by tens of percent from minute to minute, so the overhead is taken
        # request by request: its latency less the model time the server measured inside it.
        over_ms = statistics.median(x - m for x, m in zip(seq, model_s, strict=True)) * 1000
        in_ms = statistics.median(model_s) * 1000
        stack = io.BytesIO()
        np.savez(stack, frames=np.repeat(np.abs(frame)[None].astype(np.float32), 32, axis=0))
        with httpx.Client(timeout=120) as c:
            c.post(url + "/v1/estimates/batch", files=[("files", ("s.npz", stack.getvalue()))], headers=headers)
            t0 = time.perf_counter()
            for _ in range(3):
                r = c.post(url + "/v1/estimates/batch", files=[("files", ("s.npz", stack.getvalue()))], headers=headers)
                assert r.status_code == 201, r.text
            batch_fps = 96 / (time.perf_counter() - t0)
    finally:
        server.stop()
    return [
        "## Estimation service",
        "",
        f"A real `gsa serve` (1 worker) on SQLite with the models in `{model_dir.name}`, {size} x {size} .npy uploads.",
        "",
        "| what | figure |",
        "|---|---|",
        f"| raw two-model time (Estimator, batch 1, median of 20) | {raw_ms:.1f} ms |",
        f"| POST /v1/estimates, one client, median of {len(seq)} | {seq_ms:.1f} ms, of which the models {in_ms:.1f} ms |",
        f"| service overhead (each request's latency less its own model time), median | {over_ms:.1f} ms ({100 * over_ms / in_ms:.0f} % of model time) |",
        f"| POST /v1/estimates, {clients} concurrent clients x {per_client}: p50 / p99 | {p50:.0f} / {p99:.0f} ms ({single_fps:.1f} frames/s) |",
        f"| POST /v1/estimates/batch, 32 frames a request | {batch_fps:.1f} frames/s ({batch_fps / single_fps:.1f}x single) |",
        "",
        "The models alone (Estimator, no server) on a 32-frame stack run through them in pieces of",
        f"n frames (`GSA_ORT_RUN_BATCH`, default {est.run_batch}). The best of these over n = 1 is the most any",
        "batching can gain on this machine; the service's batch endpoint cannot beat it.",
        "",
        "| frames per run | ms per frame | frames/s | gain over 1 |",
        "|---|---|---|---|",
        *[f"| {n} | {ms:.1f} | {1000 / ms:.1f} | {per_frame_ms[1] / ms:.2f}x |" for n, ms in per_frame_ms.items()],
        "",
    ]


if __name__ == "__main__":
    from bench.sections import replace_section
    from inference.runtime import DEFAULT_MODEL_DIR

    section = bench_service(Path(sys.argv[1]) if len(sys.argv) > 1 else DEFAULT_MODEL_DIR)
    print("\n".join(section))
    replace_section("Estimation service", section)  # `make bench` rewrites the whole file
