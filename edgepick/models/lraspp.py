"""LR-ASPP (Howard et al. 2019, "Searching for MobileNetV3"): MobileNetV3-Large, a 1x1 conv gated
by a pooled sigmoid on the stride-16 features, added to a 1x1 classifier on the stride-8 ones.
torchvision's segmentation model for mobile CPUs; state-dict keys match `lraspp_mobilenet_v3_large`."""

from __future__ import annotations

import torch.nn.functional as F
from torch import Tensor, nn

from edgepick.models.blocks import Preprocess
from edgepick.models.config import Arch, ModelConfig
from edgepick.models.deeplabv3 import mobilenet_backbone


class LRASPPHead(nn.Module):
    def __init__(self, low_channels: int, high_channels: int, num_classes: int, inter_channels: int = 128):
        super().__init__()
        self.cbr = nn.Sequential(nn.Conv2d(high_channels, inter_channels, 1, bias=False),
                                 nn.BatchNorm2d(inter_channels), nn.ReLU(inplace=True))
        self.scale = nn.Sequential(nn.AdaptiveAvgPool2d(1), nn.Conv2d(high_channels, inter_channels, 1, bias=False),
                                   nn.Sigmoid())
        self.low_classifier = nn.Conv2d(low_channels, num_classes, 1)
        self.high_classifier = nn.Conv2d(inter_channels, num_classes, 1)

    def forward(self, low: Tensor, high: Tensor) -> Tensor:
        x = self.cbr(high) * self.scale(high)
        x = F.interpolate(x, size=low.shape[-2:], mode="bilinear", align_corners=False)
        return self.low_classifier(low) + self.high_classifier(x)


class LRASPP(nn.Module):
    """MobileNetV3 backbone (stride-8 'aux' tap as the low branch) -> LRASPPHead; logits upsampled."""

    def __init__(self, config: ModelConfig):
        super().__init__()
        self.config = config
        self.preprocess = Preprocess(config.colorspace)
        self.backbone = mobilenet_backbone(config)
        self.classifier = LRASPPHead(40, 960, config.num_classes)

    def forward(self, x: Tensor) -> dict[str, Tensor]:
        feats = self.backbone(self.preprocess(x))
        out = self.classifier(feats["aux"], feats["out"])
        return {"out": F.interpolate(out, size=x.shape[-2:], mode="bilinear", align_corners=False)}


def lraspp_mobilenet_v3_large(*, num_classes: int = 21, **kw) -> LRASPP:
    return LRASPP(ModelConfig(Arch.LRASPP_MOBILENETV3, num_classes, **kw))
