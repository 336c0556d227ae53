"""QaT: a DeepLabV3 prepared with fake-quant and trained by edgepick.train's own loop (torchao's
design: prepare_qat_pt2e returns a graph and the user's loop trains it). This module owns the
graph's life around that loop (`QatHooks`): a calibrated start, the freeze of observers and
BatchNorm statistics at a share of the steps, an eval-mode copy for validation, the checkpoint
record, and loading a checkpoint back into a graph (`load_qat`).

A QaT graph's activation fake-quants take their first range from the first training batch's
min/max, then follow it with a moving average (1% a step), where static PTQ uses percentile
ranges; a hybrid run of a few epochs at the tail of the learning-rate schedule has little room
to train such a start back. `calibrate_activations` gives the fake-quants static PTQ's ranges
instead (hybrid-QaT's default; docs/quantization.md#hybrid-qat). torchao's BatchNorm rewrites
are kept in check in torchao_compat.py.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
import torch

from edgepick.errors import CheckpointError
from edgepick.models.zoo import build_model
from edgepick.quant.config import FREEZE_AT, CalibMethod, Pt2eOptions, QatOptions, QuantConfig
from edgepick.quant.pt2e.graph import PREFIX, calibrate, prepare
from edgepick.quant.pt2e.quantizer import RuleObserver
from edgepick.quant.pt2e.torchao_compat import set_mode
from edgepick.quant.ranges import RangeRule
from edgepick.train.checkpoint import Checkpoint, load_weights
from edgepick.train.config import TrainConfig
from edgepick.train.loop import Hooks, fit, new_model
from edgepick.train.run import TrainResult


def to_eval(prepared: torch.fx.GraphModule) -> torch.fx.GraphModule:
    """BN on running statistics, dropout off (torchao's eval rewrite), BN literals kept; also on a
    deep copy, which loses the graph's own train/eval methods."""
    return set_mode(prepared, training=False)


def activation_fake_quants(prepared: torch.nn.Module) -> dict[str, torch.nn.Module]:
    """The per-tensor (activation) fake-quant modules of a QaT graph, by name."""
    from torchao.quantization.pt2e import FakeQuantizeBase

    return {name: m for name, m in prepared.named_modules()
            if isinstance(m, FakeQuantizeBase) and not m.is_per_channel}


def _observing(observer: Callable[[torch.Tensor], object]) -> Callable:
    """A forward pre-hook that shows a module's input to OBSERVER (on the CPU) and leaves the input
    as it is: a pre-hook that returns a value replaces the input, here with a CPU copy."""
    def hook(module: torch.nn.Module, args: tuple) -> None:
        observer(args[0].detach().float().cpu())
    return hook


def calibrate_activations(prepared: torch.fx.GraphModule, images: list[np.ndarray], percentile: float = 99.99,
                          hold: bool = False) -> int:
    """Set every activation fake-quant of the QaT graph PREPARED (in training mode) to the
    PERCENTILE range of its float input over IMAGES (HWC uint8 RGB), as static PTQ would; with
    HOLD, its observer then stays off, so QaT trains against those ranges. Returns how many were set."""
    from torchao.quantization.pt2e import disable_fake_quant, disable_observer, enable_fake_quant, enable_observer

    targets = activation_fake_quants(prepared)
    rule = RangeRule(CalibMethod.PERCENTILE, percentile)
    observers = {name: RuleObserver(rule=rule, eps=2 ** -12, dtype=torch.quint8,
                                    quant_min=fq.activation_post_process.quant_min,
                                    quant_max=fq.activation_post_process.quant_max) for name, fq in targets.items()}
    hooks = [fq.register_forward_pre_hook(_observing(observers[name])) for name, fq in targets.items()]
    prepared.apply(disable_fake_quant)
    prepared.apply(disable_observer)
    to_eval(prepared)  # BN on running statistics, as at deployment
    try:
        calibrate(prepared, images)
    finally:
        for h in hooks:
            h.remove()
    for name, fq in targets.items():
        lo, hi = observers[name]._non_linear_param_search()
        obs = fq.activation_post_process
        obs.min_val.copy_(torch.minimum(torch.as_tensor(lo, dtype=torch.float32), torch.zeros(())))
        obs.max_val.copy_(torch.maximum(torch.as_tensor(hi, dtype=torch.float32), torch.zeros(())))
        scale, zero_point = obs.calculate_qparams()
        fq.scale.copy_(scale.reshape(fq.scale.shape))
        fq.zero_point.copy_(zero_point.reshape(fq.zero_point.shape))
    set_mode(prepared, training=True)
    prepared.apply(enable_fake_quant)
    prepared.apply(enable_observer)
    if hold:
        for fq in targets.values():
            fq.disable_observer()
    return len(targets)


def eval_copy(prepared: torch.fx.GraphModule) -> torch.fx.GraphModule:
    """An eval-mode copy of a QaT graph: switching the graph itself between train and eval rewrites
    it (about 1 s each way), so each epoch copies the weights into this copy instead."""
    evaluator = copy.deepcopy(prepared)
    to_eval(evaluator)  # not .eval(): the copied train/eval methods act on the original
    return evaluator


def freeze(prepared: torch.fx.GraphModule) -> None:
    """End of QaT's range learning: observers stop and BN uses its running statistics (standard practice)."""
    from torchao.quantization.pt2e import disable_observer

    prepared.apply(disable_observer)
    to_eval(prepared)


class QatHooks(Hooks):
    """A QaT graph in the training loop: it trains in fp32 (fake-quant ops reject bf16), starts from
    static PTQ's ranges (config.percentile) when given CALIB_IMAGES (HOLD_RANGES: and keeps them),
    freezes after qat.freeze_at of the run's steps, validates on an eval-mode copy until then, and
    records its configs in each checkpoint."""

    bf16 = False
    param_prefix = PREFIX

    def __init__(self, config: QuantConfig, qat: QatOptions | None = None, pt2e: Pt2eOptions | None = None,
                 calib_images: list[np.ndarray] | None = None, hold_ranges: bool = False):
        self.config, self.qat, self.pt2e = config, qat or QatOptions(), pt2e or Pt2eOptions()
        self.calib_images, self.hold_ranges = calib_images, hold_ranges
        self.frozen, self.freeze_step, self.evaluator = False, 0, None

    def begin(self, model: torch.nn.Module, device: torch.device, first_step: int, last_step: int) -> None:
        if self.calib_images:
            calibrate_activations(model, self.calib_images, self.config.percentile, hold=self.hold_ranges)
        self.freeze_step = round(first_step + (last_step - first_step) * self.qat.freeze_at)
        self.evaluator = eval_copy(model)
        model.train()  # the graph's own switch: BatchNorm literals kept (torchao_compat.py)

    def epoch_start(self, model: torch.nn.Module) -> None:
        """The graph stays in its mode: training until frozen, eval after."""

    def after_step(self, model: torch.nn.Module, step: int) -> None:
        if not self.frozen and step >= self.freeze_step:
            freeze(model)
            self.frozen = True

    def eval_model(self, model: torch.nn.Module) -> torch.nn.Module:
        if self.frozen:  # in eval mode for good
            return model
        assert self.evaluator is not None, "begin() makes the evaluation copy"
        self.evaluator.load_state_dict(model.state_dict())
        return self.evaluator

    def checkpoint(self) -> dict:
        quant = {**self.config.to_dict(), **self.qat.to_dict(), **self.pt2e.to_dict()}
        return {"qat": {"quant": quant, "freeze_at": self.qat.freeze_at, "calib_images": len(self.calib_images or []),
                        "hold_ranges": self.hold_ranges}}


@dataclass(frozen=True)
class QatTraining:
    """A finished QaT run: its summary, and the fake-quant graph it trained (as its last step left it)."""

    result: TrainResult
    graph: torch.fx.GraphModule


def train_qat(cfg: TrainConfig, config: QuantConfig, qat: QatOptions | None = None, pt2e: Pt2eOptions | None = None,
              start: Checkpoint | None = None, carry_optimizer: bool = True,
              calib_images: list[np.ndarray] | None = None, hold_ranges: bool = False,
              progress: bool = True) -> QatTraining:
    """A QaT run into cfg.out: the float model (fresh, or START's weights and schedule: hybrid-QaT)
    prepared with fake-quant, then trained by edgepick.train's loop with QatHooks."""
    qat = qat or QatOptions()
    cfg = replace(cfg, aux_loss=False)  # the deployed graph has no auxiliary head
    graph = prepare(new_model(cfg, start), config, cfg.size, qat=qat, pt2e=pt2e)
    hooks = QatHooks(config, qat, pt2e, calib_images, hold_ranges)
    result = fit(cfg, graph, hooks, start=start, carry_optimizer=carry_optimizer, progress=progress)
    return QatTraining(result, graph)


def qat_configs(checkpoint: Checkpoint) -> tuple[QuantConfig, QatOptions, Pt2eOptions]:
    """The configs a QaT run's checkpoint was trained with (also from checkpoints that recorded one
    QuantConfig with every pass's fields)."""
    if checkpoint.qat is None:
        raise CheckpointError(f"{checkpoint.path} is not a QaT run's checkpoint")
    record = {**checkpoint.qat["quant"], "freeze_at": checkpoint.qat.get("freeze_at", FREEZE_AT)}
    return QuantConfig.from_dict(record), QatOptions.from_dict(record), Pt2eOptions.from_dict(record)


def load_qat(checkpoint: Checkpoint, graph: torch.fx.GraphModule | None = None) -> torch.fx.GraphModule:
    """A QaT run's fake-quant graph with its checkpoint's state: GRAPH, the graph the run trained
    (moved to the CPU), or else one rebuilt from the checkpoint's model config (torch.export and
    pt2e prepare again: seconds to a minute on a CPU)."""
    if graph is None:
        config, qat, pt2e = qat_configs(checkpoint)
        graph = prepare(build_model(checkpoint.model_config), config, checkpoint.input_size, qat=qat, pt2e=pt2e)
    else:
        graph.to("cpu", memory_format=torch.contiguous_format)  # trained on a GPU: channels-last there
    load_weights(graph, checkpoint.model, checkpoint)  # strict: every entry must match
    return graph
