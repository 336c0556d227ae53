"""DeepLabV3 models (torch). Builders follow torchvision's names and state-dict keys.

The config and its choices (edgepick.models.config) import without torch; the model classes and
builders are loaded from edgepick.models.deeplabv3 when first asked for."""

from typing import TYPE_CHECKING

from edgepick.models.config import Arch, ColorSpace, ModelConfig, OutputStride, Variant

_TORCH = {"DeepLabV3", "LogitsNet", "build_model", "deeplabv3_mobilenet_v3_large", "deeplabv3_resnet50",
          "deeplabv3_resnet101"}

__all__ = ["Arch", "ColorSpace", "DeepLabV3", "LogitsNet", "ModelConfig", "OutputStride", "Variant", "build_model",
           "deeplabv3_mobilenet_v3_large", "deeplabv3_resnet50", "deeplabv3_resnet101"]

if TYPE_CHECKING:
    from edgepick.models.deeplabv3 import (
        DeepLabV3,
        LogitsNet,
        build_model,
        deeplabv3_mobilenet_v3_large,
        deeplabv3_resnet50,
        deeplabv3_resnet101,
    )


def __getattr__(name: str) -> object:
    if name in _TORCH:
        from edgepick.models import deeplabv3

        return getattr(deeplabv3, name)
    raise AttributeError(f"module 'edgepick.models' has no attribute {name!r}")
