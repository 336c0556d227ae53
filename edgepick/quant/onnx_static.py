"""Static PTQ of a float ONNX model edgepick did not train: edgepick's int8 recipe on any graph.

onnxruntime.quantization calibrates (min/max, percentile or entropy over the caller's input
tensors) and writes the QDQ graph; edgepick chooses what it quantizes and how, and rewrites
around it (docs/quantization.md, "Your own model"):

- before: the input dims fixed, opset lifted to 13, hardswish/hardsigmoid/mean pooling in the
  forms with integer kernels (`onnx_graph.rewrite_activations`), BatchNorm folded and shapes
  inferred (onnxruntime's `quant_pre_process`);
- the recipe: U8S8, weights int8 per output channel and symmetric, 7-bit unless
  weight_bits 8 (or first-7: 7-bit only where 8-bit weights saturate, `onnx_measure`), uint8
  activations per tensor, HardSigmoid quantized as well (with placement convs: only the convs
  and the tensors they read and write, the model's own activations left float as it writes them,
  for OpenVINO, which fuses them into its int8 convs); with gelu sigmoid, each GELU written as
  c * x * sigmoid(alpha * x) on integer kernels (`onnx_gelu`); with config.equalize, conv pairs equalized
  before calibration (`onnx_equalize`); with config.adaround, each conv's weight rounding learnt
  on the calibration tensors (`onnx_adaround`); with empirical bias correction, the conv biases
  shifted back to fp32's means (`onnx_measure`);
- after: the model's outputs and the ops between its last conv and them (Resize, Sigmoid,
  Softmax, ...) in float, as edgepick's own logits are (uint8 logits tie in an ArgMax or a
  threshold); the integer activations and the padding-tap crop of `edgepick.export`.

The file is checked before it is kept: every conv not named in keep_float has int8 weights, and
onnxruntime's int8 outputs are compared with its fp32 outputs (labels, or a thresholded map).
"""

from __future__ import annotations

import contextlib
import io
import itertools
import json
import tempfile
import time
from collections.abc import Iterable, Iterator
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from edgepick.errors import ParameterError
from edgepick.export.checks import check_onnx_out, conv_weight_report
from edgepick.export.crop_convs import crop_padded_convs, graph_links
from edgepick.export.int8_activations import integer_activations
from edgepick.export.onnx_io import CONV_OPS, fix_input_shape, graph_inputs, input_dims, lift_opset, load_float_onnx, opset
from edgepick.files import atomic_path
from edgepick.geometry import Size
from edgepick.quant.config import (
    HEADROOM,
    SATURATION_CHECK_INPUTS,
    BiasCorrection,
    CalibMethod,
    GeluForm,
    Placement,
    QuantConfig,
    WeightBits,
    lockstep_images,
)
from edgepick.quant.onnx_equalize import equalize_onnx
from edgepick.quant.onnx_gelu import sigmoid_gelu
from edgepick.quant.onnx_graph import fold_affine_into_convs, rewrite_activations
from edgepick.quant.onnx_measure import correct_onnx_biases, qdq_convs, saturating_onnx_convs, to_seven_bit_onnx
from edgepick.runtime.preprocessing import Preprocessing

CHECK_TENSORS = 8  # calibration tensors on which int8 outputs are compared with fp32's
# ops that may stand between a model's last conv and its outputs; they stay float with the outputs
FLOAT_TAIL_OPS = ("Resize", "Upsample", "Sigmoid", "Softmax", "LogSoftmax", "Transpose", "Reshape", "Identity",
                  "Squeeze", "Unsqueeze", "Flatten", "Slice", "Cast")
_ORT_METHODS = {CalibMethod.MINMAX: "MinMax", CalibMethod.PERCENTILE: "Percentile", CalibMethod.ENTROPY: "Entropy"}
LOGIT_SUMS = ("Add", "Sub")  # between the logits convs and the float tail, they keep a conv's output the logits
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".webp", ".tif", ".tiff")


