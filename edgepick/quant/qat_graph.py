"""Upkeep of a QaT graph (torchao pt2e): BatchNorm literals kept through torchao's rewrites (training,
the switch to eval mode, and the BN fold in convert), and a calibrated start for QaT from a float
checkpoint (hybrid-QaT).

A QaT graph's activation fake-quants take their first range from the first training batch's
min/max, then follow it with a moving average (1% a step), where static PTQ uses percentile
ranges; a hybrid run of a few epochs at the tail of the learning-rate schedule has little room
to train such a start back. `calibrate_activations` gives the fake-quants static PTQ's ranges
instead (hybrid-QaT's default; docs/quantization.md#hybrid-qat).
"""

from __future__ import annotations

import contextlib

import numpy as np
import torch

from edgepick.quant.quantizer import PercentileObserver

BN_LITERALS = "edgepick_bn_literals"  # GraphModule.meta key: running_var name -> the module's (eps, momentum)


def _restore_literals(node: torch.fx.Node, table: dict) -> int:
    """Put the table's eps/momentum into one batch_norm node (or the `running_var + eps` add of the
    QaT weight scaling); returns how many literals changed."""
    if node.op != "call_function" or not hasattr(node.target, "_schema"):
        return 0
    names = [a.name for a in node.target._schema.arguments]
    if "running_var" in names and "eps" in names:  # a batch_norm variant
        var = node.args[names.index("running_var")] if len(node.args) > names.index("running_var") else None
        literal = {"eps": 0, "momentum": 1}
    elif node.target == torch.ops.aten.add.Tensor and len(node.args) == 2 and isinstance(node.args[1], float):
        var, literal = node.args[0], {"other": 0}  # sqrt(running_var + eps) of the QaT weight scaling
    else:
        return 0
    if not (isinstance(var, torch.fx.Node) and var.op == "get_attr" and var.target in table):
        return 0
    args, changed = list(node.args), 0
    for arg, which in literal.items():
        i = names.index(arg)
        if i < len(args) and args[i] != table[var.target][which]:
            args[i] = table[var.target][which]
            changed += 1
    node.args = tuple(args)
    return changed


def restore_bn_literals(prepared: torch.fx.GraphModule) -> int:
    """Give every BatchNorm in a prepared graph its module's eps and momentum again. torchao's QaT
    conv-BN rewrite and its train/eval switches write F.batch_norm's defaults (eps 1e-5, momentum
    0.1; "TODO: allow setting eps" in torchao 0.18), while MobileNetV3 uses eps 1e-3: a float
    checkpoint would then run with other BN arithmetic in QaT than it was trained with. Call after
    each such rewrite; returns the number of literals changed."""
    table = prepared.meta.get(BN_LITERALS, {})
    changed = sum(_restore_literals(node, table) for node in prepared.graph.nodes)
    if changed:
        prepared.recompile()
    return changed


@contextlib.contextmanager
def bn_folds_with_own_eps(prepared: torch.fx.GraphModule):
    """While converting PREPARED, fold each BN into its conv with the BN's own eps. convert_pt2e
    rewrites a QaT conv-BN into a plain conv-BN whose batch_norm carries eps 1e-5 (the same torchao
    TODO) and folds that: a QaT graph trained with MobileNetV3's 1e-3 would be exported with other
    weights, and its small-variance channels' weights past their int8 range."""
    from torchao.quantization.pt2e import qat_utils

    table = dict(prepared.meta.get(BN_LITERALS, {}))
    fold = qat_utils.fold_bn_weights_into_conv_node

    def fold_own_eps(conv_node, conv_weight_node, conv_bias_node, bn_node, m, *args, **kwargs):
        _restore_literals(bn_node, table)
        return fold(conv_node, conv_weight_node, conv_bias_node, bn_node, m, *args, **kwargs)

    qat_utils.fold_bn_weights_into_conv_node = fold_own_eps
    try:
        yield
    finally:
        qat_utils.fold_bn_weights_into_conv_node = fold


def load_qat_state(prepared: torch.fx.GraphModule, state: dict) -> None:
    """Load a QaT run's state dict into a freshly prepared graph (strict: every entry must match)."""
    prepared.load_state_dict(state)


def to_eval(prepared: torch.fx.GraphModule) -> torch.fx.GraphModule:
    """torchao's move_exported_model_to_eval (BN on running statistics, dropout off), BN literals kept."""
    from torchao.quantization.pt2e import move_exported_model_to_eval

    move_exported_model_to_eval(prepared)
    restore_bn_literals(prepared)
    return prepared


def activation_fake_quants(prepared: torch.nn.Module) -> dict[str, torch.nn.Module]:
    """The per-tensor (activation) fake-quant modules of a QaT graph, by name."""
    from torchao.quantization.pt2e import FakeQuantizeBase

    return {name: m for name, m in prepared.named_modules()
            if isinstance(m, FakeQuantizeBase) and not m.is_per_channel}


def calibrate_activations(prepared: torch.fx.GraphModule, images: list[np.ndarray], percentile: float = 99.99,
                          hold: bool = False) -> int:
    """Set every activation fake-quant of the QaT graph PREPARED (in training mode) to the
    PERCENTILE range of its float input over IMAGES (HWC uint8 RGB), as static PTQ would; with
    HOLD, its observer then stays off, so QaT trains against those ranges. Returns how many were set."""
    from torchao.quantization.pt2e import disable_fake_quant, disable_observer, enable_fake_quant, enable_observer

    targets = activation_fake_quants(prepared)
    observers = {name: PercentileObserver(percentile=percentile, eps=2 ** -12, dtype=torch.quint8,
                                          quant_min=fq.activation_post_process.quant_min,
                                          quant_max=fq.activation_post_process.quant_max) for name, fq in targets.items()}
    hooks = [fq.register_forward_pre_hook(lambda mod, args, o=observers[name]: o(args[0].detach().float().cpu()))
             for name, fq in targets.items()]
    device = next(prepared.parameters()).device
    prepared.apply(disable_fake_quant)
    prepared.apply(disable_observer)
    to_eval(prepared)  # BN on running statistics, as at deployment
    try:
        with torch.no_grad():
            for rgb in images:
                prepared(torch.from_numpy(rgb).permute(2, 0, 1)[None].float().to(device))
    finally:
        for h in hooks:
            h.remove()
    for name, fq in targets.items():
        lo, hi = observers[name]._non_linear_param_search()
        obs = fq.activation_post_process
        obs.min_val.copy_(torch.minimum(torch.as_tensor(lo, dtype=torch.float32), torch.zeros(())))
        obs.max_val.copy_(torch.maximum(torch.as_tensor(hi, dtype=torch.float32), torch.zeros(())))
        scale, zero_point = obs.calculate_qparams()
        fq.scale.copy_(scale.reshape(fq.scale.shape))
        fq.zero_point.copy_(zero_point.reshape(fq.zero_point.shape))
    prepared.train()
    restore_bn_literals(prepared)
    prepared.apply(enable_fake_quant)
    prepared.apply(enable_observer)
    if hold:
        for fq in targets.values():
            fq.disable_observer()
    return len(targets)
