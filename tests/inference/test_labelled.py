"""Labelled frames: the folder format read back, every refusal naming file and member, the split by scene."""

from datetime import UTC, datetime

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from inference.errors import DatasetError
from inference.frames import normalise_frame, resample_metres
from inference.labelled import coverage, read_folder, scene_split, write_frame
from inference.rotations import euler_from_matrix, euler_to_quaternion, quaternion_matrix, rotation_matrix

SIZE = 32


def test_quaternion_matrix_is_scipys_rotation():
    # scipy writes quaternions scalar last; ours are scalar first, as CCSDS and the API write them.
    rng = np.random.default_rng(0)
    for q in Rotation.random(20, random_state=1).as_quat():
        w_first = np.array([q[3], q[0], q[1], q[2]])
        assert np.allclose(quaternion_matrix(w_first), Rotation.from_quat(q).as_matrix(), atol=1e-12)
    a = rng.uniform(-80, 80, 3)
    assert np.allclose(euler_from_matrix(quaternion_matrix(np.array(euler_to_quaternion(*a)))), a, atol=1e-9)
    with pytest.raises(ValueError, match="unit norm"):
        quaternion_matrix(np.array([1.0, 0.1, 0.0, 0.0]))


def test_folder_round_trip(tmp_path):
    rng = np.random.default_rng(2)
    raw = rng.random((SIZE, SIZE)) + 1j * rng.random((SIZE, SIZE))
    big = rng.random((64, 48))
    write_frame(tmp_path / "a.npz", raw, angles_deg=(10.0, -20.0, 30.0), scene="pass-1", snr_db=5.0)
    write_frame(tmp_path / "b.npz", normalise_frame(np.abs(raw)), angles_deg=(1, 2, 3), normalised=True)
    write_frame(tmp_path / "c.npz", big, angles_deg=(0, 0, 0), scene="pass-1", cells_m=(0.05, 0.06))
    (tmp_path / "notes.txt").write_text("ignored: not a frame")
    got = read_folder(tmp_path, SIZE, model_cells_m=(0.1, 0.12))
    assert got.names == ("a.npz", "b.npz", "c.npz")
    assert got.scenes == ("pass-1", "b", "pass-1")  # a frame without a scene is a scene of its own
    assert np.array_equal(got.frames[0], normalise_frame(np.abs(raw)))  # complex: its magnitude, normalised
    assert np.array_equal(got.frames[1], normalise_frame(np.abs(raw)))  # normalised: taken as it is
    # cells given: resampled in metres to the models' cells (the service's rule), then normalised
    assert np.array_equal(got.frames[2], normalise_frame(resample_metres(big, (0.05, 0.06), (0.1, 0.12), SIZE)))
    assert np.allclose(got.angles_deg[0], (10, -20, 30)) and got.snr_db[0] == 5.0 and np.isnan(got.snr_db[1])
    assert got.per_scene() == {"pass-1": 2, "b": 1}
    assert len(got.list_sha256()) == 64 and got.subset([2, 0]).names == ("c.npz", "a.npz")


def test_a_j2000_label_is_placed_by_the_plans_geometry(tmp_path):
    # The resolver stands for a plan: it knows the frame's observation axes in J2000 at that moment.
    obs_axes = rotation_matrix(40.0, 10.0, -5.0)  # observation frame in J2000 (columns)
    body_to_obs = rotation_matrix(12.0, -7.0, 3.0)
    q = euler_to_quaternion(*euler_from_matrix(obs_axes @ body_to_obs))  # body to J2000
    seen = []

    def resolve(quat, when, name):
        seen.append((when, name))
        return euler_from_matrix(obs_axes.T @ quaternion_matrix(quat))

    t = datetime(2026, 6, 1, 12, 0, 5, 250000, tzinfo=UTC)
    write_frame(tmp_path / "f.npz", np.ones((SIZE, SIZE)), quaternion_j2000=q, observed_at="2026-06-01T12:00:05.25Z")
    got = read_folder(tmp_path, SIZE, resolve=resolve)
    assert np.allclose(got.angles_deg[0], (12.0, -7.0, 3.0), atol=1e-9)
    assert seen == [(t, "f.npz")] and got.observed_at == (t.isoformat(),)
    with pytest.raises(DatasetError, match="f.npz: quaternion_j2000: .*gsa adapt --plan"):
        read_folder(tmp_path, SIZE)


@pytest.mark.parametrize(
    ("members", "message"),
    [
        ({"image": np.ones((4, 4, 4))}, "image: a 2-D array"),
        ({"image": np.ones((SIZE, SIZE))}, "angles_deg: no label"),
        ({"image": np.ones((SIZE, 16)), "angles_deg": np.zeros(3)}, "the models take 32x32"),
        ({"image": np.ones((SIZE, SIZE)), "angles_deg": np.array([0.0, 95.0, 0.0])}, "y within"),
        ({"image": np.ones((SIZE, SIZE)), "angles_deg": np.zeros(2)}, "3 finite numbers"),
        ({"image": np.ones((SIZE, SIZE)), "quaternion_j2000": np.array([1.0, 0.5, 0, 0])}, "unit norm"),
        ({"image": np.ones((SIZE, SIZE)), "quaternion_j2000": np.array([1.0, 0, 0, 0])}, "observed_at"),
        ({"image": np.full((SIZE, SIZE), 0.5), "angles_deg": np.zeros(3), "normalised": np.array(True)}, "raw frame"),
        ({"image": np.ones((SIZE, SIZE)), "angles_deg": np.zeros(3), "snr_db": np.array([1.0, 2.0])}, "snr_db"),
        ({"image": np.ones((SIZE, SIZE)), "angles_deg": np.zeros(3), "range_cell_m": np.array(0.1)}, "together"),
        ({"image": np.ones((SIZE, SIZE)), "angles_deg": np.zeros(3), "attitude_sigma_deg": np.array(45.0)}, "sigma"),
        ({"image": np.ones((SIZE, SIZE)), "angles_deg": np.zeros(3), "observed_at": np.array("noon")}, "ISO 8601"),
    ],
)
def test_bad_frames_are_refused_by_file_and_member(tmp_path, members, message):
    np.savez(tmp_path / "bad.npz", **members)
    with pytest.raises(DatasetError, match=message) as err:
        read_folder(tmp_path, SIZE)
    assert str(err.value).startswith("bad.npz")


