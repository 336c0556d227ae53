"""Where 8-bit weights overflow on a CPU without VNNI, measured on the model's own activations.

onnxruntime's U8S8 kernels on AVX2-only x86 CPUs (the thesis's i5-4300U class) multiply uint8
activation codes by int8 weight codes with `vpmaddubsw`: each pair of neighbouring products along
the GEMM's K axis is added into an int16 that saturates at +-32767. 255 x 127 x 2 exceeds that,
so with 8-bit weights a conv can compute a wrong sum where two large codes meet two large weights
of the same sign; 7-bit weights (|w| <= 64) never can. Whether it happens depends on the
activations, so it is measured: the int8 model runs on sample inputs, and each conv's input codes
are paired with its weights the way the kernel pairs them (K in kernel-row, kernel-column,
input-channel order, onnxruntime's NHWC QLinearConv, padded with the zero point). Depthwise convs
run on a kernel that widens to 32 bits first and never saturate. The measure itself is numpy
(`edgepick.quant.methods.saturated_share`), shared with the ONNX pass.
"""

from __future__ import annotations

from collections.abc import Iterable
from operator import attrgetter

import torch
from torch.fx import GraphModule, Interpreter, Node

from edgepick.quant.methods import INT16, saturated_share
from edgepick.quant.pt2e.bias_correction import conv_geometry, int8_convs


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
                share = saturated_share(codes.cpu().numpy(), w.cpu().numpy(), int(n.args[0].args[2]), *conv_geometry(n), self.limit)
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


def float_weight(reference: GraphModule, name: str) -> torch.Tensor:
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
        w = float_weight(reference, name)
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
