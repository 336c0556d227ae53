"""Bias correction: a planted per-channel mean shift removed (fast and empirical), the empirical
form closing the typical gap to fp32 at every conv, one image clipped hard not setting the others'
biases, and the pass writing what it did."""

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
from edgepick.quant import (
    BiasCorrection,
    Pt2eOptions,
    PtqMethods,
    QuantConfig,
    calibrate,
    convert,
    prepare,
    quantize_module_static,
    quantize_onnx_static,
)
from edgepick.quant.pt2e.bias_correction import correct_biases, int8_convs
from edgepick.quant.pt2e.rewrites import snap_conv_biases

SIZE = Size(32, 24)


class Planted(nn.Module):
    """Two convs whose weights all sit 0.45 of a 7-bit step above the int8 grid: rounding moves
    every weight down, and on inputs with a positive mean every output channel's mean moves with it.
    A third conv writes the float logits."""

    def __init__(self):
        super().__init__()
        self.a = nn.Conv2d(3, 6, 3, padding=1)
        self.b = nn.Conv2d(6, 4, 1)
        self.logits = nn.Conv2d(4, 2, 1)
        torch.manual_seed(0)
        with torch.no_grad():
            for conv, top in ((self.a, 0.02), (self.b, 1.0)):
                w = conv.weight
                steps = torch.randint(1, 40, w.shape).float() + 0.45  # below the channel's top value
                steps.view(w.shape[0], -1)[:, 0] = 63.0  # each channel's largest |w|: exactly 63 steps
                w.copy_(steps / 63.0 * top)
                conv.bias.zero_()

    def forward(self, x):
        return self.logits(torch.relu(self.b(torch.relu(self.a(x / 255.0)))))


class SummedLogits(Planted):
    """Planted with LR-ASPP's head: the logits are the sum of two convs, one on a's output and one
    (`logits`) on b's, upsampled."""

    def __init__(self):
        super().__init__()
        self.low = nn.Conv2d(6, 2, 1)

    def forward(self, x):
        a = torch.relu(self.a(x / 255.0))
        out = self.low(a) + self.logits(torch.relu(self.b(a)))
        return nn.functional.interpolate(out, scale_factor=2.0, mode="bilinear", align_corners=False)


def _graphs(images, net=None):
    prepared = prepare((net or Planted()).eval(), QuantConfig(), SIZE, qat=False, pt2e=Pt2eOptions(hardswish_gate=False))
    calibrate(prepared, images)
    reference = copy.deepcopy(prepared)
    return reference, convert(prepared, snap_biases=False)


def _conv_means(graph, inputs):
    """Per conv node name, the per-channel mean of its output over INPUTS (not the logits conv's)."""
    from edgepick.quant.pt2e.bias_correction import Means

    convs = [n.name for n in graph.graph.nodes if n.target == torch.ops.aten.conv2d.default]
    means = Means(graph, {name: name for name in convs[:-1]})
    with torch.no_grad():
        for x in inputs:
            means.run(x)
    return means.means()


@pytest.fixture(scope="module")
def images():
    rng = np.random.default_rng(0)
    return [rng.integers(60, 256, (*SIZE.hw, 3), dtype=np.uint8) for _ in range(6)]


@pytest.mark.parametrize("method", [BiasCorrection.FAST, BiasCorrection.EMPIRICAL])
def test_a_planted_mean_shift_is_removed(images, method):
    from edgepick.quant.pt2e.graph import as_input

    inputs = [as_input(rgb) for rgb in images]
    reference, converted = _graphs(images)
    target = _conv_means(reference, inputs)
    before = _conv_means(converted, inputs)
    shift = {k: (before[k] - target[k]).abs().max().item() for k in target}
    assert min(shift.values()) > 1e-3, shift  # the plant moved every conv's mean
    moved = correct_biases(reference, converted, inputs, method)
    logits = sorted(set(int8_convs(converted)) - set(target))
    assert set(moved) == set(target) and len(logits) == 1  # the conv writing the float logits is left as it was
    snap_conv_biases(converted)
    after = _conv_means(converted, inputs)
    for k in target:
        left = (after[k] - target[k]).abs().max().item()
        assert left < shift[k] / 10, (method, k, shift[k], left)


