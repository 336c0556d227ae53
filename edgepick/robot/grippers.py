"""Grippers: a digital output (the thesis's electromagnet for bearings and disks) and the
OnRobot RG2 through its URCap's XML-RPC service on the robot (port 41414).

`probe()` finds a gripper that cannot be reached before the arm is sent anything; an RG2 that
does not answer raises RobotUnreachable (exit status 3 on the command line)."""

from __future__ import annotations

import http.client
import xmlrpc.client

from edgepick.robot.base import RobotBase, RobotError, RobotUnreachable, output_reason

RG2_PORT = 41414


class GripperFailed(RobotError):
    """The gripper answered with a fault: what it holds is unknown, so the run ends as a halt."""

    exit_code = 3  # docs/contracts.md#command-line


class DigitalGripper:
    """Magnet/vacuum on a standard (0-7) or tool (0-1) digital output: grip = on, release = off."""

    def __init__(self, robot: RobotBase, index: int, tool: bool = False):
        reason = output_reason(index, tool)
        if reason:
            raise RobotError(reason)
        self.robot, self.index, self.tool = robot, index, tool

    def probe(self) -> None:
        """Nothing to ask: the output exists (checked above) and is driven through the arm's own link."""

    def open(self, width_m: float | None = None) -> None:
        """Off (WIDTH_M is a jaw's; an output has no width)."""
        self.robot.set_digital_out(self.index, False, self.tool)

    def grip(self) -> None:
        self.robot.set_digital_out(self.index, True, self.tool)

    release = open


class _TimeoutTransport(xmlrpc.client.Transport):
    def __init__(self, timeout: float):
        super().__init__()
        self.timeout = timeout

    def make_connection(self, host):
        conn = super().make_connection(host)
        conn.timeout = self.timeout
        return conn


class RG2Gripper:
    """OnRobot RG2 two-finger gripper: `rg_grip(width_mm, force_N, tool_index, blocking, ...)`
    on the URCap's XML-RPC server. Widths in metres here, millimetres on the wire."""

    OPEN_WIDTH_M = 0.10  # how far it opens before a grip

    def __init__(self, host: str, port: int = RG2_PORT, open_width_m: float = OPEN_WIDTH_M, force_n: float = 40.0,
                 tool_index: int = 0, timeout_s: float = 5.0):
        if not 0 < open_width_m <= 0.11:
            raise RobotError(f"RG2 opening {open_width_m} m outside (0, 0.11]")
        if not 3.0 <= force_n <= 40.0:
            raise RobotError(f"RG2 force {force_n} N outside [3, 40]")
        self.where = f"{host}:{port}"
        self.url = f"http://{host}:{port}/RPC2"
        self.proxy = xmlrpc.client.ServerProxy(self.url, transport=_TimeoutTransport(timeout_s))
        self.open_width_m, self.force_n, self.tool_index = open_width_m, force_n, tool_index

    def _rpc(self, name: str, *args):
        """Call the URCap's NAME: a fault is GripperFailed, no answer at all is RobotUnreachable."""
        try:
            return getattr(self.proxy, name)(*args)
        except xmlrpc.client.Fault as exc:
            raise GripperFailed(f"the RG2 gripper at {self.where} refused {name}: {exc.faultString}") from None
        except (TimeoutError, OSError, http.client.HTTPException, xmlrpc.client.Error) as exc:
            why = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc) or type(exc).__name__
            raise RobotUnreachable(f"cannot reach the RG2 gripper at {self.where}: {why}") from None

    def _grip(self, width_m: float) -> None:
        self._rpc("rg_grip", float(width_m * 1000.0), float(self.force_n), int(self.tool_index), True, False, False)

    def width_m(self) -> float:
        return float(self._rpc("rg_get_width", int(self.tool_index))) / 1000.0

    def probe(self) -> None:
        """Ask the RG2 its opening: raises RobotUnreachable when nothing answers."""
        self.width_m()

    def open(self, width_m: float | None = None) -> None:
        """Open to WIDTH_M (a part's width and room for the fingers), at most open_width_m; None: open_width_m."""
        self._grip(self.open_width_m if width_m is None else min(width_m, self.open_width_m))

    def grip(self) -> None:
        self._grip(0.0)  # close until the force is reached

    release = open