def test_unreadable_and_empty_folders(tmp_path):
    with pytest.raises(DatasetError, match="holds no .npz"):
        read_folder(tmp_path, SIZE)
    (tmp_path / "x.npz").write_bytes(b"not a zip")
    with pytest.raises(DatasetError, match="x.npz: not a readable"):
        read_folder(tmp_path, SIZE)
    with pytest.raises(DatasetError, match="not a folder"):
        read_folder(tmp_path / "missing", SIZE)


def test_the_split_never_puts_one_scene_on_both_sides():
    rng = np.random.default_rng(4)
    scenes = [f"s{k}" for k in rng.integers(0, 7, 200)]
    for seed in range(10):
        train, val = scene_split(scenes, 0.3, seed)
        assert sorted(np.concatenate([train, val]).tolist()) == list(range(200))
        assert not {scenes[i] for i in train} & {scenes[i] for i in val}
        assert len(val) >= 0.3 * 200 * 0.5 and len(train) > 0
    with pytest.raises(DatasetError, match="1 scene.*at least 2"):
        scene_split(["only"] * 10)


def test_coverage_counts_cells_of_the_cube():
    # 15 deg cells over +-45: 6 per axis, 216 cells. Frames at the centres of 5 distinct cells, two in one.
    centres = np.array([[-37.5, -37.5, -37.5], [7.5, 7.5, 7.5], [8.0, 9.0, 10.0], [37.5, -22.5, 7.5], [0, 0, 40]])
    assert coverage(centres) == pytest.approx(4 / 216)
    assert coverage(np.array([[60.0, 0.0, 0.0]])) == 0.0  # outside the networks' range: teaches nothing there


def _bomb_npz(member: str, header_shape: tuple[int, ...], payload: bytes) -> bytes:
    """An .npz whose ``member`` has a .npy header promising ``header_shape`` of U1 and ``payload`` of zeros after it
    (deflated: megabytes of zeros take kilobytes), beside a valid image and label."""
    import io
    import zipfile

    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        for name, arr in (("image", np.ones((32, 32))), ("angles_deg", np.array([1.0, 2.0, 3.0]))):
            b = io.BytesIO()
            np.save(b, arr)
            zf.writestr(f"{name}.npy", b.getvalue())
        head = io.BytesIO()
        np.lib.format.write_array_header_1_0(head, {"descr": "<U1", "fortran_order": False, "shape": header_shape})
        zf.writestr(f"{member}.npy", head.getvalue() + payload)
    return buf.getvalue()


@pytest.mark.parametrize(
    "header_shape, payload",
    [((), b"\0" * 200_000_000), ((10**12,), b"\0" * 4)],
    ids=["zip-bomb-behind-a-small-header", "header-promising-4-TB"],
)
def test_a_member_is_never_read_past_its_size(tmp_path, header_shape, payload):
    """observed_at as a zip bomb (a 1-character header, 200 MB of zeros behind it, deflated to ~200 kB) and as a
    header promising 4 TB: both refused by name, without decompressing or allocating what they promise."""
    import resource

    from inference.labelled import observed_times, read_frame

    data = _bomb_npz("observed_at", header_shape, payload)
    assert len(data) < 1_000_000
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    with pytest.raises(DatasetError, match="observed_at") as exc:
        read_frame(tmp_path / "bomb.npz", 32, data=data)
    assert exc.value.field == "observed_at"
    assert observed_times([("bomb.npz", data)]) == []  # skipped there; read_frame names it
    grew_mb = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before) / 1024
    assert grew_mb < 100, grew_mb


@pytest.mark.parametrize(
    "scene", ["a\ud800b", "pass\u202e3", "x\x00y", "\u2066left"], ids=["surrogate", "rlo", "nul", "isolate"]
)
def test_a_scene_name_is_text_an_operator_can_read(tmp_path, scene):
    """A lone surrogate (which no database or JSON encoder takes), a bidi control or a NUL in ``scene`` is refused by
    name, not a 500 further on."""
    import io

    from inference.labelled import read_frame

    buf = io.BytesIO()
    np.savez(buf, image=np.ones((32, 32)), angles_deg=np.array([1.0, 2.0, 3.0]), scene=np.array(scene))
    with pytest.raises(DatasetError, match="printable") as exc:
        read_frame(tmp_path / "f.npz", 32, data=buf.getvalue())
    assert exc.value.field == "scene"
