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
from edgepick.models.config import Arch, ColorSpace, ModelConfig, Variant
from edgepick.models.mobilenetv3 import mobilenet_v3_large_features
from edgepick.models.resnet import ResNetFeatures

NORMALISATION = {ColorSpace.RGB: ((0.485, 0.456, 0.406), (0.229, 0.224, 0.225)),  # mean, std per colour space
                 ColorSpace.HSV: ((0.5, 0.5, 0.5), (0.29, 0.29, 0.29)),
                 ColorSpace.GRAY: ((0.449, 0.449, 0.449), (0.226, 0.226, 0.226))}


def rgb_to_hsv(x: Tensor) -> Tensor:
    """RGB in [0, 1] -> HSV in [0, 1], with ops that export to ONNX."""
    r, g, b = x[:, 0:1], x[:, 1:2], x[:, 2:3]
    v = torch.amax(x, dim=1, keepdim=True)
    delta = v - torch.amin(x, dim=1, keepdim=True)
    s = delta / (v + 1e-6)
    safe = delta + 1e-6
    h = torch.where(v == r, (g - b) / safe, torch.where(v == g, 2.0 + (b - r) / safe, 4.0 + (r - g) / safe))
    h = torch.remainder(h / 6.0, 1.0) * (delta > 0)
    return torch.cat([h, s, v], dim=1)


class Preprocess(nn.Module):
    """[0, 255] RGB -> colour space -> normalised; buffers are not part of the state dict."""

    def __init__(self, colorspace: ColorSpace = ColorSpace.RGB):
        super().__init__()
        self.colorspace = ColorSpace(colorspace)
        # plain flags for forward(): traced as constants
        self.hsv, self.gray = self.colorspace == ColorSpace.HSV, self.colorspace == ColorSpace.GRAY
        mean, std = (torch.tensor(v).view(1, 3, 1, 1) for v in NORMALISATION[self.colorspace])
        # (x / 255 - mean) / std as one multiply-add: x * scale + shift (scale folds 1/255 unless HSV needs [0, 1])
        first = 1.0 if self.hsv else 255.0
        self.register_buffer("scale", 1.0 / (first * std), persistent=False)
        self.register_buffer("shift", -mean / std, persistent=False)

    def forward(self, x: Tensor) -> Tensor:
        if self.hsv:
            x = rgb_to_hsv(x / 255.0)
        elif self.gray:
            y = 0.299 * x[:, 0:1] + 0.587 * x[:, 1:2] + 0.114 * x[:, 2:3]
            x = y.expand(-1, 3, -1, -1)
        # the constants spelt out along the width: onnxruntime's int8 graphs run this in NHWC, where a
        # per-channel [3] constant broadcasts in 3-element spans, which is slow
        width = x.shape[-1]
        return x * self.scale.expand(-1, -1, -1, width) + self.shift.expand(-1, -1, -1, width)


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


class FCNHead(nn.Sequential):
    def __init__(self, cin: int, num_classes: int):
        mid = cin // 4
        super().__init__(nn.Conv2d(cin, mid, 3, padding=1, bias=False), nn.BatchNorm2d(mid), nn.ReLU(),
                         nn.Dropout(0.1), nn.Conv2d(mid, num_classes, 1))


class MobileNetBackbone(nn.Sequential):
    """features[0..16] returning the stride-8 'aux' tap (index 4) and the last output."""

    AUX_INDEX = 4

    def forward(self, x: Tensor) -> dict[str, Tensor]:  # type: ignore[override]
        aux = x
        for i, mod in enumerate(self):
            x = mod(x)
            if i == self.AUX_INDEX:
                aux = x
        return {"aux": aux, "out": x}


class DeepLabV3(nn.Module):
    """backbone -> DeepLabHead (+ optional FCN aux head); logits upsampled to the input size."""

    def __init__(self, config: ModelConfig, backbone: nn.Module, out_ch: int, aux_ch: int):
        super().__init__()
        self.config = config
        self.preprocess = Preprocess(config.colorspace)
        self.backbone = backbone
        rates = (12, 24, 36) if config.output_stride == 8 else (6, 12, 18)
        if config.arch == Arch.MOBILENETV3:
            rates = (12, 24, 36)  # torchvision's setting for its output-stride-16 MobileNet head
        self.classifier = DeepLabHead(out_ch, config.num_classes, rates, 128 if config.variant == Variant.EDGE else 256)
        self.aux_classifier = FCNHead(aux_ch, config.num_classes) if config.aux_loss else None

    def forward(self, x: Tensor) -> dict[str, Tensor]:
        size = x.shape[-2:]
        feats = self.backbone(self.preprocess(x))
        out = {"out": F.interpolate(self.classifier(feats["out"]), size=size, mode="bilinear", align_corners=False)}
        if self.aux_classifier is not None and self.training:
            out["aux"] = F.interpolate(self.aux_classifier(feats["aux"]), size=size, mode="bilinear",
                                       align_corners=False)
        return out



