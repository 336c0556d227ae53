"""`edgepick pick` end to end: real ONNX model, real PNG frames from a folder camera, SimRobot."""

from __future__ import annotations

import json
import os
import threading

import cv2
import numpy as np
import pytest

pytest.importorskip("onnx")

from edgepick.geometry import Intrinsics  # noqa: E402
from tests.conftest import run_cli, worker_index  # noqa: E402
from tests.runtime.test_pipeline import red_model  # noqa: E402

INTR = Intrinsics.d415(320, 240)
CALIB = {"R": [[0, -1, 0], [-1, 0, 0], [0, 0, -1]], "t": [0.28, 0.0, 0.7], "rmse_m": 0.0, "n_pairs": 4}


def capture(root, boxes):
    """Frames whose red channel is the label image: a box (class 4) 6 cm tall on a table at 0.7 m."""
    (root / "rgb").mkdir(parents=True)
    (root / "depth").mkdir()
    for i, (x, y) in enumerate(boxes):
        labels = np.zeros((240, 320), np.uint8)
        cv2.rectangle(labels, (x - 30, y - 15), (x + 30, y + 15), 4, -1)
        rgb = np.zeros((240, 320, 3), np.uint8)
        rgb[..., 0] = labels
        depth = np.where(labels == 4, 640, 700).astype(np.uint16)
        cv2.imwrite(str(root / "rgb" / f"{i:03d}.png"), rgb[..., ::-1])
        cv2.imwrite(str(root / "depth" / f"{i:03d}.png"), depth)
    (root / "intrinsics.json").write_text(json.dumps(INTR.to_dict()))
    return root


def pick(tmp_path, boxes, *extra):
    cam = capture(tmp_path / "cap", boxes)
    (tmp_path / "calib.json").write_text(json.dumps(CALIB))
    return run_cli("pick", "--model", str(red_model(tmp_path / "m.onnx")), "--camera", f"dir:{cam}",
                   "--calib", str(tmp_path / "calib.json"), "--log", str(tmp_path / "log.jsonl"), *extra)


@pytest.mark.parametrize("overlap", [[], ["--overlap"]], ids=["plain", "overlap"])
def test_pick_cycles_on_the_sim_robot(tmp_path, overlap):
    proc = pick(tmp_path, [(160, 120), (140, 100)], "--cycles", "3", "--overlay-dir", str(tmp_path / "ov"), *overlap)
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    assert summary["cycles"] == 2 and summary["done"] == 2  # the folder holds two frames
    first = summary["results"][0]
    assert first["target"] == "box" and first["frame_to_command_ms"] > 0
    x, y, z = first["pose_robot"][:3]
    assert abs(x - 0.28) < 0.01 and abs(y) < 0.01 and abs(z - 0.06) < 0.002  # centre of the cell, box top
    log = [json.loads(line) for line in (tmp_path / "log.jsonl").read_text().splitlines()]
    assert len(log) == 20 and {e["result"] for e in log} == {"ok"}
    assert [e["command"] for e in log[:4]] == ["moveL", "open", "moveL", "grip"]
    assert sorted(p.name for p in (tmp_path / "ov").iterdir()) == [".edgepick", "cycle_001.png", "cycle_002.png"]
    assert "no more frames" in proc.stderr


def test_a_real_arm_without_execute_only_plans(tmp_path):
    proc = pick(tmp_path, [(160, 120)], "--robot", "ur:127.0.0.9")
    assert proc.returncode == 0, proc.stderr
    (result,) = json.loads(proc.stdout)["results"]
    assert result["outcome"] == "planned" and len(result["plan"]) == 10
    assert "nothing is sent" in proc.stderr and not (tmp_path / "log.jsonl").exists()  # nothing to log


def test_an_object_out_of_reach_is_skipped_with_nothing_sent(tmp_path):
    proc = pick(tmp_path, [(290, 20)])  # image corner: about 0.5 m from the shoulder
    assert proc.returncode == 0, proc.stderr
    (result,) = json.loads(proc.stdout)["results"]
    assert result["outcome"] == "skipped" and ("reach" in result["reason"] or "box" in result["reason"])
    (entry,) = [json.loads(line) for line in (tmp_path / "log.jsonl").read_text().splitlines()]
    assert entry["command"] == "none"


@pytest.mark.parametrize("args, message", [(["--robot", "abb"], "unknown robot"), (["--cycles", "0"], "at least 1"),
                                           (["--gripper", "vacuum"], "unknown gripper")])
def test_pick_bad_input(tmp_path, args, message):
    proc = pick(tmp_path, [(160, 120)], *args)
    assert proc.returncode == 2 and message in proc.stderr and "Traceback" not in proc.stderr


