"""Fidelity first: which activations to leave float, found by measuring (quant/onnx/accuracy.py)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from edgepick.errors import ParameterError
from edgepick.quant.config import OnnxOptions, PtqMethods, QuantConfig
from edgepick.quant.onnx.accuracy import FidelityBudget, slower_than_fp32
from edgepick.quant.onnx.static import quantize_onnx_static
from tests.quant.onnx_models import faint_channel_inputs, faint_channel_model


def _sqnr(path, xs, reference, engine: str) -> float:
    """The output's SQNR in dB of the model at PATH on XS against fp32's REFERENCE, run by ENGINE."""
    if engine == "onnxruntime":
        import onnxruntime as ort

        session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
        got = [session.run(None, {"input": x})[0] for x in xs]
    else:
        import openvino as ov

        from edgepick.runtime.session import openvino_config

        # float parts in f32, as the runtime runs them (OpenVINO's own default is bf16 where the CPU has it)
        compiled = ov.Core().compile_model(str(path), "CPU", openvino_config(2))
        got = [compiled({0: x})[compiled.outputs[0]] for x in xs]
    signal = sum(float((r.astype(np.float64) ** 2).sum()) for r in reference)
    noise = sum(float(((r.astype(np.float64) - g) ** 2).sum()) for r, g in zip(reference, got))
    return 10 * np.log10(signal / noise)


@pytest.mark.slow
def test_a_faint_channel_is_named_and_the_accuracy_aware_mode_leaves_it_float(faint, capsys):
    path, calib, check, reference, tmp = faint
    plain = quantize_onnx_static(path, calib, tmp / "plain.onnx", methods=PtqMethods(bias_correction="none"))
    assert plain.fidelity["output"]["sqnr_db"] < 10  # the faint channel is lost on the input's uint8 grid
    # one line (another may say the file runs slower than fp32 on this machine)
    warning, = [line for line in capsys.readouterr().err.splitlines() if "far from fp32's" in line]
    assert warning.startswith("edgepick: warning: the int8 outputs are far from fp32's") and "input (+" in warning
    assert plain.quant["fidelity_warning"] in warning
    fixed = quantize_onnx_static(path, calib, tmp / "fixed.onnx", methods=PtqMethods(bias_correction="none"), progress=False,
                                 budget=FidelityBudget(min_sqnr_db=25.0))
    record = fixed.quant["accuracy_aware"]
    assert record["float_tensors"] == ["input"] and record["met"]  # the fewest: one tensor
    assert record["check_tensors"] == 8  # 16 calibration tensors leave none for more checks after AdaRound's
    # AdaRound was tried first: no weight rounding brings back a channel lost on the input's grid
    tried = fixed.quant["adaround_first"]
    assert isinstance(tried["kept"], bool) and len(tried["error_before"]) == len(tried["error_after"]) == 2
    assert fixed.fidelity["output"]["sqnr_db"] >= 25.0
    assert fixed.int8_convs == fixed.convs == 2  # the convs keep int8 weights; only the input stays float
    speed = record["speed"]
    assert speed["all_int8_ms"] > 0 and speed["slowdown"] == pytest.approx(speed["kept_float_ms"] / speed["all_int8_ms"],
                                                                          abs=1e-3)
    assert speed["speedup_vs_fp32"] == pytest.approx(speed["fp32_ms"] / speed["kept_float_ms"], abs=1e-3)
    for engine in ("onnxruntime", "openvino"):
        assert _sqnr(fixed.out, check, reference, engine) > _sqnr(plain.out, check, reference, engine) + 15, engine


def test_a_file_far_from_fp32_is_made_again_with_adaround_by_default(faint, tmp_path):
    """Under the SQNR floor, the default pass tries AdaRound and keeps it only when closer on the
    check tensors and on their worse half (the record says which and why); adaround_if_far=False
    does not try."""
    path, calib, _, _, _ = faint
    methods = PtqMethods(bias_correction="none")
    tried = quantize_onnx_static(path, calib, tmp_path / "tried.onnx", methods=methods, progress=False)
    record = tried.quant["adaround_first"]
    assert record["why"] == "sqnr_floor" and len(record["error_before"]) == len(record["error_after"]) == 2
    before, after = record["error_before"], record["error_after"]
    assert record["kept"] == (sum(after) < sum(before) and max(after) < max(before))
    assert tried.quant["adaround"] is False  # the methods asked for; what AdaRound did, where kept, beside them
    assert ("adaround_convs" in tried.quant) == record["kept"]
    untried = quantize_onnx_static(path, calib, tmp_path / "untried.onnx", methods=methods,
                                   options=OnnxOptions(adaround_if_far=False), progress=False)
    assert "adaround_first" not in untried.quant and untried.fidelity["output"]["sqnr_db"] < 10
    assert tried.fidelity["output"]["sqnr_db"] >= untried.fidelity["output"]["sqnr_db"] - 0.05 or not record["kept"]


def test_adaround_is_kept_where_it_brings_a_file_back_over_the_floor(tmp_path):
    """Weights half an int8 step from the grid: nearest rounding moves the output by about itself
    (under 10 dB), AdaRound's file is kept and lands over the floor; without it the file stays under."""
    from tests.quant.onnx_models import half_step_inputs, half_step_model

    path, calib, methods = half_step_model(tmp_path / "half.onnx"), half_step_inputs(48), PtqMethods(bias_correction="none")
    tried = quantize_onnx_static(path, calib, tmp_path / "tried.onnx", methods=methods, progress=False)
    untried = quantize_onnx_static(path, calib, tmp_path / "untried.onnx", methods=methods,
                                   options=OnnxOptions(adaround_if_far=False), progress=False)
    assert tried.quant["adaround_first"]["kept"] and tried.quant["adaround_first"]["why"] == "sqnr_floor"
    assert tried.quant["adaround_convs"] == 1 and "fidelity_warning" not in tried.quant
    assert tried.fidelity["output"]["sqnr_db"] >= 10 > untried.fidelity["output"]["sqnr_db"]
    assert "fidelity_warning" in untried.quant


