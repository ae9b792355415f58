"""Orbits as operators already have them: a TLE as 2 lines, a 3LE, a text block, and a CCSDS OMM (CelesTrak's JSON,
XML and CSV). Each must give the very windows its TLE gives; skyfield's own OMM reader is the reference for the OMM."""

import copy
from datetime import datetime

import numpy as np
import pytest
from skyfield.api import EarthSatellite

from planner.propagation import timescale
from tests.conftest import KEY_A
from tests.utils.orbits import ISS_EPOCH, ISS_L1, ISS_L2, opm_kvn

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
UNITS = {"MEAN_MOTION": " [rev/day]", "INCLINATION": " [deg]", "BSTAR": " [1/ER]"}
KVN = (
    "CCSDS_OMM_VERS = 2.0\nCOMMENT GENERATED VIA SPACE-TRACK.ORG API\nCREATION_DATE = 2008-09-20T13:00:00\n"
    "ORIGINATOR = 18 SPCS\n\n"
    + "".join(f"{k} = {OMM[k]}\n" for k in META)
    + "CENTER_NAME = EARTH\nREF_FRAME = TEME\nTIME_SYSTEM = UTC\nMEAN_ELEMENT_THEORY = SGP4\n"
    + "".join(f"{k} = {v}{UNITS.get(k, '')}\n" for k, v in OMM.items() if k not in META)
)


def _iss_state():
    ts = timescale()
    sat = EarthSatellite(ISS_L1, ISS_L2, ts=ts)
    t = ts.utc(2008, 9, 20, 12, 25, 40.104192)
    return sat.at(t)


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
        {"omm_kvn": KVN},
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


def test_an_opm_state_vector_reads_as_skyfields_osculating_elements():
    """The OPM's state (skyfield's GCRS state of the ISS) gives skyfield's own osculating elements of that state."""
    from skyfield.elementslib import osculating_elements_of

    from app.schemas import OrbitIn
    from app.services.planning import to_orbit

    geo = _iss_state()
    el = to_orbit(OrbitIn.model_validate({"name": "ISS", "opm": opm_kvn(geo.position.km, geo.velocity.km_per_s)}), "x")
    ref = osculating_elements_of(geo, gm_km3_s2=398600.4418)  # the planner's GM (skyfield defaults to DE421's)
    e = el.elements
    assert abs(e.ha_km + 6378.137 - ref.apoapsis_distance.km) < 1e-6
    assert abs(e.hp_km + 6378.137 - ref.periapsis_distance.km) < 1e-6
    assert abs(e.inclination_deg - ref.inclination.degrees) < 1e-9
    assert abs(e.raan_deg - ref.longitude_of_ascending_node.degrees) < 1e-9
    # e = 0.0013: the perigee's direction is ill-conditioned (1e-5 deg is 1.6 mm of a e), their sum is not.
    assert abs((e.arg_perigee_deg - ref.argument_of_periapsis.degrees + 180) % 360 - 180) < 1e-5
    assert abs((e.mean_anomaly_deg - ref.mean_anomaly.degrees + 180) % 360 - 180) < 1e-5
    u = e.arg_perigee_deg + e.mean_anomaly_deg - ref.argument_of_periapsis.degrees - ref.mean_anomaly.degrees
    assert abs((u + 180) % 360 - 180) < 1e-7
    assert e.epoch.isoformat().startswith("2008-09-20T12:25:40.104")


