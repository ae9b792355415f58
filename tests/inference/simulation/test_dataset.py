"""Data set generation: determinism whatever the workers, manifests, bad input, and the command line."""

import json
import subprocess
import sys

import numpy as np
import pytest

from inference.errors import DatasetError
from inference.simulation.dataset import DatasetSpec, frame_truth, generate, load_arrays, load_manifest, parse_snr
from tests.utils.models import SMOKE_RADAR as SMALL  # 24 m x 29 m at 64 x 64

SMALL_ARGS = ("--n-range", "64", "--n-azimuth", "64", "--bandwidth-hz", "0.4e9", "--aperture-deg", "1.275")  # SMALL


def test_same_data_whatever_the_workers(tmp_path):
    spec = DatasetSpec(n=6, seed=7, shard_size=2, n_train=4)
    one = generate(spec, tmp_path / "one", SMALL, workers=1, progress=False)
    two = generate(spec, tmp_path / "two", SMALL, workers=2, progress=False)
    assert one["content_sha256"] == two["content_sha256"]
    assert one["split"] == {"train": [0, 4], "test": [4, 6]}
    other = generate(DatasetSpec(n=6, seed=8, shard_size=2), tmp_path / "three", SMALL, workers=1, progress=False)
    assert other["content_sha256"] != one["content_sha256"]
    data = load_arrays(tmp_path / "one")
    assert data["image"].shape == (6, 64, 64) and data["label"].shape == (6, 64, 64)
    assert data["label"].dtype == bool and data["label"].any()
    assert 0.0 <= float(data["image"].min()) and float(data["image"].max()) <= 1.0
    # Each frame's truth is a function of (seed, index) alone.
    angles, snr, seed = frame_truth(spec, 5)
    np.testing.assert_allclose(data["angles_deg"][5], angles, rtol=1e-6)
    assert data["snr_db"][5] == pytest.approx(snr, rel=1e-6) and data["seed"][5] == seed
    assert np.all(np.abs(data["angles_deg"]) <= 45.0)
    assert np.all((data["snr_db"] >= -3.0) & (data["snr_db"] <= 15.0))


def test_manifest_catches_tampering(tmp_path):
    generate(DatasetSpec(n=2, shard_size=1), tmp_path / "d", SMALL, workers=1, progress=False)
    assert load_manifest(tmp_path / "d")["frames"] == 2
    shard = tmp_path / "d" / "shard-00001.npz"
    shard.write_bytes(shard.read_bytes()[:-10])
    with pytest.raises(DatasetError, match="does not match its sha256"):
        load_manifest(tmp_path / "d")
    shard.unlink()
    with pytest.raises(DatasetError, match="missing"):
        load_manifest(tmp_path / "d")
    with pytest.raises(DatasetError, match="no manifest"):
        load_manifest(tmp_path)


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"n": 0}, "n"),
        ({"n": -5}, "n"),
        ({"n": 3, "snr_min_db": 10.0, "snr_max_db": 0.0}, "snr_db"),
        ({"n": 3, "n_train": 4}, "n_train"),
        ({"n": 3, "max_angle_deg": 95.0}, "max_angle_deg"),
        ({"n": 3, "attitudes": "sphere"}, "attitudes"),
        ({"n": 3, "attitudes": "so3", "so3_share": 0.0}, "so3_share"),
        ({"n": 3, "so3_share": 0.5}, "so3_share"),
    ],
)
def test_bad_specs(kwargs, field):
    with pytest.raises(DatasetError) as err:
        DatasetSpec(**kwargs)
    assert err.value.field == field


def test_parse_snr():
    assert parse_snr("-3:15") == (-3.0, 15.0)
    assert parse_snr("5") == (5.0, 5.0)
    assert parse_snr("none") == (None, None)
    with pytest.raises(DatasetError):
        parse_snr("loud")


def _simulate(*args, cwd):
    return subprocess.run([sys.executable, "-m", "app.cli", "simulate", *args], capture_output=True, text=True, cwd=cwd)


def test_simulate_command(tmp_path):
    out = _simulate(
        "--n",
        "4",
        "--seed",
        "1",
        "--snr-db",
        "0:10",
        "--shard-size",
        "2",
        *SMALL_ARGS,
        "--split",
        "--workers",
        "1",
        "--out",
        str(tmp_path / "set"),
        cwd=tmp_path,
    )
    assert out.returncode == 0, out.stderr
    assert "4/4 frames" in out.stderr
    manifest = json.loads((tmp_path / "set" / "manifest.json").read_text())
    assert manifest["frames"] == 4 and manifest["split"]["train"] == [0, 3]


