import io
import threading
from concurrent.futures import ThreadPoolExecutor
from datetime import datetime, timedelta

import numpy as np
import pytest
from fastapi.testclient import TestClient
from PIL import Image
from scipy.spatial.transform import Rotation
from sqlalchemy import create_engine, func, select

from app.db.models import Estimate
from app.main import create_app
from app.schemas import PAPER_EXAMPLE
from app.services.uploads import decode, prepare
from inference.errors import ModelFileError
from inference.frames import normalise_frame
from inference.simulation.radar import Imager
from inference.simulation.scene import simulate
from inference.simulation.targets import tiangong_like
from tests.conftest import KEY_A, KEY_B
from tests.utils.models import SMOKE_RADAR

A = {"X-API-Key": KEY_A}
B = {"X-API-Key": KEY_B}


@pytest.fixture(scope="module")
def frame():
    return simulate(tiangong_like(), Imager(SMOKE_RADAR), (10.0, -5.0, 20.0), 10.0, 1).image


def _npy(arr):
    buf = io.BytesIO()
    np.save(buf, arr)
    return buf.getvalue()


def _count(settings):
    engine = create_engine(settings.database_url)
    with engine.connect() as conn:
        n = conn.scalar(select(func.count()).select_from(Estimate))
    engine.dispose()
    return n


def _post(client, data, name="frame.npy", headers=A, **form):
    return client.post("/v1/estimates", files={"file": (name, data)}, data=form, headers=headers)


def test_readyz_reports_the_models(client):
    r = client.get("/readyz")
    assert r.status_code == 200
    assert r.json()["models"]["config"] == "smoke"


def test_estimate_complex_npy(client, frame):
    r = _post(client, _npy(frame))
    assert r.status_code == 201, r.text
    body = r.json()
    att = body["attitude"]
    assert len(att["euler_zyx_deg"]) == 3 and len(att["quaternion_wxyz"]) == 4
    assert np.allclose(np.linalg.det(np.array(att["rotation_matrix"])), 1.0)
    # The reading with cross-range reversed: the answer turned half about the line of sight (X), in all three forms.
    rev = body["attitude_reversed"]
    half_x = Rotation.from_rotvec([np.pi, 0.0, 0.0])
    expected = half_x * Rotation.from_quat(np.roll(att["quaternion_wxyz"], -1))
    assert Rotation.from_quat(np.roll(rev["quaternion_wxyz"], -1)).approx_equal(expected, atol=1e-9)
    np.testing.assert_allclose(rev["rotation_matrix"], expected.as_matrix(), atol=1e-9)
    assert Rotation.from_euler("ZYX", rev["euler_zyx_deg"], degrees=True).approx_equal(expected, atol=1e-9)
    assert client.get(body["links"]["self"], headers=A).json()["attitude_reversed"] == rev
    assert body["model"]["config"] == "smoke" and body["dtype"] == "complex128"
    assert set(body["timings_s"]) >= {"preprocess", "unetpp", "swin"}
    png = client.get(body["links"]["enhanced_png"], headers=A)
    assert png.status_code == 200 and png.content.startswith(b"\x89PNG")
    original = client.get(body["links"]["original_png"], headers=A)
    assert original.status_code == 200
    # Any PNG reader reads the stored images: the original is the normalised frame in 8 bits.
    pixels = np.asarray(Image.open(io.BytesIO(original.content)))
    expected = (normalise_frame(np.abs(frame)) * 255.0 + 0.5).astype(np.uint8)
    np.testing.assert_array_equal(pixels, expected)
    assert client.get(body["links"]["self"], headers=A).json()["id"] == body["id"]


def test_png_bytes_round_trips_any_shape_and_clips():
    from app.services.images import png_bytes

    frame = np.linspace(-0.5, 1.5, 15).reshape(3, 5)
    img = Image.open(io.BytesIO(png_bytes(frame)))
    assert img.mode == "L" and img.size == (5, 3)
    np.testing.assert_array_equal(np.asarray(img), (np.clip(frame, 0, 1) * 255 + 0.5).astype(np.uint8))


