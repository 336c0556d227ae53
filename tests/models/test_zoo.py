"""edgepick/models/zoo.py and the families it builds: every architecture builds from its config,
gives logits at the input size, loads torchvision's state dicts where torchvision has the model,
and refuses the settings it does not have in one line naming the parameter."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from edgepick.errors import ParameterError
from edgepick.models import Arch, ModelConfig, build_model
from edgepick.models.zoo import BUILDERS, load_backbone_weights

FIXTURE = Path(__file__).parent / "fixtures" / "torchvision_lraspp_fcn_keys.json"


@pytest.mark.parametrize("arch", list(Arch))
def test_every_architecture_gives_logits_at_the_input_size_and_trains(arch):
    torch.manual_seed(0)
    model = build_model(ModelConfig(arch, 5)).train()
    x, y = torch.rand(2, 3, 48, 72) * 255, torch.randint(0, 5, (2, 48, 72))
    out = model(x)["out"]
    assert out.shape == (2, 5, 48, 72)
    loss = torch.nn.functional.cross_entropy(out, y)
    loss.backward()
    grads = [p.grad for p in model.parameters() if p.requires_grad]
    assert torch.isfinite(loss) and all(g is not None and torch.isfinite(g).all() for g in grads)
    with torch.no_grad():
        assert model.eval()(x)["out"].shape == (2, 5, 48, 72)


@pytest.mark.parametrize("entry", sorted(json.loads(FIXTURE.read_text())["models"]))
def test_torchvision_lraspp_and_fcn_state_dicts_load_strict(entry):
    """Key names and shapes recorded from torchvision 0.28.0 load into our builders with strict=True."""
    name, aux = entry.split("/")
    recorded = json.loads(FIXTURE.read_text())["models"][entry]
    extra = {"aux_loss": aux == "aux=True"} if name.startswith("fcn") else {}
    model = BUILDERS[name](num_classes=21, **extra)
    dtypes = {"torch.float32": torch.float32, "torch.int64": torch.int64}
    model.load_state_dict({k: torch.zeros(shape, dtype=dtypes[dt]) for k, shape, dt in recorded}, strict=True)
    assert list(model.state_dict()) == [k for k, _, _ in recorded]


def test_the_builders_take_keywords_only():
    with pytest.raises(TypeError):
        BUILDERS["unet"](5)  # type: ignore[misc]
    assert BUILDERS["ddrnet23_slim"](num_classes=19).config.num_classes == 19


@pytest.mark.parametrize("change, message", [
    ({"arch": "unet", "output_stride": 8}, "output_stride=8: arch='unet' has a fixed output stride"),
    ({"arch": "segnet", "aux_loss": True}, "aux_loss=True: arch='segnet' has no auxiliary head"),
    ({"arch": "lraspp-mobilenetv3", "aux_loss": True}, "has no auxiliary head"),
    ({"arch": "fcn-resnet50", "variant": "edge"}, "the edge variant is a MobileNetV3 variant"),
])
def test_a_setting_an_architecture_does_not_have_is_refused(change, message):
    with pytest.raises(ParameterError, match=message):
        ModelConfig(**change)


def test_the_names_of_runs_made_before_there_were_several_families_still_read():
    assert Arch("mobilenetv3") is Arch.DEEPLABV3_MOBILENETV3 and Arch("resnet50") is Arch.DEEPLABV3_RESNET50
    assert {a.family for a in Arch} == {"deeplabv3", "lraspp", "fcn", "unet", "segnet", "ddrnet"}


def test_backbone_weights_go_where_there_is_a_backbone(tmp_path):
    src = build_model(ModelConfig("lraspp-mobilenetv3", 21))
    path = tmp_path / "backbone.pth"
    torch.save({f"backbone.{k}": v + 1.0 if v.is_floating_point() else v for k, v in src.backbone.state_dict().items()},
               path)
    model = build_model(ModelConfig("lraspp-mobilenetv3", 5))
    assert load_backbone_weights(model, str(path)) == len(model.backbone.state_dict())
    with pytest.raises(ParameterError, match="arch='unet' has no separate backbone"):
        load_backbone_weights(build_model(ModelConfig("unet", 5)), str(path))
