"""The calibration pass of ONNX static PTQ: every calibration tensor streamed once through the
float model into a histogram per activation (quant/onnx/calibrate.py), the range rule chosen on the
held-out first tensors (quant/onnx/qdq.py `choose_rule`), the ranges read off."""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from edgepick.progress import StageClock
from edgepick.progress import progress as progress_bar
from edgepick.quant.config import CalibMethod, QuantConfig
from edgepick.quant.onnx.calibrate import Collector, calibrated_tensors, check_memory, release_memory
from edgepick.quant.onnx.evaluator import Evaluator
from edgepick.quant.onnx.inputs import check_tensor
from edgepick.quant.onnx.qdq import choose_rule, exact_tensors


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


def calibrated(prepared: Any, pre: Path, first: np.ndarray, tensors: Iterator[Any], input_shape: tuple[int, ...],
               config: QuantConfig, ops: list[str], exclude: list[str], keep: int, hold: int, total: int | None,
               evaluator: Callable[[list[np.ndarray]], Evaluator], mean_inputs: int, clock: StageClock,
               progress: bool, shared_concat_inputs: bool = False) -> Calibrated:
    """Stream every calibration tensor through PREPARED into a histogram per activation that OPS read
    or write (the first HOLD held out until the rule is chosen on them, EVALUATOR's check tensors),
    and read the ranges off; on the first MEAN_INPUTS, the convs' per-channel output means too.
    CLOCK times the pass ("calibrate") apart from the rule's measurements ("choose_ranges").
    SHARED_CONCAT_INPUTS: each Concat's inputs read on its output's grid (`calibrate.concat_spans`)."""
    with clock("calibrate"):
        sizes = calibrated_tensors(prepared, ops)
        check_memory(prepared, sizes, int(np.prod(input_shape)) * 4 * keep)
        convs = [n.output[0] for n in prepared.graph.node if n.op_type == "Conv"]
        collector = Collector(prepared, sizes, minmax_only=config.calib_method == CalibMethod.MINMAX, means=convs,
                              mean_inputs=mean_inputs, shared_concat_inputs=shared_concat_inputs)
        kept, seen = _calibrate(collector, first, tensors, input_shape, keep, hold, total, progress)
        collector.close()  # choosing the rule needs the memory; the held-out tensors open it again
        held = kept[:hold]
        held_out = bool(held) and collector.seen >= len(held)  # else too few others: the rule is chosen on them
        if not held_out:
            _count_in(collector, held)
    with clock("choose_ranges"):
        rule, record, written = choose_rule(collector, pre, prepared, held, held_out, ops, exclude, config, evaluator,
                                            progress)
    if held_out:
        with clock("calibrate"):
            _count_in(collector, held)
    with clock("choose_ranges"):
        exact = exact_tensors(prepared)
        ranges, means = collector.ranges(rule, exact), collector.channel_means(min(mean_inputs, seen))
        del collector  # its sessions, before the int8 graphs' are made
        release_memory()
    return Calibrated(ranges, kept, seen, {**record, "exact_tensors": len(exact & set(sizes))}, written, means)


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
