"""GET /v1/plans/{id}/export/{opm,oem,czml,pointing.csv}: read back by an independent CCSDS reader (ccsds-ndm),
flown by an independent J2 integrator (tests/utils/j2.py), and pointed against skyfield."""

import csv
import io
import json
import re
import xml.etree.ElementTree as ET
from datetime import UTC, datetime

import numpy as np
import pytest
from ccsds_ndm.ndm_io import NdmIo
from skyfield.api import EarthSatellite, wgs84

from app.schemas import PAPER_EXAMPLE
from planner.elements import elements_to_state
from planner.propagation import skyfield_times, timescale
from tests.conftest import KEY_A, KEY_B, SQLITE_ONLY
from tests.utils.j2 import propagate_tod_j2
from tests.utils.orbits import ISS_EPOCH, ISS_L1, ISS_L2, PAPER_TARGET

A = {"X-API-Key": KEY_A}


@pytest.fixture(scope="module")
def plan(client):
    r = client.post("/v1/plans", json=PAPER_EXAMPLE, headers=A)
    assert r.status_code == 201, r.text
    return r.json()


def _read(tmp_path, text, name):
    path = tmp_path / f"{name}.kvn"
    path.write_text(text)
    return NdmIo().from_path(str(path))


def _t(kvn_time):
    return datetime.fromisoformat(str(kvn_time).rstrip("Z")).replace(tzinfo=UTC)


@SQLITE_ONLY
def test_opm_is_read_back_and_its_burn_meets_the_target(client, plan, tmp_path):
    r = client.get(f"/v1/plans/{plan['id']}/export/opm", headers=A)
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/plain")
    text = re.sub(r"[ \t]+=[ \t]+", " = ", r.text)  # ccsds-ndm aligns the = signs
    assert text.startswith("CCSDS_OPM_VERS = 3.0\n")
    for key in (
        "CREATION_DATE",
        "ORIGINATOR",
        "OBJECT_NAME",
        "OBJECT_ID",
        "CENTER_NAME = EARTH",
        "REF_FRAME = GCRF",
        "TIME_SYSTEM = UTC",
        "EPOCH",
        "X_DOT",
        "MAN_EPOCH_IGNITION",
        "MAN_DURATION",
        "MAN_DELTA_MASS",
        "MAN_REF_FRAME = GCRF",
        "MAN_DV_1",
        "MAN_DV_2",
        "MAN_DV_3",
    ):
        assert key in text, key
    opm = _read(tmp_path, text, "plan_opm")
    seg = opm.body.segment
    assert seg.metadata.ref_frame == "GCRF" and seg.metadata.time_system == "UTC"
    assert seg.metadata.object_name == "Sat_Obs"
    sv = seg.data.state_vector
    man = seg.data.maneuver_parameters[0]
    ph = plan["phasing"]
    t_burn = datetime.fromisoformat(ph["t_burn"])
    assert abs((_t(sv.epoch) - t_burn).total_seconds()) < 1e-3
    assert abs((_t(man.man_epoch_ignition) - t_burn).total_seconds()) < 1e-3
    dv = np.array([man.man_dv_1.value, man.man_dv_2.value, man.man_dv_3.value]) * 1000.0
    np.testing.assert_allclose(dv, ph["dv_m_s"], atol=1e-5)
    # Fly the OPM's state and burn with the independent integrator; the target from its elements likewise.
    epoch = datetime.fromisoformat(plan["epoch"])
    t_access = datetime.fromisoformat(ph["t_access"])
    tb, ta = (t_burn - epoch).total_seconds(), (t_access - epoch).total_seconds()
    r0 = np.array([sv.x.value, sv.y.value, sv.z.value])
    v0 = np.array([sv.x_dot.value, sv.y_dot.value, sv.z_dot.value]) + dv / 1000.0
    obs = propagate_tod_j2(epoch, r0, v0, tb, [ta])[:, 0]
    rt, vt = elements_to_state(*PAPER_TARGET.radians())
    t_el = (PAPER_TARGET.epoch - epoch).total_seconds()
    tgt = propagate_tod_j2(epoch, rt, vt, t_el, [ta])[:, 0]
    separation = float(np.linalg.norm(obs - tgt))
    assert abs(separation - ph["verification"]["separation_km"]) < 0.2, separation


