"""`bench --cell N`: N pick cycles per model in the synthetic cell, the true-label row first, the
same scenes for every row, success and failures by kind, and the four report files."""

from __future__ import annotations

import csv
import json

from edgepick.cli import run
from tests.runtime.test_pipeline import red_model


def test_cell_rows_and_files(tmp_path, capfd):
    model, copy = red_model(tmp_path / "red.onnx"), tmp_path / "copy.onnx"
    copy.write_bytes(model.read_bytes())
    assert run(["bench", str(model), str(copy), "--cell", "6", "--out", str(tmp_path / "out")]) == 0
    out, err = capfd.readouterr()
    rows = json.loads(out)["rows"]
    assert [r["mode"] for r in rows] == ["true labels", "fp32 CPU (red)", "fp32 CPU (copy)"]  # one mode: files named
    assert all(r["cycles"] == 6 for r in rows)
    truth, red, again = rows
    assert truth["success"] >= 3 and set(truth["failures"]) <= {"unreachable", "position", "orientation"}
    assert red["success"] + sum(red["failures"].values()) == 6
    same = ("success", "failures", "cycles", "size_mb")  # the same scenes: the same verdicts for the same model
    assert {k: red[k] for k in same} == {k: again[k] for k in same}
    assert red["p50_ms"] > 0 and red["size_mb"] is not None and truth["size_mb"] is None
    for name in ("cell.md", "cell.csv", "cell.json", "success-latency.png"):
        assert (tmp_path / "out" / name).stat().st_size > 0
    table = list(csv.reader(open(tmp_path / "out" / "cell.csv")))
    assert table[0][5] == "Grasp success (%)" and len(table) == 4
    assert "| true labels |" in err


def test_cell_bad_input(tmp_path, capfd):
    model = red_model(tmp_path / "red.onnx")
    assert run(["bench", str(model), "--cell", "0", "--out", str(tmp_path / "o")]) == 2
    assert run(["bench", str(model), "--out", str(tmp_path / "o")]) == 2
    err = capfd.readouterr().err
    assert "--cell 0" in err and "--data is needed" in err
    assert not (tmp_path / "o").exists()
