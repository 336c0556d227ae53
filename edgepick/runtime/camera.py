"""Real frame sources: a folder of PNGs (or a data set's split) and an Intel RealSense
D415/D435 (optional `[camera]` extra; pyrealsense2 is imported when one is opened).

Each source is a context manager; `read()` gives the next `edgepick.frames.Frame`. The
synthetic camera is in `edgepick.sim.camera`; `edgepick.cli.cameras.open_camera` picks a
source from a --camera spec.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from edgepick.frames import Camera, CameraError, Frame, read_depth, read_grasps, read_rgb
from edgepick.geometry import Intrinsics


class FolderCamera(Camera):
    """Frames from `rgb/*.png` + `depth/*.png` (same names) and `intrinsics.json` in PATH.

    A data set in the native layout works too: PATH may be DATA (its test split is used) or
    DATA/<split>; the intrinsics then come from DATA/meta.json and the grasp truth from
    grasps.json. `loop=True` starts again after the last frame instead of stopping.
    """

    def __init__(self, path: str | Path, loop: bool = False, split: str = "test"):
        path = Path(path)
        if (path / "meta.json").is_file() and not (path / "rgb").is_dir():
            path = path / split
        self.path, self.loop = path, loop
        meta_file = path.parent / "meta.json"
        if (path / "intrinsics.json").is_file():
            self.intrinsics = Intrinsics.load(path / "intrinsics.json")
        elif meta_file.is_file():
            self.intrinsics = Intrinsics.load(meta_file)  # a data set's split: its meta.json's intrinsics
        else:
            raise CameraError(f"{path} has no intrinsics.json (nor a data set's meta.json beside it)")
        rgb = sorted((path / "rgb").glob("*.png")) if (path / "rgb").is_dir() else []
        if not rgb:
            raise CameraError(f"{path} has no rgb/*.png frames")
        missing = [p.name for p in rgb if not (path / "depth" / p.name).is_file()]
        if missing:
            raise CameraError(f"{path}/depth lacks {len(missing)} frame(s) that rgb/ has, e.g. {missing[0]}")
        self.names = [p.stem for p in rgb]
        grasps = path / "grasps.json"
        self.truth = read_grasps(grasps) if grasps.is_file() else {}
        self.index = 0

    def read(self) -> Frame:
        if self.index >= len(self.names):
            if not self.loop:
                raise StopIteration
            self.index = 0
        name = self.names[self.index]
        self.index += 1
        rgb, depth = read_rgb(self.path / "rgb" / f"{name}.png"), read_depth(self.path / "depth" / f"{name}.png")
        intr = self.intrinsics
        if rgb.shape[:2] != depth.shape or (rgb.shape[1], rgb.shape[0]) != (intr.width, intr.height):
            raise CameraError(f"frame {name}: rgb {rgb.shape[1]}x{rgb.shape[0]}, depth {depth.shape[::-1]} and "
                              f"intrinsics {intr.width}x{intr.height} must agree")
        return Frame(rgb, depth, intr, name, self.truth.get(name))


class RealSenseCamera(Camera):
    """Intel RealSense D415/D435 through pyrealsense2: colour + depth aligned to colour,
    intrinsics from the device's colour stream, depth scale from its depth sensor."""

    same_table = True  # it looks at the cell: a part a pick failed on is still there in the next frame

    def __init__(self, width: int = 640, height: int = 480, fps: int = 30, serial: str | None = None,
                 timeout_ms: int = 5000):
        self.width, self.height, self.fps, self.serial, self.timeout_ms = width, height, fps, serial, timeout_ms
        self.pipeline = None
        self.index = 0

    def open(self) -> RealSenseCamera:
        try:
            import pyrealsense2 as rs
        except ImportError as exc:  # not installed, or its libusb is missing
            raise CameraError(f"RealSense support needs the camera extra (pip install 'edgepick[camera]') "
                              f"and libusb: {exc}") from None
        devices = rs.context().query_devices()
        serials = [d.get_info(rs.camera_info.serial_number) for d in devices]
        if not serials:
            raise CameraError("no RealSense device found (is it plugged into a USB 3 port?)")
        if self.serial and self.serial not in serials:
            raise CameraError(f"no RealSense with serial {self.serial}; found {', '.join(serials)}")
        config = rs.config()
        if self.serial:
            config.enable_device(self.serial)
        config.enable_stream(rs.stream.color, self.width, self.height, rs.format.rgb8, self.fps)
        config.enable_stream(rs.stream.depth, self.width, self.height, rs.format.z16, self.fps)
        pipeline = self.pipeline = rs.pipeline()
        try:
            profile = pipeline.start(config)
        except RuntimeError as exc:
            self.pipeline = None
            raise CameraError(f"RealSense would not start {self.width}x{self.height}@{self.fps}: {exc}") from None
        scale = profile.get_device().first_depth_sensor().get_depth_scale()
        ci = profile.get_stream(rs.stream.color).as_video_stream_profile().get_intrinsics()
        self.intrinsics = Intrinsics(ci.width, ci.height, ci.fx, ci.fy, ci.ppx, ci.ppy, float(scale))
        self.align = rs.align(rs.stream.color)
        return self

    def read(self) -> Frame:
        if self.pipeline is None:
            raise CameraError("RealSense camera is not open (use it in a with-block)")
        try:
            frames = self.align.process(self.pipeline.wait_for_frames(self.timeout_ms))
        except RuntimeError as exc:
            raise CameraError(f"RealSense gave no frame within {self.timeout_ms} ms: {exc}") from None
        color, depth = frames.get_color_frame(), frames.get_depth_frame()
        if not color or not depth:
            raise CameraError("RealSense frame set without colour or depth")
        name = f"realsense-{self.index:06d}"
        self.index += 1
        return Frame(np.asanyarray(color.get_data()).copy(), np.asanyarray(depth.get_data()).copy(),
                     self.intrinsics, name)

    def close(self) -> None:
        if self.pipeline is not None:
            try:
                self.pipeline.stop()
            finally:
                self.pipeline = None