@pytest.mark.slow
def test_keeping_a_node_float_never_lowers_fidelity_on_either_engine(faint):
    path, calib, check, reference, tmp = faint
    methods = PtqMethods(bias_correction="none")
    plain = quantize_onnx_static(path, calib, tmp / "p.onnx", QuantConfig(calib_method="minmax"), methods,
                                 progress=False)
    for node in ("conv", "relu", "head"):
        kept = quantize_onnx_static(path, calib, tmp / f"{node}.onnx",
                                    QuantConfig(calib_method="minmax", keep_float=(node,)), methods, progress=False)
        for engine in ("onnxruntime", "openvino"):
            assert _sqnr(kept.out, check, reference, engine) >= _sqnr(plain.out, check, reference, engine) - 0.05, \
                (node, engine)
    conv = quantize_onnx_static(path, calib, tmp / "c.onnx", QuantConfig(calib_method="minmax", keep_float=("conv",)),
                                methods, progress=False)
    assert conv.fidelity["output"]["sqnr_db"] > 25  # the conv reads the input's float values


def test_the_budget_is_checked_on_more_tensors_where_the_calibration_leaves_them(faint):
    path, _, _, _, tmp = faint
    calib = faint_channel_inputs(48, seed=3)  # 16x16 inputs: 32 for AdaRound to fit on, 16 to check on
    result = quantize_onnx_static(path, calib, tmp / "checked.onnx", methods=PtqMethods(bias_correction="none"),
                                  progress=False, budget=FidelityBudget(min_sqnr_db=-100.0))
    assert result.quant["accuracy_aware"]["check_tensors"] == 16 and result.quant["accuracy_aware"]["met"]


def test_a_budget_not_met_is_said_in_one_line(faint, capsys):
    path, calib, _, _, tmp = faint
    result = quantize_onnx_static(path, calib, tmp / "short.onnx", methods=PtqMethods(bias_correction="none"),
                                  progress=False, budget=FidelityBudget(min_sqnr_db=200.0, max_float=1))
    assert not result.quant["accuracy_aware"]["met"]
    warnings = [line for line in capsys.readouterr().err.splitlines() if line.startswith("edgepick: warning: the budget")]
    assert warnings == [line for line in warnings if line.startswith(  # one line; a second may say the file is slower than fp32
        "edgepick: warning: the budget is not met on the 8 check tensors (1 of at most 1 activations float)")], warnings
    assert len(warnings) == 1


