"""Grippers: the RG2 over real XML-RPC (a small URCap stand-in on 127.0.0.1), and the digital output."""

from __future__ import annotations

import socket
import threading
import time
from xmlrpc.server import SimpleXMLRPCServer

import pytest

from edgepick.robot.base import RobotError
from edgepick.robot.grippers import DigitalGripper, RG2Gripper
from edgepick.sim.robot import SimRobot


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
    yield server.server_address[1], calls
    server.shutdown()
    server.server_close()


def test_rg2_open_and_grip_send_millimetres_and_newtons(rg2_service):
    port, calls = rg2_service
    g = RG2Gripper("127.0.0.1", port=port, open_width_m=0.08, force_n=25.0)
    g.open()
    assert g.width_m() == pytest.approx(0.08)
    g.grip()
    assert calls == [(80.0, 25.0, 0, True), (0.0, 25.0, 0, True)]
    assert isinstance(calls[0][0], float) and isinstance(calls[0][1], float)  # the URCap wants floats


def test_rg2_that_does_not_answer_is_a_clear_error():
    silent = socket.socket()
    silent.bind(("127.0.0.1", 0))
    silent.listen(1)  # accepts the connection, never replies
    try:
        g = RG2Gripper("127.0.0.1", port=silent.getsockname()[1], timeout_s=0.5)
        t0 = time.monotonic()
        with pytest.raises(RobotError, match="does not answer"):
            g.grip()
        assert time.monotonic() - t0 < 5
    finally:
        silent.close()
    closed = socket.socket()
    closed.bind(("127.0.0.1", 0))
    port = closed.getsockname()[1]
    closed.close()  # nothing listens: connection refused
    with pytest.raises(RobotError, match="does not answer"):
        RG2Gripper("127.0.0.1", port=port).open()


def test_rg2_refuses_impossible_settings():
    with pytest.raises(RobotError, match="opening"):
        RG2Gripper("127.0.0.1", open_width_m=0.2)
    with pytest.raises(RobotError, match="force"):
        RG2Gripper("127.0.0.1", force_n=80)


def test_digital_gripper_drives_its_output():
    with SimRobot() as robot:
        g = DigitalGripper(robot, 1, tool=True)
        g.grip()
        assert robot.outputs[True][1] is True
        g.release()
        assert robot.outputs[True][1] is False
