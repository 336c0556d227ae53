"""quant/pt2e/torchao_compat.py workaround 2: torchao's traced pt2e patterns kept for the process, handed
out as copies, one trace per pattern function, flags and input shapes; and set_mode's rewrite only on
a change of mode. (Workaround 1, the BatchNorm literals, is tested through the QaT graph in
tests/quant/test_qat.py.)"""

from __future__ import annotations

import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("torchao")

from torchao.quantization.pt2e.export_utils import WrapperModule  # noqa: E402

from edgepick.quant.pt2e.torchao_compat import _cached, patterns_traced_once  # noqa: E402


def _pattern(flag: bool) -> WrapperModule:
    """A pattern as torchao builds one: a fresh closure over its flags, in a WrapperModule."""
    def pattern(x):
        return x + 1 if flag else x * 2
    return WrapperModule(pattern)


def test_a_pattern_is_traced_once_per_flags_and_shapes_and_handed_out_as_copies():
    calls = []

    def trace(pattern, example_inputs, is_cuda=False, **kwargs):
        calls.append(pattern)
        return torch.fx.symbolic_trace(pattern.fn)

    traced = _cached(trace)
    first = traced(_pattern(True), (torch.randn(1, 3),))
    again = traced(_pattern(True), (torch.randn(1, 3),))  # a new closure, other values: the same pattern
    assert len(calls) == 1 and again is not first and again.code == first.code
    again.graph.output(again.graph.placeholder("y"))  # a caller's edit ...
    again.recompile()
    assert again.code != first.code
    assert traced(_pattern(True), (torch.randn(1, 3),)).code == first.code  # ... stays its own
    traced(_pattern(False), (torch.randn(1, 3),))  # another flag
    traced(_pattern(True), (torch.randn(2, 3),))  # another shape
    traced(_pattern(True), (torch.randn(1, 3),), scale=torch.ones(2))  # another keyword input
    assert len(calls) == 4


def test_the_cache_serves_torchaos_own_tracing_only_within():
    from torchao.quantization.pt2e import qat_utils, utils

    original = utils._get_aten_graph_module_for_pattern
    with patterns_traced_once():
        assert qat_utils._get_aten_graph_module_for_pattern is utils._get_aten_graph_module_for_pattern
        assert utils._get_aten_graph_module_for_pattern is not original
    assert qat_utils._get_aten_graph_module_for_pattern is original and utils._get_aten_graph_module_for_pattern is original


@pytest.mark.parametrize("kind", ["conv1d", "conv2d", "conv_transpose1d", "conv_transpose2d"])
def test_torchaos_convert_patterns_call_their_conv_op(kind):
    """What the stand-in rests on: each conv kind's fold pattern calls that conv op, so it cannot
    match a graph without it."""
    from torchao.quantization.pt2e import qat_utils, utils

    from edgepick.quant.pt2e.torchao_compat import _absent_conv_kind, graph_ops

    fn = getattr(torch.nn.functional, kind)
    pattern = qat_utils._get_quantized_qat_conv_bn_pattern(True, True, True, fn, False)
    shape = (1, 1, 3) if kind.endswith("1d") else (1, 1, 3, 3)
    example = (torch.randn(*shape), torch.randn(*shape[:2], *[1] * (len(shape) - 2)), *[torch.randn(1)] * 4)
    kwargs = qat_utils._get_quantized_conv_bn_example_inputs_kwargs(True, True, True, False)
    assert kind in graph_ops(utils._get_aten_graph_module_for_pattern(pattern, example, False, **kwargs))
    assert _absent_conv_kind(pattern, frozenset({"conv3d"})) == kind
    assert _absent_conv_kind(pattern, frozenset({kind})) is None
    assert _absent_conv_kind(pattern, frozenset({"convolution"})) is None  # the generic op: might be any kind
    assert _absent_conv_kind(pattern, None) is None


@pytest.mark.slow
def test_patterns_of_conv_kinds_the_graph_lacks_are_not_traced(monkeypatch):
    from torchao.quantization.pt2e import utils
    from torchao.quantization.pt2e.quantize_pt2e import convert_pt2e, prepare_qat_pt2e

    from edgepick.quant.config import QatOptions, QuantConfig
    from edgepick.quant.pt2e import torchao_compat
    from edgepick.quant.pt2e.quantizer import EdgeQuantizer

    net = torch.nn.Sequential(torch.nn.Conv2d(3, 4, 3), torch.nn.BatchNorm2d(4), torch.nn.ReLU(),
                              torch.nn.Conv2d(4, 2, 1, bias=False), torch.nn.BatchNorm2d(2))
    example = (torch.randn(2, 3, 8, 8),)
    prepared = prepare_qat_pt2e(torch.export.export(net.train(), example).module(), EdgeQuantizer(QuantConfig(), QatOptions()))
    prepared.graph.eliminate_dead_code()  # the fake-quants of BN's batch counter, as edgepick's prepare does
    prepared.recompile()
    prepared(*example)
    original, kinds = utils._get_aten_graph_module_for_pattern, set()

    def traced(pattern, *args, **kwargs):
        fn = getattr(pattern, "fn", pattern)
        kinds.update(getattr(c.cell_contents, "__name__", None) for c in fn.__closure__ or ())
        return original(pattern, *args, **kwargs)

    monkeypatch.setattr(torchao_compat, "_TRACED", {})  # nothing cached: every pattern used is traced here
    monkeypatch.setattr(utils, "_get_aten_graph_module_for_pattern", traced)
    with patterns_traced_once(prepared):
        converted = convert_pt2e(prepared)
    assert kinds & set(torchao_compat._CONV_KINDS) == {"conv2d"}
    assert "conv2d" in torchao_compat.graph_ops(converted) and "batch_norm" not in torchao_compat.graph_ops(converted)


