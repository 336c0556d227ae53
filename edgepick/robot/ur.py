"""URRobot: a UR3 over ur_rtde (the `[robot]` extra), with the link in a worker process.

ur_rtde's constructors hold the GIL while they connect, its control interface can wait for
minutes on a controller that has vanished, and its IO interface can abort the process after
the link is gone. So the three interfaces live in a child process; this side talks to it
through a pipe with a timeout on every call, and kills it when it stops answering. The
child's stdout/stderr (ur_rtde's C++ client prints "Reconnecting..." and socket errors there)
go to a debug file on request, else nowhere: edgepick reports a failure once, in its own
words. Nothing touches the network before `connect()`; every moveL passes the envelope and
the controller's own safety limits (isPoseWithinSafetyLimits) first (RobotBase).
"""

from __future__ import annotations

import importlib.util
import math
import multiprocessing as mp
import os
import time
from multiprocessing.connection import Connection
from multiprocessing.process import BaseProcess

from edgepick.errors import ParameterError
from edgepick.robot.base import RobotBase, RobotError, RobotHalted, RobotUnreachable, SafetyStatus
from edgepick.robot.envelope import Envelope
from edgepick.robot.motion import motion_time

STALE_S = 0.5  # no new RTDE sample for this long = the link is gone (the stream runs at 125-500 Hz)


def _own_output(debug_log: str | None) -> None:
    """Point this process's file descriptors 1 and 2 (the C++ client's as well as Python's) at
    the debug log (its missing folders are created), or at the null device."""
    if debug_log:
        os.makedirs(os.path.dirname(os.path.abspath(debug_log)), exist_ok=True)
    fd = os.open(debug_log or os.devnull, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o666)
    os.dup2(fd, 1)
    os.dup2(fd, 2)
    os.close(fd)


def _worker(conn, host: str, debug_log: str | None = None) -> None:  # runs in the child process
    try:
        _own_output(debug_log)
    except OSError as exc:
        conn.send(("log", str(exc.strerror or exc)))
        return
    try:
        import rtde_control
        import rtde_io
        import rtde_receive
    except ImportError as exc:
        conn.send(("error", f"ur_rtde is not installed (pip install 'edgepick[robot]'): {exc}"))
        return
    try:
        receive = rtde_receive.RTDEReceiveInterface(host)
        control = rtde_control.RTDEControlInterface(host)
        io = rtde_io.RTDEIOInterface(host)
    except Exception as exc:  # noqa: BLE001 - ur_rtde raises RuntimeError and boost errors
        conn.send(("error", str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__))
        return
    conn.send(("ok", None))
    last_ts, last_change = None, time.monotonic()

    def fresh() -> bool:
        nonlocal last_ts, last_change
        ts = receive.getTimestamp()
        if ts != last_ts:
            last_ts, last_change = ts, time.monotonic()
        return receive.isConnected() and time.monotonic() - last_change < STALE_S

    while True:
        msg = conn.recv()
        op, args = msg[0], msg[1:]
        try:
            if op == "moveL":
                conn.send(("ok", bool(control.moveL(*args))))
            elif op == "moveJ":
                conn.send(("ok", bool(control.moveJ(*args))))
            elif op == "stop":
                control.stopL(2.0)
                conn.send(("ok", True))
            elif op == "digital":
                index, value, tool = args
                sent = io.setToolDigitalOut(index, value) if tool else io.setStandardDigitalOut(index, value)
                bit = (16 + index) if tool else index
                deadline = time.monotonic() + 0.5  # the write counts once the controller reports it
                while time.monotonic() < deadline and bool(receive.getActualDigitalOutputBits() >> bit & 1) != value:
                    time.sleep(0.01)
                conn.send(("ok", bool(sent) and bool(receive.getActualDigitalOutputBits() >> bit & 1) == value))
            elif op == "status":
                time.sleep(0.02)  # let at least one sample arrive
                conn.send(("ok", (fresh(), bool(receive.isProtectiveStopped()), bool(receive.isEmergencyStopped()),
                                  int(receive.getSafetyMode()))))
            elif op == "pose_ok":
                conn.send(("ok", bool(control.isPoseWithinSafetyLimits(list(args[0])))))
            elif op == "tcp":
                conn.send(("ok", list(receive.getActualTCPPose())))
            elif op == "disconnect":
                steps = (control.stopScript,) if args[0] else ()  # not after a stop: send nothing more
                for step in (*steps, control.disconnect, io.disconnect, receive.disconnect):
                    try:
                        step()
                    except Exception:  # noqa: BLE001 - best effort on the way out
                        pass
                conn.send(("ok", True))
                return
        except Exception as exc:  # noqa: BLE001
            conn.send(("error", str(exc)))


