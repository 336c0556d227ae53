"""Bench table formats: Markdown, CSV, JSON, PNG; thesis row names and order; durations."""

from __future__ import annotations

import csv
import json

import cv2
import pytest

from edgepick.bench.measure import Row, mode_label, order_key
from edgepick.bench.report import HEADER_55, HEADER_56, duration, write_reports
from edgepick.runtime.model_info import ModelInfo


def row(mode, p50=10.0, miou=0.5, pipeline=True, device="cpu"):
    return Row(mode, f"{mode}.onnx", "int8", 0.9, miou, p50, p50 * 1.2, 3600.0, 5.0,
               p50 + 3 if pipeline else None, p50 + 6 if pipeline else None, device)


@pytest.mark.parametrize("meta, label", [
    ({"edgepick.precision": "fp32"}, "fp32 CPU"),
    ({"edgepick.precision": "int8", "edgepick.quant": json.dumps({"mode": "static"})}, "static"),
    ({"edgepick.precision": "int8", "edgepick.quant": json.dumps({"mode": "qat", "qat_fraction": 1.0})}, "QaT"),
    ({"edgepick.precision": "int8", "edgepick.quant": json.dumps({"mode": "hybrid", "qat_fraction": 0.05})},
     "hybrid-QaT 5%"),
    ({"edgepick.precision": "int8", "edgepick.quant": json.dumps({"mode": "hybrid", "qat_fraction": 1 / 12})},
     "hybrid-QaT 8.33%"),
])
def test_mode_labels_follow_the_thesis(meta, label):
    required = {"edgepick.classes": '["a", "b"]', "edgepick.input_size": "[2, 2]", "edgepick.colorspace": "rgb"}
    assert mode_label(ModelInfo.from_metadata({**required, **meta}, "m.onnx")) == label


def test_rows_sort_in_thesis_order():
    rows = [row("hybrid-QaT 10%"), row("static"), row("hybrid-QaT 1%"), row("QaT"), row("fp32 CPU"),
            row("fp32 GPU", device="NVIDIA H100"), row("hybrid-QaT 5%")]
    assert [r.mode for r in sorted(rows, key=order_key)] == [
        "fp32 GPU", "fp32 CPU", "static", "QaT", "hybrid-QaT 1%", "hybrid-QaT 5%", "hybrid-QaT 10%"]


@pytest.mark.parametrize("seconds, text", [(None, "-"), (42, "42 s"), (200, "3 min 20 s"), (3900, "1 h 05 min"),
                                           (4 * 86400 + 20 * 3600, "4 d 20 h")])
def test_durations_read_like_the_thesis(seconds, text):
    assert duration(seconds) == text


def test_reports_in_every_format(tmp_path):
    rows = [row("fp32 CPU", 40.0, 0.60), row("static", 12.0, 0.58), row("QaT", 12.5, 0.59, pipeline=False)]
    paths = write_reports(rows, tmp_path / "out", {"title": "t", "machine": "m"})
    md = (tmp_path / "out" / "table.md").read_text()
    assert "| " + " | ".join(HEADER_55) + " |" in md and "| " + " | ".join(HEADER_56) + " |" in md
    assert "| static | 90.00 | 58.00 | 12.0 | 14.4 | 1 h 00 min | 5.00 |" in md
    assert md.count("| QaT |") == 1  # no pipeline figure: only in Table 5.5
    with open(paths["csv"]) as f:
        got = list(csv.DictReader(f))
    assert [r["mode"] for r in got] == ["fp32 CPU", "static", "QaT"] and float(got[1]["p50_ms"]) == 12.0
    data = json.loads((tmp_path / "out" / "table.json").read_text())
    assert data["context"]["machine"] == "m" and len(data["rows"]) == 3
    png = cv2.imread(paths["png"])
    assert png is not None and png.shape == (520, 800, 3) and (png < 250).any()
