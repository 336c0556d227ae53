"""`edgepick train`: one training loop for CPU, one GPU (bf16 AMP) and DDP (torchrun).

Per epoch: train with augmentation, validate (mIoU), append to metrics.json, write last.pt
(atomically), best.pt when validation mIoU improves, epoch_NNN.pt at --keep-epochs (the
hybrid-QaT switch points). --resume continues from last.pt, losing at most one epoch.

`fit` trains whatever model it is given and knows nothing of quantization: a model that needs
more from the loop (a QaT graph: its own train/eval switch, an eval copy for validation, a change
at a share of the steps, its own checkpoint entries) brings a `Hooks` object
(edgepick.quant.qat.QatHooks), as torchao's pt2e flow expects: prepare_qat_pt2e returns a graph
and the user's own loop trains it.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import time
import warnings
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

import numpy as np
import torch
import torch.distributed as dist
import torch.nn.functional as F

from edgepick.data.native import NativeDataset
from edgepick.errors import CheckpointError, ConfigError
from edgepick.files import made_by, mark
from edgepick.metrics import segmentation_metrics
from edgepick.models.deeplabv3 import DeepLabV3, ModelConfig, build_model, load_backbone_weights
from edgepick.progress import progress as progress_bar
from edgepick.schema import Where, as_dict, as_list, as_number, as_numbers, as_str
from edgepick.schema import field as required_field
from edgepick.train.checkpoint import is_qat_checkpoint, model_meta, read_checkpoint, save_atomic
from edgepick.train.data import IGNORE, augment, class_weights
from edgepick.train.setup import device_for, dist_env, log, logits, make_loaders, validate


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

    @classmethod
    def from_dict(cls, values: dict, where: Where | None = None) -> "TrainConfig":
        """The config a checkpoint recorded, each field's type checked (WHERE names the file in
        errors; keys an older edgepick wrote and this one has no use for are dropped)."""
        where = where or Where("train_config")
        values = as_dict(values, where)
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
    if kind == "tuple[int, int]":
        return tuple(as_numbers(value, where, 2, integer=True, minimum=1))
    if kind == "list[int]":
        return [as_number(v, where.at(i), integer=True) for i, v in enumerate(as_list(value, where))]
    raise TypeError(f"no check for a TrainConfig field of type {kind}")  # a new field needs one here


class Hooks:
    """What a model may need from the loop beyond plain training; these defaults train a float model."""

    bf16 = True  # the model may run under bf16 autocast on a GPU
    param_prefix = ""  # prefix of the float model's parameter names inside MODEL (to carry AdamW moments)

    def begin(self, model: torch.nn.Module, device: torch.device, first_step: int, last_step: int) -> None:
        """Before the first step; the run takes the optimizer steps (first_step, last_step]."""
        model.train()

    def epoch_start(self, model: torch.nn.Module) -> None:
        model.train()

    def after_step(self, model: torch.nn.Module, step: int) -> None:
        """After optimizer step STEP (counted over the whole schedule)."""

    def eval_model(self, model: torch.nn.Module) -> torch.nn.Module:
        """The module to validate, in eval mode."""
        return model.eval()

    def checkpoint(self) -> dict:
        """Entries each checkpoint of the run carries besides the loop's own."""
        return {}


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


def model_config(cfg: TrainConfig, classes: list[str]) -> ModelConfig:
    model_cfg = ModelConfig(cfg.arch, len(classes), cfg.output_stride, cfg.colorspace, cfg.aux_loss,
                            variant=cfg.variant)
    model_cfg.validate()
    return model_cfg


def new_model(cfg: TrainConfig, start: dict | None = None) -> DeepLabV3:
    """The float model a run begins with: fresh (seeded with cfg.seed, cfg.backbone_weights if
    given), or the weights of START, a checkpoint the run continues (a float run's epoch_NNN.pt)."""
    classes = NativeDataset.open(cfg.data, "train").classes  # validates the layout before anything is written
    check_config(cfg)
    torch.manual_seed(cfg.seed)  # before the model: same seed, same initial weights
    model = build_model(model_config(cfg, classes))
    if cfg.backbone_weights:
        load_backbone_weights(model, cfg.backbone_weights)
    if start is not None:
        if start["classes"] != classes:
            raise ConfigError(f"{start['path']} was trained on classes {start['classes']}, the data has {classes}")
        if start["epoch"] >= cfg.epochs:
            raise ConfigError(f"{start['path']} is at epoch {start['epoch']}, the budget is {cfg.epochs} epochs")
        model.load_state_dict({k: v for k, v in start["model"].items()
                               if cfg.aux_loss or not k.startswith("aux_classifier.")})
    return model


