"""Placement auto: which tensors of an .onnx model go on the int8 grid, chosen by timing the target
engine on this machine.

Which placement runs faster depends on the engine and the model: onnxruntime runs a quantized
activation on an integer kernel and a float one between a DequantizeLinear and a
QuantizeLinear, while OpenVINO fuses the float activations it recognises into its int8 convs
(docs/quantization.md). So each candidate (`Placement.ALL`, `CONVS`, `JOINS`) is made, each file
is timed on the target engine in alternating blocks (p50, the engine's own threads), and the
fastest whose worst output stays within PLACEMENT_FIDELITY_DB of the closest candidate's SQNR, or
at PLACEMENT_ENOUGH_DB or more, is kept, unless another within PLACEMENT_TRADE_DB of the closest
runs PLACEMENT_TRADE_SPEEDUP times as fast (`pick_placement`). The choice, every candidate's time
and fidelity and the machine go into the file's metadata. For OpenVINO the candidates are made from the float model
with the forms its CPU plugin needs to keep int8 kernels (`openvino_forms`), how many of each
recorded with the choice, and each candidate's hardswish left float is written in the form OpenVINO
fuses into its conv (`float_forms_for`).
"""

from __future__ import annotations

import json
import math
import sys
import tempfile
from collections.abc import Callable, Iterable, Mapping, Sized
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from edgepick.errors import EdgepickError, ParameterError
from edgepick.files import atomic_path
from edgepick.machine import cpu_summary
from edgepick.progress import StageClock
from edgepick.quant.config import GeluForm, OnnxOptions, Placement, Target
from edgepick.quant.onnx.accuracy import SQNR_FLOOR_DB
from edgepick.quant.onnx.inputs import check_tensor
from edgepick.quant.onnx.speed import TIMING_THREADS, ort_runner

PLACEMENT_CANDIDATES = (Placement.ALL, Placement.CONVS, Placement.JOINS)
# a candidate whose worst output SQNR is this much under the closest candidate's is not taken for its speed ...
PLACEMENT_FIDELITY_DB = 1.0
# ... unless it is this close to fp32 all the same: output noise under 1.8% of the signal's RMS, where no decision
# of the conformance suite's models moved (benchmarks/results/conformance/, the placements file)
PLACEMENT_ENOUGH_DB = 35.0
# ... and one up to PLACEMENT_TRADE_DB further is taken where it runs PLACEMENT_TRADE_SPEEDUP times as fast as that
# choice: a few dB bought with a much slower file (ddddocr's recogniser on OpenVINO, docs/quantization.md)
PLACEMENT_TRADE_DB, PLACEMENT_TRADE_SPEEDUP = 3.0, 1.25


def engine_runner(path: Path, target: Target, threads: int = TIMING_THREADS) -> Callable[[np.ndarray], object]:
    """A function running the ONNX file at PATH on TARGET with THREADS threads (OpenVINO's float
    parts in f32, as the runtime runs them)."""
    if target == Target.OPENVINO:
        try:
            import openvino as ov
        except ImportError:
            raise ParameterError("{target}: OpenVINO is not installed (pip install 'edgepick[peers]')",
                                 target=target) from None
        from edgepick.runtime.session import openvino_config

        compiled = ov.Core().compile_model(str(path), "CPU", openvino_config(threads))
        request = compiled.create_infer_request()
        return lambda x: request.infer({0: x})
    return ort_runner(path, threads)


def worst_sqnr(fidelity: Mapping[str, Mapping]) -> float:
    """The lowest SQNR over a result's outputs (an exact output counts as infinite)."""
    values = [f["sqnr_db"] for f in fidelity.values()]
    return min((math.inf if v is None else v for v in values), default=math.inf)


