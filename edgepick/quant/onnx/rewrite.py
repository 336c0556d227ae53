"""A float ONNX model from another exporter (read, fixed and lifted to opset 13 by
`edgepick.export.onnx_io`) made ready for edgepick's int8 recipe: its activations rewritten into the
forms that onnxruntime runs on integer kernels once quantized:

- hardswish, as HardSwish (opset 14) or spelt out as x * Clip(x + 3, 0, 6) / 6 (or * 1/6), becomes
  x * HardSigmoid(x): a QLinearMul, and a HardSigmoid that `export.int8_activations` turns into an
  integer Add. As one quantized op it would dequantize its map and run in float.
- Clip(x + 3, 0, 6) / 6 alone (hardsigmoid spelt out) becomes HardSigmoid.
- ReduceMean over H and W with keepdims (squeeze-excitation, image pooling) becomes
  GlobalAveragePool: QLinearGlobalAveragePool.
- a BatchNormalization that no conv precedes (onnxruntime folds the others into their conv)
  becomes Mul and Add by per-channel constants: QLinearMul and QLinearAdd, where
  BatchNormalization has no integer kernel.

`fold_affine_into_convs` then folds Mul and Add by constants into the conv next to them, where
the result is exactly the same function (PP-LCNetV3's learnable affine blocks, Caffe-style scale
layers): each one folded is a full pass over a feature map that the int8 model no longer makes.

`subsample_before_strided_pointwise_convs` writes a 1x1 conv's stride as a subsampling of its
input, and `spell_float_hardswish` writes each hardswish left float back in the exporters' form, for
the files made for OpenVINO (quant/onnx/placement.py).

Each rewrite computes the same function in float; each function says how many it made.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from edgepick.onnx_graph import Graph, attrs

# a constant passed through these ops is still the constant (exporters write Cast(Constant))
THROUGH = ("Cast", "Identity")


def _scalar(g: Graph, name: str | None) -> float | None:
    return g.scalar(name, THROUGH) if name else None


def _other_input(node: Any, name: str) -> str | None:
    """NODE's one input other than NAME, or None."""
    rest = [i for i in node.input if i != name]
    return rest[0] if len(rest) == 1 else None


def _hardsigmoid_of(g: Graph, add: Any) -> tuple[str, list, Any] | None:
    """Add(x, 3) -> Clip(0, 6) -> Div(6) | Mul(1/6): (x, the matched nodes, the last one), or, when
    the Clip's output goes to Mul(x, .) first and then / 6, that hardswish's nodes."""
    x = next((i for i in add.input if _scalar(g, i) != 3.0), None)
    if x is None or _scalar(g, _other_input(add, x) or "") != 3.0:
        return None
    clip = g.only_consumer(add.output[0], "Clip")
    if clip is None or len(clip.input) < 3 or _scalar(g, clip.input[1]) != 0.0 or _scalar(g, clip.input[2]) != 6.0:
        return None
    nxt = g.only_consumer(clip.output[0])
    if nxt is None:
        return None
    if _is_sixth(g, nxt, clip.output[0]):
        return x, [add, clip, nxt], nxt
    if nxt.op_type == "Mul" and _other_input(nxt, clip.output[0]) == x:  # x * clip(...) / 6
        last = g.only_consumer(nxt.output[0])
        if last is not None and _is_sixth(g, last, nxt.output[0]):
            return x, [add, clip, nxt, last], last
    return None


def _is_sixth(g: Graph, node: Any, name: str) -> bool:
    """NODE divides NAME by 6 (Div by 6 or Mul by 1/6)."""
    if node.op_type == "Div" and node.input[0] == name:
        return _scalar(g, node.input[1]) == 6.0
    if node.op_type == "Mul":
        value = _scalar(g, _other_input(node, name) or "")
        return value is not None and abs(value - 1 / 6) < 1e-6
    return False


def _hardsigmoid(x: str, out: str, tag: str) -> Any:
    from onnx import helper

    return helper.make_node("HardSigmoid", [x], [out], name=f"{tag}_hsig", alpha=1 / 6, beta=0.5)


def _gated(x: str, out: str, tag: str) -> list:
    """x * HardSigmoid(x) into OUT: hardswish, both halves on integer kernels once quantized."""
    from onnx import helper

    return [_hardsigmoid(x, f"{tag}_hsig", tag), helper.make_node("Mul", [x, f"{tag}_hsig"], [out], name=f"{tag}_mul")]


