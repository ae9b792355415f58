"""A catalogue of named bad inputs: each gets its 4xx, a message naming what to fix, and changes nothing stored.

The app runs with small operator limits (upload size, image side, page size, span,
grid, batch) so that every limit is shown to be enforced. Row counts of every table
and the number of stored image files are compared before and after each case.
"""

from __future__ import annotations

import copy
import io
import json
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from PIL import Image
from sqlalchemy import create_engine, func, select

from app.db.models import ApiKey, Estimate, Operator, Plan
from app.main import create_app
from app.schemas import PAPER_EXAMPLE
from tests.conftest import KEY_A

A = {"X-API-Key": KEY_A}
ISS_L1 = "1 25544U 98067A   08264.51782528 -.00002182  00000-0 -11606-4 0  2927"
ISS_L2 = "2 25544  51.6416 247.4627 0006703 130.5360 325.0288 15.72125391563537"
LIMITS = {
    "max_upload_bytes": 200_000,
    "max_batch_bytes": 400_000,
    "max_request_bytes": 65_536,
    "max_image_side": 128,
    "max_page_size": 5,
    "max_span_days": 2.0,
    "max_grid_points": 1000,
    "max_batch_frames": 2,
}


@pytest.fixture(scope="module")
def limited(settings):
    s = settings.model_copy(update=LIMITS)
    with TestClient(create_app(s)) as c:
        yield c, s


def _npy(arr: Any) -> bytes:
    buf = io.BytesIO()
    np.save(buf, arr, allow_pickle=True)
    return buf.getvalue()


def _frame(shape=(64, 64)) -> np.ndarray:
    return np.random.default_rng(1).random(shape) + 0.1


def _png(arr: np.ndarray, mode: str | None = None) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(arr, mode=mode).save(buf, format="PNG")
    return buf.getvalue()


def _tiff_float() -> bytes:
    buf = io.BytesIO()
    Image.fromarray(_frame().astype(np.float32), mode="F").save(buf, format="TIFF")
    return buf.getvalue()


def _multi_frame(fmt: str) -> bytes:
    """Two 8-bit frames in one file: a multi-page TIFF or an animated PNG."""
    a = Image.fromarray((_frame() * 100).astype(np.uint8), mode="L")
    b = Image.fromarray((_frame((64, 64))[::-1] * 100).astype(np.uint8), mode="L")
    buf = io.BytesIO()
    a.save(buf, format=fmt, save_all=True, append_images=[b])
    return buf.getvalue()


def _tiff_int32() -> bytes:
    buf = io.BytesIO()
    Image.fromarray((_frame() * 1000).astype(np.int32), mode="I").save(buf, format="TIFF")
    return buf.getvalue()


def _lying_npy() -> bytes:
    good = _npy(_frame())
    header_end = good.index(b"\n") + 1
    header = good[10:header_end].replace(b"(64, 64)", b"(4000, 4000)")
    return good[:8] + len(header).to_bytes(2, "little") + header + good[header_end:]


def _zip_bomb() -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("frame.npy", _npy(np.zeros((6000, 6000), np.float64))[:80] + b"\0" * (100 * 1024 * 1024))
    return buf.getvalue()


def _plan(**changes: Any) -> Callable[[], dict[str, Any]]:
    """A plan request: the paper's example with dotted-path changes (value None deletes the key)."""

    def make() -> dict[str, Any]:
        body = copy.deepcopy(PAPER_EXAMPLE)
        body["search"] = {"duration_days": 1}  # within the span limit, so each case fails for its own reason
        for path, value in changes.items():
            *parents, leaf = path.split(".")
            node = body
            for p in parents:
                node = node.setdefault(p, {})
            if value is None:
                node.pop(leaf, None)
            else:
                node[leaf] = value
        return {"json": body}

    return make


def _raw(text: str) -> Callable[[], dict[str, Any]]:
    return lambda: {"content": text.encode(), "headers": {"Content-Type": "application/json"}}