def train(cfg: TrainConfig, resume: bool = False, progress: bool = True) -> dict:
    """Train a float DeepLabV3 on a native data set (resume: continue cfg.out from its last.pt);
    returns the final summary."""
    last = None
    if resume:
        last_path = Path(cfg.out) / "last.pt"
        if not last_path.is_file():
            raise ConfigError(f"nothing to resume: {last_path} does not exist")
        last = read_checkpoint(last_path)
        if is_qat_checkpoint(last):
            raise CheckpointError(f"{cfg.out} is a QaT run; run its quantize command again to start it anew")
        epochs, data = cfg.epochs, cfg.data  # epochs 0: keep the run's own epoch budget
        where = Where(last["path"])
        cfg = TrainConfig.from_dict(required_field(last, "train_config", where), where.at("train_config"))
        cfg.epochs = max(epochs or cfg.epochs, last["epoch"])
        cfg.data = data  # the data set given now (a run moves with its data): checked to be the same one
        check_same_data(last, data)
    return fit(cfg, new_model(cfg), resume=last, progress=progress)


def check_same_data(last: dict, data: str) -> None:
    """Refuse to resume RUN on a data set other than the one it was trained on: other class names,
    or (runs that recorded it) images of another size."""
    train_ds = NativeDataset.open(data, "train")
    if train_ds.classes != last["classes"]:
        raise ConfigError(f"DATA {data} has the classes {train_ds.classes}, the run to resume was trained on "
                          f"{last['classes']}; give the run's own data set")
    recorded = last.get("data_image_size")
    if recorded is not None and list(train_ds.rgb(train_ds.ids[0]).shape[:2]) != list(recorded):
        h, w = recorded
        raise ConfigError(f"DATA {data} holds images of another size than the {w}x{h} the run was trained on; "
                          "give the run's own data set")


def carry_optimizer_state(opt: torch.optim.Optimizer, model: torch.nn.Module, start: dict, prefix: str = "") -> int:
    """Give OPT (over MODEL, whose parameter names are the float model's behind PREFIX) the AdamW
    moments that the float checkpoint START holds, matched by name; returns how many got them."""
    saved = start.get("optimizer", {}).get("state", {})
    names = [n for n, _ in build_model(ModelConfig(**start["model_config"])).named_parameters()]
    by_name = {names[i]: s for i, s in saved.items() if i < len(names)}
    carried = 0
    for name, p in model.named_parameters():
        s = by_name.get(name.removeprefix(prefix))
        if s is not None and s.get("exp_avg") is not None and s["exp_avg"].shape == p.shape:
            opt.state[p] = {k: v.to(p.device) if torch.is_tensor(v) and k != "step" else v for k, v in s.items()}
            carried += 1
    return carried


def _schedule(opt: torch.optim.Optimizer, total_steps: int) -> torch.optim.lr_scheduler.LambdaLR:
    """Poly decay (power 0.9) after a 50-step linear warm-up."""
    return torch.optim.lr_scheduler.LambdaLR(opt, lambda s: min(1.0, (s + 1) / 50) *
                                             (1 - min(s, total_steps - 1) / total_steps) ** 0.9)


