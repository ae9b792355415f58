"""Hostile clients (issues 46 and 74): what a decompression bomb, a flood of bodies that never come, abandoned work,
a key that stores without end and a key that queues hundreds of jobs cost a real `gsa serve` (one worker, shipped
models, SQLite, default limits but a storage quota of QUOTA_MB).

Run with ``python -m bench.reliability`` (``make bench`` runs it); replaces the "Hostile clients" section of
BENCHMARKS.md. Memory is the worker's peak resident set (VmHWM), CPU its user + system time (/proc), both read
from the server process itself.
"""

from __future__ import annotations

import io
import json
import socket
import statistics
import sys
import tempfile
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import httpx
import numpy as np
from PIL import Image

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import machine  # noqa: E402
from bench.sections import replace_section  # noqa: E402
from inference.runtime import DEFAULT_MODEL_DIR  # noqa: E402
from tests.utils.server import Server, access_line, leave_after, multipart  # noqa: E402

TITLE = "Hostile clients"
KEY = "bench-reliability-key-0123"
AUTH = {"X-API-Key": KEY}
SIDE = 4096
FLOOD = 1000
OTHER = {"X-API-Key": "bench-reliability-key-4567"}
QUOTA_MB = 100  # small enough to reach in a minute
SMALL_RADAR = {"n_range": 64, "n_azimuth": 64, "bandwidth_hz": 0.4e9, "aperture_deg": 1.275}


def _log(msg: str) -> None:
    print(f"bench.reliability: {msg}", file=sys.stderr, flush=True)


def _status(pid: int) -> dict[str, int]:
    out = {}
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        k, _, v = line.partition(":")
        if k in ("VmHWM", "VmRSS"):
            out[k] = int(v.split()[0]) // 1024  # MB
    return out


