"""benchmarks/peers.py's OpenVINO rows: fp32 really runs in f32, and a bf16 row only where OpenVINO
really runs bf16 (CPUs with AMX or avx512_bf16)."""

from __future__ import annotations

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
