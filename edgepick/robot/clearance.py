"""Is the hand's way down to a grasp clear? Checked on the frame's depth before a target is chosen.

The grasp step finds where an object's top is; the hand is larger than that point. A 100 mm
magnet face over a bearing lands on a taller adapter beside it; a parallel jaw puts its fingers
down on a neighbour's top, or on the object itself when it is wider than the opening, and its
body (above the fingers, wider than a small part) on a tall neighbour's top. Either way
the descent stops short (docs/contracts.md#physics-verdict: blocked, too wide). The jaw opens
only as far as the part needs (`jaw_opening_m`: its width plus room for each finger), as an RG2
is told a width, so that two parts side by side leave each other's fingers room. This module
looks at the surface under the hand's footprint, from the depth readings deprojected into the
robot frame (no parallax: a tall neighbour leans outward in the image), and
names what is in the way, so that `choose_target` picks another object first.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, fields

import numpy as np

from edgepick.errors import ParameterError
from edgepick.geometry import Intrinsics
from edgepick.robot.verdict import GRIPPER, closing_yaw_deg
from edgepick.runtime.calibration import Calibration
from edgepick.runtime.grasp_record import Grasp

REACH_ABOVE_M = 0.2  # surfaces higher than this above a grasp point are not looked for (the tallest stack is lower)


@dataclass(frozen=True)
class HandShape:
    """The hand's footprint, checked on creation. The defaults are an RG2-like jaw with a 110 mm
    stroke and a 100 mm electro-holding magnet, as sim/physics.py simulates them."""

    jaw_opening_m: float = 0.110  # between the fingers' inner faces, opened as far as it goes (the stroke)
    finger_room_m: float = 0.015  # beside the part for each finger: the jaw opens to its width plus twice this
    finger_thickness_m: float = 0.010  # across: each finger's pad beyond the opening
    finger_width_m: float = 0.024  # along the object
    finger_depth_m: float = 0.015  # the fingertips below the commanded point
    pole_radius_m: float = 0.05  # the magnet's face
    # the jaw's body above the fingers: its half-size along the closing axis and across it, and how far its
    # underside is above the commanded point (a neighbour that tall beside the part stops it)
    body_half_across_m: float = 0.040
    body_half_along_m: float = 0.030
    body_above_m: float = 0.035
    margin_m: float = 0.003  # depth noise and calibration error: footprints grow by this, heights too
    min_share: float = 0.02  # a footprint is in the way when this share of its readings stands too high

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not (math.isfinite(value) and value >= 0):
                raise ParameterError(f"{{{f.name}}}: must be 0 or more", **{f.name: value})


def jaw_opening_m(record: Grasp, shape: HandShape | None = None) -> float:
    """How far the jaw opens for RECORD's part: its width (the grasp record's `width_m`) plus
    shape.finger_room_m on each side, at most the stroke; the stroke for a part with no width.
    Room for the grasp point's own error (up to 10 mm in the cell's criterion) beside each finger,
    and the fingers no farther out than they need to be."""
    shape = shape or HandShape()
    if record.width_m is None:
        return shape.jaw_opening_m
    return round(min(shape.jaw_opening_m, record.width_m + 2 * shape.finger_room_m), 4)


def hand_clearance(depth: np.ndarray, intr: Intrinsics, calib: Calibration,
                   shape: HandShape | None = None) -> Callable[[Grasp], str | None]:
    """choose_target's CLEAR for one frame: a grasp with a robot pose -> why the hand
    cannot come down there (what stands too high under its footprint), or None when it can."""
    shape = shape or HandShape()
    inverse = np.linalg.inv(calib.R)

    def reason(record: Grasp) -> str | None:
        pose = record.pose_robot
        if pose is None or record.cls not in GRIPPER:
            return None
        grasp = np.asarray(pose[:3], np.float64)
        magnet = GRIPPER[record.cls] == "electromagnet"
        half = jaw_opening_m(record, shape) / 2
        reach = shape.pole_radius_m if magnet else max(math.hypot(half + shape.finger_thickness_m, shape.finger_width_m / 2),
                                                       math.hypot(shape.body_half_across_m, shape.body_half_along_m))
        points = _surface_near(depth, intr, calib, inverse, grasp, reach + shape.margin_m)
        if points is None:
            return None
        xy, m = points[:, :2] - grasp[:2], shape.margin_m
        if magnet:  # the face comes down until it touches the target's top: nothing under it may stand higher
            # (the target's own top is under it: a reading counts only past the margin)
            footprints = [(np.hypot(xy[:, 0], xy[:, 1]) <= shape.pole_radius_m + m, grasp[2], m, "the magnet's face")]
        else:  # the fingertips go down finger_depth_m below the grasp point beside the part, the body above them:
            # nothing of the target is under either, so a reading within the margin below them counts
            yaw = math.radians(closing_yaw_deg(pose))
            across = np.abs(xy @ [math.cos(yaw), math.sin(yaw)])
            along = np.abs(xy @ [-math.sin(yaw), math.cos(yaw)])
            fingers = (across >= half - m) & (across <= half + shape.finger_thickness_m + m) & \
                (along <= shape.finger_width_m / 2 + m)
            body = (across <= shape.body_half_across_m + m) & (along <= shape.body_half_along_m + m)
            footprints = [(fingers, grasp[2] - shape.finger_depth_m, -m, "a finger"),
                          (body, grasp[2] + shape.body_above_m, -m, "the jaw's body")]
        for under, floor, counted, what in footprints:  # a reading counts above floor + counted
            high = points[under, 2] > floor + counted
            if under.sum() and high.sum() >= shape.min_share * under.sum():
                above = 1000 * (np.percentile(points[under][high, 2], 50) - floor)
                where = f"{above:.0f} mm above" if above >= 0.5 else f"within {1000 * m:.0f} mm of"
                return f"{what} would land on something {where} where it must go ({100 * high.mean():.0f}% of the " \
                       "readings under it)"
        return None

    return reason


def _surface_near(depth: np.ndarray, intr: Intrinsics, calib: Calibration, inverse: np.ndarray, grasp: np.ndarray,
                  radius: float) -> np.ndarray | None:
    """The depth readings (DEPTH, intr.depth_scale metres each) around GRASP (robot frame) as
    robot-frame points, Nx3: those of the image window that holds every surface point within RADIUS
    of it, up to REACH_ABOVE_M above it."""
    centre = inverse @ (grasp - calib.t)  # the grasp point in the camera frame
    if centre[2] <= 0:
        return None
    # the window: the footprint circle seen at the nearest a surface could be (REACH_ABOVE_M above the grasp)
    near = max(centre[2] - REACH_ABOVE_M, centre[2] / 4)
    u, v = intr.fx * centre[0] / centre[2] + intr.cx, intr.fy * centre[1] / centre[2] + intr.cy
    r_u, r_v = intr.fx * radius / near, intr.fy * radius / near
    h, w = depth.shape
    u0, u1 = max(int(u - r_u), 0), min(int(u + r_u) + 1, w)
    v0, v1 = max(int(v - r_v), 0), min(int(v + r_v) + 1, h)
    if u0 >= u1 or v0 >= v1:
        return None
    window = depth[v0:v1, u0:u1]
    rows, cols = np.nonzero(window > 0)
    d = window[rows, cols].astype(np.float64) * intr.depth_scale
    cam = np.stack([(cols + u0 - intr.cx) * d / intr.fx, (rows + v0 - intr.cy) * d / intr.fy, d], axis=1)
    return calib.apply(cam)
