"""What a DeepLabV3 is built from (`ModelConfig`) and the choices it offers, without torch: the
command line builds its options from these enums, and checkpoints record the config."""

from __future__ import annotations

import enum
from dataclasses import dataclass, fields

from edgepick.errors import ParameterError
from edgepick.schema import member, plain


class Arch(enum.StrEnum):
    """The backbone."""

    MOBILENETV3 = "mobilenetv3"
    RESNET50 = "resnet50"
    RESNET101 = "resnet101"


class Variant(enum.StrEnum):
    """standard: torchvision's model; edge: MobileNetV3 without SE and hardswish, a 128-channel ASPP
    (quantization-friendly, not torchvision-compatible)."""

    STANDARD = "standard"
    EDGE = "edge"


class ColorSpace(enum.StrEnum):
    """The colour space the model converts its RGB input to, inside the graph."""

    RGB = "rgb"
    HSV = "hsv"
    GRAY = "gray"


class OutputStride(enum.IntEnum):
    """The backbone's output stride: 8 (denser, slower) or 16."""

    EIGHT = 8
    SIXTEEN = 16


@dataclass(frozen=True)
class ModelConfig:
    """A DeepLabV3's architecture, checked on creation."""

    arch: Arch = Arch.MOBILENETV3
    num_classes: int = 5
    output_stride: OutputStride = OutputStride.SIXTEEN
    colorspace: ColorSpace = ColorSpace.RGB
    aux_loss: bool = False
    bn_momentum: float = 0.1
    variant: Variant = Variant.STANDARD

    def __post_init__(self) -> None:
        for name, kind in (("arch", Arch), ("variant", Variant), ("colorspace", ColorSpace)):
            object.__setattr__(self, name, member(kind, name, getattr(self, name)))
        if self.output_stride not in tuple(OutputStride):
            raise ParameterError("{output_stride}: output stride must be 8 or 16", output_stride=self.output_stride)
        object.__setattr__(self, "output_stride", OutputStride(self.output_stride))
        if self.variant == Variant.EDGE and self.arch != Arch.MOBILENETV3:
            raise ParameterError("{variant}: the edge variant is a MobileNetV3 variant, not {arch}",
                                 variant=self.variant, arch=self.arch)
        if self.num_classes < 2:
            raise ParameterError("{num_classes}: need at least 2 classes", num_classes=self.num_classes)

    def to_dict(self) -> dict:
        """The config as a checkpoint records it (plain values)."""
        return {f.name: plain(getattr(self, f.name)) for f in fields(self)}
