"""Fine-tuning Swin's last stage(s) on cached features (gsa finetune), on the smoke configuration."""

import json

import numpy as np
import pytest
import torch

from app.cli import main as gsa
from inference.errors import InferenceError, ModelFileError
from inference.export import export
from inference.networks.build import build_models, get_config
from inference.simulation.dataset import DatasetSpec, generate, load_manifest, render_frames
from inference.training.checkpoints import load_trained
from inference.training.finetune import finetune, validation_spec
from inference.training.options import FinetuneOptions, recipe
from inference.training.train import train
from tests.utils.models import SMOKE_RADAR as SMALL  # 24 m x 29 m at 64 x 64


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    root = tmp_path_factory.mktemp("ft")
    generate(DatasetSpec(n=40, seed=4, shard_size=12, n_train=32), root / "data", SMALL, workers=1, progress=False)
    train(root / "data", root / "run", recipe("smoke", epochs=1, log_every=0))
    return root


@pytest.mark.parametrize("stages", [1, 2, 4])
def test_front_then_tail_is_the_whole_swin(stages):
    torch.manual_seed(0)
    _, swin = build_models(get_config("smoke"))
    swin.eval()
    x = torch.randn(3, 1, 64, 64)
    with torch.no_grad():
        torch.testing.assert_close(swin.tail(swin.front(x, stages), stages), swin(x))


def _val_mae(run_dir, data, n_val):
    """Score a run's weights (torch, the run's own UNet++) on the fresh validation set from scratch."""
    unet, swin, _, _ = load_trained(run_dir)
    spec = validation_spec(load_manifest(data), n_val)
    arrays = render_frames(spec, SMALL, 0, n_val)
    unet.eval()
    swin.eval()
    with torch.no_grad():
        pred = swin(unet(torch.from_numpy(arrays["image"].astype(np.float32))[:, None])).numpy() * 45.0
    return np.abs(pred - arrays["angles_deg"]).mean(axis=0)