@SQLITE_ONLY
def test_oem_is_read_back_with_the_burn_between_segments(client, plan, tmp_path):
    r = client.get(f"/v1/plans/{plan['id']}/export/oem", headers=A)
    assert r.status_code == 200
    oem = _read(tmp_path, r.text, "plan_oem")
    segs = oem.body.segment
    assert len(segs) == 3
    for s in segs:
        assert s.metadata.ref_frame == "GCRF" and s.metadata.time_system == "UTC" and s.metadata.center_name == "EARTH"
    t_burn = datetime.fromisoformat(plan["phasing"]["t_burn"])
    assert abs((_t(segs[1].metadata.stop_time) - t_burn).total_seconds()) < 1e-3
    assert abs((_t(segs[2].metadata.start_time) - t_burn).total_seconds()) < 1e-3
    # Before the burn the observer's position is continuous, its velocity jumps by the burn.
    last, first = segs[1].data.state_vector[-1], segs[2].data.state_vector[0]
    dr = np.array([first.x.value - last.x.value, first.y.value - last.y.value, first.z.value - last.z.value])
    dv = (
        np.array(
            [
                first.x_dot.value - last.x_dot.value,
                first.y_dot.value - last.y_dot.value,
                first.z_dot.value - last.z_dot.value,
            ]
        )
        * 1000.0
    )
    assert np.linalg.norm(dr) < 1e-5
    np.testing.assert_allclose(dv, plan["phasing"]["dv_m_s"], atol=1e-4)
    # The target's ephemeris against the independent integrator, from the target's elements.
    epoch = datetime.fromisoformat(plan["epoch"])
    states = segs[0].data.state_vector
    times = np.array([(_t(s.epoch) - epoch).total_seconds() for s in states[::20]])
    ours = np.array([[s.x.value, s.y.value, s.z.value] for s in states[::20]]).T
    rt, vt = elements_to_state(*PAPER_TARGET.radians())
    ref = propagate_tod_j2(epoch, rt, vt, (PAPER_TARGET.epoch - epoch).total_seconds(), times)
    assert np.max(np.linalg.norm(ours - ref, axis=0)) < 0.05
    # At T_access the two ephemerides are the planned separation apart.
    t_access = plan["phasing"]["t_access"]
    at = {
        s.metadata.object_id: next(
            v
            for v in s.data.state_vector
            if abs((_t(v.epoch) - datetime.fromisoformat(t_access)).total_seconds()) < 1e-3
        )
        for s in (segs[0], segs[2])
    }
    a, b = at.values()
    gap = np.linalg.norm([a.x.value - b.x.value, a.y.value - b.y.value, a.z.value - b.z.value])
    assert abs(gap - plan["phasing"]["verification"]["separation_km"]) < 1e-3


def test_czml_holds_both_satellites_the_station_and_the_moment(client, plan):
    r = client.get(f"/v1/plans/{plan['id']}/export/czml", headers=A)
    assert r.status_code == 200 and r.headers["content-type"].startswith("application/json")
    packets = {p["id"]: p for p in json.loads(r.text)}
    assert set(packets) == {"document", "target", "observer", "station", "access", "imaging"}
    assert packets["document"]["version"] == "1.0"
    t_access = datetime.fromisoformat(plan["phasing"]["t_access"])
    assert datetime.fromisoformat(
        packets["document"]["clock"]["currentTime"].replace("Z", "+00:00")
    ) - t_access < __import__("datetime").timedelta(milliseconds=1)
    pos = packets["target"]["position"]
    assert pos["referenceFrame"] == "INERTIAL" and pos["epoch"].endswith("Z")
    assert len(pos["cartesian"]) % 4 == 0 and len(pos["cartesian"]) >= 4 * 100
    # The observer in two intervals split at the burn (no interpolation across it): the same position on either
    # side of the burn, the first ending and the second starting there.
    before, after = packets["observer"]["position"]
    t_burn = datetime.fromisoformat(plan["phasing"]["t_burn"])
    for part in (before, after):
        assert part["referenceFrame"] == "INERTIAL" and len(part["cartesian"]) % 4 == 0
    edge = datetime.fromisoformat(before["interval"].split("/")[1].replace("Z", "+00:00"))
    assert abs((edge - t_burn).total_seconds()) < 1e-6 and after["interval"].startswith(before["interval"][-27:])
    np.testing.assert_allclose(before["cartesian"][-3:], after["cartesian"][1:4], atol=0.02)  # metres
    gs = PAPER_EXAMPLE["ground_station"]
    assert packets["station"]["position"]["cartographicDegrees"][:2] == [gs["longitude_deg"], gs["latitude_deg"]]
    assert all(iv.endswith("Z") for iv in "/".join(np.atleast_1d(packets["access"]["availability"])).split("/"))


