"""Training under torchrun with DistributedDataParallel (gloo, two CPU processes): the two processes split each
step's batch and average their gradients, so they take the steps one process takes over the whole batch (the
losses are per-frame means) -- checked against a one-process run of the same options, weight by weight."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest
import torch

from inference.training.options import recipe
from inference.training.train import train

FLAGS = ["--recipe", "smoke", "--epochs", "2", "--batch-size", "8", "--precision", "float32", "--threads", "1"]


def _weights(path):
    return {
        k: v.float().numpy() for k, v in torch.load(path, map_location="cpu", weights_only=False)["state_dict"].items()
    }


def test_two_processes_under_torchrun_take_the_steps_of_one(smoke_data, tmp_path):
    # Swin alone (--no-enhance), so no batch norm (whose statistics DDP keeps per process on a CPU) enters.
    one = train(
        smoke_data,
        tmp_path / "one",
        recipe("smoke", epochs=2, batch_size=8, enhance=False, precision="float32", threads=1),
    )
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc-per-node", "2"]
    cmd += [
        "-m",
        "inference.training.train",
        "--data",
        str(smoke_data),
        "--out",
        str(tmp_path / "two"),
        *FLAGS,
        "--no-enhance",
    ]
    done = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.count("trained 2 epochs") == 1  # process 0 reports; process 1 says nothing
    record = json.loads((tmp_path / "two" / "training.json").read_text())
    assert record["distributed"] == {"processes": 2, "backend": "gloo", "frames_per_process": 16}  # 2 x 16 / 2
    assert one["distributed"] == {"processes": 1, "backend": None, "frames_per_process": 32}
    a, b = _weights(tmp_path / "one" / "swin.pt"), _weights(tmp_path / "two" / "swin.pt")
    start = {k: v.float().numpy() for k, v in _initial_swin().items()}
    moved = max(float(np.abs(a[k] - start[k]).max()) for k in a)
    apart = max(float(np.abs(a[k] - b[k]).max()) for k in a)
    assert moved > 1e-3 and apart < 0.01 * moved, (moved, apart)  # summation order alone separates them
    # Scored by process 0 on the whole test split with those weights: the same errors.
    assert record["history"][-1]["test_mae_deg"] == pytest.approx(one["history"][-1]["test_mae_deg"], rel=1e-3)


def _initial_swin():
    from inference.networks.build import build_models, get_config

    torch.manual_seed(0)
    _, swin = build_models(get_config("smoke"))
    return swin.state_dict()


def test_joint_training_runs_under_torchrun_and_refuses_a_batch_smaller_than_the_processes(smoke_data, tmp_path):
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    base = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc-per-node", "2", "-m"]
    base += ["inference.training.train", "--data", str(smoke_data)]
    done = subprocess.run(
        [*base, "--out", str(tmp_path / "j"), *FLAGS], env=env, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr[-3000:]
    record = json.loads((tmp_path / "j" / "training.json").read_text())
    assert record["complete"] and record["enhance"] and record["distributed"]["processes"] == 2
    assert (tmp_path / "j" / "unetpp.pt").is_file() and (tmp_path / "j" / "swin.pt").is_file()
    # One process of two, as torchrun starts it: refused before it joins the group (no second process needed).
    from inference.errors import InferenceError

    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("WORLD_SIZE", "2")
        mp.setenv("RANK", "0")
        with pytest.raises(InferenceError, match="batch size 1 is smaller than the 2 processes"):
            train(smoke_data, tmp_path / "s", recipe("smoke", epochs=1, batch_size=1, threads=1))
