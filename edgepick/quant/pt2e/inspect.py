"""Where does int8 drift from fp32? Per-layer comparison of the float graph and the quantized
simulation (what onnxruntime's qdq_loss_debug and NNCF's accuracy-aware tools offer), and an
accuracy-aware static pass that keeps the most drifting layers in float until the mIoU drop is
inside a budget.

Each conv group's output (the conv, or the BatchNorm after it, which int8 folds into the conv)
is taken from both graphs on the same images; SQNR = 10 log10(|fp32|^2 / |fp32 - int8|^2).
Errors accumulate through the network, so layers are ranked by the SQNR they LOSE relative to
the conv before them ("added drift"), not by their absolute SQNR.
"""

from __future__ import annotations

import functools
import math
import operator
import shutil
import sys
import tempfile
import warnings
from collections.abc import Iterable, Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from edgepick.data.native import NativeDataset
from edgepick.errors import ParameterError
from edgepick.export.onnx_export import check_onnx_out
from edgepick.geometry import Size
from edgepick.models.deeplabv3 import LogitsNet, trim_dilated_convs
from edgepick.quant.config import (
    BIAS_CORRECTION_IMAGES,
    MAX_FLOAT_LAYERS,
    BiasCorrection,
    CalibMethod,
    Pt2eOptions,
    PtqMethods,
    QuantConfig,
)
from edgepick.quant.pt2e.graph import PREFIX, as_input, at_input_size, calibrate, check_keep_float, first_of, prepare
from edgepick.quant.pt2e.ptq import convert_static, measures
from edgepick.quant.pt2e.quantizer import module_path
from edgepick.quant.ranges import RangeRule
from edgepick.quant.results import AccuracyAwareResult
from edgepick.train.checkpoint import Checkpoint

CONV = torch.ops.aten.conv2d.default
COMPARED_IMAGES = 8  # val images inspect compares fp32 and int8 on, by default
BATCH_NORMS = {torch.ops.aten.batch_norm.default, torch.ops.aten._native_batch_norm_legit_no_training.default}


def conv_group_outputs(gm: torch.fx.GraphModule) -> dict[torch.fx.Node, str]:
    """Node carrying each conv group's output -> the conv's module path."""
    out = {}
    for node in gm.graph.nodes:
        if node.op != "call_function" or node.target != CONV:
            continue
        carrier = node
        users = list(node.users)
        if len(users) == 1 and users[0].target in BATCH_NORMS:
            carrier = users[0]
            getitems = [u for u in carrier.users if u.target is operator.getitem and u.args[1] == 0]
            carrier = getitems[0] if getitems else carrier
        out[carrier] = module_path(node).removeprefix(PREFIX)
    return out


class _Recorder(torch.fx.Interpreter):
    def __init__(self, gm: torch.fx.GraphModule, wanted: dict[torch.fx.Node, str]):
        super().__init__(gm)
        self.wanted, self.values = wanted, dict[str, torch.Tensor]()

    def run_node(self, n: torch.fx.Node):
        result = super().run_node(n)
        if n in self.wanted:
            self.values[self.wanted[n]] = result.detach().float().clone()  # in-place ops (hardswish_) follow
        return result


def record(gm: torch.fx.GraphModule, x: torch.Tensor) -> tuple[dict[str, torch.Tensor], torch.Tensor]:
    """Conv group outputs by module path, and the logits, for one input."""
    rec = _Recorder(gm, conv_group_outputs(gm))
    with torch.no_grad():
        logits = rec.run(x)
    return rec.values, logits


def float_graph(model: torch.nn.Module, size: Size) -> torch.fx.GraphModule:
    trim_dilated_convs(model, size)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return torch.export.export(LogitsNet(model).eval(), (torch.rand(1, 3, *size.hw) * 255,)).module()


def _sqnr(signal: float, noise: float) -> float:
    return round(10 * math.log10(signal / noise), 2) if noise > 0 else math.inf


