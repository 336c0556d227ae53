"""benchmarks/clutter_rounds.py: the rounds report of the shipped model end to end (one short round),
and the targets it holds the rounds to."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("mujoco")

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "benchmarks"))
import clutter_rounds  # noqa: E402

from edgepick.reference import reference_model  # noqa: E402


def test_the_report_holds_the_tables_the_targets_and_the_time(tmp_path):
    out = tmp_path / "report.md"
    proc = subprocess.run([sys.executable, str(REPO / "benchmarks" / "clutter_rounds.py"), "--rounds", "1",
                           "--max-cycles", "2", "--run", str(tmp_path), "--out", str(out)],
                          capture_output=True, text=True, timeout=600, cwd=REPO)
    assert proc.returncode == 0, proc.stderr
    report = out.read_text()
    assert report.startswith("# Clutter removal in the physics cell: 1 rounds per model")
    assert "Command: `python benchmarks/clutter_rounds.py --rounds 1 --max-cycles 2" in report and "mujoco " in report
    for heading in ("## Clutter removal", "## Targets", "## Time"):
        assert heading in report
    assert "reference int8: clearance >= 95%" in report and "| true labels | 1 |" in report


def _row(mode: str, model: str, success: float, clearance: float, ci: list[float]) -> dict:
    s = {"success_rate": success, "success_ci95": ci, "clearance": clearance, "clearance_ci95": ci,
         "by_lighting": {"single": {"success_rate": success, "success_ci95": ci, "clearance": 0.85,
                                    "clearance_ci95": ci}}}
    return {"mode": mode, "model": model, "rounds": s}


def test_targets_say_which_hold():
    rows = [_row("fp32 CPU", "fp32.onnx", 0.97, 0.96, [0.955, 0.98]),
            _row("static", str(reference_model()), 0.96, 0.94, [0.90, 0.97])]  # +-3.5 pp
    equivalence = [{"mode": "static", "against": "fp32 CPU", "rate": "grasp success", "verdict": "physics",
                    "difference": -0.004, "ci95": [-0.009, 0.002], "equivalence": "within"}]
    held = {target: holds for target, _, holds in clutter_rounds.targets(rows, equivalence, 1.0)}
    assert held["reference int8: grasp success >= 95%"] == "yes"
    assert held["reference int8: clearance >= 95%"] == "no"
    assert held["reference int8, single: clearance >= 90%"] == "no"
    assert held["fp32 CPU: clearance interval narrower than +-3 pp"] == "yes"
    assert held["static: clearance interval narrower than +-3 pp"] == "no"
    assert held["static minus fp32 CPU: grasp success within +-1 pp"] == "yes"


def test_the_shipped_file_is_found_by_any_path_to_it(tmp_path, monkeypatch):
    """--models may name the shipped file by a relative path: its targets are still reported."""
    monkeypatch.chdir(REPO)
    relative = str(reference_model().resolve().relative_to(REPO))
    held = {target for target, _, _ in clutter_rounds.targets([_row("static", relative, 0.96, 0.96, [0.95, 0.97])], [], 1.0)}
    assert "reference int8: grasp success >= 95%" in held