def _rewrite(g: Graph, node: Any, ranks: dict[str, int], dead: list) -> tuple[str, Any, list, list] | None:
    """What NODE is rewritten into: (the kind, the node to put the new nodes before, the new nodes,
    the nodes they replace), or None."""
    from onnx import helper

    tag = (node.name or node.output[0]) + "_edgepick"
    if node.op_type == "HardSwish":
        return "hardswish", node, _gated(node.input[0], node.output[0], tag), [node]
    if node.op_type == "Add":
        found = _hardsigmoid_of(g, node)
        if found is None or any(n in dead for n in found[1]):
            return None
        x, matched, last = found
        if len(matched) == 3:
            return "hardsigmoid", last, [_hardsigmoid(x, last.output[0], tag)], matched
        return "hardswish", last, _gated(x, last.output[0], tag), matched
    if node.op_type == "ReduceMean" and ranks.get(node.input[0]) == 4:
        given = attrs(node)
        axes = g.array(node.input[1], THROUGH) if len(node.input) > 1 and node.input[1] else given.get("axes")
        if axes is None or sorted(int(a) % 4 for a in np.ravel(axes)) != [2, 3] or given.get("keepdims", 1) != 1:
            return None
        pool = helper.make_node("GlobalAveragePool", [node.input[0]], [node.output[0]], name=f"{tag}_gap")
        return "global_average_pool", node, [pool], [node]
    if node.op_type == "BatchNormalization" and ranks.get(node.input[0]) == 4 and len(node.output) == 1:
        source = g.producer(node.input[0])
        if source is not None and source.op_type == "Conv" and len(g.consumers(node.input[0])) == 1:
            return None
        affine = _batchnorm_affine(g, node, tag)
        return ("batchnorm_affine", node, affine, [node]) if affine is not None else None
    return None


def rewrite_activations(model: Any) -> dict[str, int]:
    """Rewrite MODEL in place as the module docstring says; returns how many of each were made."""
    done = {"hardswish": 0, "hardsigmoid": 0, "global_average_pool": 0, "batchnorm_affine": 0}
    ranks = _ranks(model)
    g = Graph(model)
    new_nodes: list[tuple[Any, list]] = []  # (node to put them before, nodes)
    dead: list = []
    for node in g.nodes:
        found = _rewrite(g, node, ranks, dead)
        if found is None:
            continue
        kind, anchor, nodes, replaced = found
        new_nodes.append((anchor, nodes))
        dead.extend(replaced)
        done[kind] += 1
    for anchor, nodes in new_nodes:
        g.insert_before(anchor, nodes)
    g.remove(*dead)
    return done


def _batchnorm_affine(g: Graph, node: Any, tag: str) -> list | None:
    """Inference BatchNormalization as x * a + b, with a = gamma / sqrt(var + eps) and
    b = beta - mean * a as [1, C, 1, 1] initializers; None when its parameters are not constants."""
    from onnx import helper

    gamma, beta, mean, var = (g.array(i, THROUGH) for i in node.input[1:5])
    if gamma is None or beta is None or mean is None or var is None:
        return None
    eps = attrs(node).get("epsilon", 1e-5)
    a = (gamma / np.sqrt(var + eps)).astype(np.float32)
    b = (beta - mean * a).astype(np.float32)
    g.add_initializer(f"{tag}_bn_scale", a.reshape(1, -1, 1, 1))
    g.add_initializer(f"{tag}_bn_shift", b.reshape(1, -1, 1, 1))
    return [helper.make_node("Mul", [node.input[0], f"{tag}_bn_scale"], [f"{tag}_bn_scaled"], name=f"{tag}_bn_mul"),
            helper.make_node("Add", [f"{tag}_bn_scaled", f"{tag}_bn_shift"], [node.output[0]], name=f"{tag}_bn_add")]


def _ranks(model: Any) -> dict[str, int]:
    """Tensor name -> rank, from onnx's shape inference (empty where it cannot tell)."""
    import onnx

    try:
        inferred = onnx.shape_inference.infer_shapes(model)
    except Exception:  # noqa: BLE001 - a model shape inference cannot follow is rewritten less
        return {}
    values = [*inferred.graph.value_info, *inferred.graph.input, *inferred.graph.output]
    return {v.name: len(v.type.tensor_type.shape.dim) for v in values if v.type.tensor_type.HasField("shape")}


