"""What static PTQ measures on the calibration images, for an int8 QDQ ONNX graph written by
onnxruntime's quantizer (quant/onnx/static.py), as quant/pt2e/ptq.py does it for a torch graph:

- first-7: each conv's uint8 input codes, from the int8 model run on sample inputs, are paired
  with its 8-bit weights as an AVX2 U8S8 kernel pairs them (quant/pt2e/overflow.py); the convs whose
  pair sums come near the int16 limit are requantized to 7-bit weights from the float weights,
  on the grid onnxruntime's own 7-bit weights use (-64..64, symmetric), their int32 biases with them;
- empirical bias correction (AIMET's form): each conv's int32 bias is shifted by the median over
  the images of the gap between the float model's and its own per-channel output mean (the median,
  so that one image whose activations are clipped hard does not set every image's bias, as in
  quant/pt2e/bias_correction.py). Convs are corrected in
  waves: a wave holds the convs whose inputs depend only on convs of earlier waves, which are
  already corrected, so what a conv compensates includes the errors from upstream, once. The graph
  is cut after each wave and the images run through it together, segment by segment (as the torch
  form runs its graph node by node), so each image passes through the model once.

Both edit initializers only (weight codes, weight scales, bias codes, bias scales): the graph,
and so the latency, stays as onnxruntime wrote it. Graphs are run with onnxruntime's graph
optimisations off, each Q/DQ pair computed as written.
"""

from __future__ import annotations

from collections.abc import Callable, Collection
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from edgepick.onnx_graph import Graph, attr, copy_model

SEVEN_BIT = 64  # onnxruntime's reduce-range int8 weight grid: -64..64, scale = max |w| / 64


@dataclass(frozen=True)
class QdqConv:
    """A Conv of a QDQ graph with uint8 input codes, int8 per-channel weights and an int32 bias,
    by the names of the tensors and initializers that make it up."""

    node: Any
    codes: str  # the uint8 tensor its input DequantizeLinear reads
    input_scale: str
    input_zero: str
    weight_codes: str
    weight_scale: str
    bias_codes: str | None
    bias_scale: str | None


def qdq_convs(model: Any) -> dict[str, QdqConv]:
    """The Convs of MODEL (QDQ) with a DequantizeLinear on their input and on their own, unshared
    int8 weights, by node name; the bias, when it is a DequantizeLinear of its own int32 codes."""
    from onnx import TensorProto

    g = Graph(model)

    def own_dq(name: str) -> Any | None:
        dq = g.producer(name)
        if dq is None or dq.op_type != "DequantizeLinear" or len(g.consumers(name)) != 1:
            return None
        return dq if g.is_initializer(dq.input[0]) and len(g.consumers(dq.input[0])) == 1 else None

    found = {}
    for n in g.nodes:
        if n.op_type != "Conv" or len(n.input) < 2:
            continue
        x, w = g.producer(n.input[0]), own_dq(n.input[1])
        codes = g.initializer(w.input[0]) if w is not None else None
        if x is None or x.op_type != "DequantizeLinear" or w is None or codes is None or \
                codes.data_type != TensorProto.INT8:
            continue
        b = own_dq(n.input[2]) if len(n.input) > 2 and n.input[2] else None
        found[n.name] = QdqConv(n, x.input[0], x.input[1], x.input[2], w.input[0], w.input[1],
                                b.input[0] if b is not None else None, b.input[1] if b is not None else None)
    return found


class Values:
    """A model's initializers as arrays, read and written back by name (`values[name]`)."""

    def __init__(self, model: Any):
        self.graph = Graph(model)

    def __getitem__(self, name: str) -> np.ndarray:
        value = self.graph.array(name)
        if value is None:
            raise KeyError(name)
        return value

    def __setitem__(self, name: str, value: np.ndarray) -> None:
        self.graph.set_array(name, value)


