"""The cluster path on a real Ray cluster (``ray start --head`` on 127.0.0.1, two CPUs): a data set simulated
there, by ``gsa simulate`` and by a job of the service, is byte-identical to the one this process makes; an
address where no head answers is one clear line within seconds, not a hang."""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from inference.engine import EngineError, engine_for
from inference.simulation.dataset import DatasetSpec, generate
from inference.simulation.radar import Radar

SMALL = Radar(n_range=64, n_azimuth=64, bandwidth_hz=0.4e9, aperture_deg=1.275)
SMALL_ARGS = ["--n-range", "64", "--n-azimuth", "64", "--bandwidth-hz", "0.4e9", "--aperture-deg", "1.275"]
RAY = str(Path(sys.executable).with_name("ray"))


@pytest.fixture(scope="module")
def backend():
    return "sqlite"  # the engine is the subject here; the jobs' database paths are tested on both elsewhere


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    """A Ray head with two CPUs on this machine, started and stopped as an operator would (Ray's token
    authentication off: one user's loopback cluster; a real cluster's token travels in RAY_AUTH_TOKEN)."""
    port = _free_port()
    tmp = tmp_path_factory.mktemp("ray")
    saved = os.environ.get("RAY_AUTH_MODE")
    os.environ["RAY_AUTH_MODE"] = "disabled"  # the job workers this module's service starts inherit it
    env = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0"}
    cmd = [RAY, "start", "--head", "--node-ip-address", "127.0.0.1", "--port", str(port), "--num-cpus", "2"]
    cmd += ["--include-dashboard", "false", "--temp-dir", str(tmp), "--object-store-memory", str(200 * 2**20)]
    started = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=120)
    assert started.returncode == 0, started.stdout + started.stderr
    try:
        yield f"127.0.0.1:{port}"
    finally:
        subprocess.run([RAY, "stop", "--force"], env=env, capture_output=True, timeout=60)
        if saved is None:
            os.environ.pop("RAY_AUTH_MODE", None)
        else:
            os.environ["RAY_AUTH_MODE"] = saved


def test_gsa_simulate_on_the_cluster_writes_the_bytes_of_a_local_run(cluster, tmp_path):
    local = generate(
        DatasetSpec(n=8, seed=21, shard_size=3, n_train=6), tmp_path / "local", SMALL, workers=1, progress=False
    )
    env = {**os.environ, "GSA_RAY_ADDRESS": cluster}
    cmd = [
        sys.executable,
        "-m",
        "app.cli",
        "simulate",
        "--n",
        "8",
        "--seed",
        "21",
        "--shard-size",
        "3",
        "--n-train",
        "6",
    ]
    run = subprocess.run(
        [*cmd, *SMALL_ARGS, "--out", str(tmp_path / "ray")], env=env, capture_output=True, text=True, timeout=300
    )
    assert run.returncode == 0, run.stderr[-2000:]
    import json

    manifest = json.loads((tmp_path / "ray" / "manifest.json").read_text())
    assert manifest["engine"] == "ray" and manifest["workers"] == 2
    assert manifest["content_sha256"] == local["content_sha256"]
    for shard in local["shards"]:
        assert (tmp_path / "ray" / shard["file"]).read_bytes() == (tmp_path / "local" / shard["file"]).read_bytes()


def test_gsa_access_of_a_catalogue_on_the_cluster_writes_the_bytes_of_a_local_run(cluster, tmp_path):
    """A catalogue's shards as Ray tasks (issue 76): the same lines, byte for byte, as on this machine's one process."""
    from tests.app.api.test_catalogue import SETS, _body

    body = _body(SETS * 30, format="csv")  # 150 objects: 3 shards
    request = tmp_path / "catalogue.json"
    request.write_text(__import__("json").dumps(body))
    cmd = [sys.executable, "-m", "app.cli", "access", str(request)]
    plain = {k: v for k, v in os.environ.items() if k != "GSA_RAY_ADDRESS"}
    local = subprocess.run(cmd, env=plain, capture_output=True, text=True, timeout=300)
    on_ray = subprocess.run(cmd, env={**plain, "GSA_RAY_ADDRESS": cluster}, capture_output=True, text=True, timeout=300)
    assert local.returncode == 0 and on_ray.returncode == 0, local.stderr[-1000:] + on_ray.stderr[-1000:]
    assert on_ray.stdout == local.stdout and local.stdout.count("\n") > 150


