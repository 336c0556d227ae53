"""Fidelity first, for any ONNX model: which activations to leave float, found by measuring
(how a tensor goes float: quant/onnx/floating.py).

The scan measures, on the real int8 graph, how much output SQNR keeping each activation float
gains: the activations are split into blocks in graph order, each block is measured float at
once, the best blocks are split again, down to single tensors (a few dozen graphs instead of one
per tensor). The accuracy-aware mode then keeps the best-ranked tensors float one at a time until
the task fidelity meets the budget, skipping any that would not bring the outputs closer on both
halves of the check tensors (a gain on their sum alone can be one input's noise). Where single
tensors are not enough (an error spread over dozens of activations, as in a text recogniser),
whole regions of the graph go float, the one that brings the outputs closest first, with the
weights of the ops that then read nothing on the uint8 grid: mixed tensor by tensor, float and
int8 can end further from fp32 than either. Where no set of regions meets the budget, the
shortest float start of the graph that does (errors that add up along a backbone). Where nothing
meets the budget, the answer is the graph tried that comes closest to it by its own measure (the
task's agreement first, then the SQNR) where the search's last graph is further from it: the
search steps by the outputs' error, which a judge's decisions need not follow. Of graphs the
budget ranks alike the last stays, closest to fp32 by that error (on NudeNet's boxes the
fewest-float graph, as close on the check tensors, agreed less on others: docs/quantization.md).
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from edgepick.errors import ParameterError
from edgepick.export.onnx_io import CONV_OPS
from edgepick.onnx_graph import copy_model
from edgepick.quant.fidelity import OutputFidelity
from edgepick.quant.onnx.evaluator import JUDGED, Evaluator, Judge
from edgepick.quant.onnx.floating import float_tensors, float_weight_convs, quantized_activations

SCAN_BLOCKS = 16  # blocks of activations measured float first
SCAN_KEEP = 4  # the best blocks (then sub-blocks) split again
# an output's SQNR under this is int8 far from fp32 (segmentation logits and text maps measure 15-25 dB): the
# file is written with a warning naming the activations to leave float
SQNR_FLOOR_DB = 10.0
TIMED_RUNS = 20  # per graph, where the answer's speed is timed against fp32 and the all-int8 file


def _db(error: float) -> float:
    return -10.0 * math.log10(error) if error > 0 else math.inf


class Clock:
    """The search's time limit: SECONDS from now (None: no limit). `up` says whether it has passed."""

    def __init__(self, seconds: float | None = None):
        self.end = None if seconds is None else time.perf_counter() + seconds
        self.hit = False

    def up(self) -> bool:
        self.hit = self.hit or (self.end is not None and time.perf_counter() >= self.end)
        return self.hit


