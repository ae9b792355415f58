"""A campaign flown with errors: no errors lands every sample on its aim for nothing; small errors scale the trims in
proportion (a linear law); the paper's campaign at 10 m / 1 cm/s navigation and 1 % / 0.1 deg burns meets the
goal (every scene 90 % feasible, trims within 10 % of the budget)."""

from datetime import timedelta

import pytest

from planner.campaign import CampaignOptions, plan_campaign
from planner.dispersion import DispersionOptions, disperse, disperse_scene, trim_margin_km_s, trim_times
from planner.errors import SearchRangeError
from planner.examples import PAPER_EPOCH, PAPER_OBSERVER, PAPER_STATION, PAPER_TARGET
from planner.orbits import Orbit

QUIET = {
    "position_sigma_km": 0.0,
    "velocity_sigma_km_s": 0.0,
    "burn_magnitude_sigma": 0.0,
    "burn_pointing_sigma_deg": 0.0,
}


@pytest.fixture(scope="module")
def campaign():
    options = CampaignOptions(start=PAPER_EPOCH + timedelta(days=18), duration_s=21 * 86400.0)
    return plan_campaign(Orbit("T", PAPER_TARGET), Orbit("O", PAPER_OBSERVER), PAPER_STATION, options)


def test_without_errors_every_sample_lands_on_its_aim_for_nothing(campaign):
    d = disperse_scene(campaign, campaign.scenes[1], DispersionOptions(samples=3, **QUIET))
    assert d.feasible_share == 1.0 and d.failed == 0
    assert d.trim_max_km_s < 1e-6 and d.miss_p95_km < 1e-3


def test_trims_grow_in_proportion_to_the_burn_error(campaign):
    """Small errors are linear: twice the burn's magnitude error, twice the trims (same draws)."""
    scene = campaign.scenes[1]
    one = disperse_scene(campaign, scene, DispersionOptions(samples=12, **{**QUIET, "burn_magnitude_sigma": 0.005}))
    two = disperse_scene(campaign, scene, DispersionOptions(samples=12, **{**QUIET, "burn_magnitude_sigma": 0.01}))
    assert two.trim_p95_km_s / one.trim_p95_km_s == pytest.approx(2.0, rel=0.1)


def test_the_paper_campaign_meets_the_dispersion_goal(campaign):
    """Every scene at least 90 % feasible with all trims within 10 % of the budget (20 samples a scene)."""
    result = disperse(campaign, DispersionOptions(samples=20))
    assert len(result) == len(campaign.scenes)
    assert all(d.feasible_share >= 0.9 for d in result), result
    assert trim_margin_km_s(result) * 1000.0 <= 0.1 * campaign.options.dv_budget_m_s


def test_trims_come_a_quarter_revolution_plus_whole_ones_before_the_scene():
    first, last = trim_times(0.0, 12000.0, 5700.0, 2700.0)
    assert (12000.0 - first) / 5700.0 == pytest.approx(1.25) and (12000.0 - last) / 5700.0 == pytest.approx(0.25)
    assert trim_times(0.0, 3000.0, 5700.0, 2700.0) == [1500.0]  # no room: the middle of the approach


@pytest.mark.parametrize("field", ["samples", "position_sigma_km", "burn_pointing_sigma_deg", "trim_coast_s"])
def test_errors_out_of_range_are_refused_by_name(field):
    with pytest.raises(SearchRangeError) as info:
        DispersionOptions(**{field: -1})
    assert info.value.field == f"dispersion.{field}"