def test_an_answer_slower_than_fp32_is_said_in_one_line():
    """The accuracy-aware answer's timing against fp32 (`speed_cost`'s record): a warning only where
    the float activations have cost all of int8's gain and more."""
    speed = {"fp32_ms": 10.0, "all_int8_ms": 5.0, "kept_float_ms": 10.87, "slowdown": 2.174, "speedup_vs_fp32": 0.92,
             "threads": 2}
    assert slower_than_fp32(speed, 159) == (
        "with 159 activations float the file runs at 0.92x fp32's speed on onnxruntime on this machine (10.87 ms "
        "against 10 ms, 2 threads): a lower budget keeps fewer float, or the float model serves better")
    assert slower_than_fp32({**speed, "kept_float_ms": 8.0, "speedup_vs_fp32": 1.25}, 159) is None
    assert slower_than_fp32({}, 0) is None  # all int8: nothing was timed


def test_where_the_budget_is_not_met_the_answer_is_the_graph_closest_by_its_own_measure(faint):
    """A judge whose measure the outputs' error does not follow (the share of output values far from
    fp32's, so closer outputs score lower): the search leaves the input float, closer by the error,
    and the answer is the all-int8 graph, which the budget's own measure ranks first. With a judge
    that follows the error the float input stays (and meets it); with one that ranks every graph
    alike, the search's last graph stays, the closest by the error."""
    path, calib, _, _, tmp = faint

    def share_close(reference, got, kind):
        close = [float(np.mean(np.abs(r[0] - g[0]) <= 0.05 * np.abs(r[0]).max())) for r, g in zip(reference, got)]
        return {"far": 1.0 - float(np.mean(close)), "close": float(np.mean(close)), "alike": 0.5}[kind]

    for kind in ("far", "close", "alike"):
        budget = FidelityBudget(min_agreement=1.0, judge=lambda r, g, kind=kind: share_close(r, g, kind), max_float=1)
        record = quantize_onnx_static(path, calib, tmp / f"judged-{kind}.onnx", methods=PtqMethods(bias_correction="none"),
                                      progress=False, budget=budget).quant["accuracy_aware"]
        if kind == "far":
            assert not record["met"] and record["closest_by_budget"] and record["float_tensors"] == []
            assert "speed" not in record and record["after"]["judged"]["agreement"] > 0.0
        else:
            assert record["met"] == (kind == "close") and "closest_by_budget" not in record, (kind, record)
            assert record["float_tensors"] == ["input"], (kind, record)


def test_the_search_stops_at_its_time_limit_with_what_it_found(faint, capsys):
    """A limit that passes at once: no activation is measured float, the record says where it
    stopped, the warning says why; without the limit the same budget leaves one float."""
    path, calib, _, _, tmp = faint
    methods = PtqMethods(bias_correction="none")
    budget = FidelityBudget(min_sqnr_db=200.0, max_float=1)
    stopped = quantize_onnx_static(path, calib, tmp / "stopped.onnx", methods=methods, progress=False,
                                   budget=replace(budget, max_seconds=1e-9)).quant["accuracy_aware"]
    assert stopped["stopped_at_max_seconds"] == 1e-9 and stopped["float_tensors"] == [] and not stopped["met"]
    assert stopped["scan"] == [] and stopped["search_s"] >= 0
    assert "(0 of at most 1 activations float, the search stopped after 1e-09 s)" in capsys.readouterr().err
    searched = quantize_onnx_static(path, calib, tmp / "searched.onnx", methods=methods, progress=False,
                                    budget=budget).quant["accuracy_aware"]
    assert "stopped_at_max_seconds" not in searched and searched["float_tensors"] == ["input"]
    assert searched["graphs_measured"] > stopped["graphs_measured"]


def test_a_budget_is_checked_on_creation():
    for kwargs, message in (({}, "min_agreement or min_sqnr_db"), ({"min_agreement": 1.5}, "min_agreement=1.5"),
                            ({"min_sqnr_db": float("nan")}, "min_sqnr_db=nan"),
                            ({"min_sqnr_db": 20, "max_float": 0}, "max_float=0"),
                            ({"min_sqnr_db": 20, "max_seconds": 0.0}, "max_seconds=0.0: must be a positive"),
                            ({"min_sqnr_db": 20, "max_seconds": float("inf")}, "max_seconds=inf")):
        with pytest.raises(ParameterError, match=message):
            FidelityBudget(**kwargs)


