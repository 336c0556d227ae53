"""Cross-layer equalization: a planted 100x channel-range imbalance equalized without changing the
float function, the int8 model closer to fp32 for it, and the chains it must not cross."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch import nn

from edgepick.errors import ParameterError
from edgepick.geometry import Size
from edgepick.quant import Pt2eOptions, QuantConfig, calibrate, convert, prepare
from edgepick.quant.pt2e.equalize import EQUALIZED, equalization_pairs
from edgepick.quant.pt2e.graph import as_input

SIZE = Size(32, 24)
IMBALANCE = torch.logspace(0, 2, 8)  # 1x .. 100x


class Imbalanced(nn.Module):
    """conv-BN-ReLU-conv whose first conv drives its channels 1x to 100x as hard as each other, the
    second conv reading them back with the inverse gains: the same function as a balanced pair."""

    def __init__(self):
        super().__init__()
        torch.manual_seed(0)
        self.a = nn.Conv2d(3, 8, 3, padding=1)
        self.bn = nn.BatchNorm2d(8)
        self.b = nn.Conv2d(8, 4, 1)
        self.c = nn.Conv2d(4, 2, 1)
        with torch.no_grad():
            self.bn.weight.mul_(IMBALANCE)
            self.bn.bias.copy_(0.05 * IMBALANCE)
            self.b.weight.div_(IMBALANCE.view(1, -1, 1, 1))

    def forward(self, x):
        return self.c(torch.relu(self.b(torch.relu(self.bn(self.a(x / 255.0))))))


@pytest.fixture(scope="module")
def images():
    rng = np.random.default_rng(0)
    return [rng.integers(0, 256, (*SIZE.hw, 3), dtype=np.uint8) for _ in range(6)]


def _conv_weight(graph, name):
    from edgepick.quant.pt2e.equalize import _param

    node = next(n for n in graph.graph.nodes if n.name == name)
    return _param(graph, node.args[1]).detach()


def _int8_error(equalize, images):
    """Mean squared error of the int8 model's output against the float model's."""
    model = Imbalanced().eval()
    prepared = prepare(model, QuantConfig(), SIZE, qat=False, equalize=equalize, pt2e=Pt2eOptions(hardswish_gate=False))
    calibrate(prepared, images)
    converted = convert(prepared)
    with torch.no_grad():
        return sum(float((converted(as_input(x)) - Imbalanced().eval()(as_input(x))).pow(2).mean())
                   for x in images)


def test_a_planted_imbalance_is_equalized_without_changing_the_float_model(images):
    x = as_input(images[0])
    plain = prepare(Imbalanced().eval(), QuantConfig(), SIZE, qat=False, pt2e=Pt2eOptions(hardswish_gate=False))
    before = _conv_weight(plain, "conv2d").abs().amax(dim=(1, 2, 3))
    assert float(before.max() / before.min()) > 30  # BN folding carried the planted gains into the conv
    equalized = prepare(Imbalanced().eval(), QuantConfig(), SIZE, qat=False, equalize=True, pt2e=Pt2eOptions(hardswish_gate=False))
    pairs = equalized.meta[EQUALIZED]
    assert pairs == [("conv2d", ["conv2d_1"]), ("conv2d_1", ["conv2d_2"])]
    after = _conv_weight(equalized, "conv2d").abs().amax(dim=(1, 2, 3))
    assert float(after.max() / after.min()) < 4, after
    # each channel's range is now equal in both layers of the pair
    second = _conv_weight(equalized, "conv2d_1").abs().amax(dim=(0, 2, 3))
    assert torch.allclose(after, second, rtol=1e-2)
    with torch.no_grad():
        assert torch.allclose(plain(x), equalized(x), atol=1e-4)


def test_equalizing_brings_the_int8_model_closer_to_fp32(images):
    plain, equalized = _int8_error(False, images), _int8_error(True, images)
    assert equalized < plain / 2, (plain, equalized)


class Blocked(nn.Module):
    """Chains CLE must not cross (a residual add, a hardswish) and one it must (a squeeze-excitation gate)."""

    def __init__(self):
        super().__init__()
        self.stem = nn.Conv2d(3, 4, 1)
        self.res = nn.Conv2d(4, 4, 1)
        self.hs = nn.Conv2d(4, 4, 1)
        self.dw = nn.Conv2d(4, 4, 3, padding=1, groups=4)
        self.fc1, self.fc2 = nn.Conv2d(4, 2, 1), nn.Conv2d(2, 4, 1)
        self.project = nn.Conv2d(4, 2, 1)

    def forward(self, x):
        x = self.stem(x)
        x = x + self.res(x)  # stem and res both feed the add
        x = nn.functional.hardswish(self.hs(x))
        y = torch.relu(self.dw(x))
        gate = nn.functional.hardsigmoid(self.fc2(torch.relu(self.fc1(y.mean((2, 3), keepdim=True)))))
        return self.project(y * gate)


def test_residual_adds_and_hardswish_end_a_chain_and_a_gate_does_not(images):
    def build(equalize):
        torch.manual_seed(0)
        return prepare(Blocked().eval(), QuantConfig(), SIZE, qat=False, equalize=equalize, pt2e=Pt2eOptions(hardswish_gate=False))

    prepared = build(False)
    names = {first.name: sorted(c.name for c in after) for first, after in equalization_pairs(prepared)}
    convs = [n.name for n in prepared.graph.nodes if n.target == torch.ops.aten.conv2d.default]
    stem, res, hs, dw, fc1, fc2, project = convs
    assert names == {dw: sorted([fc1, project]), fc1: [fc2]}, names
    x = as_input(images[0])
    with torch.no_grad():
        assert torch.allclose(prepared(x), build(True)(x), atol=1e-4)


def test_qat_refuses_it():
    with pytest.raises(ParameterError, match="equalize"):
        prepare(Imbalanced().train(), QuantConfig(), SIZE, qat=True, equalize=True)
