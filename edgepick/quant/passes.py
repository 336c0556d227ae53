"""The int8 passes: static PTQ, QaT from scratch, hybrid-QaT; each ends in an ONNX model
(docs/contracts.md#onnx-model).

One public function per pass (`quantize_static`, `quantize_qat`, `quantize_hybrid`), like
onnxruntime's quantize.py; the CLI is a thin layer over them. All go through torchao's
pt2e flow: torch.export -> prepare(_qat)_pt2e with `EdgeQuantizer` -> convert_pt2e ->
torch.onnx.export(dynamo=True), and all assert that quantization really happened.
"""

from __future__ import annotations

import sys
import time
import warnings
from operator import attrgetter
from pathlib import Path

import cv2
import numpy as np
import torch

from edgepick.data.native import NativeDataset
from edgepick.errors import CheckpointError, ConfigError, EdgepickError
from edgepick.export.checks import conv_weight_report, label_agreement
from edgepick.export.onnx_export import EXPORT_PASSES, LogitsNet, contract_metadata, export_onnx
from edgepick.models.deeplabv3 import trim_dilated_convs
from edgepick.quant.qat_graph import load_qat_state, to_eval
from edgepick.quant.torchao_compat import bn_folds_with_own_eps, install_train_eval
from edgepick.progress import progress as progress_bar
from edgepick.quant.quantizer import (
    EdgeQuantizer,
    QuantConfig,
    count_quant_nodes,
    module_path,
    under,
)

PREFIX = "model."  # LogitsNet's attribute in front of every module name


class QuantizationError(EdgepickError):
    """A pass that would silently produce an unquantized model."""


DEFAULT_CALIB_IMAGES = 64  # or the whole train split when it is smaller


def model_images(data: str | Path, split: str, count: int | None, size: tuple[int, int], seed: int = 0) -> list[np.ndarray]:
    """COUNT images of DATA/<split> (None: DEFAULT_CALIB_IMAGES, or all if fewer), chosen with
    SEED, area-resized to the model's (H, W)."""
    ds = NativeDataset.open(data, split)
    count = min(DEFAULT_CALIB_IMAGES, len(ds)) if count is None else count
    if count < 1:
        raise ConfigError("the number of calibration images must be at least 1")
    if len(ds) < count:
        raise ConfigError(f"asked for {count} calibration images, but {data}/{split} has only {len(ds)}")
    ids = [ds.ids[i] for i in sorted(np.random.default_rng(seed).choice(len(ds), count, replace=False))]
    h, w = size
    return [cv2.resize(ds.rgb(i), (w, h), interpolation=cv2.INTER_AREA) for i in ids]