@dataclass(frozen=True)
class OnnxPassResult:
    """The int8 file of a model edgepick did not make (an ONNX file or an nn.Module), what was done
    to it and how close it stays to fp32."""

    out: str
    size_bytes: int
    input_shape: list[int]
    opset_in: int | None  # None for an nn.Module
    opset_out: int
    convs: int
    int8_convs: int
    float_convs: list[str]
    agreement_vs_fp32: dict[str, float]  # per output: share of equal labels (or thresholded pixels)
    rewrites: dict[str, int]  # float rewrites before quantizing, and the int8 graph passes after
    quant: dict
    calib_tensors: int
    calib_s: float

    def to_dict(self) -> dict:
        return asdict(self)


def check_tensor(x: Any, shape: tuple[int, ...] | None, what: str) -> np.ndarray:
    """X as a float32 input tensor with a batch axis (added when X lacks it), refused in one line
    naming WHAT when it is not a finite float array of SHAPE."""
    if not isinstance(x, np.ndarray) or x.dtype.kind != "f":
        got = f"{x.dtype} {x.shape}" if isinstance(x, np.ndarray) else type(x).__name__
        raise ParameterError(f"{{calib:name}}: {what} must be a float array, got {got}", calib=what)
    if shape is not None and x.ndim == len(shape) - 1:
        x = x[None]
    if shape is not None and tuple(x.shape) != tuple(shape):
        raise ParameterError(f"{{calib:name}}: {what} has shape {list(x.shape)}, the model takes {list(shape)}",
                             calib=what)
    if not np.isfinite(x).all():
        raise ParameterError(f"{{calib:name}}: {what} holds NaN or infinity", calib=what)
    return np.ascontiguousarray(x, dtype=np.float32)


def folder_tensors(folder: str | Path, preprocessing: Preprocessing | None = None,
                   size: Size | None = None) -> Iterator[np.ndarray]:
    """Calibration inputs from FOLDER: its .npy files (one input tensor each, in the model's
    layout), or else its images, made into tensors by PREPROCESSING at SIZE (its own size, or this)."""
    import cv2

    folder = Path(folder)
    if not folder.is_dir():
        raise ParameterError("{calib}: not a folder", calib=folder)
    arrays = sorted(p for p in folder.iterdir() if p.suffix.lower() == ".npy")
    images = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not arrays and not images:
        raise ParameterError("{calib}: holds no .npy tensors and no images", calib=folder)
    if arrays:
        for p in arrays:
            try:
                yield np.load(p, allow_pickle=False)
            except (OSError, ValueError) as exc:
                raise ParameterError(f"{{calib}}: {p.name} is not a readable .npy file ({exc})", calib=folder) from None
        return
    prep = preprocessing or Preprocessing()
    at = prep.size or size
    if at is None:
        raise ParameterError("{size:name} is needed for images: the model's input has no fixed size", size=None)
    for p in images:
        bgr = cv2.imread(str(p), cv2.IMREAD_COLOR)
        if bgr is None:
            raise ParameterError(f"{{calib}}: {p.name} is not a readable image", calib=folder)
        yield prep.tensor(bgr[..., ::-1], at)


class _Reader:
    """onnxruntime's CalibrationDataReader over checked tensors, keeping the first KEEP (for the
    check and for what the pass measures)."""

    def __init__(self, name: str, tensors: Iterator[np.ndarray], shape: tuple[int, ...], keep: int, progress: bool):
        from edgepick.progress import progress as progress_bar

        self.name, self.shape, self.seen, self.keep = name, shape, 0, keep
        self.kept: list[np.ndarray] = []
        self.it = iter(progress_bar(tensors, desc="calibrate", unit="tensor", enabled=progress))

    def get_next(self) -> dict | None:
        x = next(self.it, None)
        if x is None:
            return None
        x = check_tensor(x, self.shape, f"calibration tensor {self.seen + 1}")
        self.seen += 1
        if len(self.kept) < self.keep:
            self.kept.append(x)
        return {self.name: x}

    def rewind(self) -> None:  # onnxruntime's API; each tensor is read once
        pass


def _float_tail(model: Any) -> list[str]:
    """Nodes between the last convs (or other compute) and the graph outputs, left in float."""
    producer = {o: n for n in model.graph.node for o in n.output}
    names, todo = [], [o.name for o in model.graph.output]
    while todo:
        node = producer.get(todo.pop())
        if node is None or node.op_type not in FLOAT_TAIL_OPS or node.name in names:
            continue
        names.append(node.name)
        todo.append(node.input[0])
    return names


