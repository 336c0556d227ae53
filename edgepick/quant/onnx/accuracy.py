"""Fidelity first, for any ONNX model: which activations to leave float, found by measuring.

A tensor is left float by taking the Q -> DQ pair off it: the ops that read it then read the
float values, and the op that writes it writes them float; onnxruntime runs both in float, and
OpenVINO the same. That is how a node is kept float too (`QuantConfig.keep_float`): its weights,
the tensors it reads and the tensors it writes, so that it computes what fp32 computes from what
the int8 graph gives it. (Leaving only its weights float, with its input still on the uint8
grid, can lower fidelity: the int8 graph's errors no longer meet the rounding they were measured
with.)

The scan measures, on the real int8 graph, how much output SQNR keeping each activation float
gains: the activations are split into blocks in graph order, each block is measured float at
once, the best blocks are split again, down to single tensors (a few dozen graphs instead of one
per tensor). The accuracy-aware mode then keeps the best-ranked tensors float one at a time until
the task fidelity meets the budget, skipping any that would not bring the outputs closer on both
halves of the check tensors (a gain on their sum alone can be one input's noise).
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from edgepick.errors import ParameterError
from edgepick.onnx_graph import Graph, copy_model
from edgepick.quant.fidelity import BalancedError, OutputFidelity, Task, compare_outputs

SCAN_BLOCKS = 16  # blocks of activations measured float first
SCAN_KEEP = 4  # the best blocks (then sub-blocks) split again
SCAN_TENSORS = 4  # check tensors the scan measures on (the budget is checked on all of them)
# an output's SQNR under this is int8 far from fp32 (segmentation logits and text maps measure 15-25 dB): the
# file is written with a warning naming the activations to leave float
SQNR_FLOOR_DB = 10.0


def quantized_activations(model: Any) -> list[str]:
    """The activations of the QDQ MODEL on the uint8 grid (what a QuantizeLinear reads, weights not),
    in graph order."""
    weights = {i.name for i in model.graph.initializer}
    return list(dict.fromkeys(n.input[0] for n in model.graph.node
                              if n.op_type == "QuantizeLinear" and n.input[0] not in weights))


REMOVABLE_OPS = ("Relu", "Clip")  # onnxruntime's QDQ writer drops them after a quantized op: the uint8 grid clamps


def float_tensors(model: Any, names: Sequence[str], float_model: Any) -> int:
    """Take the Q -> DQ pairs off the tensors NAMES of MODEL (in place): their readers get the float
    tensor. Where onnxruntime's writer dropped a Relu or Clip that wrote the tensor in FLOAT_MODEL
    (the uint8 grid clamped for it), the op is put back. Returns how many pairs went."""
    g, fg = Graph(model), Graph(float_model)
    outputs = g.outputs
    dropped = 0
    for name in names:
        made_by, writer = fg.producer(name), g.producer(name)
        restore = (made_by is not None and made_by.op_type in REMOVABLE_OPS and writer is not None
                   and writer.op_type != made_by.op_type)
        for q in [n for n in g.consumers(name) if n.op_type == "QuantizeLinear"]:
            dqs = [n for n in g.consumers(q.output[0]) if n.op_type == "DequantizeLinear"]
            if len(dqs) != len(g.consumers(q.output[0])) or any(dq.output[0] in outputs for dq in dqs):
                continue  # a reader takes the uint8 codes themselves, or a DQ is the graph's output: leave it
            for dq in dqs:
                readers = g.consumers(dq.output[0])
                g.redirect(dq.output[0], name)
                for reader in readers:
                    if reader.op_type in ("Conv", "ConvTranspose"):
                        _float_bias(g, reader, fg)
                g.remove(dq)
            g.remove(q)
            dropped += 1
            if restore:
                assert made_by is not None and writer is not None
                _restore_activation(g, made_by, writer, fg)
                restore = False
    return dropped


def _float_bias(g: Graph, conv: Any, fg: Graph) -> None:
    """Give CONV its float bias back (FG: the float graph): onnxruntime quantizes a conv's bias to
    int32 on the input's scale times the weight's, which is coarse where the input had a wide range,
    and a float input no longer needs it."""
    if len(conv.input) < 3 or not conv.input[2]:
        return
    dq = g.producer(conv.input[2])
    bias = fg.initializer(conv.input[2])
    if dq is None or dq.op_type != "DequantizeLinear" or bias is None:
        return
    if not g.is_initializer(conv.input[2]):
        g.add_tensor(bias)
    if len(g.consumers(conv.input[2])) == 1:
        g.remove(dq)


def _restore_activation(g: Graph, activation: Any, writer: Any, fg: Graph) -> None:
    """Put the float model's ACTIVATION (a Relu or Clip) back between WRITER and the tensor it wrote."""
    import onnx

    name = activation.output[0]
    before = f"{name}_before_{activation.op_type.lower()}"
    g.set_output(writer, name, before)
    node = onnx.NodeProto()
    node.CopyFrom(activation)
    node.input[0] = before
    for bound in [i for i in fg.graph.initializer if i.name in node.input[1:] and not g.is_initializer(i.name)]:
        g.add_tensor(bound)
    constants = {n.output[0]: n for n in fg.nodes if n.op_type == "Constant"}
    g.append([constants[i] for i in node.input[1:] if i in constants])
    g.append([node])
    g.sort()


