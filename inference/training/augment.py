"""Perturbed silhouettes for Swin's training input, so it reads a target's shape and not single edge pixels.

Swin learns from UNet++'s output, which on our own frames is nearly the exact label. On
frames of another simulator or a real radar UNet++ misses or adds a pixel along the
edges, and a Swin trained only on exact silhouettes turns that into degrees of error
(bench/silhouettes.py measures it). ``perturb_silhouettes`` gives each training frame,
with a given probability, one of four plausible enhancer mistakes:

* eroded by one pixel (3 x 3 minimum), or dilated by one pixel (3 x 3 maximum);
* a part missing: a disc of 3-10 px radius, centred on a silhouette pixel, set to zero;
* edges jittered: each 16 x 16 block of the frame eroded, kept or dilated at random.

It works on grey frames in [0, 1] (UNet++'s output) as well as on binary labels, on any
torch device, and draws only from the generator it is given.
"""

from __future__ import annotations

from collections.abc import Callable

import torch
import torch.nn.functional as F

KINDS = ("eroded", "dilated", "part missing", "edges jittered")
BLOCK_PX = 16


def _eroded(x: torch.Tensor) -> torch.Tensor:
    return -F.max_pool2d(-x, 3, stride=1, padding=1)


def _dilated(x: torch.Tensor) -> torch.Tensor:
    return F.max_pool2d(x, 3, stride=1, padding=1)


def _part_missing(x: torch.Tensor, gen: torch.Generator) -> torch.Tensor:
    n, _, h, w = x.shape
    weights = (x[:, 0] > 0.5).flatten(1).float() + 1e-12  # a frame with no silhouette still draws a centre
    centre = torch.multinomial(weights, 1, generator=gen)[:, 0]
    cy, cx = (centre // w).float(), (centre % w).float()
    radius = 3.0 + 7.0 * torch.rand(n, generator=gen, device=x.device)
    yy = torch.arange(h, device=x.device, dtype=torch.float32)[None, :, None]
    xx = torch.arange(w, device=x.device, dtype=torch.float32)[None, None, :]
    inside = (yy - cy[:, None, None]) ** 2 + (xx - cx[:, None, None]) ** 2 <= radius[:, None, None] ** 2
    return x * (~inside)[:, None].to(x.dtype)


def _edges_jittered(x: torch.Tensor, gen: torch.Generator) -> torch.Tensor:
    n, _, h, w = x.shape
    blocks = torch.randint(-1, 2, (n, 1, -(-h // BLOCK_PX), -(-w // BLOCK_PX)), generator=gen, device=x.device)
    choice = F.interpolate(blocks.float(), scale_factor=BLOCK_PX, mode="nearest")[:, :, :h, :w]
    return torch.where(choice < 0, _eroded(x), torch.where(choice > 0, _dilated(x), x))


def perturb_silhouettes(x: torch.Tensor, share: float, gen: torch.Generator) -> torch.Tensor:
    """Return frames [N, 1, H, W] of which each, with probability ``share``, has one perturbation of ``KINDS``.

    >>> x = torch.zeros(1, 1, 32, 32); x[..., 10:20, 10:20] = 1
    >>> gen = torch.Generator().manual_seed(0)
    >>> perturb_silhouettes(x, 0.0, gen).equal(x)
    True
    >>> int(_dilated(x).sum()), int(_eroded(x).sum())
    (144, 64)
    """
    if not 0.0 <= share <= 1.0:
        raise ValueError(f"silhouette_noise {share} must be in [0, 1]")
    if share == 0.0 or len(x) == 0:
        return x
    n = len(x)
    pick = torch.where(
        torch.rand(n, generator=gen, device=x.device) < share,
        torch.randint(0, len(KINDS), (n,), generator=gen, device=x.device),
        torch.full((n,), -1, device=x.device, dtype=torch.long),
    )
    out = x
    makers: tuple[Callable[[torch.Tensor], torch.Tensor], ...] = (
        _eroded,
        _dilated,
        lambda t: _part_missing(t, gen),
        lambda t: _edges_jittered(t, gen),
    )
    for k, make in enumerate(makers):
        rows = torch.nonzero(pick == k)[:, 0]
        if len(rows):
            out = out.index_copy(0, rows, make(x[rows]))
    return out
