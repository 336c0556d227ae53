"""The range rule chosen again on the bias-corrected files where its measure before the correction
ranks nothing (edgepick/quant/onnx/calibration_pass.py)."""

from __future__ import annotations

import json

import numpy as np
import onnx
from onnx import helper

from edgepick.quant.config import QuantConfig
from edgepick.quant.onnx.calibration_pass import UNRANKED_DB
from edgepick.quant.onnx.static import quantize_onnx_static
from edgepick.quant.ranges import candidate_rules
from tests.quant.onnx_models import helper_model


def _offset_model(path, rng):
    """input (a large constant level and small texture) -> 3x3 conv whose taps sum to zero -> Relu ->
    1x1 conv: the texture passes and the level cancels, so each weight's rounding times the level is
    an offset larger than the signal, which bias correction takes out again."""
    w1 = rng.normal(size=(8, 1, 3, 3))
    w1 -= w1.mean(axis=(1, 2, 3), keepdims=True)
    w2 = rng.normal(size=(4, 8, 1, 1))
    nodes = [helper.make_node("Conv", ["input", "w1", "b1"], ["c1"], name="conv1"),
             helper.make_node("Relu", ["c1"], ["r1"], name="relu1"),
             helper.make_node("Conv", ["r1", "w2"], ["output"], name="conv2")]
    return helper_model(nodes, [("input", [1, 1, 24, 24])], [("output", [1, 4, 22, 22])],
                        {"w1": w1, "b1": np.full(8, 0.5), "w2": w2}, path)


def _record(path) -> dict:
    return json.loads(dict((p.key, p.value) for p in onnx.load(str(path)).metadata_props)["edgepick.quant"])


def test_where_every_rule_is_far_before_bias_correction_the_rule_is_chosen_on_the_corrected_files(tmp_path):
    rng = np.random.default_rng(0)
    model = _offset_model(tmp_path / "m.onnx", rng)
    calib = [(200.0 + rng.normal(size=(1, 1, 24, 24))).astype(np.float32) for _ in range(24)]
    result = quantize_onnx_static(model, calib, tmp_path / "int8.onnx", progress=False)
    ranges = _record(result.out)["ranges"]
    before = [c["balanced_sqnr_db"] for c in ranges["candidates"]]
    assert all(s < UNRANKED_DB for s in before), before  # the measure ranks nothing here
    after = ranges["after_correction"]
    assert set(after) == {str(r) for r in candidate_rules(QuantConfig())}
    assert ranges["rule"] == max(after, key=lambda r: after[r]) and "chosen_before_correction" in ranges
    assert min(f["sqnr_db"] for f in result.fidelity.values()) > UNRANKED_DB


def test_where_no_rule_comes_near_fp32_even_after_correction_the_first_choice_stands(tmp_path):
    """A level so large that every corrected file stays under UNRANKED_DB: that measure ranks nothing
    either, so the rule chosen first is kept, not the corrected file that happens to measure closest."""
    rng = np.random.default_rng(0)
    model = _offset_model(tmp_path / "m.onnx", rng)
    calib = [(2000.0 + rng.normal(size=(1, 1, 24, 24))).astype(np.float32) for _ in range(24)]
    ranges = _record(quantize_onnx_static(model, calib, tmp_path / "int8.onnx", progress=False).out)["ranges"]
    after = ranges["after_correction"]
    assert all(s < UNRANKED_DB for s in after.values()), after
    assert ranges["rule"] == ranges["chosen_before_correction"] != max(after, key=lambda r: after[r])


def test_where_the_measure_ranks_the_rules_they_are_not_made_again(tmp_path):
    rng = np.random.default_rng(1)
    model = _offset_model(tmp_path / "m.onnx", rng)
    calib = [rng.normal(size=(1, 1, 24, 24)).astype(np.float32) for _ in range(24)]  # no level to round
    result = quantize_onnx_static(model, calib, tmp_path / "int8.onnx", progress=False)
    ranges = _record(result.out)["ranges"]
    assert max(c["balanced_sqnr_db"] for c in ranges["candidates"]) >= UNRANKED_DB
    assert "after_correction" not in ranges
