"""Checkpoints (docs/contracts.md#run-folder): what a run saves after each epoch, written
atomically and read back checked, so that every later stage reads typed fields, not dict keys."""

from __future__ import annotations

import re
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import torch
from torch import nn

from edgepick.errors import CheckpointError, ConfigError
from edgepick.files import atomic_path
from edgepick.geometry import Size, check_size
from edgepick.models.blocks import NORMALISATION
from edgepick.models.config import Arch, ColorSpace, ModelConfig, Variant
from edgepick.models.zoo import build_model
from edgepick.schema import Where, as_dict, as_list, as_names, as_number, as_numbers, as_str, refuse_unknown
from edgepick.schema import field as required_field
from edgepick.train.config import TrainConfig
from edgepick.train.run import checkpoint_path


@dataclass(frozen=True)
class Checkpoint:
    """One epoch of a run: the model and what rebuilds it, the run's config and bookkeeping."""

    model_config: ModelConfig
    classes: tuple[str, ...]
    input_size: Size  # the model's input
    model: dict = field(repr=False, compare=False)  # the state dict: a float model's or a QaT run's graph's
    train_config: TrainConfig | None = None
    epoch: int = 0
    history: tuple[dict, ...] = ()  # one record per epoch (loss, pixel accuracy, mIoU, timings)
    train_time_s: float = 0.0  # wall time up to this epoch, the float phase of a continued run included
    best_miou: float = -1.0  # the run's best validation mIoU so far
    phase_start: int = 0  # the epoch this run's own training started after (a continued run's switch point)
    init_train_time_s: float = 0.0  # the wall time of the run it continued (hybrid-QaT's float phase)
    world_size: int = 1
    data_image_size: Size | None = None  # the data set's images
    qat: dict | None = None  # a QaT run's record: its QuantConfig, freeze_at, calibration images, held ranges
    optimizer: dict | None = field(default=None, repr=False, compare=False)  # AdamW's (last.pt, kept epochs)
    scheduler: dict | None = field(default=None, repr=False, compare=False)
    path: Path | None = field(default=None, compare=False)  # where it was read from

    def __post_init__(self) -> None:
        check_size(self.input_size, "Checkpoint input_size")
        if self.data_image_size is not None:
            check_size(self.data_image_size, "Checkpoint data_image_size")

    @property
    def colorspace(self) -> ColorSpace:
        return self.model_config.colorspace

    @property
    def normalisation(self) -> dict:
        """What the model does to its [0, 255] input inside the graph: per-channel mean and std of [0, 1]."""
        mean, std = NORMALISATION[self.colorspace]
        return {"mean": mean, "std": std, "input_range": 255}

    @property
    def is_qat(self) -> bool:
        return self.qat is not None

    def to_dict(self) -> dict:
        """The file's content (plain types and tensors)."""
        d = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "path"}
        d["model_config"] = self.model_config.to_dict()
        d["train_config"] = self.train_config.to_dict() if self.train_config is not None else None
        d["classes"], d["input_size"], d["history"] = list(self.classes), list(self.input_size.hw), list(self.history)
        d["data_image_size"] = list(self.data_image_size.hw) if self.data_image_size else None
        return d

    def save(self, path: str | Path) -> None:
        """torch.save to a temporary file beside PATH, then rename: a kill never leaves half a file."""
        with atomic_path(path) as tmp:
            torch.save(self.to_dict(), tmp)

    def without_optimizer(self) -> Checkpoint:
        """The weights and bookkeeping only: what export and the passes need, a third of the size."""
        return replace(self, optimizer=None, scheduler=None)

    @classmethod
    def load(cls, path: str | Path) -> Checkpoint:
        """A checkpoint file (or a RUN folder's best.pt), every field checked once, here."""
        path = checkpoint_path(path)
        if not path.is_file():
            raise CheckpointError(f"no checkpoint at {path}")
        try:
            d = torch.load(path, map_location="cpu", weights_only=False)
        except Exception as exc:  # noqa: BLE001 - a corrupt or foreign file is the user's
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise CheckpointError(f"cannot read checkpoint {path}: {first}") from None
        if not isinstance(d, dict) or "model" not in d or "model_config" not in d:
            raise CheckpointError(f"{path} is not an edgepick checkpoint")
        return replace(_checked(d, Where(str(path))), path=path)

    def build_model(self) -> nn.Module:
        """The float model of this checkpoint, in eval mode."""
        if self.is_qat:
            raise CheckpointError(f"{self.path} is a QaT checkpoint; use the int8 ONNX its quantize command wrote")
        model = build_model(self.model_config)
        load_weights(model, self.model, self)
        return model.eval()


_SIZE_MISMATCH = re.compile(r"size mismatch for (\S+?):")


def load_weights(module: nn.Module, state: dict, ckpt: Checkpoint) -> None:
    """Load STATE (CKPT's weights, or a subset of them) into MODULE, every tensor matching by name and
    shape; a checkpoint that does not fit is a CheckpointError naming the file, the architecture it
    records and the first tensor that does not fit, never torch's RuntimeError and its list of every
    tensor. Shapes are compared by load_state_dict itself: a fake-quant graph resizes its own scale
    and zero-point buffers to the state it is given, which a comparison beforehand would refuse."""
    try:
        module.load_state_dict(state)
    except RuntimeError as exc:
        raise CheckpointError(f"checkpoint {ckpt.path} does not fit a {ckpt.model_config.arch} model with "
                              f"{ckpt.model_config.num_classes} classes: {_first_misfit(module, state, str(exc))}") \
            from None


