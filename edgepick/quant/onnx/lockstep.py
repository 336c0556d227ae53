"""Running an int8 QDQ graph (and its float model) the way static PTQ's measurements need it:
`runner` fetches any tensors of one input's run, `channel_means` each image's per-channel means
reduced in the graph, `position_sampler` feature maps' values at given positions taken in the
graph, and `segments` cut the graph after each wave of convs, so that bias correction and AdaRound
run every measured input together, segment by segment, correcting each wave's convs before the
segments after it run (each image passes through the model once). Graphs run with onnxruntime's
graph optimisations off, each Q/DQ pair computed as written.
"""

from __future__ import annotations

from collections.abc import Callable, Collection
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from edgepick.onnx_graph import Graph, copy_model


def runner(model: Any, outputs: list[str]) -> Callable[[np.ndarray, list[str]], list[np.ndarray]]:
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


def channel_means(model: Any, outputs: list[str]) -> Callable[[np.ndarray], list[np.ndarray]]:
    """A function running a copy of MODEL on one input tensor, returning per tensor of OUTPUTS its
    [images, channels] means: a ReduceMean in the graph, so that no whole feature map is held (a
    graph output lives until the run ends, fetched or not)."""
    import onnx

    copy = copy_model(model)
    g = Graph(copy)
    ranks = tensor_ranks(copy)
    del copy.graph.output[:]
    means: list[str] = []
    after: dict[str, list[Any]] = {}
    for name in outputs:
        node = mean_node(copy, g, name, ranks.get(name, 4))
        after.setdefault(name, []).append(node)
        copy.graph.output.append(onnx.ValueInfoProto(name=node.output[0]))
        means.append(node.output[0])
    g.insert_after_producers(after)
    session = reducing_session(copy)
    image = session.get_inputs()[0].name
    return lambda x: [m.astype(np.float64) for m in session.run(means, {image: x})]


def position_sampler(model: Any, outputs: list[str]) -> tuple[list[int | None], Callable[..., list[np.ndarray]]]:
    """Per tensor of OUTPUTS of MODEL ([N, C, H, W] maps), its H*W where shape inference knows it, and
    a function running a copy of MODEL on one input tensor and the positions to take per map (flat
    indices into H*W), returning each map's values there, [N, C, P]: a Gather in the graph, so that
    no whole map is held to the run's end, as a graph output would be. A map whose size is not
    known is returned whole, [N, C, H*W]."""
    import onnx

    copy = onnx.shape_inference.infer_shapes(copy_model(model))
    dims = {v.name: [d.dim_value if d.HasField("dim_value") else 0 for d in v.type.tensor_type.shape.dim]
            for v in [*copy.graph.value_info, *copy.graph.output]}
    sizes = [dims[n][2] * dims[n][3] if len(dims.get(n, [])) == 4 and dims[n][2] * dims[n][3] > 0 else None
             for n in outputs]
    g = Graph(copy)
    del copy.graph.output[:]
    flat = g.add_initializer("edgepick_flat_maps", [0, 0, -1], np.int64)
    after: dict[str, list[Any]] = {}
    fetched, takes = [], []
    for k, (name, size) in enumerate(zip(outputs, sizes, strict=True)):
        reshaped, out = f"{name}_flat", f"{name}_sampled"
        nodes = [onnx.helper.make_node("Reshape", [name, flat], [reshaped], name=f"{reshaped}_node")]
        if size is not None:
            takes.append(f"edgepick_positions_{k}")
            copy.graph.input.append(onnx.helper.make_tensor_value_info(takes[-1], onnx.TensorProto.INT64, [None]))
            nodes.append(onnx.helper.make_node("Gather", [reshaped, takes[-1]], [out], axis=2, name=f"{out}_node"))
        else:
            out = reshaped
        after.setdefault(name, []).extend(nodes)
        copy.graph.output.append(onnx.ValueInfoProto(name=out))
        fetched.append(out)
    g.insert_after_producers(after)
    session = reducing_session(copy)
    image = model.graph.input[0].name

    def run(x: np.ndarray, positions: list[np.ndarray | None]) -> list[np.ndarray]:
        feed = {image: x, **{t: p for t, p in zip(takes, (p for p in positions if p is not None), strict=True)}}
        return session.run(fetched, feed)

    return sizes, run