class URRobot(RobotBase):
    """A UR arm at HOST through ur_rtde (RTDEControl/Receive/IOInterface) in a worker process."""

    def __init__(self, host: str, envelope: Envelope | None = None, connect_timeout_s: float = 15.0,
                 command_margin_s: float = 5.0, debug_log: str | None = None):
        super().__init__(envelope)
        self.host, self.connect_timeout_s, self.margin_s = host, connect_timeout_s, command_margin_s
        self.debug_log = debug_log  # where ur_rtde's own output goes (None: discarded)
        self.proc: BaseProcess | None = None
        self.pipe: Connection | None = None
        self.lost = False

    def _call(self, *msg, timeout: float):
        if self.proc is None or self.pipe is None or self.lost:
            raise RobotError("no link to the robot")
        try:
            self.pipe.send(msg)
            if self.pipe.poll(timeout):
                status, value = self.pipe.recv()
                if status == "error":
                    raise RobotError(f"ur_rtde {msg[0]}: {value}")
                return value
        except (EOFError, BrokenPipeError, ConnectionResetError, OSError):
            pass
        self._kill()
        self.lost = True
        return None

    def _kill(self) -> None:
        if self.proc is not None and self.proc.is_alive():
            self.proc.kill()
            self.proc.join(5)

    def _connect(self) -> None:
        if importlib.util.find_spec("rtde_control") is None:
            raise RobotError("a UR robot needs ur_rtde: pip install 'edgepick[robot]'")
        ctx = mp.get_context("spawn")
        self.pipe, child = ctx.Pipe()
        self.proc = ctx.Process(target=_worker, args=(child, self.host, self.debug_log), daemon=True)
        self.proc.start()
        child.close()  # the worker holds the only other end: its exit reads as EOF here at once
        if not self.pipe.poll(self.connect_timeout_s):
            self._kill()
            raise RobotUnreachable(f"cannot reach the robot at {self.host}: no answer from a UR controller within "
                                   f"{self.connect_timeout_s:.0f} s")
        try:
            status, value = self.pipe.recv()
        except EOFError:
            self.proc.join(5)
            status, value = "error", f"the ur_rtde worker stopped (exit status {self.proc.exitcode})"
        if status != "ok":
            self._kill()
            if status == "log":
                raise ParameterError(f"{{debug_log}} cannot be written: {value}", debug_log=self.debug_log)
            raise RobotUnreachable(f"cannot reach the robot at {self.host}: {value}")

    def _disconnect(self) -> None:
        if not self.lost:
            self._call("disconnect", not self.halted, timeout=5.0)
        self._kill()
        self.proc = None

    def _motion_timeout(self, target: list[float], speed: float, acc: float, joint: bool) -> float:
        start = self.last_target  # RobotBase: the arm's pose when this command was checked
        if joint or start is None:
            dist = 2 * math.pi if joint else 1.0
        else:
            dist = math.dist(start[:3], target[:3])
        return motion_time(dist, speed, acc) * 1.5 + self.margin_s

    def _move_l(self, pose: list[float], speed: float, acc: float) -> bool:
        return bool(self._call("moveL", pose, speed, acc, timeout=self._motion_timeout(pose, speed, acc, False)))

    def _move_j(self, q: list[float], speed: float, acc: float) -> bool:
        return bool(self._call("moveJ", q, speed, acc, timeout=self._motion_timeout(q, speed, acc, True)))

    def _stop(self) -> None:
        if not self.lost:
            self._call("stop", timeout=3.0)

    def _set_digital_out(self, index: int, value: bool, tool: bool) -> bool:
        return bool(self._call("digital", index, value, tool, timeout=self.margin_s))

    def _status(self) -> SafetyStatus:
        if self.lost or self.proc is None:
            return SafetyStatus(connected=False)
        value = self._call("status", timeout=2.0)
        if value is None:
            return SafetyStatus(connected=False)
        fresh, protective, emergency, mode = value
        if not fresh:
            self.lost = True
            self._kill()
        return SafetyStatus(connected=fresh, protective_stop=protective, emergency_stop=emergency, safety_mode=mode)

    def _within_limits(self, pose: list[float]) -> bool:
        ok = self._call("pose_ok", pose, timeout=2.0)
        if ok is None:
            self.halt("link to the robot lost")
            raise RobotHalted("link to the robot lost")
        return ok

    def tcp_pose(self) -> list[float]:
        pose = self._call("tcp", timeout=2.0)
        if pose is None:
            self.halt("link to the robot lost")
            raise RobotHalted("link to the robot lost")
        return pose
