"""quant/torchao_compat.py workaround 2: torchao's traced pt2e patterns kept for the process, handed
out as copies, one trace per pattern function, flags and input shapes. (Workaround 1, the BatchNorm
literals, is tested through the QaT graph in tests/quant/test_qat.py.)"""

from __future__ import annotations

import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("torchao")

from torchao.quantization.pt2e.export_utils import WrapperModule  # noqa: E402

from edgepick.quant.torchao_compat import _cached, patterns_traced_once  # noqa: E402


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
