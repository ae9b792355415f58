"""The reflectivity map against independent references: the radar's own image of a point, the plate's physical-optics
lobe in closed form, the exponential law as the Lomax's limit, and attitudes recovered on frames of a physics the map
was not fitted to."""

import dataclasses
import math
import subprocess
import sys

import numpy as np
import pytest

from inference.errors import DatasetError, ModelFileError
from inference.frames import normalise_frame
from inference.labelled import LabelledFrames, write_frame
from inference.reflectivity import fitting
from inference.reflectivity.build import check_frames
from inference.reflectivity.model import Geometry, Look, ReflectivityMap, nll
from inference.reflectivity.refine import Objective, refine
from inference.reflectivity.serve import read_map, save_map
from inference.reflectivity.sites import sites_of
from inference.rotations import euler_from_matrix, geodesic_deg, rotation_matrix, so3_exp
from inference.simulation.mesh import Mesh, plate_mesh
from inference.simulation.radar import Imager, Radar, window_1d
from inference.simulation.scene import Scattering, simulate
from inference.simulation.targets import TargetModel, tiangong_like


def _plate_target(su=2.0, sv=1.0):
    mesh = plate_mesh(np.zeros(3), np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0]), su, sv)
    pts = mesh.vertices
    return TargetModel("plate", pts, pts, np.tile([1.0, 0, 0], (4, 1)), np.zeros(4, np.int8), mesh=mesh)


@pytest.mark.parametrize("window", ["taylor", "hamming", "none"])
def test_a_point_images_as_the_radars_own_image_of_a_point(window):
    """The map's point spread at a fractional pixel is |image|^2 of one scatterer through the radar's imaging chain
    (the NUFFT echo, the window, the inverse FFT), normalised to its peak."""
    radar = Radar()
    rmap = ReflectivityMap(sites_of(_plate_target(), 0.5), radar, Look(window=window))
    imager = Imager(radar)
    point = np.array([[1.234, -0.777, 0.3]])
    u, v = imager.pixel_coordinates(point)
    w = np.outer(window_1d(radar.n_range, window, radar.window_sidelobe_db), window_1d(radar.n_azimuth, window, 0))
    if window == "taylor":
        w = imager.window_2d()
    image = np.abs(imager.image_from_echo(imager.echo(point, np.array([1.0 + 0j])), w)) ** 2
    win = (int(u[0]) - 6, int(v[0]) - 6, 13, 13)
    geo = Geometry(u, v, np.ones(1), np.ones(1), np.zeros(1))
    mine = rmap.splat(geo, np.ones(1), win)
    ref = image[win[0] : win[0] + 13, win[1] : win[1] + 13]
    ref = ref / ref.max()
    # Within the spread's reach (|h|^2 over -30 dB on an axis) it is the radar's to 1 % of the peak, and the point
    # lands on the same pixel.
    assert np.unravel_index(mine.argmax(), mine.shape) == np.unravel_index(ref.argmax(), ref.shape)
    assert np.max(np.abs(mine / mine.max() - ref)) < 0.01 * (1.0 if window != "none" else 4.0)


def test_sites_cover_the_mesh_and_panels_have_the_plates_sides():
    target = _plate_target(2.0, 1.0)
    s = sites_of(target, 0.1)
    assert s.areas.sum() == pytest.approx(2.0, rel=1e-9)  # both triangles' area, whatever the sampling
    assert len(s.panel_area_m2) == 1 and s.panel_area_m2[0] == pytest.approx(2.0)
    assert sorted(s.panel_extent_m[0]) == pytest.approx([1.0, 2.0], rel=1e-9)  # a rectangle's second moments
    assert len(s) >= 150  # about one site per 10 cm square


def test_the_plates_flash_is_the_physical_optics_lobe():
    """Summed over a plate's sites, the specular term is 4 pi A^2 / lambda^2 at broadside (a frame of negligible swing)
    and falls to half at the sinc^2 lobe's half-power angle, asin(0.2215 lambda / L) (PO of a flat plate)."""
    radar = Radar(aperture_deg=0.01)
    rmap = ReflectivityMap(sites_of(_plate_target(2.0, 1.0), 0.1), radar, Look(occlusion=False))
    lam = radar.wavelength_m
    broadside = rmap.geometry(np.eye(3)).spec.sum()
    assert broadside == pytest.approx(4 * math.pi * 2.0**2 / lam**2, rel=0.01)
    for side, axis in ((2.0, np.array([0.0, 0.0, 1.0])), (1.0, np.array([0.0, 1.0, 0.0]))):
        half = math.asin(0.2215 * lam / side)  # tilting about this axis moves the line of sight across the other side
        turned = rmap.geometry(so3_exp(half * axis)).spec.sum()
        assert turned / broadside == pytest.approx(0.5, abs=0.02)


