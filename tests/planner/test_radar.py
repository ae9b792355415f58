"""The radar in the scene: its elevation and range against skyfield, its SNR against the radar equation written out
here, its integration time against the angle skyfield's own line of sight sweeps, and its refusals."""

import math

import numpy as np
import pytest
from skyfield.api import EarthSatellite, wgs84

from planner.errors import StationError
from planner.frames import station_radar_view
from planner.propagation import EarthFrames, SGP4Trajectory, Station, skyfield_times, timescale
from planner.radar import Radar, radar_limits, snr_db, validate_radar
from planner.tle import parse_tle
from tests.utils.orbits import ISS_EPOCH, ISS_L1, ISS_L2

STATION = Station(31.1, 121.3, 0.0, 0.0)
SPAN_S = 86400.0


def _design_snr_db(radar: Radar, range_km: float, sigma_m2: float, t_int_s: float) -> float:
    """DESIGN.md's radar equation, SNR = Pt G^2 lambda^2 sigma n / ((4 pi)^3 R^4 k T0 F B L), written out: n pulses in
    the integration, a matched filter whose noise bandwidth is 1 / tau, T0 F the system temperature."""
    c = 299_792_458.0
    k = 1.380649e-23
    lam = c / (radar.frequency_ghz * 1e9)
    n = radar.prf_hz * t_int_s
    b = 1.0 / (radar.pulse_width_us * 1e-6)
    pt = radar.peak_power_kw * 1e3
    g = 10 ** (radar.gain_dbi / 10)
    loss = 10 ** (radar.losses_db / 10)
    snr = (
        pt
        * g**2
        * lam**2
        * sigma_m2
        * n
        / ((4 * math.pi) ** 3 * (range_km * 1e3) ** 4 * k * radar.noise_temperature_k * b * loss)
    )
    return 10 * math.log10(snr)


@pytest.mark.parametrize(
    "radar, range_km, sigma, t_int",
    [
        (Radar(), 1500.0, 10.0, 30.0),
        (Radar(), 600.0, 0.5, 8.0),
        (
            Radar(frequency_ghz=10.0, peak_power_kw=250.0, pulse_width_us=20.0, prf_hz=1000.0, gain_dbi=60.0),
            2500.0,
            3.0,
            12.0,
        ),
    ],
)
def test_snr_is_the_radar_equation(radar, range_km, sigma, t_int):
    assert float(snr_db(radar, np.array([range_km]), np.array([sigma]), np.array([t_int]))[0]) == pytest.approx(
        _design_snr_db(radar, range_km, sigma, t_int), abs=1e-6
    )
    # The fourth power of range: twice as far is 12.04 dB less.
    twice = float(snr_db(radar, np.array([2 * range_km]), np.array([sigma]), np.array([t_int]))[0])
    assert _design_snr_db(radar, range_km, sigma, t_int) - twice == pytest.approx(40 * math.log10(2), abs=1e-9)


def test_default_antenna_gain_is_a_34_m_dish_at_60_percent():
    """0.6 (pi D / lambda)^2 for D = 34 m at 15 GHz: 72.3 dBi."""
    lam = 299_792_458.0 / 15e9
    assert Radar().gain_dbi == pytest.approx(10 * math.log10(0.6 * (math.pi * 34.0 / lam) ** 2), abs=0.05)


@pytest.fixture(scope="module")
def iss_pass():
    """The ISS over Shanghai at its highest pass of a day, sampled each 20 s above the horizon."""
    frames = EarthFrames(ISS_EPOCH, 0.0, SPAN_S + 600.0)
    sat = SGP4Trajectory(parse_tle(ISS_L1, ISS_L2), ISS_EPOCH, frames)
    sky = EarthSatellite(ISS_L1, ISS_L2, ts=timescale())
    site = wgs84.latlon(STATION.latitude_deg, STATION.longitude_deg, STATION.altitude_m)
    t = np.arange(0.0, SPAN_S, 20.0)
    el = (sky - site).at(skyfield_times(ISS_EPOCH, t)).altaz()[0].degrees
    best = int(np.argmax(el))
    t_pass = t[max(best - 20, 0) : best + 20]
    t_pass = t_pass[el[max(best - 20, 0) : best + 20] > 5.0]
    return sat, frames, sky, site, t_pass


