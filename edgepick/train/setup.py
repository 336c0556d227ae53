"""What a training run stands on: its process group and device, its data loaders (an in-memory
cache or decoding workers), and validation."""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import DataLoader, DistributedSampler, RandomSampler, Sampler, Subset

from edgepick.data.native import NativeDataset
from edgepick.errors import ParameterError
from edgepick.metrics import confusion_matrix
from edgepick.train.config import Device, TrainConfig
from edgepick.train.data import SegmentationSet


def device_for(device: Device, local_rank: int) -> torch.device:
    """auto, cpu or cuda (a TrainConfig's device) -> the device this process trains on."""
    if device == Device.AUTO:
        device = Device.CUDA if torch.cuda.is_available() else Device.CPU
    if device == Device.CUDA and not torch.cuda.is_available():
        raise ParameterError("{device}: asked for, but no CUDA device is available", device=device)
    return torch.device("cuda", local_rank) if device == Device.CUDA else torch.device("cpu")


def available_memory() -> int:
    """Bytes of memory available to new allocations (MemAvailable), or 0 if unknown."""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 0


def log(msg: str, rank: int) -> None:
    if rank == 0:
        print(msg, file=sys.stderr, flush=True)


@dataclass
class Loaders:
    train: DataLoader
    val: DataLoader
    sampler: Sampler | None  # the train loader's, when it is not plain shuffling
    n_val: int  # validation images over all ranks


def make_loaders(cfg: TrainConfig, train_ds: NativeDataset, val_ds: NativeDataset, cuda: bool, rank: int,
                 world: int) -> Loaders:
    """The train loader (shuffled, an epoch_images draw, or sharded under DDP) and the val loader
    (val_images evenly spaced images, sharded). With workers -1 the images are decoded once into
    memory when they fit in a third of the free memory (up front on a GPU, off its critical path)."""
    train_set, val_set = SegmentationSet(train_ds, cfg.size), SegmentationSet(val_ds, cfg.size)
    n_val = min(cfg.val_images or len(val_set), len(val_set))
    val_ids = [round(i * len(val_set) / n_val) for i in range(n_val)]
    workers = cfg.workers
    if workers < 0:
        need = train_set.cache_bytes() + val_set.cache_bytes(n_val)
        workers = 4 if cuda and need > available_memory() / 3 else 0
    if workers == 0:
        train_set.cache = val_set.cache = True
        if cuda:
            t0 = time.perf_counter()
            train_set.preload()
            val_set.preload(val_ids[rank::world])
            log(f"decoded {len(train_set)} + {len(val_ids[rank::world])} images into memory in "
                f"{time.perf_counter() - t0:.1f}s", rank)
    gen = torch.Generator().manual_seed(cfg.seed)
    if world > 1:
        sampler = DistributedSampler(train_set, world, rank, shuffle=True, seed=cfg.seed)
    elif cfg.epoch_images:
        sampler = RandomSampler(train_set, num_samples=cfg.epoch_images, generator=gen)
    else:
        sampler = None
    per_epoch = cfg.epoch_images or len(train_set) // world
    train_loader = DataLoader(train_set, cfg.batch_size, shuffle=sampler is None, sampler=sampler,
                              drop_last=per_epoch > cfg.batch_size, num_workers=workers,
                              pin_memory=cuda, persistent_workers=workers > 0, generator=gen)
    val_loader = DataLoader(Subset(val_set, val_ids[rank::world]), cfg.batch_size,
                            num_workers=workers, pin_memory=cuda, persistent_workers=workers > 0)
    return Loaders(train_loader, val_loader, sampler, n_val)


def logits(model: torch.nn.Module, x: torch.Tensor) -> dict[str, torch.Tensor]:
    """The model's outputs as a dict (a graph made for export, such as a QaT graph, returns the
    logits tensor alone)."""
    out = model(x)
    return out if isinstance(out, dict) else {"out": out}


@torch.no_grad()
def validate(model: torch.nn.Module, loader: DataLoader, num_classes: int, device: torch.device,
             amp: bool) -> np.ndarray:
    """Confusion matrix of MODEL (already in eval mode) on a loader, argmax labels."""
    cm = np.zeros((num_classes, num_classes), np.int64)
    for img, mask in loader:
        x = img.to(device).permute(0, 3, 1, 2).float()
        with torch.autocast(device.type, dtype=torch.bfloat16, enabled=amp):
            pred = logits(model, x)["out"].argmax(1)
        cm += confusion_matrix(mask.numpy(), pred.cpu().numpy(), num_classes)
    return cm
