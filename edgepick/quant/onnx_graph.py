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

Each rewrite computes the same function in float; each function says how many it made.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from edgepick.export.crop_convs import graph_links


class _Graph:
    """Producers, consumers and constant values of a graph, for small pattern matches."""

    def __init__(self, model: Any):
        from onnx import numpy_helper

        self.model, self.graph = model, model.graph
        self.consts = {i.name: numpy_helper.to_array(i) for i in self.graph.initializer}
        for n in self.graph.node:  # constants, and constants passed through Cast or Identity
            if n.op_type == "Constant" and n.attribute and n.attribute[0].name == "value":
                self.consts[n.output[0]] = numpy_helper.to_array(n.attribute[0].t)
            elif n.op_type in ("Cast", "Identity") and n.input[0] in self.consts:
                self.consts[n.output[0]] = self.consts[n.input[0]]
        self.producer, self.consumers, self.outputs = graph_links(self.graph)

    def scalar(self, name: str) -> float | None:
        value = self.consts.get(name)
        return float(value.ravel()[0]) if value is not None and value.size == 1 else None

    def only_consumer(self, name: str, op_type: str) -> Any | None:
        users = self.consumers.get(name, [])
        if name in self.outputs or len(users) != 1 or users[0].op_type != op_type:
            return None
        return users[0]

    def other_input(self, node: Any, name: str) -> str | None:
        rest = [i for i in node.input if i != name]
        return rest[0] if len(rest) == 1 else None


def _hardsigmoid_of(g: _Graph, add: Any) -> tuple[str, list, Any] | None:
    """Add(x, 3) -> Clip(0, 6) -> Div(6) | Mul(1/6): (x, the matched nodes, the last one), or, when
    the Clip's output goes to Mul(x, .) first and then / 6, that hardswish's nodes."""
    x = next((i for i in add.input if g.scalar(i) != 3.0), None)
    if x is None or g.scalar(g.other_input(add, x) or "") != 3.0:
        return None
    clip = g.only_consumer(add.output[0], "Clip")
    if clip is None or len(clip.input) < 3 or g.scalar(clip.input[1]) != 0.0 or g.scalar(clip.input[2]) != 6.0:
        return None
    users = g.consumers.get(clip.output[0], [])
    if len(users) != 1 or clip.output[0] in g.outputs:
        return None
    nxt = users[0]
    if _is_sixth(g, nxt, clip.output[0]):
        return x, [add, clip, nxt], nxt
    if nxt.op_type == "Mul" and g.other_input(nxt, clip.output[0]) == x:  # x * clip(...) / 6
        last = g.consumers.get(nxt.output[0], [])
        if len(last) == 1 and nxt.output[0] not in g.outputs and _is_sixth(g, last[0], nxt.output[0]):
            return x, [add, clip, nxt, last[0]], last[0]
    return None


def _is_sixth(g: _Graph, node: Any, name: str) -> bool:
    """NODE divides NAME by 6 (Div by 6 or Mul by 1/6)."""
    if node.op_type == "Div" and node.input[0] == name:
        return g.scalar(node.input[1]) == 6.0
    if node.op_type == "Mul":
        value = g.scalar(g.other_input(node, name) or "")
        return value is not None and abs(value - 1 / 6) < 1e-6
    return False