def test_an_opm_and_keplerian_a_e_plan_as_their_elements(client):
    geo = _iss_state()
    body = {"ground_station": STATION, "start": ISS_EPOCH.isoformat(), "duration_days": 1.0}
    r = client.post(
        "/v1/access-windows",
        json={**body, "target": {"name": "ISS", "opm": opm_kvn(geo.position.km, geo.velocity.km_per_s)}},
        headers=A,
    )
    assert r.status_code == 200, r.text
    assert len(r.json()["access_windows"]) >= 3
    mean = client.post(
        "/v1/access-windows",
        json={
            **body,
            "reading": "mean",
            "target": {"name": "ISS", "opm": opm_kvn(geo.position.km, geo.velocity.km_per_s)},
        },
        headers=A,
    )
    assert mean.status_code == 422 and mean.json()["detail"][0]["loc"] == ["body", "reading"]
    # The paper's target as a / e and as Ha / Hp: the same windows.
    heights = {
        "epoch": "2022-11-27T16:00:00Z",
        "ha_km": 700,
        "hp_km": 600,
        "inclination_deg": 43,
        "raan_deg": 290,
        "arg_perigee_deg": 100,
        "mean_anomaly_deg": 200,
    }
    a = 6378.137 + 650.0
    kepler = {
        **{k: v for k, v in heights.items() if k not in ("ha_km", "hp_km")},
        "semi_major_axis_km": a,
        "eccentricity": 50.0 / a,
    }
    got = []
    for el in (heights, kepler):
        r = client.post(
            "/v1/access-windows",
            json={"target": {"name": "T", "elements": el}, "ground_station": STATION, "duration_days": 1.0},
            headers=A,
        )
        assert r.status_code == 200, r.text
        got.append([w["rise"][:22] for w in r.json()["access_windows"]])
    assert got[0] == got[1] and got[0]


