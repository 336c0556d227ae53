"""The safety envelope: every target is checked here before anything is sent to an arm.

Workspace box in the robot base frame, UR3 reach (500 mm from the shoulder, with a margin),
a keep-out cylinder around the base column, the table plane plus a clearance, and caps on
speed and acceleration. Targets are checked, and so is moveL's straight path to each of them
(sampled along the line). A check returns the reason a target is refused, or None.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from edgepick.errors import EdgepickError, ParameterError

UR3_REACH_M = 0.5
UR3_SHOULDER_Z_M = 0.1519  # base joint to shoulder axis (UR3 DH d1)


class SafetyError(EdgepickError):
    """A target outside the envelope: refused before anything moved."""


@dataclass(frozen=True)
class Envelope:
    """The limits every target, path, speed and joint move is checked against; checked on creation."""

    box_min: tuple[float, float, float] = (-0.45, -0.45, -0.05)
    box_max: tuple[float, float, float] = (0.45, 0.45, 0.45)
    reach_m: float = UR3_REACH_M
    reach_margin_m: float = 0.03
    base_keepout_m: float = 0.10  # radius around the base axis (singular, and the arm's own column)
    table_z_m: float = 0.0  # table plane height in the robot base frame
    clearance_m: float = 0.005  # the TCP stays this far above the table
    max_speed: float = 0.25  # moveL, m/s
    max_acc: float = 1.2  # moveL, m/s^2
    max_joint_speed: float = 1.05  # moveJ, rad/s
    max_joint_acc: float = 1.4  # moveJ, rad/s^2
    joint_limit_rad: tuple[float, ...] = field(default=(2 * math.pi,) * 6)

    def __post_init__(self) -> None:
        for name in ("box_min", "box_max", "joint_limit_rad"):
            object.__setattr__(self, name, tuple(float(v) for v in getattr(self, name)))
        sides = list(zip(self.box_min, self.box_max))
        if len(sides) != 3 or len(self.box_min) != len(self.box_max) or \
                not all(math.isfinite(lo) and math.isfinite(hi) and lo < hi for lo, hi in sides):
            raise ParameterError("{box_min} and {box_max}: three finite numbers each, every min below its max",
                                 box_min=self.box_min, box_max=self.box_max)
        if len(self.joint_limit_rad) != 6 or not all(math.isfinite(v) and v > 0 for v in self.joint_limit_rad):
            raise ParameterError("{joint_limit_rad}: six positive limits (rad)", joint_limit_rad=self.joint_limit_rad)
        for name in ("reach_m", "max_speed", "max_acc", "max_joint_speed", "max_joint_acc"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise ParameterError(f"{{{name}}}: must be a positive number", **{name: getattr(self, name)})
        for name in ("reach_margin_m", "base_keepout_m", "clearance_m"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) >= 0):
                raise ParameterError(f"{{{name}}}: must be 0 or more", **{name: getattr(self, name)})
        if not math.isfinite(self.table_z_m):
            raise ParameterError("{table_z_m}: must be a finite height", table_z_m=self.table_z_m)

    def pose_reason(self, pose: list[float] | tuple[float, ...]) -> str | None:
        """Why a TCP pose [x, y, z, rx, ry, rz] (metres, axis-angle) is refused, or None."""
        if len(pose) != 6 or not all(isinstance(v, (int, float)) and math.isfinite(v) for v in pose):
            return "target must be 6 finite numbers [x, y, z, rx, ry, rz]"
        reason = self.position_reason(pose[:3])
        if reason:
            return reason
        if math.sqrt(sum(v * v for v in pose[3:])) > 2 * math.pi:
            return "rotation vector longer than 2 pi"
        return None

    def position_reason(self, xyz) -> str | None:
        """Why a TCP position is refused: outside the box, beyond the reach, inside the base
        keep-out, or below the table plus clearance. None when it is allowed."""
        x, y, z = (float(v) for v in xyz)
        for axis, v, lo, hi in zip("xyz", (x, y, z), self.box_min, self.box_max):
            if not lo <= v <= hi:
                return f"{axis} = {v:.3f} m is outside the workspace box [{lo:.3f}, {hi:.3f}]"
        reach = math.sqrt(x * x + y * y + (z - UR3_SHOULDER_Z_M) ** 2)
        if reach > self.reach_m - self.reach_margin_m:
            return f"{reach:.3f} m from the shoulder is beyond the UR3 reach ({self.reach_m} m - " \
                   f"{self.reach_margin_m} m margin)"
        if math.hypot(x, y) < self.base_keepout_m:
            return f"{math.hypot(x, y):.3f} m from the base axis is inside the {self.base_keepout_m} m keep-out"
        if z < self.table_z_m + self.clearance_m:
            return f"z = {z:.3f} m is below the table plane + clearance ({self.table_z_m + self.clearance_m:.3f} m)"
        return None

    def path_reason(self, start, end, step_m: float = 0.005) -> str | None:
        """Why the straight TCP line from `start` to `end` (moveL's path) is refused: the first
        point along it, sampled every `step_m`, that position_reason refuses. None when clear.
        Both ends inside is not enough: the base keep-out is not convex, so a line between two
        allowed points can cross it."""
        a, b = [float(v) for v in start[:3]], [float(v) for v in end[:3]]
        if not all(math.isfinite(v) for v in a + b):
            return "path ends must be finite"
        n = max(1, math.ceil(math.dist(a, b) / step_m))
        for i in range(1, n + 1):
            point = [p + (q - p) * i / n for p, q in zip(a, b)]
            reason = self.position_reason(point)
            if reason:
                where = ", ".join(f"{v:.3f}" for v in point)
                return f"the straight path passes ({where}), where {reason}"
        return None

    def speed_reason(self, speed: float, acc: float, joint: bool = False) -> str | None:
        cap_v, cap_a = (self.max_joint_speed, self.max_joint_acc) if joint else (self.max_speed, self.max_acc)
        unit = "rad/s" if joint else "m/s"
        if not (math.isfinite(speed) and 0 < speed <= cap_v):
            return f"speed {speed} {unit} outside (0, {cap_v}]"
        if not (math.isfinite(acc) and 0 < acc <= cap_a):
            return f"acceleration {acc} {unit}^2 outside (0, {cap_a}]"
        return None

    def joints_reason(self, q: list[float] | tuple[float, ...]) -> str | None:
        if len(q) != 6 or not all(isinstance(v, (int, float)) and math.isfinite(v) for v in q):
            return "joint target must be 6 finite numbers (rad)"
        for i, (v, lim) in enumerate(zip(q, self.joint_limit_rad)):
            if abs(v) > lim:
                return f"joint {i} = {v:.3f} rad beyond +-{lim:.3f}"
        return None

    def check_move_l(self, pose, speed: float, acc: float, start=None) -> None:
        """Refuse a moveL whose target, speed or (from `start`, when known) path is not allowed."""
        reason = self.pose_reason(pose) or self.speed_reason(speed, acc) or \
            (self.path_reason(start, pose) if start is not None else None)
        if reason:
            raise SafetyError(f"refused moveL: {reason}")

    def check_move_j(self, q, speed: float, acc: float) -> None:
        reason = self.joints_reason(q) or self.speed_reason(speed, acc, joint=True)
        if reason:
            raise SafetyError(f"refused moveJ: {reason}")
