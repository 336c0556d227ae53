"""The float rewrites of a foreign ONNX model: each must compute the same function."""

from __future__ import annotations

import numpy as np
import onnx
import pytest
from onnx import TensorProto, helper, numpy_helper

from edgepick.export.onnx_io import fix_input_shape, input_dims, lift_opset, load_float_onnx, opset
from edgepick.quant.onnx.rewrite import (
    fold_affine_into_convs,
    rewrite_activations,
    spell_float_hardswish,
    subsample_before_strided_pointwise_convs,
)
from tests.quant.onnx_models import calib_tensors, export_torch, run, strided_projection_model


def _ops(model) -> list[str]:
    return [n.op_type for n in model.graph.node]


@pytest.mark.parametrize("opset_in", [11, 12])
def test_the_rewritten_torch_export_computes_the_same_at_opset_13(tmp_path, opset_in):
    src = export_torch(tmp_path / "net.onnx", opset=opset_in)
    model = load_float_onnx(src)
    assert opset(model) == opset_in and input_dims(model) == ["n", 3, "h", "w"]
    fix_input_shape(model, (1, 3, 64, 96))
    model = lift_opset(model, src)
    assert opset(model) == 13
    done = rewrite_activations(model)
    assert done == {"hardswish": 1, "hardsigmoid": 0, "global_average_pool": 1, "batchnorm_affine": 0}
    folded = fold_affine_into_convs(model)
    assert folded == 2  # the scale and the shift in front of the pointwise conv (it pads nothing)
    ops = _ops(model)
    assert "ReduceMean" not in ops and "Clip" not in ops and "Div" not in ops and ops.count("HardSigmoid") == 2
    onnx.checker.check_model(model, full_check=True)
    out = tmp_path / "rewritten.onnx"
    onnx.save(model, out)
    for x in calib_tensors(3):
        np.testing.assert_allclose(run(out, x)[0], run(src, x)[0], rtol=1e-4, atol=1e-4)


def _conv_model(path, before: list, after: list, pads: int):
    """input -> BEFORE (Mul/Add by constants) -> 3x3 conv with PADS -> AFTER -> output."""
    rng = np.random.default_rng(0)
    inits = [numpy_helper.from_array(rng.normal(size=(4, 3, 3, 3)).astype(np.float32), "w"),
             numpy_helper.from_array(rng.normal(size=4).astype(np.float32), "b")]
    nodes, x = [], "input"
    for k, (op, value) in enumerate([*before, ("Conv", None), *after]):
        if op == "Conv":
            nodes.append(helper.make_node("Conv", [x, "w", "b"], [f"t{k}"], name="conv", kernel_shape=[3, 3],
                                          pads=[pads] * 4))
        else:
            inits.append(numpy_helper.from_array(np.asarray(value, np.float32), f"c{k}"))
            nodes.append(helper.make_node(op, [x, f"c{k}"], [f"t{k}"], name=f"n{k}"))
        x = f"t{k}"
    nodes[-1].output[0] = "output"
    graph = helper.make_graph(nodes, "g", [helper.make_tensor_value_info("input", TensorProto.FLOAT, [1, 3, 8, 8])],
                              [helper.make_tensor_value_info("output", TensorProto.FLOAT, None)], inits)
    onnx.save(helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)]), path)
    return path


@pytest.mark.parametrize("before, after, pads, folds", [
    ([("Mul", [1.5])], [("Mul", [[[2.0]], [[0.5]], [[-1.0]], [[3.0]]]), ("Add", [0.25])], 1, 3),
    ([("Mul", [[[0.5]], [[2.0]], [[1.5]]]), ("Add", [[[0.1]], [[0.2]], [[0.3]]])], [], 0, 2),
    ([("Add", [0.3])], [], 1, 0),  # an added constant would change the padded border: left alone
])
def test_affine_folds_are_exact_and_only_where_exact(tmp_path, before, after, pads, folds):
    src = _conv_model(tmp_path / "m.onnx", before, after, pads)
    model = onnx.load(src)
    assert fold_affine_into_convs(model) == folds
    assert len(model.graph.node) == 1 + len(before) + len(after) - folds
    out = tmp_path / "folded.onnx"
    onnx.save(model, out)
    x = np.random.default_rng(1).normal(size=(1, 3, 8, 8)).astype(np.float32)
    np.testing.assert_allclose(run(out, x)[0], run(src, x)[0], rtol=1e-5, atol=1e-5)


