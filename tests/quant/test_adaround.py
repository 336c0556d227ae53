"""AdaRound: the learnt rounding lowers each conv's output error against round-to-nearest, stays one
grid step from the float weight, and the pass records it."""

from __future__ import annotations

import copy
import json

import numpy as np
import onnx
import pytest
import torch
from torch import nn

from edgepick.errors import ParameterError
from edgepick.geometry import Size
from edgepick.quant import Pt2eOptions, PtqMethods, QuantConfig, convert, methods, prepare, quantize_module_static
from edgepick.quant.pt2e.adaround import adaround
from edgepick.quant.pt2e.bias_correction import int8_convs
from edgepick.quant.pt2e.graph import as_input
from edgepick.quant.pt2e.overflow import float_weight

SIZE = Size(32, 24)


class Small(nn.Module):
    def __init__(self):
        super().__init__()
        torch.manual_seed(0)
        self.a = nn.Conv2d(3, 16, 3, padding=1)
        self.dw = nn.Conv2d(16, 16, 3, padding=1, groups=16)
        self.b = nn.Conv2d(16, 4, 1)

    def forward(self, x):
        return self.b(torch.relu(self.dw(torch.relu(self.a(x / 255.0)))))


@pytest.fixture(scope="module")
def inputs():
    rng = np.random.default_rng(0)
    return [as_input(rng.integers(0, 256, (*SIZE.hw, 3), dtype=np.uint8)) for _ in range(6)]


def _graphs(inputs):
    prepared = prepare(Small().eval(), QuantConfig(), SIZE, qat=False, pt2e=Pt2eOptions(hardswish_gate=False))
    with torch.no_grad():
        for x in inputs:
            prepared(x)
    return copy.deepcopy(prepared), convert(prepared, snap_biases=False)


def _codes(converted):
    from operator import attrgetter

    return {name: attrgetter(q.args[1].args[0].target)(converted).clone() for name, q in int8_convs(converted).items()}


@pytest.mark.slow
def test_adaround_lowers_the_output_error_of_round_to_nearest(inputs):
    reference, converted = _graphs(inputs)
    nearest = _codes(converted)
    report = adaround(reference, converted, inputs, seconds=60.0, steps=300)
    learnt = _codes(converted)
    assert set(report) == set(nearest)
    for name, r in report.items():
        assert r["error_adaround"] <= r["error_nearest"], (name, r)
    dense = [name for name in report if nearest[name].shape[1] > 1]
    assert all(report[n]["error_adaround"] < 0.9 * report[n]["error_nearest"] for n in dense), report
    from operator import attrgetter

    for name, q in int8_convs(converted).items():
        scale = attrgetter(q.args[1].args[1].target)(converted).view(-1, 1, 1, 1)
        w = float_weight(reference, name) / scale
        # every code is the float weight rounded down or up, and some differ from nearest rounding
        assert bool(((learnt[name] >= torch.floor(w) - 1e-6) & (learnt[name] <= torch.ceil(w) + 1e-6)).all())
    assert any(not torch.equal(nearest[n], learnt[n]) for n in dense)


def test_the_converted_model_follows_fp32_more_closely(inputs):
    reference, converted = _graphs(inputs)
    plain = copy.deepcopy(converted)
    adaround(reference, converted, inputs, seconds=60.0, steps=300)
    model = Small().eval()
    with torch.no_grad():
        error = {name: sum(float((g(x) - model(x)).pow(2).mean()) for x in inputs)
                 for name, g in (("nearest", plain), ("adaround", converted))}
    assert error["adaround"] < error["nearest"], error


@pytest.mark.slow
def test_a_pass_records_it(inputs, tmp_path):
    result = quantize_module_static(Small().eval(), inputs, tmp_path / "a.onnx",
                                    methods=PtqMethods(adaround=True, adaround_budget_s=2.0, equalize=True),
                                    progress=False)
    quant = json.loads({p.key: p.value for p in onnx.load(str(tmp_path / "a.onnx")).metadata_props}["edgepick.quant"])
    assert quant["adaround"] and quant["equalize"] and quant["adaround_convs"] >= 1 and quant["equalized_pairs"] == 2
    assert quant["measured_images"] == len(inputs)
    assert result.int8_convs == 3
    for seconds in (0, -1.0, float("nan")):
        with pytest.raises(ParameterError, match="adaround_budget_s"):
            PtqMethods(adaround_budget_s=seconds)
    with pytest.raises(ValueError, match="at least one"):
        reference, converted = _graphs(inputs)
        adaround(reference, converted, [], seconds=1.0)


def test_without_a_time_budget_every_conv_takes_the_steps_planned_from_the_models_size(inputs, monkeypatch, capsys):
    monkeypatch.setattr(methods, "WORK", 50 * 3 * methods.STEP_OVERHEAD)  # ~50 steps here: a short test
    monkeypatch.setenv("EDGEPICK_PROGRESS_S", "0")  # a progress line per conv
    reference, converted = _graphs(inputs)
    report = adaround(reference, converted, inputs, seconds=None, progress=True)
    assert "AdaRound: 3/3 conv" in capsys.readouterr().err  # the bar counts the convs, n of N
    model = Small()
    planned = methods.planned_steps(methods.STEP_OVERHEAD + c.weight.numel() for c in (model.a, model.dw, model.b))
    assert {r["steps"] for r in report.values()} == {planned} and 20 < planned < 50
