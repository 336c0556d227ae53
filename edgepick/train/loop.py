"""`edgepick train`: one training loop for CPU, one GPU (bf16 AMP) and DDP (torchrun).

Per epoch: train with augmentation, validate (mIoU), write the run folder's checkpoints and
metrics (edgepick/train/run.py: best.pt when validation mIoU improves, epoch_NNN.pt at
the kept epochs, the hybrid-QaT switch points, then last.pt). `resume_run` continues from
last.pt, losing at most one epoch.

`fit` trains whatever model it is given and knows nothing of quantization: a model that needs
more from the loop (a QaT graph: its own train/eval switch, an eval copy for validation, a change
at a share of the steps, its own checkpoint entries) brings a `Hooks` object
(edgepick.quant.QatHooks), as torchao's pt2e flow expects: prepare_qat_pt2e returns a graph
and the user's own loop trains it.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.distributed as dist
import torch.nn.functional as F
from torch import nn

from edgepick.data.native import NativeDataset
from edgepick.errors import CheckpointError, ConfigError, ParameterError
from edgepick.files import made_by, mark
from edgepick.geometry import Size
from edgepick.metrics import segmentation_metrics
from edgepick.models.config import ModelConfig
from edgepick.models.zoo import build_model, load_backbone_weights
from edgepick.progress import progress as progress_bar
from edgepick.train.checkpoint import Checkpoint, load_weights
from edgepick.train.config import Augment, TrainConfig, check_world
from edgepick.train.data import IGNORE, augment, class_weights
from edgepick.train.run import EpochRecord, Run, TrainResult
from edgepick.train.setup import device_for, log, logits, make_loaders, validate
from edgepick.train.torchrun import dist_env


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
        """Checkpoint fields each checkpoint of the run carries besides the loop's own (a QaT run's `qat`)."""
        return {}


def model_config(cfg: TrainConfig, classes: list[str]) -> ModelConfig:
    """The architecture a run of CFG on CLASSES trains."""
    return ModelConfig(cfg.arch, len(classes), cfg.output_stride, cfg.colorspace, cfg.aux_loss, variant=cfg.variant)


def new_model(cfg: TrainConfig, start: Checkpoint | None = None) -> nn.Module:
    """The float model a run begins with: fresh (seeded with cfg.seed, cfg.backbone_weights if
    given), or the weights of START, a checkpoint the run continues (a float run's epoch_NNN.pt)."""
    classes = NativeDataset.open(cfg.data, "train").classes  # validates the layout before anything is written
    torch.manual_seed(cfg.seed)  # before the model: same seed, same initial weights
    model = build_model(model_config(cfg, classes))
    if cfg.backbone_weights:
        load_backbone_weights(model, cfg.backbone_weights)
    if start is not None:
        if list(start.classes) != classes:
            raise ConfigError(f"{start.path} was trained on classes {list(start.classes)}, the data has {classes}")
        if start.epoch >= cfg.epochs:
            raise ConfigError(f"{start.path} is at epoch {start.epoch}, the budget is {cfg.epochs} epochs")
        load_weights(model, {k: v for k, v in start.model.items() if cfg.aux_loss or not k.startswith("aux_classifier.")},
                     start)
    return model


def check_run(cfg: TrainConfig, resuming: bool = False) -> tuple[NativeDataset, NativeDataset]:
    """What a run of CFG stands on, checked before its first progress line (a QaT pass calls this before
    it prepares its graph): the torchrun environment, the device, a RUN folder that holds no run (unless
    RESUMING it), and the data's train and val splits, every image of them a PNG of one size (read from
    the files' headers: a broken data set is refused now, not in the middle of the first epoch).
    Returns the two splits."""
    _, world, local_rank = dist_env()
    device_for(cfg.device, local_rank)
    if not resuming:
        Run(cfg.out).check_new()
    splits = NativeDataset.open(cfg.data, "train"), NativeDataset.open(cfg.data, "val")
    for ds in splits:
        ds.check_files()
    check_world(cfg, world)
    return splits


def train(cfg: TrainConfig, resume: bool = False, progress: bool = True) -> TrainResult:
    """Train a float segmentation model on a native data set (resume: continue cfg.out from its last.pt, see
    resume_run); returns the final summary."""
    if resume:
        return resume_run(cfg.out, cfg.data, cfg.epochs, progress)
    return fit(cfg, new_model(cfg), progress=progress)


def resume_run(out: str | Path, data: str | Path, epochs: int | None = None, progress: bool = True) -> TrainResult:
    """Continue the float run in OUT from its last.pt on DATA (the run's own data set, at any path:
    a run moves with its data), to a budget of EPOCHS (None: the run's own), never below the epochs
    it has done; returns the final summary."""
    if epochs is not None and epochs < 1:
        raise ParameterError("{epochs}: must be at least 1", epochs=epochs)
    run = Run(out)
    if not run.holds_run():
        raise ConfigError(f"nothing to resume: {run.last} does not exist")
    last = Checkpoint.load(run.last)
    if last.is_qat:
        raise CheckpointError(f"{out} is a QaT run; run its quantize command again to start it anew")
    if last.train_config is None:
        raise CheckpointError(f"{last.path} has no train_config to resume with")
    last.build_model()  # its weights fit the architecture it names, or one line says which tensor does not
    budget = last.train_config.epochs if epochs is None else epochs
    cfg = replace(last.train_config, epochs=max(budget, last.epoch), data=str(data))
    check_same_data(last, cfg.data)
    return fit(cfg, new_model(cfg), resume=last, progress=progress)


def check_same_data(last: Checkpoint, data: str) -> None:
    """Refuse to resume RUN on a data set other than the one it was trained on: other class names,
    or (runs that recorded it) images of another size."""
    train_ds = NativeDataset.open(data, "train")
    if train_ds.classes != list(last.classes):
        raise ConfigError(f"DATA {data} has the classes {train_ds.classes}, the run to resume was trained on "
                          f"{list(last.classes)}; give the run's own data set")
    recorded = last.data_image_size
    if recorded is not None and Size.of(train_ds.rgb(train_ds.ids[0])) != recorded:
        raise ConfigError(f"DATA {data} holds images of another size than the {recorded} the run was trained on; "
                          "give the run's own data set")


def carry_optimizer_state(opt: torch.optim.Optimizer, model: torch.nn.Module, start: Checkpoint,
                          prefix: str = "") -> int:
    """Give OPT (over MODEL, whose parameter names are the float model's behind PREFIX) the AdamW
    moments that the float checkpoint START holds, matched by name; returns how many got them."""
    saved = (start.optimizer or {}).get("state", {})
    names = [n for n, _ in build_model(start.model_config).named_parameters()]
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
                    steps_per_epoch: int, start: Checkpoint | None, carry_optimizer: bool, prefix: str,
                    resume: Checkpoint | None) -> dict:
    """The run's bookkeeping (epoch, history, best mIoU, times) at its first epoch: fresh, continuing
    START's schedule (and its AdamW moments), or RESUME's own state (weights, optimizer, schedule)."""
    state: dict[str, Any] = {"epoch": 0, "history": [], "best_miou": -1.0, "train_time_s": 0.0, "phase_start": 0,
             "init_train_time_s": 0.0}
    if start is not None:
        if carry_optimizer:
            carry_optimizer_state(opt, model, start, prefix)
        state.update(epoch=start.epoch, history=list(start.history), phase_start=start.epoch,
                     init_train_time_s=start.train_time_s)
        with warnings.catch_warnings():  # fast-forwarding the LR schedule before any optimizer step
            warnings.simplefilter("ignore")
            for _ in range(start.epoch * steps_per_epoch):
                sched.step()
    if resume is not None:
        if resume.optimizer is None or resume.scheduler is None:
            raise CheckpointError(f"{resume.path} holds no optimizer state to resume from (a best.pt?)")
        load_weights(model, resume.model, resume)
        opt.load_state_dict(resume.optimizer)
        sched.load_state_dict(resume.scheduler)
        state = {k: getattr(resume, k) for k in state}
        state["history"] = list(state["history"])
    return state