def test_pick_needs_a_calibration_for_a_folder_camera(tmp_path):
    cam = capture(tmp_path / "cap", [(160, 120)])
    proc = run_cli("pick", "--model", str(red_model(tmp_path / "m.onnx")), "--camera", f"dir:{cam}")
    assert proc.returncode == 2 and "--calib" in proc.stderr


def test_pick_defaults_to_the_reference_model_on_a_synthetic_camera_only(tmp_path, capfd):
    """No --model: the synthetic cell runs with the shipped reference model; a real (folder) camera
    is refused in one line, before any work, as the reference model has seen synthetic scenes only."""
    from edgepick.cli import run
    from edgepick.reference import reference_model

    assert run(["pick", "--cycles", "2", "--log", str(tmp_path / "l.jsonl")]) == 0
    out, _ = capfd.readouterr()
    summary = json.loads(out)
    assert summary["model"] == str(reference_model()) and summary["cycles"] == 2
    assert run(["pick", "--camera", f"dir:{tmp_path}", "--log", str(tmp_path / "m.jsonl")]) == 2
    err = capfd.readouterr().err
    assert "--model is needed with --camera dir:" in err and not (tmp_path / "m.jsonl").exists()


def _run(capfd, *args: str) -> tuple[int, str, str]:
    """`edgepick ARGS` in this process: exit status, stdout, stderr."""
    from edgepick.cli import run

    code = run(list(args))
    out, err = capfd.readouterr()
    return code, out, err


@pytest.mark.parametrize("robot", [["--robot", "sim"], ["--robot", "ur:127.0.0.9"]])  # the second: plan only
@pytest.mark.parametrize("spec, message", [("digital:99", "the standard digital output 99 does not exist (0..7)"),
                                           ("digital:-1", "the standard digital output -1 does not exist (0..7)"),
                                           ("tool:5", "the tool digital output 5 does not exist (0..1)"),
                                           ("tool:2", "the tool digital output 2 does not exist (0..1)"),
                                           ("digital:one", "the output must be a number, e.g. digital:0"),
                                           ("tool:", "the output must be a number, e.g. tool:0")])
def test_a_gripper_output_the_arm_lacks_is_refused_before_anything_starts(tmp_path, capfd, robot, spec, message):
    """Refused in one line naming --gripper before the model or the camera is opened (neither
    exists here), in a plan-only run too."""
    code, out, err = _run(capfd, "pick", "--model", str(tmp_path / "none.onnx"), "--camera", f"dir:{tmp_path}/none",
                          "--calib", str(tmp_path / "none.json"), *robot, "--gripper", spec,
                          "--log", str(tmp_path / "l.jsonl"))
    assert code == 2 and out == ""
    assert err.splitlines() == [f"edgepick: error: --gripper {spec}: {message}"]
    assert not (tmp_path / "l.jsonl").exists()


@pytest.mark.parametrize("host", ["rg2.invalid", "127.0.0.254"])  # does not resolve; nothing listens
def test_an_rg2_that_cannot_be_reached_is_a_halt_before_the_first_motion(tmp_path, capfd, host):
    code, out, err = _run(capfd, "pick", "--model", str(red_model(tmp_path / "m.onnx")), "--camera",
                          f"dir:{capture(tmp_path / 'cap', [(160, 120)])}", "--calib", str(_calib(tmp_path)),
                          "--gripper", f"rg2:{host}", "--log", str(tmp_path / "l.jsonl"))
    assert code == 3, err
    assert err.splitlines() == [err.strip()] and err.startswith(f"edgepick: error: cannot reach the RG2 gripper at "
                                                                f"{host}:41414: ")
    summary = json.loads(out)
    assert summary["halted"] in err and summary["cycles"] == 0 and not (tmp_path / "l.jsonl").exists()


@pytest.fixture()
def rg2_that_faults_on_grip():
    """An RG2 URCap stand-in on a loopback address at the RG2's own port: it answers the probe and
    opens, and answers a grip with a fault. Yields its host."""
    from xmlrpc.server import SimpleXMLRPCServer

    host = f"127.{1 + worker_index()}.41.{20 + os.getpid() % 200}"
    server = SimpleXMLRPCServer((host, 41414), logRequests=False, allow_none=True)

    def rg_grip(width, force, tool, blocking, depth_comp, popup):
        if width == 0.0:
            raise RuntimeError("no gripper on the tool flange")
        return True

    server.register_function(rg_grip)
    server.register_function(lambda tool: 100.0, "rg_get_width")
    threading.Thread(target=server.serve_forever, daemon=True).start()
    yield host
    server.shutdown()
    server.server_close()


