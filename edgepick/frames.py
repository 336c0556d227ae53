"""Frames and the camera interface every frame source implements (numpy + OpenCV only).

A `Frame` is one RGB image, the depth aligned to it, the intrinsics, and, when the source
knows it (a synthetic scene, a data set's test split), the grasp truth. The sources are in
`edgepick.runtime.camera` (a folder, a RealSense) and `edgepick.sim.camera` (synthetic).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from edgepick.errors import EdgepickError
from edgepick.geometry import Intrinsics
from edgepick.schema import Where, as_dict, as_list, as_number, as_numbers, as_str, field, read_json


class CameraError(EdgepickError):
    """A source that cannot be opened or read, or has no frames left."""


@dataclass
class Frame:
    rgb: np.ndarray  # HxWx3 uint8, RGB order
    depth: np.ndarray  # HxW uint16, intrinsics.depth_scale metres per unit, 0 = no depth
    intrinsics: Intrinsics
    name: str
    truth: list[dict] | None = None  # per-object grasp truth, when the source knows it (synthetic)
    labels: np.ndarray | None = None  # true class ids per pixel, when the source knows them (synthetic)
    scene: dict | None = None  # the scene's conditions, when the source knows them (synthetic: lighting, table)
    hidden: list[dict] | None = None  # truth of the objects no pixel shows (synthetic): what they hold up rests on them


class Camera:
    """Base of the frame sources: `with source: frame = source.read()`, or iterate."""

    intrinsics: Intrinsics
    # the frames show one table picked from in turn (a live camera over the cell, a clutter-removal round),
    # so a part still seen where a pick went failed there; False: each frame is a scene of its own
    same_table: bool = False

    def open(self) -> Camera:
        return self

    def read(self) -> Frame:
        raise NotImplementedError

    def close(self) -> None:
        pass

    def __enter__(self) -> Camera:
        return self.open()

    def __exit__(self, *exc) -> None:
        self.close()

    def __iter__(self):
        while True:
            try:
                yield self.read()
            except StopIteration:
                return


def read_rgb(path: str | Path) -> np.ndarray:
    """An 8-bit colour image file as HxWx3 RGB, or a one-line error."""
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise CameraError(f"cannot read {path} as a colour image")
    return np.ascontiguousarray(img[..., ::-1])


def read_depth(path: str | Path) -> np.ndarray:
    """A single-channel uint16 depth PNG, or a one-line error."""
    depth = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if depth is None or depth.ndim != 2 or depth.dtype != np.uint16:
        raise CameraError(f"cannot read {path} as a single-channel uint16 depth image")
    return depth


def read_grasps(path: str | Path) -> dict[str, list[dict]]:
    """A split's grasps.json: scene id -> the grasp truth of each object, the fields that judging
    and drawing read checked (class, pixel, angle_deg, point_camera_m, orientation_defined)."""
    where = Where(str(path))
    scenes = as_dict(read_json(path, "grasp truth"), where)
    for sid, objects in scenes.items():
        for i, obj in enumerate(as_list(objects, where.at(sid))):
            at = where.at(sid).at(i)
            as_dict(obj, at)
            as_str(field(obj, "class", at), at.at("class"))
            as_numbers(field(obj, "pixel", at), at.at("pixel"), 2)
            as_number(field(obj, "angle_deg", at), at.at("angle_deg"))
            as_numbers(field(obj, "point_camera_m", at), at.at("point_camera_m"), 3)
            if not isinstance(obj.get("orientation_defined", True), bool):
                at.at("orientation_defined").fail("must be true or false")
    return scenes
