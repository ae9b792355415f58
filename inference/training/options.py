"""What a training or fine-tuning run is told: options built by keyword, named recipes, and the
command-line flags built from the same fields.

``TrainOptions`` and ``FinetuneOptions`` are the one list of a run's knobs: ``train()`` and
``finetune()`` take them, ``python -m inference.training.train`` (and ``gsa train``) builds its
flags from their fields, and a recipe is just a named ``TrainOptions``. The recipe the shipped
models were trained with (``shipped``) lives here, not only in the GPU script.

The network's shape is the config's (``inference.networks.build.CONFIGS``); the schedule
(epochs, batch, learning rate and its decay) is the recipe's.
"""

from __future__ import annotations

import argparse
import dataclasses
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any, get_type_hints

from inference.errors import DatasetError, InferenceError

VAL_SEED = (
    20_000  # fine-tuning's fresh validation set: no training set (seed 0..) or SNR test set (10,000 + dB) uses it
)

# How a training step computes: ``auto`` is bf16 autocast wherever the hardware does bf16 natively.
PRECISIONS = ("auto", "bf16", "float32")

# The shape fields a run may override on its config (flag name -> config field).
SHAPE_FLAGS = {
    "unet_filters": "unet_filters",
    "swin_dim": "swin_embed_dim",
    "swin_depths": "swin_depths",
    "swin_heads": "swin_heads",
}


def _opt(default: Any, help: str, flag: str | None = None) -> Any:
    """A dataclass field with its command-line help (and flag name, where it is not the field's)."""
    return field(default=default, metadata={"help": help, "flag": flag})


@dataclass(frozen=True, kw_only=True)
class TrainOptions:
    """One training run: the network config, the schedule, the mode, and the machine knobs."""

    config: str = _opt("compact", "network shape: paper, compact, cpu or smoke")
    epochs: int = _opt(100, "epochs to train")
    batch_size: int = _opt(32, "frames per optimiser step")
    lr: float = _opt(2e-4, "Adam learning rate")
    lr_decay: float = _opt(0.98, "learning-rate factor per epoch, in (0, 1]")
    mode: str = _opt("joint", "joint (the paper) or two-stage (UNet++ first, then Swin on its frozen output)")
    enhance: bool = _opt(
        True, "train Swin on raw frames, no UNet++ (Table 4's 'without enhancement' row)", "no-enhance"
    )
    unet_epochs: int | None = _opt(None, "two-stage: epochs of UNet++ before Swin (default half)")
    unet_from: str | None = _opt(None, "start UNet++ from an earlier run's unetpp.pt")
    swin_from: str | None = _opt(None, "start Swin from an earlier run's swin.pt (fine-tuning with a fresh schedule)")
    ema: float | None = _opt(None, "also average the weights (decay per step, e.g. 0.999; 0: off); saved as the result")
    unet_filters: tuple[int, ...] | None = _opt(None, "override the config's UNet++ filters, e.g. 16,32,64,128,256")
    swin_dim: int | None = _opt(None, "override the config's Swin embedding dimension C")
    swin_depths: tuple[int, ...] | None = _opt(None, "override the config's Swin depths, e.g. 2,2,2,2")
    swin_heads: tuple[int, ...] | None = _opt(None, "override the config's Swin heads per stage, e.g. 1,2,4,8")
    max_train_frames: int | None = _opt(None, "train on the first N training frames only")
    silhouette_noise: float = _opt(
        0.0,
        "share of Swin's training inputs perturbed like an enhancer's mistakes: eroded or dilated by 1 px, a part "
        "missing, edges jittered (inference.training.augment); 0: off",
    )
    seed: int = _opt(0, "seed of the initial weights and the batch order")
    # Machine knobs: where and how long, not what is learnt.
    device: str | None = _opt(None, "torch device (default: cuda when there is one)")
    threads: int | None = _opt(None, "torch CPU threads (default: all cores)")
    resume: bool = _opt(False, "go on from the run's checkpoint.pt")
    max_minutes: float | None = _opt(None, "stop after the epoch in which this much time has passed")
    compile_models: bool = _opt(False, "torch.compile on a GPU", "compile")
    precision: str = _opt(
        "auto",
        "auto (bf16 autocast on a GPU, and on a CPU that computes bf16 natively: AVX-512 BF16 or AMX), bf16, or "
        "float32",
    )
    log_every: int = _opt(20, "a progress line every N steps (0: none)")

    def shape(self) -> dict[str, Any]:
        """The config-field overrides this run gives (those not None)."""
        return {cfg: getattr(self, f) for f, cfg in SHAPE_FLAGS.items() if getattr(self, f) is not None}

    def schedule(self) -> dict[str, Any]:
        return {"epochs": self.epochs, "batch_size": self.batch_size, "lr": self.lr, "lr_decay": self.lr_decay}

    def check(self) -> None:
        """Refuse options no run can start with, naming the field."""
        if self.epochs < 0:
            raise InferenceError(f"epochs {self.epochs} must be 0 or more", field="epochs")
        if self.batch_size < 1:
            raise InferenceError(f"batch_size {self.batch_size} must be at least 1", field="batch_size")
        if not self.lr > 0:
            raise InferenceError(f"lr {self.lr} must be positive", field="lr")
        check_schedule(self.lr_decay, self.ema)
        check_share(self.silhouette_noise)
        if self.precision not in PRECISIONS:
            raise InferenceError(
                f"precision {self.precision!r} must be one of {', '.join(PRECISIONS)}", field="precision"
            )
        if self.mode not in ("joint", "two-stage"):
            raise InferenceError(f"mode {self.mode!r} must be 'joint' or 'two-stage'", field="mode")
        if self.ema is not None and self.mode == "two-stage":
            raise InferenceError("ema averages jointly trained networks; use it with mode 'joint'", field="ema")
        if self.unet_epochs is not None and not 0 <= self.unet_epochs <= self.epochs:
            raise InferenceError(
                f"unet_epochs {self.unet_epochs} must be between 0 and epochs ({self.epochs})", field="unet_epochs"
            )
        for name, given, file in (("unet_from", self.unet_from, "unetpp.pt"), ("swin_from", self.swin_from, "swin.pt")):
            if given is not None and not Path(given).is_file():
                raise InferenceError(f"{given} does not exist; give an earlier run's {file}", field=name)


