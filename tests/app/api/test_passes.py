"""POST /v1/passes: a pass's frames fitted, placed in the plan target's LVLH frame at their times, fused, stored."""

import io
from datetime import datetime, timedelta

import numpy as np
import pytest
from sqlalchemy import create_engine, func, select

from app.db.models import Pass
from app.schemas import PAPER_EXAMPLE
from inference.isar import Imager, simulate
from inference.targets import tiangong_like
from tests.conftest import KEY_A, KEY_B
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


def _post(client, plan_id, times, data=None, headers=A):
    return client.post("/v1/passes", files=[("files", ("pass.npz", data or _stack(len(times))))],
                       data={"plan_id": plan_id, "observed_at": times}, headers=headers)  # fmt: skip


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
    assert len(body["uncertainty_deg"]) == 3 and isinstance(body["stable"], bool) and body["stability"]
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


@pytest.mark.parametrize(
    ("case", "field"),
    [("one_frame", "files"), ("times_missing", "observed_at"), ("time_outside_windows", "observed_at"),
     ("unknown_plan", "plan_id"), ("time_not_a_date", "observed_at")],
)  # fmt: skip
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
    else:
        r = _post(client, plan["id"], [*times[:3], "tuesday"])
    assert r.status_code == 422, r.text
    assert field in str(r.json()["detail"][0]["loc"])
    assert _count(settings) == before
