"""The int8 passes of edgepick's own models: static PTQ of a checkpoint, QaT from scratch,
hybrid-QaT; each ends in an ONNX model (docs/contracts.md#onnx-model).

One public function per pass (`quantize_static`, `quantize_qat`, `quantize_hybrid`), like
onnxruntime's quantize.py; the CLI is a thin layer over them. All go through torchao's
pt2e flow: torch.export -> prepare(_qat)_pt2e with `EdgeQuantizer` -> convert_pt2e ->
torch.onnx.export(dynamo=True), and all assert that quantization really happened. A model
edgepick did not make has its own verbs: `quantize_module_static` (an nn.Module) and
`quantize_onnx_static` (a float .onnx file).
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Iterable, Iterator, Sequence, Sized
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np
import torch

from edgepick.errors import CheckpointError, ParameterError
from edgepick.export.onnx_export import EXPORT_PASSES, check_onnx_out, contract_metadata
from edgepick.geometry import Size
from edgepick.progress import stage
from edgepick.quant.config import (
    BIAS_CORRECTION_IMAGES,
    HELD_OUT_INPUTS,
    CalibMethod,
    Pt2eOptions,
    PtqMethods,
    QatOptions,
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
from edgepick.quant.pt2e.images import AGREEMENT_IMAGES, agreement_images, check_classes
from edgepick.quant.pt2e.int8_file import export_int8
from edgepick.quant.pt2e.ptq import convert_static, measures
from edgepick.quant.pt2e.qat import load_qat, qat_configs, train_qat
from edgepick.quant.pt2e.quantizer import count_quant_nodes
from edgepick.quant.record import QuantRecord, RecordKind
from edgepick.quant.results import PassResult
from edgepick.train.checkpoint import Checkpoint
from edgepick.train.config import Device, TrainConfig
from edgepick.train.loop import check_run
from edgepick.train.run import Run


def _a_checkpoint(checkpoint: object) -> None:
    """Refuse a model from elsewhere, which has a verb of its own."""
    if isinstance(checkpoint, torch.nn.Module):
        raise ParameterError("{checkpoint:name}: an nn.Module; quantize_module_static quantizes one", checkpoint=None)
    if isinstance(checkpoint, (str, Path)) and Path(checkpoint).suffix.lower() == ".onnx":
        raise ParameterError("{checkpoint}: an ONNX model; quantize_onnx_static quantizes one",
                             checkpoint=Path(checkpoint))


def _calibrate(prepared: torch.fx.GraphModule, calib: Iterator[np.ndarray], size: Size, config: QuantConfig,
               keep: int, total: int | None, progress: bool) -> tuple[list[np.ndarray], int, dict]:
    """Calibrate PREPARED on CALIB, the rule chosen on held-out images with calib_method auto;
    returns the first KEEP images, how many were seen and the range rule's record."""
    kept: list[np.ndarray] = []
    images = first_of(calib, keep, kept)
    held = list(itertools.islice(images, HELD_OUT_INPUTS if config.calib_method == CalibMethod.AUTO else 0))
    rest = calibrate(prepared, images, size, progress, total=total - len(held) if total else None,
                     at_least_one=not held)
    ranges = choose_rule(prepared, [as_input(at_input_size(rgb, size)) for rgb in held], config, rest, labels=True)
    return kept, len(held) + rest, ranges