def check_share(silhouette_noise: float) -> None:
    """Refuse a share of perturbed silhouettes outside [0, 1]."""
    if not 0.0 <= silhouette_noise <= 1.0:
        raise InferenceError(
            f"silhouette_noise {silhouette_noise} must be in [0, 1] (the share of Swin's inputs perturbed)",
            field="silhouette_noise",
        )


def check_schedule(lr_decay: float, ema: float | None) -> None:
    """Refuse a learning-rate decay outside (0, 1] or a weight-averaging decay outside (0, 1)."""
    if not 0.0 < lr_decay <= 1.0:
        raise InferenceError(f"lr_decay {lr_decay} must be in (0, 1]", field="lr_decay")
    if ema is not None and not 0.0 < ema < 1.0:
        raise InferenceError(f"ema {ema} must be in (0, 1), e.g. 0.999", field="ema")


_SHIPPED = TrainOptions(config="compact", epochs=20, batch_size=32, lr=2e-4, lr_decay=0.9)
RECIPES: dict[str, TrainOptions] = {
    # The paper's protocol (section 4.3.3): Adam 2e-4 decayed x0.98 per epoch, batch 32, 100 epochs.
    "paper": TrainOptions(config="paper"),
    # The shipped compact networks (H100, 2026-11-23; records/checkpoints/compact-h100-e15/training.json):
    # the compact shape, 20 epochs at batch 32 decayed x0.9 (the GPU script also averages, --ema 0.999).
    "shipped": _SHIPPED,
    # Table 4's "without enhancement" row and the two-stage comparison, on the shipped schedule.
    "noenhance": replace(_SHIPPED, enhance=False),
    "twostage": replace(_SHIPPED, mode="two-stage"),
    # Issue 18's robust networks: the shipped schedule, half of Swin's inputs perturbed silhouettes
    # (train it on a `gsa simulate --variety robust` set).
    "robust": replace(_SHIPPED, silhouette_noise=0.5),
    # The compact shape on the paper's schedule at batch 16 (what `--config compact` always meant).
    "compact": TrainOptions(config="compact", batch_size=16),
    # What a 2-core CPU trains in under an hour.
    "cpu": TrainOptions(config="cpu", batch_size=8, lr=5e-4, lr_decay=0.9),
    # Tests: trains on 64 px frames on a CPU in seconds.
    "smoke": TrainOptions(config="smoke", epochs=2, batch_size=4, lr=1e-3, log_every=0),
}


