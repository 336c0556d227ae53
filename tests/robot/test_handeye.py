"""`calibrate collect`: the plan (a grid at several heights, checked whole against the envelope
before any move), the collect -> calibrate -> pick chain in the synthetic cell, plan-only sending
nothing, and the degenerate and not-seen cases leaving no pairs file."""

from __future__ import annotations

import json
import math
import socket

import numpy as np
import pytest

from edgepick.cli import run
from edgepick.robot.envelope import Envelope, SafetyError
from edgepick.robot.handeye import CollectConfig, check_plan, marker_point, plan_positions
from edgepick.robot.motion import HOME_POSE
from edgepick.sim.camera import SynthCamera


@pytest.mark.parametrize("n", [4, 7, 16, 30])
def test_plan_is_n_positions_in_the_region_off_one_plane(n):
    cfg = CollectConfig(poses=n)
    poses = np.array(plan_positions(cfg))
    assert poses.shape == (n, 6) and len({tuple(p) for p in poses[:, :3].round(6)}) == n
    lo, hi = np.array(cfg.region[0::2]), np.array(cfg.region[1::2])
    assert ((poses[:, :3] >= lo - 1e-9) & (poses[:, :3] <= hi + 1e-9)).all()
    s = np.linalg.svd(poses[:, :3] - poses[:, :3].mean(0), compute_uv=False)
    assert s[2] / s[0] > 0.1  # a volume, not a plane or a line
    check_plan(plan_positions(cfg), HOME_POSE, Envelope())


def test_a_plan_through_the_base_keep_out_is_refused_whole():
    cfg = CollectConfig(poses=8, region=(-0.3, 0.3, -0.05, 0.05, 0.1, 0.2))
    with pytest.raises(SafetyError, match="refused"):
        check_plan(plan_positions(cfg), HOME_POSE, Envelope())


def test_marker_point_turns_the_offset_with_the_tool():
    assert marker_point([0.3, 0.1, 0.2, math.pi, 0.0, 0.0], (0.0, 0.02, 0.01)) == pytest.approx([0.3, 0.08, 0.19])


def _angle_deg(R: np.ndarray) -> float:
    return math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(R) - 1) / 2))))


def test_collect_calibrate_pick_in_the_synthetic_cell(tmp_path, capfd):
    from tests.runtime.test_pipeline import red_model

    pairs, calib = tmp_path / "pairs.csv", tmp_path / "calib.json"
    assert run(["calibrate", "collect", "--robot", "sim", "--camera", "synth-cell", "--poses", "24", "--settle", "0",
                "--out", str(pairs)]) == 0
    assert json.loads(capfd.readouterr().out)["pairs"] == 24
    assert run(["calibrate", str(pairs), "--out", str(calib), "--subsets", "4,14"]) == 0
    report = json.loads(capfd.readouterr().out)
    assert len(report["leave_one_out_mm"]) == 24 and report["outliers"] == []
    assert report["subsets"]["4"]["mean_mm"] > report["subsets"]["14"]["mean_mm"]
    got, true = json.loads(calib.read_text()), SynthCamera(mount_height_m=0.7).calibration()
    assert np.linalg.norm(np.array(got["t"]) - true.t) <= 0.005
    assert _angle_deg(np.array(got["R"]).T @ true.R) <= 0.5
    red_model(tmp_path / "m.onnx", divide=64)
    assert run(["pick", "--model", str(tmp_path / "m.onnx"), "--camera", "synth-cell", "--calib", str(calib),
                "--cycles", "2", "--size", "320x240", "--log", str(tmp_path / "picks.jsonl")]) == 0
    assert json.loads(capfd.readouterr().out)["cycles"] == 2


