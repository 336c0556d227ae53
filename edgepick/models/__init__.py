"""Segmentation model families (torch): DeepLabV3, LR-ASPP, FCN, U-Net, SegNet, DDRNet. Builders
follow torchvision's names and state-dict keys where torchvision has the model.

The config and its choices (edgepick.models.config) import without torch; the model classes and
builders are loaded from edgepick.models.zoo when first asked for."""

from typing import TYPE_CHECKING

from edgepick.lazy import lazy_attributes
from edgepick.models.config import Arch, ColorSpace, ModelConfig, OutputStride, Variant

_WHERE = {
    "LogitsNet": "blocks", **dict.fromkeys(
        ("build_model", "load_backbone_weights", "deeplabv3_mobilenet_v3_large", "deeplabv3_resnet50",
         "deeplabv3_resnet101", "lraspp_mobilenet_v3_large", "fcn_resnet50", "fcn_resnet101", "unet", "segnet",
         "ddrnet23_slim"), "zoo")
}
__all__ = sorted([*_WHERE, "Arch", "ColorSpace", "ModelConfig", "OutputStride", "Variant"])

if TYPE_CHECKING:
    from edgepick.models.blocks import LogitsNet
    from edgepick.models.zoo import (
        build_model,
        ddrnet23_slim,
        deeplabv3_mobilenet_v3_large,
        deeplabv3_resnet50,
        deeplabv3_resnet101,
        fcn_resnet50,
        fcn_resnet101,
        load_backbone_weights,
        lraspp_mobilenet_v3_large,
        segnet,
        unet,
    )


__getattr__ = lazy_attributes(__name__, _WHERE)