def rewrite_activations(model: Any) -> dict[str, int]:
    """Rewrite MODEL in place as the module docstring says; returns how many of each were made."""
    from onnx import helper

    done = {"hardswish": 0, "hardsigmoid": 0, "global_average_pool": 0, "batchnorm_affine": 0}
    ranks = _ranks(model)
    g = _Graph(model)
    new_nodes: list[tuple[Any, list]] = []  # (node to put them before, nodes)
    dead: list = []
    for node in list(g.graph.node):
        tag = (node.name or node.output[0]) + "_edgepick"
        if node.op_type == "HardSwish":
            hs = helper.make_node("HardSigmoid", [node.input[0]], [f"{tag}_hsig"], name=f"{tag}_hsig",
                                  alpha=1 / 6, beta=0.5)
            new_nodes.append((node, [hs, helper.make_node("Mul", [node.input[0], f"{tag}_hsig"], [node.output[0]],
                                                          name=f"{tag}_mul")]))
            dead.append(node)
            done["hardswish"] += 1
        elif node.op_type == "Add":
            found = _hardsigmoid_of(g, node)
            if found is None or any(n in dead for n in found[1]):
                continue
            x, matched, last = found
            if len(matched) == 3:
                new_nodes.append((last, [helper.make_node("HardSigmoid", [x], [last.output[0]], name=f"{tag}_hsig",
                                                          alpha=1 / 6, beta=0.5)]))
                done["hardsigmoid"] += 1
            else:
                new_nodes.append((last, [helper.make_node("HardSigmoid", [x], [f"{tag}_hsig"], name=f"{tag}_hsig",
                                                          alpha=1 / 6, beta=0.5),
                                         helper.make_node("Mul", [x, f"{tag}_hsig"], [last.output[0]],
                                                          name=f"{tag}_mul")]))
                done["hardswish"] += 1
            dead.extend(matched)
        elif node.op_type == "ReduceMean" and ranks.get(node.input[0]) == 4:
            attrs = {a.name: helper.get_attribute_value(a) for a in node.attribute}
            axes = g.consts.get(node.input[1]) if len(node.input) > 1 and node.input[1] else attrs.get("axes")
            if axes is None or sorted(int(a) % 4 for a in np.ravel(axes)) != [2, 3] or attrs.get("keepdims", 1) != 1:
                continue
            new_nodes.append((node, [helper.make_node("GlobalAveragePool", [node.input[0]], [node.output[0]],
                                                      name=f"{tag}_gap")]))
            dead.append(node)
            done["global_average_pool"] += 1
        elif node.op_type == "BatchNormalization" and ranks.get(node.input[0]) == 4 and len(node.output) == 1:
            source = g.producer.get(node.input[0])
            if source is not None and source.op_type == "Conv" and len(g.consumers.get(node.input[0], [])) == 1:
                continue
            affine = _batchnorm_affine(g, node, tag)
            if affine is None:
                continue
            new_nodes.append((node, affine))
            dead.append(node)
            done["batchnorm_affine"] += 1
    for anchor, nodes in new_nodes:
        at = list(g.graph.node).index(anchor)
        for k, n in enumerate(nodes):
            g.graph.node.insert(at + k, n)
    for node in dead:
        g.graph.node.remove(node)
    return done


def _batchnorm_affine(g: _Graph, node: Any, tag: str) -> list | None:
    """Inference BatchNormalization as x * a + b, with a = gamma / sqrt(var + eps) and
    b = beta - mean * a as [1, C, 1, 1] initializers; None when its parameters are not constants."""
    from onnx import helper, numpy_helper

    gamma, beta, mean, var = (g.consts.get(i) for i in node.input[1:5])
    if gamma is None or beta is None or mean is None or var is None:
        return None
    eps = next((helper.get_attribute_value(a) for a in node.attribute if a.name == "epsilon"), 1e-5)
    a = (gamma / np.sqrt(var + eps)).astype(np.float32)
    b = (beta - mean * a).astype(np.float32)
    g.graph.initializer.extend([numpy_helper.from_array(a.reshape(1, -1, 1, 1), f"{tag}_bn_scale"),
                                numpy_helper.from_array(b.reshape(1, -1, 1, 1), f"{tag}_bn_shift")])
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


def _conv_params(g: _Graph, conv: Any) -> tuple[np.ndarray, np.ndarray] | None:
    """A Conv's constant weight and bias (zeros when it has none), or None."""
    w = g.consts.get(conv.input[1])
    if w is None or w.ndim != 4:
        return None
    b = g.consts.get(conv.input[2]) if len(conv.input) > 2 and conv.input[2] else np.zeros(w.shape[0], w.dtype)
    return (w, b) if b is not None else None


