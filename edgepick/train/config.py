"""What a training run is asked to do (`TrainConfig`), checked on creation, recorded in each of
its checkpoints and checked again when read back. No torch: the command line builds its options
and defaults from it."""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, fields
from typing import Any

from edgepick.errors import ParameterError
from edgepick.geometry import Size, check_size
from edgepick.models.config import Arch, ColorSpace, OutputStride, Variant
from edgepick.schema import Where, as_dict, as_list, as_number, as_numbers, as_str, member, plain, refuse_unknown
from edgepick.schema import field as required_field


class Device(enum.StrEnum):
    """Where a run trains: auto is the GPU if there is one, else the CPU."""

    AUTO = "auto"
    CPU = "cpu"
    CUDA = "cuda"


class Augment(enum.StrEnum):
    """Training-time augmentation: basic is photometric jitter, global colour casts, flips and scale;
    lights adds images relit by a dim room and one low coloured lamp (the 'hazard' condition)."""

    BASIC = "basic"
    LIGHTS = "lights"


@dataclass(frozen=True)
class TrainConfig:
    """A training run's settings, each checked on creation (a list of keep_epochs is taken as a tuple)."""

    data: str
    out: str
    arch: Arch = Arch.DEEPLABV3_MOBILENETV3
    variant: Variant = Variant.STANDARD
    epochs: int = 100
    batch_size: int = 8
    lr: float = 1e-3
    weight_decay: float = 1e-4
    size: Size = Size(640, 480)  # the model's input
    colorspace: ColorSpace = ColorSpace.RGB
    output_stride: OutputStride = OutputStride.SIXTEEN
    aux_loss: bool = False
    device: Device = Device.AUTO
    keep_epochs: tuple[int, ...] = ()  # epochs whose checkpoints are kept (hybrid-QaT switch points)
    epoch_images: int = 0  # 0: an epoch is the whole train split; N: N images drawn afresh each epoch
    val_images: int = 0  # 0: validate on the whole val split; N: on N evenly spaced val images
    backbone_weights: str | None = None
    workers: int = -1  # -1: in-memory cache (decoded up front on GPU); 4 workers on GPU if it does not fit
    seed: int = 0
    class_weighting: bool = True
    augment: Augment = Augment.BASIC

    def __post_init__(self) -> None:
        check_size(self.size, "TrainConfig size")
        for name, kind in (("arch", Arch), ("variant", Variant), ("colorspace", ColorSpace), ("device", Device),
                           ("output_stride", OutputStride), ("augment", Augment)):
            object.__setattr__(self, name, member(kind, name, getattr(self, name)))
        object.__setattr__(self, "data", str(self.data))
        object.__setattr__(self, "out", str(self.out))
        object.__setattr__(self, "keep_epochs", tuple(self.keep_epochs))
        for name in ("epochs", "batch_size"):
            if getattr(self, name) < 1:
                raise ParameterError(f"{{{name}}}: must be at least 1", **{name: getattr(self, name)})
        if not (math.isfinite(self.lr) and 0 < self.lr < 1):
            raise ParameterError("{lr}: the learning rate must be a number in (0, 1), e.g. 1e-3", lr=self.lr)
        if not (math.isfinite(self.weight_decay) and self.weight_decay >= 0):
            raise ParameterError("{weight_decay}: must be 0 or more", weight_decay=self.weight_decay)
        for name in ("epoch_images", "val_images"):
            if getattr(self, name) < 0:
                raise ParameterError(f"{{{name}}}: must be 0 (all) or positive", **{name: getattr(self, name)})
        if self.workers < -1:
            raise ParameterError("{workers}: must be -1 (decode once into memory), 0 or more", workers=self.workers)
        if self.seed < 0:
            raise ParameterError("{seed}: must be 0 or positive", seed=self.seed)
        outside = [e for e in self.keep_epochs if not 1 <= e <= self.epochs]
        if outside:
            raise ParameterError(f"{{keep_epochs}}: not an epoch of this run's budget (1..{self.epochs})",
                                 keep_epochs=outside[0])

    def to_dict(self) -> dict:
        """The config as a checkpoint records it (plain values; keep_epochs a list; size as [H, W],
        docs/contracts.md#run-folder)."""
        d = {f.name: plain(getattr(self, f.name)) for f in fields(self) if f.name != "size"}
        d["keep_epochs"] = list(self.keep_epochs)
        d["size"] = list(self.size.hw)
        return d

    @classmethod
    def from_dict(cls, values: dict, where: Where | None = None) -> TrainConfig:
        """The config a checkpoint recorded, each field's type checked (WHERE names the file in errors)."""
        where = where or Where("train_config")
        values = as_dict(values, where)
        refuse_unknown(values, (f.name for f in fields(cls)), where)
        checked: dict[str, Any] = {}
        for f in fields(cls):
            if f.name not in values:
                if f.name in ("data", "out"):
                    required_field(values, f.name, where)  # says which is missing
                continue
            checked[f.name] = _typed(values[f.name], str(f.type), where.at(f.name))
        try:
            return cls(**checked)
        except ParameterError as exc:
            where.fail(str(exc))


CHOICES: dict[str, Any] = {kind.__name__: kind for kind in (Arch, Variant, ColorSpace, OutputStride, Device, Augment)}


def _typed(value: object, kind: str, where: Where) -> object:
    """One recorded TrainConfig field, checked against its annotation."""
    if kind == "str | None" and value is None:
        return None
    if kind in ("str", "str | None"):
        return as_str(value, where)
    if kind == "bool":
        if not isinstance(value, bool):
            where.fail("must be true or false")
        return value
    if kind == "int":
        return as_number(value, where, integer=True)
    if kind == "float":
        return float(as_number(value, where))
    if kind in CHOICES:
        choices = CHOICES[kind]
        if issubclass(choices, enum.IntEnum):
            number = as_number(value, where, integer=True)
            if number not in tuple(choices):
                where.fail(f"must be one of {', '.join(str(m.value) for m in choices)}, got {number!r}")
            return choices(number)
        text = as_str(value, where)
        try:
            return choices(text)  # Arch also takes the names recorded before there were several families
        except ValueError:
            where.fail(f"must be one of {', '.join(choices)}, got {text!r}")
    if kind == "Size":
        return Size.from_hw(as_numbers(value, where, 2, integer=True, minimum=1))
    if kind == "tuple[int, ...]":
        return tuple(as_number(v, where.at(i), integer=True) for i, v in enumerate(as_list(value, where)))
    raise TypeError(f"no check for a TrainConfig field of type {kind}")  # a new field needs one here


def check_world(cfg: TrainConfig, world: int) -> None:
    """What a run's config must also meet under WORLD processes (DDP)."""
    if cfg.epoch_images and world > 1:
        raise ParameterError("{epoch_images} is for single-process runs (DDP shards the whole split)",
                             epoch_images=cfg.epoch_images)
