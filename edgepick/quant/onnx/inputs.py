"""The calibration inputs of a model edgepick did not make: tensors checked one by one (float,
finite, the model's shape), read from a folder of .npy tensors or images made into tensors."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from edgepick.errors import ParameterError
from edgepick.geometry import Size
from edgepick.runtime.preprocessing import Preprocessing

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".webp", ".tif", ".tiff")


def check_tensor(x: Any, shape: tuple[int, ...] | None, what: str) -> np.ndarray:
    """X as a float32 input tensor with a batch axis (added when X lacks it), refused in one line
    naming WHAT when it is not a finite float array of SHAPE."""
    if not isinstance(x, np.ndarray) or x.dtype.kind != "f":
        got = f"{x.dtype} {x.shape}" if isinstance(x, np.ndarray) else type(x).__name__
        raise ParameterError(f"{{calib:name}}: {what} must be a float array, got {got}", calib=what)
    if shape is not None and x.ndim == len(shape) - 1:
        x = x[None]
    if shape is not None and tuple(x.shape) != tuple(shape):
        raise ParameterError(f"{{calib:name}}: {what} has shape {list(x.shape)}, the model takes {list(shape)}",
                             calib=what)
    if not np.isfinite(x).all():
        raise ParameterError(f"{{calib:name}}: {what} holds NaN or infinity", calib=what)
    return np.ascontiguousarray(x, dtype=np.float32)


class TensorFolder:
    """Calibration inputs from a folder, read one at a time: its .npy files (one input tensor each,
    in the model's layout), or else its images, made into tensors by a preprocessing at a size.
    Its length is known before the first is read, so progress can say n of N."""

    def __init__(self, folder: str | Path, preprocessing: Preprocessing | None = None, size: Size | None = None,
                 count: int | None = None):
        folder = Path(folder)
        if not folder.is_dir():
            raise ParameterError("{calib}: not a folder", calib=folder)
        arrays = sorted(p for p in folder.iterdir() if p.suffix.lower() == ".npy")
        images = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if not arrays and not images:
            raise ParameterError("{calib}: holds no .npy tensors and no images", calib=folder)
        if count is not None and count < 1:
            raise ParameterError("{count}: must be 1 or more", count=count)
        self.folder, self.arrays = folder, bool(arrays)
        self.files = (arrays or images)[:count]
        self.preprocessing = preprocessing or Preprocessing()
        self.size = self.preprocessing.size or size
        if not self.arrays and self.size is None:
            raise ParameterError("{size:name} is needed for images: the model's input has no fixed size", size=None)

    def __len__(self) -> int:
        return len(self.files)

    def __iter__(self) -> Iterator[np.ndarray]:
        import cv2

        for p in self.files:
            if self.arrays:
                try:
                    yield np.load(p, allow_pickle=False)
                except (OSError, ValueError) as exc:
                    raise ParameterError(f"{{calib}}: {p.name} is not a readable .npy file ({exc})",
                                         calib=self.folder) from None
                continue
            bgr = cv2.imread(str(p), cv2.IMREAD_COLOR)
            if bgr is None:
                raise ParameterError(f"{{calib}}: {p.name} is not a readable image", calib=self.folder)
            assert self.size is not None
            yield self.preprocessing.tensor(bgr[..., ::-1], self.size)


def folder_tensors(folder: str | Path, preprocessing: Preprocessing | None = None, size: Size | None = None,
                   count: int | None = None) -> TensorFolder:
    """Calibration inputs from FOLDER (`TensorFolder`): the first COUNT [default: all]."""
    return TensorFolder(folder, preprocessing, size, count)
