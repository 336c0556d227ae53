"""Small float ONNX models made in the tests, standing in for models from other exporters."""

from __future__ import annotations

import warnings
from collections import Counter
from pathlib import Path

import numpy as np


def torch_net(out_channels: int = 3, two_outputs: bool = False, sigmoid: bool = False):
    """A small segmentation net with what foreign models bring: BatchNorm, hardswish spelt out as
    x * clip(x + 3, 0, 6) / 6, a squeeze-excitation block (mean pooling, hardsigmoid), a depthwise
    conv, a learnable-affine scale and shift, ConvTranspose, Concat and a bilinear Resize."""
    import torch
    from torch import nn

    class SE(nn.Module):
        def __init__(self, c: int):
            super().__init__()
            self.fc1, self.fc2 = nn.Conv2d(c, c // 2, 1), nn.Conv2d(c // 2, c, 1)

        def forward(self, x):
            pooled = x.mean((2, 3), keepdim=True)
            return x * nn.functional.hardsigmoid(self.fc2(torch.relu(self.fc1(pooled))))

    class Net(nn.Module):
        def __init__(self):
            super().__init__()
            self.c1, self.b1 = nn.Conv2d(3, 8, 3, 2, 1), nn.BatchNorm2d(8)
            self.dw, self.b2 = nn.Conv2d(8, 8, 3, 1, 1, groups=8), nn.BatchNorm2d(8)
            self.se = SE(8)
            self.scale, self.shift = nn.Parameter(torch.tensor([1.3])), nn.Parameter(torch.tensor([0.2]))
            self.pw = nn.Conv2d(8, 16, 1)
            self.c2 = nn.Conv2d(16, 16, 3, 2, 1)
            self.up = nn.ConvTranspose2d(16, 8, 2, 2)
            self.head = nn.Conv2d(16, out_channels, 1)
            self.aux = nn.Conv2d(16, 2, 1)

        def forward(self, x):
            y = self.b1(self.c1(x))
            y = y * torch.clamp(y + 3, 0, 6) / 6  # hardswish as older exporters write it
            y = self.se(torch.relu(self.b2(self.dw(y))))
            y = self.pw(y * self.scale + self.shift)
            z = torch.cat([self.up(torch.relu(self.c2(y))), y[:, :8]], 1)
            logits = nn.functional.interpolate(self.head(torch.cat([z, z], 1)[:, :16]), scale_factor=2,
                                               mode="bilinear", align_corners=False)
            if sigmoid:
                logits = torch.sigmoid(logits)
            return (logits, self.aux(z)) if two_outputs else logits

    torch.manual_seed(0)
    net = Net().eval()
    for bn in (net.b1, net.b2):
        bn.running_mean.uniform_(-0.5, 0.5)
        bn.running_var.uniform_(0.5, 2.0)
        bn.weight.data.uniform_(0.5, 1.5)
    return net


def export_torch(path: Path, opset: int = 12, **kwargs) -> Path:
    """torch_net(**kwargs) through torch's TorchScript exporter at OPSET, batch, height and width
    dynamic, BatchNorm left unfolded (as exported for training frameworks)."""
    import torch

    net = torch_net(**kwargs)
    outputs = ["logits", "aux"] if kwargs.get("two_outputs") else ["logits"]
    dynamic = {"input": {0: "n", 2: "h", 3: "w"}, **{o: {0: "n", 2: "h", 3: "w"} for o in outputs}}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(net, torch.rand(1, 3, 64, 96), str(path), opset_version=opset, dynamo=False,
                          input_names=["input"], output_names=outputs, dynamic_axes=dynamic,
                          do_constant_folding=False, training=torch.onnx.TrainingMode.PRESERVE)
    return path


def export_module(net, path: Path, shape=(1, 3, 24, 32)) -> Path:
    """A torch module made in a test, exported at opset 13 with fixed dims (input `input`, output `logits`)."""
    import torch

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(net.eval(), torch.rand(*shape) * 255, str(path), opset_version=13, dynamo=False,
                          input_names=["input"], output_names=["logits"])
    return path


def image_tensors(count: int, shape=(1, 3, 24, 32), low: int = 0) -> list[np.ndarray]:
    """Random float images in LOW..255, NCHW."""
    rng = np.random.default_rng(0)
    return [rng.integers(low, 256, shape).astype(np.float32) for _ in range(count)]


def calib_tensors(count: int, shape=(1, 3, 64, 96), seed: int = 0) -> list[np.ndarray]:
    """Smooth random inputs in the net's [0, 1] range (blurred noise: neighbouring pixels alike, as in images)."""
    import cv2

    rng = np.random.default_rng(seed)
    out = []
    for _ in range(count):
        x = rng.random(shape, dtype=np.float32)
        x[0] = np.stack([cv2.GaussianBlur(c, (0, 0), 3) for c in x[0]])
        out.append(np.ascontiguousarray(x))
    return out


def run(path: Path, x: np.ndarray) -> list[np.ndarray]:
    """onnxruntime's outputs of the model at PATH for X (graph optimisations off: the file as it is)."""
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_DISABLE_ALL
    opts.log_severity_level = 3
    session = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
    return session.run(None, {session.get_inputs()[0].name: x})


def optimized_ops(path: Path) -> Counter:
    """The op types onnxruntime runs for the file after its graph optimisations (QDQ fused into QLinear*)."""
    import onnx
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_EXTENDED
    opts.optimized_model_filepath = str(path.with_suffix(".opt.onnx"))
    opts.log_severity_level = 3
    ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
    return Counter(n.op_type for n in onnx.load(opts.optimized_model_filepath).graph.node)


def helper_model(nodes: list, inputs: list, outputs: list, initializers: dict[str, np.ndarray], path: Path,
                 opset: int = 13):
    """An ONNX model of NODES written with onnx.helper (no exporter): the graph's INPUTS and OUTPUTS
    as (name, shape) pairs, float32; INITIALIZERS by name. Saved to PATH, which is returned."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    graph = helper.make_graph(nodes, "test",
                              [helper.make_tensor_value_info(n, TensorProto.FLOAT, s) for n, s in inputs],
                              [helper.make_tensor_value_info(n, TensorProto.FLOAT, s) for n, s in outputs],
                              [numpy_helper.from_array(v.astype(np.float32) if v.dtype.kind == "f" else v, k)
                               for k, v in initializers.items()])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", opset)])
    model.ir_version = 8
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return path


def conv_relu_model(path: Path, shape=(1, 2, 32, 32)) -> tuple[Path, np.ndarray, np.ndarray]:
    """input -> 1x1 Conv (3 channels) -> conv_out -> Relu -> output: a model whose activations a test
    computes with numpy. Returns the path and the conv's weights and bias."""
    from onnx import helper

    rng = np.random.default_rng(1)
    w = rng.normal(0, 1, (3, shape[1], 1, 1)).astype(np.float32)
    b = rng.normal(0, 0.1, 3).astype(np.float32)
    nodes = [helper.make_node("Conv", ["input", "w", "b"], ["conv_out"], name="conv"),
             helper.make_node("Relu", ["conv_out"], ["output"], name="relu")]
    out_shape = [shape[0], 3, *shape[2:]]
    return helper_model(nodes, [("input", list(shape))], [("output", out_shape)], {"w": w, "b": b}, path), w, b


def detector_head_model(path: Path, size: int = 64) -> Path:
    """A detector's head as exporters write one: two 1x1 convs over a feature map, box values and an
    objectness logit, the logit through a Sigmoid, both concatenated, reshaped to [1, boxes, 5] rows.
    The objectness logit is 50 * (sum of the 3 channels) - 145: on inputs in [0, 1], a score near 0
    but where all three channels are near 1 (a box in 10^5 or fewer), up to 0.993 where they are 1."""
    from onnx import helper

    rng = np.random.default_rng(2)
    box_w = rng.normal(0, 1, (4, 3, 1, 1)).astype(np.float32)
    obj_w = np.full((1, 3, 1, 1), 50.0, np.float32)
    nodes = [helper.make_node("Conv", ["input", "box_w"], ["box"], name="box_conv"),
             helper.make_node("Conv", ["input", "obj_w", "obj_b"], ["obj_logit"], name="obj_conv"),
             helper.make_node("Sigmoid", ["obj_logit"], ["obj"], name="obj_sigmoid"),
             helper.make_node("Concat", ["box", "obj"], ["rows_nchw"], axis=1, name="concat"),
             helper.make_node("Reshape", ["rows_nchw", "rows_shape"], ["rows_t"], name="reshape"),
             helper.make_node("Transpose", ["rows_t"], ["rows"], perm=[0, 2, 1], name="transpose")]
    inits = {"box_w": box_w, "obj_w": obj_w, "obj_b": np.array([-145.0], np.float32),
             "rows_shape": np.array([1, 5, -1], np.int64)}
    return helper_model(nodes, [("input", [1, 3, size, size])], [("rows", [1, size * size, 5])], inits, path)


def box_table_model(path: Path, size: int = 32) -> Path:
    """A YOLOv8-style head on inputs in [0, 1]: per pixel a box (cx = 300 c0, cy = 300 c1, w = 30 +
    40 c2, h = 30 + 40 c0, in pixels) and two class scores through a Sigmoid (class 0 where the three
    channels sum past 2.5, class 1 where c2 - c1 passes 0.67), concatenated and reshaped to a
    [1, 6, boxes] table: a few dozen boxes above 0.25 on a random input."""
    from onnx import helper

    box_w = np.zeros((4, 3, 1, 1), np.float32)
    box_w[0, 0], box_w[1, 1], box_w[2, 2], box_w[3, 0] = 300.0, 300.0, 40.0, 40.0
    score_w = np.array([[1, 1, 1], [0, -1, 1]], np.float32).reshape(2, 3, 1, 1) * 30.0
    nodes = [helper.make_node("Conv", ["input", "box_w", "box_b"], ["box"], name="box_conv"),
             helper.make_node("Conv", ["input", "score_w", "score_b"], ["logit"], name="score_conv"),
             helper.make_node("Sigmoid", ["logit"], ["score"], name="score_sigmoid"),
             helper.make_node("Concat", ["box", "score"], ["table_nchw"], axis=1, name="concat"),
             helper.make_node("Reshape", ["table_nchw", "table_shape"], ["table"], name="reshape")]
    inits = {"box_w": box_w, "box_b": np.array([0, 0, 30, 30], np.float32), "score_w": score_w,
             "score_b": np.array([-75.0, -20.0], np.float32), "table_shape": np.array([1, 6, -1], np.int64)}
    return helper_model(nodes, [("input", [1, 3, size, size])], [("table", [1, 6, size * size])], inits, path)


def unused_initializers(path: Path) -> list[str]:
    """The initializers of the ONNX file at PATH that no node reads (onnxruntime warns of each on every load)."""
    import onnx

    model = onnx.load(str(path))
    read = {name for node in model.graph.node for name in node.input}
    return [i.name for i in model.graph.initializer if i.name not in read]


def faint_channel_model(path: Path) -> Path:
    """input (3 channels) -> 1x1 Conv -> Relu -> 1x1 Conv -> output, where the first conv reads input
    channel 2 alone, with a gain of 400: with inputs whose channel 2 spans 0.01 while the others span
    0-100, that channel's whole range is under one uint8 step of the input tensor, and it decides
    the output."""
    from onnx import helper

    w1 = np.zeros((4, 3, 1, 1), np.float32)
    w1[:, 2, 0, 0] = 400.0
    b1 = np.array([-200.0, -201.0, -199.0, -200.5], np.float32)
    w2 = np.random.default_rng(5).normal(0, 1, (2, 4, 1, 1)).astype(np.float32)
    nodes = [helper.make_node("Conv", ["input", "w1", "b1"], ["hidden"], name="conv"),
             helper.make_node("Relu", ["hidden"], ["relu"], name="relu"),
             helper.make_node("Conv", ["relu", "w2"], ["output"], name="head")]
    return helper_model(nodes, [("input", [1, 3, 16, 16])], [("output", [1, 2, 16, 16])],
                        {"w1": w1, "b1": b1, "w2": w2}, path)


def _uniform_inputs(count: int, seed: int, channels: int, span: float, odd: int, odd_span: tuple[float, float]
                    ) -> list[np.ndarray]:
    """COUNT 16x16 inputs of CHANNELS channels uniform over 0-SPAN, channel ODD over ODD_SPAN instead."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(count):
        x = rng.uniform(0, span, (1, channels, 16, 16)).astype(np.float32)
        x[0, odd] = rng.uniform(*odd_span, (16, 16))
        out.append(x)
    return out


def faint_channel_inputs(count: int, seed: int = 0) -> list[np.ndarray]:
    """Inputs for faint_channel_model: channels 0 and 1 over 0-100, channel 2 over 0.495-0.505."""
    return _uniform_inputs(count, seed, 3, 100.0, 2, (0.495, 0.505))


def half_step_model(path: Path) -> Path:
    """input (16 channels) -> 1x1 Conv -> output, each output channel one weight of 1.0 (on input
    channel 0) and fifteen of 0.55 int8 steps of it: nearest rounding takes every small weight to
    one step (or, on a coarser grid, to none), so the output that those channels carry moves by a
    half or more of itself, where rounding some down and some up (AdaRound) keeps it close."""
    from onnx import helper

    w = np.full((4, 16, 1, 1), 0.55 / 127.0, np.float32)
    w[:, 0, 0, 0] = 1.0
    nodes = [helper.make_node("Conv", ["input", "w"], ["output"], name="conv")]
    return helper_model(nodes, [("input", [1, 16, 16, 16])], [("output", [1, 4, 16, 16])], {"w": w}, path)


def half_step_inputs(count: int, seed: int = 0) -> list[np.ndarray]:
    """Inputs for half_step_model: channel 0 near zero, the others over 0-1."""
    return _uniform_inputs(count, seed, 16, 1.0, 0, (0.0, 0.01))


def strided_projection_model(path: Path) -> Path:
    """A ResNet stage's first block made small: a residual sum read by two 1x1 convs with stride 2
    (the projection and the next conv), then a 3x3 head; input (1, 3, 64, 96), in [0, 1]."""
    import torch

    class Block(torch.nn.Module):
        def __init__(self):
            super().__init__()
            self.stem = torch.nn.Conv2d(3, 16, 3, padding=1)
            self.a, self.b = torch.nn.Conv2d(16, 16, 3, padding=1), torch.nn.Conv2d(16, 16, 3, padding=1)
            self.proj, self.down = torch.nn.Conv2d(16, 32, 1, stride=2), torch.nn.Conv2d(16, 32, 1, stride=2)
            self.head = torch.nn.Conv2d(32, 4, 3, padding=1, stride=2)

        def forward(self, x):
            x = torch.relu(self.stem(x))
            x = torch.relu(x + self.b(torch.relu(self.a(x))))
            return self.head(torch.relu(self.proj(x) + self.down(x)))

    torch.manual_seed(0)
    return export_module(Block(), path, shape=(1, 3, 64, 96))
