"""A real server under load and under kill -9: nothing lost, nothing duplicated, no 5xx, a clean restart.

``gsa serve`` runs uvicorn with 2 workers on the default SQLite database (WAL, busy
timeout) and on PostgreSQL; 16 clients send mixed requests at once. The crash test
kills the whole server (master and workers) with SIGKILL in the middle of a stream
of writes and starts it again.
"""

from __future__ import annotations

import sqlite3
import threading
import time
from datetime import datetime
from pathlib import Path

import httpx
import numpy as np
import pytest
from sqlalchemy import create_engine, select

from app.db.models import Estimate
from tests.conftest import KEY_A, KEY_B
from tests.utils.databases import database_url
from tests.utils.server import Server, access_line, leave_after, multipart, run_load, stored_ids

# 224 requests: about 34 plans and 70 estimates, over the floors below (make load's bench.load goes further)
CLIENTS, REQUESTS_EACH = 16, 10


@pytest.fixture
def server_env(backend, tmp_path, pg_root, smoke_models):
    data = tmp_path / "data"
    data.mkdir()
    return {
        "GSA_DATA_DIR": str(data),
        "GSA_DATABASE_URL": database_url(backend, data, pg_root),
        "GSA_MODEL_DIR": str(smoke_models),
        "GSA_API_KEYS": f"{KEY_A},{KEY_B}",
        "GSA_ORT_THREADS": "1",
        "GSA_LOG_LEVEL": "warning",
    }


def _check_store(env: dict[str, str]) -> None:
    """Every estimate row has both its image files, and every image file belongs to a row."""
    engine = create_engine(env["GSA_DATABASE_URL"])
    with engine.connect() as conn:
        used = {d for row in conn.execute(select(Estimate.original_sha256, Estimate.enhanced_sha256)) for d in row}
    engine.dispose()
    files = {p.stem for p in (Path(env["GSA_DATA_DIR"]) / "images").glob("*/*")}
    assert used <= files, f"rows pointing at missing files: {sorted(used - files)[:5]}"
    assert files <= used, f"orphan files: {sorted(files - used)[:5]}"


def test_two_workers_under_16_clients_lose_and_duplicate_nothing(server_env, tmp_path):
    srv = Server(server_env, workers=2, log_path=tmp_path / "server.log").start()
    try:
        res = run_load(srv.url, [KEY_A, KEY_B], clients=CLIENTS, requests_each=REQUESTS_EACH)
        assert not res.errors, res.errors[:5]
        assert sum(sum(s.values()) for s in res.statuses.values()) == CLIENTS * REQUESTS_EACH
        assert all(code < 500 for s in res.statuses.values() for code in s), res.statuses
        for key in (KEY_A, KEY_B):
            for kind in ("plan", "estimate"):
                acked, stored = res.acked[key][kind], stored_ids(srv.url, key, kind)
                assert len(set(acked)) == len(acked), "an id was acknowledged twice"
                assert sorted(stored) == sorted(acked), f"{kind}s: {len(acked)} acknowledged, {len(stored)} stored"
        assert sum(len(v["estimate"]) for v in res.acked.values()) > 32
        assert sum(len(v["plan"]) for v in res.acked.values()) > 10
    finally:
        srv.stop()
    _check_store(server_env)
    assert "database is locked" not in (tmp_path / "server.log").read_text()


