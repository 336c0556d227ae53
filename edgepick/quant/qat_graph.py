"""Upkeep of a QaT graph (torchao pt2e): loading its state, its eval form, and a calibrated start
for QaT from a float checkpoint (hybrid-QaT). torchao's BatchNorm rewrites are kept in check in
torchao_compat.py.

A QaT graph's activation fake-quants take their first range from the first training batch's
min/max, then follow it with a moving average (1% a step), where static PTQ uses percentile
ranges; a hybrid run of a few epochs at the tail of the learning-rate schedule has little room
to train such a start back. `calibrate_activations` gives the fake-quants static PTQ's ranges
instead (hybrid-QaT's default; docs/quantization.md#hybrid-qat).
"""

from __future__ import annotations

import numpy as np
import torch

from edgepick.quant.quantizer import PercentileObserver
from edgepick.quant.torchao_compat import set_mode

def load_qat_state(prepared: torch.fx.GraphModule, state: dict) -> None:
    """Load a QaT run's state dict into a freshly prepared graph (strict: every entry must match)."""
    prepared.load_state_dict(state)


def to_eval(prepared: torch.fx.GraphModule) -> torch.fx.GraphModule:
    """BN on running statistics, dropout off (torchao's eval rewrite), BN literals kept; also on a
    deep copy, which loses the graph's own train/eval methods."""
    return set_mode(prepared, training=False)


def activation_fake_quants(prepared: torch.nn.Module) -> dict[str, torch.nn.Module]:
    """The per-tensor (activation) fake-quant modules of a QaT graph, by name."""
    from torchao.quantization.pt2e import FakeQuantizeBase

    return {name: m for name, m in prepared.named_modules()
            if isinstance(m, FakeQuantizeBase) and not m.is_per_channel}


def calibrate_activations(prepared: torch.fx.GraphModule, images: list[np.ndarray], percentile: float = 99.99,
                          hold: bool = False) -> int:
    """Set every activation fake-quant of the QaT graph PREPARED (in training mode) to the
    PERCENTILE range of its float input over IMAGES (HWC uint8 RGB), as static PTQ would; with
    HOLD, its observer then stays off, so QaT trains against those ranges. Returns how many were set."""
    from torchao.quantization.pt2e import disable_fake_quant, disable_observer, enable_fake_quant, enable_observer

    targets = activation_fake_quants(prepared)
    observers = {name: PercentileObserver(percentile=percentile, eps=2 ** -12, dtype=torch.quint8,
                                          quant_min=fq.activation_post_process.quant_min,
                                          quant_max=fq.activation_post_process.quant_max) for name, fq in targets.items()}
    hooks = [fq.register_forward_pre_hook(lambda mod, args, o=observers[name]: o(args[0].detach().float().cpu()))
             for name, fq in targets.items()]
    device = next(prepared.parameters()).device
    prepared.apply(disable_fake_quant)
    prepared.apply(disable_observer)
    to_eval(prepared)  # BN on running statistics, as at deployment
    try:
        with torch.no_grad():
            for rgb in images:
                prepared(torch.from_numpy(rgb).permute(2, 0, 1)[None].float().to(device))
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
