"""Adaptation: networks read back from ONNX files, fine-tuned on labelled frames split by scene, exported, trusted anew."""

import json
import shutil

import numpy as np
import pytest
import torch

from app.cli import main as gsa
from inference.errors import DatasetError, ModelFileError
from inference.export import export
from inference.labelled import write_frame
from inference.networks.build import build_models, get_config
from inference.runtime import Estimator
from inference.simulation.dataset import DatasetSpec, render_frames
from inference.training.adapt import AdaptOptions, _windows, adapt
from inference.training.checkpoints import save_checkpoint
from inference.training.recover import recover, recover_swin, recover_unet
from inference.trust import Calibration
from tests.utils.models import SMOKE_RADAR


def _run_dir(path, unet, swin, cfg):
    path.mkdir()
    for name, net in (("unetpp.pt", unet), ("swin.pt", swin)):
        save_checkpoint({"state_dict": net.state_dict(), "config": cfg, "enhance": True}, path / name)
    return path


def test_networks_read_back_from_onnx_compute_what_torch_did(tmp_path):
    # Batch norm with running statistics far from the identity: folded into the convolutions at export,
    # recovered as plain convolutions; the same function either way.
    cfg = get_config("smoke")
    torch.manual_seed(0)
    unet, swin = build_models(cfg)
    with torch.no_grad():
        for m in unet.modules():
            if isinstance(m, torch.nn.BatchNorm2d):
                m.running_mean.uniform_(-0.5, 0.5)
                m.running_var.uniform_(0.5, 2.0)
                m.weight.uniform_(0.5, 1.5)
                m.bias.uniform_(-0.2, 0.2)
        for m in swin.modules():
            if hasattr(m, "bias_table"):
                m.bias_table.normal_(0.0, 0.5)
    unet.eval()
    swin.eval()
    run = _run_dir(tmp_path / "run", unet, swin, cfg.as_dict())
    export(run, tmp_path / "f32")
    x = torch.rand(3, 1, 64, 64)
    with torch.no_grad():
        ref_u, ref_s = unet(x), swin(x)
        got_u = recover_unet(tmp_path / "f32" / "unetpp.onnx", cfg.as_dict())(x)
        got_s = recover_swin(tmp_path / "f32" / "swin.onnx", cfg.as_dict())(x)
    assert float((got_u - ref_u).abs().max()) < 1e-5
    assert float((got_s - ref_s).abs().max()) < 1e-5
    assert not any(
        isinstance(m, torch.nn.BatchNorm2d)
        for m in recover_unet(tmp_path / "f32" / "unetpp.onnx", cfg.as_dict()).modules()
    )


def test_the_shipped_set_reads_back_within_its_own_rounding():
    unet, swin, cfg, figures = recover("inference/models/shipped")
    assert cfg["unet_norm"] is False
    assert figures["swin_max_abs_diff"] < 1e-4  # float16 weights read back exactly
    assert figures["unetpp_mean_abs_diff"] < 0.01  # int8 activations against float: the card's 0.0048


def test_a_folder_that_is_not_the_configured_network_is_refused(tmp_path):
    cfg = get_config("smoke")
    unet, swin = build_models(cfg)
    run = _run_dir(tmp_path / "run", unet.eval(), swin.eval(), cfg.as_dict())
    export(run, tmp_path / "m")
    wider = {**cfg.as_dict(), "unet_filters": [8, 16, 32, 64, 128]}
    with pytest.raises(ModelFileError, match="config does not describe this file"):
        recover_unet(tmp_path / "m" / "unetpp.onnx", wider)


@pytest.fixture(scope="module")
def smoke_base(tmp_path_factory):
    from inference.simulation.dataset import generate
    from inference.training.options import recipe
    from inference.training.train import train

    root = tmp_path_factory.mktemp("base")
    generate(
        DatasetSpec(n=32, seed=5, shard_size=32, n_train=24), root / "data", SMOKE_RADAR, workers=1, progress=False
    )
    train(root / "data", root / "run", recipe("smoke", epochs=1, log_every=0))
    frames = render_frames(DatasetSpec(n=16, seed=9), SMOKE_RADAR, 0, 16)["image"].astype(np.float32)
    export(root / "run", root / "models", frames, half=True, int8=True)
    return root / "models"


