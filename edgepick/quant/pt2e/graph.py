"""The pt2e verbs on a DeepLabV3, as torchao's quantize_pt2e has them: `prepare` (observers for
static PTQ, or fake-quant for QaT), `calibrate` (the caller's images through the observers) and
`convert` (a Q/DQ graph with BatchNorm folded). prepare and convert assert that quantization really
happened, where pt2e would hand back a float model without a word."""

from __future__ import annotations

import itertools
import warnings
from collections.abc import Iterable, Iterator

import cv2
import numpy as np
import torch

from edgepick.errors import ConfigError, ParameterError, QuantizationError
from edgepick.geometry import Size, check_size
from edgepick.models.deeplabv3 import DeepLabV3, LogitsNet, trim_dilated_convs
from edgepick.quant.config import Pt2eOptions, QatOptions, QuantConfig, WeightBits
from edgepick.quant.fidelity import RuleScore, balanced_error
from edgepick.quant.pt2e.equalize import equalize as equalize_pairs
from edgepick.quant.pt2e.quantizer import EdgeQuantizer, RuleObserver, count_quant_nodes, module_path, under
from edgepick.quant.pt2e.rewrites import drop_fake_quants_after_dropout, gate_hardswish, snap_conv_biases
from edgepick.quant.pt2e.torchao_compat import bn_folds_with_own_eps, install_train_eval, patterns_traced_once, set_mode
from edgepick.quant.ranges import candidate_rules

PREFIX = "model."  # LogitsNet's attribute in front of every module name


def as_input(rgb: np.ndarray) -> torch.Tensor:
    """An HWC uint8 RGB image as the model's [1, 3, H, W] float input."""
    return torch.from_numpy(rgb).permute(2, 0, 1)[None].float()


def at_input_size(rgb: np.ndarray, size: Size, what: str = "calib") -> np.ndarray:
    """An HxWx3 uint8 RGB image at the model's input SIZE, area-resized as the runtime resizes a frame."""
    if not isinstance(rgb, np.ndarray) or rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        got = f"{rgb.dtype} {rgb.shape}" if isinstance(rgb, np.ndarray) else type(rgb).__name__
        raise ConfigError(f"{what}: images must be HxWx3 uint8 RGB arrays, got {got}")
    return rgb if rgb.shape[:2] == size.hw else cv2.resize(rgb, (size.width, size.height), interpolation=cv2.INTER_AREA)


def calibrate(prepared: torch.fx.GraphModule, images: Iterable[np.ndarray], size: Size | None = None,
              progress: bool = False, total: int | None = None, at_least_one: bool = True) -> int:
    """Run PREPARED on each of IMAGES (HxWx3 uint8 RGB, resized to the model's input SIZE when given)
    so that its observers see the activations; returns how many images it saw (at least one, unless
    not AT_LEAST_ONE). TOTAL: how many there are, for the progress line."""
    from edgepick.progress import progress as progress_bar

    device = next(prepared.parameters()).device
    seen = 0
    with torch.no_grad():
        for rgb in progress_bar(images, desc="calibrate", unit="img", total=total, enabled=progress):
            prepared(as_input(at_input_size(rgb, size) if size is not None else rgb).to(device))
            seen += 1
    if not seen and at_least_one:
        raise ConfigError("calib: no images; calibration needs at least one")
    return seen


def checked_first(images: Iterable[np.ndarray], size: Size, what: str = "calib") -> Iterator[np.ndarray]:
    """IMAGES as they come, the first one checked now: an empty or wrong input is refused before
    the slow prepare (torch.export) rather than after it."""
    it = iter(images)
    for first in it:
        at_input_size(first, size, what)
        return itertools.chain([first], it)
    raise ConfigError(f"{what}: no images; calibration needs at least one")


def first_of(images: Iterable[np.ndarray], count: int, kept: list[np.ndarray]) -> Iterator[np.ndarray]:
    """IMAGES as they come, the first COUNT of them also put in KEPT (for a check after calibrating)."""
    for rgb in images:
        if len(kept) < count:
            kept.append(rgb)
        yield rgb


