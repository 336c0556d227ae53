"""The int8 passes: static PTQ, QaT from scratch, hybrid-QaT; each ends in an ONNX model
(docs/contracts.md#onnx-model).

One public function per pass (`quantize_static`, `quantize_qat`, `quantize_hybrid`), like
onnxruntime's quantize.py; the CLI is a thin layer over them. All go through torchao's
pt2e flow: torch.export -> prepare(_qat)_pt2e with `EdgeQuantizer` -> convert_pt2e ->
torch.onnx.export(dynamo=True), and all assert that quantization really happened.
"""

from __future__ import annotations

import itertools
import sys
import time
from collections.abc import Iterable, Sequence, Sized
from dataclasses import asdict, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from edgepick.data.native import NativeDataset
from edgepick.errors import CheckpointError, ConfigError, ParameterError, QuantizationError
from edgepick.export.checks import conv_weight_report
from edgepick.export.onnx_export import EXPORT_PASSES, check_onnx_out, contract_metadata, export_onnx, label_agreement
from edgepick.geometry import Size
from edgepick.quant.config import (
    BIAS_CORRECTION_IMAGES,
    DEFAULT_CALIB_IMAGES,
    FREEZE_AT,
    HELD_OUT_INPUTS,
    CalibMethod,
    QuantConfig,
)
from edgepick.quant.pt2e.graph import (
    as_input,
    at_input_size,
    calibrate,
    check_keep_float,
    checked_first,
    choose_rule,
    convert,
    expected_int8_convs,
    first_of,
    prepare,
)
from edgepick.quant.pt2e.ptq import convert_static, measures
from edgepick.quant.pt2e.qat import load_qat, qat_config, train_qat
from edgepick.quant.pt2e.quantizer import count_quant_nodes
from edgepick.quant.results import Int8File, PassResult
from edgepick.train.checkpoint import Checkpoint
from edgepick.train.config import Device, TrainConfig
from edgepick.train.loop import check_run
from edgepick.train.run import Run

if TYPE_CHECKING:
    from edgepick.quant.onnx.static import OnnxPassResult

AGREEMENT_IMAGES = 8  # images on which each pass compares onnxruntime's labels with torch's simulation
# QuantConfig fields that only static PTQ uses: a QaT file's metadata leaves them out
STATIC_ONLY = ("calib_method", "percentile", "bias_correction", "equalize", "adaround", "adaround_budget_s",
               "placement", "target", "gelu")


def check_image_count(data: str | Path, split: str, count: int | None, what: str = "calibration images") -> int:
    """COUNT (None: DEFAULT_CALIB_IMAGES, or all if fewer), refused when DATA/<split> has fewer."""
    n = len(NativeDataset.open(data, split))
    count = min(DEFAULT_CALIB_IMAGES, n) if count is None else count
    if count < 1:
        raise ConfigError(f"the number of {what} must be at least 1")
    if n < count:
        raise ConfigError(f"asked for {count} {what}, but {data}/{split} has only {n}")
    return count


def folder_images(data: str | Path, split: str = "train", count: int | None = None, seed: int = 0,
                  what: str = "calibration images") -> list[np.ndarray]:
    """COUNT images of DATA/<split> (None: DEFAULT_CALIB_IMAGES, or all if fewer), chosen with SEED,
    as HxWx3 uint8 RGB at the data set's own size: the calibration data the passes take, from a
    native data set."""
    if seed < 0:
        raise ParameterError("{seed}: must be 0 or positive", seed=seed)
    ds = NativeDataset.open(data, split)
    count = check_image_count(data, split, count, what)
    ids = [ds.ids[i] for i in sorted(np.random.default_rng(seed).choice(len(ds), count, replace=False))]
    return [ds.rgb(i) for i in ids]


def agreement_images(data: str | Path, seed: int = 0) -> list[np.ndarray]:
    """Up to AGREEMENT_IMAGES val images of DATA: where each pass compares onnxruntime's labels with torch's."""
    n = len(NativeDataset.open(data, "val"))
    return folder_images(data, "val", min(AGREEMENT_IMAGES, n), seed, "val images")


def model_images(data: str | Path, split: str, count: int | None, size: Size, seed: int = 0,
                 what: str = "calibration images") -> list[np.ndarray]:
    """folder_images, area-resized to the model's input SIZE."""
    return [at_input_size(rgb, size) for rgb in folder_images(data, split, count, seed, what)]


