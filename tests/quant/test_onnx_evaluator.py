"""What int8 graphs are measured against, and a caller's own judge of them (quant/onnx/evaluator.py)."""

from __future__ import annotations

import numpy as np
import pytest

from edgepick.errors import ParameterError
from edgepick.quant.config import PtqMethods
from edgepick.quant.onnx.accuracy import FidelityBudget
from edgepick.quant.onnx.evaluator import JUDGED, Evaluator, judged
from edgepick.quant.onnx.static import quantize_onnx_static


def test_a_graph_measured_again_is_not_run_again_and_a_changed_one_is(faint, monkeypatch):
    """The recipe measures a graph again after trying another: the last two graphs' outputs are kept (while
    fp32's are small), keyed by the graph's bytes, so a graph changed in place is run afresh."""
    import onnx

    from edgepick.quant.fidelity import Task, TaskKind
    from edgepick.quant.onnx import evaluator as accuracy

    path, _, check, reference, _ = faint
    model = onnx.load(str(path))
    evaluator = accuracy.evaluator_for(path, model, check, {"output": Task(TaskKind.RAW)}, False)
    other = onnx.load(str(path))
    other.graph.node[0].name = "renamed"  # another graph, the same outputs
    first = evaluator.half_errors(model)
    fidelity = evaluator.fidelity(model)
    assert evaluator.graphs == 1 and first == (0.0, 0.0)
    evaluator.fidelity(other)
    assert evaluator.fidelity(model) == fidelity and evaluator.half_errors(model) == first and evaluator.graphs == 2
    weight = next(i for i in model.graph.initializer if len(i.dims) == 4)
    values = onnx.numpy_helper.to_array(weight) * 0.5
    weight.CopyFrom(onnx.numpy_helper.from_array(values, weight.name))  # changed in place: run again
    assert evaluator.half_errors(model)[0] > 0 and evaluator.graphs == 3
    monkeypatch.setattr(accuracy, "KEPT_OUTPUT_BYTES", 0)  # fp32's outputs too large to keep another's beside them
    fresh = accuracy.evaluator_for(path, onnx.load(str(path)), check, {"output": Task(TaskKind.RAW)}, False)
    fresh.fidelity(other)
    fresh.fidelity(other)
    assert fresh.graphs == 2 and fresh.kept == []


def test_a_judge_gives_a_share_of_decisions_or_is_refused():
    assert judged(0.75).agreement == 0.75 and judged(1).to_dict() == {"task": "judge", "agreement": 1.0}
    for bad in (1.5, -0.1, "0.9", True, None):
        with pytest.raises(ParameterError, match="^judge: must return the share"):
            judged(bad)
    with pytest.raises(ParameterError, match="judge needs min_agreement"):
        FidelityBudget(min_sqnr_db=20.0, judge=lambda ref, got: 1.0)


def test_the_budget_holds_the_judges_decisions_not_the_outputs_own(faint, capsys):
    """A judge sees fp32's outputs and the int8 graph's on every check tensor; with one, the budget's
    agreement is its share (the outputs' tasks are reported, not held to it)."""
    path, calib, _, _, tmp = faint
    seen = []

    def sign_of_the_mean(reference, outputs):  # a decision of the caller's own post-processing
        seen.append(len(outputs))
        return float(np.mean([np.sign(r[0].mean()) == np.sign(o[0].mean()) for r, o in zip(reference, outputs)]))

    methods = PtqMethods(bias_correction="none")
    agreed = quantize_onnx_static(path, calib, tmp / "judged.onnx", methods=methods, progress=False,
                                  budget=FidelityBudget(min_agreement=0.999, judge=sign_of_the_mean))
    record = agreed.quant["accuracy_aware"]
    assert record["before"][JUDGED]["agreement"] < 0.999  # the faint channel lost: the mean's sign flips
    assert record["met"] and record["after"][JUDGED] == {"task": "judge", "agreement": 1.0}
    assert record["float_tensors"] == ["input"]
    assert set(seen) == {record["check_tensors"]} and JUDGED not in agreed.fidelity  # the file reports its outputs

    def never(reference, outputs):
        return 0.0

    missed = quantize_onnx_static(path, calib, tmp / "never.onnx", methods=methods, progress=False,
                                  budget=FidelityBudget(min_agreement=0.5, judge=never, max_float=2))
    assert not missed.quant["accuracy_aware"]["met"]
    assert any(line.startswith("edgepick: warning: the budget is not met") for line in capsys.readouterr().err.splitlines())


def test_adaround_meeting_the_budget_is_kept_where_it_is_not_closer(faint):
    """The faint model's lost channel is no rounding's to bring back (AdaRound's file is not
    closer); a judge satisfied from its second graph on, AdaRound's, makes that file meet the
    budget all-int8: it is the answer, with no activation left float."""
    path, calib, _, _, tmp = faint
    calls = []

    def second_graph_on(reference, outputs):
        calls.append(len(outputs))
        return 0.0 if len(calls) == 1 else 1.0

    result = quantize_onnx_static(path, calib, tmp / "met.onnx", methods=PtqMethods(bias_correction="none"),
                                  progress=False, budget=FidelityBudget(min_agreement=0.99, judge=second_graph_on))
    tried = result.quant["adaround_first"]
    before, after = tried["error_before"], tried["error_after"]
    assert not (sum(after) < sum(before) and max(after) < max(before))  # not closer
    assert tried["met"] and tried["kept"] and tried["why"] == "budget" and "adaround_convs" in result.quant
    assert result.quant["accuracy_aware"]["met"] and result.quant["accuracy_aware"]["float_tensors"] == []


def test_closer_on_the_whole_and_the_worse_half_keeps_a_large_gain_that_one_half_does_not_share():
    """A graph much closer on one half and a little further on the other is kept by the worse-half
    rule (AdaRound's) and not by the both-halves rule; one a little closer on the sum while its worse
    half rises is kept by neither."""
    errors = {"before": (0.575, 0.262), "large gain": (0.196, 0.269), "worse half down a little": (0.55, 0.27),
              "even": (0.30, 0.30), "even, worse half up": (0.28, 0.31)}

    class Scripted(Evaluator):
        def half_errors(self, model):
            return errors[model]

    evaluator = Scripted(None, [], [], [], {})
    assert evaluator.closer("before", "large gain", worse_half=True)["kept"]
    assert not evaluator.closer("before", "large gain")["kept"]
    assert evaluator.closer("before", "worse half down a little", worse_half=True)["kept"]
    assert not evaluator.closer("even", "even, worse half up", worse_half=True)["kept"]
    assert evaluator.closer("before", "large gain", worse_half=True)["error_after"] == [0.196, 0.269]
