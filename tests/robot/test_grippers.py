"""Grippers: the RG2 over real XML-RPC (a small URCap stand-in on 127.0.0.1), and the digital output."""

from __future__ import annotations

import math
import socket
import threading
import time
from xmlrpc.server import SimpleXMLRPCServer

import pytest

from edgepick.robot.base import RobotError, RobotHalted, RobotUnreachable
from edgepick.robot.grippers import DigitalGripper, RG2Gripper
from edgepick.robot.pick import CommandLog, PickConfig, execute, plan_pick
from edgepick.sim.robot import SimRobot
from tests.conftest import make_grasp

RECORD = make_grasp("box", [0.3, -0.05, 0.06, math.pi, 0.0, 0.0])


@pytest.fixture()
def rg2_service():
    calls = []
    server = SimpleXMLRPCServer(("127.0.0.1", 0), logRequests=False, allow_none=True)
    state = {"width": 0.0}

    def rg_grip(width, force, tool, blocking, depth_comp, popup):
        calls.append((width, force, tool, blocking))
        state["width"] = width
        return True

    server.register_function(rg_grip)
    server.register_function(lambda tool: state["width"], "rg_get_width")
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield server.server_address[1], calls, server
    stop(server)


def stop(server: SimpleXMLRPCServer) -> None:
    """Shut the service down and close its socket: from then on a connection is refused."""
    server.shutdown()
    server.server_close()


def test_rg2_open_and_grip_send_millimetres_and_newtons(rg2_service):
    port, calls, _ = rg2_service
    g = RG2Gripper("127.0.0.1", port=port, open_width_m=0.08, force_n=25.0)
    g.open()
    assert g.width_m() == pytest.approx(0.08)
    g.grip()
    assert calls == [(80.0, 25.0, 0, True), (0.0, 25.0, 0, True)]
    assert isinstance(calls[0][0], float) and isinstance(calls[0][1], float)  # the URCap wants floats


def test_a_pick_opens_the_rg2_to_the_parts_width_and_lets_go_all_the_way(rg2_service):
    port, calls, _ = rg2_service
    record = make_grasp("adapter", [0.3, -0.05, 0.036, math.pi, 0.0, 0.0], width_m=0.044)
    plan = plan_pick(record, PickConfig())
    assert [s.width_m for s in plan if s.command == "open"] == [pytest.approx(0.074)]  # 44 mm and 15 mm a finger
    with SimRobot() as robot:
        assert execute(plan, robot, RG2Gripper("127.0.0.1", port=port), CommandLog(None), 1, PickConfig()) is None
    assert [width for width, *_ in calls] == [pytest.approx(74.0), 0.0, 100.0]  # open, grip, release
    calls.clear()
    RG2Gripper("127.0.0.1", port=port, open_width_m=0.06).open(0.074)  # never past its own setting
    assert calls[0][0] == pytest.approx(60.0)


def test_rg2_that_does_not_answer_is_a_clear_error():
    silent = socket.socket()
    silent.bind(("127.0.0.1", 0))
    silent.listen(1)  # accepts the connection, never replies
    try:
        port = silent.getsockname()[1]
        g = RG2Gripper("127.0.0.1", port=port, timeout_s=0.5)
        t0 = time.monotonic()
        with pytest.raises(RobotUnreachable, match=f"^cannot reach the RG2 gripper at 127.0.0.1:{port}: timed out$"):
            g.grip()
        assert time.monotonic() - t0 < 5
    finally:
        silent.close()
    closed = socket.socket()
    closed.bind(("127.0.0.1", 0))
    port = closed.getsockname()[1]
    closed.close()  # nothing listens: connection refused
    with pytest.raises(RobotUnreachable, match=f"at 127.0.0.1:{port}: Connection refused$"):
        RG2Gripper("127.0.0.1", port=port).open()
    with pytest.raises(RobotUnreachable, match="^cannot reach the RG2 gripper at rg2.invalid:41414: "):
        RG2Gripper("rg2.invalid").probe()  # a name that does not resolve


def test_probe_asks_the_rg2_its_opening(rg2_service):
    port, calls, _ = rg2_service
    RG2Gripper("127.0.0.1", port=port).probe()
    assert calls == []  # a question only: the fingers do not move


def test_an_rg2_lost_mid_cycle_halts_the_robot(rg2_service):
    """The RG2 answers the probe, then goes away: the cycle ends at the gripper step, the arm is
    stopped and takes no more commands (what it holds is unknown)."""
    port, _, server = rg2_service
    gripper = RG2Gripper("127.0.0.1", port=port, timeout_s=1.0)
    gripper.probe()
    stop(server)
    with SimRobot() as robot:
        reason = execute(plan_pick(RECORD, PickConfig()), robot, gripper, CommandLog(None), 1, PickConfig())
        assert reason == f"cannot reach the RG2 gripper at 127.0.0.1:{port}: Connection refused"
        assert robot.halted == reason and robot.sent == ["moveL"]  # the approach, then nothing
        with pytest.raises(RobotHalted):
            robot.move_l(PickConfig().home_pose)


def test_rg2_refuses_impossible_settings():
    with pytest.raises(RobotError, match="opening"):
        RG2Gripper("127.0.0.1", open_width_m=0.2)
    with pytest.raises(RobotError, match="force"):
        RG2Gripper("127.0.0.1", force_n=80)


@pytest.mark.parametrize("index, tool", [(8, False), (-1, False), (2, True)])
def test_a_digital_gripper_on_an_output_the_arm_lacks_is_refused(index, tool):
    with pytest.raises(RobotError, match="does not exist"):
        DigitalGripper(SimRobot(), index, tool)


def test_digital_gripper_drives_its_output():
    with SimRobot() as robot:
        g = DigitalGripper(robot, 1, tool=True)
        g.grip()
        assert robot.outputs[True][1] is True
        g.release()
        assert robot.outputs[True][1] is False