def fit(cfg: TrainConfig, model: torch.nn.Module, hooks: Hooks | None = None, start: Checkpoint | None = None,
        carry_optimizer: bool = True, resume: Checkpoint | None = None, progress: bool = True) -> TrainResult:
    """Train MODEL (built for cfg's data and size) for cfg.epochs, writing cfg.out's checkpoints
    and metrics. START: the checkpoint MODEL's weights come from, whose epochs, history and LR
    schedule the run continues (with its AdamW moments unless carry_optimizer is False); RESUME:
    this run's own last.pt. Returns the final summary. Per epoch, in order: the steps
    (_Steps.epoch), validation, the epoch's record and its checkpoints (_save_epoch)."""
    hooks = hooks or Hooks()
    train_ds, val_ds = check_run(cfg, resuming=resume is not None)
    rank, world, local_rank = dist_env()
    device = device_for(cfg.device, local_rank)
    run = Run(cfg.out)
    classes = train_ds.classes
    cuda = device.type == "cuda"
    if world > 1 and not dist.is_initialized():
        dist.init_process_group("nccl" if cuda else "gloo")
    if cuda:
        torch.cuda.set_device(device)
        model = model.to(device, memory_format=torch.channels_last)
    loaders = make_loaders(cfg, train_ds, val_ds, cuda, rank, world)
    weights = class_weights(train_ds, len(classes)).to(device) if cfg.class_weighting else None
    opt, sched, per_epoch = _optimizer(cfg, model, device, len(loaders.train))
    state = _starting_state(model, opt, sched, per_epoch, start, carry_optimizer, hooks.param_prefix, resume)
    if resume is not None:
        log(f"resuming {run.path} after epoch {state['epoch']}", rank)
    ddp = torch.nn.parallel.DistributedDataParallel(model) if world > 1 else model
    steps = _Steps(cfg, model, ddp, hooks, device, opt, sched, weights, amp=cuda and hooks.bf16)  # bf16 on GPU only
    meta: dict[str, Any] = {"model_config": model_config(cfg, classes), "classes": tuple(classes), "input_size": cfg.size,
            "train_config": cfg, "world_size": world, "data_image_size": Size.of(train_ds.rgb(train_ds.ids[0]))}
    gen = torch.Generator().manual_seed(cfg.seed * 1000 + state["epoch"] + rank)
    hooks.begin(model, device, state["phase_start"] * per_epoch, cfg.epochs * per_epoch)

    for epoch in range(state["epoch"] + 1, cfg.epochs + 1):
        if isinstance(loaders.sampler, torch.utils.data.DistributedSampler):
            loaders.sampler.set_epoch(epoch)
        hooks.epoch_start(ddp)
        t0 = time.perf_counter()
        bar = progress_bar(loaders.train, desc=f"epoch {epoch}/{cfg.epochs}", unit="batch",
                           enabled=progress and rank == 0)
        loss_sum, seen = steps.epoch(bar, gen)
        train_s = time.perf_counter() - t0
        cm = validate(hooks.eval_model(model), loaders.val, len(classes), device, steps.amp)
        if world > 1:
            cm, loss_sum, seen = _all_reduce(cm, loss_sum, seen, device)
        record = _record(epoch, segmentation_metrics(cm, classes), loss_sum, seen, train_s,
                         time.perf_counter() - t0, loaders.n_val)
        state["train_time_s"] += record.epoch_s
        state["history"].append(record.to_dict())
        state["epoch"] = epoch
        log(f"epoch {epoch}/{cfg.epochs}: loss {record.loss:.4f}  val pixel acc {record.pixel_acc:.4f}  "
            f"mIoU {record.miou:.4f}  {record.epoch_s:.1f}s", rank)
        if rank == 0:
            _save_epoch(run, cfg, steps, state, record, meta, str(device), world)
        if world > 1:
            dist.barrier()
    if world > 1:
        dist.destroy_process_group()
    history = state["history"]
    return TrainResult(out=str(run.path), epochs=state["epoch"], best_miou=state["best_miou"],
                       train_time_s=round(state["train_time_s"], 2),
                       last=EpochRecord(**history[-1]) if history else None)


