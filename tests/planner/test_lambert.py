import numpy as np
import pytest

from planner.constants import MU_EARTH_KM3_S2
from planner.elements import elements_to_state, state_to_elements
from planner.errors import LambertError
from planner.lambert import lambert, max_revolutions


def test_vallado_example_7_5():
    # Vallado, Fundamentals of Astrodynamics, example 7-5 (as used by poliastro's tests).
    sol = lambert([15945.34, 0.0, 0.0], [12214.83899, 10249.46731, 0.0], 76.0 * 60.0)
    np.testing.assert_allclose(sol.v1_km_s, [2.058913, 2.915965, 0.0], atol=1e-5)
    np.testing.assert_allclose(sol.v2_km_s, [-3.451565, 0.910315, 0.0], atol=1e-5)


def _kepler(r, v, dt):
    a, e, i, raan, argp, m = state_to_elements(r, v)
    n = np.sqrt(MU_EARTH_KM3_S2 / a**3)
    return elements_to_state(a, e, i, raan, argp, m + n * dt)


@pytest.mark.parametrize("revs", [0, 1, 2])
@pytest.mark.parametrize("low", [True, False])
def test_multi_revolution_round_trip(revs, low):
    r1, v1 = elements_to_state(7000.0, 0.01, 0.5, 0.3, 0.2, 0.0)
    r2, _ = elements_to_state(7100.0, 0.02, 0.5, 0.3, 0.2, 2.0)
    tof = 3 * 5900.0
    sol = lambert(r1, r2, tof, revs, low, prograde_normal=np.cross(r1, v1))
    r_end, v_end = _kepler(r1, sol.v1_km_s, tof)
    assert np.linalg.norm(r_end - r2) < 1e-6  # 1 mm
    np.testing.assert_allclose(v_end, sol.v2_km_s, atol=1e-9)
    # Stays prograde with respect to the departure orbit.
    assert np.cross(r1, sol.v1_km_s) @ np.cross(r1, v1) > 0


def test_too_many_revolutions_is_refused():
    r1, _ = elements_to_state(7000.0, 0.01, 0.5, 0.3, 0.2, 0.0)
    r2, _ = elements_to_state(7100.0, 0.02, 0.5, 0.3, 0.2, 2.0)
    assert max_revolutions(r1, r2, 3 * 5900.0) == 2
    with pytest.raises(LambertError, match="at most 2"):
        lambert(r1, r2, 3 * 5900.0, revolutions=3)


def test_retrograde_option_reverses_sense():
    r1, r2 = np.array([7000.0, 0, 0]), np.array([0, 7000.0, 0])
    pro = lambert(r1, r2, 1500.0)
    retro = lambert(r1, r2, 1500.0, prograde_normal=(0, 0, -1))
    assert np.cross(r1, pro.v1_km_s)[2] > 0 > np.cross(r1, retro.v1_km_s)[2]
