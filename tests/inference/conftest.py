"""Shared fixtures of the inference tests: a smoke data set at the 64-pixel radar and a smoke training run on it."""

import pytest

from inference.simulation.dataset import DatasetSpec, generate
from inference.training.options import recipe
from inference.training.train import train
from tests.utils.models import SMOKE_RADAR


@pytest.fixture(scope="session")
def smoke_data(tmp_path_factory):
    d = tmp_path_factory.mktemp("data") / "set"
    generate(DatasetSpec(n=24, seed=3, shard_size=12, n_train=16), d, SMOKE_RADAR, workers=1, progress=False)
    return d


@pytest.fixture(scope="session")
def smoke_run(smoke_data, tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    record = train(smoke_data, out, recipe("smoke", epochs=2, log_every=0))
    return out, record
