"""DeepLabV3 (ASPP head) on MobileNetV3-Large or ResNet-50/101, torchvision-compatible.

State dict keys and shapes match torchvision's `deeplabv3_*` builders, so their
checkpoints load with strict=True. The model takes float RGB in [0, 255], NCHW, and does
its own colour-space conversion and normalisation (`Preprocess`, no state), so the ONNX
export carries them in the graph (docs/contracts.md#onnx-model).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from edgepick.geometry import Size
from edgepick.models.blocks import (
    NORMALISATION,
    BackboneAndHead,
    FCNHead,
    LogitsNet,
    MobileNetBackbone,
    Preprocess,
    rgb_to_hsv,
)
from edgepick.models.config import Arch, ModelConfig, OutputStride, Variant
from edgepick.models.mobilenetv3 import mobilenet_v3_large_features
from edgepick.models.resnet import ResNetFeatures

__all__ = ["ASPP", "NORMALISATION", "DeepLabHead", "DeepLabV3", "FCNHead", "LogitsNet", "Preprocess", "build_deeplabv3",
           "deeplabv3_mobilenet_v3_large", "deeplabv3_resnet101", "deeplabv3_resnet50", "rgb_to_hsv",
           "mobilenet_backbone", "resnet_backbone", "trim_dilated_convs"]

class ASPPConv(nn.Sequential):
    def __init__(self, cin: int, cout: int, dilation: int):
        super().__init__(nn.Conv2d(cin, cout, 3, padding=dilation, dilation=dilation, bias=False),
                         nn.BatchNorm2d(cout), nn.ReLU())


class ASPPPooling(nn.Sequential):
    def __init__(self, cin: int, cout: int):
        super().__init__(nn.AdaptiveAvgPool2d(1), nn.Conv2d(cin, cout, 1, bias=False), nn.BatchNorm2d(cout), nn.ReLU())

    def forward(self, x: Tensor) -> Tensor:
        size = x.shape[-2:]
        for mod in self:
            x = mod(x)
        return F.interpolate(x, size=size, mode="bilinear", align_corners=False)


class ASPP(nn.Module):
    """Atrous spatial pyramid pooling: 1x1, three dilated 3x3, image pooling, then project."""

    def __init__(self, cin: int, rates: tuple[int, int, int], cout: int = 256):
        super().__init__()
        branches: list[nn.Module] = [nn.Sequential(nn.Conv2d(cin, cout, 1, bias=False), nn.BatchNorm2d(cout), nn.ReLU())]
        branches += [ASPPConv(cin, cout, r) for r in rates]
        branches.append(ASPPPooling(cin, cout))
        self.convs = nn.ModuleList(branches)
        self.project = nn.Sequential(nn.Conv2d(len(branches) * cout, cout, 1, bias=False), nn.BatchNorm2d(cout),
                                     nn.ReLU(), nn.Dropout(0.5))

    def forward(self, x: Tensor) -> Tensor:
        return self.project(torch.cat([conv(x) for conv in self.convs], dim=1))


class DeepLabHead(nn.Sequential):
    def __init__(self, cin: int, num_classes: int, rates: tuple[int, int, int] = (12, 24, 36), channels: int = 256):
        super().__init__(ASPP(cin, rates, channels), nn.Conv2d(channels, channels, 3, padding=1, bias=False),
                         nn.BatchNorm2d(channels), nn.ReLU(), nn.Conv2d(channels, num_classes, 1))


class DeepLabV3(BackboneAndHead):
    """backbone -> DeepLabHead (+ optional FCN aux head); logits upsampled to the input size."""

    def __init__(self, config: ModelConfig, backbone: nn.Module, out_ch: int, aux_ch: int):
        rates = (12, 24, 36) if config.output_stride == 8 else (6, 12, 18)
        if config.arch.backbone == "mobilenetv3":
            rates = (12, 24, 36)  # torchvision's setting for its output-stride-16 MobileNet head
        super().__init__(config, backbone,
                         DeepLabHead(out_ch, config.num_classes, rates, 128 if config.variant == Variant.EDGE else 256),
                         FCNHead(aux_ch, config.num_classes) if config.aux_loss else None)


@torch.no_grad()
def trim_dilated_convs(model: nn.Module, input_size: Size) -> int:
    """Shrink ASPP 3x3 kernels whose dilation reaches past the feature map; returns how many changed.

    With rate 36 on a 40x30 map (640x480 at stride 16) the outer rows of taps only ever see
    zero padding: a 1x3 kernel gives the identical result. onnxruntime's fp32 kernels skip
    such taps themselves, its int8 kernels do not (3x more work). Applied to a copy at export
    and quantization time; training keeps torchvision's shapes. Any other model is left as it is.
    """
    if not isinstance(model, DeepLabV3):
        return 0  # only DeepLabV3's ASPP has such taps
    seen: dict[str, tuple[int, int]] = {}

    def record(module: nn.Module, args: tuple) -> None:
        seen["hw"] = tuple(args[0].shape[-2:])

    hook = model.classifier[0].register_forward_pre_hook(record)
    was_training = model.training
    model.eval()(torch.zeros(1, 3, *input_size.hw))
    model.train(was_training)
    hook.remove()
    h, w = seen["hw"]
    changed = 0
    for branch in model.classifier[0].convs:
        if not isinstance(branch, ASPPConv):
            continue
        conv = branch[0]
        d = conv.dilation[0]
        drop_rows, drop_cols = d >= h, d >= w
        if not (drop_rows or drop_cols):
            continue
        rows, cols = slice(1, 2) if drop_rows else slice(0, 3), slice(1, 2) if drop_cols else slice(0, 3)
        small = nn.Conv2d(conv.in_channels, conv.out_channels, (rows.stop - rows.start, cols.stop - cols.start),
                          padding=(0 if drop_rows else d, 0 if drop_cols else d), dilation=d, bias=False)
        small.weight.copy_(conv.weight[:, :, rows, cols])
        branch[0] = small.to(conv.weight.device)
        changed += 1
    return changed


def mobilenet_backbone(config: ModelConfig) -> MobileNetBackbone:
    """MobileNetV3-Large features for a config (the edge variant without SE and hardswish)."""
    edge = config.variant == Variant.EDGE
    return MobileNetBackbone(*mobilenet_v3_large_features(config.output_stride, config.bn_momentum, se=not edge,
                                                          hardswish=not edge))


def resnet_backbone(config: ModelConfig) -> ResNetFeatures:
    """ResNet-50 or -101 features for a config, dilated to its output stride."""
    return ResNetFeatures((3, 4, 6, 3) if config.arch.backbone == "resnet50" else (3, 4, 23, 3), config.output_stride)


def build_deeplabv3(config: ModelConfig) -> DeepLabV3:
    """DeepLabV3 for a config; the keys match torchvision's builder for the same backbone."""
    if config.arch.backbone == "mobilenetv3":
        return DeepLabV3(config, mobilenet_backbone(config), 960, 40)
    return DeepLabV3(config, resnet_backbone(config), 2048, 1024)


def deeplabv3_mobilenet_v3_large(*, num_classes: int = 21, aux_loss: bool = False, **kw) -> DeepLabV3:
    return build_deeplabv3(ModelConfig(Arch.DEEPLABV3_MOBILENETV3, num_classes, aux_loss=aux_loss, **kw))


def deeplabv3_resnet50(*, num_classes: int = 21, aux_loss: bool = False, output_stride: int = 8, **kw) -> DeepLabV3:
    config = ModelConfig(Arch.DEEPLABV3_RESNET50, num_classes, OutputStride(output_stride), aux_loss=aux_loss, **kw)
    return build_deeplabv3(config)


def deeplabv3_resnet101(*, num_classes: int = 21, aux_loss: bool = False, output_stride: int = 8, **kw) -> DeepLabV3:
    config = ModelConfig(Arch.DEEPLABV3_RESNET101, num_classes, OutputStride(output_stride), aux_loss=aux_loss, **kw)
    return build_deeplabv3(config)
