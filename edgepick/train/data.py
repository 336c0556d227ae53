"""Torch data pipeline: native-layout samples resized to the training size, GPU/CPU batch augmentation."""

from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np
import torch
import torch.nn.functional as F
from torch.utils.data import Dataset

from edgepick.data.native import IGNORE, NativeDataset
from edgepick.geometry import Size


class SegmentationSet(Dataset):
    """(uint8 HWC RGB, uint8 HW mask) at a fixed size; optionally kept in memory after first read."""

    def __init__(self, ds: NativeDataset, size: Size, cache: bool = False):
        self.ds, self.size, self.cache = ds, size, cache
        self._mem: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def __len__(self) -> int:
        return len(self.ds)

    def _read(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        sid = self.ds.ids[i]
        h, w = self.size.hw
        img = cv2.resize(self.ds.rgb(sid), (w, h), interpolation=cv2.INTER_AREA)
        mask = cv2.resize(self.ds.mask(sid), (w, h), interpolation=cv2.INTER_NEAREST)
        return img, mask

    def __getitem__(self, i: int) -> tuple[torch.Tensor, torch.Tensor]:
        if i in self._mem:
            img, mask = self._mem[i]
        else:
            img, mask = self._read(i)
            if self.cache:
                self._mem[i] = (img, mask)
        return torch.from_numpy(img), torch.from_numpy(mask)

    def preload(self, indices: list[int] | None = None, threads: int = 0) -> None:
        """Decode INDICES (default: all) into the cache on a thread pool (OpenCV releases the GIL),
        so a GPU run reads from memory instead of decoding PNGs on its critical path."""
        todo = [i for i in (range(len(self)) if indices is None else indices) if i not in self._mem]
        with ThreadPoolExecutor(threads or os.cpu_count() or 1) as pool:
            for i, pair in zip(todo, pool.map(self._read, todo)):
                self._mem[i] = pair

    def cache_bytes(self, count: int | None = None) -> int:
        """Memory the cache takes with COUNT (default: all) samples."""
        return (len(self) if count is None else count) * self.size.width * self.size.height * 4


def class_weights(ds: NativeDataset, num_classes: int, max_images: int = 200) -> torch.Tensor:
    """1/sqrt(frequency) weights from up to max_images masks, normalised to mean 1."""
    counts = np.ones(num_classes)
    step = max(1, len(ds) // max_images)
    for sid in ds.ids[::step]:
        counts += np.bincount(ds.mask(sid).ravel(), minlength=num_classes)[:num_classes]
    w = 1.0 / np.sqrt(counts / counts.sum())
    return torch.tensor(w / w.mean(), dtype=torch.float32)


def augment(img: torch.Tensor, mask: torch.Tensor, gen: torch.Generator,
            lights: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
    """Batch augmentation for the thesis's lighting conditions: photometric jitter, colour casts
    (a hazard light turns metal red/orange), flips and a random scale with crop/pad; with LIGHTS,
    a share of the images is also relit by a dim room and one low coloured lamp (`coloured_lamp`).

    img: float [N, 3, H, W] in [0, 255]; mask: long [N, H, W].
    """
    n, _, h, w = img.shape
    dev = img.device

    def rand(*shape: int) -> torch.Tensor:
        return torch.rand(*shape, generator=gen).to(dev)

    gray = img.mean(1, keepdim=True)
    sat = 0.5 + rand(n, 1, 1, 1)  # saturation 0.5..1.5
    img = gray + (img - gray) * sat
    mean = img.mean((1, 2, 3), keepdim=True)
    img = mean + (img - mean) * (0.7 + 0.6 * rand(n, 1, 1, 1))  # contrast
    img = img * (0.55 + 0.9 * rand(n, 1, 1, 1))  # brightness
    cast = 1.0 + 0.25 * (rand(n, 3, 1, 1) - 0.5)  # white balance drift
    red = (rand(n, 1, 1, 1) < 0.15).float()  # occasional strong warm cast
    cast = cast * (1 - red) + red * torch.tensor([1.3, 0.8, 0.55], device=dev).view(1, 3, 1, 1)
    img = (img * cast).clamp(0, 255)
    if lights:
        img = coloured_lamp(img, gen)
    flip_x = rand(n) < 0.5
    flip_y = rand(n) < 0.5
    img = torch.where(flip_x.view(n, 1, 1, 1), img.flip(3), img)
    mask = torch.where(flip_x.view(n, 1, 1), mask.flip(2), mask)
    img = torch.where(flip_y.view(n, 1, 1, 1), img.flip(2), img)
    mask = torch.where(flip_y.view(n, 1, 1), mask.flip(1), mask)
    scale = float(0.75 + 0.5 * torch.rand(1, generator=gen))
    if abs(scale - 1.0) > 0.02:
        sh, sw = max(8, math.ceil(h * scale)), max(8, math.ceil(w * scale))
        img = F.interpolate(img, size=(sh, sw), mode="bilinear", align_corners=False)
        mask = F.interpolate(mask[:, None].float(), size=(sh, sw), mode="nearest")[:, 0].long()
        if scale > 1:
            y0 = int(torch.randint(0, sh - h + 1, (1,), generator=gen))
            x0 = int(torch.randint(0, sw - w + 1, (1,), generator=gen))
            img, mask = img[:, :, y0:y0 + h, x0:x0 + w], mask[:, y0:y0 + h, x0:x0 + w]
        else:
            img = F.pad(img, (0, w - sw, 0, h - sh), value=0.0)
            mask = F.pad(mask, (0, w - sw, 0, h - sh), value=IGNORE)
    return img.contiguous(), mask.contiguous()


LAMP_SHARE = 0.35  # share of a batch relit by `coloured_lamp`


def coloured_lamp(img: torch.Tensor, gen: torch.Generator, share: float = LAMP_SHARE) -> torch.Tensor:
    """Relight SHARE of the images as the 'hazard' scenes are lit: the room dimmed to 35-80% and a
    red-orange lamp close to the table, whose light falls off from a random point of the frame.

    A global colour cast cannot teach this: under such a lamp one side of an object is red and the
    other lit by the dim room, and the colour changes across the frame. img: float [N, 3, H, W] in
    [0, 255]."""
    n, _, h, w = img.shape
    dev = img.device

    def rand(*shape: int) -> torch.Tensor:
        return torch.rand(*shape, generator=gen).to(dev)

    chosen = rand(n, 1, 1, 1) < share
    room = 0.35 + 0.45 * rand(n, 1, 1, 1)
    # render.py's hazard lamp is (1, 0.25-0.5, 0-0.08); where it saturates red the frame turns
    # yellow, so green and blue are drawn wider
    colour = torch.cat([torch.ones(n, 1, 1, 1, device=dev), 0.25 + 0.55 * rand(n, 1, 1, 1),
                        0.35 * rand(n, 1, 1, 1)], 1)
    cy, cx = (rand(n) * h).view(n, 1, 1, 1), (rand(n) * w).view(n, 1, 1, 1)
    sigma = ((0.2 + 0.4 * rand(n)) * max(h, w)).view(n, 1, 1, 1)
    yy = torch.arange(h, device=dev, dtype=img.dtype).view(1, 1, h, 1)
    xx = torch.arange(w, device=dev, dtype=img.dtype).view(1, 1, 1, w)
    spot = (1.0 + 1.5 * rand(n, 1, 1, 1)) * torch.exp(-((yy - cy) ** 2 + (xx - cx) ** 2) / (2 * sigma ** 2))
    lit = (img * (room + spot * colour)).clamp(0, 255)
    return torch.where(chosen, lit, img)