def check_classes(ckpt: Checkpoint, data: str | Path) -> None:
    classes = NativeDataset.open(data, "train").classes
    if classes != list(ckpt.classes):
        raise CheckpointError(f"the checkpoint's classes {list(ckpt.classes)} differ from the data set's {classes}")


def _stage(message: str, enabled: bool) -> None:
    """A stage of a pass on stderr: long steps without a bar still say what they are doing."""
    if enabled:
        print(message, file=sys.stderr, flush=True)


def _export_int8(converted: torch.fx.GraphModule, out: str | Path, metadata: dict, size: Size,
                 expected_convs: int, check_images: list[np.ndarray], progress: bool = False,
                 passes: tuple[str, ...] = tuple(EXPORT_PASSES)) -> Int8File:
    """Export, then check int8 conv weights and onnxruntime-vs-torch label agreement; no file on failure."""
    _stage(f"export the int8 ONNX to {out} (torch.export, then onnx checks)", progress)
    path = export_onnx(converted, out, metadata, size, passes)
    _stage(f"compare onnxruntime's labels with torch's on {len(check_images)} val images", progress)
    report = conv_weight_report(path)
    if report["int8"] < expected_convs:
        path.unlink()
        raise QuantizationError(f"only {report['int8']} of {expected_convs} convs got int8 weights in the ONNX")
    agreement = label_agreement(path, converted, check_images)
    return Int8File(out=str(path), size_bytes=path.stat().st_size, convs=report["convs"], int8_convs=report["int8"],
                    float_convs=report["float"], agreement_vs_torch=round(agreement, 5))


def quantize_static(checkpoint: str | Path | Checkpoint | torch.nn.Module, calib: Iterable[Any], out: str | Path,
                    config: QuantConfig | None = None, check_images: Sequence[np.ndarray] | None = None,
                    progress: bool = True, export_passes: tuple[str, ...] = tuple(EXPORT_PASSES),
                    input_shape: tuple[int, ...] | None = None) -> PassResult | OnnxPassResult:
    """Static post-training quantization of a float checkpoint (or RUN): BN folded, per-channel
    int8 weights, activation ranges calibrated with config.calib_method on CALIB (HxWx3 uint8 RGB
    images, any iterable, resized to the model's input); writes an int8 ONNX after the ONNX graph
    passes EXPORT_PASSES (all by default). The onnxruntime-vs-torch label agreement is measured on
    CHECK_IMAGES [default: the first 8 calibration images]. `folder_images` draws CALIB from a data set.

    A model edgepick did not make: an nn.Module (quantize_module_static) or a float .onnx file
    (quantize_onnx_static), calibrated on its own input batches; INPUT_SHAPE fixes its input."""
    if isinstance(checkpoint, torch.nn.Module):
        from edgepick.quant.pt2e.module_static import quantize_module_static

        return quantize_module_static(checkpoint, calib, out, config, input_shape, progress)
    if isinstance(checkpoint, (str, Path)) and Path(checkpoint).suffix.lower() == ".onnx":
        from edgepick.quant.onnx.static import quantize_onnx_static

        return quantize_onnx_static(checkpoint, calib, out, config, input_shape, progress)
    config = config or QuantConfig()
    check_onnx_out(out)
    ckpt = checkpoint if isinstance(checkpoint, Checkpoint) else Checkpoint.load(checkpoint)
    model, size = ckpt.build_model(), ckpt.input_size
    check_keep_float(model, config.keep_float)
    total = len(calib) if isinstance(calib, Sized) else None
    calib = checked_first(calib, size)
    t0 = time.perf_counter()
    _stage("prepare the graph (torch.export, observers), then calibrate", progress)
    prepared = prepare(model, config, size, qat=False)
    kept: list[np.ndarray] = []
    measuring = measures(config)
    keep = max(AGREEMENT_IMAGES, BIAS_CORRECTION_IMAGES if measuring else 0)
    images = first_of(calib, keep, kept)
    held = list(itertools.islice(images, HELD_OUT_INPUTS if config.calib_method == CalibMethod.AUTO else 0))
    rest = calibrate(prepared, images, size, progress, total=total - len(held) if total else None,
                     at_least_one=not held)
    ranges = choose_rule(prepared, [as_input(at_input_size(rgb, size)) for rgb in held], config, rest)
    seen = len(held) + rest
    if measuring:
        _stage(f"convert, then measure on up to {BIAS_CORRECTION_IMAGES} calibration images (weight bits "
               f"{config.weight_bits}, bias correction {config.bias_correction})", progress)
    converted, measured = convert_static(prepared, lambda: [as_input(at_input_size(rgb, size))
                                                            for rgb in kept[:BIAS_CORRECTION_IMAGES]], config)
    kept = kept[:AGREEMENT_IMAGES]
    calib_s = time.perf_counter() - t0
    quant = {"mode": "static", "qat_fraction": None, "calib_method": config.calib_method, "calib_images": seen,
             **{k: v for k, v in config.to_dict().items() if k not in ("calib_method", "weight_averaging")},
             "ranges": ranges, **measured}
    meta = contract_metadata(ckpt, "int8", quant)
    check = [at_input_size(rgb, size, "check_images") for rgb in (kept if check_images is None else check_images)]
    file = _export_int8(converted, out, meta, size, expected_int8_convs(prepared, config), check, progress,
                        export_passes)
    return PassResult(mode="static", **asdict(file), observers=count_quant_nodes(prepared), quant=quant,
                      calib_s=round(calib_s, 2))