def _runner(model: Any, outputs: list[str]) -> Callable[[np.ndarray, list[str]], list[np.ndarray]]:
    """A function running a copy of MODEL on one input tensor, returning the tensors it names (any
    of OUTPUTS, made graph outputs); onnxruntime's graph optimisations off."""
    import onnx
    import onnxruntime as ort

    copy = copy_model(model)
    known = {o.name for o in copy.graph.output}
    copy.graph.output.extend(onnx.ValueInfoProto(name=name) for name in dict.fromkeys(outputs) if name not in known)
    opts = ort.SessionOptions()
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_DISABLE_ALL
    opts.log_severity_level = 3
    session = ort.InferenceSession(copy.SerializeToString(), opts, providers=["CPUExecutionProvider"])
    image = session.get_inputs()[0].name

    def run(x: np.ndarray, names: list[str]) -> list[np.ndarray]:
        return session.run(names, {image: x})

    return run


def _channel_means(model: Any, outputs: list[str]) -> Callable[[np.ndarray], list[np.ndarray]]:
    """A function running a copy of MODEL on one input tensor, returning per tensor of OUTPUTS its
    [images, channels] means: a ReduceMean in the graph, so that no whole feature map is held (a
    graph output lives until the run ends, fetched or not)."""
    import onnx
    import onnxruntime as ort

    copy = copy_model(model)
    g = Graph(copy)
    ranks = {v.name: len(v.type.tensor_type.shape.dim) for v in [*copy.graph.value_info, *copy.graph.output]}
    version = next((o.version for o in copy.opset_import if o.domain in ("", "ai.onnx")), 13)
    del copy.graph.output[:]
    means: list[str] = []
    after: dict[str, list[Any]] = {}
    for k, name in enumerate(outputs):
        axes = list(range(2, ranks.get(name, 4)))
        mean = f"{name}_channel_means"
        if version >= 18:
            g.add_initializer(f"{mean}_axes", axes, np.int64)
            node = onnx.helper.make_node("ReduceMean", [name, f"{mean}_axes"], [mean], keepdims=0, name=f"mean_{k}")
        else:
            node = onnx.helper.make_node("ReduceMean", [name], [mean], axes=axes, keepdims=0, name=f"mean_{k}")
        after.setdefault(name, []).append(node)
        copy.graph.output.append(onnx.ValueInfoProto(name=mean))
        means.append(mean)
    g.insert_after_producers(after)
    opts = ort.SessionOptions()
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_DISABLE_ALL
    opts.log_severity_level, opts.enable_cpu_mem_arena = 3, False
    opts.execution_order = ort.ExecutionOrder.PRIORITY_BASED  # each mean as soon as its map is made
    session = ort.InferenceSession(copy.SerializeToString(), opts, providers=["CPUExecutionProvider"])
    image = session.get_inputs()[0].name
    return lambda x: [m.astype(np.float64) for m in session.run(means, {image: x})]


def saturating_onnx_convs(model: Any, tensors: list[np.ndarray], limit: float) -> dict[str, float]:
    """For each conv of MODEL (QDQ, 8-bit weights), the largest share of its outputs over TENSORS
    that an AVX2 U8S8 kernel would compute with a pair sum beyond +-LIMIT."""
    import torch

    from edgepick.quant.pt2e.overflow import saturated_share

    convs = qdq_convs(model)
    values = Values(model)
    names = sorted({c.codes for c in convs.values()})
    run = _runner(model, names)
    share = dict.fromkeys(convs, 0.0)
    for x in tensors:
        codes = dict(zip(names, run(x, names), strict=True))
        for name, c in convs.items():
            if codes[c.codes].dtype != np.uint8 or attr(c.node, "auto_pad", b"NOTSET") not in (b"NOTSET", "NOTSET"):
                share[name] = 1.0 if codes[c.codes].dtype == np.uint8 else 0.0  # unknown padding: count it as saturating
                continue
            top, left, bottom, right = attr(c.node, "pads", [0, 0, 0, 0])
            zero = int(values[c.input_zero])
            padded = torch.nn.functional.pad(torch.from_numpy(codes[c.codes]).float(), (left, right, top, bottom),
                                             value=float(zero))
            s = saturated_share(padded, torch.tensor(values[c.weight_codes]), zero,
                                tuple(attr(c.node, "strides", [1, 1])), (0, 0),
                                tuple(attr(c.node, "dilations", [1, 1])), int(attr(c.node, "group", 1)), limit)
            share[name] = max(share[name], s)
    return share