def test_a_set_over_every_rotation_writes_its_attitudes_beyond_the_cube(tmp_path):
    out = _simulate(
        "--n", "6", "--attitudes", "so3", *SMALL_ARGS, "--workers", "1", "--out", str(tmp_path / "s"), cwd=tmp_path
    )
    assert out.returncode == 0, out.stderr
    manifest = json.loads((tmp_path / "s" / "manifest.json").read_text())
    with np.load(tmp_path / "s" / "shard-00000.npz") as shard:
        angles = shard["angles_deg"]
    assert len(angles) == 6 and np.abs(angles).max() > 45.0
    assert "so3" in json.dumps(manifest)
    # --n-train N: the first N frames train, the rest test (the shipped models' 24,000 of 25,000).
    other = _simulate(
        "--n",
        "3",
        "--seed",
        "1",
        "--n-train",
        "1",
        *SMALL_ARGS,
        "--workers",
        "1",
        "--out",
        str(tmp_path / "set2"),
        cwd=tmp_path,
    )
    assert other.returncode == 0, other.stderr
    split = json.loads((tmp_path / "set2" / "manifest.json").read_text())["split"]
    assert split == {"train": [0, 1], "test": [1, 3]}
    prev = _simulate(
        "--preview",
        str(tmp_path / "p.png"),
        "--n",
        "3",
        *SMALL_ARGS,
        cwd=tmp_path,
    )
    assert prev.returncode == 0 and (tmp_path / "p.png").stat().st_size > 5000


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--n", "0"], "positive integer"),
        (["--n", "3", "--snr-db", "15:-3"], "inverted"),
        (["--n", "3", "--bandwidth-hz", "0"], "bandwidth_hz"),
        (["--n", "3", "--n-range", "0"], "n_range"),
        (["--n", "3", "--model", "missing.obj"], "does not exist"),
        (["--n", "3", "--n-train", "4"], "n_train 4 must be within [0, n=3]"),
        (["--n", "3", "--n-train", "2", "--split"], "not both"),
        (["--n", "3", "--attitudes", "all"], "attitudes 'all': one of cube, so3"),
    ],
)
def test_simulate_bad_input_is_one_line_and_leaves_nothing(tmp_path, args, message):
    out = _simulate(*args, "--out", str(tmp_path / "set"), cwd=tmp_path)
    assert out.returncode == 2
    assert out.stderr.count("\n") == 1 and message in out.stderr
    assert not (tmp_path / "set").exists() and not (tmp_path / "set.partial").exists()


def test_model_far_larger_than_the_frame(tmp_path):
    obj = tmp_path / "big.obj"
    obj.write_text("v -20 0 0\nv 20 0 0\nv 0 20 0\nf 1 2 3\n")
    out = _simulate("--n", "2", "--model", str(obj), "--out", str(tmp_path / "set"), cwd=tmp_path)
    assert out.returncode == 2 and "frame is only" in out.stderr
    assert not (tmp_path / "set").exists()


def test_one_split_rule_for_training_export_and_evaluation():
    """Training, int8 calibration and gsa evaluate read one rule: for 7 frames without a stored split,
    frames 0-5 train and frame 6 tests everywhere (evaluate used to score [5, 7): a training frame)."""
    from inference.simulation.dataset import split_ranges
    from inference.training.train import split_indices

    manifest = {"frames": 7}
    train, test = split_indices(manifest, 7)
    assert train.tolist() == list(range(6)) and test.tolist() == [6]
    assert split_ranges(manifest) == ((0, 6), (6, 7))
    stored = {"frames": 10, "split": {"train": [0, 7], "test": [7, 10]}}
    assert split_ranges(stored) == ((0, 7), (7, 10))
    assert split_indices(stored, 10)[1].tolist() == [7, 8, 9]


def test_variety_changes_the_scattering_but_not_the_truth(tmp_path):
    from inference.simulation.dataset import DatasetSpec, render_frames

    radar = SMALL
    plain = render_frames(DatasetSpec(n=4, seed=3), radar, 0, 4)
    varied = render_frames(DatasetSpec(n=4, seed=3, variety="robust"), radar, 0, 4)
    np.testing.assert_array_equal(plain["angles_deg"], varied["angles_deg"])
    np.testing.assert_array_equal(plain["label"], varied["label"])  # the label is the exact projection either way
    assert not np.array_equal(plain["image"], varied["image"])
    again = render_frames(DatasetSpec(n=4, seed=3, variety="robust"), radar, 0, 4)
    np.testing.assert_array_equal(varied["image"], again["image"])  # seeded