@pytest.mark.parametrize("args, needle", [
    (["--marker-offset", "0,0.45,0"], "only 0 usable pairs"),  # the marker off to the side: never in view
    (["--region", "0.2,0.38,0,0.0001,0.15,0.15001"], "collinear"),  # one line of positions
    (["--poses", "3"], "at least 4"),
    (["--robot", "ur:127.0.0.1", "--camera", "realsense"], "--region is needed"),
    (["--region", "0.4,0.2,0,1,0,1"], "min below its max"),
    (["--marker", "aruco:4X4_50:99"], "ids 0 to 49"),
])
def test_degenerate_and_not_seen_end_in_one_line_and_no_file(tmp_path, capfd, args, needle):
    out = tmp_path / "pairs.csv"
    code = run(["calibrate", "collect", "--poses", "6", "--settle", "0", *args, "--out", str(out)])
    err = capfd.readouterr().err.strip().splitlines()
    assert code == 2 and err[-1].startswith("edgepick: error:") and needle in err[-1], err
    assert not out.exists()


def test_plan_only_sends_nothing_to_a_real_robot(tmp_path, capfd):
    """Without --execute, `--robot ur:HOST` prints the plan: no connection is even opened."""
    listeners = []
    for port in (29999, 30001, 30002, 30003, 30004):
        s = socket.socket()
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        s.bind(("127.0.0.77", port))
        s.listen()
        s.setblocking(False)
        listeners.append(s)
    try:
        code = run(["calibrate", "collect", "--robot", "ur:127.0.0.77", "--camera", "synth-cell", "--poses", "8",
                    "--out", str(tmp_path / "pairs.csv")])
        out, err = capfd.readouterr()
        assert code == 0 and "plan only" in err and err.count("position") == 8
        assert json.loads(out) == {"out": None, "planned": 8, "moved": False}
        for s in listeners:
            with pytest.raises(BlockingIOError):
                s.accept()
    finally:
        for s in listeners:
            s.close()
    assert not (tmp_path / "pairs.csv").exists()


def test_more_poses_than_the_cap_are_refused_saying_how_long_they_would_take():
    from edgepick.errors import ConfigError
    from edgepick.robot.handeye import MAX_POSES

    assert CollectConfig(poses=MAX_POSES).poses == MAX_POSES
    with pytest.raises(ConfigError, match=r"poses=1000000000: at most 1000 \(each position takes about 0\.5 s, "
                                          r"its move at speed=0\.1 plus settle_s=0\.5: [\d,]+ h in all\)"):
        CollectConfig(poses=1_000_000_000)
    assert CollectConfig(poses=MAX_POSES, settle_s=5.0, speed=0.01).seconds_per_position() > 5.0
    with pytest.raises(ConfigError, match=r"at most 1000 .* speed=0\.01 plus settle_s=5\.0: [\d,]+ h in all"):
        CollectConfig(poses=MAX_POSES + 1, settle_s=5.0, speed=0.01)


def test_a_camera_that_runs_out_of_frames_ends_collecting_in_one_line_back_at_the_start(tmp_path):
    import cv2

    from edgepick.frames import CameraError
    from edgepick.geometry import Intrinsics
    from edgepick.robot.handeye import collect_pairs
    from edgepick.runtime.camera import FolderCamera
    from edgepick.runtime.marker import MarkerSpec
    from edgepick.sim.robot import SimRobot

    for sub in ("rgb", "depth"):
        (tmp_path / sub).mkdir()
    (tmp_path / "intrinsics.json").write_text(json.dumps(Intrinsics.d415(320, 240).to_dict()))
    for i in range(2):
        cv2.imwrite(str(tmp_path / "rgb" / f"{i}.png"), np.full((240, 320, 3), 128, np.uint8))
        cv2.imwrite(str(tmp_path / "depth" / f"{i}.png"), np.full((240, 320), 600, np.uint16))
    cfg = CollectConfig(poses=4, settle_s=0)
    with FolderCamera(tmp_path) as camera, SimRobot(Envelope()) as robot:
        start = robot.tcp_pose()
        with pytest.raises(CameraError, match="no frame left for position 3 of 4"):
            collect_pairs(robot, camera, MarkerSpec.parse("aruco:4X4_50:7"), plan_positions(cfg), cfg)
        assert robot.tcp_pose() == pytest.approx(start)