def _exported_epoch(run: Run) -> tuple[Checkpoint, float, float]:
    """The QaT RUN's epoch to export, its best on val (best.pt, picked as a float run's best.pt is:
    the last epoch is not always the best one), and the whole run's float and QaT phase seconds."""
    last = Checkpoint.load(run.last)
    return (Checkpoint.load(run.best) if run.best.is_file() else last), last.init_train_time_s, last.train_time_s


def _finish_qat(run: Run, data: str | Path, out: str | Path, quant: dict, graph: torch.fx.GraphModule,
                progress: bool = False) -> PassResult:
    """Convert the QaT run's best epoch on val (its state loaded into GRAPH, the graph the run trained)
    and export it, with the whole run's phase times."""
    ckpt, float_s, qat_s = _exported_epoch(run)
    _stage(f"load QaT epoch {ckpt.epoch} (the best on val) into the fake-quant graph and convert it to int8", progress)
    prepared = load_qat(ckpt, graph)
    converted = convert(prepared)
    size = ckpt.input_size
    meta = contract_metadata(ckpt, "int8", quant, train_time_s=float_s + qat_s)
    check_images = [at_input_size(rgb, size) for rgb in agreement_images(data)]
    expected = expected_int8_convs(prepared, qat_config(ckpt))
    file = _export_int8(converted, out, meta, size, expected, check_images, progress)
    return PassResult(mode=quant["mode"], **asdict(file), observers=count_quant_nodes(prepared), quant=quant,
                      run=str(run.path), float_phase_s=round(float_s, 2), qat_phase_s=round(qat_s, 2),
                      val_miou_qat=ckpt.history[-1]["miou"], qat_epoch=ckpt.epoch)


def _qat_quant(mode: str, fraction: float, config: QuantConfig) -> dict:
    return {"mode": mode, "qat_fraction": fraction, "calib_method": "qat", "calib_images": None,
            **{k: v for k, v in config.to_dict().items() if k not in STATIC_ONLY}}


def quantize_qat(train_config: TrainConfig, out: str | Path, config: QuantConfig | None = None,
                 progress: bool = True) -> PassResult:
    """QaT from scratch: a whole training run (its .out the RUN folder) with fake-quant on every
    epoch, then an int8 ONNX at OUT."""
    config = config or QuantConfig()
    check_onnx_out(out)
    check_run(train_config)  # the stages below say what they do only once nothing is left to refuse
    _stage("prepare the fake-quant graph (torch.export: up to a minute on a CPU), then train every epoch with it",
           progress)
    trained = train_qat(train_config, config, progress=progress)
    return _finish_qat(Run(train_config.out), train_config.data, out, _qat_quant("qat", 1.0, config), trained.graph,
                       progress=progress)


