"""How a tensor of a QDQ graph goes float (quant/onnx/floating.py): the graph then computes closer
to fp32, never something else."""

from __future__ import annotations

import numpy as np
import onnx
import pytest
from onnx import helper

from edgepick.quant.config import PtqMethods
from edgepick.quant.onnx.floating import float_tensors, quantized_activations
from edgepick.quant.onnx.static import quantize_onnx_static
from tests.quant.onnx_models import calib_tensors, helper_model, run


def _sqnr(reference: list[np.ndarray], got: list[np.ndarray]) -> float:
    signal = sum(float((r.astype(np.float64) ** 2).sum()) for r in reference)
    noise = sum(float(((r.astype(np.float64) - g) ** 2).sum()) for r, g in zip(reference, got))
    return 10 * np.log10(signal / max(noise, 1e-30))


@pytest.fixture(scope="module")
def hard_sigmoid(tmp_path_factory):
    """conv -> HardSigmoid -> conv, its int8 file (where `export.int8_activations` writes the
    HardSigmoid as an Add quantized with 6 times the scale it is read with), check inputs and fp32's
    outputs on them."""
    tmp = tmp_path_factory.mktemp("hard_sigmoid")
    rng = np.random.default_rng(3)
    nodes = [helper.make_node("Conv", ["input", "w1", "b1"], ["features"], name="conv1", pads=[1, 1, 1, 1]),
             helper.make_node("HardSigmoid", ["features"], ["gate"], name="gate", alpha=1 / 6, beta=0.5),
             helper.make_node("Conv", ["gate", "w2", "b2"], ["output"], name="conv2")]
    weights = {"w1": rng.normal(0, 2, (8, 3, 3, 3)), "b1": rng.normal(0, 1, 8), "w2": rng.normal(0, 1, (4, 8, 1, 1)),
               "b2": rng.normal(0, 0.1, 4)}
    path = helper_model(nodes, [("input", [1, 3, 16, 16])], [("output", [1, 4, 16, 16])], weights, tmp / "fp32.onnx")
    int8 = quantize_onnx_static(path, calib_tensors(16, (1, 3, 16, 16)), tmp / "int8.onnx", progress=False,
                                methods=PtqMethods(bias_correction="none")).out
    check = calib_tensors(4, (1, 3, 16, 16), seed=5)
    return path, int8, check, [run(path, x)[0] for x in check], tmp


def _floated(hard_sigmoid, names) -> float:
    """The output SQNR of the int8 file with NAMES float."""
    path, int8, check, reference, tmp = hard_sigmoid
    model = onnx.load(int8)
    float_tensors(model, names, onnx.load(path))
    out = tmp / "floated.onnx"
    onnx.save(model, out)
    return _sqnr(reference, [run(out, x)[0] for x in check])


def test_a_pair_read_with_another_scale_goes_float_with_the_op_it_computes(hard_sigmoid):
    path, int8, check, reference, _ = hard_sigmoid
    activations = quantized_activations(onnx.load(int8))
    written = [a for a in activations if a.endswith("_int8act_sum")]
    assert written  # the HardSigmoid is an Add whose pair divides by 6 and clips: taking it off plainly drops both
    all_int8 = _sqnr(reference, [run(int8, x)[0] for x in check])
    assert _floated(hard_sigmoid, written) > all_int8 - 1.0
    assert _floated(hard_sigmoid, activations) > all_int8  # every activation float: only the weights' rounding left
