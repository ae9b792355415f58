"""POST /v1/passes: a pass's frames fitted, placed in the plan target's LVLH frame at their times, fused, stored."""

import io
from datetime import datetime, timedelta

import numpy as np
import pytest
from sqlalchemy import create_engine, func, select

from app.db.models import Pass
from app.schemas import PAPER_EXAMPLE
from app.services.scenes import scene_for, windows_of
from inference.simulation.radar import Imager
from inference.simulation.scene import simulate
from inference.simulation.targets import tiangong_like
from scene import choose_window
from scene.simulation import PassOptions, render_pass, simulate_pass
from tests.conftest import KEY_A, KEY_B, SQLITE_ONLY
from tests.utils.models import SMOKE_RADAR

A = {"X-API-Key": KEY_A}


def _stack(n=4):
    frames = [
        np.abs(simulate(tiangong_like(), Imager(SMOKE_RADAR), (10.0 + k, -5.0, 20.0), 10.0, k).image) for k in range(n)
    ]
    buf = io.BytesIO()
    np.savez(buf, frames=np.stack(frames))
    return buf.getvalue()


@pytest.fixture(scope="module")
def plan(client):
    return client.post("/v1/plans", json=PAPER_EXAMPLE, headers=A).json()


def _times(plan, n=4):
    w = plan["access_windows"][0]
    rise, end = datetime.fromisoformat(w["rise"]), datetime.fromisoformat(w["set"])
    return [(rise + (end - rise) * (k + 1) / (n + 1)).isoformat() for k in range(n)]


def _post(client, plan_id, times, data=None, headers=A, form=None):
    return client.post(
        "/v1/passes",
        files=[("files", ("pass.npz", data or _stack(len(times))))],
        data={"plan_id": plan_id, "observed_at": times, **(form or {})},
        headers=headers,
    )


def _count(settings):
    engine = create_engine(settings.database_url)
    with engine.connect() as conn:
        n = conn.scalar(select(func.count()).select_from(Pass))
    engine.dispose()
    return n


def test_a_pass_is_fused_and_stored(client, plan):
    times = _times(plan)
    r = _post(client, plan["id"], times)
    assert r.status_code == 201, r.text
    body = r.json()
    assert len(body["frames"]) == 4 and body["used"] + body["rejected"] == 4
    rot = np.array(body["attitude_lvlh"]["rotation_matrix"])
    np.testing.assert_allclose(rot @ rot.T, np.eye(3), atol=1e-9)
    assert len(body["uncertainty_deg"]) == 3 and body["stability"]
    # stable is a verdict only where enough trusted frames agree; otherwise it is null (undecided)
    assert isinstance(body["stable"], bool) if body["trusted"] else body["stable"] is None
    for f in body["frames"]:
        assert f["branch"] in ("answer", "near-mirror") or f["branch"].startswith("alternative")
        assert f["used"] == (f["rejected_because"] is None)
    # Each used frame's LVLH branch is within its residual of the fused attitude.
    for f in body["frames"]:
        r_k = np.array(f["attitude_lvlh"]["rotation_matrix"])
        angle = np.degrees(np.arccos(np.clip((np.trace(rot.T @ r_k) - 1) / 2, -1, 1)))
        assert angle == pytest.approx(f["residual_deg"], abs=1e-3)
    again = client.get(f"/v1/passes/{body['id']}", headers=A)
    assert again.status_code == 200 and again.json()["attitude_lvlh"] == body["attitude_lvlh"]
    assert client.get(f"/v1/passes/{body['id']}", headers={"X-API-Key": KEY_B}).status_code == 404
    # Found again in the listing, by plan too; never in another operator's.
    listing = client.get("/v1/passes", params={"plan_id": plan["id"]}, headers=A).json()
    row = next(p for p in listing["data"] if p["id"] == body["id"])
    assert row["frames"] == 4 and row["used"] == body["used"] and row["plan_id"] == plan["id"]
    assert listing["count"] >= 1
    assert client.get("/v1/passes", params={"plan_id": "no-such-plan"}, headers=A).json()["count"] == 0
    assert body["id"] not in client.get("/v1/passes", headers={"X-API-Key": KEY_B}).text
    # The plan links its passes; an estimate of the plan observed within the pass's frames names it, one
    # observed in another window of the plan does not.
    assert body["id"] in client.get(f"/v1/plans/{plan['id']}", headers=A).json()["pass_ids"]
    frame = io.BytesIO()
    np.save(frame, np.load(io.BytesIO(_stack(1)))["frames"][0])
    other = plan["access_windows"][1]
    ids = []
    for moment in (times[1], other["culmination"]):
        e = client.post(
            "/v1/estimates",
            files={"file": ("f.npy", frame.getvalue())},
            data={"plan_id": plan["id"], "observed_at": moment},
            headers=A,
        )
        assert e.status_code == 201, e.text
        ids.append(e.json()["id"])
    inside, outside = (client.get(f"/v1/estimates/{i}", headers=A).json()["pass_ids"] for i in ids)
    assert body["id"] in inside and body["id"] not in outside


