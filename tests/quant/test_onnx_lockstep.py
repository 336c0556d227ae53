"""The lockstep helpers' position sampler: a conv map's values at given positions, taken in the graph."""

from __future__ import annotations

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

from edgepick.quant.onnx.lockstep import position_sampler, runner


def _two_convs(height: int | str, width: int | str) -> onnx.ModelProto:
    rng = np.random.default_rng(0)
    inits = [numpy_helper.from_array(rng.normal(size=(4, 3, 3, 3)).astype(np.float32), "w1"),
             numpy_helper.from_array(rng.normal(size=(2, 4, 1, 1)).astype(np.float32), "w2")]
    nodes = [helper.make_node("Conv", ["x", "w1"], ["a"], pads=[1, 1, 1, 1], name="conv1"),
             helper.make_node("Relu", ["a"], ["r"], name="relu"),
             helper.make_node("Conv", ["r", "w2"], ["y"], name="conv2")]
    graph = helper.make_graph(nodes, "two", [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 3, height, width])],
                              [helper.make_tensor_value_info("y", TensorProto.FLOAT, None)], inits)
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])


def test_the_sampler_gives_each_maps_values_at_the_positions_asked_for():
    model, x = _two_convs(8, 6), np.random.default_rng(1).normal(size=(1, 3, 8, 6)).astype(np.float32)
    whole = runner(model, ["a", "y"])(x, ["a", "y"])
    sizes, sample = position_sampler(model, ["a", "y"])
    assert sizes == [48, 48]
    takes = [np.array([5, 0, 47]), np.array([7])]
    for full, take, got in zip(whole, takes, sample(x, takes), strict=True):
        assert got.shape == (1, full.shape[1], take.size)
        np.testing.assert_array_equal(got, full.reshape(1, full.shape[1], -1)[:, :, take])


def test_a_map_shape_inference_cannot_size_comes_back_whole():
    model, x = _two_convs("h", "w"), np.random.default_rng(2).normal(size=(1, 3, 5, 7)).astype(np.float32)
    sizes, sample = position_sampler(model, ["a"])
    assert sizes == [None]
    (got,) = sample(x, [None])
    np.testing.assert_array_equal(got, runner(model, ["a"])(x, ["a"])[0].reshape(1, 4, 35))
