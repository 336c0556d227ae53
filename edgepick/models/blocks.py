"""Parts the model families share: the in-graph preprocessing, torchvision's FCN head, the
MobileNetV3-Large backbone with its two taps, and the plain-logits wrapper export and pt2e take."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from edgepick.models.config import ColorSpace, ModelConfig

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


class BackboneAndHead(nn.Module):
    """Preprocess -> backbone (taps 'aux' and 'out') -> classifier on 'out', and aux_classifier on
    'aux' while training; logits upsampled to the input size (torchvision's _SimpleSegmentationModel,
    the frame of its DeepLabV3 and FCN)."""

    def __init__(self, config: ModelConfig, backbone: nn.Module, classifier: nn.Module,
                 aux_classifier: nn.Module | None = None):
        super().__init__()
        self.config = config
        self.preprocess = Preprocess(config.colorspace)
        self.backbone = backbone
        self.classifier = classifier
        self.aux_classifier = aux_classifier

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