def _labelled(folder, scenes, per, seed):
    """Frames of another radar's look (the robust preset's scattering), scene by scene (named by the folder)."""
    folder.mkdir()
    spec = DatasetSpec(n=scenes * per, seed=seed, variety="robust")
    arr = render_frames(spec, SMOKE_RADAR, 0, scenes * per)
    for k in range(scenes * per):
        write_frame(
            folder / f"f{k:03d}.npz",
            arr["image"][k].astype(np.float32),
            angles_deg=arr["angles_deg"][k],
            scene=f"{folder.name}-pass-{k // per}",
            normalised=True,
        )
    return folder


def test_adapt_splits_by_scene_keeps_the_best_weights_and_serves(smoke_base, tmp_path, capsys):
    frames = _labelled(tmp_path / "lab", scenes=3, per=20, seed=41)
    out = tmp_path / "adapted"
    base = tmp_path / "base"
    shutil.copytree(smoke_base, base)
    Calibration(iou_min=0.9321).write(base / "trust.json")  # the base set's trust: its search trigger is kept
    rec = adapt(base, frames, out, AdaptOptions(epochs=2, sim_ratio=0.5, validation_share=0.3))
    lab = rec["labelled"]
    assert not set(lab["train_scenes"]) & set(lab["validation_scenes"])
    assert lab["train_frames"] + lab["validation_frames"] == 60 and lab["validation_frames"] >= 20
    # The weights kept are the validation-best of every epoch, the starting ones included.
    # (the score: the held-out scenes' loss plus fresh own frames' loss, what must not be lost)
    scores = [h["score"] for h in rec["history"]]
    assert rec["after"]["score"] == pytest.approx(min(scores), rel=1e-4)
    assert rec["history"][rec["chosen_epoch"]]["score"] == min(scores)
    assert all(h["score"] == pytest.approx(h["loss"] + h["own_loss"]) for h in rec["history"])
    # A folder the service serves, its card saying how it was made, trust fitted on the held-out frames.
    card = json.loads((out / "model_card.json").read_text())
    assert card["adaptation"]["labelled"]["list_sha256"] == lab["list_sha256"]
    assert card["radar"]["n_range"] == 64
    # Swin is left as it was (UNet++ alone adapts by default): its weights read back unchanged (float16's rounding)
    _, swin_base, _, _ = recover(smoke_base)
    _, swin_out, _, _ = recover(out)
    diffs = [
        float((a - b).abs().max())
        for a, b in zip(swin_base.state_dict().values(), swin_out.state_dict().values(), strict=True)
    ]
    assert max(diffs) < 2e-3
    est = Estimator.load(out)
    assert est.estimate(np.zeros((1, 64, 64), np.float32)).angles_deg.shape == (1, 3)
    trust = json.loads((out / "trust.json").read_text())
    assert rec["calibration"]["recalibrated"] and trust["made"]["frames"] == lab["validation_frames"]
    assert trust["search_iou_min"] == rec["calibration"]["search_iou_min"] == 0.9321
    # The network path's bound limit and margin are chosen on the held-out frames (never tighter than the base's)
    chosen = trust["made"]["network_limits"]
    assert chosen["frames"] == lab["validation_frames"] and trust["max_bound_deg"] == chosen["max_bound_deg"] >= 5.0
    assert rec["calibration"]["ambiguity_margin"] == trust["ambiguity_margin"] <= 0.002
    assert sorted(trust["made"]["scenes"]) == lab["validation_scenes"]
    # One held-out scene: bounds fitted on it say so, in the record and the log
    assert rec["calibration"]["scenes"] == len(lab["validation_scenes"]) == 1
    assert "calibrated on 1 held-out scene" in rec["calibration"]["caution"]
    assert "calibrated on 1 held-out scene" in capsys.readouterr().err
    assert set(trust["made"]["labelled_frames"]) <= {p.name for p in frames.iterdir()}


