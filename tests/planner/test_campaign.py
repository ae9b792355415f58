"""A campaign of scenes: its burn sequence flown again by an independent integrator, its budget, its returns."""

import math
from datetime import timedelta

import numpy as np
import pytest

from planner.alignment import Candidate
from planner.campaign import (
    CampaignOptions,
    _tangential,
    height_change,
    plan_campaign,
    spread_order,
)
from planner.elements import elements_to_state, height_change_dv_km_s, state_to_elements
from planner.errors import PlannerError
from planner.examples import PAPER_EPOCH, PAPER_OBSERVER, PAPER_STATION, PAPER_TARGET
from planner.illumination import sun_position_km, sunlit
from planner.orbits import Orbit
from planner.plan import Feasibility, PlanOptions
from planner.propagation import NumericalJ2Trajectory
from tests.utils.j2 import fly_tod_j2

START = PAPER_EPOCH + timedelta(days=18)  # the paper's first ten days have the target in Earth's shadow throughout
ONE_METRE_KM = 1e-3


def _campaign(**kwargs):
    options = CampaignOptions(start=START, **kwargs)
    return plan_campaign(Orbit("T", PAPER_TARGET), Orbit("O", PAPER_OBSERVER), PAPER_STATION, options)


@pytest.fixture(scope="module")
def campaign():
    return _campaign(duration_s=21 * 86400.0)


@pytest.fixture(scope="module")
def returning():
    return _campaign(duration_s=10 * 86400.0, return_to_orbit=True)


def _target_independent(epoch, t):
    """The target by the independent integrator, from its Table-1 elements at the paper's epoch."""
    r0, v0 = elements_to_state(*PAPER_TARGET.radians())
    t0 = -(epoch - PAPER_EPOCH).total_seconds()
    assert t0 < float(np.min(t))  # flown forward, no burn: the integrator's own state at each time
    return fly_tod_j2(epoch, r0, v0, t0, [], t)


def test_the_whole_burn_sequence_flown_by_an_independent_integrator(campaign):
    """Every burn flown again from the campaign's start by solve_ivp with J2 about skyfield's true-of-date axis:
    the observer agrees with ours to 50 m at every burn and T_access after three weeks and four scenes, and each
    scene's separation, line-of-sight rate and illumination measured on that flight are what the campaign says."""
    assert len(campaign.scenes) >= 3
    burns = [(b.t_s, np.array(b.dv_km_s)) for b in campaign.burns]
    t_access = np.array([s.t_access_s for s in campaign.scenes])
    t = np.concatenate([t_access, [b[0] for b in burns]])
    r_ref, v_ref = fly_tod_j2(campaign.epoch, *campaign.initial_state, 0.0, burns, t)
    r_ours, _ = campaign.flown.state(t)
    assert np.linalg.norm(r_ref - r_ours, axis=0).max() < 50 * ONE_METRE_KM

    r_t, v_t = _target_independent(campaign.epoch, t_access)
    n = len(campaign.scenes)
    rho = r_t - r_ref[:, :n]
    rho_dot = v_t - v_ref[:, :n]
    separation = np.linalg.norm(rho, axis=0)
    rate = np.degrees(np.linalg.norm(np.cross(rho, rho_dot, axis=0), axis=0) / separation**2)
    lit = sunlit(r_t, sun_position_km(campaign.epoch, t_access))
    optics = campaign.options.plan.optics
    for k, scene in enumerate(campaign.scenes):
        assert scene.check.separation_km == pytest.approx(separation[k], abs=0.05)
        assert scene.check.target_angular_rate_deg_s == pytest.approx(rate[k], abs=0.02)
        assert scene.check.sunlit == bool(lit[k])
        # What makes each scene feasible holds on the independent flight.
        assert lit[k] and rate[k] < optics.max_rate_deg_s and separation[k] < optics.max_range_km
        assert scene.feasibility.feasible


def test_scenes_follow_one_another_within_the_budget(campaign):
    budget = campaign.options.dv_budget_m_s / 1000.0
    assert campaign.dv_total_km_s <= budget
    assert campaign.dv_total_km_s == pytest.approx(sum(b.dv_total_km_s for b in campaign.burns))
    last = -math.inf
    for scene in campaign.scenes:
        assert scene.dv_total_km_s == pytest.approx(sum(b.dv_total_km_s for b in scene.burns))
        assert all(b.t_s > last for b in scene.burns)  # a scene's burns come after the previous scene's fly-by
        assert min(b.t_s for b in scene.burns) < scene.t_access_s
        last = max(scene.t_access_s, *(b.t_s for b in scene.burns))
    times = [b.t_s for b in campaign.burns]
    assert times == sorted(times)


def test_scenes_spread_their_imaging_geometry(campaign):
    """Each scene's line of sight (in the target's orbital frame) is a unit vector, and no two are the same."""
    los = np.array([s.feasibility.line_of_sight_rtn for s in campaign.scenes])
    assert np.allclose(np.linalg.norm(los, axis=1), 1.0)
    angles = np.degrees(np.arccos(np.clip(los @ los.T, -1.0, 1.0)))
    assert angles[~np.eye(len(los), dtype=bool)].min() > 1.0


