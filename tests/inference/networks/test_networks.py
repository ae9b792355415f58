"""UNet++ and Swin: the paper's sizes, shapes, the shifted-window mask, the loss."""

import pytest
import torch

from inference.networks.build import build_models, get_config
from inference.networks.swin import SwinTransformer, window_partition, window_reverse
from inference.networks.unetpp import UNetPlusPlus, relative_frobenius_loss


def test_paper_sizes():
    unet, swin = build_models(get_config("paper"))
    assert sum(p.numel() for p in unet.parameters()) == pytest.approx(9.04e6, rel=0.01)
    assert sum(p.numel() for p in swin.parameters()) == pytest.approx(27.5e6, rel=0.01)


def test_shapes_and_window_round_trip():
    x = torch.randn(2, 16, 16, 5)
    assert torch.equal(window_reverse(window_partition(x, 8), 8, 16, 16), x)
    unet = UNetPlusPlus(1, (4, 8, 16, 32, 64))
    assert unet(torch.zeros(3, 1, 64, 64)).shape == (3, 1, 64, 64)
    swin = SwinTransformer(img_size=64, embed_dim=12, depths=(2, 2, 1, 1), num_heads=(1, 1, 2, 2))
    assert swin(torch.zeros(3, 1, 64, 64)).shape == (3, 3)


def test_shifted_window_mask_blocks_wrapped_neighbours():
    swin = SwinTransformer(img_size=64, embed_dim=12, depths=(2, 1, 1, 1), num_heads=(1, 1, 1, 1))
    block = swin.stages[0].blocks[1]
    assert block.shift == 4 and block.attn_mask is not None
    mask = block.attn_mask
    assert mask.shape == (4, 64, 64) and (mask == 0).all(dim=(1, 2)).tolist()[0]  # first window: no wrap
    assert (mask[-1] < 0).any()  # the corner window mixes wrapped regions


def test_relative_frobenius_loss():
    label = torch.ones(1, 1, 4, 4)
    assert float(relative_frobenius_loss(label, label)) == 0.0
    assert float(relative_frobenius_loss(torch.zeros_like(label), label)) == pytest.approx(1.0)
