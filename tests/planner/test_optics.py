"""The optics' limits against their physics: the Airy pattern's first zero, a straight fly-by flown numerically."""

import math

import numpy as np
import pytest
from scipy.special import jn_zeros

from planner.errors import PlannerError
from planner.optics import ObserverOptics, diffraction_range_km, standoff_window, sun_angle_deg


def test_the_diffraction_range_is_the_airy_patterns_first_zero():
    """The first dark ring of a circular aperture lies at sin(theta) = j1,1 / (pi D / lambda) (Born & Wolf 8.5):
    the range at which that angle spans the ground sample distance."""
    theta = jn_zeros(1, 1)[0] / math.pi * 550e-9 / 0.3
    assert diffraction_range_km(0.25, 0.3, 550.0) == pytest.approx(0.25 / math.tan(theta) / 1000.0, rel=2e-3)
    assert ObserverOptics().max_range_km == pytest.approx(111.8, abs=0.05)
    assert ObserverOptics(aperture_m=0.6).max_range_km == pytest.approx(2 * 111.8, abs=0.1)  # linear in D


@pytest.mark.parametrize("speed_km_s", [8.0, 13.4])
def test_the_tracking_limit_is_what_a_straight_fly_by_turns(speed_km_s):
    """A fly-by flown on a fine time grid: at the window's lower end the line of sight turns at most at the
    optics' rate, and 1 % closer it turns faster than it."""
    optics = ObserverOptics()
    w = standoff_window(speed_km_s, optics)
    t = np.linspace(-60.0, 60.0, 240_001)

    def peak_rate_deg_s(d_km):
        r = np.stack([np.full_like(t, d_km), speed_km_s * t, np.zeros_like(t)])
        v = np.stack([np.zeros_like(t), np.full_like(t, speed_km_s), np.zeros_like(t)])
        rate = np.linalg.norm(np.cross(r, v, axis=0), axis=0) / np.sum(r * r, axis=0)
        return math.degrees(float(rate.max()))

    assert peak_rate_deg_s(w.low_km) == pytest.approx(optics.max_rate_deg_s, rel=1e-9)
    assert peak_rate_deg_s(0.99 * w.low_km) > optics.max_rate_deg_s
    assert w.feasible and w.low_km < w.choose_km() <= w.high_km


def test_an_empty_window_names_both_limits_with_numbers():
    w = standoff_window(13.4, ObserverOptics(max_rate_deg_s=5.7))
    assert not w.feasible and w.choose_km() == w.high_km
    assert w.reasons == ("5.7 deg/s needs >= 134.7 km at 13.4 km/s; the optics resolve 0.25 m only within 111.8 km",)


def test_the_boresight_is_measured_from_the_sun():
    target = np.array([7000.0, 0.0, 0.0])
    sun = np.array([0.0, 1.496e8, 0.0])
    assert sun_angle_deg(target + [0.0, -50.0, 0.0], target, sun) == pytest.approx(0.0, abs=0.01)  # looking sunward
    assert sun_angle_deg(target + [0.0, 50.0, 0.0], target, sun) == pytest.approx(180.0, abs=0.01)  # Sun behind


@pytest.mark.parametrize(
    "field,value",
    [
        ("aperture_m", 0.0),
        ("wavelength_nm", float("nan")),
        ("gsd_m", -1.0),
        ("max_rate_deg_s", 0.0),
        ("sun_exclusion_deg", 180.0),
    ],
)
def test_optics_out_of_physical_range_name_the_field(field, value):
    with pytest.raises(PlannerError) as e:
        ObserverOptics(**{field: value})
    assert e.value.field == field