def _writes_float_output(model: Any) -> set[str]:
    """The convs that write the logits: their output reaches a graph output through nothing but
    FLOAT_TAIL_OPS and additions (LR-ASPP sums two convs' logits). Bias correction leaves them
    alone, as quant/bias_correction.py does."""
    producer = {o: n for n in model.graph.node for o in n.output}
    todo, seen, convs = [o.name for o in model.graph.output], set(), set()
    while todo:
        node = producer.get(todo.pop())
        if node is None or node.name in seen:
            continue
        seen.add(node.name)
        if node.op_type in CONV_OPS:
            convs.add(node.name)
        elif node.op_type in LOGIT_SUMS:
            todo.extend(node.input)
        elif node.op_type in FLOAT_TAIL_OPS:
            todo.append(node.input[0])
    return convs


def _float_outputs(model: Any, tail: list[str]) -> int:
    """Drop the Q -> DQ pair in front of each graph output and of each TAIL node (the float ops
    before the outputs), so that they get the float tensor the last quantized node makes; returns
    how many pairs it dropped."""
    producer, consumers, _ = graph_links(model.graph)
    readers = {name: len(nodes) for name, nodes in consumers.items()}
    into_tail = [n.input[0] for n in model.graph.node if n.name in tail]
    freed = 0
    for name in [*(o.name for o in model.graph.output), *into_tail]:
        dq = producer.get(name)
        q = producer.get(dq.input[0]) if dq is not None and dq.op_type == "DequantizeLinear" else None
        if q is None or q.op_type != "QuantizeLinear" or readers.get(q.output[0]) != 1:
            continue
        source = q.input[0]
        made = producer.get(source)
        if made is None or readers.get(source, 0) != 1 or readers.get(name, 0) > 1:
            continue
        made.output[list(made.output).index(source)] = name
        producer[name] = made
        model.graph.node.remove(q)
        model.graph.node.remove(dq)
        freed += 1
    return freed


def decisions(y: np.ndarray, nhwc: bool, probability: bool) -> np.ndarray:
    """What a segmentation output decides per pixel: the argmax over channels, or a threshold of
    a one-channel map (0.5 for a probability, 0 for a logit)."""
    axis = -1 if nhwc else 1
    if y.ndim == 4 and y.shape[axis] > 1:
        return y.argmax(axis)
    return y > (0.5 if probability else 0.0)


def output_agreement(fp32: Path, int8: Path, name: str, tensors: list[np.ndarray], nhwc: bool) -> dict[str, float]:
    """Per output, the share of pixels where the int8 model decides as the fp32 model does."""
    import onnx

    from edgepick.runtime.session import plain_session

    model = onnx.load(str(fp32))
    producer = {o: n for n in model.graph.node for o in n.output}
    prob = {o.name: getattr(producer.get(o.name), "op_type", "") in ("Sigmoid", "Softmax") for o in model.graph.output}
    a, b = plain_session(fp32), plain_session(int8)
    names = [o.name for o in a.get_outputs()]
    same = dict.fromkeys(names, 0)
    total = dict.fromkeys(names, 0)
    for x in tensors:
        for n, ya, yb in zip(names, a.run(names, {name: x}), b.run(names, {name: x})):
            da, db = decisions(ya, nhwc, prob[n]), decisions(yb, nhwc, prob[n])
            same[n] += int((da == db).sum())
            total[n] += da.size
    return {n: round(same[n] / max(total[n], 1), 5) for n in names}


