"""The radar: where points land, resolution, SNR, the image formations, and the fast echo's exactness."""

import math

import numpy as np
import pytest

from inference.errors import RadarError
from inference.rotations import rotation_matrix
from inference.simulation.radar import (
    C_M_S,
    Imager,
    Radar,
    add_noise,
    cartesian_echo_direct,
    nufft_type1,
    polar_echo_direct,
    polar_format,
    range_doppler,
)
from inference.simulation.targets import tiangong_like

RADAR = Radar()
IMAGER = Imager(RADAR)
half_db = 0.5


def _point_image(x_m, y_m, imager=IMAGER):
    return np.abs(imager.render(np.array([[x_m, y_m, 0.0]]), np.array([1.0 + 0j])))


def test_table_3_cells():
    assert RADAR.range_cell_m == pytest.approx(C_M_S / (2 * 1.6e9))  # 9.4 cm
    assert RADAR.cross_range_cell_m == pytest.approx(0.02 / (2 * math.radians(5.1)), rel=1e-3)  # 11.2 cm
    r, a = RADAR.extent_m
    assert r == pytest.approx(23.98, abs=0.01) and a == pytest.approx(28.74, abs=0.02)


@pytest.mark.parametrize(("x", "y"), [(0.0, 0.0), (2.0, -3.0), (-7.3, 9.1)])
def test_point_scatterer_lands_in_predicted_cell(x, y):
    img = _point_image(x, y)
    peak = np.unravel_index(img.argmax(), img.shape)
    expected = (round(x / RADAR.range_cell_m + 128), round(y / RADAR.cross_range_cell_m + 128))
    assert peak == expected


def test_moving_one_resolution_cell_moves_the_peak_one_cell():
    a = np.unravel_index(_point_image(1.0, 1.0).argmax(), (256, 256))
    b = np.unravel_index(_point_image(1.0 + RADAR.range_cell_m, 1.0).argmax(), (256, 256))
    c = np.unravel_index(_point_image(1.0, 1.0 + RADAR.cross_range_cell_m).argmax(), (256, 256))
    assert (b[0] - a[0], b[1] - a[1]) == (1, 0)
    assert (c[0] - a[0], c[1] - a[1]) == (0, 1)


@pytest.mark.parametrize("axis", [0, 1])
def test_3db_widths_match_the_resolution(axis):
    """Sweep a point through sub-cell offsets and read one pixel: that traces the PSF finely."""
    cell = RADAR.range_cell_m if axis == 0 else RADAR.cross_range_cell_m
    offsets = np.linspace(-2.0, 2.0, 401)
    trace = []
    for d in offsets:
        pos = (d * cell, 0.0) if axis == 0 else (0.0, d * cell)
        trace.append(_point_image(*pos)[128, 128])
    trace = np.array(trace) / max(trace)
    width_cells = (offsets[1] - offsets[0]) * np.sum(trace >= 10 ** (-3 / 20))
    assert width_cells * cell == pytest.approx(cell, rel=0.10)


def test_nufft_against_direct_sum():
    rng = np.random.default_rng(0)
    pts = rng.uniform(-10, 10, (40, 3))
    amp = rng.normal(size=40) + 1j * rng.normal(size=40)
    ref = cartesian_echo_direct(IMAGER, pts, amp)
    fast = IMAGER.echo(pts, amp)
    assert np.abs(fast - ref).max() / np.abs(ref).max() < 5e-3  # default spread 3
    u, v = IMAGER.pixel_coordinates(pts)
    kc = 4 * math.pi * RADAR.carrier_hz / C_M_S
    precise = nufft_type1(u, v, amp * np.exp(-1j * kc * pts[:, 0]), 256, 256, spread=6)
    assert np.abs(precise - ref).max() / np.abs(ref).max() < 1e-5


def test_polar_format_stays_sharp_where_range_doppler_smears():
    """A scatterer 10 m off centre drifts x * dtheta = 0.9 m (9 cells) in range over the aperture."""
    pts = np.array([[0.0, 0.0, 0.0], [6.0, 10.0, 0.0]])
    amp = np.ones(2, complex)
    exact = np.abs(IMAGER.render(pts, amp))
    echo, f, b = polar_echo_direct(RADAR, pts, amp)
    pfa = np.abs(polar_format(IMAGER, echo, f, b))
    rd = np.abs(range_doppler(IMAGER, echo))
    centre = (128, 128)
    u, v = IMAGER.pixel_coordinates(pts[1:])
    edge = (int(np.rint(u[0])), int(np.rint(v[0])))
    win = np.s_[edge[0] - 3 : edge[0] + 4, edge[1] - 3 : edge[1] + 4]
    # Bicubic resampling of the polar samples costs ~10 % of the peak out there; no reformatting costs ~80 %.
    assert pfa[win].max() / exact[win].max() > 0.85
    assert rd[win].max() / exact[win].max() < 0.5
    # Near the centre both are fine.
    assert rd[centre] / exact[centre] > 0.9 and pfa[centre] / exact[centre] > 0.9


@pytest.mark.parametrize("snr_db", [-3.0, 0.0, 10.0])
def test_measured_snr_matches_the_request(snr_db):
    model = tiangong_like()
    rot = rotation_matrix(10.0, 20.0, -5.0)
    rng = np.random.default_rng(1)
    clean = IMAGER.echo(model.scatterers @ rot.T, np.ones(len(model.scatterers), complex))
    noisy = add_noise(clean, snr_db, rng)
    measured = 10 * np.log10(np.mean(np.abs(clean) ** 2) / np.mean(np.abs(noisy - clean) ** 2))
    assert measured == pytest.approx(snr_db, abs=half_db)


@pytest.mark.parametrize(
    "kwargs", [{"bandwidth_hz": 0.0}, {"n_range": 0}, {"n_azimuth": 0}, {"aperture_deg": 0.0}, {"n_range": 255}]
)
def test_bad_radar_parameters(kwargs):
    with pytest.raises(RadarError):
        Radar(**kwargs)


def test_fast_polar_echo_matches_the_direct_sum():
    from inference.simulation.radar import polar_echo

    pts = np.random.default_rng(3).uniform(-10, 10, (40, 3))
    amps = np.exp(2j * np.pi * np.random.default_rng(4).random(40))
    fast = polar_echo(RADAR, pts, amps)
    direct, _, _ = polar_echo_direct(RADAR, pts, amps)
    assert np.abs(fast - direct).max() < 1e-2 * np.abs(direct).max()