def _upload(data: bytes | Callable[[], bytes], name: str = "f.npy", **form: str) -> Callable[[], dict[str, Any]]:
    return lambda: {"files": {"file": (name, data() if callable(data) else data)}, "data": form}


def _raw_multipart(filename: bytes, data: bytes) -> dict[str, Any]:
    """A multipart upload written byte for byte (httpx would percent-encode a NUL in the file name)."""
    b = b"gsa-test-boundary"
    body = (
        b"--" + b + b'\r\nContent-Disposition: form-data; name="file"; filename="' + filename + b'"\r\n'
        b"Content-Type: application/octet-stream\r\n\r\n" + data + b"\r\n--" + b + b"--\r\n"
    )
    return {"content": body, "headers": {"Content-Type": "multipart/form-data; boundary=" + b.decode()}}


@dataclass(frozen=True)
class Case:
    name: str
    method: str
    path: str
    request: Callable[[], dict[str, Any]]
    status: int
    says: str  # the message must contain this (the field or what to fix)


PLANS, EST = "/v1/plans", "/v1/estimates"
CASES = [
    # A lone surrogate in JSON text (issue 46: a 500 on stations, plans and access windows, on both databases)
    Case(
        "surrogate_station_name",
        "POST",
        "/v1/stations",
        _raw('{"name": "a\\ud800b", "latitude_deg": 10, "longitude_deg": 20}'),
        422,
        "name holds a lone UTF-16 surrogate",
    ),
    Case(
        "surrogate_plan_target_name",
        "POST",
        PLANS,
        lambda: _raw(json.dumps({**PAPER_EXAMPLE, "search": {"duration_days": 1}}).replace('"GS"', '"G\\udc00S"'))(),
        422,
        "ground_station.name holds a lone UTF-16 surrogate",
    ),
    Case(
        "surrogate_access_key",
        "POST",
        "/v1/access-windows",
        _raw('{"target": {"name": "T", "tle": ["a", "b"]}, "ground_station": {"name": "g", "\\ud800": 1}}'),
        422,
        "lone UTF-16 surrogate",
    ),
    # A date-time UTC cannot hold (found by make fuzz: it was a 500)
    Case(
        "epoch_beyond_utc",
        "POST",
        PLANS,
        _plan(**{"target.elements.epoch": "0001-01-01T00:00:00+14:00"}),
        422,
        "outside years 1-9999",
    ),
    # TLEs
    Case(
        "tle_line_too_short",
        "POST",
        PLANS,
        _plan(**{"target.elements": None, "target.tle": [ISS_L1[:60], ISS_L2]}),
        422,
        "tle",
    ),
    Case(
        "tle_bad_checksum",
        "POST",
        PLANS,
        _plan(**{"target.elements": None, "target.tle": [ISS_L1, ISS_L2[:-1] + "0"]}),
        422,
        "checksum",
    ),
    Case(
        "tle_non_ascii",
        "POST",
        PLANS,
        _plan(**{"target.elements": None, "target.tle": [ISS_L1[:-2] + "é7", ISS_L2]}),
        422,
        "tle",
    ),
    Case("tle_one_line", "POST", PLANS, _plan(**{"target.elements": None, "target.tle": [ISS_L1]}), 422, "tle"),
    Case("tle_and_elements_both", "POST", PLANS, _plan(**{"target.tle": [ISS_L1, ISS_L2]}), 422, "exactly one"),
    # numbers that make no sense
    Case(
        "elements_nan",
        "POST",
        PLANS,
        _raw(json.dumps(PAPER_EXAMPLE).replace('"ha_km": 700', '"ha_km": NaN', 1)),
        422,
        "ha_km",
    ),
    Case(
        "elements_infinity",
        "POST",
        PLANS,
        _raw(json.dumps(PAPER_EXAMPLE).replace('"hp_km": 600', '"hp_km": Infinity', 1)),
        422,
        "hp_km",
    ),
    Case("elements_1e308", "POST", PLANS, _plan(**{"target.elements.ha_km": 1e308}), 422, "ha_km"),
    Case("perigee_negative", "POST", PLANS, _plan(**{"target.elements.hp_km": -50}), 422, "hp_km"),
    Case(
        "inclination_over_180",
        "POST",
        PLANS,
        _plan(**{"observer.elements.inclination_deg": 200}),
        422,
        "inclination_deg",
    ),
    Case("apogee_below_perigee", "POST", PLANS, _plan(**{"target.elements.ha_km": 500}), 422, "ha_km"),
    Case("latitude_91", "POST", PLANS, _plan(**{"ground_station.latitude_deg": 91}), 422, "latitude_deg"),
    # types, shapes and unknown fields
    Case("string_for_number", "POST", PLANS, _plan(**{"target.elements.ha_km": "high"}), 422, "ha_km"),
    Case("list_for_object", "POST", PLANS, _plan(target=[1, 2]), 422, "target"),
    Case("unknown_field", "POST", PLANS, _plan(**{"target.elements.colour": "red"}), 422, "colour"),
    Case("epoch_not_a_date", "POST", PLANS, _plan(**{"target.elements.epoch": "yesterday"}), 422, "epoch"),
    Case("body_not_json", "POST", PLANS, _raw("{not json"), 422, "JSON"),
    Case("body_empty", "POST", PLANS, _raw(""), 422, "body"),
    # names
    Case("name_with_path_separator", "POST", PLANS, _plan(**{"target.name": "../../etc/passwd"}), 422, "name"),
    Case("name_with_nul", "POST", PLANS, _plan(**{"observer.name": "obs\x00; DROP TABLE plans;--"}), 422, "name"),
    Case(
        "name_10000_characters", "POST", PLANS, _plan(**{"target.name": "x'; DELETE FROM plans;--" * 400}), 422, "name"
    ),
    # a box whose corner takes the observer under 100 km: refused before planning, naming the box field
    Case(
        "box_below_perigee_limit",
        "POST",
        PLANS,
        _plan(**{"search.dhp_min_km": -300, "search.step_km": 50}),
        422,
        "dhp_min_km",
    ),
    Case(
        "box_apogee_below_perigee_limit",
        "POST",
        PLANS,
        _plan(
            **{"observer.elements.ha_km": 400, "search.dha_min_km": -320, "search.dhp_min_km": 0, "search.step_km": 10}
        ),
        422,
        "dha_min_km",
    ),
    # the encounter's options
    Case("standoff_zero", "POST", PLANS, _plan(**{"search.standoff_km": 0}), 422, "standoff_km"),
    Case("standoff_over_500", "POST", PLANS, _plan(**{"search.standoff_km": 5000}), 422, "standoff_km"),
    Case("min_separation_negative", "POST", PLANS, _plan(**{"search.min_separation_km": -1}), 422, "min_separation_km"),
    Case(
        "min_separation_above_standoff",
        "POST",
        PLANS,
        _plan(**{"search.standoff_km": 2, "search.min_separation_km": 3}),
        422,
        "min_separation_km",
    ),
    Case(
        "tracking_rate_zero",
        "POST",
        PLANS,
        _plan(**{"search.max_tracking_rate_deg_s": 0}),
        422,
        "max_tracking_rate_deg_s",
    ),
    Case(
        "tracking_rate_nan",
        "POST",
        PLANS,
        _raw(
            json.dumps({**PAPER_EXAMPLE, "search": {"duration_days": 1, "max_tracking_rate_deg_s": 1}}).replace(
                '"max_tracking_rate_deg_s": 1', '"max_tracking_rate_deg_s": NaN'
            )
        ),
        422,
        "max_tracking_rate_deg_s",
    ),
    # NUL and other control characters, refused at the edge on both databases (PostgreSQL cannot store NUL)
    Case("nul_in_plan_id", "GET", "/v1/plans/abc%00", lambda: {}, 422, "plan_id"),
    Case("nul_in_target_filter", "GET", "/v1/plans?target_name=a%00b", lambda: {}, 422, "target_name"),
    Case("newline_in_target_filter", "GET", "/v1/plans?target_name=a%0Ab", lambda: {}, 422, "control characters"),
    Case("nul_in_estimate_id", "GET", "/v1/estimates/abc%00", lambda: {}, 422, "estimate_id"),
    Case("nul_in_estimate_delete", "DELETE", "/v1/estimates/abc%00", lambda: {}, 422, "estimate_id"),
    Case("nul_in_estimate_png", "GET", "/v1/estimates/abc%00/enhanced.png", lambda: {}, 422, "estimate_id"),
    Case("nul_in_estimates_filter", "GET", "/v1/estimates?plan_id=a%00", lambda: {}, 422, "plan_id"),
    Case("nul_in_form_plan_id", "POST", EST, _upload(lambda: _npy(_frame()), plan_id="abc\x00"), 422, "plan_id"),
    Case(
        "nul_in_batch_plan_id",
        "POST",
        EST + "/batch",
        lambda: {"files": [("files", ("f.npy", _npy(_frame())))], "data": {"plan_id": "a\x00b"}},
        422,
        "plan_id",
    ),
    Case(
        "nul_in_upload_filename",
        "POST",
        EST,
        lambda: _raw_multipart(b"f\x00.npy", _npy(_frame())),
        422,
        "control characters",
    ),
    # operator limits
    Case("span_over_limit", "POST", PLANS, _plan(**{"search.duration_days": 5}), 422, "GSA_MAX_SPAN_DAYS"),
    Case("grid_over_limit", "POST", PLANS, _plan(**{"search.step_km": 0.01}), 422, "step_km"),
    Case(
        "access_span_over_limit",
        "POST",
        "/v1/access-windows",
        lambda: {
            "json": {
                "target": PAPER_EXAMPLE["target"],
                "ground_station": PAPER_EXAMPLE["ground_station"],
                "duration_days": 3,
            }
        },
        422,
        "duration_days",
    ),
    Case("request_body_over_limit", "POST", PLANS, _plan(**{"target.name": "x" * 70_000}), 413, "limit"),
    # uploads
    Case("upload_empty", "POST", EST, _upload(b""), 422, "empty"),
    Case("upload_unknown_format", "POST", EST, _upload(b"hello, this is text", "f.txt"), 422, "unknown format"),
    Case("npy_truncated", "POST", EST, _upload(lambda: _npy(_frame())[:1000]), 422, "npy"),
    Case("npy_lying_header", "POST", EST, _upload(_lying_npy), 422, "npy"),
    Case("npy_object_dtype", "POST", EST, _upload(lambda: _npy(np.array([{"a": 1}], dtype=object))), 422, "dtype"),
    Case("npy_strings", "POST", EST, _upload(lambda: _npy(np.full((64, 64), "abc"))), 422, "dtype"),
    Case("npz_zip_bomb", "POST", EST, _upload(_zip_bomb, "bomb.npz"), 422, "unpacks to"),
    Case("png_that_is_not", "POST", EST, _upload(b"\x89PNG\r\n\x1a\n" + b"garbage" * 50, "f.png"), 422, "PNG"),
    Case("tiff_float_depth", "POST", EST, _upload(_tiff_float, "f.tif"), 422, "grayscale"),
    Case("tiff_int32", "POST", EST, _upload(_tiff_int32, "f.tif"), 422, "16-bit"),
    Case("tiff_two_pages", "POST", EST, _upload(lambda: _multi_frame("TIFF"), "f.tif"), 422, "multi-page TIFF"),
    Case("apng_two_frames", "POST", EST, _upload(lambda: _multi_frame("PNG"), "f.png"), 422, "animated PNG"),
    Case("frame_constant", "POST", EST, _upload(lambda: _npy(np.full((64, 64), 0.7))), 422, "constant"),
    Case("png_rgb", "POST", EST, _upload(lambda: _png(np.zeros((64, 64, 3), np.uint8) + 9), "f.png"), 422, "grayscale"),
    Case("frame_wrong_shape", "POST", EST, _upload(lambda: _npy(_frame((32, 48)))), 422, "resample"),
    Case("frame_3d_to_single", "POST", EST, _upload(lambda: _npy(_frame((2, 64, 64)))), 422, "batch"),
    Case("frame_4d", "POST", EST, _upload(lambda: _npy(_frame((1, 2, 64, 64)))), 422, "2-D"),
    Case("frame_all_nan", "POST", EST, _upload(lambda: _npy(np.full((64, 64), np.nan))), 422, "NaN"),
    Case("frame_with_inf", "POST", EST, _upload(lambda: _npy(np.where(_frame() > 0.5, np.inf, 1.0))), 422, "infinite"),
    Case("frame_all_zero", "POST", EST, _upload(lambda: _npy(np.zeros((64, 64)))), 422, "all zero"),
    Case(
        "image_side_over_limit",
        "POST",
        EST,
        _upload(lambda: _npy(_frame((64, 200))), resample="true"),
        422,
        "GSA_MAX_IMAGE_SIDE",
    ),
    Case("upload_over_size_limit", "POST", EST, _upload(lambda: _npy(_frame((100, 300)))), 413, "upload limit"),
    Case("unknown_plan_id", "POST", EST, _upload(lambda: _npy(_frame()), plan_id="0" * 36), 422, "plan_id"),
    Case(
        "observed_at_without_plan",
        "POST",
        EST,
        _upload(lambda: _npy(_frame()), observed_at="2022-11-28T11:28:29Z"),
        422,
        "plan_id",
    ),
    Case("snr_not_a_number", "POST", EST, _upload(lambda: _npy(_frame()), snr_db="nan"), 422, "snr_db"),
    # the fit's fields
    Case("refine_not_a_bool", "POST", EST, _upload(lambda: _npy(_frame()), refine="perhaps"), 422, "refine"),
    Case("unknown_target", "POST", EST, _upload(lambda: _npy(_frame()), target="hubble"), 422, "target"),
    Case(
        "unknown_target_in_batch",
        "POST",
        EST + "/batch",
        lambda: {"files": [("files", ("f.npy", _npy(_frame())))], "data": {"target": "../etc"}},
        422,
        "target",
    ),
    Case(
        "range_cell_without_cross_range",
        "POST",
        EST,
        _upload(lambda: _npy(_frame()), range_cell_m="0.1"),
        422,
        "cross_range_cell_m",
    ),
    Case(
        "cross_range_cell_without_range",
        "POST",
        EST,
        _upload(lambda: _npy(_frame()), cross_range_cell_m="0.1"),
        422,
        "range_cell_m",
    ),
    Case(
        "range_cell_zero",
        "POST",
        EST,
        _upload(lambda: _npy(_frame()), range_cell_m="0", cross_range_cell_m="0.1"),
        422,
        "range_cell_m",
    ),
    Case(
        "cross_range_cell_nan",
        "POST",
        EST,
        _upload(lambda: _npy(_frame()), range_cell_m="0.1", cross_range_cell_m="nan"),
        422,
        "cross_range_cell_m",
    ),
    Case(
        "cells_too_coarse_for_the_frame",
        "POST",
        EST,
        _upload(lambda: _npy(_frame()), range_cell_m="0.001", cross_range_cell_m="0.001"),
        422,
        "cell",
    ),
    Case(
        "batch_over_frame_limit",
        "POST",
        EST + "/batch",
        lambda: {"files": [("files", (f"f{k}.npy", _npy(_frame()))) for k in range(3)]},
        422,
        "GSA_MAX_BATCH_FRAMES",
    ),
    # listings
    Case("page_size_over_limit", "GET", PLANS + "?limit=10", lambda: {}, 422, "limit"),
    Case("page_size_zero", "GET", EST + "?limit=0", lambda: {}, 422, "limit"),
    Case("scenes_page_size_over_limit", "GET", "/v1/scenes?limit=6", lambda: {}, 422, "GSA_MAX_PAGE_SIZE"),
    Case("unknown_query_parameter", "GET", PLANS + "?limt=5", lambda: {}, 422, "limt"),
    Case("offset_negative", "GET", PLANS + "?offset=-1", lambda: {}, 422, "offset"),
    Case("filter_not_a_date", "GET", EST + "?created_after=tuesday", lambda: {}, 422, "created_after"),
    Case("plan_id_10000_characters", "GET", PLANS + "/" + "9" * 10000, lambda: {}, 404, "not found"),
]


