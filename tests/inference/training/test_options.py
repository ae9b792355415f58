"""Training options: recipes, flags built from the option fields, and the recipe the shipped models record."""

from __future__ import annotations

import argparse
import json
from dataclasses import fields
from pathlib import Path

import pytest

from inference.errors import InferenceError
from inference.training.options import (
    RECIPES,
    FinetuneOptions,
    TrainOptions,
    add_option_arguments,
    options_from_args,
    recipe,
)
from inference.training.train import add_arguments

ROOT = Path(__file__).resolve().parents[3]


def test_the_shipped_recipe_is_what_the_shipped_networks_training_record_says():
    record = json.loads((ROOT / "records/checkpoints/compact-h100-e15/training.json").read_text())
    shipped = RECIPES["shipped"]
    assert shipped.config == record["config"]["name"]
    for key in ("epochs", "batch_size", "lr", "lr_decay"):  # that run's config still held its schedule
        assert getattr(shipped, key) == record["config"][key], key
    assert (shipped.mode, shipped.enhance, shipped.seed) == (record["mode"], record["enhance"], record["seed"])


def test_flags_override_the_recipe_and_leave_the_rest_alone():
    p = argparse.ArgumentParser()
    add_arguments(p)
    args = p.parse_args(["--data", "d", "--recipe", "shipped", "--epochs", "3", "--no-enhance", "--swin-depths", "2,2"])
    opts = options_from_args(TrainOptions, args, base=recipe(args.recipe))
    assert (opts.epochs, opts.enhance, opts.swin_depths) == (3, False, (2, 2))
    assert (opts.batch_size, opts.lr_decay, opts.config) == (32, 0.9, "compact")  # the recipe's, untouched
    assert opts.shape() == {"swin_depths": (2, 2)}


def test_every_option_field_has_a_flag():
    for cls in (TrainOptions, FinetuneOptions):
        p = argparse.ArgumentParser()
        add_option_arguments(p, cls)
        dests = {a.dest for a in p._actions}
        assert {f.name for f in fields(cls)} <= dests, cls


def test_ema_zero_turns_the_averaging_off_and_bad_options_name_their_field():
    p = argparse.ArgumentParser()
    add_option_arguments(p, FinetuneOptions)
    assert options_from_args(FinetuneOptions, p.parse_args(["--ema", "0"])).ema is None
    assert options_from_args(FinetuneOptions, p.parse_args([])).ema == 0.999
    with pytest.raises(InferenceError, match="unknown recipe 'fast'") as e:
        recipe("fast")
    assert e.value.field == "recipe"
    with pytest.raises(InferenceError, match="unknown training option"):
        recipe("smoke", epoch=3)
    for bad, field in ((dict(batch_size=0), "batch_size"), (dict(lr=0.0), "lr"), (dict(mode="both"), "mode")):
        with pytest.raises(InferenceError) as e:
            recipe("smoke", **bad).check()
        assert e.value.field == field