class LogitsNet(nn.Module):
    """DeepLabV3 (or any torchvision-style segmentation model) -> its plain `out` logits tensor:
    what torch.export, pt2e and the ONNX writer take."""

    def __init__(self, model: nn.Module):
        super().__init__()
        self.model = model

    def forward(self, x: Tensor) -> Tensor:
        out = self.model(x)
        return out["out"] if isinstance(out, dict) else out  # a model of one's own may give the tensor itself


def build_model(config: ModelConfig) -> DeepLabV3:
    """DeepLabV3 for a config; the keys match torchvision's builder for the same arch."""
    if config.arch == Arch.MOBILENETV3:
        edge = config.variant == Variant.EDGE
        backbone = MobileNetBackbone(*mobilenet_v3_large_features(config.output_stride, config.bn_momentum,
                                                                  se=not edge, hardswish=not edge))
        return DeepLabV3(config, backbone, 960, 40)
    blocks = (3, 4, 6, 3) if config.arch == Arch.RESNET50 else (3, 4, 23, 3)
    return DeepLabV3(config, ResNetFeatures(blocks, config.output_stride), 2048, 1024)


@torch.no_grad()
def trim_dilated_convs(model: DeepLabV3, input_size: Size) -> int:
    """Shrink ASPP 3x3 kernels whose dilation reaches past the feature map; returns how many changed.

    With rate 36 on a 40x30 map (640x480 at stride 16) the outer rows of taps only ever see
    zero padding: a 1x3 kernel gives the identical result. onnxruntime's fp32 kernels skip
    such taps themselves, its int8 kernels do not (3x more work). Applied to a copy at export
    and quantization time; training keeps torchvision's shapes.
    """
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


def deeplabv3_mobilenet_v3_large(num_classes: int = 21, aux_loss: bool = False, **kw) -> DeepLabV3:
    return build_model(ModelConfig(Arch.MOBILENETV3, num_classes, aux_loss=aux_loss, **kw))


def deeplabv3_resnet50(num_classes: int = 21, aux_loss: bool = False, **kw) -> DeepLabV3:
    return build_model(ModelConfig(Arch.RESNET50, num_classes, output_stride=kw.pop("output_stride", 8),
                                   aux_loss=aux_loss, **kw))


def deeplabv3_resnet101(num_classes: int = 21, aux_loss: bool = False, **kw) -> DeepLabV3:
    return build_model(ModelConfig(Arch.RESNET101, num_classes, output_stride=kw.pop("output_stride", 8),
                                   aux_loss=aux_loss, **kw))


def load_backbone_weights(model: DeepLabV3, path: str) -> int:
    """Load backbone weights from a file: a torchvision classification or segmentation state dict.

    Accepts keys prefixed `backbone.` (segmentation), `features.` (MobileNetV3 classifier) or
    bare ResNet keys; returns the number of tensors loaded. Shape mismatches are an error.
    """
    from edgepick.errors import CheckpointError

    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - any unreadable file is the user's
        raise CheckpointError(f"cannot read backbone weights {path}: {exc}") from None
    state = state.get("model", state) if isinstance(state, dict) else state
    if not isinstance(state, dict) or not all(isinstance(k, str) and torch.is_tensor(v) for k, v in state.items()):
        raise CheckpointError(f"{path} is not a state dict (parameter names to tensors), so it holds no backbone "
                              "weights")
    target = model.backbone.state_dict()
    picked = {}
    for key, val in state.items():
        for prefix in ("backbone.", "features.", ""):
            if key.startswith(prefix) and key[len(prefix):] in target:
                k = key[len(prefix):]
                if target[k].shape != val.shape:
                    raise CheckpointError(f"backbone weight {key} has shape {tuple(val.shape)}, "
                                          f"expected {tuple(target[k].shape)}")
                picked[k] = val
                break
    if len(picked) < len(target) // 2:
        raise CheckpointError(f"{path} does not hold {model.config.arch} backbone weights "
                              f"({len(picked)} of {len(target)} tensors matched)")
    model.backbone.load_state_dict(picked, strict=False)
    return len(picked)