def test_kill_9_mid_writes_loses_no_acknowledged_write_and_restarts_clean(server_env, backend, tmp_path):
    srv = Server(server_env, workers=2, log_path=tmp_path / "server.log").start()
    stop = threading.Event()
    results = []

    def writers() -> None:
        results.append(run_load(srv.url, [KEY_A], clients=8, requests_each=400, seed=7, stop=stop))

    t = threading.Thread(target=writers)
    t.start()
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:  # kill once some writes are acknowledged and more are in flight
        time.sleep(0.5)
        try:
            n = httpx.get(srv.url + "/v1/estimates", params={"limit": 1}, headers={"X-API-Key": KEY_A}).json()["count"]
        except httpx.HTTPError:
            n = 0
        if n >= 24:
            break
    srv.kill()
    stop.set()
    t.join()
    acked = results[0].acked[KEY_A]
    # 24 were stored when the kill came; each of the 8 clients may have had one of them stored but not yet
    # acknowledged (its response in flight), so at least 24 - 8 were acknowledged.
    assert len(acked["estimate"]) >= 24 - 8
    assert results[0].errors, "the kill should have cut some requests off"

    if backend == "sqlite":
        db = Path(server_env["GSA_DATA_DIR"]) / "gsa.db"
        with sqlite3.connect(db) as conn:
            assert conn.execute("PRAGMA integrity_check").fetchone()[0] == "ok"

    srv2 = Server(server_env, workers=1, log_path=tmp_path / "server.log").start()
    try:
        assert httpx.get(srv2.url + "/readyz").json()["database"]["ok"]
        for kind in ("plan", "estimate"):
            stored = set(stored_ids(srv2.url, KEY_A, kind))
            missing = set(acked[kind]) - stored
            assert not missing, f"{len(missing)} acknowledged {kind}s are gone after kill -9"
    finally:
        srv2.stop()
    _check_store(server_env)  # the restart swept what the kill left half-written


def test_the_data_directory_is_private(tmp_path, smoke_models):
    """The database, its WAL files, the key secret and stored images: 0600 files in 0700 folders."""
    import io
    import stat

    import numpy as np
    from fastapi.testclient import TestClient

    from app.core.config import Settings
    from app.core.db import upgrade_database
    from app.main import create_app

    data = tmp_path / "fresh" / "data"
    s = Settings(
        data_dir=data, api_keys="k-files-0123456789", model_dir=smoke_models, database_url=f"sqlite:///{data}/gsa.db"
    )
    upgrade_database(s.database_url)
    buf = io.BytesIO()
    np.save(buf, np.random.default_rng(0).random((64, 64)) + 0.1)
    with TestClient(create_app(s)) as client:
        r = client.post(
            "/v1/estimates", files={"file": ("f.npy", buf.getvalue())}, headers={"X-API-Key": "k-files-0123456789"}
        )
        assert r.status_code == 201, r.text
    paths = [data, *data.rglob("*")]
    assert any(p.name == "gsa.db" for p in paths) and any(p.name == "key-secret" for p in paths)
    assert any(p.suffix == ".png" or p.parent.name != "data" for p in paths if p.is_file())
    for p in paths:
        mode = stat.S_IMODE(p.stat().st_mode)
        assert mode & 0o077 == 0, f"{p.relative_to(tmp_path)} is {oct(mode)}"