def _state(settings) -> dict[str, int]:
    engine = create_engine(settings.database_url)
    with engine.connect() as conn:
        counts = {
            t.__tablename__: conn.scalar(select(func.count()).select_from(t))
            for t in (Operator, ApiKey, Plan, Estimate)
        }
    engine.dispose()
    images = settings.data_dir / "images"
    counts["image_files"] = sum(1 for _ in images.rglob("*")) if images.exists() else 0
    return counts


def test_the_catalogue_is_large_and_its_names_unique():
    assert len(CASES) >= 30
    assert len({c.name for c in CASES}) == len(CASES)


@pytest.mark.parametrize("case", CASES, ids=lambda c: c.name)
def test_bad_input(limited, case: Case):
    client, settings = limited
    client.get("/v1/plans", headers=A)  # the operator row exists before the count
    before = _state(settings)
    kwargs = case.request()
    headers = {**A, **kwargs.pop("headers", {})}
    r = client.request(case.method, case.path, headers=headers, **kwargs)
    assert r.status_code == case.status, r.text[:500]
    assert case.says.lower() in r.text.lower(), r.text[:500]
    assert r.json()["request_id"] == r.headers["X-Request-ID"]
    assert _state(settings) == before


def test_a_good_upload_passes_the_same_limits(limited):
    """The limits refuse the cases above, not ordinary work."""
    client, settings = limited
    before = _state(settings)
    r = client.post(EST, files={"file": ("ok.npy", _npy(_frame()))}, headers=A)
    assert r.status_code == 201, r.text
    after = _state(settings)
    assert after["estimates"] == before["estimates"] + 1 and after["image_files"] >= before["image_files"]