def conv_params(g: Graph, conv: Any) -> tuple[np.ndarray, np.ndarray] | None:
    """A Conv's constant weight and bias (zeros when it has none), or None."""
    w = g.array(conv.input[1], THROUGH)
    if w is None or w.ndim != 4:
        return None
    b = g.array(conv.input[2], THROUGH) if len(conv.input) > 2 and conv.input[2] else np.zeros(w.shape[0], w.dtype)
    return (w, b) if b is not None else None


def set_conv_params(g: Graph, conv: Any, w: np.ndarray, b: np.ndarray, tag: str) -> None:
    """Give CONV new weight and bias initializers (its old ones may be shared with other nodes)."""
    g.add_initializer(f"{tag}_w", w.astype(np.float32))
    g.add_initializer(f"{tag}_b", b.astype(np.float32))
    g.set_inputs(conv, [conv.input[0], f"{tag}_w", f"{tag}_b"])


def _channel_const(value: np.ndarray | None, channels: int) -> np.ndarray | None:
    """A constant as one value per channel of an NCHW map: a scalar, [C], [C, 1, 1] or [1, C, 1, 1]."""
    if value is None or value.size not in (1, channels):
        return None
    if value.size == channels and channels > 1 and value.ndim >= 3 and value.shape[-2:] != (1, 1):
        return None
    if value.size == channels and channels > 1 and value.ndim == 1 and channels != value.shape[0]:
        return None
    return np.broadcast_to(value.astype(np.float64).reshape(-1), (channels,)).copy()


def _fold_after(g: Graph, node: Any, const: str, src: Any, folded: int) -> bool:
    """Fold NODE (Mul or Add by the constant CONST) into the Conv SRC that makes its other input."""
    params = conv_params(g, src)
    if params is None:
        return False
    w, b = params
    value = _channel_const(g.array(const, THROUGH), w.shape[0])
    if value is None:
        return False
    if node.op_type == "Mul":
        w, b = w * value.reshape(-1, 1, 1, 1), b * value
    else:
        b = b + value
    set_conv_params(g, src, w, b, f"{src.name or src.output[0]}_fold{folded}")
    return True


