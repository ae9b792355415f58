import copy
import math

import pytest
from sqlalchemy import create_engine, func, select, text

from app.db.models import Plan
from app.schemas import PAPER_EXAMPLE
from tests.conftest import KEY_A, KEY_B, SQLITE_ONLY
from tests.utils.bodies import with_value
from tests.utils.orbits import ISS_L1, ISS_L2

A = {"X-API-Key": KEY_A}
B = {"X-API-Key": KEY_B}


def _count(settings):
    engine = create_engine(settings.database_url)
    with engine.connect() as conn:
        n = conn.scalar(select(func.count()).select_from(Plan))
    engine.dispose()
    return n


@pytest.fixture(scope="module")
def paper_plan(client):
    r = client.post("/v1/plans", json=PAPER_EXAMPLE, headers=A)
    assert r.status_code == 201, r.text
    return r.json()


def test_healthz(client):
    r = client.get("/healthz")
    assert r.status_code == 200
    assert r.json() == {"status": "ok"}


def test_paper_example_is_accepted_and_stored(client, paper_plan):
    p = paper_plan
    assert p["target_name"] == "Sat_Target"
    assert len(p["access_windows"]) > 50
    assert (
        p["candidates"]
        and {"t_access", "delta_ha_km", "delta_hp_km", "miss_km", "feasibility"} <= p["candidates"][0].keys()
    )
    assert p["phasing"]["verification"]["miss_km"] < 1e-3
    assert p["chosen"]["miss_km"] < 0.1
    r = client.get(f"/v1/plans/{p['id']}", headers=A)
    assert r.status_code == 200
    assert r.json()["candidates"] == p["candidates"]


def test_other_operator_gets_404(client, paper_plan):
    r = client.get(f"/v1/plans/{paper_plan['id']}", headers=B)
    assert r.status_code == 404
    assert r.json()["detail"] == "Plan not found"
    r = client.get("/v1/plans", headers=B)
    assert r.status_code == 200
    assert all(item["id"] != paper_plan["id"] for item in r.json()["data"])


def test_list_paginates_and_filters(client, paper_plan):
    r = client.get("/v1/plans", params={"target_name": "Sat_Target", "limit": 1}, headers=A)
    assert r.status_code == 200
    body = r.json()
    assert body["count"] >= 1 and len(body["data"]) == 1
    assert body["data"][0]["target_name"] == "Sat_Target"
    assert body["data"][0]["created_at"].endswith(("Z", "+00:00"))  # times come back in UTC, stated
    # Each row says whether its chosen scene can be flown and what it costs (the paper's ten days: unlit, 168 m/s).
    row = next(
        p
        for p in client.get("/v1/plans", params={"limit": 100}, headers=A).json()["data"]
        if p["id"] == paper_plan["id"]
    )
    assert row["feasible"] is paper_plan["chosen"]["feasibility"]["feasible"] is False
    assert row["dv_total_m_s"] == pytest.approx(paper_plan["chosen"]["dv_total_m_s"])
    r = client.get("/v1/plans", params={"target_name": "nobody"}, headers=A)
    assert r.json() == {"data": [], "count": 0}
    r = client.get("/v1/plans", params={"created_after": "2100-01-01T00:00:00Z"}, headers=A)
    assert r.json()["count"] == 0


@pytest.mark.parametrize("headers", [{}, {"X-API-Key": "wrong"}])
def test_requires_a_valid_key(client, headers):
    r = client.post("/v1/plans", json=PAPER_EXAMPLE, headers=headers)
    assert r.status_code == 401
    assert client.get("/v1/plans", headers=headers).status_code == 401


def _with(path, value):
    return with_value(PAPER_EXAMPLE, path, value)


