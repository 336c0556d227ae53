"""Image sizes and pinhole camera geometry shared by the generator, training and the runtime (numpy only)."""

from __future__ import annotations

import numbers
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from edgepick.errors import ConfigError
from edgepick.schema import Where, as_dict, as_number, field, read_json


@dataclass(frozen=True)
class Size:
    """An image or model input size, width first as cameras and the command line state it (640x480).
    Not a tuple on purpose: `.hw` gives the (height, width) that numpy, torch and file metadata keep,
    so an order is never guessed."""

    width: int
    height: int

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < 1:
                raise ConfigError(f"size: {name} must be a positive whole number, got {value!r}")
            object.__setattr__(self, name, int(value))

    @classmethod
    def parse(cls, text: str) -> Size:
        """'640x480' (WIDTHxHEIGHT, the command line's form) -> Size(640, 480)."""
        try:
            width, height = (int(v) for v in str(text).lower().split("x"))
        except ValueError:
            raise ConfigError(f"size must be WIDTHxHEIGHT like 640x480, got {text!r}") from None
        return cls(width, height)

    @classmethod
    def from_hw(cls, hw: Sequence[int]) -> Size:
        """The size of a (height, width) pair: an array's shape[:2] or a file's [H, W] metadata."""
        height, width = hw
        return cls(width, height)

    @classmethod
    def of(cls, image: np.ndarray) -> Size:
        """The size of an HxW or HxWxC image array."""
        return cls.from_hw(image.shape[:2])

    @property
    def hw(self) -> tuple[int, int]:
        """(height, width): the order of numpy and torch shapes and of edgepick's file metadata."""
        return self.height, self.width

    def __str__(self) -> str:
        return f"{self.width}x{self.height}"


def check_size(value: object, what: str) -> Size:
    """VALUE when it is a Size; a (height, width) or (width, height) tuple is refused rather than guessed."""
    if not isinstance(value, Size):
        raise ConfigError(f"{what} must be a Size(width, height) (edgepick.Size), got {value!r}")
    return value


# A RealSense D415 colour stream at 640x480 has fx ~ fy ~ 615 px.
D415_FOCAL_640 = 615.0

