"""benchmarks/ptq_methods_onnx.py: static PTQ methods over calibration seeds on a model edgepick did
not make, and its foreground agreement measure."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("onnx")
sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import ptq_methods_onnx  # noqa: E402


def test_foreground_agreement_counts_only_pixels_either_model_calls_foreground():
    fp32 = np.zeros((1, 3, 4, 5), np.float32)
    fp32[0, 1, 0, :2] = 1  # two pixels of class 1, the rest class 0
    int8 = fp32.copy()
    int8[0, 2, 0, 0] = 2  # one of them now class 2
    int8[0, 1, 3, 4] = 1  # and one background pixel class 1
    foreground, every = ptq_methods_onnx.agreement(lambda x: [int8], [[fp32]], [None], False, [False])
    assert foreground == [pytest.approx(1 / 3)]  # 3 pixels either calls foreground, 1 equal
    assert every == [pytest.approx(18 / 20)]
    background = np.zeros_like(fp32)
    background[0, 0] = 1
    foreground, _ = ptq_methods_onnx.agreement(lambda x: [background], [[background]], [None], False, [False])
    assert np.isnan(foreground[0])


@pytest.mark.slow
def test_each_case_gets_a_row_over_the_seeds(tmp_path, monkeypatch, capsys):
    pytest.importorskip("openvino")
    from tests.quant.onnx_models import calib_tensors, export_torch

    export_torch(tmp_path / "net.onnx", opset=13, two_outputs=True)
    (tmp_path / "calib").mkdir()
    for k, x in enumerate(calib_tensors(7)):
        np.save(tmp_path / "calib" / f"{k}.npy", x)
    monkeypatch.setattr(sys, "argv", [
        "ptq_methods_onnx.py", "--onnx", str(tmp_path / "net.onnx"), "--calib", str(tmp_path / "calib"),
        "--held", "2", "--calib-count", "3", "--seeds", "0,1", "--cases", "7/none,first-7/empirical,7/none/ada",
        "--adaround-budget", "2", "--runs", "2", "--threads", "1", "--openvino"])
    ptq_methods_onnx.main()
    report = capsys.readouterr().out
    rows = [line.split(" | ") for line in report.splitlines() if line.startswith("| ") and "(ms)" not in line]
    assert [r[:4] for r in rows] == [["| 7", "9-9", "none", "-"], ["| first-7", rows[1][1], "empirical", "-"],
                                     ["| 7", "9-9", "none", "ada"]]
    for r in rows:  # two outputs, each mean (min-max) of a share in percent, on onnxruntime and OpenVINO
        for cell in (r[4], r[5], r[8]):
            values = [v.split(" (")[0] for v in cell.split(" / ")]
            assert len(values) == 2 and all(v == "no foreground" or 50 <= float(v) <= 100 for v in values)
        assert float(r[4].split(" (")[0]) >= 50  # the first output's argmax has a foreground
    assert "Each seed draws 3 of the first 5 inputs to calibrate; agreement and latency on the last 2" in report
