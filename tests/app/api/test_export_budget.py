"""Exports under the plan budget: a plan without a burn is refused before any recomputing; for a plan made before
exports were stored with it, the recompute and the writing stop at GSA_PLAN_TIMEOUT_S (503, the documented answer),
and the writing itself obeys the stop."""

from __future__ import annotations

import copy

import pytest
from fastapi.testclient import TestClient

from app.main import create_app
from app.schemas import PAPER_EXAMPLE
from app.services import exports
from planner.errors import PlanningStopped
from tests.conftest import KEY_A

A = {"X-API-Key": KEY_A}


@pytest.fixture(scope="module")
def backend() -> str:
    """What this module tests does not depend on the database: SQLite alone (the suite's time is kept for the rest)."""
    return "sqlite"


@pytest.fixture(scope="module")
def plans(client):
    """A plan with a burn and one without (a station at the pole never sees a 43-deg orbit's target)."""
    with_burn = client.post("/v1/plans", json=PAPER_EXAMPLE, headers=A).json()
    polar = copy.deepcopy(PAPER_EXAMPLE)
    polar["ground_station"]["latitude_deg"] = 89.9
    without = client.post("/v1/plans", json=polar, headers=A).json()
    assert with_burn["phasing"] is not None and without["phasing"] is None
    return with_burn, without


@pytest.fixture(scope="module")
def tight(settings):
    """The same database, with a plan budget no recompute fits in."""
    with TestClient(create_app(settings.model_copy(update={"plan_timeout_s": 0.001}))) as c:
        yield c


@pytest.mark.parametrize("kind", ["opm", "oem", "czml"])
def test_a_plan_without_a_burn_is_refused_before_any_recompute(plans, tight, kind):
    """Under a budget no recompute fits in, the answer is still the 422 that names the missing burn (it was a 503
    after the budget ran out, or 10-15 s of work under the default budget)."""
    _, without = plans
    r = tight.get(f"/v1/plans/{without['id']}/export/{kind}", headers=A)
    assert r.status_code == 422, r.text
    assert "no phasing burn" in r.json()["detail"][0]["msg"]


@pytest.mark.parametrize("kind", ["opm", "oem", "czml", "geojson", "pointing.csv"])
def test_every_export_stops_at_the_plan_budget(plans, client, tight, kind):
    from sqlalchemy import delete

    from app.db.models import PlanExport

    with_burn, _ = plans
    with client.app.state.session_factory() as session:  # as a plan made before exports were stored
        session.execute(delete(PlanExport).where(PlanExport.plan_id == with_burn["id"]))
        session.commit()
    r = tight.get(f"/v1/plans/{with_burn['id']}/export/{kind}", headers=A)
    assert r.status_code == 503, r.text
    assert "GSA_PLAN_TIMEOUT_S" in r.json()["detail"]
    assert client.get(f"/v1/plans/{with_burn['id']}/export/{kind}", headers=A).status_code == 200


def test_writing_the_pointing_file_obeys_the_stop():
    from app.schemas import PlanCreate
    from app.services.planning import run_plan

    req = PlanCreate.model_validate(PAPER_EXAMPLE)
    plan, result = run_plan(req)
    windows = result.model_dump(mode="json")["access_windows"]
    assert len(windows) > 2 * exports.POINTING_CHUNK
    asked = []

    def stop():
        asked.append(1)
        return "the client disconnected" if len(asked) > 2 else None

    with pytest.raises(PlanningStopped, match=f"pass {2 * exports.POINTING_CHUNK} of"):
        exports.pointing_csv(plan, windows, stop)
    assert len(asked) == 3
