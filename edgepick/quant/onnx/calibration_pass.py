"""The calibration pass of ONNX static PTQ: every calibration tensor streamed once through the
float model into a histogram per activation (quant/onnx/calibrate.py), the range rule chosen on the
held-out first tensors (quant/onnx/qdq.py `choose_rule`; where that measure ranks nothing, again on the
bias-corrected files: `ranges_after_correction`), the ranges read off."""

from __future__ import annotations

import itertools
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from edgepick.progress import StageClock
from edgepick.progress import progress as progress_bar
from edgepick.quant.config import CalibMethod, Placement, PtqMethods, QuantConfig
from edgepick.quant.fidelity import ranked_rule
from edgepick.quant.onnx.calibrate import Collector, calibrated_tensors, check_memory, release_memory
from edgepick.quant.onnx.evaluator import Evaluator
from edgepick.quant.onnx.inputs import check_tensor
from edgepick.quant.onnx.qdq import choose_rule, exact_tensors, rule_score
from edgepick.quant.ranges import RangeRule, candidate_rules

# a rule measure under this (dB, before bias correction) ranks the candidates by an error the correction then
# removes (u2netp: docs/quantization.md, Calibration methods)
UNRANKED_DB = 10.0


@dataclass(frozen=True)
class Calibrated:
    """What calibration leaves: each activation's range, the first calibration tensors (kept for the
    measurements and the fidelity check), how many there were, the range rule's record, the graph
    it was chosen on and the float convs' output means."""

    ranges: dict[str, tuple[float, float]]
    kept: list[np.ndarray]
    seen: int
    record: dict
    written: Any | None  # the QDQ graph the rule was chosen on (qdq.qdq_for), None when not chosen
    means: dict[str, list[np.ndarray]]  # fp32's per-channel conv output means on the first tensors, for bias correction
    # every candidate rule's ranges where the rule's measure (before bias correction) left each candidate under
    # UNRANKED_DB: the choice is then made again on the corrected files (`ranges_after_correction`)
    candidates: dict[str, dict[str, tuple[float, float]]] = field(default_factory=dict)


def calibrated(prepared: Any, pre: Path, first: np.ndarray, tensors: Iterator[Any], input_shape: tuple[int, ...],
               config: QuantConfig, ops: list[str], exclude: list[str], keep: int, hold: int, total: int | None,
               evaluator: Callable[[list[np.ndarray]], Evaluator], mean_inputs: int, clock: StageClock,
               progress: bool, placement: Placement = Placement.ALL) -> Calibrated:
    """Stream every calibration tensor through PREPARED into a histogram per activation that OPS read
    or write (the first HOLD held out until the rule is chosen on them, EVALUATOR's check tensors),
    and read the ranges off; on the first MEAN_INPUTS, the convs' per-channel output means too.
    CLOCK times the pass ("calibrate") apart from the rule's measurements ("choose_ranges").
    PLACEMENT joins reads each Concat's inputs on its output's grid (`calibrate.concat_spans`); convs
    and joins leave a conv's output float where no quantized op reads it (`qdq.qdq_model`)."""
    with clock("calibrate"):
        sizes = calibrated_tensors(prepared, ops)
        check_memory(prepared, sizes, int(np.prod(input_shape)) * 4 * keep)
        convs = [n.output[0] for n in prepared.graph.node if n.op_type == "Conv"]
        collector = Collector(prepared, sizes, minmax_only=config.calib_method == CalibMethod.MINMAX, means=convs,
                              mean_inputs=mean_inputs, shared_concat_inputs=placement == Placement.JOINS)
        kept, seen = _calibrate(collector, first, tensors, input_shape, keep, hold, total, progress)
        collector.close()  # choosing the rule needs the memory; the held-out tensors open it again
        held = kept[:hold]
        held_out = bool(held) and collector.seen >= len(held)  # else too few others: the rule is chosen on them
        if not held_out:
            _count_in(collector, held)
    with clock("choose_ranges"):
        rule, record, written = choose_rule(collector, pre, prepared, held, held_out, ops, exclude, config, evaluator,
                                            progress, conv_outputs=placement == Placement.ALL)
    if held_out:
        with clock("calibrate"):
            _count_in(collector, held)
    with clock("choose_ranges"):
        exact = exact_tensors(prepared)
        ranges, means = collector.ranges(rule, exact), collector.channel_means(min(mean_inputs, seen))
        scores = [c["balanced_sqnr_db"] for c in record.get("candidates", [])]
        unranked = bool(scores) and mean_inputs > 0 and all(s is not None and s < UNRANKED_DB for s in scores)
        candidates = {str(r): collector.ranges(r, exact) for r in candidate_rules(config)} if unranked else {}
        del collector  # its sessions, before the int8 graphs' are made
        release_memory()
    return Calibrated(ranges, kept, seen, {**record, "exact_tensors": len(exact & set(sizes))}, written, means,
                      candidates)