def _cpu_s(pid: int) -> float:
    import os

    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _gradient_png(seed: int) -> bytes:
    """A 4096 x 4096 8-bit frame that PNG compresses to tens of kB: 16 MiB of pixels, 128 MiB as float64."""
    y, x = np.mgrid[0:SIDE, 0:SIDE]
    img = ((x // 64 + y // 64 + seed) % 200 + 20).astype(np.uint8)
    buf = io.BytesIO()
    Image.fromarray(img, mode="L").save(buf, format="PNG", optimize=True)
    return buf.getvalue()


def decoded(srv: Server, pid: int) -> list[str]:
    one = _gradient_png(0)
    base = _status(pid)
    body, ctype = multipart([("resample", "true")], [("files", f"bomb-{k}.png", one) for k in range(16)])
    t0 = time.monotonic()
    r = httpx.post(srv.url + "/v1/estimates/batch", content=body, headers={**AUTH, "Content-Type": ctype}, timeout=120)
    bomb_ms = (time.monotonic() - t0) * 1000.0
    after_bomb = _status(pid)
    _log(f"bomb: {r.status_code} in {bomb_ms:.0f} ms, peak {base['VmHWM']} -> {after_bomb['VmHWM']} MB")
    body2, ctype2 = multipart([("resample", "true")], [("files", f"big-{k}.png", _gradient_png(k)) for k in range(2)])
    t0 = time.monotonic()
    r2 = httpx.post(
        srv.url + "/v1/estimates/batch", content=body2, headers={**AUTH, "Content-Type": ctype2}, timeout=600
    )
    big_s = time.monotonic() - t0
    after_big = _status(pid)
    _log(f"largest allowed: {r2.status_code} in {big_s:.1f} s, peak {after_bomb['VmHWM']} -> {after_big['VmHWM']} MB")
    return [
        f"- **Decompression bomb**: 16 PNGs of 4096 x 4096 in one {len(body) / 1024:.0f}-kB request (2 GiB as the "
        f"float64 frames the service holds): answered {r.status_code} in {bomb_ms:.0f} ms from the files' headers; "
        f"the worker's peak resident memory went {base['VmHWM']} -> {after_bomb['VmHWM']} MB (it was +2.2 GB before "
        "the budget).",
        f"- **The largest request the budget allows** (GSA_MAX_DECODED_MB 256): 2 such frames ({len(body2) / 1024:.0f} "
        f"kB), resampled and estimated: {r2.status_code} in {big_s:.1f} s; peak resident memory "
        f"{after_bomb['VmHWM']} -> {after_big['VmHWM']} MB.",
    ]


def flood(srv: Server) -> list[str]:
    head = (
        b"POST /v1/estimates HTTP/1.1\r\nHost: x\r\nContent-Type: multipart/form-data; boundary=b\r\n"
        b"Content-Length: 100000\r\n\r\n"
    )
    held = []
    for _ in range(FLOOD):
        s = socket.create_connection(("127.0.0.1", srv.port))
        s.sendall(head)
        held.append(s)
    opened = time.monotonic()
    lat, codes = [], []
    with httpx.Client(timeout=30.0, headers=AUTH) as client:
        for _ in range(20):
            t0 = time.monotonic()
            codes.append(client.get(srv.url + "/v1/plans").status_code)
            lat.append((time.monotonic() - t0) * 1000.0)
            time.sleep(0.1)
    answered_408, closed_s = 0, []
    for s in held:
        s.settimeout(max(0.1, opened + 15.0 - time.monotonic()))
        try:
            got = s.recv(4096)
            if got.startswith(b"HTTP/1.1 408"):
                answered_408 += 1
            closed_s.append(time.monotonic() - opened)
        except OSError:
            pass
        finally:
            s.close()
    _log(f"flood: normal p50 {statistics.median(lat):.0f} ms max {max(lat):.0f} ms, {answered_408} answered 408")
    ok = sum(c == 200 for c in codes)
    return [
        f"- **Bodies that never come**: {FLOOD} connections sent complete headers of an upload and no body (no key "
        f"needed); meanwhile {ok} of {len(codes)} normal requests (`GET /v1/plans`) were answered 200, median "
        f"{statistics.median(lat):.0f} ms, slowest {max(lat):.0f} ms; {answered_408} of the {FLOOD} were answered 408 "
        f"and closed, the last {max(closed_s or [0.0]):.1f} s after they opened (GSA_HEADER_TIMEOUT_S, 10 s, without "
        "a byte of body; GSA_BODY_TIMEOUT_S, 120 s, for the whole body). Before, one such connection was still open "
        "at 90 s.",
    ]


def _frames_npz(n: int) -> bytes:
    from inference.simulation.catalogue import good_frames

    buf = io.BytesIO()
    np.savez(buf, frames=good_frames(n, 86_000)[0])
    return buf.getvalue()


def abandoned(srv: Server, pid: int, log: Path) -> list[str]:
    plan = httpx.post(srv.url + "/v1/plans", json=_plan_30_days(), headers=AUTH, timeout=300).json()
    w = plan["access_windows"][0]
    rise, end = datetime.fromisoformat(w["rise"]), datetime.fromisoformat(w["set"])
    n = 24  # 24 frames of 256 x 256 float32: 6 MB, under the 8-MiB upload limit
    npz = _frames_npz(n)
    times = [("observed_at", (rise + (end - rise) * (k + 1) / (n + 1)).isoformat()) for k in range(n)]
    cases = {
        "24-frame batch": (
            "POST",
            "/v1/estimates/batch",
            multipart([("normalised", "true")], [("files", "f.npz", npz)]),
        ),
        "24-frame pass": (
            "POST",
            "/v1/passes",
            multipart([("plan_id", plan["id"]), ("normalised", "true"), *times], [("files", "f.npz", npz)]),
        ),
        "30-day plan's pointing.csv": ("GET", f"/v1/plans/{plan['id']}/export/pointing.csv", (b"", "")),
    }
    lines = []
    for name, (method, path, (body, ctype)) in cases.items():
        extra = f"Content-Type: {ctype}\r\nContent-Length: {len(body)}\r\n" if body else ""
        head = f"{method} {path} HTTP/1.1\r\nHost: x\r\nX-API-Key: {KEY}\r\n{extra}\r\n".encode()
        lines_now = [json.loads(x) for x in log.read_text().splitlines() if x.startswith("{")]
        seen = sum(1 for x in lines_now if x.get("path") == path and "status" in x)
        cpu0 = _cpu_s(pid)
        leave_after(srv.port, head + body, 0.5)
        line = access_line(log, path, seen, timeout_s=300.0)
        time.sleep(0.3)
        left_cpu = _cpu_s(pid) - cpu0
        status = line["status"] if line else "never ended"
        cpu0 = _cpu_s(pid)
        r = httpx.request(
            method,
            srv.url + path,
            content=body or None,
            headers={**AUTH, **({"Content-Type": ctype} if ctype else {})},
            timeout=600,
        )
        whole_cpu = _cpu_s(pid) - cpu0
        _log(f"{name}: abandoned {left_cpu:.1f} CPU-s ({status}), whole {whole_cpu:.1f} CPU-s ({r.status_code})")
        lines.append(f"| {name} | {left_cpu:.1f} (ended {status}) | {whole_cpu:.1f} ({r.status_code}) |")
    return [
        "- **Abandoned work**: the client leaves 0.5 s after sending; the worker's CPU time until the request ended, "
        "against the same request waited for (nothing of the abandoned one is stored). A batch or pass stops between "
        "frames' fits; the networks' one run over the whole batch is not cut (most of what the abandoned ones "
        "still cost):",
        "",
        "| request | abandoned: CPU-s | waited for: CPU-s |",
        "|---|---|---|",
        *lines,
    ]


def _labelled_npz(n: int, seed: int) -> list[tuple[str, str, bytes]]:
    from inference.labelled import write_frame

    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        buf = io.BytesIO()
        write_frame(buf, rng.random((256, 256)).astype(np.float32) + 0.01, angles_deg=(k % 40, 0.0, 0.0), scene="s")
        out.append(("files", f"f{seed}-{k}.npz", buf.getvalue()))
    return out


def storage(srv: Server) -> list[str]:
    """One key uploads 64 labelled frames a request until the quota answers; the other key still stores."""
    t0, stored, last = time.monotonic(), 0, None
    with httpx.Client(timeout=120.0, headers=AUTH) as client:
        for k in range(1000):
            body, ctype = multipart([], _labelled_npz(64, k))
            last = client.post(
                srv.url + "/v1/targets/tiangong-like/labelled-frames", content=body, headers={"Content-Type": ctype}
            )
            if last.status_code != 201:
                break
            stored = last.json()["count"]
        seconds = time.monotonic() - t0
        body, ctype = multipart([], _labelled_npz(1, 99_999))
        other = httpx.post(
            srv.url + "/v1/targets/tiangong-like/labelled-frames",
            content=body,
            headers={**OTHER, "Content-Type": ctype},
            timeout=60,
        )
        gone = client.delete(srv.url + "/v1/targets/tiangong-like/labelled-frames", params={"all": "true"})
    assert last is not None
    detail = str(last.json().get("detail", ""))[:160]
    _log(f"storage: {stored} frames in {seconds:.1f} s, then {last.status_code}")
    return [
        "",
        f"- **A key that stores without end** (GSA_QUOTA_STORAGE_MB {QUOTA_MB}): 64 labelled 256 x 256 frames a "
        f"request, as fast as answered: {stored} frames stored in {seconds:.1f} s, then {last.status_code} "
        f'("{detail}..."). Another key\'s upload meanwhile: {other.status_code}. `DELETE '
        f"/v1/targets/tiangong-like/labelled-frames?all=true` removed {gone.json()['deleted']} frames and their "
        "images. Before: no quota (11,724 frames, 779 MB, in 120 s) and nothing could be deleted.",
    ]


def queue(srv: Server) -> list[str]:
    """One key asks for 300 one-frame data sets; then another key asks for one: how long until it is done."""
    with httpx.Client(timeout=60.0, headers=AUTH) as client:
        codes = [
            client.post(srv.url + "/v1/datasets", json={"n": 1, "radar": SMALL_RADAR}).status_code for _ in range(300)
        ]
        t0 = time.monotonic()
        mine = httpx.post(srv.url + "/v1/datasets", json={"n": 1, "radar": SMALL_RADAR}, headers=OTHER).json()
        while httpx.get(srv.url + f"/v1/jobs/{mine['id']}", headers=OTHER).json()["state"] in ("queued", "running"):
            time.sleep(0.2)
        waited = time.monotonic() - t0
        for job in client.get(srv.url + "/v1/jobs", params={"limit": 100}).json()["data"]:
            client.delete(srv.url + f"/v1/jobs/{job['id']}")
    accepted, refused = codes.count(202), codes.count(429)
    _log(f"queue: {accepted} accepted, {refused} refused; the other key's job done in {waited:.1f} s")
    return [
        f"- **A key that queues 300 jobs** (one-frame data sets; GSA_QUOTA_QUEUED_JOBS 16, GSA_JOB_WORKERS 1): "
        f"{accepted} accepted, {refused} answered 429. Another key's one-frame data set asked for next was done "
        f"{waited:.1f} s later: jobs start in turn between keys. Before: all 300 queued, first come first served, and "
        "another key's job waited about 20 minutes.",
    ]


def _plan_30_days() -> dict[str, Any]:
    from app.schemas import PAPER_EXAMPLE

    return {**PAPER_EXAMPLE, "search": {"duration_days": 30}}


def main() -> None:
    today = datetime.now(UTC).strftime("%Y-%m-%d")
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        log = root / "server.log"
        env = {
            "GSA_DATA_DIR": str(root / "data"),
            "GSA_MODEL_DIR": str(DEFAULT_MODEL_DIR),
            "GSA_API_KEYS": f"{KEY},{OTHER['X-API-Key']}",
            "GSA_QUOTA_STORAGE_MB": str(QUOTA_MB),
            "GSA_LOG_LEVEL": "info",
            "GSA_LOG_JSON": "true",
        }
        srv = Server(env, workers=1, log_path=log).start()
        try:
            assert srv.proc is not None
            pid = srv.proc.pid
            _log("decoded sizes")
            lines = decoded(srv, pid)
            _log("slow-body flood")
            lines += flood(srv)
            _log("abandoned work")
            lines += abandoned(srv, pid, log)
            _log("storage quota")
            lines += storage(srv)
            _log("queued jobs")
            lines += queue(srv)
        finally:
            srv.stop()
    section = [
        f"## {TITLE}",
        "",
        f"Machine: {machine()}. Date: {today}. Command: `python -m bench.reliability` (bench/reliability.py). "
        f"One `gsa serve` worker, shipped models, SQLite, default limits but GSA_QUOTA_STORAGE_MB {QUOTA_MB}.",
        "",
        *lines,
        "",
    ]
    replace_section(TITLE, section)
    print("\n".join(section))


if __name__ == "__main__":
    main()
