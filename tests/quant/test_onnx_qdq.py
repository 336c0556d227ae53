"""The QDQ graph for edgepick's own ranges, the tensors never clipped and the per-model choice of the
range rule (quant/onnx/qdq.py, through quantize_onnx_static)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import onnx
import pytest

from edgepick.quant.config import PtqMethods, QuantConfig
from edgepick.quant.fidelity import Task
from edgepick.quant.onnx.qdq import OUTPUT_GRID_DB, exact_tensors
from edgepick.quant.onnx.static import quantize_onnx_static
from tests.quant.onnx_models import calib_tensors, conv_relu_model, detector_head_model, export_torch, optimized_ops, run


def _head_inputs(count: int, size: int = 64, seed: int = 0) -> list[np.ndarray]:
    """Feature maps in [0, 1]; in the first, one box where every channel is 1: the one confident box
    (a score of 0.993) among all of them, which a 99.99th percentile leaves out."""
    rng = np.random.default_rng(seed)
    out = [rng.random((1, 3, size, size), dtype=np.float32) for _ in range(count)]
    out[0][0, :, 5, 7] = 1.0
    return out


def test_the_tensors_that_reach_an_output_through_no_conv_are_found(tmp_path):
    model = onnx.load(str(detector_head_model(tmp_path / "d.onnx")))
    assert exact_tensors(model) == {"rows", "rows_t", "rows_nchw", "rows_shape", "box", "obj", "obj_logit"}
    path, _, _ = conv_relu_model(tmp_path / "m.onnx")
    assert exact_tensors(onnx.load(str(path))) == {"output", "conv_out"}


def test_a_detectors_rare_high_scores_are_not_clipped(tmp_path):
    """onnxruntime's percentile ranges clip the objectness logit and the score where one box in a
    thousand is confident; edgepick keeps the whole range of every tensor that reaches an output
    through no conv, whatever the rule for the others."""
    from onnxruntime.quantization import CalibrationMethod, QuantFormat, QuantType, quantize_static

    src = detector_head_model(tmp_path / "head.onnx")
    calib, check = _head_inputs(16), _head_inputs(4, seed=9)
    ours = quantize_onnx_static(src, calib, tmp_path / "ours.onnx", QuantConfig(calib_method="percentile"),
                                PtqMethods(bias_correction="none"), progress=False)

    class Reader:
        def __init__(self):
            self.it = iter(calib)

        def get_next(self):
            x = next(self.it, None)
            return None if x is None else {"input": x}

    theirs = tmp_path / "ort.onnx"
    quantize_static(str(src), str(theirs), Reader(), quant_format=QuantFormat.QDQ, per_channel=True,
                    activation_type=QuantType.QUInt8, weight_type=QuantType.QInt8,
                    calibrate_method=CalibrationMethod.Percentile, extra_options={"CalibPercentile": 99.99})
    for x in check[:1]:  # with its confident box
        fp32 = run(src, x)[0][0, :, 4]
        top = int(fp32.argmax())
        assert fp32[top] > 0.99
        assert abs(run(Path(ours.out), x)[0][0, top, 4] - fp32[top]) < 0.01
        assert run(theirs, x)[0][0, top, 4] < fp32[top] - 0.1  # clipped: the check can tell the two apart
    assert ours.fidelity["rows"]["task"] == "raw" and ours.fidelity["rows"]["agreement"] is None
    assert ours.quant["ranges"]["exact_tensors"] == 6  # box, obj_logit, obj, rows_nchw, rows_t, rows


@pytest.mark.parametrize("count, held_out, task", [(20, 8, "labels"), (10, 0, "labels"), (20, 8, "raw")])
def test_auto_measures_every_rule_on_held_out_tensors_and_keeps_the_closest(tmp_path, count, held_out, task):
    """Each candidate rule measured on the held-out tensors: the closest outputs are kept, or a rule
    that changes fewer of fp32's decisions (beyond chance: tests/quant/test_fidelity.py); where the
    output decides nothing (raw), the closest outputs alone."""
    path, _, _ = conv_relu_model(tmp_path / "m.onnx")
    rng = np.random.default_rng(4)
    xs = [rng.standard_t(2, (1, 2, 32, 32)).astype(np.float32) for _ in range(count)]
    result = quantize_onnx_static(path, xs, tmp_path / "int8.onnx", progress=False, task=Task.parse(task))
    ranges = result.quant["ranges"]
    assert result.quant["calib_method"] == "auto" and result.calib_tensors == count
    assert ranges["held_out"] == held_out  # with fewer than twice the held-out tensors, all are used for both
    scores = {c["rule"]: (c.get("decision_agreement", 1.0), c["balanced_sqnr_db"]) for c in ranges["candidates"]}
    assert set(scores) == {"minmax", "percentile 99.99", "percentile 99.999", "percentile 99.9999", "entropy", "mse"}
    closest = max(scores, key=lambda rule: scores[rule][1])
    kept = ranges["rule"]
    assert kept == closest or scores[kept][0] > scores[closest][0]
    assert all(("decision_agreement" in c) == (task != "raw") for c in ranges["candidates"])
    recorded = json.loads({p.key: p.value for p in onnx.load(result.out).metadata_props}["edgepick.quant"])
    assert recorded["ranges"] == ranges


def test_the_outputs_stay_on_the_uint8_grid_only_where_that_costs_no_fidelity(tmp_path):
    """A one-channel map behind a Sigmoid is as close to fp32 on the uint8 grid as in float: it stays
    there, and the conv that writes it runs as an integer conv. A three-class logits map loses more
    than OUTPUT_GRID_DB on the grid: its Q/DQ pair is dropped and that conv runs in float. A Concat
    of boxes and scores is never put on one grid (the scores would round away)."""
    sig = quantize_onnx_static(export_torch(tmp_path / "sig.onnx", opset=13, out_channels=1, sigmoid=True),
                               calib_tensors(8), tmp_path / "sig8.onnx", progress=False)
    grid = sig.quant["outputs_on_grid"]
    assert grid["kept"] and sig.rewrites["float_outputs"] == 0
    assert grid["channel_sqnr_db_on_grid"]["logits"] >= grid["channel_sqnr_db_float"]["logits"] - OUTPUT_GRID_DB
    ops = optimized_ops(Path(sig.out))
    assert "Conv" not in ops and ops["Sigmoid"] == 1, ops  # the head conv integer, the Sigmoid after it float
    recorded = json.loads({p.key: p.value for p in onnx.load(sig.out).metadata_props}["edgepick.quant"])
    assert recorded["outputs_on_grid"] == grid

    logits = quantize_onnx_static(export_torch(tmp_path / "net.onnx", opset=13), calib_tensors(8),
                                  tmp_path / "net8.onnx", progress=False)
    grid = logits.quant["outputs_on_grid"]
    assert not grid["kept"] and logits.rewrites["float_outputs"] == 1
    assert grid["channel_sqnr_db_on_grid"]["logits"] < grid["channel_sqnr_db_float"]["logits"] - OUTPUT_GRID_DB
    assert optimized_ops(Path(logits.out))["Conv"] == 1

    head = quantize_onnx_static(detector_head_model(tmp_path / "head.onnx"), _head_inputs(8), tmp_path / "head8.onnx",
                                progress=False)
    assert "outputs_on_grid" not in head.quant and head.rewrites["float_outputs"] == 1


def test_a_relu_the_writer_left_out_before_a_float_output_is_put_back(tmp_path):
    """onnxruntime's writer drops a Relu after a quantized conv (the uint8 grid clamps for it); where
    the output then goes float, the Relu must come back, or the output keeps the conv's negative
    half (an output SQNR of -2.6 dB on a plain conv + Relu stack before it did)."""
    path, _, _ = conv_relu_model(tmp_path / "m.onnx")
    xs = [np.random.default_rng(k).normal(0, 1, (1, 2, 32, 32)).astype(np.float32) for k in range(8)]
    result = quantize_onnx_static(path, xs, tmp_path / "int8.onnx", progress=False)
    assert result.rewrites["float_outputs"] == 1
    out = run(Path(result.out), xs[0])[0]
    assert out.min() >= 0.0 and result.fidelity["output"]["sqnr_db"] > 30, result.fidelity
    assert "Relu" in {n.op_type for n in onnx.load(result.out).graph.node}


def test_the_graph_the_rule_was_chosen_on_is_taken_again_where_it_is_what_the_writer_writes(tmp_path, monkeypatch):
    """qdq_for takes the graph written for other ranges and sets the new qparams, the file the writer would
    write; where a bias comes near the int32 limit (the writer then widens the weight's scale) it writes afresh."""
    from onnxruntime.quantization.registry import QDQRegistry, QLinearOpsRegistry

    from edgepick.quant.config import Placement
    from edgepick.quant.onnx import qdq
    from edgepick.quant.onnx.static import placement_ops
    from tests.quant.test_onnx_measure import _pooled_chain_model, _qparams

    path = _pooled_chain_model(tmp_path / "chain.onnx")
    float_model = onnx.load(str(path))
    ops = placement_ops(Placement.ALL, {*QDQRegistry, *QLinearOpsRegistry})
    first = {"x": (-1.0, 1.0), "conv": (-4.0, 4.0), "relu": (0.0, 4.0), "pool": (0.0, 2.0), "rows": (0.0, 2.0),
             "y": (-9.0, 9.0)}
    second = {**first, "x": (-2.0, 1.5), "relu": (0.0, 1.5), "y": (-5.0, 7.0)}
    tiny = {**first, "x": (-1e-7, 1e-7)}  # the conv's bias on a grid of ~1e-11: beyond int32
    written = qdq.qdq_model(path, first, ops, [], False)
    fresh, fresh_tiny = qdq.qdq_model(path, second, ops, [], False), qdq.qdq_model(path, tiny, ops, [], False)
    calls = []
    monkeypatch.setattr(qdq, "qdq_model", lambda *a: calls.append(a) or fresh_tiny)
    again = qdq.qdq_for(written, path, float_model, second, ops, [], False)
    assert not calls and again is not written
    got, want = _qparams(again), _qparams(fresh)
    assert set(got) == set(want)
    for name in want:
        np.testing.assert_allclose(got[name], want[name], rtol=1e-6, err_msg=name)
    assert qdq.qdq_for(written, path, float_model, tiny, ops, [], False) is fresh_tiny and len(calls) == 1
    assert qdq.qdq_for(None, path, float_model, second, ops, [], False) is fresh_tiny and len(calls) == 2


def test_the_graph_taken_again_folds_a_relu_only_where_the_writer_quantizes_it(tmp_path):
    """Where the writer quantizes convs alone it leaves the Relu float and does not give the conv's output
    the Relu's range; the graph taken again must not either (it did: OpenVINO's files then changed)."""
    from edgepick.export.onnx_io import CONV_OPS
    from edgepick.quant.onnx import qdq
    from tests.quant.test_onnx_measure import _qparams

    path, _, _ = conv_relu_model(tmp_path / "m.onnx")
    float_model = onnx.load(str(path))
    ops = sorted(CONV_OPS)
    first = {"input": (-1.0, 1.0), "conv_out": (-4.0, 4.0), "output": (0.0, 4.0)}
    second = {"input": (-2.0, 1.5), "conv_out": (-3.0, 6.0), "output": (0.0, 5.0)}
    written = qdq.qdq_model(path, first, ops, [], False)
    again, fresh = qdq.qdq_for(written, path, float_model, second, ops, [], False), qdq.qdq_model(path, second, ops, [], False)
    got, want = _qparams(again), _qparams(fresh)
    assert set(got) == set(want) and "conv_out_zero_point" in want
    for name in want:
        np.testing.assert_allclose(got[name], want[name], rtol=1e-6, err_msg=name)
