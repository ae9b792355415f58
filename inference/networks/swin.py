"""Swin transformer (Liu et al. 2021) regressing attitude, as in Hou et al. 2023 section 4.3.2.

Built bottom-up in timm's style: window helpers, WindowAttention, SwinBlock,
PatchMerging, SwinStage, SwinTransformer. Written for ONNX export: reshapes use -1
for the batch, the shift mask is a buffer, and attention is written out.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

__all__ = ["SwinTransformer"]


def window_partition(x: torch.Tensor, window: int, hwc: tuple[int, int, int] | None = None) -> torch.Tensor:
    """Split x [B, H, W, C] into windows [B * nW, window * window, C].

    ``hwc``: H, W and C as plain ints when the caller knows them, so an ONNX export holds
    constants instead of computing them from the tensor's shape at run time.
    """
    if hwc is None:
        _, h, w, c = x.shape
    else:
        h, w, c = hwc
    x = x.reshape(-1, h // window, window, w // window, window, c)
    return x.permute(0, 1, 3, 2, 4, 5).reshape(-1, window * window, c)


def window_reverse(windows: torch.Tensor, window: int, h: int, w: int, c: int | None = None) -> torch.Tensor:
    """Join windows [B * nW, window * window, C] back into [B, H, W, C]."""
    c = c or windows.shape[-1]
    x = windows.reshape(-1, h // window, w // window, window, window, c)
    return x.permute(0, 1, 3, 2, 4, 5).reshape(-1, h, w, c)


def relative_position_index(window: int) -> torch.Tensor:
    """Return the [window^2, window^2] index into the relative-position bias table."""
    coords = torch.stack(torch.meshgrid(torch.arange(window), torch.arange(window), indexing="ij")).flatten(1)
    rel = (coords[:, :, None] - coords[:, None, :]).permute(1, 2, 0) + (window - 1)
    return rel[:, :, 0] * (2 * window - 1) + rel[:, :, 1]


class WindowAttention(nn.Module):
    """Multi-head self-attention inside windows, with a learned relative-position bias."""

    bias_index: torch.Tensor

    def __init__(self, dim: int, num_heads: int, window: int) -> None:
        super().__init__()
        self.num_heads = num_heads
        self.dim = dim
        self.scale = (dim // num_heads) ** -0.5
        self.qkv = nn.Linear(dim, 3 * dim)
        self.proj = nn.Linear(dim, dim)
        self.bias_table = nn.Parameter(torch.zeros((2 * window - 1) ** 2, num_heads))
        nn.init.trunc_normal_(self.bias_table, std=0.02)
        self.register_buffer("bias_index", relative_position_index(window).flatten(), persistent=False)
        self.n = window * window

    def forward(self, x: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        """x: [B * nW, N, C]; mask: [nW, N, N] of 0 / -100 or None."""
        n, c = self.n, self.dim
        qkv = self.qkv(x).reshape(-1, n, 3, self.num_heads, c // self.num_heads).permute(2, 0, 3, 1, 4)
        q, k, v = qkv[0], qkv[1], qkv[2]
        attn = (q * self.scale) @ k.transpose(-2, -1)
        bias = self.bias_table[self.bias_index].reshape(n, n, -1).permute(2, 0, 1)
        attn = attn + bias.unsqueeze(0)
        if mask is not None:
            nw = mask.shape[0]
            attn = attn.reshape(-1, nw, self.num_heads, n, n) + mask[None, :, None]
            attn = attn.reshape(-1, self.num_heads, n, n)
        attn = attn.softmax(dim=-1)
        out = (attn @ v).transpose(1, 2).reshape(-1, n, c)
        return self.proj(out)


class SwinBlock(nn.Module):
    """A (shifted-)window attention block and an MLP, each pre-normalised with a residual."""

    def __init__(
        self, dim: int, resolution: int, num_heads: int, window: int, shift: int, mlp_ratio: float = 4.0
    ) -> None:
        super().__init__()
        if resolution <= window:  # one window covers the map: nothing to shift
            window, shift = resolution, 0
        self.window, self.shift, self.resolution = window, shift, resolution
        self.norm1 = nn.LayerNorm(dim)
        self.attn = WindowAttention(dim, num_heads, window)
        self.norm2 = nn.LayerNorm(dim)
        hidden = int(dim * mlp_ratio)
        self.mlp = nn.Sequential(nn.Linear(dim, hidden), nn.GELU(), nn.Linear(hidden, dim))
        self.register_buffer("attn_mask", self._mask() if shift else None, persistent=False)
        self.dim = dim

    def _mask(self) -> torch.Tensor:
        r, w, s = self.resolution, self.window, self.shift
        img = torch.zeros(1, r, r, 1)
        cnt = 0
        for hs in (slice(0, -w), slice(-w, -s), slice(-s, None)):
            for ws in (slice(0, -w), slice(-w, -s), slice(-s, None)):
                img[:, hs, ws, :] = cnt
                cnt += 1
        win = window_partition(img, w).squeeze(-1)
        mask = win[:, None, :] - win[:, :, None]
        return mask.masked_fill(mask != 0, -100.0).masked_fill(mask == 0, 0.0)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """x: [B, H, W, C] -> [B, H, W, C]."""
        r, c = self.resolution, self.dim  # plain ints: no shape arithmetic in the exported graph
        y = self.norm1(x)
        if self.shift:
            y = torch.roll(y, shifts=(-self.shift, -self.shift), dims=(1, 2))
        windows = self.attn(window_partition(y, self.window, (r, r, c)), self.attn_mask)
        y = window_reverse(windows, self.window, r, r, c)
        if self.shift:
            y = torch.roll(y, shifts=(self.shift, self.shift), dims=(1, 2))
        x = x + y
        return x + self.mlp(self.norm2(x))


class PatchMerging(nn.Module):
    """Halve the resolution and double the channels: [B, H, W, C] -> [B, H/2, W/2, 2C]."""

    def __init__(self, dim: int) -> None:
        super().__init__()
        self.norm = nn.LayerNorm(4 * dim)
        self.reduction = nn.Linear(4 * dim, 2 * dim, bias=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = torch.cat([x[:, 0::2, 0::2], x[:, 1::2, 0::2], x[:, 0::2, 1::2], x[:, 1::2, 1::2]], dim=-1)
        return self.reduction(self.norm(x))


class SwinStage(nn.Module):
    """Optional patch merging, then ``depth`` blocks alternating W-MSA and SW-MSA."""

    def __init__(self, dim: int, resolution: int, depth: int, num_heads: int, window: int, downsample: bool) -> None:
        super().__init__()
        self.downsample = PatchMerging(dim // 2) if downsample else nn.Identity()
        self.blocks = nn.Sequential(
            *(SwinBlock(dim, resolution, num_heads, window, 0 if k % 2 == 0 else window // 2) for k in range(depth))
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.blocks(self.downsample(x))


class SwinTransformer(nn.Module):
    """Swin regressing ``num_outputs`` values from a [B, in_chans, img_size, img_size] frame."""

    def __init__(
        self,
        img_size: int = 256,
        patch_size: int = 4,
        in_chans: int = 1,
        embed_dim: int = 96,
        depths: tuple[int, ...] = (2, 2, 6, 2),
        num_heads: tuple[int, ...] = (3, 6, 12, 24),
        window_size: int = 8,
        num_outputs: int = 3,
    ) -> None:
        super().__init__()
        self.patch_embed = nn.Conv2d(in_chans, embed_dim, patch_size, stride=patch_size)
        self.embed_norm = nn.LayerNorm(embed_dim)
        res = img_size // patch_size
        stages = []
        for k, (depth, heads) in enumerate(zip(depths, num_heads, strict=True)):
            stages.append(SwinStage(embed_dim * 2**k, res // 2**k, depth, heads, window_size, downsample=k > 0))
        self.stages = nn.Sequential(*stages)
        self.num_features = embed_dim * 2 ** (len(depths) - 1)
        self.norm = nn.LayerNorm(self.num_features)
        self.head = nn.Linear(self.num_features, num_outputs)
        self.apply(self._init)

    @staticmethod
    def _init(m: nn.Module) -> None:
        if isinstance(m, nn.Linear):
            nn.init.trunc_normal_(m.weight, std=0.02)
            if m.bias is not None:
                nn.init.zeros_(m.bias)

    def embed(self, x: torch.Tensor) -> torch.Tensor:
        """x: [B, 1, H, W] -> patch tokens [B, H/4, W/4, C], the first stage's input."""
        return self.embed_norm(self.patch_embed(x).permute(0, 2, 3, 1))

    def pool(self, x: torch.Tensor) -> torch.Tensor:
        """The last stage's tokens [B, h, w, C'] -> pooled features [B, num_features]."""
        return self.norm(x).mean(dim=(1, 2))

    def forward_features(self, x: torch.Tensor) -> torch.Tensor:
        """x: [B, 1, H, W] -> pooled features [B, num_features]."""
        return self.pool(self.stages(self.embed(x)))

    def forward_head(self, x: torch.Tensor) -> torch.Tensor:
        return self.head(x)

    def split_stages(self, train_stages: int) -> tuple[list[nn.Module], list[nn.Module]]:
        """The stages as (frozen, trained) for fine-tuning: the trained ones are the last ``train_stages``."""
        stages = list(self.stages.children())
        return stages[: len(stages) - train_stages], stages[len(stages) - train_stages :]

    def front(self, x: torch.Tensor, train_stages: int) -> torch.Tensor:
        """The frozen part: frames [B, 1, H, W] -> the last frozen stage's tokens [B, h, w, C]."""
        y = self.embed(x)
        for stage in self.split_stages(train_stages)[0]:
            y = stage(y)
        return y

    def tail(self, f: torch.Tensor, train_stages: int) -> torch.Tensor:
        """The trained part: the front's tokens -> scaled angles [B, 3]; ``front`` then ``tail`` is ``forward``."""
        for stage in self.split_stages(train_stages)[1]:
            f = stage(f)
        return self.forward_head(self.pool(f))

    def tail_modules(self, train_stages: int) -> nn.ModuleList:
        """What fine-tuning trains: the last ``train_stages`` stages, the final norm and the head."""
        return nn.ModuleList([*self.split_stages(train_stages)[1], self.norm, self.head])

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.forward_head(self.forward_features(x))


def angle_loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean squared error on the (scaled) angles, the paper's Swin loss."""
    return F.mse_loss(pred, target)


def cube_angle_loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """``angle_loss`` over the frames whose scaled angles lie within [-1, 1] on every axis (the cube Swin answers).

    A set with frames over all of SO(3) teaches UNet++ every attitude, while Swin's regressed Euler triple, which
    wraps at +-180 deg and is singular at y = +-90, learns the cube only (the library search answers the rest).
    Weighted rather than indexed, so a GPU step does not wait on the mask; the same as ``angle_loss`` when every
    frame is inside, 0 when none is.
    """
    inside = (target.abs() <= 1.0).all(dim=1).to(pred.dtype)
    per_frame = ((pred - target) ** 2).mean(dim=1)
    return (per_frame * inside).sum() / inside.sum().clamp(min=1.0)
