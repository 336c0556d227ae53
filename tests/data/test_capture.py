"""`edgepick data capture` through the synthetic camera: the same interface a RealSense uses."""

from __future__ import annotations

import json

from edgepick.runtime.camera import FolderCamera
from tests.conftest import run_cli


def test_capture_writes_a_folder_that_the_folder_camera_reads(tmp_path):
    proc = run_cli("data", "capture", str(tmp_path / "cap"), "--camera", "synth:4", "--count", "3", "--size", "160x120",
                   check=True)
    assert json.loads(proc.stdout)["frames"] == 3
    intr = json.loads((tmp_path / "cap" / "intrinsics.json").read_text())
    assert (intr["width"], intr["height"]) == (160, 120)
    frames = list(FolderCamera(tmp_path / "cap"))
    assert len(frames) == 3 and frames[0].rgb.shape == (120, 160, 3) and frames[0].depth.dtype.name == "uint16"


def test_capture_bad_input_leaves_nothing(tmp_path):
    for args, message in ((["--camera", "webcam"], "unknown camera"), (["--count", "0"], "at least 1"),
                          (["--camera", "realsense"], "RealSense")):
        proc = run_cli("data", "capture", str(tmp_path / "cap"), *args)
        assert proc.returncode == 2 and message in proc.stderr and "Traceback" not in proc.stderr, proc.stderr
        assert list(tmp_path.iterdir()) == []