def _as_input(rgb: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(rgb).permute(2, 0, 1)[None].float()


def check_keep_float(model: torch.nn.Module, names: list[str]) -> None:
    known = {n for n, _ in model.named_modules()}
    unknown = [n for n in names if n not in known]
    if unknown:
        raise ConfigError(f"--keep-float names no module of the model: {', '.join(unknown)} "
                          f"(see 'edgepick quantize inspect' for layer names)")


def check_classes(ckpt: dict, data: str | Path) -> None:
    classes = NativeDataset.open(data, "train").classes
    if classes != ckpt["classes"]:
        raise CheckpointError(f"the checkpoint's classes {ckpt['classes']} differ from the data set's {classes}")


class GatedHardswish(torch.nn.Module):
    """hardswish(x) written as x * hardsigmoid(x). Quantized, the gate gets its own uint8 grid and
    onnxruntime runs both halves on integer kernels (QLinearAdd after export's integer_activations,
    QLinearMul); a quantized HardSwish it runs in float, dequantizing the whole map."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x * torch.nn.functional.hardsigmoid(x)


def gate_hardswish(model: torch.nn.Module) -> int:
    """Replace every nn.Hardswish of MODEL by GatedHardswish (the same function; no weights move)."""
    names = [name for name, m in model.named_modules() if isinstance(m, torch.nn.Hardswish)]
    for name in names:
        parent, _, child = name.rpartition(".")
        setattr(model.get_submodule(parent), child, GatedHardswish())
    return len(names)


def prepare(model: torch.nn.Module, config: QuantConfig, size: tuple[int, int], qat: bool) -> torch.fx.GraphModule:
    """torch.export + pt2e prepare of MODEL (changed in place); raises if no observer/fake-quant was
    inserted (the silent-float trap)."""
    from torchao.quantization.pt2e.quantize_pt2e import prepare_pt2e, prepare_qat_pt2e

    check_keep_float(model, config.keep_float)
    trim_dilated_convs(model, size)  # exact; int8 kernels do not skip taps that only see padding
    if config.hardswish_gate:
        gate_hardswish(model)
    net = LogitsNet(model).train(qat)
    example = (torch.rand(2 if qat else 1, 3, *size) * 255,)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        batch = torch.export.Dim("batch", min=1, max=4096)  # QaT trains on batches
        graph = torch.export.export(net, example, dynamic_shapes=({0: batch},) if qat else None).module()
        quantizer = EdgeQuantizer(config, qat=qat, prefix=PREFIX)
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
    install_train_eval(prepared, model, PREFIX)
    return prepared


def drop_fake_quants_after_dropout(prepared: torch.fx.GraphModule) -> int:
    """Remove each fake-quant that reads a dropout of an already fake-quantized tensor (ASPP's
    Dropout(0.5) before the head conv): it learnt its range from training's 1/(1-p)-scaled values,
    2x the deployed ones, where the dropout is gone, so the head conv read its input at half the
    resolution. The conv reads the grid before the dropout instead. Returns how many were removed."""
    from torchao.quantization.pt2e import FakeQuantizeBase

    def is_fake_quant(node: torch.fx.Node) -> bool:
        return node.op == "call_module" and isinstance(prepared.get_submodule(node.target), FakeQuantizeBase)

    dropouts = (torch.ops.aten.dropout.default, torch.ops.aten.dropout_.default)
    removed = 0
    for node in list(prepared.graph.nodes):
        src = node.args[0] if is_fake_quant(node) and node.args else None
        if (isinstance(src, torch.fx.Node) and src.target in dropouts
                and isinstance(src.args[0], torch.fx.Node) and is_fake_quant(src.args[0])):
            node.replace_all_uses_with(src)
            prepared.graph.erase_node(node)
            removed += 1
    return removed


def convert(prepared: torch.fx.GraphModule, snap_biases: bool = True) -> torch.fx.GraphModule:
    """pt2e convert (Q/DQ graph, BN folded), with conv biases on onnxruntime's int32 grid
    (snap_biases=False only to measure what that does: benchmarks/agreement.py)."""
    from torchao.quantization.pt2e.quantize_pt2e import convert_pt2e

    to_eval(prepared)
    with warnings.catch_warnings(), bn_folds_with_own_eps(prepared):
        warnings.simplefilter("ignore")
        converted = convert_pt2e(prepared)
    if snap_biases:
        snap_conv_biases(converted)
    return converted


def snap_conv_biases(converted: torch.fx.GraphModule) -> int:
    """Round each int8 conv's float bias to the int32 grid (scale = input scale x weight scale) that
    onnxruntime quantizes it to when it fuses the conv into QLinearConv. The int8 model onnxruntime
    runs is unchanged, and torch's simulation computes the same sums, so the label-agreement check
    compares like with like (benchmarks/agreement.py measures the difference). Returns how many
    biases were snapped."""
    qd = torch.ops.quantized_decomposed
    snapped = 0
    for node in converted.graph.nodes:
        if node.target != torch.ops.aten.conv2d.default or len(node.args) < 3:
            continue
        x, w, b = node.args[:3]
        if not (isinstance(x, torch.fx.Node) and x.target == qd.dequantize_per_tensor.default
                and isinstance(w, torch.fx.Node) and w.target == qd.dequantize_per_channel.default
                and isinstance(b, torch.fx.Node) and b.op == "get_attr" and not isinstance(x.args[1], torch.fx.Node)):
            continue
        w_scale = attrgetter(w.args[1].target)(converted) if isinstance(w.args[1], torch.fx.Node) else w.args[1]
        step = torch.tensor(x.args[1], dtype=torch.float32) * torch.as_tensor(w_scale, dtype=torch.float32)
        bias = attrgetter(b.target)(converted)
        with torch.no_grad():
            bias.copy_(torch.round(bias / step) * step)
        snapped += 1
    return snapped


def expected_int8_convs(prepared: torch.fx.GraphModule, config: QuantConfig) -> int:
    """Convs the quantizer was asked to quantize (all but those under --keep-float)."""
    paths = [module_path(n).removeprefix(PREFIX) for n in prepared.graph.nodes
             if n.op == "call_function" and n.target == torch.ops.aten.conv2d.default]
    return sum(not under(p, config.keep_float) for p in paths)


def _stage(message: str, enabled: bool) -> None:
    """A stage of a pass on stderr: long steps without a bar still say what they are doing."""
    if enabled:
        print(message, file=sys.stderr, flush=True)


def export_int8(converted: torch.fx.GraphModule, out: str | Path, metadata: dict, size: tuple[int, int],
                expected_convs: int, check_images: list[np.ndarray], progress: bool = False,
                passes: tuple[str, ...] = tuple(EXPORT_PASSES)) -> dict:
    """Export, then check int8 conv weights and onnxruntime-vs-torch label agreement; no file on failure."""
    _stage(f"export the int8 ONNX to {out} (torch.export, then onnx checks)", progress)
    path = export_onnx(converted, out, metadata, size, passes)
    _stage(f"compare onnxruntime's labels with torch's on {len(check_images)} val images", progress)
    report = conv_weight_report(path)
    if report["int8"] < expected_convs:
        path.unlink()
        raise QuantizationError(f"only {report['int8']} of {expected_convs} convs got int8 weights in the ONNX")
    agreement = label_agreement(path, converted, check_images)
    return {"out": str(path), "size_bytes": path.stat().st_size, "convs": report["convs"],
            "int8_convs": report["int8"], "float_convs": report["float"], "agreement_vs_torch": round(agreement, 5)}


def quantize_static(checkpoint: str | Path, data: str | Path, out: str | Path, config: QuantConfig | None = None,
                    calib_images: int | None = None, seed: int = 0, progress: bool = True,
                    export_passes: tuple[str, ...] = tuple(EXPORT_PASSES)) -> dict:
    """Static post-training quantization: BN folded, per-channel int8 weights, activation ranges
    calibrated on CALIB_IMAGES train images (None: 64, or all if fewer) with config.calib_method;
    writes an int8 ONNX after the ONNX graph passes EXPORT_PASSES (all by default)."""
    from edgepick.train.checkpoint import load_model

    config = (config or QuantConfig()).validate()
    model, ckpt = load_model(checkpoint)
    check_classes(ckpt, data)
    size = tuple(ckpt["input_size"])
    images = model_images(data, "train", calib_images, size, seed)
    check_images = model_images(data, "val", min(8, len(NativeDataset.open(data, "val"))), size, seed)
    check_keep_float(model, config.keep_float)
    t0 = time.perf_counter()
    _stage(f"prepare the graph (torch.export, observers) to calibrate on {len(images)} train images", progress)
    prepared = prepare(model, config, size, qat=False)
    with torch.no_grad():
        for rgb in progress_bar(images, desc="calibrate", unit="img", enabled=progress):
            prepared(_as_input(rgb))
    converted = convert(prepared)
    calib_s = time.perf_counter() - t0
    quant = {"mode": "static", "qat_fraction": None, "calib_method": config.calib_method,
             "calib_images": len(images),
             **{k: v for k, v in config.to_dict().items() if k not in ("calib_method", "weight_averaging")}}
    meta = contract_metadata(ckpt, "int8", quant)
    result = export_int8(converted, out, meta, size, expected_int8_convs(prepared, config), check_images, progress,
                         export_passes)
    return {"mode": "static", **result, "observers": count_quant_nodes(prepared), "calib_s": round(calib_s, 2),
            "quant": quant}


def load_qat(checkpoint: dict) -> torch.fx.GraphModule:
    """Rebuild a QaT run's fake-quant graph from its checkpoint."""
    from edgepick.models.deeplabv3 import ModelConfig, build_model

    tc = checkpoint["train_config"]
    prepared = prepare(build_model(ModelConfig(**checkpoint["model_config"])), QuantConfig(**tc["quant"]),
                       tuple(tc["size"]), qat=True)
    load_qat_state(prepared, checkpoint["model"])
    return prepared


def _finish_qat(run: Path, data: str | Path, out: str | Path, quant: dict, progress: bool = False) -> dict:
    """Convert the QaT run's best epoch on val (best.pt, picked as a float RUN's best.pt is: the
    last epoch is not always the best one) and export it, with the whole run's phase times."""
    from edgepick.train.checkpoint import read_checkpoint

    last = read_checkpoint(run / "last.pt")
    ckpt = read_checkpoint(run / "best.pt") if (run / "best.pt").is_file() else last
    prepared = load_qat(ckpt)
    converted = convert(prepared)
    size = tuple(ckpt["input_size"])
    float_s, qat_s = float(last.get("init_train_time_s", 0.0)), float(last["train_time_s"])
    meta = contract_metadata(ckpt, "int8", quant, train_time_s=float_s + qat_s)
    check_images = model_images(data, "val", min(8, len(NativeDataset.open(data, "val"))), size)
    expected = expected_int8_convs(prepared, QuantConfig(**ckpt["train_config"]["quant"]))
    result = export_int8(converted, out, meta, size, expected, check_images, progress)
    return {"mode": quant["mode"], **result, "run": str(run), "observers": count_quant_nodes(prepared),
            "float_phase_s": round(float_s, 2), "qat_phase_s": round(qat_s, 2), "val_miou_qat": ckpt["history"][-1]["miou"],
            "qat_epoch": ckpt["epoch"],
            "quant": quant}


def _qat_quant(mode: str, fraction: float, config: QuantConfig) -> dict:
    return {"mode": mode, "qat_fraction": fraction, "calib_method": "qat", "calib_images": None,
            **{k: v for k, v in config.to_dict().items() if k not in ("calib_method", "percentile")}}


def quantize_qat(train_config, out: str | Path, config: QuantConfig | None = None, progress: bool = True) -> dict:
    """QaT from scratch: a whole training run (train_config: TrainConfig, its .out the RUN folder) with
    fake-quant on every epoch, then an int8 ONNX at OUT."""
    from dataclasses import replace

    from edgepick.train.loop import train

    config = (config or QuantConfig()).validate()
    _check_out(out)
    cfg = replace(train_config, qat=True, quant=config.to_dict(), aux_loss=False)
    train(cfg, progress=progress)
    return _finish_qat(Path(cfg.out), cfg.data, out, _qat_quant("qat", 1.0, config), progress=progress)


def quantize_hybrid(run: str | Path, data: str | Path, out: str | Path, qat_fraction: float,
                    config: QuantConfig | None = None, qat_run: str | Path | None = None, progress: bool = True,
                    freeze_at: float = 0.7, carry_optimizer: bool = True, calib_images: int | None = None,
                    hold_ranges: bool | None = None, device: str = "auto") -> dict:
    """Hybrid-QaT: of the float RUN's epoch budget E, continue from its epoch_NNN.pt at (1 - p)E
    (its weights, LR schedule and, unless carry_optimizer is False, AdamW moments) and train the
    last pE epochs with fake-quant (into QAT_RUN), observers and BN frozen after FREEZE_AT of the
    QaT steps (1.0: never), then export the int8 ONNX. The activation ranges start from static
    PTQ's (config.percentile over CALIB_IMAGES train images; None: 64, or all if fewer) and HOLD_RANGES
    (None: yes when calibrated) keeps them for the whole phase: a short phase at the tail of the
    learning-rate schedule has little room to train moving min/max ranges back (docs/quantization.md).
    CALIB_IMAGES 0: the first batch's min/max, moving. DEVICE is this machine's choice (auto, cpu,
    cuda), not the float run's."""
    from edgepick.train.checkpoint import read_checkpoint
    from edgepick.train.loop import TrainConfig, train

    if not 0.0 < qat_fraction < 1.0:
        raise ConfigError(f"--qat-fraction must be inside (0, 1), got {qat_fraction}")
    if not 0.0 <= freeze_at <= 1.0:
        raise ConfigError(f"--freeze-at must be inside [0, 1], got {freeze_at}")
    n_train = len(NativeDataset.open(data, "train"))
    if calib_images is None:
        calib_images = min(DEFAULT_CALIB_IMAGES, n_train)
    if calib_images < 0 or (hold_ranges and not calib_images):
        raise ConfigError("--calib-images must be 0 (off) or positive, and --hold-ranges needs it")
    if calib_images > n_train:
        raise ConfigError(f"asked for {calib_images} calibration images, but {data}/train has fewer")
    hold_ranges = bool(calib_images) if hold_ranges is None else hold_ranges
    config = (config or QuantConfig()).validate()
    _check_out(out)
    qat_dir = Path(qat_run) if qat_run else Path(out).with_suffix(".run")
    if qat_dir.exists() and (not qat_dir.is_dir() or any(qat_dir.iterdir())):
        raise ConfigError(f"--run {qat_dir} already exists and is not empty; choose a new folder")
    run = Path(run)
    last = read_checkpoint(run / "last.pt" if run.is_dir() else run)
    if last.get("train_config", {}).get("qat"):
        raise CheckpointError(f"{run} is a QaT run; hybrid-QaT starts from a float run")
    check_classes(last, data)
    tc = {**last["train_config"], "size": tuple(last["train_config"]["size"])}
    budget = tc["epochs"]
    switch = round((1.0 - qat_fraction) * budget)
    if switch >= budget:
        raise ConfigError(f"--qat-fraction {qat_fraction} of {budget} epochs is less than one epoch")
    init = Path(last["path"]).parent / f"epoch_{switch:03d}.pt"
    if not init.is_file():
        raise ConfigError(f"{init} does not exist: train the float run with --keep-epochs {switch}")
    qat_run = Path(qat_run) if qat_run else Path(out).with_suffix(".run")
    cfg = TrainConfig(**{**tc, "data": str(data), "out": str(qat_run), "keep_epochs": [], "qat": True,
                         "quant": config.to_dict(), "init_from": str(init), "aux_loss": False,
                         "device": device, "freeze_at": freeze_at, "carry_optimizer": carry_optimizer,
                         "qat_calib_images": calib_images, "qat_hold_ranges": hold_ranges})
    train(cfg, progress=progress)
    quant = {**_qat_quant("hybrid", qat_fraction, config), "freeze_at": freeze_at, "carry_optimizer": carry_optimizer,
             "calib_images": calib_images or None, "hold_ranges": hold_ranges}
    if calib_images:
        quant["calib_method"] = f"qat from percentile {config.percentile}"
    return _finish_qat(qat_run, data, out, quant, progress=progress)


def _check_out(out: str | Path) -> None:
    if Path(out).suffix != ".onnx":
        raise ConfigError(f"--out must name an .onnx file, got {out}")
