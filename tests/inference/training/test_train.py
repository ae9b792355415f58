"""Training on the smoke configuration: losses fall, bf16, resume, averaged weights, two-stage, the command."""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from inference.errors import DatasetError, InferenceError, ModelFileError
from inference.export import export
from inference.networks.build import build_models, get_config
from inference.runtime import Estimator
from inference.training.options import recipe
from inference.training.train import train
from tests.utils.models import SMOKE_RADAR as SMALL


def test_training_lowers_the_losses_and_writes_everything(smoke_run):
    out, record = smoke_run
    hist = record["history"]
    assert len(hist) == 2 and record["complete"]
    assert hist[-1]["unet_loss"] < hist[0]["unet_loss"]
    for name in ("unetpp.pt", "swin.pt", "checkpoint.pt", "training.json", "loss.png"):
        assert (out / name).is_file()
    assert record["data"]["train"] == 16 and record["data"]["test"] == 8


def test_cpu_bf16_is_used_where_linux_says_the_cpu_has_it(monkeypatch):
    from inference.training import train as train_module

    flags = Path("/proc/cpuinfo")
    if flags.is_file():  # the kernel's own CPU flags, not torch's probe
        have = {"avx512_bf16", "amx_tile"} & set(flags.read_text().split())
        assert train_module.cpu_has_native_bf16() == bool(have)
    cpu, gpu = torch.device("cpu"), torch.device("cuda")
    assert train_module.uses_bf16(gpu, "auto") and not train_module.uses_bf16(gpu, "float32")
    assert train_module.uses_bf16(cpu, "bf16") and not train_module.uses_bf16(cpu, "float32")
    for native in (True, False):
        monkeypatch.setattr(train_module, "cpu_has_native_bf16", lambda native=native: native)
        assert train_module.uses_bf16(cpu, "auto") == native
    with pytest.raises(InferenceError, match="precision 'fp8' must be one of auto, bf16, float32") as e:
        recipe("smoke", precision="fp8").check()
    assert e.value.field == "precision"


def test_bf16_and_float32_training_learn_alike(smoke_data, tmp_path):
    records = {
        p: train(smoke_data, tmp_path / p, recipe("smoke", epochs=2, precision=p, log_every=0))
        for p in ("bf16", "float32")
    }
    assert [r["hardware"]["bf16_autocast"] for r in records.values()] == [True, False]
    for r in records.values():
        assert r["history"][-1]["unet_loss"] < r["history"][0]["unet_loss"]
    # The same seed and batches: bf16 keeps 8 bits of mantissa, so the first epoch's mean losses agree
    # to a per cent or two (measured: 2e-4 and 1e-3), not to the last bit.
    first = [r["history"][0] for r in records.values()]
    assert first[0]["unet_loss"] == pytest.approx(first[1]["unet_loss"], rel=0.01)
    assert first[0]["swin_loss"] == pytest.approx(first[1]["swin_loss"], rel=0.02)
    assert first[0]["unet_loss"] != first[1]["unet_loss"]  # and they did compute differently


def test_resume_continues_from_the_checkpoint(smoke_data, smoke_run, tmp_path):
    out, _ = smoke_run
    shutil.copytree(out, tmp_path / "run")
    record = train(smoke_data, tmp_path / "run", recipe("smoke", epochs=3, resume=True, log_every=0))
    assert [h["epoch"] for h in record["history"]] == [1, 2, 3]