def _set_conv_params(g: _Graph, conv: Any, w: np.ndarray, b: np.ndarray, tag: str) -> None:
    """Give CONV new weight and bias initializers (its old ones may be shared with other nodes)."""
    from onnx import numpy_helper

    g.graph.initializer.extend([numpy_helper.from_array(w.astype(np.float32), f"{tag}_w"),
                                numpy_helper.from_array(b.astype(np.float32), f"{tag}_b")])
    del conv.input[1:]
    conv.input.extend([f"{tag}_w", f"{tag}_b"])


def _channel_const(value: np.ndarray | None, channels: int) -> np.ndarray | None:
    """A constant as one value per channel of an NCHW map: a scalar, [C], [C, 1, 1] or [1, C, 1, 1]."""
    if value is None or value.size not in (1, channels):
        return None
    if value.size == channels and channels > 1 and value.ndim >= 3 and value.shape[-2:] != (1, 1):
        return None
    if value.size == channels and channels > 1 and value.ndim == 1 and channels != value.shape[0]:
        return None
    return np.broadcast_to(value.astype(np.float64).reshape(-1), (channels,)).copy()


def fold_affine_into_convs(model: Any) -> int:
    """Fold, in place, Mul/Add by constants into an adjacent Conv where that is exact: after a
    conv (its only reader), x * a and x + b go into its weight and bias; before a conv (its only
    reader), x * a goes into the weights (zero padding stays zero) and x + b into the bias when
    the conv pads nothing. Returns how many Mul/Add nodes it removed."""
    from onnx import helper

    folded = 0
    changed = True
    while changed:
        changed = False
        g = _Graph(model)
        for node in g.graph.node:
            if node.op_type not in ("Mul", "Add") or len(node.input) != 2:
                continue
            const_in = [i for i in node.input if i in g.consts]
            if len(const_in) != 1:
                continue
            x = g.other_input(node, const_in[0]) or node.input[0]
            src = g.producer.get(x)
            if src is not None and src.op_type == "Conv" and len(g.consumers.get(x, [])) == 1 and x not in g.outputs:
                params = _conv_params(g, src)
                if params is None:
                    continue
                w, b = params
                value = _channel_const(g.consts[const_in[0]], w.shape[0])
                if value is None:
                    continue
                if node.op_type == "Mul":
                    w, b = w * value.reshape(-1, 1, 1, 1), b * value
                else:
                    b = b + value
                _set_conv_params(g, src, w, b, f"{src.name or src.output[0]}_fold{folded}")
            else:
                users = g.consumers.get(node.output[0], [])
                if len(users) != 1 or users[0].op_type != "Conv" or users[0].input[0] != node.output[0] \
                        or node.output[0] in g.outputs:
                    continue
                conv = users[0]
                params = _conv_params(g, conv)
                attrs = {a.name: helper.get_attribute_value(a) for a in conv.attribute}
                group = attrs.get("group", 1)
                if params is None:
                    continue
                w, b = params
                value = _channel_const(g.consts[const_in[0]], w.shape[1] * group)
                if value is None:
                    continue
                per_in = value.reshape(group, w.shape[1])  # input channel c of group k: value[k * Cin_g + c]
                per_in = np.repeat(per_in, w.shape[0] // group, axis=0)  # [Cout, Cin_g]
                if node.op_type == "Mul":
                    w = w * per_in[:, :, None, None]
                else:
                    if any(attrs.get("pads", [0])) or attrs.get("auto_pad", b"NOTSET") not in (b"NOTSET", b"VALID"):
                        continue
                    b = b + (w * per_in[:, :, None, None]).sum(axis=(1, 2, 3))
                _set_conv_params(g, conv, w, b, f"{conv.name or conv.output[0]}_fold{folded}")
            _bypass(g, node, x)
            folded += 1
            changed = True
            break
    return folded


def _bypass(g: _Graph, node: Any, x: str) -> None:
    """Remove NODE, its readers reading X instead (or, at a graph output, X's producer writing it)."""
    out = node.output[0]
    if out in g.outputs:
        src = g.producer[x]
        src.output[list(src.output).index(x)] = out
    else:
        for user in g.consumers.get(out, []):
            for k, name in enumerate(user.input):
                if name == out:
                    user.input[k] = x
    g.graph.node.remove(node)
