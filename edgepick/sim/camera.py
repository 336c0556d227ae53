"""SynthCamera: the synthetic scene generator (edgepick.data.render) as a live camera.

Each frame carries its grasp truth, so the pick loop can score its grasps; mounted over a
cell, it also knows the cell's exact camera-to-robot calibration.
"""

from __future__ import annotations

import numpy as np

from edgepick.data.render import SceneRenderer
from edgepick.frames import Camera, CameraError, Frame
from edgepick.geometry import Intrinsics
from edgepick.runtime.calibration import Calibration


class SynthCamera(Camera):
    """The synthetic scene generator as a live camera; each frame carries its grasp truth.

    With `mount_height_m` the camera is fixed straight above the table, like a camera
    mounted over a robot cell; `calibration()` then gives its camera-to-robot transform.
    """

    MOUNT_XY_M = (0.28, 0.0)  # robot-frame point under the camera centre

    def __init__(self, width: int = 640, height: int = 480, seed: int = 0, frames: int | None = None,
                 mount_height_m: float | None = None):
        self.intrinsics = Intrinsics.d415(width, height)
        self.renderer = SceneRenderer(self.intrinsics)
        self.seed, self.frames, self.index, self.mount = seed, frames, 0, mount_height_m

    def calibration(self):
        """Camera looking straight down at the robot's table (z = 0): image right = robot -y,
        image down = robot -x."""
        if self.mount is None:
            raise CameraError("only a mounted synthetic camera (mount_height_m) has a fixed calibration")
        R = np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
        return Calibration(R, np.array([*self.MOUNT_XY_M, self.mount]), 0.0, 0)

    def read(self) -> Frame:
        if self.frames is not None and self.index >= self.frames:
            raise StopIteration
        scene = self.renderer.render(np.random.default_rng([self.seed, 7, self.index]), camera_height_m=self.mount)
        name = f"synth-{self.seed}-{self.index:06d}"
        self.index += 1
        return Frame(scene.rgb, scene.depth, self.intrinsics, name, scene.grasps)
