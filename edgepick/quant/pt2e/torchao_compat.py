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

2. Pattern tracing. The QaT conv-BN rewrite in `prepare_qat_pt2e`, the fold in `convert_pt2e`
   and the train/eval switches torch.export their match and replacement patterns again on every
   call, for every conv kind and flag combination: 12 exports in prepare and 96 in convert, about
   5 s and 20 s on a 2-core CPU, most of each QaT pass's own time. PyTorch PR #116440
   ("_fold_conv_bn_qat is taking a long time currently ... cache the patterns if possible") left
   it at that. `patterns_traced_once` keeps each traced pattern (by its code, the flags it closes
   over and its example inputs' shapes) and hands out copies, so every prepare, convert and switch
   after the first in a process traces none. And a pattern built around a conv kind that the graph
   being rewritten does not contain (convert tries conv1d, conv2d, conv_transpose1d and
   conv_transpose2d on every graph) cannot match anything in it: it is not traced at all, a
   one-node stand-in of that conv op takes its place; a conv2d-only model's first convert traces
   24 patterns instead of 96. The fuse in prepare and the fold in convert also skip their whole
   pass for such a kind (each pass rewrites the graph's dequantize nodes and regenerates its
   Python code about ten times, ~0.5 s for a DeepLabV3-MobileNetV3 graph, to match nothing).
   Tests that fail without it:
   tests/quant/test_torchao_compat.py::test_a_pattern_is_traced_once_per_flags_and_shapes_and_handed_out_as_copies
   and ::test_patterns_of_conv_kinds_the_graph_lacks_are_not_traced (what the stand-in rests on:
   ::test_torchaos_convert_patterns_call_their_conv_op) and
   ::test_per_kind_rewrites_for_conv_kinds_the_graph_lacks_are_skipped_with_the_same_result;
   every QaT test in tests/quant runs on
   the cached patterns.
   Delete when torchao caches its patterns and skips conv kinds a graph lacks (both its fuse and fold).
"""

from __future__ import annotations

import contextlib
import copy
import types
from collections.abc import Callable, Iterator
from typing import Any

import torch

BN_LITERALS = "edgepick_bn_literals"  # GraphModule.meta key: running_var name -> the module's (eps, momentum)
MODE = "edgepick_training"  # GraphModule.meta key: the mode set_mode last put the graph in (True: training)


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
    """torchao's train/eval rewrite of PREPARED, then its BatchNorms' own literals back. A graph this
    function has put in that mode already is left as it is: the rewrite is a pattern search over the
    whole graph (about a second on a CPU) that would find nothing to change."""
    from torchao.quantization.pt2e import move_exported_model_to_eval, move_exported_model_to_train

    if prepared.meta.get(MODE) == training:
        return prepared
    with patterns_traced_once(prepared):  # the switch traces its dropout and BatchNorm patterns too
        (move_exported_model_to_train if training else move_exported_model_to_eval)(prepared)
    restore_bn_literals(prepared)
    prepared.meta[MODE] = training
    return prepared


_TRACED: dict[tuple, torch.fx.GraphModule] = {}


def _shape_of(value: Any) -> Any:
    """What a traced pattern depends on in a value: a tensor's shape, dtype and device, else the value."""
    if isinstance(value, torch.Tensor):
        return ("tensor", tuple(value.shape), value.dtype, value.device.type)
    if isinstance(value, (tuple, list)):
        return tuple(_shape_of(v) for v in value)
    return value


_CONV_KINDS = ("conv1d", "conv2d", "conv3d", "conv_transpose1d", "conv_transpose2d", "conv_transpose3d")
_ANY_CONV = {"convolution", "_convolution", "convolution_overrideable"}  # ops that stand for any conv kind


def graph_ops(graph: torch.fx.GraphModule) -> frozenset[str]:
    """The names of the aten ops GRAPH calls (aten.conv2d.default -> "conv2d")."""
    return frozenset(n.target._opname for n in graph.graph.nodes
                     if n.op == "call_function" and isinstance(getattr(n.target, "_opname", None), str))


def _absent_conv_kind(pattern: Callable, ops: frozenset[str] | None) -> str | None:
    """The conv kind (a torch.nn.functional conv) that PATTERN is built around, when the graph's
    OPS show that it cannot match there; None when it might (or OPS is unknown)."""
    if ops is None or ops & _ANY_CONV:
        return None
    fn = getattr(pattern, "fn", pattern)  # torchao wraps each pattern function in a WrapperModule
    for cell in getattr(fn, "__closure__", None) or ():
        value = cell.cell_contents
        name = getattr(value, "__name__", None)
        if name in _CONV_KINDS and value is getattr(torch.nn.functional, name) and name not in ops:
            return name
    return None


def _stand_in(kind: str) -> torch.fx.GraphModule:
    """A pattern that matches nothing in a graph without the op KIND: that op alone."""
    graph = torch.fx.Graph()
    x, w = graph.placeholder("x"), graph.placeholder("w")
    packet = getattr(torch.ops.aten, kind)
    graph.output(graph.call_function(getattr(packet, packet.overloads()[0]), (x, w)))
    return torch.fx.GraphModule(torch.nn.Module(), graph)


def _cached(trace: Callable[..., torch.fx.GraphModule],
            ops: frozenset[str] | None = None) -> Callable[..., torch.fx.GraphModule]:
    """TRACE (torchao's _get_aten_graph_module_for_pattern) with its results kept and copied out;
    a pattern around a conv kind missing from OPS (the rewritten graph's ops) gets a stand-in."""
    def traced_once(pattern: Callable, example_inputs: tuple, is_cuda: bool = False, **kwargs: Any) -> torch.fx.GraphModule:
        kind = _absent_conv_kind(pattern, ops)
        if kind is not None:
            return _stand_in(kind)
        fn = getattr(pattern, "fn", pattern)  # torchao wraps each pattern function in a WrapperModule
        try:
            key = (fn.__code__, tuple(_shape_of(c.cell_contents) for c in fn.__closure__ or ()),
                   _shape_of(tuple(example_inputs)), is_cuda, tuple(sorted((k, _shape_of(v)) for k, v in kwargs.items())))
            hash(key)
        except (AttributeError, TypeError, ValueError):  # not a plain function of hashable flags: trace it
            return trace(pattern, example_inputs, is_cuda, **kwargs)
        if key not in _TRACED:
            _TRACED[key] = trace(pattern, example_inputs, is_cuda, **kwargs)
        return copy.deepcopy(_TRACED[key])

    return traced_once


@contextlib.contextmanager
def patterns_traced_once(graph: torch.fx.GraphModule | None = None) -> Iterator[None]:
    """Within: torchao's pt2e pattern tracing served from a per-process cache, and no tracing at
    all for conv kinds that GRAPH (the graph torchao rewrites within) lacks (workaround 2)."""
    from torchao.quantization.pt2e import qat_utils, utils

    ops = None if graph is None else graph_ops(graph)
    original = utils._get_aten_graph_module_for_pattern
    helpers = {name: getattr(qat_utils, name) for name in _PER_KIND_HELPERS}
    qat_utils._get_aten_graph_module_for_pattern = utils._get_aten_graph_module_for_pattern = _cached(original, ops)
    for name, helper in helpers.items():
        setattr(qat_utils, name, _skipping_absent_kinds(helper, ops))
    try:
        yield
    finally:
        qat_utils._get_aten_graph_module_for_pattern = utils._get_aten_graph_module_for_pattern = original
        for name, helper in helpers.items():
            setattr(qat_utils, name, helper)


# torchao's conv-BN rewrites that run once per conv kind, on the whole graph: a pass for a kind the graph
# lacks matches nothing, but still rewrites the graph's dequantize nodes and regenerates its code about
# ten times (torch.fx recompiles the graph after every pattern it tries).
_PER_KIND_HELPERS = ("_fuse_conv_bn_qat_helper", "_fold_conv_bn_qat_helper")


def _skipping_absent_kinds(helper: Callable[..., torch.fx.GraphModule],
                           ops: frozenset[str] | None) -> Callable[..., torch.fx.GraphModule]:
    """HELPER (m, conv_fn, example_inputs, is_cuda), returning M as it is when conv_fn's kind is one
    the graph's OPS show it lacks."""
    def helper_for_present_kinds(m: torch.fx.GraphModule, conv_fn: Callable, *args: Any, **kwargs: Any
                                 ) -> torch.fx.GraphModule:
        kind = getattr(conv_fn, "__name__", None)
        if ops is not None and not ops & _ANY_CONV and kind in _CONV_KINDS and kind not in ops:
            return m
        return helper(m, conv_fn, *args, **kwargs)

    return helper_for_present_kinds
