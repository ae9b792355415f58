"""gsa evaluate: the paper's Tables 4 and 7 for exported models."""

import json

import numpy as np
import pytest
import torch

from inference.errors import InferenceError
from inference.export import export
from inference.networks.build import build_models, get_config
from inference.runtime import Estimator
from inference.training.options import recipe
from inference.training.train import train


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