def quantize_onnx_static(model: str | Path, calib: Iterable[np.ndarray], out: str | Path,
                         config: QuantConfig | None = None, input_shape: tuple[int, ...] | None = None,
                         progress: bool = True) -> OnnxPassResult:
    """Static PTQ of the float ONNX file MODEL with edgepick's recipe, calibrated on CALIB (the
    model's input tensors, float, with or without the batch axis; `folder_tensors` reads a folder),
    written to OUT. INPUT_SHAPE fixes dynamic input dims [default: the first tensor's shape].
    config.keep_float names ONNX nodes to leave in float."""
    import onnxruntime
    from onnxruntime.quantization import (
        CalibrationMethod,
        QuantFormat,
        QuantType,
        quant_pre_process,
        quantize_static,
    )
    from onnxruntime.quantization.registry import QDQRegistry, QLinearOpsRegistry

    config = config or QuantConfig()
    check_onnx_out(out, model)
    onnxruntime.set_default_logger_severity(3)  # its quantizer's sessions warn about every unused initializer
    if config.bias_correction == BiasCorrection.FAST:
        raise ParameterError("{bias_correction}: fast is not available for ONNX models; use empirical",
                             bias_correction=config.bias_correction)
    if config.calib_method not in _ORT_METHODS:
        raise ParameterError(f"{{calib_method}}: not available for ONNX models; use one of "
                             f"{', '.join(m.value for m in _ORT_METHODS)}", calib_method=config.calib_method)
    proto = load_float_onnx(model)
    known = {n.name for n in proto.graph.node}
    unknown = [k for k in config.keep_float if k not in known]
    if unknown:
        raise ParameterError(f"{{keep_float:name}} names no node of the model: {', '.join(unknown)}",
                             keep_float=tuple(unknown))
    name, rank = graph_inputs(proto)[0].name, len(input_dims(proto))
    tensors = iter(calib)
    first = next(tensors, None)
    if first is None:
        raise ParameterError("{calib:name}: no tensors; calibration needs at least one", calib=None)
    if input_shape is None:
        fixed = [d if isinstance(d, int) else None for d in input_dims(proto)]
        arr = check_tensor(first, None, "calibration tensor 1")
        input_shape = tuple(arr.shape if arr.ndim == rank else (1, *arr.shape))
        if any(f is not None and f != s for f, s in zip(fixed, input_shape)):
            raise ParameterError(f"{{calib:name}}: calibration tensor 1 has shape {list(arr.shape)}, the model "
                                 f"takes {input_dims(proto)}", calib=None)
    check_tensor(first, input_shape, "calibration tensor 1")
    t0 = time.perf_counter()
    opset_in = opset(proto)
    fix_input_shape(proto, tuple(input_shape))
    proto = lift_opset(proto, model)
    every_op = config.placement == Placement.ALL
    rewrites = {**(rewrite_activations(proto) if every_op else {}), "affine_folded": fold_affine_into_convs(proto)}
    nhwc = len(input_shape) == 4 and input_shape[-1] in (1, 3, 4) and input_shape[1] not in (1, 3, 4)
    with tempfile.TemporaryDirectory(prefix="edgepick-onnx-") as tmp:
        pre, qdq = Path(tmp) / "float.onnx", Path(tmp) / "qdq.onnx"
        with _quiet():
            quant_pre_process(proto, str(pre))
        import onnx

        prepared = onnx.load(str(pre))
        if config.equalize:
            rewrites["equalized_pairs"] = equalize_onnx(prepared)
            onnx.save(prepared, str(pre))
        hw = input_shape[1:3] if nhwc else input_shape[-2:]
        measured = lockstep_images(*hw) if config.bias_correction != BiasCorrection.NONE or config.adaround else 0
        keep = max(CHECK_TENSORS, measured, SATURATION_CHECK_INPUTS if config.weight_bits == WeightBits.FIRST_SEVEN
                   else 0)
        reader = _Reader(name, itertools.chain([first], tensors), tuple(input_shape), keep, progress)
        ops = sorted({*QDQRegistry, *QLinearOpsRegistry, "HardSigmoid"} - {"ArgMax"}) if every_op else sorted(CONV_OPS)
        with _quiet():
            quantize_static(str(pre), str(qdq), reader, quant_format=QuantFormat.QDQ, per_channel=True,
                            reduce_range=config.reduce_range, activation_type=QuantType.QUInt8,
                            weight_type=QuantType.QInt8, calibrate_method=CalibrationMethod[_ORT_METHODS[
                                config.calib_method]], op_types_to_quantize=ops,
                            nodes_to_exclude=[*config.keep_float, *_float_tail(prepared)],
                            extra_options={"ActivationSymmetric": False, "WeightSymmetric": True,
                                           "CalibPercentile": config.percentile, "CalibMaxIntermediateOutputs": 4})
        int8 = onnx.load(str(qdq))
        if config.gelu == GeluForm.SIGMOID:  # before the bias correction, which then measures it
            rewrites["sigmoid_gelu"] = sigmoid_gelu(int8)
        done = _measure(prepared, int8, reader.kept, measured, config)
        steps = {**rewrites, "float_outputs": _float_outputs(int8, _float_tail(prepared)), **integer_activations(int8),
                 "cropped_convs": crop_padded_convs(int8)}
        quant = {"mode": "static", "source": "onnx", "calib_method": config.calib_method.value,
                 "calib_images": reader.seen, "percentile": config.percentile, "weight_bits": config.weight_bits.value,
                 "placement": config.placement.value, "gelu": config.gelu.value, "equalize": config.equalize,
                 "bias_correction": config.bias_correction.value,
                 "adaround": config.adaround, **({"adaround_budget_s": config.adaround_budget_s} if config.adaround else {}),
                 "keep_float": list(config.keep_float), **done}
        if config.equalize:
            quant["equalized_pairs"] = rewrites["equalized_pairs"]
        entry = int8.metadata_props.add()
        entry.key, entry.value = "edgepick.quant", json.dumps(quant)
        calib_s = time.perf_counter() - t0
        with atomic_path(out) as path:
            onnx.save(int8, str(path))
            onnx.checker.check_model(str(path), full_check=True)
            report = conv_weight_report(path)
            expected = sum(1 for n in prepared.graph.node if n.op_type in CONV_OPS and n.name not in config.keep_float)
            if report["int8"] < expected:
                from edgepick.quant.graph import QuantizationError

                raise QuantizationError(f"only {report['int8']} of {expected} convs got int8 weights in the ONNX: "
                                        f"{', '.join(report['float'])} stayed float")
            agreement = output_agreement(pre, path, name, reader.kept[:CHECK_TENSORS], nhwc)
    out = Path(out)
    return OnnxPassResult(out=str(out), size_bytes=out.stat().st_size, input_shape=list(input_shape),
                          opset_in=opset_in, opset_out=opset(int8), convs=report["convs"], int8_convs=report["int8"],
                          float_convs=report["float"], agreement_vs_fp32=agreement, rewrites=steps, quant=quant,
                          calib_tensors=reader.seen, calib_s=round(calib_s, 2))


