"""A scene's placements against skyfield's own vectors, its windows against the service's, its refusals."""

from datetime import timedelta

import numpy as np
import pytest
from skyfield.api import EarthSatellite, wgs84

from app.schemas import PAPER_EXAMPLE, AccessCreate
from app.services.planning import run_access
from app.services.scenes import scene_for, windows_of
from planner.examples import PAPER_STATION, PAPER_TARGET
from planner.orbits import Orbit
from planner.propagation import skyfield_times, timescale
from planner.tle import parse_tle
from scene import Scene, SceneError
from scene.geometry import access_windows
from tests.utils.orbits import ISS_EPOCH, ISS_L1, ISS_L2

SITE = (40.0, -75.0, 100.0)  # lat, lon (deg), altitude (m)
ten_microradians = 1e-5


def _skyfield_los_in_lvlh(times):
    """The unit line of sight, target to station, in the target's LVLH axes (radial, along-track, normal)."""
    sat = EarthSatellite(ISS_L1, ISS_L2, ts=timescale())
    site = wgs84.latlon(*SITE)
    t = skyfield_times(ISS_EPOCH, np.array([(x - ISS_EPOCH).total_seconds() for x in times]))
    state = sat.at(t)
    r, v = state.position.km, state.velocity.km_per_s
    los = -(sat - site).at(t).position.km
    out, axes = [], []
    for k in range(len(times)):
        x = r[:, k] / np.linalg.norm(r[:, k])
        z = np.cross(r[:, k], v[:, k])
        z /= np.linalg.norm(z)
        a = np.stack([x, np.cross(z, x), z], axis=1)
        axes.append(a)
        out.append(a.T @ los[:, k] / np.linalg.norm(los[:, k]))
    return np.array(out), np.array(axes)


def test_placements_against_skyfield():
    """LVLH axes, the line of sight and its rate (a central difference of skyfield's over 0.1 s) at five moments of
    an ISS pass over a mid-latitude station, all from one scene."""
    from planner.propagation import Station

    station = Station(*SITE)
    windows = access_windows(Orbit("ISS", tle=parse_tle(ISS_L1, ISS_L2)), station, "osculating", ISS_EPOCH, 86400.0)
    w = max(windows, key=lambda x: x.max_elevation_deg)
    scene = Scene.over(Orbit("ISS", tle=parse_tle(ISS_L1, ISS_L2)), station, "osculating", w.rise, w.set)
    times = [w.rise + (w.set - w.rise) * f for f in (0.1, 0.3, 0.5, 0.7, 0.9)]
    placed = scene.placements(times)
    los, axes = _skyfield_los_in_lvlh(times)
    np.testing.assert_allclose(placed.lvlh, axes, atol=ten_microradians)
    np.testing.assert_allclose(placed.los_lvlh, los, atol=ten_microradians)
    ahead = _skyfield_los_in_lvlh([t + timedelta(seconds=0.05) for t in times])[0]
    behind = _skyfield_los_in_lvlh([t - timedelta(seconds=0.05) for t in times])[0]
    rate = (ahead - behind) / 0.1
    np.testing.assert_allclose(placed.los_rate_lvlh, rate, atol=1e-6, rtol=1e-3)
    for k in range(len(times)):  # the observation frame: X the line of sight, Y along its rate, right-handed
        obs = placed.observation_in_lvlh(k)
        np.testing.assert_allclose(obs[:, 0], los[k], atol=ten_microradians)
        y = rate[k] - (rate[k] @ los[k]) * los[k]
        np.testing.assert_allclose(obs[:, 1], y / np.linalg.norm(y), atol=1e-3)
        assert np.linalg.det(obs) == pytest.approx(1.0, abs=1e-12)
    # A body held at identity in its observation frame is, in LVLH, the observation axes themselves.
    body_lvlh, body_j2000 = placed.attitudes(2, np.eye(3))
    np.testing.assert_allclose(body_lvlh, placed.observation_in_lvlh(2), atol=1e-12)
    np.testing.assert_allclose(body_j2000, placed.observation[2], atol=1e-12)


def test_the_scenes_windows_are_the_services_and_the_paper_example_is_one_scene():
    """The scene's access search from the planner's Table 1 objects gives the windows the service answers for
    PAPER_EXAMPLE (its JSON twin), to the microsecond."""
    mine = access_windows(
        Orbit("Sat_Target", elements=PAPER_TARGET), PAPER_STATION, "osculating", PAPER_TARGET.epoch, 86400.0
    )
    req = AccessCreate.model_validate(
        {"target": PAPER_EXAMPLE["target"], "ground_station": PAPER_EXAMPLE["ground_station"], "duration_days": 1}
    )
    theirs = windows_of(run_access(req))
    assert len(mine) == len(theirs) >= 3
    for a, b in zip(mine, theirs, strict=True):
        assert abs((a.rise - b.rise).total_seconds()) < 1e-6 and abs((a.set - b.set).total_seconds()) < 1e-6
        assert a.max_elevation_deg == pytest.approx(b.max_elevation_deg, abs=1e-9)
    converted = scene_for(PAPER_EXAMPLE, mine[0].rise, mine[0].set)
    assert converted.target.elements == PAPER_TARGET and converted.station == PAPER_STATION


def test_a_scene_refuses_a_span_it_cannot_hold():
    target = Orbit("Sat_Target", elements=PAPER_TARGET)
    start = PAPER_TARGET.epoch + timedelta(days=1)
    with pytest.raises(SceneError) as e:
        Scene.over(target, PAPER_STATION, "osculating", start, start - timedelta(seconds=1))
    assert e.value.loc == ["observed_at"] and "before it starts" in e.value.message
    far = PAPER_TARGET.epoch + timedelta(days=61)
    with pytest.raises(SceneError) as e:
        Scene.over(target, PAPER_STATION, "osculating", far, far, field="window")
    assert e.value.loc == ["window"] and "60 days" in e.value.message
