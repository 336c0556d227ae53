"""SimRobot: the `Robot` protocol in-process, with UR3 limits and simulated motion time.

No network, nothing moves. It can be told to raise a protective stop or lose its link on a
given motion command, or to refuse targets beyond an x as a controller's safety limits would,
so the pick loop's stop and refusal handling is testable without an arm.
"""

from __future__ import annotations

import math
import time

from edgepick.robot.base import RobotBase, SafetyStatus
from edgepick.robot.envelope import Envelope
from edgepick.robot.motion import HOME_POSE, motion_time

PROTECTIVE_STOP_MODE = 3  # the controller's safety mode during a protective stop


class SimRobot(RobotBase):
    """An in-process UR3 behind the same guard as URRobot; its only limits are the envelope's
    (and x <= refuse_poses_beyond_x, when given)."""

    def __init__(self, envelope: Envelope | None = None, start_pose: list[float] | None = None,
                 protective_stop_on: int | None = None, drop_link_on: int | None = None,
                 refuse_poses_beyond_x: float | None = None, realtime: float = 0.0):
        super().__init__(envelope)
        self.realtime = realtime  # wall seconds slept per simulated second of motion (0: motion takes no time)
        self.refuse_poses_beyond_x = refuse_poses_beyond_x
        self.pose = list(start_pose or HOME_POSE)
        self.q = [0.0, -1.57, 1.57, -1.57, -1.57, 0.0]
        self.outputs = {False: [False] * 8, True: [False] * 2}  # standard, tool
        self.motion_s = 0.0  # simulated time spent moving
        self.moves = 0
        self.protective_stop_on, self.drop_link_on = protective_stop_on, drop_link_on
        self.state = SafetyStatus(connected=False)

    def _connect(self) -> None:
        self.state = SafetyStatus(connected=True)

    def _disconnect(self) -> None:
        self.state.connected = False

    def _fault(self, target: list[float]) -> bool:
        """Inject the configured fault on this motion command: stops halfway. True if one fired."""
        self.moves += 1
        if self.moves not in (self.protective_stop_on, self.drop_link_on):
            return False
        self.pose[:3] = [(a + b) / 2 for a, b in zip(self.pose[:3], target[:3])]
        if self.moves == self.protective_stop_on:
            self.state.protective_stop, self.state.safety_mode = True, PROTECTIVE_STOP_MODE
        else:
            self.state.connected = False
        return True

    def _move_l(self, pose: list[float], speed: float, acc: float) -> bool:
        if self._fault(pose):
            return False
        self._move(motion_time(math.dist(self.pose[:3], pose[:3]), speed, acc))
        self.pose = list(pose)
        return True

    def _move_j(self, q: list[float], speed: float, acc: float) -> bool:
        if self._fault(self.pose):
            return False
        self._move(motion_time(max(abs(a - b) for a, b in zip(self.q, q)), speed, acc))
        self.q = list(q)
        return True

    def _move(self, seconds: float) -> None:
        """Count a motion's time, and spend its share of wall time (realtime), as an arm's blocking move would."""
        self.motion_s += seconds
        if self.realtime > 0:
            time.sleep(seconds * self.realtime)

    def _stop(self) -> None:
        pass

    def _set_digital_out(self, index: int, value: bool, tool: bool) -> bool:
        self.outputs[tool][index] = value
        return True

    def _status(self) -> SafetyStatus:
        return self.state

    def _within_limits(self, pose: list[float]) -> bool:
        return self.refuse_poses_beyond_x is None or pose[0] <= self.refuse_poses_beyond_x

    def tcp_pose(self) -> list[float]:
        return list(self.pose)
