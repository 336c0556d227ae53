"""Static PTQ of a float ONNX model edgepick did not make: edgepick's int8 recipe on any graph.

edgepick calibrates (quant/onnx/calibrate.py: every calibration tensor streamed once through the
model, a histogram per activation, memory bounded), chooses the range rule per model by measuring
the outputs (quant/onnx/qdq.py; `CalibMethod.AUTO`, the default), has onnxruntime's QDQ quantizer
write the Q/DQ pairs for those ranges, and rewrites around it (docs/quantization.md, "Your own model"):

- before: the input dims fixed, opset lifted to 13, hardswish/hardsigmoid/mean pooling in the
  forms with integer kernels (`rewrite.rewrite_activations`), BatchNorm folded and shapes
  inferred (onnxruntime's `quant_pre_process`);
- the recipe: U8S8, weights int8 per output channel and symmetric, 7-bit unless
  weight_bits 8 (or first-7: 7-bit only where 8-bit weights saturate, `measure`), uint8
  activations per tensor, HardSigmoid quantized as well (with placement convs: only the convs
  and the tensors they read, a conv's own activation reading its float output, the model's other
  activations left float as it writes them, for OpenVINO, which fuses them into its int8 convs);
  with options.gelu sigmoid, each GELU written as c * x * sigmoid(alpha * x) on integer kernels
  (`gelu`); with methods.equalize, conv pairs equalized before calibration (`equalize`); with
  methods.adaround, each conv's weight rounding learnt on the calibration tensors (`adaround`); with
  empirical bias correction, the conv biases shifted back to fp32's means (`measure`);
- after: the ops between the last conv and the outputs (Resize, Sigmoid, ...) float, the outputs
  on the uint8 grid unless that costs fidelity (`qdq.outputs_on_grid`); export's integer
  activations and padding-tap crop; initializers no node reads dropped.

The file is checked before it is kept: every conv not named in keep_float has int8 weights, and
onnxruntime's int8 outputs are compared with its fp32 outputs (quant/fidelity.py: SQNR and
cosine per output, and the share of agreeing decisions where the output decides something).
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
from collections.abc import Callable, Iterable, Mapping, Sized
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from edgepick.errors import ParameterError
from edgepick.export.checks import check_onnx_out, require_int8_convs
from edgepick.export.crop_convs import crop_padded_convs
from edgepick.export.int8_activations import integer_activations
from edgepick.export.onnx_io import (
    CONV_OPS,
    constants_to_initializers,
    drop_unused_initializers,
    fix_input_shape,
    input_dims,
    lift_opset,
    load_float_onnx,
    opset,
)
from edgepick.files import atomic_path
from edgepick.onnx_graph import Graph, copy_model
from edgepick.progress import StageClock
from edgepick.quant.config import (
    HEADROOM,
    SATURATION_CHECK_INPUTS,
    BiasCorrection,
    CalibMethod,
    GeluForm,
    OnnxOptions,
    Placement,
    PtqMethods,
    QuantConfig,
    WeightBits,
    accuracy_check_inputs,
    check_inputs,
    lockstep_images,
)
from edgepick.quant.fidelity import Task, check_task_names, output_tasks, worst_sqnr
from edgepick.quant.methods import INT16, adaround_done
from edgepick.quant.onnx.accuracy import SQNR_FLOOR_DB, FidelityBudget, fidelity_first
from edgepick.quant.onnx.adaround import adaround_onnx
from edgepick.quant.onnx.calibrate import release_memory
from edgepick.quant.onnx.calibration_pass import Calibrated, calibrated, ranges_after_correction
from edgepick.quant.onnx.equalize import equalize_onnx
from edgepick.quant.onnx.evaluator import Evaluator, Judge, evaluator_for
from edgepick.quant.onnx.floating import REMOVABLE_OPS, float_tensors, node_tensors
from edgepick.quant.onnx.gelu import sigmoid_gelu
from edgepick.quant.onnx.inputs import check_tensor
from edgepick.quant.onnx.measure import correct_onnx_biases, qdq_convs, saturating_onnx_convs, to_seven_bit_onnx
from edgepick.quant.onnx.preprocess import pre_process
from edgepick.quant.onnx.qdq import float_tail, outputs_on_grid, qdq_for, writes_float_output
from edgepick.quant.onnx.rewrite import fold_affine_into_convs, rewrite_activations
from edgepick.quant.onnx.speed import slower_than_fp32_warning, speed_against_fp32
from edgepick.quant.record import QuantRecord, RecordKind
from edgepick.quant.results import OnnxPassResult

# fp32's outputs on the check tensors are kept from choosing the rule to the fidelity check when no larger (made
# again otherwise: held through bias correction, a 2048x1024 segmentation model's would raise its peak)
HELD_REFERENCE_BYTES = 64 << 20


def _read(model: str | Path, config: QuantConfig, task: Task | Mapping[str, Task] | None) -> tuple[Any, int]:
    """The float model, its nodes named and its Constants made initializers (how many: returned),
    refused when keep_float or TASK names what it does not have."""
    proto = load_float_onnx(model)
    Graph(proto).name_nodes()  # the quantizer and keep_float know nodes by name
    constants = constants_to_initializers(proto)
    known = {n.name for n in proto.graph.node}
    unknown = [k for k in config.keep_float if k not in known]
    if unknown:
        raise ParameterError(f"{{keep_float:name}} names no node of the model: {', '.join(unknown)}",
                             keep_float=tuple(unknown))
    check_task_names(proto, task)
    return proto, constants


def _prepared(proto: Any, model: str | Path, input_shape: tuple[int, ...], pre: Path, options: OnnxOptions,
              equalize: bool, rewrites: dict[str, int]) -> Any:
    """PROTO (read from MODEL) with its opset lifted, input dims fixed to INPUT_SHAPE and rewritten
    for OPTIONS, pre-processed (shapes inferred, BatchNorm folded) into the file PRE, equalized when
    asked; what was rewritten is counted into REWRITES. Returns the graph PRE holds."""
    import onnx

    proto = lift_opset(proto, model)  # before the shapes are cleared: the converter needs them
    fix_input_shape(proto, input_shape)
    rewrites.update(rewrite_activations(proto) if options.placement == Placement.ALL else {})
    rewrites["affine_folded"] = fold_affine_into_convs(proto)
    pre_process(proto, pre)
    prepared = onnx.load(str(pre))
    drop_unused_initializers(prepared)
    if equalize:
        rewrites["equalized_pairs"] = equalize_onnx(prepared)
    onnx.save(prepared, str(pre))
    return prepared


class _CheckOutputs:
    """fp32's outputs on the check tensors (an Evaluator of the float file PRE), made when first asked
    for and kept for every later check: choosing the rule, the measurements' checks, the fidelity."""

    def __init__(self, pre: Path, prepared: Any, tasks: dict[str, Task], nhwc: bool, judge: Judge | None):
        self.pre, self.prepared, self.tasks, self.nhwc, self.judge = pre, prepared, tasks, nhwc, judge
        self.made: Evaluator | None = None
        self.after_calibration = False

    def __call__(self, tensors: list[np.ndarray]) -> Evaluator:
        if self.made is not None and len(self.made.inputs) != len(tensors):  # the accuracy-aware mode checks on more
            self.made = None
        if self.made is None:
            if self.after_calibration:  # the measurements' memory; during calibration there is none to free
                release_memory()
            self.made = evaluator_for(self.pre, self.prepared, tensors, self.tasks, self.nhwc, self.judge)
        return self.made

    def release_if_large(self) -> None:
        """After calibration: let the outputs go when they are larger than HELD_REFERENCE_BYTES: they are
        made again after the measurements, whose peak they would raise."""
        self.after_calibration = True
        if self.made is not None and sum(a.nbytes for out in self.made.reference for a in out) > HELD_REFERENCE_BYTES:
            self.made = None


