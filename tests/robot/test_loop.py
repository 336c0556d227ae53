"""`edgepick pick` end to end: real ONNX model, real PNG frames from a folder camera, SimRobot."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

pytest.importorskip("onnx")

from edgepick.geometry import Intrinsics  # noqa: E402
from tests.conftest import run_cli  # noqa: E402
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


def test_pick_cycles_on_the_sim_robot(tmp_path):
    proc = pick(tmp_path, [(160, 120), (140, 100)], "--cycles", "3", "--overlay-dir", str(tmp_path / "ov"))
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
    assert sorted(p.name for p in (tmp_path / "ov").iterdir()) == ["cycle_001.png", "cycle_002.png"]
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
