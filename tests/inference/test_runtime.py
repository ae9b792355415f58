"""Estimator.estimate from many threads: frames share runs, each caller gets its own answers."""

from __future__ import annotations

import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest

from inference.errors import ModelFileError
from inference.export import export
from inference.runtime import Estimator

CARD = {"config": {"img_size": 8}, "angle_scale_deg": 45.0, "files": {}}


class FakeSession:
    """Stands in for an ONNX Runtime session: slow enough for callers to pile up, and it records its batches."""

    def __init__(self, role: str, batches: list[tuple[str, int]], lock: threading.Lock, fail_on: float | None = None):
        self.role, self.batches, self.lock, self.fail_on = role, batches, lock, fail_on
        self.active = 0

    def run(self, _outputs: None, feeds: dict[str, np.ndarray]) -> list[np.ndarray]:
        x = feeds["frame"]
        with self.lock:
            self.active += 1
            assert self.active == 1, "two runs of one network at once"
            self.batches.append((self.role, len(x)))
        try:
            time.sleep(0.02)
            if self.fail_on is not None and np.any(x == self.fail_on):
                raise RuntimeError("the model failed on this frame")
            if self.role == "unetpp":
                return [x * 2.0]  # "enhanced": twice the frame
            return [np.repeat(x.mean(axis=(1, 2, 3))[:, None], 3, axis=1) / 45.0]  # angles: the frame's mean
        finally:
            with self.lock:
                self.active -= 1


def _estimator(run_batch: int = 4, fail_on: float | None = None) -> tuple[Estimator, list[tuple[str, int]]]:
    batches: list[tuple[str, int]] = []
    lock = threading.Lock()
    sessions = {role: FakeSession(role, batches, lock, fail_on) for role in ("unetpp", "swin")}
    return Estimator(Path("."), CARD, sessions, run_batch=run_batch), batches


def _frame(value: float, n: int = 1) -> np.ndarray:
    return np.full((n, 8, 8), value, np.float32)


def test_concurrent_callers_share_runs_and_get_their_own_answers():
    est, batches = _estimator(run_batch=4)
    start = threading.Barrier(12)

    def call(k: int) -> tuple[int, np.ndarray, np.ndarray, dict[str, float]]:
        start.wait()
        res = est.estimate(_frame(float(k + 1)))
        return k, res.angles_deg, res.enhanced, res.timings_s

    with ThreadPoolExecutor(12) as pool:
        results = list(pool.map(call, range(12)))
    for k, angles, enhanced, timings in results:
        assert angles.shape == (1, 3) and enhanced.shape == (1, 8, 8)
        np.testing.assert_allclose(angles, 2.0 * (k + 1))  # enhanced is 2x the frame; Swin gives its mean
        np.testing.assert_allclose(enhanced, 2.0 * (k + 1))
        assert timings["unetpp"] > 0 and timings["swin"] > 0
    swin_runs = [n for role, n in batches if role == "swin"]
    assert sum(swin_runs) == 12
    assert max(swin_runs) > 1, "callers waiting together were never run together"
    assert max(swin_runs) <= 4


def test_a_request_is_never_split_and_big_stacks_run_in_pieces():
    est, batches = _estimator(run_batch=4)
    res = est.estimate(np.concatenate([_frame(float(v)) for v in range(10)]))
    np.testing.assert_allclose(res.angles_deg[:, 0], 2.0 * np.arange(10))
    assert [n for role, n in batches if role == "unetpp"] == [4, 4, 2]


def test_frames_of_other_sizes_wait_for_their_own_run():
    est, _ = _estimator()
    start = threading.Barrier(6)

    def call(k: int) -> tuple[int, ...]:
        start.wait()
        side = 8 if k % 2 else 16
        return est.estimate(np.full((1, side, side), float(k), np.float32)).enhanced.shape

    with ThreadPoolExecutor(6) as pool:
        shapes = list(pool.map(call, range(6)))
    assert shapes == [(1, 16, 16), (1, 8, 8)] * 3


def test_a_failed_run_raises_in_its_callers_and_the_estimator_goes_on():
    est, _ = _estimator(fail_on=-1.0)
    with pytest.raises(RuntimeError, match="failed on this frame"):
        est.estimate(_frame(-1.0))
    np.testing.assert_allclose(est.estimate(_frame(3.0)).angles_deg, 6.0)  # not stuck waiting on the failed run


def test_sessions_do_not_spin_wait():
    from inference.runtime import session_options

    opts = session_options(2)
    # Two sessions share 2 cores; a spinning pool steals them from the other network (BENCHMARKS.md).
    assert opts.get_session_config_entry("session.intra_op.allow_spinning") == "0"
    assert opts.intra_op_num_threads == 2 and opts.inter_op_num_threads == 1


def test_runtime_refuses_bad_model_files(smoke_run, tmp_path):
    out, _ = smoke_run
    export(out, tmp_path / "m")
    path = tmp_path / "m" / "swin.onnx"
    path.write_bytes(path.read_bytes()[:-100])
    with pytest.raises(ModelFileError, match="swin.onnx does not match"):
        Estimator.load(tmp_path / "m")
    path.unlink()
    with pytest.raises(ModelFileError, match="swin.onnx is missing"):
        Estimator.load(tmp_path / "m")
    with pytest.raises(ModelFileError, match="model_card.json is missing"):
        Estimator.load(tmp_path / "nothing")
