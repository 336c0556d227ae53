"""`bench --cell N`: N pick cycles per model in the synthetic cell, the true-label row first, the
same scenes for every row, success and failures by kind, and the four report files."""

from __future__ import annotations

import csv
import json

import cv2
import pytest

from edgepick.bench import cell
from edgepick.cli import run
from tests.runtime.test_pipeline import red_model


def test_cell_rows_and_files(tmp_path, capfd):
    model, copy = red_model(tmp_path / "red.onnx", divide=64), tmp_path / "copy.onnx"
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


@pytest.mark.parametrize("args, message", [(["--rounds", "0"], "--rounds 0: must be at least 1"),
                                           (["--rounds", "2", "--max-cycles", "-2"], "--max-cycles -2: must be at least 1"),
                                           (["--cell", "--max-cycles", "3"], "--max-cycles 3: caps the cycles of a round"),
                                           (["--cell", "--margin", "0"], "--margin 0.0: must be a number of percentage")])
def test_cell_rounds_bad_input_is_one_line_and_nothing_written(tmp_path, capfd, args, message):
    model = red_model(tmp_path / "red.onnx")
    assert run(["bench", str(model), *args, "--out", str(tmp_path / "o")]) == 2
    out, err = capfd.readouterr()
    assert out == "" and err.count("\n") == 1 and message in err and not (tmp_path / "o").exists()


def test_cell_rounds_rows_and_int8_against_fp32(tmp_path, capfd):
    """--rounds: every row clears the same tables laid out alike, each with its rounds summed; the int8
    row against the fp32 one, paired by round, in cell.json and cell.md."""
    pytest.importorskip("mujoco")
    from edgepick.reference import reference_model

    fp32 = red_model(tmp_path / "red.onnx", divide=64)
    assert run(["bench", str(fp32), str(reference_model()), "--cell", "--rounds", "2", "--max-cycles", "3",
                "--verdict", "physics", "--out", str(tmp_path / "out")]) == 0
    out, err = capfd.readouterr()
    result = json.loads(out)
    rows = result["rows"]
    assert [r["mode"] for r in rows] == ["true labels", "fp32 CPU", "static"]
    for r in rows:
        s = r["rounds"]
        assert s["rounds"] == 2 and s["picks"] == r["cycles"] <= 6 and s["verdict"] == "physics"
        assert [d["parts"] for d in s["per_round"]] == [d["parts"] for d in rows[0]["rounds"]["per_round"]]  # alike
        assert r["success_ci95"] is not None and s["clearance_ci95"] is not None
    rates = {(e["rate"], e["verdict"]) for e in result["equivalence"]}
    assert rates == {("grasp success", "geometric"), ("grasp success", "physics"), ("clearance", "physics")}
    assert all(e["mode"] == "static" and e["against"] == "fp32 CPU" and e["paired_by"] == "round" and e["pairs"] == 2
               for e in result["equivalence"])
    md = (tmp_path / "out" / "cell.md").read_text()
    assert "## Clutter removal" in md and "## int8 against fp32 on the same scenes" in md and "rounds per model" in md
    assert json.loads((tmp_path / "out" / "cell.json").read_text())["equivalence"] == result["equivalence"]


