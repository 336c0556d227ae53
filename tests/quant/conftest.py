"""Fixtures the ONNX quantization tests share."""

from __future__ import annotations

import pytest

from tests.quant.onnx_models import faint_channel_inputs, faint_channel_model


@pytest.fixture(scope="module")
def faint(tmp_path_factory):
    """The faint-channel model, its inputs (calibration, check) and fp32's outputs on the check inputs."""
    import onnxruntime as ort

    tmp = tmp_path_factory.mktemp("faint")
    path = faint_channel_model(tmp / "faint.onnx")
    check = faint_channel_inputs(4, seed=9)
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    return path, faint_channel_inputs(16), check, [session.run(None, {"input": x})[0] for x in check], tmp