def quantize_onnx_static(model: str | Path, calib: Iterable[np.ndarray], out: str | Path,
                         config: QuantConfig | None = None, methods: PtqMethods | None = None,
                         options: OnnxOptions | None = None, input_shape: tuple[int, ...] | None = None,
                         progress: bool = True, task: Task | Mapping[str, Task] | None = None,
                         budget: FidelityBudget | None = None) -> OnnxPassResult:
    """Static PTQ of the float ONNX file MODEL with edgepick's recipe, calibrated on CALIB (the
    model's input tensors, float, with or without the batch axis; `folder_tensors` reads a folder),
    METHODS applied on them, OPTIONS the placement and GELU form; written to OUT. INPUT_SHAPE fixes
    dynamic input dims [default: the first tensor's shape]. config.keep_float names ONNX nodes to
    leave in float (their weights, inputs and outputs). TASK says what the outputs decide, for the
    fidelity report (one Task for all, or per output name) [default: guessed per output]. BUDGET:
    the accuracy-aware mode (quant/onnx/accuracy.py), which leaves the activations that matter most
    float until the outputs meet it; without one, a file whose worst output falls under
    SQNR_FLOOR_DB is written with a warning naming them."""
    import onnxruntime

    config, methods, options = config or QuantConfig(), methods or PtqMethods(), options or OnnxOptions()
    if options.placement == Placement.AUTO:
        from edgepick.quant.onnx.placement import choose_placement

        return choose_placement(quantize_onnx_static, model, calib, out, options, progress, config=config,
                                methods=methods, input_shape=input_shape, task=task, budget=budget)
    check_onnx_out(out, model)
    onnxruntime.set_default_logger_severity(3)  # its sessions warn about every unused initializer of the input
    if methods.bias_correction == BiasCorrection.FAST:
        raise ParameterError("{bias_correction}: fast is not available for ONNX models; use empirical",
                             bias_correction=methods.bias_correction)
    proto, constants = _read(model, config, task)
    total, tensors = len(calib) if isinstance(calib, Sized) else None, iter(calib)
    first, input_shape = _first_tensor(proto, next(tensors, None), input_shape)
    t0, clock = time.perf_counter(), StageClock()
    opset_in = opset(proto)
    nhwc = len(input_shape) == 4 and input_shape[-1] in (1, 3, 4) and input_shape[1] not in (1, 3, 4)
    with tempfile.TemporaryDirectory(prefix="edgepick-onnx-") as tmp:
        pre, rewrites = Path(tmp) / "float.onnx", {"constants_to_initializers": constants}
        with clock("prepare"):
            prepared = _prepared(proto, model, tuple(input_shape), pre, options, methods.equalize, rewrites)
            tasks = output_tasks(prepared, _output_shapes(prepared), task, nhwc)
        hw = input_shape[1:3] if nhwc else input_shape[-2:]
        measured, hold = lockstep_images(*hw) if methods.measures else 0, check_inputs(*hw)
        # AdaRound and bias correction (AdaRound also tried by a budget or adaround_if_far) fit on the tensors after the check's
        fitting = lockstep_images(*hw) if methods.measures or budget is not None or options.adaround_if_far else 0
        check = hold if budget is None else accuracy_check_inputs(hw[0], hw[1], total, fitting)
        keep = max(check + fitting, SATURATION_CHECK_INPUTS if config.weight_bits == WeightBits.FIRST_SEVEN else 0)
        ops = placement_ops(options.placement, _quantizer_registry())
        exclude = [*config.keep_float, *float_tail(prepared)]
        checks = _CheckOutputs(pre, prepared, tasks, nhwc, budget.judge if budget is not None else None)
        cal = calibrated(prepared, pre, first, tensors, tuple(input_shape), config, ops, exclude, keep,
                         hold if config.calib_method == CalibMethod.AUTO else 0, total, checks,
                         check + measured if methods.bias_correction == BiasCorrection.EMPIRICAL else 0, clock, progress, options.placement)
        checks.release_if_large()

        def checker() -> Evaluator:
            return checks(cal.kept[:check])

        def build(with_methods: PtqMethods, ranges: dict | None = None) -> tuple[Any, dict]:
            with clock("write_qdq"):
                int8 = qdq_for(cal.written, pre, prepared, ranges or cal.ranges, ops, exclude, config.reduce_range,
                               options.placement == Placement.ALL)
                if options.gelu == GeluForm.SIGMOID:  # before the bias correction, which then measures it
                    rewrites["sigmoid_gelu"] = sigmoid_gelu(int8)
            with clock("corrections"):
                return int8, _measure(prepared, int8, cal, check, measured or lockstep_images(*hw), config,
                                      with_methods, checker, progress)

        evaluator = checker()
        int8, done, cal = ranges_after_correction(cal, build, methods, evaluator, progress)
        if not methods.adaround and (budget is not None or options.adaround_if_far):
            int8, done = adaround_first(int8, done, build, methods, evaluator, budget, progress)
        with clock("finish"):
            int8, steps, accuracy = _finished(int8, prepared, rewrites, config, evaluator, budget, progress, options)
        quant = QuantRecord(RecordKind.ONNX, config, cal.seen, methods, options, ranges=cal.record, measured={
            **done, **accuracy, **({"equalized_pairs": rewrites["equalized_pairs"]} if methods.equalize else {})}
                            ).to_dict()
        calib_s = time.perf_counter() - t0
        with atomic_path(out) as path, clock("write_check"):
            fidelity, report = _write_checked(int8, path, prepared, config, quant, evaluator)
    return OnnxPassResult.of(Path(out), report, fidelity, input_shape=list(input_shape), opset_in=opset_in,
                             opset_out=opset(int8), rewrites=steps, quant=quant, calib_tensors=cal.seen,
                             calib_s=round(calib_s, 2), stage_s=clock.to_dict())


