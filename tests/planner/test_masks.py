"""Azimuth-dependent horizon masks and atmospheric refraction, against skyfield's own look angles.

The references: skyfield's topocentric altitude and azimuth on a 1-s grid (with its own
refraction model, ``altaz(temperature_C, pressure_mbar)``, where refraction is on), the mask
interpolated by the test itself, every crossing refined by brentq. Nothing of planner.access is used.
"""

import numpy as np
import pytest
from scipy.optimize import brentq
from skyfield.api import EarthSatellite, wgs84
from skyfield.earthlib import refract

from planner.access import access_windows, refraction_deg
from planner.errors import StationError
from planner.propagation import EarthFrames, SGP4Trajectory, Station, skyfield_times, timescale
from planner.tle import parse_tle
from tests.utils.orbits import ISS_EPOCH, ISS_L1, ISS_L2

SITE = (31.1, 121.3, 0.0)
SPAN_S = 86400.0
# Hills to the west, a low gap to the south-east, and a mask that wraps through north.
MASK = ((0.0, 8.0), (60.0, 3.0), (135.0, 1.0), (200.0, 12.0), (270.0, 25.0), (330.0, 15.0))


def _test_mask(az_deg):
    pts = np.array(MASK + ((MASK[0][0] + 360.0, MASK[0][1]),))
    return np.interp(np.mod(az_deg, 360.0), pts[:, 0], pts[:, 1])


class Sky:
    def __init__(self, refraction: bool) -> None:
        self.sat = EarthSatellite(ISS_L1, ISS_L2, ts=timescale())
        self.site = wgs84.latlon(*SITE)
        self.kw = {"temperature_C": 10.0, "pressure_mbar": 1010.0} if refraction else {}

    def g(self, t_s, mask=True):
        alt, az, _ = (self.sat - self.site).at(skyfield_times(ISS_EPOCH, np.atleast_1d(t_s))).altaz(**self.kw)
        return alt.degrees - (_test_mask(az.degrees) if mask else 0.0)

    def crossings(self, mask=True):
        t = np.arange(0.0, SPAN_S + 0.5, 1.0)
        g = self.g(t, mask)
        idx = np.flatnonzero(np.sign(g[1:]) != np.sign(g[:-1]))
        roots = np.array([brentq(lambda x: float(self.g(x, mask)[0]), t[i], t[i + 1], xtol=1e-6) for i in idx])
        return roots[g[idx] < 0], roots[g[idx] > 0]


def _ours(**station):
    frames = EarthFrames(ISS_EPOCH, -3600.0, SPAN_S + 3600.0)
    sat = SGP4Trajectory(parse_tle(ISS_L1, ISS_L2), ISS_EPOCH, frames)
    return access_windows(sat, Station(*SITE, **station), frames, 0.0, SPAN_S)


def test_an_azimuth_mask_against_a_skyfield_scan():
    rises, sets = Sky(refraction=False).crossings()
    w = _ours(mask=MASK)
    assert len(rises) >= 3
    np.testing.assert_allclose(w.rise_s[~w.rise_clipped], rises, atol=0.01, rtol=0)
    np.testing.assert_allclose(w.set_s[~w.set_clipped], sets, atol=0.01, rtol=0)
    # The culmination is the highest point of the pass (not the furthest above the mask).
    sky = Sky(refraction=False)
    for k in range(len(w)):
        t = np.linspace(w.rise_s[k], w.set_s[k], 400)
        assert w.max_elevation_deg[k] >= sky.g(t, mask=False).max() - 1e-4


def test_refraction_against_skyfields_refracted_altitudes():
    h = np.array([-0.5, 0.0, 0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 45.0, 80.0])
    ref = np.array([refract(x, 10.0, 1010.0) for x in h]) - h  # skyfield inverts Bennett's formula
    np.testing.assert_allclose(refraction_deg(h), ref, atol=0.002, rtol=0)
    assert refraction_deg(np.array([-2.0]))[0] == 0.0  # below -1 deg: none, as skyfield
    # Rises come earlier and sets later by what the refracted horizon adds; both within 0.1 s.
    rises, sets = Sky(refraction=True).crossings(mask=False)
    w = _ours(refraction=True)
    np.testing.assert_allclose(w.rise_s[~w.rise_clipped], rises, atol=0.1, rtol=0)
    np.testing.assert_allclose(w.set_s[~w.set_clipped], sets, atol=0.1, rtol=0)
    plain = _ours()  # every geometric pass lies inside a longer refracted one (and low passes appear)
    assert len(w) >= len(plain)
    for r, s in zip(plain.rise_s, plain.set_s, strict=True):
        assert np.any((w.rise_s < r - 5.0) & (w.set_s > s + 5.0))


@pytest.mark.parametrize(
    "mask,message",
    [
        (((10.0, 5.0), (5.0, 5.0)), "does not increase"),
        (((10.0, 5.0), (10.0, 6.0)), "does not increase"),
        (((360.0, 5.0),), r"outside \[0, 360\)"),
        (((10.0, 95.0),), r"outside \[-5, 89\]"),
    ],
)
def test_a_bad_mask_names_the_point_and_what_to_fix(mask, message):
    with pytest.raises(StationError, match=message) as e:
        _ours(mask=mask)
    assert e.value.field == "mask"