def node_tensors(model: Any, nodes: Sequence[str]) -> list[str]:
    """The float tensors the nodes NODES of the QDQ MODEL read and write, as the float graph names
    them (a DequantizeLinear's output traced back to what its QuantizeLinear read)."""
    g = Graph(model)
    found: list[str] = []
    for node in (n for n in g.nodes if n.name in set(nodes)):
        for name in node.input:
            dq = g.producer(name)
            q = g.producer(dq.input[0]) if dq is not None and dq.op_type == "DequantizeLinear" else None
            if q is not None and q.op_type == "QuantizeLinear":
                found.append(q.input[0])
        found.extend(o for o in node.output if any(c.op_type == "QuantizeLinear" for c in g.consumers(o)))
    return list(dict.fromkeys(found))


@dataclass
class Evaluator:
    """Runs candidate int8 graphs on check tensors against fp32's outputs there."""

    float_model: Any  # the float graph the int8 one was written from
    reference: list[list[np.ndarray]]  # fp32's outputs, per check tensor
    inputs: list[np.ndarray]
    names: list[str]  # the outputs, in the order the graphs give them
    tasks: dict[str, Task]
    nhwc: bool = False
    graphs: int = 0  # how many graphs were measured
    input_name: str = ""

    def session(self, model: Any) -> Any:
        import onnxruntime as ort

        opts = ort.SessionOptions()
        opts.log_severity_level = 3
        opts.enable_cpu_mem_arena = False  # many graphs are made one after another: none keeps its peak
        session = ort.InferenceSession(model.SerializeToString(), opts, providers=["CPUExecutionProvider"])
        self.input_name = session.get_inputs()[0].name
        self.graphs += 1
        return session

    def fidelity(self, model: Any) -> dict[str, OutputFidelity]:
        """Each output's fidelity (quant/fidelity.py) of MODEL on every check tensor."""
        session = self.session(model)
        pairs = ((ref, session.run(self.names, {self.input_name: x})) for x, ref in zip(self.inputs, self.reference))
        return compare_outputs(self.names, self.tasks, pairs, self.nhwc)

    def error(self, model: Any, count: int | None = SCAN_TENSORS) -> float:
        """The worst output's balanced relative error (quant/fidelity.py) of MODEL on the first COUNT
        tensors, summed one input at a time."""
        return self._worst_error(self.session(model), self.inputs[:count], self.reference)

    def half_errors(self, model: Any) -> tuple[float, ...]:
        """`error` of MODEL on each half of the check tensors (one value for a single tensor): a change
        the accuracy-aware mode keeps must bring the outputs closer on both, not only on their sum."""
        session, half = self.session(model), max(1, len(self.inputs) // 2)
        halves = [(self.inputs[:half], self.reference[:half]), (self.inputs[half:], self.reference[half:])]
        return tuple(self._worst_error(session, inputs, reference) for inputs, reference in halves if inputs)

    def _worst_error(self, session: Any, inputs: Sequence[np.ndarray], reference: Sequence[list[np.ndarray]]) -> float:
        errors = [BalancedError(self.nhwc) for _ in self.names]
        for x, ref in zip(inputs, reference):
            for error, r, t in zip(errors, ref, session.run(self.names, {self.input_name: x})):
                error.add(r, t)
        return max(e.value for e in errors)


def _db(error: float) -> float:
    return -10.0 * math.log10(error) if error > 0 else math.inf


def rank_tensors(model: Any, evaluator: Evaluator, candidates: list[str]) -> list[tuple[str, float]]:
    """CANDIDATES (activations of the QDQ MODEL) with the output SQNR in dB that leaving each float
    gains, best first: blocks in graph order, the best split again, down to single tensors."""
    base = _db(evaluator.error(model))

    def gain(names: list[str]) -> float:
        trial = copy_model(model)
        float_tensors(trial, names, evaluator.float_model)
        return _db(evaluator.error(trial)) - base

    singles: dict[str, float] = {}
    blocks = [list(b) for b in np.array_split(np.array(candidates, dtype=object), min(SCAN_BLOCKS, len(candidates)))]
    while blocks:
        scored = sorted(((gain(b), b) for b in blocks if b), key=lambda s: -s[0])
        blocks = []
        for value, block in scored[:SCAN_KEEP]:
            if len(block) == 1:
                singles[block[0]] = value
            elif value > 0:
                blocks.extend(list(b) for b in np.array_split(np.array(block, dtype=object), min(SCAN_KEEP, len(block))))
    return sorted(singles.items(), key=lambda s: -s[1])


@dataclass(frozen=True)
class FidelityBudget:
    """How close the accuracy-aware mode brings the int8 outputs to fp32's: every output that
    decides something agrees on at least MIN_AGREEMENT of its decisions, every output's SQNR is at
    least MIN_SQNR_DB; at most MAX_FLOAT activations are left float for it."""

    min_agreement: float | None = None
    min_sqnr_db: float | None = None
    max_float: int = 6

    def __post_init__(self) -> None:
        if self.min_agreement is None and self.min_sqnr_db is None:
            raise ParameterError("{min_agreement:name} or {min_sqnr_db:name}: the budget needs one",
                                 min_agreement=None, min_sqnr_db=None)
        if self.min_agreement is not None and not 0.0 < self.min_agreement <= 1.0:
            raise ParameterError("{min_agreement}: a share in (0, 1]", min_agreement=self.min_agreement)
        if self.min_sqnr_db is not None and not math.isfinite(self.min_sqnr_db):
            raise ParameterError("{min_sqnr_db}: must be a finite number of dB", min_sqnr_db=self.min_sqnr_db)
        if self.max_float < 1:
            raise ParameterError("{max_float}: must be 1 or more", max_float=self.max_float)

    def met(self, fidelity: dict[str, OutputFidelity]) -> bool:
        for f in fidelity.values():
            if self.min_sqnr_db is not None and f.sqnr_db < self.min_sqnr_db:
                return False
            if self.min_agreement is not None and f.agreement is not None and f.agreement < self.min_agreement:
                return False
        return True


def restore_fidelity(model: Any, evaluator: Evaluator, budget: FidelityBudget,
                     progress: Callable[[str], None] = lambda _: None) -> tuple[Any, dict]:
    """MODEL (a QDQ graph) with the fewest activations left float, in the scan's order, that meets
    BUDGET (or the best found within budget.max_float); a tensor whose float values would lower
    the measured fidelity is not kept. Returns the graph and what was done."""
    fidelity = evaluator.fidelity(model)
    record: dict = {"before": {n: f.to_dict() for n, f in fidelity.items()}, "float_tensors": []}
    if budget.met(fidelity):
        return model, {**record, "met": True, "graphs_measured": evaluator.graphs}
    original = model
    progress("scan which activations to leave float")
    ranked = rank_tensors(model, evaluator, quantized_activations(model))
    record["scan"] = [{"tensor": t, "gain_db": round(g, 2)} for t, g in ranked[:20]]
    best = evaluator.half_errors(model)
    kept: list[str] = []
    for name, value in ranked:
        if len(kept) >= budget.max_float or value <= 0:
            break
        trial = copy_model(model)
        float_tensors(trial, [*kept, name], evaluator.float_model)
        errors = evaluator.half_errors(trial)
        if any(e >= b for e, b in zip(errors, best)):
            continue  # leaving it float would not bring the outputs closer on both halves of the check tensors
        kept, best, model = [*kept, name], errors, trial
        fidelity = evaluator.fidelity(model)
        progress(f"{len(kept)} float: {name}")
        if budget.met(fidelity):
            break
    record.update(float_tensors=kept, after={n: f.to_dict() for n, f in fidelity.items()}, met=budget.met(fidelity),
                  graphs_measured=evaluator.graphs)
    if kept:
        record["speed"] = speed_cost(original, model, evaluator.inputs[0])
    return model, record


def speed_cost(int8: Any, kept_float: Any, x: np.ndarray, threads: int = 2) -> dict:
    """onnxruntime's median ms of the all-int8 graph INT8 and of KEPT_FLOAT on X, timed in alternating
    blocks on THREADS threads, and their ratio: what the float activations cost on this machine."""
    import onnxruntime as ort

    from edgepick.runtime.session import median_ms

    def runner(model: Any):
        opts = ort.SessionOptions()
        opts.intra_op_num_threads, opts.log_severity_level = threads, 3
        session = ort.InferenceSession(model.SerializeToString(), opts, providers=["CPUExecutionProvider"])
        name = session.get_inputs()[0].name
        return lambda image: session.run(None, {name: image})

    ms = median_ms({"all_int8_ms": runner(int8), "kept_float_ms": runner(kept_float)}, x)
    return {**ms, "slowdown": round(ms["kept_float_ms"] / ms["all_int8_ms"], 3), "threads": threads}


def evaluator_for(pre: Path, float_model: Any, check: list[np.ndarray], tasks: dict[str, Task],
                  nhwc: bool) -> Evaluator:
    """What int8 graphs are measured against: fp32's (the file PRE, FLOAT_MODEL) outputs on the CHECK tensors."""
    evaluator = Evaluator(float_model, [], check, [o.name for o in float_model.graph.output], tasks, nhwc)
    fp32 = evaluator.session(float_model)
    evaluator.reference = [fp32.run(evaluator.names, {evaluator.input_name: x}) for x in check]
    evaluator.graphs = 0  # int8 graphs measured
    return evaluator


def fidelity_first(int8: Any, evaluator: Evaluator, budget: FidelityBudget | None,
                    progress: bool) -> tuple[Any, dict]:
    """With BUDGET, INT8 with the activations that matter most left float until its outputs meet it
    (`restore_fidelity`); without, INT8 as it is, and where its worst output's SQNR is under
    SQNR_FLOOR_DB a one-line warning naming the activations whose float values would gain most.
    Returns the graph and what to record."""
    def stage(message: str) -> None:
        if progress:
            print(f"accuracy-aware: {message}", file=sys.stderr, flush=True)

    if budget is not None:
        int8, record = restore_fidelity(int8, evaluator, budget, stage)
        return int8, {"accuracy_aware": record}
    worst = min(f.sqnr_db for f in evaluator.fidelity(int8).values())
    if worst >= SQNR_FLOOR_DB:
        return int8, {}
    ranked = rank_tensors(int8, evaluator, quantized_activations(int8))[:3]
    named = ", ".join(f"{t} (+{g:.1f} dB)" for t, g in ranked) or "none found"
    warning = (f"the int8 outputs are far from fp32's (worst output SQNR {worst:.1f} dB, under {SQNR_FLOOR_DB:g}); "
               f"leaving float most helps: {named}; the accuracy-aware mode (--min-sqnr or --min-agreement) keeps "
               "such activations float")
    print(f"edgepick: warning: {warning}", file=sys.stderr, flush=True)
    return int8, {"fidelity_warning": warning}