def compare(float_gm: torch.fx.GraphModule, int8_gm: torch.fx.GraphModule, images: list[np.ndarray]) -> dict:
    """Per-layer SQNR and added drift, logits SQNR and label agreement over IMAGES."""
    sig: dict[str, float] = {}
    noise: dict[str, float] = {}
    order: list[str] = []
    log_sig = log_noise = 0.0
    same = total = 0
    for rgb in images:
        x = as_input(rgb)
        f_vals, f_logits = record(float_gm, x)
        q_vals, q_logits = record(int8_gm, x)
        for path, f in f_vals.items():
            if path not in q_vals or q_vals[path].shape != f.shape:
                continue
            if path not in sig:
                order.append(path)
                sig[path] = noise[path] = 0.0
            sig[path] += float((f ** 2).sum())
            noise[path] += float(((f - q_vals[path]) ** 2).sum())
        log_sig += float((f_logits ** 2).sum())
        log_noise += float(((f_logits - q_logits) ** 2).sum())
        same += int((f_logits.argmax(1) == q_logits.argmax(1)).sum())
        total += f_logits.argmax(1).numel()
    layers, prev = [], None
    for path in order:
        s = _sqnr(sig[path], noise[path])
        layers.append({"layer": path, "sqnr_db": s,
                       "added_drift_db": None if prev is None or math.isinf(prev) or math.isinf(s) else round(prev - s, 2)})
        prev = s
    return {"layers": layers, "logits_sqnr_db": _sqnr(log_sig, log_noise),
            "label_agreement": round(same / total, 5) if total else None, "images": len(images)}


def ranked(report: dict) -> list[str]:
    """Layers by added drift, worst first (the keep-float candidates)."""
    rows = [r for r in report["layers"] if r["added_drift_db"] is not None]
    return [r["layer"] for r in sorted(rows, key=lambda r: -r["added_drift_db"])]


def _gain(after: float | None, before: float | None) -> float | None:
    """AFTER - BEFORE in dB, or None where either is missing or infinite (an exact layer)."""
    if after is None or before is None or not (math.isfinite(after) and math.isfinite(before)):
        return None
    return round(after - before, 2)


def method_stages(methods: PtqMethods) -> list[tuple[str, PtqMethods]]:
    """METHODS as cumulative stages in the order the pass applies them: first none of them (name ""),
    then with equalization, AdaRound and bias correction added one by one."""
    stage = replace(methods, equalize=False, adaround=False, bias_correction=BiasCorrection.NONE)
    stages = [("", stage)]
    for name, changes in (("equalize", {"equalize": True}), ("adaround", {"adaround": True}),
                          ("bias_correction", {"bias_correction": methods.bias_correction})):
        if getattr(methods, name) not in (False, BiasCorrection.NONE):
            stage = replace(stage, **changes)
            stages.append((name, stage))
    return stages


def inspect(checkpoint: str | Path | Checkpoint, calib: Iterable[np.ndarray], images: Sequence[np.ndarray],
            config: QuantConfig | None = None, methods: PtqMethods | None = None, pt2e: Pt2eOptions | None = None,
            progress: bool = True) -> dict:
    """Calibrate a static int8 model (in memory) on CALIB and compare it layer by layer with fp32 on
    IMAGES (HxWx3 uint8 RGB, resized to the model's input; `folder_images` draws both from a data set).
    With METHODS (equalize, adaround, bias_correction), the model is made again with each added in
    turn, and each layer says how many dB of SQNR each one gained it (`<method>_gain_db`);
    report[<method>] has the logits SQNR and label agreement after it."""
    config, methods = config or QuantConfig(), methods or PtqMethods()
    if not images:
        raise ParameterError("{images}: give at least one image to compare on", images=images)
    ckpt = checkpoint if isinstance(checkpoint, Checkpoint) else Checkpoint.load(checkpoint)
    size = ckpt.input_size
    float_gm = float_graph(ckpt.build_model(), size)
    compared = [at_input_size(rgb, size, "images") for rgb in images]
    stages = method_stages(methods)
    calib = list(calib) if len(stages) > 1 else calib  # each stage calibrates anew
    report: dict = {}
    for name, stage in stages:
        prepared = prepare(ckpt.build_model(), config, size, qat=False, equalize=stage.equalize, pt2e=pt2e)
        kept: list[np.ndarray] = []
        calibrate(prepared, first_of(calib, BIAS_CORRECTION_IMAGES, kept), size, progress)
        samples = [as_input(at_input_size(rgb, size)) for rgb in kept] if measures(config, stage) else []
        converted, measured = convert_static(prepared, functools.partial(list, samples), config, stage)
        result = compare(float_gm, converted, compared)
        if not name:
            report = {**result, "ranked": ranked(result), **measured}
            sqnr = {r["layer"]: r["sqnr_db"] for r in report["layers"]}
            continue
        report.update(measured)
        for row in report["layers"]:
            after = next((r["sqnr_db"] for r in result["layers"] if r["layer"] == row["layer"]), None)
            row[f"{name}_gain_db"] = _gain(after, sqnr.get(row["layer"]))
        sqnr = {r["layer"]: r["sqnr_db"] for r in result["layers"]}
        report[name] = {"logits_sqnr_db": result["logits_sqnr_db"], "label_agreement": result["label_agreement"]}
        if name == "bias_correction":
            report[name].update(method=methods.bias_correction.value, images=len(kept))
    return report


