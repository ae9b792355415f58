"""Decompression bombs: a request's frames and decoded bytes are checked from each file's header, before a pixel.

Real bombs (a 16-kB PNG or TIFF of 4096 x 4096, an .npz whose member unpacks to 16 MiB, a labelled frame of the
same) are sent with the decoded budget (GSA_MAX_DECODED_MB) set to 16 MiB, counted at 8 bytes a pixel: each must
be refused with a 413 naming the setting, nothing stored, and the Python heap of the request (numpy's buffers
are traced by tracemalloc) must stay far below what decoding a single such frame would take (16 MiB as uint8,
128 MiB as the float64 magnitudes the service holds).
"""

from __future__ import annotations

import io
import tracemalloc

import numpy as np
import pytest
from fastapi.testclient import TestClient
from PIL import Image
from sqlalchemy import create_engine, func, select

from app.db.models import Estimate, LabelledFrame
from app.main import create_app
from inference.labelled import write_frame
from tests.conftest import KEY_A

A = {"X-API-Key": KEY_A}
SIDE = 4096
HEAP_LIMIT = 6 * 2**20  # a decoded 4096 x 4096 frame is 16 MiB even as uint8


@pytest.fixture(scope="module")
def backend() -> str:
    """What this module tests does not depend on the database: SQLite alone (the suite's time is kept for the rest)."""
    return "sqlite"


@pytest.fixture(scope="module")
def small_budget(settings):
    s = settings.model_copy(update={"max_decoded_mb": 16, "max_batch_frames": 4})
    with TestClient(create_app(s)) as c:
        yield c, s


def _png(side: int = SIDE) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(np.zeros((side, side), np.uint8), mode="L").save(buf, format="PNG", optimize=True)
    return buf.getvalue()


def _tiff() -> bytes:
    buf = io.BytesIO()
    Image.fromarray(np.zeros((SIDE, SIDE), np.uint8), mode="L").save(
        buf, format="TIFF", compression="tiff_adobe_deflate"
    )
    return buf.getvalue()


def _npz() -> bytes:
    buf = io.BytesIO()
    np.savez_compressed(buf, a=np.zeros((SIDE, SIDE), np.uint8))
    return buf.getvalue()


def _labelled() -> bytes:
    buf = io.BytesIO()
    write_frame(buf, np.zeros((SIDE, SIDE), np.uint8), angles_deg=(1.0, 2.0, 3.0), scene="bomb")
    return buf.getvalue()


def _rows(settings) -> tuple[int, int]:
    engine = create_engine(settings.database_url)
    with engine.connect() as conn:
        n = (
            conn.scalar(select(func.count()).select_from(Estimate)),
            conn.scalar(select(func.count()).select_from(LabelledFrame)),
        )
    engine.dispose()
    return n


def _traced(call):
    tracemalloc.start()
    try:
        r = call()
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return r, peak


@pytest.mark.parametrize(
    ("route", "field", "make"),
    [
        ("/v1/estimates", "file", _png),
        ("/v1/estimates", "file", _tiff),
        ("/v1/estimates", "file", _npz),
        ("/v1/estimates/batch", "files", _png),
        ("/v1/estimates/batch", "files", _npz),
        ("/v1/targets/tiangong-like/labelled-frames", "files", _labelled),
    ],
    ids=["png", "tiff", "npz", "batch-png", "batch-npz", "labelled"],
)
def test_a_bomb_is_refused_from_its_header_before_it_is_decoded(small_budget, route, field, make):
    client, settings = small_budget
    data = make()
    assert len(data) < 200_000  # a bomb: small on the wire
    before = _rows(settings)
    r, peak = _traced(lambda: client.post(route, files=[(field, ("bomb.bin", data))], headers=A))
    assert r.status_code == 413, r.text
    assert "GSA_MAX_DECODED_MB" in r.json()["detail"] and "bomb.bin" in r.json()["detail"]
    assert peak < HEAP_LIMIT, f"{peak / 2**20:.1f} MiB traced while refusing a bomb"
    assert _rows(settings) == before


def test_the_budget_is_the_whole_requests(small_budget):
    """Two 1024 x 1024 frames take 16 MiB decoded (at the limit); a third is refused before any is decoded."""
    client, settings = small_budget
    ramp = np.add.outer(np.arange(1024), np.arange(1024))
    frames = [((ramp // 8 + k) % 200 + 1).astype(np.uint8) for k in range(3)]  # small on the wire
    pngs = []
    for f in frames:
        buf = io.BytesIO()
        Image.fromarray(f, mode="L").save(buf, format="PNG")
        pngs.append(buf.getvalue())
    before = _rows(settings)
    r, peak = _traced(
        lambda: client.post(
            "/v1/estimates/batch",
            files=[("files", (f"f{k}.png", p)) for k, p in enumerate(pngs)],
            data={"resample": "true"},
            headers=A,
        )
    )
    assert r.status_code == 413, r.text
    assert "'f2.png'" in r.json()["detail"]
    # every file's header is charged before any file is decoded: not even the first two were
    assert peak < HEAP_LIMIT, f"{peak / 2**20:.1f} MiB traced"
    assert _rows(settings) == before


def test_more_files_than_frames_is_refused_before_any_file_is_read(small_budget):
    """Five files where four frames are allowed: the count answers, though the first file is not even an image."""
    client, _ = small_budget
    files = [("files", ("junk.bin", b"not an image"))] + [("files", (f"f{k}.png", _png(64))) for k in range(4)]
    r = client.post("/v1/estimates/batch", files=files, headers=A)
    assert r.status_code == 422, r.text
    (err,) = r.json()["detail"]
    assert err["loc"][-1] == "files" and "GSA_MAX_BATCH_FRAMES" in err["msg"] and "5 files" in err["msg"]


def test_a_stack_over_the_frame_limit_is_refused_from_its_header(small_budget):
    client, _ = small_budget
    buf = io.BytesIO()
    np.savez_compressed(buf, frames=np.zeros((5, 64, 64), np.float32))
    r = client.post("/v1/estimates/batch", files=[("files", ("stack.npz", buf.getvalue()))], headers=A)
    assert r.status_code == 422, r.text
    (err,) = r.json()["detail"]
    assert "GSA_MAX_BATCH_FRAMES" in err["msg"] and "stack.npz" in err["msg"]


def test_an_npy_whose_header_promises_more_than_follows_is_refused(small_budget):
    client, _ = small_budget
    buf = io.BytesIO()
    np.save(buf, np.zeros((4, 4), np.float64))
    raw = buf.getvalue().replace(b"(4, 4)", b"(4000, 4)")  # same header length: the header promises 4000 rows
    r = client.post("/v1/estimates", files=[("file", ("huge.npy", raw))], headers=A)
    assert r.status_code == 422, r.text
    assert "promises" in r.json()["detail"][0]["msg"]
