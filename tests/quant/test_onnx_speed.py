"""The int8 file timed against the float model on this machine (quant/onnx/speed.py)."""

from __future__ import annotations

import json

import onnx
import pytest

from edgepick.quant.config import OnnxOptions
from edgepick.quant.onnx.speed import slower_than_fp32_warning, speed_against_fp32
from edgepick.quant.onnx.static import quantize_onnx_static
from tests.quant.onnx_models import calib_tensors, export_torch


def test_the_static_pass_records_both_times_on_this_machine(tmp_path):
    src = export_torch(tmp_path / "net.onnx")
    result = quantize_onnx_static(src, calib_tensors(4), tmp_path / "int8.onnx", progress=False)
    speed = result.quant["speed"]
    assert speed["fp32_ms"] > 0 and speed["int8_ms"] > 0 and speed["threads"] == 2 and speed["machine"]
    assert speed["speedup_vs_fp32"] == pytest.approx(speed["fp32_ms"] / speed["int8_ms"], abs=1e-3)
    written = json.loads(dict((p.key, p.value) for p in onnx.load(result.out).metadata_props)["edgepick.quant"])
    assert written["speed"] == speed


def test_without_it_nothing_is_timed(tmp_path):
    src = export_torch(tmp_path / "net.onnx")
    result = quantize_onnx_static(src, calib_tensors(4), tmp_path / "int8.onnx", progress=False,
                                  options=OnnxOptions(time_against_fp32=False))
    assert "speed" not in result.quant


def test_a_graph_timed_against_itself_runs_at_about_its_own_speed(tmp_path):
    """Both graphs given are timed and the ratio is theirs, and the record names the machine. One graph timed
    twice is near 1x on a quiet machine; on a loaded shared CPU (the test suite's own workers) it left 0.5-2x
    once, so the bound is wide: it catches the two graphs timed differently (threads, inputs), not the noise."""
    src = export_torch(tmp_path / "net.onnx")
    model = onnx.load(str(src))
    x = calib_tensors(1)[0]
    speed = speed_against_fp32(model, model, x)
    assert set(speed) == {"fp32_ms", "int8_ms", "speedup_vs_fp32", "threads", "machine"}
    assert speed["fp32_ms"] > 0 and speed["int8_ms"] > 0 and speed["machine"]
    assert speed["speedup_vs_fp32"] == round(speed["fp32_ms"] / speed["int8_ms"], 3)
    assert 0.2 < speed["speedup_vs_fp32"] < 5.0


def test_the_pass_says_so_where_the_int8_file_is_the_slower(tmp_path, monkeypatch, capsys):
    import edgepick.quant.onnx.static as static

    slow = {"fp32_ms": 1.0, "int8_ms": 2.0, "speedup_vs_fp32": 0.5, "threads": 2, "machine": "this CPU"}
    monkeypatch.setattr(static, "speed_against_fp32", lambda *args: slow)
    result = quantize_onnx_static(export_torch(tmp_path / "net.onnx"), calib_tensors(4), tmp_path / "int8.onnx",
                                  progress=False)
    warned = [line for line in capsys.readouterr().err.splitlines() if "fp32's speed" in line]
    assert warned == [f"edgepick: warning: {slower_than_fp32_warning(slow)}"] and result.quant["speed"] == slow


def test_a_slower_int8_file_is_said_in_one_line():
    speed = {"fp32_ms": 10.0, "int8_ms": 12.5, "speedup_vs_fp32": 0.8, "threads": 2, "machine": "AMD EPYC (avx2)"}
    line = slower_than_fp32_warning(speed)
    assert line is not None and "\n" not in line and "0.80x fp32's speed" in line and "AMD EPYC (avx2)" in line
    # within the timing's noise of fp32, or faster: nothing to say
    assert slower_than_fp32_warning({**speed, "int8_ms": 10.5, "speedup_vs_fp32": round(10 / 10.5, 3)}) is None
    assert slower_than_fp32_warning({**speed, "int8_ms": 8.0, "speedup_vs_fp32": 1.25}) is None
