"""Checkpoints: written atomically, carrying everything needed to rebuild and run the model."""

from __future__ import annotations

from pathlib import Path

import torch

from edgepick.errors import CheckpointError
from edgepick.files import atomic_path
from edgepick.models.deeplabv3 import _NORM, DeepLabV3, ModelConfig, build_model


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
    path = Path(path)
    if path.is_dir():  # a RUN folder: take its best checkpoint
        path = path / "best.pt"
    if not path.is_file():
        raise CheckpointError(f"no checkpoint at {path}")
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as exc:  # noqa: BLE001 - a corrupt or foreign file is the user's
        raise CheckpointError(f"cannot read checkpoint {path}: {exc}") from None
    if not isinstance(ckpt, dict) or "model" not in ckpt or "model_config" not in ckpt:
        raise CheckpointError(f"{path} is not an edgepick checkpoint")
    ckpt["path"] = str(path)
    return ckpt


def is_qat_checkpoint(ckpt: dict) -> bool:
    """A QaT run's checkpoint holds a fake-quant graph's state, not a float model's."""
    return "qat" in ckpt or bool(ckpt.get("train_config", {}).get("qat"))  # the latter: older QaT runs


def load_model(path: str | Path) -> tuple[DeepLabV3, dict]:
    """Rebuild the model of a checkpoint (or RUN folder) in eval mode; returns (model, checkpoint)."""
    ckpt = read_checkpoint(path)
    if is_qat_checkpoint(ckpt):
        raise CheckpointError(f"{ckpt['path']} is a QaT checkpoint; use the int8 ONNX its quantize command wrote")
    cfg = ModelConfig(**ckpt["model_config"])
    model = build_model(cfg)
    missing, unexpected = model.load_state_dict(ckpt["model"], strict=False)
    if missing or unexpected:
        raise CheckpointError(f"checkpoint {ckpt['path']} does not fit a {cfg.arch} model "
                              f"({len(missing)} missing, {len(unexpected)} unexpected tensors)")
    return model.eval(), ckpt
