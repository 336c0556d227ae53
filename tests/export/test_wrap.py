"""`model wrap` and `model info`: a model from elsewhere, float or int8, run by eval, bench and grasp."""

from __future__ import annotations

import json
import re
from pathlib import Path

import cv2
import numpy as np
import pytest

from edgepick.geometry import Size
from edgepick.runtime.preprocessing import Preprocessing
from edgepick.runtime.session import Segmenter
from tests.conftest import run_cli
from tests.quant.onnx_models import calib_tensors, export_torch, run

PREP = ["--size", "96x64", "--channels", "bgr", "--mean", "0.4,0.5,0.6", "--std", "0.2,0.25,0.3"]
PREPROCESSING = Preprocessing(size=Size(96, 64), channels="bgr", mean=(0.4, 0.5, 0.6), std=(0.2, 0.25, 0.3))


def _classes(data: Path) -> list[str]:
    return json.loads((data / "meta.json").read_text())["classes"]


def _rgb(data: Path, split: str = "val") -> np.ndarray:
    path = sorted((data / split / "rgb").glob("*.png"))[0]
    return cv2.imread(str(path))[..., ::-1].copy()


def test_a_wrapped_model_labels_as_its_own_outputs_say(small_data, tmp_path):
    classes = _classes(small_data)
    src = export_torch(tmp_path / "net.onnx", out_channels=len(classes))
    proc = run_cli("model", "wrap", str(src), "--classes", ",".join(classes), *PREP, "--out", str(tmp_path / "w.onnx"))
    assert proc.returncode == 0, proc.stderr
    result = json.loads(proc.stdout)
    assert result["precision"] == "fp32" and result["label_step"] == "argmax" and result["input_size"] == [64, 96]
    seg = Segmenter(tmp_path / "w.onnx", threads=1)
    assert seg.info.classes == classes and seg.info.input_size == Size(96, 64)
    rgb = cv2.resize(_rgb(small_data), (96, 64), interpolation=cv2.INTER_AREA)
    ours = seg.infer(rgb[None])
    logits = run(src, PREPROCESSING.tensor(rgb, Size(96, 64)))[0]
    assert (ours == logits.argmax(1)[0]).mean() >= 0.999


@pytest.mark.slow
def test_quantize_wrap_eval_bench_and_grasp_on_a_model_from_elsewhere(small_data, tmp_path):
    """The whole path for an opset-12 export with dynamic dims: int8 by `quantize static`, then
    wrapped, then run by the commands that take edgepick's own models."""
    classes = _classes(small_data)
    src = export_torch(tmp_path / "net.onnx", opset=12, out_channels=len(classes))
    calib = tmp_path / "calib"
    calib.mkdir()
    for k, rgb in enumerate(sorted((small_data / "train" / "rgb").glob("*.png"))[:6]):
        cv2.imwrite(str(calib / f"{k}.png"), cv2.imread(str(rgb)))
    proc = run_cli("quantize", "static", str(src), "--calib", str(calib), *PREP, "--out", str(tmp_path / "q.onnx"))
    assert proc.returncode == 0, proc.stderr
    proc = run_cli("model", "wrap", str(tmp_path / "q.onnx"), "--classes", ",".join(classes), *PREP,
                   "--out", str(tmp_path / "qw.onnx"))
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["precision"] == "int8"
    info = json.loads(run_cli("model", "info", str(tmp_path / "qw.onnx"), check=True).stdout)
    assert info["edgepick_model"] is True and info["int8_convs"] == info["convs"] == 8
    assert json.loads(info["metadata"]["edgepick.quant"])["source"] == "onnx"
    raw = json.loads(run_cli("model", "info", str(src), check=True).stdout)
    assert raw["edgepick_model"] is False and "not an edgepick model" in raw["why_not"] and raw["opset"] == 12

    evaluated = run_cli("eval", str(tmp_path / "qw.onnx"), str(small_data), "--split", "val")
    assert evaluated.returncode == 0, evaluated.stderr
    assert 0.0 <= json.loads(evaluated.stdout)["miou"] <= 1.0
    bench = run_cli("bench", str(tmp_path / "qw.onnx"), "--data", str(small_data), "--runs", "3",
                    "--out", str(tmp_path / "bench"))
    assert bench.returncode == 0, bench.stderr
    assert "| static |" in (tmp_path / "bench" / "table.md").read_text()  # the pass's own mode, kept by wrap
    scene = sorted((small_data / "test" / "rgb").glob("*.png"))[0].name
    grasp = run_cli("grasp", "--model", str(tmp_path / "qw.onnx"), "--rgb", str(small_data / "test" / "rgb" / scene),
                    "--depth", str(small_data / "test" / "depth" / scene), "--intrinsics", str(small_data / "meta.json"))
    assert grasp.returncode == 0, grasp.stderr
    assert isinstance(json.loads(grasp.stdout), list)


