"""Networks, training, ONNX export and the runtime, on the smoke configuration."""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from inference.errors import DatasetError, InferenceError, ModelFileError
from inference.export import export
from inference.networks.build import build_models, get_config
from inference.networks.swin import SwinTransformer, window_partition, window_reverse
from inference.networks.unetpp import UNetPlusPlus, relative_frobenius_loss
from inference.rotations import euler_to_quaternion
from inference.runtime import Estimator
from inference.simulation.dataset import DatasetSpec, generate
from inference.simulation.radar import Radar
from inference.training.options import recipe
from inference.training.train import train

SMALL = Radar(n_range=64, n_azimuth=64, bandwidth_hz=0.4e9, aperture_deg=5.1 / 4)


@pytest.fixture(scope="module")
def smoke_data(tmp_path_factory):
    d = tmp_path_factory.mktemp("data") / "set"
    generate(DatasetSpec(n=24, seed=3, shard_size=12, n_train=16), d, SMALL, workers=1, progress=False)
    return d


@pytest.fixture(scope="module")
def smoke_run(smoke_data, tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    record = train(smoke_data, out, recipe("smoke", epochs=2, log_every=0))
    return out, record


def test_paper_sizes():
    unet, swin = build_models(get_config("paper"))
    assert sum(p.numel() for p in unet.parameters()) == pytest.approx(9.04e6, rel=0.01)
    assert sum(p.numel() for p in swin.parameters()) == pytest.approx(27.5e6, rel=0.01)


def test_shapes_and_window_round_trip():
    x = torch.randn(2, 16, 16, 5)
    assert torch.equal(window_reverse(window_partition(x, 8), 8, 16, 16), x)
    unet = UNetPlusPlus(1, (4, 8, 16, 32, 64))
    assert unet(torch.zeros(3, 1, 64, 64)).shape == (3, 1, 64, 64)
    swin = SwinTransformer(img_size=64, embed_dim=12, depths=(2, 2, 1, 1), num_heads=(1, 1, 2, 2))
    assert swin(torch.zeros(3, 1, 64, 64)).shape == (3, 3)


def test_shifted_window_mask_blocks_wrapped_neighbours():
    swin = SwinTransformer(img_size=64, embed_dim=12, depths=(2, 1, 1, 1), num_heads=(1, 1, 1, 1))
    block = swin.stages[0].blocks[1]
    assert block.shift == 4 and block.attn_mask is not None
    mask = block.attn_mask
    assert mask.shape == (4, 64, 64) and (mask == 0).all(dim=(1, 2)).tolist()[0]  # first window: no wrap
    assert (mask[-1] < 0).any()  # the corner window mixes wrapped regions


def test_relative_frobenius_loss():
    label = torch.ones(1, 1, 4, 4)
    assert float(relative_frobenius_loss(label, label)) == 0.0
    assert float(relative_frobenius_loss(torch.zeros_like(label), label)) == pytest.approx(1.0)


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


def test_compare_counts_swin_epochs_and_writes_table_and_plot(smoke_data, smoke_run, tmp_path):
    from inference.evaluation.compare import compare, main

    out, joint = smoke_run
    two = train(smoke_data, tmp_path / "two", recipe("smoke", epochs=3, mode="two-stage", unet_epochs=2, log_every=0))
    raw = train(smoke_data, tmp_path / "raw", recipe("smoke", epochs=1, enhance=False, log_every=0))
    text = compare([out, tmp_path / "two", tmp_path / "raw"], tmp_path / "cmp")
    rows = {line.split(" | ")[0].strip("| "): line for line in text.splitlines() if line.startswith("| ")}
    # two-stage: UNet++ alone for 2 epochs, so its Swin has trained 1 epoch, scored as in its record
    assert "two-stage (UNet++ 2 epochs, then Swin on its output) | 1 |" in rows["two"]
    assert " / ".join(f"{v:.2f}" for v in two["history"][2]["test_mae_deg"]) in rows["two"]
    assert "| 2 |" in rows[out.name] and "no enhancement" in rows["raw"]
    epoch2 = rows["2"].split(" | ")
    assert epoch2[1] == " / ".join(f"{v:.2f}" for v in joint["history"][1]["test_mae_deg"]) and epoch2[2] == ""
    assert raw["history"][0]["test_mae_deg"][0] > 0
    assert (tmp_path / "cmp" / "compare.md").read_text() == text
    assert (tmp_path / "cmp" / "compare.png").stat().st_size > 5000
    assert main([str(tmp_path / "missing"), "--out", str(tmp_path / "bad")]) == 2
    assert main([str(out), str(out), "--out", str(tmp_path / "bad")]) == 2
    assert not (tmp_path / "bad").exists()


def _train_fresh(data, out):
    train(data, out, recipe("smoke", epochs=1, lr=1e-12, mode="two-stage", unet_epochs=0, log_every=0))
    return out / "swin.pt"


def test_export_parity_and_runtime(smoke_run, smoke_data, tmp_path):
    out, _ = smoke_run
    from inference.simulation.dataset import load_arrays

    frames = load_arrays(smoke_data)["image"][:4].astype(np.float32)
    card = export(out, tmp_path / "models", frames=frames)
    for role in ("unetpp", "swin"):
        assert card["files"][role]["parity_max_rel_diff"] < 1e-4
    est = Estimator.load(tmp_path / "models")
    res = est.estimate(frames)
    assert res.angles_deg.shape == (4, 3) and res.enhanced.shape == (4, 64, 64)
    # The same numbers as torch.
    unet, swin = build_models(get_config("smoke"))
    unet.load_state_dict(torch.load(out / "unetpp.pt", weights_only=False)["state_dict"])
    swin.load_state_dict(torch.load(out / "swin.pt", weights_only=False)["state_dict"])
    unet.eval()
    swin.eval()
    with torch.no_grad():
        ref = swin(unet(torch.from_numpy(frames[:, None]))).numpy() * 45.0
    np.testing.assert_allclose(res.angles_deg, ref, rtol=1e-3, atol=1e-3)
    # A stack split into runs of 3 + 1 frames gives the frames' own answers, in order.
    split = Estimator.load(tmp_path / "models", run_batch=3).estimate(frames)
    np.testing.assert_allclose(split.angles_deg, res.angles_deg, rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(split.enhanced, res.enhanced, rtol=1e-4, atol=1e-5)
    with pytest.raises(ValueError, match="run_batch"):
        Estimator.load(tmp_path / "models", run_batch=0)
    # --half stores the large weights in float16 behind Casts: the files shrink, the graph still computes in float32.
    import onnx

    # Swin's window shapes are constants of the graph, not computed from the input at run time.
    assert not any(n.op_type == "Shape" for n in onnx.load(str(tmp_path / "models" / "swin.onnx")).graph.node)

    half = export(out, tmp_path / "f16", frames=frames, half=True)
    for role in ("unetpp", "swin"):
        f = half["files"][role]
        assert f["bytes"] < 0.6 * card["files"][role]["bytes"]
        assert f["float16_tensors"] > 0 and f["parity_max_rel_diff"] < 1e-4 and f["half_max_rel_diff"] < 1e-2
        graph = onnx.load(str(tmp_path / "f16" / f["file"])).graph
        assert graph.output[0].type.tensor_type.elem_type == onnx.TensorProto.FLOAT
        assert sum(i.data_type == onnx.TensorProto.FLOAT16 for i in graph.initializer) == f["float16_tensors"]
    b = Estimator.load(tmp_path / "f16").estimate(frames)
    assert b.angles_deg.dtype == np.float32
    np.testing.assert_allclose(b.angles_deg, res.angles_deg, atol=0.05)  # degrees


def test_int8_export_quantises_unet_and_keeps_the_angles(smoke_run, smoke_data, tmp_path, capsys):
    import onnx

    from inference.export import INT8_ANGLE_TOL_DEG, main
    from inference.simulation.dataset import load_arrays

    out, _ = smoke_run
    # The command line: UNet++ calibrated on the data set's 16 training frames (8 calibrate, 8 check).
    assert (
        main(
            [
                "--run",
                str(out),
                "--out",
                str(tmp_path / "i8"),
                "--int8",
                "--half",
                "--frames",
                str(smoke_data),
                "--n-frames",
                "100",
            ]
        )
        == 0
    )
    assert "int8: angles change by" in capsys.readouterr().out
    card = json.loads((tmp_path / "i8" / "model_card.json").read_text())
    u, s = card["files"]["unetpp"], card["files"]["swin"]
    assert u["weights"].startswith("int8") and u["int8_calibration_frames"] == 8 and u["int8_check_frames"] == 8
    assert max(u["int8_angle_change_deg"]["mean"]) <= INT8_ANGLE_TOL_DEG
    assert "float16_tensors" not in u and s["float16_tensors"] > 0  # --half still applies to Swin
    assert card["export_options"]["frames"]["first_training_frames"] == 16  # the card says what calibrated it
    graph = onnx.load(str(tmp_path / "i8" / "unetpp.onnx")).graph
    ops = {n.op_type for n in graph.node}
    assert {"QuantizeLinear", "DequantizeLinear"} <= ops
    assert sum(n.op_type == "QuantizeLinear" for n in graph.node) == u["int8_quantized_activations"] > 0
    assert any(i.data_type == onnx.TensorProto.INT8 for i in graph.initializer)
    # 7-bit weights: a pair of uint8 x int8 products then fits int16 (255 x 64 x 2 = 32640), so no CPU saturates.
    weights = [onnx.numpy_helper.to_array(i) for i in graph.initializer if i.data_type == onnx.TensorProto.INT8]
    assert max(int(np.abs(w.astype(np.int32)).max()) for w in weights) <= 64
    assert card["selfcheck"]["img_size"] == card["config"]["img_size"] and card["selfcheck"]["tolerance"] > 0
    float_card = export(out, tmp_path / "f32")
    assert u["bytes"] < 0.5 * float_card["files"]["unetpp"]["bytes"]
    # The service runs it, and its angles stay near the float models' on frames it did not calibrate on.
    frames = load_arrays(smoke_data)["image"][16:].astype(np.float32)
    got = Estimator.load(tmp_path / "i8").estimate(frames)
    ref = Estimator.load(tmp_path / "f32").estimate(frames)
    assert got.enhanced.dtype == np.float32
    assert np.abs(got.angles_deg - ref.angles_deg).mean() < 4 * INT8_ANGLE_TOL_DEG
    assert np.abs(got.enhanced - ref.enhanced).mean() < 0.05 * np.abs(ref.enhanced).mean() + 1e-3


def test_a_failed_export_leaves_the_models_in_place(smoke_run, smoke_data, tmp_path, monkeypatch):
    import inference.export as ex
    from inference.files import sha256_file
    from inference.simulation.dataset import load_arrays

    out, _ = smoke_run
    frames = load_arrays(smoke_data)["image"][:16].astype(np.float32)
    export(out, tmp_path / "models")
    before = {f.name: sha256_file(f) for f in (tmp_path / "models").iterdir()}
    monkeypatch.setattr(ex, "INT8_ANGLE_TOL_DEG", -1.0)  # no quantised model can pass
    with pytest.raises(InferenceError, match="unetpp.onnx: int8 UNet\\+\\+ moves the angles"):
        export(out, tmp_path / "models", frames=frames, int8=True)
    assert {f.name: sha256_file(f) for f in (tmp_path / "models").iterdir()} == before
    assert Estimator.load(tmp_path / "models").estimate(frames[:2]).angles_deg.shape == (2, 3)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["models"]  # no staging folder left behind


def test_int8_export_refuses_without_enough_real_frames(smoke_run, smoke_data, tmp_path, capsys):
    from inference.export import main

    out, _ = smoke_run
    with pytest.raises(InferenceError, match="needs at least 8 real frames"):
        export(out, tmp_path / "m", int8=True)
    assert main(["--run", str(out), "--out", str(tmp_path / "m"), "--int8"]) == 2
    assert "--int8 needs --frames DATA" in capsys.readouterr().err
    assert (
        main(
            ["--run", str(out), "--out", str(tmp_path / "m"), "--int8", "--frames", str(smoke_data), "--n-frames", "4"]
        )
        == 2
    )
    assert "--n-frames 4 is too few" in capsys.readouterr().err
    assert not (tmp_path / "m").exists()  # refused before anything was written


def test_evaluate_writes_the_tables_and_skips_unet_for_a_raw_frame_model(smoke_run, smoke_data, tmp_path):
    from inference.evaluation.evaluate import evaluate
    from inference.simulation.dataset import load_arrays

    out, _ = smoke_run
    export(out, tmp_path / "m")
    res = evaluate(tmp_path / "m", smoke_data, n_snr=3, out_dir=tmp_path / "res", progress=False, record=True)
    assert set(res["rows"]) == {"with enhancement", "0 dB", "5 dB", "10 dB"}
    assert res["rows"]["with enhancement"]["n"] == 8 and res["rows"]["0 dB"]["n"] == 3  # test split 16..23
    assert "0.730 / 0.705 / 0.958" in (tmp_path / "res" / "results.md").read_text()  # beside the paper's figures
    assert (tmp_path / "res" / "errors.png").stat().st_size > 5000
    assert json.loads((tmp_path / "m" / "model_card.json").read_text())["evaluation"]["rows"] == res["rows"]
    # A Swin trained on raw frames (Table 4's other row): the runtime skips UNet++ and the rows say so.
    train(smoke_data, tmp_path / "raw", recipe("smoke", epochs=1, enhance=False, log_every=0))
    assert export(tmp_path / "raw", tmp_path / "mraw")["enhance"] is False
    est = Estimator.load(tmp_path / "mraw")
    frames = load_arrays(smoke_data)["image"][:3].astype(np.float32)
    got = est.estimate(frames)
    assert not est.enhances and Estimator.load(tmp_path / "m").enhances
    np.testing.assert_array_equal(got.enhanced, frames)
    _, swin = build_models(get_config("smoke"))
    swin.load_state_dict(torch.load(tmp_path / "raw" / "swin.pt", weights_only=False)["state_dict"])
    with torch.no_grad():
        ref = swin.eval()(torch.from_numpy(frames[:, None])).numpy() * 45.0
    np.testing.assert_allclose(got.angles_deg, ref, rtol=1e-3, atol=1e-3)
    raw = evaluate(tmp_path / "mraw", smoke_data, n_snr=3, out_dir=tmp_path / "res2", progress=False)
    assert set(raw["rows"]) == {"without enhancement"} | {f"{d} dB, without enhancement" for d in (0, 5, 10)}
    with pytest.raises(InferenceError, match="does not use"):
        export(tmp_path / "raw", tmp_path / "x", frames=frames.repeat(4, axis=0), int8=True)
    # Both rows of Table 4 in one table: each model scored on the same frames as when scored alone.
    card_before = (tmp_path / "m" / "model_card.json").read_text()
    both = evaluate(
        tmp_path / "m",
        smoke_data,
        n_snr=3,
        out_dir=tmp_path / "res3",
        progress=False,
        without=tmp_path / "mraw",
        record=True,
    )
    assert both["rows"] == res["rows"] | raw["rows"]
    assert both["without_model"]["swin_sha256"] == est.identity["swin_sha256"]
    md = (tmp_path / "res3" / "results.md").read_text()
    assert "| without enhancement (n=8) |" in md and "1.387 / 1.223 / 1.797" in md
    assert (tmp_path / "m" / "model_card.json").read_text() == card_before  # the card keeps its own rows only
    with pytest.raises(InferenceError, match="--without takes models trained on raw frames"):
        evaluate(tmp_path / "m", smoke_data, n_snr=3, out_dir=tmp_path / "res4", without=tmp_path / "m")
    with pytest.raises(InferenceError, match="reads raw frames too"):
        evaluate(tmp_path / "mraw", smoke_data, n_snr=3, out_dir=tmp_path / "res4", without=tmp_path / "mraw")
    assert not (tmp_path / "res4").exists()


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


def test_quaternion_matches_rotation_matrix():
    from inference.rotations import rotation_matrix

    z, y, x = 30.0, -20.0, 10.0
    w, qx, qy, qz = euler_to_quaternion(z, y, x)
    r = np.array(
        [
            [1 - 2 * (qy**2 + qz**2), 2 * (qx * qy - w * qz), 2 * (qx * qz + w * qy)],
            [2 * (qx * qy + w * qz), 1 - 2 * (qx**2 + qz**2), 2 * (qy * qz - w * qx)],
            [2 * (qx * qz - w * qy), 2 * (qy * qz + w * qx), 1 - 2 * (qx**2 + qy**2)],
        ]
    )
    np.testing.assert_allclose(r, rotation_matrix(z, y, x), atol=1e-12)


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