BAD = [
    (_with(["target", "elements", "hp_km"], 80), "hp_km"),
    (_with(["target", "elements", "ha_km"], 500), "ha_km"),
    (_with(["ground_station", "latitude_deg"], 91), "latitude_deg"),
    (_with(["ground_station", "longitude_deg"], -200), "longitude_deg"),
    (_with(["search"], {"duration_days": 31}), "duration_days"),
    (_with(["search"], {"dha_min_km": 10, "dha_max_km": -10}), "dha_min_km"),
    (_with(["search"], {"step_km": 0}), "step_km"),
    (_with(["target", "colour"], "red"), "colour"),
    (_with(["target", "tle"], [ISS_L1, ISS_L2[:-1] + "0"]), "tle"),
    (_with(["observer", "elements"], None), "observer"),
    (_with(["target", "name"], "a/b"), "name"),
    (_with(["observer_optics"], {"aperture_m": 0}), "aperture_m"),
    (_with(["observer_optics"], {"wavelength_nm": 50}), "wavelength_nm"),
    (_with(["observer_optics"], {"gsd_m": -0.25}), "gsd_m"),
    (_with(["observer_optics"], {"max_rate_deg_s": 0}), "max_rate_deg_s"),
    (_with(["observer_optics"], {"sun_exclusion_deg": 180}), "sun_exclusion_deg"),
    (_with(["observer_optics"], {"focal_length_m": 2}), "focal_length_m"),
]


@pytest.mark.parametrize(("body", "field"), BAD)
def test_bad_input_is_422_naming_the_field_and_stores_nothing(client, settings, body, field):
    body = copy.deepcopy(body)  # the same case runs on every backend
    if field == "tle":
        body["target"].pop("elements")
    before = _count(settings)
    r = client.post("/v1/plans", json=body, headers=A)
    assert r.status_code == 422, r.text
    assert field in r.text
    assert _count(settings) == before


def test_optics_out_of_range_are_named_where_they_were_given(client):
    """An optics field is a 422 at observer_optics.<field>; the search's older twin at its own place."""
    r = client.post("/v1/plans", json=_with(["observer_optics"], {"aperture_m": 0}), headers=A)
    assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body", "observer_optics", "aperture_m"]
    old = _with(["search"], {"max_phase_angle_deg": 181})
    r = client.post("/v1/plans", json=old, headers=A)
    assert r.status_code == 422 and "max_phase_angle_deg" in str(r.json()["detail"][0]["loc"])


def test_the_standoff_is_chosen_from_the_optics(client):
    """By default the observer is aimed where the optics both track the fly-by (relative speed / rate) and resolve
    the ground sample distance (g D / 1.22 lambda): a 0.6 m aperture allows it, a 0.1 m one does not, and says
    why with numbers; the search's older max_tracking_rate_deg_s is still read."""
    body = _with(["search"], {"duration_days": 8})
    big = client.post("/v1/plans", json={**body, "observer_optics": {"aperture_m": 0.6}}, headers=A).json()
    v = big["phasing"]["verification"]
    assert v["target_angular_rate_deg_s"] < 10.0 and v["separation_km"] < 223.6
    assert v["standoff_km"] == pytest.approx(v["relative_speed_km_s"] / math.radians(10.0) * 1.05, rel=0.01)
    small = client.post("/v1/plans", json={**body, "observer_optics": {"aperture_m": 0.1}}, headers=A).json()
    reasons = small["chosen"]["feasibility"]["reasons"]
    assert any(r.startswith("10 deg/s needs >= ") and "only within 37.3 km" in r for r in reasons), reasons
    older = client.post(
        "/v1/plans", json=_with(["search"], {"duration_days": 8, "max_tracking_rate_deg_s": 20}), headers=A
    ).json()
    w = older["phasing"]["verification"]
    assert w["standoff_km"] == pytest.approx(w["relative_speed_km_s"] / math.radians(20.0) * 1.05, rel=0.01)


def test_bad_checksum_message_says_which_line(client):
    body = copy.deepcopy(PAPER_EXAMPLE)
    body["target"] = {"name": "ISS", "tle": [ISS_L1, ISS_L2[:-1] + "0"]}
    r = client.post("/v1/plans", json=body, headers=A)
    assert r.status_code == 422
    assert "line 2 checksum" in r.json()["detail"][0]["msg"]