@SQLITE_ONLY
def test_a_pass_sent_asynchronously_is_a_job_whose_pass_is_the_synchronous_one(client, plan):
    """``Prefer: respond-async``: 202 and a job; the worker process fuses the same frames to the same attitude
    as the synchronous request (every frame's too), stored and linked from the job; a bad one is a 422 now."""
    import time

    times = _times(plan, 5)
    data = _stack(5)
    sync = _post(client, plan["id"], times, data=data).json()
    r = client.post(
        "/v1/passes",
        files=[("files", ("pass.npz", data))],
        data={"plan_id": plan["id"], "observed_at": times},
        headers={**A, "Prefer": "respond-async"},
    )
    assert r.status_code == 202 and r.json()["kind"] == "pass" and r.json()["total"] == 5, r.text
    deadline = time.monotonic() + 180
    while (job := client.get(f"/v1/jobs/{r.json()['id']}", headers=A).json())["state"] in ("queued", "running"):
        assert time.monotonic() < deadline, job
        time.sleep(0.3)
    assert job["state"] == "done", job
    assert job["result_url"] == f"/v1/passes/{job['result']['pass_id']}"
    fused = client.get(job["result_url"], headers=A).json()
    # The job's frames wait on disk in float32 (half of float64's bytes, issue 74): the fused matrix moves ~1e-8.
    np.testing.assert_allclose(
        fused["attitude_lvlh"]["rotation_matrix"], sync["attitude_lvlh"]["rotation_matrix"], atol=1e-6
    )
    assert [f["used"] for f in fused["frames"]] == [f["used"] for f in sync["frames"]]
    assert fused["id"] in client.get(f"/v1/plans/{plan['id']}", headers=A).json()["pass_ids"]
    bad = client.post(
        "/v1/passes",
        files=[("files", ("pass.npz", data))],
        data={"plan_id": plan["id"], "observed_at": times[:4]},
        headers={**A, "Prefer": "respond-async"},
    )
    assert bad.status_code == 422 and bad.json()["detail"][0]["loc"][-1] == "observed_at"


@pytest.mark.parametrize(
    ("case", "field"),
    [
        ("one_frame", "files"),
        ("times_missing", "observed_at"),
        ("time_outside_windows", "observed_at"),
        ("unknown_plan", "plan_id"),
        ("time_not_a_date", "observed_at"),
        ("integration_count", "integration_s"),
        ("integration_not_positive", "integration_s"),
        ("integration_1e-300", "integration_s"),
        ("aperture_without_integration", "integration_s"),
        ("cells_without_aperture", "aperture_deg"),
        ("aperture_too_wide", "aperture_deg"),
    ],
)
def test_bad_passes_are_422_and_store_nothing(client, settings, plan, case, field):
    before = _count(settings)
    times = _times(plan)
    if case == "one_frame":
        r = _post(client, plan["id"], times[:1])
    elif case == "times_missing":
        r = _post(client, plan["id"], times[:3], data=_stack(4))
    elif case == "time_outside_windows":
        late = (datetime.fromisoformat(plan["access_windows"][0]["set"]) + timedelta(minutes=3)).isoformat()
        r = _post(client, plan["id"], [*times[:3], late])
    elif case == "unknown_plan":
        r = _post(client, "0" * 36, times)
    elif case == "integration_count":
        r = _post(client, plan["id"], times, form={"integration_s": ["10", "10", "10"]})
    elif case == "integration_not_positive":
        r = _post(client, plan["id"], times, form={"integration_s": ["10", "10", "-1", "10"]})
    elif case == "integration_1e-300":  # was stored as a sweep of 5.1e300 deg/s (issue 46)
        r = _post(client, plan["id"], times, form={"integration_s": ["10", "10", "1e-300", "10"]})
        assert "deg/s" in r.json()["detail"][0]["msg"]
    elif case == "aperture_without_integration":
        r = _post(client, plan["id"], times, form={"aperture_deg": "5.1"})
    elif case == "cells_without_aperture":  # the frames' own radar: its aperture is not the models'
        cells = {"range_cell_m": "0.1", "cross_range_cell_m": "0.1"}
        r = _post(client, plan["id"], times, form={"integration_s": ["10"] * 4, **cells})
    elif case == "aperture_too_wide":
        r = _post(client, plan["id"], times, form={"integration_s": ["10"] * 4, "aperture_deg": "40"})
    else:
        r = _post(client, plan["id"], [*times[:3], "tuesday"])
    assert r.status_code == 422, r.text
    assert field in str(r.json()["detail"][0]["loc"])
    assert _count(settings) == before


