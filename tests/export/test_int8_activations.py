"""integer_activations: HardSigmoid and mean pooling between Q/DQ get integer kernels in onnxruntime
(QLinearAdd, QLinearGlobalAveragePool) with the same uint8 outputs up to one step, and the exported
int8 model (hardswish quantized as x * hardsigmoid(x)) has no activation left in float."""

from __future__ import annotations

import numpy as np
import onnx
import onnxruntime as ort
import pytest
from onnx import TensorProto, helper, numpy_helper

from edgepick.export.int8_activations import TAG, integer_activations

C, H, W = 8, 12, 16


def qdq_model(op: str, x_scale: float = 0.06, x_zero: int = 100, y_scale: float = 0.05, y_zero: int = 0,
              **attrs) -> onnx.ModelProto:
    """uint8 x -> DequantizeLinear -> OP -> QuantizeLinear -> y (uint8); OP 'PoolChain' is the exporter's
    adaptive_avg_pool2d: ReduceMean(-1, -2) -> Reshape(-1) -> Gather(arange as [1, C, 1, 1])."""
    inits = [numpy_helper.from_array(np.float32(x_scale), "x_scale"), numpy_helper.from_array(np.uint8(x_zero), "x_zp"),
             numpy_helper.from_array(np.float32(y_scale), "y_scale"), numpy_helper.from_array(np.uint8(y_zero), "y_zp")]
    nodes = [helper.make_node("DequantizeLinear", ["x", "x_scale", "x_zp"], ["xf"], name="dq")]
    if op in ("ReduceMean", "PoolChain"):
        axes = attrs.pop("axes", [-1, -2])
        inits.append(numpy_helper.from_array(np.asarray(axes, np.int64), "axes"))
        nodes.append(helper.make_node("ReduceMean", ["xf", "axes"], ["yf"], name="mean", **attrs))
        if op == "PoolChain":
            inits += [numpy_helper.from_array(np.asarray([-1], np.int64), "flat"),
                      numpy_helper.from_array(np.arange(C, dtype=np.int64).reshape(1, C, 1, 1), "order")]
            nodes[-1].output[0] = "m"
            nodes += [helper.make_node("Reshape", ["m", "flat"], ["m1"], name="reshape"),
                      helper.make_node("Gather", ["m1", "order"], ["yf"], name="gather", axis=0)]
    else:
        nodes.append(helper.make_node(op, ["xf"], ["yf"], name="act", **attrs))
    nodes.append(helper.make_node("QuantizeLinear", ["yf", "y_scale", "y_zp"], ["y"], name="q"))
    graph = helper.make_graph(nodes, "g", [helper.make_tensor_value_info("x", TensorProto.UINT8, [1, C, H, W])],
                              [helper.make_tensor_value_info("y", TensorProto.UINT8, [None] * 4)], inits)
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", 21)])


def run(model: onnx.ModelProto, x: np.ndarray, optimized_to: str | None = None) -> np.ndarray:
    opts = ort.SessionOptions()
    opts.log_severity_level = 3
    if optimized_to:
        opts.optimized_model_filepath = optimized_to
    return ort.InferenceSession(model.SerializeToString(), opts, providers=["CPUExecutionProvider"]).run(
        None, {"x": x})[0]


def op_types_run(model: onnx.ModelProto, x: np.ndarray, tmp_path) -> set[str]:
    """The op types onnxruntime actually runs (its optimized graph)."""
    path = str(tmp_path / "optimized.onnx")
    run(model, x, path)
    return {n.op_type for n in onnx.load(path).graph.node}


X = np.random.default_rng(0).integers(0, 256, (1, C, H, W), dtype=np.uint8)


@pytest.mark.parametrize("y_scale", [1 / 255, 0.9 / 255])
def test_hardsigmoid_becomes_an_integer_add_with_the_same_outputs(tmp_path, y_scale):
    model = qdq_model("HardSigmoid", y_scale=y_scale, alpha=1 / 6, beta=0.5)
    before = run(model, X)
    assert op_types_run(model, X, tmp_path) >= {"HardSigmoid"}
    assert integer_activations(model)["HardSigmoid"] == 1
    onnx.checker.check_model(model, full_check=True)
    after = run(model, X)
    assert np.abs(after.astype(int) - before).max() <= 1  # QLinearAdd's own rounding only
    assert (after == before).mean() > 0.95
    assert before.min() == 0 and before.max() == 255  # both clips are exercised
    ran = op_types_run(model, X, tmp_path)
    assert "QLinearAdd" in ran and "HardSigmoid" not in ran and "DequantizeLinear" not in ran


@pytest.mark.parametrize("op,axes", [("ReduceMean", [-1, -2]), ("ReduceMean", [2, 3]), ("PoolChain", [-1, -2])])
def test_mean_over_the_map_becomes_an_integer_global_pool(tmp_path, op, axes):
    model = qdq_model(op, axes=axes, y_scale=0.06, y_zero=100)
    before = run(model, X)
    assert integer_activations(model)["ReduceMean"] == 1
    onnx.checker.check_model(model, full_check=True)
    after = run(model, X)
    assert after.shape == before.shape == (1, C, 1, 1)
    assert np.abs(after.astype(int) - before).max() <= 1
    ran = op_types_run(model, X, tmp_path)
    assert "QLinearGlobalAveragePool" in ran and not ran & {"ReduceMean", "Gather", "DequantizeLinear"}


@pytest.mark.parametrize("model", [
    qdq_model("HardSigmoid", y_zero=5, alpha=1 / 6, beta=0.5),       # saturation would not clip at 0
    qdq_model("HardSigmoid", y_scale=1.5 / 255, alpha=1 / 6, beta=0.5),  # nor at 1
    qdq_model("ReduceMean", axes=[1]),                                # channel mean: not a pooling
    qdq_model("ReduceMean", axes=[2, 3], keepdims=0),
], ids=["hsig-zero-point", "hsig-range", "mean-channels", "mean-no-keepdims"])
def test_what_it_cannot_rewrite_exactly_is_left_alone(model):
    before = model.SerializeToString()
    assert sum(integer_activations(model).values()) == 0
    assert model.SerializeToString() == before


def test_float_graphs_are_left_alone():
    x = helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, C, H, W])
    graph = helper.make_graph([helper.make_node("HardSwish", ["x"], ["y"])], "g", [x],
                              [helper.make_tensor_value_info("y", TensorProto.FLOAT, [None] * 4)])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 21)])
    assert sum(integer_activations(model).values()) == 0


def test_int8_export_of_the_standard_model_has_no_float_activations(onnx_files):
    """MobileNetV3 as torchvision builds it (hardswish, SE blocks) and ASPP image pooling: after the
    export of static int8 none of them is left in float (the labels' agreement with torch's
    simulation: tests/quant/test_passes.py)."""
    model = onnx.load(onnx_files["static"]["out"])
    ops = [n.op_type for n in model.graph.node]
    assert not {"HardSwish", "HardSigmoid", "ReduceMean"} & set(ops)
    assert ops.count("GlobalAveragePool") == 9  # 8 SE blocks + ASPP pooling
    assert sum(TAG in n.name and n.op_type == "Add" for n in model.graph.node) == 8 + 20  # SE gates + hardswish
    read = {i for n in model.graph.node for i in n.input}
    assert all(i.name in read for i in model.graph.initializer)