def check_keep_float(model: torch.nn.Module, names: tuple[str, ...]) -> None:
    """Refuse module names (QuantConfig.keep_float) that MODEL does not have."""
    known = {n for n, _ in model.named_modules()}
    unknown = [n for n in names if n not in known]
    if unknown:
        raise ParameterError(f"{{keep_float:name}} names no module of the model: {', '.join(unknown)} "
                             f"(see 'edgepick quantize inspect' for layer names)", keep_float=tuple(unknown))


def prepare(model: torch.nn.Module, config: QuantConfig, size: Size, qat: bool | QatOptions,
            input_shape: tuple[int, ...] | None = None, equalize: bool = False,
            pt2e: Pt2eOptions | None = None) -> torch.fx.GraphModule:
    """torch.export + pt2e prepare of MODEL (changed in place: trimmed taps, gated hardswish as PT2E
    says); QAT (True, or QaT's options) gives a fake-quant graph with a batch dimension to train,
    False an observed graph for static PTQ. Raises if no observer or fake-quant was inserted (the
    silent-float trap). MODEL is edgepick's DeepLabV3 or any segmentation module (a `{"out": ...}`
    dict or a tensor out) taking [N, 3, H, W] at SIZE, or INPUT_SHAPE when given. With EQUALIZE
    (static PTQ only), conv pairs are equalized (quant/pt2e/equalize.py) before any observer runs."""
    from torchao.quantization.pt2e.quantize_pt2e import prepare_pt2e, prepare_qat_pt2e

    options = QatOptions() if qat is True else qat or None
    pt2e = pt2e or Pt2eOptions()
    check_size(size, "size")
    check_keep_float(model, config.keep_float)
    if options and equalize:
        raise ParameterError("{equalize}: a static PTQ method; QaT learns its weights in training", equalize=True)
    if options and config.weight_bits == WeightBits.FIRST_SEVEN:
        raise ParameterError("{weight_bits}: first-7 is measured after static calibration; QaT trains on one weight "
                             "grid from the start: use 7 or 8", weight_bits=config.weight_bits)
    if isinstance(model, DeepLabV3):
        trim_dilated_convs(model, size)  # exact; int8 kernels do not skip taps that only see padding
    if pt2e.hardswish_gate:
        gate_hardswish(model)
    qat = options is not None
    net = LogitsNet(model).train(qat)
    shape = tuple(input_shape) if input_shape else (1, 3, *size.hw)
    example = (torch.rand(2 if qat else shape[0], *shape[1:]) * 255,)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        batch = torch.export.Dim("batch", min=1, max=4096)  # QaT trains on batches
        graph = torch.export.export(net, example, dynamic_shapes=({0: batch},) if qat else None).module()
        quantizer = EdgeQuantizer(config, options, pt2e, prefix=PREFIX)
        with patterns_traced_once(graph):
            prepared = prepare_qat_pt2e(graph, quantizer) if qat else prepare_pt2e(graph, quantizer)
    # drop fake-quants nobody reads (left by the QaT conv-BN rewrite); train()/eval() would drop them
    # later anyway, and a checkpoint must load into a freshly prepared graph
    prepared.graph.eliminate_dead_code()
    if qat:
        drop_fake_quants_after_dropout(prepared)
    prepared.delete_all_unused_submodules()
    prepared.recompile()
    if count_quant_nodes(prepared) == 0:
        raise QuantizationError("pt2e inserted no observers: the model would stay float")
    if equalize:
        equalize_pairs(prepared)  # BN is folded and no observer has run yet
    install_train_eval(prepared, model, PREFIX)
    return prepared


