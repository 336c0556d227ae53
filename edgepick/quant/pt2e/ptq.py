"""Static PTQ's conversion: pt2e `convert`, then what static PTQ measures on the calibration
images, in this order: 7-bit weights where 8-bit ones would saturate (`WeightBits.FIRST_SEVEN`,
quant/pt2e/overflow.py), learnt weight rounding (AdaRound, quant/pt2e/adaround.py) on that weight grid, bias
correction (quant/pt2e/bias_correction.py) of what rounding leaves, and the conv biases on onnxruntime's
int32 grid. Cross-layer equalization acts before calibration, in `graph.prepare`."""

from __future__ import annotations

import copy
from collections.abc import Callable

import torch
from torch.fx import GraphModule

from edgepick.quant.config import (
    HEADROOM,
    SATURATION_CHECK_INPUTS,
    BiasCorrection,
    PtqMethods,
    QuantConfig,
    WeightBits,
    lockstep_images,
)
from edgepick.quant.methods import adaround_done
from edgepick.quant.pt2e.adaround import adaround
from edgepick.quant.pt2e.bias_correction import correct_biases
from edgepick.quant.pt2e.equalize import EQUALIZED
from edgepick.quant.pt2e.graph import PREFIX, convert
from edgepick.quant.pt2e.overflow import INT16, saturating_convs, to_seven_bit
from edgepick.quant.pt2e.quantizer import module_path
from edgepick.quant.pt2e.rewrites import snap_conv_biases


def measures(config: QuantConfig, methods: PtqMethods) -> bool:
    """Whether conversion runs the model on calibration inputs (first-7, AdaRound, bias correction),
    so that the caller keeps BIAS_CORRECTION_IMAGES of them."""
    return config.weight_bits == WeightBits.FIRST_SEVEN or methods.measures


def within_lockstep(samples: list[torch.Tensor]) -> list[torch.Tensor]:
    """The first SAMPLES (input batches) holding `lockstep_images` images of their size: the
    empirical bias correction and AdaRound hold all their activations at once."""
    if not samples:
        return samples
    wanted, kept, images = lockstep_images(*samples[0].shape[-2:]), [], 0
    for x in samples:
        if images >= wanted:
            break
        kept.append(x)
        images += x.shape[0]
    return kept


def convert_static(prepared: GraphModule, inputs: Callable[[], list[torch.Tensor]], config: QuantConfig,
                   methods: PtqMethods, progress: bool = False) -> tuple[GraphModule, dict]:
    """`convert` PREPARED (calibrated); with config.weight_bits first-7, METHODS' AdaRound or a bias correction,
    measure on INPUTS() (model input batches, called only then) against a copy of PREPARED taken before
    convert, which rewrites the graph it is given. Returns the graph and what was done:
    PROGRESS: a bar over AdaRound's convs. {"seven_bit_convs": [module paths]} for first-7, {"equalized_pairs": n} after CLE,
    {"adaround_convs": n} for the convs whose learnt rounding replaced round-to-nearest, {"measured_images": n}
    for the images AdaRound and bias correction used (`within_lockstep`)."""
    done: dict = {}
    if methods.equalize:
        done["equalized_pairs"] = len(prepared.meta.get(EQUALIZED, []))
    if not measures(config, methods):
        return convert(prepared), done
    reference = copy.deepcopy(prepared)
    converted = convert(prepared, snap_biases=False)
    samples = inputs()
    if config.weight_bits == WeightBits.FIRST_SEVEN:
        share = saturating_convs(converted, samples[:SATURATION_CHECK_INPUTS], HEADROOM * INT16)
        names = [name for name, s in share.items() if s > 0]
        to_seven_bit(reference, converted, names)
        paths = {n.name: module_path(n).removeprefix(PREFIX) for n in converted.graph.nodes}
        done["seven_bit_convs"] = [paths[name] for name in names]
    if methods.measures:
        samples = within_lockstep(samples)
        done["measured_images"] = sum(x.shape[0] for x in samples)
    if methods.adaround:
        done.update(adaround_done(adaround(reference, converted, samples, methods.adaround_budget_s, progress=progress)))
    if methods.bias_correction != BiasCorrection.NONE:
        correct_biases(reference, converted, samples, methods.bias_correction)
    snap_conv_biases(converted)
    return converted, done