def test_one_channel_and_two_output_models(tmp_path):
    sig = export_torch(tmp_path / "sig.onnx", out_channels=1, sigmoid=True)
    proc = run_cli("model", "wrap", str(sig), "--classes", "background,object", "--size", "96x64",
                   "--out", str(tmp_path / "sw.onnx"))
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["label_step"] == "threshold 0.5"
    x = calib_tensors(1, seed=3)[0]
    rgb = np.ascontiguousarray((x[0].transpose(1, 2, 0) * 255).round().astype(np.uint8))
    labels = Segmenter(tmp_path / "sw.onnx", threads=1).infer(rgb[None])
    probability = run(sig, Preprocessing().tensor(rgb, Size(96, 64)))[0][0, 0]
    assert set(np.unique(labels)) <= {0, 1} and (labels == (probability > 0.5)).mean() >= 0.999

    two = export_torch(tmp_path / "two.onnx", two_outputs=True)
    proc = run_cli("model", "wrap", str(two), "--classes", "a,b", "--output", "aux", "--size", "96x64",
                   "--out", str(tmp_path / "tw.onnx"))
    assert proc.returncode == 0, proc.stderr  # the half-resolution aux map, resized to the input
    assert Segmenter(tmp_path / "tw.onnx", threads=1).infer(rgb[None]).shape == (64, 96)


@pytest.mark.parametrize("args, message", [
    (["{TXT}", "--classes", "a,b,c"], "MODEL .*not an ONNX file"),
    (["{NET}", "--classes", "a,b"], "--classes a,b: 2 names for an output of 3 channels"),
    (["{NET}", "--classes", "a,b,c", "--output", "nope"], "--output nope: the model has no such output"),
    (["{NET}", "--classes", "a,b,c", "--threshold", "0.5"], "--threshold 0.5: is for a one-channel output"),
    (["{NET}", "--classes", "a,a,b"], "--classes .*different"),
    (["{DYN}", "--classes", "a,b,c"], "--size is needed"),
    (["{OURS}", "--classes", "a,b,c"], "input is not float32"),
])
def test_a_wrap_mistake_is_one_line_exit_2_and_nothing_written(tmp_path, args, message):
    net = export_torch(tmp_path / "net.onnx")
    (tmp_path / "t.onnx").write_text("text")
    from tests.runtime.test_pipeline import red_model

    paths = {"NET": net, "TXT": tmp_path / "t.onnx", "DYN": net, "OURS": red_model(tmp_path / "ours.onnx")}
    if "{DYN}" not in args:
        args = [*args, "--size", "96x64"]
    out = tmp_path / "out" / "w.onnx"
    proc = run_cli("model", "wrap", *(a.format(**paths) for a in args), "--out", str(out))
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.startswith("edgepick: error:") and proc.stderr.count("\n") == 1, proc.stderr
    assert re.search(message, proc.stderr), proc.stderr
    assert not (tmp_path / "out").exists() or list((tmp_path / "out").iterdir()) == []
