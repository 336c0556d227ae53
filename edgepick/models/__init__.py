"""DeepLabV3 models (torch). Builders follow torchvision's names and state-dict keys.

The config and its choices (edgepick.models.config) import without torch; the model classes and
builders are loaded from edgepick.models.deeplabv3 when first asked for."""

from edgepick.models.config import Arch, ColorSpace, ModelConfig, OutputStride, Variant

_TORCH = {"DeepLabV3", "build_model", "deeplabv3_mobilenet_v3_large", "deeplabv3_resnet50", "deeplabv3_resnet101"}

__all__ = ["Arch", "ColorSpace", "DeepLabV3", "ModelConfig", "OutputStride", "Variant", "build_model",
           "deeplabv3_mobilenet_v3_large", "deeplabv3_resnet50", "deeplabv3_resnet101"]


def __getattr__(name: str):
    if name in _TORCH:
        from edgepick.models import deeplabv3

        return getattr(deeplabv3, name)
    raise AttributeError(f"module 'edgepick.models' has no attribute {name!r}")
