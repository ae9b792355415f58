"""Orbits as operators already have them: a TLE as 2 lines, a 3LE, a text block, and a CCSDS OMM (CelesTrak's JSON,
XML and CSV). Each must give the very windows its TLE gives; skyfield's own OMM reader is the reference for the OMM."""

import copy

import numpy as np
import pytest
from skyfield.api import EarthSatellite

from planner.propagation import timescale
from tests.conftest import KEY_A
from tests.utils.orbits import ISS_EPOCH, ISS_L1, ISS_L2

A = {"X-API-Key": KEY_A}
STATION = {"name": "GS", "latitude_deg": 40.0, "longitude_deg": -75.0, "altitude_m": 100.0}
# The ISS TLE of the sgp4 and skyfield documentation, as CelesTrak would serve it as an OMM.
OMM = {
    "OBJECT_NAME": "ISS (ZARYA)",
    "OBJECT_ID": "1998-067A",
    "EPOCH": "2008-09-20T12:25:40.104192",
    "MEAN_MOTION": 15.72125391,
    "ECCENTRICITY": 0.0006703,
    "INCLINATION": 51.6416,
    "RA_OF_ASC_NODE": 247.4627,
    "ARG_OF_PERICENTER": 130.536,
    "MEAN_ANOMALY": 325.0288,
    "EPHEMERIS_TYPE": 0,
    "CLASSIFICATION_TYPE": "U",
    "NORAD_CAT_ID": 25544,
    "ELEMENT_SET_NO": 292,
    "REV_AT_EPOCH": 56353,
    "BSTAR": -1.1606e-05,
    "MEAN_MOTION_DOT": -2.182e-05,
    "MEAN_MOTION_DDOT": 0,
}
META = ("OBJECT_NAME", "OBJECT_ID")
XML = (
    '<?xml version="1.0" encoding="UTF-8"?>\n<ndm><omm id="CCSDS_OMM_VERS" version="2.0"><header><CREATION_DATE/>'
    "<ORIGINATOR/></header><body><segment><metadata>"
    + "".join(f"<{k}>{OMM[k]}</{k}>" for k in META)
    + "<CENTER_NAME>EARTH</CENTER_NAME><REF_FRAME>TEME</REF_FRAME><TIME_SYSTEM>UTC</TIME_SYSTEM>"
    "<MEAN_ELEMENT_THEORY>SGP4</MEAN_ELEMENT_THEORY></metadata><data><meanElements>"
    + "".join(
        f"<{k}>{OMM[k]}</{k}>"
        for k in (
            "EPOCH",
            "MEAN_MOTION",
            "ECCENTRICITY",
            "INCLINATION",
            "RA_OF_ASC_NODE",
            "ARG_OF_PERICENTER",
            "MEAN_ANOMALY",
        )
    )
    + "</meanElements><tleParameters>"
    + "".join(
        f"<{k}>{OMM[k]}</{k}>"
        for k in (
            "EPHEMERIS_TYPE",
            "CLASSIFICATION_TYPE",
            "NORAD_CAT_ID",
            "ELEMENT_SET_NO",
            "REV_AT_EPOCH",
            "BSTAR",
            "MEAN_MOTION_DOT",
            "MEAN_MOTION_DDOT",
        )
    )
    + "</tleParameters></data></segment></body></omm></ndm>"
)
CSV = ",".join(OMM) + "\n" + ",".join(str(v) for v in OMM.values()) + "\n"


def _windows(client, target):
    body = {
        "target": {"name": "ISS", **target},
        "ground_station": STATION,
        "start": ISS_EPOCH.isoformat(),
        "duration_days": 1.0,
    }
    r = client.post("/v1/access-windows", json=body, headers=A)
    assert r.status_code == 200, r.text
    return r.json()["access_windows"]


def test_every_form_of_the_same_orbit_gives_the_same_passes(client):
    reference = _windows(client, {"tle": [ISS_L1, ISS_L2]})
    assert len(reference) >= 4
    forms = [
        {"tle": ["0 ISS (ZARYA)", ISS_L1, ISS_L2]},
        {"tle": ["ISS (ZARYA)", ISS_L1, ISS_L2]},
        {"tle": f"ISS (ZARYA)\n{ISS_L1}\n{ISS_L2}\n"},
        {"omm": OMM},
        {"omm_xml": XML},
        {"omm_csv": CSV},
    ]
    for form in forms:
        got = _windows(client, form)
        assert [w["rise"] for w in got] == [w["rise"] for w in reference], form
        assert [w["max_elevation_deg"] for w in got] == [w["max_elevation_deg"] for w in reference], form


def test_the_omm_propagates_as_skyfields_own_omm_reader_has_it():
    from app.schemas import OrbitIn
    from app.services.planning import to_orbit

    orbit = to_orbit(OrbitIn.model_validate({"name": "ISS", "omm": OMM}), "target")
    ts = timescale()
    ours = EarthSatellite(orbit.tle.line1, orbit.tle.line2, ts=ts)
    ref = EarthSatellite.from_omm(ts, {k: str(v) for k, v in OMM.items()})
    t = ts.utc(2008, 9, 20, 12, np.arange(0, 1440, 60))
    np.testing.assert_allclose(ours.at(t).position.km, ref.at(t).position.km, atol=1e-6)


BAD = [
    ({"omm": {**OMM, "ECCENTRICITY": 1.5}}, ["body", "target", "omm", "ECCENTRICITY"]),
    ({"omm": {k: v for k, v in OMM.items() if k != "MEAN_MOTION"}}, ["body", "target", "omm", "MEAN_MOTION"]),
    ({"omm": {**OMM, "NORAD_CAT_ID": 9_999_999}}, ["body", "target", "omm", "NORAD_CAT_ID"]),
    ({"omm": {**OMM, "EPOCH": "yesterday"}}, ["body", "target", "omm", "EPOCH"]),
    ({"omm_xml": XML.replace('version="2.0"', 'version="1.0"')}, ["body", "target", "omm_xml", "CCSDS_OMM_VERS"]),
    ({"omm_xml": "<ndm><omm"}, ["body", "target", "omm_xml"]),
    ({"omm_csv": "OBJECT_NAME\nISS\n"}, ["body", "target", "omm_csv", "EPOCH"]),
    ({"tle": ["a", ISS_L1, ISS_L2, ISS_L2]}, ["body", "target", "tle"]),
    ({"tle": f"{ISS_L1}\n"}, ["body", "target", "tle"]),
    ({"tle": [ISS_L1, ISS_L2], "omm": OMM}, ["body", "target"]),
]


@pytest.mark.parametrize(("target", "loc"), BAD, ids=[str(i) for i in range(len(BAD))])
def test_bad_orbit_inputs_name_the_field(client, target, loc):
    body = {
        "target": {"name": "ISS", **copy.deepcopy(target)},
        "ground_station": STATION,
        "start": ISS_EPOCH.isoformat(),
        "duration_days": 1.0,
    }
    r = client.post("/v1/access-windows", json=body, headers=A)
    assert r.status_code == 422, r.text
    got = r.json()["detail"][0]["loc"]
    assert got[: len(loc)] == loc, (got, r.text)