def test_idle_and_slow_connections_are_closed_and_1000_held_do_not_block(tmp_path, smoke_models):
    """GSA_HEADER_TIMEOUT_S: a socket that sends nothing, and one that sends its headers a byte at a time
    (slowloris), are closed at the deadline; an idle keep-alive connection after GSA_KEEP_ALIVE_TIMEOUT_S;
    with 1,000 idle sockets held the service still answers; SIGTERM stops it within GSA_SHUTDOWN_GRACE_S.
    The database does not matter here: SQLite."""
    import os
    import signal
    import socket

    data = tmp_path / "data"
    env = {
        "GSA_DATA_DIR": str(data),
        "GSA_MODEL_DIR": str(smoke_models),
        "GSA_API_KEYS": KEY_A,
        "GSA_ORT_THREADS": "1",
        "GSA_LOG_LEVEL": "warning",
        "GSA_HEADER_TIMEOUT_S": "2",
        "GSA_KEEP_ALIVE_TIMEOUT_S": "1",
        "GSA_SHUTDOWN_GRACE_S": "3",
    }
    srv = Server(env, workers=1, log_path=tmp_path / "server.log").start()
    addr = ("127.0.0.1", srv.port)

    def closed_after(sock: socket.socket, trickle: bytes = b"") -> float:
        """Seconds until the server closes ``sock`` (sending ``trickle`` a byte every 0.3 s meanwhile)."""
        start = time.monotonic()
        sock.settimeout(0.3)
        sent = 0
        while time.monotonic() - start < 15.0:
            try:
                if not sock.recv(4096):
                    return time.monotonic() - start
            except TimeoutError:
                if sent < len(trickle):
                    try:
                        sock.sendall(trickle[sent : sent + 1])
                    except OSError:
                        return time.monotonic() - start
                    sent += 1
            except OSError:
                return time.monotonic() - start
        return float("inf")

    try:
        assert closed_after(socket.create_connection(addr)) < 3.5  # sends nothing
        slow = b"GET /healthz HTTP/1.1\r\nHost: x\r\n" + b"X-Slow: " + b"a" * 200 + b"\r\n\r\n"
        assert closed_after(socket.create_connection(addr), slow) < 3.5  # slowloris
        keep = socket.create_connection(addr)
        keep.sendall(b"GET /healthz HTTP/1.1\r\nHost: x\r\n\r\n")
        assert b"200 OK" in keep.recv(4096)
        assert closed_after(keep) < 2.5  # idle after a response: the keep-alive timeout
        held = [socket.create_connection(addr) for _ in range(1000)]
        try:
            t0 = time.monotonic()
            r = httpx.get(srv.url + "/healthz", timeout=5.0)
            assert r.status_code == 200 and time.monotonic() - t0 < 2.0
            r = httpx.get(srv.url + "/v1/plans", headers={"X-API-Key": KEY_A}, timeout=5.0)
            assert r.status_code == 200
        finally:
            for s in held:
                s.close()
        assert srv.proc is not None
        t0 = time.monotonic()
        os.killpg(srv.proc.pid, signal.SIGTERM)
        srv.proc.wait(timeout=10.0)
        assert time.monotonic() - t0 < 3.0 + 2.0
    finally:
        srv.stop()


