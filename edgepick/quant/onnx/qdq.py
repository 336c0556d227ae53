"""The QDQ graph of a float ONNX model for given activation ranges, and the per-model choice of the
rule those ranges come from.

onnxruntime's QDQ quantizer places the Q/DQ pairs and quantizes the weights; the ranges are
edgepick's own (quant/onnx/calibrate.py), handed to it as a calibrator would. Which rule reads the
ranges best off the histograms depends on the model: a percentile that suits a segmentation
backbone clips a detector's rare high objectness logits, min/max wastes levels on a tensor with
one outlier. With `CalibMethod.AUTO`, every candidate rule gives a QDQ graph, each graph runs on
held-out calibration tensors, and the one whose outputs stay closest to fp32's is kept (the
lowest relative error per output channel, worst output first). Whatever the rule, the tensors
that reach a graph output through no conv or matmul (a head's logits, a Sigmoid's scores, the
Concat of boxes and scores) keep their whole min/max range: clipping them changes the output
itself.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from edgepick.export.onnx_io import CONV_OPS
from edgepick.onnx_graph import Graph, copy_model
from edgepick.quant.config import QuantConfig
from edgepick.quant.fidelity import OutputFidelity, RuleScore, compare_outputs, most_changed, ranked_rule
from edgepick.quant.onnx.calibrate import Collector
from edgepick.quant.onnx.evaluator import Evaluator
from edgepick.quant.onnx.floating import REMOVABLE_OPS, restore_activation
from edgepick.quant.onnx.measure import adjusted_ranges, requantize_activations
from edgepick.quant.ranges import RangeRule, candidate_rules

# ops that may stand between a model's last conv and its outputs; they stay float with the outputs
FLOAT_TAIL_OPS = ("Resize", "Upsample", "Sigmoid", "Softmax", "LogSoftmax", "Transpose", "Reshape", "Identity",
                  "Squeeze", "Unsqueeze", "Flatten", "Slice", "Cast")
LOGIT_SUMS = ("Add", "Sub")  # between the logits convs and the float tail, they keep a conv's output the logits
# what the outputs on the uint8 grid may lose against float outputs and still stay on it (outputs_on_grid): dB of
# SQNR, on the whole output and on its worst channel, and the share of its decisions
OUTPUT_GRID_DB, OUTPUT_GRID_AGREEMENT = 0.5, 0.001
GRID_OPS = ("Conv", "MatMul", "Gemm")  # onnxruntime runs them as integer kernels only when their output is quantized
COMPUTE_OPS = ("Conv", "ConvTranspose", "MatMul", "Gemm", "LSTM", "GRU", "RNN", "Einsum", "Attention")


def qdq_model(prepared: Path, ranges: dict[str, tuple[float, float]], op_types: Sequence[str],
              exclude: Sequence[str], reduce_range: bool, conv_outputs: bool = True) -> Any:
    """The QDQ ModelProto onnxruntime's quantizer writes from the float model PREPARED (shapes
    inferred) with RANGES for the activations: U8S8, weights per channel and symmetric (7-bit with
    REDUCE_RANGE), activations asymmetric; nodes of OP_TYPES quantized but those in EXCLUDE. Without
    CONV_OUTPUTS a conv's output is on the grid only where a quantized op reads it (placements convs
    and joins, for OpenVINO: docs/quantization.md); onnxruntime needs it there to run an integer conv."""
    from onnxruntime.quantization.calibrate import CalibrationMethod, TensorsData
    from onnxruntime.quantization.qdq_quantizer import QDQQuantizer
    from onnxruntime.quantization.quant_utils import QuantType, load_model_with_shape_infer

    model = load_model_with_shape_infer(Path(prepared))
    data = TensorsData(CalibrationMethod.MinMax,
                       {name: (np.array(lo, np.float32), np.array(hi, np.float32)) for name, (lo, hi) in ranges.items()})
    quantizer = QDQQuantizer(model, True, reduce_range, QuantType.QInt8, QuantType.QUInt8, data, [], list(exclude),
                             list(op_types), {"ActivationSymmetric": False, "WeightSymmetric": True,
                                                     "OpTypesToExcludeOutputQuantization": [] if conv_outputs else list(CONV_OPS)})
    quantizer.quantize_model()
    quantizer.model.topological_sort()  # as its save_model_to_file does: passes after it walk the nodes in order
    return quantizer.model.model


def exact_tensors(model: Any) -> set[str]:
    """The tensors of MODEL from which a graph output is reached through no compute op (conv,
    matmul, ...): what they hold is what the output holds, so their range is never clipped."""
    g = Graph(model)
    found: set[str] = set()
    todo = [o.name for o in model.graph.output]
    while todo:
        name = todo.pop()
        if name in found:
            continue
        found.add(name)
        node = g.producer(name)
        if node is not None and node.op_type not in COMPUTE_OPS:
            todo.extend(i for i in node.input if i)
    return found


def float_tail(model: Any) -> list[str]:
    """Nodes between the last convs (or other compute) and the graph outputs, left in float."""
    g = Graph(model)
    names, todo = [], [o.name for o in model.graph.output]
    while todo:
        node = g.producer(todo.pop())
        if node is None or node.op_type not in FLOAT_TAIL_OPS or node.name in names:
            continue
        names.append(node.name)
        todo.append(node.input[0])
    return names


def writes_float_output(model: Any) -> set[str]:
    """The convs that write the logits: their output reaches a graph output through nothing but
    FLOAT_TAIL_OPS and additions (LR-ASPP sums two convs' logits). Bias correction leaves them
    alone, as quant/pt2e/bias_correction.py does."""
    g = Graph(model)
    todo, seen, convs = [o.name for o in model.graph.output], set(), set()
    while todo:
        node = g.producer(todo.pop())
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


def float_outputs(model: Any, tail: list[str], float_model: Any, keep: Sequence[str] = ()) -> int:
    """Drop the Q -> DQ pair in front of each graph output and of each TAIL node (the float ops
    before the outputs), so that they get the float tensor the last quantized node makes, but where
    an op of a type in KEEP writes it; a Relu or Clip onnxruntime's writer left out there (the uint8
    grid clamped for it) is put back from FLOAT_MODEL. Returns how many pairs it dropped."""
    g, fg = Graph(model), Graph(float_model)
    into_tail = [n.input[0] for n in g.nodes if n.name in tail]
    freed = 0
    for name in [*(o.name for o in model.graph.output), *into_tail]:
        dq = g.producer(name)
        q = g.producer(dq.input[0]) if dq is not None and dq.op_type == "DequantizeLinear" else None
        if q is None or q.op_type != "QuantizeLinear" or len(g.consumers(q.output[0])) != 1:
            continue
        source = q.input[0]
        made = g.producer(source)
        if made is None or made.op_type in keep or len(g.consumers(source)) != 1 or len(g.consumers(name)) > 1:
            continue
        g.remove(q, dq)
        g.set_output(made, source, name)
        activation = fg.producer(name)
        if activation is not None and activation.op_type in REMOVABLE_OPS and made.op_type != activation.op_type:
            restore_activation(g, activation, made, fg)
        freed += 1
    return freed


def outputs_on_grid(int8: Any, tail: list[str], evaluator: Evaluator) -> tuple[Any, int, dict]:
    """INT8 with the outputs written by convs and matmuls (and such inputs of the TAIL ops before the
    outputs) on the uint8 grid, as onnxruntime's quantizer leaves them, where that takes no output,
    and none of its channels, more than OUTPUT_GRID_DB further from fp32 on EVALUATOR's check tensors
    and moves no more than OUTPUT_GRID_AGREEMENT of its decisions off fp32's (uint8 logits can tie in
    an ArgMax or at a threshold); every other output pair dropped (`float_outputs`). On the grid
    those convs run as integer convs: in float after dequantizing their inputs, a table-cell
    detector's four output convs made it 1.15x onnxruntime's best file's time (docs/quantization.md).
    A Concat of boxes and scores stays float: one uint8 grid over both would round the scores away.
    Returns the graph, how many pairs were dropped and the record."""
    floated = copy_model(int8)
    dropped = float_outputs(floated, tail, evaluator.float_model)
    mixed = copy_model(int8)
    partly = float_outputs(mixed, tail, evaluator.float_model, keep=GRID_OPS)
    if partly == dropped:
        return floated, dropped, {}
    (on_grid, grid_channels), (off_grid, float_channels) = _fidelity(evaluator, mixed), _fidelity(evaluator, floated)
    kept = all(on_grid[n].sqnr_db >= off_grid[n].sqnr_db - OUTPUT_GRID_DB and
               grid_channels[n] >= float_channels[n] - OUTPUT_GRID_DB and
               _agreed(on_grid[n]) >= _agreed(off_grid[n]) - OUTPUT_GRID_AGREEMENT for n in on_grid)
    record = {"kept": kept, **{key: {n: None if math.isinf(v) else round(v, 2) for n, v in values.items()}
                               for key, values in (("channel_sqnr_db_on_grid", grid_channels),
                                                   ("channel_sqnr_db_float", float_channels))},
              "agreement_on_grid": {n: f.agreement for n, f in on_grid.items()},
              "agreement_float": {n: f.agreement for n, f in off_grid.items()}}
    return (mixed, partly, record) if kept else (floated, dropped, record)


def _agreed(fidelity: OutputFidelity) -> float:
    """FIDELITY's agreement, 1.0 where it decides nothing (raw, or no cell above a threshold in either file)."""
    return 1.0 if fidelity.agreement is None else fidelity.agreement