def test_elevation_and_range_against_skyfield(iss_pass):
    sat, frames, sky, site, t = iss_pass
    view = station_radar_view(sat, STATION, frames, t, None)
    alt, _, dist = (sky - site).at(skyfield_times(ISS_EPOCH, t)).altaz()
    np.testing.assert_allclose(view.elevation_deg, alt.degrees, atol=0.01)
    np.testing.assert_allclose(view.range_km, dist.km, atol=0.05)
    assert np.all(np.isnan(view.snr_db)) and np.all(np.isnan(view.rcs_m2))  # no cross section given: no SNR


def _skyfield_los_lvlh(sky, site, t_s):
    """The line of sight target to site in the target's radial / along-track / normal axes, from skyfield alone."""
    times = skyfield_times(ISS_EPOCH, np.atleast_1d(t_s))
    sat = sky.at(times)
    r, v = sat.position.km, sat.velocity.km_per_s
    s = site.at(times).position.km
    radial = r / np.linalg.norm(r, axis=0)
    normal = np.cross(r, v, axis=0)
    normal /= np.linalg.norm(normal, axis=0)
    along = np.cross(normal, radial, axis=0)
    los = (s - r) / np.linalg.norm(s - r, axis=0)
    return np.stack([(los * radial).sum(0), (los * along).sum(0), (los * normal).sum(0)])


def test_integration_sweeps_the_aperture_by_skyfields_own_line_of_sight(iss_pass):
    """Over isar_integration_s centred on a moment, skyfield's line of sight in the target's LVLH frame turns through
    the radar's aperture (5.1 deg), within 0.5 %, though the rate changes across it (fastest overhead)."""
    sat, frames, sky, site, t = iss_pass
    radar = Radar()
    view = station_radar_view(sat, STATION, frames, t, None)
    for k in range(0, t.size, 3):
        half = view.integration_s[k] / 2.0
        a, b = _skyfield_los_lvlh(sky, site, np.array([t[k] - half, t[k] + half])).T
        swept = math.degrees(math.acos(float(np.clip(a @ b, -1.0, 1.0))))
        assert swept == pytest.approx(radar.aperture_deg, rel=0.005)
    # Overhead, the line of sight turns fastest: the shortest integration is at the highest elevation.
    assert int(np.argmin(view.integration_s)) == int(np.argmax(view.elevation_deg))


def test_snr_uses_the_cross_section_given_at_the_aspect(iss_pass):
    """A cross section that depends on the aspect is read at the line of sight in LVLH, and the SNR follows it."""
    sat, frames, _, _, t = iss_pass

    def sigma(los):  # 100 m^2 looking up at the target from below (radial -1), 1 m^2 side-on
        return 1.0 + 99.0 * np.clip(-los[0], 0.0, 1.0) ** 2

    view = station_radar_view(sat, STATION, frames, t, sigma)
    np.testing.assert_allclose(view.rcs_m2, sigma(view.los_lvlh))
    expected = [
        _design_snr_db(Radar(), r, s, min(ti, 60.0))
        for r, s, ti in zip(view.range_km, view.rcs_m2, view.integration_s, strict=True)
    ]
    np.testing.assert_allclose(view.snr_db, expected, atol=1e-6)


def test_limits_name_each_one_missed():
    radar = Radar()
    assert radar_limits(radar, 30.0, 20.0, 60.0) == []
    low, slow, weak = radar_limits(radar, 5.7, 90.0, 30.0)
    assert "5.7 deg elevation" in low and "min_elevation_deg 10" in low
    assert "90.0 s" in slow and "max_integration_s" in slow
    assert "30.0 dB" in weak and "min_snr_db 45.2" in weak
    (fast,) = radar_limits(radar, 80.0, 2.0, 70.0)
    assert "256" in fast and "55 Hz" in fast  # 2 s holds 110 pulses at 55 Hz: the frame's 256 alias
    assert radar_limits(radar, 30.0, 20.0, math.nan) == []  # no SNR computed: not judged


@pytest.mark.parametrize(
    "change, field",
    [
        ({"prf_hz": -1.0}, "radar.prf_hz"),
        ({"gain_dbi": math.nan}, "radar.gain_dbi"),
        ({"min_elevation_deg": 95.0}, "radar.min_elevation_deg"),
        ({"pulse_width_us": 20000.0, "prf_hz": 100.0}, "radar.pulse_width_us"),  # a duty cycle of 2
        ({"bandwidth_ghz": 40.0, "frequency_ghz": 15.0}, "radar.bandwidth_ghz"),
    ],
)
def test_radar_out_of_physical_range_is_refused_by_name(change, field):
    with pytest.raises(StationError) as info:
        validate_radar(Radar(**change))
    assert info.value.field == field