def test_a_return_puts_the_observer_back_on_its_original_orbit(returning):
    """After its return the observer (flown independently through every burn) is where it would have been,
    shifted along its orbit by the slot shift reported, to 50 m and 5 cm/s."""
    assert returning.scenes, "the return campaign planned no scene"
    scene = returning.scenes[0]
    kinds = [b.kind for b in scene.burns]
    assert kinds[-2:] == ["return", "arrival"]
    arrival = scene.burns[-1]
    burns = [(b.t_s, np.array(b.dv_km_s)) for b in returning.burns]
    r_ref, v_ref = fly_tod_j2(returning.epoch, *returning.initial_state, 0.0, burns, [arrival.t_s + 600.0])
    shifted = arrival.t_s + 600.0 + scene.slot_shift_s
    r_orig, v_orig = fly_tod_j2(returning.epoch, *returning.initial_state, 0.0, [], [shifted])
    assert np.linalg.norm(r_ref - r_orig) < 50 * ONE_METRE_KM
    assert np.linalg.norm(v_ref - v_orig) < 5e-5
    assert returning.dv_total_km_s <= returning.options.dv_budget_m_s / 1000.0


def test_a_tangential_burn_puts_the_other_apsis_where_vis_viva_says():
    """At perigee (mean anomaly 0) the burn's point stays an apsis and the other goes where it was asked."""
    a0, e0, i, raan, argp, _ = PAPER_OBSERVER.radians()
    r, v = elements_to_state(a0, e0, i, raan, argp, 0.0)
    apogee = a0 * (1 + e0)
    assert np.linalg.norm(_tangential(r, v, apogee, 0.0)) == 0.0
    for other in (6900.0, 7200.0, 8000.0):
        dv = _tangential(r, v, apogee, other - apogee)
        assert abs(np.dot(dv, v)) == pytest.approx(np.linalg.norm(dv) * np.linalg.norm(v))  # along the velocity
        a, e, *_ = state_to_elements(r, v + dv)
        rn = np.linalg.norm(r)
        apsides = sorted((float(a * (1 - e)), float(a * (1 + e))))
        closest = min(apsides, key=lambda x: abs(x - other))
        assert closest == pytest.approx(other, abs=1e-6)
        assert min(apsides, key=lambda x: abs(x - rn)) == pytest.approx(rn, abs=1e-6)


def test_the_height_change_is_two_burns_costing_what_the_plan_reckons():
    r0, v0 = elements_to_state(*PAPER_OBSERVER.radians())
    span = 3 * 6000.0
    base = NumericalJ2Trajectory(r0, v0, 0.0, span)
    for dha, dhp in ((20.0, -10.0), (-15.0, 5.0), (0.0, 12.5)):
        changed, ready, burns = height_change(r0, v0, base, 0.0, span, dha, dhp, None)
        assert [b[2] for b in burns] == (["apogee"] if dha == 0.0 else ["perigee", "apogee"])
        total = sum(float(np.linalg.norm(b[1])) for b in burns)
        a, e = PAPER_OBSERVER.a_km, PAPER_OBSERVER.e
        assert total == pytest.approx(float(height_change_dv_km_s(a, e, dha, dhp)), rel=0.05)
        assert 0.0 < ready < 1.6 * 6000.0
        # After the change, the osculating apsides sit where the unchanged orbit's do at the same moment, moved
        # by what was asked (to J2's differing wobble on the two orbits).
        for t in (ready + 1.0, ready + 2000.0, ready + 4000.0):
            r, v = changed.state(t)
            rb, vb = base.state(t)
            a1, e1, *_ = state_to_elements(r[:, 0], v[:, 0])
            a0, e0, *_ = state_to_elements(rb[:, 0], vb[:, 0])
            assert float(a1 * (1 + e1) - a0 * (1 + e0)) == pytest.approx(dha, abs=1.0)
            assert float(a1 * (1 - e1) - a0 * (1 - e0)) == pytest.approx(dhp, abs=1.0)


def _feas(dv_m_s, los, feasible=True):
    return Feasibility(True, 50.0, 10.0, feasible, (), 90.0, dv_m_s / 1000.0, 50.0, 10.0, 9.0, los)


def test_the_spread_order_prefers_a_new_line_of_sight_among_nearly_as_cheap_scenes():
    cand = [Candidate(0, "+OC", 0.0, 0.0, 0.0, 0.0, 0.0, None, np.zeros(1), np.zeros(1))] * 4
    feas = [
        _feas(100.0, (1.0, 0.0, 0.0)),  # the cheapest, the same side as before
        _feas(110.0, (0.0, 1.0, 0.0)),  # nearly as cheap, a new side
        _feas(300.0, (0.0, 0.0, 1.0)),  # a new side, far dearer
        _feas(50.0, (0.0, 0.0, -1.0), feasible=False),
    ]
    assert spread_order([])(cand, feas)[0] == 0
    assert spread_order([(1.0, 0.0, 0.0)])(cand, feas)[:3] == [1, 0, 2]


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"duration_s": 91 * 86400.0}, "duration_days"),
        ({"dv_budget_m_s": -1.0}, "dv_budget_m_s"),
        ({"scene_span_s": 3600.0}, "scene_span_days"),
        ({"plan": PlanOptions(reading="mean")}, "reading"),
    ],
)
def test_bad_campaign_options_name_their_field(kwargs, field):
    with pytest.raises(PlannerError) as err:
        CampaignOptions(**kwargs)
    assert err.value.field == field


def test_a_stretch_without_a_scene_says_why():
    """The paper's first ten days: every candidate has the target in Earth's shadow."""
    c = plan_campaign(
        Orbit("T", PAPER_TARGET),
        Orbit("O", PAPER_OBSERVER),
        PAPER_STATION,
        CampaignOptions(start=PAPER_EPOCH, duration_s=10 * 86400.0),
    )
    assert not c.scenes and not c.burns and c.dv_total_km_s == 0.0
    assert "target in Earth's shadow" in c.stretches[0].note
    assert c.stretches[0].candidates > 0 and c.stretches[0].feasible == 0