def quantize_static(checkpoint: str | Path | Checkpoint, calib: Iterable[np.ndarray], out: str | Path,
                    config: QuantConfig | None = None, methods: PtqMethods | None = None,
                    pt2e: Pt2eOptions | None = None, check_images: Sequence[np.ndarray] | None = None,
                    progress: bool = True, export_passes: tuple[str, ...] = tuple(EXPORT_PASSES)) -> PassResult:
    """Static post-training quantization of a float checkpoint (or RUN): BN folded, per-channel
    int8 weights, activation ranges calibrated with config.calib_method on CALIB (HxWx3 uint8 RGB
    images, any iterable, resized to the model's input), METHODS applied on them; writes an int8
    ONNX after the ONNX graph passes EXPORT_PASSES (all by default). The onnxruntime-vs-torch label
    agreement is measured on CHECK_IMAGES [default: the first 8 calibration images].
    `folder_images` draws CALIB from a data set."""
    _a_checkpoint(checkpoint)
    config, methods, pt2e = config or QuantConfig(), methods or PtqMethods(), pt2e or Pt2eOptions()
    check_onnx_out(out)
    ckpt = checkpoint if isinstance(checkpoint, Checkpoint) else Checkpoint.load(checkpoint)
    model, size = ckpt.build_model(), ckpt.input_size
    check_keep_float(model, config.keep_float)
    total = len(calib) if isinstance(calib, Sized) else None
    calib = checked_first(calib, size)
    t0 = time.perf_counter()
    stage("prepare the graph (torch.export, observers), then calibrate", progress)
    prepared = prepare(model, config, size, qat=False, equalize=methods.equalize, pt2e=pt2e)
    measuring = measures(config, methods)
    kept, seen, ranges = _calibrate(prepared, calib, size, config,
                                    max(AGREEMENT_IMAGES, BIAS_CORRECTION_IMAGES if measuring else 0), total, progress)
    if measuring:
        stage(f"convert, then measure on up to {BIAS_CORRECTION_IMAGES} calibration images (weight bits "
              f"{config.weight_bits}, bias correction {methods.bias_correction})", progress)
    converted, measured = convert_static(prepared, lambda: [as_input(at_input_size(rgb, size))
                                                            for rgb in kept[:BIAS_CORRECTION_IMAGES]], config, methods,
                                         progress)
    calib_s = time.perf_counter() - t0
    quant = QuantRecord(RecordKind.STATIC, config, seen, methods, pt2e=pt2e, ranges=ranges, measured=measured).to_dict()
    check = [at_input_size(rgb, size, "check_images")
             for rgb in (kept[:AGREEMENT_IMAGES] if check_images is None else check_images)]
    file = export_int8(converted, out, contract_metadata(ckpt, "int8", quant), size,
                       expected_int8_convs(prepared, config), check, progress, export_passes)
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
    stage(f"load QaT epoch {ckpt.epoch} (the best on val) into the fake-quant graph and convert it to int8", progress)
    prepared = load_qat(ckpt, graph)
    converted = convert(prepared)
    size = ckpt.input_size
    meta = contract_metadata(ckpt, "int8", quant, train_time_s=float_s + qat_s)
    check_images = [at_input_size(rgb, size) for rgb in agreement_images(data)]
    expected = expected_int8_convs(prepared, qat_configs(ckpt)[0])
    file = export_int8(converted, out, meta, size, expected, check_images, progress)
    return PassResult(mode=quant["mode"], **asdict(file), observers=count_quant_nodes(prepared), quant=quant,
                      run=str(run.path), float_phase_s=round(float_s, 2), qat_phase_s=round(qat_s, 2),
                      val_miou_qat=ckpt.history[-1]["miou"], qat_epoch=ckpt.epoch)


def quantize_qat(train_config: TrainConfig, out: str | Path, config: QuantConfig | None = None,
                 qat: QatOptions | None = None, pt2e: Pt2eOptions | None = None, progress: bool = True) -> PassResult:
    """QaT from scratch: a whole training run (its .out the RUN folder) with fake-quant on every
    epoch, then an int8 ONNX at OUT."""
    config, qat, pt2e = config or QuantConfig(), qat or QatOptions(), pt2e or Pt2eOptions()
    check_onnx_out(out)
    check_run(train_config)  # the stages below say what they do only once nothing is left to refuse
    stage("prepare the fake-quant graph (torch.export: up to a minute on a CPU), then train every epoch with it",
          progress)
    trained = train_qat(train_config, config, qat, pt2e, progress=progress)
    quant = QuantRecord(RecordKind.QAT, config, qat=qat, pt2e=pt2e, qat_fraction=1.0, calib_method="qat").to_dict()
    return _finish_qat(Run(train_config.out), train_config.data, out, quant, trained.graph, progress=progress)