def to_seven_bit_onnx(float_model: Any, model: Any, names: list[str]) -> None:
    """Requantize the weights of the convs NAMES of MODEL (QDQ) to 7 bits from the float weights
    and biases of the same convs in FLOAT_MODEL (the graph that was quantized), in place."""
    convs, values, floats = qdq_convs(model), Values(model), Values(float_model)
    by_name = {n.name: n for n in float_model.graph.node}
    for name in names:
        c, source = convs[name], by_name[name]
        w = floats[source.input[1]].astype(np.float64)
        absmax = np.abs(w).reshape(w.shape[0], -1).max(axis=1)
        scale = np.where(absmax > 0, absmax / SEVEN_BIT, 1.0).astype(np.float32)
        shape = (-1, *[1] * (w.ndim - 1))
        values[c.weight_codes] = np.clip(np.round(w / scale.reshape(shape)), -SEVEN_BIT, SEVEN_BIT).astype(np.int8)
        values[c.weight_scale] = scale
        if c.bias_codes is not None and c.bias_scale is not None:
            bias_scale = (values[c.input_scale].astype(np.float64) * scale).astype(np.float32)
            b = floats[source.input[2]].astype(np.float64)
            values[c.bias_codes] = np.clip(np.round(b / bias_scale), -2 ** 31, 2 ** 31 - 1).astype(np.int32)
            values[c.bias_scale] = bias_scale


@dataclass
class _Segment:
    """Nodes of a graph that run once the convs of the waves before it are corrected: the convs of
    one wave and what their inputs need, with the constant nodes (weight DequantizeLinears) they read."""

    nodes: list
    wave: list[str]
    inputs: list[str] = field(default_factory=list)  # tensors made by earlier segments (or the graph input)
    outputs: list[str] = field(default_factory=list)  # its wave's conv outputs and the tensors later segments read
    last: list[str] = field(default_factory=list)  # tensors no segment after it reads


def _segments(model: Any, convs: Collection[str]) -> list[_Segment]:
    """MODEL cut after each wave of CONVS: a conv's wave is the most of CONVS on any path from the
    graph input to it, so the convs of a wave depend only on convs of earlier waves."""
    graph = model.graph
    constant = {i.name for i in graph.initializer}
    const_nodes: dict[str, Any] = {}  # constant tensor -> the node that makes it
    depth: dict[str, int] = {}  # tensor -> the most CONVS on a path that made it
    by_depth: dict[int, _Segment] = {}
    for n in graph.node:  # ONNX nodes are in topological order
        if all(i in constant for i in n.input if i):
            constant.update(n.output)
            const_nodes.update(dict.fromkeys(n.output, n))
            continue
        d = max((depth.get(i, 0) for i in n.input if i and i not in constant), default=0)
        segment = by_depth.setdefault(d, _Segment([], []))
        segment.nodes.append(n)
        if n.name in convs:
            segment.wave.append(n.name)
        for o in n.output:
            depth[o] = d + 1 if n.name in convs else d
    last_use: dict[str, int] = {}
    for d, segment in by_depth.items():
        for n in segment.nodes:
            for i in n.input:
                if i and i not in constant:
                    last_use[i] = max(last_use.get(i, 0), d)
    segments = [by_depth[d] for d in sorted(by_depth)]
    order = {id(n): k for k, n in enumerate(graph.node)}
    for d, segment in zip(sorted(by_depth), segments, strict=True):
        made = {o for n in segment.nodes for o in n.output}
        segment.inputs = list(dict.fromkeys(i for n in segment.nodes for i in n.input
                                            if i and i not in constant and i not in made))
        segment.outputs = [o for n in segment.nodes for o in n.output
                           if last_use.get(o, -1) > d or (n.name in segment.wave and o == n.output[0])]
        segment.last = [i for i in segment.inputs if last_use[i] == d]
        needed: list[Any] = []
        todo = [i for n in segment.nodes for i in n.input if i in const_nodes]
        while todo:  # the constant nodes this segment reads, in graph order
            node = const_nodes[todo.pop()]
            if all(node is not m for m in needed):
                needed.append(node)
                todo.extend(i for i in node.input if i in const_nodes)
        segment.nodes = sorted([*needed, *segment.nodes], key=lambda n: order[id(n)])
    return segments


