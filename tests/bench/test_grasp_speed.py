"""benchmarks/grasp_speed.py: another commit's grasp step, unpacked and imported beside this
checkout's, makes records of its own (the comparison can tell them apart); a bad commit name stops
the script in one line before any work."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "benchmarks"))
import grasp_speed  # noqa: E402

from edgepick.runtime import grasp  # noqa: E402
from edgepick.sim.camera import SynthCamera  # noqa: E402


def committed() -> bool:
    return subprocess.run(["git", "-C", str(REPO), "rev-parse", "--verify", "-q", "HEAD"], capture_output=True).returncode == 0


@pytest.mark.skipif(not committed(), reason="needs the repository's git history")
def test_a_commits_grasp_step_runs_beside_this_one(tmp_path):
    theirs = grasp_speed.grasp_step_of("HEAD", tmp_path)
    assert Path(theirs.__code__.co_filename).is_relative_to(tmp_path)
    assert grasp.grasp_records.__module__ == "edgepick.runtime.grasp" and "edgepick.runtime.grasp" in sys.modules
    assert sys.modules["edgepick.runtime.grasp"] is grasp  # this checkout's modules are back in place
    camera = SynthCamera(640, 480, seed=0, mount_height_m=0.7)
    frames = [camera.read() for _ in range(2)]
    labels, cal = [f.labels for f in frames], camera.calibration()
    old, new, same = grasp_speed.compare(theirs, lambda *a: [], frames, labels, cal, 1)
    assert old.shape == new.shape == (2,) and (old > 0).all() and (new > 0).all()
    assert same == 0  # the cell's frames hold objects: HEAD's records are not the empty ones
    assert grasp_speed.compare(grasp.grasp_records, grasp.grasp_records, frames, labels, cal, 1)[2] == 2


def test_a_bad_commit_is_one_line_before_any_work():
    proc = subprocess.run([sys.executable, str(REPO / "benchmarks" / "grasp_speed.py"), "--against", "no-such-commit"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 1 and proc.stdout == ""
    assert proc.stderr.strip() == f"grasp_speed: error: --against no-such-commit: not a commit of {REPO}"
