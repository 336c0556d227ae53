"""Static PTQ of float ONNX models edgepick did not make (`quantize_onnx_static`, `quantize static MODEL.onnx`)."""

from __future__ import annotations

import json
import re
from collections import Counter
from pathlib import Path

import cv2
import numpy as np
import onnx
import pytest

from edgepick.errors import ParameterError
from edgepick.export.checks import conv_weight_report
from edgepick.quant.config import OnnxOptions, QuantConfig
from edgepick.quant.onnx.static import fitting_tensors, quantize_onnx_static
from tests.conftest import run_cli, without_torch
from tests.quant.onnx_models import (
    box_table_model,
    calib_tensors,
    export_torch,
    optimized_ops,
    run,
    unused_initializers,
)


def test_an_opset_12_export_with_dynamic_dims_becomes_an_all_int8_model(tmp_path):
    src = export_torch(tmp_path / "net.onnx", opset=12)
    result = quantize_onnx_static(src, calib_tensors(8), tmp_path / "int8.onnx", progress=False)
    assert result.opset_in == 12 and result.opset_out == 13 and result.input_shape == [1, 3, 64, 96]
    assert result.convs == result.int8_convs == 8 and result.float_convs == []  # ConvTranspose included
    assert result.rewrites["hardswish"] == 1 and result.rewrites["global_average_pool"] == 1
    assert result.rewrites["HardSigmoid"] == 2 and result.rewrites["float_outputs"] == 1
    assert result.agreement_vs_fp32["logits"] >= 0.97, result.agreement_vs_fp32
    assert result.calib_tensors == 8 and json.loads(
        dict((p.key, p.value) for p in onnx.load(result.out).metadata_props)["edgepick.quant"])["source"] == "onnx"
    ops = optimized_ops(Path(result.out))
    # every activation on integer kernels: no float HardSigmoid/ReduceMean/BatchNormalization/Div is left to run
    assert not {"HardSigmoid", "ReduceMean", "BatchNormalization", "Div", "Clip"} & set(ops), ops
    # the head's output (the logits) stays float, and onnxruntime has no integer ConvTranspose kernel
    assert ops["QLinearConv"] == 6 and ops["QLinearMul"] == 2 and ops["QLinearGlobalAveragePool"] == 1, ops
    x = calib_tensors(1, seed=5)[0]
    assert run(Path(result.out), x)[0].dtype == np.float32  # the logits stay float
    # the folded affine blocks' constants are gone from the file, not left for onnxruntime to warn about
    assert unused_initializers(Path(result.out)) == [] and result.rewrites["unused_initializers"] > 0


def _float_ops_on_the_int8_grid(path: Path) -> list[str]:
    """The ops of the QDQ file at PATH that are not convs yet write a tensor put on the int8 grid
    that no conv reads."""
    model = onnx.load(str(path))
    weights = {i.name for i in model.graph.initializer}
    writer = {o: n for n in model.graph.node for o in n.output}
    conv = {"Conv", "ConvTranspose"}
    found = []
    for q in (n for n in model.graph.node if n.op_type == "QuantizeLinear" and n.input[0] not in weights):
        dq = [n for n in model.graph.node if n.op_type == "DequantizeLinear" and q.output[0] in n.input]
        readers = {r.op_type for d in dq for r in model.graph.node if d.output[0] in r.input}
        source = writer.get(q.input[0])
        if source is not None and source.op_type not in conv and not readers & conv:
            found.append(source.op_type)
    return found


def test_placement_convs_leaves_the_models_own_activations_float(tmp_path):
    """placement convs (for OpenVINO): only the convs and the tensors they read are put on the int8
    grid; a conv's own activation (the Relus, the hardswish) reads its float output and the
    squeeze-excitation's gate stays as the model writes it, in float, as NNCF's files leave them for
    OpenVINO to fuse into the conv. The default quantizes their outputs too, for onnxruntime's
    integer kernels."""
    src = export_torch(tmp_path / "net.onnx", opset=13)
    files = {}
    for placement in ("all", "convs"):
        result = quantize_onnx_static(src, calib_tensors(8), tmp_path / f"{placement}.onnx",
                                      options=OnnxOptions(placement=placement), progress=False)
        assert result.convs == result.int8_convs == 8 and result.agreement_vs_fp32["logits"] >= 0.97
        files[placement] = Path(result.out)
        quant = json.loads(dict((p.key, p.value) for p in onnx.load(result.out).metadata_props)["edgepick.quant"])
        assert quant["placement"] == placement
    assert _float_ops_on_the_int8_grid(files["convs"]) == []
    assert {"Add", "Concat"} <= set(_float_ops_on_the_int8_grid(files["all"]))  # the gates' integer Add, ...
    model = onnx.load(str(files["convs"]))
    ops = Counter(n.op_type for n in model.graph.node)
    assert ops["Clip"] == 1 and ops["HardSigmoid"] == 1 and ops["ReduceMean"] == 1 and ops["Relu"] == 3, ops  # as exported
    writer = {o: n for n in model.graph.node for o in n.output}
    assert all(writer[n.input[0]].op_type == "Conv" for n in model.graph.node if n.op_type == "Relu")