def _measure(prepared: Any, int8: Any, kept: list[np.ndarray], images: int, config: QuantConfig) -> dict:
    """first-7, AdaRound and empirical bias correction on the QDQ graph INT8 (in place), in that
    order, measured on KEPT (the first calibration tensors; IMAGES of them for AdaRound and the
    correction); returns what was done."""
    done: dict = {}
    if config.weight_bits == WeightBits.FIRST_SEVEN:
        from edgepick.quant.overflow import INT16

        share = saturating_onnx_convs(int8, kept[:SATURATION_CHECK_INPUTS], HEADROOM * INT16)
        done["seven_bit_convs"] = [name for name, s in share.items() if s > 0]
        to_seven_bit_onnx(prepared, int8, done["seven_bit_convs"])
    if config.adaround:
        from edgepick.quant.onnx_adaround import adaround_onnx

        seven = set(qdq_convs(int8)) if config.weight_bits == WeightBits.SEVEN else set(done.get("seven_bit_convs", []))
        rounded = adaround_onnx(prepared, int8, kept[:images], config.adaround_budget_s, seven)
        done["adaround_convs"] = sum(r["error_adaround"] < r["error_nearest"] for r in rounded.values())
    if config.adaround or config.bias_correction == BiasCorrection.EMPIRICAL:
        done["measured_images"] = min(images, len(kept))
    if config.bias_correction == BiasCorrection.EMPIRICAL:
        correct_onnx_biases(prepared, int8, kept[:images], _writes_float_output(prepared))
    return done


@contextlib.contextmanager
def _quiet() -> Iterator[None]:
    """onnxruntime's quantizer prints its steps to stdout, where edgepick's commands print their
    JSON; edgepick's own progress bar says what it is doing."""
    with contextlib.redirect_stdout(io.StringIO()):
        yield