def adaround_first(int8: Any, done: dict, build: Callable[[PtqMethods], tuple[Any, dict]], methods: PtqMethods,
                   evaluator: Evaluator, budget: FidelityBudget | None, progress: bool) -> tuple[Any, dict]:
    """Where INT8 (made with METHODS, DONE) misses BUDGET (without one: where its worst output's SQNR
    is under SQNR_FLOOR_DB), the same graph with AdaRound (BUILD makes it), kept when it brings the
    outputs closer on the check tensors and on their worse half, or meets BUDGET (all int8: the answer): the
    accuracy-aware mode's first step, before any activation is left float, and the default pass's
    answer to a file far from fp32. On the conformance models under 99.5% or under the floor,
    AdaRound moved the task metric further than float activations did (docs/quantization.md)."""
    fidelity = evaluator.fidelity(int8)
    if budget.met(fidelity) if budget is not None else worst_sqnr(fidelity) >= SQNR_FLOOR_DB:
        return int8, done
    mode = "accuracy-aware" if budget is not None else "static"
    why = "the budget is not met" if budget is not None else \
        f"worst output SQNR {worst_sqnr(fidelity):.1f} dB, under {SQNR_FLOOR_DB:g}"
    if progress:
        print(f"{mode}: {why}; trying AdaRound first", file=sys.stderr, flush=True)
    rounded, rounded_done = build(replace(methods, adaround=True))
    tried = {**evaluator.closer(int8, rounded, worse_half=True), "why": "budget" if budget is not None else "sqnr_floor"}
    if budget is not None:
        tried["met"] = budget.met(evaluator.fidelity(rounded))
        tried["kept"] = tried["kept"] or tried["met"]
    if progress:
        reason = "it meets the budget" if tried.get("met") else \
            f"{'' if tried['kept'] else 'not '}closer to fp32 on the check tensors and on their worse half"
        print(f"{mode}: AdaRound {'kept' if tried['kept'] else 'not kept'} ({reason})", file=sys.stderr, flush=True)
    record = {"adaround_first": tried}
    return (rounded, {**rounded_done, **record}) if tried["kept"] else (int8, {**done, **record})


