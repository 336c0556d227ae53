"""What a training run is asked to do (`TrainConfig`), recorded in each of its checkpoints and
checked when read back."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields

from edgepick.errors import ConfigError
from edgepick.geometry import Size, check_size
from edgepick.schema import Where, as_dict, as_list, as_number, as_numbers, as_str
from edgepick.schema import field as required_field


@dataclass
class TrainConfig:
    data: str
    out: str
    arch: str = "mobilenetv3"
    variant: str = "standard"  # edge: MobileNetV3 without SE/hardswish, 128-channel ASPP (quantization-friendly)
    epochs: int = 100
    batch_size: int = 8
    lr: float = 1e-3
    weight_decay: float = 1e-4
    size: Size = Size(640, 480)  # the model's input
    colorspace: str = "rgb"
    output_stride: int = 16
    aux_loss: bool = False
    device: str = "auto"
    keep_epochs: list[int] = field(default_factory=list)
    epoch_images: int = 0  # 0: an epoch is the whole train split; N: N images drawn afresh each epoch
    val_images: int = 0  # 0: validate on the whole val split; N: on N evenly spaced val images
    backbone_weights: str | None = None
    workers: int = -1  # -1: in-memory cache (decoded up front on GPU); 4 workers on GPU if it does not fit
    seed: int = 0
    class_weighting: bool = True

    def __post_init__(self) -> None:
        check_size(self.size, "TrainConfig size")

    def to_dict(self) -> dict:
        """The form a checkpoint records (plain types; size as [H, W], docs/contracts.md#run-folder)."""
        d = asdict(self)
        d["size"] = list(self.size.hw)
        return d

    @classmethod
    def from_dict(cls, values: dict, where: Where | None = None) -> "TrainConfig":
        """The config a checkpoint recorded, each field's type checked (WHERE names the file in errors)."""
        where = where or Where("train_config")
        values = as_dict(values, where)
        unknown = sorted(set(values) - {f.name for f in fields(cls)})
        if unknown:
            where.fail(f"has unknown fields {', '.join(map(str, unknown))}")
        checked = {}
        for f in fields(cls):
            if f.name not in values:
                if f.name in ("data", "out"):
                    required_field(values, f.name, where)  # says which is missing
                continue
            checked[f.name] = _typed(values[f.name], f.type, where.at(f.name))
        return cls(**checked)


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
    if kind == "Size":
        return Size.from_hw(as_numbers(value, where, 2, integer=True, minimum=1))
    if kind == "list[int]":
        return [as_number(v, where.at(i), integer=True) for i, v in enumerate(as_list(value, where))]
    raise TypeError(f"no check for a TrainConfig field of type {kind}")  # a new field needs one here


def check_config(cfg: TrainConfig, world: int = 1) -> None:
    if cfg.epochs < 1 or cfg.batch_size < 1:
        raise ConfigError("--epochs and --batch-size must be at least 1")
    if not (math.isfinite(cfg.lr) and 0 < cfg.lr < 1):
        raise ConfigError(f"--lr {cfg.lr}: the learning rate must be a number in (0, 1), e.g. 1e-3")
    if cfg.epoch_images < 0 or cfg.val_images < 0:
        raise ConfigError("--epoch-images and --val-images must be 0 (all) or positive")
    if cfg.epoch_images and world > 1:
        raise ConfigError("--epoch-images is for single-process runs (DDP shards the whole split)")
    if cfg.seed < 0:
        raise ConfigError(f"--seed {cfg.seed}: must be 0 or positive")
    outside = [e for e in cfg.keep_epochs if not 1 <= e <= cfg.epochs]
    if outside:
        raise ConfigError(f"--keep-epochs {outside[0]}: not an epoch of this run's budget (1..{cfg.epochs})")