@pytest.mark.slow
@pytest.mark.parametrize("helps_both_halves", [True, False])
def test_a_float_activation_is_kept_only_when_it_brings_both_halves_of_the_check_tensors_closer(faint, helps_both_halves):
    """The accuracy-aware mode keeps the faint model's input float (the scan's best) only where that
    lowers the error on each half of the check tensors; a gain on one half alone is not taken."""
    import onnx

    from edgepick.quant.fidelity import Task, TaskKind
    from edgepick.quant.onnx.accuracy import restore_fidelity
    from edgepick.quant.onnx.evaluator import Evaluator, evaluator_for
    from edgepick.quant.onnx.floating import quantized_activations

    path, calib, check, _, tmp = faint
    plain = quantize_onnx_static(path, calib, tmp / "halves.onnx", methods=PtqMethods(bias_correction="none"),
                                 progress=False)
    float_model = onnx.load(str(path))
    real = evaluator_for(path, float_model, check, {"output": Task(TaskKind.RAW)}, nhwc=False)

    class Scripted(Evaluator):
        def half_errors(self, model):
            if "input" in quantized_activations(model):
                return 0.5, 0.5  # all int8
            return (0.01, 0.02) if helps_both_halves else (0.01, 0.9)

    evaluator = Scripted(**{f: getattr(real, f) for f in ("float_model", "reference", "inputs", "names", "tasks", "nhwc")})
    _, record = restore_fidelity(onnx.load(plain.out), evaluator, FidelityBudget(min_sqnr_db=25.0))
    assert record["scan"][0]["tensor"] == "input"
    assert record["float_tensors"] == (["input"] if helps_both_halves else [])


@pytest.mark.slow
def test_where_single_activations_are_not_enough_whole_regions_go_float_with_their_convs_weights(tmp_path, capsys):
    """A budget past what any few activations give (the net's own int8 SQNR + 8 dB): the mode goes
    on region by region, and the convs that then read nothing on the uint8 grid get their float
    weights. Judged by the outputs' error (a judge of the caller's own), the regions are the answer
    and the file counts their convs as float; judged by the SQNR, the answer is the graph tried
    closest to the budget by it: the single tensors where the regions do not raise the SQNR over
    theirs, else the regions (on this net a matter of tenths of a dB, which AdaRound's rounding,
    tried first, and the thread count move)."""
    from edgepick.quant.fidelity import balanced_error
    from tests.quant.onnx_models import calib_tensors, export_torch

    path, calib = export_torch(tmp_path / "net.onnx"), calib_tensors(16)
    plain = quantize_onnx_static(path, calib, tmp_path / "plain.onnx", progress=False)

    def follows_the_error(reference, got):
        return 1.0 / (1.0 + 1e3 * balanced_error([r[0] for r in reference], [g[0] for g in got]))

    budget = FidelityBudget(min_agreement=1.0, judge=follows_the_error, max_float=100)
    wide = quantize_onnx_static(path, calib, tmp_path / "wide.onnx", progress=False, budget=budget)
    record = wide.quant["accuracy_aware"]
    singles = {s["tensor"] for s in record["scan"] if s["gain_db"] > 0}
    assert set(record["float_tensors"]) - singles  # tensors the scan never ranked alone: a region's
    assert record["float_weight_convs"] and wide.int8_convs == wide.convs - len(record["float_weight_convs"])
    assert wide.fidelity["logits"]["sqnr_db"] > plain.fidelity["logits"]["sqnr_db"]

    capsys.readouterr()
    budget = FidelityBudget(min_sqnr_db=plain.fidelity["logits"]["sqnr_db"] + 8, max_float=100)
    record = quantize_onnx_static(path, calib, tmp_path / "sqnr.onnx", budget=budget).quant["accuracy_aware"]
    tried = [float(line.split("worst SQNR ")[1].split(" dB")[0]) for line in capsys.readouterr().err.splitlines()
             if "budget not met" in line and "worst SQNR" in line]  # the regions' steps
    assert tried and record["after"]["logits"]["sqnr_db"] >= max(tried)
    if record.get("closest_by_budget"):  # the single tensors, an earlier graph of the search
        assert set(record["float_tensors"]) <= singles and "float_weight_convs" not in record
    else:  # the regions, the search's last graph
        assert record["float_weight_convs"] and set(record["float_tensors"]) - singles