def _starting_state(model: torch.nn.Module, opt: torch.optim.Optimizer, sched: torch.optim.lr_scheduler.LambdaLR,
                    steps_per_epoch: int, start: dict | None, carry_optimizer: bool, prefix: str,
                    resume: dict | None) -> dict:
    """The run's bookkeeping (epoch, history, best mIoU, times) at its first epoch: fresh, continuing
    START's schedule (and its AdamW moments), or RESUME's own state (weights, optimizer, schedule)."""
    state = {"epoch": 0, "history": [], "best_miou": -1.0, "train_time_s": 0.0, "phase_start": 0,
             "init_train_time_s": 0.0}
    if start is not None:
        if carry_optimizer:
            carry_optimizer_state(opt, model, start, prefix)
        state.update(epoch=start["epoch"], history=list(start["history"]), phase_start=start["epoch"],
                     init_train_time_s=start["train_time_s"])
        with warnings.catch_warnings():  # fast-forwarding the LR schedule before any optimizer step
            warnings.simplefilter("ignore")
            for _ in range(start["epoch"] * steps_per_epoch):
                sched.step()
    if resume is not None:
        model.load_state_dict(resume["model"])
        opt.load_state_dict(resume["optimizer"])
        sched.load_state_dict(resume["scheduler"])
        state = {k: resume[k] for k in state if k in resume}
    return state


def fit(cfg: TrainConfig, model: torch.nn.Module, hooks: Hooks | None = None, start: dict | None = None,
        carry_optimizer: bool = True, resume: dict | None = None, progress: bool = True) -> dict:
    """Train MODEL (built for cfg's data and size) for cfg.epochs, writing cfg.out's checkpoints
    and metrics. START: the checkpoint MODEL's weights come from, whose epochs, history and LR
    schedule the run continues (with its AdamW moments unless carry_optimizer is False); RESUME:
    this run's own last.pt. Returns the final summary. One function on purpose (nanoGPT's
    train.py): the epoch, the step and the checkpoint read in one sitting."""
    hooks = hooks or Hooks()
    rank, world, local_rank = dist_env()
    device = device_for(cfg.device, local_rank)
    out = Path(cfg.out)
    if resume is None and (out / "last.pt").exists():
        raise ConfigError(f"{out} already holds a training run; pass --resume or choose a new --out")
    train_ds, val_ds = NativeDataset.open(cfg.data, "train"), NativeDataset.open(cfg.data, "val")
    classes = train_ds.classes
    check_config(cfg, world)
    cuda = device.type == "cuda"
    amp = cuda and hooks.bf16  # bf16 autocast on GPU; CPU fp32
    if world > 1 and not dist.is_initialized():
        dist.init_process_group("nccl" if cuda else "gloo")
    if cuda:
        torch.cuda.set_device(device)
        model = model.to(device, memory_format=torch.channels_last)
    loaders = make_loaders(cfg, train_ds, val_ds, cuda, rank, world)
    weights = class_weights(train_ds, len(classes)).to(device) if cfg.class_weighting else None
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    steps_per_epoch = max(1, len(loaders.train))
    sched = _schedule(opt, cfg.epochs * steps_per_epoch)
    state = _starting_state(model, opt, sched, steps_per_epoch, start, carry_optimizer, hooks.param_prefix, resume)
    if resume is not None:
        log(f"resuming {out} after epoch {state['epoch']}", rank)
    ddp = torch.nn.parallel.DistributedDataParallel(model) if world > 1 else model
    meta = {**model_meta(model_config(cfg, classes), classes, cfg.size), "train_config": asdict(cfg),
            "world_size": world, "data_image_size": list(train_ds.rgb(train_ds.ids[0]).shape[:2])}
    gen = torch.Generator().manual_seed(cfg.seed * 1000 + state["epoch"] + rank)
    hooks.begin(model, device, state["phase_start"] * steps_per_epoch, cfg.epochs * steps_per_epoch)

    for epoch in range(state["epoch"] + 1, cfg.epochs + 1):
        if isinstance(loaders.sampler, torch.utils.data.DistributedSampler):
            loaders.sampler.set_epoch(epoch)
        hooks.epoch_start(ddp)
        t0 = time.perf_counter()
        bar = progress_bar(loaders.train, desc=f"epoch {epoch}/{cfg.epochs}", unit="batch",
                           enabled=progress and rank == 0)
        loss_sum, seen = 0.0, 0
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
            hooks.after_step(model, sched.last_epoch)
            loss_sum += float(loss.detach()) * len(x)
            seen += len(x)
            bar.set_postfix(loss=f"{loss_sum / seen:.3f}")
        train_s = time.perf_counter() - t0
        cm = validate(hooks.eval_model(model), loaders.val, len(classes), device, amp)
        if world > 1:
            cm, loss_sum, seen = _all_reduce(cm, loss_sum, seen, device)
        record = _record(epoch, segmentation_metrics(cm, classes), loss_sum, seen, train_s,
                         time.perf_counter() - t0, loaders.n_val)
        state["train_time_s"] += record["epoch_s"]
        state["history"].append(record)
        state["epoch"] = epoch
        log(f"epoch {epoch}/{cfg.epochs}: loss {record['loss']:.4f}  val pixel acc {record['pixel_acc']:.4f}  "
            f"mIoU {record['miou']:.4f}  {record['epoch_s']:.1f}s", rank)
        if rank == 0:
            _save(out, cfg, state, record, {"model": model.state_dict(), "optimizer": opt.state_dict(),
                                            "scheduler": sched.state_dict(), **meta, **hooks.checkpoint()},
                  str(device), world)
        if world > 1:
            dist.barrier()
    if world > 1:
        dist.destroy_process_group()
    return {"out": str(out), "epochs": state["epoch"], "best_miou": state["best_miou"],
            "train_time_s": round(state["train_time_s"], 2), "last": state["history"][-1] if state["history"] else None}


