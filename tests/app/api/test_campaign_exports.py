"""A campaign's OPM and OEM read back by ccsds-ndm and flown by an independent J2 integrator.

What is checked is the flight the exports describe, not the database: these run on SQLite alone (the campaign
routes and their storage run on both databases in test_campaigns)."""

from datetime import UTC, datetime

import numpy as np
import pytest
from ccsds_ndm.ndm_io import NdmIo

from app.schemas import CAMPAIGN_EXAMPLE
from planner.elements import elements_to_state
from tests.conftest import KEY_A, KEY_B
from tests.utils.j2 import fly_tod_j2, propagate_tod_j2
from tests.utils.orbits import PAPER_TARGET

A = {"X-API-Key": KEY_A}
B = {"X-API-Key": KEY_B}


@pytest.fixture(scope="module")
def backend():
    return "sqlite"


@pytest.fixture(scope="module")
def campaign(client):
    r = client.post("/v1/campaigns", json=CAMPAIGN_EXAMPLE, headers=A)
    assert r.status_code == 201, r.text
    return r.json()


def _t(kvn_time):
    return datetime.fromisoformat(str(kvn_time).rstrip("Z")).replace(tzinfo=UTC)


def _read(tmp_path, text, name):
    path = tmp_path / f"{name}.kvn"
    path.write_text(text)
    return NdmIo().from_path(str(path))


def test_the_opm_holds_every_burn_and_flies_to_each_scene(client, campaign, tmp_path):
    r = client.get(f"/v1/campaigns/{campaign['id']}/export/opm", headers=A)
    assert r.status_code == 200
    assert "META_START" not in r.text
    from app.schemas import OrbitIn
    from app.services.planning import to_orbit

    back = to_orbit(OrbitIn.model_validate({"name": "x", "opm": r.text}), "observer")  # the service reads it back
    assert abs((back.epoch - datetime.fromisoformat(campaign["epoch"])).total_seconds()) < 1e-6
    opm = _read(tmp_path, r.text, "campaign_opm")
    seg = opm.body.segment
    sv = seg.data.state_vector
    burns = [b for s in campaign["scenes"] for b in s["burns"]]
    mans = seg.data.maneuver_parameters
    assert len(mans) == len(burns)
    epoch = datetime.fromisoformat(campaign["epoch"])
    assert abs((_t(sv.epoch) - epoch).total_seconds()) < 1e-3
    flown = []
    for man, b in zip(mans, burns, strict=True):
        t = (_t(man.man_epoch_ignition) - epoch).total_seconds()
        assert abs(t - (datetime.fromisoformat(b["time"]) - epoch).total_seconds()) < 1e-3
        dv = np.array([man.man_dv_1.value, man.man_dv_2.value, man.man_dv_3.value])
        np.testing.assert_allclose(dv * 1000.0, b["dv_m_s"], atol=1e-5)
        flown.append(((datetime.fromisoformat(b["time"]) - epoch).total_seconds(), dv))
    # Fly the OPM's state through every burn with the independent integrator; the target from its elements.
    r0 = np.array([sv.x.value, sv.y.value, sv.z.value])
    v0 = np.array([sv.x_dot.value, sv.y_dot.value, sv.z_dot.value])
    t_access = np.array([(datetime.fromisoformat(s["t_access"]) - epoch).total_seconds() for s in campaign["scenes"]])
    obs, _ = fly_tod_j2(epoch, r0, v0, 0.0, flown, t_access)
    rt, vt = elements_to_state(*PAPER_TARGET.radians())
    tgt = propagate_tod_j2(epoch, rt, vt, (PAPER_TARGET.epoch - epoch).total_seconds(), t_access)
    separation = np.linalg.norm(obs - tgt, axis=0)
    # Chained open-loop from the start state, fly-bys amplify every metre (issue 73: 1 mm/s on a first burn moves a
    # second scene by 12.6 km). Both integrators end 30 days ~21 m from a 1e-13 run at rtol 1e-10
    # (design/measurements.md, "A compiled J2 integrator"); this campaign's fourth scene turns that into 0.29 km
    # (measured 2026-12-08). 0.5 km is still a small part of what 1 mm/s on one burn moves a later scene.
    np.testing.assert_allclose(separation, [s["check"]["separation_km"] for s in campaign["scenes"]], atol=0.5)