def test_hostile_strings_in_filters_match_nothing_and_change_nothing(limited):
    client, settings = limited
    before = _state(settings)
    for value in ("' OR 1=1 --", "%", "_", 'x"; DROP TABLE plans; --', "ü" * 100):
        r = client.get(PLANS, params={"target_name": value}, headers=A)
        assert r.status_code == 200 and r.json()["count"] == 0, (value, r.text)
    assert _state(settings) == before


def test_a_chunked_body_over_the_limit_is_413_without_content_length(limited):
    client, settings = limited
    before = _state(settings)

    def chunks():
        for _ in range(100):
            yield b" " * 1000

    r = client.post(PLANS, content=chunks(), headers={**A, "Content-Type": "application/json"})
    assert r.status_code == 413 and "limit" in r.json()["detail"]
    assert _state(settings) == before


def test_pages_hold_at_most_the_limit_and_default_to_the_operator_cap(limited):
    client, _settings = limited
    for k in range(7):
        assert client.post(EST, files={"file": (f"p{k}.npy", _npy(_frame() + k))}, headers=A).status_code == 201
    total = client.get(EST, params={"limit": 1}, headers=A).json()["count"]
    assert total >= 7
    assert len(client.get(EST, params={"limit": 3}, headers=A).json()["data"]) == 3
    assert len(client.get(EST, headers=A).json()["data"]) == 5  # default 20, capped by GSA_MAX_PAGE_SIZE=5
    pages = [
        e["id"]
        for off in range(0, total, 5)
        for e in client.get(EST, params={"limit": 5, "offset": off}, headers=A).json()["data"]
    ]
    assert len(pages) == len(set(pages)) == total
