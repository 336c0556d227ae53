"""Where 8-bit weights saturate an AVX2 U8S8 kernel's int16 pairs, and first-7's 7-bit weights there only."""

from __future__ import annotations

import copy
import json

import numpy as np
import onnx
import pytest
import torch
from torch import nn

from edgepick.errors import ParameterError
from edgepick.geometry import Size
from edgepick.quant import PtqMethods, QuantConfig, WeightBits, calibrate, prepare, quantize_module_static
from edgepick.quant.methods import saturated_share as numpy_share
from edgepick.quant.pt2e.bias_correction import int8_convs
from edgepick.quant.pt2e.graph import as_input
from edgepick.quant.pt2e.overflow import saturating_convs
from edgepick.quant.pt2e.ptq import convert_static

SIZE = Size(16, 12)
ONE = ((1, 1), (0, 0), (1, 1), 1)  # stride, padding, dilation, groups
THREE = ((1, 1), (1, 1), (1, 1), 1)


def saturated_share(codes: torch.Tensor, weights: torch.Tensor, *geometry) -> float:
    return numpy_share(codes.numpy(), weights.numpy(), *geometry)


def test_a_pair_saturates_where_two_large_codes_meet_two_large_weights_of_one_sign():
    codes = torch.full((1, 2, 3, 3), 255, dtype=torch.uint8)
    big = torch.tensor([[127, 127]], dtype=torch.int8).view(1, 2, 1, 1)
    assert saturated_share(codes, big, 0, *ONE) == 1.0  # 255 * 254 > 32767
    assert saturated_share(codes, big // 2, 0, *ONE) == 0.0  # 7-bit weights: 255 * 126 fits
    assert saturated_share(codes, big * torch.tensor([1, -1], dtype=torch.int8).view(1, 2, 1, 1), 0, *ONE) == 0.0
    dark = codes.clone()
    dark[0, 1, 0, 0] = 0  # one position where the second code is small
    assert saturated_share(dark, big, 0, *ONE) == pytest.approx(8 / 9)
    depthwise = torch.full((2, 1, 3, 3), 127, dtype=torch.int8)
    assert saturated_share(codes, depthwise, 0, (1, 1), (1, 1), (1, 1), 2) == 0.0


def test_pairs_run_along_kernel_row_column_then_channel():
    """With 3 input channels, K is (tap 0: c0 c1 c2, tap 1: c0 c1 c2, ...): the second pair joins tap 0's
    c2 with tap 1's c0, and tap 0's c0 and c2 are in different pairs."""
    codes = torch.full((1, 3, 1, 2), 255, dtype=torch.uint8)
    w = torch.zeros(1, 3, 1, 2, dtype=torch.int8)
    w[0, 2, 0, 0] = w[0, 0, 0, 1] = 127  # tap 0's c2 and tap 1's c0: one pair
    assert saturated_share(codes, w, 0, *ONE) == 1.0
    w.zero_()
    w[0, 0, 0, 0] = w[0, 2, 0, 0] = 127  # tap 0's c0 and c2: two pairs
    assert saturated_share(codes, w, 0, *ONE) == 0.0
    padded = torch.zeros(1, 2, 1, 1, dtype=torch.uint8)  # a 1x1 map: every other tap reads padding
    w3 = torch.zeros(1, 2, 3, 3, dtype=torch.int8)
    w3[0, :, 0, 0] = 127
    assert saturated_share(padded, w3, 255, *THREE) == 1.0  # padding is the zero point, here 255
    assert saturated_share(padded, w3, 0, *THREE) == 0.0


class Bright(nn.Module):
    """conv a: every channel's weights one large value of one sign, so bright images saturate its
    pairs with 8-bit weights; conv b: pairs of opposite signs, which never saturate."""

    def __init__(self):
        super().__init__()
        self.a = nn.Conv2d(3, 4, 3, padding=1)
        self.b = nn.Conv2d(4, 2, 1)
        with torch.no_grad():
            self.a.weight.fill_(0.1)
            self.b.weight.copy_(torch.tensor([1.0, -1.0, 1.0, -1.0]).repeat(2, 1).view(2, 4, 1, 1))

    def forward(self, x):
        return self.b(torch.relu(self.a(x / 255.0)))


@pytest.fixture(scope="module")
def bright():
    rng = np.random.default_rng(0)
    return [rng.integers(240, 256, (*SIZE.hw, 3), dtype=np.uint8) for _ in range(3)]


def _converted(bright, bits):
    config, methods = QuantConfig(weight_bits=bits), PtqMethods(bias_correction="none")  # the weights as rounded
    prepared = prepare(Bright().eval(), config, SIZE, qat=False)
    calibrate(prepared, bright)
    return convert_static(prepared, lambda: [as_input(rgb) for rgb in bright], config, methods)


def test_first_7_gives_7_bit_weights_only_where_8_bit_ones_saturate(bright):
    inputs = [as_input(rgb) for rgb in bright]
    eight, done = _converted(bright, WeightBits.EIGHT)
    assert done == {}
    share = saturating_convs(eight, inputs)
    names = sorted(int8_convs(eight))
    assert share[names[0]] > 0.5 and share[names[1]] == 0.0
    first, done = _converted(bright, WeightBits.FIRST_SEVEN)
    assert done == {"seven_bit_convs": ["a"]}
    assert all(v == 0.0 for v in saturating_convs(first, inputs).values())
    codes = {name: node.args[1].args[0] for name, node in int8_convs(first).items()}
    top = {name: int(getattr(first, codes[name].target).abs().max()) for name in names}
    assert top == {names[0]: 63, names[1]: 127}  # 7 bits on a (the quantizer's -64..63 grid), 8 on b
    seven, _ = _converted(bright, WeightBits.SEVEN)
    a_seven = getattr(seven, int8_convs(seven)[names[0]].args[1].args[0].target)
    assert torch.equal(getattr(first, codes[names[0]].target), a_seven)  # as if quantized with 7 bits at once


def test_first_7_is_recorded_and_refused_by_qat(bright, tmp_path):
    result = quantize_module_static(Bright().eval(), [as_input(rgb) for rgb in bright], tmp_path / "b.onnx",
                             QuantConfig(weight_bits="first-7"), progress=False)
    meta = json.loads({p.key: p.value for p in onnx.load(str(tmp_path / "b.onnx")).metadata_props}["edgepick.quant"])
    assert meta["weight_bits"] == "first-7" and meta["seven_bit_convs"] == ["a"] == result.quant["seven_bit_convs"]
    with pytest.raises(ParameterError, match="weight_bits"):
        prepare(copy.deepcopy(Bright()), QuantConfig(weight_bits="first-7"), SIZE, qat=True)
    assert QuantConfig.from_dict({"reduce_range": False}).weight_bits == WeightBits.EIGHT
    assert QuantConfig.from_dict({"reduce_range": True}) == QuantConfig()
