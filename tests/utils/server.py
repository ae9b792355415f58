"""A real ``gsa serve`` (uvicorn, N workers) in a subprocess, and a mixed-request load generator.

Used by the load and crash tests and by ``bench/load.py``; needs httpx only.
"""

from __future__ import annotations

import io
import os
import random
import signal
import socket
import subprocess
import sys
import threading
import time
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
import numpy as np


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass
class Server:
    """``gsa serve`` in its own process group (so kill -9 reaches the workers too)."""

    env: dict[str, str]
    workers: int = 2
    port: int = field(default_factory=free_port)
    proc: subprocess.Popen[bytes] | None = None
    log_path: Path | None = None

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def start(self, timeout_s: float = 90.0) -> Server:
        env = {**os.environ, **self.env}
        log = open(self.log_path, "ab") if self.log_path else subprocess.DEVNULL  # noqa: SIM115
        gsa = Path(sys.executable).with_name("gsa")
        cmd = [str(gsa)] if gsa.exists() else [sys.executable, "-m", "app.cli"]
        self.proc = subprocess.Popen(
            [*cmd, "serve", "--port", str(self.port), "--workers", str(self.workers)],
            env=env,
            stdout=log,
            stderr=log,
            start_new_session=True,
        )
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"gsa serve exited with {self.proc.returncode}; see {self.log_path}")
            try:
                if httpx.get(self.url + "/readyz", timeout=2.0).status_code == 200:
                    # One worker answered; which one is not visible, so give the others a moment for their models.
                    time.sleep(0.5 * (self.workers - 1))
                    return self
            except httpx.HTTPError:
                pass
            time.sleep(0.2)
        self.kill()
        raise RuntimeError(f"gsa serve did not answer /readyz within {timeout_s} s; see {self.log_path}")

    def kill(self, sig: int = signal.SIGKILL) -> None:
        if self.proc is not None and self.proc.poll() is None:
            os.killpg(self.proc.pid, sig)
            self.proc.wait(timeout=30)

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGTERM)
            try:
                self.proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                self.kill()


def npy_bytes(arr: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, arr)
    return buf.getvalue()


def multipart(fields: list[tuple[str, str]], files: list[tuple[str, str, bytes]]) -> tuple[bytes, str]:
    """A multipart/form-data body written out by hand (for raw sockets): the body and its Content-Type."""
    import uuid

    boundary = uuid.uuid4().hex
    parts = [f'--{boundary}\r\nContent-Disposition: form-data; name="{k}"\r\n\r\n{v}\r\n'.encode() for k, v in fields]
    for name, filename, data in files:
        parts.append(
            f'--{boundary}\r\nContent-Disposition: form-data; name="{name}"; filename="{filename}"\r\n'
            "Content-Type: application/octet-stream\r\n\r\n".encode()
            + data
            + b"\r\n"
        )
    return b"".join(parts) + f"--{boundary}--\r\n".encode(), f"multipart/form-data; boundary={boundary}"


def leave_after(port: int, request: bytes, after_s: float) -> None:
    """Send a whole request on a raw socket and close it ``after_s`` later, without reading the answer."""
    sock = socket.create_connection(("127.0.0.1", port))
    sock.sendall(request)
    time.sleep(after_s)
    sock.close()


def access_line(log: Path, path: str, seen: int = 0, timeout_s: float = 60.0) -> dict[str, Any] | None:
    """The server's JSON access line of request number ``seen`` + 1 to ``path`` once it is written, or None."""
    import json

    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        lines = [json.loads(x) for x in log.read_text().splitlines() if x.startswith("{")]
        mine = [x for x in lines if x.get("path") == path and "status" in x]
        if len(mine) > seen:
            return mine[seen]
        time.sleep(0.2)
    return None


def plan_body(k: int) -> dict[str, Any]:
    """A one-day plan of the paper's scene (about 0.1 s of planner time), varied by ``k``."""
    from app.schemas import PAPER_EXAMPLE

    body: dict[str, Any] = {key: dict(value) for key, value in PAPER_EXAMPLE.items()}
    body["target"] = {**PAPER_EXAMPLE["target"], "name": f"load-target-{k}"}
    body["search"] = {"duration_days": 1}
    return body


@dataclass
class LoadResult:
    latencies: dict[str, list[float]]
    statuses: dict[str, dict[int, int]]
    acked: dict[str, dict[str, list[str]]]  # key -> kind -> ids acknowledged with 2xx
    errors: list[str]
    wall_s: float

    def percentiles(self) -> dict[str, dict[str, float]]:
        out = {}
        for op, lat in sorted(self.latencies.items()):
            a = np.array(lat) * 1000.0
            out[op] = {
                "n": len(a),
                "p50_ms": float(np.percentile(a, 50)),
                "p95_ms": float(np.percentile(a, 95)),
                "p99_ms": float(np.percentile(a, 99)),
                "max_ms": float(a.max()),
            }
        return out


