"""Placement auto: the candidates made, timed on the target engine and the choice recorded (quant/onnx/placement.py)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import onnx
import pytest

from edgepick.errors import ParameterError
from edgepick.quant.config import OnnxOptions, PtqMethods
from edgepick.quant.onnx.accuracy import FidelityBudget
from edgepick.quant.onnx.placement import (
    PLACEMENT_ENOUGH_DB,
    PLACEMENT_FIDELITY_DB,
    fidelity_threshold_db,
    pick_placement,
)
from edgepick.quant.onnx.static import quantize_onnx_static
from tests.quant.onnx_models import calib_tensors, export_torch, strided_projection_model


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
    assert choice["chosen"] == pick_placement(times, sqnr) == result.quant["placement"]
    assert result.out == str(tmp_path / "auto.onnx") and sorted(p.name for p in tmp_path.iterdir()) == ["auto.onnx",
                                                                                                          "net.onnx"]
    recorded = json.loads({p.key: p.value for p in onnx.load(result.out).metadata_props}["edgepick.quant"])
    assert recorded["placement_choice"] == choice
    stages = result.stage_s  # every candidate's stages summed, and the timing of the candidates
    assert stages["time_placements"] > 0 and stages["calibrate"] > 0 and stages["write_check"] > 0


def test_placement_auto_tries_adaround_once_on_the_chosen_file_where_it_is_far_from_fp32(faint, tmp_path):
    """The faint model lands under the SQNR floor with every placement: the candidates are made
    without AdaRound and only the chosen one is made again with it tried; the file records the
    user's adaround_if_far and the AdaRound step."""
    from edgepick.quant.onnx.placement import choose_placement

    path, calib, _, _, _ = faint
    asked: list[bool] = []

    def quantize(*args, options, **kwargs):
        asked.append(options.adaround_if_far)
        return quantize_onnx_static(*args, options=options, **kwargs)

    options = OnnxOptions(placement="auto")
    result = choose_placement(quantize, path, calib, tmp_path / "auto.onnx", options, False,
                              methods=PtqMethods(bias_correction="none"))
    assert asked == [False, False, False, True]
    assert result.quant["adaround_if_far"] is True and result.quant["adaround_first"]["why"] == "sqnr_floor"
    assert result.quant["placement"] == result.quant["placement_choice"]["chosen"]
    asked.clear()  # with a budget, each candidate's accuracy-aware mode has tried AdaRound: no file made again
    budgeted = choose_placement(quantize, path, calib, tmp_path / "budget.onnx", options, False,
                                methods=PtqMethods(bias_correction="none"),
                                budget=FidelityBudget(min_sqnr_db=200.0, max_seconds=1e-9))  # nothing float: under the floor
    assert min(f["sqnr_db"] for f in budgeted.fidelity.values()) < 10
    assert asked == [False, False, False] and budgeted.quant["adaround_first"]["why"] == "budget"


def test_a_target_without_placement_auto_is_refused():
    with pytest.raises(ParameterError, match="^target='openvino': .*give placement auto"):
        OnnxOptions(target="openvino")


@pytest.mark.slow
def test_for_openvino_a_strided_pointwise_conv_keeps_its_int8_kernel(tmp_path):
    """OpenVINO moves a 1x1 conv's stride onto its dequantized input as an f32 pooling and runs the
    conv in f32; the file made for it subsamples in the float graph first (quant/onnx/rewrite.py)."""
    ov = pytest.importorskip("openvino")
    import edgepick.quant.onnx.placement as placement
    from edgepick.runtime.session import openvino_config

    src = strided_projection_model(tmp_path / "block.onnx")

    def conv_precisions(path) -> list[str]:
        compiled = ov.Core().compile_model(str(path), "CPU", openvino_config(2))
        return sorted(op.get_rt_info()["runtimePrecision"].astype(str) for op in compiled.get_runtime_model().get_ordered_ops()
                      if op.get_rt_info()["layerType"].astype(str) == "Convolution")

    made = {}
    for name, forms in (("with", placement.openvino_forms), ("without", lambda model, tmp: (model, {}))):
        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(placement, "openvino_forms", forms)
            made[name] = quantize_onnx_static(src, calib_tensors(6), tmp_path / f"{name}.onnx",
                                              methods=PtqMethods(bias_correction="none"),
                                              options=OnnxOptions(placement="auto", target="openvino"), progress=False)
    assert made["with"].quant["placement_choice"]["subsampled_pointwise_convs"] == 2  # not the 3x3 head
    assert conv_precisions(made["with"].out) == ["u8"] * 6
    assert "f32" in conv_precisions(made["without"].out)  # what the rewrite is for: this OpenVINO still does it