def test_upload_uses_the_training_normalisation(frame):
    (up,) = decode(_npy(frame), "f.npy")
    np.testing.assert_array_equal(prepare(up, 64, False), normalise_frame(np.abs(frame)))


def test_png_8_and_16_bit(client, frame):
    mag = np.abs(frame)
    for dtype, scale in ((np.uint8, 255), (np.uint16, 65535)):
        img = Image.fromarray((mag / mag.max() * scale).astype(dtype))
        buf = io.BytesIO()
        img.save(buf, format="PNG")
        r = _post(client, buf.getvalue(), name="frame.png")
        assert r.status_code == 201, r.text


def test_batch_endpoint_stores_one_row_each(client, settings, frame):
    stack = np.stack([np.abs(frame)] * 3)
    buf = io.BytesIO()
    np.savez(buf, frames=stack)
    before = _count(settings)
    r = client.post(
        "/v1/estimates/batch",
        files=[("files", ("s.npz", buf.getvalue())), ("files", ("f.npy", _npy(frame)))],
        headers=A,
    )
    assert r.status_code == 201, r.text
    assert r.json()["count"] == 4 and _count(settings) == before + 4


def test_plan_ties_attitude_to_lvlh_and_j2000(client, frame):
    plan = client.post("/v1/plans", json=PAPER_EXAMPLE, headers=A).json()
    r = _post(client, _npy(frame), plan_id=plan["id"], observed_at=plan["chosen"]["t_access"])
    assert r.status_code == 201, r.text
    body = r.json()
    r_obs = np.array(body["attitude"]["rotation_matrix"])
    r_j2000 = np.array(body["attitude_j2000"]["rotation_matrix"])
    r_lvlh = np.array(body["attitude_lvlh"]["rotation_matrix"])
    for m in (r_j2000, r_lvlh):
        np.testing.assert_allclose(m @ m.T, np.eye(3), atol=1e-9)
    assert not np.allclose(r_obs, r_j2000)
    scenes = client.get("/v1/scenes", headers=A).json()
    scene = next(s for s in scenes["data"] if s["plan_id"] == plan["id"])
    assert [e["id"] for e in scene["estimates"]] == [body["id"]]
    listed = client.get("/v1/estimates", params={"plan_id": plan["id"]}, headers=A).json()
    assert listed["count"] == 1
    linked = client.get(f"/v1/plans/{plan['id']}", headers=A).json()
    assert linked["estimate_ids"] == [body["id"]] and linked["pass_ids"] == []
    # A moment the station cannot see the target is refused, the nearest window named; nothing stored.
    w = plan["access_windows"][0]
    late = (datetime.fromisoformat(w["set"]) + timedelta(seconds=90)).isoformat()
    r = _post(client, _npy(frame), plan_id=plan["id"], observed_at=late)
    assert r.status_code == 422, r.text
    detail = r.json()["detail"][0]
    assert (
        detail["loc"][-1] == "observed_at"
        and "the nearest is window 0" in detail["msg"]
        and "after it sets" in detail["msg"]
    )
    assert client.get("/v1/estimates", params={"plan_id": plan["id"]}, headers=A).json()["count"] == 1


def test_scenes_page_through_plans_each_with_its_own_estimates(client, frame):
    before = client.get("/v1/scenes", headers=A).json()["count"]  # the module's client is shared
    first = client.post("/v1/plans", json=PAPER_EXAMPLE, headers=A).json()
    second = client.post("/v1/plans", json=PAPER_EXAMPLE, headers=A).json()
    t = first["chosen"]["t_access"]
    ids = {
        p["id"]: [_post(client, _npy(frame), plan_id=p["id"], observed_at=t).json()["id"] for _ in range(2)]
        for p in (first, second)
    }
    _post(client, _npy(frame))  # an estimate tied to no plan belongs to no scene
    pages = [client.get("/v1/scenes", params={"limit": 1, "offset": k}, headers=A).json() for k in (0, 1)]
    assert [p["count"] for p in pages] == [before + 2] * 2
    assert [p["data"][0]["plan_id"] for p in pages] == [second["id"], first["id"]]  # newest first
    for page in pages:
        scene = page["data"][0]
        assert [e["id"] for e in scene["estimates"]] == ids[scene["plan_id"]]  # in upload order
    other = client.get("/v1/scenes", params={"limit": 100}, headers=B).json()["data"]
    assert not {s["plan_id"] for s in other} & set(ids)


