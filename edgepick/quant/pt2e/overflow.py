"""Where 8-bit weights overflow on a CPU without VNNI, measured on the model's own activations.

onnxruntime's U8S8 kernels on AVX2-only x86 CPUs (the thesis's i5-4300U class) multiply uint8
activation codes by int8 weight codes with `vpmaddubsw`: each pair of neighbouring products along
the GEMM's K axis is added into an int16 that saturates at +-32767. 255 x 127 x 2 exceeds that,
so with 8-bit weights a conv can compute a wrong sum where two large codes meet two large weights
of the same sign; 7-bit weights (|w| <= 64) never can. Whether it happens depends on the
activations, so it is measured: the int8 model runs on sample inputs, and each conv's input codes
are paired with its weights the way the kernel pairs them (K in kernel-row, kernel-column,
input-channel order, onnxruntime's NHWC QLinearConv, padded with the zero point). Depthwise convs
run on a kernel that widens to 32 bits first and never saturate.
"""

from __future__ import annotations

from collections.abc import Iterable
from operator import attrgetter

import torch
import torch.nn.functional as F
from torch.fx import GraphModule, Interpreter, Node

from edgepick.quant.pt2e.bias_correction import conv_geometry, int8_convs

INT16 = 32767
_PAIRS_AT_ONCE = 32  # K pairs multiplied per step: memory is pairs x positions x output channels


def saturated_share(codes: torch.Tensor, weights: torch.Tensor, zero_point: int, stride: tuple, padding: tuple,
                    dilation: tuple, groups: int, limit: float = INT16) -> float:
    """Share of a conv's outputs (positions x output channels) where at least one int16 pair sum of
    uint8 input CODES [N, C, H, W] and int8 WEIGHTS [M, C/groups, kh, kw] leaves +-LIMIT."""
    m, c_group, kh, kw = weights.shape
    if c_group == 1 and groups > 1:  # depthwise: its kernel never adds pairs in int16
        return 0.0
    x = F.pad(codes.float(), (padding[1], padding[1], padding[0], padding[0]), value=float(zero_point))
    hit = None
    per_group = m // groups
    for g in range(groups):
        xg = x[:, g * c_group:(g + 1) * c_group]
        cols = F.unfold(xg, (kh, kw), dilation=dilation, stride=stride)  # [N, C*kh*kw, L] in (c, kh, kw) order
        n, _, positions = cols.shape
        cols = cols.view(n, c_group, kh * kw, positions).transpose(1, 2).reshape(n, -1, positions)
        w = weights[g * per_group:(g + 1) * per_group].float().permute(0, 2, 3, 1).reshape(per_group, -1)
        k = w.shape[1] + w.shape[1] % 2
        cols = F.pad(cols, (0, 0, 0, k - cols.shape[1]))
        w = F.pad(w, (0, k - w.shape[1]))
        a = cols.permute(1, 0, 2).reshape(k // 2, 2, n * positions)  # [pairs, 2, N*L]
        b = w.t().reshape(k // 2, 2, per_group)  # [pairs, 2, M_g]
        over = torch.zeros(n * positions, per_group, dtype=torch.bool)
        for j in range(0, k // 2, _PAIRS_AT_ONCE):
            sums = torch.bmm(a[j:j + _PAIRS_AT_ONCE].transpose(1, 2), b[j:j + _PAIRS_AT_ONCE])  # [pairs, N*L, M_g]
            over |= (sums.abs() > limit).any(dim=0)
        hit = over if hit is None else torch.cat([hit, over], dim=1)
    assert hit is not None
    return float(hit.float().mean())


class _Codes(Interpreter):
    """Runs an int8 graph and, at each conv in CONVS, measures the saturated share of its input codes."""

    def __init__(self, graph: GraphModule, convs: dict[str, Node], limit: float):
        super().__init__(graph)
        self.convs, self.share, self.limit = convs, dict.fromkeys(convs, 0.0), limit
        # the quantize node whose uint8 output each conv reads, through its dequantize node
        self.readers = {conv.args[0].args[0].name for conv in convs.values() if isinstance(conv.args[0].args[0], Node)}
        self.codes: dict[str, torch.Tensor] = {}

    def run_node(self, n: Node):
        out = super().run_node(n)
        if n.name in self.readers:
            self.codes[n.name] = out
        elif n.name in self.convs:
            q = n.args[0].args[0]
            codes = self.codes.get(q.name) if isinstance(q, Node) else None
            if codes is not None and codes.dtype == torch.uint8:
                w = attrgetter(n.args[1].args[0].target)(self.module)
                share = saturated_share(codes, w, int(n.args[0].args[2]), *conv_geometry(n), self.limit)
                self.share[n.name] = max(self.share[n.name], share)
        return out


def saturating_convs(converted: GraphModule, inputs: Iterable[torch.Tensor], limit: float = INT16) -> dict[str, float]:
    """For each int8 conv of CONVERTED (a converted pt2e graph), the largest share of its outputs,
    over INPUTS (model input batches), that an AVX2 U8S8 kernel would compute with a pair sum
    beyond +-LIMIT (the int16 range: a saturated, wrong sum)."""
    convs = int8_convs(converted)
    runner = _Codes(converted, convs, limit)
    with torch.no_grad():
        for x in inputs:
            runner.run(x)
            runner.codes.clear()
    return runner.share


def _float_weight(reference: GraphModule, name: str) -> torch.Tensor:
    """The float (BN-folded) weight of conv NAME in REFERENCE, the observed graph before convert."""
    conv = next(n for n in reference.graph.nodes if n.name == name)
    w = conv.args[1]
    while isinstance(w, Node) and w.op != "get_attr":  # through the weight's observer
        w = w.args[0]
    if not isinstance(w, Node):
        raise ValueError(f"conv {name} has no weight parameter in the float graph")
    return attrgetter(w.target)(reference).detach()


def to_seven_bit(reference: GraphModule, converted: GraphModule, names: Iterable[str]) -> int:
    """Requantize the weights of the convs NAMES of CONVERTED to 7 bits (-64..63 per output channel,
    symmetric, as the quantizer's 7-bit spec would have made them), from the float weights of
    REFERENCE. Activation ranges are unchanged: calibration observed float activations. Returns how
    many convs changed; their biases need snapping again (the weight scale moved)."""
    from torchao.quantization.pt2e import PerChannelMinMaxObserver

    convs = int8_convs(converted)
    changed = 0
    for name in names:
        dq = convs[name].args[1]
        observer = PerChannelMinMaxObserver(ch_axis=0, dtype=torch.int8, quant_min=-64, quant_max=63,
                                            qscheme=torch.per_channel_symmetric, eps=2 ** -12)
        w = _float_weight(reference, name)
        observer(w)
        scale, _ = observer.calculate_qparams()
        codes = torch.clamp(torch.round(w / scale.view(-1, *[1] * (w.dim() - 1))), -64, 63).to(torch.int8)
        attrgetter(dq.args[0].target)(converted).copy_(codes)
        scales = attrgetter(dq.args[1].target)(converted)
        scales.copy_(scale.to(scales.dtype))
        dq.update_arg(4, -64)
        dq.update_arg(5, 63)
        changed += 1
    converted.recompile()
    return changed
