"""edgepick/train/checkpoint.py: a checkpoint's description is checked when it is read, so that a
bogus or foreign file is one line naming the field, whatever it holds."""

from __future__ import annotations

import copy

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

torch = pytest.importorskip("torch")

from edgepick.errors import EdgepickError  # noqa: E402
from edgepick.geometry import Size  # noqa: E402
from edgepick.train.checkpoint import Checkpoint  # noqa: E402
from tests.test_schema import _paths, json_values  # noqa: E402

GOOD = {"model": {"backbone.0.0.weight": torch.zeros(2, 3, 1, 1)},
        "model_config": {"arch": "mobilenetv3", "num_classes": 3, "output_stride": 16, "colorspace": "rgb",
                         "aux_loss": False, "bn_momentum": 0.1, "variant": "standard"},
        "classes": ["background", "a", "b"], "input_size": [96, 128], "epoch": 3,
        "history": [{"epoch": 1, "miou": 0.5}], "train_time_s": 12.5,
        "train_config": {"data": "d", "out": "r", "epochs": 10, "size": [96, 128], "lr": 0.001, "keep_epochs": [9]}}


@st.composite
def mutated_checkpoint(draw):
    ckpt = copy.deepcopy(GOOD)
    path = draw(st.sampled_from([p for p in _paths({k: v for k, v in ckpt.items() if k != "model"}) if p]))
    parent = ckpt
    for key in path[:-1]:
        parent = parent[key]
    if draw(st.booleans()):
        del parent[path[-1]]
    else:
        parent[path[-1]] = draw(json_values)
    return ckpt


def test_a_good_checkpoint_reads_and_its_train_config_too(tmp_path):
    torch.save(GOOD, tmp_path / "c.pt")
    ckpt = Checkpoint.load(tmp_path / "c.pt")
    assert ckpt.path == tmp_path / "c.pt" and ckpt.classes == ("background", "a", "b") and ckpt.epoch == 3
    assert ckpt.train_config.size == Size(128, 96) and ckpt.train_config.keep_epochs == (9,)
    assert ckpt.input_size == Size(128, 96)
    ckpt.save(tmp_path / "again.pt")
    saved = torch.load(tmp_path / "again.pt", weights_only=False)  # the file keeps [H, W] (docs/contracts.md#run-folder)
    assert saved["input_size"] == [96, 128] and saved["train_config"]["size"] == [96, 128]
    again = Checkpoint.load(tmp_path / "again.pt")  # what save writes, load reads back the same
    assert again == ckpt and again.model.keys() == ckpt.model.keys()
    assert all(torch.equal(again.model[k], v) for k, v in ckpt.model.items())


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(ckpt=mutated_checkpoint())
def test_any_mutated_description_reads_or_is_one_line(tmp_path, ckpt):
    torch.save(ckpt, tmp_path / "c.pt")
    try:
        Checkpoint.load(tmp_path / "c.pt")
    except EdgepickError as exc:
        assert "\n" not in str(exc) and str(exc).strip(), str(exc)


@pytest.mark.parametrize("change, message", [
    ({"input_size": [31, 33]}, "input_size[0] must be 32 or more"),
    ({"input_size": [36, 44]}, "44x36 (WIDTHxHEIGHT) must have sides that are multiples of 8"),
    ({"input_size": [96.5, 128]}, "input_size[0] must be a whole number"),
    ({"classes": "abc"}, "classes must be a list"),
    ({"model_config": {**GOOD["model_config"], "arch": "vgg"}}, "model_config.arch must be one of"),
    ({"model": [1]}, "model must be a state dict"),
    ({"colorspace": "rgb"}, "has unknown fields colorspace"),
    ({"train_config": {**GOOD["train_config"], "quant": {}}}, "train_config has unknown fields quant"),
    ({"model_config": {**GOOD["model_config"], "\n": None}}, "model_config has unknown fields '\\n'"),
    ({"model_config": {**GOOD["model_config"], " x": 1, 5: 1}}, "model_config has unknown fields ' x', 5"),
])
def test_the_field_at_fault_is_named(tmp_path, change, message):
    torch.save({**GOOD, **change}, tmp_path / "c.pt")
    with pytest.raises(EdgepickError) as info:
        Checkpoint.load(tmp_path / "c.pt")
    assert message in str(info.value) and str(info.value).startswith(str(tmp_path / "c.pt"))


def test_sizes_are_size_objects_and_a_tuple_is_refused():
    """The Python API takes Size(width, height); a bare tuple (whose order would be a guess) is one line."""
    from edgepick.errors import ConfigError
    from edgepick.models.config import ModelConfig
    from edgepick.train.config import TrainConfig

    assert TrainConfig(data="d", out="r").size == Size(640, 480)
    with pytest.raises(ConfigError, match=r"TrainConfig size must be a Size\(width, height\)"):
        TrainConfig(data="d", out="r", size=(480, 640))
    cfg = TrainConfig(data="d", out="r", size=Size(128, 96))
    assert cfg.to_dict()["size"] == [96, 128] and TrainConfig.from_dict(cfg.to_dict()) == cfg
    with pytest.raises(ConfigError, match=r"Checkpoint input_size must be a Size\(width, height\)"):
        Checkpoint(model_config=ModelConfig(num_classes=3), classes=("a", "b", "c"), input_size=(96, 128), model={})


def test_a_saved_checkpoint_holds_plain_values_that_read_back_as_the_configs(tmp_path):
    """The configs' choices (enums) are written as their strings and numbers: the file loads with
    torch's weights_only unpickler, which refuses every class of edgepick's, and reads back equal."""
    from edgepick.models.config import ModelConfig
    from edgepick.train.config import TrainConfig

    tc = TrainConfig(data="d", out="r", epochs=10, size=Size(128, 96), keep_epochs=[9], device="cpu", output_stride=8)
    ckpt = Checkpoint(model_config=ModelConfig("deeplabv3-resnet50", 3, 8, "hsv"), classes=("background", "a", "b"),
                      input_size=Size(128, 96), model=dict(GOOD["model"]), train_config=tc)
    ckpt.save(tmp_path / "c.pt")
    d = torch.load(tmp_path / "c.pt", weights_only=True)
    assert d["model_config"]["arch"] == "deeplabv3-resnet50" and type(d["model_config"]["arch"]) is str
    assert type(d["train_config"]["device"]) is str and type(d["train_config"]["output_stride"]) is int
    assert d["train_config"]["keep_epochs"] == [9] and d["train_config"]["size"] == [96, 128]
    again = Checkpoint.load(tmp_path / "c.pt")
    assert again.model_config == ckpt.model_config and again.train_config == tc
