"""SegNet (Badrinarayanan et al. 2017), the thesis's SegNet of Table 5.4: a VGG16-BN encoder whose
five 2x2 max pools keep the positions of their maxima, and a mirrored decoder that puts each value
back at its position (max unpooling) before its convs."""

from __future__ import annotations

import torch.nn.functional as F
from torch import Tensor, nn

from edgepick.models.blocks import Preprocess
from edgepick.models.config import Arch, ModelConfig

ENCODER: tuple[tuple[int, ...], ...] = ((64, 64), (128, 128), (256, 256, 256), (512, 512, 512), (512, 512, 512))  # VGG16's 13 convs
# after each unpool, deepest first
DECODER: tuple[tuple[int, ...], ...] = ((512, 512, 512), (512, 512, 256), (256, 256, 128), (128, 64), (64,))


def convs(cin: int, widths: tuple[int, ...]) -> nn.Sequential:
    layers: list[nn.Module] = []
    for w in widths:
        layers += [nn.Conv2d(cin, w, 3, padding=1, bias=False), nn.BatchNorm2d(w), nn.ReLU(inplace=True)]
        cin = w
    return nn.Sequential(*layers)


class SegNet(nn.Module):
    """Five encoder stages (convs, then a 2x2 max pool with indices), five decoder stages (max
    unpool to the stage's size, then convs), a 3x3 classifier at full resolution."""

    def __init__(self, config: ModelConfig):
        super().__init__()
        self.config = config
        self.preprocess = Preprocess(config.colorspace)
        cin, encoder = 3, []
        for widths in ENCODER:
            encoder.append(convs(cin, widths))
            cin = widths[-1]
        self.encoder = nn.ModuleList(encoder)
        decoder = []
        for widths in DECODER:
            decoder.append(convs(cin, widths))
            cin = widths[-1]
        self.decoder = nn.ModuleList(decoder)
        self.classifier = nn.Conv2d(cin, config.num_classes, 3, padding=1)

    def forward(self, x: Tensor) -> dict[str, Tensor]:
        x = self.preprocess(x)
        pooled = []
        for stage in self.encoder:
            x = stage(x)
            size = x.shape[-2:]
            x, where = F.max_pool2d(x, 2, 2, return_indices=True)
            pooled.append((where, size))
        for stage in self.decoder:
            where, size = pooled.pop()
            x = stage(F.max_unpool2d(x, where, 2, 2, output_size=size))
        return {"out": self.classifier(x)}


def segnet(*, num_classes: int = 21, **kw) -> SegNet:
    return SegNet(ModelConfig(Arch.SEGNET, num_classes, **kw))