def choose_placement(quantize: Callable[..., Any], model: str | Path, calib: Iterable[np.ndarray], out: str | Path,
                     options: OnnxOptions, progress: bool, **given: Any) -> Any:
    """Make MODEL's int8 file with each candidate placement (QUANTIZE: quantize_onnx_static, given
    GIVEN), time each on options.target, and write the fastest that keeps fidelity to OUT. Returns
    its result, with the choice in its quant record."""
    from edgepick.export.checks import check_onnx_out
    from edgepick.runtime.session import median_ms

    check_onnx_out(out, model)
    tensors = calib if isinstance(calib, Sized) and iter(calib) is not calib else list(calib)
    first = next(iter(tensors), None)
    made: dict[Placement, Any] = {}
    spelt: dict[Placement, int] = {}  # hardswish left float, in OpenVINO's form
    failed: dict[str, str] = {}
    clock = StageClock()
    with tempfile.TemporaryDirectory(prefix="edgepick-placement-") as tmp:
        with clock("prepare"):
            source, forms = (openvino_forms(model, Path(tmp)) if options.target == Target.OPENVINO else (model, {}))
        candidates = {}
        for placement in PLACEMENT_CANDIDATES:  # AdaRound, where the file is far from fp32, for the chosen one only
            candidate = candidates[placement] = replace(options, placement=placement, target=Target.ONNXRUNTIME,
                                                        gelu=options.gelu if placement == Placement.ALL else GeluForm.FLOAT,
                                                        adaround_if_far=False, time_against_fp32=False)
            if progress:
                print(f"placement auto: make the {placement} file", file=sys.stderr, flush=True)
            try:
                made[placement] = quantize(source, tensors, Path(tmp) / f"{placement}.onnx", options=candidate,
                                           progress=progress, **given)
                spelt[placement] = float_forms_for(options.target, Path(made[placement].out))
            except EdgepickError as exc:
                if not made and placement == PLACEMENT_CANDIDATES[-1]:
                    raise
                failed[placement.value] = str(exc)
        if not made:
            raise ParameterError("{placement}: no candidate placement could be made", placement=options.placement)
        x = check_tensor(first, tuple(next(iter(made.values())).input_shape), "calibration tensor 1")
        with clock("time_placements"):
            runners = {p.value: engine_runner(Path(r.out), options.target) for p, r in made.items()}
            ms = median_ms(runners, x, timed=20)
        sqnr = {p.value: worst_sqnr(r.fidelity) for p, r in made.items()}
        chosen = Placement(pick_placement(ms, sqnr))
        record = {"target": options.target.value, "chosen": chosen.value, "threads": TIMING_THREADS,
                  "machine": cpu_summary(),
                  "candidates": [{"placement": p.value, "p50_ms": ms[p.value],
                                  "worst_sqnr_db": None if math.isinf(sqnr[p.value]) else round(sqnr[p.value], 2)}
                                 for p in made],
                  **({"failed": failed} if failed else {}), **forms,
                  **({"float_hardswish_spelt_out": spelt[chosen]} if spelt.get(chosen) else {})}
        if progress:
            times = ", ".join(f"{p} {ms[p]:.1f} ms" for p in ms)
            print(f"placement auto: {chosen} on {options.target} ({times})", file=sys.stderr, flush=True)
        result, again = made[chosen], []
        # with a budget each candidate has tried AdaRound already (the accuracy-aware mode's first step)
        if options.adaround_if_far and given.get("budget") is None and sqnr[chosen.value] < SQNR_FLOOR_DB:
            if progress:
                print(f"placement auto: {chosen} again, with AdaRound tried", file=sys.stderr, flush=True)
            result = quantize(source, tensors, Path(tmp) / "chosen.onnx", progress=progress, **given,
                              options=replace(candidates[chosen], adaround_if_far=True))
            again.append(result)
            float_forms_for(options.target, Path(result.out))
        quant = {**result.quant, "adaround_if_far": options.adaround_if_far, "placement_choice": record}
        with clock("write_check"):
            _write_with(Path(result.out), Path(out), quant)
    stages = StageClock()
    for candidate in [*made.values(), *again]:  # every candidate made in full (the chosen again), the choice's stages
        stages.add(candidate.stage_s)
    stages.add(clock.seconds)
    return replace(result, out=str(out), size_bytes=Path(out).stat().st_size, quant=quant, stage_s=stages.to_dict())


def pick_placement(p50_ms: Mapping[str, float], worst_sqnr_db: Mapping[str, float]) -> str:
    """The fastest candidate at `fidelity_threshold_db` or above; or, where one within PLACEMENT_TRADE_DB
    of the closest candidate runs PLACEMENT_TRADE_SPEEDUP times as fast as that, the fastest such."""
    close = [p for p in p50_ms if worst_sqnr_db[p] >= fidelity_threshold_db(worst_sqnr_db.values())]
    chosen = min(close, key=p50_ms.__getitem__)
    near = [p for p in p50_ms if worst_sqnr_db[p] >= max(worst_sqnr_db.values()) - PLACEMENT_TRADE_DB
            and p50_ms[p] * PLACEMENT_TRADE_SPEEDUP <= p50_ms[chosen]]
    return min(near, key=p50_ms.__getitem__) if near else chosen


def fidelity_threshold_db(worst_sqnr_db: Iterable[float]) -> float:
    """The worst output SQNR a candidate needs to be chosen for its speed: within PLACEMENT_FIDELITY_DB
    of the closest candidate's, or PLACEMENT_ENOUGH_DB, whichever is lower."""
    return min(max(worst_sqnr_db) - PLACEMENT_FIDELITY_DB, PLACEMENT_ENOUGH_DB)


def openvino_forms(model: str | Path, tmp: Path) -> tuple[str | Path, dict[str, int]]:
    """MODEL with the float rewrites that keep OpenVINO's int8 kernels (quant/onnx/rewrite.py
    subsample_before_strided_pointwise_convs), written under TMP by its own name when there was
    any to make; and how many were made, for the record."""
    import onnx

    from edgepick.quant.onnx.rewrite import subsample_before_strided_pointwise_convs

    proto = onnx.load(str(model))
    count = subsample_before_strided_pointwise_convs(proto)
    if not count:
        return model, {}
    path = tmp / "openvino-forms" / Path(model).name
    path.parent.mkdir()
    onnx.save(proto, str(path))
    return path, {"subsampled_pointwise_convs": count}


def float_forms_for(target: Target, path: Path) -> int:
    """Rewrite the int8 file at PATH, in place, into the float forms TARGET runs fastest: for OpenVINO
    each hardswish left float spelt out as exporters write it (quant/onnx/rewrite.py
    spell_float_hardswish). Returns how many were rewritten."""
    if target != Target.OPENVINO:
        return 0
    import onnx

    from edgepick.quant.onnx.rewrite import spell_float_hardswish

    model = onnx.load(str(path))
    count = spell_float_hardswish(model)
    if count:
        onnx.save(model, str(path))
    return count


def _write_with(source: Path, out: Path, quant: dict) -> None:
    """Copy the int8 file SOURCE to OUT with QUANT as its edgepick.quant record."""
    import onnx

    model = onnx.load(str(source))
    entry = next(p for p in model.metadata_props if p.key == "edgepick.quant")
    entry.value = json.dumps(quant)
    with atomic_path(out) as path:
        onnx.save(model, str(path))
