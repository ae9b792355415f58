"""A plan over a network of radars: every station's passes searched at once, each candidate naming its radar; the
same as planning each station alone and taking the cheapest feasible scene across them."""

import numpy as np
import pytest
from skyfield.api import wgs84

from planner.errors import StationError
from planner.examples import PAPER_EPOCH, PAPER_OBSERVER, PAPER_TARGET
from planner.orbits import Orbit
from planner.plan import PlanOptions, make_plan
from planner.propagation import Station, skyfield_times

SHANGHAI = Station(31.1, 121.3, 0.0, 0.0, name="Shanghai")
TIRA = Station(50.6166, 7.1296, 307.0, 5.0, name="Tira")
OPTS = PlanOptions(start=PAPER_EPOCH, duration_s=10 * 86400.0)
TARGET, OBSERVER = Orbit("T", PAPER_TARGET), Orbit("O", PAPER_OBSERVER)


@pytest.fixture(scope="module")
def plans():
    return {
        "network": make_plan(TARGET, OBSERVER, [SHANGHAI, TIRA], OPTS),
        "Shanghai": make_plan(TARGET, OBSERVER, SHANGHAI, OPTS),
        "Tira": make_plan(TARGET, OBSERVER, TIRA, OPTS),
    }


def _key(plan, k):
    c = plan.candidates[k]
    return round(c.t_access_s, 2), plan.stations[plan.windows.station_of(c.pass_index)].name


def test_a_network_is_every_station_planned_alone(plans):
    net = plans["network"]
    assert len(net.windows) == len(plans["Shanghai"].windows) + len(plans["Tira"].windows)
    assert np.all(np.diff(net.windows.rise_s) >= 0)  # one set in time order
    alone = {}
    for name in ("Shanghai", "Tira"):
        p = plans[name]
        for k in range(len(p.candidates)):
            alone[(round(p.candidates[k].t_access_s, 2), name)] = p.feasibility[k]
    together = {_key(net, k): net.feasibility[k] for k in range(len(net.candidates))}
    assert together.keys() == alone.keys()
    # A chosen candidate's figures are its verified burn's, the others' their screening's: compare the screened ones.
    chosen = {_key(p, p.chosen_index) for p in plans.values() if p.chosen_index is not None}
    for key, f in together.items():
        if key in chosen:
            continue
        g = alone[key]
        assert f.reasons == g.reasons and f.feasible == g.feasible, key
        assert f.radar_elevation_deg == pytest.approx(g.radar_elevation_deg, abs=1e-9)
        assert f.dv_total_km_s == pytest.approx(g.dv_total_km_s, rel=1e-9, nan_ok=True)
    # The chosen scene is the cheapest feasible one across both radars.
    feasible = [
        (p.chosen_feasibility.dv_total_km_s, n)
        for n, p in plans.items()
        if n != "network" and p.chosen_feasibility.feasible
    ]
    if feasible:
        best_dv, best_station = min(feasible)
        assert net.chosen_feasibility.feasible
        assert net.chosen_feasibility.dv_total_km_s == pytest.approx(best_dv, rel=1e-9)
        assert net.station.name == best_station


def test_each_candidates_radar_elevation_is_its_own_stations(plans):
    """Against skyfield's altazimuth frame at the candidate's own station (the target's GCRS position from the plan)."""
    net = plans["network"]
    seen = set()
    for k, c in enumerate(net.candidates):
        st = net.stations[net.windows.station_of(c.pass_index)]
        seen.add(st.name)
        t = skyfield_times(net.epoch, np.array([c.t_access_s]))
        site = wgs84.latlon(st.latitude_deg, st.longitude_deg, st.altitude_m)
        rel = net.target_trajectory.state(c.t_access_s)[0][:, 0] - site.at(t).position.km[:, 0]
        up = (site.rotation_at(t)[:, :, 0] @ rel)[2]
        assert net.feasibility[k].radar_elevation_deg == pytest.approx(
            np.degrees(np.arcsin(up / np.linalg.norm(rel))), abs=0.01
        )
    assert seen == {"Shanghai", "Tira"}


def test_an_empty_network_is_refused():
    with pytest.raises(StationError) as info:
        make_plan(TARGET, OBSERVER, [], OPTS)
    assert info.value.field == "ground_stations"