def convert(prepared: torch.fx.GraphModule, snap_biases: bool = True) -> torch.fx.GraphModule:
    """pt2e convert (Q/DQ graph, BN folded with each BN's own eps), with conv biases on onnxruntime's
    int32 grid (snap_biases=False only to measure what that does: benchmarks/agreement.py)."""
    from torchao.quantization.pt2e.quantize_pt2e import convert_pt2e

    set_mode(prepared, training=False)
    with warnings.catch_warnings(), bn_folds_with_own_eps(prepared), patterns_traced_once(prepared):
        warnings.simplefilter("ignore")
        converted = convert_pt2e(prepared)
    if snap_biases:
        snap_conv_biases(converted)
    return converted


def choose_rule(prepared: torch.fx.GraphModule, held: list[torch.Tensor], config: QuantConfig, fitted: int,
                labels: bool = False) -> dict:
    """Set the range rule of PREPARED's activation observers (calibrated on FITTED other inputs than
    HELD) and count HELD in. With calib_method auto, PREPARED runs HELD with its activations on each
    candidate rule's uint8 grid (the weights float: they are the same for every rule), and the rule
    whose logits stay closest to fp32's is kept (each class weighted alike: the ONNX path's
    measure). LABELS (a segmentation model's logits, as edgepick's own checkpoints have): the rule
    that changes fewest of fp32's labels (argmax over channels) is kept, the logits' error breaking
    ties; the logits' error alone can prefer a tighter range that clips the few high logits a label
    turns on. With fewer FITTED inputs than HELD, HELD are counted in first and the choice is made
    on them. Returns what was chosen and measured."""
    observers = [m for m in prepared.modules() if isinstance(m, RuleObserver)]
    rules = candidate_rules(config)
    held_out = bool(held) and fitted >= len(held)
    device = next(prepared.parameters()).device
    if not held_out:
        _count_in(prepared, held, device)
    if len(rules) == 1 or not held or not observers:
        _count_in(prepared, held if held_out else [], device)  # a fixed rule: every input calibrates
        return {"rule": str(observers[0].rule) if observers else str(rules[0])}
    for o in observers:
        o.observing = False
    with torch.no_grad():
        reference = [_arrays(prepared(x.to(device))) for x in held]
        scores = []
        for rule in rules:
            for o in observers:
                o.simulate(rule)
            outputs = [_arrays(prepared(x.to(device))) for x in held]
            worst = max(balanced_error([r[k] for r in reference], [o[k] for o in outputs])
                        for k in range(len(reference[0])))
            if labels:  # counted only for logits known to be [N, classes, H, W]: another output may have no axis 1
                changed = sum(int((r[0].argmax(1) != o[0].argmax(1)).sum()) for r, o in zip(reference, outputs))
                scores.append(RuleScore(rule, worst, changed, sum(r[0][:, 0].size for r in reference)))
            else:
                scores.append(RuleScore(rule, worst))
    best = min(scores, key=lambda s: s.rank)
    for o in observers:
        o.simulate(None)
        o.rule, o.observing = best.rule, True
    if held_out:
        _count_in(prepared, held, device)
    return {"rule": str(best.rule), "held_out": len(held) if held_out else 0,
            "candidates": [s.to_dict() for s in scores]}


def _arrays(out: torch.Tensor | tuple | list) -> list[np.ndarray]:
    """A graph's output (a tensor, or several) as arrays."""
    return [t.detach().cpu().numpy() for t in (out if isinstance(out, (tuple, list)) else [out])]


def _count_in(prepared: torch.fx.GraphModule, inputs: list[torch.Tensor], device: torch.device) -> None:
    with torch.no_grad():
        for x in inputs:
            prepared(x.to(device))


def expected_int8_convs(prepared: torch.fx.GraphModule, config: QuantConfig) -> int:
    """Convs the quantizer was asked to quantize (all but those under --keep-float)."""
    paths = [module_path(n).removeprefix(PREFIX) for n in prepared.graph.nodes
             if n.op == "call_function" and n.target == torch.ops.aten.conv2d.default]
    return sum(not under(p, config.keep_float) for p in paths)
