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
