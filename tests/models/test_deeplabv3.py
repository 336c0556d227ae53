import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from edgepick.errors import ConfigError
from edgepick.models import ModelConfig, build_model, deeplabv3_mobilenet_v3_large, deeplabv3_resnet50, deeplabv3_resnet101
from edgepick.models.blocks import rgb_to_hsv
from edgepick.models.zoo import load_backbone_weights

FIXTURE = Path(__file__).parent / "fixtures" / "torchvision_deeplabv3_keys.json"
BUILDERS = {"deeplabv3_mobilenet_v3_large": deeplabv3_mobilenet_v3_large, "deeplabv3_resnet50": deeplabv3_resnet50,
            "deeplabv3_resnet101": deeplabv3_resnet101}


@pytest.mark.parametrize("entry", sorted(json.loads(FIXTURE.read_text())["models"]))
def test_torchvision_state_dict_loads_strict(entry):
    """Key names and shapes recorded from torchvision 0.29.1 load into our builders with strict=True."""
    name, aux = entry.split("/")
    recorded = json.loads(FIXTURE.read_text())["models"][entry]
    model = BUILDERS[name](num_classes=21, aux_loss=aux == "aux=True")
    dtypes = {"torch.float32": torch.float32, "torch.int64": torch.int64}
    state = {k: torch.zeros(shape, dtype=dtypes[dt]) for k, shape, dt in recorded}
    model.load_state_dict(state, strict=True)
    assert list(model.state_dict()) == [k for k, _, _ in recorded]


@pytest.mark.parametrize("arch,stride", [("mobilenetv3", 16), ("mobilenetv3", 8), ("resnet50", 8), ("resnet50", 16)])
def test_output_shape_and_stride(arch, stride):
    model = build_model(ModelConfig(arch, 5, output_stride=stride)).eval()
    x = torch.rand(1, 3, 64, 96) * 255
    with torch.no_grad():
        out = model(x)["out"]
        feats = model.backbone(model.preprocess(x))["out"]
    assert out.shape == (1, 5, 64, 96)
    assert feats.shape[-2:] == (64 // stride, 96 // stride)


def test_aux_head_only_in_training():
    model = build_model(ModelConfig("mobilenetv3", 3, aux_loss=True))
    x = torch.rand(2, 3, 64, 64) * 255
    assert set(model.train()(x)) == {"out", "aux"}
    assert set(model.eval()(x)) == {"out"}


def test_hsv_matches_opencv():
    rgb = np.random.default_rng(0).integers(0, 256, (16, 16, 3), dtype=np.uint8)
    ours = rgb_to_hsv(torch.from_numpy(rgb).permute(2, 0, 1)[None].float() / 255)[0].permute(1, 2, 0).numpy()
    ref = cv2.cvtColor(rgb.astype(np.float32) / 255, cv2.COLOR_RGB2HSV)  # H in degrees
    hue_err = np.abs(ours[..., 0] * 360 - ref[..., 0])
    hue_err = np.minimum(hue_err, 360 - hue_err)
    assert hue_err.max() < 0.1 and np.abs(ours[..., 1:] - ref[..., 1:]).max() < 1e-4


@pytest.mark.parametrize("colorspace", ["rgb", "hsv", "gray"])
def test_colorspaces_run(colorspace):
    model = build_model(ModelConfig("mobilenetv3", 5, colorspace=colorspace)).eval()
    with torch.no_grad():
        out = model(torch.rand(1, 3, 32, 32) * 255)["out"]
    assert torch.isfinite(out).all()


def test_bn_momentum_is_not_torchvisions_001():
    model = build_model(ModelConfig())
    assert all(m.momentum == 0.1 for m in model.modules() if isinstance(m, torch.nn.BatchNorm2d))


def test_backbone_weights_from_file(tmp_path):
    src = build_model(ModelConfig("mobilenetv3", 21))
    path = tmp_path / "tv_classifier.pth"  # a torchvision classifier-style file: features.* keys
    torch.save({f"features.{k}": v + 1.0 if v.is_floating_point() else v
                for k, v in src.backbone.state_dict().items()}, path)
    model = build_model(ModelConfig("mobilenetv3", 5))
    n = load_backbone_weights(model, str(path))
    assert n == len(model.backbone.state_dict())
    k = "0.0.weight"
    assert torch.equal(model.backbone.state_dict()[k], src.backbone.state_dict()[k] + 1.0)


def test_backbone_weights_of_wrong_arch_refused(tmp_path):
    from edgepick.errors import CheckpointError

    path = tmp_path / "r50.pth"
    torch.save(build_model(ModelConfig("resnet50", 5)).backbone.state_dict(), path)
    with pytest.raises(CheckpointError):
        load_backbone_weights(build_model(ModelConfig("mobilenetv3", 5)), str(path))


def test_edge_variant_has_no_se_or_hardswish_and_a_slim_head():
    from edgepick.models.mobilenetv3 import SqueezeExcitation

    standard = build_model(ModelConfig("mobilenetv3", 5))
    edge = build_model(ModelConfig("mobilenetv3", 5, variant="edge"))
    kinds = {type(m) for m in edge.modules()}
    assert SqueezeExcitation not in kinds and torch.nn.Hardswish not in kinds
    assert SqueezeExcitation in {type(m) for m in standard.modules()}
    assert edge.classifier[0].project[0].out_channels == 128 and edge.classifier[4].in_channels == 128
    params = lambda m: sum(p.numel() for p in m.parameters())  # noqa: E731
    assert params(edge) < 0.75 * params(standard)
    assert edge.eval()(torch.rand(1, 3, 64, 96) * 255)["out"].shape == (1, 5, 64, 96)
    with pytest.raises(ConfigError, match="MobileNetV3 variant"):
        build_model(ModelConfig("resnet50", 5, variant="edge"))
