"""gsa compare: training runs side by side."""

from inference.training.options import recipe
from inference.training.train import train


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