def quantize_accuracy_aware(checkpoint: str | Path, calib: Iterable[np.ndarray], data: str | Path, out: str | Path,
                            max_drop_pp: float, config: QuantConfig | None = None, methods: PtqMethods | None = None,
                            pt2e: Pt2eOptions | None = None, max_float_layers: int = MAX_FLOAT_LAYERS,
                            progress: bool = True) -> AccuracyAwareResult:
    """Static PTQ (CONFIG, METHODS) calibrated on CALIB (HxWx3 uint8 RGB images, every step on the
    same ones) that keeps the layers adding the most drift in float, one at a time, until the mIoU
    on DATA's val split (onnxruntime; its labels score each step) is within MAX_DROP_PP points of
    the fp32 model's, or MAX_FLOAT_LAYERS are float. Writes the best file found at OUT and reports
    every step."""
    from edgepick.evaluation import evaluate
    from edgepick.export.onnx_export import export_checkpoint
    from edgepick.quant.pt2e.images import agreement_images, check_classes, folder_images
    from edgepick.quant.pt2e.passes import quantize_static

    if not (math.isfinite(max_drop_pp) and max_drop_pp >= 0):
        raise ParameterError("{max_drop_pp}: must be a number of percentage points, 0 or more", max_drop_pp=max_drop_pp)
    if max_float_layers < 1:
        raise ParameterError("{max_float_layers}: must be at least 1", max_float_layers=max_float_layers)
    config, methods = config or QuantConfig(), methods or PtqMethods()
    check_onnx_out(out)
    n_val = len(NativeDataset.open(data, "val"))
    ckpt = Checkpoint.load(checkpoint)
    check_classes(ckpt, data)
    check_keep_float(ckpt.build_model(), config.keep_float)
    calib = [at_input_size(rgb, ckpt.input_size) for rgb in calib]  # held, for every step
    if not calib:
        raise ParameterError("{calib:name}: no images; calibration needs at least one", calib=None)
    compared, check = folder_images(data, "val", min(COMPARED_IMAGES, n_val), what="val images"), agreement_images(data)
    if n_val < COMPARED_IMAGES:  # said once every input has passed its checks: a refusal stays one line
        print(f"edgepick: warning: {data}/val has {n_val} images; the val mIoU that the accuracy-aware search "
              "compares moves in coarse steps on so few", file=sys.stderr, flush=True)
    work = Path(tempfile.mkdtemp(prefix="accuracy-aware-"))
    try:
        fp32 = export_checkpoint(checkpoint, work / "fp32.onnx").out
        base = evaluate(fp32, data, "val", progress=False)["miou"]
        candidates: list[str] | None = None  # ranked by `inspect` only once a step misses the budget
        keep = list(config.keep_float)
        steps: list[dict] = []
        chosen: dict | None = None
        while True:
            cfg = replace(config, keep_float=tuple(keep))
            path = work / f"step{len(steps)}.onnx"
            res = quantize_static(ckpt, calib, path, cfg, methods, pt2e, check_images=check, progress=False)
            if config.calib_method == CalibMethod.AUTO:  # the rule auto chose holds for the steps after this one
                config = RangeRule.parse(res.quant["ranges"]["rule"]).pinned(config)
            miou = evaluate(path, data, "val", progress=False)["miou"]
            drop = round(100 * (base - miou), 3)
            steps.append({"keep_float": list(keep), "val_miou": miou, "drop_pp": drop, "file": str(path)})
            if chosen is None or drop < chosen["drop_pp"]:
                chosen = {**steps[-1], "result": res}
            added = len(keep) - len(config.keep_float)
            if drop <= max_drop_pp or added >= max_float_layers:
                break
            if candidates is None:
                # the ranking is the first stage's (no method): the stages after it would be made for nothing
                candidates = ranked(inspect(ckpt, calib, compared, config, method_stages(methods)[0][1], pt2e,
                                            progress=progress))
            if not candidates:
                break
            keep.append(candidates.pop(0))
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        shutil.move(chosen["file"], out)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return AccuracyAwareResult(out=str(out), fp32_val_miou=base, budget_pp=max_drop_pp,
                               met=chosen["drop_pp"] <= max_drop_pp,
                               chosen={k: v for k, v in chosen.items() if k not in ("file", "result")}, steps=steps,
                               agreement_vs_torch=chosen["result"].agreement_vs_torch)
