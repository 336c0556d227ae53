"""Cross-layer equalization on a float ONNX graph (BatchNorm already folded by onnxruntime's
`quant_pre_process`): the same rescaling as `edgepick.quant.pt2e.equalize` does on a torch graph (see
there why), with the weights as initializers. Each equalized conv gets initializers of its own, as
`rewrite.fold_affine_into_convs` gives them; the float function is unchanged."""

from __future__ import annotations

from typing import Any

import numpy as np

from edgepick.onnx_graph import Graph, attr
from edgepick.quant.methods import ROUNDS, TOLERANCE, equalizing_scales
from edgepick.quant.onnx.rewrite import conv_params, set_conv_params

# one data input, commutes with a positive per-channel scale of it
_HOMOGENEOUS = {"Relu", "MaxPool", "AveragePool", "GlobalAveragePool", "Resize", "Upsample", "Dropout", "Identity"}


def _layout(g: Graph, conv: Any) -> str | None:
    """'dense', 'depthwise', or None (other grouped convs, weights that are not constants)."""
    params = conv_params(g, conv)
    if params is None:
        return None
    group = attr(conv, "group", 1)
    if group == 1:
        return "dense"
    return "depthwise" if params[0].shape[1] == 1 and group == params[0].shape[0] else None


def _next_convs(g: Graph, conv: Any) -> list[Any] | None:
    """The convs reading CONV's output through homogeneous ops only, or None (see equalize.next_convs)."""
    scaled, found, todo = {conv.output[0]}, [], [conv.output[0]]
    muls = []
    while todo:
        name = todo.pop()
        if name in g.outputs:
            return None
        for user in g.consumers(name):
            if user.op_type == "Conv":
                if user.input[0] != name or any(i in scaled for i in user.input[1:]) or _layout(g, user) is None:
                    return None
                if user not in found:
                    found.append(user)
                continue
            if user.op_type in _HOMOGENEOUS:
                if any(i in scaled for i in user.input[1:]):
                    return None
            elif user.op_type == "Mul":
                muls.append(user)
            else:
                return None
            for out in user.output[:1]:
                if out not in scaled:
                    scaled.add(out)
                    todo.append(out)
    if any(sum(i in scaled for i in m.input) != 1 for m in muls):
        return None
    return found or None


def equalize_onnx(model: Any, rounds: int = ROUNDS) -> int:
    """Equalize, in place, every conv pair of MODEL (an onnx ModelProto, BatchNorm folded). Returns
    how many pairs it rescaled."""
    g = Graph(model)
    pairs = []
    for node in g.nodes:
        if node.op_type == "Conv" and _layout(g, node) is not None:
            after = _next_convs(g, node)
            if after:
                pairs.append((node, after))
    if not pairs:
        return 0
    params: dict[int, list[np.ndarray]] = {}
    layouts: dict[int, str | None] = {}
    for first, after in pairs:
        for c in [first, *after]:
            found = conv_params(g, c)
            assert found is not None  # _layout accepted it
            params[id(c)] = [p.astype(np.float64) for p in found]
            layouts[id(c)] = _layout(g, c)

    def input_range(conv: Any) -> np.ndarray:
        w = params[id(conv)][0]
        return np.abs(w).max(axis=(1, 2, 3)) if layouts[id(conv)] == "depthwise" else np.abs(w).max(axis=(0, 2, 3))

    for _ in range(rounds):
        moved = 0.0
        for first, after in pairs:
            w1, b1 = params[id(first)]
            r1 = np.abs(w1).max(axis=(1, 2, 3))
            r2 = np.max([input_range(c) for c in after], axis=0)
            if r1.shape != r2.shape:
                continue
            s = equalizing_scales(r1, r2)
            params[id(first)] = [w1 / s.reshape(-1, 1, 1, 1), b1 / s]
            for c in after:
                w, b = params[id(c)]
                shape = (-1, 1, 1, 1) if layouts[id(c)] == "depthwise" else (1, -1, 1, 1)
                params[id(c)] = [w * s.reshape(shape), b]
            moved = max(moved, float(np.abs(s - 1).max()))
        if moved < TOLERANCE:
            break
    done = set()
    for k, (first, after) in enumerate(pairs):
        for c in [first, *after]:
            if id(c) not in done:
                done.add(id(c))
                w, b = params[id(c)]
                set_conv_params(g, c, w, b, f"{c.name or c.output[0]}_equalized{k}")
    return len(pairs)
