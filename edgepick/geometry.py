"""Pinhole camera geometry shared by the generator and the runtime (numpy only)."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from edgepick.errors import EdgepickError

# A RealSense D415 colour stream at 640x480 has fx ~ fy ~ 615 px.
D415_FOCAL_640 = 615.0


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
    def d415(cls, width: int = 640, height: int = 480) -> "Intrinsics":
        """Typical D415 colour intrinsics scaled to the given resolution."""
        f = D415_FOCAL_640 * width / 640.0
        return cls(width, height, f, f, (width - 1) / 2.0, (height - 1) / 2.0)

    @classmethod
    def from_dict(cls, d: dict) -> "Intrinsics":
        try:
            intr = cls(int(d["width"]), int(d["height"]), float(d["fx"]), float(d["fy"]),
                       float(d["cx"]), float(d["cy"]), float(d.get("depth_scale", 0.001)))
        except (KeyError, TypeError, ValueError) as exc:
            raise EdgepickError(f"intrinsics need width, height, fx, fy, cx, cy: {exc}") from None
        vals = [intr.fx, intr.fy, intr.cx, intr.cy, intr.depth_scale]
        if intr.width <= 0 or intr.height <= 0 or not all(np.isfinite(vals)) or intr.fx <= 0 or intr.fy <= 0:
            raise EdgepickError("intrinsics must have positive size and focal lengths and finite values")
        if intr.depth_scale <= 0:
            raise EdgepickError(f"intrinsics depth_scale {intr.depth_scale}: must be positive (metres per depth "
                                "unit, e.g. 0.001 for millimetres)")
        return intr

    @classmethod
    def load(cls, path: str | Path) -> "Intrinsics":
        try:
            return cls.from_dict(json.loads(Path(path).read_text()))
        except (OSError, json.JSONDecodeError) as exc:
            raise EdgepickError(f"cannot read intrinsics file {path}: {exc}") from None

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


def deproject(intr: Intrinsics, u: float, v: float, depth_m: float) -> np.ndarray:
    """Camera-frame 3D point (metres) of pixel (u, v) at depth z."""
    return np.array([(u - intr.cx) / intr.fx * depth_m, (v - intr.cy) / intr.fy * depth_m, depth_m])


def project(intr: Intrinsics, point: np.ndarray) -> np.ndarray:
    """Pixel (u, v) of a camera-frame 3D point."""
    x, y, z = point
    return np.array([intr.fx * x / z + intr.cx, intr.fy * y / z + intr.cy])