def test_other_requests_are_served_while_the_models_run(client, frame, monkeypatch):
    est = client.app.state.model_sets.default
    running, answered, seen = threading.Event(), threading.Event(), []
    real = est.estimate

    def slow(frames):
        running.set()
        seen.append(answered.wait(10))  # a model run on the event loop would hold /healthz until this times out
        return real(frames)

    monkeypatch.setattr(est, "estimate", slow)
    with ThreadPoolExecutor(1) as pool:
        posted = pool.submit(_post, client, _npy(frame))
        assert running.wait(10)
        assert client.get("/healthz").status_code == 200
        answered.set()
        assert posted.result().status_code == 201
    assert seen == [True]


def test_other_operator_cannot_see_or_delete(client, frame):
    eid = _post(client, _npy(frame)).json()["id"]
    assert client.get(f"/v1/estimates/{eid}", headers=B).status_code == 404
    assert client.get(f"/v1/estimates/{eid}/enhanced.png", headers=B).status_code == 404
    assert client.delete(f"/v1/estimates/{eid}", headers=B).status_code == 404
    assert client.get(f"/v1/estimates/{eid}", headers=A).status_code == 200
    assert client.delete(f"/v1/estimates/{eid}", headers=A).status_code == 204
    assert client.get(f"/v1/estimates/{eid}", headers=A).status_code == 404


def _bomb():
    import zipfile

    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("x.npy", b"\x00" * (80 * 1024 * 1024))
    return buf.getvalue()


def _tiff32():
    buf = io.BytesIO()
    Image.fromarray(np.zeros((64, 64), np.float32)).save(buf, format="TIFF")
    return buf.getvalue()


BAD = [
    (b"hello, not an image", "f.bin", "unknown format"),
    (b"", "f.npy", "empty"),
    (_npy(np.zeros((64, 64, 2))), "f.npy", "2-D"),
    (_npy(np.full((64, 64), np.nan)), "f.npy", "NaN"),
    (_npy(np.full((64, 64), np.inf)), "f.npy", "NaN or infinite"),
    (_npy(np.random.default_rng(2).random((32, 32)) + 0.1), "f.npy", "the models take 64x64"),
    (_npy(np.array(["a"] * 4).reshape(2, 2)), "f.npy", "dtype"),
    (
        b"\x93NUMPY\x01\x00{'descr': '<f8', 'fortran_order': False, 'shape': (999999, 999999), }" + b" " * 10 + b"\n",
        "f.npy",
        "not a readable",
    ),
    (b"\x89PNG\r\n\x1a\n" + b"\x00" * 40, "f.png", "not a readable PNG"),
    (_bomb(), "f.npz", "unpacks to"),
    (_tiff32(), "f.tif", "8- or 16-bit"),
]


@pytest.mark.parametrize(("data", "name", "message"), BAD)
def test_bad_uploads_are_4xx_and_store_nothing(client, settings, data, name, message):
    before = _count(settings)
    r = _post(client, data, name=name)
    assert r.status_code == 422, r.text
    assert message in r.json()["detail"][0]["msg"]
    assert _count(settings) == before


def test_unknown_plan_and_oversize(client, settings, frame):
    before = _count(settings)
    r = _post(client, _npy(frame), plan_id="no-such-plan", observed_at="2022-12-04T11:28:36Z")
    assert r.status_code == 422 and "no plan" in r.json()["detail"][0]["msg"]
    big = _npy(np.zeros((1100, 1100)))  # 9.7 MB, over the 8 MB default
    r = _post(client, big)
    assert r.status_code == 413
    assert _count(settings) == before


