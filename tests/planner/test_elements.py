import math

import numpy as np
import pytest

from planner.constants import J2, MU_EARTH_KM3_S2, R_EARTH_KM
from planner.elements import (
    Elements,
    elements_to_state,
    height_change_dv_km_s,
    j2_secular_rates,
    raan_rate_change_rad_s,
    secular_state,
    state_to_elements,
)
from planner.errors import ElementsError
from tests.utils.orbits import PAPER_EPOCH, PAPER_TARGET


def test_sun_synchronous_raan_rate():
    # Vallado, "Fundamentals of Astrodynamics" (4th ed.), sec. 9.6: a sun-synchronous orbit
    # at 800 km altitude, circular, needs i = 98.6 deg for +0.9856 deg/day.
    a = R_EARTH_KM + 800.0
    raan_dot, _, _ = j2_secular_rates(a, 0.0, math.radians(98.6))
    assert math.degrees(float(raan_dot)) * 86400.0 == pytest.approx(0.9856, abs=0.005)


def test_critical_inclination_freezes_perigee():
    _, argp_dot, _ = j2_secular_rates(7000.0, 0.01, math.radians(63.4349))
    assert abs(float(argp_dot)) < 1e-11


def test_secular_rates_array_matches_scalar():
    a = np.array([7000.0, 7500.0])
    scalars = [j2_secular_rates(x, 0.01, 1.0)[0] for x in a]
    arr, _, _ = j2_secular_rates(a, 0.01, 1.0)
    np.testing.assert_allclose(arr, scalars, rtol=0, atol=0)


def test_state_round_trip_scalar_and_array():
    r, v = elements_to_state(7000.0, 0.1, 0.9, 2.0, 3.0, 4.0)
    out = state_to_elements(r, v)
    np.testing.assert_allclose([float(x) for x in out], [7000.0, 0.1, 0.9, 2.0, 3.0, 4.0], rtol=1e-11)
    m = np.linspace(0.1, 6.2, 7)
    r, v = elements_to_state(7000.0, 0.1, 0.9, 2.0, 3.0, m)
    assert r.shape == (3, 7)
    np.testing.assert_allclose(state_to_elements(r, v)[5], m, atol=1e-10)


def test_vis_viva_energy():
    r, v = elements_to_state(8000.0, 0.2, 0.3, 0.0, 0.0, 1.0)
    energy = 0.5 * v @ v - MU_EARTH_KM3_S2 / np.linalg.norm(r)
    assert energy == pytest.approx(-MU_EARTH_KM3_S2 / 16000.0, rel=1e-12)


def test_secular_state_moves_node_at_the_j2_rate():
    rad = PAPER_TARGET.radians()
    r, v = secular_state(rad, [0.0, 86400.0])
    _, _, _, raan, _, _ = state_to_elements(r, v)
    expected = float(j2_secular_rates(rad[0], rad[1], rad[2])[0]) * 86400.0
    assert float(raan[1] - raan[0]) == pytest.approx(expected, rel=1e-9)


def test_raan_rate_change_is_the_difference_of_rates():
    el = PAPER_TARGET
    a, e, i = el.a_km, el.e, math.radians(el.inclination_deg)
    changed = el.with_heights(19.0, 29.3)
    base = j2_secular_rates(a, e, i)[0]
    new = j2_secular_rates(changed.a_km, changed.e, i)[0]
    assert float(raan_rate_change_rad_s(a, e, i, 19.0, 29.3)) == pytest.approx(float(new - base), rel=1e-12)
    # Raising the orbit slows the (westward) precession of a prograde orbit.
    assert float(raan_rate_change_rad_s(a, e, i, 20.0, 20.0)) > 0


def test_j2_constant_is_the_design_value():
    assert J2 == 1.08262668e-3


def test_height_change_dv_matches_hohmann():
    # Raising a circular 7000 km orbit to 7100 km: the Hohmann transfer's two burns.
    mu = MU_EARTH_KM3_S2
    r1, r2 = 7000.0, 7100.0
    at = 0.5 * (r1 + r2)
    hohmann = (math.sqrt(mu * (2 / r1 - 1 / at)) - math.sqrt(mu / r1)) + (
        math.sqrt(mu / r2) - math.sqrt(mu * (2 / r2 - 1 / at))
    )
    assert float(height_change_dv_km_s(r1, 0.0, 100.0, 100.0)) == pytest.approx(hohmann, rel=1e-12)


@pytest.mark.parametrize(
    ("field", "kwargs"),
    [
        ("hp_km", dict(hp_km=80.0)),
        ("ha_km", dict(ha_km=500.0, hp_km=600.0)),
        ("inclination_deg", dict(inclination_deg=181.0)),
        ("raan_deg", dict(raan_deg=math.nan)),
    ],
)
def test_bad_elements_name_the_field(field, kwargs):
    base = dict(
        epoch=PAPER_EPOCH,
        ha_km=700.0,
        hp_km=600.0,
        inclination_deg=43.0,
        raan_deg=0.0,
        arg_perigee_deg=0.0,
        mean_anomaly_deg=0.0,
    )
    base.update(kwargs)
    with pytest.raises(ElementsError) as err:
        Elements(**base)
    assert err.value.field == field


def test_with_heights_swaps_apsides_when_needed():
    el = PAPER_TARGET.with_heights(-100.0, 0.0)  # 600 / 600: still ordered
    assert el.ha_km == el.hp_km == 600.0
    swapped = PAPER_TARGET.with_heights(-150.0, 0.0)
    assert (swapped.ha_km, swapped.hp_km) == (600.0, 550.0)
    assert swapped.arg_perigee_deg == pytest.approx(280.0)
