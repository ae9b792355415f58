"""Checkpoints: saving them atomically, the averaged weights inside them, loading a trained run,
and float16 weights in pieces small enough to hand back from a GPU machine (``pipeline pack``/``join``)."""

from __future__ import annotations

import hashlib
import io
from pathlib import Path
from typing import Any

import torch

from inference.errors import ModelFileError
from inference.files import write_atomic
from inference.networks.build import build_models, config_from_dict

PIECE_BYTES = 15 * 1024 * 1024


def save_checkpoint(obj: Any, path: Path) -> None:
    """Save atomically, so a reader (or a cut-off run) never sees half a file."""
    write_atomic(path, lambda tmp: torch.save(obj, tmp))


def averaged_weights(state: dict[str, Any]) -> dict[str, Any]:
    """Return the network weights inside an ``AveragedModel`` state dict (without its ``module.`` prefix)."""
    return {k[len("module.") :]: v for k, v in state.items() if k.startswith("module.")}


def load_trained(run_dir: str | Path) -> tuple[torch.nn.Module, torch.nn.Module, dict[str, Any], bool]:
    """Load ``unetpp.pt`` and ``swin.pt`` from a training run; raise ModelFileError naming a bad file.

    Returns the networks, the configuration, and whether Swin reads UNet++'s output (the
    default) or raw frames (``gsa train --no-enhance``), as swin.pt records.
    """
    d = Path(run_dir)
    models = []
    cfg_dict: dict[str, Any] = {}
    enhance = True
    for name in ("unetpp.pt", "swin.pt"):
        path = d / name
        if not path.is_file():
            raise ModelFileError(f"checkpoint {path} is missing", field="model")
        try:
            ck = torch.load(path, map_location="cpu", weights_only=False)
        except Exception as exc:
            raise ModelFileError(f"checkpoint {path} cannot be read: {exc}", field="model") from None
        cfg_dict = ck["config"]
        models.append(ck["state_dict"])
        if name == "swin.pt":
            enhance = bool(ck.get("enhance", True))
    cfg = config_from_dict(cfg_dict)
    unet, swin = build_models(cfg)
    unet.load_state_dict(models[0])
    swin.load_state_dict(models[1])
    unet.eval()
    swin.eval()
    return unet, swin, cfg.as_dict(), enhance


def write_pieces(
    name: str, state: dict[str, Any], config: dict[str, Any], out: Path, **extra: Any
) -> list[dict[str, Any]]:
    """Write a network's checkpoint in float16, in pieces under PIECE_BYTES; return each piece's file, sha256, size."""
    half = {k: (v.half() if v.is_floating_point() else v) for k, v in state.items()}
    buf = io.BytesIO()
    torch.save({"state_dict": half, "config": config, **extra}, buf)
    blob = buf.getvalue()
    pieces = []
    for k in range(0, len(blob), PIECE_BYTES):
        part = blob[k : k + PIECE_BYTES]
        path = out / f"{name}.part{k // PIECE_BYTES:02d}"
        path.write_bytes(part)
        pieces.append({"file": path.name, "sha256": hashlib.sha256(part).hexdigest(), "bytes": len(part)})
    return pieces


def read_pieces(pieces: Path, name: str, manifest: dict[str, Any]) -> dict[str, Any]:
    """One network's checkpoint rebuilt from its pieces (each checked against its sha256)."""
    blob = b""
    for p in manifest[name]:
        part = (pieces / p["file"]).read_bytes()
        if hashlib.sha256(part).hexdigest() != p["sha256"]:
            raise ModelFileError(f"piece {pieces / p['file']} does not match its sha256", field="model")
        blob += part
    ck: dict[str, Any] = torch.load(io.BytesIO(blob), map_location="cpu", weights_only=False)
    return ck


def same_half(a: dict[str, Any], b: dict[str, Any]) -> bool:
    """Whether two state dicts are the same once stored in float16 (a piece can then serve both)."""
    return a.keys() == b.keys() and all(
        torch.equal(v.half() if v.is_floating_point() else v, b[k].half() if b[k].is_floating_point() else b[k])
        for k, v in a.items()
    )
