"""Model sets, one per target: `gsa train --model` makes one for a mesh, the service serves it beside the default
set, a request's target picks it, and the answer names the set that made it."""

import hashlib
import io
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.core.config import Settings
from app.core.db import upgrade_database
from app.main import create_app
from inference.errors import ModelFileError
from inference.runtime import UNNAMED_CARD_TARGET, ModelSets
from inference.simulation.targets import DEFAULT_TARGET

KEY = {"X-API-Key": "k-model-sets-0123456"}
BOX = """# a 4 x 2 x 1.5 m box
v -2 -1 -0.75
v 2 -1 -0.75
v 2 1 -0.75
v -2 1 -0.75
v -2 -1 0.75
v 2 -1 0.75
v 2 1 0.75
v -2 1 0.75
f 1 2 3
f 1 3 4
f 5 6 7
f 5 7 8
f 1 2 6
f 1 6 5
f 2 3 7
f 2 7 6
f 3 4 8
f 3 8 7
f 4 1 5
f 4 5 8
"""


def _gsa(*args, cwd):
    return subprocess.run([sys.executable, "-m", "app.cli", *args], capture_output=True, text=True, cwd=cwd)


@pytest.fixture(scope="module")
def box_set(tmp_path_factory):
    """A smoke model set trained on a box mesh by `gsa train --model`, exported."""
    root = tmp_path_factory.mktemp("box")
    (root / "box.obj").write_text(BOX)
    cwd = Path(__file__).resolve().parents[2]
    args = ("--model", str(root / "box.obj"), "--recipe", "smoke", "--epochs", "1", "--n", "16", "--n-train", "12")
    trained = _gsa("train", *args, "--out", str(root / "run"), cwd=cwd)
    assert trained.returncode == 0, trained.stderr[-2000:]
    exported = _gsa("export", "--run", str(root / "run"), "--out", str(root / "models"), cwd=cwd)
    assert exported.returncode == 0, exported.stderr[-2000:]
    return root


def test_the_card_records_the_target_it_was_trained_on(box_set):
    card = json.loads((box_set / "models" / "model_card.json").read_text())
    assert card["target"] == "box"
    model = card["target_model"]
    assert model["mesh_sha256"] == hashlib.sha256((box_set / "box.obj").read_bytes()).hexdigest()
    assert model["radius_m"] == pytest.approx(np.sqrt(2**2 + 1**2 + 0.75**2), abs=0.1)  # the box's half-diagonal
    # A box is symmetric about all three body planes: its mirror-pair labels coincide.
    assert {s["plane"] for s in model["symmetries"] if s["share_within"] > 0.95} == {"yz", "xz", "xy"}
    assert model["mirror_pair_label_iou"]["mean"] > 0.95  # (its skin is a random sample: not exactly symmetric)
    assert card["max_angle_deg"] == 45.0
    assert card["radar"]["n_range"] == 64  # the smoke networks' frames, the 24 m scene kept


def test_the_service_answers_each_target_with_its_own_set(box_set, smoke_models, tmp_path):
    settings = Settings(
        data_dir=tmp_path,
        api_keys="k-model-sets-0123456",
        model_dir=smoke_models,
        extra_model_dirs=str(box_set / "models"),
        target_model=box_set / "box.obj",
        database_url=f"sqlite:///{tmp_path / 'gsa.db'}",
    )
    upgrade_database(settings.database_url)
    frame = np.random.default_rng(0).random((64, 64)).astype(np.float32)
    buf = io.BytesIO()
    np.save(buf, frame)
    with TestClient(create_app(settings)) as client:
        ready = client.get("/readyz").json()
        sets = {s["target"]: s for s in ready["model_sets"]}
        assert set(sets) == {DEFAULT_TARGET, "box"} and sets[DEFAULT_TARGET]["default"] and not sets["box"]["default"]
        assert sets["box"]["unetpp_sha256"] and str(box_set) not in client.get("/readyz").text  # no server path
        for target, trained_on in (("box", "box"), (None, DEFAULT_TARGET), ("comsat-like", DEFAULT_TARGET)):
            form = {"target": target} if target else {}
            r = client.post("/v1/estimates", files={"file": ("f.npy", buf.getvalue())}, data=form, headers=KEY)
            assert r.status_code == 201, r.text
            body = r.json()
            assert body["target"] == (target or DEFAULT_TARGET) and body["model"]["trained_on"] == trained_on
            assert body["model"]["unetpp_sha256"] == sets[trained_on]["unetpp_sha256"]


def test_a_set_of_a_target_the_service_does_not_know_stops_it_naming_the_folder(box_set, smoke_models, tmp_path):
    settings = Settings(
        data_dir=tmp_path,
        api_keys="k-0123456789abcdef",
        model_dir=smoke_models,
        extra_model_dirs=str(box_set / "models"),
        database_url=f"sqlite:///{tmp_path / 'gsa.db'}",
    )
    with pytest.raises(ModelFileError, match=r"models is trained on 'box'.*GSA_TARGET_MODEL"):
        create_app(settings)


def test_two_sets_of_one_target_are_refused(smoke_models):
    with pytest.raises(ModelFileError, match="one set per target"):
        ModelSets.load(smoke_models, [smoke_models])


def test_an_unnamed_card_means_the_simulators_default_target():
    assert UNNAMED_CARD_TARGET == DEFAULT_TARGET


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (("--model", "missing.obj", "--recipe", "smoke"), "missing.obj does not exist"),
        (("--model", "box.obj", "--data", "d", "--recipe", "smoke"), "give --data"),
        (("--recipe", "smoke"), "give --data"),
        (("--model", "box.obj", "--recipe", "smoke", "--variety", "nope"), "unknown variety preset 'nope'"),
    ],
)
def test_gsa_train_model_refuses_bad_input_in_one_line(tmp_path, args, says):
    (tmp_path / "box.obj").write_text(BOX)
    r = _gsa("train", *args, "--out", str(tmp_path / "run"), cwd=tmp_path)
    assert r.returncode == 2 and says in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert not (tmp_path / "run" / "data").exists()