def recipe(name: str, **overrides: Any) -> TrainOptions:
    """Return the named recipe with ``overrides`` (field names of ``TrainOptions``) applied."""
    if name not in RECIPES:
        raise InferenceError(f"unknown recipe {name!r}; choose one of {', '.join(RECIPES)}", field="recipe")
    unknown = sorted(set(overrides) - {f.name for f in fields(TrainOptions)})
    if unknown:
        raise InferenceError(f"unknown training option(s) {', '.join(unknown)}", field="recipe")
    return replace(RECIPES[name], **overrides)


@dataclass(frozen=True, kw_only=True)
class FinetuneOptions:
    """One fine-tuning run of Swin's last stage(s) against a fixed enhancer."""

    enhancer: str | None = _opt(None, "exported model directory whose UNet++ enhances the frames (default: the run's)")
    epochs: int = _opt(4, "epochs to fine-tune")
    lr: float = _opt(4e-5, "Adam learning rate")
    lr_decay: float = _opt(0.9, "learning-rate factor per epoch")
    batch_size: int = _opt(32, "frames per optimiser step")
    ema: float | None = _opt(0.999, "weight-averaging decay per step; 0 turns it off")
    train_stages: int = _opt(1, "how many of Swin's last stages to train")
    n_val: int = _opt(1000, "frames of the fresh validation set")
    val_seed: int = _opt(VAL_SEED, "seed of the validation set (no training or SNR test set uses it)")
    max_train_frames: int | None = _opt(None, "train on the first N training frames only")
    silhouette_noise: float = _opt(
        0.0,
        "share of the training frames whose enhanced silhouette is perturbed before caching (eroded or dilated "
        "by 1 px, a part missing, edges jittered); validation and test frames stay as they are",
    )
    seed: int = _opt(0, "seed of the batch order")
    threads: int | None = _opt(None, "torch CPU threads (default: all cores)")
    cache_dir: str | None = _opt(
        None, "where the feature cache lives (default: --out); an earlier round's --out reuses it", "cache"
    )


