"""The QDQ graph of a float ONNX model for given activation ranges, and the per-model choice of the
rule those ranges come from.

onnxruntime's QDQ quantizer places the Q/DQ pairs and quantizes the weights; the ranges are
edgepick's own (quant/onnx_calibrate.py), handed to it as a calibrator would. Which rule reads the
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

from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from edgepick.quant.fidelity import RuleScore, balanced_error
from edgepick.quant.ranges import RangeRule

COMPUTE_OPS = ("Conv", "ConvTranspose", "MatMul", "Gemm", "LSTM", "GRU", "RNN", "Einsum", "Attention")


def qdq_model(prepared: Path, ranges: dict[str, tuple[float, float]], op_types: Sequence[str],
              exclude: Sequence[str], reduce_range: bool) -> Any:
    """The QDQ ModelProto onnxruntime's quantizer writes from the float model PREPARED (shapes
    inferred) with RANGES for the activations: U8S8, weights per channel and symmetric (7-bit with
    REDUCE_RANGE), activations asymmetric; nodes of OP_TYPES quantized but those in EXCLUDE."""
    from onnxruntime.quantization.calibrate import CalibrationMethod, TensorsData
    from onnxruntime.quantization.qdq_quantizer import QDQQuantizer
    from onnxruntime.quantization.quant_utils import QuantType, load_model_with_shape_infer

    model = load_model_with_shape_infer(Path(prepared))
    data = TensorsData(CalibrationMethod.MinMax,
                       {name: (np.array(lo, np.float32), np.array(hi, np.float32)) for name, (lo, hi) in ranges.items()})
    quantizer = QDQQuantizer(model, True, reduce_range, QuantType.QInt8, QuantType.QUInt8, data, [], list(exclude),
                             list(op_types), {"ActivationSymmetric": False, "WeightSymmetric": True})
    quantizer.quantize_model()
    quantizer.model.topological_sort()  # as its save_model_to_file does: passes after it walk the nodes in order
    return quantizer.model.model


def exact_tensors(model: Any) -> set[str]:
    """The tensors of MODEL from which a graph output is reached through no compute op (conv,
    matmul, ...): what they hold is what the output holds, so their range is never clipped."""
    producer = {o: n for n in model.graph.node for o in n.output}
    found: set[str] = set()
    todo = [o.name for o in model.graph.output]
    while todo:
        name = todo.pop()
        if name in found:
            continue
        found.add(name)
        node = producer.get(name)
        if node is not None and node.op_type not in COMPUTE_OPS:
            todo.extend(i for i in node.input if i)
    return found


def score_rules(rules: Iterable[RangeRule], build: Callable[[RangeRule], Any], held: list[np.ndarray],
                reference: list[list[np.ndarray]], nhwc: bool = False) -> list[RuleScore]:
    """Each rule's int8 graph (BUILD(rule), a ModelProto) run on HELD against fp32's REFERENCE outputs."""
    import onnxruntime as ort

    scores = []
    for rule in rules:
        model = build(rule)
        opts = ort.SessionOptions()
        opts.log_severity_level = 3
        session = ort.InferenceSession(model.SerializeToString(), opts, providers=["CPUExecutionProvider"])
        name = session.get_inputs()[0].name
        outputs = [session.run(None, {name: x}) for x in held]
        worst = max(balanced_error([r[k] for r in reference], [o[k] for o in outputs], nhwc)
                    for k in range(len(reference[0])))
        scores.append(RuleScore(rule, worst))
    return scores