ISS_PLAN = {
    "target": {"name": "ISS", "tle": [ISS_L1, ISS_L2]},
    "observer": PAPER_EXAMPLE["observer"],
    "ground_station": {"name": "GS", "latitude_deg": 40.0, "longitude_deg": -75.0, "altitude_m": 100.0},
    "search": {"start": ISS_EPOCH.isoformat(), "duration_days": 1.0},
}


def test_pointing_file_against_skyfield(client):
    body = dict(ISS_PLAN, observer=dict(PAPER_EXAMPLE["observer"]))
    body["observer"]["elements"] = dict(body["observer"]["elements"], epoch=ISS_EPOCH.isoformat())
    plan = client.post("/v1/plans", json=body, headers=A)
    assert plan.status_code == 201, plan.text
    plan = plan.json()
    r = client.get(f"/v1/plans/{plan['id']}/export/pointing.csv", headers=A)
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/csv")
    rows = list(csv.DictReader(io.StringIO(r.text)))
    windows = plan["access_windows"]
    assert {int(x["access"]) for x in rows} == set(range(len(windows)))
    for k, w in enumerate(windows):
        mine = [x for x in rows if int(x["access"]) == k]
        span = (datetime.fromisoformat(w["set"]) - datetime.fromisoformat(w["rise"])).total_seconds()
        assert abs(len(mine) - span) <= 2  # one row a second
        assert abs(max(float(x["elevation_deg"]) for x in mine) - w["max_elevation_deg"]) < 0.01
    sat = EarthSatellite(ISS_L1, ISS_L2, ts=timescale())
    site = wgs84.latlon(40.0, -75.0, 100.0)
    sample = rows[:: max(1, len(rows) // 40)]
    when = [datetime.fromisoformat(x["time_utc"].replace("Z", "+00:00")) for x in sample]
    assert all(x["time_utc"].endswith("Z") for x in sample)
    t = skyfield_times(ISS_EPOCH, np.array([(w - ISS_EPOCH).total_seconds() for w in when]))
    alt, az, dist = (sat - site).at(t).altaz()
    np.testing.assert_allclose([float(x["elevation_deg"]) for x in sample], alt.degrees, atol=2e-3)
    d_az = (np.array([float(x["azimuth_deg"]) for x in sample]) - az.degrees + 180) % 360 - 180
    assert np.max(np.abs(d_az * np.cos(alt.radians))) < 2e-3
    np.testing.assert_allclose([float(x["range_km"]) for x in sample], dist.km, atol=2e-3)
    # The GeoJSON's sky track of the chosen pass (what the console's sky plot draws): the same look angles
    geo = client.get(f"/v1/plans/{plan['id']}/export/geojson", headers=A).json()
    inview = next(f for f in geo["features"] if f["properties"]["kind"] == "target_in_view")
    sky = inview["properties"]["sky_time_az_el_deg"]
    assert len(sky) > 10 and all(row[2] >= -1e-6 for row in sky)
    when = [datetime.fromisoformat(row[0].replace("Z", "+00:00")) for row in sky]
    t = skyfield_times(ISS_EPOCH, np.array([(w - ISS_EPOCH).total_seconds() for w in when]))
    alt, az, _ = (sat - site).at(t).altaz()
    np.testing.assert_allclose([row[2] for row in sky], alt.degrees, atol=2e-3)
    d_az = (np.array([row[1] for row in sky]) - az.degrees + 180) % 360 - 180
    assert np.max(np.abs(d_az * np.cos(alt.radians))) < 2e-3


def test_exports_are_the_operators_own(client, plan):
    for kind in ("opm", "oem", "czml", "pointing.csv"):
        assert client.get(f"/v1/plans/{plan['id']}/export/{kind}", headers={"X-API-Key": KEY_B}).status_code == 404
        assert client.get(f"/v1/plans/no-such-plan/export/{kind}", headers=A).status_code == 404


def _central_deg(lat1, lon1, lat2, lon2):
    p1, p2, dl = np.radians(lat1), np.radians(lat2), np.radians(lon2 - lon1)
    return np.degrees(np.arccos(np.clip(np.sin(p1) * np.sin(p2) + np.cos(p1) * np.cos(p2) * np.cos(dl), -1, 1)))


def test_geojson_tracks_station_and_where_it_sees_the_target(client, plan):
    r = client.get(f"/v1/plans/{plan['id']}/export/geojson", headers=A)
    assert r.status_code == 200 and r.headers["content-type"].startswith("application/geo+json")
    doc = r.json()
    assert doc["type"] == "FeatureCollection"
    kinds = {f["properties"]["kind"]: f for f in doc["features"]}
    assert set(kinds) == {
        "station",
        "target_track",
        "target_in_view",
        "visibility_circle",
        "visibility_footprint",
        "observer_track",
        "t_access",
        "observer_at_t_access",
        "night",
    }
    for f in doc["features"]:
        if f["geometry"]["type"] in ("Polygon", "MultiPolygon"):
            continue  # read back by shapely below
        parts = f["geometry"]["coordinates"]
        for part in parts if f["geometry"]["type"] == "MultiLineString" else [[parts]]:
            lon, lat = np.array(part).T
            assert np.all(np.abs(lon) <= 180) and np.all(np.abs(lat) <= 90)
            assert np.all(np.abs(np.diff(lon)) < 180)  # cut at the antimeridian (RFC 7946 3.1.9)
    s_lon, s_lat = kinds["station"]["geometry"]["coordinates"]
    assert (s_lat, s_lon) == (31.1, 121.3)
    # Every in-view sub-point lies within the visibility circle (two computations: look angles, and the
    # circle's spherical geometry); every sub-point outside the circle's largest radius is out of view.
    circle = np.concatenate([np.array(p) for p in kinds["visibility_circle"]["geometry"]["coordinates"]])
    radius = _central_deg(s_lat, s_lon, circle[:, 1], circle[:, 0])
    seen = np.concatenate([np.array(p) for p in kinds["target_in_view"]["geometry"]["coordinates"]])
    assert seen.size and np.all(_central_deg(s_lat, s_lon, seen[:, 1], seen[:, 0]) <= radius.max() + 0.2)
    # The footprint is a polygon GIS tools can fill (shapely reads it back valid): the station inside, the area
    # that of a spherical cap of the circle's mean radius within 5 % (the mask makes it a little uneven).
    from shapely.geometry import Point, shape

    foot = shape(kinds["visibility_footprint"]["geometry"])
    assert foot.geom_type == "Polygon" and foot.is_valid and foot.contains(Point(s_lon, s_lat))
    assert all(foot.buffer(0.05).contains(Point(x, y)) for x, y in circle[::10])
    # T_access lies on the target's track.
    a_lon, a_lat = kinds["t_access"]["geometry"]["coordinates"]
    track = np.concatenate([np.array(p) for p in kinds["target_track"]["geometry"]["coordinates"]])
    assert _central_deg(a_lat, a_lon, track[:, 1], track[:, 0]).min() < 1.5  # 20-s steps at 7 km/s
    written = datetime.fromisoformat(kinds["t_access"]["properties"]["time"].replace("Z", "+00:00"))
    assert kinds["t_access"]["properties"]["time"].endswith("Z")
    assert written == datetime.fromisoformat(plan["chosen"]["t_access"])  # to the microsecond
    # The observer is where the plan flies it, across its burn: beside the target at T_access (80.6 km planned:
    # 0.72 deg of arc on the ground), not where it would have been unburnt (thousands of km).
    o_lon, o_lat = kinds["observer_at_t_access"]["geometry"]["coordinates"]
    standoff_deg = np.degrees(plan["chosen"]["standoff_km"] / 6378.137)
    assert _central_deg(a_lat, a_lon, np.array([o_lat]), np.array([o_lon]))[0] < standoff_deg + 0.05


@SQLITE_ONLY
def test_geojson_night_side_against_skyfield(client, plan):
    """The night polygon at T_access holds the ground points where skyfield puts the Sun's centre below the
    horizon (its own topocentric altitude, de421), and none where it is above, away from a 1-deg band at the line."""
    from shapely.geometry import Point, shape
    from skyfield.api import wgs84

    from planner.propagation import ephemeris, skyfield_times

    doc = client.get(f"/v1/plans/{plan['id']}/export/geojson", headers=A).json()
    night = next(f for f in doc["features"] if f["properties"]["kind"] == "night")
    poly = shape(night["geometry"])
    assert poly.is_valid
    when = datetime.fromisoformat(night["properties"]["time"].replace("Z", "+00:00"))
    assert when == datetime.fromisoformat(plan["chosen"]["t_access"])
    eph = ephemeris()
    t = skyfield_times(when, np.array([0.0]))[0]
    rng = np.random.default_rng(11)
    checked = 0
    for lat, lon in zip(np.degrees(np.arcsin(rng.uniform(-1, 1, 400))), rng.uniform(-180, 180, 400), strict=True):
        alt = (eph["earth"] + wgs84.latlon(lat, lon)).at(t).observe(eph["sun"]).apparent().altaz()[0].degrees
        if abs(alt) < 1.0:
            continue
        assert poly.contains(Point(lon, lat)) == (alt < 0.0), (lat, lon, alt)
        checked += 1
    assert checked > 350
    a_lon, a_lat = night["properties"]["antisolar_point"]
    assert poly.contains(Point(a_lon, a_lat))


@SQLITE_ONLY
@pytest.mark.parametrize("fmt", ["kvn", "xml"])
def test_the_opm_goes_back_in_as_an_observer(client, plan, fmt):
    """The service reads its own OPM, KVN (502.0-B-3: no META_START/META_STOP) or XML: as a new plan's observer,
    its state read back to the millimetre (the XML's numbers read by the standard library's XML parser) and
    planned."""
    r = client.get(f"/v1/plans/{plan['id']}/export/opm?format={fmt}", headers=A)
    assert r.status_code == 200
    text = r.text
    if fmt == "kvn":
        assert r.headers["content-type"].startswith("text/plain")
        assert "META_START" not in text and "META_STOP" not in text
        values = {k.strip(): v for k, v in (line.split("=", 1) for line in text.splitlines() if "=" in line)}
        r_opm = np.array([float(values[k].split()[0]) for k in ("X", "Y", "Z")])
        v_opm = np.array([float(values[k].split()[0]) for k in ("X_DOT", "Y_DOT", "Z_DOT")])
    else:
        assert r.headers["content-type"].startswith("application/xml")
        assert "attachment" in r.headers["content-disposition"] and ".xml" in r.headers["content-disposition"]
        root = ET.fromstring(text)
        assert root.tag == "opm" and root.get("version") == "3.0" and root.get("id") == "CCSDS_OPM_VERS"
        sv = root.find("body/segment/data/stateVector")
        assert root.findtext("body/segment/metadata/REF_FRAME") == "GCRF" and sv.find("X").get("units") == "km"
        r_opm = np.array([float(sv.findtext(k)) for k in ("X", "Y", "Z")])
        v_opm = np.array([float(sv.findtext(k)) for k in ("X_DOT", "Y_DOT", "Z_DOT")])
        kvn = client.get(f"/v1/plans/{plan['id']}/export/opm", headers=A).text
        assert f"X                        = {r_opm[0]} [km]" in kvn  # the same state in both forms
    body = dict(PAPER_EXAMPLE, observer={"name": "from its own OPM", "opm": text})
    body["search"] = {"start": plan["phasing"]["t_burn"], "duration_days": 2}
    r = client.post("/v1/plans", json=body, headers=A)
    assert r.status_code == 201, r.text
    # Its burn is listed in the OPM and not applied: the plan says so, naming when it was.
    burn_at = plan["phasing"]["t_burn"][:19]
    said = [n for n in r.json()["notes"] if "manoeuvre" in n]
    assert len(said) == 1 and "observer from its own OPM" in said[0] and burn_at in said[0], r.json()["notes"]
    assert "applies none of them" in said[0]
    from app.schemas import OrbitIn
    from app.services.planning import to_orbit

    el = to_orbit(OrbitIn.model_validate({"name": "x", "opm": text}), "observer").elements
    r_back, v_back = elements_to_state(*el.radians())
    assert np.linalg.norm(r_back - r_opm) < 1e-6 and np.linalg.norm(v_back - v_opm) < 1e-9


@SQLITE_ONLY
def test_the_oem_in_xml_holds_the_kvn_states(client, plan, tmp_path):
    """The OEM with format=xml, read by the standard library's XML parser: the segments and states of the KVN one."""
    kvn = _read(tmp_path, client.get(f"/v1/plans/{plan['id']}/export/oem", headers=A).text, "oem")
    r = client.get(f"/v1/plans/{plan['id']}/export/oem?format=xml", headers=A)
    assert r.status_code == 200 and r.headers["content-type"].startswith("application/xml")
    root = ET.fromstring(r.text)
    assert root.tag == "oem" and root.get("version") == "3.0"
    segs = root.findall("body/segment")
    assert len(segs) == len(kvn.body.segment) == 3
    for seg, ref in zip(segs, kvn.body.segment, strict=True):
        assert seg.findtext("metadata/OBJECT_ID") == ref.metadata.object_id
        states = seg.findall("data/stateVector")
        assert len(states) == len(ref.data.state_vector)
        for s, v in zip(states[::37], ref.data.state_vector[::37], strict=True):
            assert s.findtext("EPOCH") == v.epoch and float(s.findtext("Z_DOT")) == v.z_dot.value
    wrong = client.get(f"/v1/plans/{plan['id']}/export/czml?format=xml", headers=A)  # CZML has one form
    assert wrong.status_code == 422 and wrong.json()["detail"][0]["loc"] == ["query", "format"], wrong.text
    bad = client.get(f"/v1/plans/{plan['id']}/export/oem?format=json", headers=A)
    assert bad.status_code == 422 and bad.json()["detail"][0]["loc"] == ["query", "format"], bad.text


def _without_creation_date(text):
    return re.sub(r"CREATION_DATE\W+[\d\-T:.]+", "", text)


@SQLITE_ONLY
def test_exports_are_served_as_stored_and_an_older_plan_is_recomputed_once(client, plan, monkeypatch):
    """Every export is written when the plan is made: served with no planning at all (the planner made to fail).
    A plan stored before (its exports gone) is recomputed on the first request, the same files but their
    creation date, and served as stored after that."""
    from app.services import planning

    exports_of = [
        ("opm", ""),
        ("opm", "?format=xml"),
        ("oem", ""),
        ("oem", "?format=xml"),
        ("czml", ""),
        ("geojson", ""),
        ("pointing.csv", ""),
    ]

    def no_planning(*a, **k):
        raise AssertionError("an export planned again")

    with monkeypatch.context() as m:
        m.setattr(planning, "make_plan", no_planning)
        stored = {}
        for kind, query in exports_of:
            r = client.get(f"/v1/plans/{plan['id']}/export/{kind}{query}", headers=A)
            assert r.status_code == 200, (kind, r.text)
            stored[kind + query] = r.text
    assert stored["pointing.csv"].count("\n") > 1000
    from sqlalchemy import delete

    from app.db.models import PlanExport

    with client.app.state.session_factory() as session:
        session.execute(delete(PlanExport).where(PlanExport.plan_id == plan["id"]))
        session.commit()
    calls = []
    real = planning.make_plan
    monkeypatch.setattr(planning, "make_plan", lambda *a, **k: calls.append(1) or real(*a, **k))
    for kind, query in exports_of:
        r = client.get(f"/v1/plans/{plan['id']}/export/{kind}{query}", headers=A)
        assert r.status_code == 200, (kind, r.text)
        assert _without_creation_date(r.text) == _without_creation_date(stored[kind + query]), kind + query
    assert len(calls) == 1  # recomputed once, then kept


def test_a_footprint_across_the_antimeridian_and_about_a_pole_stays_fillable():
    """Stations where hand-cut rings go wrong: at 179.5 E the footprint is two polygons either side of +-180; at 85 N
    it encloses the pole and is closed along the map's edge. shapely reads each back valid, the station inside."""
    from shapely.geometry import Point, shape

    from app.services.exports import footprint_polygon
    from planner.frames import visibility_circle
    from planner.propagation import Station

    for lat, lon, kind in ((10.0, 179.5, "MultiPolygon"), (85.0, 20.0, "Polygon")):
        station = Station(latitude_deg=lat, longitude_deg=lon, altitude_m=0.0, min_elevation_deg=10.0)
        c_lat, c_lon = visibility_circle(station, 500.0)
        foot = shape(footprint_polygon(c_lat, c_lon))
        assert foot.geom_type == kind and foot.is_valid, (lat, lon)
        assert foot.buffer(1e-6).contains(Point(lon, lat))
        lons = np.concatenate([np.array(g.exterior.coords)[:, 0] for g in getattr(foot, "geoms", [foot])])
        assert np.all(np.abs(lons) <= 180.0)


def test_a_track_cut_at_the_antimeridian_runs_on_to_it():
    """A track crossing 180 deg between two samples: the first part ends on the antimeridian and the next begins
    there, at the latitude where the track crosses (a line in lon/lat here, so the crossing is exact), both ways."""
    from app.services.exports import line_parts

    east = line_parts(np.array([0.0, 8.0, 14.0, 20.0]), np.array([170.0, 178.0, -176.0, -170.0]))
    assert east == [[[170.0, 0.0], [178.0, 8.0], [180.0, 10.0]], [[-180.0, 10.0], [-176.0, 14.0], [-170.0, 20.0]]]
    west = line_parts(np.array([20.0, 14.0, 8.0]), np.array([-170.0, -176.0, 178.0]))
    assert west == [[[-170.0, 20.0], [-176.0, 14.0], [-180.0, 10.0]], [[180.0, 10.0], [178.0, 8.0]]]
    hidden = line_parts(
        np.array([0.0, 8.0, 14.0, 20.0]),
        np.array([170.0, 178.0, -176.0, -170.0]),
        keep=np.array([True, False, True, True]),
    )
    assert hidden == [[[-176.0, 14.0], [-170.0, 20.0]]]  # a crossing out of view draws nothing


@SQLITE_ONLY
@pytest.mark.parametrize("fmt", ["kvn", "xml"])
def test_the_oem_goes_back_in_as_a_target(client, plan, fmt):
    """The service reads its own OEM (KVN or XML) as an orbit: its first segment is the target, which two-body + J2
    from its first state flies again within 10 m of every state the OEM lists, and its other segments (the
    observer's) are named in the plan's note as not flown."""
    r = client.get(f"/v1/plans/{plan['id']}/export/oem?format={fmt}", headers=A)
    assert r.status_code == 200
    body = dict(PAPER_EXAMPLE, target={"name": "from its own OEM", "oem": r.text})
    res = client.post("/v1/access-windows", json={k: body[k] for k in ("target", "ground_station")}, headers=A)
    assert res.status_code == 200, res.text
    back = client.post("/v1/plans", json=body, headers=A)
    assert back.status_code == 201, back.text
    note = next(n for n in back.json()["notes"] if "OEM" in n)
    assert "later segment(s)" in note and "departs from its states by up to" in note
    assert float(note.split("by up to ")[1].split(" km")[0]) < 0.01  # its own J2 flight, sampled: metres at most
