"""SimRobot behind the guard: commands are checked before sending, stops halt everything after."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest

from edgepick.robot.base import RobotError, RobotHalted, SafetyStatus
from edgepick.robot.envelope import SafetyError
from edgepick.robot.grippers import DigitalGripper
from edgepick.robot.motion import motion_time
from edgepick.robot.pick import CommandLog, PickConfig, choose_target, execute, plan_pick
from edgepick.sim.robot import SimRobot
from tests.conftest import make_grasp

DOWN = [math.pi, 0.0, 0.0]
RECORD = make_grasp("box", [0.3, -0.05, 0.06, *DOWN])


def test_moves_outputs_and_motion_time():
    with SimRobot() as robot:
        robot.move_l([0.3, 0.0, 0.2, *DOWN], 0.25, 1.2)
        assert robot.tcp_pose()[:3] == [0.3, 0.0, 0.2]
        robot.move_j([0.1, -1.5, 1.5, -1.5, -1.5, 0.0])
        robot.set_digital_out(3, True)
        robot.set_digital_out(1, True, tool=True)
        assert robot.outputs[False][3] and robot.outputs[True][1]
        assert robot.motion_s > 0 and robot.sent == ["moveL", "moveJ", "setDigitalOut", "setDigitalOut"]
        with pytest.raises(RobotError, match="does not exist"):
            robot.set_digital_out(2, True, tool=True)
    assert not robot.connected
    assert motion_time(0.25, 0.25, 1.2) == pytest.approx(1.0 + 0.25 / 1.2)
    assert motion_time(0.01, 0.25, 1.2) == pytest.approx(2 * math.sqrt(0.01 / 1.2))


def test_out_of_envelope_target_is_refused_with_nothing_sent():
    with SimRobot() as robot:
        with pytest.raises(SafetyError):
            robot.move_l([0.3, 0.0, -0.1, *DOWN])
        assert robot.sent == [] and robot.tcp_pose() == SimRobot().tcp_pose()


def test_a_full_pick_cycle_is_logged(tmp_path):
    log = CommandLog(tmp_path / "log.jsonl")
    with SimRobot() as robot:
        record, plan, note = choose_target([RECORD], robot.envelope, PickConfig())
        assert record is RECORD and note == "ok"
        assert execute(plan, robot, DigitalGripper(robot, 0), log, 1, PickConfig()) is None
    log.close()
    lines = (tmp_path / "log.jsonl").read_text().splitlines()
    assert len(lines) == len(plan) == 10 and all('"result": "ok"' in line for line in lines)
    assert tuple(robot.tcp_pose()) == PickConfig().home_pose and robot.outputs[False][0] is False  # released


@pytest.mark.parametrize("fault", ["protective_stop_on", "drop_link_on"])
def test_a_stop_mid_move_ends_the_cycle_and_nothing_more_is_sent(fault):
    log = CommandLog(None)
    robot = SimRobot(**{fault: 2})  # the second motion command (the descent) stops halfway
    with robot:
        plan = plan_pick(RECORD, PickConfig())
        reason = execute(plan, robot, DigitalGripper(robot, 0), log, 1, PickConfig())
        assert reason and ("protective stop (controller safety mode PROTECTIVE_STOP)" in reason or "link" in reason)
        sent = list(robot.sent)
        assert sent == ["moveL", "setDigitalOut", "moveL"]  # approach, open, descend: then nothing
        with pytest.raises(RobotHalted):
            robot.move_l([0.3, 0.0, 0.2, *DOWN])
        assert robot.sent == sent
    assert [e["result"][:5] for e in log.records] == ["ok", "ok", "error"]


def test_a_target_beyond_the_controllers_limits_is_refused_with_nothing_sent():
    """The same hook as a UR controller's isPoseWithinSafetyLimits: a single moveL is refused
    before it is sent, and a plan with such a target is not chosen."""
    robot = SimRobot(refuse_poses_beyond_x=0.28)
    with robot:
        with pytest.raises(SafetyError, match=r"refused moveL: \(0.300, 0.000, 0.200\) is outside the "
                                              "controller's safety limits"):
            robot.move_l([0.3, 0.0, 0.2, *DOWN])
        assert robot.sent == [] and robot.tcp_pose() == SimRobot().tcp_pose()
        record, plan, note = choose_target([RECORD], robot.envelope, PickConfig(), limits=robot.limits_reason)
        assert record is None and note == "box: approach above the object: (0.300, -0.050, 0.140) is outside the " \
            "controller's safety limits"
        near = replace(RECORD, pose_robot=(0.25, -0.05, 0.06, *DOWN))
        assert choose_target([RECORD, near], robot.envelope, PickConfig(), limits=robot.limits_reason)[0] is near


@pytest.mark.parametrize("status, problem", [
    (SafetyStatus(True, protective_stop=True, safety_mode=3),
     "protective stop (controller safety mode PROTECTIVE_STOP)"),
    (SafetyStatus(True, emergency_stop=True, safety_mode=7),
     "emergency stop (controller safety mode ROBOT_EMERGENCY_STOP)"),
    (SafetyStatus(True, safety_mode=9), "safety stop (controller safety mode FAULT)"),
    (SafetyStatus(True, safety_mode=5), "safety stop (controller safety mode SAFEGUARD_STOP)"),
    (SafetyStatus(True, protective_stop=True), "protective stop"),
    (SafetyStatus(True, safety_mode=2), None),  # reduced mode: the arm still moves
    (SafetyStatus(False, safety_mode=1), "link to the robot lost")])
def test_a_halt_names_the_controllers_safety_mode(status, problem):
    assert status.problem() == problem


def test_target_choice_skips_unreachable_and_depthless_objects():
    far = replace(RECORD, area_px=5000, pose_robot=(0.40, 0.25, 0.05, *DOWN))
    nodepth = make_grasp("disk", None, area_px=9000, depth_m=None)
    robot = SimRobot()
    record, plan, note = choose_target([nodepth, far, RECORD], robot.envelope, PickConfig())
    assert record is RECORD
    record, plan, note = choose_target([nodepth, far], robot.envelope, PickConfig())
    assert record is None and plan == [] and "no valid depth" in note and "reach" in note
    record, _, note = choose_target([RECORD], robot.envelope, PickConfig(classes=("bearing",)))
    assert record is None and "requested classes" in note


BEHIND = [-0.30, -0.11, 0.31, *DOWN]  # the arm on the far side of the base column


def test_a_path_through_the_keep_out_is_refused_though_every_target_is_inside():
    robot = SimRobot(start_pose=BEHIND)
    plan = plan_pick(RECORD, PickConfig())
    assert all(robot.envelope.pose_reason(s.target) is None for s in plan if s.target)  # each target is fine
    record, plan_out, note = choose_target([RECORD], robot.envelope, PickConfig(), start=BEHIND)
    assert record is None and "approach above the object" in note and "keep-out" in note
    with robot:
        with pytest.raises(SafetyError, match="straight path .* keep-out"):
            robot.move_l(plan[0].target)  # the guard refuses it too, from the arm's reported pose
        assert robot.sent == []
    assert choose_target([RECORD], robot.envelope, PickConfig())[0] is RECORD  # from home the path is clear


def test_a_path_from_below_the_table_clearance_is_refused():
    low = [0.30, -0.05, 0.002, *DOWN]  # e.g. jogged down onto the table by hand
    robot = SimRobot(start_pose=low)
    with robot:
        with pytest.raises(SafetyError, match="straight path .* table"):
            robot.move_l([0.30, 0.10, 0.03, *DOWN])  # a target above the clearance, a path that grazes the table
        assert robot.sent == []


def test_path_checks_sample_the_whole_line():
    env = SimRobot().envelope
    assert env.path_reason([0.15, -0.15, 0.2], [0.15, 0.15, 0.2]) is None  # passes 0.15 m from the base axis
    reason = env.path_reason([0.05, -0.3, 0.2], [0.05, 0.3, 0.2])  # passes 0.05 m from it
    assert reason and "keep-out" in reason and reason.startswith("the straight path passes (0.050, -0.08")
