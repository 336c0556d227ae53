"""U-Net (Ronneberger et al. 2015), the thesis's U-Net of Table 5.4: four 2x2 max-pool steps down
and four up, two 3x3 conv-BN-ReLU per level, skip connections by concatenation. Upsampling is
bilinear followed by the level's convs (as the widely used PyTorch-UNet's bilinear form), not a
transposed conv: every conv is then a plain one that int8 kernels run, and the bottom level holds
512 channels, not 1024 (17 M parameters instead of 31 M)."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from edgepick.models.blocks import Preprocess
from edgepick.models.config import Arch, ModelConfig

WIDTHS = (64, 128, 256, 512, 512)  # per level, top to bottom


class DoubleConv(nn.Sequential):
    """(3x3 conv, BN, ReLU) twice."""

    def __init__(self, cin: int, cout: int, mid: int | None = None):
        mid = mid or cout
        super().__init__(nn.Conv2d(cin, mid, 3, padding=1, bias=False), nn.BatchNorm2d(mid), nn.ReLU(inplace=True),
                         nn.Conv2d(mid, cout, 3, padding=1, bias=False), nn.BatchNorm2d(cout), nn.ReLU(inplace=True))


class Up(nn.Module):
    """Bilinear 2x up, concatenated with the skip, then DoubleConv."""

    def __init__(self, cin: int, cout: int):
        super().__init__()
        self.conv = DoubleConv(cin, cout, cin // 2)

    def forward(self, x: Tensor, skip: Tensor) -> Tensor:
        x = F.interpolate(x, size=skip.shape[-2:], mode="bilinear", align_corners=False)
        return self.conv(torch.cat([skip, x], dim=1))


class UNet(nn.Module):
    """Encoder levels inc, down1..down4; decoder up1..up4; a 1x1 classifier. Input sides need not be
    multiples of 16: each up step resizes to its skip's size."""

    def __init__(self, config: ModelConfig):
        super().__init__()
        self.config = config
        self.preprocess = Preprocess(config.colorspace)
        w = WIDTHS
        self.inc = DoubleConv(3, w[0])
        self.downs = nn.ModuleList(DoubleConv(w[i], w[i + 1]) for i in range(4))
        ups, below = [], w[4]
        for skip in reversed(w[:4]):  # each up step halves the skip's channels, down to the top's
            ups.append(Up(skip + below, max(skip // 2, w[0])))
            below = max(skip // 2, w[0])
        self.ups = nn.ModuleList(ups)
        self.classifier = nn.Conv2d(w[0], config.num_classes, 1)

    def forward(self, x: Tensor) -> dict[str, Tensor]:
        skips = [self.inc(self.preprocess(x))]
        for down in self.downs:
            skips.append(down(F.max_pool2d(skips[-1], 2)))
        y = skips.pop()
        for up in self.ups:
            y = up(y, skips.pop())
        return {"out": self.classifier(y)}


def unet(*, num_classes: int = 21, **kw) -> UNet:
    return UNet(ModelConfig(Arch.UNET, num_classes, **kw))
