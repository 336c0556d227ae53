"""What static PTQ measures on the calibration images, for an int8 QDQ ONNX graph written by
onnxruntime's quantizer (quant/onnx/static.py), as quant/pt2e/ptq.py does it for a torch graph:

- first-7: each conv's uint8 input codes, from the int8 model run on sample inputs, are paired
  with its 8-bit weights as an AVX2 U8S8 kernel pairs them (`edgepick.quant.methods.saturated_share`); the convs whose
  pair sums come near the int16 limit are requantized to 7-bit weights from the float weights,
  on the grid onnxruntime's own 7-bit weights use (-64..64, symmetric), their int32 biases with them;
- empirical bias correction (AIMET's form): each conv's int32 bias is shifted by the median over
  the images of the gap between the float model's and its own per-channel output mean (the median,
  so that one image whose activations are clipped hard does not set every image's bias, as in
  quant/pt2e/bias_correction.py). Convs are corrected in
  waves: a wave holds the convs whose inputs depend only on convs of earlier waves, which are
  already corrected, so what a conv compensates includes the errors from upstream, once. The graph
  is cut after each wave and the images run through it together, segment by segment (as the torch
  form runs its graph node by node), so each image passes through the model once.

Both edit initializers only (weight codes, weight scales, bias codes, bias scales): the graph,
and so the latency, stays as onnxruntime wrote it. Graphs are run with onnxruntime's graph
optimisations off, each Q/DQ pair computed as written.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from edgepick.onnx_graph import Graph, attr
from edgepick.quant.methods import bias_shift, saturated_share
from edgepick.quant.onnx.lockstep import channel_means, image_means, runner, segment_session, segments

SEVEN_BIT = 64  # onnxruntime's reduce-range int8 weight grid: -64..64, scale = max |w| / 64
BIASED_OPS = ("Conv", "ConvTranspose", "Gemm")  # their int32 bias's scale is the input's times the weight's
BIAS_SCALE_ROOM = 1.01  # a bias scale within 1% of the writer's widening limit: the writer is asked again


@dataclass(frozen=True)
class QdqConv:
    """A Conv of a QDQ graph with uint8 input codes, int8 per-channel weights and an int32 bias,
    by the names of the tensors and initializers that make it up."""

    node: Any
    codes: str  # the uint8 tensor its input DequantizeLinear reads
    input_scale: str
    input_zero: str
    weight_codes: str
    weight_scale: str
    bias_codes: str | None
    bias_scale: str | None


def qdq_convs(model: Any, op_types: tuple[str, ...] = ("Conv",)) -> dict[str, QdqConv]:
    """The Convs (or nodes of OP_TYPES) of MODEL (QDQ) with a DequantizeLinear on their input and on
    their own, unshared int8 weights, by node name; the bias, when it is a DequantizeLinear of its own
    int32 codes."""
    from onnx import TensorProto

    g = Graph(model)

    def own_dq(name: str) -> Any | None:
        dq = g.producer(name)
        if dq is None or dq.op_type != "DequantizeLinear" or len(g.consumers(name)) != 1:
            return None
        return dq if g.is_initializer(dq.input[0]) and len(g.consumers(dq.input[0])) == 1 else None

    found = {}
    for n in g.nodes:
        if n.op_type not in op_types or len(n.input) < 2:
            continue
        x, w = g.producer(n.input[0]), own_dq(n.input[1])
        codes = g.initializer(w.input[0]) if w is not None else None
        if x is None or x.op_type != "DequantizeLinear" or w is None or codes is None or \
                codes.data_type != TensorProto.INT8:
            continue
        b = own_dq(n.input[2]) if len(n.input) > 2 and n.input[2] else None
        found[n.name] = QdqConv(n, x.input[0], x.input[1], x.input[2], w.input[0], w.input[1],
                                b.input[0] if b is not None else None, b.input[1] if b is not None else None)
    return found


class Values:
    """A model's initializers as arrays, read and written back by name (`values[name]`)."""

    def __init__(self, model: Any):
        self.graph = Graph(model)

    def __getitem__(self, name: str) -> np.ndarray:
        value = self.graph.array(name)
        if value is None:
            raise KeyError(name)
        return value

    def __setitem__(self, name: str, value: np.ndarray) -> None:
        self.graph.set_array(name, value)


def adjusted_ranges(float_model: Any, ranges: dict[str, tuple[float, float]], op_types: Collection[str] | None = None,
                    exclude: Collection[str] = ()) -> dict[str, tuple[float, float]]:
    """RANGES as onnxruntime's QDQ writer adjusts them before it computes the qparams: a Relu's or
    Clip's input (read by it alone) takes its output's range, a Softmax's output is [0, 1]; as its
    writer does, only for the nodes it quantizes (of OP_TYPES, or any type; none in EXCLUDE)."""
    g = Graph(float_model)
    adjusted = dict(ranges)
    for n in g.nodes:
        if (op_types is not None and n.op_type not in op_types) or n.name in exclude:
            continue
        if n.op_type in ("Relu", "Clip") and len(g.consumers(n.input[0])) == 1 and n.output[0] in adjusted:
            if n.input[0] in adjusted:
                adjusted[n.input[0]] = adjusted[n.output[0]]
        elif n.op_type == "Softmax" and n.output[0] in adjusted:
            adjusted[n.output[0]] = (0.0, 1.0)
    return adjusted


