"""How a camera image becomes a foreign model's float input: the options a user gives for a model
edgepick did not train (`quantize static MODEL.onnx --calib IMAGES`, and `model wrap`, which puts
the same steps into the graph). edgepick's own models take uint8 RGB and normalise inside.
Imports without numpy or OpenCV (the command line builds its options from it).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

from edgepick.errors import ParameterError
from edgepick.geometry import Size
from edgepick.schema import member

if TYPE_CHECKING:
    import numpy as np


class ChannelOrder(enum.StrEnum):
    """The order of the colour channels the model was trained on."""

    RGB = "rgb"
    BGR = "bgr"  # OpenCV's order, and Caffe-era models'


class Layout(enum.StrEnum):
    """Where the channel axis of the model's image input is."""

    NCHW = "nchw"  # PyTorch, Paddle, ONNX's usual
    NHWC = "nhwc"  # TensorFlow (tf2onnx), Keras


@dataclass(frozen=True)
class Preprocessing:
    """uint8 RGB -> float32 input: resized to SIZE (area), channels in CHANNELS order, then
    (x * SCALE - MEAN) / STD per channel (MEAN and STD in the model's channel order), in LAYOUT
    with a batch axis of 1. The default is
    [0, 1] RGB NCHW; ImageNet models add mean=(0.485, 0.456, 0.406), std=(0.229, 0.224, 0.225)."""

    size: Size | None = None  # None: the model's own input size
    channels: ChannelOrder = ChannelOrder.RGB
    scale: float = 1.0 / 255.0
    mean: tuple[float, float, float] = (0.0, 0.0, 0.0)
    std: tuple[float, float, float] = (1.0, 1.0, 1.0)
    layout: Layout = Layout.NCHW

    def __post_init__(self) -> None:
        object.__setattr__(self, "channels", member(ChannelOrder, "channels", self.channels))
        object.__setattr__(self, "layout", member(Layout, "layout", self.layout))
        object.__setattr__(self, "mean", tuple(float(v) for v in self.mean))
        object.__setattr__(self, "std", tuple(float(v) for v in self.std))
        if not math.isfinite(self.scale) or self.scale <= 0:
            raise ParameterError("{scale}: must be a positive number", scale=self.scale)
        if len(self.mean) != 3 or not all(math.isfinite(v) for v in self.mean):
            raise ParameterError("{mean}: must be three finite numbers, one per channel", mean=self.mean)
        if len(self.std) != 3 or not all(math.isfinite(v) and v > 0 for v in self.std):
            raise ParameterError("{std}: must be three positive numbers, one per channel", std=self.std)

    def input_shape(self, size: Size) -> tuple[int, int, int, int]:
        """The model input's shape for images at SIZE."""
        return (1, 3, *size.hw) if self.layout == Layout.NCHW else (1, *size.hw, 3)

    def tensor(self, rgb: np.ndarray, size: Size) -> np.ndarray:
        """An HxWx3 uint8 RGB image as the model's float32 input at SIZE."""
        import cv2
        import numpy as np

        if rgb.shape[:2] != size.hw:
            rgb = cv2.resize(rgb, (size.width, size.height), interpolation=cv2.INTER_AREA)
        x = rgb[..., ::-1] if self.channels == ChannelOrder.BGR else rgb
        mean, std = (np.asarray(v, np.float32) for v in (self.mean, self.std))
        x = (x.astype(np.float32) * np.float32(self.scale) - mean) / std
        x = x.transpose(2, 0, 1) if self.layout == Layout.NCHW else x
        return np.ascontiguousarray(x[None], dtype=np.float32)

    def to_dict(self) -> dict:
        """Plain values, for JSON."""
        return {"size": list(self.size.hw) if self.size else None, "channels": self.channels.value,
                "scale": self.scale, "mean": list(self.mean), "std": list(self.std), "layout": self.layout.value}
