"""Named configurations of the two networks and the one function that builds them from a config."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

from inference.errors import InferenceError
from inference.networks.swin import SwinTransformer
from inference.networks.unetpp import UNetPlusPlus


@dataclass(frozen=True)
class ModelConfig:
    """Both networks' shape (the schedule is the training recipe's: ``inference.training.options``)."""

    name: str
    img_size: int = 256
    unet_filters: tuple[int, ...] = (32, 64, 128, 256, 512)
    unet_norm: bool = False
    swin_embed_dim: int = 96
    swin_depths: tuple[int, ...] = (2, 2, 6, 2)
    swin_heads: tuple[int, ...] = (3, 6, 12, 24)
    swin_window: int = 8

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


CONFIGS = {
    # The paper: UNet++ 32..512, Swin-T (C = 96, depths 2-2-6-2, heads 3-6-12-24), window 8 at 256 px.
    "paper": ModelConfig("paper"),
    # For shipping from a CPU: a quarter of the UNet++ filters, Swin at C = 48.
    "compact": ModelConfig("compact", unet_filters=(16, 32, 64, 128, 256), unet_norm=True, swin_embed_dim=48),
    # What a 2-core CPU can train in under an hour: UNet++ 8..128, Swin C = 24, depths 2-2-2-2.
    "cpu": ModelConfig(
        "cpu",
        unet_filters=(8, 16, 32, 64, 128),
        unet_norm=True,
        swin_embed_dim=24,
        swin_depths=(2, 2, 2, 2),
        swin_heads=(1, 2, 4, 8),
    ),
    # Tests: tiny, trains on 64 px frames on a CPU in seconds.
    "smoke": ModelConfig(
        "smoke",
        img_size=64,
        unet_filters=(4, 8, 16, 32, 64),
        unet_norm=True,
        swin_embed_dim=12,
        swin_depths=(1, 1, 1, 1),
        swin_heads=(1, 1, 2, 2),
    ),
}


# What configs written before the schedule moved to the recipes also hold (read back, then dropped).
SCHEDULE_KEYS = ("epochs", "batch_size", "lr", "lr_decay", "extra")


def config_from_dict(d: dict[str, Any]) -> ModelConfig:
    """Rebuild the config a checkpoint or card records (older ones also hold their schedule)."""
    return get_config(d["name"], **{k: v for k, v in d.items() if k != "name" and k not in SCHEDULE_KEYS})


def get_config(name: str, **overrides: Any) -> ModelConfig:
    """Return the named network shape with ``overrides`` (config field names) applied and checked."""
    if name not in CONFIGS:
        raise InferenceError(f"unknown config {name!r}; choose one of {', '.join(CONFIGS)}", field="config")
    base = CONFIGS[name].as_dict()
    unknown = sorted(set(overrides) - set(base))
    if unknown:
        raise InferenceError(f"unknown config field(s) {', '.join(unknown)}", field="config")
    base.update({k: v for k, v in overrides.items() if v is not None})
    for key in ("unet_filters", "swin_depths", "swin_heads"):
        base[key] = tuple(int(v) for v in base[key])
    cfg = ModelConfig(**base)
    check_shape(cfg)
    return cfg


def check_shape(cfg: ModelConfig) -> None:
    """Refuse network shapes the models cannot be built with, naming the field to fix."""
    if len(cfg.unet_filters) != 5 or min(cfg.unet_filters) < 1:
        raise InferenceError(
            f"unet_filters {cfg.unet_filters} must be five positive channel counts", field="unet_filters"
        )
    if cfg.swin_embed_dim < 1:
        raise InferenceError(f"swin_embed_dim {cfg.swin_embed_dim} must be positive", field="swin_embed_dim")
    if not cfg.swin_depths or min(cfg.swin_depths) < 1:
        raise InferenceError(f"swin_depths {cfg.swin_depths} must be positive block counts", field="swin_depths")
    if len(cfg.swin_heads) != len(cfg.swin_depths):
        raise InferenceError(
            f"swin_heads {cfg.swin_heads} needs one head count per stage of swin_depths {cfg.swin_depths}",
            field="swin_heads",
        )
    for k, heads in enumerate(cfg.swin_heads):
        dim = cfg.swin_embed_dim * 2**k
        if heads < 1 or dim % heads:
            raise InferenceError(
                f"stage {k + 1} has {dim} channels (swin_embed_dim x 2^{k}), which {heads} heads do not divide",
                field="swin_heads",
            )
    side = cfg.img_size // 4
    if cfg.img_size % 4 or side % 2 ** (len(cfg.swin_depths) - 1):
        raise InferenceError(
            f"{len(cfg.swin_depths)} Swin stages halve {side}x{side} patches too often for img_size {cfg.img_size}",
            field="swin_depths",
        )


def build_models(cfg: ModelConfig) -> tuple[UNetPlusPlus, SwinTransformer]:
    """Build UNet++ and Swin from a config (the only place that reads one)."""
    unet = UNetPlusPlus(1, cfg.unet_filters, cfg.unet_norm)
    swin = SwinTransformer(
        img_size=cfg.img_size,
        in_chans=1,
        embed_dim=cfg.swin_embed_dim,
        depths=cfg.swin_depths,
        num_heads=cfg.swin_heads,
        window_size=cfg.swin_window,
        num_outputs=3,
    )
    return unet, swin