def test_a_body_that_never_comes_or_trickles_is_answered_408_and_closed(tmp_path, smoke_models):
    """GSA_BODY_TIMEOUT_S: complete headers and then no body (no key needed to try it) are answered 408 after
    GSA_HEADER_TIMEOUT_S without a byte; a body sent a byte at a time, inside that pause, is answered 408 at the
    body's deadline; the log holds one line each, no traceback; the service answers meanwhile. Then a decompression
    bomb is refused without the worker's memory growing."""
    import socket

    env = {
        "GSA_DATA_DIR": str(tmp_path / "data"),
        "GSA_MODEL_DIR": str(smoke_models),
        "GSA_API_KEYS": KEY_A,
        "GSA_ORT_THREADS": "1",
        "GSA_LOG_LEVEL": "info",
        "GSA_HEADER_TIMEOUT_S": "1",
        "GSA_BODY_TIMEOUT_S": "3",
    }
    log = tmp_path / "server.log"
    srv = Server(env, workers=1, log_path=log).start()
    head = (
        b"POST /v1/estimates HTTP/1.1\r\nHost: x\r\nContent-Type: multipart/form-data; boundary=b\r\n"
        b"Content-Length: 100000\r\n\r\n"
    )

    def answer_after(trickle: bytes) -> tuple[float, bytes]:
        """Seconds until the server closes the connection, and what it answered (a byte of ``trickle`` every 0.5 s)."""
        sock = socket.create_connection(("127.0.0.1", srv.port))
        sock.sendall(head)
        sock.settimeout(0.5)
        start, got, sent = time.monotonic(), b"", 0
        try:
            while time.monotonic() - start < 20.0:
                try:
                    chunk = sock.recv(4096)
                    if not chunk:
                        break
                    got += chunk
                except TimeoutError:
                    if sent < len(trickle):
                        sock.sendall(trickle[sent : sent + 1])
                        sent += 1
                except OSError:
                    break
            return time.monotonic() - start, got
        finally:
            sock.close()

    try:
        waited, got = answer_after(b"")
        assert 0.7 < waited < 2.5, waited
        assert got.startswith(b"HTTP/1.1 408") and b"GSA_HEADER_TIMEOUT_S" in got, got
        waited, got = answer_after(b"--b\r\n" + b"x" * 100)
        assert 2.6 < waited < 5.0, waited
        assert got.startswith(b"HTTP/1.1 408") and b"GSA_BODY_TIMEOUT_S" in got, got
        assert httpx.get(srv.url + "/healthz", timeout=5.0).status_code == 200
        # A decompression bomb on the same server: 16 PNGs of 4096 x 4096 (2 GiB as float64, under 400 kB on the
        # wire) are refused from their headers: the worker's peak resident memory does not grow (it was +2.2 GB).
        import io

        from PIL import Image

        y, x = np.mgrid[0:4096, 0:4096]
        png = io.BytesIO()
        Image.fromarray(((x // 64 + y // 64) % 200 + 20).astype(np.uint8), mode="L").save(png, format="PNG")
        assert srv.proc is not None
        status = Path(f"/proc/{srv.proc.pid}/status")

        def peak_mb() -> int:
            line = next(x for x in status.read_text().splitlines() if x.startswith("VmHWM:"))
            return int(line.split()[1]) // 1024

        before = peak_mb()
        r = httpx.post(
            srv.url + "/v1/estimates/batch",
            files=[("files", (f"bomb-{k}.png", png.getvalue())) for k in range(16)],
            data={"resample": "true"},
            headers={"X-API-Key": KEY_A},
            timeout=60.0,
        )
        assert r.status_code == 413 and "GSA_MAX_DECODED_MB" in r.json()["detail"], r.text
        assert peak_mb() - before < 64, (before, peak_mb())
    finally:
        srv.stop()
    text = log.read_text()
    assert "Traceback" not in text, text[-3000:]


def test_a_client_that_leaves_stops_its_plan(tmp_path, smoke_models):
    """A 30-day plan (about 2 s of work) whose client disconnects after 0.3 s is stopped: nothing is stored,
    and the server answers the next request at once."""
    import json
    import socket

    from app.schemas import PAPER_EXAMPLE

    data = tmp_path / "data"
    env = {
        "GSA_DATA_DIR": str(data),
        "GSA_MODEL_DIR": str(smoke_models),
        "GSA_API_KEYS": KEY_A,
        "GSA_ORT_THREADS": "1",
        "GSA_LOG_LEVEL": "warning",
    }
    srv = Server(env, workers=1, log_path=tmp_path / "server.log").start()
    try:
        body = json.dumps({**PAPER_EXAMPLE, "search": {"duration_days": 30}}).encode()
        head = (
            f"POST /v1/plans HTTP/1.1\r\nHost: x\r\nX-API-Key: {KEY_A}\r\nContent-Type: application/json\r\n"
            f"Content-Length: {len(body)}\r\n\r\n"
        ).encode()
        sock = socket.create_connection(("127.0.0.1", srv.port))
        sock.sendall(head + body)
        time.sleep(0.3)
        sock.close()
        time.sleep(4.0)  # long enough for the whole plan had it gone on
        r = httpx.get(srv.url + "/v1/plans", headers={"X-API-Key": KEY_A}, timeout=5.0)
        assert r.status_code == 200 and r.json()["count"] == 0
        # The same plan from a client that waits is stored: the test above is not vacuous.
        r = httpx.post(
            srv.url + "/v1/plans",
            content=body,
            timeout=60.0,
            headers={"X-API-Key": KEY_A, "Content-Type": "application/json"},
        )
        assert r.status_code == 201, r.text
    finally:
        srv.stop()


def test_a_client_that_leaves_stops_its_batch_pass_and_export(tmp_path, smoke_models):
    """A 48-frame batch or pass whose client disconnects after 0.5 s stops between frames: its request ends in a 499
    well before the whole work would, and nothing is stored; the same request waited for is stored. A 30-day
    plan's pointing.csv (seconds of recomputing and writing, for a plan made before exports were stored) whose
    client leaves after 0.3 s stops too."""
    import io
    import sqlite3

    from app.schemas import PAPER_EXAMPLE

    env = {
        "GSA_DATA_DIR": str(tmp_path / "data"),
        "GSA_MODEL_DIR": str(smoke_models),
        "GSA_API_KEYS": KEY_A,
        "GSA_ORT_THREADS": "1",
        "GSA_FIT_THREADS": "1",
        "GSA_LOG_LEVEL": "info",
        "GSA_LOG_JSON": "true",
    }
    log = tmp_path / "server.log"
    srv = Server(env, workers=1, log_path=log).start()
    auth = {"X-API-Key": KEY_A}
    try:
        n = 48
        buf = io.BytesIO()
        np.savez(buf, frames=np.random.default_rng(2).random((n, 64, 64)) + 0.05)
        plan = httpx.post(srv.url + "/v1/plans", json=PAPER_EXAMPLE, headers=auth, timeout=60.0).json()
        w = plan["access_windows"][0]
        rise, end = datetime.fromisoformat(w["rise"]), datetime.fromisoformat(w["set"])
        times = [("observed_at", (rise + (end - rise) * (k + 1) / (n + 1)).isoformat()) for k in range(n)]
        for route, form, listing in (
            ("/v1/estimates/batch", [("resample", "true")], "/v1/estimates"),
            ("/v1/passes", [("plan_id", plan["id"]), *times], "/v1/passes"),
        ):
            body, ctype = multipart(form, [("files", "pass.npz", buf.getvalue())])
            head = (
                f"POST {route} HTTP/1.1\r\nHost: x\r\nX-API-Key: {KEY_A}\r\n"
                f"Content-Type: {ctype}\r\nContent-Length: {len(body)}\r\n\r\n"
            ).encode()
            leave_after(srv.port, head + body, 0.5)
            ended = access_line(log, route)
            assert ended is not None and ended["status"] == 499, (route, ended)
            assert httpx.get(srv.url + listing, headers=auth, timeout=5.0).json()["count"] == 0
            # The same request waited for is stored, and takes far longer than the abandoned one ran.
            t0 = time.monotonic()
            r = httpx.post(srv.url + route, content=body, headers={**auth, "Content-Type": ctype}, timeout=300.0)
            whole_s = time.monotonic() - t0
            assert r.status_code == 201, r.text[:500]
            assert ended["duration_ms"] / 1000.0 < 0.5 * whole_s, (route, ended["duration_ms"], whole_s)
        month = {**PAPER_EXAMPLE, "search": {"duration_days": 30}}
        long_plan = httpx.post(srv.url + "/v1/plans", json=month, headers=auth, timeout=120.0).json()
        with sqlite3.connect(tmp_path / "data" / "gsa.db") as db:  # as a plan made before exports were stored
            db.execute("DELETE FROM plan_exports WHERE plan_id = ?", (long_plan["id"],))
        path = f"/v1/plans/{long_plan['id']}/export/pointing.csv"
        leave_after(srv.port, f"GET {path} HTTP/1.1\r\nHost: x\r\nX-API-Key: {KEY_A}\r\n\r\n".encode(), 0.3)
        ended = access_line(log, path)
        assert ended is not None, "the abandoned export never ended"
        t0 = time.monotonic()
        r = httpx.get(srv.url + path, headers=auth, timeout=120.0)
        whole_s = time.monotonic() - t0
        assert r.status_code == 200 and r.text.count("\n") > 1000
        assert ended["duration_ms"] / 1000.0 < 0.5 * whole_s, (ended, whole_s)
    finally:
        srv.stop()


def test_a_short_environment_key_stops_the_service_at_start(tmp_path):
    """GSA_API_KEYS took 7-character keys silently (issue 46): a key under 16 characters is refused by name."""
    import pydantic

    from app.core.config import MIN_KEY_LENGTH, Settings

    with pytest.raises(
        pydantic.ValidationError, match=f"key of 7 characters; each key needs at least {MIN_KEY_LENGTH}"
    ):
        Settings(data_dir=tmp_path, api_keys="long-enough-key-0123,short-k")
    assert Settings(data_dir=tmp_path, api_keys="x" * MIN_KEY_LENGTH).env_api_keys == ["x" * MIN_KEY_LENGTH]