def test_a_lone_batchnorm_becomes_an_exact_mul_and_add(tmp_path):
    rng = np.random.default_rng(0)
    inits = [numpy_helper.from_array(rng.uniform(0.5, 2, 3).astype(np.float32), n) for n in ("g", "v")]
    inits += [numpy_helper.from_array(rng.normal(size=3).astype(np.float32), n) for n in ("be", "m")]
    inits += [numpy_helper.from_array(rng.normal(size=(2, 3, 1, 1)).astype(np.float32), "w")]
    nodes = [helper.make_node("Relu", ["input"], ["r"]),
             helper.make_node("BatchNormalization", ["r", "g", "be", "m", "v"], ["bn"], epsilon=1e-3),
             helper.make_node("Conv", ["bn", "w"], ["output"], kernel_shape=[1, 1])]
    graph = helper.make_graph(nodes, "g", [helper.make_tensor_value_info("input", TensorProto.FLOAT, [1, 3, 4, 4])],
                              [helper.make_tensor_value_info("output", TensorProto.FLOAT, None)], inits)
    src = tmp_path / "bn.onnx"
    onnx.save(helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)]), src)
    model = onnx.load(src)
    assert rewrite_activations(model)["batchnorm_affine"] == 1 and "BatchNormalization" not in _ops(model)
    onnx.save(model, tmp_path / "affine.onnx")
    x = rng.normal(size=(1, 3, 4, 4)).astype(np.float32)
    np.testing.assert_allclose(run(tmp_path / "affine.onnx", x)[0], run(src, x)[0], rtol=1e-5, atol=1e-5)


def test_a_strided_pointwise_conv_subsampled_first_computes_the_same(tmp_path):
    src = strided_projection_model(tmp_path / "block.onnx")
    model = onnx.load(str(src))
    assert subsample_before_strided_pointwise_convs(model) == 2  # the two 1x1 convs, not the strided 3x3 head
    assert _ops(model).count("MaxPool") == 2
    onnx.save(model, str(tmp_path / "subsampled.onnx"))
    for x in calib_tensors(2):
        for a, b in zip(run(src, x), run(tmp_path / "subsampled.onnx", x)):
            np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-5)


def test_a_float_hardswish_spelt_back_out_computes_the_same(tmp_path):
    """x * HardSigmoid(x) (hardswish as rewrite_activations writes it) back to x * Clip(x + 3, 0, 6) / 6;
    the squeeze-excitation's x * HardSigmoid(y) is no hardswish and stays."""
    src = export_torch(tmp_path / "net.onnx", opset=13)
    model = load_float_onnx(src)
    assert rewrite_activations(model)["hardswish"] == 1 and _ops(model).count("HardSigmoid") == 2
    onnx.save(model, str(tmp_path / "gated.onnx"))
    assert spell_float_hardswish(model) == 1
    assert _ops(model).count("HardSigmoid") == 1 and _ops(model).count("Clip") == 1
    onnx.checker.check_model(model, full_check=True)
    onnx.save(model, str(tmp_path / "spelt.onnx"))
    assert spell_float_hardswish(model) == 0  # nothing left to rewrite
    for x in calib_tensors(2):
        np.testing.assert_allclose(run(tmp_path / "spelt.onnx", x)[0], run(tmp_path / "gated.onnx", x)[0],
                                   rtol=1e-5, atol=1e-5)