def test_a_gripper_failure_mid_cycle_ends_pick_as_a_halt(tmp_path, capfd, rg2_that_faults_on_grip):
    host = rg2_that_faults_on_grip
    code, out, err = _run(capfd, "pick", "--model", str(red_model(tmp_path / "m.onnx")), "--camera",
                          f"dir:{capture(tmp_path / 'cap', [(160, 120), (140, 100)])}", "--calib",
                          str(_calib(tmp_path)), "--gripper", f"rg2:{host}", "--cycles", "2",
                          "--log", str(tmp_path / "l.jsonl"))
    assert code == 3, err
    summary = json.loads(out)
    (result,) = summary["results"]  # the second cycle never started
    assert result["outcome"] == "stopped" and f"the RG2 gripper at {host}:41414 refused rg_grip" in result["reason"]
    assert err.splitlines()[-1].startswith(f"edgepick: error: robot halted: the RG2 gripper at {host}:41414 refused "
                                           "rg_grip: ")
    log = [json.loads(line) for line in (tmp_path / "l.jsonl").read_text().splitlines()]
    assert [e["command"] for e in log] == ["moveL", "open", "moveL", "grip"]  # nothing after the failed grip


def _calib(tmp_path):
    (tmp_path / "calib.json").write_text(json.dumps(CALIB))
    return tmp_path / "calib.json"


def test_overlap_reads_the_next_frame_once_the_arm_has_left_and_changes_no_decision():
    """pick --overlap: each next frame is read and segmented right after the arm reaches the place
    approach pose, on a worker thread, and every cycle chooses, plans and is judged as without it."""
    from edgepick.data.render import CLASSES
    from edgepick.robot.grippers import DigitalGripper
    from edgepick.robot.loop import Cell, run_cycles
    from edgepick.robot.pick import CommandLog, PickConfig
    from edgepick.sim.camera import SynthCamera
    from edgepick.sim.oracle import TruthPipeline
    from edgepick.sim.robot import SimRobot

    def run(overlap):
        cam, robot = SynthCamera(640, 480, seed=3, mount_height_m=0.7), SimRobot(realtime=0.002)
        reads, read = [], cam.read

        def watched_read():
            reads.append((threading.current_thread() is threading.main_thread(), [round(v, 4) for v in robot.pose[:3]]))
            return read()

        cam.read = watched_read
        cal = cam.calibration()
        with cam, robot:
            cell = Cell(cam, TruthPipeline(list(CLASSES), cal), robot, DigitalGripper(robot, 0), CommandLog(None), cal)
            results = run_cycles(cell, cfg=PickConfig(), cycles=6, echo=lambda line: None, overlap=overlap)
        return results, reads

    plain, plain_reads = run(False)
    ahead, ahead_reads = run(True)
    keys = ("frame", "target", "pixel", "pose_robot", "verdict", "outcome")
    assert [{k: r.to_dict().get(k) for k in keys} for r in ahead] == [{k: r.to_dict().get(k) for k in keys} for r in plain]
    assert len(ahead_reads) == len(plain_reads) == 6  # no frame read beyond the last cycle
    assert all(main for main, _ in plain_reads)
    cfg = PickConfig()
    place = [round(v, 4) for v in cfg.place_pose[:3]]
    left = [place[:2] + [round(place[2] + cfg.approach_m, 4)], place, [round(v, 4) for v in cfg.home_pose[:3]]]
    for (main, arm), result in zip(ahead_reads[1:], ahead):
        if result.outcome == "done":  # the next frame was read by the worker, the arm past the place approach
            assert not main and arm in left
    assert all(r.frame_to_frame_ms is not None for r in ahead[1:]) and any(r.arm_wait_ms is not None for r in ahead)


@pytest.mark.parametrize("same_table", [True, False], ids=["one-table", "fresh-scenes"])
def test_on_one_table_a_part_still_there_after_its_pick_is_tried_after_the_others(same_table):
    """A camera over one table whose picks all fail (every frame shows the table as it was): each cycle
    goes to another part while others are left. A camera of fresh scenes (same_table False) remembers
    nothing: the same frame gets the same choice."""
    from edgepick.data.render import CLASSES
    from edgepick.robot.grippers import DigitalGripper
    from edgepick.robot.loop import Cell, run_cycles
    from edgepick.robot.pick import CommandLog, PickConfig
    from edgepick.sim.camera import SynthCamera
    from edgepick.sim.oracle import TruthPipeline
    from edgepick.sim.robot import SimRobot

    cam, robot = SynthCamera(640, 480, seed=6, mount_height_m=0.7), SimRobot()
    frame = cam.read()  # a box and an adapter the hand can come down on, among others
    cam.read = lambda: frame
    cam.same_table = same_table
    cal = cam.calibration()
    with robot:
        cell = Cell(cam, TruthPipeline(list(CLASSES), cal), robot, DigitalGripper(robot, 0), CommandLog(None), cal)
        results = run_cycles(cell, cfg=PickConfig(), cycles=2, echo=lambda line: None)
    points = [tuple(round(v, 3) for v in r.chosen.chosen_pose()[:3]) for r in results]
    assert len(points) == 2 and all(r.outcome == "done" for r in results)
    assert len(set(points)) == (2 if same_table else 1), points