def _first_misfit(module: nn.Module, state: dict, message: str) -> str:
    """The first tensor of STATE that MODULE cannot take, in words, from load_state_dict's MESSAGE."""
    own = module.state_dict()
    size = _SIZE_MISMATCH.search(message)
    if size and size.group(1) in own and size.group(1) in state:
        name, more = size.group(1), message.count("size mismatch for") - 1
        return (f"{name} has shape {list(state[name].shape)} in the file, {list(own[name].shape)} in the model"
                + (f" ({more} more of another shape)" if more else ""))
    missing, unexpected = [k for k in own if k not in state], [k for k in state if k not in own]
    counts = f" ({len(missing)} missing, {len(unexpected)} unexpected tensors)"
    if missing:
        return f"the file has no tensor {missing[0]}{counts}"
    if unexpected:
        return f"the model has no tensor {unexpected[0]}{counts}"
    lines = [line.strip() for line in message.splitlines() if line.strip()]
    return lines[-1] if lines else "load_state_dict refused its tensors"


def load_model(path: str | Path) -> tuple[nn.Module, Checkpoint]:
    """The float model of a checkpoint (or RUN folder) in eval mode, and the checkpoint."""
    ckpt = Checkpoint.load(path)
    return ckpt.build_model(), ckpt


def check_model_config(value: object, where: Where) -> ModelConfig:
    """A checkpoint's model_config: every field typed and in range."""
    mc = as_dict(value, where)
    refuse_unknown(mc, (f.name for f in fields(ModelConfig)), where)
    checked: dict[str, Any] = {
        "arch": _arch(required_field(mc, "arch", where), where.at("arch")),
        "num_classes": as_number(required_field(mc, "num_classes", where), where.at("num_classes"), integer=True,
                                 minimum=2, maximum=255),
        "output_stride": as_number(mc.get("output_stride", 16), where.at("output_stride"), integer=True),
        "colorspace": as_str(mc.get("colorspace", "rgb"), where.at("colorspace"), tuple(ColorSpace)),
        "aux_loss": _flag(mc.get("aux_loss", False), where.at("aux_loss")),
        "bn_momentum": as_number(mc.get("bn_momentum", 0.1), where.at("bn_momentum"), above=0, maximum=1),
        "variant": as_str(mc.get("variant", "standard"), where.at("variant"), tuple(Variant)),
    }
    try:
        return ModelConfig(**checked)
    except ConfigError as exc:
        where.fail(str(exc))


def _arch(value: object, where: Where) -> Arch:
    """A recorded architecture, the names of runs made before there were several families included."""
    name = as_str(value, where)
    try:
        return Arch(name)
    except ValueError:
        where.fail(f"must be one of {', '.join(Arch)}, got {name!r}")


def _flag(value: object, where: Where) -> bool:
    if not isinstance(value, bool):
        where.fail("must be true or false")
    return value


def _optional_dict(d: dict, key: str, where: Where) -> dict | None:
    return None if d.get(key) is None else as_dict(d[key], where.at(key))


def _size(value: object, where: Where, minimum: int = 1) -> Size:
    """A recorded [H, W] size."""
    return Size.from_hw(as_numbers(value, where, 2, integer=True, minimum=minimum, maximum=8192))


def _checked(d: dict, where: Where) -> Checkpoint:
    """A Checkpoint from a file's dict: the model's config, its state dict, one class name per output
    class, the input size (H, W: multiples of 8, at least 32, the backbone's stride), and the run's
    config and bookkeeping when present. A field edgepick does not write is refused."""
    refuse_unknown(d, {f.name for f in fields(Checkpoint)} - {"path"}, where)
    cfg = check_model_config(d["model_config"], where.at("model_config"))
    if not isinstance(d["model"], dict) or not all(torch.is_tensor(v) for v in d["model"].values()):
        where.at("model").fail("must be a state dict (parameter names to tensors)")
    classes = as_names(required_field(d, "classes", where), where.at("classes"), min_length=2)
    if len(classes) != cfg.num_classes:
        where.at("classes").fail(f"names {len(classes)} classes but the model has {cfg.num_classes}")
    input_size = _size(required_field(d, "input_size", where), where.at("input_size"), minimum=32)
    if input_size.width % 8 or input_size.height % 8:
        where.at("input_size").fail(f"{input_size} (WIDTHxHEIGHT) must have sides that are multiples of 8 (the "
                                    "backbone's stride)")
    train_config = d.get("train_config")
    image_size = d.get("data_image_size")
    return Checkpoint(
        model_config=cfg, classes=tuple(classes), input_size=input_size, model=d["model"],
        train_config=TrainConfig.from_dict(train_config, where.at("train_config")) if train_config is not None
        else None,
        epoch=as_number(d.get("epoch", 0), where.at("epoch"), integer=True, minimum=0),
        history=tuple(as_dict(r, where.at("history").at(i))
                      for i, r in enumerate(as_list(d.get("history", []), where.at("history")))),
        train_time_s=float(as_number(d.get("train_time_s", 0.0), where.at("train_time_s"), minimum=0)),
        best_miou=float(as_number(d.get("best_miou", -1.0), where.at("best_miou"), minimum=-1, maximum=1)),
        phase_start=as_number(d.get("phase_start", 0), where.at("phase_start"), integer=True, minimum=0),
        init_train_time_s=float(as_number(d.get("init_train_time_s", 0.0), where.at("init_train_time_s"), minimum=0)),
        world_size=as_number(d.get("world_size", 1), where.at("world_size"), integer=True, minimum=1),
        data_image_size=_size(image_size, where.at("data_image_size")) if image_size is not None else None,
        qat=_optional_dict(d, "qat", where), optimizer=_optional_dict(d, "optimizer", where),
        scheduler=_optional_dict(d, "scheduler", where))
