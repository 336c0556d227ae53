"""Checkpoints: written atomically, carrying everything needed to rebuild and run the model."""

from __future__ import annotations

from dataclasses import fields
from pathlib import Path

import torch

from edgepick.errors import CheckpointError, ConfigError
from edgepick.files import atomic_path
from edgepick.models.deeplabv3 import _NORM, ARCHS, COLORSPACES, VARIANTS, DeepLabV3, ModelConfig, build_model
from edgepick.schema import Where, as_dict, as_list, as_names, as_number, as_numbers, as_str, field


def save_atomic(obj: dict, path: str | Path) -> None:
    """torch.save to a temporary file beside PATH, then rename: a kill never leaves half a file."""
    with atomic_path(path) as tmp:
        torch.save(obj, tmp)


def model_meta(model_cfg: ModelConfig, classes: list[str], input_size: tuple[int, int]) -> dict:
    """What a checkpoint says about its model: arch, classes, input size, colour space, normalisation."""
    mean, std = _NORM[model_cfg.colorspace]
    return {"model_config": model_cfg.to_dict(), "classes": list(classes), "input_size": list(input_size),
            "colorspace": model_cfg.colorspace, "normalisation": {"mean": mean, "std": std, "input_range": 255}}


def read_checkpoint(path: str | Path) -> dict:
    """A checkpoint (or a RUN folder's best.pt), its description checked (check_checkpoint)."""
    path = Path(path)
    if path.is_dir():  # a RUN folder: take its best checkpoint
        path = path / "best.pt"
    if not path.is_file():
        raise CheckpointError(f"no checkpoint at {path}")
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as exc:  # noqa: BLE001 - a corrupt or foreign file is the user's
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise CheckpointError(f"cannot read checkpoint {path}: {first}") from None
    if not isinstance(ckpt, dict) or "model" not in ckpt or "model_config" not in ckpt:
        raise CheckpointError(f"{path} is not an edgepick checkpoint")
    check_checkpoint(ckpt, Where(str(path)))
    ckpt["path"] = str(path)
    return ckpt


def check_model_config(value: object, where: Where) -> ModelConfig:
    """A checkpoint's model_config: every field typed and in range."""
    mc = as_dict(value, where)
    unknown = sorted(set(mc) - {f.name for f in fields(ModelConfig)})
    if unknown:
        where.fail(f"has unknown fields {', '.join(map(str, unknown))}")
    checked = {
        "arch": as_str(field(mc, "arch", where), where.at("arch"), ARCHS),
        "num_classes": as_number(field(mc, "num_classes", where), where.at("num_classes"), integer=True, minimum=2,
                                 maximum=255),
        "output_stride": as_number(mc.get("output_stride", 16), where.at("output_stride"), integer=True),
        "colorspace": as_str(mc.get("colorspace", "rgb"), where.at("colorspace"), COLORSPACES),
        "aux_loss": mc.get("aux_loss", False),
        "bn_momentum": as_number(mc.get("bn_momentum", 0.1), where.at("bn_momentum"), above=0, maximum=1),
        "variant": as_str(mc.get("variant", "standard"), where.at("variant"), VARIANTS),
    }
    if not isinstance(checked["aux_loss"], bool):
        where.at("aux_loss").fail("must be true or false")
    try:
        return ModelConfig(**checked).validate()
    except ConfigError as exc:
        where.fail(str(exc))


def check_checkpoint(ckpt: dict, where: Where) -> None:
    """What the passes read from a checkpoint, checked: the model's config, its state dict, the
    class names (one per output class), the input size (H, W: multiples of 8, at least 32, the
    backbone's stride), the colour space and, when present, the epoch and training time."""
    cfg = check_model_config(ckpt["model_config"], where.at("model_config"))
    if not isinstance(ckpt["model"], dict) or not all(torch.is_tensor(v) for v in ckpt["model"].values()):
        where.at("model").fail("must be a state dict (parameter names to tensors)")
    classes = as_names(field(ckpt, "classes", where), where.at("classes"), min_length=2)
    if len(classes) != cfg.num_classes:
        where.at("classes").fail(f"names {len(classes)} classes but the model has {cfg.num_classes}")
    h, w = as_numbers(field(ckpt, "input_size", where), where.at("input_size"), 2, integer=True, minimum=32,
                      maximum=4096)
    if h % 8 or w % 8:
        where.at("input_size").fail(f"{w}x{h} (WIDTHxHEIGHT) must have sides that are multiples of 8 (the "
                                    "backbone's stride)")
    if as_str(field(ckpt, "colorspace", where), where.at("colorspace"), COLORSPACES) != cfg.colorspace:
        where.at("colorspace").fail(f"is {ckpt['colorspace']!r} but model_config says {cfg.colorspace!r}")
    if "epoch" in ckpt:
        as_number(ckpt["epoch"], where.at("epoch"), integer=True, minimum=0)
    if "train_time_s" in ckpt:
        as_number(ckpt["train_time_s"], where.at("train_time_s"), minimum=0)
    if "history" in ckpt:
        for i, record in enumerate(as_list(ckpt["history"], where.at("history"))):
            as_dict(record, where.at("history").at(i))
    if "train_config" in ckpt:
        as_dict(ckpt["train_config"], where.at("train_config"))


def is_qat_checkpoint(ckpt: dict) -> bool:
    """A QaT run's checkpoint holds a fake-quant graph's state, not a float model's."""
    return "qat" in ckpt or bool((ckpt.get("train_config") or {}).get("qat"))  # the latter: older QaT runs


def load_model(path: str | Path) -> tuple[DeepLabV3, dict]:
    """Rebuild the model of a checkpoint (or RUN folder) in eval mode; returns (model, checkpoint)."""
    ckpt = read_checkpoint(path)
    if is_qat_checkpoint(ckpt):
        raise CheckpointError(f"{ckpt['path']} is a QaT checkpoint; use the int8 ONNX its quantize command wrote")
    cfg = ModelConfig(**ckpt["model_config"])  # checked by read_checkpoint
    model = build_model(cfg)
    missing, unexpected = model.load_state_dict(ckpt["model"], strict=False)
    if missing or unexpected:
        raise CheckpointError(f"checkpoint {ckpt['path']} does not fit a {cfg.arch} model "
                              f"({len(missing)} missing, {len(unexpected)} unexpected tensors)")
    return model.eval(), ckpt
