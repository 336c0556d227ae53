"""Placement auto: the candidates made, timed on the target engine and the choice recorded (quant/onnx/placement.py)."""

from __future__ import annotations

import json

import onnx
import pytest

from edgepick.errors import ParameterError
from edgepick.quant.config import OnnxOptions, PtqMethods
from edgepick.quant.onnx.placement import PLACEMENT_FIDELITY_DB
from edgepick.quant.onnx.static import quantize_onnx_static
from tests.quant.onnx_models import calib_tensors, export_torch


@pytest.mark.slow
@pytest.mark.parametrize("target", ["onnxruntime", "openvino"])
def test_placement_auto_times_each_candidate_on_the_target_and_records_the_choice(tmp_path, target):
    src = export_torch(tmp_path / "net.onnx", opset=13)
    result = quantize_onnx_static(src, calib_tensors(6), tmp_path / "auto.onnx",
                                  methods=PtqMethods(bias_correction="none"),
                                  options=OnnxOptions(placement="auto", target=target), progress=False)
    choice = result.quant["placement_choice"]
    assert choice["target"] == target and choice["threads"] == 2 and choice["machine"]
    times = {c["placement"]: c["p50_ms"] for c in choice["candidates"]}
    sqnr = {c["placement"]: c["worst_sqnr_db"] for c in choice["candidates"]}
    assert set(times) == {"all", "convs", "joins"} and min(times.values()) > 0
    close = [p for p in times if sqnr[p] >= max(sqnr.values()) - PLACEMENT_FIDELITY_DB]
    assert choice["chosen"] == min(close, key=times.get) == result.quant["placement"]
    assert result.out == str(tmp_path / "auto.onnx") and sorted(p.name for p in tmp_path.iterdir()) == ["auto.onnx",
                                                                                                          "net.onnx"]
    recorded = json.loads({p.key: p.value for p in onnx.load(result.out).metadata_props}["edgepick.quant"])
    assert recorded["placement_choice"] == choice


def test_a_target_without_placement_auto_is_refused():
    with pytest.raises(ParameterError, match="^target='openvino': .*give placement auto"):
        OnnxOptions(target="openvino")
