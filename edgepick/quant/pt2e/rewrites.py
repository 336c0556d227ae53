"""Rewrites made for int8, each exact in float: the model's hardswish as a gate both halves of
which quantize, and two edits of the pt2e graph (no fake-quant learns from training's dropout;
conv biases on onnxruntime's int32 grid). Trimming the dilated taps that only see padding is
exact for the float model too, so it lives with the model (models/deeplabv3.trim_dilated_convs)."""

from __future__ import annotations

from operator import attrgetter

import torch


class GatedHardswish(torch.nn.Module):
    """hardswish(x) written as x * hardsigmoid(x). Quantized, the gate gets its own uint8 grid and
    onnxruntime runs both halves on integer kernels (QLinearAdd after export's integer_activations,
    QLinearMul); a quantized HardSwish it runs in float, dequantizing the whole map."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x * torch.nn.functional.hardsigmoid(x)


def gate_hardswish(model: torch.nn.Module) -> int:
    """Replace every nn.Hardswish of MODEL by GatedHardswish (the same function; no weights move)."""
    names = [name for name, m in model.named_modules() if isinstance(m, torch.nn.Hardswish)]
    for name in names:
        parent, _, child = name.rpartition(".")
        setattr(model.get_submodule(parent), child, GatedHardswish())
    return len(names)


def drop_fake_quants_after_dropout(prepared: torch.fx.GraphModule) -> int:
    """Remove each fake-quant that reads a dropout of an already fake-quantized tensor (ASPP's
    Dropout(0.5) before the head conv): it learnt its range from training's 1/(1-p)-scaled values,
    2x the deployed ones, where the dropout is gone, so the head conv read its input at half the
    resolution. The conv reads the grid before the dropout instead. Returns how many were removed."""
    from torchao.quantization.pt2e import FakeQuantizeBase

    def is_fake_quant(node: torch.fx.Node) -> bool:
        return node.op == "call_module" and isinstance(prepared.get_submodule(node.target), FakeQuantizeBase)

    dropouts = (torch.ops.aten.dropout.default, torch.ops.aten.dropout_.default)
    removed = 0
    for node in list(prepared.graph.nodes):
        src = node.args[0] if is_fake_quant(node) and node.args else None
        if (isinstance(src, torch.fx.Node) and src.target in dropouts
                and isinstance(src.args[0], torch.fx.Node) and is_fake_quant(src.args[0])):
            node.replace_all_uses_with(src)
            prepared.graph.erase_node(node)
            removed += 1
    return removed


def snap_conv_biases(converted: torch.fx.GraphModule) -> int:
    """Round each int8 conv's float bias to the int32 grid (scale = input scale x weight scale) that
    onnxruntime quantizes it to when it fuses the conv into QLinearConv. The int8 model onnxruntime
    runs is unchanged, and torch's simulation computes the same sums, so the label-agreement check
    compares like with like (benchmarks/agreement.py measures the difference). Returns how many
    biases were snapped."""
    qd = torch.ops.quantized_decomposed
    snapped = 0
    for node in converted.graph.nodes:
        if node.target != torch.ops.aten.conv2d.default or len(node.args) < 3:
            continue
        x, w, b = node.args[:3]
        if not (isinstance(x, torch.fx.Node) and x.target == qd.dequantize_per_tensor.default
                and isinstance(w, torch.fx.Node) and w.target == qd.dequantize_per_channel.default
                and isinstance(b, torch.fx.Node) and b.op == "get_attr" and not isinstance(x.args[1], torch.fx.Node)):
            continue
        w_scale = attrgetter(w.args[1].target)(converted) if isinstance(w.args[1], torch.fx.Node) else w.args[1]
        step = torch.tensor(x.args[1], dtype=torch.float32) * torch.as_tensor(w_scale, dtype=torch.float32)
        bias = attrgetter(b.target)(converted)
        with torch.no_grad():
            bias.copy_(torch.round(bias / step) * step)
        snapped += 1
    return snapped
