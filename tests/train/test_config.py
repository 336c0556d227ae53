"""edgepick/train/config.py: a TrainConfig is checked when it is made, names the parameter at
fault, cannot be changed afterwards, and records plain values that read back the same."""

from __future__ import annotations

import dataclasses
import json

import pytest

from edgepick.errors import ParameterError
from edgepick.models.config import Arch, OutputStride
from edgepick.schema import FileContentError, Where
from edgepick.train.config import Augment, Device, TrainConfig, check_world


def test_a_config_is_frozen_and_takes_a_list_of_kept_epochs_as_a_tuple():
    cfg = TrainConfig(data="d", out="r", epochs=10, keep_epochs=[9, 5], device="cpu", output_stride=8)
    assert cfg.keep_epochs == (9, 5) and cfg.device is Device.CPU and cfg.output_stride is OutputStride.EIGHT
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.epochs = 20  # type: ignore[misc]
    assert dataclasses.replace(cfg, epochs=20).epochs == 20


@pytest.mark.parametrize("change, message", [
    ({"epochs": 0}, "epochs=0: must be at least 1"),
    ({"batch_size": 0}, "batch_size=0: must be at least 1"),
    ({"lr": float("nan")}, "lr=nan: the learning rate must be a number in (0, 1)"),
    ({"lr": 1.5}, "lr=1.5: the learning rate"),
    ({"epoch_images": -1}, "epoch_images=-1: must be 0 (all) or positive"),
    ({"val_images": -2}, "val_images=-2: must be 0 (all) or positive"),
    ({"seed": -1}, "seed=-1: must be 0 or positive"),
    ({"workers": -2}, "workers=-2: must be -1"),
    ({"epochs": 2, "keep_epochs": [2, 5]}, "keep_epochs=5: not an epoch of this run's budget (1..2)"),
    ({"arch": "vgg"}, "arch='vgg': must be one of deeplabv3-mobilenetv3, deeplabv3-resnet50, deeplabv3-resnet101, "
                          "lraspp-mobilenetv3, fcn-resnet50, fcn-resnet101, unet, segnet, ddrnet23-slim"),
    ({"device": "tpu"}, "device='tpu': must be one of auto, cpu, cuda"),
    ({"output_stride": 4}, "output_stride=4: must be one of 8, 16"),
    ({"augment": "hazard"}, "augment='hazard': must be one of basic, lights"),
])
def test_a_bad_value_is_refused_on_creation_naming_the_parameter(change, message):
    with pytest.raises(ParameterError) as info:
        TrainConfig(data="d", out="r", **change)
    assert str(info.value).startswith(message), str(info.value)
    assert not any(word.startswith("--") for word in str(info.value).split())


def test_what_a_checkpoint_records_is_plain_and_reads_back_equal():
    cfg = TrainConfig(data="d", out="r", arch="deeplabv3-resnet50", keep_epochs=[3], device=Device.CUDA)
    recorded = cfg.to_dict()
    assert recorded["arch"] == "deeplabv3-resnet50" and type(recorded["arch"]) is str and type(recorded["output_stride"]) is int
    assert recorded["keep_epochs"] == [3] and json.loads(json.dumps(recorded))["device"] == "cuda"
    again = TrainConfig.from_dict(recorded)
    assert again == cfg and again.arch is Arch.DEEPLABV3_RESNET50


def test_a_recorded_value_out_of_range_is_one_line_naming_the_file():
    with pytest.raises(FileContentError, match=r"^run/last\.pt: train_config epochs=0: must be at least 1$"):
        TrainConfig.from_dict({"data": "d", "out": "r", "epochs": 0}, Where("run/last.pt", "train_config"))
    with pytest.raises(FileContentError, match=r"train_config\.device must be one of auto, cpu, cuda, got 'tpu'"):
        TrainConfig.from_dict({"data": "d", "out": "r", "device": "tpu"}, Where("run/last.pt", "train_config"))


def test_epoch_images_is_for_single_process_runs():
    cfg = TrainConfig(data="d", out="r", epoch_images=100)
    check_world(cfg, 1)
    with pytest.raises(ParameterError, match=r"epoch_images=100 is for single-process runs"):
        check_world(cfg, 2)


def test_a_run_recorded_before_there_were_several_families_reads_as_deeplabv3():
    recorded = TrainConfig(data="d", out="r").to_dict()
    for old, arch in (("mobilenetv3", Arch.DEEPLABV3_MOBILENETV3), ("resnet101", Arch.DEEPLABV3_RESNET101)):
        assert TrainConfig.from_dict({**recorded, "arch": old}).arch is arch


def test_a_run_recorded_before_augment_was_a_setting_reads_as_basic():
    recorded = TrainConfig(data="d", out="r", augment="lights").to_dict()
    assert recorded["augment"] == "lights" and TrainConfig.from_dict(recorded).augment is Augment.LIGHTS
    del recorded["augment"]
    assert TrainConfig.from_dict(recorded).augment is Augment.BASIC
