"""DeepLabV3 models (torch). Builders follow torchvision's names and state-dict keys."""

from edgepick.models.deeplabv3 import (ARCHS, COLORSPACES, DeepLabV3, LogitsNet, ModelConfig, build_model,
                                       deeplabv3_mobilenet_v3_large, deeplabv3_resnet50, deeplabv3_resnet101)

__all__ = ["ARCHS", "COLORSPACES", "DeepLabV3", "LogitsNet", "ModelConfig", "build_model",
           "deeplabv3_mobilenet_v3_large", "deeplabv3_resnet50", "deeplabv3_resnet101"]