def test_a_data_set_job_runs_on_the_cluster(cluster, settings, tmp_path):
    from app.main import create_app
    from tests.conftest import KEY_A

    on_ray = settings.model_copy(update={"ray_address": cluster})
    with TestClient(create_app(on_ray)) as client:
        body = {
            "n": 6,
            "seed": 4,
            "shard_size": 2,
            "radar": {"n_range": 64, "n_azimuth": 64, "bandwidth_hz": 0.4e9, "aperture_deg": 1.275},
        }
        r = client.post("/v1/datasets", json=body, headers={"X-API-Key": KEY_A})
        assert r.status_code == 202 and r.json()["engine"] == "ray", r.text
        deadline = time.monotonic() + 180
        while (job := client.get(f"/v1/jobs/{r.json()['id']}", headers={"X-API-Key": KEY_A}).json())["state"] in (
            "queued",
            "running",
        ) and time.monotonic() < deadline:
            time.sleep(0.3)
    assert job["state"] == "done", job
    assert job["result"]["engine"] == "ray" and job["result"]["workers"] == 2
    here = generate(DatasetSpec(n=6, seed=4, shard_size=2), tmp_path / "here", SMALL, workers=1, progress=False)
    assert job["result"]["content_sha256"] == here["content_sha256"]


def test_gsa_train_on_the_cluster_is_ray_trains_torchtrainer_with_ddp(cluster, smoke_data, tmp_path):
    """Two Ray Train workers (TorchTrainer) train one run with DistributedDataParallel: worker 0 writes it."""
    env = {**os.environ, "GSA_RAY_ADDRESS": cluster, "OMP_NUM_THREADS": "1"}
    cmd = [sys.executable, "-m", "app.cli", "train", "--data", str(smoke_data), "--out", str(tmp_path / "run")]
    cmd += ["--recipe", "smoke", "--epochs", "2", "--batch-size", "8", "--threads", "1", "--ray-workers", "2"]
    done = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    import json

    record = json.loads((tmp_path / "run" / "training.json").read_text())
    assert record["complete"] and record["distributed"] == {"processes": 2, "backend": "gloo", "frames_per_process": 16}
    assert (tmp_path / "run" / "swin.pt").is_file() and (tmp_path / "run" / "unetpp.pt").is_file()
    assert "2 Ray Train workers" in done.stderr and "epoch 2/2 done on the cluster" in done.stderr
    assert "trained 2 epochs" in done.stdout


def test_gsa_adapt_on_the_cluster_is_ray_train_with_ddp(cluster, smoke_models, tmp_path):
    """An adaptation on the cluster: two Ray Train workers share each step (DDP on their CPUs); worker 0 keeps the
    best weights, exports and recalibrates; its lines reach the command's stderr."""
    import json

    import numpy as np

    from inference.labelled import write_frame
    from inference.simulation.dataset import render_frames
    from tests.utils.models import SMOKE_RADAR

    folder = tmp_path / "lab"
    folder.mkdir()
    arr = render_frames(DatasetSpec(n=24, seed=77, variety="robust"), SMOKE_RADAR, 0, 24)
    for k in range(24):
        write_frame(
            folder / f"f{k:02d}.npz",
            arr["image"][k].astype(np.float32),
            angles_deg=arr["angles_deg"][k],
            scene=f"s{k // 8}",
            normalised=True,
        )
    env = {**os.environ, "GSA_RAY_ADDRESS": cluster, "OMP_NUM_THREADS": "1"}
    cmd = [sys.executable, "-m", "app.cli", "adapt", "--frames", str(folder), "--base", str(smoke_models)]
    cmd += ["--out", str(tmp_path / "adapted"), "--epochs", "2", "--sim-ratio", "0.5", "--batch-size", "8"]
    done = subprocess.run([*cmd, "--ray-workers", "2"], env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    card = json.loads((tmp_path / "adapted" / "model_card.json").read_text())
    assert card["adaptation"]["processes"] == 2 and card["adaptation"]["labelled"]["frames"] == 24
    assert "2 Ray Train workers" in done.stderr and "adapt: epoch 2/2" in done.stderr
    assert "recalibrated" in card["adaptation"]["calibration"] and (tmp_path / "adapted" / "unetpp.onnx").is_file()
    assert json.loads(done.stdout)["chosen_epoch"] in (0, 1, 2)


def test_an_address_where_no_head_answers_is_a_clear_error_in_seconds(tmp_path):
    port = _free_port()  # nothing listens there
    started = time.monotonic()
    with pytest.raises(EngineError, match=f"127.0.0.1:{port}: no Ray head answers there"):
        engine_for(f"127.0.0.1:{port}")
    with pytest.raises(EngineError, match="not an address"):
        engine_for("headnode")
    env = {**os.environ, "GSA_RAY_ADDRESS": f"127.0.0.1:{port}"}
    run = subprocess.run(
        [sys.executable, "-m", "app.cli", "simulate", "--n", "2", *SMALL_ARGS, "--out", str(tmp_path / "x")],
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 2 and run.stderr.count("\n") == 1, run.stderr
    assert "no Ray head answers there" in run.stderr and not (tmp_path / "x").exists()
    serve = subprocess.run(
        [sys.executable, "-m", "app.cli", "serve", "--port", str(_free_port())],
        env={**env, "GSA_DATA_DIR": str(tmp_path / "data")},
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert serve.returncode == 2 and "GSA_RAY_ADDRESS" in serve.stderr and "Traceback" not in serve.stderr
    assert time.monotonic() - started < 60
    shutil.rmtree(tmp_path / "data", ignore_errors=True)