# The mix of one client's requests: writes (plans, estimates, a batch) and reads (listings, own records).
MIX = [
    ("post_plan", 0.15),
    ("post_estimate", 0.30),
    ("post_batch", 0.05),
    ("list_plans", 0.15),
    ("list_estimates", 0.15),
    ("get_own", 0.15),
    ("scenes", 0.05),
]


def run_load(
    url: str,
    keys: list[str],
    clients: int = 16,
    requests_each: int = 50,
    frame_size: int = 64,
    seed: int = 0,
    stop: threading.Event | None = None,
    frames: np.ndarray | None = None,
) -> LoadResult:
    """Send ``clients`` x ``requests_each`` mixed requests concurrently; record latencies and acknowledged ids.

    The estimates upload noise frames of ``frame_size`` (the models' worst case: nothing fits, so every
    frame is searched), or, with ``frames`` ([N, H, W], normalised), those frames in turn, as normalised.
    """
    lat: dict[str, list[float]] = defaultdict(list)
    statuses: dict[str, dict[int, int]] = defaultdict(lambda: defaultdict(int))
    acked: dict[str, dict[str, list[str]]] = {k: {"plan": [], "estimate": []} for k in keys}
    errors: list[str] = []
    lock = threading.Lock()
    ops, weights = zip(*MIX, strict=True)

    def client(c: int) -> None:
        rng = random.Random(seed * 1000 + c)
        key = keys[c % len(keys)]
        mine: list[tuple[str, str]] = []
        with httpx.Client(base_url=url, headers={"X-API-Key": key}, timeout=120.0) as http:
            for k in range(requests_each):
                if stop is not None and stop.is_set():
                    return
                op = rng.choices(ops, weights)[0]
                if frames is None:
                    frame = np.random.default_rng(seed * 100_000 + c * 1000 + k).random((frame_size, frame_size)) + 0.05
                    batch = [frame * (j + 1) for j in range(4)]
                    form = {}
                else:
                    pick = (c * 1000 + k) % len(frames)
                    frame = frames[pick]
                    batch = [frames[(pick + j) % len(frames)] for j in range(4)]
                    form = {"normalised": "true"}
                t0 = time.perf_counter()
                try:
                    if op == "post_plan":
                        r = http.post("/v1/plans", json=plan_body(c * 1000 + k))
                    elif op == "post_estimate":
                        r = http.post("/v1/estimates", files={"file": (f"c{c}-{k}.npy", npy_bytes(frame))}, data=form)
                    elif op == "post_batch":
                        r = http.post(
                            "/v1/estimates/batch",
                            files=[("files", (f"c{c}-{k}-{j}.npy", npy_bytes(b))) for j, b in enumerate(batch)],
                            data=form,
                        )
                    elif op == "list_plans":
                        r = http.get("/v1/plans", params={"limit": 20})
                    elif op == "list_estimates":
                        r = http.get("/v1/estimates", params={"limit": 20})
                    elif op == "scenes":
                        r = http.get("/v1/scenes", params={"limit": 5})
                    else:
                        kind, rid = rng.choice(mine) if mine else ("plan", "none")
                        r = http.get(f"/v1/{kind}s/{rid}")
                        if not mine:
                            op = "get_missing"
                except httpx.HTTPError as exc:
                    with lock:
                        errors.append(f"{op}: {type(exc).__name__}: {exc}")
                    continue
                dt = time.perf_counter() - t0
                new: list[tuple[str, str]] = []
                if r.status_code == 201:
                    body = r.json()
                    if op == "post_plan":
                        new = [("plan", body["id"])]
                    elif op == "post_estimate":
                        new = [("estimate", body["id"])]
                    else:
                        new = [("estimate", e["id"]) for e in body["data"]]
                mine += new
                with lock:
                    lat[op].append(dt)
                    statuses[op][r.status_code] += 1
                    for kind, rid in new:
                        acked[key][kind].append(rid)
                    if r.status_code >= 500 or "locked" in r.text:
                        errors.append(f"{op}: {r.status_code} {r.text[:200]}")

    t0 = time.perf_counter()
    threads = [threading.Thread(target=client, args=(c,)) for c in range(clients)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return LoadResult(dict(lat), {k: dict(v) for k, v in statuses.items()}, acked, errors, time.perf_counter() - t0)


def stored_ids(url: str, key: str, kind: str) -> list[str]:
    """Every id of ``kind`` the operator of ``key`` has, read back page by page."""
    out: list[str] = []
    with httpx.Client(base_url=url, headers={"X-API-Key": key}, timeout=60.0) as http:
        while True:
            r = http.get(f"/v1/{kind}s", params={"limit": 100, "offset": len(out)})
            r.raise_for_status()
            page = [row["id"] for row in r.json()["data"]]
            if not page:
                return out
            out += page
