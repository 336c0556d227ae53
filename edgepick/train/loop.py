"""`edgepick train`: float training of DeepLabV3, one loop for CPU, one GPU or DDP (torchrun).

Per epoch: train with augmentation, validate (mIoU), append to metrics.json, write last.pt
(atomically), best.pt when validation mIoU improves, epoch_NNN.pt at --keep-epochs (the
hybrid-QaT switch points). --resume continues from last.pt, losing at most one epoch.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import sys
import time
import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
import torch.distributed as dist
import torch.nn.functional as F
from torch.utils.data import DataLoader, DistributedSampler, RandomSampler, Subset

from edgepick.data.native import NativeDataset
from edgepick.errors import ConfigError
from edgepick.metrics import confusion_matrix, segmentation_metrics
from edgepick.models.deeplabv3 import ModelConfig, build_model, load_backbone_weights
from edgepick.train.checkpoint import model_meta, read_checkpoint, save_atomic
from edgepick.train.data import IGNORE, SegmentationSet, augment, class_weights
from edgepick.progress import progress as progress_bar


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
    size: tuple[int, int] = (480, 640)  # H, W
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
    # QaT (edgepick quantize qat|hybrid): the whole run trains with fake-quant
    qat: bool = False
    quant: dict | None = None  # QuantConfig as a dict
    init_from: str | None = None  # float checkpoint to continue from (hybrid: epoch_NNN.pt), epochs counted on
    freeze_at: float = 0.7  # share of the QaT steps after which observers and BN statistics are frozen
    carry_optimizer: bool = True  # init_from: continue with its AdamW moments (a fresh AdamW jolts a converged model)
    qat_calib_images: int = 0  # init_from: start activation ranges from static PTQ's (percentile over N train images)
    qat_hold_ranges: bool = False  # with qat_calib_images: keep those ranges (activation observers off)


def _dist() -> tuple[int, int, int]:
    if int(os.environ.get("WORLD_SIZE", "1")) > 1:
        return int(os.environ["RANK"]), int(os.environ["WORLD_SIZE"]), int(os.environ.get("LOCAL_RANK", 0))
    return 0, 1, 0


def _device(name: str, local_rank: int) -> torch.device:
    if name == "auto":
        name = "cuda" if torch.cuda.is_available() else "cpu"
    if name == "cuda":
        if not torch.cuda.is_available():
            raise ConfigError("--device cuda asked for, but no CUDA device is available")
        return torch.device("cuda", local_rank)
    if name != "cpu":
        raise ConfigError(f"unknown device {name!r}; choose auto, cpu or cuda")
    return torch.device("cpu")


def available_memory() -> int:
    """Bytes of memory available to new allocations (MemAvailable), or 0 if unknown."""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 0


def _log(msg: str, rank: int) -> None:
    if rank == 0:
        print(msg, file=sys.stderr, flush=True)


@torch.no_grad()
def validate(model: torch.nn.Module, loader: DataLoader, num_classes: int, device: torch.device,
             amp: bool, set_eval: bool = True) -> np.ndarray:
    """Confusion matrix of the model on a loader (eval mode, argmax labels; set_eval=False for a
    model already in eval mode)."""
    if set_eval:
        model.eval()
    cm = np.zeros((num_classes, num_classes), np.int64)
    for img, mask in loader:
        x = img.to(device).permute(0, 3, 1, 2).float()
        with torch.autocast(device.type, dtype=torch.bfloat16, enabled=amp):
            pred = logits(model, x)["out"].argmax(1)
        cm += confusion_matrix(mask.numpy(), pred.cpu().numpy(), num_classes)
    return cm


def logits(model: torch.nn.Module, x: torch.Tensor) -> dict[str, torch.Tensor]:
    """The model's outputs as a dict (a QaT graph returns the logits tensor alone)."""
    out = model(x)
    return out if isinstance(out, dict) else {"out": out}


def freeze_qat(model: torch.nn.Module) -> bool:
    """End of QaT: stop the observers and use BN running statistics (standard practice)."""
    from torchao.quantization.pt2e import disable_observer

    from edgepick.quant.qat_graph import to_eval

    model.apply(disable_observer)
    to_eval(model)
    return True


def qat_evaluator(prepared: torch.nn.Module) -> torch.nn.Module:
    """An eval-mode copy of a QaT graph: switching the graph itself between train and eval rewrites
    it (about 1 s each way), so each epoch copies the weights into this copy instead."""
    import copy

    from edgepick.quant.qat_graph import to_eval

    evaluator = copy.deepcopy(prepared)
    to_eval(evaluator)  # not .eval(): the copied train/eval hooks act on the original
    return evaluator