@pytest.mark.slow
def test_per_kind_rewrites_for_conv_kinds_the_graph_lacks_are_skipped_with_the_same_result(monkeypatch):
    """convert's conv-BN fold runs once per conv kind over the whole graph; under the workaround it
    runs for conv2d only, and the converted graph (ops, tensors, outputs) is what the fold of every
    kind makes (patterns served from the cache both times, so only the skip differs)."""
    import copy

    from torchao.quantization.pt2e import qat_utils
    from torchao.quantization.pt2e.quantize_pt2e import convert_pt2e, prepare_qat_pt2e

    from edgepick.quant.config import QatOptions, QuantConfig
    from edgepick.quant.pt2e import torchao_compat
    from edgepick.quant.pt2e.quantizer import EdgeQuantizer

    net = torch.nn.Sequential(torch.nn.Conv2d(3, 4, 3), torch.nn.BatchNorm2d(4), torch.nn.ReLU(),
                              torch.nn.Conv2d(4, 2, 1, bias=False), torch.nn.BatchNorm2d(2))
    example = (torch.randn(2, 3, 8, 8),)
    prepared = prepare_qat_pt2e(torch.export.export(net.train(), example).module(), EdgeQuantizer(QuantConfig(), QatOptions()))
    prepared.graph.eliminate_dead_code()
    prepared.recompile()
    prepared(*example)
    with monkeypatch.context() as without_skip:
        without_skip.setattr(torchao_compat, "_PER_KIND_HELPERS", ())
        with patterns_traced_once(prepared):
            alone = convert_pt2e(copy.deepcopy(prepared))
    original, kinds = qat_utils._fold_conv_bn_qat_helper, []

    def folding(m, conv_fn, *args, **kwargs):
        kinds.append(conv_fn.__name__)
        return original(m, conv_fn, *args, **kwargs)

    monkeypatch.setattr(qat_utils, "_fold_conv_bn_qat_helper", folding)
    with patterns_traced_once(prepared):
        converted = convert_pt2e(prepared)
    assert kinds == ["conv2d"]
    def ops(graph):  # node names aside (torch.fx numbers them by what it saw before)
        return [(n.op, str(n.target) if n.op != "get_attr" else "attr") for n in graph.graph.nodes]

    assert ops(converted) == ops(alone)
    ours, theirs = list(converted.state_dict().values()), list(alone.state_dict().values())
    assert len(ours) == len(theirs) and all(torch.equal(a, b) for a, b in zip(ours, theirs))
    assert torch.equal(converted(*example), alone(*example))


def test_a_graph_is_not_switched_into_the_mode_it_is_in(monkeypatch):
    """set_mode runs torchao's train/eval rewrite (a pattern search over the whole graph) only when
    the mode changes; a deep copy keeps the mode its graph is in."""
    import copy

    import torchao.quantization.pt2e as pt2e
    from torchao.quantization.pt2e.quantize_pt2e import prepare_qat_pt2e

    from edgepick.quant.config import QatOptions, QuantConfig
    from edgepick.quant.pt2e.quantizer import EdgeQuantizer
    from edgepick.quant.pt2e.torchao_compat import set_mode

    net = torch.nn.Sequential(torch.nn.Conv2d(3, 4, 3), torch.nn.BatchNorm2d(4), torch.nn.ReLU())
    example = (torch.randn(2, 3, 8, 8),)
    prepared = prepare_qat_pt2e(torch.export.export(net.train(), example).module(), EdgeQuantizer(QuantConfig(), QatOptions()))
    calls = []

    def counted(name: str):
        rewrite = getattr(pt2e, name)
        return lambda graph: calls.append(name) or rewrite(graph)

    for name in ("move_exported_model_to_train", "move_exported_model_to_eval"):
        monkeypatch.setattr(pt2e, name, counted(name))

    def training_flags(graph) -> set:
        return {n.args[5] for n in graph.graph.nodes if n.target == torch.ops.aten.batch_norm.default}

    assert training_flags(prepared) == {True}
    for mode, flags, rewrites in ((False, {False}, 1), (False, {False}, 1), (True, {True}, 2), (True, {True}, 2),
                                  (False, {False}, 3)):
        set_mode(prepared, training=mode)
        assert training_flags(prepared) == flags and len(calls) == rewrites, (mode, calls)
    twin = copy.deepcopy(prepared)
    set_mode(twin, training=False)
    assert len(calls) == 3 and training_flags(twin) == {False}
    set_mode(twin, training=True)
    assert calls[-1] == "move_exported_model_to_train" and training_flags(twin) == {True}
