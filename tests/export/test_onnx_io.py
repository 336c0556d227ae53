"""Reading a float ONNX from another exporter: refusals naming `model`, fixed dims, `model info`."""

from __future__ import annotations

import onnx
import pytest
from onnx import TensorProto, helper

from edgepick.errors import ParameterError
from edgepick.export.onnx_io import describe, fix_input_shape, input_dims, load_float_onnx
from tests.quant.onnx_models import export_torch


def test_a_file_that_is_not_a_float_conv_model_is_refused_naming_model(tmp_path):
    (tmp_path / "text.onnx").write_text("not a model")
    with pytest.raises(ParameterError, match="^model=.*not an ONNX file"):
        load_float_onnx(tmp_path / "text.onnx")
    graph = helper.make_graph([helper.make_node("Relu", ["input"], ["output"])], "g",
                              [helper.make_tensor_value_info("input", TensorProto.FLOAT, [1, 3, 4, 4])],
                              [helper.make_tensor_value_info("output", TensorProto.FLOAT, None)])
    onnx.save(helper.make_model(graph), tmp_path / "relu.onnx")
    with pytest.raises(ParameterError, match="no Conv or ConvTranspose"):
        load_float_onnx(tmp_path / "relu.onnx")
    with pytest.raises(ParameterError, match="no such file"):
        load_float_onnx(tmp_path / "none.onnx")


def test_a_fixed_input_shape_must_fit_the_fixed_dims(tmp_path):
    model = load_float_onnx(export_torch(tmp_path / "net.onnx"))
    with pytest.raises(ParameterError, match="input_shape"):
        fix_input_shape(model, (1, 4, 64, 96))  # the channel dim is fixed at 3
    with pytest.raises(ParameterError, match="input_shape"):
        fix_input_shape(model, (1, 3, 64))
    fix_input_shape(model, (2, 3, 32, 48))
    assert input_dims(model) == [2, 3, 32, 48]


def test_describe_says_what_a_file_is(tmp_path):
    info = describe(export_torch(tmp_path / "net.onnx", opset=12, two_outputs=True))
    assert info["inputs"] == [{"name": "input", "dtype": "float32", "shape": ["n", 3, "h", "w"]}]
    assert [o["name"] for o in info["outputs"]] == ["logits", "aux"] and info["opset"] == 12
    assert info["precision"] == "fp32" and info["convs"] == 9 and info["int8_convs"] == 0
    assert info["edgepick_model"] is False and "not an edgepick model" in info["why_not"]
