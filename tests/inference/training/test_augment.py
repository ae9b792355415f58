"""Perturbed silhouettes: scipy's morphology as the reference, and each kind doing only what it says."""

import numpy as np
import pytest
import torch
from scipy.ndimage import grey_dilation, grey_erosion

from inference.training.augment import KINDS, _dilated, _edges_jittered, _eroded, _part_missing, perturb_silhouettes


def _frames(n=6, seed=0):
    rng = np.random.default_rng(seed)
    x = np.zeros((n, 1, 48, 48), np.float32)
    for k in range(n):
        r0, c0 = rng.integers(5, 20, 2)
        x[k, 0, r0 : r0 + 15, c0 : c0 + 20] = rng.uniform(0.6, 1.0)  # a grey silhouette, as UNet++ answers
        x[k, 0, r0 + 4 : r0 + 8, c0 + 20 : c0 + 26] = 0.8  # a wing
    return torch.from_numpy(x)


def test_erosion_and_dilation_are_scipys_3_by_3():
    x = _frames()
    for k in range(len(x)):
        img = x[k, 0].numpy()
        assert np.array_equal(_eroded(x)[k, 0].numpy(), grey_erosion(img, size=3, mode="constant", cval=np.inf))
        assert np.array_equal(_dilated(x)[k, 0].numpy(), grey_dilation(img, size=3, mode="constant", cval=-np.inf))


def test_a_missing_part_only_removes_pixels_in_one_disc_on_the_silhouette():
    x = _frames()
    y = _part_missing(x, torch.Generator().manual_seed(3))
    assert torch.all(y <= x)
    for k in range(len(x)):
        gone = np.argwhere((x[k, 0] > 0.5).numpy() & (y[k, 0] == 0).numpy())
        assert len(gone) > 0
        centre = gone.mean(axis=0)
        assert np.max(np.hypot(*(gone - centre).T)) <= 2 * 10.0 + 1  # one disc of at most 10 px radius


def test_jittered_edges_lie_between_the_erosion_and_the_dilation_and_move_some_of_both():
    x = _frames()
    y = _edges_jittered(x, torch.Generator().manual_seed(4))
    assert torch.all(_eroded(x) <= y) and torch.all(y <= _dilated(x))
    assert torch.any(y < x) and torch.any(y > x)


def test_the_share_is_kept_and_the_generator_alone_decides():
    x = _frames(n=400, seed=1)
    y = perturb_silhouettes(x, 0.5, torch.Generator().manual_seed(7))
    changed = (y != x).flatten(1).any(dim=1).float().mean().item()
    assert 0.4 < changed < 0.6  # a perturbation that changes nothing (a disc off a tiny silhouette) is rare here
    again = perturb_silhouettes(x, 0.5, torch.Generator().manual_seed(7))
    assert torch.equal(y, again)
    assert torch.equal(perturb_silhouettes(x, 0.0, torch.Generator()), x)
    assert len(KINDS) == 4


@pytest.mark.parametrize("share", [-0.1, 1.5])
def test_a_share_outside_0_1_is_refused(share):
    from inference.errors import InferenceError
    from inference.training.options import TrainOptions

    with pytest.raises(InferenceError, match="silhouette_noise"):
        TrainOptions(silhouette_noise=share).check()
