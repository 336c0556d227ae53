"""GELU on onnxruntime's integer kernels (`edgepick/quant/onnx/gelu.py`, OnnxOptions(gelu="sigmoid"))."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import onnx
import pytest

from edgepick.errors import ParameterError
from edgepick.quant.config import OnnxOptions
from edgepick.quant.onnx.gelu import fit_sigmoid_gelu
from edgepick.quant.onnx.static import quantize_onnx_static
from tests.quant.onnx_models import calib_tensors, export_module, optimized_ops

erf = np.vectorize(math.erf)


def _net(activation: str):
    """conv -> ACTIVATION -> conv -> ACTIVATION -> conv: 'gelu' (exported as Div, Erf, Add, Mul, Mul)
    or 'erf' (an Erf that is no GELU)."""
    import torch
    from torch import nn

    class Net(nn.Module):
        def __init__(self):
            super().__init__()
            self.c1, self.c2, self.head = nn.Conv2d(3, 8, 3, 1, 1), nn.Conv2d(8, 8, 3, 1, 1), nn.Conv2d(8, 3, 1)

        def act(self, x):
            return nn.functional.gelu(x) if activation == "gelu" else torch.erf(x)

        def forward(self, x):
            return self.head(self.act(self.c2(self.act(self.c1(x)))))

    torch.manual_seed(0)
    return Net()


def _quantize(tmp_path: Path, activation: str, gelu: str):
    src = export_module(_net(activation), tmp_path / f"{activation}.onnx", shape=(1, 3, 32, 48))
    calib = [4 * x - 2 for x in calib_tensors(8, shape=(1, 3, 32, 48))]  # inputs in [-2, 2]: both GELU sides
    return quantize_onnx_static(src, calib, tmp_path / f"{activation}-{gelu}.onnx", options=OnnxOptions(gelu=gelu),
                                progress=False)


@pytest.mark.slow
def test_gelu_sigmoid_runs_each_gelu_on_integer_kernels(tmp_path):
    fast = _quantize(tmp_path, "gelu", "sigmoid")
    assert fast.rewrites["sigmoid_gelu"] == 2 and fast.int8_convs == fast.convs == 3
    assert fast.agreement_vs_fp32["logits"] >= 0.97, fast.agreement_vs_fp32
    assert json.loads(dict((p.key, p.value) for p in onnx.load(fast.out).metadata_props)["edgepick.quant"])[
        "gelu"] == "sigmoid"
    ops = optimized_ops(Path(fast.out))
    assert ops["QLinearSigmoid"] == 2 and ops["QLinearMul"] == 2 and not {"Erf", "Div", "Sigmoid"} & set(ops), ops
    exact = _quantize(tmp_path, "gelu", "float")
    assert "sigmoid_gelu" not in exact.rewrites and optimized_ops(Path(exact.out))["Erf"] == 2  # run in float


def test_an_erf_that_is_no_gelu_is_left_as_it_is(tmp_path):
    result = _quantize(tmp_path, "erf", "sigmoid")
    assert result.rewrites["sigmoid_gelu"] == 0
    assert optimized_ops(Path(result.out))["Erf"] == 2


def test_the_fit_finds_gelu_and_refuses_other_curves():
    scale, zero, y_scale, y_zero = 6.0 / 255, 128, 3.0 / 255, 40
    x = (np.arange(256) - zero) * scale
    gelu = 0.5 * x * (1 + erf(x / np.sqrt(2)))
    alpha, c = fit_sigmoid_gelu(x, gelu, y_scale, y_zero)
    assert 1.6 < alpha < 1.9 and abs(c - 1) < 0.02
    gate = np.clip(np.round(256 / (1 + np.exp(-alpha * x))), 0, 255) / 256
    codes = lambda v: np.clip(np.round(v / y_scale) + y_zero, 0, 255)  # noqa: E731
    assert np.abs(codes(c * x * gate) - codes(gelu)).max() <= 2
    assert fit_sigmoid_gelu(x, 2 * gelu, y_scale, y_zero)[1] == pytest.approx(2 * c, rel=0.02)  # the 0.5 folded away
    for other in (np.tanh(x), erf(x), -gelu, x * x):
        assert fit_sigmoid_gelu(x, other, y_scale, y_zero) is None


def test_gelu_sigmoid_needs_placement_all():
    with pytest.raises(ParameterError, match="gelu='sigmoid': with placement='convs'"):
        OnnxOptions(gelu="sigmoid", placement="convs")