def rank_tensors(model: Any, evaluator: Evaluator, candidates: list[str],
                 clock: Clock | None = None) -> list[tuple[str, float]]:
    """CANDIDATES (activations of the QDQ MODEL) with the output SQNR in dB that leaving each float
    gains, best first: blocks in graph order, the best split again, down to single tensors (those
    found when CLOCK's limit passes)."""
    base = _db(evaluator.error(model))

    def gain(names: list[str]) -> float:
        trial = copy_model(model)
        float_tensors(trial, names, evaluator.float_model)
        return _db(evaluator.error(trial)) - base

    singles: dict[str, float] = {}
    blocks = [list(b) for b in np.array_split(np.array(candidates, dtype=object), min(SCAN_BLOCKS, len(candidates)))]
    while blocks and not (clock and clock.up()):
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
    decides something agrees on at least MIN_AGREEMENT of its decisions (with a JUDGE, the share it
    gives instead: the caller's own post-processing), every output's SQNR is at least MIN_SQNR_DB;
    at most MAX_FLOAT activations are left float for it, and the search stops after MAX_SECONDS
    (None: when done) with the closest graph found by then."""

    min_agreement: float | None = None
    min_sqnr_db: float | None = None
    max_float: int = 6
    judge: Judge | None = field(default=None, compare=False)
    max_seconds: float | None = None

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
        if self.max_seconds is not None and not (math.isfinite(self.max_seconds) and self.max_seconds > 0):
            raise ParameterError("{max_seconds}: must be a positive number of seconds", max_seconds=self.max_seconds)
        if self.judge is not None and self.min_agreement is None:
            raise ParameterError("{judge:name} needs {min_agreement:name}: the share its decisions must agree on",
                                 judge=None, min_agreement=None)

    def met(self, fidelity: dict[str, OutputFidelity]) -> bool:
        return self.shortfall(fidelity) == (0.0, 0.0)

    def shortfall(self, fidelity: dict[str, OutputFidelity]) -> tuple[float, float]:
        """How far FIDELITY is from the budget by its own measures: the most an agreement falls under
        min_agreement (a share) and the most an SQNR falls under min_sqnr_db (dB); (0, 0) where met.
        Where no graph meets the budget, the mode's answer is the one with the least (agreement first)."""
        judged = JUDGED in fidelity  # the judge's agreement stands for the outputs' own
        agreement = sqnr = 0.0
        for name, f in fidelity.items():
            if self.min_sqnr_db is not None:
                sqnr = max(sqnr, self.min_sqnr_db - f.sqnr_db)
            if self.min_agreement is not None and f.agreement is not None and judged == (name == JUDGED):
                agreement = max(agreement, self.min_agreement - f.agreement)
        return agreement, sqnr


def restore_fidelity(model: Any, evaluator: Evaluator, budget: FidelityBudget,
                     progress: Callable[[str], None] = lambda _: None) -> tuple[Any, dict]:
    """MODEL (a QDQ graph) with the fewest activations left float that meets BUDGET (or the best
    found within budget.max_float). First the scan's best single tensors one at a time, a tensor
    kept only when it brings the outputs closer on both halves of the check tensors; where that is
    not enough, whole regions of the graph (`_widen`), or a float start (`_float_start`); after
    budget.max_seconds, what was found by then. Returns the graph and what was done."""
    clock, started = Clock(budget.max_seconds), time.perf_counter()
    fidelity = evaluator.fidelity(model)
    record: dict = {"check_tensors": len(evaluator.inputs), "before": {n: f.to_dict() for n, f in fidelity.items()},
                    "float_tensors": []}
    if budget.met(fidelity):
        return model, {**record, "met": True, "graphs_measured": evaluator.graphs,
                       "search_s": round(time.perf_counter() - started, 1)}
    original, closest = model, _Closest(budget, model, [], fidelity)
    progress("scan which activations to leave float")
    ranked = rank_tensors(model, evaluator, quantized_activations(model), clock)
    record["scan"] = [{"tensor": t, "gain_db": round(g, 2)} for t, g in ranked[:20]]
    best = evaluator.half_errors(model)
    kept: list[str] = []
    for name, value in ranked:
        if len(kept) >= budget.max_float or value <= 0 or clock.up():
            break
        trial = copy_model(model)
        float_tensors(trial, [*kept, name], evaluator.float_model)
        errors = evaluator.half_errors(trial)
        if any(e >= b for e, b in zip(errors, best)):
            continue  # leaving it float would not bring the outputs closer on both halves of the check tensors
        kept, best, model = [*kept, name], errors, trial
        fidelity = evaluator.fidelity(model)
        closest.offer(model, kept, fidelity)
        progress(f"{len(kept)} float: {name}")
        if budget.met(fidelity):
            break
    if not budget.met(fidelity) and len(kept) < budget.max_float and not clock.up():
        rest = [t for t in quantized_activations(original) if t not in kept]
        widened = _widen(original, kept, rest, evaluator, budget, best, progress, clock)
        if (widened is None or not budget.met(widened[2])) and not clock.up():
            widened = _float_start(original, kept, rest, evaluator, budget, best, progress, clock) or widened
        if widened is not None:
            model, kept, fidelity = widened
            closest.offer(*widened)
    if closest.shortfall < budget.shortfall(fidelity):
        progress(f"budget not met: the closest graph by its own measure has {len(closest.kept)} float")
        model, kept, fidelity = closest.model, closest.kept, closest.fidelity
        record["closest_by_budget"] = True
    before = set(float_weight_convs(original))
    if weights := [n for n in float_weight_convs(model) if n not in before]:
        record["float_weight_convs"] = weights
    record.update(float_tensors=kept, after={n: f.to_dict() for n, f in fidelity.items()}, met=budget.met(fidelity),
                  graphs_measured=evaluator.graphs, search_s=round(time.perf_counter() - started, 1))
    if clock.hit:
        record["stopped_at_max_seconds"] = budget.max_seconds
    if kept:
        record["speed"] = speed_cost(evaluator.float_model, original, model, evaluator.inputs[0])
    return model, record


class _Closest:
    """The graph closest to BUDGET by its own measure (`FidelityBudget.shortfall`) of those offered,
    the first of equals (the fewest float): the accuracy-aware mode's answer where none meets it and
    the search's last graph is further from it."""

    def __init__(self, budget: FidelityBudget, model: Any, kept: list[str], fidelity: dict[str, OutputFidelity]):
        self.budget, self.model, self.kept, self.fidelity = budget, model, kept, fidelity
        self.shortfall = budget.shortfall(fidelity)

    def offer(self, model: Any, kept: list[str], fidelity: dict[str, OutputFidelity]) -> None:
        shortfall = self.budget.shortfall(fidelity)
        if shortfall < self.shortfall:
            self.model, self.kept, self.fidelity, self.shortfall = model, kept, fidelity, shortfall


def _summary(fidelity: dict[str, OutputFidelity]) -> str:
    """The worst output SQNR and the lowest agreement of FIDELITY, for a progress line."""
    agreements = [f.agreement for f in fidelity.values() if f.agreement is not None]
    worst = min(f.sqnr_db for f in fidelity.values())
    return f"worst SQNR {worst:.1f} dB" + (f", agreement {100 * min(agreements):.2f}%" if agreements else "")


def _widen(original: Any, kept: list[str], rest: list[str], evaluator: Evaluator, budget: FidelityBudget,
           best: tuple[float, ...], progress: Callable[[str], None],
           clock: Clock | None = None) -> tuple[Any, list[str], dict] | None:
    """ORIGINAL with KEPT and whole regions of REST (activations in graph order, SCAN_BLOCKS
    stretches of it) left float, one region at a time, each time the one that brings the outputs
    closest, until BUDGET is met; the last region is then halved while a half still meets it.
    Regions, not single tensors: float and int8 mixed tensor by tensor can end further from fp32
    than either (the int8 parts were calibrated on what fp32 gives them). Taken only if it brings
    the outputs closer than BEST on both halves of the check tensors; else None. Stops where CLOCK's
    limit passes, with the regions found by then."""
    clock = clock or Clock()
    room = budget.max_float - len(kept)
    regions = [list(b) for b in np.array_split(np.array(rest, dtype=object), min(SCAN_BLOCKS, len(rest))) if len(b)]


    def trial(names: list[str]) -> tuple[Any, dict[str, OutputFidelity], float]:
        graph = copy_model(original)
        float_tensors(graph, [*kept, *names], evaluator.float_model, weights=True)
        if not int8_conv_left(graph):
            return None, {}, math.inf  # no int8 model any more: never taken
        return graph, *evaluator.measure(graph)

    chosen: list[str] = []
    found: tuple[Any, dict[str, OutputFidelity], float] | None = None
    while regions and not clock.up():
        fits = [r for r in regions if len(chosen) + len(r) <= room]
        if not fits:
            break
        closest: tuple[Any, dict[str, OutputFidelity], float] = (None, {}, math.inf)
        region = fits[0]
        for candidate in fits:  # the closest, one graph held at a time
            if clock.up():
                break
            measured = trial([*chosen, *candidate])
            if measured[2] < closest[2]:
                closest, region = measured, candidate
        graph, fidelity, error = closest
        if graph is None or (found is not None and error >= found[2]) or clock.hit:
            break  # no region brings the outputs closer, or not all were measured
        regions.remove(region)
        if budget.met(fidelity):
            while len(region) > 1 and not clock.up():  # the shortest half of the region that still meets it
                halves = [list(h) for h in np.array_split(np.array(region, dtype=object), 2)]
                met = [(t, h) for t, h in ((trial([*chosen, *h]), h) for h in halves)
                       if t[0] is not None and budget.met(t[1])]
                if not met:
                    break
                (graph, fidelity, error), region = met[0]
            chosen, found = [*chosen, *region], (graph, fidelity, error)
            progress(f"{len(kept) + len(chosen)} float: {_summary(fidelity)}, budget met")
            break
        chosen, found = [*chosen, *region], (graph, fidelity, error)
        progress(f"{len(kept) + len(chosen)} float: {_summary(fidelity)}, budget not met")
    if found is None or any(e >= b for e, b in zip(evaluator.half_errors(found[0]), best)):
        return None  # not closer to fp32 on both halves of the check tensors: kept as it was
    return found[0], [*kept, *chosen], found[1]


def int8_conv_left(graph: Any) -> bool:
    """Whether one of GRAPH's convs still reads int8 weights: a graph with none is no int8 model, and
    the accuracy-aware mode never gives one as its answer."""
    return len(float_weight_convs(graph)) < sum(n.op_type in CONV_OPS for n in graph.graph.node)


def _float_start(original: Any, kept: list[str], rest: list[str], evaluator: Evaluator, budget: FidelityBudget,
                 best: tuple[float, ...], progress: Callable[[str], None],
                 clock: Clock | None = None) -> tuple[Any, list[str], dict] | None:
    """ORIGINAL with KEPT and the shortest start of REST (activations in graph order) left float, with
    the weights of the ops that then read nothing on the uint8 grid, that meets BUDGET: found by
    halving the start's length; None where the longest start the budget allows does not meet it with a
    conv left int8, or where the start found does not bring the outputs closer than BEST on both
    halves of the check tensors. A start rather than regions in between: where int8 errors add up along the graph (a text
    recogniser's backbone) no region alone brings the outputs back, and the int8 part after a float
    start reads what fp32 gives it, as it was calibrated on. Where CLOCK's limit passes, the shortest
    start found by then."""
    clock = clock or Clock()

    def trial(count: int) -> tuple[Any, dict[str, OutputFidelity]]:
        graph = copy_model(original)
        float_tensors(graph, [*kept, *rest[:count]], evaluator.float_model, weights=True)
        return graph, evaluator.fidelity(graph)

    def met(tried: tuple[Any, dict[str, OutputFidelity]]) -> bool:  # with a conv left int8: else no int8 model
        return budget.met(tried[1]) and int8_conv_left(tried[0])

    short, long = 0, min(budget.max_float - len(kept), len(rest))  # short: not met; long: met
    if long < 1:
        return None
    found = trial(long)
    if not met(found):
        return None
    while long - short > 1 and not clock.up():
        middle = (short + long) // 2
        tried = trial(middle)
        if met(tried):
            long, found = middle, tried
        else:
            short = middle
    if any(e >= b for e, b in zip(evaluator.half_errors(found[0]), best)):
        return None
    progress(f"{len(kept) + long} float (the graph's first {long} activations): {_summary(found[1])}, budget met")
    return found[0], [*kept, *rest[:long]], found[1]


def speed_cost(fp32: Any, int8: Any, kept_float: Any, x: np.ndarray, threads: int = 2) -> dict:
    """onnxruntime's median ms of the float graph FP32, the all-int8 graph INT8 and KEPT_FLOAT on X,
    timed in alternating blocks on THREADS threads: what the float activations cost on this machine
    (`slowdown` against the all-int8 file) and what is left of int8's gain (`speedup_vs_fp32`)."""
    from edgepick.quant.onnx.speed import ort_runner
    from edgepick.runtime.session import median_ms

    ms = median_ms({"fp32_ms": ort_runner(fp32, threads), "all_int8_ms": ort_runner(int8, threads),
                    "kept_float_ms": ort_runner(kept_float, threads)}, x, timed=TIMED_RUNS)
    return {**ms, "slowdown": round(ms["kept_float_ms"] / ms["all_int8_ms"], 3),
            "speedup_vs_fp32": round(ms["fp32_ms"] / ms["kept_float_ms"], 3), "threads": threads}


def slower_than_fp32(speed: dict, floats: int) -> str | None:
    """The one-line warning where the accuracy-aware answer, with FLOATS activations float, runs slower
    than the float model on this machine (SPEED: `speed_cost`'s record); None where it is faster."""
    if speed.get("speedup_vs_fp32", math.inf) >= 1.0:
        return None
    return (f"with {floats} activations float the file runs at {speed['speedup_vs_fp32']:.2f}x fp32's speed on "
            f"onnxruntime on this machine ({speed['kept_float_ms']:g} ms against {speed['fp32_ms']:g} ms, "
            f"{speed['threads']} threads): a lower budget keeps fewer float, or the float model serves better")


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
        if not record["met"]:
            stopped = f", the search stopped after {budget.max_seconds:g} s" if "stopped_at_max_seconds" in record else ""
            print(f"edgepick: warning: the budget is not met on the {len(evaluator.inputs)} check tensors "
                  f"({len(record['float_tensors'])} of at most {budget.max_float} activations float{stopped}); the file "
                  "is the closest found (accuracy_aware in its edgepick.quant)", file=sys.stderr, flush=True)
        if slower := slower_than_fp32(record.get("speed", {}), len(record["float_tensors"])):
            print(f"edgepick: warning: {slower}", file=sys.stderr, flush=True)
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
