"""ONNX pass: give onnxruntime integer kernels for the activations it would run in float.

In a QDQ graph onnxruntime fuses DequantizeLinear -> Conv/Add/Mul/GlobalAveragePool ->
QuantizeLinear into QLinear* kernels, but HardSigmoid and ReduceMean have no such fusion:
each dequantizes its input map, runs in float (NCHW, so with transposes around the NHWC int8
convs) and quantizes again. This pass rewrites them, in place, into ops that do fuse:

- HardSigmoid(x) = clip(x + 3, 0, 6) / 6 becomes an Add of the constant 3, quantized with the
  output's scale times 6: the same uint8 values up to rounding, and saturation does the clip
  (the output range starts at 0 and ends at or below 1). QLinearAdd. With hardswish quantized
  as x * hardsigmoid(x) (quant.rewrites.GatedHardswish) this covers MobileNetV3's hardswish too.
- ReduceMean over H and W (SE blocks, ASPP image pooling; the exporter may add a Reshape and
  an identity Gather after it) becomes GlobalAveragePool. QLinearGlobalAveragePool.

benchmarks/quant_speed.py times the default model with and without this pass and the gate.
Nodes it adds are named `<node>_int8act_*`; it only touches uint8 QDQ groups, so fp32 graphs
are left as they are.
"""

from __future__ import annotations

import numpy as np

from edgepick.onnx_graph import Graph, attrs

TAG = "_int8act"


def integer_activations(model) -> dict[str, int]:
    """Rewrite MODEL (onnx ModelProto) as described above; returns how many nodes of each kind."""
    import onnx

    ranks = {v.name: len(v.type.tensor_type.shape.dim)
             for v in onnx.shape_inference.infer_shapes(model).graph.value_info}
    g = Graph(model)
    done = {"HardSigmoid": 0, "ReduceMean": 0}
    for node in [n for n in g.nodes if n.op_type in done]:
        dq = g.producer(node.input[0])
        if dq is None or dq.op_type != "DequantizeLinear":
            continue
        chain = _chain_to_quantize(g, node)
        if chain is None:
            continue
        q = chain[-1]
        y_scale, y_zero = _qparams(g, q)
        if _qparams(g, dq)[0] is None or y_scale is None or y_zero is None:
            continue
        if node.op_type == "ReduceMean":
            new = _global_pool(g, node, chain) if ranks.get(node.input[0]) == 4 else None
        else:
            new = _hardsigmoid(g, node, q, y_scale, y_zero)
        if new is None:
            continue
        g.replace([node, *chain], new, at=q)
        done[node.op_type] += 1
    return done


def _chain_to_quantize(g: Graph, node) -> list | None:
    """The nodes from NODE's output to the QuantizeLinear that takes it, each the only consumer
    of the one before: just the Q, or (after ReduceMean) order-keeping Reshape/Gather then Q."""
    chain, out = [], node.output[0]
    while True:
        nxt = g.only_consumer(out)
        if nxt is None:
            return None
        chain.append(nxt)
        if nxt.op_type == "QuantizeLinear":
            return chain
        if node.op_type != "ReduceMean" or nxt.op_type not in ("Reshape", "Gather") or len(chain) > 3:
            return None
        if nxt.op_type == "Gather":
            idx = g.array(nxt.input[1])
            if idx is None or not np.array_equal(idx.ravel(), np.arange(idx.size)):
                return None
        out = nxt.output[0]


def _qparams(g: Graph, node) -> tuple[float | None, int | None]:
    """Per-tensor uint8 scale and zero point of a Q/DQ node, or (None, None)."""
    scale = g.array(node.input[1])
    zero = g.array(node.input[2]) if len(node.input) > 2 else None
    if scale is None or zero is None or scale.size != 1 or zero.size != 1 or zero.dtype != np.uint8:
        return None, None
    return float(scale.ravel()[0]), int(zero.ravel()[0])


def _dq_constant(g: Graph, tag: str, value: float) -> tuple[list, str]:
    """A DequantizeLinear that gives VALUE (> 0) from a uint8 initializer (255 steps of VALUE / 255)."""
    from onnx import helper
    q = g.add_initializer(f"{tag}_q", 255, np.uint8)
    s = g.add_initializer(f"{tag}_scale", value / 255.0, np.float32)
    z = g.add_initializer(f"{tag}_zero", 0, np.uint8)
    return [helper.make_node("DequantizeLinear", [q, s, z], [tag], name=f"{tag}_dq")], tag


def _hardsigmoid(g: Graph, node, q, y_scale: float, y_zero: int) -> list | None:
    """clip(alpha * x + beta, 0, 1) -> Q  as  Add(x, beta / alpha) -> Q with scale y_scale / alpha."""
    from onnx import helper
    a = attrs(node)
    alpha, beta = float(a.get("alpha", 0.2)), float(a.get("beta", 0.5))
    top = y_scale * (255 - y_zero)
    if alpha <= 0 or beta <= 0 or y_zero != 0 or top > 1.0 + y_scale / 2:
        return None  # saturation would not be the clip to [0, 1]
    tag = f"{node.name or node.output[0]}{TAG}"
    nodes, shift = _dq_constant(g, f"{tag}_shift", beta / alpha)
    scale = g.add_initializer(f"{tag}_scale", y_scale / alpha, np.float32)
    nodes += [helper.make_node("Add", [node.input[0], shift], [f"{tag}_sum"], name=f"{tag}_add"),
              helper.make_node("QuantizeLinear", [f"{tag}_sum", scale, q.input[2]], [q.output[0]], name=f"{tag}_q",
                               **attrs(q))]
    return nodes


def _global_pool(g: Graph, node, chain) -> list | None:
    """ReduceMean over axes 2, 3 of a 4-d tensor, keepdims -> GlobalAveragePool, then the same Q."""
    from onnx import helper
    a = attrs(node)
    axes = g.array(node.input[1]) if len(node.input) > 1 and node.input[1] else a.get("axes")
    if axes is None or sorted(int(v) % 4 for v in np.ravel(axes)) != [2, 3] or a.get("keepdims", 1) != 1:
        return None
    q = chain[-1]
    if len(chain) > 1:  # the Reshape/Gather kept the element order; they must end at [N, C, 1, 1]
        idx = g.array(chain[-2].input[1]) if chain[-2].op_type == "Gather" else None
        if idx is None or idx.ndim != 4 or idx.shape[0] != 1 or idx.shape[2:] != (1, 1):
            return None
    tag = f"{node.name or node.output[0]}{TAG}"
    return [helper.make_node("GlobalAveragePool", [node.input[0]], [f"{tag}_pool"], name=f"{tag}_pool"),
            helper.make_node("QuantizeLinear", [f"{tag}_pool", *q.input[1:]], [q.output[0]], name=f"{tag}_q",
                             **attrs(q))]