def _quantizer_registry() -> set[str]:
    """The op types onnxruntime's QDQ quantizer can put on the int8 grid."""
    from onnxruntime.quantization.registry import QDQRegistry, QLinearOpsRegistry

    return {*QDQRegistry, *QLinearOpsRegistry}


def _finished(int8: Any, prepared: Any, rewrites: dict[str, int], config: QuantConfig, evaluator: Evaluator,
              budget: FidelityBudget | None, progress: bool, options: OnnxOptions) -> tuple[Any, dict[str, int], dict]:
    """INT8 with the float tail, the outputs on the grid or not, keep_float's tensors float, the accuracy-aware
    mode or the low-fidelity warning, export's integer activations and padding-tap crop, then timed against
    fp32 (options.time_against_fp32; the accuracy-aware mode times its answer itself); returns it, every
    rewrite made, and what the accuracy and speed steps record."""
    int8, dropped, grid = outputs_on_grid(int8, float_tail(prepared), evaluator)
    steps = {**rewrites, "float_outputs": dropped}
    if config.keep_float:
        steps["kept_float_tensors"] = float_tensors(int8, node_tensors(int8, config.keep_float), prepared)
    int8, accuracy = fidelity_first(int8, evaluator, budget, progress)
    accuracy.update({"outputs_on_grid": grid} if grid else {})
    steps.update(**integer_activations(int8), cropped_convs=crop_padded_convs(int8))
    steps["unused_initializers"] = drop_unused_initializers(int8)
    if options.time_against_fp32 and budget is None:
        accuracy["speed"] = speed_against_fp32(prepared, int8, evaluator.inputs[0])
        if slower := slower_than_fp32_warning(accuracy["speed"]):
            print(f"edgepick: warning: {slower}", file=sys.stderr, flush=True)
    return int8, steps, accuracy


