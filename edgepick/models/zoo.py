"""The model families by name: `build_model` for a ModelConfig, the torchvision-style builders, and
backbone weights for the families that have a backbone."""

from __future__ import annotations

import torch
from torch import nn

from edgepick.errors import CheckpointError, ParameterError
from edgepick.models.config import ModelConfig
from edgepick.models.ddrnet import DDRNet, ddrnet23_slim
from edgepick.models.deeplabv3 import (
    build_deeplabv3,
    deeplabv3_mobilenet_v3_large,
    deeplabv3_resnet50,
    deeplabv3_resnet101,
)
from edgepick.models.fcn import build_fcn, fcn_resnet50, fcn_resnet101
from edgepick.models.lraspp import LRASPP, lraspp_mobilenet_v3_large
from edgepick.models.seg_net import SegNet, segnet
from edgepick.models.u_net import UNet, unet

BUILDERS = {"deeplabv3_mobilenet_v3_large": deeplabv3_mobilenet_v3_large, "deeplabv3_resnet50": deeplabv3_resnet50,
            "deeplabv3_resnet101": deeplabv3_resnet101, "lraspp_mobilenet_v3_large": lraspp_mobilenet_v3_large,
            "fcn_resnet50": fcn_resnet50, "fcn_resnet101": fcn_resnet101, "unet": unet, "segnet": segnet,
            "ddrnet23_slim": ddrnet23_slim}
FAMILIES = {"deeplabv3": build_deeplabv3, "fcn": build_fcn, "lraspp": LRASPP, "unet": UNet, "segnet": SegNet,
            "ddrnet": DDRNet}


def build_model(config: ModelConfig) -> nn.Module:
    """The model a config describes, with fresh weights: it takes float RGB in [0, 255], NCHW, and
    returns {"out": logits at the input size} (and "aux" while training, where it has that head)."""
    return FAMILIES[config.arch.family](config)


def load_backbone_weights(model: nn.Module, path: str) -> int:
    """Load backbone weights from a file: a torchvision classification or segmentation state dict.

    Accepts keys prefixed `backbone.` (segmentation), `features.` (MobileNetV3 classifier) or
    bare ResNet keys; returns the number of tensors loaded. Shape mismatches are an error.
    """
    backbone = getattr(model, "backbone", None)
    if backbone is None:
        raise ParameterError("{backbone_weights}: {arch} has no separate backbone to load weights into",
                             backbone_weights=path, arch=model.config.arch)
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - any unreadable file is the user's
        raise CheckpointError(f"cannot read backbone weights {path}: {exc}") from None
    state = state.get("model", state) if isinstance(state, dict) else state
    if not isinstance(state, dict) or not all(isinstance(k, str) and torch.is_tensor(v) for k, v in state.items()):
        raise CheckpointError(f"{path} is not a state dict (parameter names to tensors), so it holds no backbone "
                              "weights")
    target = backbone.state_dict()
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
    backbone.load_state_dict(picked, strict=False)
    return len(picked)
