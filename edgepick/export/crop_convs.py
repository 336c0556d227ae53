"""ONNX pass: split an int8 conv into output regions that each run only the taps that see input.

DeepLabV3's ASPP convs (3x3, dilation 12/24/36 on a 40x30 map at 640x480) mostly read zero
padding: at rate 24, two thirds of the taps fall outside the map for most outputs. onnxruntime's
fp32 conv skips such taps; its int8 QLinearConv computes them. This pass cuts the output into
bands where the set of in-range taps is constant; each band is a conv with the smaller kernel on
a slice of the input and no padding. A padded tap adds (zero point - zero point) * w = 0 to the
int32 sum, so each output gets the same accumulator and the same uint8 value. In the QDQ graph,
DequantizeLinear -> Conv [-> Relu] -> QuantizeLinear becomes, per region, Slice (uint8) -> the
same QDQ group with a Slice of the one stored kernel (folded when onnxruntime loads the file),
and the regions' uint8 outputs are joined by Concat. Region nodes are named `<conv>_padcrop<i><j>_*`.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import pairwise
from typing import Any

import numpy as np

from edgepick.onnx_graph import Graph, attrs

CROP_TAG = "_padcrop"


@dataclass(frozen=True)
class Band:
    """Outputs [out0, out1) of one axis use kernel taps [tap0, tap1] and input [in0, in1)."""
    out0: int
    out1: int
    tap0: int
    tap1: int
    in0: int
    in1: int


def axis_bands(length: int, kernel: int, dilation: int, pad0: int, pad1: int) -> list[Band] | None:
    """One axis of a stride-1 conv split into bands of outputs that use the same in-range taps;
    None when some output sees only padding (then there is nothing to gain from cropping)."""
    n_out = length + pad0 + pad1 - dilation * (kernel - 1)
    first = [max(0, pad0 - t * dilation) for t in range(kernel)]  # first output where tap t is in range
    stop = [min(n_out, length + pad0 - t * dilation) for t in range(kernel)]  # one past its last
    cuts = sorted({0, n_out, *(c for c in first + stop if 0 < c < n_out)})
    bands = []
    for a, b in pairwise(cuts):
        taps = [t for t in range(kernel) if first[t] <= a and b <= stop[t]]
        if not taps:
            return None
        t0, t1 = taps[0], taps[-1]
        bands.append(Band(a, b, t0, t1, a - pad0 + t0 * dilation, b - 1 - pad0 + t1 * dilation + 1))
    return bands


def tap_work(bands: list[Band]) -> int:
    """Output positions times kernel taps computed over one axis."""
    return sum((b.out1 - b.out0) * (b.tap1 - b.tap0 + 1) for b in bands)


@dataclass
class _Group:
    """One int8 conv: x_q -> DequantizeLinear -> Conv (kernel: int8 initializer -> DequantizeLinear)
    [-> Relu] -> QuantizeLinear."""
    conv: Any  # onnx NodeProtos
    x_dq: Any
    w_dq: Any
    tail: list[Any]


def crop_padded_convs(model, min_saving: float = 0.25) -> int:
    """Rewrite, in place, each dense (group 1), stride-1 int8 conv of MODEL (an onnx ModelProto with
    static shapes) whose in-range taps are at most (1 - MIN_SAVING) of those it computes; returns how
    many. Depthwise convs are left whole: they are cheap, and a 5x5 kernel would make 25 regions."""
    import onnx

    shapes = {v.name: [d.dim_value for d in v.type.tensor_type.shape.dim]
              for v in onnx.shape_inference.infer_shapes(model).graph.value_info}
    g = Graph(model)
    done = 0
    for conv in [n for n in g.nodes if n.op_type == "Conv"]:
        group = _int8_group(g, conv)
        given = attrs(conv)
        shape, kernel = shapes.get(conv.input[0]), list(given.get("kernel_shape", []))
        if (group is None or not shape or len(shape) != 4 or 0 in shape or len(kernel) != 2 or given.get("group", 1) != 1
                or given.get("auto_pad", b"NOTSET") != b"NOTSET" or any(s != 1 for s in given.get("strides", [1, 1]))):
            continue
        dil, pads = list(given.get("dilations", [1, 1])), list(given.get("pads", [0, 0, 0, 0]))
        rows = axis_bands(shape[2], kernel[0], dil[0], pads[0], pads[2])
        cols = axis_bands(shape[3], kernel[1], dil[1], pads[1], pads[3])
        if rows is None or cols is None:
            continue
        full = rows[-1].out1 * cols[-1].out1 * kernel[0] * kernel[1]
        if tap_work(rows) * tap_work(cols) > (1.0 - min_saving) * full:
            continue
        _split(g, group, given, rows, cols)
        done += 1
    return done


def _int8_group(g: Graph, conv: Any) -> _Group | None:
    """The QDQ group around CONV, or None when it is not an int8 conv with a requantized output."""
    x_dq, w_dq = g.producer(conv.input[0]), g.producer(conv.input[1])
    if x_dq is None or x_dq.op_type != "DequantizeLinear" or w_dq is None or w_dq.op_type != "DequantizeLinear":
        return None
    if not g.is_initializer(w_dq.input[0]):
        return None
    tail: list[Any] = []
    out = conv.output[0]
    while (nxt := g.only_consumer(out)) is not None and not (tail and tail[-1].op_type == "QuantizeLinear"):
        if nxt.op_type not in ("Relu", "QuantizeLinear"):
            break
        tail.append(nxt)
        out = nxt.output[0]
    if not tail or tail[-1].op_type != "QuantizeLinear":
        return None
    return _Group(conv, x_dq, w_dq, tail)


def _split(g: Graph, group: _Group, given: dict, rows: list[Band], cols: list[Band]) -> None:
    """Replace GROUP by one QDQ group per band of ROWS x COLS (see the module doc)."""
    from onnx import helper, numpy_helper

    conv, base = group.conv, group.conv.name or group.conv.output[0]
    conv_attrs = {k: v for k, v in given.items() if k not in ("pads", "kernel_shape", "auto_pad")}
    nodes, consts = [], []

    def const(name: str, values: list[int]) -> str:
        consts.append(numpy_helper.from_array(np.asarray(values, dtype=np.int64), name))
        return name

    def copy(node, inputs: list[str], output: str, name: str):
        return helper.make_node(node.op_type, inputs, [output], name=name, **attrs(node))

    band_outs = []
    for i, r in enumerate(rows):
        parts = []
        for j, c in enumerate(cols):
            tag = f"{base}{CROP_TAG}{i}{j}"
            axes = const(f"{tag}_axes", [2, 3])
            nodes.append(helper.make_node("Slice", [group.x_dq.input[0], const(f"{tag}_x0", [r.in0, c.in0]),
                                                    const(f"{tag}_x1", [r.in1, c.in1]), axes], [f"{tag}_xq"],
                                          name=f"{tag}_slice"))
            nodes.append(copy(group.x_dq, [f"{tag}_xq", *group.x_dq.input[1:]], f"{tag}_x", f"{tag}_dqx"))
            nodes.append(helper.make_node("Slice", [group.w_dq.input[0], const(f"{tag}_k0", [r.tap0, c.tap0]),
                                                    const(f"{tag}_k1", [r.tap1 + 1, c.tap1 + 1]), axes], [f"{tag}_wq"],
                                          name=f"{tag}_kernel"))
            nodes.append(copy(group.w_dq, [f"{tag}_wq", *group.w_dq.input[1:]], f"{tag}_w", f"{tag}_dqw"))
            y = f"{tag}_y"
            nodes.append(helper.make_node("Conv", [f"{tag}_x", f"{tag}_w", *conv.input[2:]], [y], name=f"{tag}_conv",
                                          kernel_shape=[r.tap1 - r.tap0 + 1, c.tap1 - c.tap0 + 1], **conv_attrs))
            for k, node in enumerate(group.tail):
                nodes.append(copy(node, [y, *node.input[1:]], f"{tag}_t{k}", f"{tag}_{node.op_type.lower()}"))
                y = f"{tag}_t{k}"
            parts.append(y)
        band_outs.append(f"{base}{CROP_TAG}_band{i}")
        nodes.append(helper.make_node("Concat", parts, [band_outs[-1]], name=f"{band_outs[-1]}_concat", axis=3))
    nodes.append(helper.make_node("Concat", band_outs, [group.tail[-1].output[0]], name=f"{base}{CROP_TAG}_concat",
                                  axis=2))
    g.replace([conv, *group.tail], nodes, at=group.tail[-1])  # every input of the regions is made before it
    for old in (group.x_dq, group.w_dq):
        if not g.consumers(old.output[0]):
            g.remove(old)
    for tensor in consts:
        g.add_tensor(tensor)
