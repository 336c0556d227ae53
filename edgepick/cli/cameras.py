"""--camera specs: 'synth[:SEED]', 'synth-cell[:SEED]', 'dir:PATH', 'realsense[:SERIAL]'.

Here, above the runtime and the simulators, because it picks among both.
"""

from __future__ import annotations

from edgepick.frames import Camera, CameraError
from edgepick.geometry import Size
from edgepick.runtime.camera import FolderCamera, RealSenseCamera
from edgepick.sim.camera import SynthCamera


def open_camera(spec: str, size: Size = Size(640, 480), seed: int = 0, loop: bool = False) -> Camera:
    """'synth[:SEED]' | 'synth-cell[:SEED]' | 'dir:PATH' | 'realsense[:SERIAL]' -> an unopened source
    streaming frames of SIZE (a folder's frames are the size they are)."""
    kind, _, arg = spec.partition(":")
    width, height = size.width, size.height
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
