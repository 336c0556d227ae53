"""AdaRound on a float ONNX model: the small net of test_adaround exported by torch, its convs
rounded on the QDQ graph closer to fp32's outputs than round-to-nearest."""

from __future__ import annotations

import functools
import json

import numpy as np
import onnx
import pytest

from edgepick.quant import PtqMethods, methods, quantize_onnx_static
from edgepick.quant.onnx import adaround as onnx_adaround
from edgepick.quant.onnx import static as onnx_static
from edgepick.quant.onnx.measure import Values, qdq_convs
from tests.quant.onnx_models import export_module, image_tensors, run
from tests.quant.test_adaround import Small


def _export(path):
    return export_module(Small(), path)


def _tensors(count=6):
    return image_tensors(count)


@pytest.mark.slow
def test_adaround_lowers_each_convs_error_and_rounds_each_weight_down_or_up(tmp_path, monkeypatch):
    seen = {}
    original = onnx_adaround.adaround_onnx

    def spy(float_model, model, tensors, seconds, seven_bit, progress=False):
        convs = qdq_convs(model)
        values, nodes = Values(model), {n.name: n for n in float_model.graph.node}
        seen["nearest"] = {name: values[c.weight_codes] for name, c in convs.items()}
        seen["report"] = report = original(float_model, model, tensors, seconds, seven_bit, steps=300)
        seen["learnt"] = {name: Values(model)[c.weight_codes] for name, c in convs.items()}
        seen["w"] = {name: Values(float_model)[nodes[name].input[1]] / values[c.weight_scale].reshape(-1, 1, 1, 1)
                     for name, c in convs.items()}
        return report

    monkeypatch.setattr(onnx_static, "adaround_onnx", spy)
    path, tensors = _export(tmp_path / "f.onnx"), _tensors()
    quantize_onnx_static(path, tensors, tmp_path / "a.onnx", methods=PtqMethods(adaround=True), progress=False)
    report, nearest, learnt = seen["report"], seen["nearest"], seen["learnt"]
    assert set(report) == set(nearest) and len(report) == 3
    for name, r in report.items():
        assert r["error_adaround"] <= r["error_nearest"], (name, r)
        w = seen["w"][name]
        assert ((learnt[name] >= np.floor(w) - 1e-6) & (learnt[name] <= np.ceil(w) + 1e-6)).all(), name
    dense = [name for name in report if nearest[name].shape[1] > 1]
    gain = {n: report[n]["error_adaround"] / report[n]["error_nearest"] for n in dense}
    assert max(gain.values()) < 1.0 and min(gain.values()) < 0.7, gain  # measured: 0.51 and 0.90
    assert any(not np.array_equal(nearest[n], learnt[n]) for n in dense)


@pytest.mark.slow
def test_the_int8_file_follows_fp32_more_closely_and_records_it(tmp_path, monkeypatch):
    # a fixed step count, for a result that does not depend on the machine's speed (measured: the
    # logits' squared error 4.3e-6 with nearest rounding, 2.1e-6 with AdaRound)
    monkeypatch.setattr(onnx_static, "adaround_onnx", functools.partial(onnx_adaround.adaround_onnx, steps=300))
    path, tensors = _export(tmp_path / "f.onnx"), _tensors()
    error = {}
    for ada in (False, True):
        out = tmp_path / f"int8-{ada}.onnx"
        quantize_onnx_static(path, tensors, out, methods=PtqMethods(adaround=ada, adaround_budget_s=5.0), progress=False)
        error[ada] = sum(float(((run(out, x)[0] - run(path, x)[0]) ** 2).mean()) for x in tensors)
    assert error[True] < error[False], error
    quant = json.loads({p.key: p.value for p in onnx.load(str(tmp_path / "int8-True.onnx")).metadata_props}[
        "edgepick.quant"])
    assert quant["adaround"] and quant["adaround_budget_s"] == 5.0 and quant["adaround_convs"] >= 1
    assert quant["measured_images"] == len(tensors)


@pytest.mark.slow
def test_without_a_time_budget_every_conv_takes_the_planned_steps_and_the_file_is_the_same_twice(tmp_path, monkeypatch,
                                                                                                capsys):
    # a plan of ~100 steps for this model, to keep the test short; the time budget would take MAX_STEPS here
    monkeypatch.setattr(methods, "WORK", 100 * 3 * (methods.STEP_OVERHEAD + 300))
    monkeypatch.setenv("EDGEPICK_PROGRESS_S", "0")  # a progress line per conv
    seen = []
    original = onnx_adaround.adaround_onnx

    def spy(*args, **kwargs):
        seen.append(original(*args, **kwargs))
        return seen[-1]

    monkeypatch.setattr(onnx_static, "adaround_onnx", spy)
    path, tensors = _export(tmp_path / "f.onnx"), _tensors()
    files = [tmp_path / f"int8-{k}.onnx" for k in range(2)]
    for k, out in enumerate(files):
        quantize_onnx_static(path, tensors, out, methods=PtqMethods(adaround=True), progress=k == 0)
    assert "AdaRound: 3/3 conv" in capsys.readouterr().err  # the bar counts the convs, n of N
    steps = {r["steps"] for report in seen for r in report.values()}
    assert len(seen) == 2 and len(steps) == 1 and 20 < steps.pop() < 120, seen
    # the same graph and record, but for the times measured on this machine (`speed`)
    models = [onnx.load(str(f)) for f in files]
    assert models[0].graph.SerializeToString() == models[1].graph.SerializeToString()
    metadata = [{p.key: p.value for p in m.metadata_props} for m in models]
    records = [json.loads(m.pop("edgepick.quant")) for m in metadata]
    assert metadata[0] == metadata[1] and [r.pop("speed")["threads"] for r in records] == [2, 2]
    assert records[0] == records[1]
    quant = records[0]
    assert quant["adaround_budget_s"] is None and quant["adaround_steps"] == seen[0][next(iter(seen[0]))]["steps"]


def test_spilled_targets_come_back_as_added_side_by_side_and_leave_no_file(tmp_path):
    targets = onnx_adaround.SpilledTargets(tmp_path)
    rng = np.random.default_rng(0)
    parts = {"conv_a": [rng.normal(size=(3, 5)), rng.normal(size=(3, 2))], "conv_b": [rng.normal(size=(4, 5))]}
    for k in range(2):
        for name, rows in parts.items():
            if k < len(rows):
                targets.add(name, rows[k])
    np.testing.assert_array_equal(targets.pop("conv_b"), parts["conv_b"][0].astype(np.float32))
    np.testing.assert_array_equal(targets.pop("conv_a"), np.concatenate(parts["conv_a"], axis=1).astype(np.float32))
    assert list(tmp_path.iterdir()) == []