def test_a_simulated_pass_goes_in_as_it_is(client, plan):
    """gsa simulate --pass's frames.npz and times, uploaded as they are (normalised), fuse over the stored plan."""
    opts = PassOptions(aperture_deg=SMOKE_RADAR.aperture_deg, max_frames=6, seed=3)
    rng = np.random.default_rng(3)
    _, window = choose_window(windows_of(plan), None)
    meta = simulate_pass(scene_for(PAPER_EXAMPLE, window.rise, window.set), opts, rng)
    images, _ = render_pass(meta, opts, rng, SMOKE_RADAR)
    buf = io.BytesIO()
    np.savez(buf, image=images)
    times = [f.observed_at.isoformat() for f in meta]
    integration = [f.integration_s for f in meta]
    r = client.post(
        "/v1/passes",
        files=[("files", ("frames.npz", buf.getvalue()))],
        data={
            "plan_id": plan["id"],
            "observed_at": times,
            "normalised": "true",
            "integration_s": [str(t) for t in integration],
            "aperture_deg": str(opts.aperture_deg),
        },
        headers=A,
    )
    assert r.status_code == 201, r.text
    body = r.json()
    assert len(body["frames"]) == len(meta) and body["attitude_j2000"]["at"]
    # The measured sweep is the aperture over the integration time; a still target's is the line of sight's own
    # rate, which the simulator found by sweeping the line of sight through the body numerically.
    for f, t in zip(body["frames"], integration, strict=True):
        assert f["sweep_deg_s"] == pytest.approx(opts.aperture_deg / t, rel=1e-4)
        if body["stable"] is not False:
            assert abs(f["sweep_model_deg_s"] - f["sweep_deg_s"]) < 3.0 * f["sweep_sigma_deg_s"]
        assert 0.02 * f["sweep_deg_s"] <= f["sweep_sigma_deg_s"] + 1e-5  # rounded to 5 decimals
    # The smoke models' frames are not trusted: no turning model is fitted to them, and no verdict is given.
    trusted = sum(1 for f in body["frames"] if f["quality"]["trusted"])
    assert (body["turning_chi2"] is None) == (trusted < 4)
    assert body["trusted"] or body["stable"] is None
    stored = client.get(f"/v1/passes/{body['id']}", headers=A).json()
    assert (stored["turning_chi2"], stored["stable"]) == (body["turning_chi2"], body["stable"])
    assert "alternative_lvlh" in body and stored["alternative_lvlh"] == body["alternative_lvlh"]
    # A still, trusted pass is fitted to its frames' silhouettes at once; an undecided one is not.
    assert body["common_fit"] is None or body["stable"] is True
    assert stored["common_fit"] == body["common_fit"]
    assert [f["sweep_deg_s"] for f in stored["frames"]] == [f["sweep_deg_s"] for f in body["frames"]]


def test_an_unknown_form_field_is_refused_by_name(client, plan, settings):
    """A misspelt field (planid for plan_id) must not be ignored: 422 naming it, nothing stored."""
    before = _count(settings)
    r = client.post(
        "/v1/passes",
        files=[("files", ("pass.npz", _stack(2)))],
        data={"plan_id": plan["id"], "observed_at": _times(plan, 2), "planid": "x"},
        headers=A,
    )
    assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body", "planid"], r.text
    assert "plan_id" in r.json()["detail"][0]["msg"]
    assert _count(settings) == before
    one = client.post("/v1/estimates", files={"file": ("f.npz", _stack(1))}, data={"obsreved_at": "x"}, headers=A)
    assert one.status_code == 422 and one.json()["detail"][0]["loc"] == ["body", "obsreved_at"]


