"""Grasp: what the grasp step (runtime/grasp.py) finds of one object, as the pick loop, the verdicts
and the recordings read it; `to_dict()` is its record of docs/contracts.md#grasp-record, as
`edgepick grasp` prints it. No numpy or OpenCV."""

from __future__ import annotations

import math
from dataclasses import dataclass

from edgepick.errors import ParameterError

NO_DEPTH = "no valid depth under the object"


@dataclass(frozen=True)
class Grasp:
    """One object's grasp, checked on creation. Without a depth (`depth_m` None) it has no 3D point
    nor robot pose, and `reason` says why; `pose_robot` needs a calibration. `occluded` is 0 where
    there is no depth to compare the rim with."""

    cls: str  # the object's class name
    pixel: tuple[float, float]  # the grasp point in the image (x right, y down)
    angle_deg: float  # the major axis in the image, in (-90, 90]
    orientation_defined: bool  # False: nearly round, the yaw is free
    area_px: int
    depth_m: float | None = None  # the surface the tool meets
    point_camera_m: tuple[float, ...] | None = None  # x, y, z
    pose_robot: tuple[float, ...] | None = None  # x, y, z, rx, ry, rz: the UR base frame, axis-angle
    occluded: float = 0.0  # the share of its rim under nearer objects
    partial: bool = False  # cut by the image border
    reason: str | None = None  # why there is no depth
    width_m: float | None = None  # across the major axis, where the jaw closes; None: no depth, or no defined axis

    def __post_init__(self) -> None:
        for name, size in (("pixel", 2), ("point_camera_m", 3), ("pose_robot", 6)):
            value = getattr(self, name)
            if value is not None:
                value = tuple(value)
                if len(value) != size or not all(math.isfinite(v) for v in value):
                    raise ParameterError(f"{{{name}}}: must be {size} finite numbers", **{name: list(value)})
                object.__setattr__(self, name, value)
        if (self.depth_m is None) != (self.point_camera_m is None):
            raise ParameterError("{depth_m}: a depth and a camera point go together", depth_m=self.depth_m)
        if self.depth_m is None and self.pose_robot is not None:
            raise ParameterError("{pose_robot}: a robot pose needs a depth", pose_robot=list(self.pose_robot))
        if (self.depth_m is None) != (self.reason is not None):
            raise ParameterError("{reason}: says why there is no depth, and only then", reason=self.reason)
        if not 0.0 <= self.occluded <= 1.0:
            raise ParameterError("{occluded}: must be in [0, 1]", occluded=self.occluded)
        if self.width_m is not None and not (math.isfinite(self.width_m) and self.width_m > 0 and
                                             self.depth_m is not None and self.orientation_defined):
            raise ParameterError("{width_m}: a positive width, of an object with a depth and a defined axis",
                                 width_m=self.width_m)

    def chosen_pose(self) -> tuple[float, ...]:
        """`pose_robot` of a grasp the pick may choose, which always has one (a ValueError otherwise)."""
        if self.pose_robot is None:
            raise ValueError(f"the {self.cls} at {list(self.pixel)} has no robot pose: {self.reason or 'no calibration'}")
        return self.pose_robot

    def to_dict(self) -> dict:
        """The record of docs/contracts.md#grasp-record, its keys in the order `grasp` prints them."""
        out: dict = {"class": self.cls, "pixel": list(self.pixel), "angle_deg": self.angle_deg,
                     "orientation_defined": self.orientation_defined, "area_px": self.area_px,
                     "depth_m": self.depth_m,
                     "point_camera_m": None if self.point_camera_m is None else list(self.point_camera_m)}
        if self.depth_m is None:
            out["reason"] = self.reason
        else:
            if self.pose_robot is not None:
                out["pose_robot"] = list(self.pose_robot)
            out["width_m"] = self.width_m
            out["occluded"] = self.occluded
        out["partial"] = self.partial
        return out

    @classmethod
    def from_dict(cls, record: dict) -> Grasp:
        """A grasp from its record (to_dict's inverse)."""
        return cls(record["class"], record["pixel"], record["angle_deg"], record["orientation_defined"],
                   record["area_px"], record["depth_m"], record["point_camera_m"], record.get("pose_robot"),
                   record.get("occluded", 0.0), record["partial"], record.get("reason"), record.get("width_m"))