def _write_checked(int8: Any, path: Path, prepared: Any, config: QuantConfig, quant: dict,
                   evaluator: Evaluator) -> tuple[dict[str, dict], dict]:
    """Write INT8 with its metadata to PATH, check it (onnx's checker, every conv not kept float int8)
    and compare its outputs with fp32's (EVALUATOR's check tensors); returns the fidelity per output,
    also recorded in the file, and the file's conv report."""
    import onnx

    # every conv int8 but those kept float and those the accuracy-aware mode gave float weights
    made_float = {*config.keep_float, *quant.get("accuracy_aware", {}).get("float_weight_convs", [])}
    expected = sum(1 for n in prepared.graph.node if n.op_type in CONV_OPS and n.name not in made_float)
    onnx.save(int8, str(path))
    report = require_int8_convs(path, expected)
    fidelity = {n: f.to_dict() for n, f in evaluator.fidelity(int8).items() if n in evaluator.names}  # the outputs
    for key, value in (("edgepick.quant", quant), ("edgepick.fidelity", fidelity)):
        entry = int8.metadata_props.add()
        entry.key, entry.value = key, json.dumps(value)
    onnx.save(int8, str(path))
    onnx.checker.check_model(str(path), full_check=True)
    return fidelity, report


def _first_tensor(proto: Any, first: Any, input_shape: tuple[int, ...] | None) -> tuple[np.ndarray, tuple[int, ...]]:
    """The first calibration tensor, checked, and the input shape (INPUT_SHAPE, or the tensor's)."""
    if first is None:
        raise ParameterError("{calib:name}: no tensors; calibration needs at least one", calib=None)
    if input_shape is None:
        rank = len(input_dims(proto))
        fixed = [d if isinstance(d, int) else None for d in input_dims(proto)]
        arr = check_tensor(first, None, "calibration tensor 1")
        input_shape = tuple(arr.shape if arr.ndim == rank else (1, *arr.shape))
        if any(f is not None and f != s for f, s in zip(fixed, input_shape)):
            raise ParameterError(f"{{calib:name}}: calibration tensor 1 has shape {list(arr.shape)}, the model "
                                 f"takes {input_dims(proto)}", calib=None)
    return check_tensor(first, input_shape, "calibration tensor 1"), tuple(input_shape)


