"""How close an int8 model's outputs stay to fp32's, for any kind of output.

Per output: the SQNR (signal-to-quantization-noise ratio, dB) and the cosine similarity of the int8
values against fp32's, which mean something for every output (logits, probabilities, box
regressions, embeddings); and, where the output decides something, the share of decisions that
agree (`Task`): per-pixel labels (the argmax over channels), the cells of a thresholded map (their
F1 score: a sparse score map's negatives would otherwise hide lost detections), the top-1 class of
each row, a detector's boxes (detections.py), a recogniser's strings (strings.py). A raw
regression decides nothing and gets no agreement: the sign of a box coordinate says nothing about
the box. Numpy only.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from edgepick.errors import ParameterError
from edgepick.onnx_graph import Graph
from edgepick.quant.detections import detections, found_again
from edgepick.quant.ranges import RangeRule
from edgepick.quant.strings import characters_read_again

PROBABILITY_OPS = ("Sigmoid", "Softmax")
# ops that move or reshape values without changing them: a probability stays one through them
SHAPE_OPS = ("Reshape", "Transpose", "Squeeze", "Unsqueeze", "Flatten", "Identity", "Concat", "Slice", "Gather",
             "Split")


class TaskKind(enum.StrEnum):
    """What an output decides (`--task`)."""

    LABELS = "labels"  # a class per pixel: the argmax over the channel axis
    THRESHOLD = "threshold"  # the cells of a map above T (threshold:T; 0.5 for a probability), judged by their F1
    TOP1 = "top1"  # a class per row: the argmax over the last axis
    BOXES = "boxes"  # a detector's box table (boxes:T): cx, cy, w, h and class scores per row (YOLOv8 and later)
    BOXES_OBJ = "boxes-obj"  # the same with an objectness score after the box (boxes-obj:T; YOLOv5)
    CTC = "ctc"  # a text recogniser's strings: greedy CTC decoding of [steps, classes] scores, class 0 the blank
    RAW = "raw"  # nothing: SQNR and cosine only


# the kinds that take a threshold (KIND:T), and T where none is given
THRESHOLDS = {TaskKind.THRESHOLD: 0.5, TaskKind.BOXES: 0.25, TaskKind.BOXES_OBJ: 0.25}


@dataclass(frozen=True)
class Task:
    """What an output decides, and how the decision is read off it."""

    kind: TaskKind
    threshold: float = math.nan  # KIND:T's T; NaN: the kind's default (THRESHOLDS; 0.5 for the others)

    def __post_init__(self) -> None:
        object.__setattr__(self, "kind", TaskKind(self.kind))
        if math.isnan(self.threshold):
            object.__setattr__(self, "threshold", THRESHOLDS.get(self.kind, 0.5))
        if not math.isfinite(self.threshold):
            raise ParameterError("{task}: the threshold must be a finite number", task=str(self))

    def __str__(self) -> str:
        return f"{self.kind.value}:{self.threshold:g}" if self.kind in THRESHOLDS else self.kind.value

    @classmethod
    def parse(cls, text: str) -> Task:
        """'labels', 'threshold[:T]', 'top1', 'boxes[:T]', 'boxes-obj[:T]', 'ctc' or 'raw', refused in one line
        naming `task`."""
        kind, _, value = str(text).strip().partition(":")
        try:
            task_kind = TaskKind(kind)
        except ValueError:
            raise ParameterError(f"{{task}}: not one of {', '.join(k.value for k in TaskKind)} (threshold:T, "
                                 "boxes:T)", task=text) from None
        if task_kind not in THRESHOLDS:
            if value:
                raise ParameterError(f"{{task}}: only {', '.join(THRESHOLDS)} take a value (KIND:T)", task=text)
            return cls(task_kind)
        try:
            threshold = float(value) if value else None
        except ValueError:
            raise ParameterError(f"{{task}}: T in {task_kind.value}:T must be a number", task=text) from None
        if threshold is not None and not math.isfinite(threshold):
            raise ParameterError("{task}: the threshold must be a finite number", task=text)
        return cls(task_kind) if threshold is None else cls(task_kind, threshold)

    @property
    def boxes(self) -> bool:
        """Whether the output is a detector's box table (boxes, boxes-obj)."""
        return self.kind in (TaskKind.BOXES, TaskKind.BOXES_OBJ)

    def check_shape(self, shape: tuple[int, ...], output: str) -> None:
        """Refuse, naming `task`, a box task on an OUTPUT of SHAPE that holds no table of box rows,
        and a CTC task on one that holds no sequence of class scores."""
        if self.kind == TaskKind.CTC and (len(shape) not in (2, 3) or 0 < shape[-1] < 2):
            raise ParameterError(f"{{task}}: output {output} of shape {list(shape)} holds no CTC scores ([steps, "
                                 "classes], [1, steps, classes] or [steps, 1, classes])", task=str(self))
        least = 6 if self.kind == TaskKind.BOXES_OBJ else 5
        table = shape[1:] if len(shape) == 3 and shape[0] in (0, 1) else shape  # 0: a dim not known before a run
        known = [d for d in table if d > 0]
        if self.boxes and (len(table) != 2 or (len(known) == 2 and min(known) < least)
                           or (len(known) == 1 and known[0] < least)):
            raise ParameterError(f"{{task}}: output {output} of shape {list(shape)} is no box table ([1, boxes, "
                                 f"{least} or more attributes], either way round)", task=str(self))

    def decide(self, y: np.ndarray, nhwc: bool = False) -> np.ndarray | None:
        """The decisions Y makes (None for raw)."""
        if self.kind == TaskKind.LABELS:
            return y.argmax(-1 if nhwc else 1)
        if self.kind == TaskKind.THRESHOLD:
            return y > self.threshold
        if self.kind == TaskKind.TOP1:
            return y.argmax(-1)
        return None

    def agree(self, ref: np.ndarray, test: np.ndarray, nhwc: bool = False) -> tuple[int, int] | None:
        """How many of the decisions of REF (fp32's output) and TEST agree, and how many were made
        (None: raw decides nothing). Boxes: twice the detections found again and the detections of
        both, so that their ratio over several images is the F1 score of TEST's boxes against REF's.
        Threshold: likewise for the cells above T (twice those above in both, those above in each): a
        score map is mostly cells below T in both, and counting them would hide the detections lost.
        CTC: the characters read the same and read, their ratio the character accuracy."""
        if self.boxes:
            objectness = self.kind == TaskKind.BOXES_OBJ
            images = zip(ref, test) if ref.ndim == 3 else [(ref, test)]
            same = made = 0
            for a, b in images:
                found, shown = detections(a, self.threshold, objectness), detections(b, self.threshold, objectness)
                same += 2 * found_again(found, shown)
                made += len(found[0]) + len(shown[0])
            return same, made
        if self.kind == TaskKind.CTC:
            return characters_read_again(ref, test)
        da, db = self.decide(ref, nhwc), self.decide(test, nhwc)
        if da is None or db is None:
            return None
        if self.kind == TaskKind.THRESHOLD:
            return 2 * int((da & db).sum()), int(da.sum() + db.sum())
        return int((da == db).sum()), int(da.size)