def _ints(text: str) -> tuple[int, ...]:
    """argparse type for a comma-separated list of integers ("2,2,6,2")."""
    try:
        return tuple(int(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a comma-separated list of integers") from None


def add_option_arguments(p: argparse.ArgumentParser, cls: type, skip: tuple[str, ...] = ()) -> None:
    """Add one flag per field of the options dataclass ``cls``; a flag not given leaves the field alone.

    Every flag defaults to ``argparse.SUPPRESS``, so ``options_from_args`` can tell a flag given
    from one left out and a recipe's values survive the flags nobody typed.
    """
    hints = get_type_hints(cls)
    for f in fields(cls):
        if f.name in skip:
            continue
        flag = "--" + (f.metadata.get("flag") or f.name).replace("_", "-")
        kind = hints[f.name]
        doc = f.metadata.get("help", "")
        if kind is bool:
            p.add_argument(
                flag, dest=f.name, action="store_const", const=not f.default, default=argparse.SUPPRESS, help=doc
            )
            continue
        text = str(kind)
        typ: Any = _ints if "tuple" in text else int if "int" in text else float if "float" in text else str
        shown = f" (default {f.default})" if f.default is not None else ""
        p.add_argument(flag, dest=f.name, type=typ, default=argparse.SUPPRESS, help=doc + shown)


def options_from_args(cls: type, args: argparse.Namespace, base: Any = None) -> Any:
    """Build ``cls`` from the flags given in ``args`` (on top of ``base``, a recipe, when given)."""
    given = {f.name: getattr(args, f.name) for f in fields(cls) if hasattr(args, f.name)}
    if given.get("ema") == 0:  # `--ema 0` turns the averaging off
        given["ema"] = None
    return dataclasses.replace(base, **given) if base is not None else cls(**given)


def crop_problem(crop_px: int, train_swin: bool) -> str | None:
    """What is wrong with adapting on ``crop_px`` windows (``AdaptOptions.crop_px``), in words after the field's name;
    None where nothing is. The one rule of ``gsa adapt --crop-px`` and the API's ``crop_px``."""
    if crop_px and not (32 <= crop_px <= 4096 and crop_px % 16 == 0):
        return f"must be 0 (whole frames) or a multiple of 16 from 32 to 4096; {crop_px} is not"
    if crop_px and train_swin:
        return (
            "cannot go with train_swin: Swin reads whole frames; train on windows (UNet++ alone) or with Swin, not both"
        )
    return None


@dataclass(frozen=True)
class AdaptOptions:
    """How to adapt (``gsa adapt``'s flags; torch-free, so the service checks an adaptation's options with it)."""

    sim_ratio: float = 1.0  # simulated frames per labelled training frame
    epochs: int = 30
    max_minutes: float = 25.0  # stop after the epoch in which this runs out
    batch_size: int = 8
    # The shipped networks' last training rates were 2-3e-5 (lr decayed x0.9 a epoch; Swin's tail fine-tuned at
    # 2.4e-5): fine-tuning faster than they ended makes them forget our own frames (at 1e-4 the default
    # frames' median went from 0.29 to 9 deg in 20 minutes on physical-optics frames).
    lr_unet: float = 3e-5
    lr_swin: float = 5e-6
    # Swin's reading of the silhouette is left as it is unless asked: on small sets it forgets more than it learns
    # (measured: 12 steps on 48 of our own frames moved its median 1.26 -> 1.5-2.1 deg at every rate and optimiser
    # tried, Adam 5e-6..2e-5, SGD 1e-3; UNet++ alone 1.26 -> 1.31-1.47). With it, only its last stage, norm and head.
    train_swin: bool = False
    validation_share: float = 0.3
    shift_px: int = 6  # translations up to this many pixels (frame and label alike)
    # Each step on a square window of this many pixels about a point of the target (0: whole frames; a multiple of
    # 16, UNet++'s four halvings). UNet++ is convolutional: a window teaches it the same look at a fraction of the
    # cost, so the budget buys more steps (design/measurements.md, "Adapting on windows of the frame").
    crop_px: int = 0
    noise_share: float = 0.5  # share of frames given extra noise
    seed: int = 0
    precision: str = "auto"  # "auto": bf16 where the CPU computes it natively

    def __post_init__(self) -> None:
        checks = (
            ("sim_ratio", 0.0 <= self.sim_ratio <= 20.0),
            ("epochs", 1 <= self.epochs <= 1000),
            ("max_minutes", 0.0 < self.max_minutes <= 24 * 60),
            ("batch_size", 1 <= self.batch_size <= 256),
            ("lr_unet", 0.0 <= self.lr_unet < 1.0),
            ("lr_swin", 0.0 <= self.lr_swin < 1.0),
            ("validation_share", 0.05 <= self.validation_share <= 0.8),
            ("shift_px", 0 <= self.shift_px <= 32),
            ("noise_share", 0.0 <= self.noise_share <= 1.0),
            ("precision", self.precision in ("auto", "bf16", "fp32")),
        )
        problem = crop_problem(self.crop_px, self.train_swin)
        if problem:
            raise DatasetError(f"crop_px {problem}", field="crop_px")
        for name, ok in checks:
            if not ok:
                raise DatasetError(f"{name} = {getattr(self, name)!r} is out of range", field=name)
