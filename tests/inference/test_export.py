"""ONNX export: parity with torch, int8, staging that leaves the models in place on failure."""

import json

import numpy as np
import pytest
import torch

from inference.errors import InferenceError
from inference.export import export
from inference.networks.build import build_models, get_config
from inference.runtime import Estimator


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


def test_a_search_unet_joins_a_set_and_is_served_beside_its_networks(smoke_run, smoke_data, tmp_path, capsys):
    """gsa export --search-unet: a run's UNet++ added to a set as the one the library search fits. The set's networks
    stay as they were; the service runs it and it computes what torch does; an int8 one is checked on the silhouette
    the search fits; the card always names the file there; a tampered file is refused by name."""
    from inference.errors import ModelFileError
    from inference.export import SEARCH_INT8_MIN_IOU, main
    from inference.files import sha256_file
    from inference.simulation.dataset import load_arrays

    out, _ = smoke_run
    frames = load_arrays(smoke_data)["image"][:16].astype(np.float32)
    export(out, tmp_path / "m")
    assert Estimator.load(tmp_path / "m").search_enhancer is None
    networks = {n: sha256_file(tmp_path / "m" / n) for n in ("unetpp.onnx", "swin.onnx")}
    assert main(["--run", str(out), "--out", str(tmp_path / "m"), "--search-unet"]) == 0
    assert "search UNet++: search_unetpp-" in capsys.readouterr().out
    est = Estimator.load(tmp_path / "m")
    assert {n: sha256_file(tmp_path / "m" / n) for n in networks} == networks
    unet, _ = build_models(get_config("smoke"))
    unet.load_state_dict(torch.load(out / "unetpp.pt", weights_only=False)["state_dict"])
    unet.eval()
    with torch.no_grad():
        ref = unet(torch.from_numpy(frames[:2, None])).numpy()[:, 0]
    got = np.stack([est.search_enhancer(f) for f in frames[:2]])
    np.testing.assert_allclose(got, ref, rtol=1e-3, atol=1e-4)
    float_file = est.card["files"]["search_unetpp"]["file"]
    assert est.identity["search_unetpp_sha256"] == est.card["files"]["search_unetpp"]["sha256"]
    # int8 in its place: checked on its silhouettes; the float file it replaced is gone.
    entry = main(
        ["--run", str(out), "--out", str(tmp_path / "m"), "--search-unet", "--int8", "--frames", str(smoke_data)]
    )
    assert entry == 0
    card = json.loads((tmp_path / "m" / "model_card.json").read_text())
    e = card["files"]["search_unetpp"]
    assert e["weights"].startswith("int8") and e["int8_silhouette_iou"]["mean"] >= SEARCH_INT8_MIN_IOU
    assert e["file"] != float_file and not (tmp_path / "m" / float_file).exists()
    assert (tmp_path / "m" / e["file"]).is_file() and e["selfcheck"]["img_size"] == 64
    # Too few frames for int8: refused, the set unchanged.
    with pytest.raises(InferenceError, match="needs at least 8 real frames"):
        from inference.export import export_search_enhancer

        export_search_enhancer(out, tmp_path / "m", frames[:4], int8=True)
    assert json.loads((tmp_path / "m" / "model_card.json").read_text()) == card
    with open(tmp_path / "m" / e["file"], "ab") as f:
        f.write(b"0")
    with pytest.raises(ModelFileError, match=e["file"]):
        Estimator.load(tmp_path / "m")
