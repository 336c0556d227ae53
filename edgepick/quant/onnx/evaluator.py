"""What int8 graphs are measured against: fp32's outputs on the check tensors (the first calibration
tensors), and a runner of candidate graphs on them that gives each output's fidelity
(quant/fidelity.py), a balanced error for ranking candidates, and, where the caller gives a judge of
its own (`Judge`: its post-processing's decisions, as NNCF's accuracy control takes a validation
function), that judge's agreement, which a budget then holds the graph to."""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from edgepick.errors import ParameterError
from edgepick.quant.fidelity import BalancedError, OutputFidelity, Task, TaskKind, compare_outputs

SCAN_TENSORS = 4  # check tensors the sensitivity scan measures on (a budget is checked on all of them)
# a caller's own judge of an int8 graph: fp32's outputs and the graph's on each check tensor (each a list in the
# graph's output order) -> the share (0-1) of the decisions it makes of them that agree; reported beside the
# outputs' fidelity under JUDGED
Judge = Callable[[list[list[np.ndarray]], list[list[np.ndarray]]], float]
JUDGED = "judged"
JUDGE_SCALE = 1_000_000  # a judge's share kept as agreeing decisions out of this many

# the outputs of the last KEPT_GRAPHS graphs measured are kept when fp32's on the check tensors are no larger than
# KEPT_OUTPUT_BYTES: the recipe measures a graph again after trying another (bias correction's check, the
# outputs-on-grid check, the fidelity)
KEPT_OUTPUT_BYTES = 64 << 20
KEPT_GRAPHS = 2