def test_tle_target_plan(client):
    body = copy.deepcopy(PAPER_EXAMPLE)
    body["target"] = {"name": "ISS", "tle": [ISS_L1, ISS_L2]}
    body["observer"]["elements"]["epoch"] = "2008-09-20T12:00:00Z"
    body["search"] = {"start": "2008-09-20T12:00:00Z", "duration_days": 3, "max_miss_km": 50}
    r = client.post("/v1/plans", json=body, headers=A)
    assert r.status_code == 201, r.text
    assert len(r.json()["access_windows"]) > 5


def test_access_windows_endpoint(client):
    body = {"target": PAPER_EXAMPLE["target"], "ground_station": PAPER_EXAMPLE["ground_station"], "duration_days": 1}
    r = client.post("/v1/access-windows", json=body, headers=A)
    assert r.status_code == 200, r.text
    w = r.json()["access_windows"]
    assert len(w) >= 4
    assert all(x["rise"] < x["culmination"] < x["set"] for x in w)


def test_openapi_carries_the_paper_example(client):
    r = client.get("/openapi.json")
    assert r.status_code == 200
    assert "Sat_Target" in r.text


def test_sqlite_is_in_wal_mode(tmp_path):
    from app.core.db import make_engine, upgrade_database

    url = f"sqlite:///{tmp_path / 'gsa.db'}"
    upgrade_database(url)
    engine = make_engine(url)
    with engine.connect() as conn:
        assert conn.execute(text("PRAGMA journal_mode")).scalar() == "wal"
        assert conn.execute(text("PRAGMA busy_timeout")).scalar() == 30000
    engine.dispose()


def test_page_size_limit(client):
    r = client.get("/v1/plans", params={"limit": 5000}, headers=A)
    assert r.status_code == 422


@pytest.mark.parametrize("offset", ["+14:00", "-12:00", "+05:30", "Z"])
def test_time_filters_compare_instants_whatever_the_offset(client, paper_plan, offset):
    """created_after / created_before with any UTC offset mean the same instant (SQLite compared the text)."""
    from datetime import datetime, timedelta, timezone

    created = datetime.fromisoformat(paper_plan["created_at"].replace("Z", "+00:00"))
    hours, minutes = (0, 0) if offset == "Z" else (int(offset[:3]), int(offset[0] + offset[4:]))
    zone = timezone(timedelta(hours=hours, minutes=minutes))

    def stamp(moment):
        text = moment.astimezone(zone).isoformat(timespec="microseconds")
        return text.replace("+00:00", "Z") if offset == "Z" else text

    def ids(**params):
        r = client.get("/v1/plans", params={**params, "limit": 100}, headers=A)
        assert r.status_code == 200, r.text
        return {p["id"] for p in r.json()["data"]}

    second = timedelta(seconds=1)
    assert paper_plan["id"] in ids(created_after=stamp(created - second))
    assert paper_plan["id"] not in ids(created_after=stamp(created + second))
    assert paper_plan["id"] in ids(created_before=stamp(created + second))
    assert paper_plan["id"] not in ids(created_before=stamp(created - second))


def test_a_tle_far_from_the_span_is_noted_and_one_further_is_refused(client):
    """A TLE more than GSA_MAX_TLE_AGE_DAYS (30) from the span is noted; beyond GSA_MAX_EPOCH_GAP_DAYS (60),
    or osculating elements as far, the request is refused before any propagation, naming the field."""
    from tests.utils.orbits import ISS_L1, ISS_L2

    iss = {"name": "ISS", "tle": [ISS_L1, ISS_L2]}  # epoch 2008-09-20
    station = PAPER_EXAMPLE["ground_station"]
    body = {"target": iss, "ground_station": station, "start": "2008-10-30T00:00:00Z", "duration_days": 1}
    r = client.post("/v1/access-windows", json=body, headers=A)
    assert r.status_code == 200
    body["start"] = "2009-01-01T00:00:00Z"
    r = client.post("/v1/access-windows", json=body, headers=A)
    assert r.status_code == 422 and r.json()["detail"][0]["loc"][-2:] == ["target", "tle"]
    assert "GSA_MAX_EPOCH_GAP_DAYS" in r.text
    plan = copy.deepcopy(PAPER_EXAMPLE)
    plan["target"] = iss
    plan["search"] = {"start": "2008-10-25T00:00:00Z", "duration_days": 1}
    r = client.post("/v1/plans", json=plan, headers=A)
    assert r.status_code == 422 and r.json()["detail"][0]["loc"][-3:] == ["observer", "elements", "epoch"]
    plan["observer"] = copy.deepcopy(plan["observer"])
    plan["observer"]["elements"]["epoch"] = "2008-10-25T00:00:00Z"
    r = client.post("/v1/plans", json=plan, headers=A)
    assert r.status_code == 201, r.text
    assert any("TLE's epoch 2008-09-20" in n and "fresher TLE" in n for n in r.json()["notes"])


