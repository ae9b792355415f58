"""Physics of the ISAR simulator: where points land, resolution, SNR, labels, and the fast path's exactness."""

import math

import numpy as np
import pytest

from inference.errors import ModelFileError, RadarError
from inference.simulation.isar import (
    C_M_S,
    Imager,
    Radar,
    add_noise,
    cartesian_echo_direct,
    check_fits,
    euler_from_matrix,
    normalise_frame,
    nufft_type1,
    polar_echo_direct,
    polar_format,
    projection_matrix,
    range_doppler,
    rotation_matrix,
    simulate,
)
from inference.simulation.targets import FLAT, TargetModel, cylinder, load_model, tiangong_like

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


def _cluster_model(p_body):
    pts = np.asarray(p_body, float) + np.random.default_rng(0).normal(0, 0.02, (200, 3))
    return TargetModel("dot", pts, pts, np.zeros_like(pts), np.full(len(pts), FLAT, np.int8))


@pytest.mark.parametrize("angles", [(0.0, 0.0, 0.0), (30.0, -20.0, 10.0), (-45.0, 45.0, -45.0)])
def test_label_moves_as_the_rotation_predicts(angles):
    p = np.array([5.0, 2.0, 1.0])
    model = _cluster_model(p)
    frame = simulate(model, IMAGER, angles, None, 0)
    rows, cols = np.nonzero(frame.label)
    expected = projection_matrix(RADAR) @ rotation_matrix(*angles) @ p
    assert rows.mean() == pytest.approx(expected[0] / RADAR.range_cell_m + 128, abs=1.0)
    assert cols.mean() == pytest.approx(expected[1] / RADAR.cross_range_cell_m + 128, abs=1.0)


def test_image_and_label_overlap():
    """On noise-free frames, the bright part of the image lies on the label.

    Not all of it: an end cap facing the radar flashes, and its 25-dB sidelobes run
    along the row and column off the silhouette (0.80 of the bright pixels on the
    label at zero attitude, over 0.98 at the others).
    """
    from scipy.ndimage import binary_dilation

    model = tiangong_like()
    for k, angles in enumerate([(0.0, 0.0, 0.0), (20.0, -30.0, 40.0), (-40.0, 10.0, -25.0)]):
        frame = simulate(model, IMAGER, angles, None, k)
        bright = normalise_frame(np.abs(frame.image)) > 0.5  # within 20 dB of the brightest
        on_label = binary_dilation(frame.label, iterations=2)
        precision = (bright & on_label).sum() / bright.sum()
        assert precision > (0.75 if k == 0 else 0.95)
        iou = (bright & frame.label).sum() / (bright | frame.label).sum()
        assert iou > 0.1


def test_euler_round_trip():
    for z, y, x in [(10.0, -20.0, 30.0), (-44.0, 44.0, 0.5)]:
        assert euler_from_matrix(rotation_matrix(z, y, x)) == pytest.approx((z, y, x), abs=1e-9)


def test_normalise_frame_is_robust_to_one_bright_cell():
    rng = np.random.default_rng(0)
    mag = np.abs(rng.normal(size=(256, 256)))
    mag[10, 10] = 1e4  # 80 dB above the rest
    out = normalise_frame(mag)
    assert out.dtype == np.float32 and out.min() >= 0 and out.max() <= 1
    assert np.median(out) > 0.5  # the rest is not crushed to black
    assert np.all(normalise_frame(np.zeros((4, 4))) == 0)


def test_default_target_has_no_mirror_plane_and_fits():
    model = tiangong_like()
    assert model.mirror_planes == []
    check_fits(model, RADAR)
    assert 3000 < len(model.scatterers) < 6000


def test_symmetric_target_reports_its_mirror_planes():
    p, n, _, _ = cylinder(np.array([-3.0, 0, 0]), np.array([1.0, 0, 0]), 1.0, 6.0, 0.1)
    model = TargetModel("can", p, p, n, np.zeros(len(p), np.int8))
    assert set(model.mirror_planes) == {"yz", "xz", "xy"}


@pytest.mark.parametrize(
    "kwargs", [{"bandwidth_hz": 0.0}, {"n_range": 0}, {"n_azimuth": 0}, {"aperture_deg": 0.0}, {"n_range": 255}]
)
def test_bad_radar_parameters(kwargs):
    with pytest.raises(RadarError):
        Radar(**kwargs)


def test_model_files(tmp_path):
    obj = tmp_path / "box.obj"
    obj.write_text(
        "v -1 -1 -1\nv 1 -1 -1\nv 1 1 -1\nv -1 1 -1\nv -1 -1 1\nv 1 -1 1\nv 1 1 1\nv -1 1 1\n"
        "f 1 2 3 4\nf 5 6 7 8\nf 1 2 6 5\nf 2 3 7 6\nf 3 4 8 7\nf 4 1 5 8\n"
    )
    box = load_model(obj)
    assert len(box.scatterers) > 50 and np.abs(box.surface).max() <= 1.05
    ply = tmp_path / "pts.ply"
    ply.write_text(
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n0 0 0\n1 0 0\n0 1 0\n"
    )
    assert len(load_model(ply).surface) == 3
    with pytest.raises(ModelFileError, match="does not exist"):
        load_model(tmp_path / "missing.obj")
    empty = tmp_path / "empty.obj"
    empty.write_text("")
    with pytest.raises(ModelFileError, match="no usable vertices"):
        load_model(empty)
    junk = tmp_path / "junk.ply"
    junk.write_bytes(b"\x00\x01garbage")
    with pytest.raises(ModelFileError, match="not a PLY"):
        load_model(junk)
    with pytest.raises(ModelFileError, match="frame is only"):
        check_fits(load_model(obj, scale=20.0), RADAR)


def test_default_frames_are_unchanged_by_the_scattering_options():
    """The hash of three default frames, recorded on the commit before inference.simulation.isar.Scattering existed."""
    import hashlib

    from inference.simulation.dataset import DatasetSpec, render_frames

    a = render_frames(DatasetSpec(n=3, seed=0), RADAR, 0, 3)
    digest = hashlib.sha256(a["image"].tobytes() + a["label"].tobytes()).hexdigest()
    assert digest == "cfddc122e75fce63eb09552a5c8953761952b81d0dcf676feb7bcf22eaac5a44"


def test_fast_polar_echo_matches_the_direct_sum():
    from inference.simulation.isar import polar_echo

    pts = np.random.default_rng(3).uniform(-10, 10, (40, 3))
    amps = np.exp(2j * np.pi * np.random.default_rng(4).random(40))
    fast = polar_echo(RADAR, pts, amps)
    direct, _, _ = polar_echo_direct(RADAR, pts, amps)
    assert np.abs(fast - direct).max() < 1e-2 * np.abs(direct).max()


def test_every_variant_images_the_target_where_its_label_is():
    from inference.simulation.isar import VARIANTS

    model = tiangong_like()
    for name, sc in VARIANTS.items():
        f = simulate(model, IMAGER, (15.0, -10.0, 20.0), None, 2, sc)
        mag = np.abs(f.image)
        inside = mag[f.label].mean()
        outside = mag[~f.label].mean()
        assert inside > 5 * outside, name


def test_bad_scattering_options_are_refused():
    from inference.simulation.isar import Scattering

    for kw in ({"window": "kaiser"}, {"edge_gain": -1}, {"scatterers": "mesh"}, {"scale_error": 0.5}):
        with pytest.raises(RadarError, match=next(iter(kw))):
            Scattering(**kw)