def test_the_region_search_takes_the_region_that_meets_the_budget_then_its_shortest_half(tmp_path, monkeypatch):
    """The search itself (`_widen`), on a scripted evaluator: no region but the third brings the
    error under the budget's, and only its first half is needed; a graph with no conv left int8 is
    never the answer."""
    import math

    import onnx

    from edgepick.quant.fidelity import OutputFidelity, Task, TaskKind
    from edgepick.quant.onnx import accuracy

    model = onnx.load(str(faint_channel_model(tmp_path / "faint.onnx")))
    needed = {"t8", "t9"}  # of the third region, t8..t11

    class Scripted:  # the float tensors of a graph: what the stand-in float_tensors wrote into it
        float_model = model

        def measure(self, graph):
            floated = set(graph.doc_string.split(","))
            error = 0.001 if needed <= floated else 0.5 - 0.01 * len(floated)
            return {"output": OutputFidelity(Task(TaskKind.RAW), signal=1.0, noise=error)}, error

        def half_errors(self, graph):
            return (self.measure(graph)[1],) * 2

    def float_tensors(graph, names, float_model, weights=False):
        graph.doc_string = ",".join(names)
        return len(names)

    rest = [f"t{k}" for k in range(64)]  # 16 regions of 4
    budget = FidelityBudget(min_sqnr_db=20.0, max_float=100)
    monkeypatch.setattr(accuracy, "float_tensors", float_tensors)
    monkeypatch.setattr(accuracy, "float_weight_convs", lambda graph: [])  # every conv still int8
    found = accuracy._widen(model, [], rest, Scripted(), budget, (0.4, 0.4), lambda _: None)
    assert found is not None
    _, names, fidelity = found
    assert names == ["t8", "t9"] and math.isclose(fidelity["output"].sqnr_db, 30.0)
    monkeypatch.setattr(accuracy, "float_weight_convs", lambda graph: ["conv1", "conv2"])  # both convs float
    assert accuracy._widen(model, [], rest, Scripted(), budget, (0.4, 0.4), lambda _: None) is None  # no int8 model


def test_where_no_region_is_enough_the_shortest_float_start_of_the_graph_that_meets_the_budget(tmp_path, monkeypatch):
    """The start search (`_float_start`), on a scripted evaluator: the outputs meet the budget only
    once the graph's first 37 activations are float (errors that add up along a backbone); the
    search finds that length by halving, and gives up where the budget allows fewer."""
    import onnx

    from edgepick.quant.fidelity import OutputFidelity, Task, TaskKind
    from edgepick.quant.onnx import accuracy

    model = onnx.load(str(faint_channel_model(tmp_path / "faint.onnx")))
    rest = [f"t{k}" for k in range(100)]

    class Scripted:
        float_model = model
        graphs = 0

        def fidelity(self, graph):
            self.graphs += 1
            start = set(rest[:37]) <= set(graph.doc_string.split(","))
            return {"output": OutputFidelity(Task(TaskKind.RAW), signal=1.0, noise=0.001 if start else 0.5)}

        def half_errors(self, graph):
            return 0.01, 0.01

    def float_tensors(graph, names, float_model, weights=False):
        assert weights  # the ops that then read float values compute with float weights
        graph.doc_string = ",".join(names)
        return len(names)

    monkeypatch.setattr(accuracy, "float_tensors", float_tensors)
    monkeypatch.setattr(accuracy, "float_weight_convs", lambda graph: [])  # every conv still int8
    evaluator = Scripted()
    budget, best = FidelityBudget(min_sqnr_db=20.0, max_float=65), (0.4, 0.4)
    found = accuracy._float_start(model, ["x"], rest, evaluator, budget, best, lambda _: None)
    assert found is not None and found[1] == ["x", *rest[:37]] and evaluator.graphs <= 8
    assert accuracy._float_start(model, ["x"], rest, Scripted(), FidelityBudget(min_sqnr_db=20.0, max_float=37), best,
                                 lambda _: None) is None  # 36 activations are all the budget leaves
    assert accuracy._float_start(model, ["x"], rest, Scripted(), budget, (0.4, 0.005),
                                 lambda _: None) is None  # not closer on the second half of the check tensors
    monkeypatch.setattr(accuracy, "float_weight_convs", lambda graph: ["conv1", "conv2"])  # both the faint model's convs float
    assert accuracy._float_start(model, ["x"], rest, Scripted(), budget, best, lambda _: None) is None  # no int8 left