def guess_task(shape: tuple[int, ...], made_by: str | bool | None, nhwc: bool = False) -> Task:
    """The task an output of SHAPE most likely has, given the op that MADE_BY it ("Softmax",
    "Sigmoid"; True: some probability; None or False: not one): labels for a multi-channel map, a
    threshold for a one-channel map (0.5 for a probability, else 0); for a table of probabilities,
    the top-1 class of each row after a Softmax, each score above or below 0.5 after a Sigmoid;
    raw (no decision) for anything else, box regressions among them."""
    if len(shape) == 4:
        channels = shape[-1] if nhwc else shape[1]
        return Task(TaskKind.LABELS) if channels > 1 else Task(TaskKind.THRESHOLD, 0.5 if made_by else 0.0)
    if made_by == "Softmax" and len(shape) in (2, 3) and shape[-1] > 1:
        return Task(TaskKind.TOP1)
    if made_by:
        return Task(TaskKind.THRESHOLD, 0.5)
    return Task(TaskKind.RAW)


def probability_outputs(model) -> dict[str, str | None]:
    """Per graph output of the ONNX MODEL: the op (Sigmoid or Softmax) that makes it a probability,
    through ops that only move values (Reshape, Transpose, a Concat of such, ...); None if none."""
    g = Graph(model)

    def made_by(name: str, depth: int = 0) -> str | None:
        node = g.producer(name)
        if node is None or depth > 32:
            return None
        if node.op_type in PROBABILITY_OPS:
            return node.op_type
        if node.op_type not in SHAPE_OPS:
            return None
        inputs = [i for i in node.input if g.producer(i) is not None]
        if not inputs:
            return None
        if node.op_type == "Concat":
            found = {made_by(i, depth + 1) for i in inputs}
            return found.pop() if len(found) == 1 else None
        return made_by(inputs[0], depth + 1)

    return {o.name: made_by(o.name) for o in model.graph.output}