def test_target_and_observer_in_one_plane_are_refused(client):
    """Target and observer on the same orbit: no line of nodes, so a 422 saying so instead of a 10,000-km 'plan'."""
    plan = copy.deepcopy(PAPER_EXAMPLE)
    plan["observer"] = copy.deepcopy(plan["target"])
    plan["observer"]["name"] = "twin"
    plan["search"] = {"duration_days": 1}
    r = client.post("/v1/plans", json=plan, headers=A)
    assert r.status_code == 422, r.text
    assert r.json()["detail"][0]["loc"][-1] == "observer" and "line of nodes" in r.text


def test_the_openapi_document_says_what_the_service_enforces(client, settings):
    """limit's maximum is the operator's page size; an orbit is oneOf elements / tle; and a request without a
    key is 401 before any parameter is judged (an unknown query parameter included)."""
    spec = client.get("/openapi.json").json()
    limits = [
        s["maximum"]
        for ops in spec["paths"].values()
        for op in ops.values()
        for p in op.get("parameters", [])
        if p["name"] == "limit"
        for s in (p["schema"], *p["schema"].get("anyOf", []))
        if s.get("type") == "integer"
    ]
    assert len(limits) >= 3 and set(limits) == {settings.max_page_size}
    r = client.get("/v1/plans", params={"limit": settings.max_page_size + 1}, headers=A)
    assert r.status_code == 422
    orbit = spec["components"]["schemas"]["OrbitIn"]
    sources = ("elements", "tle", "omm", "omm_xml", "omm_csv", "omm_kvn", "opm", "oem")
    assert orbit["oneOf"] == [{"required": [k]} for k in sources]
    assert client.get("/v1/plans", params={"colour": "red"}).status_code == 401
    assert client.get("/v1/plans", params={"colour": "red"}, headers=A).status_code == 422


def test_a_plan_over_its_time_budget_is_503_and_stores_nothing(settings):
    from fastapi.testclient import TestClient

    from app.main import create_app

    quick = settings.model_copy(update={"plan_timeout_s": 0.05})
    with TestClient(create_app(quick)) as c:
        before = c.get("/v1/plans", headers=A).json()["count"]
        r = c.post("/v1/plans", json=PAPER_EXAMPLE, headers=A)
        assert r.status_code == 503, r.text
        assert "GSA_PLAN_TIMEOUT_S" in r.json()["detail"]
        assert c.get("/v1/plans", headers=A).json()["count"] == before


def test_resident_memory_reading_sees_an_allocation():
    import numpy as np

    from app.core.observability import resident_mb

    before = resident_mb()
    block = np.ones(40_000_000)  # 305 MiB, every page touched
    assert resident_mb() - before > 250
    del block


def test_a_plan_over_its_memory_budget_is_503_and_stores_nothing(settings, monkeypatch):
    """The worker's resident memory growing past GSA_PLAN_MEMORY_MB stops the plan at its next step."""
    import itertools

    from fastapi.testclient import TestClient

    import app.api.deps as deps_module
    from app.main import create_app

    grows = itertools.count(100.0, 40.0)  # each reading 40 MiB above the last
    monkeypatch.setattr(deps_module, "resident_mb", lambda: next(grows))
    tight = settings.model_copy(update={"plan_memory_mb": 100.0})
    with TestClient(create_app(tight)) as c:
        before = c.get("/v1/plans", headers=A).json()["count"]
        r = c.post("/v1/plans", json=PAPER_EXAMPLE, headers=A)
        assert r.status_code == 503, r.text
        assert "GSA_PLAN_MEMORY_MB" in r.json()["detail"]
        assert c.get("/v1/plans", headers=A).json()["count"] == before