def test_each_kind_of_model_has_a_verb_of_its_own(tmp_path):
    import torch

    from edgepick.quant import quantize_static

    with pytest.raises(ParameterError, match="checkpoint=.*an ONNX model; quantize_onnx_static quantizes one"):
        quantize_static(export_torch(tmp_path / "net.onnx"), calib_tensors(2), tmp_path / "q.onnx")
    with pytest.raises(ParameterError, match="an nn.Module; quantize_module_static quantizes one"):
        quantize_static(torch.nn.Conv2d(3, 2, 1), calib_tensors(2), tmp_path / "q.onnx")


def test_one_channel_sigmoid_and_two_output_models(tmp_path):
    sig = quantize_onnx_static(export_torch(tmp_path / "sig.onnx", out_channels=1, sigmoid=True), calib_tensors(6),
                               tmp_path / "sig8.onnx", progress=False)
    assert sig.int8_convs == sig.convs and list(sig.agreement_vs_fp32) == ["logits"]
    assert sig.agreement_vs_fp32["logits"] >= 0.97
    two = quantize_onnx_static(export_torch(tmp_path / "two.onnx", two_outputs=True), calib_tensors(6),
                               tmp_path / "two8.onnx", progress=False)
    assert sorted(two.agreement_vs_fp32) == ["aux", "logits"] and two.rewrites["float_outputs"] == 2
    assert min(two.agreement_vs_fp32.values()) >= 0.97
    outs = run(Path(two.out), calib_tensors(1)[0])
    assert [o.dtype for o in outs] == [np.float32, np.float32] and outs[1].shape == (1, 2, 32, 48)


def test_bad_calibration_data_is_refused_before_anything_is_written(tmp_path):
    src = export_torch(tmp_path / "net.onnx")
    good = calib_tensors(2)
    nan = good[0].copy()
    nan[0, 0, 0, 0] = np.nan
    for bad, message in (([], "no tensors"), ([good[0].astype(np.float64)[:, :2]], r"shape \[1, 2, 64, 96\]"),
                         ([good[0].astype(np.uint8)], "float array"), ([nan], "NaN"),
                         ([good[0], np.zeros((1, 3, 32, 32), np.float32)], "tensor 2 has shape")):
        with pytest.raises(ParameterError, match=message):
            quantize_onnx_static(src, bad, tmp_path / "out.onnx", progress=False)
    with pytest.raises(ParameterError, match="keep_float"):
        quantize_onnx_static(src, good, tmp_path / "out.onnx", QuantConfig(keep_float=("nope",)), progress=False)
    before = src.read_bytes()
    with pytest.raises(ParameterError, match="^out=.*is the model it is made from"):
        quantize_onnx_static(src, good, src, progress=False)  # never over the user's own float model
    assert src.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["net.onnx"]


def test_keep_float_leaves_the_named_conv_float(tmp_path):
    src = export_torch(tmp_path / "net.onnx")
    first = next(n.name for n in onnx.load(src).graph.node if n.op_type == "Conv")
    result = quantize_onnx_static(src, calib_tensors(4), tmp_path / "k.onnx", QuantConfig(keep_float=(first,)),
                                  progress=False)
    assert result.float_convs == [first] and result.int8_convs == result.convs - 1
    assert conv_weight_report(result.out)["float"] == [first]


