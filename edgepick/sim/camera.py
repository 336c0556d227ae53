"""SynthCamera: the synthetic scene generator (edgepick.data.render) as a live camera.

Each frame carries its grasp truth, so the pick loop can score its grasps; mounted over a
cell, it also knows the cell's exact camera-to-robot calibration, and can show a marker on the
robot's tool (`ToolMarker`) where the arm's reported pose puts it, for `calibrate collect`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from edgepick.data.render import SceneRenderer
from edgepick.frames import Camera, CameraError, Frame
from edgepick.geometry import Intrinsics
from edgepick.runtime.calibration import Calibration
from edgepick.runtime.marker import MarkerSpec


@dataclass
class ToolMarker:
    """A printed marker on the tool: SPEC, its centre OFFSET_M from the TCP in the tool frame, and
    TCP_POSE, a callable giving the arm's pose [x, y, z, rx, ry, rz] when a frame is taken."""

    spec: MarkerSpec
    tcp_pose: Callable[[], list[float]]
    offset_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    depth_bias: float = 0.005  # sigma of the plate's per-frame depth offset, x z^2 (m); 0: pixel noise only

    def plate_robot(self) -> np.ndarray:
        """The printed plate's corners [4, 3] in the robot frame (marker plus a quarter-side white
        margin), in the marker image's order: top left, top right, bottom right, bottom left."""
        pose = self.tcp_pose()
        rot = cv2.Rodrigues(np.asarray(pose[3:], np.float64))[0]
        centre = np.asarray(pose[:3], np.float64) + rot @ np.asarray(self.offset_m, np.float64)
        h = 0.75 * (self.spec.size_m or 0.04)
        local = np.array([[-h, -h, 0.0], [h, -h, 0.0], [h, h, 0.0], [-h, h, 0.0]])  # seen from the camera above
        return centre + local @ rot.T


def draw_plate(rgb: np.ndarray, depth: np.ndarray, intr: Intrinsics, rays: np.ndarray, corners_cam: np.ndarray,
               texture: np.ndarray, rng: np.random.Generator, depth_bias: float = 0.005) -> None:
    """Paint a flat textured plate with camera-frame corners CORNERS_CAM into the frame: its image
    by a perspective warp, its depth by intersecting each pixel's ray (RAYS: intr.rays(), made once)
    with its plane (D415-like noise)."""
    if (corners_cam[:, 2] <= 0.05).any():
        return
    px = np.stack([corners_cam[:, 0] / corners_cam[:, 2] * intr.fx + intr.cx,
                   corners_cam[:, 1] / corners_cam[:, 2] * intr.fy + intr.cy], 1).astype(np.float32)
    th, tw = texture.shape[:2]
    warp = cv2.getPerspectiveTransform(np.array([[0, 0], [tw, 0], [tw, th], [0, th]], np.float32), px)
    h, w = depth.shape
    image = cv2.warpPerspective(texture, warp, (w, h), flags=cv2.INTER_LINEAR)
    alpha = cv2.warpPerspective(np.ones((th, tw), np.float32), warp, (w, h), flags=cv2.INTER_LINEAR)
    shade = 0.85 * image.astype(np.float32)[..., None]
    rgb[:] = np.clip(rgb * (1 - alpha[..., None]) + shade * alpha[..., None], 0, 255).astype(np.uint8)
    normal = np.cross(corners_cam[1] - corners_cam[0], corners_cam[3] - corners_cam[0])
    ys, xs = np.nonzero(alpha > 0.5)
    hit = rays[ys, xs]
    z = float(normal @ corners_cam[0]) / (hit @ normal)
    # D415-like: 0.8 mm per pixel, and a per-frame offset of the whole plate growing with z^2, which
    # no averaging over pixels removes (1% at 2 m, half Intel's 2% bound: 1.25 mm at 0.5 m)
    bias = rng.normal(0, 1.0) * depth_bias * float(corners_cam[:, 2].mean()) ** 2
    z = z + bias + rng.normal(0, 0.0008, z.shape)
    depth[ys, xs] = np.clip(np.round(z / intr.depth_scale), 0, 65535).astype(np.uint16)


class SynthCamera(Camera):
    """The synthetic scene generator as a live camera; each frame carries its grasp truth.

    With `mount_height_m` the camera is fixed straight above the table, like a camera
    mounted over a robot cell; `calibration()` then gives its camera-to-robot transform, and the
    objects lie in the cell's pick area, a tray the UR3 reaches (PICK_AREA_M, robot frame), while
    the camera sees the table around it.
    """

    MOUNT_XY_M = (0.28, 0.0)  # robot-frame point under the camera centre
    PICK_AREA_M = ((0.14, 0.38), (-0.22, 0.22))  # x and y ranges of the objects' centres (robot frame)

    def __init__(self, width: int = 640, height: int = 480, seed: int = 0, frames: int | None = None,
                 mount_height_m: float | None = None):
        self.intrinsics = Intrinsics.d415(width, height)
        self.renderer = SceneRenderer(self.intrinsics)
        self.seed, self.frames, self.index, self.mount = seed, frames, 0, mount_height_m
        self.tool_marker: ToolMarker | None = None

    def show_tool_marker(self, marker: ToolMarker) -> None:
        """From now on, draw MARKER at the pose the arm reports (a mounted camera only)."""
        if self.mount is None:
            raise CameraError("only a mounted synthetic camera (synth-cell) can see the robot's tool")
        self.tool_marker = marker
        # the printed plate: the marker, 200 px, in a white margin of a quarter of its side
        self._plate = cv2.copyMakeBorder(marker.spec.image(200), 50, 50, 50, 50, cv2.BORDER_CONSTANT, value=255)

    def calibration(self):
        """Camera looking straight down at the robot's table (z = 0): image right = robot -y,
        image down = robot -x."""
        if self.mount is None:
            raise CameraError("only a mounted synthetic camera (mount_height_m) has a fixed calibration")
        R = np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
        return Calibration(R, np.array([*self.MOUNT_XY_M, self.mount]), 0.0, 0)

    def in_pick_area(self, point_camera: np.ndarray) -> bool:
        """Whether a table point (camera frame) lies in the cell's pick area."""
        x, y, _ = self.calibration().apply(point_camera)
        (x0, x1), (y0, y1) = self.PICK_AREA_M
        return x0 <= x <= x1 and y0 <= y <= y1

    def read(self) -> Frame:
        if self.frames is not None and self.index >= self.frames:
            raise StopIteration
        scene = self.renderer.render(np.random.default_rng([self.seed, 7, self.index]), camera_height_m=self.mount,
                                     area=None if self.mount is None else self.in_pick_area)
        name = f"synth-{self.seed}-{self.index:06d}"
        self.index += 1
        if self.tool_marker is not None:
            cal = self.calibration()
            corners = (self.tool_marker.plate_robot() - cal.t) @ cal.R  # robot -> camera frame
            draw_plate(scene.rgb, scene.depth, self.intrinsics, self.renderer.rays, corners, self._plate,
                       np.random.default_rng([self.seed, 11, self.index]), self.tool_marker.depth_bias)
        return Frame(scene.rgb, scene.depth, self.intrinsics, name, scene.grasps, scene.mask, scene.info, scene.hidden)