def test_the_lomax_likelihood_tends_to_speckles():
    rng = np.random.default_rng(0)
    y = rng.exponential(size=500) * 0.3
    low, high = y < 1e-4, y > 1
    mu_a, mu_b = np.full(500, 0.25), np.full(500, 0.4)
    plain = nll(mu_a, y, low, high) - nll(mu_b, y, low, high)
    heavy = nll(mu_a, y, low, high, 1e7) - nll(mu_b, y, low, high, 1e7)
    assert heavy == pytest.approx(plain, rel=1e-4)
    # Heavier-tailed: one pixel far above the mean costs less under the Lomax than under the exponential.
    one = np.array([50.0])
    none = np.zeros(1, bool)
    assert nll(np.ones(1), one, none, none, 2.0) < nll(np.ones(1), one, none, none)


def _frames(model, imager, angles, scattering, seed):
    out = []
    for k, a in enumerate(angles):
        f = simulate(model, imager, tuple(float(x) for x in a), 10.0, seed + k, scattering)
        out.append(normalise_frame(np.abs(f.image)))
    return np.stack(out)


@pytest.fixture(scope="module")
def dense_map():
    """A map fitted on 24 frames of speckle from dense scatterers (12 multiplicative steps), with its history."""
    model = tiangong_like()
    radar = Radar()
    train = np.random.default_rng(4).uniform(-35, 35, (24, 3))
    rmap = ReflectivityMap(sites_of(model, 0.15), radar, Look())
    frames = _frames(model, Imager(radar), train, Scattering(scatterers="dense"), 100)
    history = fitting.fit(rmap, fitting.prepare(rmap, frames, train), 12)
    return rmap, history


def test_a_map_fitted_on_one_physics_recovers_attitudes_on_another(dense_map):
    """Fitted on 24 frames of speckle from dense scatterers, the map refines frames of the lattice of scattering
    centres (another scattering, another law per kind) from starts 2 deg off to under 1 deg (median)."""
    rmap, history = dense_map
    assert history[-1] < history[0]  # the likelihood rises as the multiplicative steps go
    rng = np.random.default_rng(5)
    test = rng.uniform(-35, 35, (4, 3))
    shown = _frames(tiangong_like(), Imager(rmap.radar), test, Scattering(), 500)
    errors = []
    for truth, frame in zip(test, shown, strict=True):
        w = rng.normal(size=3)
        start = euler_from_matrix(so3_exp(np.radians(2.0) * w / np.linalg.norm(w)) @ rotation_matrix(*truth))
        best = refine(rmap, frame, {"start": np.array(start)}, Objective(), max_renders=100)[0]
        errors.append(float(geodesic_deg(best.angles_deg, truth)[0]))
    assert np.median(errors) < 1.0, errors


def test_a_still_pass_is_refined_on_its_frames_together(dense_map):
    """A still pass seen by another physics (the lattice of scattering centres): 6 frames along a sweep, their
    attitudes all off by one body rotation of 3 deg, as a pass's silhouette fusion would leave them. The service's
    pass refinement (``ImageRefiner.refine_still``) finds one turn that brings every frame within 1 deg (median)."""
    from inference.reflectivity.serve import ImageRefiner

    rmap, _ = dense_map
    rng = np.random.default_rng(11)
    centre, way = rng.uniform(-25, 25, 3), rng.normal(size=3)
    truth = np.array([centre + t * way / np.linalg.norm(way) for t in np.linspace(-8.0, 8.0, 6)])
    shown = _frames(tiangong_like(), Imager(rmap.radar), truth, Scattering(), 700)
    w = rng.normal(size=3)
    error = so3_exp(np.radians(3.0) * w / np.linalg.norm(w))
    starts = np.array([euler_from_matrix(rotation_matrix(*a) @ error) for a in truth])
    done = ImageRefiner(rmap).refine_still(shown, starts)
    assert done is not None and done.frames == 6 and done.nll_per_pixel < done.start_nll_per_pixel
    after = np.array([euler_from_matrix(rotation_matrix(*a) @ done.turn) for a in starts])
    errors = geodesic_deg(after, truth)
    assert np.median(errors) < 1.0, errors
    # A map whose build found held-out passes not sharpened leaves a pass to its silhouettes.
    quiet = dataclasses.replace(rmap, record={"calibration": {"informative": True, "pass_informative": False}})
    assert ImageRefiner(quiet).refine_still(shown, starts) is None