def test_the_opm_in_xml_holds_the_kvn_burns_and_goes_back_in(client, campaign, tmp_path):
    """format=xml: the same state and burns (read by the standard library's XML parser), and the service reads it
    back as an observer at the campaign's start."""
    import xml.etree.ElementTree as ET

    from app.schemas import OrbitIn
    from app.services.planning import to_orbit

    kvn = _read(tmp_path, client.get(f"/v1/campaigns/{campaign['id']}/export/opm", headers=A).text, "opm")
    r = client.get(f"/v1/campaigns/{campaign['id']}/export/opm?format=xml", headers=A)
    assert r.status_code == 200 and r.headers["content-type"].startswith("application/xml")
    root = ET.fromstring(r.text)
    mans = root.findall("body/segment/data/maneuverParameters")
    assert len(mans) == len(kvn.body.segment.data.maneuver_parameters) >= 1
    for man, ref in zip(mans, kvn.body.segment.data.maneuver_parameters, strict=True):
        assert man.findtext("MAN_EPOCH_IGNITION") == ref.man_epoch_ignition
        assert [float(man.findtext(f"MAN_DV_{k}")) for k in (1, 2, 3)] == [
            ref.man_dv_1.value,
            ref.man_dv_2.value,
            ref.man_dv_3.value,
        ]
    back = to_orbit(OrbitIn.model_validate({"name": "x", "opm": r.text}), "observer")
    assert abs((back.epoch - datetime.fromisoformat(campaign["epoch"])).total_seconds()) < 1e-6


def test_the_oem_has_one_observer_segment_between_burns(client, campaign, tmp_path):
    r = client.get(f"/v1/campaigns/{campaign['id']}/export/oem", headers=A)
    assert r.status_code == 200
    segs = _read(tmp_path, r.text, "campaign_oem").body.segment
    burns = [b for s in campaign["scenes"] for b in s["burns"]]
    assert len(segs) == 1 + len(burns) + 1
    for k, b in enumerate(burns):
        before, after = segs[1 + k], segs[2 + k]
        t_burn = datetime.fromisoformat(b["time"])
        assert abs((_t(before.metadata.stop_time) - t_burn).total_seconds()) < 1e-3
        assert abs((_t(after.metadata.start_time) - t_burn).total_seconds()) < 1e-3
        last, first = before.data.state_vector[-1], after.data.state_vector[0]
        dr = [first.x.value - last.x.value, first.y.value - last.y.value, first.z.value - last.z.value]
        dv = [
            first.x_dot.value - last.x_dot.value,
            first.y_dot.value - last.y_dot.value,
            first.z_dot.value - last.z_dot.value,
        ]
        assert np.linalg.norm(dr) < 1e-5
        np.testing.assert_allclose(np.array(dv) * 1000.0, b["dv_m_s"], atol=1e-4)


def _target_gcrs(epoch, t_s):
    """The target by the independent J2 integrator from its elements (GCRS, km, (3, N))."""
    rt, vt = elements_to_state(*PAPER_TARGET.radians())
    return propagate_tod_j2(epoch, rt, vt, (PAPER_TARGET.epoch - epoch).total_seconds(), np.asarray(t_s, float))