def _fidelity(evaluator: Evaluator, model: Any) -> tuple[dict, dict[str, float]]:
    """MODEL's fidelity per output on EVALUATOR's check tensors, and each output's lowest SQNR over
    its channels (axis 1), from one run."""
    got = list(evaluator.outputs(model))
    signal: dict[str, Any] = {n: 0.0 for n in evaluator.names}
    noise: dict[str, Any] = {n: 0.0 for n in evaluator.names}
    for ref, out in zip(evaluator.reference, got):
        for name, r, t in zip(evaluator.names, ref, out):
            r64 = r.astype(np.float64)
            axes = tuple(a for a in range(r.ndim) if a != 1) if r.ndim > 1 else None
            signal[name] = signal[name] + (r64 ** 2).sum(axis=axes)
            noise[name] = noise[name] + ((r64 - t) ** 2).sum(axis=axes)
    channels = {n: float(np.min(np.where(noise[n] > 0, 10 * np.log10(np.maximum(signal[n], 1e-30) /
                                                                    np.maximum(noise[n], 1e-300)), np.inf)))
                for n in evaluator.names}
    return compare_outputs(evaluator.names, evaluator.tasks, zip(evaluator.reference, got), evaluator.nhwc), channels


def choose_rule(collector: Collector, pre: Path, float_model: Any, held: list[np.ndarray], held_out: bool, ops: list[str],
                exclude: list[str], config: QuantConfig, evaluator: Callable[[list[np.ndarray]], Evaluator],
                progress: bool, conv_outputs: bool = True) -> tuple[RangeRule, dict, Any | None]:
    """The range rule: config's own, or with auto the candidate whose int8 graph of the float file
    PRE gives outputs closest to fp32's on the HELD tensors, unless another changes fewer of fp32's
    decisions beyond chance (`ranked_rule`: the output whose task decides something that changes
    most; EVALUATOR gives fp32's outputs on them and each output's task): the error alone can prefer
    a tighter range that clips the few high values a decision turns on.
    HELD_OUT: COLLECTOR has not counted them yet, the caller does after. Returns the rule, what was
    measured, and the QDQ graph the candidates were measured on as the writer wrote it (None with one
    rule: nothing written), for `qdq_for`."""
    rules = candidate_rules(config)
    if len(rules) == 1:
        return rules[0], {"rule": str(rules[0])}, None
    from edgepick.progress import progress as progress_bar

    check = evaluator(held)
    tail, exact = float_tail(float_model), exact_tensors(float_model)
    # one graph written, its qparams set for each rule in turn: the graph does not depend on the ranges
    pristine = qdq_model(pre, collector.ranges(rules[0], exact), ops, exclude, config.reduce_range, conv_outputs)
    written = copy_model(pristine)
    float_outputs(written, tail, float_model)
    scores = []
    for rule in progress_bar(rules, desc="choose ranges", unit="rule", enabled=progress):
        # every Relu and Clip read by a quantized op alone folded into its grid, as every placement's writer folds them
        requantize_activations(written, float_model, adjusted_ranges(float_model, collector.ranges(rule, exact)))
        scores.append(rule_score(check, written, rule))
    best = ranked_rule(scores)
    return best.rule, {"rule": str(best.rule), "held_out": len(held) if held_out else 0,
                       "candidates": [s.to_dict() for s in scores]}, pristine


def rule_score(evaluator: Evaluator, graph: Any, rule: RangeRule) -> RuleScore:
    """RULE's int8 GRAPH measured on EVALUATOR's check tensors as every candidate rule is: its outputs'
    error and the decisions it changes (the outputs' tasks alone, not a caller's judge)."""
    fidelity, error = evaluator.measure(graph, judge=False)
    return RuleScore(rule, error, *most_changed(fidelity), decisions="decision")


def qdq_for(written: Any | None, prepared: Path, float_model: Any, ranges: dict[str, tuple[float, float]],
            op_types: Sequence[str], exclude: Sequence[str], reduce_range: bool, conv_outputs: bool = True) -> Any:
    """`qdq_model` for RANGES: a copy of WRITTEN (the writer's graph of the same float model for
    other ranges) with the qparams of RANGES where that is what the writer writes
    (`requantize_activations` says so), else written afresh. onnxruntime's writer takes about as
    long as a calibration pass on a small model."""
    if written is not None:
        model = copy_model(written)
        if requantize_activations(model, float_model, adjusted_ranges(float_model, ranges, op_types, exclude)):
            return model
    return qdq_model(prepared, ranges, op_types, exclude, reduce_range, conv_outputs)