def test_gsa_pass_sends_a_simulated_pass_to_the_service(client, plan, tmp_path, monkeypatch, capsys):
    """gsa pass DIR --server: the frames and each frame's time go up as the route takes them (repeated fields)."""
    import json

    import httpx

    from app.cli import main
    from app.services.passes import pass_record

    opts = PassOptions(aperture_deg=SMOKE_RADAR.aperture_deg, max_frames=4, seed=5)
    rng = np.random.default_rng(5)
    index, window = choose_window(windows_of(plan), None)
    meta = simulate_pass(scene_for(PAPER_EXAMPLE, window.rise, window.set), opts, rng)
    images, snrs = render_pass(meta, opts, rng, SMOKE_RADAR)
    np.savez(tmp_path / "frames.npz", image=images.astype(np.float32))
    cells = (SMOKE_RADAR.range_cell_m, SMOKE_RADAR.cross_range_cell_m)
    record = pass_record(meta, snrs, opts, 0, plan["access_windows"][index], PAPER_EXAMPLE, cells)
    (tmp_path / "pass.json").write_text(json.dumps(record))

    def request(method, url, **kwargs):  # the service in-process, reached the way httpx reaches a real one
        kwargs.pop("timeout", None)
        return client.request(method, url.replace("http://gsa.test", ""), **kwargs)

    monkeypatch.setattr(httpx, "request", request)
    rc = main(["pass", str(tmp_path), "--server", "http://gsa.test", "--api-key", KEY_A, "--plan-id", plan["id"]])
    out, err = capsys.readouterr()
    assert rc == 0, out
    assert out.startswith("pass ") and "fused, body to LVLH" in out
    assert "queued as job" in err and "done" in err.splitlines()[-1], err  # a job, followed with its progress


def test_a_pass_is_placed_from_one_scene(client, plan, monkeypatch):
    """One validation of the stored plan and one propagation of its target place a whole pass: every frame, the
    sweeps' neighbours half an integration away, and both fusions (before: up to five and four)."""
    import scene.geometry
    from app.schemas import PlanCreate

    counts = {"validations": 0, "propagations": 0}
    validate, propagate = PlanCreate.model_validate.__func__, scene.geometry.trajectory

    def counting_validate(cls, *args, **kwargs):
        counts["validations"] += 1
        return validate(cls, *args, **kwargs)

    def counting_trajectory(*args, **kwargs):
        counts["propagations"] += 1
        return propagate(*args, **kwargs)

    monkeypatch.setattr(PlanCreate, "model_validate", classmethod(counting_validate))
    monkeypatch.setattr(scene.geometry, "trajectory", counting_trajectory)
    times = _times(plan, 4)
    r = _post(client, plan["id"], times, form={"integration_s": ["20"] * 4, "aperture_deg": "2"})
    assert r.status_code == 201, r.text
    assert counts == {"validations": 1, "propagations": 1}
    # A batch of frames tied to the plan at one moment: placed once for all of them.
    counts.update(validations=0, propagations=0)
    r = client.post(
        "/v1/estimates/batch",
        files=[("files", ("b.npz", _stack(3)))],
        data={"plan_id": plan["id"], "observed_at": times[0]},
        headers=A,
    )
    assert r.status_code == 201, r.text
    assert counts == {"validations": 1, "propagations": 1}
    assert all(e["attitude_lvlh"] is not None for e in r.json()["data"])