def test_each_scenes_pointing_file_against_skyfield(client, campaign):
    """pointing.csv?scene=K: one row a second over the pass scene K images in (its access.csv row), the look angles
    of the target flown by the independent integrator as skyfield's station sees it (skyfield's altaz)."""
    import csv
    import io

    from skyfield.api import wgs84
    from skyfield.constants import AU_KM
    from skyfield.positionlib import ICRF

    from planner.propagation import skyfield_times

    epoch = datetime.fromisoformat(campaign["epoch"])
    gs = CAMPAIGN_EXAMPLE["ground_station"]
    site = wgs84.latlon(gs["latitude_deg"], gs["longitude_deg"], gs["altitude_m"])
    access = list(
        csv.DictReader(io.StringIO(client.get(f"/v1/campaigns/{campaign['id']}/export/access.csv", headers=A).text))
    )
    everything = client.get(f"/v1/campaigns/{campaign['id']}/export/pointing.csv", headers=A)
    assert everything.status_code == 200 and everything.headers["content-type"].startswith("text/csv")
    all_rows = list(csv.DictReader(io.StringIO(everything.text)))
    for sc in campaign["scenes"][:2]:
        r = client.get(f"/v1/campaigns/{campaign['id']}/export/pointing.csv?scene={sc['index']}", headers=A)
        assert r.status_code == 200, r.text
        assert f"scene-{sc['index']}" in r.headers["content-disposition"]
        rows = list(csv.DictReader(io.StringIO(r.text)))
        k = {int(x["access"]) for x in rows}
        assert len(k) == 1
        (k,) = k
        assert str(sc["index"]) in access[k]["scene"].split(";")  # the pass access.csv marks for this scene
        w = sc["access_window"]
        span = (datetime.fromisoformat(w["set"]) - datetime.fromisoformat(w["rise"])).total_seconds()
        assert abs(len(rows) - span) <= 2
        assert abs(max(float(x["elevation_deg"]) for x in rows) - w["max_elevation_deg"]) < 0.01
        assert all(x in all_rows for x in rows[:: max(1, len(rows) // 10)])  # every scene's file is part of the whole
        sample = rows[:: max(1, len(rows) // 12)]
        t_s = np.array(
            [(datetime.fromisoformat(x["time_utc"].replace("Z", "+00:00")) - epoch).total_seconds() for x in sample]
        )
        t = skyfield_times(epoch, t_s)
        d = _target_gcrs(epoch, t_s) - site.at(t).position.km
        alt, az, dist = ICRF(d / AU_KM, t=t, center=site).altaz()
        np.testing.assert_allclose([float(x["elevation_deg"]) for x in sample], alt.degrees, atol=0.01)
        d_az = (np.array([float(x["azimuth_deg"]) for x in sample]) - az.degrees + 180) % 360 - 180
        assert np.max(np.abs(d_az * np.cos(alt.radians))) < 0.01
        np.testing.assert_allclose([float(x["range_km"]) for x in sample], dist.km, atol=0.1)
    bad = client.get(f"/v1/campaigns/{campaign['id']}/export/pointing.csv?scene=99", headers=A)
    assert bad.status_code == 422 and bad.json()["detail"][0]["loc"] == ["query", "scene"], bad.text
    assert "its scenes are" in bad.json()["detail"][0]["msg"]
    assert client.get(f"/v1/campaigns/{campaign['id']}/export/pointing.csv", headers=B).status_code == 404


def test_the_campaign_geojson_puts_each_scene_and_burn_where_the_independent_flight_does(client, campaign):
    """GeoJSON of the whole campaign: the station, each scene's pass track, the target under each T_access (within
    0.01 deg of the independent integrator's target, skyfield's WGS-84 sub-point) and each burn with its size."""
    from skyfield.api import wgs84
    from skyfield.constants import AU_KM
    from skyfield.positionlib import Geocentric

    from planner.propagation import skyfield_times

    r = client.get(f"/v1/campaigns/{campaign['id']}/export/geojson", headers=A)
    assert r.status_code == 200 and r.headers["content-type"].startswith("application/geo+json")
    geo = r.json()
    assert geo["type"] == "FeatureCollection"
    kinds = [f["properties"]["kind"] for f in geo["features"]]
    scenes = campaign["scenes"]
    burns = [b for s in scenes for b in s["burns"]]
    assert kinds.count("station") == 1 and kinds.count("t_access") == len(scenes) == kinds.count("scene_pass")
    assert kinds.count("burn") == len(burns) == kinds.count("burn")
    epoch = datetime.fromisoformat(campaign["epoch"])
    points = [f for f in geo["features"] if f["properties"]["kind"] == "t_access"]
    t_s = np.array([(datetime.fromisoformat(s["t_access"]) - epoch).total_seconds() for s in scenes])
    t = skyfield_times(epoch, t_s)
    sub = wgs84.subpoint_of(Geocentric(_target_gcrs(epoch, t_s) / AU_KM, t=t, center=399))
    for k, f in enumerate(points):
        lon, lat = f["geometry"]["coordinates"]
        assert f["properties"]["scene"] == scenes[k]["index"]
        assert abs(lat - sub.latitude.degrees[k]) < 0.01
        assert abs((lon - sub.longitude.degrees[k] + 180) % 360 - 180) < 0.01
    got = [f["properties"] for f in geo["features"] if f["properties"]["kind"] == "burn"]
    for p, b in zip(got, burns, strict=True):
        assert abs(p["dv_m_s"] - float(np.linalg.norm(b["dv_m_s"]))) < 1e-3
        assert (
            abs(
                (
                    datetime.fromisoformat(p["time"].replace("Z", "+00:00")) - datetime.fromisoformat(b["time"])
                ).total_seconds()
            )
            < 1e-3
        )
    for f in geo["features"]:
        if f["geometry"]["type"] == "MultiLineString":
            assert all(-180 <= x <= 180 and -90 <= y <= 90 for part in f["geometry"]["coordinates"] for x, y in part)