def test_averaged_weights_are_scored_saved_resumed_and_packed(smoke_data, tmp_path):
    from inference.training.checkpoints import averaged_weights
    from inference.training.pipeline import pack

    out = tmp_path / "ema"
    rec = train(smoke_data, out, recipe("smoke", epochs=2, ema=0.5, log_every=0))
    assert rec["ema"] == 0.5 and all(len(h["ema_test_mae_deg"]) == 3 for h in rec["history"])
    ck = torch.load(out / "checkpoint.pt", weights_only=False)
    saved = torch.load(out / "swin.pt", weights_only=False)["state_dict"]
    avg = averaged_weights(ck["ema"]["swin"])
    assert set(avg) == set(saved) == set(ck["swin"])
    torch.testing.assert_close(saved["head.weight"], avg["head.weight"])
    assert not torch.equal(saved["head.weight"], ck["swin"]["head.weight"])  # the average, not the last step
    # The average carries over a resume, and pack hands back the averaged weights.
    again = train(smoke_data, out, recipe("smoke", epochs=3, ema=0.5, resume=True, log_every=0))
    assert len(again["history"]) == 3 and "ema_test_mae_deg" in again["history"][-1]
    ck3 = torch.load(out / "checkpoint.pt", weights_only=False)
    assert int(ck3["ema"]["swin"]["n_averaged"]) == 3 * int(ck["ema"]["swin"]["n_averaged"]) // 2
    manifest = pack(out, tmp_path / "pieces")
    assert manifest["averaged_weights"] is True
    with pytest.raises(InferenceError, match="ema 1.5 must be in"):
        train(smoke_data, tmp_path / "bad", recipe("smoke", ema=1.5))
    with pytest.raises(InferenceError, match="use it with mode 'joint'"):
        train(smoke_data, tmp_path / "bad", recipe("smoke", ema=0.9, mode="two-stage"))


def test_enhance_all_enhances_only_the_rows_asked_for():
    from inference.training.train import enhance_all

    unet, _ = build_models(get_config("smoke"))
    images = np.random.default_rng(0).random((6, 64, 64)).astype(np.float16)
    every = enhance_all(unet, images, torch.device("cpu"), batch=4)
    some = enhance_all(unet, images, torch.device("cpu"), batch=4, rows=np.array([5, 0, 2, 2]))
    np.testing.assert_array_equal(some[[0, 2, 5]], every[[0, 2, 5]])
    assert not some[[1, 3, 4]].any() and every[[1, 3, 4]].any()


def test_two_stage_from_a_trained_unet_freezes_it_and_trains_swin(smoke_data, smoke_run, tmp_path):
    out, _ = smoke_run
    unet_before = torch.load(out / "unetpp.pt", weights_only=False)["state_dict"]
    swin_before = torch.load(out / "swin.pt", weights_only=False)["state_dict"]
    record = train(
        smoke_data,
        tmp_path / "two",
        recipe("smoke", epochs=2, mode="two-stage", unet_epochs=0, unet_from=out / "unetpp.pt", log_every=0),
    )
    unet_after = torch.load(tmp_path / "two" / "unetpp.pt", weights_only=False)["state_dict"]
    swin_after = torch.load(tmp_path / "two" / "swin.pt", weights_only=False)["state_dict"]
    assert all(torch.equal(unet_before[k], unet_after[k]) for k in unet_before)  # frozen, loaded as given
    assert any(not torch.equal(swin_before[k], swin_after[k]) for k in swin_before)
    assert record["unet_epochs"] == 0 and all(h["unet_loss"] == 0.0 for h in record["history"])
    with pytest.raises(InferenceError, match="unet_epochs"):
        train(smoke_data, tmp_path / "bad", recipe("smoke", epochs=2, mode="two-stage", unet_epochs=5))
    with pytest.raises(InferenceError, match="unetpp.pt"):
        train(smoke_data, tmp_path / "bad", recipe("smoke", unet_from=tmp_path / "missing.pt"))


def _train_fresh(data, out):
    train(data, out, recipe("smoke", epochs=1, lr=1e-12, mode="two-stage", unet_epochs=0, log_every=0))
    return out / "swin.pt"


def test_swin_from_starts_swin_from_earlier_weights_with_a_fresh_schedule(smoke_data, smoke_run, tmp_path):
    out, _ = smoke_run
    swin_before = torch.load(out / "swin.pt", weights_only=False)["state_dict"]
    record = train(
        smoke_data,
        tmp_path / "ft",
        recipe(
            "smoke",
            epochs=1,
            lr=1e-12,
            lr_decay=0.5,
            mode="two-stage",
            unet_epochs=0,
            unet_from=out / "unetpp.pt",
            swin_from=out / "swin.pt",
            log_every=0,
        ),
    )
    swin_after = torch.load(tmp_path / "ft" / "swin.pt", weights_only=False)["state_dict"]
    # a vanishing learning rate leaves the loaded weights where the earlier run left them
    assert all(torch.allclose(swin_before[k], swin_after[k], atol=1e-6) for k in swin_before)
    assert record["swin_from"] == str(out / "swin.pt") and record["schedule"]["lr_decay"] == 0.5
    fresh = torch.load(_train_fresh(smoke_data, tmp_path / "fresh"), weights_only=False)["state_dict"]
    assert any(not torch.allclose(swin_before[k], fresh[k], atol=1e-6) for k in swin_before)
    with pytest.raises(InferenceError, match="swin.pt"):
        train(smoke_data, tmp_path / "bad", recipe("smoke", swin_from=tmp_path / "missing.pt"))
    with pytest.raises(InferenceError, match="swin_from|does not fit"):
        train(smoke_data, tmp_path / "bad", recipe("smoke", swin_from=out / "unetpp.pt", log_every=0))
    with pytest.raises(InferenceError, match="lr_decay"):
        train(smoke_data, tmp_path / "bad", recipe("smoke", lr_decay=1.5))


