"""Frame sources behind one interface: a folder of PNGs, the synthetic generator as a live
stream, and an Intel RealSense D415/D435 (optional `[camera]` extra).

Each source is a context manager; `read()` gives the next `Frame` (RGB, depth aligned to
colour, intrinsics); `open_camera("synth" | "dir:PATH" | "realsense[:SERIAL]")` picks one.
numpy + OpenCV only (pyrealsense2 is imported when a RealSense is opened).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from edgepick.errors import EdgepickError
from edgepick.runtime.geometry import Intrinsics


class CameraError(EdgepickError):
    """A source that cannot be opened or read, or has no frames left."""


@dataclass
class Frame:
    rgb: np.ndarray  # HxWx3 uint8, RGB order
    depth: np.ndarray  # HxW uint16, intrinsics.depth_scale metres per unit, 0 = no depth
    intrinsics: Intrinsics
    name: str
    truth: list[dict] | None = None  # per-object grasp truth, when the source knows it (synthetic)


class Camera:
    """Base of the frame sources: `with source: frame = source.read()`, or iterate."""

    intrinsics: Intrinsics

    def open(self) -> "Camera":
        return self

    def read(self) -> Frame:
        raise NotImplementedError

    def close(self) -> None:
        pass

    def __enter__(self) -> "Camera":
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
            self.intrinsics = Intrinsics.from_dict(json.loads(meta_file.read_text())["intrinsics"])
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
        self.truth = json.loads(grasps.read_text()) if grasps.is_file() else {}
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


class SynthCamera(Camera):
    """The synthetic scene generator as a live camera; each frame carries its grasp truth.

    With `mount_height_m` the camera is fixed straight above the table, like a camera
    mounted over a robot cell; `calibration()` then gives its camera-to-robot transform.
    """

    MOUNT_XY_M = (0.28, 0.0)  # robot-frame point under the camera centre

    def __init__(self, width: int = 640, height: int = 480, seed: int = 0, frames: int | None = None,
                 mount_height_m: float | None = None):
        from edgepick.data.render import SceneRenderer  # numpy + OpenCV only

        self.intrinsics = Intrinsics.d415(width, height)
        self.renderer = SceneRenderer(self.intrinsics)
        self.seed, self.frames, self.index, self.mount = seed, frames, 0, mount_height_m

    def calibration(self):
        """Camera looking straight down at the robot's table (z = 0): image right = robot -y,
        image down = robot -x."""
        from edgepick.runtime.calibration import Calibration

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


class RealSenseCamera(Camera):
    """Intel RealSense D415/D435 through pyrealsense2: colour + depth aligned to colour,
    intrinsics from the device's colour stream, depth scale from its depth sensor."""

    def __init__(self, width: int = 640, height: int = 480, fps: int = 30, serial: str | None = None,
                 timeout_ms: int = 5000):
        self.width, self.height, self.fps, self.serial, self.timeout_ms = width, height, fps, serial, timeout_ms
        self.pipeline = None
        self.index = 0

    def open(self) -> "RealSenseCamera":
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
        self.pipeline = rs.pipeline()
        try:
            profile = self.pipeline.start(config)
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


def open_camera(spec: str, width: int = 640, height: int = 480, seed: int = 0, loop: bool = False) -> Camera:
    """'synth[:SEED]' | 'synth-cell[:SEED]' | 'dir:PATH' | 'realsense[:SERIAL]' -> an unopened source."""
    kind, _, arg = spec.partition(":")
    if kind in ("synth", "synth-cell"):
        if arg and not arg.isdigit():
            raise CameraError(f"--camera {spec}: the seed after '{kind}:' must be a whole number >= 0")
        seed = int(arg) if arg else seed
        if kind == "synth":
            return SynthCamera(width, height, seed=seed)
        return SynthCamera(width, height, seed=seed, mount_height_m=0.7)  # over a robot cell (fixed calibration)
    if kind == "dir" and arg:
        return FolderCamera(arg, loop=loop)
    if kind == "realsense":
        return RealSenseCamera(width, height, serial=arg or None)
    raise CameraError(f"unknown camera {spec!r}: use synth, synth-cell, dir:PATH or realsense[:SERIAL]")