def quantize_hybrid(run: str | Path, data: str | Path, out: str | Path, qat_fraction: float,
                    config: QuantConfig | None = None, qat_run: str | Path | None = None, progress: bool = True,
                    freeze_at: float = FREEZE_AT, carry_optimizer: bool = True,
                    calib: Iterable[np.ndarray] | int | None = None, hold_ranges: bool | None = None,
                    device: Device = Device.AUTO) -> PassResult:
    """Hybrid-QaT: of the float RUN's epoch budget E, continue from its epoch_NNN.pt at (1 - p)E
    (its weights, LR schedule and, unless carry_optimizer is False, AdamW moments) and train the
    last pE epochs on DATA with fake-quant (into QAT_RUN), observers and BN frozen after FREEZE_AT of
    the QaT steps (1.0: never), then export the int8 ONNX.

    The activation ranges start from static PTQ's (config.percentile) over CALIB: HxWx3 uint8 RGB
    images, or how many to draw from DATA's train split with the run's seed (None: 64, or all if
    fewer; 0 or no images: the first batch's min/max, moving). HOLD_RANGES (None: yes when
    calibrated) keeps them for the whole phase: a short phase at the tail of the learning-rate
    schedule has little room to train moving min/max ranges back (docs/quantization.md). DEVICE is
    this machine's choice (auto, cpu, cuda), not the float run's."""
    if not 0.0 < qat_fraction < 1.0:
        raise ParameterError("{qat_fraction}: must be inside (0, 1)", qat_fraction=qat_fraction)
    if not 0.0 <= freeze_at <= 1.0:
        raise ParameterError("{freeze_at}: must be inside [0, 1]", freeze_at=freeze_at)
    if isinstance(calib, int) and calib < 0:
        raise ParameterError("{calib}: a number of calibration images must be 0 (none) or positive", calib=calib)
    if isinstance(calib, int) and calib:
        check_image_count(data, "train", calib)
    config = config or QuantConfig()
    check_onnx_out(out)
    qat_run = Path(qat_run) if qat_run else Path(out).with_suffix(".run")
    if qat_run.exists() and (not qat_run.is_dir() or any(qat_run.iterdir())):
        raise ParameterError("{qat_run}: already exists and is not empty; choose a new folder", qat_run=qat_run)
    # load the epoch checkpoint -> prepare -> calibrate -> fit (train_qat) -> convert -> export (_finish_qat)
    start, cfg = _switch_point(Path(run), data, qat_fraction)
    start.build_model()  # weights that do not fit are refused now, not after the stage lines below
    cfg = replace(cfg, data=str(data), out=str(qat_run), keep_epochs=(), device=device)
    check_run(cfg)  # the stages below say what they do only once nothing is left to refuse
    drawn = calib is None or isinstance(calib, int)  # drawn from DATA's train split, else given
    count = calib if isinstance(calib, int) else None
    images = [] if calib is None or isinstance(calib, int) else list(calib)
    if hold_ranges and (count == 0 or not (drawn or images)):
        raise ParameterError("{hold_ranges} needs calibration images ({calib:name})", hold_ranges=hold_ranges,
                             calib=calib)
    if drawn and count != 0:
        _stage(f"continue {run} from epoch {start.epoch} of {cfg.epochs}; draw the calibration images", progress)
        images = folder_images(data, "train", count, cfg.seed)
    images = [at_input_size(rgb, cfg.size) for rgb in images]
    hold_ranges = bool(images) if hold_ranges is None else hold_ranges
    _stage("prepare the fake-quant graph (torch.export: up to a minute on a CPU), then train the QaT epochs", progress)
    trained = train_qat(cfg, config, start=start, carry_optimizer=carry_optimizer, freeze_at=freeze_at,
                        calib_images=images or None, hold_ranges=hold_ranges, progress=progress)
    quant = {**_qat_quant("hybrid", qat_fraction, config), "freeze_at": freeze_at, "carry_optimizer": carry_optimizer,
             "calib_images": len(images) or None, "hold_ranges": hold_ranges}
    if images:
        quant["calib_method"] = f"qat from percentile {config.percentile}"
    return _finish_qat(Run(qat_run), data, out, quant, trained.graph, progress=progress)


def _switch_point(run: Path, data: str | Path, qat_fraction: float) -> tuple[Checkpoint, TrainConfig]:
    """The float RUN's checkpoint at (1 - qat_fraction) of its epoch budget, and the run's config."""
    last = Checkpoint.load(Run(run).last if run.is_dir() else run)
    if last.is_qat:
        raise CheckpointError(f"{run} is a QaT run; hybrid-QaT starts from a float run")
    if last.train_config is None:
        raise CheckpointError(f"{last.path} has no train_config: hybrid-QaT continues a run edgepick trained")
    check_classes(last, data)
    cfg = last.train_config
    switch = round((1.0 - qat_fraction) * cfg.epochs)
    if switch >= cfg.epochs:
        raise ParameterError(f"{{qat_fraction}} of {cfg.epochs} epochs is less than one epoch",
                             qat_fraction=qat_fraction)
    init = Run(last.path.parent if last.path else run).epoch(switch)
    if not init.is_file():
        raise ParameterError(f"{init} does not exist: train the float run with {{keep_epochs}}", keep_epochs=(switch,))
    return Checkpoint.load(init), cfg