def requantize_activations(model: Any, float_model: Any, ranges: dict[str, tuple[float, float]]) -> bool:
    """Set the uint8 qparams of MODEL's activations (QDQ, as onnxruntime wrote it from FLOAT_MODEL) to
    those of RANGES, as its writer computes them, and the int32 bias codes of its Convs,
    ConvTransposes and Gemms to the new input scales: the graph calib_method auto measures each
    candidate rule with, without writing it again.
    (onnxruntime's writer may also widen a weight's scale where a bias would overflow int32; here
    such a bias clips, so a candidate's measure can differ from its written file's in that case.)
    Returns whether MODEL is now what the writer writes for RANGES: every activation's qparams and
    every int32 bias set, and no bias scale, before or after, near the limit where it widens."""
    from onnxruntime.quantization.quant_utils import compute_scale_zp

    values = Values(model)
    weights = {i.name for i in float_model.graph.initializer}
    done: set[str] = set()
    exact = True
    for q in values.graph.nodes:
        if q.op_type != "QuantizeLinear" or q.input[0] in weights or len(q.input) < 3 or q.input[1] in done:
            continue
        if not values.graph.is_initializer(q.input[1]) or not values.graph.is_initializer(q.input[2]):
            continue
        # qparams shared along a chain (a pool or Reshape after a Relu: one scale initializer, named after the
        # chain's first tensor) take that tensor's range, as the writer computes them
        owner = q.input[1].removesuffix("_scale")
        tensor = owner if owner in ranges else q.input[0]
        zero_point = values[q.input[2]]
        if tensor not in ranges or zero_point.dtype != np.uint8:
            exact = False
            continue
        done.add(q.input[1])
        low, high = ranges[tensor]
        zero, scale = compute_scale_zp(np.array(low, np.float32), np.array(high, np.float32), np.array(0, np.uint8),
                                       np.array(255, np.uint8))
        values[q.input[1]] = np.asarray(scale, np.float32).reshape(values[q.input[1]].shape)
        values[q.input[2]] = np.asarray(zero, np.uint8).reshape(zero_point.shape)
    floats, by_name = Values(float_model), {n.name: n for n in float_model.graph.node}
    biases = 0
    for name, c in qdq_convs(model, BIASED_OPS).items():
        source = by_name.get(name)
        if c.bias_codes is None or c.bias_scale is None or source is None or len(source.input) < 3:
            continue
        scale = (values[c.input_scale].astype(np.float64) * values[c.weight_scale]).astype(np.float32)
        bias = floats[source.input[2]].astype(np.float64)
        exact = exact and _clear_of_int32(bias, values[c.bias_scale]) and _clear_of_int32(bias, scale)
        values[c.bias_codes] = np.clip(np.round(bias / scale), -2 ** 31, 2 ** 31 - 1).astype(np.int32)
        values[c.bias_scale] = scale.reshape(values[c.bias_scale].shape)
        biases += 1
    return exact and biases == _int32_biases(values.graph)


def _clear_of_int32(bias: np.ndarray, scale: np.ndarray) -> bool:
    """Whether BIAS on the grid of SCALE (per channel, or one for all) stays clear of the int32 limit
    at which onnxruntime's writer widens the weight's scale (its _adjust_weight_scale_for_int32_bias:
    1.0001 * 2|b| / (2^32 - 2)), with a margin of BIAS_SCALE_ROOM."""
    flat = np.asarray(scale, np.float64).reshape(-1)
    need = 1.0001 * 2.0 * (np.abs(bias).reshape(-1) if flat.size > 1 else np.abs(bias).max(initial=0.0)) / (2.0 ** 32 - 2)
    return bool(np.all(flat >= need * BIAS_SCALE_ROOM))


def _int32_biases(g: Graph) -> int:
    """How many DequantizeLinears of GRAPH read int32 initializers (the biases its writer quantized)."""
    from onnx import TensorProto

    return sum(1 for n in g.nodes if n.op_type == "DequantizeLinear" and (c := g.initializer(n.input[0])) is not None
               and c.data_type == TensorProto.INT32)


