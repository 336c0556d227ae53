"""Helpers shared by the benchmark scripts (run as `python benchmarks/NAME.py`)."""

from __future__ import annotations

from pathlib import Path


def untrained_checkpoint(path: Path, size: tuple[int, int], classes: list[str], variant: str = "standard") -> Path:
    """A seeded, untrained default model (DeepLabV3-MobileNetV3) as a checkpoint: latency does
    not depend on the weights, so speed benchmarks need no training run."""
    import torch

    from edgepick.models.deeplabv3 import ModelConfig, build_model
    from edgepick.train.checkpoint import model_meta

    torch.manual_seed(0)
    cfg = ModelConfig(num_classes=len(classes), variant=variant)
    torch.save({"model": build_model(cfg).state_dict(), "train_time_s": 0.0, **model_meta(cfg, classes, size)}, path)
    return path


def emit(report: str, out: str | None) -> None:
    """Print a Markdown report, and write it to OUT when given."""
    print(report)
    if out:
        Path(out).write_text(report)