def _fold_before(g: Graph, node: Any, const: str, folded: int) -> bool:
    """Fold NODE (Mul or Add by the constant CONST) into the Conv that is its only reader, where exact."""
    conv = g.only_consumer(node.output[0], "Conv")
    if conv is None or conv.input[0] != node.output[0]:
        return False
    params = conv_params(g, conv)
    given = attrs(conv)
    group = given.get("group", 1)
    if params is None:
        return False
    w, b = params
    value = _channel_const(g.array(const, THROUGH), w.shape[1] * group)
    if value is None:
        return False
    per_in = value.reshape(group, w.shape[1])  # input channel c of group k: value[k * Cin_g + c]
    per_in = np.repeat(per_in, w.shape[0] // group, axis=0)  # [Cout, Cin_g]
    if node.op_type == "Mul":
        w = w * per_in[:, :, None, None]
    else:
        if any(given.get("pads", [0])) or given.get("auto_pad", b"NOTSET") not in (b"NOTSET", b"VALID"):
            return False
        b = b + (w * per_in[:, :, None, None]).sum(axis=(1, 2, 3))
    set_conv_params(g, conv, w, b, f"{conv.name or conv.output[0]}_fold{folded}")
    return True


def _fold_one(g: Graph, folded: int) -> bool:
    """Fold the first Mul/Add by a constant that can go into a conv next to it; whether one went."""
    for node in g.nodes:
        if node.op_type not in ("Mul", "Add") or len(node.input) != 2:
            continue
        const_in = [i for i in node.input if g.is_constant(i, THROUGH)]
        if len(const_in) != 1:
            continue
        x = _other_input(node, const_in[0]) or node.input[0]
        src = g.producer(x)
        if src is not None and src.op_type == "Conv" and len(g.consumers(x)) == 1 and x not in g.outputs:
            if not _fold_after(g, node, const_in[0], src, folded):
                continue
        elif not _fold_before(g, node, const_in[0], folded):
            continue
        _bypass(g, node, x)
        return True
    return False


def fold_affine_into_convs(model: Any) -> int:
    """Fold, in place, Mul/Add by constants into an adjacent Conv where that is exact: after a
    conv (its only reader), x * a and x + b go into its weight and bias; before a conv (its only
    reader), x * a goes into the weights (zero padding stays zero) and x + b into the bias when
    the conv pads nothing. Returns how many Mul/Add nodes it removed."""
    g = Graph(model)
    folded = 0
    while _fold_one(g, folded):
        folded += 1
    return folded


def _bypass(g: Graph, node: Any, x: str) -> None:
    """Remove NODE, its readers reading X instead (or, at a graph output, X's producer writing it)."""
    out = node.output[0]
    if out in g.outputs:
        src = g.producer(x)
        assert src is not None, "a conv made X"
        g.set_output(src, x, out)
    else:
        g.redirect(out, x)
    g.remove(node)


def subsample_before_strided_pointwise_convs(model: Any) -> int:
    """Rewrite, in place, each 1x1 conv with a stride and no padding as MaxPool(1x1, that stride)
    then the conv with stride 1: the same function. OpenVINO's CPU plugin moves such a stride onto
    the conv's input as a pooling; on a dequantized input that pooling runs in f32 and the conv
    loses its int8 kernel (a ResNet's strided projections, open-nsfw's among them). Written in the
    float graph, the subsampled map is quantized for the conv like any other input. Returns how
    many convs it rewrote."""
    import onnx

    g = Graph(model)
    done = 0
    for conv in list(g.nodes):
        a = attrs(conv)
        strides, pad = list(a.get("strides", [])), a.get("auto_pad", b"NOTSET")
        if conv.op_type != "Conv" or list(a.get("kernel_shape", [])) != [1, 1] or max(strides, default=1) == 1 \
                or any(a.get("pads", [])) or (pad.decode() if isinstance(pad, bytes) else pad) not in ("NOTSET", "VALID"):
            continue
        tag = f"{conv.name or conv.output[0]}_subsample"
        g.insert_before(conv, [onnx.helper.make_node("MaxPool", [conv.input[0]], [tag], name=tag, kernel_shape=[1, 1],
                                                     strides=strides)])
        g.set_input(conv, 0, tag)
        next(x for x in conv.attribute if x.name == "strides").ints[:] = [1] * len(strides)
        done += 1
    return done


def spell_float_hardswish(model: Any) -> int:
    """Rewrite, in place, each x * HardSigmoid(x) (hardswish as torch below opset 14, onnxruntime's
    pre-processing and `rewrite_activations` write it) that is left float, nothing quantized between
    its two halves, as x * Clip(x + 3, 0, 6) / 6: the same function, in the form exporters write and
    OpenVINO's CPU plugin fuses into the conv before it as one post-op (with the next QuantizeLinear).
    HardSigmoid and Mul it runs as two more passes over the map, HardSigmoid on a reference kernel.
    Returns how many it rewrote."""
    from onnx import helper

    g = Graph(model)
    pairs = []
    for mul in g.nodes:
        if mul.op_type != "Mul" or len(mul.input) != 2:
            continue
        for x, gate in (mul.input, reversed(mul.input)):
            hsig = g.producer(gate)
            if hsig is not None and hsig.op_type == "HardSigmoid" and hsig.input[0] == x \
                    and len(g.consumers(gate)) == 1 and gate not in g.outputs \
                    and abs(attrs(hsig).get("alpha", 0.2) - 1 / 6) < 1e-6 and abs(attrs(hsig).get("beta", 0.5) - 0.5) < 1e-6:
                pairs.append((hsig, mul, x))
                break
    for hsig, mul, x in pairs:
        tag = f"{mul.name or mul.output[0]}_hardswish"
        three, zero, six = (g.add_initializer(f"{tag}_{v:g}", v, np.float32) for v in (3.0, 0.0, 6.0))
        g.replace([hsig, mul], [helper.make_node("Add", [x, three], [f"{tag}_plus3"], name=f"{tag}_add"),
                                helper.make_node("Clip", [f"{tag}_plus3", zero, six], [f"{tag}_clip"], name=f"{tag}_clip"),
                                helper.make_node("Div", [f"{tag}_clip", six], [f"{tag}_gate"], name=f"{tag}_div"),
                                helper.make_node("Mul", [x, f"{tag}_gate"], [mul.output[0]], name=f"{tag}_mul")],
                  at=mul)
    return len(pairs)