def test_resample_on_request(client):
    r = _post(client, _npy(np.random.default_rng(0).random((100, 80))), resample="true")
    assert r.status_code == 201, r.text


def test_already_normalised_frames_are_taken_as_sent(client, settings, frame):
    """A data set's frames are stored normalised; normalising them again would feed the models another image."""
    norm = normalise_frame(np.abs(frame))
    raw = _post(client, _npy(frame)).json()
    (up,) = decode(_npy(norm), "n.npy", allow_stack=False)
    assert np.abs(prepare(up, 64, False) - norm).max() > 0.1  # normalised twice: another image
    np.testing.assert_array_equal(prepare(up, 64, False, normalised=True), norm)
    sent = _post(client, _npy(norm.astype(np.float16)), normalised="true")
    assert sent.status_code == 201, sent.text
    body = sent.json()
    assert body["input_normalised"] is True and raw["input_normalised"] is False
    np.testing.assert_allclose(body["attitude"]["euler_zyx_deg"], raw["attitude"]["euler_zyx_deg"], atol=0.05)
    assert client.get(f"/v1/estimates/{body['id']}", headers=A).json()["input_normalised"] is True
    # Values outside [0, 1] cannot be a normalised frame: 422, nothing stored.
    before = _count(settings)
    r = _post(client, _npy(np.abs(frame)), normalised="true")
    assert r.status_code == 422 and "normalised=true needs values in [0, 1]" in r.json()["detail"][0]["msg"]
    mag = np.abs(frame)
    r = _post(client, _npy(mag / mag.max()), normalised="true")  # in [0, 1], but raw: one pixel at 1.0
    assert r.status_code == 422 and "this is a raw frame" in r.json()["detail"][0]["msg"]
    assert _count(settings) == before
    batch = client.post(
        "/v1/estimates/batch",
        files=[("files", ("s.npy", _npy(np.stack([norm, norm]))))],
        data={"normalised": "true"},
        headers=A,
    )
    assert batch.status_code == 201, batch.text
    assert all(e["input_normalised"] for e in batch.json()["data"])


def test_sixteen_concurrent_clients_lose_nothing(client, settings, frame):
    before = _count(settings)
    data = _npy(frame)
    lock = threading.Lock()
    ids = []

    def one(_):
        r = _post(client, data)
        with lock:
            ids.append((r.status_code, r.json().get("id")))

    with ThreadPoolExecutor(16) as pool:
        list(pool.map(one, range(16)))
    assert all(code == 201 for code, _ in ids)
    assert len({i for _, i in ids}) == 16 and _count(settings) == before + 16


def test_service_refuses_to_start_on_a_corrupt_model(settings, tmp_path):
    import shutil

    bad = tmp_path / "models"
    shutil.copytree(settings.model_dir, bad)
    (bad / "unetpp.onnx").write_bytes(b"truncated")
    with pytest.raises(ModelFileError, match="unetpp.onnx"):
        create_app(settings.model_copy(update={"model_dir": bad}))
    assert TestClient  # the factory raised before any request could be served


def test_every_answer_is_fitted_and_checked(client, frame):
    body = _post(client, _npy(frame)).json()
    assert body["refined"] is True and body["target"] == "tiangong-like"
    assert body["attitude_network"] is not None and len(body["attitude_network"]["euler_zyx_deg"]) == 3
    q = body["quality"]
    assert 0.0 <= q["silhouette_iou"] <= 1.0 and len(q["uncertainty_deg"]) == 3
    assert isinstance(q["trusted"], bool) and (q["trusted"] == (q["reasons"] == []))
    assert isinstance(body["alternatives"], list) and "fit" in body["timings_s"]
    # The smoke models' one-epoch Swin is far off, and the check says so.
    assert q["trusted"] is False
    stored = client.get(body["links"]["self"], headers=A).json()
    assert stored["quality"] == q and stored["attitude"] == body["attitude"]