def test_an_so3_share_mixes_cube_and_every_rotation_frame_by_frame():
    """Of 2,000 frames at share 0.3: the frames beyond the cube number about 0.3 x 96 % (a uniform rotation lies in
    the +-45 deg cube with probability 3.7 %, which the cube-drawn frames count in), each frame's attitude is its
    own draw's whatever the share (the coin has a stream of its own), and the cube frames are the cube's draws."""
    n = 2000
    mixed = DatasetSpec(n=n, seed=5, attitudes="so3", so3_share=0.3)
    every = DatasetSpec(n=n, seed=5, attitudes="so3")
    cube = DatasetSpec(n=n, seed=5)
    angles = np.array([frame_truth(mixed, i)[0] for i in range(n)])
    beyond = np.max(np.abs(angles), axis=1) > 45.0
    expected = n * 0.3 * (1 - 0.037)
    assert abs(beyond.sum() - expected) < 4 * np.sqrt(expected), beyond.sum()
    from_every = np.array([frame_truth(every, i)[0] == tuple(angles[i]) for i in range(n)])
    from_cube = np.array([frame_truth(cube, i)[0] == tuple(angles[i]) for i in range(n)])
    assert np.all(from_every ^ from_cube) and np.all(from_every[beyond])
    assert abs(from_every.mean() - 0.3) < 0.04, from_every.mean()
    assert [frame_truth(every, i) for i in range(50)] == [
        frame_truth(DatasetSpec(n=n, seed=5, attitudes="so3", so3_share=1.0), i) for i in range(50)
    ]


def test_a_variety_share_mixes_default_and_varied_frames_frame_by_frame():
    from inference.simulation.dataset import render_frames

    radar = SMALL
    n = 12
    plain = render_frames(DatasetSpec(n=n, seed=3), radar, 0, n)
    varied = render_frames(DatasetSpec(n=n, seed=3, variety="robust"), radar, 0, n)
    mixed = render_frames(DatasetSpec(n=n, seed=3, variety="robust", variety_share=0.5), radar, 0, n)
    # Each mixed frame is, to the bit, either the default frame or the fully varied set's frame.
    as_plain = [np.array_equal(mixed["image"][i], plain["image"][i]) for i in range(n)]
    as_varied = [np.array_equal(mixed["image"][i], varied["image"][i]) for i in range(n)]
    assert all(p != v for p, v in zip(as_plain, as_varied, strict=True))
    assert 2 <= sum(as_varied) <= n - 2  # 4 of 12 here; a fair coin lands outside 2..10 once in 160 sets
    np.testing.assert_array_equal(mixed["label"], plain["label"])
    for bad, match in ((0.0, "must be in"), (1.5, "must be in")):
        with pytest.raises(DatasetError, match=match) as e:
            DatasetSpec(n=4, variety="robust", variety_share=bad)
        assert e.value.field == "variety_share"
    with pytest.raises(DatasetError, match="needs a variety preset"):
        DatasetSpec(n=4, variety_share=0.5)


def test_bad_variety_is_refused_before_any_work():
    from inference.errors import InferenceError
    from inference.simulation.dataset import DatasetSpec

    with pytest.raises(InferenceError, match="unknown variety preset"):
        DatasetSpec(n=4, variety="fancy")
    with pytest.raises(InferenceError, match="window"):
        DatasetSpec(n=4, variety="robust", variety_overrides=(("window", "kaiser"),))


def test_a_shard_is_the_same_bytes_whenever_it_is_written(tmp_path, monkeypatch):
    """A shard's bytes are its arrays' alone: written a year later (the clock moved), it is byte for byte the one
    written now (each member carries one fixed zip time; a writer stamping the clock would fail this)."""
    import time as time_module

    spec = DatasetSpec(n=2, seed=3, shard_size=2)
    now = generate(spec, tmp_path / "now", SMALL, workers=1, progress=False)
    real = time_module.time
    monkeypatch.setattr(time_module, "time", lambda: real() + 400 * 86400.0)
    later = generate(spec, tmp_path / "later", SMALL, workers=1, progress=False)
    assert (tmp_path / "now" / "shard-00000.npz").read_bytes() == (tmp_path / "later" / "shard-00000.npz").read_bytes()
    assert now["content_sha256"] == later["content_sha256"]
    with np.load(tmp_path / "later" / "shard-00000.npz") as z:  # still an ordinary .npz
        assert z["image"].shape == (2, 64, 64) and z["label"].dtype == np.uint8


@pytest.mark.parametrize("spec_kwargs", [{"variety": "robust"}, {"variety": "robust", "attitudes": "so3"}, {}])
def test_the_catalogues_frames_of_a_spec_are_the_frames_its_training_set_holds(spec_kwargs):
    """``catalogue.simulated`` (the frames benchmarks and ``gsa calibrate`` score on) against ``render_frames`` (the
    frames a training set is written from): one spec, the same frames, its variety preset included. Before, the
    catalogue dropped the spec's variety: bench.so3's "robust preset" row and the calibration's robust frames were
    default frames of another seed."""
    from inference.simulation.catalogue import simulated
    from inference.simulation.dataset import render_frames

    spec = DatasetSpec(n=3, seed=5, **spec_kwargs)
    frames, angles, _, labels = simulated(spec, SMALL)
    stored = render_frames(spec, SMALL, 0, 3)
    np.testing.assert_allclose(angles, stored["angles_deg"], atol=1e-4)
    np.testing.assert_array_equal(labels, np.unpackbits(stored["label"], axis=-1).astype(bool))
    np.testing.assert_allclose(frames, stored["image"].astype(np.float32), atol=2e-3)  # the set stores float16
