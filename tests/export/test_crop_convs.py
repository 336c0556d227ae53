"""crop_padded_convs: an int8 conv split into regions that skip padding-only taps gives the same
uint8 outputs in onnxruntime, and the exported int8 model uses it where ASPP's rates reach past the map."""

from __future__ import annotations

import json
from itertools import pairwise
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest
from onnx import TensorProto, helper, numpy_helper

from edgepick.export.crop_convs import CROP_TAG, axis_bands, crop_padded_convs
from edgepick.geometry import Size


@pytest.mark.parametrize("length,kernel,dilation,pad0,pad1", [
    (30, 3, 12, 12, 12), (30, 3, 24, 24, 24), (40, 3, 36, 36, 36), (16, 3, 12, 12, 12), (30, 5, 2, 4, 4),
    (7, 3, 1, 1, 1), (20, 3, 6, 6, 2), (12, 1, 1, 0, 0)])
def test_axis_bands_match_the_taps_each_output_reads(length, kernel, dilation, pad0, pad1):
    bands = axis_bands(length, kernel, dilation, pad0, pad1)
    n_out = length + pad0 + pad1 - dilation * (kernel - 1)
    assert bands[0].out0 == 0 and bands[-1].out1 == n_out
    assert all(a.out1 == b.out0 for a, b in pairwise(bands))
    for b in bands:
        for o in range(b.out0, b.out1):
            in_range = [t for t in range(kernel) if 0 <= o - pad0 + t * dilation < length]
            assert in_range == list(range(b.tap0, b.tap1 + 1))
        assert b.in0 == b.out0 - pad0 + b.tap0 * dilation and b.in1 == b.out1 - 1 - pad0 + b.tap1 * dilation + 1
        assert 0 <= b.in0 < b.in1 <= length


