"""Did a pick cycle succeed? The grasp success criterion of the synthetic cell
(docs/contracts.md#grasp-success), computed from the scene's truth and the cell's true calibration.

A cycle succeeds when the chosen target is a real object of its class (not a false detection),
the commanded grasp point is within 10 mm of that object's true grasp point (thesis 5.1.5: the
1 cm calibration budget), and, for a two-finger grasp of an object whose orientation is defined,
the fingers close within 15 degrees of the object's true minor axis, both in the robot frame.
The gripper per class is the thesis's: an electromagnet for bearings and disks (position only),
two fingers for adapters and boxes.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from edgepick.frames import Frame
from edgepick.intervals import rounded, wilson
from edgepick.runtime.calibration import Calibration
from edgepick.runtime.grasp import top_down_pose
from edgepick.runtime.grasp_record import Grasp

POSITION_M = 0.010
ANGLE_DEG = 15.0
GRIPPER = {"bearing": "electromagnet", "disk": "electromagnet", "adapter": "two-finger", "box": "two-finger"}
class VerdictRule(enum.StrEnum):
    """Which verdicts a cycle in the synthetic cell gets: this module's geometric rule, the physics
    check (sim/physics.py, the [sim] extra) beside it, or both shown."""

    GEOMETRIC = "geometric"
    PHYSICS = "physics"
    BOTH = "both"


FAILURES = ("false detection", "position", "orientation", "unreachable", "no object seen", "robot stopped")


@dataclass(frozen=True)
class Verdict:
    """A judged cycle's verdict, checked on creation: the geometric rule's (`judge`, with the errors it
    measured of a chosen target) or the physics check's (sim/physics.py: why it failed, how high the
    part rose, the solids it left out, its time). `to_dict()` is a cycle's "verdict" or "physics"."""

    success: bool
    failure: str | None = None  # None exactly when it succeeded
    measured: bool = False  # the geometric rule measured a chosen target: its errors belong to the record
    position_error_m: float | None = None  # None: a false detection
    angle_error_deg: float | None = None  # None: not a two-finger grasp of an object with an orientation
    note: str | None = None
    lifted_m: float | None = None
    left_out: int | None = None
    ms: float | None = None

    def __post_init__(self) -> None:
        if self.success != (self.failure is None):
            raise ValueError(f"a verdict names its failure exactly when it failed: {self}")
        if not self.measured and (self.position_error_m, self.angle_error_deg) != (None, None):
            raise ValueError(f"errors belong to a verdict that measured them: {self}")

    def stopped(self) -> Verdict:
        """This verdict on a cycle the robot stopped: a failure, whatever the grasp would have been."""
        return replace(self, success=False, failure="robot stopped")

    def to_dict(self) -> dict:
        """The verdict as `pick` prints it: success and failure, then what its rule measured."""
        out: dict = {"success": self.success, "failure": self.failure}
        if self.measured:
            out.update(position_error_m=self.position_error_m, angle_error_deg=self.angle_error_deg)
        for name in ("note", "lifted_m", "left_out", "ms"):
            if getattr(self, name) is not None:
                out[name] = getattr(self, name)
        return out


def closing_yaw_deg(pose: Sequence[float]) -> float:
    """The fingers' closing direction (tool x) of a top-down pose, as a yaw in (-90, 90] degrees."""
    rot = np.asarray(pose[3:], np.float64)
    angle = float(np.linalg.norm(rot))
    if angle < 1e-9:
        x = np.array([1.0, 0.0, 0.0])
    else:
        k = rot / angle
        x = np.array([1.0, 0.0, 0.0]) * math.cos(angle) + np.cross(k, [1.0, 0.0, 0.0]) * math.sin(angle) \
            + k * k[0] * (1 - math.cos(angle))
    yaw = math.degrees(math.atan2(x[1], x[0]))
    return (yaw + 90.0) % 180.0 - 90.0


def yaw_difference_deg(a: float, b: float) -> float:
    """Difference of two closing directions, which repeat every 180 degrees."""
    d = abs(a - b) % 180.0
    return min(d, 180.0 - d)


def judge(record: Grasp, frame: Frame, truth_cal: Calibration) -> Verdict:
    """The verdict on one chosen target (with a robot pose): success, the failure (FAILURES) and the errors."""
    same = [t for t in frame.truth or [] if t["class"] == record.cls]
    if not same:
        return Verdict(False, "false detection", measured=True)
    commanded = np.asarray(record.chosen_pose()[:3], np.float64)
    true_points = [truth_cal.apply(np.asarray(t["point_camera_m"], np.float64)) for t in same]
    k = int(np.argmin([np.linalg.norm(p - commanded) for p in true_points]))
    obj, error = same[k], float(np.linalg.norm(true_points[k] - commanded))
    angle_error = None
    if GRIPPER.get(record.cls) == "two-finger" and obj.get("orientation_defined"):
        u, v = obj["pixel"]
        true_pose = top_down_pose(truth_cal, frame.intrinsics, u, v, obj["point_camera_m"][2], obj["angle_deg"], True)
        angle_error = yaw_difference_deg(closing_yaw_deg(record.chosen_pose()), closing_yaw_deg(true_pose))
    failure = "position" if error > POSITION_M else \
        "orientation" if angle_error is not None and angle_error > ANGLE_DEG else None
    return Verdict(failure is None, failure, True, round(error, 4), None if angle_error is None else round(angle_error, 1))


DETECTED_PX = 15.0  # a grasp record of an object's class this close to its true grasp pixel found it (17 mm at 0.7 m)


def undetected(records: list[Grasp], truth: list[dict]) -> int:
    """How many of the scene's objects no grasp record of their class found (within DETECTED_PX
    of the true grasp pixel): objects the model missed, or that the grasp step could not separate."""
    return sum(not any(r.cls == t["class"] and math.dist(r.pixel, t["pixel"]) <= DETECTED_PX for r in records)
               for t in truth)


def summarize(judged: Sequence[Verdict]) -> dict:
    """Grasp success over the judged cycles' verdicts (the synthetic cell; robot/cycle.py's `verdicts`
    picks one rule's): count, rate (over all of them and over the reachable ones, each with its 95%
    Wilson interval) and failures by kind."""
    if not judged:
        return {}
    kinds = list(dict.fromkeys([*FAILURES, *(v.failure for v in judged if v.failure is not None)]))
    counts = {f: sum(v.failure == f for v in judged) for f in kinds}
    failures = {f: n for f, n in counts.items() if n}  # in FAILURES' order, then the physics check's own
    ok = sum(v.success for v in judged)
    reachable = len(judged) - failures.get("unreachable", 0)
    return {"success": ok, "success_rate": round(ok / len(judged), 4), "success_ci95": rounded(wilson(ok, len(judged))),
            "success_rate_reachable": round(ok / reachable, 4) if reachable else None,
            "success_reachable_ci95": rounded(wilson(ok, reachable)), "failures": failures}
