"""Cross-layer equalization (CLE) for static PTQ, as AIMET and Nagel et al. 2019 ("Data-Free
Quantization Through Weight Equalization and Bias Correction") have it.

Where a conv's output reaches the next convs only through operations that commute with a positive
per-channel scale (ReLU, pooling, upsampling, an elementwise product such as a squeeze-excitation
gate, observers), output channel i of the first conv can be divided by s_i and input channel i of
the next convs multiplied by s_i without changing the float function. Choosing
s_i = sqrt(r1_i / r2_i), with r1_i and r2_i the channel's largest |weight| in the two layers, gives
both the same range sqrt(r1_i * r2_i). A channel that the first conv (often a depthwise one after
BatchNorm folding) drives 100x harder than its neighbours then stops owning the whole per-tensor
activation grid between the two layers, so the quiet channels keep their resolution.

It runs on the prepared pt2e graph (BatchNorm already folded into the convs, observers inserted but
not yet run), before calibration, so the activation ranges are observed on the equalized model.
Hardswish, ReLU6 and residual additions do not commute with a per-channel scale and end a chain.
"""

from __future__ import annotations

from operator import attrgetter

import torch
from torch.fx import GraphModule, Node
from torchao.quantization.pt2e import ObserverBase

from edgepick.quant.methods import ROUNDS, TOLERANCE, equalizing_scales
from edgepick.quant.pt2e.bias_correction import conv_geometry

EQUALIZED = "edgepick_equalized"  # GraphModule.meta key: the equalized pairs, (first conv, [next convs])

_aten = torch.ops.aten
_CONV = _aten.conv2d.default
# one data input, commutes with a positive per-channel scale of it
_HOMOGENEOUS = {
    _aten.relu.default, _aten.relu_.default, _aten.adaptive_avg_pool2d.default, _aten.avg_pool2d.default,
    _aten.max_pool2d.default, _aten.upsample_bilinear2d.vec, _aten.upsample_nearest2d.vec,
    _aten.dropout.default, _aten.clone.default,
}


def _is_observer(gm: GraphModule, n: Node) -> bool:
    return n.op == "call_module" and isinstance(gm.get_submodule(n.target), ObserverBase)


def _param(gm: GraphModule, node: object) -> torch.Tensor | None:
    """The parameter a conv's weight or bias argument reads (through its weight observer), or None."""
    while isinstance(node, Node) and _is_observer(gm, node):
        node = node.args[0]
    if isinstance(node, Node) and node.op == "get_attr":
        return attrgetter(node.target)(gm)
    return None


def _layout(gm: GraphModule, conv: Node) -> str | None:
    """'dense' (groups 1), 'depthwise' (one input channel per filter), or None (other grouped convs,
    or a weight that is not a parameter)."""
    w = _param(gm, conv.args[1])
    if w is None or w.dim() != 4:
        return None
    groups = conv_geometry(conv)[3]
    if groups == 1:
        return "dense"
    return "depthwise" if w.shape[1] == 1 and groups == w.shape[0] else None


def next_convs(gm: GraphModule, conv: Node) -> list[Node] | None:
    """The convs that read CONV's output through per-channel-homogeneous operations only, or None
    where any path from it meets something else (an add, a concat, a hardswish, a graph output)."""
    scaled, found, todo = {conv}, [], list(conv.users)
    while todo:
        n = todo.pop()
        if n in scaled or n in found:
            continue
        if n.target == _CONV:
            if n.args[0] not in scaled or any(a in scaled for a in n.args[1:3]) or _layout(gm, n) is None:
                return None
            found.append(n)
            continue
        if _is_observer(gm, n) or n.target in _HOMOGENEOUS:
            if any(a in scaled for a in n.args[1:]):
                return None
        elif n.target == _aten.mean.dim:
            if sorted(d % 4 for d in n.args[1]) not in ([2, 3], [3], [2]):
                return None
        elif n.target != _aten.mul.Tensor:
            return None
        scaled.add(n)
        todo.extend(n.users)
    for n in scaled:  # an elementwise product scales once: of two scaled factors it would scale twice
        if n.target == _aten.mul.Tensor and sum(a in scaled for a in n.args) != 1:
            return None
    return found or None


def _weight(gm: GraphModule, conv: Node) -> torch.Tensor:
    """The weight parameter of a conv that next_convs or equalization_pairs accepted."""
    w = _param(gm, conv.args[1])
    if w is None:
        raise ValueError(f"conv {conv.name} has no weight parameter")
    return w


def _input_channel_range(gm: GraphModule, conv: Node) -> torch.Tensor:
    w = _weight(gm, conv).detach()
    if _layout(gm, conv) == "depthwise":
        return w.abs().amax(dim=(1, 2, 3))
    return w.abs().amax(dim=(0, 2, 3))


def _scale_input_channels(gm: GraphModule, conv: Node, s: torch.Tensor) -> None:
    w = _weight(gm, conv)
    shape = (-1, 1, 1, 1) if _layout(gm, conv) == "depthwise" else (1, -1, 1, 1)
    w.mul_(s.view(shape))


def equalization_pairs(gm: GraphModule) -> list[tuple[Node, list[Node]]]:
    """Each conv with a parameter weight and the convs that read it through homogeneous ops only."""
    pairs = []
    for n in gm.graph.nodes:
        if n.target == _CONV and _layout(gm, n) is not None:
            after = next_convs(gm, n)
            if after:
                pairs.append((n, after))
    return pairs


def equalize(prepared: GraphModule, rounds: int = ROUNDS) -> list[tuple[str, list[str]]]:
    """Equalize the weight ranges of every conv pair of PREPARED in place (see the module doc); the
    float function is unchanged. Returns the pairs by node name and records them in
    prepared.meta[EQUALIZED]."""
    pairs = equalization_pairs(prepared)
    with torch.no_grad():
        for _ in range(rounds):
            moved = 0.0
            for first, after in pairs:
                w1 = _weight(prepared, first)
                r1 = w1.detach().abs().amax(dim=(1, 2, 3))
                r2 = torch.stack([_input_channel_range(prepared, c) for c in after]).amax(dim=0)
                if r1.shape != r2.shape:
                    continue
                s = torch.from_numpy(equalizing_scales(r1.double().numpy(), r2.double().numpy())).to(w1.dtype)
                w1.div_(s.view(-1, 1, 1, 1))
                b1 = _param(prepared, first.args[2]) if len(first.args) > 2 else None
                if b1 is not None:
                    b1.div_(s)
                for c in after:
                    _scale_input_channels(prepared, c, s)
                moved = max(moved, float((s - 1).abs().max()))
            if moved < TOLERANCE:
                break
    record = [(first.name, [c.name for c in after]) for first, after in pairs]
    prepared.meta[EQUALIZED] = record
    return record