@pytest.mark.slow
def test_for_openvino_a_float_hardswish_goes_into_its_conv(tmp_path):
    """torch writes hardswish as x * HardSigmoid(x) below opset 14 (onnxruntime's pre-processing does
    so with a HardSwish op), which OpenVINO runs as two more passes over the map; spelt out as
    x * Clip(x + 3, 0, 6) / 6 it fuses into the conv before it, the file's outputs the same."""
    ov = pytest.importorskip("openvino")
    from torch import nn

    from edgepick.quant.config import Target
    from edgepick.quant.onnx.placement import float_forms_for
    from edgepick.runtime.session import openvino_config
    from tests.quant.onnx_models import export_module, image_tensors, run

    net = nn.Sequential(nn.Conv2d(3, 8, 3, padding=1), nn.Hardswish(), nn.Conv2d(8, 8, 3, padding=1, groups=8),
                        nn.Hardswish(), nn.Conv2d(8, 4, 1))
    made = quantize_onnx_static(export_module(net, tmp_path / "net.onnx"), image_tensors(4), tmp_path / "convs.onnx",
                                options=OnnxOptions(placement="convs", time_against_fp32=False), progress=False)
    path = Path(made.out)

    def passes() -> list[str]:  # the layers OpenVINO runs, but constants, reshapes of constants and layout reorders
        compiled = ov.Core().compile_model(str(path), "CPU", openvino_config(2))
        types = [op.get_rt_info()["layerType"].astype(str) for op in compiled.get_runtime_model().get_ordered_ops()]
        return [t for t in types if t not in ("Input", "Output", "Const", "Reshape", "Reorder")]

    x = image_tensors(1)[0]
    before = run(path, x)
    unfused = passes()
    assert unfused.count("Convolution") == 3 and len(unfused) > 4  # each HardSigmoid, Mul and quantization a pass
    assert float_forms_for(Target.ONNXRUNTIME, path) == 0
    assert float_forms_for(Target.OPENVINO, path) == 2
    assert passes() == ["Subgraph"] + ["Convolution"] * 3  # the input's quantization, then the convs, all fused
    for a, b in zip(run(path, x), before):
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-4)


def test_a_candidate_is_close_enough_within_a_db_of_the_best_or_at_the_enough_level():
    assert fidelity_threshold_db([20.0, 18.0]) == 20.0 - PLACEMENT_FIDELITY_DB  # a low-SQNR model: the best's db
    assert fidelity_threshold_db([50.1, 39.8, 42.4]) == PLACEMENT_ENOUGH_DB  # all close enough to fp32
    assert fidelity_threshold_db([35.5, 30.0]) == 35.5 - PLACEMENT_FIDELITY_DB


def test_a_candidate_a_few_db_further_is_taken_only_where_it_runs_much_faster():
    # ddddocr's recogniser on OpenVINO: joins 2.3 dB further than convs, 1.4x as fast
    assert pick_placement({"all": 3.11, "convs": 4.46, "joins": 3.19}, {"all": 25.96, "convs": 30.81, "joins": 28.5}) == "joins"
    # PP-OCRv6's detector: convs 1.95 dB further than joins and only 5% faster: joins stays
    assert pick_placement({"all": 31.67, "convs": 31.25, "joins": 32.92}, {"all": 17.85, "convs": 22.13, "joins": 24.08}) == "joins"
    # within 1 dB the fastest is taken whatever its speed; past 3 dB never
    assert pick_placement({"all": 2.0, "convs": 1.9}, {"all": 20.0, "convs": 19.2}) == "convs"
    assert pick_placement({"all": 4.0, "convs": 1.0}, {"all": 20.0, "convs": 16.9}) == "all"
