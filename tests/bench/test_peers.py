"""benchmarks/peers.py's OpenVINO rows: fp32 really runs in f32, and a bf16 row only where OpenVINO
really runs bf16 (CPUs with AMX or avx512_bf16)."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import pytest

ov = pytest.importorskip("openvino")
pytest.importorskip("onnx")

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import peers  # noqa: E402

from edgepick.geometry import Size  # noqa: E402
from tests.runtime.test_session import compile_spy, red_channel_model  # noqa: E402


def test_openvino_rows_run_in_the_precision_they_are_labelled(tmp_path, monkeypatch):
    compiled = compile_spy(monkeypatch)
    path = red_channel_model(tmp_path / "m.onnx")
    fp32 = peers.OpenVinoModel(ov.Core().read_model(str(path)), 1, Size(12, 8))
    bf16 = peers.OpenVinoModel(ov.Core().read_model(str(path)), 1, Size(12, 8), precision="bf16")
    assert [config["INFERENCE_PRECISION_HINT"] for config, _ in compiled] == ["f32", "bf16"]
    assert fp32.compiled.get_property("INFERENCE_PRECISION_HINT") == ov.Type.f32 and not fp32.runs_in_bf16()
    assert bf16.compiled.get_property("INFERENCE_PRECISION_HINT") in (ov.Type.bf16, ov.Type.f32)  # f32: no bf16 here


@pytest.mark.slow
def test_peers_onnx_compares_every_tool_on_a_model_edgepick_did_not_make(tmp_path, monkeypatch, capsys):
    pytest.importorskip("nncf")
    import numpy as np
    import peers_onnx

    from tests.quant.onnx_models import calib_tensors, export_torch

    export_torch(tmp_path / "net.onnx", opset=12, two_outputs=True)
    (tmp_path / "calib").mkdir()
    for k, x in enumerate(calib_tensors(6)):
        np.save(tmp_path / "calib" / f"{k}.npy", x)
    monkeypatch.setattr(sys, "argv", ["peers_onnx.py", "--onnx", str(tmp_path / "net.onnx"), "--calib",
                                      str(tmp_path / "calib"), "--calib-count", "4", "--runs", "2", "--threads", "1",
                                      "--edgepick-methods", "first-7/empirical/cle,7/none/convs"])
    peers_onnx.main()
    report = capsys.readouterr().out
    rows = [line for line in report.splitlines() if line.startswith("| ") and "(ms)" not in line]
    assert [r.split(" | ")[0] for r in rows[:7]] == [
        "| fp32 (onnxruntime)", "| onnxruntime quantize_static, defaults",
        "| onnxruntime quantize_static, QDQ U8S8 per-channel reduce-range", "| fp32 (OpenVINO)", "| NNCF + OpenVINO",
        "| edgepick static (onnxruntime)", "| edgepick static (OpenVINO)"]
    assert [r.split(" | ")[0] for r in rows[7:11]] == [
        "| edgepick static, first-7/empirical/cle (onnxruntime)", "| edgepick static, first-7/empirical/cle (OpenVINO)",
        "| edgepick static, 7/none/convs (onnxruntime)", "| edgepick static, 7/none/convs (OpenVINO)"]
    assert "edgepick's fastest file on OpenVINO against NNCF + OpenVINO" in report
    assert "edgepick's fastest file on onnxruntime against onnxruntime's own best settings" in report
    header = next(line for line in report.splitlines() if line.startswith("| op |"))
    fastest = re.search(r"fastest file on onnxruntime against onnxruntime.s own best settings: [0-9.]+x \((.+)\)\.", report).group(1)
    expected = ["op", "onnxruntime quantize_static, best (ms)", "edgepick (ms)"]
    if fastest != "edgepick static (onnxruntime)":  # the op table profiles edgepick's fastest file too
        expected.append(f"{fastest} (ms)")
    assert [c.strip() for c in header.strip("|").split("|")] == expected
    assert peers_onnx.method_config("7/empirical/convs")["options"].placement == "convs"
    assert peers_onnx.method_config("7/empirical/gelu-sigmoid")["options"].gelu == "sigmoid"
    with pytest.raises(SystemExit, match="expected"):
        peers_onnx.method_config("7/empirical/convs/convs")
    with pytest.raises(SystemExit, match="with placement='convs'"):
        peers_onnx.method_config("7/empirical/convs/gelu-sigmoid")
    assert rows[0].split(" | ")[1] == "100.00 / 100.00"  # fp32 against itself, both outputs
    assert "lifted to opset 13" in report and "9 of 9 convs int8" in report


def test_text_pages_writes_readable_pages_of_the_size_asked(tmp_path, monkeypatch):
    import cv2
    import text_pages

    monkeypatch.setattr(sys, "argv", ["text_pages.py", str(tmp_path / "pages"), "--count", "3", "--size", "160x120"])
    text_pages.main()
    pages = sorted((tmp_path / "pages").glob("*.png"))
    assert [p.name for p in pages] == ["000.png", "001.png", "002.png"]
    images = [cv2.imread(str(p)) for p in pages]
    assert all(im.shape == (120, 160, 3) and im.std() > 5 for im in images)  # text on a page, not a blank