def carry_optimizer_state(opt: torch.optim.Optimizer, model: torch.nn.Module, start: dict) -> int:
    """Give OPT (over MODEL, a float model or its QaT graph) the AdamW moments that the float
    checkpoint START holds, matched by parameter name; returns how many parameters got them."""
    from edgepick.models.deeplabv3 import ModelConfig, build_model

    saved = start.get("optimizer", {}).get("state", {})
    names = [n for n, _ in build_model(ModelConfig(**start["model_config"])).named_parameters()]
    by_name = {names[i]: s for i, s in saved.items() if i < len(names)}
    carried = 0
    for name, p in model.named_parameters():
        s = by_name.get(name.removeprefix("model."))  # the QaT graph wraps the model as .model
        if s is not None and s.get("exp_avg") is not None and s["exp_avg"].shape == p.shape:
            opt.state[p] = {k: v.to(p.device) if torch.is_tensor(v) and k != "step" else v for k, v in s.items()}
            carried += 1
    return carried


def train(cfg: TrainConfig, resume: bool = False, progress: bool = True) -> dict:
    """Train a float DeepLabV3 on a native data set; returns the final summary."""
    rank, world, local_rank = _dist()
    device = _device(cfg.device, local_rank)
    out = Path(cfg.out)
    last_path = out / "last.pt"
    if resume:
        if not last_path.is_file():
            raise ConfigError(f"nothing to resume: {last_path} does not exist")
        ckpt = read_checkpoint(last_path)
        epochs = cfg.epochs  # 0: keep the run's own epoch budget
        cfg = TrainConfig(**{**ckpt["train_config"], "size": tuple(ckpt["train_config"]["size"])})
        cfg.epochs = max(epochs or cfg.epochs, ckpt["epoch"])
    elif last_path.exists():
        raise ConfigError(f"{out} already holds a training run; pass --resume or choose a new --out")
    model_cfg = ModelConfig(cfg.arch, 0, cfg.output_stride, cfg.colorspace, cfg.aux_loss, variant=cfg.variant)
    train_ds = NativeDataset.open(cfg.data, "train")  # validates the layout before anything is written
    val_ds = NativeDataset.open(cfg.data, "val")
    classes = train_ds.classes
    model_cfg.num_classes = len(classes)
    model_cfg.validate()
    if cfg.epochs < 1 or cfg.batch_size < 1:
        raise ConfigError("--epochs and --batch-size must be at least 1")
    if not (math.isfinite(cfg.lr) and 0 < cfg.lr < 1):
        raise ConfigError(f"--lr {cfg.lr}: the learning rate must be a number in (0, 1), e.g. 1e-3")
    if cfg.epoch_images < 0 or cfg.val_images < 0:
        raise ConfigError("--epoch-images and --val-images must be 0 (all) or positive")
    if cfg.epoch_images and world > 1:
        raise ConfigError("--epoch-images is for single-process runs (DDP shards the whole split)")
    torch.manual_seed(cfg.seed)  # before the model: same seed, same initial weights
    model = build_model(model_cfg)
    if cfg.backbone_weights:
        load_backbone_weights(model, cfg.backbone_weights)
    start = read_checkpoint(cfg.init_from) if cfg.init_from and not resume else None
    if start is not None:
        if start["classes"] != classes:
            raise ConfigError(f"{cfg.init_from} was trained on classes {start['classes']}, the data has {classes}")
        if start["epoch"] >= cfg.epochs:
            raise ConfigError(f"{cfg.init_from} is at epoch {start['epoch']}, the budget is {cfg.epochs} epochs")
        weights = {k: v for k, v in start["model"].items() if cfg.aux_loss or not k.startswith("aux_classifier.")}
        model.load_state_dict(weights)
    if cfg.qat:
        from edgepick.quant.passes import prepare
        from edgepick.quant.quantizer import QuantConfig

        model = prepare(model, QuantConfig(**(cfg.quant or {})), cfg.size, qat=True)
    cuda = device.type == "cuda"
    amp = cuda and not cfg.qat  # bf16 autocast on GPU (fake-quant ops reject bf16: QaT runs fp32); CPU fp32
    if world > 1 and not dist.is_initialized():
        dist.init_process_group("nccl" if cuda else "gloo")
    if cuda:
        torch.cuda.set_device(device)
        model = model.to(device, memory_format=torch.channels_last)
    if cfg.qat and cfg.qat_calib_images and start is not None:  # hybrid: begin where static PTQ would
        from edgepick.quant.passes import model_images
        from edgepick.quant.qat_graph import calibrate_activations

        calibrate_activations(model, model_images(cfg.data, "train", cfg.qat_calib_images, cfg.size, cfg.seed),
                              QuantConfig(**(cfg.quant or {})).percentile, hold=cfg.qat_hold_ranges)
    train_set = SegmentationSet(train_ds, cfg.size)
    val_set = SegmentationSet(val_ds, cfg.size)
    n_val = min(cfg.val_images or len(val_set), len(val_set))
    val_ids = [round(i * len(val_set) / n_val) for i in range(n_val)]
    workers = cfg.workers
    if workers < 0:  # the cache when it fits in a third of the free memory, else decoding workers
        need = train_set.cache_bytes() + val_set.cache_bytes(n_val)
        workers = 4 if cuda and need > available_memory() / 3 else 0
    if workers == 0:
        train_set.cache = val_set.cache = True
        if cuda:  # decode everything now on a thread pool, not on the GPU's critical path
            t0 = time.perf_counter()
            train_set.preload()
            val_set.preload(val_ids[rank::world])
            _log(f"decoded {len(train_set)} + {len(val_ids[rank::world])} images into memory in "
                 f"{time.perf_counter() - t0:.1f}s", rank)
    gen_loader = torch.Generator().manual_seed(cfg.seed)
    if world > 1:
        sampler = DistributedSampler(train_set, world, rank, shuffle=True, seed=cfg.seed)
    elif cfg.epoch_images:
        sampler = RandomSampler(train_set, num_samples=cfg.epoch_images, generator=gen_loader)
    else:
        sampler = None
    per_epoch = cfg.epoch_images or len(train_set) // world
    train_loader = DataLoader(train_set, cfg.batch_size, shuffle=sampler is None, sampler=sampler,
                              drop_last=per_epoch > cfg.batch_size, num_workers=workers,
                              pin_memory=cuda, persistent_workers=workers > 0, generator=gen_loader)
    val_loader = DataLoader(Subset(val_set, val_ids[rank::world]), cfg.batch_size,
                            num_workers=workers, pin_memory=cuda, persistent_workers=workers > 0)
    weights = class_weights(train_ds, len(classes)).to(device) if cfg.class_weighting else None
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    steps_per_epoch = max(1, len(train_loader))
    total_steps = cfg.epochs * steps_per_epoch
    sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda s: min(1.0, (s + 1) / 50) *
                                              (1 - min(s, total_steps - 1) / total_steps) ** 0.9)
    state = {"epoch": 0, "history": [], "best_miou": -1.0, "train_time_s": 0.0, "phase_start": 0,
             "init_train_time_s": 0.0}
    if start is not None:  # continue the float run's schedule (and its optimizer moments)
        if cfg.carry_optimizer:
            carry_optimizer_state(opt, model, start)
        state.update(epoch=start["epoch"], history=list(start["history"]), phase_start=start["epoch"],
                     init_train_time_s=start["train_time_s"])
        with warnings.catch_warnings():  # fast-forwarding the LR schedule before any optimizer step
            warnings.simplefilter("ignore")
            for _ in range(start["epoch"] * steps_per_epoch):
                sched.step()
    if resume:
        if cfg.qat:
            from edgepick.quant.qat_graph import load_qat_state

            load_qat_state(model, ckpt["model"])
        else:
            model.load_state_dict(ckpt["model"])
        opt.load_state_dict(ckpt["optimizer"])
        sched.load_state_dict(ckpt["scheduler"])
        state = {k: ckpt[k] for k in state if k in ckpt}
        _log(f"resuming {out} after epoch {state['epoch']}", rank)
    ddp = torch.nn.parallel.DistributedDataParallel(model) if world > 1 else model
    meta = model_meta(model_cfg, classes, cfg.size)
    gen = torch.Generator().manual_seed(cfg.seed * 1000 + state["epoch"] + rank)
    first = state["phase_start"]
    freeze_step = round(((cfg.epochs - first) * cfg.freeze_at + first) * steps_per_epoch)
    frozen = False
    evaluator = qat_evaluator(model) if cfg.qat else None
    ddp.train()  # a QaT graph's own train() keeps its BatchNorm literals (quant/torchao_compat.py)

    for epoch in range(state["epoch"] + 1, cfg.epochs + 1):
        if isinstance(sampler, DistributedSampler):
            sampler.set_epoch(epoch)
        if evaluator is None:
            ddp.train()
        t0 = time.perf_counter()
        loss_sum, seen = 0.0, 0
        bar = progress_bar(train_loader, desc=f"epoch {epoch}/{cfg.epochs}", unit="batch",
                           enabled=progress and rank == 0)
        for img, mask in bar:
            x = img.to(device, non_blocking=True).permute(0, 3, 1, 2).float()
            y = mask.to(device, non_blocking=True).long()
            x, y = augment(x, y, gen)
            if cuda:
                x = x.contiguous(memory_format=torch.channels_last)
            with torch.autocast(device.type, dtype=torch.bfloat16, enabled=amp):
                outputs = logits(ddp, x)
                loss = F.cross_entropy(outputs["out"].float(), y, weight=weights, ignore_index=IGNORE)
                if "aux" in outputs:
                    loss = loss + 0.4 * F.cross_entropy(outputs["aux"].float(), y, weight=weights,
                                                        ignore_index=IGNORE)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            sched.step()
            if cfg.qat and not frozen and sched.last_epoch >= freeze_step:
                frozen = freeze_qat(model)
            loss_sum += float(loss.detach()) * len(x)
            seen += len(x)
            bar.set_postfix(loss=f"{loss_sum / seen:.3f}")
        train_s = time.perf_counter() - t0
        if evaluator is None:
            cm = validate(model, val_loader, len(classes), device, amp)
        elif frozen:  # the QaT graph is in eval mode for good
            cm = validate(model, val_loader, len(classes), device, amp, set_eval=False)
        else:
            evaluator.load_state_dict(model.state_dict())
            cm = validate(evaluator, val_loader, len(classes), device, amp, set_eval=False)
        if world > 1:
            t = torch.tensor(cm, device=device)
            dist.all_reduce(t)
            cm = t.cpu().numpy()
            stats = torch.tensor([loss_sum, seen], dtype=torch.float64, device=device)
            dist.all_reduce(stats)
            loss_sum, seen = float(stats[0]), int(stats[1])
        epoch_s = time.perf_counter() - t0
        m = segmentation_metrics(cm, classes)
        state["train_time_s"] += epoch_s
        record = {"epoch": epoch, "loss": round(loss_sum / max(seen, 1), 5), "pixel_acc": m["pixel_acc"],
                  "miou": m["miou"], "per_class_iou": {c: v["iou"] for c, v in m["per_class"].items()},
                  "epoch_s": round(epoch_s, 2), "train_s": round(train_s, 2), "images": seen,
                  "val_images": n_val,
                  "images_per_s": round(seen / train_s, 2)}
        state["history"].append(record)
        state["epoch"] = epoch
        _log(f"epoch {epoch}/{cfg.epochs}: loss {record['loss']:.4f}  val pixel acc {m['pixel_acc']:.4f}  "
             f"mIoU {m['miou']:.4f}  {epoch_s:.1f}s", rank)
        if rank == 0:
            improved = (m["miou"] or 0.0) > state["best_miou"]
            if improved:
                state["best_miou"] = m["miou"] or 0.0
            out.mkdir(parents=True, exist_ok=True)  # only now: a failed first epoch leaves no RUN behind
            ckpt_out = {"model": model.state_dict(), "optimizer": opt.state_dict(), "scheduler": sched.state_dict(),
                        "train_config": asdict(cfg), **meta, **state, "world_size": world}
            save_atomic(ckpt_out, last_path)
            if improved:
                shutil.copyfile(last_path, out / ".best.tmp")
                os.replace(out / ".best.tmp", out / "best.pt")
            if epoch in cfg.keep_epochs:
                shutil.copyfile(last_path, out / f".epoch_{epoch:03d}.tmp")
                os.replace(out / f".epoch_{epoch:03d}.tmp", out / f"epoch_{epoch:03d}.pt")
            summary = {"epochs": epoch, "best_miou": state["best_miou"], "train_time_s": round(state["train_time_s"], 2),
                       "device": str(device), "world_size": world, "arch": cfg.arch, "size": list(cfg.size),
                       "history": state["history"]}
            tmp = out / ".metrics.json.tmp"
            tmp.write_text(json.dumps(summary, indent=1))
            os.replace(tmp, out / "metrics.json")
        if world > 1:
            dist.barrier()
    if world > 1:
        dist.destroy_process_group()
    return {"out": str(out), "epochs": state["epoch"], "best_miou": state["best_miou"],
            "train_time_s": round(state["train_time_s"], 2), "last": state["history"][-1] if state["history"] else None}