@dataclass
class Evaluator:
    """Runs candidate int8 graphs on check tensors against fp32's outputs there."""

    float_model: Any  # the float graph the int8 one was written from
    reference: list[list[np.ndarray]]  # fp32's outputs, per check tensor
    inputs: list[np.ndarray]
    names: list[str]  # the outputs, in the order the graphs give them
    tasks: dict[str, Task]
    nhwc: bool = False
    judge: Judge | None = None  # the caller's own judge (JUDGED), with the outputs' fidelity
    graphs: int = 0  # how many graphs were measured
    input_name: str = ""
    kept: list[tuple[bytes, list[list[np.ndarray]]]] = field(default_factory=list, repr=False)  # see `outputs`

    def session(self, model: Any) -> Any:
        """An onnxruntime session of MODEL (a ModelProto, or one serialized)."""
        import onnxruntime as ort

        opts = ort.SessionOptions()
        opts.log_severity_level = 3
        opts.enable_cpu_mem_arena = False  # many graphs are made one after another: none keeps its peak
        data = model if isinstance(model, bytes) else model.SerializeToString()
        session = ort.InferenceSession(data, opts, providers=["CPUExecutionProvider"])
        self.input_name = session.get_inputs()[0].name
        self.graphs += 1
        return session

    def outputs(self, model: Any) -> Iterator[list[np.ndarray]]:
        """MODEL's outputs on each check tensor in turn, in `reference`'s order. Where fp32's are no
        larger than KEPT_OUTPUT_BYTES, the last KEPT_GRAPHS graphs' are kept, and a graph the same as one
        of them (byte for byte) is not run again; otherwise one tensor's are held at a time."""
        data = model.SerializeToString()
        digest = hashlib.sha256(data).digest()
        for kept_digest, outputs in self.kept:
            if kept_digest == digest:
                return iter(outputs)
        session = self.session(data)
        if sum(a.nbytes for out in self.reference for a in out) > KEPT_OUTPUT_BYTES:
            return (session.run(self.names, {self.input_name: x}) for x in self.inputs)
        outputs = [session.run(self.names, {self.input_name: x}) for x in self.inputs]
        self.kept = [*self.kept, (digest, outputs)][-KEPT_GRAPHS:]
        return iter(outputs)

    def fidelity(self, model: Any) -> dict[str, OutputFidelity]:
        """Each output's fidelity (quant/fidelity.py) of MODEL on every check tensor (and the judge's, JUDGED)."""
        if self.judge is not None:
            return self.measure(model)[0]
        return compare_outputs(self.names, self.tasks, zip(self.reference, self.outputs(model)), self.nhwc)

    def measure(self, model: Any, judge: bool = True) -> tuple[dict[str, OutputFidelity], float]:
        """`fidelity` and `error` of MODEL on every check tensor, from one run of each (one tensor's
        outputs held at a time where no judge needs them all). JUDGE False: the outputs' tasks alone,
        the caller's judge not asked (it answers for the budget, and may count its calls)."""
        judge = judge and self.judge is not None
        outputs = self.outputs(model)
        if judge:
            outputs = iter(kept := list(outputs))
        errors = [BalancedError(self.nhwc) for _ in self.names]
        fidelity = compare_outputs(self.names, self.tasks, [], self.nhwc)
        for ref, got in zip(self.reference, outputs):
            for name, error, r, t in zip(self.names, errors, ref, got):
                error.add(r, t)
                fidelity[name].add(r, t, self.nhwc)
        if judge and self.judge is not None:  # (the second test for the type checker)
            fidelity[JUDGED] = judged(self.judge(self.reference, kept))
        return fidelity, max(e.value for e in errors)

    def error(self, model: Any, count: int | None = SCAN_TENSORS) -> float:
        """The worst output's balanced relative error (quant/fidelity.py) of MODEL on the first COUNT
        tensors, summed one input at a time."""
        return self._worst_error(self.session(model), self.inputs[:count], self.reference)

    def half_errors(self, model: Any) -> tuple[float, ...]:
        """`error` of MODEL on each half of the check tensors (one value for a single tensor): a change
        the accuracy-aware mode keeps must bring the outputs closer on both, not only on their sum."""
        half, got = max(1, len(self.inputs) // 2), self.outputs(model)
        errors: list[list[BalancedError]] = []
        for k, ref in enumerate(self.reference):
            if k in (0, half):
                errors.append([BalancedError(self.nhwc) for _ in self.names])
            for error, r, t in zip(errors[-1], ref, next(got)):
                error.add(r, t)
        return tuple(max(e.value for e in part) for part in errors)

    def closer(self, before: Any, after: Any, worse_half: bool = False) -> dict:
        """Whether the graph AFTER brings the outputs closer to fp32's than BEFORE on both halves of
        the check tensors (the rule an optional step of the recipe is kept by), with both errors.
        WORSE_HALF: closer on the check tensors as a whole and on the half where the error is highest
        instead, for a change of every weight learnt on other tensors (AdaRound), whose gain on one
        half is not noise that the other half's small rise should throw away."""
        errors_before, errors_after = self.half_errors(before), self.half_errors(after)
        kept = (sum(errors_after) < sum(errors_before) and max(errors_after) < max(errors_before)) if worse_half \
            else all(a < b for a, b in zip(errors_after, errors_before))
        return {"kept": kept, "error_before": [round(e, 6) for e in errors_before],
                "error_after": [round(e, 6) for e in errors_after]}

    def _worst_error(self, session: Any, inputs: Sequence[np.ndarray], reference: Sequence[list[np.ndarray]]) -> float:
        errors = [BalancedError(self.nhwc) for _ in self.names]
        for x, ref in zip(inputs, reference):
            for error, r, t in zip(errors, ref, session.run(self.names, {self.input_name: x})):
                error.add(r, t)
        return max(e.value for e in errors)


def evaluator_for(pre: Path, float_model: Any, check: list[np.ndarray], tasks: dict[str, Task], nhwc: bool,
                  judge: Judge | None = None) -> Evaluator:
    """What int8 graphs are measured against: fp32's (the file PRE, FLOAT_MODEL) outputs on the CHECK
    tensors, each output judged by its TASKS entry and the whole by JUDGE where one is given."""
    evaluator = Evaluator(float_model, [], check, [o.name for o in float_model.graph.output], tasks, nhwc, judge)
    fp32 = evaluator.session(float_model)
    evaluator.reference = [fp32.run(evaluator.names, {evaluator.input_name: x}) for x in check]
    evaluator.graphs = 0  # int8 graphs measured
    return evaluator


def judged(share: Any) -> OutputFidelity:
    """A judge's SHARE of agreeing decisions as an OutputFidelity: an agreement only (no SQNR budget
    reads it); refused, naming `judge`, where it is no share in [0, 1]."""
    if isinstance(share, bool) or not isinstance(share, (int, float, np.floating)) or not 0.0 <= float(share) <= 1.0:
        raise ParameterError(f"{{judge:name}}: must return the share (0-1) of decisions that agree, got {share!r}",
                             judge=None)
    return OutputFidelity(Task(TaskKind.RAW), same=round(float(share) * JUDGE_SCALE), decided=JUDGE_SCALE, judged=True)