def test_refine_false_answers_swin_alone(client, frame):
    body = _post(client, _npy(frame), refine="false").json()
    assert body["refined"] is False
    assert body["attitude"]["euler_zyx_deg"] == body["attitude_network"]["euler_zyx_deg"]
    assert body["quality"]["uncertainty_deg"] and body["alternatives"] == []


def test_another_target_is_fitted_from_the_library(client, frame):
    assert set(client.get("/readyz").json()["targets"]) >= {"tiangong-like", "comsat-like"}
    body = _post(client, _npy(frame), target="comsat-like").json()
    assert body["target"] == "comsat-like" and body["attitude_network"] is None and body["refined"] is True
    # The smoke models carry no calibration: every answer says its bounds are defaults.
    assert any("not calibrated for these models" in r for r in body["quality"]["reasons"])


def test_cells_in_metres_resample_about_the_centre(client):
    """A frame of twice the models' cells, resampled in metres, shows the target at the models' scale."""
    from app.services.uploads import resample_metres

    coarse = type(SMOKE_RADAR)(
        n_range=32, n_azimuth=32, bandwidth_hz=SMOKE_RADAR.bandwidth_hz / 2, aperture_deg=SMOKE_RADAR.aperture_deg / 2
    )
    model = tiangong_like()
    a = simulate(model, Imager(coarse), (20.0, 10.0, -15.0), None, 0).label.astype(float)
    b = simulate(model, Imager(SMOKE_RADAR), (20.0, 10.0, -15.0), None, 0).label
    cells = (coarse.range_cell_m, coarse.cross_range_cell_m)
    model_cells = (SMOKE_RADAR.range_cell_m, SMOKE_RADAR.cross_range_cell_m)
    out = resample_metres(a, cells, model_cells, 64) > 0.5
    assert np.count_nonzero(out & b) / np.count_nonzero(out | b) > 0.75
    r = _post(
        client,
        _npy(simulate(model, Imager(coarse), (20.0, 10.0, -15.0), 10.0, 0).image),
        range_cell_m=str(cells[0]),
        cross_range_cell_m=str(cells[1]),
    )
    assert r.status_code == 201, r.text


def test_a_gsa_simulate_shard_is_read_as_it_is(client, tmp_path):
    """A shard's frames, not its labels and truths, each taken as the normalised frame the file says it is."""
    from inference.simulation.dataset import DatasetSpec, generate

    generate(DatasetSpec(n=3, seed=11, shard_size=3), tmp_path / "set", SMOKE_RADAR, workers=1, progress=False)
    data = (tmp_path / "set" / "shard-00000.npz").read_bytes()
    frames = decode(data, "shard-00000.npz")
    assert len(frames) == 3 and all(f.normalised for f in frames)
    assert [f.shape for f in frames] == [(SMOKE_RADAR.n_range, SMOKE_RADAR.n_azimuth)] * 3
    # Taken as sent: a frame normalised twice would change (its top 0.5 % are clipped to 1 again).
    np.testing.assert_array_equal(
        prepare(frames[0], SMOKE_RADAR.n_range, False), frames[0].magnitude.astype(np.float32)
    )
    r = client.post("/v1/estimates/batch", files=[("files", ("shard-00000.npz", data))], headers=A)
    assert r.status_code == 201, r.text
    assert r.json()["count"] == 3 and all(e["input_normalised"] for e in r.json()["data"])