def reducing_session(model: Any) -> Any:
    """An onnxruntime session of MODEL, whose nodes that reduce a feature map (a mean, a Gather of some
    positions) stand right after the node making it: run in that order, with no arena and no graph
    optimisation, so that each map is reduced as soon as it is made and freed as early as without them."""
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_DISABLE_ALL
    opts.log_severity_level, opts.enable_cpu_mem_arena = 3, False
    opts.execution_order = ort.ExecutionOrder.PRIORITY_BASED
    return ort.InferenceSession(model.SerializeToString(), opts, providers=["CPUExecutionProvider"])


def tensor_ranks(model: Any) -> dict[str, int]:
    """The rank of each tensor MODEL's shape inference knows."""
    return {v.name: len(v.type.tensor_type.shape.dim) for v in [*model.graph.value_info, *model.graph.output,
                                                                 *model.graph.input]}


def mean_node(model: Any, g: Graph, name: str, rank: int) -> Any:
    """A ReduceMean node of MODEL (G its Graph, which takes its axes initializer) giving tensor NAME's
    (of RANK) per-image, per-channel means as NAME_channel_means, [images, channels]."""
    import onnx

    version = next((o.version for o in model.opset_import if o.domain in ("", "ai.onnx")), 13)
    axes, mean = list(range(2, rank)), f"{name}_channel_means"
    if version >= 18:
        g.add_initializer(f"{mean}_axes", axes, np.int64)
        return onnx.helper.make_node("ReduceMean", [name, f"{mean}_axes"], [mean], keepdims=0, name=f"{mean}_node")
    return onnx.helper.make_node("ReduceMean", [name], [mean], axes=axes, keepdims=0, name=f"{mean}_node")


@dataclass
class Segment:
    """Nodes of a graph that run once the convs of the waves before it are corrected: the convs of
    one wave and what their inputs need, with the constant nodes (weight DequantizeLinears) they read."""

    nodes: list
    wave: list[str]
    inputs: list[str] = field(default_factory=list)  # tensors made by earlier segments (or the graph input)
    outputs: list[str] = field(default_factory=list)  # its wave's conv outputs and the tensors later segments read
    last: list[str] = field(default_factory=list)  # tensors no segment after it reads


def segments(model: Any, convs: Collection[str]) -> list[Segment]:
    """MODEL cut after each wave of CONVS: a conv's wave is the most of CONVS on any path from the
    graph input to it, so the convs of a wave depend only on convs of earlier waves."""
    graph = model.graph
    constant = {i.name for i in graph.initializer}
    const_nodes: dict[str, Any] = {}  # constant tensor -> the node that makes it
    depth: dict[str, int] = {}  # tensor -> the most CONVS on a path that made it
    by_depth: dict[int, Segment] = {}
    for n in graph.node:  # ONNX nodes are in topological order
        if all(i in constant for i in n.input if i):
            constant.update(n.output)
            const_nodes.update(dict.fromkeys(n.output, n))
            continue
        d = max((depth.get(i, 0) for i in n.input if i and i not in constant), default=0)
        segment = by_depth.setdefault(d, Segment([], []))
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


def segment_session(model: Any, segment: Segment, examples: dict[str, np.ndarray]) -> Any:
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


def image_means(y: np.ndarray) -> np.ndarray:
    """[images, channels]: each image's per-channel mean of the batch Y."""
    return y.reshape(*y.shape[:2], -1).mean(axis=2, dtype=np.float64)


