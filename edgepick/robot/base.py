"""`RobotBase`: the guard every robot (URRobot, SimRobot) shares.

`RobotBase` checks each target, and moveL's straight path to it from the arm's pose, against
the envelope BEFORE anything is sent, checks each command's result and the safety status
AFTER it, and once a protective/emergency stop or a lost link has been seen it sends nothing
more. Beside the envelope, a moveL target must pass the controller's own safety limits
(`_within_limits`, ur_rtde's isPoseWithinSafetyLimits on a UR). As a context manager it always
stops and disconnects on the way out. Subclasses implement the `_`-prefixed transport methods only.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

from edgepick.errors import EdgepickError
from edgepick.robot.envelope import Envelope, SafetyError

DIGITAL_OUTPUTS = {False: 8, True: 2}  # a UR3's standard outputs 0-7 and tool outputs 0-1
# the controller's safety modes (RTDE safety_mode) in which the arm does not move
STOP_MODES = {3: "PROTECTIVE_STOP", 4: "RECOVERY", 5: "SAFEGUARD_STOP", 6: "SYSTEM_EMERGENCY_STOP",
              7: "ROBOT_EMERGENCY_STOP", 8: "VIOLATION", 9: "FAULT", 12: "AUTOMATIC_MODE_SAFEGUARD_STOP",
              13: "SYSTEM_THREE_POSITION_ENABLING_STOP"}


class RobotError(EdgepickError):
    """The arm or its link failed: stopped, unreachable, or a command not carried out."""


class RobotHalted(RobotError):
    """A protective/emergency stop or a lost link: the robot takes no more commands."""

    exit_code = 3  # docs/contracts.md#command-line: the robot halted or its link failed


class RobotUnreachable(RobotError):
    """No link to the controller could be opened (nothing listening, no answer, refused)."""

    exit_code = 3


def output_reason(index: int, tool: bool) -> str | None:
    """Why digital output INDEX (standard, or tool) does not exist on the arm, or None."""
    limit = DIGITAL_OUTPUTS[tool]
    if 0 <= index < limit:
        return None
    return f"{'tool' if tool else 'standard'} digital output {index} does not exist (0..{limit - 1})"


@dataclass
class SafetyStatus:
    """What the controller reports after each command: link, stop flags and safety mode."""

    connected: bool
    protective_stop: bool = False
    emergency_stop: bool = False
    safety_mode: int | None = None  # the controller's own safety mode, when it reports one

    def problem(self) -> str | None:
        """Why the robot takes no more commands (with the controller's safety mode), or None."""
        if not self.connected:
            return "link to the robot lost"
        mode = None if self.safety_mode is None else STOP_MODES.get(self.safety_mode)
        if self.emergency_stop:
            words = "emergency stop"
        elif self.protective_stop:
            words = "protective stop"
        elif mode:
            words = "safety stop"
        else:
            return None
        return f"{words} (controller safety mode {mode})" if mode else words


class RobotBase:
    """Envelope-guarded commands; `with robot:` connects, and stops + disconnects at exit."""

    def __init__(self, envelope: Envelope | None = None):
        self.envelope = envelope or Envelope()
        self.halted: str | None = None
        self.connected = False
        self.sent: list[str] = []  # names of the commands that reached the transport
        self.on_send: Callable[[], object] | None = None  # called as each command goes out (latency probes)
        self.last_target: list[float] | None = None  # where the last moveL went: the next one's path start
        self._limits_verdicts: dict[tuple[float, ...], bool] = {}  # the controller's answers, by pose

    # -- transport (subclasses) ---------------------------------------------------------------
    def _connect(self) -> None:
        raise NotImplementedError

    def _disconnect(self) -> None:
        raise NotImplementedError

    def _move_l(self, pose: list[float], speed: float, acc: float) -> bool:
        raise NotImplementedError

    def _move_j(self, q: list[float], speed: float, acc: float) -> bool:
        raise NotImplementedError

    def _stop(self) -> None:
        raise NotImplementedError

    def _set_digital_out(self, index: int, value: bool, tool: bool) -> bool:
        raise NotImplementedError

    def _status(self) -> SafetyStatus:
        raise NotImplementedError

    def _within_limits(self, pose: list[float]) -> bool:
        """The controller's own verdict on a TCP pose: inside its safety limits (and reachable)."""
        raise NotImplementedError

    def tcp_pose(self) -> list[float]:
        raise NotImplementedError

    # -- guarded commands ---------------------------------------------------------------------
    def connect(self) -> RobotBase:
        self._connect()
        self.connected = True
        self._after("connect", True)
        self.last_target = self.tcp_pose()
        return self

    def _before(self, name: str) -> None:
        if self.halted:
            raise RobotHalted(f"{name} not sent: robot halted earlier ({self.halted})")
        if not self.connected:
            raise RobotError(f"{name} not sent: not connected")

    def _after(self, name: str, ok: bool) -> None:
        problem = self._status().problem()
        if problem:
            self.halted = problem
            raise RobotHalted(f"{name}: {problem}; the robot takes no more commands")
        if not ok:
            raise RobotError(f"{name} was not carried out by the controller")

    def _send(self, name: str) -> None:
        self.sent.append(name)
        if self.on_send is not None:
            self.on_send()

    def _path_start(self) -> list[float] | None:
        """The arm's pose a moveL starts from: the last confirmed target, else the reported TCP."""
        if self.last_target is None and self.connected and not self.halted:
            try:
                self.last_target = self.tcp_pose()
            except Exception:  # noqa: BLE001 - no pose: the target checks still apply
                return None
        return self.last_target

    def halt(self, reason: str) -> None:
        """Take no more commands from now on, e.g. after the gripper failed mid-pick."""
        self.halted = self.halted or reason

    def limits_reason(self, pose: list[float]) -> str | None:
        """Why the controller's own safety limits refuse this TCP target, or None. Asks the
        controller once per pose of a run (nothing moves: the plan's check and the moveL's own
        ask once between them, and the place and home poses once a run); the envelope is checked
        separately."""
        target = [float(v) for v in pose]
        key = tuple(round(v, 6) for v in target)
        if key not in self._limits_verdicts:
            self._limits_verdicts[key] = bool(self._within_limits(target))
        if self._limits_verdicts[key]:
            return None
        return f"({', '.join(f'{v:.3f}' for v in target[:3])}) is outside the controller's safety limits"

    def move_l(self, pose: list[float], speed: float | None = None, acc: float | None = None) -> None:
        """Move the TCP in a straight line, after the envelope and the controller's limits allow it."""
        speed = self.envelope.max_speed if speed is None else speed
        acc = self.envelope.max_acc if acc is None else acc
        self.envelope.check_move_l(pose, speed, acc, start=self._path_start())
        self._before("moveL")
        target = [float(v) for v in pose]
        reason = self.limits_reason(target)
        if reason:
            raise SafetyError(f"refused moveL: {reason}")
        self._send("moveL")
        try:
            self._after("moveL", self._move_l(target, speed, acc))
        except BaseException:
            self.last_target = None  # where the arm stopped is unknown
            raise
        self.last_target = target

    def move_j(self, q: list[float], speed: float | None = None, acc: float | None = None) -> None:
        speed = self.envelope.max_joint_speed if speed is None else speed
        acc = self.envelope.max_joint_acc if acc is None else acc
        self.envelope.check_move_j(q, speed, acc)
        self._before("moveJ")
        self._send("moveJ")
        self.last_target = None  # a joint move ends at a pose read back when the next moveL needs it
        self._after("moveJ", self._move_j([float(v) for v in q], speed, acc))

    def set_digital_out(self, index: int, value: bool, tool: bool = False) -> None:
        reason = output_reason(index, tool)
        if reason:
            raise RobotError(reason)
        self._before("setDigitalOut")
        self._send("setDigitalOut")
        self._after("setDigitalOut", self._set_digital_out(index, bool(value), tool))

    def stop(self) -> None:
        """Decelerate and stop; allowed even when halted (never raises for a dead link)."""
        if self.connected:
            try:
                self._stop()
            except Exception:  # noqa: BLE001 - stopping must not mask the original problem
                pass

    def disconnect(self) -> None:
        if self.connected:
            try:
                self._disconnect()
            finally:
                self.connected = False

    def __enter__(self) -> RobotBase:
        return self.connect()

    def __exit__(self, *exc) -> None:
        try:
            if not self.halted:
                self.stop()
        finally:
            self.disconnect()


def pose_distance(a: list[float], b: list[float]) -> float:
    return math.dist(a[:3], b[:3])