def test_a_smaller_swin_behind_a_trained_unet_trains_exports_and_runs(smoke_data, smoke_run, tmp_path):
    out, _ = smoke_run
    shape = {"swin_dim": 8, "swin_depths": (1, 1, 1, 1), "swin_heads": (1, 1, 2, 2)}
    options = recipe("smoke", epochs=1, mode="two-stage", unet_epochs=0, unet_from=out / "unetpp.pt", **shape)
    record = train(smoke_data, tmp_path / "small", options)
    assert record["config"]["swin_embed_dim"] == 8 and tuple(record["config"]["swin_heads"]) == (1, 1, 2, 2)
    swin = torch.load(tmp_path / "small" / "swin.pt", weights_only=False)
    assert swin["state_dict"]["patch_embed.weight"].shape[0] == 8
    card = export(tmp_path / "small", tmp_path / "models")  # export rebuilds the overridden shape from the record
    assert card["config"]["swin_embed_dim"] == 8
    assert card["files"]["swin"]["parity_max_rel_diff"] < 1e-4
    angles = Estimator.load(tmp_path / "models").estimate(np.zeros((2, 64, 64), np.float32)).angles_deg
    assert angles.shape == (2, 3) and np.isfinite(angles).all()
    with pytest.raises(InferenceError, match="which 5 heads do not divide"):
        train(smoke_data, tmp_path / "bad", recipe("smoke", swin_heads=(5, 1, 2, 2)))
    with pytest.raises(InferenceError, match="one head count per stage"):
        train(smoke_data, tmp_path / "bad", recipe("smoke", swin_depths=(1, 1, 1)))
    with pytest.raises(InferenceError, match="unknown config field"):
        get_config("smoke", swin_width=3)
    with pytest.raises(InferenceError, match="another network shape"):  # resuming with a different shape
        train(smoke_data, tmp_path / "small", recipe("smoke", epochs=2, resume=True, log_every=0))
    assert not (tmp_path / "bad").exists()


def test_train_command_shape_flags(smoke_data, tmp_path):
    from inference.training.train import main

    assert (
        main(
            [
                "--data",
                str(smoke_data),
                "--config",
                "smoke",
                "--out",
                str(tmp_path / "r"),
                "--epochs",
                "1",
                "--swin-dim",
                "8",
                "--swin-heads",
                "1,1,2,2",
                "--unet-filters",
                "2,4,8,16,32",
            ]
        )
        == 0
    )
    cfg = json.loads((tmp_path / "r" / "training.json").read_text())["config"]
    assert (cfg["swin_embed_dim"], cfg["unet_filters"]) == (8, [2, 4, 8, 16, 32])
    with pytest.raises(SystemExit):
        main(["--data", str(smoke_data), "--out", str(tmp_path / "x"), "--swin-depths", "2,two"])
    assert (
        main(["--data", str(smoke_data), "--config", "smoke", "--out", str(tmp_path / "y"), "--swin-heads", "1,1"]) == 2
    )