def test_success_latency_is_a_scatter_with_every_label_in_full(tmp_path):
    """success-latency.png: x the pipeline p50, y grasp success, one point per row with its whole mode
    label beside it, inside the image and clear of the other labels (two models on one spot here), the
    true-label row in grey."""
    def row(mode, model, p50, success):
        return cell.CellRow(mode, model, 20, p50, 1.0, p50, p50 * 1.2, None, success, success / 20, success / 20)

    rows = [row("true labels", "-", 6.0, 19), row("static (deeplabv3-mobilenetv3-640x480-static-int8)", "a", 95.0, 16),
            row("static (static)", "b", 96.0, 16), row("fp32 CPU", "c", 180.0, 10)]
    layout = cell._plot(rows, tmp_path / "s.png")
    png = cv2.imread(str(tmp_path / "s.png"))
    h, w = png.shape[:2]
    ink = png.min(axis=2) < 180  # text and points; the grey grid is lighter
    boxes = [box for _, box in layout]
    for r, (x0, y0, x1, y1) in zip(rows, boxes):
        assert x1 - x0 == cv2.getTextSize(r.mode, cell.FONT, cell.SCALE, 1)[0][0]  # the whole label's width
        assert 0 <= x0 and x1 < w and 0 <= y0 and y1 < h
        assert ink[y0:y1, x0:x0 + 4].any() and ink[y0:y1, x1 - 6:x1].any()  # drawn to its last letter
    assert all(cell._overlap(a, b) == 0 for i, a in enumerate(boxes) for b in boxes[i + 1:])
    (truth, ref, static, fp32) = [point for point, _ in layout]
    assert truth[0] < ref[0] < static[0] < fp32[0]  # slower further right
    assert fp32[1] > static[1] == ref[1] > truth[1]  # higher success higher
    b, g, r = (int(v) for v in png[truth[1], truth[0]])
    assert b == g == r < 200  # the true-label row in grey


def test_cell_physics_verdict_beside_the_geometric_one(tmp_path, capfd):
    """--verdict both: each row gains the physics check's success, and where the two rules disagree."""
    import pytest

    pytest.importorskip("mujoco")
    from edgepick.sim.physics import PHYSICS_FAILURES

    model = red_model(tmp_path / "red.onnx", divide=64)
    assert run(["bench", str(model), "--cell", "6", "--verdict", "both", "--out", str(tmp_path / "out")]) == 0
    out, err = capfd.readouterr()
    rows = json.loads(out)["rows"]
    for r in rows:
        p = r["physics"]
        assert p["executions"] == 6 and p["success"] + sum(p["failures"].values()) == 6
        standing = 6 - p["failures"].get("unsettled", 0)  # the rate over the scenes that stand as rendered
        assert p["success_rate_standing"] == (round(p["success"] / standing, 4) if standing else None)
        assert set(p["failures"]) <= {*PHYSICS_FAILURES, "unreachable", "no object seen", "robot stopped"}
        for counts in r["disagreements"].values():  # each disagreement is a cycle one rule passed and one did not
            assert sum(counts.values()) <= 6
        assert sum(d["executions"] for d in r["by_lighting"].values()) == 6
        assert set(r["by_lighting"]) <= {"ceiling", "ceiling+white", "single", "hazard"}
    truth = rows[0]
    assert truth["physics"]["ms_p50"] > 0  # the true labels always choose something to simulate
    geometric_only = sum(c["geometric only"] for c in truth["disagreements"].values())
    physics_only = sum(c["physics only"] for c in truth["disagreements"].values())
    assert truth["success"] - geometric_only + physics_only == truth["physics"]["success"]
    md = (tmp_path / "out" / "cell.md").read_text()
    assert "Physics success (%)" in md and "of standing scenes (%)" in md and "## By light condition (thesis Table 5.3)" in md
    assert "## Where the geometric rule and the physics check disagree" in err


def test_cell_reports_success_per_light_condition_without_physics(tmp_path, capfd):
    model = red_model(tmp_path / "red.onnx", divide=64)
    assert run(["bench", str(model), "--cell", "4", "--out", str(tmp_path / "out")]) == 0
    rows = json.loads(capfd.readouterr().out)["rows"]
    for r in rows:
        assert r["physics"] is None and r["disagreements"] == {}
        lights = r["by_lighting"]
        assert sum(d["executions"] for d in lights.values()) == 4
        assert sum(d["success"] for d in lights.values()) == r["success"]
        assert all(d["undetected"] >= 0 for d in lights.values())
    assert sum(d["undetected"] for d in rows[0]["by_lighting"].values()) < 4  # true labels find almost everything
