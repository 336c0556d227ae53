"""edgepick/train/data.py: the batch augmentation, and the coloured lamp that `--augment lights` adds."""

from __future__ import annotations

import torch

from edgepick.train.data import augment, coloured_lamp


def frames(n: int = 4, h: int = 48, w: int = 64) -> torch.Tensor:
    """Grey frames with a white square: a neutral scene to relight."""
    img = torch.full((n, 3, h, w), 120.0)
    img[:, :, 10:30, 20:40] = 230.0
    return img


def test_the_lamp_relights_the_chosen_share_red_orange_and_leaves_the_rest():
    img = frames(n=64)
    lit = coloured_lamp(img, torch.Generator().manual_seed(0), share=0.5)
    changed = (lit != img).flatten(1).any(1)
    assert 16 < int(changed.sum()) < 48  # about half, drawn per image
    assert torch.equal(lit[~changed], img[~changed])
    red, green, blue = lit[changed].mean((2, 3)).unbind(1)
    assert bool((red > green).all() and (red > blue).all())  # a warm lamp, never a cool cast
    assert float(lit.min()) >= 0 and float(lit.max()) <= 255


def test_the_lamp_falls_off_across_the_frame():
    lit = coloured_lamp(frames(n=16), torch.Generator().manual_seed(1), share=1.0)
    red = lit[:, 0, 40:, :]  # the grey part below the square: only the lamp changes it
    assert bool(((red.amax((1, 2)) - red.amin((1, 2))) > 10).all())  # not one gain for the whole frame


def test_lights_adds_the_lamp_and_basic_stays_as_it_was():
    img, mask = frames(n=8), torch.zeros(8, 48, 64, dtype=torch.long)
    basic = augment(img, mask, torch.Generator().manual_seed(2))
    again = augment(img, mask, torch.Generator().manual_seed(2), lights=False)
    lights = augment(img, mask, torch.Generator().manual_seed(2), lights=True)
    assert torch.equal(basic[0], again[0]) and torch.equal(basic[1], again[1])
    assert not torch.equal(basic[0], lights[0])
    assert lights[0].shape == img.shape and lights[1].shape == mask.shape