def test_training_refuses_bad_data(smoke_data, tmp_path):
    with pytest.raises(DatasetError, match="no manifest"):
        train(tmp_path, tmp_path / "out", recipe("smoke"))
    with pytest.raises(DatasetError, match="takes 256x256"):
        train(smoke_data, tmp_path / "out", recipe("compact"))
    bad = tmp_path / "bad"
    shutil.copytree(smoke_data, bad)
    manifest = json.loads((bad / "manifest.json").read_text())
    manifest["shards"][0]["sha256"] = "0" * 64
    (bad / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(DatasetError, match="does not match its sha256"):
        train(bad, tmp_path / "out", recipe("smoke"))
    with pytest.raises(InferenceError, match="unknown config"):
        get_config("huge")


def test_training_batches_are_the_same_from_numpy_and_from_device_tensors():
    """On a GPU the data set lives on the device as tensors; a batch must not depend on where it came from."""
    from inference.training.train import _tensors

    rng = np.random.default_rng(0)
    data = {
        "image": rng.random((10, 8, 8)).astype(np.float16),
        "label": rng.random((10, 8, 8)) > 0.5,
        "angles_deg": rng.uniform(-45, 45, (10, 3)).astype(np.float32),
    }
    tensors = {k: torch.from_numpy(v) for k, v in data.items()}
    sel = np.array([1, 4, 7])
    for a, b in zip(
        _tensors(data["image"], data, sel, torch.device("cpu")),
        _tensors(tensors["image"], tensors, sel, torch.device("cpu")),
        strict=True,
    ):
        assert a.dtype == b.dtype == torch.float32
        torch.testing.assert_close(a, b)
    x, y, a = _tensors(tensors["image"], tensors, sel, torch.device("cpu"))
    assert x.shape == (3, 1, 8, 8) and y.shape == (3, 1, 8, 8)
    np.testing.assert_allclose(a.numpy() * 45.0, data["angles_deg"][sel], rtol=1e-6)


def test_gpu_pipeline_at_toy_size(tmp_path):
    """The GPU commands end to end on a CPU: simulate, train, evaluate, pieces out, join back, export."""
    from inference.training.pipeline import join, pack
    from inference.training.pipeline import run as pipeline_run

    work = tmp_path / "work"
    manifest = pipeline_run(
        work,
        recipe("smoke", max_minutes=5, epochs=1),
        n=12,
        out=tmp_path / "out",
        radar=SMALL,
        name="a",
        n_train=8,
        n_snr=4,
    )
    assert manifest["complete"] and manifest["swin"]
    assert json.loads((work / "data" / "manifest.json").read_text())["split"] == {"train": [0, 8], "test": [8, 12]}
    for f in (tmp_path / "out").iterdir():
        assert f.stat().st_size < 16 * 1024 * 1024
    # The torch weights were scored on the test split and on each fresh SNR set.
    rows = json.loads((tmp_path / "out" / "evaluation.json").read_text())["rows"]
    assert set(rows) == {"with enhancement", "0 dB", "5 dB", "10 dB"}
    assert rows["with enhancement"]["n"] == 4 and rows["0 dB"]["n"] == 4
    join(tmp_path / "out", tmp_path / "run")
    assert (tmp_path / "run" / "evaluation.json").exists()
    card = export(tmp_path / "run", tmp_path / "models")
    assert card["files"]["swin"]["parity_max_rel_diff"] < 1e-4
    # The float16 pieces hold the trained weights to float16 precision.
    ck = torch.load(work / "a" / "swin.pt", weights_only=False)
    back = torch.load(tmp_path / "run" / "swin.pt", weights_only=False)
    for k, v in ck["state_dict"].items():
        if v.is_floating_point():
            torch.testing.assert_close(back["state_dict"][k], v.half().float())
    # A second call resumes instead of starting again; a second run shares the data.
    again = pipeline_run(work, recipe("smoke", max_minutes=5, epochs=2), n=12, radar=SMALL, name="a", evaluate=False)
    assert again["epochs"] == 2
    other = pipeline_run(
        work, recipe("smoke", max_minutes=5, epochs=1, max_train_frames=4), n=12, radar=SMALL, name="b", evaluate=False
    )
    assert other["epochs"] == 1
    assert json.loads((work / "b" / "training.json").read_text())["data"]["train"] == 4
    # A Swin on raw frames (gsa_train.sh's noenhance run) is scored without UNet++: Table 4's other row.
    raw = pipeline_run(work, recipe("smoke", max_minutes=5, epochs=1, enhance=False), n=12, radar=SMALL, name="raw")
    assert raw["epochs"] == 1
    raw_rows = json.loads((work / "raw" / "evaluation.json").read_text())["rows"]
    assert set(raw_rows) == {"without enhancement"} | {f"{d} dB, without enhancement" for d in (0, 5, 10)}
    assert json.loads((work / "raw" / "training.json").read_text())["enhance"] is False
    # Two stages (gpu_train.sh's twostage run): UNet++ for one epoch, then Swin on its frozen output.
    two = pipeline_run(
        work,
        recipe("smoke", max_minutes=5, epochs=2, mode="two-stage", unet_epochs=1),
        n=12,
        radar=SMALL,
        name="two",
        evaluate=False,
    )
    assert two["epochs"] == 2
    staged = json.loads((work / "two" / "training.json").read_text())
    assert staged["mode"] == "two-stage" and staged["unet_epochs"] == 1 and staged["history"][1]["unet_loss"] == 0.0
    # A run can start from joined pieces (how a later GPU session continues the shipped weights).
    cont = pipeline_run(
        work,
        recipe(
            "smoke",
            max_minutes=5,
            epochs=1,
            lr=1e-12,
            unet_from=tmp_path / "run" / "unetpp.pt",
            swin_from=tmp_path / "run" / "swin.pt",
        ),
        n=12,
        radar=SMALL,
        name="c",
        evaluate=False,
    )
    assert cont["epochs"] == 1
    rec = json.loads((work / "c" / "training.json").read_text())
    assert rec["swin_from"].endswith("swin.pt") and rec["schedule"]["lr"] == 1e-12
    torch.testing.assert_close(
        torch.load(work / "c" / "swin.pt", weights_only=False)["state_dict"]["head.weight"],
        back["state_dict"]["head.weight"],
    )
    # pack takes the newest epoch from the checkpoint, even while no final weights exist.
    (work / "b" / "swin.pt").unlink()
    assert pack(work / "b", tmp_path / "out3")["epochs"] == 1
    with pytest.raises(ModelFileError, match="checkpoint.pt is missing"):
        pack(tmp_path / "nowhere", tmp_path / "out4")


def test_swin_learns_the_cube_only_from_a_set_over_so3():
    """cube_angle_loss: the mean squared error over the frames inside the cube (scaled angles within [-1, 1]),
    computed directly; the paper's loss where every frame is inside; 0 (not NaN) where none is."""
    from inference.networks.swin import angle_loss, cube_angle_loss

    gen = torch.Generator().manual_seed(0)
    pred = torch.randn(6, 3, generator=gen)
    target = torch.tensor(
        [[0.1, -0.5, 0.9], [2.0, 0.1, 0.1], [0.0, 0.0, -1.0], [-3.9, 1.5, 0.2], [0.3, 0.3, 0.3], [1.0, 1.0, 1.01]]
    )
    inside = [0, 2, 4]
    direct = sum(float(((pred[k] - target[k]) ** 2).mean()) for k in inside) / len(inside)
    assert float(cube_angle_loss(pred, target)) == pytest.approx(direct, rel=1e-6)
    assert float(cube_angle_loss(pred[inside], target[inside])) == pytest.approx(
        float(angle_loss(pred[inside], target[inside])), rel=1e-6
    )
    assert float(cube_angle_loss(pred[[1, 3]], target[[1, 3]])) == 0.0


def test_gpu_pipeline_over_so3_at_toy_size(tmp_path):
    """A set half over every rotation: UNet++'s silhouettes are scored inside and outside the cube each epoch,
    Swin's MAE and the evaluation rows over the test frames inside the cube only (counted from the set itself)."""
    from inference.simulation.dataset import load_arrays
    from inference.training.pipeline import run as pipeline_run

    work = tmp_path / "work"
    pipeline_run(
        work,
        recipe("smoke", max_minutes=5, epochs=1),
        n=16,
        out=tmp_path / "out",
        radar=SMALL,
        name="so3",
        n_train=8,
        attitudes="so3",
        so3_share=0.5,
    )
    angles = load_arrays(work / "data", verify=False)["angles_deg"][8:]
    inside = int(np.all(np.abs(angles) <= 45.0, axis=1).sum())
    assert 0 < inside < 8, inside  # both kinds in the test split (seed 0)
    history = json.loads((tmp_path / "out" / "training.json").read_text())["history"]
    iou = history[-1]["test_silhouette_iou"]
    assert set(iou) == {"cube", "outside"} and all(0.0 <= v <= 1.0 for v in iou.values())
    assert np.all(np.isfinite(history[-1]["test_mae_deg"]))
    rows = json.loads((tmp_path / "out" / "evaluation.json").read_text())["rows"]
    assert rows["with enhancement"]["n"] == inside