def _optimizer(cfg: TrainConfig, model: torch.nn.Module, device: torch.device, batches: int
               ) -> tuple[torch.optim.Optimizer, torch.optim.lr_scheduler.LambdaLR, int]:
    """AdamW over MODEL, its schedule over cfg.epochs of BATCHES steps, and the steps per epoch."""
    # on a CPU the fused AdamW kernel is several times faster per step than the multi-tensor default,
    # whose step costs as much as the forward pass at small input sizes; a GPU keeps PyTorch's default
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay,
                            fused=True if device.type == "cpu" else None)
    per_epoch = max(1, batches)
    return opt, _schedule(opt, cfg.epochs * per_epoch), per_epoch


@dataclass(frozen=True)
class _Steps:
    """What fit's optimizer steps use: the model and the module that trains it (its DDP wrapper on more
    than one process), the hooks, the device, AdamW and its schedule, the loss's class weights, and
    whether the forward pass runs under bf16 autocast (AMP)."""

    cfg: TrainConfig
    model: torch.nn.Module
    ddp: torch.nn.Module
    hooks: Hooks
    device: torch.device
    opt: torch.optim.Optimizer
    sched: torch.optim.lr_scheduler.LambdaLR
    weights: torch.Tensor | None
    amp: bool

    def epoch(self, batches, gen: torch.Generator) -> tuple[float, int]:
        """One epoch's steps over BATCHES (a progress bar over the train loader), augmented with GEN;
        returns the summed loss (per image) and the images seen."""
        device, cuda = self.device, self.device.type == "cuda"
        loss_sum, seen = 0.0, 0
        for img, mask in batches:
            x = img.to(device, non_blocking=True).permute(0, 3, 1, 2).float()
            y = mask.to(device, non_blocking=True).long()
            x, y = augment(x, y, gen, lights=self.cfg.augment == Augment.LIGHTS)
            if cuda:
                x = x.contiguous(memory_format=torch.channels_last)
            loss = self.loss(x, y)
            self.opt.zero_grad(set_to_none=True)
            loss.backward()
            self.opt.step()
            self.sched.step()
            self.hooks.after_step(self.model, self.sched.last_epoch)
            loss_sum += float(loss.detach()) * len(x)
            seen += len(x)
            batches.set_postfix(loss=f"{loss_sum / seen:.3f}")
        return loss_sum, seen

    def loss(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        """The weighted cross-entropy of a batch (plus 0.4 of the auxiliary head's, where the model has one)."""
        with torch.autocast(self.device.type, dtype=torch.bfloat16, enabled=self.amp):
            outputs = logits(self.ddp, x)
            loss = F.cross_entropy(outputs["out"].float(), y, weight=self.weights, ignore_index=IGNORE)
            if "aux" in outputs:
                loss = loss + 0.4 * F.cross_entropy(outputs["aux"].float(), y, weight=self.weights,
                                                    ignore_index=IGNORE)
        return loss


def _save_epoch(run: Run, cfg: TrainConfig, steps: _Steps, state: dict, record: EpochRecord, meta: dict,
                device: str, world: int) -> None:
    """Rank 0 after each epoch: the best mIoU so far updated, the epoch's checkpoints (_save) and metrics.json."""
    improved = (record.miou or 0.0) > state["best_miou"]
    if improved:
        state["best_miou"] = record.miou or 0.0
    ckpt = Checkpoint(model=steps.model.state_dict(), optimizer=steps.opt.state_dict(), scheduler=steps.sched.state_dict(),
                      **meta, **{**state, "history": tuple(state["history"])}, **steps.hooks.checkpoint())
    _save(run, ckpt, improved, record.epoch in cfg.keep_epochs)
    run.write_metrics({"epochs": record.epoch, "best_miou": state["best_miou"],
                       "train_time_s": round(state["train_time_s"], 2), "device": device,
                       "world_size": world, "arch": cfg.arch, "size": list(cfg.size.hw),
                       "history": state["history"]})


def _all_reduce(cm: np.ndarray, loss_sum: float, seen: int, device: torch.device) -> tuple[np.ndarray, float, int]:
    """Sum the ranks' confusion matrices and loss totals (DDP)."""
    t = torch.tensor(cm, device=device)
    dist.all_reduce(t)
    stats = torch.tensor([loss_sum, seen], dtype=torch.float64, device=device)
    dist.all_reduce(stats)
    return t.cpu().numpy(), float(stats[0]), int(stats[1])


def _record(epoch: int, m: dict, loss_sum: float, seen: int, train_s: float, epoch_s: float,
            n_val: int) -> EpochRecord:
    """One epoch's entry of metrics.json's history."""
    return EpochRecord(epoch=epoch, loss=round(loss_sum / max(seen, 1), 5), pixel_acc=m["pixel_acc"], miou=m["miou"],
                       per_class_iou={c: v["iou"] for c, v in m["per_class"].items()}, epoch_s=round(epoch_s, 2),
                       train_s=round(train_s, 2), images=seen, val_images=n_val, images_per_s=round(seen / train_s, 2))


def _save(run: Run, ckpt: Checkpoint, improved: bool, kept: bool) -> None:
    """best.pt if validation mIoU improved, epoch_NNN.pt if the epoch is kept, then last.pt: last
    comes last, so a run killed in between resumes from the epoch before and writes the others again.
    Each file is written atomically."""
    run.path.mkdir(parents=True, exist_ok=True)  # only now: a failed first epoch leaves no RUN behind
    if made_by(run.path) != "train":
        mark(run.path, "train")
    if improved:  # the weights to export and quantize
        ckpt.without_optimizer().save(run.best)
    if kept:  # a hybrid-QaT switch point: it carries the AdamW moments on
        ckpt.save(run.epoch(ckpt.epoch))
    ckpt.save(run.last)