def test_the_convs_summed_into_the_logits_are_left_alone(images):
    """Correcting the means of convs whose outputs are added into the logits would match the
    logits' means, which moved labels away from fp32's (benchmarks/results/ptq-methods-onnx/)."""
    from edgepick.quant.pt2e.graph import as_input

    reference, converted = _graphs(images, SummedLogits())
    convs = int8_convs(converted)
    adds = [n for n in converted.graph.nodes if n.target == torch.ops.aten.add.Tensor]
    assert len(convs) == 4 and len(adds) == 1  # the add is quantized: its inputs are quantized conv outputs
    moved = correct_biases(reference, converted, [as_input(rgb) for rgb in images], BiasCorrection.EMPIRICAL)
    assert sorted(moved) == sorted(list(convs)[i] for i in (0, 2)), (list(convs), moved)  # a and b, not low, logits


def _gaps(reference, converted, inputs):
    """Per conv (not the logits conv), [images, channels]: fp32's per-image channel means minus
    the int8 graph's, over INPUTS."""
    from edgepick.quant.pt2e.bias_correction import ImageMeans

    convs = [n.name for n in reference.graph.nodes if n.target == torch.ops.aten.conv2d.default][:-1]
    means = []
    for graph in (reference, converted):
        runner = ImageMeans(graph, convs)
        with torch.no_grad():
            for x in inputs:
                runner.run(x)
        means.append({k: torch.cat(v) for k, v in runner.rows.items()})
    return {k: means[0][k] - means[1][k] for k in convs}


def test_the_empirical_form_closes_the_gap_at_every_conv_where_the_fast_one_does_not(images):
    """Ranges calibrated on darker images clip the input of the first conv: its per-pixel errors
    move the mean of the second conv's output through the ReLU between them. Only the empirical
    form, which runs the int8 model itself, sees that: it leaves no typical (median) gap to fp32."""
    from edgepick.quant.pt2e.graph import as_input

    inputs = [as_input(rgb) for rgb in images]
    left = {}
    for method in (BiasCorrection.FAST, BiasCorrection.EMPIRICAL):
        reference, converted = _graphs([rgb // 2 for rgb in images])
        correct_biases(reference, converted, inputs, method)
        gaps = _gaps(reference, converted, inputs)
        left[method] = max(torch.quantile(g, 0.5, dim=0).abs().max().item() for g in gaps.values())
    assert left[BiasCorrection.EMPIRICAL] < 1e-5 and left[BiasCorrection.FAST] > 1e-3, left


def test_one_image_clipped_hard_does_not_set_the_bias_of_the_others(images):
    """Calibrated on dark images, a white one is clipped at the first conv's input and its outputs
    fall far below fp32's. Its error must not be handed to the others: the images in range keep
    their planted shift removed (a mean over all images would leave a sixth of the white image's gap)."""
    from edgepick.quant.pt2e.graph import as_input

    dark = [rgb // 2 for rgb in images]
    typical = [as_input(rgb) for rgb in dark[:5]]
    white = as_input(np.full_like(images[0], 255))
    reference, converted = _graphs(dark)
    before = _gaps(reference, converted, [*typical, white])
    plant = {k: g[:5].mean(0).abs().max().item() for k, g in before.items()}
    clipped = {k: (g[5] - g[:5].mean(0)).abs().max().item() for k, g in before.items()}
    assert all(clipped[k] / 6 > plant[k] for k in plant), (clipped, plant)  # a mean would leave more than the plant
    correct_biases(reference, converted, [*typical, white], BiasCorrection.EMPIRICAL)
    after = _gaps(reference, converted, typical)
    for k in plant:
        left = after[k].mean(0).abs().max().item()
        assert left < plant[k] / 10, (k, plant[k], left)


def test_none_changes_nothing_and_onnx_models_say_it_is_not_there(images, tmp_path):
    reference, converted = _graphs(images)
    assert correct_biases(reference, converted, [], BiasCorrection.NONE) == {}
    with pytest.raises(ValueError, match="at least one"):
        correct_biases(reference, converted, [], BiasCorrection.FAST)
    with pytest.raises(ParameterError, match="bias_correction"):
        quantize_onnx_static(tmp_path / "m.onnx", [], tmp_path / "o.onnx", methods=PtqMethods(bias_correction="fast"))
    with pytest.raises(ParameterError, match="bias_correction"):
        PtqMethods(bias_correction="median")


def test_a_module_pass_records_its_bias_correction(images, tmp_path):
    from edgepick.quant.pt2e.graph import as_input

    result = quantize_module_static(Planted().eval(), [as_input(rgb) for rgb in images], tmp_path / "p.onnx",
                                    methods=PtqMethods(bias_correction=BiasCorrection.EMPIRICAL), progress=False)
    assert result.quant["bias_correction"] == "empirical" and result.int8_convs == 3
    meta = {p.key: p.value for p in onnx.load(str(tmp_path / "p.onnx")).metadata_props}
    assert json.loads(meta["edgepick.quant"])["bias_correction"] == "empirical"
