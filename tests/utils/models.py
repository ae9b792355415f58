"""A tiny exported model pair (the smoke configuration on 64 x 64 frames) for service tests."""

from pathlib import Path

from inference.export import export
from inference.simulation.dataset import DatasetSpec, generate
from inference.simulation.radar import Radar
from inference.training.options import recipe
from inference.training.train import train

SMOKE_RADAR = Radar(n_range=64, n_azimuth=64, bandwidth_hz=0.4e9, aperture_deg=5.1 / 4)


def make_smoke_models(root: Path) -> Path:
    """Simulate 16 frames, train the smoke networks for one epoch, export; return the model directory."""
    generate(
        DatasetSpec(n=16, seed=5, shard_size=16, n_train=12), root / "data", SMOKE_RADAR, workers=1, progress=False
    )
    train(root / "data", root / "run", recipe("smoke", epochs=1, log_every=0))
    export(root / "run", root / "models")
    return root / "models"