@dataclass
class OutputFidelity:
    """Running sums for one output over several inputs."""

    task: Task
    signal: float = 0.0  # sum of fp32's squares
    noise: float = 0.0  # sum of squared differences
    dot: float = 0.0
    norm_int8: float = 0.0
    same: int = 0
    decided: int = 0
    cosines: list[float] = field(default_factory=list)
    judged: bool = False  # a caller's own judge's agreement (quant/onnx/evaluator.py), not an output's

    def add(self, ref: np.ndarray, int8: np.ndarray, nhwc: bool = False) -> None:
        a, b = ref.astype(np.float64).ravel(), int8.astype(np.float64).ravel()
        self.signal += float(a @ a)
        self.noise += float((a - b) @ (a - b))
        self.dot += float(a @ b)
        self.norm_int8 += float(b @ b)
        agreed = self.task.agree(ref, int8, nhwc)
        if agreed is not None:
            self.same += agreed[0]
            self.decided += agreed[1]

    @property
    def sqnr_db(self) -> float:
        if self.noise == 0.0:
            return math.inf
        return 10.0 * math.log10(max(self.signal, 1e-30) / self.noise)

    @property
    def cosine(self) -> float:
        if self.signal == 0.0 or self.norm_int8 == 0.0:
            return 1.0 if self.signal == self.norm_int8 else 0.0
        return self.dot / math.sqrt(self.signal * self.norm_int8)

    @property
    def agreement(self) -> float | None:
        return round(self.same / self.decided, 5) if self.decided else None

    def to_dict(self) -> dict:
        if self.judged:
            return {"task": "judge", "agreement": self.agreement}
        sqnr = self.sqnr_db
        return {"task": str(self.task), "sqnr_db": round(sqnr, 2) if math.isfinite(sqnr) else None,
                "cosine": round(self.cosine, 6), "agreement": self.agreement}


def compare_outputs(names: list[str], tasks: dict[str, Task], pairs, nhwc: bool = False) -> dict[str, OutputFidelity]:
    """Per output name, the fidelity over PAIRS ((fp32 outputs, int8 outputs) per input, in NAMES' order)."""
    found = {name: OutputFidelity(tasks[name]) for name in names}
    for ref, int8 in pairs:
        for name, a, b in zip(names, ref, int8):
            found[name].add(a, b, nhwc)
    return found


def worst_sqnr(fidelity: dict[str, OutputFidelity]) -> float:
    """The lowest SQNR over the outputs (inf when every output is exact)."""
    return min((f.sqnr_db for f in fidelity.values()), default=math.inf)


def channel_axis(shape: tuple[int, ...], nhwc: bool = False) -> int | None:
    """The axis whose entries are different quantities of an output: the channels of a map, the
    attributes of a [1, boxes, attributes] table (the shorter of its two axes), None otherwise."""
    if len(shape) == 4:
        return 3 if nhwc else 1
    if len(shape) == 3:
        return 1 if shape[1] < shape[2] else 2
    return None


@dataclass
class BalancedError:
    """Relative squared error of an output against fp32's, summed input by input, each channel
    (`channel_axis`) weighted alike, so that a small-valued score channel counts as much as a box
    coordinate in pixels."""

    nhwc: bool = False
    signal: Any = 0.0  # per channel (or one sum where the output has no channel axis)
    noise: Any = 0.0

    def add(self, ref: np.ndarray, test: np.ndarray) -> None:
        axis = channel_axis(ref.shape, self.nhwc)
        others = tuple(a for a in range(ref.ndim) if a != axis) if axis is not None else None
        ref64 = ref.astype(np.float64)
        self.signal = self.signal + (ref64 ** 2).sum(axis=others)
        self.noise = self.noise + ((ref64 - test) ** 2).sum(axis=others)

    @property
    def value(self) -> float:
        return float(np.mean(np.asarray(self.noise) / np.maximum(self.signal, 1e-30)))


def balanced_error(ref: list[np.ndarray], test: list[np.ndarray], nhwc: bool = False) -> float:
    """BalancedError of TEST against REF (one output over several inputs)."""
    error = BalancedError(nhwc)
    for r, t in zip(ref, test):
        error.add(r, t)
    return error.value


