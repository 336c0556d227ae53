"""Graph: producers, consumers, attributes and values read off an ONNX graph, and edits after which
those answers stay true."""

from __future__ import annotations

import numpy as np
import pytest

onnx = pytest.importorskip("onnx")

from onnx import helper, numpy_helper  # noqa: E402

from edgepick.onnx_graph import Graph, attr, attrs, copy_model  # noqa: E402


def _model():
    """x -> Relu (r) -> Mul by a Constant (m) -> Add by an initializer (y); Clip reads r too (c)."""
    nodes = [helper.make_node("Relu", ["x"], ["r"], name="relu"),
             helper.make_node("Constant", [], ["two"], name="const", value=numpy_helper.from_array(np.float32(2.0))),
             helper.make_node("Mul", ["r", "two"], ["m"], name="mul"),
             helper.make_node("Add", ["m", "bias"], ["y"], name="add"),
             helper.make_node("Clip", ["r"], ["c"], name="clip", min=0.0, max=6.0)]
    graph = helper.make_graph(nodes, "g", [helper.make_tensor_value_info("x", onnx.TensorProto.FLOAT, [1, 2])],
                              [helper.make_tensor_value_info("y", onnx.TensorProto.FLOAT, [1, 2]),
                               helper.make_tensor_value_info("c", onnx.TensorProto.FLOAT, [1, 2])],
                              [numpy_helper.from_array(np.array([1.0, -1.0], np.float32), "bias"),
                               numpy_helper.from_array(np.array([7.0], np.float32), "unused")])
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])


def test_links_attributes_and_values():
    g = Graph(_model())
    assert g.producer("m").name == "mul" and g.producer("x") is None and g.producer("bias") is None
    assert [n.name for n in g.consumers("r")] == ["mul", "clip"] and g.consumers("y") == []
    assert g.only_consumer("m").name == "add" and g.only_consumer("r") is None and g.only_consumer("y") is None
    assert g.only_consumer("m", "Mul") is None
    assert g.outputs == {"y", "c"} and g.inputs == ["x"]
    clip = g.node("clip")
    assert attr(clip, "max") == 6.0 and attr(clip, "missing", 3) == 3 and attrs(clip) == {"min": 0.0, "max": 6.0}
    assert g.scalar("two") == 2.0 and g.array("bias").tolist() == [1.0, -1.0] and g.array("r") is None
    assert g.is_constant("two") and g.is_constant("bias") and not g.is_constant("m")


def test_edits_keep_the_links_true():
    model = _model()
    g = Graph(model)
    mul = g.node("mul")
    g.replace(mul, [helper.make_node("Div", ["r", "two"], ["m"], name="div")])
    assert g.producer("m").name == "div" and [n.name for n in g.nodes] == ["relu", "const", "div", "add", "clip"]
    g.insert_after(g.node("relu"), [helper.make_node("Neg", ["r"], ["n"], name="neg")])
    assert g.producer("n").name == "neg" and g.index(g.node("neg")) == 1
    g.redirect("r", "x")
    assert [n.name for n in g.consumers("x")] == ["relu", "neg", "div", "clip"] and g.consumers("r") == []
    g.set_output(g.node("add"), "y", "y2")
    assert g.producer("y") is None and g.producer("y2").name == "add"
    g.set_array("bias", np.array([3.0, 4.0], np.float32))
    g.set_array("fresh", np.zeros(2, np.int64))
    assert g.array("bias").tolist() == [3.0, 4.0] and g.array("fresh").dtype == np.int64
    assert g.drop_unused_initializers() == 2 and not g.is_initializer("unused") and not g.is_initializer("fresh")
    g.remove(g.node("neg"))
    assert g.producer("n") is None and len(model.graph.node) == 5


def test_reordering_and_names():
    model = _model()
    g = Graph(model)
    g.set_nodes(list(reversed(g.nodes)))
    g.sort()
    assert [n.name for n in g.nodes] == ["const", "relu", "clip", "mul", "add"]  # each after what it reads
    g.insert_after_producers({"r": [helper.make_node("Abs", ["r"], ["a"])], "x": [helper.make_node("Abs", ["x"], ["b"])]})
    assert [n.op_type for n in g.nodes][1:3] == ["Relu", "Abs"] and g.nodes[-1].output[0] == "b"
    assert g.name_nodes() == 2 and len({n.name for n in g.nodes}) == len(g.nodes)
    copy = copy_model(model)
    other = Graph(copy)
    other.remove(other.nodes[0])
    assert len(copy.graph.node) == len(model.graph.node) - 1