def test_adapt_refusals_leave_nothing(smoke_base, tmp_path, capsys):
    one = _labelled(tmp_path / "one", scenes=1, per=6, seed=2)
    with pytest.raises(DatasetError, match="at least 2"):
        adapt(smoke_base, one, tmp_path / "o", AdaptOptions(epochs=1))
    with pytest.raises(DatasetError, match="base set's networks know"):
        adapt(smoke_base, one, tmp_path / "o", AdaptOptions(epochs=1), target="comsat-like")
    assert not (tmp_path / "o").exists()
    # two folders of one scene each make two scenes: read as one set (names kept apart), split between them
    two = _labelled(tmp_path / "two", scenes=1, per=6, seed=3)
    rec = adapt(smoke_base, [one, two], tmp_path / "both", AdaptOptions(epochs=1, sim_ratio=0.0, train_swin=True))
    assert rec["labelled"]["frames"] == 12 and len(rec["labelled"]["train_scenes"]) == 1
    assert rec["history"][1]["train_swin_loss"] > 0  # with train_swin, Swin's last stage trains too
    with pytest.raises(DatasetError, match="Swin reads whole frames"):
        AdaptOptions(crop_px=32, train_swin=True)
    rec = adapt(smoke_base, [one, two], tmp_path / "windows", AdaptOptions(epochs=1, sim_ratio=0.0, crop_px=32))
    assert "windows of 32 px about the target, label alike" in rec["augmentations"]
    assert rec["history"][1]["train_unet_loss"] > 0
    capsys.readouterr()
    code = gsa(
        ["adapt", "--frames", str(tmp_path / "missing"), "--base", str(smoke_base), "--out", str(tmp_path / "o")]
    )
    err = capsys.readouterr().err
    assert code == 2 and "not a folder of labelled frames" in err and len(err.strip().splitlines()) == 1
    code = gsa(["adapt", "--frames", str(one), "--base", str(smoke_base), "--out", str(smoke_base)])
    assert code == 2 and "new folder" in capsys.readouterr().err
    code = gsa(
        ["adapt", "--frames", str(one), "--base", str(smoke_base), "--out", str(tmp_path / "o"), "--crop-px", "100"]
    )
    err = capsys.readouterr().err
    assert (
        code == 2
        and "crop_px must be" in err
        and "multiple of 16" in err
        and "100 is not" in err
        and len(err.strip().splitlines()) == 1
    )
    assert not (tmp_path / "o").exists()


def test_windows_cut_frame_and_label_at_the_same_place_about_the_target():
    # Each pixel of the frame holds its own index, so a window's first pixel says where it was cut.
    h = w = 64
    x = torch.arange(h * w, dtype=torch.float32).view(1, 1, h, w).repeat(50, 1, 1, 1)
    y = torch.zeros(50, 1, h, w)
    y[:, :, 40:60, 2:12] = 1.0  # a silhouette near a corner: windows about it must stay inside the frame
    y[:25, :, 5:9, 50:54] = 1.0
    xs, ys = _windows(x, y, 32, torch.Generator().manual_seed(1))
    assert xs.shape == ys.shape == (50, 1, 32, 32)
    for k in range(50):
        r, c = divmod(int(xs[k, 0, 0, 0]), w)
        assert torch.equal(xs[k], x[k, :, r : r + 32, c : c + 32])  # a contiguous window of the frame
        assert torch.equal(ys[k], y[k, :, r : r + 32, c : c + 32])  # the label cut at the same place
        assert ys[k].sum() > 0  # showing part of the target
    corners = {divmod(int(v), w) for v in xs[25:, 0, 0, 0]}  # one silhouette: every window about it
    assert all(8 <= r <= 32 and c == 0 for r, c in corners)
    # frames no larger than the window come back whole
    same = _windows(x[:, :, :32, :32], y[:, :, :32, :32], 32, torch.Generator())
    assert torch.equal(same[0], x[:, :, :32, :32])