def _labelled(n, scenes, size=256):
    return LabelledFrames(
        np.zeros((n, size, size), np.float32),
        np.zeros((n, 3)),
        tuple(f"s{k % scenes}" for k in range(n)),
        tuple(f"f{k}" for k in range(n)),
        np.full(n, np.nan),
        np.full(n, np.nan),
        tuple(None for _ in range(n)),
    )


def test_a_map_refuses_frames_it_cannot_be_built_from():
    with pytest.raises(DatasetError, match="at least 2 scenes") as exc:
        check_frames(_labelled(6, 1), Radar())
    assert exc.value.field == "frames"
    with pytest.raises(DatasetError, match="128x128 px") as exc:
        check_frames(_labelled(6, 2, 128), Radar())
    assert exc.value.field == "frames"


def test_a_map_file_is_refused_for_another_target_or_another_mesh(tmp_path):
    model = tiangong_like()
    rmap = ReflectivityMap(sites_of(model, 0.3), Radar(), Look(), record={"spacing_m": 0.3})
    save_map(rmap, tmp_path)
    path = tmp_path / "reflectivity.npz"
    again = read_map(path, model, Radar())
    assert np.array_equal(again.law, rmap.law) and again.look == rmap.look
    moved = Mesh(model.mesh.vertices * 1.01, model.mesh.faces, model.mesh.two_sided)
    with pytest.raises(ModelFileError, match="not this one"):
        read_map(path, dataclasses.replace(model, mesh=moved), Radar())
    with pytest.raises(ModelFileError, match="another radar"):
        read_map(path, model, Radar(bandwidth_hz=1.0e9))


def test_adapt_map_only_refuses_one_scene_in_one_line(tmp_path):
    folder = tmp_path / "frames"
    folder.mkdir()
    for k in range(4):
        write_frame(
            folder / f"{k}.npz", np.random.default_rng(k).random((256, 256)), angles_deg=(1.0, 2.0, 3.0), scene="a"
        )
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "inference.training.adapt",
            "--map-only",
            "--frames",
            str(folder),
            "--out",
            str(tmp_path / "out"),
        ],
        capture_output=True,
        text=True,
    )
    assert proc.returncode != 0
    last = [line for line in proc.stderr.splitlines() if line.strip()][-1]
    assert "at least 2 scenes" in last and "Traceback" not in proc.stderr
    assert not (tmp_path / "out").exists()


def test_a_set_with_a_map_answers_on_the_image(tmp_path):
    """The service's checkers (``load_checkers``, what the API loads) refine on the image where the set's card lists
    a map: ``refined_on`` image, the likelihood, and bounds and reasons of their own; a map altered after its card was
    written is refused by name."""
    import json
    import shutil

    from inference.runtime import DEFAULT_MODEL_DIR, Estimator
    from inference.trust import load_checkers

    model = tiangong_like()
    radar = Radar()
    rng = np.random.default_rng(9)
    angles = rng.uniform(-30, 30, (6, 3))
    frames = _frames(model, Imager(radar), angles, Scattering(), 900)
    rmap = ReflectivityMap(sites_of(model, 0.2), radar, Look(), record={"spacing_m": 0.2})
    fitting.fit(rmap, fitting.prepare(rmap, frames[:5], angles[:5]), 6)
    rmap.record["calibration"] = {"scale": [1.0, 1.0, 1.0], "floor_deg": [0.3, 0.3, 0.3], "deviance_max": 5.0}
    d = tmp_path / "set"
    shutil.copytree(DEFAULT_MODEL_DIR, d)
    entry = save_map(rmap, d)
    card = json.loads((d / "model_card.json").read_text())
    card["files"]["map"] = entry
    (d / "model_card.json").write_text(json.dumps(card))
    est = Estimator.load(d)
    checker = load_checkers(d, est.img_size).get("tiangong-like")
    res = est.estimate(frames[5:])
    c = checker.check_many(frames[5:], res.enhanced, res.angles_deg)[0]
    assert c.refined_on == "image" and c.image_fit is not None
    assert c.image_fit["deviance"] < c.image_fit["deviance_max"]
    assert float(geodesic_deg(c.angles_deg, angles[5])[0]) < 3.0
    # The map's view of the frame at the answer shows where the frame is bright: the two correlate (40 dB normalised)
    # over the frame, far more than at an attitude 20 deg off.
    predicted, residual = checker.image.views(frames[5], c.angles_deg)
    assert predicted.shape == residual.shape == frames[5].shape
    off, _ = checker.image.views(frames[5], c.angles_deg + np.array([20.0, 0.0, 0.0]))
    here = float(np.corrcoef(predicted.ravel(), frames[5].ravel())[0, 1])
    there = float(np.corrcoef(off.ravel(), frames[5].ravel())[0, 1])
    assert here > 0.45 and here > there + 0.2, (here, there)
    with (d / "reflectivity.npz").open("ab") as fh:
        fh.write(b"\0")
    with pytest.raises(ModelFileError, match="sha256"):
        load_checkers(d, est.img_size)