def test_rows_stored_in_the_first_format_read_as_they_did(client, settings, plan):
    """Rows written before results carried a format version (times with +00:00, no ``format``, an estimate without
    ``refined``) are answered through the same models as new ones."""
    from sqlalchemy import update
    from sqlalchemy.orm import Session

    from app.db.models import Estimate
    from app.db.models import Plan as PlanRow

    times = _times(plan)
    fresh = _post(client, plan["id"], times).json()
    frame = io.BytesIO()
    np.save(frame, np.load(io.BytesIO(_stack(1)))["frames"][0])
    est = client.post("/v1/estimates", files={"file": ("f.npy", frame.getvalue())}, headers=A).json()

    def first_format(value):
        if isinstance(value, dict):
            return {k: first_format(v) for k, v in value.items() if k != "format"}
        if isinstance(value, list):
            return [first_format(v) for v in value]
        if isinstance(value, str) and value.endswith("Z") and value[4:5] == "-" and value[10:11] == "T":
            return datetime.fromisoformat(value.replace("Z", "+00:00")).isoformat()
        return value

    engine = create_engine(settings.database_url)
    with Session(engine) as session:
        row = session.get(Pass, fresh["id"])
        old = first_format(row.result)
        assert "format" not in old and old["frames"][0]["observed_at"].endswith("+00:00")
        session.execute(update(Pass).where(Pass.id == fresh["id"]).values(result=old))
        e = session.get(Estimate, est["id"])
        old_estimate = {k: v for k, v in first_format(e.result).items() if k not in ("refined", "cells_m")}
        session.execute(update(Estimate).where(Estimate.id == est["id"]).values(result=old_estimate))
        p = session.get(PlanRow, plan["id"])
        session.execute(update(PlanRow).where(PlanRow.id == plan["id"]).values(result=first_format(p.result)))
        session.commit()
    engine.dispose()
    again = client.get(f"/v1/passes/{fresh['id']}", headers=A)
    assert again.status_code == 200 and again.json() == fresh
    old_est = client.get(f"/v1/estimates/{est['id']}", headers=A).json()
    assert old_est["refined"] is False  # the first format's rows were never fitted
    assert {k: v for k, v in old_est.items() if k != "refined"} == {k: v for k, v in est.items() if k != "refined"}
    got = client.get(f"/v1/plans/{plan['id']}", headers=A).json()
    assert got["access_windows"] == plan["access_windows"] and got["chosen"] == plan["chosen"]


def _rotation_angle_deg(a, b):
    return float(np.degrees(np.arccos(np.clip((np.trace(np.asarray(a).T @ np.asarray(b)) - 1.0) / 2.0, -1.0, 1.0))))


def test_a_pass_s_attitude_leaves_as_a_ccsds_aem(client, plan):
    """GET /v1/passes/{id}/export/aem: ADM 2.0's AEM, a quaternion a second from the first frame to the last.
    Read with scipy (scalar last): at the fusion's own moment it is the pass's attitude_j2000 (another code path:
    the fusion's LVLH at mid-pass), and a target still in LVLH turns in GCRF at the orbit's rate, |r x v| / r^2 of
    the paper's 700 x 600 km orbit (0.0615-0.0633 deg/s). XML is read back by ccsds-ndm; no plan is a 409."""
    from ccsds_ndm.ndm_io import NdmIo
    from scipy.spatial.transform import Rotation

    times = _times(plan, 5)
    body = _post(client, plan["id"], times, data=_stack(5)).json()
    r = client.get(f"/v1/passes/{body['id']}/export/aem", headers=A)
    assert r.status_code == 200 and r.text.startswith("CCSDS_AEM_VERS = 2.0"), r.text[:300]
    rows = r.text[r.text.index("DATA_START") + 10 : r.text.index("DATA_STOP")].split("\n")
    rows = [ln.split() for ln in rows if ln.strip()]
    when = [datetime.fromisoformat(x[0] + "+00:00") for x in rows]
    mats = [Rotation.from_quat([float(v) for v in x[1:5]]).as_matrix() for x in rows]
    first, last = (datetime.fromisoformat(t.replace("Z", "+00:00")) for t in (times[0], times[-1]))
    assert when[0] == first and when[-1] == last and len(rows) >= (last - first).total_seconds()
    at = datetime.fromisoformat(body["attitude_j2000"]["at"].replace("Z", "+00:00"))
    k = int(np.argmin([abs((t - at).total_seconds()) for t in when]))
    off = abs((when[k] - at).total_seconds())
    assert _rotation_angle_deg(mats[k], body["attitude_j2000"]["rotation_matrix"]) < 0.07 * off + 1e-3
    if body["stable"] is not False:
        rates = [_rotation_angle_deg(mats[j], mats[j + 1]) for j in range(len(mats) - 2)]  # 1 s apart
        assert 0.0612 < min(rates) and max(rates) < 0.0636, (min(rates), max(rates))
    xml = client.get(f"/v1/passes/{body['id']}/export/aem", params={"format": "xml"}, headers=A)
    segment = NdmIo().from_string(xml.text).body.segment[0]
    q0 = segment.data.attitude_state[0].quaternion_ephemeris.quaternion
    np.testing.assert_allclose(Rotation.from_quat([q0.q1, q0.q2, q0.q3, q0.qc]).as_matrix(), mats[0], atol=1e-9)
    assert (segment.metadata.ref_frame_a, segment.metadata.ref_frame_b) == ("GCRF", "SC_BODY_1")
    assert client.get(f"/v1/passes/{body['id']}/export/aem", headers={"X-API-Key": KEY_B}).status_code == 404