def _count_in(collector: Collector, held: list[np.ndarray]) -> None:
    """The held-out tensors (the first calibration tensors) into COLLECTOR, numbered as they came."""
    for k, x in enumerate(held):
        collector.add(x, k)


def _calibrate(collector: Collector, first: np.ndarray, rest: Iterator[Any], shape: tuple[int, ...], keep: int,
               hold: int, total: int | None, progress: bool) -> tuple[list[np.ndarray], int]:
    """Every calibration tensor, checked, into COLLECTOR but the first HOLD (held out for choosing the
    rule, counted in later); returns the first KEEP tensors and how many there were."""
    kept: list[np.ndarray] = []
    bar = progress_bar(desc="calibrate", total=total, unit="tensor", enabled=progress)
    seen = 0
    for k, x in enumerate(itertools.chain([first], rest)):
        x = first if k == 0 else check_tensor(x, shape, f"calibration tensor {k + 1}")
        if len(kept) < keep:
            kept.append(x)
        if k >= hold:
            collector.add(x, k)
        seen += 1
        bar.update()
    bar.close()
    return kept, seen


def ranges_after_correction(cal: Calibrated, build: Callable[..., tuple[Any, dict]], methods: PtqMethods,
                            evaluator: Evaluator, progress: bool) -> tuple[Any, dict, Calibrated]:
    """The graph BUILD makes with CAL's ranges and METHODS; where CAL holds every candidate rule's
    ranges (their measure before bias correction ranked nothing: UNRANKED_DB), each
    made with its correction, and the one whose outputs come closest to fp32's on the check tensors
    kept where it comes within UNRANKED_DB of them (ranked as `choose_rule` ranks: the closest, unless one
    changes fewer decisions beyond chance; else that measure ranks nothing either, and the
    first choice stands: on picodet, whose files stay under it, the closest after correction agreed
    less once AdaRound was applied), every rule's SQNR after correction in the ranges record."""
    int8, done = build(methods)
    if not cal.candidates:
        return int8, done, cal
    chosen = cal.record["rule"]
    made = {chosen: (int8, done, cal.ranges)}  # the graphs of the closest and of the fewest decisions changed so far
    scores = {chosen: rule_score(evaluator, int8, RangeRule.parse(chosen))}
    for rule, ranges in cal.candidates.items():
        if rule != chosen:
            graph, built = build(methods, ranges)
            made[rule], scores[rule] = (graph, built, ranges), rule_score(evaluator, graph, RangeRule.parse(rule))
            leaders = {str(min(scores.values(), key=key).rule) for key in (lambda s: s.error, lambda s: s.rank)}
            made = {r: g for r, g in made.items() if r in leaders or r == chosen}
    rule = str(ranked_rule(list(scores.values())).rule)
    if scores[rule].error > 10.0 ** (-UNRANKED_DB / 10.0):
        rule = chosen
    int8, done, ranges = made[rule]
    if progress:
        print(f"ranges: every rule far from fp32 before bias correction; after it: {rule}",
              file=sys.stderr, flush=True)
    after = {r: round(s.sqnr_db, 2) if s.error > 0 else None for r, s in scores.items()}
    record = {**cal.record, "rule": rule, "chosen_before_correction": chosen, "after_correction": after}
    return int8, done, replace(cal, ranges=ranges, record=record, candidates={})

