"""benchmarks/session_switch.py: a float net and its int8 file timed one after the other, then in
alternating blocks with each pause; the pause the timings use is put back afterwards."""

from __future__ import annotations

import re
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import session_switch  # noqa: E402

from edgepick.runtime import session  # noqa: E402


def test_each_pause_gets_a_row_with_both_p50s_and_the_speed_up(tmp_path):
    pause = session.SWITCH_PAUSE_S
    out = tmp_path / "report.md"
    assert session_switch.main(["--pauses", "0,0.05", "--runs", "3", "--out", str(out)]) == 0
    rows = re.findall(r"^\| (.+?) \| ([\d.]+) \| ([\d.]+) \| ([\d.]+)x \|$", out.read_text(), re.M)
    assert [r[0] for r in rows] == ["none: one model after the other", "0 s", "0.05 s"]
    for _, fp32, int8, ratio in rows:
        assert abs(float(ratio) - float(fp32) / float(int8)) < 0.02 * float(ratio)  # of the unrounded p50s
    assert "Command: `python benchmarks/session_switch.py --pauses 0,0.05 --runs 3" in out.read_text()
    assert session.SWITCH_PAUSE_S == pause  # set per row, then put back
