"""MobileNetV3-Large feature extractor with torchvision's module names (dilated tail for DeepLabV3).

Module layout mirrors torchvision.models.mobilenetv3 so that `features.*` weights load
with strict=True. BatchNorm momentum defaults to 0.1, not torchvision's 0.01: with 0.01
the running statistics lag far behind after a short training run and eval-mode
predictions collapse to background.
"""

from __future__ import annotations

from functools import partial

from torch import Tensor, nn


def make_divisible(v: float, divisor: int = 8) -> int:
    new_v = max(divisor, int(v + divisor / 2) // divisor * divisor)
    return new_v + divisor if new_v < 0.9 * v else new_v


class ConvBNAct(nn.Sequential):
    """Conv2d -> BatchNorm -> activation, named 0/1/2 like torchvision's Conv2dNormActivation."""

    def __init__(self, cin: int, cout: int, k: int = 3, stride: int = 1, groups: int = 1, dilation: int = 1,
                 norm: type[nn.Module] | partial = nn.BatchNorm2d, act: type[nn.Module] | None = nn.ReLU):
        pad = (k - 1) // 2 * dilation
        layers: list[nn.Module] = [nn.Conv2d(cin, cout, k, stride, pad, dilation=dilation, groups=groups, bias=False),
                                   norm(cout)]
        if act is not None:
            layers.append(act(inplace=True))
        super().__init__(*layers)
        self.out_channels = cout


class SqueezeExcitation(nn.Module):
    def __init__(self, channels: int, squeeze: int):
        super().__init__()
        self.avgpool = nn.AdaptiveAvgPool2d(1)
        self.fc1 = nn.Conv2d(channels, squeeze, 1)
        self.fc2 = nn.Conv2d(squeeze, channels, 1)
        self.activation = nn.ReLU()
        self.scale_activation = nn.Hardsigmoid()

    def forward(self, x: Tensor) -> Tensor:
        s = self.scale_activation(self.fc2(self.activation(self.fc1(self.avgpool(x)))))
        return x * s


class InvertedResidual(nn.Module):
    def __init__(self, cin: int, k: int, expanded: int, cout: int, use_se: bool, act: str, stride: int,
                 dilation: int, norm: partial):
        super().__init__()
        self.use_res_connect = stride == 1 and cin == cout
        act_layer = nn.Hardswish if act == "HS" else nn.ReLU
        layers: list[nn.Module] = []
        if expanded != cin:
            layers.append(ConvBNAct(cin, expanded, 1, norm=norm, act=act_layer))
        layers.append(ConvBNAct(expanded, expanded, k, stride=1 if dilation > 1 else stride, groups=expanded,
                                dilation=dilation, norm=norm, act=act_layer))
        if use_se:
            layers.append(SqueezeExcitation(expanded, make_divisible(expanded // 4, 8)))
        layers.append(ConvBNAct(expanded, cout, 1, norm=norm, act=None))
        self.block = nn.Sequential(*layers)
        self.out_channels = cout
        self._is_cn = stride > 1  # a stage boundary (torchvision's marker)

    def forward(self, x: Tensor) -> Tensor:
        y = self.block(x)
        return x + y if self.use_res_connect else y


# (in, kernel, expanded, out, SE, activation, stride)
LARGE = [
    (16, 3, 16, 16, False, "RE", 1), (16, 3, 64, 24, False, "RE", 2),
    (24, 3, 72, 24, False, "RE", 1), (24, 5, 72, 40, True, "RE", 2),
    (40, 5, 120, 40, True, "RE", 1), (40, 5, 120, 40, True, "RE", 1),
    (40, 3, 240, 80, False, "HS", 2), (80, 3, 200, 80, False, "HS", 1),
    (80, 3, 184, 80, False, "HS", 1), (80, 3, 184, 80, False, "HS", 1),
    (80, 3, 480, 112, True, "HS", 1), (112, 3, 672, 112, True, "HS", 1),
    (112, 5, 672, 160, True, "HS", 2), (160, 5, 960, 160, True, "HS", 1),
    (160, 5, 960, 160, True, "HS", 1),
]


def mobilenet_v3_large_features(output_stride: int = 16, bn_momentum: float = 0.1, se: bool = True,
                                hardswish: bool = True) -> nn.Sequential:
    """The 17 `features` modules of MobileNetV3-Large; output stride 16 (torchvision) or 8.

    se=False drops the squeeze-excitation blocks and hardswish=False uses ReLU throughout: the
    quantization-friendly 'edge' variant (no float-only ReduceMean/HardSigmoid in int8 graphs).
    """
    if output_stride not in (8, 16):
        raise ValueError("output_stride must be 8 or 16")
    norm = partial(nn.BatchNorm2d, eps=0.001, momentum=bn_momentum)
    top_act = nn.Hardswish if hardswish else nn.ReLU
    layers: list[nn.Module] = [ConvBNAct(3, 16, 3, stride=2, norm=norm, act=top_act)]
    dilate_from = 7 if output_stride == 8 else 13  # index into `features` where dilation starts
    dilation = 1
    for i, (cin, k, exp, cout, use_se, act, stride) in enumerate(LARGE, start=1):
        if i >= dilate_from and stride > 1:
            dilation *= 2  # keep the resolution: the stride becomes dilation
        layers.append(InvertedResidual(cin, k, exp, cout, use_se and se, act if hardswish else "RE", stride,
                                       dilation, norm))
    layers.append(ConvBNAct(160, 960, 1, norm=norm, act=top_act))
    return nn.Sequential(*layers)