def _segment_session(model: Any, segment: _Segment, examples: dict[str, np.ndarray]) -> Any:
    """An onnxruntime session of SEGMENT of MODEL, its inputs typed as EXAMPLES (their arrays)."""
    import onnx
    import onnxruntime as ort

    used = {i for n in segment.nodes for i in n.input}
    graph = onnx.helper.make_graph(
        segment.nodes, "segment",
        [onnx.helper.make_tensor_value_info(name, onnx.helper.np_dtype_to_tensor_dtype(examples[name].dtype),
                                            list(examples[name].shape)) for name in segment.inputs],
        [onnx.ValueInfoProto(name=name) for name in segment.outputs],
        [i for i in model.graph.initializer if i.name in used])
    part = onnx.helper.make_model(graph, opset_imports=model.opset_import, ir_version=model.ir_version)
    opts = ort.SessionOptions()
    opts.log_severity_level, opts.enable_cpu_mem_arena = 3, False  # one segment after another: none keeps its peak
    return ort.InferenceSession(part.SerializeToString(), opts, providers=["CPUExecutionProvider"])


def _image_means(y: np.ndarray) -> np.ndarray:
    """[images, channels]: each image's per-channel mean of the batch Y."""
    return y.reshape(*y.shape[:2], -1).mean(axis=2, dtype=np.float64)


def correct_onnx_biases(float_model: Any, model: Any, tensors: list[np.ndarray], skip: set[str]) -> int:
    """Empirical bias correction of MODEL (QDQ) in place, against the same convs of FLOAT_MODEL on
    TENSORS (model inputs): MODEL runs on all TENSORS together, segment by segment (`_segments`),
    and each wave's convs are corrected before the segments after it run. Convs named in SKIP are
    left alone. Returns how many convs were corrected."""
    by_name = {n.name: n for n in float_model.graph.node}
    convs = {name: c for name, c in qdq_convs(model).items() if name not in skip and name in by_name}
    bias = {name: (c.bias_codes, c.bias_scale) for name, c in convs.items()
            if c.bias_codes is not None and c.bias_scale is not None}
    if not bias:
        return 0
    names = list(bias)
    fp32 = _channel_means(float_model, [by_name[name].output[0] for name in names])
    rows: dict[str, list[np.ndarray]] = {name: [] for name in names}
    for x in tensors:
        for name, means in zip(names, fp32(x), strict=True):
            rows[name].append(means)
    target = {name: np.concatenate(r) for name, r in rows.items()}
    values = Values(model)
    image = model.graph.input[0].name
    env = [{image: x} for x in tensors]  # per tensor, what later segments read
    for segment in _segments(model, bias):
        if not segment.outputs:  # after the last wave: nothing left to correct
            break
        session = _segment_session(model, segment, env[0])
        for e in env:
            e.update(zip(segment.outputs, session.run(segment.outputs, {i: e[i] for i in segment.inputs}), strict=True))
            for name in segment.last:
                del e[name]
        for name in segment.wave:
            codes_name, scale_name = bias[name]
            out, scale = convs[name].node.output[0], values[scale_name].astype(np.float64)
            got = np.concatenate([_image_means(e[out]) for e in env])
            delta = np.median(target[name] - got, axis=0)
            codes = values[codes_name]
            moved = np.clip(np.round(codes + (delta / scale).reshape(codes.shape)), -2 ** 31, 2 ** 31 - 1)
            values[codes_name] = moved.astype(np.int32)
            step = ((moved - codes) * scale).astype(np.float32).reshape(1, -1, *[1] * (env[0][out].ndim - 2))
            for e in env:  # the conv's output as the corrected bias gives it, for the segments after
                e[out] = e[out] + step
    return len(bias)
