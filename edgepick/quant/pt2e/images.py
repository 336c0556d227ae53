"""The images the torch passes take from a native data set: calibration images drawn from a split
(or with a float run's own seed, for hybrid-QaT),
the val images each pass compares onnxruntime's labels with torch's on, and the checks that a data
set fits the request and the checkpoint."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from edgepick.data.native import NativeDataset
from edgepick.errors import CheckpointError, ConfigError, ParameterError
from edgepick.geometry import Size
from edgepick.quant.config import DEFAULT_CALIB_IMAGES
from edgepick.quant.pt2e.graph import at_input_size
from edgepick.train.checkpoint import Checkpoint
from edgepick.train.run import Run

AGREEMENT_IMAGES = 8  # images on which each pass compares onnxruntime's labels with torch's simulation


def check_image_count(data: str | Path, split: str, count: int | None, what: str = "calibration images") -> int:
    """COUNT (None: DEFAULT_CALIB_IMAGES, or all if fewer), refused when DATA/<split> has fewer."""
    n = len(NativeDataset.open(data, split))
    count = min(DEFAULT_CALIB_IMAGES, n) if count is None else count
    if count < 1:
        raise ConfigError(f"the number of {what} must be at least 1")
    if n < count:
        raise ConfigError(f"asked for {count} {what}, but {data}/{split} has only {n}")
    return count


def folder_images(data: str | Path, split: str = "train", count: int | None = None, seed: int = 0,
                  what: str = "calibration images") -> list[np.ndarray]:
    """COUNT images of DATA/<split> (None: DEFAULT_CALIB_IMAGES, or all if fewer), chosen with SEED,
    as HxWx3 uint8 RGB at the data set's own size: the calibration data the passes take, from a
    native data set."""
    if seed < 0:
        raise ParameterError("{seed}: must be 0 or positive", seed=seed)
    ds = NativeDataset.open(data, split)
    count = check_image_count(data, split, count, what)
    ids = [ds.ids[i] for i in sorted(np.random.default_rng(seed).choice(len(ds), count, replace=False))]
    return [ds.rgb(i) for i in ids]


def agreement_images(data: str | Path, seed: int = 0) -> list[np.ndarray]:
    """Up to AGREEMENT_IMAGES val images of DATA: where each pass compares onnxruntime's labels with torch's."""
    n = len(NativeDataset.open(data, "val"))
    return folder_images(data, "val", min(AGREEMENT_IMAGES, n), seed, "val images")


def model_images(data: str | Path, split: str, count: int | None, size: Size, seed: int = 0,
                 what: str = "calibration images") -> list[np.ndarray]:
    """folder_images, area-resized to the model's input SIZE."""
    return [at_input_size(rgb, size) for rgb in folder_images(data, split, count, seed, what)]


def check_classes(ckpt: Checkpoint, data: str | Path) -> None:
    """Refuse a data set whose classes are not the checkpoint's."""
    classes = NativeDataset.open(data, "train").classes
    if classes != list(ckpt.classes):
        raise CheckpointError(f"the checkpoint's classes {list(ckpt.classes)} differ from the data set's {classes}")


def run_images(run: str | Path, data: str | Path, count: int | None = None) -> list[np.ndarray]:
    """COUNT train images of DATA (None: DEFAULT_CALIB_IMAGES, or all if fewer) drawn with the float
    RUN's own seed: hybrid-QaT's calibrated start as `quantize hybrid --calib-images` draws it."""
    last = Checkpoint.load(Run(run).last if Path(run).is_dir() else run)
    return folder_images(data, "train", count, last.train_config.seed if last.train_config else 0)
