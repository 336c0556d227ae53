"""How a tensor of a QDQ graph goes float, for keep-float and the accuracy-aware mode.

A tensor is left float by taking the Q -> DQ pair off it: the ops that read it then read the
float values, and the op that writes it writes them float; onnxruntime runs both in float, and
OpenVINO the same. That is how a node is kept float too (`QuantConfig.keep_float`): its weights,
the tensors it reads and the tensors it writes, so that it computes what fp32 computes from what
the int8 graph gives it. (Leaving only its weights float, with its input still on the uint8
grid, can lower fidelity: the int8 graph's errors no longer meet the rounding they were measured
with.) A pair whose DQ reads with another scale than its Q wrote computes an op (MobileNetV3's
HardSigmoid, written by `export.int8_activations`): it goes float as that op in float ops.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from edgepick.export.onnx_io import CONV_OPS
from edgepick.onnx_graph import Graph


def quantized_activations(model: Any) -> list[str]:
    """The activations of the QDQ MODEL on the uint8 grid (what a QuantizeLinear reads, weights not),
    in graph order."""
    weights = {i.name for i in model.graph.initializer}
    return list(dict.fromkeys(n.input[0] for n in model.graph.node
                              if n.op_type == "QuantizeLinear" and n.input[0] not in weights))


REMOVABLE_OPS = ("Relu", "Clip")  # onnxruntime's QDQ writer drops them after a quantized op: the uint8 grid clamps


def float_tensors(model: Any, names: Sequence[str], float_model: Any, weights: bool = False) -> int:
    """Take the Q -> DQ pairs off the tensors NAMES of MODEL (in place): their readers get the float
    tensor (and, with WEIGHTS, their float weights once they read nothing on the uint8 grid). Where
    onnxruntime's writer dropped a Relu or Clip that wrote the tensor in FLOAT_MODEL (the uint8 grid
    clamped for it), the op is put back. Returns how many pairs went."""
    g, fg = Graph(model), Graph(float_model)
    outputs = g.outputs
    dropped = 0
    for name in names:
        made_by, writer = fg.producer(name), g.producer(name)
        restore = (made_by is not None and made_by.op_type in REMOVABLE_OPS and writer is not None
                   and writer.op_type != made_by.op_type)
        for q in [n for n in g.consumers(name) if n.op_type == "QuantizeLinear"]:
            dqs = [n for n in g.consumers(q.output[0]) if n.op_type == "DequantizeLinear"]
            if len(dqs) != len(g.consumers(q.output[0])) or any(dq.output[0] in outputs for dq in dqs):
                continue  # a reader takes the uint8 codes themselves, or a DQ is the graph's output: leave it
            maps = [_pair_map(g, q, dq) for dq in dqs]
            if any(m is None for m in maps):
                continue  # a pair whose map is not known (per-channel, not constant): leave it
            for dq, map_nodes in zip(dqs, maps):
                readers = g.consumers(dq.output[0])
                g.redirect(dq.output[0], map_nodes[-1].output[0] if map_nodes else name)
                if map_nodes:
                    g.insert_before(q, map_nodes)
                for reader in readers:
                    if weights and reader.op_type in WEIGHTED_OPS:
                        _float_weights(g, reader, fg)
                    if reader.op_type in ("Conv", "ConvTranspose"):
                        _float_bias(g, reader, fg)
                g.remove(dq)
            g.remove(q)
            dropped += 1
            if restore:
                assert made_by is not None and writer is not None
                restore_activation(g, made_by, writer, fg)
                restore = False
    return dropped


def _pair_map(g: Graph, q: Any, dq: Any) -> list[Any] | None:
    """The float ops that compute what the pair Q -> DQ computes, up to rounding: none when DQ reads
    with Q's scale and zero point (the pair only rounds and clamps to the grid); else the clamp to
    Q's grid, then DQ's scale over Q's and the shift between their zero points. A rewrite may write
    an op into such a pair (`export.int8_activations` writes HardSigmoid as an Add quantized with 6
    times the scale it is read with: the grid's clamp is the clip, the scales' ratio the division),
    and then taking the pair off would drop the op. None when a scale or zero point is no constant
    scalar."""
    from onnx import helper

    q_scale, dq_scale = g.scalar(q.input[1]), g.scalar(dq.input[1])
    q_zero = g.array(q.input[2]) if len(q.input) > 2 and q.input[2] else np.zeros((), np.uint8)
    dq_zero = g.array(dq.input[2]) if len(dq.input) > 2 and dq.input[2] else np.zeros((), np.uint8)
    if q_scale is None or dq_scale is None or q_zero is None or dq_zero is None or q_zero.size != 1 or dq_zero.size != 1:
        return None
    if q_scale == dq_scale and q_zero.item() == dq_zero.item():
        return []
    info = np.iinfo(q_zero.dtype)
    zq, zdq = int(q_zero.item()), int(dq_zero.item())
    tag = f"{dq.output[0]}_float_pair"
    low = g.add_initializer(f"{tag}_low", (info.min - zq) * q_scale, np.float32)
    high = g.add_initializer(f"{tag}_high", (info.max - zq) * q_scale, np.float32)
    ratio = g.add_initializer(f"{tag}_ratio", dq_scale / q_scale, np.float32)
    nodes = [helper.make_node("Clip", [q.input[0], low, high], [f"{tag}_clipped"], name=f"{tag}_clip"),
             helper.make_node("Mul", [f"{tag}_clipped", ratio], [f"{tag}_scaled"], name=f"{tag}_scale")]
    if zq != zdq:
        shift = g.add_initializer(f"{tag}_shift", dq_scale * (zq - zdq), np.float32)
        nodes.append(helper.make_node("Add", [f"{tag}_scaled", shift], [f"{tag}_shifted"], name=f"{tag}_shift"))
    return nodes


WEIGHTED_OPS = ("Conv", "ConvTranspose", "MatMul", "Gemm")  # ops whose int8 weights go float with their input


def _float_weights(g: Graph, node: Any, fg: Graph) -> None:
    """Give NODE its float weights back (FG: the float graph) once no input it reads is on the
    uint8 grid any more: it then computes in float from float values, and its int8 weights would
    only add their rounding to what it computes."""
    inputs = [(k, g.producer(name)) for k, name in enumerate(node.input) if name]
    dequantized = [(k, dq) for k, dq in inputs if dq is not None and dq.op_type == "DequantizeLinear"]
    if any(not g.is_initializer(dq.input[0]) for _, dq in dequantized):
        return  # an activation still read on the uint8 grid
    for k, dq in dequantized:
        name = dq.input[0].removesuffix("_quantized")
        weight = fg.initializer(name)
        if weight is None or name == dq.input[0]:
            continue
        if name == dq.output[0]:  # a bias: the DequantizeLinear writes it under its float name
            if len(g.consumers(name)) == 1:
                g.remove(dq)
                g.add_tensor(weight)
            continue
        if not g.is_initializer(name):
            g.add_tensor(weight)
        g.set_input(node, k, name)
        if not g.consumers(dq.output[0]):
            g.remove(dq)


def _float_bias(g: Graph, conv: Any, fg: Graph) -> None:
    """Give CONV its float bias back (FG: the float graph): onnxruntime quantizes a conv's bias to
    int32 on the input's scale times the weight's, which is coarse where the input had a wide range,
    and a float input no longer needs it."""
    if len(conv.input) < 3 or not conv.input[2]:
        return
    dq = g.producer(conv.input[2])
    bias = fg.initializer(conv.input[2])
    if dq is None or dq.op_type != "DequantizeLinear" or bias is None:
        return
    if not g.is_initializer(conv.input[2]):
        g.add_tensor(bias)
    if len(g.consumers(conv.input[2])) == 1:
        g.remove(dq)


def restore_activation(g: Graph, activation: Any, writer: Any, fg: Graph) -> None:
    """Put the float model's ACTIVATION (a Relu or Clip) back between WRITER and the tensor it wrote."""
    import onnx

    name = activation.output[0]
    before = f"{name}_before_{activation.op_type.lower()}"
    g.set_output(writer, name, before)
    node = onnx.NodeProto()
    node.CopyFrom(activation)
    node.input[0] = before
    for bound in [i for i in fg.graph.initializer if i.name in node.input[1:] and not g.is_initializer(i.name)]:
        g.add_tensor(bound)
    constants = {n.output[0]: n for n in fg.nodes if n.op_type == "Constant"}
    g.append([constants[i] for i in node.input[1:] if i in constants])
    g.append([node])
    g.sort()


def node_tensors(model: Any, nodes: Sequence[str]) -> list[str]:
    """The float tensors the nodes NODES of the QDQ MODEL read and write, as the float graph names
    them (a DequantizeLinear's output traced back to what its QuantizeLinear read)."""
    g = Graph(model)
    found: list[str] = []
    for node in (n for n in g.nodes if n.name in set(nodes)):
        for name in node.input:
            dq = g.producer(name)
            q = g.producer(dq.input[0]) if dq is not None and dq.op_type == "DequantizeLinear" else None
            if q is not None and q.op_type == "QuantizeLinear":
                found.append(q.input[0])
        found.extend(o for o in node.output if any(c.op_type == "QuantizeLinear" for c in g.consumers(o)))
    return list(dict.fromkeys(found))


def float_weight_convs(model: Any) -> list[str]:
    """The convs of the QDQ MODEL that read float weights (an initializer, not a DequantizeLinear)."""
    g = Graph(model)
    return [n.name for n in g.nodes if n.op_type in CONV_OPS and len(n.input) > 1 and g.is_initializer(n.input[1])]
