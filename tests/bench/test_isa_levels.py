"""benchmarks/isa_levels.py: int8 files compared on onnxruntime and on OpenVINO at capped
instruction-set levels, against a reference model's labels or labels saved elsewhere."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import isa_levels  # noqa: E402


def test_object_agreement_counts_only_pixels_either_labels_as_an_object():
    reference = np.zeros((1, 4, 5), np.uint8)
    reference[0, 0, :2] = 1
    labels = reference.copy()
    labels[0, 0, 0] = 2  # one object pixel relabelled
    labels[0, 3, 4] = 3  # one background pixel called an object
    objects, every = isa_levels.agreement(labels, reference)
    assert objects == pytest.approx(1 / 3)
    assert every == pytest.approx(18 / 20)
    with pytest.raises(SystemExit, match="not the same images"):
        isa_levels.agreement(labels[:, :3], reference)


def _rows(report: str) -> list[list[str]]:
    return [line.strip("| ").split(" | ") for line in report.splitlines()
            if line.startswith("| ") and "(ms)" not in line]


def test_each_level_runs_every_model_against_the_reference(onnx_files, small_data, tmp_path, monkeypatch, capsys):
    pytest.importorskip("openvino")
    fp32, static = onnx_files["fp32"]["out"], onnx_files["static"]["out"]
    common = ["--data", str(small_data), "--count", "2", "--threads", "1", "--runs", "2"]
    monkeypatch.setattr(sys, "argv", ["isa_levels.py", "--models", fp32, "--reference", fp32,
                                      "--write-labels", str(tmp_path / "ref.npz"), *common])
    isa_levels.main()
    assert np.load(tmp_path / "ref.npz")["labels"].shape == (2, 240, 320)  # the frames' own size
    monkeypatch.setattr(sys, "argv", ["isa_levels.py", "--models", fp32, static, "--reference-labels",
                                      str(tmp_path / "ref.npz"), "--isa", "default,AVX2", *common])
    isa_levels.main()
    rows = _rows(capsys.readouterr().out)
    assert [r[:3] for r in rows] == [
        ["onnxruntime", "the CPU's own", "fp32.onnx"], ["onnxruntime", "the CPU's own", "static.onnx"],
        ["openvino", "default", "fp32.onnx"], ["openvino", "default", "static.onnx"],
        ["openvino", "AVX2", "fp32.onnx"], ["openvino", "AVX2", "static.onnx"]]
    assert float(rows[0][3]) == 100.0 and float(rows[0][6]) == 1.0  # onnxruntime's fp32 is the reference
    for r in rows[1:]:  # the suite's weak model labels few object pixels: its int8 agrees on most pixels
        assert 0 <= float(r[3]) <= 100 and 80 <= float(r[4]) <= 100 and float(r[5]) > 0


def test_one_reference_is_required(small_data, monkeypatch):
    monkeypatch.setattr(sys, "argv", ["isa_levels.py", "--models", "m.onnx", "--data", str(small_data)])
    with pytest.raises(SystemExit, match="one of --reference"):
        isa_levels.main()
