"""What a segmentation model is built from (`ModelConfig`) and the choices it offers, without torch:
the command line builds its options from these enums, and checkpoints record the config."""

from __future__ import annotations

import enum
from dataclasses import dataclass, fields

from edgepick.errors import ParameterError
from edgepick.schema import member, plain


class Arch(enum.StrEnum):
    """The architecture: a family (DeepLabV3, LR-ASPP, FCN, U-Net, SegNet, DDRNet) and, where it has
    one, its backbone. The thesis compared SegNet, FCN, U-Net and DeepLabV3 (Table 5.4)."""

    DEEPLABV3_MOBILENETV3 = "deeplabv3-mobilenetv3"
    DEEPLABV3_RESNET50 = "deeplabv3-resnet50"
    DEEPLABV3_RESNET101 = "deeplabv3-resnet101"
    LRASPP_MOBILENETV3 = "lraspp-mobilenetv3"
    FCN_RESNET50 = "fcn-resnet50"
    FCN_RESNET101 = "fcn-resnet101"
    UNET = "unet"
    SEGNET = "segnet"
    DDRNET23_SLIM = "ddrnet23-slim"

    @classmethod
    def _missing_(cls, value: object) -> Arch | None:
        """The names runs and model files recorded before there was more than one family."""
        return {"mobilenetv3": cls.DEEPLABV3_MOBILENETV3, "resnet50": cls.DEEPLABV3_RESNET50,
                "resnet101": cls.DEEPLABV3_RESNET101}.get(str(value))

    @property
    def family(self) -> str:
        """deeplabv3, lraspp, fcn, unet, segnet or ddrnet."""
        return self.value.split("-")[0].removesuffix("23")

    @property
    def backbone(self) -> str | None:
        """mobilenetv3, resnet50 or resnet101; None for the families that have no separate backbone."""
        return self.value.split("-")[1] if self.family in ("deeplabv3", "lraspp", "fcn") else None

    @property
    def dilated(self) -> bool:
        """Whether its backbone's output stride is a choice (8 or 16): a backbone with dilated convolutions."""
        return self.backbone is not None

    @property
    def has_aux(self) -> bool:
        """Whether it has torchvision's auxiliary FCN head on the stride-8/16 tap (--aux-loss)."""
        return self.family in ("deeplabv3", "fcn")


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
    """A segmentation model's architecture, checked on creation."""

    arch: Arch = Arch.DEEPLABV3_MOBILENETV3
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
        if self.variant == Variant.EDGE and self.arch.backbone != "mobilenetv3":
            raise ParameterError("{variant}: the edge variant is a MobileNetV3 variant, not {arch}",
                                 variant=self.variant, arch=self.arch)
        if self.output_stride != OutputStride.SIXTEEN and not self.arch.dilated:
            raise ParameterError("{output_stride}: {arch} has a fixed output stride; only deeplabv3, lraspp and fcn "
                                 "take 8", output_stride=int(self.output_stride), arch=self.arch)
        if self.aux_loss and not self.arch.has_aux:
            raise ParameterError("{aux_loss}: {arch} has no auxiliary head; only deeplabv3 and fcn do",
                                 aux_loss=self.aux_loss, arch=self.arch)
        if self.num_classes < 2:
            raise ParameterError("{num_classes}: need at least 2 classes", num_classes=self.num_classes)

    def to_dict(self) -> dict:
        """The config as a checkpoint records it (plain values)."""
        return {f.name: plain(getattr(self, f.name)) for f in fields(self)}