@pytest.mark.slow
def test_the_command_line_calibrates_on_npy_tensors_or_on_images(tmp_path):
    src = export_torch(tmp_path / "net.onnx")
    (tmp_path / "npy").mkdir()
    (tmp_path / "img").mkdir()
    for k, x in enumerate(calib_tensors(4)):
        np.save(tmp_path / "npy" / f"{k}.npy", x[0])  # without the batch axis: one sample each
        cv2.imwrite(str(tmp_path / "img" / f"{k}.png"), (x[0].transpose(1, 2, 0) * 255).astype(np.uint8))
    proc = run_cli("quantize", "static", str(src), "--calib", str(tmp_path / "npy"), "--out", str(tmp_path / "a.onnx"))
    assert proc.returncode == 0, proc.stderr
    result = json.loads(proc.stdout)
    assert result["calib_tensors"] == 4 and result["int8_convs"] == result["convs"] == 8
    proc = run_cli("quantize", "static", str(src), "--calib", str(tmp_path / "img"), "--size", "96x64",
                   "--calib-images", "3", "--mean", "0.5,0.5,0.5", "--std", "0.5,0.5,0.5", "--channels", "bgr",
                   "--out", str(tmp_path / "b.onnx"))
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["input_shape"] == [1, 3, 64, 96] and json.loads(proc.stdout)["calib_tensors"] == 3


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> dict[str, Path]:
    """The files and folders the mistakes below are made with."""
    from onnx import TensorProto, helper

    tmp = tmp_path_factory.mktemp("inputs")
    for name in ("npy", "nan", "empty", "img"):
        (tmp / name).mkdir()
    x = calib_tensors(1)[0]
    np.save(tmp / "npy" / "0.npy", x)
    x[0, 0, 0, 0] = np.nan
    np.save(tmp / "nan" / "0.npy", x)
    cv2.imwrite(str(tmp / "img" / "0.png"), np.zeros((64, 96, 3), np.uint8))
    (tmp / "t.onnx").write_text("text")
    graph = helper.make_graph([helper.make_node("Relu", ["input"], ["output"])], "g",
                              [helper.make_tensor_value_info("input", TensorProto.FLOAT, [1, 3, 4, 4])],
                              [helper.make_tensor_value_info("output", TensorProto.FLOAT, None)])
    onnx.save(helper.make_model(graph), tmp / "relu.onnx")
    return {"TXT": tmp / "t.onnx", "RELU": tmp / "relu.onnx", "NET": export_torch(tmp / "net.onnx"),
            "NPY": tmp / "npy", "NAN": tmp / "nan", "EMPTY": tmp / "empty", "IMG": tmp / "img"}


@pytest.mark.parametrize("args, message", [
    (["{TXT}", "--calib", "{NPY}"], "MODEL .*not an ONNX file"),
    (["{RELU}", "--calib", "{NPY}"], "no Conv or ConvTranspose"),
    (["{NET}", "--calib", "{EMPTY}"], "--calib .*holds no .npy tensors and no images"),
    (["{NET}", "--calib", "{NPY}", "--input-shape", "1,3,32,32"], "--calib: calibration tensor 1 has shape"),
    (["{NET}", "--calib", "{NAN}"], "--calib: calibration tensor 1 holds NaN"),
    (["{NET}", "--calib", "{IMG}"], "--size is needed for images"),
    (["{NET}", "--data", "{EMPTY}", "--calib", "{NPY}"], "--data is for a RUN or checkpoint"),
    (["{NET}"], "--calib DIR is needed"),
    (["{NET}", "--calib", "{NPY}", "--mean", "1,2"], "--mean 1,2: must be 3"),
    (["{NET}", "--calib", "{NPY}", "--task", "box"], "--task box: not one of labels, threshold, top1, boxes, boxes-obj, ctc, raw"),
    (["{NET}", "--calib", "{NPY}", "--task", "ctc"], r"--task ctc: output logits of shape \[1, 3, \d+, \d+\] holds no CTC scores"),
    (["{NET}", "--calib", "{NPY}", "--task", "boxes"], r"--task boxes:0.25: output logits of shape \[1, 3, \d+, \d+\] is no box table"),
    (["{NET}", "--calib", "{NPY}", "--task", "nope=raw"], "--task names no output of the model: nope"),
    (["{NET}", "--calib", "{NPY}", "--task", "raw", "--task", "labels"], "--task labels: one task for all"),
    (["{NET}", "--calib", "{NPY}", "--task", "raw", "--task", "logits=labels"], "--task: give one task for all outputs, or"),
    (["{NET}", "--calib", "{NPY}", "--max-seconds", "5"], "--max-seconds limits the accuracy-aware mode"),
    (["{NET}", "--calib", "{NPY}", "--min-sqnr", "9", "--max-seconds", "0"], "--max-seconds 0.0: must be a positive"),
])
def test_a_mistake_is_one_line_exit_2_and_nothing_written(inputs, tmp_path, args, message):
    """Found before torch is imported (in a second, not after seconds of imports): here torch cannot be imported."""
    out = tmp_path / "out" / "q.onnx"
    proc = run_cli("quantize", "static", *(a.format(**inputs) for a in args), "--out", str(out),
                   env=without_torch(tmp_path / "blocked"))
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.startswith("edgepick: error:") and proc.stderr.count("\n") == 1, proc.stderr
    assert re.search(message, proc.stderr), proc.stderr
    assert not (tmp_path / "out").exists() or list((tmp_path / "out").iterdir()) == []