def test_the_fitted_outline_is_the_edge_of_the_projection(client, frame):
    r = client.post("/v1/estimates", files={"file": ("f.npy", _npy(frame))}, headers=A)
    assert r.status_code == 201, r.text
    eid = r.json()["id"]
    png = client.get(f"/v1/estimates/{eid}/outline.png", headers=A)
    assert png.status_code == 200 and png.headers["content-type"] == "image/png"
    edge = np.asarray(Image.open(io.BytesIO(png.content)))
    assert edge.shape == (SMOKE_RADAR.n_range, SMOKE_RADAR.n_azimuth) and set(np.unique(edge)) <= {0, 255}
    assert 0 < (edge == 255).sum() < edge.size // 4  # a boundary, not a filled shape
    assert client.get(f"/v1/estimates/{eid}/outline.png", headers={"X-API-Key": KEY_B}).status_code == 404
    # A set without a reflectivity map has no map views, and says how to make one.
    for view in ("map", "residual"):
        r = client.get(f"/v1/estimates/{eid}/{view}.png", headers=A)
        assert r.status_code == 404 and "map-only" in r.json()["detail"]
    original = client.get(f"/v1/estimates/{eid}/original.png", headers=A).content
    from app.services.images import png_frame

    assert np.array_equal(png_frame(original), np.asarray(Image.open(io.BytesIO(original)), float) / 255.0)


def test_an_estimate_s_attitude_leaves_as_a_ccsds_apm(client, frame):
    """GET /v1/estimates/{id}/export/apm: ADM 2.0's APM, KVN (QUAT_START..QUAT_STOP, as the standard lays it out)
    and XML (read back by ccsds-ndm); scipy's rotation of (Q1, Q2, Q3, QC) is the estimate's body-to-GCRF matrix,
    and EPOCH its observation time. Without an inertial attitude it is a 409 saying how to get one."""
    from ccsds_ndm.ndm_io import NdmIo
    from scipy.spatial.transform import Rotation

    plan = client.post("/v1/plans", json=PAPER_EXAMPLE, headers=A).json()
    when = plan["chosen"]["t_access"]
    body = _post(client, _npy(frame), plan_id=plan["id"], observed_at=when).json()
    kvn = client.get(f"/v1/estimates/{body['id']}/export/apm", headers=A)
    assert kvn.status_code == 200 and kvn.headers["content-type"].startswith("text/plain")
    text = kvn.text
    assert text.startswith("CCSDS_APM_VERS = 2.0") and "REF_FRAME_A    = GCRF" in text
    block = text[text.index("QUAT_START") : text.index("QUAT_STOP")]
    q = {k.strip(): float(v) for k, v in (ln.split("=") for ln in block.splitlines()[1:] if "=" in ln and ln[0] == "Q")}
    expected = np.array(body["attitude_j2000"]["rotation_matrix"])
    np.testing.assert_allclose(
        Rotation.from_quat([q["Q1"], q["Q2"], q["Q3"], q["QC"]]).as_matrix(), expected, atol=1e-9
    )
    epoch = next(ln.split("=", 1)[1].strip() for ln in text.splitlines() if ln.startswith("EPOCH"))
    assert datetime.fromisoformat(epoch + "+00:00") == datetime.fromisoformat(when.replace("Z", "+00:00"))
    xml = client.get(f"/v1/estimates/{body['id']}/export/apm", params={"format": "xml"}, headers=A)
    assert xml.status_code == 200 and xml.headers["content-type"].startswith("application/xml")
    read = NdmIo().from_string(xml.text)
    state = read.body.segment.data.quaternion_state[0]
    back = [state.quaternion.q1, state.quaternion.q2, state.quaternion.q3, state.quaternion.qc]
    np.testing.assert_allclose(Rotation.from_quat(back).as_matrix(), expected, atol=1e-9)
    assert (state.ref_frame_a, state.ref_frame_b) == ("GCRF", "SC_BODY_1")
    plain = _post(client, _npy(frame)).json()  # no plan, no time: no inertial attitude
    refused = client.get(f"/v1/estimates/{plain['id']}/export/apm", headers=A)
    assert refused.status_code == 409 and "plan_id and observed_at" in refused.json()["detail"]
    assert client.get(f"/v1/estimates/{body['id']}/export/apm", headers=B).status_code == 404
    bad = client.get(f"/v1/estimates/{body['id']}/export/apm", params={"format": "json"}, headers=A)
    assert bad.status_code == 422