def test_map_only_builds_a_new_set_with_its_map_and_record(tmp_path, monkeypatch):
    """``gsa adapt --map-only``'s path end to end, at toy sizes: a new folder with the base set's files, the map and a
    card that lists it and records every trial; the base set untouched; the new set answers on the image."""
    import json

    from inference.reflectivity import build
    from inference.reflectivity.sets import map_only
    from inference.runtime import DEFAULT_MODEL_DIR, Estimator
    from inference.trust import load_checkers

    for name, value in (("SPACING_M", 0.3), ("SELECT_FRAMES", 2), ("CALIBRATION_FRAMES", 3), ("SELECT_ITERATIONS", 2)):
        monkeypatch.setattr(build, name, value)
    monkeypatch.setattr(build, "SELECT_RENDERS", 8)
    monkeypatch.setattr(fitting, "ITERATIONS", 3)
    model, radar = tiangong_like(), Radar()
    angles = np.random.default_rng(2).uniform(-30, 30, (8, 3))
    frames = _frames(model, Imager(radar), angles, Scattering(), 40)
    labelled = LabelledFrames(
        frames,
        angles,
        tuple(f"scene-{k % 2}" for k in range(8)),
        tuple(f"f{k}" for k in range(8)),
        np.full(8, np.nan),
        np.full(8, np.nan),
        tuple(None for _ in range(8)),
    )
    before = (DEFAULT_MODEL_DIR / "model_card.json").read_bytes()
    out = tmp_path / "with-map"
    record = map_only(DEFAULT_MODEL_DIR, labelled, out)
    assert (DEFAULT_MODEL_DIR / "model_card.json").read_bytes() == before
    card = json.loads((out / "model_card.json").read_text())
    assert card["files"]["map"]["file"] == "reflectivity.npz" and card["map"] == json.loads(json.dumps(record))
    assert [t["trial"] for t in record["trials"]][:3] == ["window taylor", "window hamming", "window none"]
    assert (
        record["frames"] == 8
        and record["scenes"] == 2
        and set(record["divergence_per_scene"]) == {"scene-0", "scene-1"}
    )
    cal = record["calibration"]  # the held-out scene was refined as a pass too, from each of PASS_STARTS starts
    assert len(cal["pass_errors_deg"]) == build.PASS_STARTS and cal["pass_median_deg"] is not None
    assert cal["pass_informative"] == (cal["pass_median_deg"] < build.INFORMATIVE * build.START_DEG)
    est = Estimator.load(out)
    checker = load_checkers(out, est.img_size).get("tiangong-like")
    assert checker.image is not None and checker.image.calibrated
    assert checker.image.pass_informative == cal["pass_informative"]


def test_a_map_that_did_not_sharpen_held_out_answers_never_answers():
    """A map whose build found its held-out answers no closer than their starts leaves the silhouette's answer."""
    from inference.checked import Checked, Quality
    from inference.reflectivity.serve import ImageRefiner

    rmap = ReflectivityMap(
        sites_of(tiangong_like(), 0.3), Radar(), Look(), record={"calibration": {"informative": False}}
    )
    checked = Checked(np.zeros(3), None, True, Quality(0.9, (1.0, 1.0, 1.0), True, []), [], {})
    assert ImageRefiner(rmap).refine_checked(checked, np.zeros((256, 256)), np.zeros((256, 256)), None) is checked