# What a file's intrinsics may say (docs/contracts.md#intrinsics-and-calibration): every real camera a
# picking cell uses lies well inside, and a value outside is a wrong unit or a field written into another.
FOCAL_MIN_PER_PX = 0.05  # fx >= width / 20 (fy: height): a view wider than 2 atan(10) = 169 degrees is a
#                          fisheye's, which a pinhole model without distortion cannot describe
FOCAL_MAX_PER_PX = 100.0  # fx <= 100 x width: a view narrower than 0.6 degrees is a telescope's
PRINCIPAL_MARGIN = 1.0  # cx within one image width outside the image (cy: height): an image cropped from a
#                         larger sensor's can have its principal point outside, never far outside
DEPTH_SCALE_MIN_M = 1e-6  # metres per depth unit; finer, and uint16's 65535 units end at 6.6 cm, nearer
#                           than any depth camera measures
DEPTH_SCALE_MAX_M = 0.01  # coarser than 1 cm per unit cannot place a grasp within the 10 mm it is judged by


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics of a colour-aligned depth camera (docs/contracts.md#intrinsics-and-calibration)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    depth_scale: float = 0.001

    @classmethod
    def d415(cls, width: int = 640, height: int = 480) -> Intrinsics:
        """Typical D415 colour intrinsics scaled to the given resolution."""
        f = D415_FOCAL_640 * width / 640.0
        return cls(width, height, f, f, (width - 1) / 2.0, (height - 1) / 2.0)

    @classmethod
    def from_dict(cls, d: dict, where: Where | None = None) -> Intrinsics:
        """Intrinsics from their JSON object, every field checked (WHERE names the file in errors)."""
        where = where or Where("intrinsics")
        d = as_dict(d, where)
        size = {k: as_number(field(d, k, where), where.at(k), integer=True, minimum=1, maximum=65535)
                for k in ("width", "height")}
        focal = {k: as_number(field(d, k, where), where.at(k), above=0) for k in ("fx", "fy")}
        centre = {k: as_number(field(d, k, where), where.at(k)) for k in ("cx", "cy")}
        scale = check_depth_scale(as_number(field(d, "depth_scale", where, 0.001), where.at("depth_scale"), above=0),
                                  where.at("depth_scale"))
        for focal_key, centre_key, side in (("fx", "cx", "width"), ("fy", "cy", "height")):
            check_axis(focal[focal_key], centre[centre_key], size[side], side, where.at(focal_key),
                       where.at(centre_key))
        return cls(size["width"], size["height"], float(focal["fx"]), float(focal["fy"]), float(centre["cx"]),
                   float(centre["cy"]), float(scale))

    @classmethod
    def load(cls, path: str | Path) -> Intrinsics:
        """intrinsics.json (docs/contracts.md#intrinsics-and-calibration), or a data set's meta.json,
        whose "intrinsics" entry holds the same object."""
        value = read_json(path, "intrinsics file")
        where = Where(str(path))
        if isinstance(value, dict) and "intrinsics" in value and "fx" not in value:  # a data set's meta.json
            return cls.from_dict(value["intrinsics"], where.at("intrinsics"))
        return cls.from_dict(value, where)

    def to_dict(self) -> dict:
        return asdict(self)

    def matrix(self) -> np.ndarray:
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1]], dtype=np.float64)

    def rays(self) -> np.ndarray:
        """Per-pixel ray directions (x/z, y/z, 1) as an [H, W, 3] float32 array."""
        u = (np.arange(self.width, dtype=np.float32) - self.cx) / self.fx
        v = (np.arange(self.height, dtype=np.float32) - self.cy) / self.fy
        rays = np.empty((self.height, self.width, 3), np.float32)
        rays[..., 0] = u[None, :]
        rays[..., 1] = v[:, None]
        rays[..., 2] = 1.0
        return rays


def check_axis(focal: float, centre: float, pixels: int, side: str, at_focal: Where, at_centre: Where) -> None:
    """One image axis of a camera's intrinsics: its focal length and principal point in pixels, within
    FOCAL_*_PER_PX and PRINCIPAL_MARGIN of the image's PIXELS along it (SIDE: width or height)."""
    low, high = FOCAL_MIN_PER_PX * pixels, FOCAL_MAX_PER_PX * pixels
    if not low <= focal <= high:
        at_focal.fail(f"must be in [{low:g}, {high:g}] px for an image {pixels} px in {side} (a field of view of 169 "
                      f"to 0.6 degrees), got {focal!r}")
    margin = PRINCIPAL_MARGIN * pixels
    if not -margin <= centre <= pixels + margin:
        at_centre.fail(f"must lie within one image {side} of the {pixels} px image, in [{-margin:g}, "
                       f"{pixels + margin:g}] px, got {centre!r}")


def check_depth_scale(scale: float, where: Where) -> float:
    """A depth scale (metres per depth unit) within DEPTH_SCALE_MIN_M and DEPTH_SCALE_MAX_M."""
    if not DEPTH_SCALE_MIN_M <= scale <= DEPTH_SCALE_MAX_M:
        where.fail(f"must be in [{DEPTH_SCALE_MIN_M:g}, {DEPTH_SCALE_MAX_M:g}] metres per depth unit (0.001: "
                   f"millimetres), got {scale!r}")
    return scale


def deproject(intr: Intrinsics, u: float, v: float, depth_m: float) -> np.ndarray:
    """Camera-frame 3D point (metres) of pixel (u, v) at depth z."""
    return np.array([(u - intr.cx) / intr.fx * depth_m, (v - intr.cy) / intr.fy * depth_m, depth_m])


def project(intr: Intrinsics, point: np.ndarray) -> np.ndarray:
    """Pixel (u, v) of a camera-frame 3D point."""
    x, y, z = point
    return np.array([intr.fx * x / z + intr.cx, intr.fy * y / z + intr.cy])
