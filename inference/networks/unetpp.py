"""UNet++ (Zhou et al. 2018), as in Hou et al. 2023 section 4.3.1: nested skip paths, deep supervision.

Node X(i, j): depth i (filters[i] channels), position j along the skip path. Each node
is two 3x3 convolutions with ReLU; down-sampling is 2x2 max-pooling; up-sampling a
2x2 transposed convolution of stride 2. X(i, j) takes [X(i, 0..j-1), Up(X(i+1, j-1))].
A 1-channel 1x1 convolution follows each of X(0, 1)..X(0, 4); their mean is the
enhanced frame.
"""

from __future__ import annotations

import torch
from torch import nn

__all__ = ["UNetPlusPlus"]


class ConvBlock(nn.Module):
    """Two 3x3 convolutions with ReLU (optionally batch-normalised)."""

    def __init__(self, in_chans: int, out_chans: int, norm: bool = False) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        for c_in in (in_chans, out_chans):
            layers.append(nn.Conv2d(c_in, out_chans, 3, padding=1, bias=not norm))
            if norm:
                layers.append(nn.BatchNorm2d(out_chans))
            layers.append(nn.ReLU(inplace=True))
        self.block = nn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.block(x)


class UNetPlusPlus(nn.Module):
    """UNet++ with ``len(filters)`` depths; input and output [B, 1, H, W], H and W divisible by 2^(depth-1)."""

    def __init__(
        self, in_chans: int = 1, filters: tuple[int, ...] = (32, 64, 128, 256, 512), norm: bool = False
    ) -> None:
        super().__init__()
        self.filters = filters
        depth = len(filters)
        self.pool = nn.MaxPool2d(2)
        self.nodes = nn.ModuleDict()
        self.ups = nn.ModuleDict()
        for i in range(depth):
            for j in range(depth - i):
                if j == 0:
                    c_in = in_chans if i == 0 else filters[i - 1]
                else:
                    c_in = j * filters[i] + filters[i]
                    self.ups[f"{i}_{j}"] = nn.ConvTranspose2d(filters[i + 1], filters[i], 2, stride=2)
                self.nodes[f"{i}_{j}"] = ConvBlock(c_in, filters[i], norm)
        self.heads = nn.ModuleList(nn.Conv2d(filters[0], 1, 1) for _ in range(depth - 1))

    def forward_features(self, x: torch.Tensor) -> list[torch.Tensor]:
        """Return the top-row nodes X(0, 1)..X(0, depth-1), each [B, filters[0], H, W]."""
        depth = len(self.filters)
        grid: dict[tuple[int, int], torch.Tensor] = {}
        for i in range(depth):
            grid[(i, 0)] = self.nodes[f"{i}_0"](x if i == 0 else self.pool(grid[(i - 1, 0)]))
        for j in range(1, depth):
            for i in range(depth - j):
                up = self.ups[f"{i}_{j}"](grid[(i + 1, j - 1)])
                grid[(i, j)] = self.nodes[f"{i}_{j}"](torch.cat([grid[(i, k)] for k in range(j)] + [up], dim=1))
        return [grid[(0, j)] for j in range(1, depth)]

    def forward_head(self, features: list[torch.Tensor]) -> torch.Tensor:
        """Return the mean of the deep-supervision heads, [B, 1, H, W]."""
        return torch.stack([head(f) for head, f in zip(self.heads, features, strict=True)]).mean(dim=0)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.forward_head(self.forward_features(x))


def relative_frobenius_loss(out: torch.Tensor, label: torch.Tensor) -> torch.Tensor:
    """Return the batch mean of ||out - label||_F / ||label||_F (the paper's UNet++ loss)."""
    num = torch.linalg.vector_norm((out - label).flatten(1), dim=1)
    den = torch.linalg.vector_norm(label.flatten(1), dim=1).clamp_min(1e-6)
    return (num / den).mean()