def _output_shapes(model: Any) -> dict[str, tuple[int, ...]]:
    """The static shape of each graph output (0 where a dim is unknown)."""
    return {o.name: tuple(d.dim_value for d in o.type.tensor_type.shape.dim) for o in model.graph.output}


def fitting_tensors(kept: list[np.ndarray], check: int, images: int) -> tuple[int, int]:
    """Where the IMAGES tensors AdaRound and bias correction fit on start among the calibration
    tensors KEPT, and how many there are: after the CHECK tensors that judge what they did, where
    enough were given (else as far along as there are, overlapping the check tensors: a budget or a
    correction judged on the tensors it was fit on is met more easily than on other images)."""
    count = min(images, len(kept))
    return min(check, len(kept) - count), count


def _measure(prepared: Any, int8: Any, cal: Calibrated, check: int, images: int, config: QuantConfig,
             methods: PtqMethods, checker: Callable[[], Evaluator], progress: bool = False) -> dict:
    """first-7, AdaRound and empirical bias correction on the QDQ graph INT8 (in place), in that
    order; AdaRound and the correction fit on IMAGES calibration tensors CAL kept after the CHECK
    tensors (fitting_tensors; fp32's side of the correction from calibration where it counted it),
    and the correction is kept only where it brings the outputs closer to fp32's on both halves of
    the check tensors (CHECKER gives their Evaluator): on a table-cell detector at 1024x1024 it took
    every output 7-11 dB further from fp32 (docs/quantization.md). Returns what was done."""
    done: dict = {}
    kept = cal.kept
    start, count = fitting_tensors(kept, check, images)
    fit = kept[start:start + count]
    if config.weight_bits == WeightBits.FIRST_SEVEN:
        share = saturating_onnx_convs(int8, kept[:SATURATION_CHECK_INPUTS], HEADROOM * INT16)
        done["seven_bit_convs"] = [name for name, s in share.items() if s > 0]
        to_seven_bit_onnx(prepared, int8, done["seven_bit_convs"])
    if methods.adaround:
        seven = set(qdq_convs(int8)) if config.weight_bits == WeightBits.SEVEN else set(done.get("seven_bit_convs", []))
        done.update(adaround_done(adaround_onnx(prepared, int8, fit, methods.adaround_budget_s, seven,
                                                progress=progress)))
    if methods.adaround or methods.bias_correction == BiasCorrection.EMPIRICAL:
        done["measured_images"] = count
    if methods.bias_correction == BiasCorrection.EMPIRICAL:
        uncorrected = copy_model(int8)
        means = {name: got[start:start + count] for name, got in cal.means.items()}
        correct_onnx_biases(prepared, int8, fit, writes_float_output(prepared), means)
        done["bias_correction_kept"] = checker().closer(uncorrected, int8)
        if not done["bias_correction_kept"]["kept"]:
            int8.CopyFrom(uncorrected)
    return done


# Placement.JOINS: what NNCF puts on the int8 grid for OpenVINO besides the convs
JOIN_OPS = ("MatMul", "Gemm", "Add", "Concat", "Split", "MaxPool", "AveragePool", "GlobalAveragePool")


def placement_ops(placement: Placement, registry: set[str]) -> list[str]:
    """The op types PLACEMENT quantizes, of onnxruntime's quantizer's REGISTRY. Every placement names
    Relu and Clip: where one alone reads a quantized op's output the writer folds it into that
    output's grid, and leaves it float elsewhere: under convs and joins a conv's output is float
    (`qdq_model`), its Relu reads it as NNCF's files leave it for OpenVINO to fuse into the conv."""
    if placement == Placement.ALL:
        return sorted({*registry, "HardSigmoid"} - {"ArgMax"})
    if placement == Placement.JOINS:
        return sorted({*CONV_OPS, *JOIN_OPS, *REMOVABLE_OPS})
    return sorted({*CONV_OPS, *REMOVABLE_OPS})