def _check_hybrid(qat_fraction: float, out: str | Path, qat_run: Path) -> None:
    """Refuse hybrid-QaT's settings that cannot work, before any work."""
    if not 0.0 < qat_fraction < 1.0:
        raise ParameterError("{qat_fraction}: must be inside (0, 1)", qat_fraction=qat_fraction)
    check_onnx_out(out)
    if qat_run.exists() and (not qat_run.is_dir() or any(qat_run.iterdir())):
        raise ParameterError("{qat_run}: already exists and is not empty; choose a new folder", qat_run=qat_run)


def quantize_hybrid(run: str | Path, data: str | Path, out: str | Path, qat_fraction: float,
                    calib: Iterable[np.ndarray], config: QuantConfig | None = None, qat: QatOptions | None = None,
                    pt2e: Pt2eOptions | None = None, qat_run: str | Path | None = None, progress: bool = True,
                    carry_optimizer: bool = True, hold_ranges: bool | None = None,
                    device: Device = Device.AUTO) -> PassResult:
    """Hybrid-QaT: of the float RUN's epoch budget E, continue from its epoch_NNN.pt at (1 - p)E
    (its weights, LR schedule and, unless carry_optimizer is False, AdamW moments) and train the
    last pE epochs on DATA with fake-quant (into QAT_RUN), observers and BN frozen after
    qat.freeze_at of the QaT steps (1.0: never), then export the int8 ONNX.

    The activation ranges start from static PTQ's (config.percentile) over CALIB, HxWx3 uint8 RGB
    images (`run_images` draws them as the command line does; none: the first batch's min/max,
    moving). HOLD_RANGES (None: yes when calibrated) keeps them for the whole phase: a short phase
    at the tail of the learning-rate schedule has little room to train moving min/max ranges back
    (docs/quantization.md). DEVICE is this machine's choice (auto, cpu, cuda), not the float run's."""
    config, qat, pt2e = config or QuantConfig(), qat or QatOptions(), pt2e or Pt2eOptions()
    qat_run = Path(qat_run) if qat_run else Path(out).with_suffix(".run")
    _check_hybrid(qat_fraction, out, qat_run)
    # load the epoch checkpoint -> prepare -> calibrate -> fit (train_qat) -> convert -> export (_finish_qat)
    start, cfg = _switch_point(Path(run), data, qat_fraction)
    start.build_model()  # weights that do not fit are refused now, not after the stage lines below
    cfg = replace(cfg, data=str(data), out=str(qat_run), keep_epochs=(), device=device)
    check_run(cfg)  # the stages below say what they do only once nothing is left to refuse
    images = [at_input_size(rgb, cfg.size, "calib") for rgb in calib]
    if hold_ranges and not images:
        raise ParameterError("{hold_ranges} needs calibration images ({calib:name})", hold_ranges=hold_ranges,
                             calib=None)
    hold_ranges = bool(images) if hold_ranges is None else hold_ranges
    stage(f"continue {run} from epoch {start.epoch} of {cfg.epochs}: prepare the fake-quant graph (torch.export: up "
          "to a minute on a CPU), then train the QaT epochs", progress)
    trained = train_qat(cfg, config, qat, pt2e, start=start, carry_optimizer=carry_optimizer,
                        calib_images=images or None, hold_ranges=hold_ranges, progress=progress)
    quant = QuantRecord(RecordKind.HYBRID, config, len(images) or None, qat=qat, pt2e=pt2e, qat_fraction=qat_fraction,
                        calib_method=f"qat from percentile {config.percentile}" if images else "qat",
                        hybrid={"carry_optimizer": carry_optimizer, "hold_ranges": hold_ranges}).to_dict()
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
