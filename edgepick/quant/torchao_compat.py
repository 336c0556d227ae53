"""Workarounds for torchao's pt2e QaT, all in this module (seen with torchao 0.18.0, torch 2.13).

1. BatchNorm eps and momentum. torchao's QaT conv-BN rewrite, its train/eval switches
   (`move_exported_model_to_train/eval`) and the BN fold in `convert_pt2e` write F.batch_norm's
   defaults (eps 1e-5, momentum 0.1) into the graph: "TODO: allow setting eps" in
   torchao/quantization/pt2e/qat_utils.py (no upstream issue found). MobileNetV3 uses eps 1e-3,
   so a float checkpoint would run QaT with other BN arithmetic than it was trained with, and a
   QaT graph would be folded into other weights (small-variance channels past their int8 range).
   Kept in ONE place: the graph's own train/eval switch (`install_train_eval`, `set_mode`) puts
   each BN's own literals back after torchao's rewrite, and `bn_folds_with_own_eps` does it for
   the fold in convert. Tests that fail without it:
   tests/quant/test_qat.py::test_qat_graph_keeps_the_models_batchnorm_eps and
   ::test_converted_qat_graph_computes_what_qat_trained.
   Delete when torchao takes eps/momentum from the BN node it replaces (check that TODO).
"""

from __future__ import annotations

import contextlib
import types

import torch

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


def install_train_eval(prepared: torch.fx.GraphModule, model: torch.nn.Module, prefix: str) -> None:
    """Give a prepared graph train()/eval() that switch BN and dropout the torchao way AND keep each
    BatchNorm's own eps/momentum (those of MODEL's modules, named PREFIX + name in the graph)."""
    prepared.meta[BN_LITERALS] = {f"{prefix}{name}.running_var": (m.eps, m.momentum)
                                  for name, m in model.named_modules()
                                  if isinstance(m, torch.nn.modules.batchnorm._BatchNorm)}

    def train(self, mode: bool = True):
        return set_mode(self, training=mode)

    def eval(self):
        return set_mode(self, training=False)

    prepared.train = types.MethodType(train, prepared)
    prepared.eval = types.MethodType(eval, prepared)
    restore_bn_literals(prepared)  # the QaT conv-BN rewrite of prepare already wrote the defaults


def set_mode(prepared: torch.fx.GraphModule, training: bool) -> torch.fx.GraphModule:
    """torchao's train/eval rewrite of PREPARED, then its BatchNorms' own literals back."""
    from torchao.quantization.pt2e import move_exported_model_to_eval, move_exported_model_to_train

    (move_exported_model_to_train if training else move_exported_model_to_eval)(prepared)
    restore_bn_literals(prepared)
    return prepared
