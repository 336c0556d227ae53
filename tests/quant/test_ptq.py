"""Static PTQ's conversion: the images the lockstep methods measure on are bounded by pixels."""

from __future__ import annotations

import pytest
import torch

from edgepick.quant.config import BIAS_CORRECTION_IMAGES, MIN_LOCKSTEP_IMAGES
from edgepick.quant.pt2e.ptq import within_lockstep


@pytest.mark.parametrize(("hw", "batch", "expected"), [
    ((240, 320), 1, BIAS_CORRECTION_IMAGES),  # the size the bound is set at: all 32
    ((480, 640), 1, 8),  # four times the pixels: a quarter of the images
    ((480, 640), 2, 8),
    ((960, 1280), 1, MIN_LOCKSTEP_IMAGES),  # never fewer than the minimum
    ((24, 32), 1, BIAS_CORRECTION_IMAGES),  # small inputs: every image given
])
def test_lockstep_images_are_bounded_by_pixels(hw, batch, expected):
    samples = [torch.zeros(batch, 3, *hw) for _ in range(BIAS_CORRECTION_IMAGES // batch)]
    kept = within_lockstep(samples)
    assert sum(x.shape[0] for x in kept) == expected
    assert all(a is b for a, b in zip(kept, samples, strict=False))  # the first ones, in order
