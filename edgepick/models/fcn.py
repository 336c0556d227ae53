"""FCN (Long et al. 2015) as torchvision builds it: a dilated ResNet-50/101 and one 3x3 conv head,
the thesis's FCN (ResNet101) of Table 5.4. State-dict keys match torchvision's `fcn_resnet*`."""

from __future__ import annotations

from edgepick.models.blocks import BackboneAndHead, FCNHead
from edgepick.models.config import Arch, ModelConfig, OutputStride
from edgepick.models.deeplabv3 import resnet_backbone


class FCN(BackboneAndHead):
    """ResNet features -> FCNHead (+ optional aux FCNHead on layer3); logits upsampled to the input."""


def build_fcn(config: ModelConfig) -> FCN:
    return FCN(config, resnet_backbone(config), FCNHead(2048, config.num_classes),
               FCNHead(1024, config.num_classes) if config.aux_loss else None)


def fcn_resnet50(*, num_classes: int = 21, aux_loss: bool = False, output_stride: int = 8, **kw) -> FCN:
    config = ModelConfig(Arch.FCN_RESNET50, num_classes, OutputStride(output_stride), aux_loss=aux_loss, **kw)
    return build_fcn(config)


def fcn_resnet101(*, num_classes: int = 21, aux_loss: bool = False, output_stride: int = 8, **kw) -> FCN:
    config = ModelConfig(Arch.FCN_RESNET101, num_classes, OutputStride(output_stride), aux_loss=aux_loss, **kw)
    return build_fcn(config)