@SQLITE_ONLY
def test_memory_stays_flat_over_repeated_plans(client):
    """A bounded soak: 30 one-day plans through the API; resident memory after the first 10 grows < 5 MB
    (each plan used to keep every integration step: ~0.4 MB a one-day plan, 8 MB here). make load runs 500."""
    import gc

    def rss_mb():
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * 4096 / 2**20

    body = copy.deepcopy(PAPER_EXAMPLE)
    body["search"] = {"duration_days": 1}
    marks = []
    for k in range(30):
        assert client.post("/v1/plans", json=body, headers=A).status_code == 201
        if k in (9, 29):
            gc.collect()
            marks.append(rss_mb())
    assert marks[1] - marks[0] < 5.0, marks


def test_405_lists_every_method_of_the_path(client):
    r = client.put("/v1/plans", headers=A)
    assert r.status_code == 405
    assert {m.strip() for m in r.headers["allow"].split(",")} >= {"GET", "POST"}


def test_access_report_csv_matches_the_plan(client, paper_plan):
    import csv
    import io
    from datetime import datetime

    r = client.get(f"/v1/plans/{paper_plan['id']}/export/access.csv", headers=A)
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/csv")
    assert "attachment" in r.headers["content-disposition"]
    rows = list(csv.DictReader(io.StringIO(r.text)))
    windows = paper_plan["access_windows"]
    assert len(rows) == len(windows) > 0
    # One pass numbering everywhere: the row's number is the window's place in the plan (pass_index), from 0.
    assert [int(row["access"]) for row in rows] == list(range(len(windows)))
    chosen = paper_plan["chosen"]
    w_chosen = windows[chosen["pass_index"]]
    assert w_chosen["rise"] <= chosen["t_access"] <= w_chosen["set"]
    # The pass the scene images in is marked, and only it.
    assert [k for k, row in enumerate(rows) if row["scene"]] == [chosen["pass_index"]]
    assert rows[chosen["pass_index"]]["scene"] == "chosen"
    for row, w in zip(rows, windows, strict=True):
        for col, key in (("rise_utc", "rise"), ("culmination_utc", "culmination"), ("set_utc", "set")):
            assert row[col].endswith("Z")
            got = datetime.fromisoformat(row[col].replace("Z", "+00:00"))
            assert abs((got - datetime.fromisoformat(w[key])).total_seconds()) < 1e-3
        rise = datetime.fromisoformat(row["rise_utc"].replace("Z", "+00:00"))
        end = datetime.fromisoformat(row["set_utc"].replace("Z", "+00:00"))
        assert float(row["duration_s"]) == pytest.approx((end - rise).total_seconds(), abs=2e-3)
        assert 0 <= float(row["rise_azimuth_deg"]) < 360 and float(row["max_elevation_deg"]) >= 0
        assert float(row["min_range_km"]) == pytest.approx(w["min_range_km"], abs=1e-3)
    assert (
        client.get(f"/v1/plans/{paper_plan['id']}/export/access.csv", headers={"X-API-Key": KEY_B}).status_code == 404
    )


@pytest.mark.parametrize(
    ("field", "loc"),
    [
        ("t_s", ["search"]),  # the planner's own name: an equatorial target from latitude 89.9 was told 'search.t_s'
        ("grid_s", ["search"]),
        (None, ["search"]),
        ("max_miss_km", ["search", "max_miss_km"]),
        ("target", ["target"]),
        ("ground_station", ["ground_station"]),
    ],
)
def test_a_planner_refusal_names_a_field_of_the_request(field, loc):
    from app.schemas import PlanCreate
    from app.services.planning import planner_loc

    assert planner_loc(field) == loc
    node = PlanCreate.model_json_schema()
    defs = node.get("$defs", {})
    for part in loc:  # every name it gives is a field the request has
        props = node.get("properties", {})
        assert part in props, (loc, part)
        node = props[part]
        ref = node.get("$ref") or next((x.get("$ref") for x in node.get("anyOf", []) if "$ref" in x), None)
        node = defs[ref.split("/")[-1]] if ref else node