@dataclass(frozen=True)
class RuleScore:
    """A candidate rule and how far its int8 outputs fell from fp32's on the held-out tensors: by
    their values and, where an output decides something (its task: labels, a threshold, top-1,
    boxes, strings), by the decisions it changes."""

    rule: RangeRule
    error: float  # the worst output's balanced relative squared error
    changed: int | None = None  # decisions that differ from fp32's (the output that changes the largest share)
    decided: int = 0  # that output's decisions (each pixel's label for an edgepick run's logits)
    decisions: str = "label"  # what they are: the record's key is f"{decisions}_agreement"

    @property
    def sqnr_db(self) -> float:
        return -10.0 * math.log10(self.error) if self.error > 0 else math.inf

    @property
    def changed_share(self) -> float:
        return self.changed / self.decided if self.changed and self.decided else 0.0

    @property
    def rank(self) -> tuple[float, float]:
        """What the best rule minimises: the share of decisions changed where they are counted, then the error."""
        return (self.changed_share, self.error)

    def to_dict(self) -> dict:
        found = {"rule": str(self.rule), "balanced_sqnr_db": round(self.sqnr_db, 2) if self.error > 0 else None}
        if self.changed is not None:
            found[f"{self.decisions}_agreement"] = round(1 - self.changed_share, 6)
        return found


def beyond_chance(fewer: RuleScore, more: RuleScore, z: float = 2.0) -> bool:
    """Whether FEWER changes a smaller share of fp32's decisions than MORE by more than chance: the
    difference of the shares over its standard error (McNemar's bound for paired decisions: each
    rule's changed decisions taken as discordant), above Z. A face map's few cells or a detector's
    boxes on a few held-out images change by a handful between rules, which says nothing."""
    if fewer.changed is None or more.changed is None or not fewer.decided or not more.decided:
        return False
    spread = math.sqrt(fewer.changed / fewer.decided ** 2 + more.changed / more.decided ** 2)
    return more.changed_share - fewer.changed_share > z * spread


def ranked_rule(scores: list[RuleScore]) -> RuleScore:
    """The rule kept among measured SCORES: the one with the closest outputs, unless a rule changes
    fewer of fp32's decisions beyond chance (`beyond_chance`; the fewest such, the closest among equals)."""
    closest, fewest = min(scores, key=lambda s: s.error), min(scores, key=lambda s: s.rank)
    return fewest if beyond_chance(fewest, closest) else closest


def most_changed(fidelity: dict[str, OutputFidelity]) -> tuple[int | None, int]:
    """Over the outputs of FIDELITY that decide something, the decisions changed and made by the one
    that changes the largest share of them; (None, 0) where none decides (raw outputs alone)."""
    shares = [(f.decided - f.same, f.decided) for f in fidelity.values() if f.task.kind != TaskKind.RAW]
    if not shares:
        return None, 0
    return max(shares, key=lambda cd: cd[0] / cd[1] if cd[1] else 0.0)


def parse_tasks(values: Iterable[str]) -> Task | dict[str, Task] | None:
    """Task texts as quantize_onnx_static takes them: one Task for every output ("ctc"), or one per
    output name ("537=threshold:0.2", "538=raw"); none given: None (guessed per output). Refused in
    one line naming `task`: a common task given twice, or a common one mixed with named ones."""
    named: dict[str, Task] = {}
    common: Task | None = None
    for value in values:
        name, sep, text = value.rpartition("=")
        try:
            task = Task.parse(text)
        except ParameterError as exc:  # named as the user wrote it, OUTPUT= included
            raise ParameterError(exc.template, **{**exc.parameters, "task": value}) from None
        if sep:
            named[name] = task
        elif common is not None:
            raise ParameterError("{task}: one task for all outputs is given twice; name the output (OUTPUT=TASK)",
                                 task=value)
        else:
            common = task
    if named and common is not None:
        raise ParameterError("{task:name}: give one task for all outputs, or OUTPUT=TASK for each, not both", task=None)
    return named or common


def check_task_names(model: Any, task: Task | Mapping[str, Task] | None) -> None:
    """Refuse a TASK mapping that names an output MODEL does not have."""
    names = [o.name for o in model.graph.output]
    unknown = sorted(set(task) - set(names)) if isinstance(task, Mapping) else []
    if unknown:
        raise ParameterError(f"{{task:name}} names no output of the model: {', '.join(unknown)} (it has "
                             f"{', '.join(names)})", task=None)


def output_tasks(model: Any, shapes: Mapping[str, tuple[int, ...]], task: Task | Mapping[str, Task] | None,
                 nhwc: bool) -> dict[str, Task]:
    """Per graph output of MODEL, the Task its fidelity is judged by: TASK (one for all, or per output
    name), else guessed from its shape and whether a Sigmoid or Softmax makes it."""
    names = [o.name for o in model.graph.output]
    check_task_names(model, task)
    probability = probability_outputs(model)
    found = {}
    for name in names:
        given = task.get(name) if isinstance(task, Mapping) else task
        if given is not None:
            given.check_shape(tuple(shapes[name]), name)
        found[name] = given if given is not None else guess_task(shapes[name], probability[name], nhwc)
    return found