@pytest.mark.slow
def test_the_json_reports_sqnr_and_cosine_per_output_and_a_raw_output_no_agreement(inputs, tmp_path):
    out = tmp_path / "q.onnx"
    proc = run_cli("quantize", "static", str(inputs["NET"]), "--calib", str(inputs["NPY"]), "--task", "logits=raw",
                   "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    result = json.loads(proc.stdout)
    fidelity = result["fidelity"]["logits"]
    assert fidelity["task"] == "raw" and fidelity["agreement"] is None and result["agreement_vs_fp32"] == {}
    assert 10.0 < fidelity["sqnr_db"] < 80.0 and 0.9 < fidelity["cosine"] <= 1.0
    recorded = json.loads({p.key: p.value for p in onnx.load(str(out)).metadata_props}["edgepick.fidelity"])
    assert recorded == result["fidelity"]
    # where the time went, stage by stage: the calibration pass apart from the measurements that choose the recipe
    stages = result["stage_s"]
    assert list(stages) == ["prepare", "calibrate", "choose_ranges", "write_qdq", "corrections", "finish",
                            "write_check"]
    assert all(s >= 0 for s in stages.values()) and stages["calibrate"] > 0 and stages["choose_ranges"] > 0
    assert sum(stages.values()) - stages["write_check"] <= result["calib_s"] + 0.05



def test_the_onnx_pass_and_all_its_methods_run_without_torch(inputs, tmp_path):
    """first-7, equalization, AdaRound and bias correction on an .onnx model: numpy and onnxruntime only."""
    out = tmp_path / "q.onnx"
    proc = run_cli("quantize", "static", str(inputs["NET"]), "--calib", str(inputs["NPY"]), "--weight-bits", "first-7",
                   "--equalize", "--adaround", "--adaround-budget", "2", "--out", str(out),
                   env=without_torch(tmp_path / "blocked"))
    assert proc.returncode == 0, proc.stderr
    quant = json.loads(proc.stdout)["quant"]
    assert quant["adaround"] and quant["equalize"] and "seven_bit_convs" in quant and quant["measured_images"] >= 1


def test_bias_correction_fits_on_the_tensors_after_the_check_tensors_that_judge_it(tmp_path, monkeypatch):
    """A correction (or AdaRound's rounding, or a budget) judged on the tensors it was fit on is met
    more easily than on other images: the fit takes the tensors after the check tensors where there
    are enough, and overlaps them as little as it can where there are not."""
    kept = [np.full(1, k) for k in range(12)]
    assert fitting_tensors(kept, 8, 4) == (8, 4) and fitting_tensors(kept, 8, 8) == (4, 8)
    assert fitting_tensors(kept[:3], 8, 4) == (0, 3)
    import edgepick.quant.onnx.static as static

    seen: list[list[float]] = []
    real = static.correct_onnx_biases

    def spy(float_model, int8, tensors, *args):
        seen.append([float(t[0, 0, 0, 0]) for t in tensors])
        return real(float_model, int8, tensors, *args)

    monkeypatch.setattr(static, "correct_onnx_biases", spy)
    xs = [np.random.default_rng(k).uniform(0, 1, (1, 3, 32, 32)).astype(np.float32) for k in range(40)]
    result = quantize_onnx_static(box_table_model(tmp_path / "m.onnx"), xs, tmp_path / "int8.onnx", progress=False)
    # 32x32 inputs: checked on the first 8, fit on the 32 after them
    assert seen == [[float(x[0, 0, 0, 0]) for x in xs[8:40]]] and result.quant["measured_images"] == 32