def test_finetune_trains_the_tail_only_and_keeps_the_best_validation_weights(run, capsys):
    out = run / "ft"
    rec = finetune(run / "run", run / "data", out, FinetuneOptions(epochs=3, lr=3e-3, batch_size=8, n_val=16))
    before = torch.load(run / "run" / "swin.pt", weights_only=False)["state_dict"]
    after = torch.load(out / "swin.pt", weights_only=False)["state_dict"]
    trained = [k for k in before if k.startswith(("stages.3.", "norm.", "head."))]
    frozen = [k for k in before if k not in trained]
    assert trained and frozen
    for k in frozen:  # the cached front is exactly the run's
        assert torch.equal(before[k], after[k]), k
    # The kept weights are the ones with the lowest mean validation error, the starting weights included.
    candidates = [rec["start_val_mae_deg"]] + [h[k] for h in rec["history"] for k in ("val_mae_deg", "ema_val_mae_deg")]
    assert np.mean(rec["chosen"]["val_mae_deg"]) == pytest.approx(min(np.mean(c) for c in candidates))
    assert len(rec["history"]) == 3 and all(h["swin_loss"] > 0 for h in rec["history"])
    if rec["chosen"]["epoch"] > 0:
        assert any(not torch.equal(before[k], after[k]) for k in trained)
    # swin.pt scores what the record says on the validation set, recomputed from the frames (float16 cache aside).
    np.testing.assert_allclose(_val_mae(out, run / "data", 16), rec["chosen"]["val_mae_deg"], atol=0.05)
    assert (out / "unetpp.pt").read_bytes() == (run / "run" / "unetpp.pt").read_bytes()
    training = json.loads((out / "training.json").read_text())
    assert training["finetune"]["test_mae_deg_after"] == rec["test_mae_deg_after"]
    assert training["history"] == json.loads((run / "run" / "training.json").read_text())["history"]
    assert (out / "finetune.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "caching training frames 32/32" in capsys.readouterr().err
    # The export takes it as it is, and the card says how it was fine-tuned.
    card = export(out, run / "models")
    assert card["finetune"]["chosen"] == rec["chosen"] and card["final_epoch"]["epoch"] == 1


def test_the_feature_cache_is_reused_only_for_the_same_inputs(run, capsys):
    out = run / "again"
    finetune(run / "run", run / "data", out, FinetuneOptions(epochs=1, batch_size=8, n_val=16))
    capsys.readouterr()
    finetune(run / "run", run / "data", out, FinetuneOptions(epochs=1, batch_size=8, n_val=16))
    assert "caching" not in capsys.readouterr().err
    # A cut-off cache goes on from where it stopped.
    meta = out / "features-train.json"
    m = json.loads(meta.read_text())
    meta.write_text(json.dumps({**m, "done": 20}))
    finetune(run / "run", run / "data", out, FinetuneOptions(epochs=1, batch_size=8, n_val=16))
    err = capsys.readouterr().err
    assert "caching training frames 32/32" in err and "caching training frames 20/" not in err
    assert "caching test" not in err
    # A second round, from the first round's output, reads the first round's cache: the front is the same.
    rec2 = finetune(out, run / "data", run / "round2", FinetuneOptions(epochs=1, batch_size=8, n_val=16, cache_dir=out))
    assert "caching" not in capsys.readouterr().err
    first = json.loads((out / "training.json").read_text())["finetune"]
    assert rec2["previous_round"] == first and rec2["start_val_mae_deg"] == first["chosen"]["val_mae_deg"]
    assert not (run / "round2" / "features-train.npy").exists()
    # Training two stages needs other features: everything is cached again.
    finetune(run / "run", run / "data", out, FinetuneOptions(epochs=1, batch_size=8, n_val=16, train_stages=2))
    err = capsys.readouterr().err
    assert "caching training frames 32/32" in err and "caching test frames 8/8" in err


def test_an_exported_enhancer_is_recorded(run, capsys):
    export(run / "run", run / "enh")
    rec = finetune(
        run / "run",
        run / "data",
        run / "with-enh",
        FinetuneOptions(enhancer=run / "enh", epochs=1, batch_size=8, n_val=16),
    )
    card = json.loads((run / "enh" / "model_card.json").read_text())
    assert rec["enhancer"]["unetpp_sha256"] == card["files"]["unetpp"]["sha256"]


def test_finetune_refuses_bad_input(run, tmp_path, capsys):
    with pytest.raises(InferenceError, match="train_stages 5 must be between 1 and 4"):
        finetune(run / "run", run / "data", tmp_path / "o", FinetuneOptions(train_stages=5))
    with pytest.raises(InferenceError, match="new directory"):
        finetune(run / "run", run / "data", run / "run")
    with pytest.raises(InferenceError, match="n_val"):
        finetune(run / "run", run / "data", tmp_path / "o", FinetuneOptions(n_val=3))
    with pytest.raises(ModelFileError, match="checkpoint .* is missing"):
        finetune(tmp_path, run / "data", tmp_path / "o")
    assert not (tmp_path / "o").exists()  # nothing started
    # The command line: one line and exit 2.
    assert gsa(["finetune", "--run", str(run / "run"), "--data", str(tmp_path), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "manifest.json" in err[0]


def test_a_finetuned_run_packs_into_pieces_that_reuse_the_unchanged_unet(run, tmp_path):
    from inference.training.pipeline import join, pack

    ft = run / "ft2"
    finetune(run / "run", run / "data", ft, FinetuneOptions(epochs=1, lr=3e-3, batch_size=8, n_val=16))
    base = pack(run / "run", tmp_path / "base")  # a training run: from its checkpoint
    m = pack(ft, tmp_path / "ft", reuse=tmp_path / "base")  # a fine-tuned run has no checkpoint: its .pt files
    assert m["finetuned"] and m["epochs"] == 1
    assert [p["file"] for p in m["unetpp"]] == [f"../base/{p['file']}" for p in base["unetpp"]]
    assert m["swin"][0]["file"] == "swin.part00" and (tmp_path / "ft" / "swin.part00").is_file()
    assert not (tmp_path / "ft" / "unetpp.part00").exists()
    join(tmp_path / "ft", tmp_path / "back")
    for name in ("unetpp", "swin"):
        want = torch.load(ft / f"{name}.pt", weights_only=False)["state_dict"]
        got = torch.load(tmp_path / "back" / f"{name}.pt", weights_only=False)["state_dict"]
        for k, v in want.items():
            torch.testing.assert_close(got[k], v.half().float() if v.is_floating_point() else v, rtol=0, atol=0)
    assert "finetune" in json.loads((tmp_path / "back" / "training.json").read_text())
    # Without reuse both networks are written.
    assert pack(ft, tmp_path / "all")["unetpp"][0]["file"] == "unetpp.part00"