BAD = [
    ({"omm": {**OMM, "ECCENTRICITY": 1.5}}, ["body", "target", "omm", "ECCENTRICITY"]),
    ({"omm": {k: v for k, v in OMM.items() if k != "MEAN_MOTION"}}, ["body", "target", "omm", "MEAN_MOTION"]),
    ({"omm": {**OMM, "NORAD_CAT_ID": 9_999_999}}, ["body", "target", "omm", "NORAD_CAT_ID"]),
    ({"omm": {**OMM, "EPOCH": "yesterday"}}, ["body", "target", "omm", "EPOCH"]),
    ({"omm_xml": XML.replace('version="2.0"', 'version="1.0"')}, ["body", "target", "omm_xml", "CCSDS_OMM_VERS"]),
    ({"omm_xml": "<ndm><omm"}, ["body", "target", "omm_xml"]),
    (  # an external entity (XXE) is never resolved: any DTD is refused
        {"omm_xml": XML.replace("<ndm>", '<!DOCTYPE ndm [<!ENTITY x SYSTEM "file:///etc/passwd">]><ndm>')},
        ["body", "target", "omm_xml"],
    ),
    ({"omm_csv": "OBJECT_NAME\nISS\n"}, ["body", "target", "omm_csv", "EPOCH"]),
    ({"tle": ["a", ISS_L1, ISS_L2, ISS_L2]}, ["body", "target", "tle"]),
    ({"tle": f"{ISS_L1}\n"}, ["body", "target", "tle"]),
    ({"tle": [ISS_L1, ISS_L2], "omm": OMM}, ["body", "target"]),
    (
        {"omm_kvn": KVN.replace("CCSDS_OMM_VERS = 2.0", "CCSDS_OMM_VERS = 1.0")},
        ["body", "target", "omm_kvn", "CCSDS_OMM_VERS"],
    ),
    ({"omm_kvn": KVN + "MEAN_MOTION 15.7\n"}, ["body", "target", "omm_kvn"]),
    ({"omm_kvn": KVN + KVN}, ["body", "target", "omm_kvn"]),
    ({"opm": opm_kvn((7000.0, 0, 0), (0, 7.5, 0), frame="ITRF")}, ["body", "target", "opm", "REF_FRAME"]),
    ({"opm": opm_kvn((7000.0, 0, 0), (0, 7.5, 0), version="1.0")}, ["body", "target", "opm", "CCSDS_OPM_VERS"]),
    ({"opm": opm_kvn((7000.0, 0, 0), (0, 12.0, 0))}, ["body", "target", "opm"]),
    ({"opm": opm_kvn((7000.0, 0, 0), (0, 7.5, 0), epoch="soon")}, ["body", "target", "opm", "EPOCH"]),
    ({"opm": opm_kvn((7000.0, 0, 0), (0, 7.5, 0)).replace("Z_DOT", "W_DOT")}, ["body", "target", "opm", "Z_DOT"]),
    (
        {
            "elements": {
                "epoch": "2022-11-27T16:00:00Z",
                "ha_km": 700,
                "hp_km": 600,
                "semi_major_axis_km": 7000,
                "eccentricity": 0.01,
                "inclination_deg": 43,
                "raan_deg": 0,
                "arg_perigee_deg": 0,
                "mean_anomaly_deg": 0,
            }
        },
        ["body", "target", "elements"],
    ),
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


def _windows_named(client, name, target):
    body = {"target": {"name": name, **target}, "ground_station": STATION, "start": ISS_EPOCH.isoformat()}
    return client.post("/v1/access-windows", json={**body, "duration_days": 1.0}, headers=A)


def test_celestraks_json_array_and_a_file_of_several_tles_give_the_one_named(client):
    """CelesTrak serves OMM JSON as an array and TLEs as files of many satellites: the orbit's name (or NORAD
    number) picks one; two that match, or none, is a 422 listing what is there."""
    from tests.utils.orbits import SSO_L1, SSO_L2

    reference = _windows(client, {"tle": [ISS_L1, ISS_L2]})
    decoy = {**OMM, "OBJECT_NAME": "DECOY", "NORAD_CAT_ID": 99999, "MEAN_ANOMALY": 10.0}
    served = [decoy, OMM, {**decoy, "OBJECT_NAME": "DECOY 2", "NORAD_CAT_ID": 99998}]
    text = f"DECOY SSO\n{SSO_L1}\n{SSO_L2}\n0 ISS (ZARYA)\n{ISS_L1}\n{ISS_L2}\n"
    for name, target in (
        ("ISS", {"omm": [OMM]}),
        ("iss  (zarya)", {"omm": served}),
        ("25544", {"omm": served}),
        ("ISS (ZARYA)", {"tle": text}),
        ("25544", {"tle": text.splitlines()}),
    ):
        r = _windows_named(client, name, target)
        assert r.status_code == 200, (name, r.text)
        assert [w["rise"] for w in r.json()["access_windows"]] == [w["rise"] for w in reference], name
    from app.schemas import OrbitIn
    from app.services.planning import to_orbit

    for name in ("43001", "decoy sso"):
        picked = to_orbit(OrbitIn.model_validate({"name": name, "tle": text}), "target").tle
        assert picked is not None and picked.line1 == SSO_L1
    for target, source in (({"omm": served}, "omm"), ({"tle": text}, "tle")):
        r = _windows_named(client, "HUBBLE", target)
        assert r.status_code == 422, r.text
        detail = r.json()["detail"][0]
        assert detail["loc"][-2:] == ["target", source] and "none matches" in detail["msg"]
        assert ("DECOY" in detail["msg"]) and "NORAD" in detail["msg"]


def test_ccsds_day_of_year_epochs_read_as_their_calendar_dates(client):
    """502.0-B-3 allows YYYY-DDDThh:mm:ss epochs: the same OMM and OPM with day 264 of 2008 read as 2008-09-20."""
    from app.schemas import OrbitIn
    from app.services.planning import to_orbit

    reference = _windows(client, {"omm": OMM})
    doy = {**OMM, "EPOCH": "2008-264T12:25:40.104192"}
    assert [w["rise"] for w in _windows(client, {"omm": doy})] == [w["rise"] for w in reference]
    geo = _iss_state()
    calendar_opm = opm_kvn(geo.position.km, geo.velocity.km_per_s)
    doy_opm = calendar_opm.replace("EPOCH = 2008-09-20T12:25:40.104192", "EPOCH = 2008-264T12:25:40.104192Z")
    assert doy_opm != calendar_opm
    a = to_orbit(OrbitIn.model_validate({"name": "x", "opm": calendar_opm}), "target").elements
    b = to_orbit(OrbitIn.model_validate({"name": "x", "opm": doy_opm}), "target").elements
    assert a == b
    bad = _windows_named(client, "ISS", {"omm": {**OMM, "EPOCH": "2023-366T00:00:00"}})
    assert bad.status_code == 422 and bad.json()["detail"][0]["loc"][-1] == "EPOCH"


def _libraryopm_kvn(geo, fmt, epoch="2008-09-20T12:25:40.104192"):
    """An OPM written by ccsds-ndm's own writer from its own data classes (not by the service's writer)."""
    from ccsds_ndm.mapping import NDMFileFormats
    from ccsds_ndm.models.ndmxml4 import ndmxml_4_0_0_common_4_0 as c
    from ccsds_ndm.models.ndmxml4 import ndmxml_4_0_0_opm_3_0 as o
    from ccsds_ndm.models.ndmxml4.ndmxml_4_0_0_master_4_0 import Opm
    from ccsds_ndm.ndm_io import NdmIo

    r, v = geo.position.km, geo.velocity.km_per_s
    km = [c.PositionTypeUo(value=float(x), units=c.PositionUnits.KM) for x in r]
    km_s = [c.VelocityTypeUo(value=float(x), units=c.VelocityUnits.KM_S) for x in v]
    message = Opm(
        header=c.OdmHeader(creation_date="2026-12-05T00:00:00", originator="TEST"),
        body=o.OpmBody(
            segment=o.OpmSegment(
                metadata=o.OpmMetadata(
                    object_name="ISS (ZARYA)",
                    object_id="1998-067A",
                    center_name="EARTH",
                    ref_frame="EME2000",
                    time_system="UTC",
                ),
                data=o.OpmData(
                    state_vector=c.StateVectorType(
                        epoch=epoch, x=km[0], y=km[1], z=km[2], x_dot=km_s[0], y_dot=km_s[1], z_dot=km_s[2]
                    )
                ),
            )
        ),
    )
    return NdmIo().to_string(message, NDMFileFormats.XML if fmt == "xml" else NDMFileFormats.KVN)


def test_an_opm_in_xml_from_the_librarys_writer_reads_as_its_kvn_and_as_skyfields_state(client):
    """CCSDS tools write OPMs in XML too: one from ccsds-ndm's writer (and its day-of-year epoch) gives the elements
    of the same message in KVN and of the hand-written KVN above, and plans the same windows."""
    from app.schemas import OrbitIn
    from app.services.planning import to_orbit

    geo = _iss_state()
    xml = _libraryopm_kvn(geo, "xml")
    assert xml.lstrip().startswith("<?xml") and "<stateVector>" in xml
    read = {
        name: to_orbit(OrbitIn.model_validate({"name": "x", "opm": text}), "target").elements
        for name, text in (
            ("xml", xml),
            ("kvn", _libraryopm_kvn(geo, "kvn")),
            ("hand", opm_kvn(geo.position.km, geo.velocity.km_per_s)),
            ("xml-doy", _libraryopm_kvn(geo, "xml", epoch="2008-264T12:25:40.104192")),
        )
    }
    ref = read["hand"]
    for name, el in read.items():
        assert abs(el.ha_km - ref.ha_km) < 1e-6 and abs(el.raan_deg - ref.raan_deg) < 1e-9, name
        assert abs((el.epoch - ref.epoch).total_seconds()) < 1e-6, name
    rises = [
        [datetime.fromisoformat(w["rise"]) for w in _windows(client, {"opm": text})]
        for text in (xml, opm_kvn(geo.position.km, geo.velocity.km_per_s))  # the hand-written one: 9 decimals
    ]
    assert len(rises[0]) == len(rises[1]) >= 3
    assert max(abs((a - b).total_seconds()) for a, b in zip(*rises, strict=True)) < 1e-3
    # What is not an OPM is refused by name: an OEM's XML, a second message, a broken document.
    oem_xml = '<?xml version="1.0"?><oem id="CCSDS_OEM_VERS" version="3.0"><header/></oem>'
    for text, words in ((oem_xml, "not an OPM"), (xml.replace("<opm", "<opm x").replace("</opm>", ""), "readable")):
        r = _windows_named(client, "ISS", {"opm": text})
        assert r.status_code == 422, r.text
        detail = r.json()["detail"][0]
        assert detail["loc"][-1] == "opm" and words in detail["msg"], detail


def _iss_ephemeris(hours=24.0, step_s=60.0):
    """The ISS by skyfield's SGP4 in GCRS, every ``step_s`` over ``hours`` from its TLE's epoch (epochs, r, v)."""
    from datetime import UTC, timedelta

    ts = timescale()
    sat = EarthSatellite(ISS_L1, ISS_L2, ts=ts)
    t0 = datetime(2008, 9, 20, 12, 25, 40, 104192, tzinfo=UTC)
    epochs = [t0 + timedelta(seconds=s) for s in np.arange(0.0, hours * 3600.0 + 1e-9, step_s)]
    geo = sat.at(ts.from_datetimes(epochs))
    return epochs, geo.position.km.T, geo.velocity.km_per_s.T


def test_an_oem_plans_as_its_first_state_and_says_how_far_j2_departs_from_it(client):
    """An OEM of the ISS (skyfield's SGP4, a day at 60 s, written by hand in KVN) plans exactly as an OPM of its first
    state; the plan's note gives the largest departure of two-body + J2 from the OEM's states, which the independent
    J2 integrator (tests/utils/j2.py) flown from that state measures too."""
    from tests.utils.j2 import propagate_tod_j2
    from tests.utils.orbits import oem_kvn

    epochs, r, v = _iss_ephemeris()
    body = {"ground_station": STATION, "search": {"start": ISS_EPOCH.isoformat(), "duration_days": 1.0}}
    observer = {"name": "OBS", "opm": opm_kvn(r[0] + np.array([0.0, 0.0, 60.0]), v[0])}
    got = {}
    for source, text in (("oem", oem_kvn(epochs, r, v, segments=2)), ("opm", opm_kvn(r[0], v[0]))):
        res = client.post(
            "/v1/plans", json={**body, "observer": observer, "target": {"name": "ISS", source: text}}, headers=A
        )
        assert res.status_code == 201, res.text
        got[source] = res.json()
    assert [w["rise"] for w in got["oem"]["access_windows"]] == [w["rise"] for w in got["opm"]["access_windows"]]
    note = next(n for n in got["oem"]["notes"] if "OEM" in n)
    assert "1 later segment(s)" in note
    claimed = float(note.split("by up to ")[1].split(" km")[0])
    t = np.array([(e - epochs[0]).total_seconds() for e in epochs])
    flown = propagate_tod_j2(epochs[0], r[0], v[0], 0.0, t)
    truth = float(np.max(np.linalg.norm(flown - r.T, axis=0)))
    assert truth > 1.0  # SGP4's drag and higher harmonics: J2 alone departs by kilometres in a day
    assert abs(claimed - truth) < 0.05 * truth, (claimed, truth)


@pytest.mark.parametrize(
    ("change", "field", "words"),
    [
        (lambda t: t.replace("REF_FRAME = GCRF", "REF_FRAME = ITRF"), "REF_FRAME", "EME2000 or GCRF or ICRF"),
        (lambda t: t.replace("CCSDS_OEM_VERS = 3.0", "CCSDS_OEM_VERS = 1.0"), "CCSDS_OEM_VERS", "versions 2.0 and 3.0"),
        (lambda t: t.replace("META_STOP\n", "META_STOP\nthis is not a state\n", 1), "oem", "line"),
        (lambda t: t.replace("CCSDS_OEM_VERS", "CCSDS_OPM_VERS"), "oem", "OPM"),
    ],
)
def test_a_bad_oem_is_refused_naming_what_to_fix(client, change, field, words):
    from tests.utils.orbits import oem_kvn

    epochs, r, v = _iss_ephemeris(hours=1.0)
    body = {"ground_station": STATION, "start": ISS_EPOCH.isoformat(), "duration_days": 1.0}
    res = client.post(
        "/v1/access-windows", json={**body, "target": {"name": "ISS", "oem": change(oem_kvn(epochs, r, v))}}, headers=A
    )
    assert res.status_code == 422, res.text
    d = res.json()["detail"][0]
    assert d["loc"][:3] == ["body", "target", "oem"] and d["loc"][-1] == field and words in d["msg"], d
    mean = client.post(
        "/v1/access-windows",
        json={**body, "reading": "mean", "target": {"name": "ISS", "oem": oem_kvn(epochs, r, v)}},
        headers=A,
    )
    assert mean.status_code == 422 and "OEM" in mean.json()["detail"][0]["msg"]