def qdq_conv_model(h: int, w: int, kernel: tuple[int, int], dilation: int, pads: list[int], relu: bool,
                   group: int = 1, seed: int = 0) -> onnx.ModelProto:
    """uint8 x -> DequantizeLinear -> Conv (int8 per-channel weight, int32 bias) [-> Relu] -> QuantizeLinear,
    plus a second output that reads the same dequantized input (it must survive the rewrite)."""
    rng = np.random.default_rng(seed)
    cin, cout = 16, 8 if group == 1 else 16
    weight = rng.integers(-63, 64, (cout, cin // group, *kernel), dtype=np.int8)  # 7-bit: no int16 saturation
    w_scale = rng.uniform(0.002, 0.01, cout).astype(np.float32)
    x_scale = np.float32(0.05)
    inits = [numpy_helper.from_array(weight, "w_q"), numpy_helper.from_array(w_scale, "w_scale"),
             numpy_helper.from_array(np.zeros(cout, np.int8), "w_zp"),
             numpy_helper.from_array(rng.integers(-2000, 2000, cout).astype(np.int32), "b_q"),
             numpy_helper.from_array((w_scale * x_scale).astype(np.float32), "b_scale"),
             numpy_helper.from_array(x_scale, "x_scale"), numpy_helper.from_array(np.uint8(128), "x_zp"),
             numpy_helper.from_array(np.float32(0.04), "y_scale"), numpy_helper.from_array(np.uint8(3), "y_zp")]
    nodes = [helper.make_node("DequantizeLinear", ["x", "x_scale", "x_zp"], ["xf"], name="dqx"),
             helper.make_node("DequantizeLinear", ["w_q", "w_scale", "w_zp"], ["wf"], name="dqw", axis=0),
             helper.make_node("DequantizeLinear", ["b_q", "b_scale"], ["bf"], name="dqb", axis=0),
             helper.make_node("Conv", ["xf", "wf", "bf"], ["y"], name="aspp", kernel_shape=list(kernel),
                              dilations=[dilation, dilation], pads=pads, group=group),
             helper.make_node("ReduceMean", ["xf"], ["pooled"], name="pool", keepdims=1)]
    if relu:
        nodes.append(helper.make_node("Relu", ["y"], ["yr"], name="relu"))
    nodes.append(helper.make_node("QuantizeLinear", ["yr" if relu else "y", "y_scale", "y_zp"], ["out"], name="q"))
    graph = helper.make_graph(nodes, "g", [helper.make_tensor_value_info("x", TensorProto.UINT8, [1, cin, h, w])],
                              [helper.make_tensor_value_info("out", TensorProto.UINT8, [None] * 4),
                               helper.make_tensor_value_info("pooled", TensorProto.FLOAT, [None] * 4)], inits)
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", 21)])


def run(model: onnx.ModelProto, x: np.ndarray) -> list[np.ndarray]:
    opts = ort.SessionOptions()
    opts.log_severity_level = 3
    return ort.InferenceSession(model.SerializeToString(), opts, providers=["CPUExecutionProvider"]).run(None, {"x": x})


@pytest.mark.parametrize("h,w,kernel,dilation,pads,relu,group", [
    (30, 40, (3, 3), 12, [12, 12, 12, 12], True, 1),   # ASPP rate 12 at 640x480
    (30, 40, (3, 3), 24, [24, 24, 24, 24], True, 1),   # rate 24
    (30, 40, (1, 3), 36, [0, 36, 0, 36], False, 1),    # rate 36, already trimmed to 1x3
    (10, 9, (3, 3), 4, [4, 2, 4, 6], False, 1),        # uneven pads
])
def test_cropped_int8_conv_gives_the_same_uint8_outputs(h, w, kernel, dilation, pads, relu, group):
    model = qdq_conv_model(h, w, kernel, dilation, pads, relu, group)
    x = np.random.default_rng(1).integers(0, 256, (1, 16, h, w), dtype=np.uint8)
    before = run(model, x)
    assert crop_padded_convs(model) == 1
    onnx.checker.check_model(model, full_check=True)
    convs = [n for n in model.graph.node if n.op_type == "Conv"]
    assert len(convs) > 1 and all(CROP_TAG in n.name for n in convs)
    after = run(model, x)
    assert before[0].shape == after[0].shape and np.array_equal(before[0], after[0])
    np.testing.assert_array_equal(before[1], after[1])
    assert len(np.unique(before[0])) > 20  # not a trivially constant output


def test_regions_come_after_inputs_made_between_conv_and_quantize():
    """A QuantizeLinear scale made by a Constant node after the conv: the regions must follow it."""
    model = qdq_conv_model(30, 40, (3, 3), 24, [24, 24, 24, 24], True)
    x = np.random.default_rng(2).integers(0, 256, (1, 16, 30, 40), dtype=np.uint8)
    before = run(model, x)
    scale = next(i for i in model.graph.initializer if i.name == "y_scale")
    model.graph.initializer.remove(scale)
    q_at = next(k for k, n in enumerate(model.graph.node) if n.op_type == "QuantizeLinear")
    model.graph.node.insert(q_at, helper.make_node("Constant", [], ["y_scale"], value=scale, name="scale"))
    assert crop_padded_convs(model) == 1
    onnx.checker.check_model(model, full_check=True)  # nodes in topological order
    assert np.array_equal(run(model, x)[0], before[0])


def test_convs_that_read_little_padding_depthwise_and_fp32_convs_are_left_alone():
    model = qdq_conv_model(30, 40, (3, 3), 1, [1, 1, 1, 1], True)  # 3x3, pad 1: ~12% of taps are padding
    assert crop_padded_convs(model) == 0
    assert crop_padded_convs(qdq_conv_model(12, 16, (5, 5), 2, [4, 4, 4, 4], True, group=16)) == 0
    fp32 = qdq_conv_model(30, 40, (3, 3), 24, [24, 24, 24, 24], True)
    for node in fp32.graph.node:  # the same conv with a float kernel: onnxruntime's fp32 conv skips padding itself
        if node.op_type == "Conv":
            node.input[1] = "w_f32"
    fp32.graph.initializer.append(numpy_helper.from_array(np.ones((8, 16, 3, 3), np.float32), "w_f32"))
    assert crop_padded_convs(fp32) == 0


@pytest.mark.slow
def test_int8_export_crops_aspp_and_keeps_labels(small_data: Path, tmp_path: Path):
    """At 256x192 the map is 16x12: ASPP's rate 12 reaches past it along the width only, so its
    1x3 kernel is split into three column bands. Every conv still counts as one int8 conv."""
    import torch

    from edgepick.export.checks import conv_weight_report
    from edgepick.models import ModelConfig, build_model
    from edgepick.quant.pt2e.images import agreement_images, folder_images
    from edgepick.quant.pt2e.passes import quantize_static
    from edgepick.train.checkpoint import Checkpoint

    classes = json.loads((small_data / "meta.json").read_text())["classes"]
    torch.manual_seed(0)
    cfg = ModelConfig(num_classes=len(classes), variant="edge")
    ckpt = tmp_path / "untrained.pt"
    Checkpoint(model_config=cfg, classes=tuple(classes), input_size=Size(256, 192), model=build_model(cfg).state_dict()).save(ckpt)
    result = quantize_static(ckpt, folder_images(small_data, "train", 4), tmp_path / "int8.onnx",
                             check_images=agreement_images(small_data), progress=False)
    names = [n.name for n in onnx.load(result.out).graph.node if n.op_type == "Conv"]
    assert sum(CROP_TAG in n for n in names) == 3
    report = conv_weight_report(result.out)
    assert report["convs"] == report["int8"] == result.int8_convs == len(names) - 2 and report["float"] == []
    assert result.agreement_vs_torch >= 0.995