def _all_reduce(cm: np.ndarray, loss_sum: float, seen: int, device: torch.device) -> tuple[np.ndarray, float, int]:
    """Sum the ranks' confusion matrices and loss totals (DDP)."""
    t = torch.tensor(cm, device=device)
    dist.all_reduce(t)
    stats = torch.tensor([loss_sum, seen], dtype=torch.float64, device=device)
    dist.all_reduce(stats)
    return t.cpu().numpy(), float(stats[0]), int(stats[1])


def _record(epoch: int, m: dict, loss_sum: float, seen: int, train_s: float, epoch_s: float, n_val: int) -> dict:
    """One epoch's entry of metrics.json's history."""
    return {"epoch": epoch, "loss": round(loss_sum / max(seen, 1), 5), "pixel_acc": m["pixel_acc"],
            "miou": m["miou"], "per_class_iou": {c: v["iou"] for c, v in m["per_class"].items()},
            "epoch_s": round(epoch_s, 2), "train_s": round(train_s, 2), "images": seen, "val_images": n_val,
            "images_per_s": round(seen / train_s, 2)}


RESUME_ONLY = ("optimizer", "scheduler")  # what only --resume and hybrid-QaT read


def _save(out: Path, cfg: TrainConfig, state: dict, record: dict, ckpt: dict, device: str, world: int) -> None:
    """last.pt (atomically), best.pt if validation mIoU improved, epoch_NNN.pt if kept, metrics.json."""
    improved = (record["miou"] or 0.0) > state["best_miou"]
    if improved:
        state["best_miou"] = record["miou"] or 0.0
    out.mkdir(parents=True, exist_ok=True)  # only now: a failed first epoch leaves no RUN behind
    if made_by(out) != "train":
        mark(out, "train")
    # last.pt goes last: a run killed in between resumes from the epoch before and writes the others again
    full = {**ckpt, **state}
    if improved:  # the weights to export and quantize: no optimizer state (a third of last.pt's size)
        save_atomic({k: v for k, v in full.items() if k not in RESUME_ONLY}, out / "best.pt")
    last_path = out / "last.pt"
    if record["epoch"] in cfg.keep_epochs:  # a hybrid-QaT switch point: it carries the AdamW moments on
        kept = out / f"epoch_{record['epoch']:03d}.pt"
        save_atomic(full, kept)
        shutil.copyfile(kept, out / ".last.pt.tmp")
        os.replace(out / ".last.pt.tmp", last_path)
    else:
        save_atomic(full, last_path)
    summary = {"epochs": record["epoch"], "best_miou": state["best_miou"],
               "train_time_s": round(state["train_time_s"], 2), "device": device, "world_size": world,
               "arch": cfg.arch, "size": list(cfg.size), "history": state["history"]}
    tmp = out / ".metrics.json.tmp"
    tmp.write_text(json.dumps(summary, indent=1))
    os.replace(tmp, out / "metrics.json")
