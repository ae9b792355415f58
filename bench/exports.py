"""Plan exports (issue 44): what an export costs once it is stored with its plan, against recomputing the plan, on
a real `gsa serve` (one worker, shipped models, SQLite).

Run with ``python -m bench.exports`` (``make bench`` runs it); replaces the "Plan exports" section of
BENCHMARKS.md. For each example plan (the paper's 10-day search, 72 passes; the ISS over a masked station, 5 days):
the POST's time (planning and writing every export), each export's GET as stored (median of 7), the same export's
first GET for a plan made before exports were stored (its rows removed: the plan recomputed, as every export was
before), and the stored bytes.
"""

from __future__ import annotations

import json
import sqlite3
import statistics
import sys
import tempfile
import time
from datetime import UTC, datetime
from pathlib import Path

import httpx

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import machine  # noqa: E402
from bench.sections import replace_section  # noqa: E402
from inference.runtime import DEFAULT_MODEL_DIR  # noqa: E402
from tests.utils.server import Server  # noqa: E402

TITLE = "Plan exports"
KEY = "bench-exports-key-0123456"
AUTH = {"X-API-Key": KEY}
EXPORTS = ("opm", "opm?format=xml", "oem", "oem?format=xml", "czml", "geojson", "pointing.csv")
ROOT = Path(__file__).resolve().parents[1]
PLANS = {"paper": ROOT / "examples" / "paper-plan.json", "iss": ROOT / "examples" / "iss-plan.json"}
REPEATS = 7


def _log(msg: str) -> None:
    print(f"bench.exports: {msg}", file=sys.stderr, flush=True)


def _ms(f) -> float:  # type: ignore[no-untyped-def]
    t0 = time.perf_counter()
    f()
    return (time.perf_counter() - t0) * 1000.0


def _get(client: httpx.Client, url: str) -> None:
    r = client.get(url, headers=AUTH, timeout=300.0)
    assert r.status_code == 200, r.text[:300]


def main() -> None:
    today = datetime.now(UTC).strftime("%Y-%m-%d")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp) / "data"
        env = {"GSA_DATA_DIR": str(data), "GSA_MODEL_DIR": str(DEFAULT_MODEL_DIR), "GSA_API_KEYS": KEY}
        srv = Server(env, workers=1, log_path=Path(tmp) / "server.log").start()
        try:
            with httpx.Client(base_url=srv.url) as client:
                for name, path in PLANS.items():
                    body = json.loads(path.read_text())
                    posts = []
                    for _ in range(3):
                        t0 = time.perf_counter()
                        r = client.post("/v1/plans", json=body, headers=AUTH, timeout=300.0)
                        posts.append((time.perf_counter() - t0) * 1000.0)
                        assert r.status_code == 201, r.text[:300]
                    plan = r.json()
                    with sqlite3.connect(data / "gsa.db") as db:
                        stored = db.execute(
                            "SELECT name, length(body) FROM plan_exports WHERE plan_id = ?", (plan["id"],)
                        ).fetchall()
                    for kind in EXPORTS:
                        url = f"/v1/plans/{plan['id']}/export/{kind}"
                        served = statistics.median(_ms(lambda u=url: _get(client, u)) for _ in range(REPEATS))
                        size = len(client.get(url, headers=AUTH).content)
                        with sqlite3.connect(data / "gsa.db") as db:  # as a plan made before exports were stored
                            db.execute("DELETE FROM plan_exports WHERE plan_id = ?", (plan["id"],))
                        again = _ms(lambda u=url: _get(client, u))
                        rows.append((name, kind, served, again, size))
                        _log(f"{name} {kind}: {served:.1f} ms stored, {again:.0f} ms recomputed, {size} bytes")
                    rows.append((name, "POST", statistics.median(posts), sum(n for _, n in stored), len(stored)))
        finally:
            srv.stop()
    section = [
        f"## {TITLE}",
        "",
        f"`python -m bench.exports`, {today}, {machine()}: a real `gsa serve` (one worker, SQLite), the example plans",
        "(`examples/paper-plan.json`: 10 days, 72 passes; `examples/iss-plan.json`: 5 days over a masked station).",
        f"Each export's GET as stored (median of {REPEATS}), and its first GET for a plan made before exports were",
        "stored (the plan recomputed: what every export cost before). Sizes are the response's bytes.",
        "",
        "| plan | export | served as stored (ms) | plan recomputed (ms) | bytes |",
        "|---|---|---:|---:|---:|",
    ]
    for name, kind, served, again, size in rows:
        if kind != "POST":
            section.append(f"| {name} | {kind} | {served:.1f} | {again:.0f} | {size:,} |")
    section += [
        "",
        "| plan | POST /v1/plans, median of 3 (ms) | exports stored | stored bytes (zlib) |",
        "|---|---:|---:|---:|",
    ]
    for name, kind, post, stored_bytes, count in rows:
        if kind == "POST":
            section.append(f"| {name} | {post:.0f} | {count} | {stored_bytes:,} |")
    replace_section(TITLE, section)
    print("\n".join(section))


if __name__ == "__main__":
    main()
