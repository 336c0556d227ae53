"""The grasp success criterion (docs/contracts.md#grasp-success): position within 10 mm of the true
grasp point, two-finger closing within 15 degrees of the true minor axis, false detections; and the
pick loop's per-cycle verdict on the synthetic cell with the scenes' true labels."""

from __future__ import annotations

import math

import numpy as np
import pytest

from edgepick.frames import Frame
from edgepick.geometry import Intrinsics
from edgepick.robot.verdict import Verdict, closing_yaw_deg, judge, yaw_difference_deg
from edgepick.runtime.calibration import Calibration
from edgepick.runtime.grasp import top_down_pose
from edgepick.runtime.grasp_record import Grasp
from tests.conftest import make_grasp

INTR = Intrinsics.d415(640, 480)
CAL = Calibration(np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]]), np.array([0.28, 0.0, 0.7]), 0, 0)
BOX = {"class": "box", "pixel": [320.0, 240.0], "angle_deg": 30.0, "orientation_defined": True,
       "point_camera_m": [0.0, 0.0, 0.62]}


def _frame(*truth: dict) -> Frame:
    return Frame(np.zeros((480, 640, 3), np.uint8), np.zeros((480, 640), np.uint16), INTR, "f", list(truth))


def _record(cls: str, du: float = 0.0, angle: float = 30.0) -> Grasp:
    pose = top_down_pose(CAL, INTR, 320.0 + du, 240.0, 0.62, angle, True)
    return make_grasp(cls, pose)


@pytest.mark.parametrize("phi", [-80.0, -30.0, 0.0, 45.0, 89.0])
def test_closing_yaw_reads_back_the_pose(phi):
    rot = [math.pi * math.cos(math.radians(phi) / 2), math.pi * math.sin(math.radians(phi) / 2), 0.0]
    assert closing_yaw_deg([0, 0, 0, *rot]) == pytest.approx(phi, abs=1e-6)
    assert yaw_difference_deg(89.0, -89.0) == pytest.approx(2.0)


def test_success_position_orientation_and_false_detection():
    ok = judge(_record("box"), _frame(BOX), CAL)
    assert ok.success and ok.position_error_m < 0.001 and ok.angle_error_deg < 0.5
    far = judge(_record("box", du=20.0), _frame(BOX), CAL)  # 20 px at 0.62 m: ~20 mm
    assert not far.success and far.failure == "position" and far.position_error_m > 0.015
    turned = judge(_record("box", angle=30.0 + 25.0), _frame(BOX), CAL)
    assert not turned.success and turned.failure == "orientation" and turned.angle_error_deg == pytest.approx(25, abs=1)
    slight = judge(_record("box", angle=30.0 + 10.0), _frame(BOX), CAL)
    assert slight.success
    magnet = judge(_record("disk", angle=80.0), _frame({**BOX, "class": "disk"}), CAL)  # no angle for a magnet
    assert magnet.success and magnet.angle_error_deg is None
    ghost = judge(_record("adapter"), _frame(BOX), CAL)
    assert ghost.to_dict() == {"success": False, "failure": "false detection", "position_error_m": None,
                               "angle_error_deg": None}


def test_a_verdict_prints_what_its_rule_measured_and_names_its_failure_exactly_when_it_failed():
    assert list(Verdict(False, "unreachable").to_dict()) == ["success", "failure"]
    assert list(Verdict(True, measured=True, position_error_m=0.002).to_dict()) == \
        ["success", "failure", "position_error_m", "angle_error_deg"]
    physics = Verdict(False, "blocked", note="the hand lands on a box", lifted_m=0.0, ms=12.5)
    assert list(physics.to_dict()) == ["success", "failure", "note", "lifted_m", "ms"]
    assert physics.stopped().to_dict() == {**physics.to_dict(), "failure": "robot stopped"}
    for wrong in ({"success": True, "failure": "position"}, {"success": False},
                  {"success": True, "position_error_m": 0.001}):
        with pytest.raises(ValueError):
            Verdict(**wrong)


def test_pick_loop_judges_each_cycle_with_the_true_labels():
    from edgepick.data.render import CLASSES
    from edgepick.robot.grippers import DigitalGripper
    from edgepick.robot.loop import Cell, run_cycles
    from edgepick.robot.pick import CommandLog, PickConfig
    from edgepick.sim.camera import SynthCamera
    from edgepick.sim.oracle import TruthPipeline
    from edgepick.sim.robot import SimRobot

    cam, robot, lines = SynthCamera(640, 480, seed=0, mount_height_m=0.7), SimRobot(), []
    cal = cam.calibration()
    with cam, robot:
        results = run_cycles(Cell(cam, TruthPipeline(list(CLASSES), cal), robot, DigitalGripper(robot, 0), CommandLog(None), cal),
                             cfg=PickConfig(), cycles=12, echo=lines.append)
    verdicts = [r.verdict for r in results]
    assert len(verdicts) == 12 and all("verdict:" in line for line in lines)
    assert sum(v.success for v in verdicts) >= 6
    assert {v.failure for v in verdicts if not v.success} <= {"position", "orientation", "unreachable"}


def test_undetected_counts_the_objects_no_record_of_their_class_found():
    from edgepick.robot.verdict import undetected

    truth = [{"class": "box", "pixel": [100, 100]}, {"class": "disk", "pixel": [300, 200]},
             {"class": "box", "pixel": [500, 400]}]
    records = [make_grasp("box", None, pixel=(104, 109)),  # 9.8 px: found
               make_grasp("bearing", None, pixel=(300, 200)),  # the disk's pixel, another class: not found
               make_grasp("box", None, pixel=(520, 400))]  # 20 px off: not found
    assert undetected(records, truth) == 2
    assert undetected([], truth) == 3 and undetected(records, []) == 0