def saturating_onnx_convs(model: Any, tensors: list[np.ndarray], limit: float) -> dict[str, float]:
    """For each conv of MODEL (QDQ, 8-bit weights), the largest share of its outputs over TENSORS
    that an AVX2 U8S8 kernel would compute with a pair sum beyond +-LIMIT."""
    convs = qdq_convs(model)
    values = Values(model)
    names = sorted({c.codes for c in convs.values()})
    run = runner(model, names)
    share = dict.fromkeys(convs, 0.0)
    for x in tensors:
        codes = dict(zip(names, run(x, names), strict=True))
        for name, c in convs.items():
            if codes[c.codes].dtype != np.uint8 or attr(c.node, "auto_pad", b"NOTSET") not in (b"NOTSET", "NOTSET"):
                share[name] = 1.0 if codes[c.codes].dtype == np.uint8 else 0.0  # unknown padding: count it as saturating
                continue
            top, left, bottom, right = attr(c.node, "pads", [0, 0, 0, 0])
            zero = int(values[c.input_zero])
            padded = np.pad(codes[c.codes], ((0, 0), (0, 0), (top, bottom), (left, right)), constant_values=zero)
            s = saturated_share(padded, values[c.weight_codes], zero, tuple(attr(c.node, "strides", [1, 1])), (0, 0),
                                tuple(attr(c.node, "dilations", [1, 1])), int(attr(c.node, "group", 1)), limit)
            share[name] = max(share[name], s)
    return share


def to_seven_bit_onnx(float_model: Any, model: Any, names: list[str]) -> None:
    """Requantize the weights of the convs NAMES of MODEL (QDQ) to 7 bits from the float weights
    and biases of the same convs in FLOAT_MODEL (the graph that was quantized), in place."""
    convs, values, floats = qdq_convs(model), Values(model), Values(float_model)
    by_name = {n.name: n for n in float_model.graph.node}
    for name in names:
        c, source = convs[name], by_name[name]
        w = floats[source.input[1]].astype(np.float64)
        absmax = np.abs(w).reshape(w.shape[0], -1).max(axis=1)
        scale = np.where(absmax > 0, absmax / SEVEN_BIT, 1.0).astype(np.float32)
        shape = (-1, *[1] * (w.ndim - 1))
        values[c.weight_codes] = np.clip(np.round(w / scale.reshape(shape)), -SEVEN_BIT, SEVEN_BIT).astype(np.int8)
        values[c.weight_scale] = scale
        if c.bias_codes is not None and c.bias_scale is not None:
            bias_scale = (values[c.input_scale].astype(np.float64) * scale).astype(np.float32)
            b = floats[source.input[2]].astype(np.float64)
            values[c.bias_codes] = np.clip(np.round(b / bias_scale), -2 ** 31, 2 ** 31 - 1).astype(np.int32)
            values[c.bias_scale] = bias_scale


def correct_onnx_biases(float_model: Any, model: Any, tensors: list[np.ndarray], skip: set[str],
                        fp32_means: Mapping[str, list[np.ndarray]] | None = None) -> int:
    """Empirical bias correction of MODEL (QDQ) in place, against the same convs of FLOAT_MODEL on
    TENSORS (model inputs): MODEL runs on all TENSORS together, segment by segment (`segments`),
    and each wave's convs are corrected before the segments after it run. Convs named in SKIP are
    left alone. FP32_MEANS: FLOAT_MODEL's per-channel means of its conv outputs on TENSORS, where
    calibration counted them (run for them otherwise). Returns how many convs were corrected."""
    by_name = {n.name: n for n in float_model.graph.node}
    convs = {name: c for name, c in qdq_convs(model).items() if name not in skip and name in by_name}
    bias = {name: (c.bias_codes, c.bias_scale) for name, c in convs.items()
            if c.bias_codes is not None and c.bias_scale is not None}
    if not bias:
        return 0
    names = list(bias)
    outputs = [by_name[name].output[0] for name in names]
    if fp32_means and all(len(fp32_means.get(out, [])) >= len(tensors) for out in outputs):
        target = {name: np.concatenate(fp32_means[out][:len(tensors)]) for name, out in zip(names, outputs)}
    else:
        fp32 = channel_means(float_model, outputs)
        rows: dict[str, list[np.ndarray]] = {name: [] for name in names}
        for x in tensors:
            for name, means in zip(names, fp32(x), strict=True):
                rows[name].append(means)
        target = {name: np.concatenate(r) for name, r in rows.items()}
    values = Values(model)
    image = model.graph.input[0].name
    env = [{image: x} for x in tensors]  # per tensor, what later segments read
    for segment in segments(model, bias):
        if not segment.outputs:  # after the last wave: nothing left to correct
            break
        session = segment_session(model, segment, env[0])
        for e in env:
            e.update(zip(segment.outputs, session.run(segment.outputs, {i: e[i] for i in segment.inputs}), strict=True))
            for name in segment.last:
                del e[name]
        for name in segment.wave:
            codes_name, scale_name = bias[name]
            out, scale = convs[name].node.output[0], values[scale_name].astype(np.float64)
            got = np.concatenate([image_means(e[out]) for e in env])
            delta = bias_shift(target[name], got)
            codes = values[codes_name]
            moved = np.clip(np.round(codes + (delta / scale).reshape(codes.shape)), -2 ** 31, 2 ** 31 - 1)
            values[codes_name] = moved.astype(np.int32)
            step = ((moved - codes) * scale).astype(np.float32).reshape(1, -1, *[1] * (env[0][out].ndim - 2))
            for e in env:  # the conv's output as the corrected bias gives it, for the segments after
                e[out] = e[out] + step
    return len(bias)
