"""benchmarks/quant_speed.per_op(by="conv"): profiler time grouped by kind of convolution."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
from quant_speed import per_op  # noqa: E402


def four_convs(path: Path) -> None:
    """image -> first conv (3 in) -> depthwise -> 1x1 -> dense 3x3, each with its own weight."""
    rng = np.random.default_rng(0)
    shapes = {"w_first": (8, 3, 3, 3), "w_dw": (8, 1, 3, 3), "w_pw": (16, 8, 1, 1), "w_dense": (4, 16, 3, 3)}
    inits = [numpy_helper.from_array(rng.standard_normal(s).astype(np.float32), n) for n, s in shapes.items()]
    nodes = [helper.make_node("Conv", ["image", "w_first"], ["a"], name="first", pads=[1, 1, 1, 1]),
             helper.make_node("Conv", ["a", "w_dw"], ["b"], name="dw", pads=[1, 1, 1, 1], group=8),
             helper.make_node("Conv", ["b", "w_pw"], ["c"], name="pw"),
             helper.make_node("Conv", ["c", "w_dense"], ["d"], name="dense", pads=[1, 1, 1, 1]),
             helper.make_node("Relu", ["d"], ["out"], name="relu")]
    graph = helper.make_graph(nodes, "g", [helper.make_tensor_value_info("image", TensorProto.FLOAT, [1, 3, 32, 32])],
                              [helper.make_tensor_value_info("out", TensorProto.FLOAT, [1, 4, 32, 32])], inits)
    onnx.save(helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)]), path)


def test_profiler_time_is_grouped_by_kind_of_conv(tmp_path):
    four_convs(tmp_path / "m.onnx")
    image = np.zeros((1, 3, 32, 32), np.float32)
    by_kind = per_op(str(tmp_path / "m.onnx"), image, threads=1, runs=2, prefix=str(tmp_path / "p"), by="conv")
    kinds = {k for k in by_kind if k != "other ops"}
    assert kinds == {"first (3 input channels)", "depthwise", "1x1", "dense kxk (ASPP, head; cropped taps included)"}
    assert all(ms > 0 for ms in by_kind.values())
