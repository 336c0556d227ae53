"""DDRNet-23-slim (Pan et al. 2021, "Deep Dual-resolution Networks"): a real-time network of plain
conv-BN-ReLU residual blocks in two branches, one kept at 1/8 of the input and one going down to
1/64, fused both ways after each stage, with a pyramid pooling module (DAPPM) on the low branch.

The pooling module and the head here put each BatchNorm after its conv (conv-BN-ReLU), where the
paper's code puts it before (BN-ReLU-conv): a BatchNorm after a pooling or a sum has no conv to fold
into and runs in float between int8 ops. No auxiliary head."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from edgepick.models.blocks import Preprocess
from edgepick.models.config import Arch, ModelConfig


def conv_bn(cin: int, cout: int, k: int = 3, stride: int = 1, relu: bool = False) -> nn.Sequential:
    layers: list[nn.Module] = [nn.Conv2d(cin, cout, k, stride, k // 2, bias=False), nn.BatchNorm2d(cout)]
    return nn.Sequential(*layers, nn.ReLU(inplace=True)) if relu else nn.Sequential(*layers)


class BasicBlock(nn.Module):
    expansion = 1

    def __init__(self, cin: int, planes: int, stride: int = 1, last: bool = False):
        super().__init__()
        self.conv1, self.conv2 = conv_bn(cin, planes, 3, stride, relu=True), conv_bn(planes, planes)
        self.downsample = conv_bn(cin, planes, 1, stride) if stride != 1 or cin != planes else None
        self.relu = not last  # a stage's last block leaves its ReLU to the fusion that follows

    def forward(self, x: Tensor) -> Tensor:
        out = self.conv2(self.conv1(x)) + (x if self.downsample is None else self.downsample(x))
        return F.relu(out) if self.relu else out


class Bottleneck(nn.Module):
    expansion = 2

    def __init__(self, cin: int, planes: int, stride: int = 1, last: bool = False):
        super().__init__()
        out = planes * self.expansion
        self.conv1, self.conv2 = conv_bn(cin, planes, 1, relu=True), conv_bn(planes, planes, 3, stride, relu=True)
        self.conv3 = conv_bn(planes, out, 1)
        self.downsample = conv_bn(cin, out, 1, stride) if stride != 1 or cin != out else None
        self.relu = not last

    def forward(self, x: Tensor) -> Tensor:
        out = self.conv3(self.conv2(self.conv1(x))) + (x if self.downsample is None else self.downsample(x))
        return F.relu(out) if self.relu else out


def stage(block: type[BasicBlock] | type[Bottleneck], cin: int, planes: int, blocks: int, stride: int = 1) -> nn.Sequential:
    layers = [block(cin, planes, stride, last=blocks == 1)]
    layers += [block(planes * block.expansion, planes, last=i == blocks - 1) for i in range(1, blocks)]
    return nn.Sequential(*layers)


class DAPPM(nn.Module):
    """Deep aggregation pyramid pooling: average pools of 1/2, 1/4, 1/8 and the whole map, each
    upsampled and added to the finer level before its 3x3 conv, concatenated, plus a shortcut."""

    POOLS = ((5, 2, 2), (9, 4, 4), (17, 8, 8))  # kernel, stride, padding

    def __init__(self, cin: int, branch: int, cout: int):
        super().__init__()
        self.scales = nn.ModuleList([conv_bn(cin, branch, 1, relu=True)] +
                                    [nn.Sequential(nn.AvgPool2d(k, s, p), *conv_bn(cin, branch, 1, relu=True))
                                     for k, s, p in self.POOLS] +
                                    [nn.Sequential(nn.AdaptiveAvgPool2d(1), *conv_bn(cin, branch, 1, relu=True))])
        self.process = nn.ModuleList(conv_bn(branch, branch, 3, relu=True) for _ in range(4))
        self.compression = conv_bn(5 * branch, cout, 1)
        self.shortcut = conv_bn(cin, cout, 1)

    def forward(self, x: Tensor) -> Tensor:
        x = F.relu(x)
        levels = [self.scales[0](x)]
        for scale, process in zip(self.scales[1:], self.process):
            up = F.interpolate(scale(x), size=x.shape[-2:], mode="bilinear", align_corners=False)
            levels.append(process(up + levels[-1]))
        return self.compression(torch.cat(levels, 1)) + self.shortcut(x)


class DDRNet(nn.Module):
    """DDRNet-23-slim: stem and two stages to 1/8, then a high branch at 1/8 and a low branch down to
    1/64 exchanging features after stages 3 and 4; DAPPM on the low branch, added to the high
    branch; a 3x3 + 1x1 head at 1/8; logits upsampled to the input size."""

    def __init__(self, config: ModelConfig, planes: int = 32, spp_planes: int = 128, head_planes: int = 64):
        super().__init__()
        self.config = config
        self.preprocess = Preprocess(config.colorspace)
        p = planes
        self.stem = nn.Sequential(conv_bn(3, p, 3, 2, relu=True), conv_bn(p, p, 3, 2, relu=True))
        self.layer1, self.layer2 = stage(BasicBlock, p, p, 2), stage(BasicBlock, p, 2 * p, 2, 2)
        self.layer3, self.layer3_ = stage(BasicBlock, 2 * p, 4 * p, 2, 2), stage(BasicBlock, 2 * p, 2 * p, 2)
        self.layer4, self.layer4_ = stage(BasicBlock, 4 * p, 8 * p, 2, 2), stage(BasicBlock, 2 * p, 2 * p, 2)
        self.compression3, self.compression4 = conv_bn(4 * p, 2 * p, 1), conv_bn(8 * p, 2 * p, 1)
        self.down3 = conv_bn(2 * p, 4 * p, 3, 2)
        self.down4 = nn.Sequential(conv_bn(2 * p, 4 * p, 3, 2, relu=True), conv_bn(4 * p, 8 * p, 3, 2))
        self.layer5_, self.layer5 = stage(Bottleneck, 2 * p, 2 * p, 1), stage(Bottleneck, 8 * p, 8 * p, 1, 2)
        self.spp = DAPPM(16 * p, spp_planes, 4 * p)
        self.head = nn.Sequential(conv_bn(4 * p, head_planes, 3, relu=True),
                                  nn.Conv2d(head_planes, config.num_classes, 1))

    def forward(self, x: Tensor) -> dict[str, Tensor]:
        size = x.shape[-2:]
        x = self.layer2(F.relu(self.layer1(self.stem(self.preprocess(x)))))
        high_size = x.shape[-2:]
        low, high = self.layer3(F.relu(x)), self.layer3_(F.relu(x))
        low, high = (low + self.down3(F.relu(high)),
                     high + F.interpolate(self.compression3(F.relu(low)), size=high_size, mode="bilinear",
                                          align_corners=False))
        low, high = self.layer4(F.relu(low)), self.layer4_(F.relu(high))
        low, high = (low + self.down4(F.relu(high)),
                     high + F.interpolate(self.compression4(F.relu(low)), size=high_size, mode="bilinear",
                                          align_corners=False))
        high = self.layer5_(F.relu(high))
        low = F.interpolate(self.spp(self.layer5(F.relu(low))), size=high_size, mode="bilinear", align_corners=False)
        out = self.head(F.relu(low + high))
        return {"out": F.interpolate(out, size=size, mode="bilinear", align_corners=False)}


def ddrnet23_slim(*, num_classes: int = 21, **kw) -> DDRNet:
    return DDRNet(ModelConfig(Arch.DDRNET23_SLIM, num_classes, **kw))
